// A warm Simulator step allocates nothing, through a fast pull's fine steps and back (replaced
// global operator new): it runs at the haptic rate.
#include <gtest/gtest.h>

#include <algorithm>

#include "vcsim/sim.h"

#include "counting_new.h"
#include "jl4_scene.h"

using vcsim::test::g_allocations;

namespace vcsim {
namespace {

TEST(SimulatorNoAlloc, WarmStepsThroughAFastPullAllocateNothing) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#else
  const Scenario sc = test::jl4_with_j_wire(128, true);
  Simulator sim(sc);
  StepCommands cmds = test::jl4_with_j_wire_commands();
  std::vector<HandFeedback> fb;
  int fine = 0, coarse = 0;  // steps taken with each mass set
  // In at 80 mm/s (the wire 20 mm ahead), then the wire 30 mm back at 300 mm/s and in again at
  // 300 mm/s, twice: the second round, warm, must not allocate.
  auto round = [&](double t0) {
    double depth = 0.14;
    while (sim.time() < t0 + 0.2) {
      depth = std::max(0.11, depth - 0.3 * sc.dt);
      cmds.drive[1].translation = depth;
      sim.step(cmds);
      sim.feedback(fb);
      ++(sim.split() > 1 ? fine : coarse);
    }
    while (sim.time() < t0 + 0.4) {
      depth = std::min(0.14, depth + 0.3 * sc.dt);
      cmds.drive[1].translation = depth;
      sim.step(cmds);
      sim.feedback(fb);
      ++(sim.split() > 1 ? fine : coarse);
    }
  };
  while (sim.time() < 1.75) {
    cmds.drive[0].translation = std::min(0.120, 0.080 * sim.time());
    cmds.drive[1].translation = std::min(0.140, 0.080 * sim.time() + 0.020);
    sim.step(cmds);
  }
  round(sim.time());
  const long before = g_allocations.load();
  const std::int64_t steps = sim.metrics().steps;
  fine = coarse = 0;
  round(sim.time());
  EXPECT_EQ(g_allocations.load() - before, 0);
  EXPECT_GT(fine, 300) << "the fast moves are stepped finely";
  EXPECT_GT(coarse, 100) << "and the pauses between them are not";
  EXPECT_GT(sim.metrics().steps - steps, 700);
  EXPECT_EQ(sim.metrics().rollbacks, 0);
#endif
}

// Rewinding (the trainer's, a learning environment's reset): a snapshot taken into storage of the
// same state's shape, and a restore, allocate nothing; nor do the steps after a restore.
TEST(SimulatorNoAlloc, SnapshotIntoItsStorageAndRestoreAllocateNothing) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#else
  Simulator sim(test::jl4_with_j_wire(128, true));
  StepCommands cmds = test::jl4_with_j_wire_commands();
  auto run_to = [&](double t) {
    while (sim.time() < t) {
      cmds.drive[0].translation = std::min(0.120, 0.080 * sim.time());
      cmds.drive[1].translation = std::min(0.140, 0.080 * sim.time() + 0.020);
      sim.step(cmds);
    }
  };
  run_to(0.5);
  SimState snap = sim.snapshot();
  run_to(1.0);
  sim.restore(snap);
  run_to(1.0);  // warm: the steps after a restore too
  const long before = g_allocations.load();
  snap = sim.state();
  run_to(1.2);
  sim.restore(snap);
  run_to(1.2);
  EXPECT_EQ(g_allocations.load() - before, 0);
#endif
}

}  // namespace
}  // namespace vcsim
