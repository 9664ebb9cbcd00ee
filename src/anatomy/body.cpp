// Closed body meshes for imaging (torso, lungs, heart, spine, ribs, sternum, diaphragm) placed
// from the vessel tree: the heart is the tree's heart model, the spine follows the descending
// aorta, ribs hang from the spine. Sizes are typical adult values (docs/anatomy.md).
#include <algorithm>
#include <cmath>

#include "field.h"
#include "vcsim/anatomy.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

// Flips every triangle if the enclosed signed volume is negative (normals must face outward).
void orient_outward(TriangleMesh& m) {
  double vol = 0.0;
  for (const auto& t : m.triangles)
    vol += m.vertices[t[0]].dot(m.vertices[t[1]].cross(m.vertices[t[2]]));
  if (vol < 0.0)
    for (auto& t : m.triangles) std::swap(t[1], t[2]);
  m.recompute_normals();
}

// Ellipsoid with semi-axes r along the columns of R (orthonormal), centred at c.
TriangleMesh ellipsoid(const Vec3& c, const Mat3& R, const Vec3& r, int rings = 24,
                       int sectors = 36) {
  TriangleMesh m;
  m.vertices.push_back(c + R * Vec3(0, 0, -r.z()));
  for (int i = 1; i < rings; ++i) {
    const double th = kPi * i / rings - 0.5 * kPi;
    for (int j = 0; j < sectors; ++j) {
      const double ph = 2.0 * kPi * j / sectors;
      m.vertices.push_back(c + R * Vec3(r.x() * std::cos(th) * std::cos(ph),
                                        r.y() * std::cos(th) * std::sin(ph), r.z() * std::sin(th)));
    }
  }
  m.vertices.push_back(c + R * Vec3(0, 0, r.z()));
  const int top = m.num_vertices() - 1;
  auto at = [&](int i, int j) { return 1 + (i - 1) * sectors + (j % sectors); };
  for (int j = 0; j < sectors; ++j) m.triangles.push_back({0, at(1, j + 1), at(1, j)});
  for (int i = 1; i + 1 < rings; ++i)
    for (int j = 0; j < sectors; ++j) {
      m.triangles.push_back({at(i, j), at(i, j + 1), at(i + 1, j + 1)});
      m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i + 1, j)});
    }
  for (int j = 0; j < sectors; ++j)
    m.triangles.push_back({top, at(rings - 1, j), at(rings - 1, j + 1)});
  orient_outward(m);
  return m;
}

// A solid tube along a polyline with an elliptical cross-section (semi-axes a, b; b along the
// frame's second axis) and flat caps; frames by parallel transport.
TriangleMesh solid_tube(const std::vector<Vec3>& line, double a, double b, int sides,
                        const Vec3& first_normal = Vec3::Zero()) {
  TriangleMesh m;
  const int n = static_cast<int>(line.size());
  Vec3 t0 = (line[1] - line[0]).normalized();
  Vec3 u = first_normal.norm() > 0 ? Vec3(first_normal - first_normal.dot(t0) * t0)
                                   : internal::any_perpendicular(t0);
  u.normalize();
  for (int i = 0; i < n; ++i) {
    const Vec3 t = (line[std::min(i + 1, n - 1)] - line[std::max(i - 1, 0)]).normalized();
    u = (u - u.dot(t) * t).normalized();  // parallel transport (projection)
    const Vec3 w = t.cross(u);
    for (int k = 0; k < sides; ++k) {
      const double ph = 2.0 * kPi * k / sides;
      m.vertices.push_back(line[i] + a * std::cos(ph) * u + b * std::sin(ph) * w);
    }
  }
  for (int i = 0; i + 1 < n; ++i)
    for (int k = 0; k < sides; ++k) {
      const int p = i * sides + k, q = i * sides + (k + 1) % sides;
      m.triangles.push_back({p, q, q + sides});
      m.triangles.push_back({p, q + sides, p + sides});
    }
  const int c0 = m.num_vertices();
  m.vertices.push_back(line.front());
  m.vertices.push_back(line.back());
  for (int k = 0; k < sides; ++k) {
    m.triangles.push_back({c0, (k + 1) % sides, k});
    m.triangles.push_back({c0 + 1, (n - 1) * sides + k, (n - 1) * sides + (k + 1) % sides});
  }
  orient_outward(m);
  return m;
}

void append(TriangleMesh& dst, const TriangleMesh& src) {
  const int off = dst.num_vertices();
  dst.vertices.insert(dst.vertices.end(), src.vertices.begin(), src.vertices.end());
  for (auto t : src.triangles) dst.triangles.push_back({t[0] + off, t[1] + off, t[2] + off});
  dst.normals.insert(dst.normals.end(), src.normals.begin(), src.normals.end());
}

}  // namespace

std::string_view to_string(Material m) {
  switch (m) {
    case Material::kSoftTissue:
      return "soft_tissue";
    case Material::kLung:
      return "lung";
    case Material::kHeart:
      return "heart";
    case Material::kBone:
      return "bone";
    case Material::kBlood:
      return "blood";
  }
  return "soft_tissue";
}

std::vector<BodyPart> build_body_context(const VesselTree& tree) {
  if (!tree.heart) throw InputError(tree.name, "heart", "a heart model is needed for the body");
  const HeartModel& h = *tree.heart;
  // Vessel extent and the descending aorta (points of aorta segments behind the heart).
  Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
  std::vector<Vec3> desc;
  for (const auto& s : tree.segments)
    for (const Vec3& p : s.points) {
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
      if (s.kind == VesselKind::kAorta && p.y() > h.centre.y() + 30 * kMm) desc.push_back(p);
    }
  // Spine behind and right of the descending aorta (constant beyond its ends).
  auto spine_at = [&](double z) {
    if (desc.empty()) return Vec3(0.0, h.centre.y() + 100 * kMm, z);
    const Vec3* best = &desc.front();
    for (const Vec3& p : desc)
      if (std::abs(p.z() - z) < std::abs(best->z() - z)) best = &p;
    return Vec3(best->x() - 12 * kMm, best->y() + 30 * kMm, z);
  };
  const double z_top = hi.z() + 20 * kMm, z_bot = lo.z() - 40 * kMm;
  std::vector<BodyPart> parts;

  // Torso: an elliptical cylinder 350 x 260 mm around the spine's anterior, groin to neck.
  {
    const Vec3 sc = spine_at(h.centre.z());
    std::vector<Vec3> line = {Vec3(0.0, sc.y() - 95 * kMm, z_bot),
                              Vec3(0.0, sc.y() - 95 * kMm, z_top)};
    parts.push_back(
        {"torso", Material::kSoftTissue, solid_tube(line, 175 * kMm, 130 * kMm, 48, Vec3::UnitX())});
  }
  // Lungs: either side of the heart and mediastinum.
  const Mat3 I = Mat3::Identity();
  parts.push_back(
      {"lung_left", Material::kLung,
       ellipsoid(Vec3(h.centre.x() + 70 * kMm, h.centre.y() + 35 * kMm, h.centre.z() + 75 * kMm), I,
                 Vec3(48, 70, 115) * kMm)});
  parts.push_back({"lung_right", Material::kLung,
                   ellipsoid(Vec3(-95 * kMm, h.centre.y() + 35 * kMm, h.centre.z() + 80 * kMm), I,
                             Vec3(52, 72, 120) * kMm)});
  // Heart: the tree's model (the coronaries run on its surface).
  {
    Mat3 R;
    R.col(2) = h.axis;
    R.col(0) = h.anterior;
    R.col(1) = h.axis.cross(h.anterior);
    parts.push_back({"heart", Material::kHeart,
                     ellipsoid(h.centre, R, Vec3(h.radii.y(), h.radii.z(), h.radii.x()))});
  }
  // Spine: vertebral bodies (cylinders 22 mm tall, 6 mm discs) from the sacrum to the neck.
  {
    TriangleMesh spine;
    for (double z = z_bot + 20 * kMm; z + 22 * kMm < z_top; z += 28 * kMm) {
      const Vec3 c = spine_at(z + 11 * kMm);
      const double r = (z < h.centre.z() - 120 * kMm ? 22.0 : 17.0) * kMm;  // lumbar wider
      append(spine, solid_tube({Vec3(c.x(), c.y(), z), Vec3(c.x(), c.y(), z + 22 * kMm)}, r, r, 16));
    }
    parts.push_back({"spine", Material::kBone, spine});
  }
  // Ribs: ten pairs of 10 mm round bars curving from the spine to the front, sloping down.
  {
    TriangleMesh ribs;
    const double z0 = h.centre.z() + 140 * kMm;
    for (int k = 0; k < 10; ++k) {
      const double z = z0 - k * 26 * kMm;
      const Vec3 sp = spine_at(z);
      const double half_width = (110.0 + 5.0 * std::min(k, 6)) * kMm;
      for (double side : {-1.0, 1.0}) {
        std::vector<Vec3> line;
        for (int i = 0; i <= 16; ++i) {
          const double a = kPi * i / 16.0;  // 0 at the spine, pi at the front
          line.emplace_back(side * (15 * kMm + half_width * std::sin(a)),
                            sp.y() + (1.0 - std::cos(a)) * 0.5 * (-85 * kMm - sp.y()),
                            z - 45 * kMm * (1.0 - std::cos(a)) * 0.5);
        }
        append(ribs, solid_tube(line, 5 * kMm, 5 * kMm, 8));
      }
    }
    parts.push_back({"ribs", Material::kBone, ribs});
  }
  // Sternum: a 30 x 12 x 170 mm bar in front of the heart.
  {
    const double y = h.centre.y() - h.radii.y() - 35 * kMm;
    parts.push_back(
        {"sternum", Material::kBone,
         solid_tube({Vec3(0, y, h.centre.z() - 20 * kMm), Vec3(0, y, h.centre.z() + 150 * kMm)},
                    15 * kMm, 6 * kMm, 4, Vec3::UnitX())});
  }
  // Diaphragm: a dome whose top lies just under the heart's inferior surface.
  {
    const double z_heart_low = h.centre.z() - std::abs(h.axis.z()) * h.radii.x() - 15 * kMm;
    parts.push_back({"diaphragm", Material::kSoftTissue,
                     ellipsoid(Vec3(0.0, h.centre.y() + 30 * kMm, z_heart_low - 40 * kMm), I,
                               Vec3(150, 110, 40) * kMm)});
  }
  return parts;
}

}  // namespace vcsim
