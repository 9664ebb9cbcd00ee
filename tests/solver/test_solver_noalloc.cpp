// A warm instrument step with contacts allocates nothing (replaced global operator new).
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>

#include "vcsim/solver.h"

#include "counting_new.h"

using vcsim::test::g_allocations;

using namespace vcsim;

TEST(SolverNoAlloc, WarmInstrumentStepWithContactsAllocatesNothing) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#else
  BentTubeSpec spec;
  spec.radius = 0.8e-3;  // narrow: most nodes near the wall, queried every step
  spec.cap_end = true;
  TriangleMesh mesh = make_bent_tube(spec);
  check_and_repair(mesh, "tube");
  AabbTree tree;
  tree.build(mesh);
  RodDef d;
  d.length = 0.08;
  d.segments = 60;
  d.outer_radius = 0.45e-3;
  d.base = BoundaryKind::kFree;
  d.density = 1e6;
  Instrument inst =
      make_instrument(d, Sheath{}, ContactMaterial{}, 0.015);  // tip 5 mm before the bend
  SolverSettings s;
  s.rod.dt = 2e-4;
  s.rod.drag = 20;
  DriveCommand c{DriveCommand::Mode::kVelocity, 0.1, 1.0};
  StepProfile prof;
  StaticWall wall(mesh, tree, /*parallel_min=*/1);  // every batch that can split goes parallel
  // Warm up until a batch of queries has gone parallel (the thread pool's first use allocates).
  int warm_queries = 0;
  for (int k = 0; k < 300 || (warm_queries < 2 * StaticWall::kParallelChunk && k < 3000); ++k) {
    instrument_step(inst, &wall, s, c, &prof);
    warm_queries = std::max(warm_queries, prof.num_queries);
  }
  ASSERT_GE(warm_queries, 2 * StaticWall::kParallelChunk);
  const long before = g_allocations.load();
  int contacts = 0, queries = 0;
  for (int k = 0; k < 300; ++k) {
    instrument_step(inst, &wall, s, c, &prof);
    contacts = std::max(contacts, prof.num_contacts);
    queries = std::max(queries, prof.num_queries);
  }
  EXPECT_EQ(g_allocations.load() - before, 0);
  EXPECT_GT(contacts, 0) << "the test must exercise contacts";
  EXPECT_GE(queries, 2 * StaticWall::kParallelChunk) << "the test must exercise parallel queries";
#endif
}
