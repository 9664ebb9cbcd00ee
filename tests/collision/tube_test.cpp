// Procedural tubes and sphere contacts against them, checked with the analytic geometry of the
// faceted (polygonal) cross-section and against the smooth cylinder within the faceting error.
#include "test_util.h"
#include "vcsim/collision.h"

#include <gtest/gtest.h>

#include <numbers>

namespace vcsim {
namespace {

using std::numbers::pi;
using test::straight_tube;

constexpr double kR = 2e-3;  // lumen radius
constexpr double kL = 40e-3;
constexpr int kSides = 32;

// For a straight tube along z built by make_tube, vertex j sits at angle 2 pi j / n about the
// axis, measured from +x toward +y; facet k spans vertices k, k+1 and its plane lies
// R cos(pi / n) from the axis.
double facet_mid_angle(int k, int n) {
  return (2.0 * k + 1.0) * pi / n;
}

// Distance from an interior point (polar e, phi) to the polygon wall: the nearest facet line.
double polygon_wall_distance(double e, double phi, double radius, int n) {
  double best = std::numeric_limits<double>::infinity();
  for (int k = 0; k < n; ++k)
    best = std::min(best, radius * std::cos(pi / n) - e * std::cos(phi - facet_mid_angle(k, n)));
  return best;
}

Vec3 polar(double e, double phi, double z) {
  return Vec3(e * std::cos(phi), e * std::sin(phi), z);
}

class StraightTubeContact : public ::testing::Test {
 protected:
  void SetUp() override {
    mesh = straight_tube(kR, kL, kSides, 41);
    check_and_repair(mesh);
    tree.build(mesh);
  }
  TriangleMesh mesh;
  AabbTree tree;
};

TEST(Tube, NormalsPointTowardTheCentreline) {
  BentTubeSpec spec;
  spec.radius = kR;
  spec.sides = kSides;
  spec.ring_spacing = 0.5e-3;
  const TriangleMesh m = make_bent_tube(spec);
  const auto line =
      bent_centreline(spec.straight1, spec.bend_radius, spec.bend_angle, spec.straight2, 1e-5);
  for (int t = 0; t < m.num_triangles(); ++t) {
    const auto& tri = m.triangles[t];
    const Vec3 c = (m.vertices[tri[0]] + m.vertices[tri[1]] + m.vertices[tri[2]]) / 3.0;
    Vec3 q = Vec3::Zero();
    test::polyline_distance(line, c, &q);
    EXPECT_GT(m.normals[t].dot((q - c).normalized()), 0.98) << "triangle " << t;
  }
}

TEST(Tube, BentTubeIsAManifoldWithTwoOpenEnds) {
  BentTubeSpec spec;
  spec.radius = kR;
  spec.sides = kSides;
  spec.ring_spacing = 0.5e-3;
  TriangleMesh m = make_bent_tube(spec);
  const MeshReport r = check_and_repair(m);
  EXPECT_EQ(r.components, 1);
  EXPECT_EQ(r.boundary_loops.size(), 2u);
  EXPECT_EQ(r.flipped_for_consistency, 0);
  EXPECT_EQ(r.flipped_for_lumen, 0);
  EXPECT_EQ(r.degenerate_removed, 0);
  // Pappus: cross-section area times centreline length (within the chord error of the rings).
  const double length = spec.straight1 + spec.bend_radius * spec.bend_angle + spec.straight2;
  const double area = 0.5 * kSides * kR * kR * std::sin(2.0 * pi / kSides);
  EXPECT_NEAR(r.component_volumes[0], area * length, 1e-3 * area * length);
}

TEST(Tube, RingsAreUntwisted) {
  // Rotation-minimising frames on a straight line: every ring is the first one shifted in z.
  const TriangleMesh m = straight_tube(kR, kL, 12, 9);
  for (int i = 1; i < 9; ++i) {
    for (int j = 0; j < 12; ++j) {
      const Vec3 d = m.vertices[i * 12 + j] - m.vertices[j];
      EXPECT_NEAR(d.head<2>().norm(), 0.0, 1e-15);
    }
  }
}

TEST(Tube, BadSpecsAreRefused) {
  TubeSpec spec;
  spec.centreline = {Vec3::Zero(), Vec3::UnitZ()};
  spec.sides = 2;
  EXPECT_THROW(make_tube(spec), InputError);
  spec.sides = 8;
  spec.centreline = {Vec3::Zero(), Vec3::Zero()};
  EXPECT_THROW(make_tube(spec), InputError);
  spec.centreline = {Vec3::Zero(), Vec3(0, 0, std::numeric_limits<double>::quiet_NaN())};
  EXPECT_THROW(make_tube(spec), InputError);
  BentTubeSpec bent;
  bent.bend_radius = 0.5 * bent.radius;
  EXPECT_THROW(make_bent_tube(bent), InputError);
}

TEST_F(StraightTubeContact, SphereOnTheAxisTouchesNothing) {
  for (double z = 0.0; z <= kL; z += 1e-3) {
    const SphereContact c = tree.query_sphere(mesh, Vec3(0, 0, z), 0.45e-3);
    EXPECT_FALSE(c.touching) << "z = " << z;
    EXPECT_FALSE(c.centre_outside) << "z = " << z;
  }
}

TEST_F(StraightTubeContact, OffsetSphereIsHalfARadiusDeep) {
  const double r = 0.8e-3;
  const double e = kR - 0.5 * r;
  const double faceting = kR * (1.0 - std::cos(pi / kSides));  // polygon vs circle
  for (double phi = 0.0; phi < 2.0 * pi; phi += 0.137) {
    for (double z : {5e-3, 17.3e-3, 30e-3}) {
      const SphereContact c = tree.query_sphere(mesh, polar(e, phi, z), r);
      ASSERT_TRUE(c.touching);
      EXPECT_FALSE(c.centre_outside);
      EXPECT_NEAR(c.depth, r - polygon_wall_distance(e, phi, kR, kSides), 1e-12);
      EXPECT_NEAR(c.depth, 0.5 * r, faceting + 1e-12);
      EXPECT_NEAR(c.normal.norm(), 1.0, 1e-12);
      // Into the lumen: toward the axis, and within the span of the facets it touches.
      const Vec3 inward = -polar(1.0, phi, 0.0);
      EXPECT_GT(c.normal.dot(inward), 0.9);
      EXPECT_NEAR(c.normal.z(), 0.0, 1e-12);
    }
  }
  // On a facet's mid-angle the touched facets are symmetric: the normal is exactly radial.
  const double phi = facet_mid_angle(5, kSides);
  const SphereContact c = tree.query_sphere(mesh, polar(e, phi, 20e-3), r);
  EXPECT_NEAR(c.normal.dot(-polar(1.0, phi, 0.0)), 1.0, 1e-12);
  EXPECT_GT(c.num_touching, 2);
}

TEST_F(StraightTubeContact, CentreBehindTheWallIsPushedBack) {
  const double r = 0.45e-3;
  const double wall = kR * std::cos(pi / kSides);  // facet plane distance from the axis
  for (int k : {0, 7, 20}) {
    const double phi = facet_mid_angle(k, kSides);
    for (double beyond : {0.1 * r, 0.5 * r, 0.99 * r}) {
      const SphereContact c = tree.query_sphere(mesh, polar(wall + beyond, phi, 20e-3), r);
      ASSERT_TRUE(c.touching);
      EXPECT_TRUE(c.centre_outside);
      EXPECT_NEAR(c.distance, beyond, 1e-12);
      EXPECT_NEAR(c.depth, r + beyond, 1e-12);
      EXPECT_NEAR(c.normal.dot(-polar(1.0, phi, 0.0)), 1.0, 1e-9);  // points inward
      EXPECT_TRUE(c.point.isApprox(polar(wall, phi, 20e-3), 1e-12));
    }
    // Farther than the radius: only found within the escape distance.
    const Vec3 far = polar(wall + 1.5 * r, phi, 20e-3);
    EXPECT_FALSE(tree.query_sphere(mesh, far, r).touching);
    const SphereContact c = tree.query_sphere(mesh, far, r, {.escape_distance = r});
    ASSERT_TRUE(c.touching);
    EXPECT_TRUE(c.centre_outside);
    EXPECT_NEAR(c.depth, 2.5 * r, 1e-12);
    EXPECT_EQ(c.num_touching, 0);
    EXPECT_NEAR(c.normal.dot(-polar(1.0, phi, 0.0)), 1.0, 1e-9);
  }
  // Behind a vertex (between two facets), the pseudo-normal still says "outside".
  const SphereContact v = tree.query_sphere(mesh, polar(kR + 0.2 * r, 0.0, 20e-3), r);
  ASSERT_TRUE(v.touching);
  EXPECT_TRUE(v.centre_outside);
  EXPECT_NEAR(v.depth, 1.2 * r, 1e-12);
  EXPECT_NEAR(v.normal.dot(-Vec3::UnitX()), 1.0, 1e-9);
}

TEST(Tube, DeadEndStopsASphereBeyondTheCap) {
  TriangleMesh m = straight_tube(kR, kL, kSides, 41, /*cap=*/true);
  check_and_repair(m);
  AabbTree tree;
  tree.build(m);
  const double r = 0.45e-3;
  const SphereContact in = tree.query_sphere(m, Vec3(0.3e-3, 0, kL - 0.2 * r), r);
  ASSERT_TRUE(in.touching);
  EXPECT_FALSE(in.centre_outside);
  EXPECT_NEAR(in.depth, 0.8 * r, 1e-12);
  EXPECT_NEAR(in.normal.z(), -1.0, 1e-12);
  const SphereContact out = tree.query_sphere(m, Vec3(0.3e-3, 0, kL + 0.4 * r), r);
  ASSERT_TRUE(out.touching);
  EXPECT_TRUE(out.centre_outside);
  EXPECT_NEAR(out.depth, 1.4 * r, 1e-12);
  EXPECT_NEAR(out.normal.z(), -1.0, 1e-12);
}

TEST(Tube, BentTubeOuterWallDepth) {
  BentTubeSpec spec;
  spec.radius = kR;
  spec.sides = kSides;
  spec.ring_spacing = 0.25e-3;
  TriangleMesh m = make_bent_tube(spec);
  check_and_repair(m);
  AabbTree tree;
  tree.build(m);
  const double r = 0.45e-3;
  // Sagitta of a ring-to-ring chord on the outer wall, plus the polygon error.
  const double ds = spec.ring_spacing * (1.0 + kR / spec.bend_radius);
  const double tol =
      kR * (1.0 - std::cos(pi / kSides)) + ds * ds / (8.0 * (spec.bend_radius + kR)) + 1e-9;
  for (double a = 0.05; a < spec.bend_angle; a += 0.1) {
    // Centreline point and outward direction (away from the bend centre) at arc angle a.
    const Vec3 centre(spec.bend_radius, 0.0, spec.straight1);
    const Vec3 q(spec.bend_radius * (1 - std::cos(a)), 0.0,
                 spec.straight1 + spec.bend_radius * std::sin(a));
    const Vec3 out = (q - centre).normalized();
    EXPECT_FALSE(tree.query_sphere(m, q, r).touching);
    const SphereContact c = tree.query_sphere(m, q + (kR - 0.5 * r) * out, r);
    ASSERT_TRUE(c.touching);
    EXPECT_NEAR(c.depth, 0.5 * r, tol);
    EXPECT_GT(c.normal.dot(-out), 0.99);
    const SphereContact o = tree.query_sphere(m, q + (kR + 0.3 * r) * out, r);
    ASSERT_TRUE(o.touching);
    EXPECT_TRUE(o.centre_outside);
    EXPECT_NEAR(o.depth, 1.3 * r, tol);
    EXPECT_GT(o.normal.dot(-out), 0.99);
  }
}

}  // namespace
}  // namespace vcsim
