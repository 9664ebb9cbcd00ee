// The trainer's physics thread: a Simulator stepped at real time (RealTimePacer) from what the
// hands do (the window's controls and, at the same time, a live OpenIGTLink device), every
// step's commands recorded exactly (CommandRecording), snapshots kept for a rewind, and the
// state the window draws handed over as a copy (ViewState) under a mutex. The window never
// touches the Simulator while the thread runs; the thread never touches GL.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "vcsim/assess.h"
#include "vcsim/haptics.h"
#include "vcsim/render.h"
#include "vcsim/sim.h"

namespace vcsim::trainer {

// Bits of StepCommands::buttons the trainer sets (docs/devices.md: provisional meanings).
inline constexpr std::uint32_t kButtonFluoro = 1u << 0;  // fluoroscopy pedal
inline constexpr std::uint32_t kButtonCine = 1u << 1;    // cine pedal
inline constexpr std::uint32_t kButtonDeploy = 1u << 2;  // stent deployment

// What the hands at the window do now (keyboard, mouse, gamepad): written by the window's
// thread whenever an input changes it, read by the physics thread at every step.
struct OperatorCommands {
  std::vector<DriveCommand> drive;  // (instrument) velocity mode: m/s and rad/s
  double syringe_flow = 0.0;        // m^3/s
  double balloon_pressure = 0.0;    // Pa
  std::uint32_t buttons = 0;
  std::uint64_t seq = 0;  // counts the input events that changed these (latency measurement)
  double event_us = 0.0;  // wall clock (now_us) of the event that made `seq`
};

// What the window draws of the simulation: a copy made by the physics thread.
struct ViewState {
  std::uint64_t version = 0;  // grows with every copy handed over
  FrameSnapshot frame;        // what the fluoroscopy and the 3D view draw
  double time = 0.0;          // s simulated (procedure time)
  std::int64_t steps = 0;
  bool paused = false;
  std::vector<double> depth, roll;          // (instrument) m, rad
  std::vector<HandFeedback> feedback;       // (instrument) what each hand feels
  std::vector<std::uint8_t> device_driven;  // (instrument) 1: the device commands it
  double contrast_volume = 0.0;             // m^3 injected (the state's)
  double syringe_flow = 0.0;                // m^3/s of the last step
  double balloon_pressure = 0.0;            // Pa of the last step
  std::uint32_t buttons = 0;                // of the last step
  double fluoro_time = 0.0;                 // s simulated with the fluoroscopy pedal down
  std::uint64_t input_seq = 0;              // OperatorCommands::seq the last step used
  double lag = 0.0;                         // s, the last step's lag behind the wall clock
  int rollbacks = 0;
  std::vector<std::uint8_t> landmarks;   // (landmark) 1 when reached
  std::vector<std::string> instruments;  // the scene's, in order (an exchange changes them)
  int exchanges = 0;                     // instrument exchanges made in the session
  int assessment_events = 0;             // Assessment::num_events() (the film's key moments)
  IgtlStats device;
  bool has_device = false;
  std::int64_t recorded_steps = 0;
  std::string message;  // the last thing the physics thread wants the person to know
};

enum class Request { kPause, kResume, kTogglePause, kRewind, kRestart };

class PhysicsThread {
 public:
  // Builds the simulator now (in the caller's thread) and the initial snapshot. `device` may be
  // null. Does not start stepping before start().
  PhysicsThread(const Scenario& scenario, IgtlServer* device);
  ~PhysicsThread();
  PhysicsThread(const PhysicsThread&) = delete;
  PhysicsThread& operator=(const PhysicsThread&) = delete;

  const SimModel& model() const { return sim_.model(); }
  const std::shared_ptr<const SimModel>& shared_model() const { return sim_.shared_model(); }
  void start();
  // Ends the thread (joins it); then the simulator and the recording may be read.
  void stop();

  // From the window's thread.
  void set_operator(const OperatorCommands& c);
  void request(Request r, double seconds = 0.0);
  // An instrument exchange (docs/scenarios.md, "Instrument exchange"): queued, made between two
  // steps, recorded; a refusal becomes the view's message. A rewind never goes back across one
  // (the snapshots start again after it); a restart does.
  void exchange(const InstrumentChange& c);
  // Copies the latest view into `out` when it is newer than out.version; false otherwise.
  bool latest(ViewState& out);

  // After stop().
  const Simulator& simulator() const { return sim_; }
  CommandRecording& recording() { return recording_; }
  const std::vector<float>& lag_samples() const { return lags_; }  // s, one per step
  RunLoopStats loop_stats() const { return stats_; }
  double fluoro_time() const { return fluoro_time_; }
  int rewinds() const { return rewinds_; }
  int exchanges() const { return exchanges_made_; }
  // What the session measured (docs/assessment.md), of the steps that led to the final state: a
  // rewind takes it back with the state.
  const Assessment& assessment() const { return assess_; }
  int restarts() const { return restarts_; }

  // Snapshots for a rewind: one every kSnapshotEvery s of simulated time, the last kSnapshots.
  static constexpr double kSnapshotEvery = 0.5;
  static constexpr std::size_t kSnapshots = 24;

 private:
  void run();
  void loop();
  void publish(bool paused);
  void handle(Request r, double seconds);
  void poll_commands();
  // Makes `c` between two steps; the engine's refusal (also in message_) when it refuses it.
  std::optional<InputError> apply_exchange(const InstrumentChange& c);
  // The scene's instruments changed (an exchange, a restart): commands resized, the device bound
  // to the new order.
  void scene_changed(const InstrumentChange& c);

  Simulator sim_;
  IgtlServer* device_;
  SimState initial_;
  struct Saved {
    SimState state;
    double fluoro_time = 0.0;
    Assessment assessment;
  };
  std::deque<Saved> ring_;
  double next_snapshot_ = 0.0;
  CommandRecording recording_;
  StepCommands cmds_, dev_cmds_;
  InstrumentChange change_;  // one a device asks for
  int exchanges_made_ = 0;
  std::vector<HandFeedback> feedback_;
  double fluoro_time_ = 0.0;
  Assessment assess_, initial_assess_;
  int rewinds_ = 0, restarts_ = 0;
  std::vector<float> lags_;
  RunLoopStats stats_;
  std::uint64_t used_seq_ = 0;
  double last_lag_ = 0.0;
  std::string message_;

  std::thread thread_;
  std::mutex m_;  // guards everything below
  std::condition_variable cv_;
  bool quit_ = false, paused_ = false;
  OperatorCommands op_;
  std::vector<std::pair<Request, double>> requests_;
  std::vector<InstrumentChange> exchanges_;  // asked for by the window, not yet made
  ViewState view_;                           // the latest copy handed over
  ViewState back_;  // filled by the physics thread outside the lock, then swapped in
};

}  // namespace vcsim::trainer
