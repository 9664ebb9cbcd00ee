// vcsim mesh import and export: lumen meshes from STL (ASCII and binary), OBJ and PLY files.
#pragma once

#include "vcsim/collision.h"

#include <string>

namespace vcsim {

struct MeshLoadOptions {
  double unit_scale = 1.0;  // metres per file unit, e.g. 1e-3 for files in millimetres
};

// Loads a triangle mesh (format from the extension: .stl, .obj, .ply, any case), scales it to
// metres, joins vertices with identical file coordinates and runs check_and_repair (its
// findings go to *report if given). A missing, empty, truncated or malformed file, non-finite
// coordinates or an unknown extension throw InputError naming the path and what was expected.
TriangleMesh load_mesh(const std::string& path, const MeshLoadOptions& options = {},
                       MeshReport* report = nullptr);

// Writers. `unit_scale` is metres per file unit as for loading (1e-3 writes millimetres), so
// the same value round-trips. Throw InputError if the file cannot be written.
void write_stl(const TriangleMesh& mesh, const std::string& path, bool binary = true,
               double unit_scale = 1.0);
void write_obj(const TriangleMesh& mesh, const std::string& path, double unit_scale = 1.0);

}  // namespace vcsim
