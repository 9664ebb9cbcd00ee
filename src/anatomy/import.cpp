// Patient meshes: a lumen mesh from a file with centrelines from our JSON or a SimVascular .pth
// path file (Vascular Model Repository), radii measured on the mesh where the file has none.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "field.h"
#include "vcsim/anatomy.h"
#include "vcsim/mesh_io.h"

namespace vcsim {

void measure_radii_on_mesh(VesselTree& tree, const TriangleMesh& mesh, const std::string& source) {
  if (mesh.normals.size() != mesh.triangles.size())
    throw InputError(source, "mesh", "expected a checked mesh (normals set)");
  AabbTree bvh;
  bvh.build(mesh);
  for (std::size_t i = 0; i < tree.segments.size(); ++i) {
    VesselSegment& s = tree.segments[i];
    if (s.radii.size() == s.points.size()) continue;
    s.radii.clear();
    for (std::size_t k = 0; k < s.points.size(); ++k) {
      const SphereContact c = bvh.query_sphere(mesh, s.points[k], 0.05);
      if (!c.touching || c.centre_outside)
        throw InputError(
            source, "segments[" + std::to_string(i) + "].points[" + std::to_string(k) + "]",
            "expected the centreline inside the lumen mesh (within 50 mm of its wall)");
      s.radii.push_back(c.distance);
    }
  }
  // A path starting inside an earlier one's lumen branches from it.
  for (std::size_t i = 1; i < tree.segments.size(); ++i) {
    VesselSegment& s = tree.segments[i];
    if (s.parent >= 0) continue;
    double best = 0.0;
    for (std::size_t j = 0; j < i; ++j) {
      const double f = internal::segment_field(tree.segments[j], s.points.front());
      if (f < best) {
        best = f;
        s.parent = static_cast<int>(j);
      }
    }
    if (s.parent < 0)
      throw InputError(
          source, "segments[" + std::to_string(i) + "]",
          "expected the path '" + s.name + "' to start inside an earlier path's lumen");
  }
  tree.target.distance =
      std::min(tree.target.distance, segment_length(tree.segments[tree.target.segment]));
  validate_tree(tree, source);
}

Lumen import_lumen(const std::string& mesh_path, const VesselTree& tree, double unit_scale) {
  const double t0 = now_us();
  validate_tree(tree, mesh_path);
  Lumen lu;
  MeshLoadOptions opt;
  opt.unit_scale = unit_scale;
  lu.mesh = load_mesh(mesh_path, opt, &lu.report);
  lu.cache_status = "off";
  lu.ends = open_ends(tree);
  // Each vertex belongs to the segment whose swept spheres it is nearest to.
  const auto pieces = internal::make_pieces(tree, {});
  const int nv = lu.mesh.num_vertices();
  lu.vertex_segment.assign(nv, 0);
  lu.vertex_arc.assign(nv, 0.0);
  for (int v = 0; v < nv; ++v) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& pc : pieces) {
      const auto e = internal::eval_piece(pc, lu.mesh.vertices[v]);
      if (std::abs(e.f) < best) {
        best = std::abs(e.f);
        lu.vertex_segment[v] = pc.segment;
        lu.vertex_arc[v] = pc.s0 + e.t * (pc.b - pc.a).norm();
      }
    }
  }
  internal::finish_lumen(tree, lu);
  lu.build_seconds = (now_us() - t0) * 1e-6;
  return lu;
}

namespace {
std::string lower_extension(const std::string& path) {
  std::string e = std::filesystem::path(path).extension().string();
  std::transform(e.begin(), e.end(), e.begin(), [](unsigned char c) { return std::tolower(c); });
  return e;
}
}  // namespace

VesselTree load_mesh_centrelines(const std::string& centrelines_path, const std::string& mesh_path,
                                 double unit_scale) {
  if (lower_extension(centrelines_path) != ".pth") return load_vessel_tree(centrelines_path);
  VesselTree tree = load_pth_paths(centrelines_path, unit_scale);
  MeshLoadOptions mo;
  mo.unit_scale = unit_scale;
  measure_radii_on_mesh(tree, load_mesh(mesh_path, mo), centrelines_path);
  return tree;
}

}  // namespace vcsim
