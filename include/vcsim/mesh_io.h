// vcsim mesh import and export: lumen meshes from STL (ASCII and binary), OBJ and PLY files.
#pragma once

#include "vcsim/collision.h"

#include <cstdint>
#include <span>
#include <string>

namespace vcsim {

struct MeshLoadOptions {
  double unit_scale = 1.0;  // metres per file unit, e.g. 1e-3 for files in millimetres
  // false: the mesh as read (vertices joined, indices and coordinates checked) without
  // check_and_repair, for a caller that repairs it first (repair_mesh, `vcsim anatomy repair`).
  bool check = true;
};

// Loads a triangle mesh (format from the extension: .stl, .obj, .ply, any case), scales it to
// metres, joins vertices with identical file coordinates and runs check_and_repair (its
// findings go to *report if given). A missing, empty, truncated or malformed file, non-finite
// coordinates or an unknown extension throw InputError naming the path and what was expected.
TriangleMesh load_mesh(const std::string& path, const MeshLoadOptions& options = {},
                       MeshReport* report = nullptr);
// The same from the file's bytes; `ext` is the format ("stl", "obj" or "ply") and `source` names
// the file in errors.
TriangleMesh load_mesh_bytes(std::span<const char> bytes, const std::string& ext,
                             const std::string& source, const MeshLoadOptions& options = {},
                             MeshReport* report = nullptr);

// Limits of a mesh file (docs/collision.md), checked on its bytes before it is parsed: its size,
// and the triangles and vertices its header or lines declare (polygons counted as the triangles
// they become). A file beyond them is refused, never read into memory in full.
inline constexpr std::uint64_t kMaxMeshFileBytes = 1ull << 30;  // 1 GiB
inline constexpr std::uint64_t kMaxMeshTriangles = 2'000'000;
inline constexpr std::uint64_t kMaxMeshVertices = 3 * kMaxMeshTriangles;

// Writers. `unit_scale` is metres per file unit as for loading (1e-3 writes millimetres), so
// the same value round-trips. Throw InputError if the file cannot be written.
void write_stl(const TriangleMesh& mesh, const std::string& path, bool binary = true,
               double unit_scale = 1.0);
void write_obj(const TriangleMesh& mesh, const std::string& path, double unit_scale = 1.0);
// ASCII PLY (vertex x y z as double, faces as vertex_indices lists).
void write_ply(const TriangleMesh& mesh, const std::string& path, double unit_scale = 1.0);

}  // namespace vcsim
