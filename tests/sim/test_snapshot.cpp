// The engine as a library (issue 24): a SimState is the whole of what changes, so a copy of it is
// a snapshot; restoring one and replaying the same commands gives the same states and hand forces
// bit for bit; the model is never written by a run; and the default scenario's state after 2 s is
// pinned by its hash.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include "vcsim/sim.h"

#include "jl4_scene.h"

namespace vcsim {
namespace {

Scenario default_scenario() {
  return load_scenario(default_scenarios_dir() / "default.json");
}

// What one step left behind: the state's hash and every hand's force and torque.
struct Trace {
  std::vector<std::uint64_t> hash;
  std::vector<double> feel;
};

void record(const Simulator& sim, std::vector<HandFeedback>& fb, Trace& t) {
  t.hash.push_back(sim.state().hash());
  sim.feedback(fb);
  for (const HandFeedback& f : fb) {
    t.feel.push_back(f.axial_force);
    t.feel.push_back(f.torque);
  }
}

void expect_same(const Trace& a, const Trace& b) {
  ASSERT_EQ(a.hash.size(), b.hash.size());
  for (std::size_t k = 0; k < a.hash.size(); ++k) ASSERT_EQ(a.hash[k], b.hash[k]) << "step " << k;
  ASSERT_EQ(a.feel.size(), b.feel.size());
  for (std::size_t k = 0; k < a.feel.size(); ++k)
    ASSERT_EQ(std::memcmp(&a.feel[k], &b.feel[k], sizeof(double)), 0) << "value " << k;
}

// The default scenario with its autopilot in the beating heart, to 1.2 s (the J wire climbing
// the iliac, the catheter behind it); a snapshot; then 0.4 s of the autopilot's commands with
// 3 ml/s of contrast injected through them, recorded. Restored into the same simulator and into
// a second one of the same model, the recorded commands give the same state hash and the same
// hand forces at every step. The model's hash is the same before and after.
TEST(Snapshot, RestoreAndReplayGiveTheSameStatesAndForcesBitForBit) {
  Simulator sim(default_scenario());
  const std::uint64_t model_hash = sim.model().hash();
  Autopilot pilot(sim);
  StepCommands cmds;
  while (sim.time() < 1.2) {
    pilot.command(sim, cmds);
    sim.step(cmds);
  }
  ASSERT_GT(sim.depth(0), 0.05) << "the procedure is under way";
  const SimState snap = sim.snapshot();
  EXPECT_LT(snap.bytes(), 1u << 20) << "a snapshot under 1 MB";

  std::vector<StepCommands> recorded;
  std::vector<HandFeedback> fb;
  Trace first;
  while (sim.time() < 1.6) {
    pilot.command(sim, cmds);
    if (sim.time() > 1.3 && sim.time() < 1.5) cmds.syringe_flow = 3e-6;  // m^3/s
    recorded.push_back(cmds);
    sim.step(cmds);
    record(sim, fb, first);
  }
  EXPECT_GT(sim.state().contrast.volume, 0.5e-6) << "contrast went in";
  EXPECT_EQ(sim.metrics().rollbacks, 0);
  EXPECT_NE(first.hash.front(), first.hash.back());

  sim.restore(snap);
  EXPECT_EQ(sim.state().hash(), snap.hash());
  Trace again;
  for (const StepCommands& c : recorded) {
    sim.step(c);
    record(sim, fb, again);
  }
  expect_same(first, again);

  Simulator other(sim.shared_model());
  other.restore(snap);
  Trace elsewhere;
  for (const StepCommands& c : recorded) {
    other.step(c);
    record(other, fb, elsewhere);
  }
  expect_same(first, elsewhere);
  EXPECT_EQ(sim.model().hash(), model_hash) << "a run never writes its model";
}

// The same in a static anatomy (the lumen's own tree and the leaf caches of its queries, which a
// snapshot does not carry): a JL4 with its J wire pushed in, turned and pulled back fast (fine
// steps and their masses), snapshot taken between two pulls.
TEST(Snapshot, RestoreAndReplayInAStaticAnatomyWithFineSteps) {
  Simulator sim(test::jl4_with_j_wire(128, false));
  StepCommands cmds = test::jl4_with_j_wire_commands();
  auto command = [&](double t) {
    cmds.drive[0].translation = std::min(0.20, 0.1 * t);
    cmds.drive[0].rotation = 0.5 * t;
    // The wire ahead, then pulled back and pushed on at 300 mm/s.
    const double wave = t < 2.2 ? 0.0 : 0.03 * std::abs(std::sin(10.0 * (t - 2.2)));
    cmds.drive[1].translation = std::min(0.24, 0.1 * t + 0.04) - wave;
  };
  while (sim.time() < 2.3) {
    command(sim.time());
    sim.step(cmds);
  }
  const SimState snap = sim.snapshot();
  std::vector<HandFeedback> fb;
  Trace first;
  int split = 0;
  while (sim.time() < 2.6) {
    command(sim.time());
    sim.step(cmds);
    split = std::max(split, sim.split());
    record(sim, fb, first);
  }
  EXPECT_GT(split, 1) << "fine steps were taken";
  sim.restore(snap);
  Trace again;
  while (sim.time() < 2.6) {
    command(sim.time());
    sim.step(cmds);
    record(sim, fb, again);
  }
  expect_same(first, again);
}

TEST(Snapshot, AStateOfAnotherModelIsRefused) {
  Simulator a(test::jl4_with_j_wire(64, false));
  Simulator b(test::jl4_with_j_wire(96, false));
  try {
    a.restore(b.snapshot());
    ADD_FAILURE() << "restored a state with other node counts";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), "snapshot");
    EXPECT_NE(std::string(e.what()).find("node count"), std::string::npos) << e.what();
  }
  // Commands of the wrong size or not finite are refused before the state changes.
  const std::uint64_t before = a.state().hash();
  StepCommands bad;
  bad.reset(3);
  EXPECT_THROW(a.step(bad), InputError);
  bad.reset(2);
  bad.drive[1].translation = std::nan("");
  EXPECT_THROW(a.step(bad), InputError);
  EXPECT_EQ(a.state().hash(), before);
}

// Box2D's determinism test does the same: the default scenario's state after 2 s of simulated time
// (the autopilot's J wire and catheter in the iliac arteries, the heart beating), as one hash over
// everything that changes. It holds across builds (release, the sanitizers: the same operations
// in the same order, no fused multiply-add) and thread counts.
//
// On an intended change of behaviour (physics, the autopilot, the default scenario, the anatomy)
// this fails: check that the change is meant and that `make run` still reaches every landmark,
// then put the hash the failure prints here and say why in the commit message.
TEST(Snapshot, TheDefaultScenariosHashAfterTwoSecondsIsPinned) {
  Simulator sim(default_scenario());
  Autopilot pilot(sim);
  StepCommands cmds;
  while (sim.time() < 2.0 - 1e-9) {
    pilot.command(sim, cmds);
    sim.step(cmds);
  }
  EXPECT_EQ(sim.metrics().steps, 4000);
  EXPECT_EQ(sim.state().hash(), 0x0e3270f9338a71b1ull)
      << "now 0x" << std::hex << sim.state().hash();
}

}  // namespace
}  // namespace vcsim

namespace vcsim {
namespace {

// The engine's threads change no result (docs/architecture.md, "Threads"): the default scene's
// first second (the J wire and the guide, 256 nodes each, side by side on two threads when the
// machine has them) is the same bit for bit on one thread, hand forces included.
TEST(Simulator, TheStepIsTheSameOnOneThread) {
  auto run = [](bool one) {
    std::optional<ThreadLimit> limit;
    if (one) limit.emplace(1);
    Simulator sim(load_scenario(default_scenarios_dir() / "default.json"));
    Autopilot pilot(sim);
    StepCommands cmds;
    double force = 0.0;
    while (sim.time() < 1.0 - 1e-9) {
      pilot.command(sim, cmds);
      sim.step(cmds);
      force += sim.instrument(0).drive.axial_force;
    }
    return std::make_pair(sim.state().hash(), force);
  };
  const auto many = run(false), one = run(true);
  EXPECT_EQ(many.first, one.first);
  EXPECT_EQ(many.second, one.second);
}

}  // namespace
}  // namespace vcsim
