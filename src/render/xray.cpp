// X-ray materials and the closed meshes the renderer draws: tubes for instruments, the lumen
// closed per segment, body parts. No GL here.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <unordered_map>

#include "vcsim/render.h"
#include "vcsim/units.h"

namespace vcsim {

std::string_view to_string(XrayMaterial m) {
  switch (m) {
    case XrayMaterial::kSoftTissue:
      return "soft_tissue";
    case XrayMaterial::kLung:
      return "lung";
    case XrayMaterial::kBone:
      return "bone";
    case XrayMaterial::kBlood:
      return "blood";
    case XrayMaterial::kIodine:
      return "iodine";
    case XrayMaterial::kNitinol:
      return "nitinol";
    case XrayMaterial::kSteel:
      return "steel";
    case XrayMaterial::kPtIr:
      return "pt_ir";
    case XrayMaterial::kCoCr:
      return "cocr";
  }
  return "unknown";
}

double attenuation_per_m(XrayMaterial m, BeamEnergy e) {
  // clinical.md "X-ray imaging", cm^-1 at 60 / 80 keV, computed from NIST tables.
  const bool e60 = e == BeamEnergy::k60keV;
  double per_cm = 0.0;
  switch (m) {
    case XrayMaterial::kSoftTissue:
    case XrayMaterial::kBlood:
      per_cm = e60 ? 0.22 : 0.19;
      break;
    // Inflated lung: soft tissue scaled by density 0.26 / 1.06 g/cm^3 (estimate).
    case XrayMaterial::kLung:
      per_cm = (e60 ? 0.22 : 0.19) * 0.26 / 1.06;
      break;
    case XrayMaterial::kBone:
      per_cm = e60 ? 0.60 : 0.43;
      break;
    case XrayMaterial::kIodine:
      per_cm = e60 ? 2.65 : 1.23;
      break;  // 350 mgI/ml, over blood
    case XrayMaterial::kNitinol:
      per_cm = e60 ? 7.6 : 3.8;
      break;
    case XrayMaterial::kSteel:
      per_cm = e60 ? 10.1 : 5.0;
      break;
    case XrayMaterial::kPtIr:
      per_cm = e60 ? 93.0 : 187.0;
      break;
    // L-605 (above tungsten's K-edge at 69.5 keV the 80 keV value is the higher).
    case XrayMaterial::kCoCr:
      per_cm = e60 ? 14.8 : 15.4;
      break;
  }
  return per_cm * 100.0;
}

std::array<float, kNumXrayMaterials> line_integral_weights(BeamEnergy e) {
  std::array<float, kNumXrayMaterials> w{};
  const double soft = attenuation_per_m(XrayMaterial::kSoftTissue, e);
  for (int k = 0; k < kNumXrayMaterials; ++k) {
    const auto m = static_cast<XrayMaterial>(k);
    double v = attenuation_per_m(m, e);
    // Parts inside the torso replace the soft tissue already counted along the ray; iodine is a
    // term added to blood.
    if (m != XrayMaterial::kSoftTissue && m != XrayMaterial::kIodine) v -= soft;
    w[k] = static_cast<float>(v);
  }
  return w;
}

// ---------------------------------------------------------------------------------------------

TriangleMesh tube_mesh(std::span<const Vec3> nodes_in, std::span<const double> radii, int sides) {
  if (sides < 3) sides = 3;
  // Drop repeated nodes (a zero-length edge has no tangent).
  std::vector<Vec3> p;
  std::vector<double> r;
  for (std::size_t i = 0; i < nodes_in.size(); ++i) {
    if (!p.empty() && (nodes_in[i] - p.back()).norm() < 1e-9) continue;
    p.push_back(nodes_in[i]);
    r.push_back(radii.size() == nodes_in.size() ? radii[i] : (radii.empty() ? 0.0 : radii[0]));
  }
  TriangleMesh m;
  const int n = static_cast<int>(p.size());
  if (n < 2) return m;
  constexpr double kTwoPi = 2.0 * kPi;
  // Rings with frames by parallel transport, so the tube does not twist.
  Vec3 t = (p[1] - p[0]).normalized();
  Vec3 nrm = t.unitOrthogonal();
  for (int i = 0; i < n; ++i) {
    const Vec3 ti = (i == 0)       ? (p[1] - p[0]).normalized()
                    : (i == n - 1) ? (p[i] - p[i - 1]).normalized()
                                   : (p[i + 1] - p[i - 1]).normalized();
    nrm = (nrm - nrm.dot(ti) * ti);
    nrm = nrm.norm() > 1e-12 ? nrm.normalized() : ti.unitOrthogonal();
    t = ti;
    const Vec3 b = t.cross(nrm);
    for (int j = 0; j < sides; ++j) {
      const double a = kTwoPi * j / sides;
      m.vertices.push_back(p[i] + r[i] * (std::cos(a) * nrm + std::sin(a) * b));
    }
  }
  auto at = [sides](int i, int j) { return i * sides + (j % sides); };
  // (n, b, t) is right-handed, so rings run counter-clockwise seen from +t: these windings face
  // out.
  for (int i = 0; i + 1 < n; ++i)
    for (int j = 0; j < sides; ++j) {
      m.triangles.push_back({at(i, j), at(i, j + 1), at(i + 1, j + 1)});
      m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i + 1, j)});
    }
  const int c0 = m.num_vertices();
  m.vertices.push_back(p.front());
  const int c1 = m.num_vertices();
  m.vertices.push_back(p.back());
  for (int j = 0; j < sides; ++j) {
    m.triangles.push_back({c0, at(0, j + 1), at(0, j)});
    m.triangles.push_back({c1, at(n - 1, j), at(n - 1, j + 1)});
  }
  m.recompute_normals();
  return m;
}

int cap_boundary_loops(TriangleMesh& mesh) {
  auto key = [](int a, int b) {
    return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(a)) << 32) |
           static_cast<std::uint32_t>(b);
  };
  std::unordered_map<std::uint64_t, int> directed;
  directed.reserve(mesh.triangles.size() * 3);
  for (const auto& t : mesh.triangles)
    for (int e = 0; e < 3; ++e) ++directed[key(t[e], t[(e + 1) % 3])];
  // Boundary edges: a -> b with no b -> a. Several may leave one vertex (pinched loops).
  std::unordered_multimap<int, int> next;
  for (const auto& t : mesh.triangles)
    for (int e = 0; e < 3; ++e) {
      const int a = t[e], b = t[(e + 1) % 3];
      if (!directed.count(key(b, a))) next.emplace(a, b);
    }
  int loops = 0;
  while (!next.empty()) {
    // Walk one loop, consuming edges, until it comes back to its start.
    std::vector<std::pair<int, int>> edges;
    auto it = next.begin();
    const int start = it->first;
    int a = it->first, b = it->second;
    next.erase(it);
    edges.emplace_back(a, b);
    while (b != start) {
      auto nx = next.find(b);
      if (nx == next.end()) break;  // an open chain (inconsistent winding): close it anyway
      a = nx->first;
      b = nx->second;
      next.erase(nx);
      edges.emplace_back(a, b);
    }
    Vec3 c = Vec3::Zero();
    for (const auto& e : edges) c += mesh.vertices[e.first];
    c /= static_cast<double>(edges.size());
    const int ci = mesh.num_vertices();
    mesh.vertices.push_back(c);
    // The cap runs each boundary edge the other way, so the closed surface keeps one winding.
    for (const auto& e : edges) mesh.triangles.push_back({e.second, e.first, ci});
    if (b != start) mesh.triangles.push_back({start, b, ci});
    ++loops;
  }
  mesh.recompute_normals();
  return loops;
}

XrayMesh lumen_xray_mesh(const Lumen& lumen, LumenXraySource* source) {
  XrayMesh out;
  out.name = "lumen";
  out.material = XrayMaterial::kBlood;
  const TriangleMesh& src = lumen.mesh;
  int num_segments = 0;
  for (int s : lumen.triangle_segment) num_segments = std::max(num_segments, s + 1);
  std::vector<std::vector<int>> by_segment(num_segments);
  for (int t = 0; t < src.num_triangles(); ++t) by_segment[lumen.triangle_segment[t]].push_back(t);
  std::vector<int> local(src.num_vertices(), -1);
  if (source) {
    *source = {};
    source->cap_start.push_back(0);
  }
  for (int s = 0; s < num_segments; ++s) {
    if (by_segment[s].empty()) continue;
    // This segment's triangles as their own mesh, closed at junctions and open ends.
    TriangleMesh part;
    std::vector<int> used;
    for (int t : by_segment[s]) {
      std::array<int, 3> tri{};
      for (int k = 0; k < 3; ++k) {
        const int v = src.triangles[t][k];
        if (local[v] < 0) {
          local[v] = part.num_vertices();
          part.vertices.push_back(src.vertices[v]);
          used.push_back(v);
        }
        tri[k] = local[v];
      }
      part.triangles.push_back(tri);
    }
    for (int v : used) local[v] = -1;
    const int copied = part.num_vertices(), open_triangles = part.num_triangles();
    cap_boundary_loops(part);
    const int base = out.mesh.num_vertices();
    if (source) {
      source->vertex.insert(source->vertex.end(), used.begin(), used.end());
      source->vertex.insert(source->vertex.end(), part.vertices.size() - used.size(), -1);
      // Each cap is a fan (loop edge, centre): its centre is the vertex past the copied ones.
      for (int c = copied; c < part.num_vertices(); ++c) {
        source->cap_centre.push_back(base + c);
        for (int t = open_triangles; t < part.num_triangles(); ++t)
          if (part.triangles[t][2] == c) source->cap_loop.push_back(base + part.triangles[t][1]);
        source->cap_start.push_back(static_cast<int>(source->cap_loop.size()));
      }
    }
    out.mesh.vertices.insert(out.mesh.vertices.end(), part.vertices.begin(), part.vertices.end());
    out.vertex_group.insert(out.vertex_group.end(), part.vertices.size(), s);
    // The lumen's normals face into the vessel; the renderer wants them out of the blood.
    for (const auto& t : part.triangles)
      out.mesh.triangles.push_back({base + t[0], base + t[2], base + t[1]});
  }
  out.mesh.recompute_normals();
  return out;
}

LumenXrayMorph make_lumen_xray_morph(const LumenXraySource& source, const LesionMorph& morph) {
  LumenXrayMorph m;
  std::unordered_map<int, int> index;  // Lumen vertex -> its place in the morph
  for (std::size_t k = 0; k < morph.vertices.size(); ++k)
    index.emplace(morph.vertices[k], static_cast<int>(k));
  std::vector<char> moved(source.vertex.size(), 0);
  for (std::size_t v = 0; v < source.vertex.size(); ++v) {
    const auto it = source.vertex[v] >= 0 ? index.find(source.vertex[v]) : index.end();
    if (it == index.end()) continue;
    m.vertex.push_back(static_cast<int>(v));
    m.morph.push_back(it->second);
    moved[v] = 1;
  }
  m.cap_start.push_back(0);
  for (std::size_t c = 0; c < source.cap_centre.size(); ++c) {
    const auto loop =
        std::span(source.cap_loop)
            .subspan(static_cast<std::size_t>(source.cap_start[c]),
                     static_cast<std::size_t>(source.cap_start[c + 1] - source.cap_start[c]));
    if (std::none_of(loop.begin(), loop.end(), [&](int v) { return moved[v] != 0; })) continue;
    m.cap_centre.push_back(source.cap_centre[c]);
    m.cap_loop.insert(m.cap_loop.end(), loop.begin(), loop.end());
    m.cap_start.push_back(static_cast<int>(m.cap_loop.size()));
  }
  return m;
}

void apply_lumen_xray_morph(const LumenXrayMorph& m, std::span<const Vec3> morphed,
                            std::span<Vec3> render_vertices) {
  for (std::size_t i = 0; i < m.vertex.size(); ++i)
    render_vertices[m.vertex[i]] = morphed[m.morph[i]];
  for (std::size_t c = 0; c < m.cap_centre.size(); ++c) {
    Vec3 sum = Vec3::Zero();
    for (int k = m.cap_start[c]; k < m.cap_start[c + 1]; ++k) sum += render_vertices[m.cap_loop[k]];
    const int n = m.cap_start[c + 1] - m.cap_start[c];
    if (n > 0) render_vertices[m.cap_centre[c]] = sum / n;
  }
}

XrayMesh body_part_mesh(const BodyPart& part, float bone_fill) {
  XrayMesh x;
  x.name = part.name;
  x.mesh = part.mesh;
  switch (part.material) {
    case Material::kSoftTissue:
    case Material::kHeart:
      x.material = XrayMaterial::kSoftTissue;
      break;
    case Material::kLung:
      x.material = XrayMaterial::kLung;
      break;
    case Material::kBone:
      x.material = XrayMaterial::kBone;
      x.fill = bone_fill;
      break;
    case Material::kBlood:
      x.material = XrayMaterial::kBlood;
      break;
  }
  return x;
}

std::vector<XrayMesh> body_xray_meshes(const std::vector<BodyPart>& parts, float bone_fill) {
  std::vector<XrayMesh> out;
  for (const BodyPart& p : parts) {
    const bool embedded_soft = (p.material == Material::kSoftTissue ||
                                p.material == Material::kHeart || p.material == Material::kBlood) &&
                               p.name != "torso";
    if (!embedded_soft) out.push_back(body_part_mesh(p, bone_fill));
  }
  return out;
}

namespace {

// The part of a polyline between arc lengths s0 < s1, with interpolated radii.
void sub_polyline(const std::vector<Vec3>& p, const std::vector<double>& r, double s0, double s1,
                  std::vector<Vec3>& q, std::vector<double>& rq) {
  q.clear();
  rq.clear();
  auto rad = [&](std::size_t i) { return r.size() == p.size() ? r[i] : r.at(0); };
  double s = 0.0;
  for (std::size_t i = 0; i + 1 < p.size(); ++i) {
    const double len = (p[i + 1] - p[i]).norm();
    const double a = s, b = s + len;
    if (len > 0.0 && b > s0 && a < s1) {
      const double u0 = std::clamp((s0 - a) / len, 0.0, 1.0);
      const double u1 = std::clamp((s1 - a) / len, 0.0, 1.0);
      if (q.empty()) {
        q.push_back(p[i] + u0 * (p[i + 1] - p[i]));
        rq.push_back(rad(i) + u0 * (rad(i + 1) - rad(i)));
      }
      q.push_back(p[i] + u1 * (p[i + 1] - p[i]));
      rq.push_back(rad(i) + u1 * (rad(i + 1) - rad(i)));
    }
    s = b;
  }
}

}  // namespace

std::vector<XrayMesh> instrument_xray_meshes(const InstrumentVisual& inst) {
  std::vector<XrayMesh> out;
  if (inst.nodes.size() < 2 || inst.radii.empty()) return out;
  double length = 0.0;
  for (std::size_t i = 0; i + 1 < inst.nodes.size(); ++i)
    length += (inst.nodes[i + 1] - inst.nodes[i]).norm();
  out.push_back(
      {inst.name + "_shaft", tube_mesh(inst.nodes, inst.radii), inst.shaft, inst.shaft_fill, {}});
  std::vector<Vec3> q;
  std::vector<double> rq;
  if (inst.radiopaque_length > 0.0) {
    sub_polyline(inst.nodes, inst.radii, std::max(0.0, length - inst.radiopaque_length), length, q,
                 rq);
    out.push_back(
        {inst.name + "_radiopaque", tube_mesh(q, rq), inst.radiopaque, inst.radiopaque_fill, {}});
  }
  for (double d : inst.marker_from_tip) {
    const double c = length - d;
    sub_polyline(inst.nodes, inst.radii, c - 0.5 * inst.marker_length, c + 0.5 * inst.marker_length,
                 q, rq);
    for (double& x : rq) x *= inst.marker_radius_factor;
    if (q.size() >= 2)
      out.push_back({inst.name + "_marker", tube_mesh(q, rq, 12), XrayMaterial::kPtIr, 1.0f, {}});
  }
  return out;
}

XrayMesh balloon_xray_mesh(std::span<const Vec3> nodes, std::span<const double> radii,
                           float contrast, int sides) {
  // Iodine counts its own term (the inflation medium's water is soft tissue, which the torso
  // already counts), weighted by its fraction of 350 mgI/ml.
  return {"balloon", tube_mesh(nodes, radii, sides), XrayMaterial::kIodine, contrast, {}};
}

XrayMesh stent_xray_mesh(std::span<const Vec3> rings, std::span<const double> radii, double wall,
                         float fill, int sides) {
  XrayMesh x{"stent", tube_mesh(rings, radii, sides), XrayMaterial::kCoCr, fill, {}};
  if (x.mesh.triangles.empty()) return x;
  // The inner surface, wound inward: with the outer one the closed surface of the wall. The same
  // nodes give tube_mesh the same rings and frames, so the two walls stay parallel.
  std::vector<double> inner(rings.size());
  for (std::size_t k = 0; k < rings.size(); ++k) {
    const double r = radii.size() == rings.size() ? radii[k] : radii[0];
    inner[k] = std::max(0.5 * r, r - wall);
  }
  const TriangleMesh in = tube_mesh(rings, inner, sides);
  const int base = x.mesh.num_vertices();
  x.mesh.vertices.insert(x.mesh.vertices.end(), in.vertices.begin(), in.vertices.end());
  for (const auto& t : in.triangles)
    x.mesh.triangles.push_back({base + t[0], base + t[2], base + t[1]});
  x.mesh.recompute_normals();
  return x;
}

float stent_fill(const StentSpec& spec, BeamEnergy e) {
  const double mu = e == BeamEnergy::k60keV ? spec.attenuation_60kev : spec.attenuation_80kev;
  const double scale = mu > 0.0 ? mu / attenuation_per_m(XrayMaterial::kCoCr, e) : 1.0;
  return static_cast<float>(spec.metal_coverage * scale);
}

std::vector<InstrumentVisual> demo_instruments(const VesselTree& tree) {
  std::vector<InstrumentVisual> out;
  const int lm = tree.find("left_main");
  if (tree.access.segment < 0) return out;
  if (lm >= 0) {
    InstrumentVisual cath;
    cath.name = "guiding_catheter";
    cath.nodes = route(tree, tree.access, TreeLocation{lm, 1.0e-3}, 2.0e-3);
    cath.radii = {1.0e-3};              // 6F: 2 mm outer diameter
    cath.shaft = XrayMaterial::kSteel;  // the braid; the polymer is close to soft tissue
    cath.shaft_fill = 0.04f;            // braid volume fraction of the wall (estimate)
    out.push_back(cath);
  }
  if (tree.target.segment >= 0) {
    InstrumentVisual wire;
    wire.name = "guidewire";
    // The wire crosses the target lesion by 20 mm, as before a balloon is advanced.
    TreeLocation tip = tree.target;
    tip.distance = std::min(tip.distance + 20e-3, segment_length(tree.segments[tip.segment]));
    wire.nodes = route(tree, tree.access, tip, 1.0e-3);
    wire.radii = {0.178e-3};  // 0.014 inch
    wire.shaft = XrayMaterial::kNitinol;
    wire.radiopaque_length = 30e-3;
    wire.radiopaque = XrayMaterial::kPtIr;
    wire.radiopaque_fill = 0.5f;
    out.push_back(wire);
  }
  return out;
}

std::vector<float> left_coronary_contrast(const VesselTree& tree, float c) {
  std::vector<float> out(tree.segments.size(), 0.0f);
  const int lm = tree.find("left_main");
  for (int i = 0; i < tree.num_segments(); ++i)
    for (int j = i; j >= 0; j = tree.segments[j].parent)
      if (j == lm) {
        out[i] = c;
        break;
      }
  return out;
}

Vec3 left_coronary_centre(const VesselTree& tree) {
  const std::vector<float> left = left_coronary_contrast(tree, 1.0f);
  Vec3 sum = Vec3::Zero();
  int count = 0;
  for (int i = 0; i < tree.num_segments(); ++i)
    if (left[i] > 0.0f)
      for (const Vec3& q : tree.segments[i].points) {
        sum += q;
        ++count;
      }
  if (count > 0) return sum / count;
  return tree.heart ? tree.heart->centre : Vec3::Zero();
}

}  // namespace vcsim
