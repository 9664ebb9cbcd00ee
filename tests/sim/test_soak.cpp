// The soak's random hands (issue 29, part 4): within their limits, every gesture used, the same
// seed the same run; and a short soak of the beating patient stays finite with no rollback.
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "jl4_scene.h"
#include "vcsim/sim.h"

namespace vcsim {
namespace {

TEST(SoakHands, StayWithinTheirSpeedsAndDepthsAndAreSeeded) {
  auto model = build_sim_model(test::jl4_with_j_wire(64, false));
  SoakSettings s;
  s.seed = 5;
  s.max_depth = 0.3;
  Simulator sim(model);
  SoakHands hands(*model, s);
  StepCommands cmd;
  std::set<long> speeds;  // distinct commanded speeds seen (mm/s, rounded)
  bool pushed = false, pulled = false, turned = false;
  double deepest = 0.0;
  const int steps = static_cast<int>(8.0 / sim.dt());
  for (int k = 0; k < steps; ++k) {
    hands.command(sim, cmd);
    ASSERT_EQ(cmd.drive.size(), 2u);
    for (int i = 0; i < 2; ++i) {
      const DriveCommand& d = cmd.drive[static_cast<std::size_t>(i)];
      ASSERT_EQ(d.mode, DriveCommand::Mode::kVelocity);
      ASSERT_LE(std::abs(d.translation), s.max_speed + 1e-12);
      ASSERT_LE(std::abs(d.rotation), s.max_spin + 1e-12);
      pushed = pushed || d.translation > 0.05;
      pulled = pulled || d.translation < -0.05;
      turned = turned || std::abs(d.rotation) > 1.0;
      speeds.insert(std::lround(d.translation * 1e3));
    }
    sim.step(cmd);
    for (int i = 0; i < 2; ++i) {
      ASSERT_LE(sim.depth(i), s.max_depth + s.max_speed * sim.dt() + 1e-9);
      ASSERT_GE(sim.depth(i), 0.0);
      deepest = std::max(deepest, sim.depth(i));
    }
  }
  EXPECT_TRUE(pushed && pulled && turned);
  EXPECT_GT(speeds.size(), 4u);  // several gestures, each at its own speed
  EXPECT_GT(deepest, 0.1);
  EXPECT_EQ(sim.metrics().rollbacks, 0);

  // The same seed: the same run; another seed: another.
  auto run = [&](std::uint64_t seed) {
    Simulator again(model);
    SoakSettings t = s;
    t.seed = seed;
    SoakHands h(*model, t);
    for (int k = 0; k < 2000; ++k) {
      h.command(again, cmd);
      again.step(cmd);
    }
    return again.state().hash();
  };
  EXPECT_EQ(run(5), run(5));
  EXPECT_NE(run(5), run(6));
}

TEST(Soak, AShortSoakOfTheBeatingPatientIsFiniteWithoutRollback) {
  Scenario sc = test::jl4_with_j_wire(128, true);
  Simulator sim(sc);
  SoakSettings s;
  s.duration = 3.0;
  s.seed = 2;
  const SoakReport r = soak(sim, s);
  EXPECT_EQ(r.steps, static_cast<std::int64_t>(std::lround(3.0 / sim.dt())));
  EXPECT_NEAR(r.simulated, 3.0, 1e-9);
  EXPECT_TRUE(r.finite);
  EXPECT_EQ(r.rollbacks, 0);
  ASSERT_EQ(r.instruments.size(), 2u);
  EXPECT_EQ(r.instruments[0].name, "catheter");
  EXPECT_GT(r.instruments[0].deepest, 0.05);
  EXPECT_GT(r.instruments[0].checked_steps, 1000);
  EXPECT_GT(resident_megabytes(), 1.0);
  // What the run counted is what the report holds.
  for (std::size_t i = 0; i < r.instruments.size(); ++i)
    EXPECT_EQ(r.instruments[i].escape.steps, sim.metrics().escapes[i].steps);
}

// An escape fails the soak (issue 29: the abuse runs have none), as a rollback does.
TEST(Soak, AnEscapeIsAFailure) {
  SoakReport r;
  r.instruments.resize(2);
  EXPECT_TRUE(r.passed());
  r.instruments[1].escape.steps = 1;
  EXPECT_FALSE(r.passed());
  r.instruments[1].escape.steps = 0;
  r.rollbacks = 1;
  EXPECT_FALSE(r.passed());
}

}  // namespace
}  // namespace vcsim
