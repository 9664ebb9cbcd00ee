// vcsim procedure: what the treatment does to the vessel (docs/procedure.md). Balloons inflated by
// pressure along their compliance charts, fitted to the vessel; lesions that hold a balloon's
// waist below their opening pressure, yield to it above, and recoil when it deflates; stents that
// expand with their balloons, stay at their expanded size less recoil, follow the beating vessel
// and hold it open; and the outcomes a cardiologist measures. Split like the other levels: a
// ProcedureModel built once, a ProcedureState that changes (part of SimState), and two step
// functions around the solver's step.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "vcsim/anatomy.h"
#include "vcsim/commands.h"
#include "vcsim/instruments.h"
#include "vcsim/solver.h"

namespace vcsim {

// ---------------------------------------------------------------------------------------------
// Model

// A balloon (a balloon catheter's, or a stent system's delivery balloon) on an instrument.
// Balloons keep their index for the whole run: when their instrument is removed from the scene
// (an exchange, docs/scenarios.md) the balloon stays in the model as removed (`instrument` -1),
// its state and stent with it, so that its events, its outcome and a stent it deployed remain.
struct BalloonModel {
  int instrument = -1;      // the scene's instrument it is on; -1: removed from the scene
  std::string label;        // what reports call it: its instrument's name (set by the sim layer)
  std::string catalogue;    // its instrument's catalogue entry
  std::vector<int> outers;  // the instruments whose lumens it runs in (the guide)
  BalloonSpec spec;
  std::optional<StentSpec> stent;  // crimped on the balloon
  // The rod's nodes along the balloon at its longest (rated burst), proximal to distal, and each
  // node's distance from the balloon's distal end along the rod (m).
  int first = 0, last = -1;
  std::vector<double> from_distal;  // (last - first + 1)
  std::vector<double> node_length;  // (last - first + 1) balloon length each node carries (m)
  double shaft_radius = 0.0;        // of the folded balloon: half the crossing profile (m)
  int nodes() const { return last - first + 1; }
  bool removed() const { return instrument < 0; }
};

// How a lesion takes a balloon (per lesion of the tree; estimates, docs/procedure.md).
struct LesionMechanics {
  double opening_pressure = 6.0 * 101325.0;  // Pa: below it the lesion holds the balloon's waist
  double recoil = 0.3;  // fraction of the radius a balloon gained that it gives back on deflation
  // A crossing instrument pressing the plaque harder than crossing_force compresses it (the
  // Dotter effect): the lumen there widens at crossing_rate while the load lasts, and stays.
  double crossing_force = 0.3;    // N on one node
  double crossing_rate = 2.0e-3;  // m/s of lumen radius
};

struct LesionModel {
  int lesion = -1;  // index in the tree's lesions
  LesionSpan span;
  LesionMechanics mechanics;
  double reference_diameter = 0.0;  // the healthy lumen's diameter at its two ends, mean (m)
};

struct ProcedureModel {
  std::vector<BalloonModel> balloons;
  std::vector<LesionModel> lesions;  // one per tree lesion
  std::vector<LesionSpan> spans;     // (lesion) as lumen_section takes them
  LesionMorph morph;                 // the lumen vertices the lesions move
  std::vector<Vec3> morph_limit;     // (morph vertices) at the largest opening a balloon may make
  static constexpr double kMaxOpening = 1.5;
};

// Where ring k of a stent's n rings sits on its balloon while crimped: m from the balloon's distal
// end (the stent centred on the nominal working length; k = 0 at the stent's distal end).
double stent_ring_from_distal(const BalloonModel& balloon, std::size_t k, std::size_t n);

// The balloons of the scene's instruments (specs[i] of solver.instruments[i]) and the tree's
// lesions with their mechanics (one per lesion, or empty for the defaults). Throws InputError.
ProcedureModel make_procedure_model(const VesselTree& tree, const Lumen& lumen,
                                    const SolverModel& solver,
                                    std::span<const InstrumentSpec> specs,
                                    std::span<const LesionMechanics> mechanics = {});
// The balloon of instrument i (specs[i] must have one): which of its rod's nodes carry it, and
// the instruments whose lumens it runs in. Throws InputError (too few nodes along the balloon).
BalloonModel make_balloon_model(const SolverModel& solver, std::span<const InstrumentSpec> specs,
                                int instrument);

// ---------------------------------------------------------------------------------------------
// State

struct BalloonState {
  double pressure = 0.0;      // Pa gauge in the balloon (0 once ruptured)
  double max_pressure = 0.0;  // Pa, the highest it held
  bool ruptured = false;
  double free_diameter = 0.0;  // m: the chart's at the pressure
  // Where its middle lies while it is inflated in a vessel (rest anatomy; segment -1: not), and
  // where it last did.
  TreeLocation centre, last;
  std::vector<double> radius;  // (balloon nodes) its radius at each node now (m)
  // (balloon nodes) the lumen's radius that stops it at each node (m; 1 where not fitted), and
  // where and when it was measured on the wall (queried again when the node has moved on, the
  // wall changed shape, or kRefit has passed)
  std::vector<double> lumen;
  std::vector<double> lumen_s;
  double lumen_time = -1.0;
  std::uint64_t lumen_epoch = 0;
  static constexpr double kRefit = 10e-3;       // s
  static constexpr double kRefitMove = 0.1e-3;  // m along the vessel
  // (balloon nodes) arc length of each node along last.segment, when last inflated there
  std::vector<double> s;
  // (balloon nodes) how far beyond lumen - r of the vessel's axis each node lay when the balloon
  // began to press on the wall (m; -1 while not held): the folded balloon, wider than the shaft
  // it lay on the wall as, unfolds onto the axis over the pressure its chart starts at, not in a
  // step (docs/procedure.md, "Hold").
  std::vector<double> hold_excess;
  // The largest free diameter it reached in a vessel, over the reference diameter there.
  double max_ratio = 0.0;
  bool over_expanded = false;    // the free diameter passed 1.2 x the reference diameter
  Vec3 mid_rest = Vec3::Zero();  // its middle node at rest before the solver's step (m)
};

struct StentState {
  enum class Phase { kCrimped, kDeployed };
  Phase phase = Phase::kCrimped;
  // (rings, from its distal end) while crimped: the largest radius its balloon gave each ring (m)
  std::vector<double> expanded;
  // Deployed: its rings in the rest anatomy, along one segment, and their radii (m).
  int segment = -1;
  std::vector<double> ring_s;
  std::vector<double> ring_radius;
  double deployed_at = 0.0;  // s
};

struct ProcedureEvent {
  enum class Kind { kRupture, kOverExpansion, kStentDeployed, kPressureRefused };
  Kind kind = Kind::kRupture;
  double time = 0.0;  // s
  int balloon = -1;
  double value = 0.0;  // Pa (rupture, refused), diameter ratio (over-expansion), m (stent)
};
const char* to_string(ProcedureEvent::Kind k);

struct ProcedureState {
  std::vector<BalloonState> balloons;  // (balloon)
  // (balloon) used for stent systems; a deployed stent stays in the vessel when its balloon's
  // instrument is removed from the scene
  std::vector<StentState> stents;
  // (lesion) how far each lesion is opened now, the most a balloon opened it, and what a stent
  // holds open
  std::vector<LesionOpening> opening, max_opening, stent_hold;
  // (lesion) how far the inflated balloons push each lesion open this step
  std::vector<LesionOpening> pushed;
  // (lesion) how far crossing instruments have compressed each lesion (plastic)
  std::vector<LesionOpening> crossed;
  // (lesion) the opening the wall shows: `opening` once it has moved on by more than
  // kWallOpeningStep at some sample (a held balloon's opening trembles by less each step, and
  // each change re-morphs the lumen)
  std::vector<LesionOpening> wall_opening;
  static constexpr double kWallOpeningStep = 2e-3;
  std::uint64_t wall_epoch = 0;        // counts the changes of the wall's shape (openings, stents)
  std::vector<ProcedureEvent> events;  // in order (capacity reserved: rare)
  bool refusing = false;  // a pressure with no balloon in the patient was refused (logged once)

  void hash_into(StateHasher& h) const;
};

ProcedureState make_procedure_state(const ProcedureModel& model, SolverState& solver);
// Sizes `state` for the balloons `model` has beyond those of the state (added to the scene with
// their instruments), as make_procedure_state does, and sizes those instruments' holds.
void extend_procedure_state(const ProcedureModel& model, ProcedureState& state,
                            SolverState& solver);

// ---------------------------------------------------------------------------------------------
// Step

// Before the solver's step to t + dt, in two parts around bringing the wall to the lesions'
// opening. First: the indeflator's pressure into each balloon in the patient (a balloon outside
// it refuses it, logged once as an event), rupture past rated burst pressure, where each inflated
// balloon lies, the lesions it opens (above their opening pressure) and how they recoil.
void procedure_before_step(const ProcedureModel& model, const SolverModel& solver_model,
                           const VesselTree& tree, const CardiacMotion* motion,
                           const StepCommands& commands, double t, double dt, ProcedureState& state,
                           SolverState& solver);
// Then, with the wall showing those openings: each inflated balloon's radius fitted to it (it
// stops at the nearest wall point from the vessel's axis), and the hold it puts on its
// instrument's nodes (BalloonHold: the axis and the balloon's pressure on the wall) at t1 = t + dt.
// A stent on its balloon expands with it.
void procedure_fit(const ProcedureModel& model, const SolverModel& solver_model,
                   const VesselTree& tree, const CardiacMotion* motion, VesselWall& wall, double t1,
                   ProcedureState& state, SolverState& solver);
// After the solver's step (its wall contacts in `solver_ws`): a stent whose balloon deflated
// stays (deployed), at its expanded radius less its acute recoil, holding the lesion open; a
// deployed stent that an inflated balloon grips is enlarged by it (post-dilation) and moves with
// it; a lesion pressed by an instrument beyond its crossing force widens there (Dotter effect).
void procedure_after_step(const ProcedureModel& model, const SolverModel& solver_model,
                          const VesselTree& tree, const CardiacMotion* motion, double time,
                          double dt, ProcedureState& state, const SolverState& solver,
                          const SolverWorkspace& solver_ws);

// ---------------------------------------------------------------------------------------------
// What a cardiologist measures (docs/procedure.md)

struct LesionOutcome {
  double reference_diameter = 0.0;  // m
  double mld_before = 0.0;          // minimal lumen diameter as built (m)
  double mld_now = 0.0;             // now (m)
  double stenosis_before = 0.0;     // diameter stenosis, 1 - MLD / reference
  double stenosis_now = 0.0;
};
struct StentOutcome {
  bool deployed = false;
  double diameter_min = 0.0, diameter_max = 0.0;  // m
  double start = 0.0, end = 0.0;                  // arc length along its segment (m)
  int lesion = -1;                                // the lesion it lies on (-1: none)
  double longitudinal_offset = 0.0;  // its centre from the lesion's centre (m, + distal)
  bool geographic_miss = false;      // it does not cover the lesion with 2 mm margins both ends
  double malapposition = 0.0;        // largest gap between the stent and the lumen around it (m)
};
struct BalloonOutcome {
  bool removed = false;       // its instrument was removed from the scene
  double max_pressure = 0.0;  // Pa
  double max_ratio = 0.0;     // balloon-to-artery: free diameter over the reference diameter
  bool ruptured = false;
  bool over_expanded = false;
};
struct ProcedureOutcome {
  std::vector<LesionOutcome> lesions;
  std::vector<BalloonOutcome> balloons;
  std::vector<StentOutcome> stents;  // (balloon) of stent systems, removed ones included
};
ProcedureOutcome procedure_outcome(const ProcedureModel& model, const VesselTree& tree,
                                   const ProcedureState& state);

// The lumen's radius at arc length s of a segment with the lesions as the state has them (m).
double lumen_radius_now(const ProcedureModel& model, const VesselTree& tree,
                        const ProcedureState& state, int segment, double s);

}  // namespace vcsim
