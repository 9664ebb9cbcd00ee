// SimWorkspace's insides. Internal to src/sim.
#pragma once

#include <memory>
#include <vector>

#include "vcsim/beating_wall.h"
#include "vcsim/sim.h"

namespace vcsim::internal {

// A deployed stent as the instruments meet it at the step's time: its rings' centres (moved with
// the vessel) and radii.
struct StentTube {
  std::vector<Vec3> rest, amp_c, amp_r;  // (rings) centres at rest and their motion amplitudes
  std::vector<Vec3> centre;              // (rings) m, now
  std::vector<double> radius;            // (rings) m
  Vec3 middle = Vec3::Zero();            // centre of a sphere holding the whole stent
  double reach = 0.0;                    // its radius (m)
};

// The wall the instruments meet: the lumen (lesions opened as the state has them), the caps of
// its closed ends (WallExit::closed: a hemisphere of the end's radius on its disc, beyond it;
// physics.md 6.4) and, inside it, the deployed stents, whose struts hold what passes through them.
// A node inside a stent's span or a cap's meets whichever it penetrates most.
class ProcedureWall final : public VesselWall {
 public:
  VesselWall* lumen = nullptr;
  std::vector<StentTube> stents;
  const CardiacMotion* motion = nullptr;
  // The tree's open ends (open_ends order) at rest and their motion amplitudes at the centre;
  // exits() moves them to the time set (their discs carried, not turned: a distal coronary's end
  // turns by a few degrees, a fraction of its radius in the escape check and in its cap).
  std::vector<WallExit> exits_rest;
  std::vector<Vec3> exit_amp_c, exit_amp_r;

  void set_time(double t) override {
    time_ = t;
    lumen->set_time(t);
  }
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<SphereContact> out) override;
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<LeafCache* const> caches, double slack,
                     std::span<SphereContact> out) override;
  Vec3 velocity(const SphereContact& hit) const override;
  double speed_bound() const override { return lumen->speed_bound(); }
  // The lumen's moving parts, and near a deployed stent (it beats with its vessel) whenever the
  // lumen moves at all.
  bool moves_near(const Vec3& centre, double radius) const override;
  // The lumen's wall only: a stent lies inside the vessel and a cap beyond its end.
  SegmentCrossings segment_crossings(const Vec3& a, const Vec3& b) override {
    return lumen->segment_crossings(a, b);
  }
  std::span<const WallExit> exits() override;

 private:
  void add_stents(std::span<const Vec3> centres, std::span<const double> radii,
                  std::span<SphereContact> out) const;
  void add_caps(std::span<const Vec3> centres, std::span<const double> radii,
                std::span<SphereContact> out);
  double time_ = 0.0;
  std::vector<WallExit> exits_;  // (exit) at exits_time_
  double exits_time_ = -1.0;
};

// The tree's open ends as the wall's exits, with their motion amplitudes (none without motion),
// in open_ends order; with `mesh_lumen` (a lumen imported from a mesh file) each end is the mesh's
// own opening nearest it, and the mesh's openings that no end reaches follow. With `sheath` (a
// lumen built from the tree) every end but the access end is closed (physics.md 6.4): the access
// end is the one behind the sheath (facing against its axis, its centre behind the access point),
// the nearest such; a mesh's openings stay open.
void make_exits(const VesselTree& tree, const CardiacMotion* motion, ProcedureWall& wall,
                const Lumen* mesh_lumen = nullptr, const Sheath* sheath = nullptr);

// Index (open_ends order) of the tree's access end: the open end behind the sheath, facing
// against its axis, nearest the access point; -1 if none.
int access_end(const VesselTree& tree, const Sheath& sheath);

struct SimScratch {
  // With `reuse` (a workspace of a model with the same anatomy, an exchange apart): its wall
  // taken over instead of built again, leaving `reuse` unusable.
  SimScratch(const SimModel& model, SimScratch* reuse);
  // The lumen: the beating lumen's patches, moved lazily to each fine step's time where the
  // instruments can reach them (a pure function of that time and the lesions' opening), or a
  // static tree's queries (the workspace's own mesh and tree when lesions can open).
  std::unique_ptr<BeatingLumen> beating;
  std::unique_ptr<BeatingWall> beating_wall;
  TriangleMesh static_mesh;
  AabbTree static_tree;
  std::unique_ptr<StaticWall> static_wall;
  ProcedureWall wall;
  // The lesions' opening the lumen shows (compared with the state's before each step).
  std::vector<LesionOpening> shown_opening;
  std::vector<Vec3> morphed;                // (morph vertices) scratch
  std::vector<int> morph_triangles;         // triangles with a morph vertex (static lumen)
  std::vector<std::uint64_t> shown_stents;  // hash of each stent's rings the wall shows
  SolverWorkspace solver;
  std::vector<Vec3> old_tips;  // (instrument) the tips before the step
};

// Brings the wall to the state before a step ending at t1: the lumen morphed to the lesions'
// opening if it changed, the deployed stents' tubes rebuilt if they changed and moved to t1. A
// changed wall invalidates every node's clearance and leaf cache (the state's and the solver
// workspace's). Allocates only when a stent is first deployed.
void sync_wall(const SimModel& model, SimState& state, SimScratch& scratch, double t1);

}  // namespace vcsim::internal
