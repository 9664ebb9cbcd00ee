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

namespace {

// Value of attribute `name` in the XML tag text `tag` (e.g. x="1.5"); false if absent.
bool attribute(const std::string& tag, const std::string& name, std::string& value) {
  std::size_t p = 0;
  while ((p = tag.find(name, p)) != std::string::npos) {
    const bool start_ok = p == 0 || std::isspace(static_cast<unsigned char>(tag[p - 1]));
    std::size_t q = p + name.size();
    while (q < tag.size() && std::isspace(static_cast<unsigned char>(tag[q]))) ++q;
    if (start_ok && q < tag.size() && tag[q] == '=') {
      ++q;
      while (q < tag.size() && std::isspace(static_cast<unsigned char>(tag[q]))) ++q;
      if (q < tag.size() && (tag[q] == '"' || tag[q] == '\'')) {
        const std::size_t e = tag.find(tag[q], q + 1);
        if (e == std::string::npos) return false;
        value = tag.substr(q + 1, e - q - 1);
        return true;
      }
    }
    p += name.size();
  }
  return false;
}

double parse_number(const std::string& s, const std::string& src, const std::string& field) {
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != s.size())
    throw InputError(src, field, "expected a number, got '" + s + "'");
  return require_finite(v, src, field);
}

}  // namespace

VesselTree load_pth_paths(const std::string& path, double unit_scale) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw InputError(path, "file", "expected a readable SimVascular .pth file");
  std::stringstream ss;
  ss << f.rdbuf();
  const std::string text = ss.str();
  VesselTree t;
  t.name = std::filesystem::path(path).stem().string();
  // Each <path ...> element holds <path_point> elements with a <pos x= y= z= /> each.
  std::size_t at = 0;
  int index = 0;
  while ((at = text.find("<path ", at)) != std::string::npos) {
    const std::size_t tag_end = text.find('>', at);
    const std::size_t end = text.find("</path>", at);
    if (tag_end == std::string::npos || end == std::string::npos)
      throw InputError(path, "path", "expected a closed <path> element");
    VesselSegment seg;
    std::string id;
    seg.name = t.name;
    if (attribute(text.substr(at, tag_end - at), "id", id) && index > 0) seg.name += "_" + id;
    if (index > 0 && !attribute(text.substr(at, tag_end - at), "id", id))
      seg.name += "_" + std::to_string(index);
    std::size_t p = at;
    int k = 0;
    while ((p = text.find("<path_point", p)) != std::string::npos && p < end) {
      const std::size_t pos = text.find("<pos", p);
      const std::size_t pos_end = pos == std::string::npos ? pos : text.find('>', pos);
      if (pos == std::string::npos || pos_end == std::string::npos || pos > end)
        throw InputError(path, "path_point[" + std::to_string(k) + "]", "expected a <pos x y z/>");
      const std::string tag = text.substr(pos, pos_end - pos);
      Vec3 v;
      for (int a = 0; a < 3; ++a) {
        const std::string axis(1, "xyz"[a]);
        std::string val;
        const std::string field = "path_point[" + std::to_string(k) + "].pos." + axis;
        if (!attribute(tag, axis, val)) throw InputError(path, field, "missing");
        v[a] = parse_number(val, path, field) * unit_scale;
      }
      if (seg.points.empty() || (v - seg.points.back()).norm() > 1e-9) seg.points.push_back(v);
      p = pos_end;
      ++k;
    }
    if (seg.points.size() < 2)
      throw InputError(path, "path[" + std::to_string(index) + "]",
                       "expected at least 2 path points");
    t.segments.push_back(std::move(seg));
    at = end;
    ++index;
  }
  if (t.segments.empty()) throw InputError(path, "path", "no <path> element found");
  t.access = {0, 0.0};
  t.target = {t.num_segments() - 1, 0.0};
  return t;
}

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

bool is_mesh_file(const std::string& path) {
  const std::string e = lower_extension(path);
  return e == ".stl" || e == ".obj" || e == ".ply";
}

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
