// Closest point on a triangle against dense sampling.
#include "vcsim/collision.h"

#include <gtest/gtest.h>

#include <random>

namespace vcsim {
namespace {

Vec3 random_vec(std::mt19937& rng, double scale) {
  std::uniform_real_distribution<double> u(-scale, scale);
  return Vec3(u(rng), u(rng), u(rng));
}

// The exact closest point can never be farther than the best of a dense barycentric sampling,
// and never closer than that by more than the sampling spacing.
TEST(ClosestPointOnTriangle, MatchesDenseSampling) {
  std::mt19937 rng(12345);
  constexpr int kSamples = 150;
  for (int trial = 0; trial < 300; ++trial) {
    const Vec3 a = random_vec(rng, 1.0);
    const Vec3 b = random_vec(rng, 1.0);
    const Vec3 c = random_vec(rng, 1.0);
    const Vec3 p = random_vec(rng, 2.0);
    const ClosestPoint cp = closest_point_on_triangle(p, a, b, c);
    const double exact = (p - cp.point).norm();

    double sampled = std::numeric_limits<double>::infinity();
    for (int i = 0; i <= kSamples; ++i) {
      for (int j = 0; i + j <= kSamples; ++j) {
        const double u = static_cast<double>(i) / kSamples;
        const double v = static_cast<double>(j) / kSamples;
        sampled = std::min(sampled, (p - (a + u * (b - a) + v * (c - a))).norm());
      }
    }
    const double spacing = std::max({(b - a).norm(), (c - a).norm(), (c - b).norm()}) / kSamples;
    EXPECT_LE(exact, sampled + 1e-12) << "trial " << trial;
    EXPECT_GE(exact, sampled - 2.0 * spacing) << "trial " << trial;

    // The point lies on the triangle: barycentric coordinates in [0, 1].
    const Vec3 n = (b - a).cross(c - a);
    const double area2 = n.squaredNorm();
    const double v = (cp.point - a).cross(c - a).dot(n) / area2;
    const double w = (b - a).cross(cp.point - a).dot(n) / area2;
    EXPECT_GE(v, -1e-9);
    EXPECT_GE(w, -1e-9);
    EXPECT_LE(v + w, 1.0 + 1e-9);
    EXPECT_NEAR((cp.point - a).dot(n), 0.0, 1e-9 * std::sqrt(area2));
  }
}

TEST(ClosestPointOnTriangle, RegionsOfATriangle) {
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  auto region = [&](const Vec3& p) { return closest_point_on_triangle(p, a, b, c).region; };
  EXPECT_EQ(region(Vec3(0.2, 0.2, 1.0)), TriangleRegion::kFace);
  EXPECT_EQ(region(Vec3(-1, -1, 0.3)), TriangleRegion::kVertexA);
  EXPECT_EQ(region(Vec3(2, -0.5, 0)), TriangleRegion::kVertexB);
  EXPECT_EQ(region(Vec3(-0.5, 2, 0)), TriangleRegion::kVertexC);
  EXPECT_EQ(region(Vec3(0.5, -1, 0)), TriangleRegion::kEdgeAB);
  EXPECT_EQ(region(Vec3(-1, 0.5, 0)), TriangleRegion::kEdgeCA);
  EXPECT_EQ(region(Vec3(1, 1, 0)), TriangleRegion::kEdgeBC);
  const ClosestPoint f = closest_point_on_triangle(Vec3(0.2, 0.3, -2.0), a, b, c);
  EXPECT_TRUE(f.point.isApprox(Vec3(0.2, 0.3, 0.0)));
}

TEST(ClosestPointOnTriangle, DegenerateTriangleGivesFinitePoint) {
  const Vec3 a(0, 0, 0), b(1, 0, 0), c(2, 0, 0);
  const ClosestPoint cp = closest_point_on_triangle(Vec3(0.5, 1, 0), a, b, c);
  EXPECT_TRUE(cp.point.allFinite());
  const ClosestPoint same = closest_point_on_triangle(Vec3(0.5, 1, 0), a, a, a);
  EXPECT_TRUE(same.point.isApprox(a));
}

}  // namespace
}  // namespace vcsim
