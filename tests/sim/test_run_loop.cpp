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
  pacer.wait(dt);  // starts the clock: t = 1 ms is now
  const double start = now_us();
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
  pacer.wait(3 * dt);
  EXPECT_EQ(pacer.late_steps(), 2);
  EXPECT_GE(pacer.max_lag(), 0.35);
  EXPECT_EQ(pacer.resyncs(), 1);
  // After the resync the schedule starts again from now: the next step is due, not late, so
  // the run goes on in real time instead of racing through the stall.
  const double before = now_us();
  pacer.wait(4 * dt);
  EXPECT_GE(now_us() - before, 0.5 * dt * 1e6);
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

}  // namespace
}  // namespace vcsim
