// The solver's scratch (SolverWorkspace's insides) and the view of one instrument that a fine
// step works on. Internal to src/solver.
#pragma once

#include <array>
#include <limits>
#include <span>
#include <vector>

#include "vcsim/solver.h"

namespace vcsim::internal {

// InstrumentScratch::room of a node with no wall to watch for.
inline constexpr double kNoWall = std::numeric_limits<double>::infinity();

// One instrument's scratch, sized once for its node count.
struct InstrumentScratch {
  RodWorkspace rod;
  // Contact detection: the nodes queried this step, where, how wide, and what was found.
  std::vector<SphereContact> hits;       // (n)
  std::vector<int> query_nodes;          // (n)
  std::vector<Vec3> query_points;        // (n)
  std::vector<double> query_radii;       // (n)
  std::vector<LeafCache*> query_caches;  // (n) the queried nodes' caches
  // Wall leaves near each node (static walls). A pure cache of the static tree: a query gives the
  // same answer with or without it, so a restored state need not carry it.
  std::vector<LeafCache> leaf_cache;  // (n)
  std::vector<NodeContact> contacts;  // active contacts, capacity n
  // Collision samples between the nodes (SolverSettings::edge_sample_spacing): each one's edge
  // and parameter along it, fixed by the rest lengths; their queries; their contacts
  // (NodeContact::along).
  std::vector<int> sample_edge;
  std::vector<double> sample_along;
  std::vector<int> sample_query;  // (samples) the samples queried this step
  std::vector<Vec3> sample_points;
  std::vector<double> sample_radii;
  std::vector<double> sample_reach;  // the queried samples' contact reach (m, radius less margin)
  std::vector<LeafCache> sample_cache;  // a pure cache, as leaf_cache
  std::vector<LeafCache*> sample_caches;
  std::vector<SphereContact> sample_hits;
  std::vector<NodeContact> edge_contacts;
  // (n) How near the wall each free node may be now, at least (m; from its query or its
  // clearance; -1 for a node that does not meet the wall): samples far enough are not queried.
  std::vector<double> gap;
  std::vector<int> edge_contact_of;  // (n) hand-force scratch: an edge contact near it (-1: none)
  // (n) How far each node may travel this fine step and still meet no wall that its detection
  // did not see (m; infinity where it is not against the wall; for a node in contact, its gap and
  // the contact margin: held off its own wall only, it may meet another face beyond).
  std::vector<double> room;
  std::vector<Vec3> contact_normal;  // (n) the normal of the node's wall contact, if it has one
  // (n) 1 + the index of the coupling whose outer instrument's lumen holds the node this step;
  // 0: none (the node meets the wall)
  std::vector<unsigned char> sheathed;
  std::vector<Vec3> coupling_impulse;  // (n) coaxial coupling impulses on each node this step
  // Hand-force scratch (physics.md 6.1): reactions of inner instruments on this one's nodes, and
  // each node's wall contact and coupling contact this step (-1: none).
  std::vector<Vec3> felt_load;        // (n)
  std::vector<int> wall_contact_of;   // (n)
  std::vector<int> wall_contact2_of;  // (n) a second wall contact (catch_late_movers; -1: none)
  std::vector<int> coupling_of;       // (n) the node's concentric contact (-1: none)
  std::vector<int> coupling_pair;     // (n) the coupling it belongs to
  std::vector<int> rim_of;            // (n) the rim contact of the edge from node i (-1: none)
  std::vector<int> rim_pair;          // (n)
  std::array<double, 3> stage_us{};   // profile scratch: this instrument's stage times (us)
  // The node farthest outside the vessel so far in this step (reset by each try of the step).
  NodeEscape escape;
  // An edge seen through the wall by the step's edge check (check_edges; edge true), if any.
  NodeEscape edge_escape;

  void resize(const RodModel& md, double sample_spacing);
};

struct CouplingScratch {
  std::vector<CoaxialContact> contacts;  // capacity = inner nodes
  double clearance = 0.0;                // m, set by each fine step
};

// One instrument as a fine step sees it: its model, the rod of the step's split, its state and
// its scratch.
struct Inst {
  const InstrumentModel* im = nullptr;
  const RodModel* md = nullptr;
  InstrumentState* st = nullptr;
  InstrumentScratch* w = nullptr;

  const RodModel& model() const { return *md; }
  RodState& rod() const { return st->rod; }
  DriveState& drive() const { return st->drive; }
  RodWorkspace& ws() const { return w->rod; }
  bool parked() const { return st->parked; }
  bool driven() const { return im->driven; }
  // Node i is held by an inflated balloon this step (BalloonHold): no wall query.
  bool held(int i) const {
    const BalloonHold& h = st->hold;
    return i >= h.first && i <= h.last;
  }
};

// One coupling as a fine step sees it.
struct Pair {
  const CouplingModel* cm = nullptr;
  CouplingScratch* s = nullptr;
};

struct SolverScratch {
  std::vector<InstrumentScratch> inst;          // (instrument)
  std::vector<CouplingScratch> coupling;        // (coupling)
  std::vector<Inst> bound;                      // (instrument) rebound for each fine step's split
  std::vector<Pair> pairs;                      // (coupling)
  std::vector<DriveCommand> sub_drive;          // (instrument) the hand's command for one fine step
  std::vector<double> fine_force, fine_torque;  // (instrument) hand force summed over them
  // The step's start, for a step taken again split finer or undone.
  std::vector<RodState> backup_rod;      // (instrument)
  std::vector<DriveState> backup_drive;  // (instrument)
};

// One fine step of every instrument that is not parked, with settings.rod.dt, against the wall
// as set (the stages of docs/architecture.md). `profile`, if given, receives this fine step's
// stage times.
void fine_step(std::span<Inst> insts, std::span<const Pair> couplings, VesselWall* wall,
               const SolverSettings& settings, std::span<const DriveCommand> commands,
               StepProfile* profile);

// After a step: the edge between two free nodes that passes through the wall deepest, both nodes
// inside, its deepest point behind the wall by more than the rod's radius, is the instrument's
// edge_escape of the step, unless a node was seen out (physics.md 6.3). Changes no state.
void check_edges(const Inst& in, VesselWall& wall, const SolverSettings& settings);

// After a fine step's positions: fills each driven instrument's DriveState force and torque (raw
// and low-passed). Inner instruments are evaluated before the outer ones that carry them, whose
// hands feel their reactions (physics.md 6.1).
void hand_feedback(std::span<Inst> insts, std::span<const Pair> couplings,
                   const SolverSettings& settings);

}  // namespace vcsim::internal
