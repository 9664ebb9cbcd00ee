// Shared helpers for the collision tests: reference answers computed the slow, obvious way.
#pragma once

#include "vcsim/collision.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

namespace vcsim::test {

// Straight tube along +z from the origin.
inline TriangleMesh straight_tube(double radius, double length, int sides, int rings,
                                  bool cap = false) {
  TubeSpec spec;
  spec.centreline = {Vec3::Zero(), Vec3(0.0, 0.0, length)};
  spec.radius = radius;
  spec.sides = sides;
  spec.rings = rings;
  spec.cap_end = cap;
  return make_tube(spec);
}

// Distance from p to a polyline, and the closest point on it.
inline double polyline_distance(const std::vector<Vec3>& line, const Vec3& p, Vec3* closest) {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i + 1 < line.size(); ++i) {
    const Vec3 d = line[i + 1] - line[i];
    const double t = std::clamp((p - line[i]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    const Vec3 q = line[i] + t * d;
    const double dist = (p - q).norm();
    if (dist < best) {
      best = dist;
      if (closest) *closest = q;
    }
  }
  return best;
}

struct BruteForce {
  double d_min = std::numeric_limits<double>::infinity();
  int closest = -1;
  int touching = 0;
  Vec3 weighted_normal = Vec3::Zero();
};

// Every triangle, no tree: the closest distance, the overlapping triangles and the contact
// normal with the documented weight (depth times area inside the sphere).
inline BruteForce brute_force(const TriangleMesh& m, const Vec3& c, double r) {
  BruteForce b;
  for (int t = 0; t < m.num_triangles(); ++t) {
    const auto& tri = m.triangles[t];
    const Vec3& p0 = m.vertices[tri[0]];
    const Vec3& p1 = m.vertices[tri[1]];
    const Vec3& p2 = m.vertices[tri[2]];
    const double d = (c - closest_point_on_triangle(c, p0, p1, p2).point).norm();
    if (d < b.d_min) {
      b.d_min = d;
      b.closest = t;
    }
    if (d < r) {
      ++b.touching;
      const double area = 0.5 * (p1 - p0).cross(p2 - p0).norm();
      const double w = (r - d) * std::min(area, std::numbers::pi * (r * r - d * d));
      b.weighted_normal += w * m.normals[t];
    }
  }
  return b;
}

}  // namespace vcsim::test
