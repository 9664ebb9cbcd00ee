// SimWorkspace's insides. Internal to src/sim.
#pragma once

#include <memory>
#include <vector>

#include "vcsim/beating_wall.h"
#include "vcsim/sim.h"

namespace vcsim::internal {

struct SimScratch {
  explicit SimScratch(const SimModel& model);
  // The wall: the beating lumen's patches, moved lazily to each fine step's time where the
  // instruments can reach them (a pure function of that time), or the static tree's queries.
  std::unique_ptr<BeatingLumen> beating;
  std::unique_ptr<BeatingWall> beating_wall;
  std::unique_ptr<StaticWall> static_wall;
  VesselWall* wall = nullptr;
  SolverWorkspace solver;
  std::vector<Vec3> old_tips;  // (instrument) the tips before the step
};

}  // namespace vcsim::internal
