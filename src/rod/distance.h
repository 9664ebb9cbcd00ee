// Distance-constraint solvers for one rod (internal).
#pragma once

#include <span>

#include "vcsim/rod.h"

namespace vcsim::internal {

// Constraint impulses on the first and last node (what a held end feels), accumulated.
struct DistanceImpulses {
  Vec3 first = Vec3::Zero();
  Vec3 last = Vec3::Zero();
};

// One global iteration; false if the factorisation failed (velocities then untouched).
bool distance_global(const RodModel& md, double dt, std::span<const Vec3> x, std::span<Vec3> v,
                     RodWorkspace& ws, DistanceImpulses& out);
void distance_local_gs(const RodModel& md, double dt, std::span<const Vec3> x, std::span<Vec3> v,
                       RodWorkspace& ws, DistanceImpulses& out);
void distance_local_jacobi(const RodModel& md, double dt, std::span<const Vec3> x,
                           std::span<Vec3> v, RodWorkspace& ws, DistanceImpulses& out);

}  // namespace vcsim::internal
