// vcsim sim: a procedure as one simulation, split the way the rod and solver layers are. A
// Scenario (data/scenarios/*.json) names the patient, the instruments from the catalogue and how
// they are nested, the input (a scripted timeline or the autopilot), landmarks, contrast and the
// fluoroscopy view. From it a SimModel is built once (anatomy and its wall, the solver model of
// the instruments, names resolved to indices) and never written during a run; a SimState holds
// everything that changes (instruments, split, contrast, metrics, the random generator), so that
// copying it is a snapshot; a SimWorkspace holds the scratch (the beating wall's moving patches,
// the solver's contact lists and backups). sim_step advances a state by one step of dt from
// commands resolved to instrument indices and SI units (docs/architecture.md "The sim step").
// Simulator owns the three for the common case, with snapshot and restore.
//
// The Autopilot is a closed-loop controller that produces commands, never moving nodes.
// Files carry units in key names (mm, deg, s, ml/s); structs hold SI.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "vcsim/anatomy.h"
#include "vcsim/commands.h"
#include "vcsim/haptics.h"
#include "vcsim/instruments.h"
#include "vcsim/procedure.h"
#include "vcsim/solver.h"
#include "vcsim/units.h"

namespace vcsim {

// ---------------------------------------------------------------------------------------------
// Scenario

struct ScenarioInstrument {
  std::string name;       // the name timelines, landmarks and the autopilot use ("catheter")
  std::string catalogue;  // catalogue entry ("catheter-jl4-6f")
  std::string inside;     // name of the instrument whose lumen holds this one, "" for none
  // Name of the wire this one rides on (a balloon or stent catheter over the coronary wire, a
  // catheter exchanged over a wire): the wire runs in its lumen; "" for none. Both must be
  // `inside` the same instrument (or neither).
  std::string over;
  bool rim = true;              // with `inside`: its edges leaving that lumen wrap round its rim
  int max_nodes = 256;          // at most 512
  double tip_segment = 1.0e-3;  // m, most distal segment
};
// The instrument an input source's exchange adds (InstrumentChange::Kind::kAdd).
ScenarioInstrument to_scenario_instrument(const InstrumentChange& change);

// A place an instrument's distal tip should reach: in `segment`, at least `distance` m beyond
// its ostium (where it leaves its parent's lumen; anatomy's ostium_distance). An instrument added
// during the run counts once it is in the scene; one removed before reaching it misses it.
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
// gives `flow` for `duration` s. kWait: nothing for `duration` s. kPlace: `instrument` (a balloon
// or stent catheter on its wire) is advanced past lesion `lesion` and drawn back until the middle
// of its two markers lies on the lesion's middle, as seen along the route over a beat, within
// `tolerance` (Autopilot::place). kInflate: the indeflator ramps
// to `pressure` over `ramp` s and holds it `duration` s. kDeflate: no pressure for `duration` s.
// kAdd: `added` is brought into the scene (outside the patient, at the sheath); kRemove:
// `instrument`, withdrawn by an earlier phase, leaves it (docs/scenarios.md, "Instrument
// exchange").
struct AutopilotPhase {
  enum class Kind {
    kNavigate,
    kWithdraw,
    kInject,
    kWait,
    kPlace,
    kInflate,
    kDeflate,
    kAdd,
    kRemove
  };
  Kind kind = Kind::kNavigate;
  std::string instrument;
  std::string goal_segment;
  double goal_distance = 0.0;  // m beyond the goal segment's ostium
  double tolerance = 3e-3;     // m: the goal counts as reached within this arc length
  std::string follower;
  double follow_gap = 0.03;      // m
  double depth = 0.0;            // m (withdraw)
  std::string relative_to;       // (withdraw)
  double flow = 0.0;             // m^3/s (inject)
  double duration = 0.0;         // s (inject, wait)
  double speed = 0.1;            // m/s, advance and withdrawal speed
  double seat = 0.0;             // m pushed on once the goal is reached (navigate)
  int lesion = 0;                // (place)
  double approach_speed = 0.01;  // m/s over the last 70 mm of the route (place: the coronary)
  double pressure = 0.0;         // Pa (inflate)
  double ramp = 3.0;             // s (inflate)
  ScenarioInstrument added;      // (add) its name is `instrument`
};
const char* to_string(AutopilotPhase::Kind k);

struct ContrastSettings {
  double blood_flow = 1.5e-6;  // m^3/s into the injected vessel's tree (clinical.md, LCA at rest)
  double blood_speed = 0.2;    // m/s, mean transport speed of contrast in the coronaries
  double washout = 1.0;        // s, time constant of clearance after the bolus
  double concentration = 1.0;  // of the injected contrast, fraction of 350 mgI/ml
  void validate(const std::string& source) const;
};

// Contrast transport (docs/scenarios.md): an injection at a tree location fills that segment and
// every segment downstream of it after a transport delay (centreline distance / blood speed) to
// c = concentration q / (q + Q), q the syringe flow and Q the blood flow through the injected
// vessel (the coronary flow for a coronary, the cardiac output elsewhere); without flow the
// contrast washes out with a time constant. The state of it; contrast_step advances it.
struct ContrastState {
  std::vector<float> concentration;  // (segment) fraction of 350 mgI/ml
  std::vector<double> arrival;  // (segment) transport delay from the injection point, s; < 0 none
  std::vector<float> history;   // syringe flow of the last 2 s, ring buffer (m^3/s)
  std::size_t pos = 0;          // newest entry of `history`
  int segment = -1;             // where the current injection entered (-1: none)
  double volume = 0.0;          // m^3 injected so far
};
ContrastState make_contrast_state(const VesselTree& tree, double dt);
// One step of dt with a syringe flow (m^3/s); `at` is where an injection enters (read when one
// starts). Allocates nothing.
void contrast_step(const VesselTree& tree, const ContrastSettings& settings, double dt, double flow,
                   const TreeLocation& at, ContrastState& state);

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

// Limits of a run, enforced when a scenario is read (docs/scenarios.md): the smallest physics
// step, and the most steps a run may take (time limit / dt): a step of 1e-8 s ran for days and one
// of 1e-10 s exhausted memory (the contrast history keeps 2 s of steps).
inline constexpr double kMinScenarioDt = 1e-5;  // s (0.01 ms)
inline constexpr double kMaxRunSteps = 3.6e7;   // an hour at 0.1 ms
// Throws InputError(source, field) when time_limit / dt is above kMaxRunSteps.
void check_run_steps(double dt, double time_limit, const std::string& source,
                     const std::string& field);

struct Scenario {
  std::string name;
  std::string description;
  std::string source;  // file it was read from (errors)
  // A built-in patient ("default", "left-dominant") or a vessel tree file (vcsim-anatomy JSON),
  // relative to the scenario's folder.
  std::string anatomy = "default";
  // With an anatomy that is a lumen mesh (.stl, .obj, .ply: a segmented patient or a phantom,
  // docs/anatomy.md "A mesh in a run"): its centrelines (vcsim-anatomy JSON or SimVascular .pth,
  // relative to the scenario's folder) and the length of the files' unit (m).
  std::string centrelines;
  double mesh_unit = 1e-3;
  // Without centrelines: they are computed from the mesh (centrelines_from_mesh) from the open
  // end nearest this point (m), where the sheath goes in.
  std::optional<Vec3> inlet;
  bool beating = true;
  MotionSettings motion;
  double dt = 1e-3;          // s, physics step (1 kHz or faster)
  double time_limit = 60.0;  // s of simulated time before the run ends unfinished
  // End the run at the first step with a node outside the vessel (physics.md 6.3), as `vcsim run
  // --stop-on-escape` does.
  bool stop_on_escape = false;
  std::uint64_t seed = 1;  // of the state's random generator (SimState::random)
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
  // A step in which a node of an inserted instrument moved faster than runaway_speed (m/s) is
  // taken again split finer, and if a node still runs away, from rest (SubStepSettings::runaway,
  // physics.md 5.4): counted in metrics.runaway_steps and calmed_steps. 0: never.
  double runaway_speed = 30.0;
  std::vector<ScenarioInstrument> instruments;
  // How each lesion of the anatomy takes a balloon (one per lesion; empty: the defaults).
  std::vector<LesionMechanics> lesions;
  // What the treatment must achieve for the run to succeed, besides its landmarks.
  struct Targets {
    double residual_stenosis =
        -1.0;  // fraction: every lesion's diameter stenosis below it (<0: none)
    bool stent_covers_lesion = false;  // a stent deployed over its lesion with 2 mm margins
  } targets;
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
// Index of the instrument named `name` in `list`, or -1.
int find_instrument_in(std::span<const ScenarioInstrument> list, std::string_view name);
// Checks a list of instruments as a scenario declares them (the scenario's, or a scene's after an
// exchange): names given and unique; `inside` names another instrument, itself inside none;
// `over` names another instrument inside the same one. InputError naming `source` and, for
// instrument i, field_of(i) + ".name", ".inside" or ".over".
void validate_instruments(std::span<const ScenarioInstrument> list, const std::string& source,
                          const std::function<std::string(int)>& field_of);
// data/scenarios of the source tree ($VCSIM_SCENARIOS_DIR if set).
std::filesystem::path default_scenarios_dir();
// A scenario named on a command line: a file, or a name in default_scenarios_dir() ("default").
// InputError(source, field) when it is neither.
std::filesystem::path find_scenario(const std::string& name_or_path, const std::string& source,
                                    const std::string& field);

// ---------------------------------------------------------------------------------------------
// Model

// The patient of a scene, built once per run and shared by every model of it (an exchange of
// instruments builds a new model around the same anatomy).
struct SimAnatomy {
  VesselTree tree;  // at rest, lesions applied
  Lumen lumen;
  std::optional<CardiacMotion> motion;  // when the scenario beats and the anatomy has a heart
  AabbTree static_tree;                 // the lumen's tree when it does not beat (else empty)
  TreeLocator locator;                  // the tree's edges, for locating tips (locate())
};

struct SimModel {
  explicit SimModel(std::shared_ptr<const SimAnatomy> anatomy);

  // As read, but for `instruments`: the scene's now (an exchange changes them). Names, the
  // autopilot's plan, landmarks, fluoroscopy, settings.
  Scenario scenario;
  std::shared_ptr<const SimAnatomy> anatomy;
  const VesselTree& tree;  // the anatomy's, named as the step and its readers use them
  const Lumen& lumen;
  const std::optional<CardiacMotion>& motion;
  const AabbTree& static_tree;
  const TreeLocator& locator;
  // The catalogue the scene's instruments came from (and those an exchange adds).
  std::shared_ptr<const InstrumentCatalogue> catalogue;
  Sheath sheath;                      // the introducer sheath every instrument enters through
  std::vector<InstrumentSpec> specs;  // (instrument) from the catalogue
  SolverModel solver;  // the instruments at the femoral sheath, their couplings, the splits
  // (landmark) instrument and segment index; instrument -1: not in the scene (one the autopilot
  // adds later, or one removed)
  std::vector<std::pair<int, int>> landmark_ids;
  std::vector<int> outer_of;  // (instrument) the instrument whose lumen holds it, -1: none
  // Balloons on the instruments (and those of removed instruments, kept with their stents), the
  // lesions and how they open.
  ProcedureModel procedure;

  double dt() const { return solver.dt(); }
  int num_instruments() const { return static_cast<int>(specs.size()); }
  // The name -> index table of the instruments (-1: no such instrument).
  int instrument_index(std::string_view name) const { return scenario.find_instrument(name); }
  const std::string& instrument_name(int i) const { return scenario.instruments[i].name; }
  // FNV-1a over everything a step reads (the solver model, the anatomy's wall, the settings):
  // a run must leave it unchanged (tested).
  std::uint64_t hash() const;
};

// Builds the anatomy (cached lumen), the wall and the instruments at the sheath. Throws
// InputError for a scenario that does not fit the anatomy or the catalogue.
std::shared_ptr<const SimModel> build_sim_model(Scenario scenario);
// The same in an anatomy given instead of the scenario's (a varied patient: vary_anatomy); the
// tree is checked (validate_tree) and scenario.anatomy only names it.
std::shared_ptr<const SimModel> build_sim_model(Scenario scenario, VesselTree tree);
// The model of `from`'s scene with another list of instruments (an exchange; docs/architecture.md
// "Instrument exchange"): the anatomy shared, the lesions and the introducer sheath kept (its
// lumen widened only for a wider instrument), the instruments built as build_sim_model builds
// them, balloons keeping their indices (a removed instrument's balloon stays, removed). Checks
// the instruments as build_sim_model does (the rules that need the state are
// Simulator::change_instruments'): InputError naming `source` and, for instrument i,
// `field_of(i)`.
std::shared_ptr<const SimModel> rebuild_sim_model(const SimModel& from,
                                                  std::vector<ScenarioInstrument> instruments,
                                                  const std::string& source,
                                                  const std::function<std::string(int)>& field_of);

// ---------------------------------------------------------------------------------------------
// State

struct LandmarkRecord {
  bool reached = false;
  double time = 0.0;  // s, simulated time first reached
};

// An instrument's nodes found outside the vessel (physics.md 6.3): behind the lumen's wall by
// more than their radius, or beyond an open end of the vessel tree. Seen by the contact queries.
// The same record holds its edges seen through the wall (SimMetrics::edge_crossings; `edge`).
struct EscapeRecord {
  std::int64_t steps = 0;  // steps in which one of its nodes (or edges) was seen outside
  double time = -1.0;      // s, the first such step's end; < 0: none
  int node = -1;           // the first step's node farthest out
  double distance = 0.0;   // m, how far out it was: behind the wall or a closed end's cap, or
                           // beyond an open end's plane
  // The end (index in open_ends(tree)) it left by: through an open end's disc, or behind a closed
  // end's cap (physics.md 6.4); -1: the wall
  int exit = -1;
  double max_distance = 0.0;  // m, the farthest out seen
  // An edge (nodes node, node + 1) through the wall, both nodes inside, and `distance` its
  // deepest point's behind it (physics.md 6.3)
  bool edge = false;
  // The first step's node (an edge's deepest point): where it was (m) and the tree's place
  // nearest it at rest (locate())
  Vec3 position = Vec3::Zero();
  TreeLocation near;
};

// What a run has done so far (accumulated by every step; no wall-clock times, so that equal
// states are equal bit for bit).
struct SimMetrics {
  std::int64_t steps = 0;
  std::vector<double> tip_path;          // (instrument) m travelled by the distal tip
  std::vector<double> peak_wall_force;   // (instrument) N, largest wall contact force
  std::vector<double> peak_axial_force;  // (instrument) N at the hand, largest magnitude
  // (instrument) N, largest change of the hand force from one step to the next while inserted:
  // a physical load builds up over milliseconds, a numerical spike within a step.
  std::vector<double> peak_axial_jump;
  std::vector<double> peak_torque;        // (instrument) N m at the hand, largest magnitude
  std::vector<double> last_axial_force;   // (instrument) N of the previous step, NaN if outside
  std::vector<LandmarkRecord> landmarks;  // (landmark) of SimModel::scenario.landmarks
  double next_landmark_check = 0.0;       // s
  int rollbacks = 0;                      // steps that produced a non-finite value and were undone
  // Steps taken again split after a sudden change of a hand force (Scenario::fine_step_jump).
  std::int64_t resplit_steps = 0;
  // Steps in which a node ran away (Scenario::runaway_speed), and of them those taken again from
  // rest because a finer split did not calm it.
  std::int64_t runaway_steps = 0;
  std::int64_t calmed_steps = 0;
  std::vector<EscapeRecord> escapes;  // (instrument)
  std::int64_t escape_steps = 0;      // steps in which any instrument was seen outside the vessel
  // (instrument) Its edges seen through the wall between two nodes inside the vessel, checked
  // every SolverSettings::edge_check_period (physics.md 6.3): reported, and kept apart from the
  // escapes until the edges have contacts of their own (the default run has one, 0.5 mm deep).
  std::vector<EscapeRecord> edge_crossings;
  std::int64_t edge_crossing_checks = 0;  // checks that found an edge through the wall
};

struct SimState {
  SolverState solver;  // instruments (rods, drives, contact coherence), time, split and its hold
  ProcedureState procedure;  // balloons, lesions' opening, stents, events
  ContrastState contrast;
  SimMetrics metrics;
  // For the procedure's random events (seeded by Scenario::seed; none draws from it yet).
  Random random;
  // The model this is a state of, when a Simulator holds it: a snapshot carries it, so that a
  // restore goes back across an exchange of instruments. Not part of the hash.
  std::shared_ptr<const SimModel> model;

  double time() const { return solver.time; }  // s
  // FNV-1a over every value above (the escape records only once there is one: a run without an
  // escape hashes as it did before they were kept).
  std::uint64_t hash() const;
  // Bytes of memory a copy (a snapshot) holds.
  std::size_t bytes() const;
};

SimState make_sim_state(const SimModel& model);
// `state` of model `from` carried to model `to` (rebuilt from it by an exchange): time, contrast,
// landmarks, the random generator and the procedure (lesions, balloons by index) as they are;
// each kept instrument's state (rods, drive, contact coherence) and metrics unchanged, matched
// by name; an added instrument outside the patient at the sheath (parked once stepped).
SimState carry_sim_state(const SimModel& from, const SimState& state, const SimModel& to);

// ---------------------------------------------------------------------------------------------
// Workspace and step

namespace internal {
struct SimScratch;
}

// Scratch for stepping one state of a model: the wall (the beating lumen's patches, moved to each
// step's time where instruments can reach them, or the static tree's queries), the solver's
// workspace. The model must outlive it. A state can be restored into it at any time: every
// answer of the wall depends on the time only.
class SimWorkspace {
 public:
  explicit SimWorkspace(const SimModel& model);
  // For a model sharing `old`'s anatomy (an exchange, a restore across one): the wall taken over
  // from `old` (the beating lumen, the morphed static lumen, the stents as shown) instead of
  // built again; `old` is left unusable.
  SimWorkspace(const SimModel& model, SimWorkspace&& old);
  ~SimWorkspace();
  SimWorkspace(const SimWorkspace&) = delete;
  SimWorkspace& operator=(const SimWorkspace&) = delete;

  SolverWorkspace& solver();
  const SolverWorkspace& solver() const;
  VesselWall& wall();
  internal::SimScratch& scratch() { return *s_; }

 private:
  std::unique_ptr<internal::SimScratch> s_;
};

// Wall-clock time of a sim step's stages (microseconds).
struct SimStepProfile {
  StepProfile instruments;  // the solver's stages, summed over the fine steps
  double procedure = 0.0;   // balloons, lesions, the wall brought to them; stents after the solver
  double solver = 0.0;      // solver_step: sub-steps, wall motion, instruments
  double contrast = 0.0;    // injection point and transport
  double metrics = 0.0;     // tip paths, peak forces
  double landmarks = 0.0;   // landmark checks (every 5 ms of simulated time)
  double total = 0.0;
};

// The sim step's stages as `vcsim run --profile` and metrics.json ("profile") name them, each
// timed on every step (docs/architecture.md, "The sim step"). Disjoint but for `total`: the
// instruments' stages are summed over the fine steps; `substeps` is the solver's own work around
// them (backups, the split, a re-split or rollback: the fine steps run again are in the others).
enum class SimStage {
  kProcedure,
  kWall,
  kDrive,
  kForces,
  kVelocities,
  kCollision,
  kCoupling,
  kDistance,
  kContacts,
  kPositions,
  kFeedback,
  kSubsteps,
  kContrast,
  kMetrics,
  kLandmarks,
  kTotal,
  kCount
};
inline constexpr int kNumSimStages = static_cast<int>(SimStage::kCount);
const char* to_string(SimStage s);
// A step's profile by stage (us).
std::array<double, kNumSimStages> stage_times(const SimStepProfile& p);

// One step of model.dt(): the instruments (solver_step, in the beating wall), contrast, metrics
// and landmarks. `commands` must hold one drive command per instrument (asserted). No heap
// allocation once warm.
void sim_step(const SimModel& model, SimState& state, SimWorkspace& ws,
              const StepCommands& commands, SimStepProfile* profile = nullptr);

// Reading a state as a trainee reads the screen.
// The distal tip of instrument i, in the vessel as it is now.
Vec3 tip(const SimState& state, int i);
// The tip carried back to the anatomy at rest (undoing the cardiac motion where it is).
Vec3 tip_rest(const SimModel& model, const SimState& state, int i);
TreeHit tip_location(const SimModel& model, const SimState& state, int i);
bool all_landmarks_reached(const SimState& state);

// ---------------------------------------------------------------------------------------------
// Simulator: a model, its state and workspace together

// Accumulated wall-clock time of a Simulator's steps (not part of the state: it differs from run
// to run).
struct SimProfile {
  double wall_time = 0.0;  // s spent in step()
  std::int64_t steps = 0;
  SimStepProfile sum;                                   // stage times summed over the steps (us)
  std::array<DurationHistogram, kNumSimStages> stages;  // (SimStage) per-step times
  // Each stage's mean, median and 99th percentile per step (us): `vcsim run --profile`.
  std::string table() const;
};

class Simulator {
 public:
  // Builds the model (build_sim_model) and its initial state.
  explicit Simulator(Scenario scenario);
  // Another simulation of a model already built (a batch, a vector of learning environments).
  explicit Simulator(std::shared_ptr<const SimModel> model);
  ~Simulator();
  Simulator(const Simulator&) = delete;
  Simulator& operator=(const Simulator&) = delete;

  // One step of dt. Commands of the wrong size or with a non-finite value are refused with
  // InputError("commands", ...) before anything changes. A step that produces a non-finite value
  // is undone, counted in metrics().rollbacks and the instruments are held still for that step.
  void step(const StepCommands& commands);

  // A copy of the whole state; restore() puts one back (of this model: InputError otherwise).
  // Restoring a snapshot and replaying the same commands gives the same states bit for bit.
  // A snapshot carries its model (SimState::model): restoring one taken before an exchange of
  // instruments goes back to that scene.
  SimState snapshot() const { return state_; }
  void restore(const SimState& snapshot);

  // An instrument inserted less than this counts as withdrawn (its tip in the sheath's valve): a
  // position command to 0 leaves a rounding's worth, the autopilot's withdrawal stops within
  // 0.5 mm of its depth.
  static constexpr double kWithdrawnDepth = 1e-3;  // m
  // Instrument exchange (docs/scenarios.md): the scene's instruments become `instruments`, kept
  // ones matched by name (the same catalogue entry and discretisation; their nesting may be
  // declared anew), the others removed or added, before the next step. Refused with InputError
  // naming `source` and field_of(i) for the list's instrument i (field_of(-1): the list as a
  // whole), the simulation unchanged: removing an instrument still in the patient (inserted
  // kWithdrawnDepth or more: withdraw it first) or one that another is kept inside or over, an
  // unknown catalogue entry, a name twice, a kept instrument declared with another catalogue
  // entry, no instrument left. Rebuilds the model's instruments (not the anatomy) and a
  // workspace; allocates.
  void change_instruments(std::vector<ScenarioInstrument> instruments,
                          const std::string& source = "exchange",
                          const std::function<std::string(int)>& field_of = {});
  // One instrument added (after the others) or removed, as an input source asks for it; errors
  // name change.source and change.field.
  void exchange(const InstrumentChange& change);
  // The scene's instrument names in its order.
  std::vector<std::string> instrument_names() const;

  const SimModel& model() const { return *model_; }
  const std::shared_ptr<const SimModel>& shared_model() const { return model_; }
  const SimState& state() const { return state_; }
  const SimProfile& profile() const { return profile_; }
  // Its scratch (the wall as the last step left it, the contact lists): for inspection.
  SimWorkspace& workspace() { return *ws_; }

  const Scenario& scenario() const { return model_->scenario; }
  double time() const { return state_.time(); }
  double dt() const { return model_->dt(); }
  const VesselTree& tree() const { return model_->tree; }  // at rest, lesions applied
  const Lumen& lumen() const { return model_->lumen; }
  const CardiacMotion* motion() const { return model_->motion ? &*model_->motion : nullptr; }
  int num_instruments() const { return model_->num_instruments(); }
  const InstrumentSpec& instrument_spec(int i) const { return model_->specs[i]; }
  const InstrumentModel& instrument_model(int i) const { return model_->solver.instruments[i]; }
  // The rod's model for an unsplit step (its geometry is the same in every split).
  const RodModel& rod_model(int i) const { return instrument_model(i).rod(); }
  const InstrumentState& instrument(int i) const { return state_.solver.instruments[i]; }
  Vec3 tip(int i) const { return vcsim::tip(state_, i); }
  Vec3 tip_rest(int i) const { return vcsim::tip_rest(*model_, state_, i); }
  TreeHit tip_location(int i) const { return vcsim::tip_location(*model_, state_, i); }
  // Inserted depth of an instrument (m).
  double depth(int i) const { return instrument(i).drive.depth; }
  // How many fine steps the last step was split into (1: none; physics.md 5.4).
  int split() const { return state_.solver.split; }
  // Contrast concentration per segment (fraction of 350 mgI/ml).
  const std::vector<float>& contrast() const { return state_.contrast.concentration; }
  const SimMetrics& metrics() const { return state_.metrics; }
  // The last step's wall contacts of instrument i.
  std::span<const NodeContact> contacts(int i) const;
  // What each hand feels, into `out` (one per instrument; no allocation once warm).
  void feedback(std::vector<HandFeedback>& out) const;
  bool all_landmarks_reached() const { return vcsim::all_landmarks_reached(state_); }
  // The route (centreline points) from the access to a place, m.
  std::vector<Vec3> route_to(const TreeLocation& to, double spacing = 1e-3) const;

 private:
  std::shared_ptr<const SimModel> model_;
  SimState state_;
  std::unique_ptr<SimWorkspace> ws_;
  SimProfile profile_;
};

// ---------------------------------------------------------------------------------------------
// Running against an input source, as fast as possible or in real time

// While one lives, the engine's parallel work (instruments of 256 nodes or more side by side,
// wall-query batches) runs on at most `threads` threads, the caller's included (1: all on the
// caller's thread, leaving the other cores to a renderer or a window). The results are the same
// bit for bit with any count (Simulator.TheStepIsTheSameOnOneThread). `threads` >= 1.
class ThreadLimit {
 public:
  explicit ThreadLimit(int threads);
  ~ThreadLimit();
  ThreadLimit(const ThreadLimit&) = delete;
  ThreadLimit& operator=(const ThreadLimit&) = delete;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

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
  double max_lag() const { return max_lag_; }    // s, the largest lag seen (before any resync)
  double last_lag() const { return last_lag_; }  // s, the last wait's lag (0: on time)
  std::int64_t resyncs() const { return resyncs_; }

 private:
  double step_, max_catch_up_;
  bool started_ = false;
  double origin_us_ = 0.0;  // wall clock (now_us) at simulated time 0
  std::int64_t late_ = 0, resyncs_ = 0;
  double max_lag_ = 0.0;
  double last_lag_ = 0.0;
};

struct RunLoopSettings {
  double end_time = 0.0;       // s simulated; the loop ends when the simulator reaches it
  bool realtime = false;       // pace to the wall clock (RealTimePacer)
  double max_catch_up = 0.25;  // s, see RealTimePacer
  // When set (a signal handler may set it: lock-free), the loop ends before the next step.
  const std::atomic<bool>* stop = nullptr;
  // End the loop after the first step in which a node was seen outside the vessel
  // (SimMetrics::escapes; `vcsim run --stop-on-escape`).
  bool stop_on_escape = false;
};

struct RunLoopStats {
  std::int64_t steps = 0;
  std::int64_t late_steps = 0;  // real time only (RealTimePacer)
  double max_lag = 0.0;         // s
  std::int64_t resyncs = 0;
  bool stopped = false;            // ended by RunLoopSettings::stop
  bool stopped_on_escape = false;  // ended by RunLoopSettings::stop_on_escape
  int exchanges = 0;               // instrument exchanges applied
  int refused_exchanges = 0;       // and refused (the input source was told)
};

// What a caller does around each step (film, progress, a controller's log).
class RunObserver {
 public:
  virtual ~RunObserver() = default;
  // After an exchange changed the scene's instruments (before the next step).
  virtual void exchanged(const Simulator& sim, const InstrumentChange& change) {
    (void)sim;
    (void)change;
  }
  // With the commands for the next step; false ends the run before that step.
  virtual bool before_step(const Simulator& sim, const StepCommands& commands) {
    (void)sim;
    (void)commands;
    return true;
  }
  virtual void after_step(const Simulator& sim) { (void)sim; }
};

// Steps `sim` until settings.end_time, *settings.stop or the observer says so: per step, waits for
// the wall clock (real time), applies the instrument exchanges `input` asks for (InputSource::
// poll_exchange; each refusal handed back to it, each change to it and the observer), polls it
// for the commands, steps, and publishes the hub forces back to `input`. Allocates nothing per
// step once warm (besides what the observer does, and an exchange).
RunLoopStats run_loop(Simulator& sim, InputSource& input, const RunLoopSettings& settings,
                      RunObserver* observer = nullptr);

// ---------------------------------------------------------------------------------------------
// A run's report

class Autopilot;

// What a run's caller knows besides the simulator: how it was driven and filmed, and its clocks.
struct RunReport {
  std::string scenario_file;
  double end_time = 0.0;     // s simulated the run was to last
  double wall_time = 0.0;    // s of the loop, wall clock
  double setup_time = 0.0;   // s building the scene
  double render_time = 0.0;  // s drawing frames (on their own thread)
  int frames = 0;
  // s of fluoroscopy (a trainer: the time its pedal was held); < 0: frames at the scenario's
  // frame rate (a headless run films throughout).
  double fluoroscopy_time = -1.0;
  std::string video;       // file, "" for none
  std::string input_type;  // "autopilot", "timeline", "igtl", "replay" or "trainer"
  bool realtime = false;
  RunLoopStats loop;
  // A live device (input_type "igtl").
  std::string device_address;
  int device_port = 0;
  IgtlStats device;
  const Autopilot* autopilot = nullptr;  // when it drove the run
};

struct RunOutcome {
  bool success = false;  // every landmark and target reached, no instrument outside the vessel
  bool escaped = false;  // an instrument was seen outside the vessel (SimMetrics::escape_steps)
  std::string text;      // "all landmarks reached", or what was missed and why
};
// One line saying where instrument i's first escape was (SimMetrics::escapes): "t = 1.23 s:
// 'wire' node 250 left the vessel through the open end of 'main' (start), 3.1 mm beyond it".
std::string describe_escape(const SimModel& model, int i, const EscapeRecord& e);
// Each instrument's first escape, once: after a step, fresh() gives the describe_escape lines of
// the instruments seen outside the vessel for the first time ("ESCAPE: ..."), and of those with
// an edge seen through the wall for the first time ("EDGE: ...", SimMetrics::edge_crossings).
// Keyed by name, so an instrument
// exchanged for another of the same name is not reported again. The consoles of `vcsim run`
// and `vcsim soak` print them as they happen.
class EscapeReporter {
 public:
  std::vector<std::string> fresh(const Simulator& sim);

 private:
  std::int64_t escape_steps_ = 0, edge_checks_ = 0;
  std::vector<std::string> reported_;        // names of the instruments whose escape was reported
  std::vector<std::string> reported_edges_;  // ... whose edge crossing was reported
};
RunOutcome run_outcome(const Simulator& sim, const RunReport& report);

// DIR/metrics.json (docs/scenarios.md, "metrics.json"): the run's figures, instruments, landmarks,
// input and outcome. Throws InputError naming the file when it cannot be written.
void write_run_metrics(const std::filesystem::path& file, const Simulator& sim,
                       const RunReport& report);
// The same in a few lines for a person (landmarks, real-time factor, files).
void print_run_summary(std::ostream& out, const Simulator& sim, const RunReport& report,
                       const std::filesystem::path& frames_dir,
                       const std::filesystem::path& metrics);

// Every step's hand force and torque per instrument as CSV (`vcsim run --force-log`): time,
// then depth (mm), force (N) and torque (N mm) of each instrument, under a header naming them
// (repeated after an exchange, naming the scene's instruments from there on).
class ForceLog : public RunObserver {
 public:
  // Throws InputError("run", "--force-log", ...) when the file cannot be written.
  ForceLog(const std::filesystem::path& file, const SimModel& model);
  ~ForceLog() override;
  void after_step(const Simulator& sim) override;
  void exchanged(const Simulator& sim, const InstrumentChange& change) override;

 private:
  void header(const SimModel& model);
  struct File;
  std::unique_ptr<File> f_;
};

// A run's commands and instrument exchanges as a CommandRecording (`vcsim run --record`), which
// `vcsim run --replay` steps to the same state: each step's commands as the step takes them,
// each exchange as it is made.
class CommandRecorder : public RunObserver {
 public:
  CommandRecorder(const Simulator& sim, std::string made_by);
  bool before_step(const Simulator& sim, const StepCommands& commands) override;
  void exchanged(const Simulator& sim, const InstrumentChange& change) override;
  // The recording, with the hash of the state after its last step.
  const CommandRecording& finish(const Simulator& sim);

 private:
  CommandRecording rec_;
};

// ---------------------------------------------------------------------------------------------
// Autopilot

// Drives the scenario's autopilot plan through commands (position mode), reading the state as a
// trainee reads the screen: tip positions and forces. A plain value: copying it with a snapshot
// of the state resumes both.
class Autopilot {
 public:
  Autopilot(const SimModel& model, const SimState& state);
  explicit Autopilot(const Simulator& sim) : Autopilot(sim.model(), sim.state()) {}
  // The commands for the next step (one drive command per instrument).
  void command(const SimModel& model, const SimState& state, StepCommands& out);
  void command(const Simulator& sim, StepCommands& out) { command(sim.model(), sim.state(), out); }
  // The exchange of instruments its current phase asks for (an add or remove phase): true with
  // `out` filled, until the scene has changed (rebind) or the change is refused (refused).
  bool exchange_wanted(InstrumentChange& out) const;
  // The scene's instruments changed (its own exchange or another's): its per-instrument commands
  // follow them by name, and a phase that asked for the change is done.
  void rebind(const SimModel& model, const SimState& state);
  // Its exchange was refused (the scene unchanged): it gives up, saying why.
  void refused(const InputError& why);
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
  void start_phase(const SimModel& model, const SimState& state);
  void navigate(const SimModel& model, const SimState& state, const AutopilotPhase& ph);
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
  std::vector<int> origin_;  // (plan phase) its index in the scenario's plan, -1: one it inserted
  std::string source_;       // the scenario's file (errors)
  std::vector<std::string> names_;  // the instruments the per-instrument arrays follow
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
  std::vector<double> entry_;  // (segment) m along it past which a tip there is off the route
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
  double aim_along_ = 0.0;  // m of the aim ahead of the tip along its shaft (< 0: behind)
  double pressure_ = 0.0;   // Pa commanded to the indeflator
  // A place phase (Autopilot::place): past the lesion's middle, drawn back to it, watched, and
  // adjusted between watches.
  enum class PlaceStage { kPast, kDrawBack, kWatch, kAdjust };
  PlaceStage place_stage_ = PlaceStage::kPast;
  double place_limit_ = 0.0;  // m of commanded depth an adjustment moves the hand to
  double draw_from_ = 0.0;    // m of commanded depth where the first draw-back began
  double watch_since_ = 0.0;  // s: the hand still and the markers watched since then
  double watch_sum_ = 0.0;    // their distance to go summed over the watch's steps
  int watch_n_ = 0;
  int still_watches_ = 0;    // watches in a row since the hand last moved
  int watches_ = 0;          // in this phase
  int placed_ = -1;          // the instrument the last place phase placed (watched while inflating)
  double place_goal_ = 0.0;  // m along the place route: the lesion's middle
  TreeLocation place_target_;  // the lesion's middle
  // +1 where the route goes down the lesion's segment (its arc length growing), -1 where it goes
  // up it (an access below the lesion in the same vessel or a branch of it)
  int place_direction_ = 1;
  void place(const SimModel& model, const SimState& state, const AutopilotPhase& ph);
  double markers_remaining(const SimModel& model, const SimState& state, int instrument);
};

// The autopilot as an input source of a simulator: it reads the simulator's state as a trainee
// reads the screen.
class AutopilotInput : public InputSource {
 public:
  AutopilotInput(Autopilot& pilot, const Simulator& sim) : pilot_(pilot), sim_(sim) {}
  void poll(double sim_time, StepCommands& out) override;
  bool poll_exchange(double sim_time, InstrumentChange& out) override;
  void exchanged(const InstrumentChange& change, std::span<const std::string> instruments) override;
  void exchange_refused(const InstrumentChange& change, const InputError& why) override;

 private:
  Autopilot& pilot_;
  const Simulator& sim_;
};

// ---------------------------------------------------------------------------------------------
// Soak (docs/scenarios.md, "Soak")

struct SoakSettings {
  double duration = 3600.0;  // s simulated
  std::uint64_t seed = 1;
  double max_speed = 0.2;     // m/s: the fastest push or pull (a hand's quick pull)
  double max_spin = 2 * kPi;  // rad/s: the fastest turn (a flick of the fingers)
  double max_depth = 1.2;     // m: the deepest insertion (and 0.2 m short of each instrument's end)
};

// Seeded random hands on every instrument: holds, pushes, pulls, turns, fast reversals (push and
// pull every 0.1-0.3 s), full withdrawals followed by reinsertion, and now and then an injection.
// Velocity commands within the settings' speeds, the depth kept in [0, max_depth]. A plain value
// reading the state (as the Autopilot); the same seed gives the same run.
class SoakHands {
 public:
  SoakHands(const SimModel& model, const SoakSettings& settings);
  void command(const Simulator& sim, StepCommands& out);

 private:
  enum class Gesture { kHold, kPush, kPull, kTurn, kReversals, kWithdraw, kReinsert };
  struct Hand {
    Gesture gesture = Gesture::kHold;
    double until = 0.0, started = 0.0;  // s
    double speed = 0.0, spin = 0.0;     // m/s, rad/s
    double reversal = 0.0;              // s per half period of a reversal gesture
    double target = -1.0;               // m: depth a withdrawal or reinsertion goes to
    double max_depth = 1.0;             // m
  };
  double uniform(double lo, double hi);
  void next_gesture(Hand& h, double now, double depth);
  SoakSettings settings_;
  Random rng_;
  std::vector<Hand> hands_;
  double inject_until_ = -1.0;
};

struct SoakReport {
  std::int64_t steps = 0;
  double simulated = 0.0;  // s
  double wall = 0.0;       // s
  int rollbacks = 0;       // steps that produced a non-finite value and were undone
  std::int64_t runaway_steps = 0, calmed_steps = 0;  // SimMetrics' counts
  bool finite = true;                                // the final state holds finite values only
  double resident_start_mb = 0.0, resident_after_first_minute_mb = 0.0, resident_end_mb = 0.0;
  std::vector<double> resident_samples_mb;  // each simulated minute
  // The hand force's smoothness: steps more than 1 N off the median of their 11 neighbours.
  struct Instrument {
    std::string name;
    std::int64_t checked_steps = 0;  // inserted steps with 5 inserted neighbours on each side
    std::int64_t departures = 0;
    double largest_departure = 0.0;  // N
    double largest_force = 0.0;      // N
    double deepest = 0.0;            // m inserted at most
    int withdrawals = 0;             // times pulled all the way out (and back in)
    std::int64_t slipped_steps = 0;  // steps in which the hand's grip slipped (DriveState)
    EscapeRecord escape;             // seen outside the vessel (SimMetrics::escapes)
  };
  std::vector<Instrument> instruments;
  // Resident size growth from the end of the first simulated minute to the end (fraction).
  double memory_growth() const;
  // No non-finite value, no rollback, memory flat (growth under 1 %), and no instrument seen
  // outside the vessel (docs/scenarios.md, "Soak").
  bool passed() const;
};

// Watches a soak's steps (SoakReport's force figures).
class SoakWatch {
 public:
  explicit SoakWatch(int instruments);
  void after_step(const Simulator& sim);
  SoakReport& report() { return report_; }

 private:
  std::vector<std::vector<double>> window_;  // (instrument) the last 11 hand forces
  std::vector<unsigned char> inserted_;      // (instrument) in the body at the last step
  SoakReport report_;
};

// Resident set size of this process (MB), from /proc/self/statm; 0 where unavailable.
double resident_megabytes();

// Runs `sim` for settings.duration under SoakHands, sampling the resident size each simulated
// minute. The observer (a force log) sees every step.
SoakReport soak(Simulator& sim, const SoakSettings& settings, RunObserver* observer = nullptr);

}  // namespace vcsim
