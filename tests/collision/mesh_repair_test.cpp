// Mesh checks and repair: open ends, manifoldness, orientation, lumen-facing normals.
#include "test_util.h"
#include "vcsim/collision.h"

#include <gtest/gtest.h>

#include <functional>
#include <numbers>

namespace vcsim {
namespace {

using test::straight_tube;

// Regular n-gon of radius R: the cross-section of a straight tube.
double polygon_area(double radius, int sides) {
  return 0.5 * sides * radius * radius * std::sin(2.0 * std::numbers::pi / sides);
}

bool throws_input_error_with(const std::function<void()>& f, const std::string& text) {
  try {
    f();
  } catch (const InputError& e) {
    return std::string(e.what()).find(text) != std::string::npos;
  }
  return false;
}

TEST(MeshRepair, StraightTubeHasTwoOpenEndsAndNothingToRepair) {
  const double R = 2e-3, L = 30e-3;
  const int sides = 24, rings = 20;
  TriangleMesh m = straight_tube(R, L, sides, rings);
  const MeshReport r = check_and_repair(m);
  EXPECT_EQ(r.vertices, sides * rings);
  EXPECT_EQ(r.triangles, 2 * sides * (rings - 1));
  EXPECT_EQ(r.components, 1);
  ASSERT_EQ(r.boundary_loops.size(), 2u);
  EXPECT_EQ(r.boundary_loops[0].size(), static_cast<std::size_t>(sides));
  EXPECT_EQ(r.boundary_loops[1].size(), static_cast<std::size_t>(sides));
  EXPECT_EQ(r.boundary_edges, 2 * sides);
  EXPECT_EQ(r.degenerate_removed, 0);
  EXPECT_EQ(r.flipped_for_consistency, 0);
  EXPECT_EQ(r.flipped_for_lumen, 0);
  // Planar end loops, so the capped volume is exactly the prism.
  ASSERT_EQ(r.component_volumes.size(), 1u);
  EXPECT_NEAR(r.component_volumes[0], polygon_area(R, sides) * L, 1e-12 * R * R * L);
  EXPECT_FALSE(r.summary().empty());
}

TEST(MeshRepair, DeadEndTubeHasOneOpenEnd) {
  TriangleMesh m = straight_tube(2e-3, 20e-3, 16, 10, /*cap=*/true);
  const MeshReport r = check_and_repair(m);
  EXPECT_EQ(r.boundary_loops.size(), 1u);
  EXPECT_EQ(r.flipped_for_consistency + r.flipped_for_lumen, 0);
  EXPECT_NEAR(r.component_volumes[0], polygon_area(2e-3, 16) * 20e-3, 1e-18);
  // The cap faces back into the tube (-z).
  for (int t = m.num_triangles() - 16; t < m.num_triangles(); ++t)
    EXPECT_NEAR(m.normals[t].z(), -1.0, 1e-12);
}

TEST(MeshRepair, FlippedTrianglesAreRestored) {
  const TriangleMesh ref = straight_tube(3e-3, 30e-3, 20, 15);
  TriangleMesh m = ref;
  int flipped = 0;
  for (int t = 0; t < m.num_triangles(); t += 7, ++flipped)
    std::swap(m.triangles[t][0], m.triangles[t][1]);
  const MeshReport r = check_and_repair(m);
  EXPECT_EQ(r.flipped_for_consistency, flipped);
  EXPECT_EQ(r.flipped_for_lumen, 0);
  for (int t = 0; t < m.num_triangles(); ++t)
    EXPECT_NEAR(m.normals[t].dot(ref.normals[t]), 1.0, 1e-12) << "triangle " << t;
}

TEST(MeshRepair, OutwardMeshIsTurnedToFaceTheLumen) {
  const TriangleMesh ref = straight_tube(3e-3, 30e-3, 20, 15, /*cap=*/true);
  TriangleMesh m = ref;
  for (auto& t : m.triangles) std::swap(t[1], t[2]);
  // And a few flipped back, so both repairs are needed.
  for (int t = 3; t < m.num_triangles(); t += 11) std::swap(m.triangles[t][1], m.triangles[t][2]);
  const MeshReport r = check_and_repair(m);
  EXPECT_GT(r.flipped_for_consistency, 0);
  EXPECT_EQ(r.flipped_for_lumen, m.num_triangles());
  for (int t = 0; t < m.num_triangles(); ++t)
    EXPECT_NEAR(m.normals[t].dot(ref.normals[t]), 1.0, 1e-12) << "triangle " << t;
}

TEST(MeshRepair, ClosedOctahedronFacesInward) {
  TriangleMesh m;
  m.vertices = {Vec3(1, 0, 0),  Vec3(-1, 0, 0), Vec3(0, 1, 0),
                Vec3(0, -1, 0), Vec3(0, 0, 1),  Vec3(0, 0, -1)};
  m.triangles = {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4},
                 {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}};  // outward winding
  const MeshReport r = check_and_repair(m);
  EXPECT_TRUE(r.boundary_loops.empty());
  EXPECT_EQ(r.flipped_for_lumen, 8);
  EXPECT_NEAR(r.component_volumes[0], 4.0 / 3.0, 1e-12);
  for (int t = 0; t < 8; ++t) {
    const auto& tri = m.triangles[t];
    const Vec3 centroid = (m.vertices[tri[0]] + m.vertices[tri[1]] + m.vertices[tri[2]]) / 3.0;
    EXPECT_LT(m.normals[t].dot(centroid), 0.0);
  }
}

TEST(MeshRepair, TwoComponentsAreOrientedSeparately) {
  TriangleMesh a = straight_tube(2e-3, 10e-3, 12, 6);
  const TriangleMesh ref = a;
  TriangleMesh b = a;
  for (auto& v : b.vertices) v.x() += 10e-3;
  for (auto& t : b.triangles) std::swap(t[1], t[2]);  // second tube inside out
  const int offset = a.num_vertices();
  for (const auto& v : b.vertices) a.vertices.push_back(v);
  for (auto t : b.triangles) a.triangles.push_back({t[0] + offset, t[1] + offset, t[2] + offset});
  const MeshReport r = check_and_repair(a);
  EXPECT_EQ(r.components, 2);
  EXPECT_EQ(r.boundary_loops.size(), 4u);
  EXPECT_EQ(r.flipped_for_lumen, ref.num_triangles());
  for (int t = 0; t < a.num_triangles(); ++t)
    EXPECT_NEAR(a.normals[t].dot(ref.normals[t % ref.num_triangles()]), 1.0, 1e-12);
}

TEST(MeshRepair, DegenerateTrianglesAndUnusedVerticesAreRemoved) {
  const TriangleMesh ref = straight_tube(2e-3, 10e-3, 12, 6);
  TriangleMesh m = ref;
  const auto t0 = m.triangles[0];
  m.triangles.push_back({t0[0], t0[0], t0[1]});  // repeated index
  const int mid = m.num_vertices();
  m.vertices.push_back(0.5 * (m.vertices[t0[0]] + m.vertices[t0[1]]));
  m.triangles.push_back({t0[0], t0[1], mid});    // collinear: zero area
  m.triangles.push_back({t0[1], t0[0], t0[2]});  // duplicate, other winding
  m.triangles.push_back(t0);                     // duplicate
  const MeshReport r = check_and_repair(m);
  EXPECT_EQ(r.degenerate_removed, 2);
  EXPECT_EQ(r.duplicates_removed, 2);
  EXPECT_EQ(r.unused_vertices_removed, 1);
  EXPECT_EQ(m.num_triangles(), ref.num_triangles());
  EXPECT_EQ(m.num_vertices(), ref.num_vertices());
  EXPECT_EQ(r.boundary_loops.size(), 2u);
}

TEST(MeshRepair, NonManifoldEdgeIsRefused) {
  TriangleMesh m = straight_tube(2e-3, 10e-3, 12, 6);
  const auto t0 = m.triangles[0];
  m.vertices.push_back(Vec3(0.0, 0.0, 5e-3));
  m.triangles.push_back({t0[0], t0[1], m.num_vertices() - 1});  // third triangle on an edge
  EXPECT_TRUE(throws_input_error_with([&] { check_and_repair(m, "fin.stl"); }, "manifold"));
  EXPECT_TRUE(throws_input_error_with([&] { check_and_repair(m, "fin.stl"); }, "fin.stl"));
}

TEST(MeshRepair, MoebiusStripIsRefused) {
  TriangleMesh m;
  const int n = 24;
  for (int i = 0; i < n; ++i) {
    const double a = 2.0 * std::numbers::pi * i / n;
    const Vec3 centre(std::cos(a), std::sin(a), 0.0);
    const Vec3 across = std::cos(0.5 * a) * centre + std::sin(0.5 * a) * Vec3::UnitZ();
    m.vertices.push_back(centre + 0.2 * across);
    m.vertices.push_back(centre - 0.2 * across);
  }
  for (int i = 0; i < n; ++i) {
    const int a0 = 2 * i, a1 = 2 * i + 1;
    // The last quad joins with a half twist.
    const int b0 = i + 1 < n ? 2 * (i + 1) : 1;
    const int b1 = i + 1 < n ? 2 * (i + 1) + 1 : 0;
    m.triangles.push_back({a0, a1, b0});
    m.triangles.push_back({b0, a1, b1});
  }
  EXPECT_TRUE(throws_input_error_with([&] { check_and_repair(m, "moebius"); }, "orient"));
}

TEST(MeshRepair, BadInputIsRefused) {
  TriangleMesh m = straight_tube(2e-3, 10e-3, 12, 6);
  TriangleMesh nan = m;
  nan.vertices[5].y() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(throws_input_error_with([&] { check_and_repair(nan, "src"); }, "vertex 5"));
  TriangleMesh index = m;
  index.triangles[3][1] = 100000;
  EXPECT_TRUE(throws_input_error_with([&] { check_and_repair(index, "src"); }, "triangle 3"));
  TriangleMesh empty;
  EXPECT_TRUE(throws_input_error_with([&] { check_and_repair(empty, "src"); }, "at least one"));
}

// A closed unit cube (12 triangles, outward winding) of side a.
TriangleMesh cube(double a) {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i) m.vertices.push_back(a * Vec3(i & 1, (i >> 1) & 1, (i >> 2) & 1));
  m.triangles = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  m.recompute_normals();
  return m;
}

TEST(MeshRepair, FinOnAnEdgeIsRefusedNamingTheRepairAndRepairKeepsTheClosedSurface) {
  const double a = 10e-3;
  TriangleMesh m = cube(a);
  // A fin on the edge 0-1 sticking out below the cube at 45 degrees: three triangles on it.
  m.vertices.push_back(Vec3(0.5 * a, -0.5 * a, -0.5 * a));
  m.triangles.push_back({0, 1, 8});
  TriangleMesh refused = m;
  EXPECT_TRUE(throws_input_error_with([&] { check_and_repair(refused, "fin.stl"); },
                                      "run 'vcsim anatomy repair IN OUT'"));
  const MeshRepairReport rr = repair_mesh(m, "fin.stl");
  EXPECT_EQ(rr.non_manifold_edges, 1);
  EXPECT_EQ(rr.non_manifold_dropped, 1);
  EXPECT_EQ(rr.triangles_before, 13);
  EXPECT_EQ(rr.triangles_after, 12);
  EXPECT_EQ(rr.unused_vertices_removed, 1);
  EXPECT_FALSE(rr.summary().empty());
  const MeshReport r = check_and_repair(m, "fin.stl");
  // The cube is what is left: closed, one component, its volume.
  EXPECT_EQ(r.triangles, 12);
  EXPECT_EQ(r.vertices, 8);
  EXPECT_EQ(r.boundary_edges, 0);
  EXPECT_EQ(r.components, 1);
  ASSERT_EQ(r.component_volumes.size(), 1u);
  EXPECT_NEAR(r.component_volumes[0], a * a * a, 1e-12 * a * a * a);
}

TEST(MeshRepair, FinInsideTheSurfaceOnTwoEdgesIsDroppedAndSpeckAndDegenerateGo) {
  const double a = 10e-3;
  TriangleMesh m = cube(a);
  // A fin inside the cube on two crowded edges: 1-2 (the bottom face's diagonal) and 2-6 (a
  // cube edge); its third edge 6-1 is open.
  m.triangles.push_back({1, 2, 6});
  // A speck far away, a degenerate triangle and a duplicate.
  const int s0 = m.num_vertices();
  m.vertices.push_back(Vec3(5 * a, 0, 0));
  m.vertices.push_back(Vec3(5 * a + 1e-4, 0, 0));
  m.vertices.push_back(Vec3(5 * a, 1e-4, 0));
  m.triangles.push_back({s0, s0 + 1, s0 + 2});
  m.triangles.push_back({0, 1, 1});
  m.triangles.push_back({4, 5, 6});
  TriangleMesh refused = m;
  EXPECT_THROW(check_and_repair(refused), InputError);
  MeshRepairSettings settings;
  settings.min_component_fraction = 0.2;  // the speck is 1 triangle, the cube 12
  const MeshRepairReport rr = repair_mesh(m, "mesh", settings);
  EXPECT_EQ(rr.non_manifold_edges, 2);
  EXPECT_EQ(rr.non_manifold_dropped, 1);
  EXPECT_EQ(rr.degenerate_removed, 1);
  EXPECT_EQ(rr.duplicates_removed, 1);
  EXPECT_EQ(rr.components_dropped, 1);
  EXPECT_EQ(rr.component_triangles_dropped, 1);
  const MeshReport r = check_and_repair(m);
  EXPECT_EQ(r.triangles, 12);
  EXPECT_EQ(r.boundary_edges, 0);
  EXPECT_NEAR(r.component_volumes.at(0), a * a * a, 1e-12 * a * a * a);
}

TEST(MeshRepair, ManifoldMeshIsLeftAsItIs) {
  TriangleMesh m = straight_tube(2e-3, 20e-3, 16, 10);
  const TriangleMesh before = m;
  const MeshRepairReport rr = repair_mesh(m);
  EXPECT_EQ(rr.non_manifold_edges + rr.non_manifold_dropped + rr.components_dropped, 0);
  EXPECT_EQ(m.triangles, before.triangles);
  EXPECT_EQ(m.vertices, before.vertices);
}

}  // namespace
}  // namespace vcsim
