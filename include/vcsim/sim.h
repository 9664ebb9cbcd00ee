// vcsim sim: a procedure as one simulation. A Scenario (data/scenarios/*.json) names the patient,
// the instruments from the catalogue and how they are nested, the input (a scripted timeline or
// the autopilot), landmarks to reach, contrast and the fluoroscopy view. A Simulator holds the
// Scene (anatomy, beating wall, instrument models) and the State (rods, drive, contrast, metrics)
// and advances them by one fixed step from the device commands (docs/architecture.md "The step").
// The Autopilot is a closed-loop controller that produces device commands, never moving nodes.
//
// Files carry units in key names (mm, deg, s, ml/s); structs hold SI.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "vcsim/anatomy.h"
#include "vcsim/beating_wall.h"
#include "vcsim/haptics.h"
#include "vcsim/instruments.h"
#include "vcsim/solver.h"

namespace vcsim {

// ---------------------------------------------------------------------------------------------
// Scenario

struct ScenarioInstrument {
  std::string name;             // the name timelines, landmarks and the autopilot use ("catheter")
  std::string catalogue;        // catalogue entry ("catheter-jl4-6f")
  std::string inside;           // name of the instrument whose lumen holds this one, "" for none
  bool rim = true;              // with `inside`: its edges leaving that lumen wrap round its rim
  int max_nodes = 256;          // at most 512
  double tip_segment = 1.0e-3;  // m, most distal segment
};

// A place an instrument's distal tip should reach: in `segment`, at least `distance` m beyond
// its ostium (where it leaves its parent's lumen; anatomy's ostium_distance).
struct Landmark {
  std::string name;
  std::string instrument;
  std::string segment;
  double distance = 0.0;  // m
};

// One phase of the autopilot's plan. kNavigate: `instrument`'s tip is steered along the route
// from where it is to `goal` (rotate the shaped tip toward the branch, advance, back off and
// retry when stuck); `follower` keeps its tip `follow_gap` m behind the leader's tip (a catheter
// over its wire), other instruments hold. kWithdraw: `instrument` is pulled back to `depth`
// (0 = out of the patient), or to `depth` behind the depth of `relative_to`. kInject: the syringe
// gives `flow` ml/s for `duration` s. kWait: nothing for `duration` s.
struct AutopilotPhase {
  enum class Kind { kNavigate, kWithdraw, kInject, kWait };
  Kind kind = Kind::kNavigate;
  std::string instrument;
  std::string goal_segment;
  double goal_distance = 0.0;  // m beyond the goal segment's ostium
  double tolerance = 3e-3;     // m: the goal counts as reached within this arc length
  std::string follower;
  double follow_gap = 0.03;  // m
  double depth = 0.0;        // m (withdraw)
  std::string relative_to;   // (withdraw)
  double flow = 0.0;         // ml/s (inject)
  double duration = 0.0;     // s (inject, wait)
  double speed = 0.1;        // m/s, advance and withdrawal speed
  double seat = 0.0;         // m pushed on once the goal is reached (navigate)
};
const char* to_string(AutopilotPhase::Kind k);

struct ContrastSettings {
  double blood_flow = 1.5;     // ml/s into the injected vessel's tree (clinical.md, LCA at rest)
  double blood_speed = 0.2;    // m/s, mean transport speed of contrast in the coronaries
  double washout = 1.0;        // s, time constant of clearance after the bolus
  double concentration = 1.0;  // of the injected contrast, fraction of 350 mgI/ml
  void validate(const std::string& source) const;
};

// Contrast transport (docs/scenarios.md): an injection at a tree location fills that segment and
// every segment downstream of it after a transport delay (centreline distance / blood speed) to
// c = concentration q / (q + Q), q the syringe flow and Q the blood flow through the injected
// vessel (the coronary flow for a coronary, the cardiac output elsewhere); without flow the
// contrast washes out with a time constant.
class ContrastModel {
 public:
  ContrastModel() = default;
  ContrastModel(const VesselTree& tree, const ContrastSettings& settings, double dt);
  // One step of dt; `at` is where the injection enters (used when an injection starts).
  void step(double flow_ml_s, const TreeLocation& at);
  const std::vector<float>& concentration() const { return c_; }
  int injected_segment() const { return segment_; }
  double volume() const { return volume_; }  // ml injected so far

 private:
  const VesselTree* tree_ = nullptr;
  ContrastSettings s_;
  double dt_ = 1e-3;
  std::vector<float> c_;
  std::vector<double> arrival_;  // (segment) transport delay from the injection point, s; < 0 no
  std::vector<float> history_;   // syringe flow of the last 2 s, ring buffer (ml/s)
  std::size_t pos_ = 0;
  int segment_ = -1;
  double volume_ = 0.0;
};

// The fluoroscopy the runner records (validated against the C-arm's limits by the renderer).
struct FluoroSettings {
  double primary_deg = 40.0;     // + LAO, - RAO
  double secondary_deg = -30.0;  // + CRA, - CAU
  double fov_mm = 200.0;
  int size = 512;
  double dose = 1e4;  // photons per pixel before the patient
  int energy_kev = 60;
  double fps = 15.0;        // frames per simulated second
  bool follow_tip = false;  // pan the table to keep the last phase's instrument tip centred
};

// What the hands feel (physics.md 6.1): the hand-force definition and an optional low-pass for a
// haptic device.
struct FeedbackSettings {
  SolverSettings::HandForce hand_force = SolverSettings::HandForce::kQuasiStatic;
  double cutoff_hz = 0.0;  // first-order low-pass of force and torque; 0: the raw signal
};

struct Scenario {
  std::string name;
  std::string description;
  std::string source;  // file it was read from (errors)
  // A built-in patient ("default", "left-dominant") or a vessel tree file (vcsim-anatomy JSON),
  // relative to the scenario's folder.
  std::string anatomy = "default";
  bool beating = true;
  MotionSettings motion;
  double dt = 1e-3;          // s, physics step (1 kHz or faster)
  double time_limit = 60.0;  // s of simulated time before the run ends unfinished
  // The introducer sheath's straight part inside the vessel from the access point (m; 0: none),
  // its lumen 0.2 mm wider than the widest instrument (physics.md 6.2).
  double sheath_length = 25e-3;
  // While a hand moves faster than fine_step_speed (m/s), each step is split into as many steps
  // as keep the hand's travel per step within fine_step_travel (m), at least 2 and at most
  // fine_steps, with the masses scaled for the shorter step (physics.md 5.4): the scaled inertia
  // of a fast pull grows with the travel per step. fine_steps 1: never split.
  int fine_steps = 8;
  double fine_step_speed = 0.13;
  double fine_step_travel = 25e-6;
  // A step after which a hand force has changed by more than fine_step_jump (N) is taken again
  // split at least twice as finely (and at least as for a hand at fine_step_speed; at most
  // fine_steps), and steps stay split so for fine_step_hold (s): a scaled mass stopped or let go
  // suddenly (physics.md 5.4). 0: never.
  double fine_step_jump = 0.3;
  double fine_step_hold = 0.02;
  std::vector<ScenarioInstrument> instruments;
  std::string timeline;  // timeline file (relative to the scenario's folder); "" = autopilot
  std::vector<AutopilotPhase> autopilot;
  std::vector<Landmark> landmarks;
  ContrastSettings contrast;
  FluoroSettings fluoro;
  FeedbackSettings feedback;
  std::filesystem::path base_dir;  // folder relative paths start from

  int find_instrument(std::string_view name) const;  // index or -1
};

// Parses a scenario; InputError names `source` and the field ("instruments[1].catalogue").
// Segment names are checked against the anatomy when the Simulator is built.
Scenario parse_scenario(std::string_view json_text, const std::string& source,
                        const std::filesystem::path& base_dir = ".");
Scenario load_scenario(const std::filesystem::path& file);
// data/scenarios of the source tree ($VCSIM_SCENARIOS_DIR if set).
std::filesystem::path default_scenarios_dir();

// ---------------------------------------------------------------------------------------------
// Where things are in the tree

// The tree location nearest a point: the segment whose lumen (centreline distance minus radius)
// is nearest, and the arc length of the projection. `inside` is false when the point is outside
// every lumen by more than `slack` m.
struct TreeHit {
  TreeLocation loc;
  double outside = 0.0;  // m beyond the lumen radius (< 0 inside)
};
TreeHit locate(const VesselTree& tree, const Vec3& p);
// True when `seg` is `ancestor` or lies below it.
bool is_descendant(const VesselTree& tree, int seg, int ancestor);

// ---------------------------------------------------------------------------------------------
// Simulator

struct LandmarkRecord {
  std::string name;
  std::string instrument;
  bool reached = false;
  double time = 0.0;  // s, simulated time first reached
};

struct SimMetrics {
  double sim_time = 0.0;   // s
  double wall_time = 0.0;  // s spent in step()
  std::int64_t steps = 0;
  std::vector<double> tip_path;          // (instrument) m travelled by the distal tip
  std::vector<double> peak_wall_force;   // (instrument) N, largest wall contact force
  std::vector<double> peak_axial_force;  // (instrument) N at the hand, largest magnitude
  // (instrument) N, largest change of the hand force from one step to the next while inserted:
  // a physical load builds up over milliseconds, a numerical spike within a step.
  std::vector<double> peak_axial_jump;
  std::vector<double> peak_torque;  // (instrument) N m at the hand, largest magnitude
  std::vector<LandmarkRecord> landmarks;
  double contrast_volume = 0.0;  // ml injected
  int rollbacks = 0;             // steps that produced a non-finite value and were undone
  // Steps taken again split after a sudden change of a hand force (Scenario::fine_step_jump).
  std::int64_t resplit_steps = 0;
};

class Simulator {
 public:
  // Builds the anatomy (cached lumen), the beating wall and the instruments at the sheath.
  // Throws InputError for a scenario that does not fit the anatomy or the catalogue.
  explicit Simulator(Scenario scenario);
  ~Simulator();
  Simulator(const Simulator&) = delete;
  Simulator& operator=(const Simulator&) = delete;

  // One step of dt: commands (by instrument name, operator units) -> drive, wall at t + dt,
  // instruments, contrast, metrics. A step that produces a non-finite value is undone, counted
  // in metrics().rollbacks and the instruments are held still for that step.
  void step(const DeviceCommands& commands);

  const Scenario& scenario() const { return sc_; }
  double time() const { return time_; }
  const VesselTree& tree() const { return tree_; }  // at rest, lesions applied
  const Lumen& lumen() const { return lumen_; }
  const CardiacMotion* motion() const { return motion_ ? &*motion_ : nullptr; }
  int num_instruments() const { return static_cast<int>(insts_.size()); }
  const Instrument& instrument(int i) const { return insts_[i]; }
  const InstrumentSpec& instrument_spec(int i) const { return specs_[i]; }
  // Distal tip position and its tree location (in the vessel as it is now).
  Vec3 tip(int i) const;
  // The tip carried back to the anatomy at rest (undoing the cardiac motion where it is).
  Vec3 tip_rest(int i) const;
  TreeHit tip_location(int i) const;
  // Inserted depth of an instrument (m).
  double depth(int i) const { return insts_[i].drive.depth; }
  // How many fine steps the last step was split into (1: none; physics.md 5.4).
  int split() const { return split_; }
  // Contrast concentration per segment (fraction of 350 mgI/ml).
  const std::vector<float>& contrast() const { return contrast_.concentration(); }
  const SimMetrics& metrics() const { return metrics_; }
  std::vector<ForceFeedback> feedback() const;
  // The same into `out`, reusing its storage (no allocation once warm: for every step).
  void feedback(std::vector<ForceFeedback>& out) const;
  bool all_landmarks_reached() const;
  // The route (centreline points) from the access to a place, m.
  std::vector<Vec3> route_to(const TreeLocation& to, double spacing = 1e-3) const;

 private:
  void update_metrics(const std::vector<Vec3>& old_tips);
  // The fastest hand this step's commands ask for (m/s).
  double hand_speed() const;
  // How many fine steps a step at this hand speed is split into (1: not split).
  int split_for(double speed) const;
  // The split of a hand at fine_step_speed (at least 2).
  int threshold_split() const;
  // The instruments over one step of dt, in split_ fine steps; the hand force is their mean.
  void advance();
  // Puts in every instrument's masses and inertias for steps of dt / n (kept momentum where a
  // mass grows, kept velocity where it shrinks).
  void use_masses(int n);

  // An instrument's masses and inertias (RodModel's fields of the same names).
  struct MassSet {
    std::vector<double> node_mass, inv_mass;
    std::vector<Vec3> inertia, inv_inertia;
  };

  Scenario sc_;
  VesselTree tree_;
  Lumen lumen_;
  std::optional<CardiacMotion> motion_;
  std::unique_ptr<BeatingLumen> beating_;
  std::unique_ptr<BeatingWall> beating_wall_;
  AabbTree static_tree_;
  std::unique_ptr<StaticWall> static_wall_;
  VesselWall* wall_ = nullptr;
  std::vector<InstrumentSpec> specs_;
  std::vector<Instrument> insts_;
  std::vector<Coupling> couplings_;
  SolverSettings settings_;
  std::vector<DriveCommand> drive_;
  std::vector<DriveCommand> sub_drive_;  // (instrument) the hand's command for one fine step
  // (n - 1, instrument) the masses scaled for steps of dt / n, n = 1 .. fine_steps (n = 1: the
  // scenario's step), built once.
  std::vector<std::vector<MassSet>> masses_;
  int split_ = 1;  // the steps are split into split_ fine steps and use masses_[split_ - 1]
  double hold_until_ = -1.0;  // s: steps before this stay split at least held_split_ times
  int held_split_ = 1;        // (a sudden load)
  std::vector<double> fine_force_, fine_torque_;  // (instrument) hand force summed over them
  std::vector<RodState> backup_;
  std::vector<DriveState> backup_drive_;
  ContrastModel contrast_;
  std::vector<Vec3> old_tips_;
  std::vector<std::pair<int, int>> landmark_ids_;  // (landmark) instrument and segment index
  double next_landmark_check_ = 0.0;
  std::vector<double> last_axial_force_;  // (instrument) N of the previous step, NaN if outside
  double time_ = 0.0;
  SimMetrics metrics_;
};

// ---------------------------------------------------------------------------------------------
// Running against an input source, as fast as possible or in real time

// Paces simulated time to the wall clock. wait(t) sleeps (never spins) until the wall clock has
// run t - t0 seconds since the first call (t0 its argument), so a paced run never gets ahead of
// real time. When the caller is behind, wait() returns at once and records the lag; a step is
// late when it starts more than one step behind. A lag beyond `max_catch_up` (a stall: swapping,
// a debugger, a physics slower than real time) is not made up: the schedule moves to now, so
// the run goes on in real time instead of racing, and the move is counted as a resync.
class RealTimePacer {
 public:
  explicit RealTimePacer(double step_s, double max_catch_up_s = 0.25);
  void wait(double sim_time);  // s
  std::int64_t late_steps() const { return late_; }
  double max_lag() const { return max_lag_; }  // s, the largest lag seen (before any resync)
  std::int64_t resyncs() const { return resyncs_; }

 private:
  double step_, max_catch_up_;
  bool started_ = false;
  double origin_us_ = 0.0;  // wall clock (now_us) at simulated time 0
  std::int64_t late_ = 0, resyncs_ = 0;
  double max_lag_ = 0.0;
};

struct RunLoopSettings {
  double end_time = 0.0;       // s simulated; the loop ends when the simulator reaches it
  bool realtime = false;       // pace to the wall clock (RealTimePacer)
  double max_catch_up = 0.25;  // s, see RealTimePacer
  // When set (a signal handler may set it: lock-free), the loop ends before the next step.
  const std::atomic<bool>* stop = nullptr;
};

struct RunLoopStats {
  std::int64_t steps = 0;
  std::int64_t late_steps = 0;  // real time only (RealTimePacer)
  double max_lag = 0.0;         // s
  std::int64_t resyncs = 0;
  bool stopped = false;  // ended by RunLoopSettings::stop
};

// What a caller does around each step (film, progress, a controller's log).
class RunObserver {
 public:
  virtual ~RunObserver() = default;
  // With the commands for the next step; false ends the run before that step.
  virtual bool before_step(const Simulator& sim, const DeviceCommands& commands) {
    (void)sim;
    (void)commands;
    return true;
  }
  virtual void after_step(const Simulator& sim) { (void)sim; }
};

// Steps `sim` until settings.end_time, *settings.stop or the observer says so: per step, waits for
// the wall clock (real time), polls `input` for the commands, steps, and publishes the hub forces
// back to `input`. Allocates nothing per step once warm (besides what the observer does).
RunLoopStats run_loop(Simulator& sim, InputSource& input, const RunLoopSettings& settings,
                      RunObserver* observer = nullptr);

// ---------------------------------------------------------------------------------------------
// Autopilot

// Drives the scenario's autopilot plan through device commands (position mode, operator units),
// reading the simulator's state as a trainee reads the screen: tip positions and forces.
class Autopilot {
 public:
  explicit Autopilot(const Simulator& sim);
  // The commands for the next step.
  void command(const Simulator& sim, DeviceCommands& out);
  bool finished() const { return failed_ || phase_ >= static_cast<int>(plan_.size()); }
  bool failed() const { return failed_; }  // gave up (stuck after every retry)
  int phase() const { return phase_; }
  const std::string& status() const { return status_; }  // what it is doing, for the log
  int retries() const { return retries_total_; }

  int max_retries = 16;        // per phase, then the autopilot gives up
  double stuck_time = 0.8;     // s without progress before backing off
  double backoff = 0.015;      // m pulled back before a retry
  double max_slack = 0.06;     // m inserted without tip progress (a loop forming) before a retry
  double retry_turn = 0.7854;  // rad turned before each retry (an eighth of a turn)
  double steer_gain = 3.0;     // 1/s, roll rate per radian of tip misalignment
  double max_spin = 3.14;      // rad/s at the hand
  double max_accel = 3.0;      // m/s^2 of a withdrawal's pull at the hand (0: a velocity step)
  int max_reengage = 3;        // re-engagements of a held instrument that fell out, per run
  bool trace = false;          // print what it sees and does to stderr, 4 times a second

 private:
  void start_phase(const Simulator& sim);
  void navigate(const Simulator& sim, const AutopilotPhase& ph);
  // An instrument seated at a goal by an earlier phase (a guiding catheter in an ostium).
  struct Hold {
    int instrument = -1;
    AutopilotPhase phase;  // the phase that seated it (run again to re-engage)
    double depth = 0.0;    // seated depth (m)
    double target = 0.0;   // tip progress along the route to keep (m)
    double seen = 0.0;     // last time the tip was within reach of its route (s)
    std::vector<Vec3> route;
    std::vector<double> route_s;
  };
  std::vector<AutopilotPhase> plan_;
  std::vector<Hold> holds_;
  int phase_ = -1;
  bool failed_ = false;
  double phase_start_ = 0.0;
  double pull_speed_ = 0.0;                         // m/s of the current withdrawal
  std::vector<double> depth_, roll_, roll_target_;  // (instrument) commanded, m and rad
  int leader_ = -1, follower_ = -1;
  int relative_ = -1;  // the instrument a withdraw phase's depth is relative to, or -1
  int goal_segment_ = -1;
  double goal_distance_ = 0.0;           // m from the goal segment's first point
  std::vector<Vec3> route_;              // current navigation route (rest anatomy)
  std::vector<double> route_s_;          // arc length along it
  std::vector<int> route_segment_;       // segment each route point lies in
  std::vector<unsigned char> on_route_;  // (segment) 1 if the route passes through it
  double progress_ = 0.0;
  double best_progress_ = 0.0;
  double best_time_ = 0.0;
  double depth_at_best_ = -1.0;       // inserted depth when the tip last made progress (m)
  double phase_best_progress_ = 0.0;  // the furthest the tip got along the route in this phase
  double phase_best_depth_ = 0.0;     // the inserted depth then (m)
  double roll_start_ = 0.0;           // roll when the phase started (rad)
  bool backing_off_ = false;
  double backoff_until_ = 0.0;  // depth to pull back to
  int retries_ = 0;
  int retries_total_ = 0;
  int reengaged_ = 0;
  std::string status_;
  double next_trace_ = 0.0;
  double aim_distance_ = 0.0, aim_angle_ = 0.0;  // of the leader's tip to its aim (trace)
};

}  // namespace vcsim
