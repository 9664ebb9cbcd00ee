// vcsim solver: instruments (rods) driven through an access sheath inside a vessel wall, a wire
// running in a catheter's lumen, the hand's force. Like the rod layer, it is split into what is
// built once (SolverModel, never written during a run), what changes (SolverState: copying it is
// a snapshot) and scratch (SolverWorkspace, sized once, private to src/solver).
//
// solver_step advances one step of the model's dt; inside it, a fast hand or a sudden load splits
// the step into fine steps with the masses for them (physics.md 5.4), and a step that produced a
// non-finite value is undone. Each fine step runs the stages of docs/architecture.md: drive,
// forces, velocities, collision detection, N block iterations of [global distance solve, wall
// contacts with Coulomb friction, coaxial coupling], positions, hand force.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "vcsim/collision.h"
#include "vcsim/commands.h"
#include "vcsim/rod.h"

namespace vcsim {

// Coulomb friction between an instrument and the vessel wall.
struct ContactMaterial {
  double mu_static = 0.1;
  double mu_dynamic = 0.08;
  void validate(const std::string& source = "contact") const;
};

// Access sheath: the instrument enters the body at access_point along d3 of `frame`; d1 is the
// reference for the roll angle. The part outside the body stays on the sheath axis.
struct Sheath {
  Vec3 access_point = Vec3::Zero();
  Quat frame = Quat::Identity();
  double max_speed = 0.5;  // m/s: translation rate limit (a tracked device cannot jump)
  double max_spin = 30.0;  // rad/s: rotation rate limit
  // The introducer sheath's straight tube inside the body, from the access point along the axis:
  // its length (0: none) and lumen radius (m). Free nodes inside it are held within its lumen
  // (physics.md 6.2) instead of meeting the vessel wall.
  double length = 0.0;
  double inner_radius = 0.0;
  // The hand's grip (physics.md 6.5): the most axial force (N) and twisting moment (N m) it passes
  // on. A command to push on (pull, turn) against a hand force beyond it slips: the instrument
  // stays where it is in that step while the hand moves on. The default run's hand reads at most
  // 2.6 N and 5.8 N mm (docs/measurements.md), so it never slips there.
  double grip_force = 20.0;
  double grip_torque = 0.05;
};

struct DriveState {
  double depth = 0.0;        // inserted length beyond the access point (m)
  double roll = 0.0;         // rad
  double depth_rate = 0.0;   // m/s over the last step
  double roll_rate = 0.0;    // rad/s over the last step
  double axial_force = 0.0;  // N at the hand along the axis, > 0 when the rod resists insertion
  double torque = 0.0;       // N m at the hand about the axis, > 0 when it resists positive roll
  int first_free = 0;        // first node inside the body
  // The hand force and torque before the optional low-pass (SolverSettings::feedback_cutoff_hz;
  // physics.md 6.1); equal to axial_force and torque without it.
  double axial_force_raw = 0.0;  // N
  double torque_raw = 0.0;       // N m
  // The grip slipped in the last (fine) step: the command's advance or turn was not applied
  // (Sheath::grip_force, grip_torque). An output for reports; the step does not read it, and it
  // is not hashed (a state equal in everything else steps on the same).
  bool slipped = false;
};

// One contact of a node with the wall in the last step (an output: SolverWorkspace::contacts).
struct NodeContact {
  int node = 0;
  Vec3 normal = Vec3::Zero();         // into the lumen
  double depth = 0.0;                 // > 0 penetration, < 0 speculative gap (m)
  double lambda_n = 0.0;              // accumulated normal impulse (N s)
  Vec3 lambda_t = Vec3::Zero();       // accumulated friction impulse (N s)
  Vec3 wall_velocity = Vec3::Zero();  // of the wall at the contact (m/s)
  double lambda_bias = 0.0;  // part of lambda_n taken back after the step (penetration fix-up)
  // Normal impulse (N s) pressing the node on the wall besides the contact's own, for friction
  // only: an inflated balloon's pressure on the vessel (BalloonHold), which anchors it.
  double preload = 0.0;
  // An edge's contact (SolverWorkspace::edge_contacts): at the point (1 - along) x[node] + along
  // x[node + 1] of the edge from `node`, its impulses shared by the two nodes in those weights.
  // 0 for a node's own contact.
  double along = 0.0;
};

// A node found outside the vessel in a step (an output: SolverWorkspace::escape; physics.md
// 6.3): its centre behind the lumen's wall by more than its radius, or beyond an open end's disc
// (VesselWall::exits) by more than its radius, or behind a closed end's cap by more than its
// radius. Seen by the contact queries the step makes anyway; it changes nothing (the caller counts
// and reports it).
struct NodeEscape {
  int node = -1;          // the farthest out of the step's escaped nodes; -1: none
  double distance = 0.0;  // m: its centre behind the wall or cap, or beyond the open end's plane
  // The wall's exit (index in VesselWall::exits) it left by, through its disc or, for a closed
  // end, through its cap; -1: the wall
  int exit = -1;
  // An edge seen through the wall instead, both its nodes inside (physics.md 6.3): `node` is its
  // first node, `distance` its deepest point's behind the wall, `along` where that point lies on
  // it (0 .. 1).
  bool edge = false;
  double along = 0.0;
};

// One wire node held inside the outer instrument's lumen in the last step (concentric
// constraint; an output: SolverWorkspace::coupling_contacts).
struct CoaxialContact {
  int node = 0;                // inner instrument's node
  int segment = 0;             // outer instrument's edge: nodes segment, segment + 1
  double t = 0.0;              // position of the projection on that edge (0 .. 1)
  Vec3 normal = Vec3::Zero();  // from the outer centreline toward the inner node
  double excess = 0.0;         // radial offset beyond the clearance (> 0 violated, < 0 gap), m
  double lambda_n = 0.0;
  Vec3 lambda_t = Vec3::Zero();
  // The inner point: node + a (node + 1 - node). Above 0 only for a rim contact: the inner rod's
  // edge leaving through the outer one's distal end, against its rim (outer node segment + 1).
  double a = 0.0;
};

// ---------------------------------------------------------------------------------------------
// Model

// An instrument as built: never written during a run.
struct InstrumentModel {
  // (split) the rod with its masses and inertias for steps of dt / split (physics.md 5.4):
  // rods[0] for a whole step, rods[k - 1] for a step split into k. They differ in node_mass,
  // inv_mass, inertia and inv_inertia only.
  std::vector<RodModel> rods;
  Sheath sheath;
  ContactMaterial contact;
  bool driven = true;  // false: a free rod (no sheath), e.g. lying on a surface

  const RodModel& rod(int split = 1) const { return rods[split - 1]; }
};

// An inner instrument (wire) running in the lumen of an outer one (catheter). Both enter through
// the same sheath. Wire nodes whose inserted arc length is within the catheter's inserted depth
// are held within the clearance (ID - wire OD) / 2 by impulses perpendicular to the catheter,
// shared by the two nearest catheter nodes in proportion to their distance (VCSim3's concentric
// constraints), with optional lumen friction; they skip the wall collision.
// An inner instrument may be inside several outer ones (a wire in a balloon catheter that is in
// a guide): its couplings are listed innermost outer first, and each node is held by the first
// whose inserted length covers it.
struct CouplingModel {
  int inner = 0;
  int outer = 1;
  double mu = 0.04;  // wire-in-catheter lumen friction (clinical.md)
  // The edges that leave through the outer instrument's distal opening pass inside its rim and
  // wrap round it (physics.md 7.1); false: only the nodes are held (VCSim3's constraints).
  bool rim = true;
};

struct SolverSettings {
  RodSettings rod;
  bool collisions = true;
  // s of simulated time between checks of the edges between free nodes against the wall (an
  // escape the nodes' own queries cannot see, physics.md 6.3); 0: every step. It changes no
  // state, only what is reported, so it is not part of the model's hash.
  double edge_check_period = 0.05;
  // Collision samples between the nodes (physics.md 6.3): an edge longer than this (m, at rest)
  // gets evenly spaced points no farther apart, queried against the wall as spheres of the rod's
  // radius; where one comes nearer the wall than the edge's nodes (a ridge such as a carina, the
  // inner side of a bend), it gets a contact shared by the two nodes. 0: only the nodes collide.
  // The first split's value sizes the workspace. At 3 mm a 0.014" wire's 10.5 mm shaft edges get
  // three samples, which keeps them off the carina's sharp apex; at 2 mm the phantom's autopilot
  // no longer steers its wire into the branch (physics.md 6.3).
  double edge_sample_spacing = 3e-3;
  double contact_margin = 2e-4;         // m, speculative: contacts within this gap are solved
  double penetration_correction = 0.5;  // fraction of a penetration removed per step
  double coherence_margin = 0.6e-3;     // m, query radius beyond contact reach (for skipping)
  double leaf_cache_slack = 0.1e-3;  // m, how far a node may move before its leaves are re-listed
  // How the hand's axial force is formed (physics.md 6.1). kQuasiStatic (the default): the
  // reactions a rod of negligible mass (nodes and frames) would need in the step's shape, walked
  // from the tip; free of the scaled inertia. kImpulses: the step's own wall and coupling reactions
  // (less their fix-ups) and applied loads, carrying the scaled momentum they stop (8-15 times
  // the spikes in the default scenario). Both follow the capstan equation in slow motion
  // (tests/solver/test_feedback.cpp). The torque is the hub's twisting moment either way.
  enum class HandForce { kImpulses, kQuasiStatic };
  HandForce hand_force = HandForce::kQuasiStatic;
  // Optional first-order low-pass of the hand force and torque for a haptic device (Hz);
  // 0 reports the raw signal.
  double feedback_cutoff_hz = 0.0;
  // Steps with several instruments of 256 nodes or more run each instrument's forces,
  // integration and distance solve on the TBB threads (same results, bit for bit).
  bool parallel_instruments = true;
  void validate(const std::string& source = "solver") const;
};

// When a step is split into fine steps (physics.md 5.4). A split of k uses the instruments'
// rods[k - 1] and the model's settings[k - 1]; the most is the number of both.
struct SubStepSettings {
  // While a hand moves faster than `speed` (m/s), each step is split into as many fine steps as
  // keep the hand's travel per fine step within `travel` (m), at least 2: the scaled inertia of a
  // fast pull grows with the travel per step.
  double speed = 0.13;
  double travel = 25e-6;
  // A step after which a hand force has changed by more than `jump` (N) is taken again split at
  // least twice as finely (and at least as for a hand at `speed`), and steps stay split so for
  // `hold` (s): a scaled mass stopped or let go suddenly. 0: never.
  double jump = 0.0;
  double hold = 0.02;
  // A step in which a node of an instrument in the body moved faster than `runaway` (m/s), far
  // beyond what a hand and a beating wall can drive (they move at most about 1 m/s), is a step
  // the solver did not converge on: it is taken again split at least twice as finely, and if a
  // node still runs away, taken again from rest (every velocity zeroed). 0: never.
  double runaway = 0.0;
};

struct SolverModel {
  std::vector<InstrumentModel> instruments;
  std::vector<CouplingModel> couplings;
  // (split) the settings of a fine step of dt / split; settings[0].rod.dt is the step, dt.
  std::vector<SolverSettings> settings;
  SubStepSettings substeps;

  double dt() const { return settings[0].rod.dt; }
  int max_split() const { return static_cast<int>(settings.size()); }
  // Checks sizes and indices (every instrument has max_split() rods; couplings name two
  // different instruments, no pair twice; an inner's outers innermost first, each inside the
  // next) and every setting; throws InputError.
  void validate(const std::string& source = "solver") const;
  // FNV-1a over every value that the step reads (tests assert that a run never changes it).
  std::uint64_t hash() const;
};

// Builds a driven instrument's model as the simulator places it: the rod laid on the sheath axis
// (depth 0, roll 0). The rod's own boundaries must be free (the drive holds the rod). One split.
// Throws InputError for bad input.
InstrumentModel make_instrument_model(const RodDef& def, const Sheath& sheath,
                                      const ContactMaterial& contact);
// A free rod (no drive), e.g. for friction experiments; its state comes from make_state.
InstrumentModel make_free_instrument_model(const RodDef& def, const ContactMaterial& contact);

// The quasi-static instruments of a scenario run (physics.md 5.4): splits 1 .. max_split, each
// rod's masses scaled by scale_for_time_step for dt / split from the rod as built (rods[0]), and
// each split's settings those of settings[0] with dt / split and set_quasi_static_damping.
void make_quasi_static(SolverModel& model, int max_split);

// ---------------------------------------------------------------------------------------------
// State

// A balloon inflated on an instrument, set before each step (by the procedure, from the vessel
// and the balloon's pressure): nodes first .. last are held within `play` of the vessel's axis
// instead of meeting the wall, and their friction with the wall carries the balloon's pressure
// on it (NodeContact::preload), which anchors an inflated balloon (physics.md 8).
struct BalloonHold {
  int first = 0, last = -1;         // held nodes (none when last < first)
  std::vector<Vec3> axis;           // (n) the vessel's centreline point at each held node (m)
  std::vector<Vec3> tangent;        // (n) the centreline's direction there
  std::vector<Vec3> axis_velocity;  // (n) the vessel's velocity there (m/s)
  std::vector<double> play;         // (n) how far the node may be from the axis (m)
  std::vector<double> wall_load;    // (n) the balloon's pressure on the wall around the node (N)
  bool active() const { return last >= first; }
  void clear() { last = first - 1; }
};

// Everything of an instrument that changes during a run.
struct InstrumentState {
  RodState rod;
  DriveState drive;
  // Entirely outside the body and not being pushed in: the step skips it (nothing of it moves).
  // Set by each step from its command.
  bool parked = false;
  // Contact coherence (physics.md 6): where each node was last queried and the wall-free radius
  // found around that point (0: touching or unknown), how far a moving wall may have moved since
  // the start (wall_travel, summed at its speed bound) and at each node's query (travel_at; -1
  // where no moving part of the wall can ever reach the queried sphere: the still aorta while the
  // heart beats). It decides which nodes are queried and how wide, so it is state, not scratch.
  std::vector<Vec3> query_centre;  // (n)
  std::vector<double> clearance;   // (n)
  std::vector<double> travel_at;   // (n) m, or -1
  // The same for the collision samples between the nodes (InstrumentScratch::sample_edge), sized
  // by the step that first meets them (their count comes from the settings, not the model; a
  // state of another size is taken as unknown and queried again).
  std::vector<Vec3> sample_centre;       // (samples)
  std::vector<double> sample_clearance;  // (samples)
  std::vector<double> sample_travel_at;  // (samples) m, or -1
  double wall_travel = 0.0;              // m
  BalloonHold hold;                      // (sized n when a balloon is inflated)
};

// A driven instrument lying straight on the sheath axis with `depth` (m) inserted and the hand
// at `roll` (rad). Throws InputError for a depth beyond the rod's length less one segment.
InstrumentState make_instrument_state(const InstrumentModel& model, double depth,
                                      double roll = 0.0);
// A free instrument in the shape the definition gives (make_state).
InstrumentState make_free_instrument_state(const InstrumentModel& model, const RodDef& def);

struct SolverState {
  std::vector<InstrumentState> instruments;  // (instrument)
  double time = 0.0;                         // s
  // The fine steps of the last step (1: none) and the split a sudden load holds until hold_until.
  int split = 1;
  double hold_until = -1.0;  // s
  int held_split = 1;

  // FNV-1a over every value (rods, drives, contact coherence, split); equal for equal states.
  std::uint64_t hash() const;
  void hash_into(StateHasher& h) const;
};

SolverState make_solver_state(const SolverModel& model, std::vector<InstrumentState> instruments);

// ---------------------------------------------------------------------------------------------
// Step

struct StepProfile {
  // microseconds. collision: the wall's contacts found (and the sheath's, the holds');
  // constraints: the block iterations (distance, contacts with the wall, and the coupling's
  // solve); coupling: the coaxial pairs' detection, solve and projection; integrate_positions:
  // positions and the contacts' bias removed; wall: moving the beating wall to each fine step's
  // time and refitting its tree; feedback: the hands' forces and the rods' end of step.
  double drive = 0, forces = 0, integrate_velocities = 0, collision = 0, constraints = 0,
         distance = 0, contacts = 0, integrate_positions = 0, total = 0;
  double wall = 0, coupling = 0, feedback = 0;
  int num_contacts = 0;
  int num_queries = 0;         // the nodes' wall queries
  int num_sample_queries = 0;  // the collision samples' (physics.md 6.3)
};

// What a step did besides moving the instruments.
struct StepInfo {
  int split = 1;             // fine steps it was split into
  bool resplit = false;      // taken again, split finer, after a sudden load
  bool rolled_back = false;  // it produced a non-finite value: undone, instruments held still
  bool runaway = false;      // a node ran away (SubStepSettings::runaway): taken again finer
  bool calmed = false;       // ... and still ran away: taken again from rest
};

namespace internal {
struct SolverScratch;
}

// Scratch sized once for a model (contact lists, query buffers, leaf caches, backups for the
// re-split and the rollback): a warm step allocates nothing. Holds the last step's contacts for
// reading until the next step.
class SolverWorkspace {
 public:
  explicit SolverWorkspace(const SolverModel& model);
  ~SolverWorkspace();
  SolverWorkspace(SolverWorkspace&&) noexcept;
  SolverWorkspace& operator=(SolverWorkspace&&) noexcept;

  // The last fine step's wall contacts of an instrument (the introducer sheath's lumen included).
  std::span<const NodeContact> contacts(int instrument) const;
  // ... and the contacts of its edges' collision samples (NodeContact::along; physics.md 6.3).
  std::span<const NodeContact> edge_contacts(int instrument) const;
  // The last fine step's concentric and rim contacts of a coupling, and its clearance (m).
  std::span<const CoaxialContact> coupling_contacts(int coupling) const;
  double coupling_clearance(int coupling) const;
  // True when the node lay in another instrument's lumen in the last fine step (no wall query).
  bool sheathed(int instrument, int node) const;
  // The instrument's node farthest outside the vessel over the last step's fine steps (node -1:
  // none; a step undone by a rollback has none).
  NodeEscape escape(int instrument) const;
  // The instrument's edge deepest through the wall, both its nodes inside, if the last step
  // checked the edges (SolverSettings::edge_check_period; node -1: none or not checked).
  NodeEscape edge_escape(int instrument) const;

  // Forgets what the leaf caches know of the wall (after the wall changed shape).
  void clear_caches();

  internal::SolverScratch& scratch() { return *s_; }
  const internal::SolverScratch& scratch() const { return *s_; }

 private:
  std::unique_ptr<internal::SolverScratch> s_;
};

// One step of model.dt(): commands[i] drives instruments[i]; `wall` (nullptr: no collisions) is
// set to the time of each fine step. Sub-steps, re-split and rollback as in the header comment.
// `profile`, if given, receives the stages' times summed over the fine steps. No heap allocation
// once warm.
StepInfo solver_step(const SolverModel& model, SolverState& state, SolverWorkspace& ws,
                     VesselWall* wall, std::span<const DriveCommand> commands,
                     StepProfile* profile = nullptr);

// Diagnostics: the centreline's arc length inside the body and its rest length.
double compression(const RodModel& model, const RodState& state);  // (rest - arc) / rest

}  // namespace vcsim
