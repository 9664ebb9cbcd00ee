// The run loop: the real-time pacer never runs ahead of the wall clock and records lateness; the
// loop polls, steps and publishes once per step and ends at its time, its stop flag or its
// observer; and an OpenIGTLink client drives a wire in the default patient in process. Waits
// are bounded; the only timing assertions are lower bounds a sleep guarantees.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <thread>

#include "../common/igtl_client.h"
#include "vcsim/core.h"
#include "vcsim/sim.h"

namespace vcsim {
namespace {

using namespace std::chrono_literals;

const bool kIgnoreSigpipe = (std::signal(SIGPIPE, SIG_IGN), true);

Scenario wire_scenario() {
  Scenario sc = parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "push",
    "motion": {"beating": false}, "dt_ms": 0.5,
    "instruments": [{"name": "wire", "catalogue": "wire-035-j3-hydrophilic", "tip_segment_mm": 2}],
    "input": {"type": "timeline", "file": "unused.json"}})",
                               "push.json");
  return sc;
}

TEST(SimulatorRunLoop, PacerNeverRunsAheadOfTheWallClock) {
  const double dt = 1e-3;
  RealTimePacer pacer(dt);
  // The pacer's clock starts inside the first wait, at or after `start`: read before it, so a
  // thread preempted between that wait and the read cannot make the bound below too tight.
  const double start = now_us();
  pacer.wait(dt);  // starts the clock: t = 1 ms is now
  for (int k = 2; k <= 60; ++k) {
    pacer.wait(k * dt);
    ASSERT_GE(now_us() - start, (k - 1) * dt * 1e6 - 1.0) << k;  // 1 us: the clock's rounding
  }
}

TEST(SimulatorRunLoop, PacerRecordsLatenessAndDoesNotRace) {
  const double dt = 1e-3;
  RealTimePacer pacer(dt, 0.25);
  pacer.wait(dt);
  EXPECT_EQ(pacer.late_steps(), 0);
  std::this_thread::sleep_for(50ms);  // a slow step
  pacer.wait(2 * dt);
  EXPECT_EQ(pacer.late_steps(), 1);
  EXPECT_GE(pacer.max_lag(), 0.048);
  EXPECT_EQ(pacer.resyncs(), 0);
  std::this_thread::sleep_for(400ms);  // a stall beyond the catch-up limit
  // After the resync the schedule starts again from the late wait's own clock reading (at or
  // after `before`): the next step is a whole step later, not late, so the run goes on in real
  // time instead of racing through the stall. Without the resync both waits would return at once.
  const double before = now_us();
  pacer.wait(3 * dt);
  EXPECT_EQ(pacer.late_steps(), 2);
  EXPECT_GE(pacer.max_lag(), 0.35);
  EXPECT_EQ(pacer.resyncs(), 1);
  pacer.wait(4 * dt);
  EXPECT_GE(now_us() - before, dt * 1e6 - 1.0);  // 1 us: the clock's rounding
}

// An input that counts what the loop asks of it.
class CountingInput : public InputSource {
 public:
  void poll(double, StepCommands& out) override {
    ++polls;
    out.drive.resize(1);
    out.drive[0].mode = DriveCommand::Mode::kPosition;
    out.drive[0].translation = 0.020;
  }
  void publish(std::span<const HandFeedback> feedback) override {
    ++publishes;
    if (feedback.size() != 1 || !std::isfinite(feedback[0].axial_force)) ++bad_feedback;
  }
  int polls = 0, publishes = 0, bad_feedback = 0;
};

TEST(SimulatorRunLoop, PollsStepsAndPublishesUntilItsEnd) {
  Simulator sim(wire_scenario());
  CountingInput input;
  RunLoopSettings s;
  s.end_time = 0.1;
  RunLoopStats st = run_loop(sim, input, s);
  EXPECT_EQ(st.steps, 200);
  EXPECT_EQ(sim.metrics().steps, 200);
  EXPECT_EQ(input.polls, 200);
  EXPECT_EQ(input.publishes, 200);
  EXPECT_EQ(input.bad_feedback, 0);
  EXPECT_FALSE(st.stopped);
  EXPECT_NEAR(sim.depth(0), 0.020, 1e-6);

  // The stop flag ends the loop before the next step; so does the observer.
  std::atomic<bool> stop{true};
  s.end_time = 1.0;
  s.stop = &stop;
  st = run_loop(sim, input, s);
  EXPECT_TRUE(st.stopped);
  EXPECT_EQ(st.steps, 0);
  struct StopAfter : RunObserver {
    bool before_step(const Simulator& sim, const StepCommands&) override {
      return sim.metrics().steps < 210;
    }
  } observer;
  stop = false;
  st = run_loop(sim, input, s, &observer);
  EXPECT_FALSE(st.stopped);
  EXPECT_EQ(st.steps, 10);
}

// Every step is profiled by stage (`vcsim run --profile`, metrics.json "profile"): each stage
// counted once per step, none negative, and the disjoint stages add up to no more than the step's
// total; the wire's stages (forces, collision, the distance solve) take time, the procedure's
// none (no balloon in the scene) beyond the clock's own reading.
TEST(SimulatorRunLoop, EveryStepIsProfiledByStage) {
  Simulator sim(wire_scenario());
  CountingInput input;
  RunLoopSettings s;
  s.end_time = 0.1;
  run_loop(sim, input, s);
  const SimProfile& p = sim.profile();
  double parts = 0.0;
  for (int k = 0; k < kNumSimStages; ++k) {
    const DurationHistogram& h = p.stages[static_cast<std::size_t>(k)];
    EXPECT_EQ(h.count(), 200) << to_string(static_cast<SimStage>(k));
    EXPECT_GE(h.mean(), 0.0) << to_string(static_cast<SimStage>(k));
    EXPECT_LE(h.quantile(0.5), h.quantile(0.99) * (1.0 + 1e-12));
    if (static_cast<SimStage>(k) != SimStage::kTotal) parts += h.mean();
  }
  const double total = p.stages[static_cast<std::size_t>(SimStage::kTotal)].mean();
  EXPECT_GT(total, 0.0);
  EXPECT_LE(parts, total * 1.0001);
  for (SimStage st : {SimStage::kForces, SimStage::kCollision, SimStage::kDistance})
    EXPECT_GT(p.stages[static_cast<std::size_t>(st)].mean(), 0.0) << to_string(st);
  const std::string table = p.table();
  EXPECT_NE(table.find("| collision |"), std::string::npos) << table;
  EXPECT_NE(table.find("| total |"), std::string::npos) << table;
}

TEST(SimulatorRunLoop, RealTimeRunTakesAtLeastItsSimulatedTime) {
  Simulator sim(wire_scenario());
  CountingInput input;
  RunLoopSettings s;
  s.end_time = 0.2;
  s.realtime = true;
  const double start = now_us();
  const RunLoopStats st = run_loop(sim, input, s);
  EXPECT_EQ(st.steps, 400);
  // The last step starts when the wall clock reaches 0.2 s, counted from the first step's due
  // time (which is when it starts): at least 0.2 s - dt after the start.
  EXPECT_GE(now_us() - start, (0.2 - 0.5e-3) * 1e6 - 1.0);
  EXPECT_GE(st.max_lag, 0.0);
}

TEST(SimulatorRunLoop, IgtlClientDrivesTheWire) {
  Simulator sim(wire_scenario());
  IgtlServerOptions o;
  o.port = 0;
  o.instruments = {"wire"};
  o.log = [](const std::string&) {};
  IgtlServer server(o);

  // The client pushes the wire to 25 mm once it is connected, then keeps repeating it.
  std::atomic<bool> done{false};
  std::thread client([&] {
    test::IgtlClient c;
    if (!c.connect(server.port())) return;
    while (!done) {
      c.send_transform("wire", 25.0);
      std::this_thread::sleep_for(20ms);
    }
    c.close();
  });

  // Wait (bounded) for the first command before the clock starts, so the outcome does not
  // depend on how fast the client thread gets going on a loaded machine.
  for (int i = 0; i < 1000 && server.stats().messages_accepted == 0; ++i)
    std::this_thread::sleep_for(10ms);
  RunLoopSettings s;
  s.end_time = 0.5;  // 0.5 m/s drive limit: 25 mm takes 50 ms
  s.realtime = true;
  const RunLoopStats st = run_loop(sim, server, s);
  done = true;
  client.join();
  const IgtlStats is = server.stats();
  EXPECT_EQ(st.steps, 1000);
  EXPECT_GE(is.connections, 1u);
  EXPECT_GE(is.messages_accepted, 1u);
  EXPECT_EQ(is.messages_dropped, 0u);
  EXPECT_NEAR(sim.depth(0), 0.025, 1e-4);
  EXPECT_GT(sim.metrics().tip_path[0], 0.015);
}

// An OpenIGTLink client changes the scene on the "exchange" device (docs/devices.md): a catheter
// added over the wire is answered "done", then driven by its name and felt (force_cath); removing
// the wire while it is in the patient is refused and answered, as is a request that does not
// parse; the run goes on. The loop runs without pacing, step by step between the client's moves.
TEST(SimulatorRunLoop, IgtlClientExchangesInstruments) {
  Simulator sim(wire_scenario());
  IgtlServerOptions o;
  o.port = 0;
  o.instruments = {"wire"};
  o.log = [](const std::string&) {};
  // This client reads only the messages it asks for. At the default 200 Hz the force feedback
  // it leaves unread fills its receive window in a few seconds, and a run slowed by TSan and a
  // loaded machine then outlasts the server's 3 s user timeout for a silent client, which drops
  // it (the policy for a device that lost power). 20 Hz leaves the window far from full.
  o.feedback_rate_hz = 20.0;
  IgtlServer server(o);
  test::IgtlClient c;
  ASSERT_TRUE(c.connect(server.port()));
  auto accepted = [&](std::uint64_t n) {
    for (int i = 0; i < 1000 && server.stats().messages_accepted < n; ++i)
      std::this_thread::sleep_for(10ms);
    return server.stats().messages_accepted >= n;
  };
  RunLoopSettings s;
  auto run_to = [&](double t) {
    s.end_time = t;
    run_loop(sim, server, s);
  };
  const double dt = sim.dt();
  ASSERT_TRUE(c.send_sensor("wire", {30.0, 0.0}));
  ASSERT_TRUE(accepted(1));
  run_to(0.1);  // 30 mm at the drive's 0.5 m/s
  EXPECT_NEAR(sim.depth(0), 0.030, 1e-9);

  ASSERT_TRUE(c.send_string("exchange", "add cath catheter-jr4-6f over=wire"));
  ASSERT_TRUE(accepted(2));
  run_to(0.1 + dt);  // applied before the step
  ASSERT_EQ(sim.num_instruments(), 2);
  EXPECT_EQ(sim.model().instrument_name(1), "cath");
  std::string reply;
  ASSERT_TRUE(c.read_string("exchange", reply));
  EXPECT_EQ(reply, "done: add cath catheter-jr4-6f over=wire");
  ASSERT_TRUE(c.send_sensor("cath", {20.0, 0.0}));
  ASSERT_TRUE(accepted(3));
  run_to(0.2);
  EXPECT_NEAR(sim.depth(1), 0.020, 1e-9);
  EXPECT_NEAR(sim.depth(0), 0.030, 1e-9);
  std::vector<double> force;
  EXPECT_TRUE(c.read_sensor("force_cath", force));
  EXPECT_EQ(force.size(), 2u);

  ASSERT_TRUE(c.send_string("exchange", "remove wire"));
  ASSERT_TRUE(accepted(4));
  run_to(0.2 + dt);
  ASSERT_TRUE(c.read_string("exchange", reply));
  EXPECT_EQ(reply.rfind("refused: remove wire: ", 0), 0u) << reply;
  EXPECT_NE(reply.find("withdraw it first"), std::string::npos) << reply;
  EXPECT_EQ(sim.num_instruments(), 2);

  ASSERT_TRUE(c.send_string("exchange", "swap wire cath"));
  ASSERT_TRUE(c.read_string("exchange", reply));
  EXPECT_EQ(reply.rfind("refused: swap wire cath: expected \"add NAME", 0), 0u) << reply;
  run_to(0.3);
  const IgtlStats st = server.stats();
  EXPECT_EQ(st.exchanges, 1u);
  EXPECT_EQ(st.exchanges_refused, 1u);
  EXPECT_EQ(st.messages_dropped, 1u);
  EXPECT_EQ(sim.num_instruments(), 2);
  c.close();
}

}  // namespace
}  // namespace vcsim
