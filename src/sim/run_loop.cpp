// The loop that connects a Simulator to an InputSource (timeline, autopilot, OpenIGTLink), at
// full speed or paced to the wall clock for a live device.
#include <algorithm>
#include <chrono>
#include <thread>

#include <tbb/global_control.h>

#include "vcsim/core.h"
#include "vcsim/sim.h"

namespace vcsim {

RealTimePacer::RealTimePacer(double step_s, double max_catch_up_s)
    : step_(step_s), max_catch_up_(max_catch_up_s) {}

void RealTimePacer::wait(double sim_time) {
  const double now = now_us();
  last_lag_ = 0.0;
  if (!started_) {
    started_ = true;
    origin_us_ = now - sim_time * 1e6;
    return;
  }
  const double due = origin_us_ + sim_time * 1e6;
  if (now < due) {
    // Absolute deadlines: oversleeping one step (the kernel's timer slack) is not carried over.
    using namespace std::chrono;
    const auto until = steady_clock::time_point(
        duration_cast<steady_clock::duration>(duration<double, std::micro>(due)));
    std::this_thread::sleep_until(until);
    return;
  }
  const double lag = (now - due) * 1e-6;
  last_lag_ = lag;
  max_lag_ = std::max(max_lag_, lag);
  if (lag > step_) ++late_;
  if (lag > max_catch_up_) {
    origin_us_ += lag * 1e6;
    ++resyncs_;
  }
}

RunLoopStats run_loop(Simulator& sim, InputSource& input, const RunLoopSettings& settings,
                      RunObserver* observer) {
  RunLoopStats stats;
  RealTimePacer pacer(sim.dt(), settings.max_catch_up);
  StepCommands cmds;
  cmds.reset(static_cast<std::size_t>(sim.num_instruments()));
  std::vector<HandFeedback> feedback;
  InstrumentChange change;
  const double dt = sim.dt();
  while (sim.time() < settings.end_time - 1e-9) {
    if (settings.stop && settings.stop->load(std::memory_order_relaxed)) {
      stats.stopped = true;
      break;
    }
    // The step computes the state at t + dt: not before the wall clock gets there.
    if (settings.realtime) pacer.wait(sim.time() + dt);
    // Instrument exchanges asked for before this step, each applied (or refused) in turn.
    while (input.poll_exchange(sim.time(), change)) {
      try {
        sim.exchange(change);
      } catch (const InputError& e) {
        ++stats.refused_exchanges;
        input.exchange_refused(change, e);
        continue;
      }
      ++stats.exchanges;
      input.exchanged(change, sim.instrument_names());
      if (observer) observer->exchanged(sim, change);
    }
    input.poll(sim.time(), cmds);
    if (observer && !observer->before_step(sim, cmds)) break;
    sim.step(cmds);
    ++stats.steps;
    sim.feedback(feedback);
    input.publish(feedback);
    if (observer) observer->after_step(sim);
    if (settings.stop_on_escape && sim.metrics().escape_steps > 0) {
      stats.stopped_on_escape = true;
      break;
    }
  }
  stats.late_steps = pacer.late_steps();
  stats.max_lag = pacer.max_lag();
  stats.resyncs = pacer.resyncs();
  return stats;
}

struct ThreadLimit::Impl {
  explicit Impl(int threads)
      : control(tbb::global_control::max_allowed_parallelism,
                static_cast<std::size_t>(std::max(1, threads))) {}
  tbb::global_control control;
};

ThreadLimit::ThreadLimit(int threads) : impl_(std::make_unique<Impl>(threads)) {}

ThreadLimit::~ThreadLimit() = default;

}  // namespace vcsim
