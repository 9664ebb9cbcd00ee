// The trainer's physics thread (physics.h).
#include "physics.h"

#include <algorithm>
#include <cstdio>
#include <optional>

#include "vcsim/core.h"

namespace vcsim::trainer {

namespace {
// A copy of the state for the window every this many steps (1 ms at the default 0.5 ms step):
// a few microseconds each, and at most a millisecond added to what the window shows.
constexpr int kPublishEvery = 2;
}  // namespace

PhysicsThread::PhysicsThread(const Scenario& scenario, IgtlServer* device)
    : sim_(scenario),
      device_(device),
      initial_(sim_.snapshot()),
      assess_(sim_),
      initial_assess_(assess_) {
  const auto n = static_cast<std::size_t>(sim_.num_instruments());
  recording_.scenario = scenario.name;
  recording_.scenario_file = scenario.source;
  recording_.dt = sim_.dt();
  for (const ScenarioInstrument& si : scenario.instruments)
    recording_.instruments.push_back(si.name);
  recording_.model_hash = sim_.model().hash();
  cmds_.reset(n);
  dev_cmds_.reset(n);
  op_.drive.assign(n, DriveCommand{});
  ring_.push_back({initial_, 0.0, initial_assess_});
  next_snapshot_ = kSnapshotEvery;
  lags_.reserve(1 << 20);
  publish(false);
}

PhysicsThread::~PhysicsThread() {
  stop();
}

void PhysicsThread::start() {
  if (thread_.joinable()) return;
  thread_ = std::thread([this] { run(); });
}

void PhysicsThread::stop() {
  {
    std::lock_guard lock(m_);
    quit_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void PhysicsThread::set_operator(const OperatorCommands& c) {
  {
    std::lock_guard lock(m_);
    const std::vector<DriveCommand> keep = std::move(op_.drive);
    op_ = c;
    if (op_.drive.size() != keep.size()) op_.drive = keep;  // never resized from outside
  }
  cv_.notify_all();
}

void PhysicsThread::request(Request r, double seconds) {
  {
    std::lock_guard lock(m_);
    requests_.emplace_back(r, seconds);
  }
  cv_.notify_all();
}

void PhysicsThread::exchange(const InstrumentChange& c) {
  {
    std::lock_guard lock(m_);
    exchanges_.push_back(c);
  }
  cv_.notify_all();
}

bool PhysicsThread::latest(ViewState& out) {
  std::lock_guard lock(m_);
  if (view_.version == out.version) return false;
  out = view_;
  return true;
}

void PhysicsThread::publish(bool paused) {
  ViewState& v = back_;
  const int n = sim_.num_instruments();
  v.frame = snapshot(sim_);
  v.time = sim_.time();
  v.steps = sim_.metrics().steps;
  v.paused = paused;
  v.depth.resize(static_cast<std::size_t>(n));
  v.roll.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    v.depth[static_cast<std::size_t>(i)] = sim_.instrument(i).drive.depth;
    v.roll[static_cast<std::size_t>(i)] = sim_.instrument(i).drive.roll;
  }
  sim_.feedback(v.feedback);
  v.device_driven.assign(static_cast<std::size_t>(n), 0);
  if (device_) {
    const std::uint64_t mask = device_->commanded_mask();
    for (int i = 0; i < n && i < 64; ++i)
      v.device_driven[static_cast<std::size_t>(i)] = (mask >> i) & 1u ? 1 : 0;
    v.device = device_->stats();
  }
  v.has_device = device_ != nullptr;
  v.contrast_volume = sim_.state().contrast.volume;
  v.syringe_flow = cmds_.syringe_flow;
  v.balloon_pressure = cmds_.balloon_pressure;
  v.buttons = cmds_.buttons;
  v.fluoro_time = fluoro_time_;
  v.input_seq = used_seq_;
  v.lag = last_lag_;
  v.rollbacks = sim_.metrics().rollbacks;
  v.landmarks.resize(sim_.metrics().landmarks.size());
  for (std::size_t k = 0; k < v.landmarks.size(); ++k)
    v.landmarks[k] = sim_.metrics().landmarks[k].reached ? 1 : 0;
  v.recorded_steps = recording_.steps();
  v.instruments = sim_.instrument_names();
  v.exchanges = exchanges_made_;
  v.assessment_events = assess_.num_events();
  v.message = message_;
  std::lock_guard lock(m_);
  v.version = view_.version + 1;
  std::swap(view_, back_);
}

void PhysicsThread::poll_commands() {
  // The device's exchanges first (the commands below are then for the scene they make), each
  // made or refused and answered.
  if (device_)
    while (device_->poll_exchange(sim_.time(), change_))
      if (std::optional<InputError> why = apply_exchange(change_))
        device_->exchange_refused(change_, *why);
  // What the window's hands do (copied under the lock), then the device for what it drives.
  {
    std::lock_guard lock(m_);
    std::copy(op_.drive.begin(), op_.drive.end(), cmds_.drive.begin());
    cmds_.syringe_flow = op_.syringe_flow;
    cmds_.balloon_pressure = op_.balloon_pressure;
    cmds_.buttons = op_.buttons;
    used_seq_ = op_.seq;
  }
  if (!device_) return;
  device_->poll(sim_.time(), dev_cmds_);
  const std::uint64_t mask = device_->commanded_mask();
  for (std::size_t i = 0; i < cmds_.drive.size() && i < 64 && i < dev_cmds_.drive.size(); ++i)
    if ((mask >> i) & 1u) cmds_.drive[i] = dev_cmds_.drive[i];
  if (cmds_.syringe_flow == 0.0) cmds_.syringe_flow = dev_cmds_.syringe_flow;
  cmds_.balloon_pressure = std::max(cmds_.balloon_pressure, dev_cmds_.balloon_pressure);
  cmds_.buttons |= dev_cmds_.buttons;
}

std::optional<InputError> PhysicsThread::apply_exchange(const InstrumentChange& c) {
  try {
    sim_.exchange(c);
  } catch (const InputError& e) {
    message_ = std::string("exchange refused: ") + e.what();
    return e;
  }
  recording_.append_exchange(c);
  assess_.exchanged(sim_, c);
  ++exchanges_made_;
  scene_changed(c);
  // A rewind stays on this side of the exchange: the snapshots start again after the next step
  // (a snapshot of this very moment would truncate the recording to before the exchange).
  ring_.clear();
  next_snapshot_ = sim_.time();
  message_ = describe(c);
  return std::nullopt;
}

void PhysicsThread::scene_changed(const InstrumentChange& c) {
  const auto n = static_cast<std::size_t>(sim_.num_instruments());
  cmds_.reset(n);
  dev_cmds_.reset(n);
  {
    // The window's next commands are for the new scene (set_operator keeps this size).
    std::lock_guard lock(m_);
    op_.drive.assign(n, DriveCommand{});
  }
  if (device_) device_->exchanged(c, sim_.instrument_names());
}

void PhysicsThread::handle(Request r, double seconds) {
  switch (r) {
    case Request::kPause:
      paused_ = true;
      break;
    case Request::kResume:
      paused_ = false;
      break;
    case Request::kTogglePause:
      paused_ = !paused_;
      break;
    case Request::kRewind: {
      // The newest snapshot at least `seconds` before now (or the oldest kept).
      if (ring_.empty()) {
        message_ = "nothing to rewind to yet: an exchange was just made";
        break;
      }
      const double target = sim_.time() - seconds;
      while (ring_.size() > 1 && ring_.back().state.time() > target + 1e-9) ring_.pop_back();
      const Saved& s = ring_.back();
      sim_.restore(s.state);
      fluoro_time_ = s.fluoro_time;
      assess_ = s.assessment;
      // The recording keeps exactly the steps that led to the restored state.
      recording_.truncate(s.state.metrics.steps);
      next_snapshot_ = s.state.time() + kSnapshotEvery;
      ++rewinds_;
      char buf[96];
      std::snprintf(buf, sizeof buf, "rewound to %.1f s", sim_.time());
      message_ = buf;
      break;
    }
    case Request::kRestart: {
      const std::vector<std::string> before = sim_.instrument_names();
      sim_.restore(initial_);
      ring_.clear();
      ring_.push_back({initial_, 0.0, initial_assess_});
      next_snapshot_ = kSnapshotEvery;
      fluoro_time_ = 0.0;
      assess_ = initial_assess_;
      recording_.clear();
      ++restarts_;
      message_ = "restarted";
      if (sim_.instrument_names() != before) {
        // The scenario's instruments again: a remove of what the session had added, for the
        // device's log.
        InstrumentChange undo;
        undo.kind = InstrumentChange::Kind::kRemove;
        undo.name = "instruments exchanged since the start (restart)";
        scene_changed(undo);
      }
      break;
    }
  }
}

void PhysicsThread::run() {
  try {
    loop();
  } catch (const std::exception& e) {
    // Nothing the window does reaches here (its commands are finite); should the engine fail,
    // the session stops stepping and says why, and what was recorded is still saved.
    message_ = std::string("physics stopped: ") + e.what();
    std::fprintf(stderr, "trainer: %s\n", message_.c_str());
    publish(true);
  }
}

void PhysicsThread::loop() {
  const double dt = sim_.dt();
  std::unique_ptr<RealTimePacer> pacer;
  std::vector<std::pair<Request, double>> todo;
  int since_publish = 0;
  for (;;) {
    bool paused = false;
    {
      std::unique_lock lock(m_);
      if (quit_) break;
      todo.swap(requests_);
    }
    for (const auto& [r, s] : todo) {
      handle(r, s);
      // After a pause, a rewind or a restart the clock starts again from here.
      if (pacer) stats_.resyncs += pacer->resyncs();
      pacer.reset();
    }
    {
      std::lock_guard lock(m_);
      paused = paused_;
    }
    std::vector<InstrumentChange> changes;
    {
      std::lock_guard lock(m_);
      changes.swap(exchanges_);
    }
    for (const InstrumentChange& c : changes) apply_exchange(c);
    if (!todo.empty() || !changes.empty() || paused) publish(paused);
    todo.clear();
    if (paused) {
      std::unique_lock lock(m_);
      cv_.wait_for(lock, std::chrono::milliseconds(50),
                   [&] { return quit_ || !requests_.empty(); });
      continue;
    }
    if (!pacer) pacer = std::make_unique<RealTimePacer>(dt);
    // The step computes the state at t + dt: not before the wall clock gets there.
    pacer->wait(sim_.time() + dt);
    last_lag_ = pacer->last_lag();
    lags_.push_back(static_cast<float>(last_lag_));
    ++stats_.steps;
    stats_.max_lag = std::max(stats_.max_lag, last_lag_);
    if (last_lag_ > dt) ++stats_.late_steps;
    poll_commands();
    assess_.before_step(sim_, cmds_);
    sim_.step(cmds_);
    assess_.after_step(sim_);
    recording_.append(cmds_);
    if (cmds_.buttons & kButtonFluoro) fluoro_time_ += dt;
    if (device_) {
      sim_.feedback(feedback_);
      device_->publish(feedback_);
    }
    if (sim_.time() >= next_snapshot_ - 1e-9) {
      ring_.push_back({sim_.snapshot(), fluoro_time_, assess_});
      if (ring_.size() > kSnapshots) ring_.pop_front();
      next_snapshot_ += kSnapshotEvery;
    }
    if (++since_publish >= kPublishEvery) {
      since_publish = 0;
      publish(false);
    }
  }
  if (pacer) stats_.resyncs += pacer->resyncs();
  publish(false);
}

}  // namespace vcsim::trainer
