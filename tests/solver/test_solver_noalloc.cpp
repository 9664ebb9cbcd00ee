// A warm instrument step with contacts, and a warm pair step with the rim and the sheath, allocate
// nothing (replaced global operator new).
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>
#include <vector>

#include "vcsim/solver.h"

#include "solver_rig.h"

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
  test::Rig inst = test::driven(d, Sheath{}, ContactMaterial{}, 0.015);  // tip 5 mm before the bend
  SolverSettings s;
  s.rod.dt = 2e-4;
  s.rod.drag = 20;
  DriveCommand c{DriveCommand::Mode::kVelocity, 0.1, 1.0};
  StepProfile prof;
  StaticWall wall(mesh, tree, /*parallel_min=*/1);  // every batch that can split goes parallel
  // Warm up until a batch of queries has gone parallel (the thread pool's first use allocates).
  int warm_queries = 0;
  for (int k = 0; k < 300 || (warm_queries < 2 * StaticWall::kParallelChunk && k < 3000); ++k) {
    inst.step(&wall, s, c, &prof);
    warm_queries = std::max(warm_queries, prof.num_queries);
  }
  ASSERT_GE(warm_queries, 2 * StaticWall::kParallelChunk);
  const long before = g_allocations.load();
  int contacts = 0, queries = 0;
  for (int k = 0; k < 300; ++k) {
    inst.step(&wall, s, c, &prof);
    contacts = std::max(contacts, prof.num_contacts);
    queries = std::max(queries, prof.num_queries);
  }
  EXPECT_EQ(g_allocations.load() - before, 0);
  EXPECT_GT(contacts, 0) << "the test must exercise contacts";
  EXPECT_GE(queries, 2 * StaticWall::kParallelChunk) << "the test must exercise parallel queries";
#endif
}

// The same for a wire with a curved tip being pulled back into a catheter through the introducer
// sheath: concentric, rim (physics.md 7.1) and sheath (6.2) contacts, the hand-force walk with
// two reactions at a node.
TEST(SolverNoAlloc, WarmPairStepWithRimAndSheathAllocatesNothing) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#else
  RodDef cd;
  cd.length = 0.1;
  cd.segments = 40;
  cd.outer_radius = 1.0e-3;
  cd.inner_radius = 0.6e-3;
  cd.youngs_modulus = 1e9;
  cd.base = cd.tip = BoundaryKind::kFree;
  RodDef wd = cd;
  wd.length = 0.12;
  wd.segments = 60;
  wd.outer_radius = 0.2e-3;
  wd.inner_radius = 0.0;
  wd.tip_shape = {TipSection::arc(5e-3, 2.0)};  // its last 10 mm curved
  Sheath sh;
  sh.length = 0.02;
  sh.inner_radius = 1.1e-3;
  const double dt = 2e-4;
  std::vector<InstrumentModel> models;
  models.push_back(make_instrument_model(wd, sh, ContactMaterial{}));
  models.push_back(make_instrument_model(cd, sh, ContactMaterial{}));
  for (InstrumentModel& im : models) scale_for_time_step(im.rods[0], dt, kQuasiStaticKpRatio);
  std::vector<InstrumentState> states;
  states.push_back(make_instrument_state(models[0], 0.068));  // 8 mm out of the catheter
  states.push_back(make_instrument_state(models[1], 0.06));
  SolverSettings s;
  s.rod.dt = dt;
  set_quasi_static_damping(s.rod);
  s.rod.gravity = Vec3(1.0, 0.0, 0.0);  // sideways: the shafts lean on the sheath's lumen
  s.collisions = false;
  test::Rig insts(std::move(models), std::move(states), s, {CouplingModel{}});
  insts.model.couplings[0].inner = 0;
  insts.model.couplings[0].outer = 1;
  using M = DriveCommand::Mode;
  const DriveCommand hold[] = {{M::kPosition, 0.068, 0.0}, {M::kPosition, 0.06, 0.0}};
  for (int k = 0; k < 500; ++k) insts.step(nullptr, hold);
  const DriveCommand pull[] = {{M::kVelocity, -0.02, 0.0}, {M::kVelocity, 0.0, 0.0}};
  const long before = g_allocations.load();
  int rims = 0, sheath = 0;
  for (int k = 0; k < 300; ++k) {
    insts.step(nullptr, pull);
    for (const CoaxialContact& c : insts.ws.coupling_contacts(0)) rims += c.a > 0.0 ? 1 : 0;
    sheath += static_cast<int>(insts.contacts(1).size());
  }
  EXPECT_EQ(g_allocations.load() - before, 0);
  EXPECT_GT(rims, 0) << "the test must exercise the rim";
  EXPECT_GT(sheath, 0) << "the test must exercise the sheath";
#endif
}
