// The batch sphere query and refit allocate nothing once warm (they run inside the step).
#include "vcsim/collision.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <new>
#include <random>

#include "counting_new.h"

using vcsim::test::g_allocations;

namespace vcsim {
namespace {

TEST(CollisionAllocation, BatchQueryAndRefitAllocateNothingOnceWarm) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#endif
  BentTubeSpec spec;
  spec.radius = 3e-3;
  spec.ring_spacing = 0.5e-3;
  TriangleMesh mesh = make_bent_tube(spec);
  check_and_repair(mesh);
  AabbTree tree;
  tree.build(mesh);

  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-3.5e-3, 3.5e-3);
  std::vector<Vec3> centres(256);
  for (auto& c : centres) c = Vec3(u(rng), u(rng), 10e-3 + 2.0 * u(rng));
  const std::vector<double> radii{0.45e-3};
  std::vector<SphereContact> out(centres.size());
  tree.query_spheres(mesh, centres, radii, out);  // warm

  const long before = g_allocations;
  int touching = 0;
  for (int step = 0; step < 20; ++step) {
    for (auto& v : mesh.vertices) v.x() += 1e-6;
    mesh.recompute_normals();
    tree.refit(mesh);
    tree.query_spheres(mesh, centres, radii, out);
    for (const auto& c : out) touching += c.touching;
  }
  EXPECT_EQ(g_allocations - before, 0);
  EXPECT_GT(touching, 0);       // the loop did real work
  EXPECT_GT(g_allocations, 0);  // and the counter does count
}

}  // namespace
}  // namespace vcsim
