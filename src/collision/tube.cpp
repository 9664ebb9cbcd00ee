// Procedural tubes: a circle swept along a centreline, the vessel phantom of tests and
// experiments.
#include "vcsim/collision.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace vcsim {

namespace {

constexpr const char* kTube = "TubeSpec";

// Point and tangent at arc length s along a polyline with cumulative lengths `cum`.
Vec3 point_at(const std::vector<Vec3>& p, const std::vector<double>& cum, double s) {
  s = std::clamp(s, 0.0, cum.back());
  const auto it = std::upper_bound(cum.begin(), cum.end(), s);
  const auto i = static_cast<std::size_t>(std::clamp<std::ptrdiff_t>(
      it - cum.begin() - 1, 0, static_cast<std::ptrdiff_t>(p.size()) - 2));
  const double len = cum[i + 1] - cum[i];
  const double f = len > 0.0 ? (s - cum[i]) / len : 0.0;
  return p[i] + f * (p[i + 1] - p[i]);
}

// Any unit vector perpendicular to t.
Vec3 perpendicular(const Vec3& t) {
  const Vec3 axis = std::abs(t.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY();
  return (axis - axis.dot(t) * t).normalized();
}

}  // namespace

TriangleMesh make_tube(const TubeSpec& spec) {
  require_positive(spec.radius, kTube, "radius");
  if (spec.sides < 3) throw InputError(kTube, "sides", "at least 3");
  if (spec.rings < 2) throw InputError(kTube, "rings", "at least 2");
  // Centreline without repeated points.
  std::vector<Vec3> p;
  for (std::size_t i = 0; i < spec.centreline.size(); ++i) {
    const Vec3& q = spec.centreline[i];
    if (!q.allFinite())
      throw InputError(kTube, "centreline[" + std::to_string(i) + "]", "finite coordinates");
    if (p.empty() || (q - p.back()).norm() > 0.0) p.push_back(q);
  }
  if (p.size() < 2) throw InputError(kTube, "centreline", "at least 2 distinct points");
  std::vector<double> cum(p.size(), 0.0);
  for (std::size_t i = 1; i < p.size(); ++i) cum[i] = cum[i - 1] + (p[i] - p[i - 1]).norm();
  const double length = cum.back();

  // Ring centres evenly spaced by arc length; tangents by central differences over half a ring
  // spacing, which follow a finely sampled curve smoothly across its polyline corners.
  const int nr = spec.rings;
  const int ns = spec.sides;
  const double ds = length / (nr - 1);
  std::vector<Vec3> x(nr), t(nr);
  for (int i = 0; i < nr; ++i) {
    const double s = ds * i;
    x[i] = point_at(p, cum, s);
    const Vec3 d = point_at(p, cum, s + 0.5 * ds) - point_at(p, cum, s - 0.5 * ds);
    t[i] = d.normalized();
  }

  // Rotation-minimising frames by the double reflection method (Wang, Juettler, Zheng and Liu,
  // ACM TOG 2008): no twist is introduced along the tube, whatever the curve does.
  std::vector<Vec3> u(nr);
  u[0] = perpendicular(t[0]);
  for (int i = 0; i + 1 < nr; ++i) {
    const Vec3 v1 = x[i + 1] - x[i];
    const double c1 = v1.squaredNorm();
    const Vec3 rl = u[i] - (2.0 / c1) * v1.dot(u[i]) * v1;
    const Vec3 tl = t[i] - (2.0 / c1) * v1.dot(t[i]) * v1;
    const Vec3 v2 = t[i + 1] - tl;
    const double c2 = v2.squaredNorm();
    Vec3 r = c2 > 1e-30 ? Vec3(rl - (2.0 / c2) * v2.dot(rl) * v2) : rl;
    u[i + 1] = (r - r.dot(t[i + 1]) * t[i + 1]).normalized();
  }

  TriangleMesh m;
  m.vertices.reserve(static_cast<std::size_t>(nr) * ns + 1);
  for (int i = 0; i < nr; ++i) {
    const Vec3 v = t[i].cross(u[i]);  // (u, v, t) right-handed
    for (int j = 0; j < ns; ++j) {
      const double th = 2.0 * std::numbers::pi * j / ns;
      m.vertices.push_back(x[i] + spec.radius * (std::cos(th) * u[i] + std::sin(th) * v));
    }
  }
  // With (u, v, t) right-handed, (V(i,j), V(i,j+1), V(i+1,j)) winds outward; the reverse faces
  // the lumen.
  auto V = [ns](int i, int j) { return i * ns + (j % ns); };
  for (int i = 0; i + 1 < nr; ++i) {
    for (int j = 0; j < ns; ++j) {
      m.triangles.push_back({V(i, j), V(i + 1, j), V(i, j + 1)});
      m.triangles.push_back({V(i, j + 1), V(i + 1, j), V(i + 1, j + 1)});
    }
  }
  if (spec.cap_end) {
    const int c = m.num_vertices();
    m.vertices.push_back(x[nr - 1]);
    for (int j = 0; j < ns; ++j) m.triangles.push_back({c, V(nr - 1, j + 1), V(nr - 1, j)});
  }
  m.recompute_normals();
  return m;
}

std::vector<Vec3> bent_centreline(double straight1, double bend_radius, double bend_angle,
                                  double straight2, double max_segment) {
  constexpr const char* kSrc = "bent_centreline";
  require_nonnegative(straight1, kSrc, "straight1");
  require_positive(bend_radius, kSrc, "bend_radius");
  require_finite(bend_angle, kSrc, "bend_angle");
  if (bend_angle < 0.0 || bend_angle >= 2.0 * std::numbers::pi)
    throw InputError(kSrc, "bend_angle", "an angle in [0, 2 pi) rad");
  require_nonnegative(straight2, kSrc, "straight2");
  require_positive(max_segment, kSrc, "max_segment");
  auto pieces = [&](double len) {
    return std::max(1, static_cast<int>(std::ceil(len / max_segment)));
  };

  std::vector<Vec3> p{Vec3::Zero()};
  if (straight1 > 0.0) {
    const int n = pieces(straight1);
    for (int k = 1; k <= n; ++k) p.push_back(Vec3(0.0, 0.0, straight1 * k / n));
  }
  // Arc about the centre (R, 0, straight1), turning from +z toward +x.
  if (bend_angle > 0.0) {
    const int n = pieces(bend_radius * bend_angle);
    for (int k = 1; k <= n; ++k) {
      const double a = bend_angle * k / n;
      p.push_back(
          Vec3(bend_radius * (1.0 - std::cos(a)), 0.0, straight1 + bend_radius * std::sin(a)));
    }
  }
  if (straight2 > 0.0) {
    const Vec3 start = p.back();
    const Vec3 dir(std::sin(bend_angle), 0.0, std::cos(bend_angle));
    const int n = pieces(straight2);
    for (int k = 1; k <= n; ++k) p.push_back(start + dir * (straight2 * k / n));
  }
  return p;
}

TriangleMesh make_bent_tube(const BentTubeSpec& spec) {
  constexpr const char* kSrc = "BentTubeSpec";
  require_positive(spec.radius, kSrc, "radius");
  require_positive(spec.ring_spacing, kSrc, "ring_spacing");
  if (spec.bend_angle > 0.0 && !(spec.bend_radius > spec.radius))
    throw InputError(kSrc, "bend_radius", "larger than the tube radius (else the wall folds)");
  TubeSpec tube;
  tube.centreline = bent_centreline(spec.straight1, spec.bend_radius, spec.bend_angle,
                                    spec.straight2, 0.25 * spec.ring_spacing);
  const double length = spec.straight1 + spec.bend_radius * spec.bend_angle + spec.straight2;
  tube.radius = spec.radius;
  tube.sides = spec.sides;
  tube.rings = std::max(2, static_cast<int>(std::lround(length / spec.ring_spacing)) + 1);
  tube.cap_end = spec.cap_end;
  return make_tube(tube);
}

}  // namespace vcsim
