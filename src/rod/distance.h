// Distance-constraint solvers for one rod (internal).
#pragma once

#include <span>

#include "vcsim/rod.h"

namespace vcsim::internal {

// Each uses the workspace's effective inverse masses and adds every node's constraint impulse
// (held nodes included) to ws.node_impulse.
// One global iteration; false if the factorisation failed (velocities then untouched).
bool distance_global(const RodModel& md, double dt, std::span<const Vec3> x, std::span<Vec3> v,
                     RodWorkspace& ws);
void distance_local_gs(const RodModel& md, double dt, std::span<const Vec3> x, std::span<Vec3> v,
                       RodWorkspace& ws);
void distance_local_jacobi(const RodModel& md, double dt, std::span<const Vec3> x,
                           std::span<Vec3> v, RodWorkspace& ws);

}  // namespace vcsim::internal
