// Force and torque at the hand of every driven instrument (physics.md 6.1), internal to the solver.
#pragma once

#include <span>

#include "vcsim/solver.h"

namespace vcsim::internal {

// After the step's positions: fills each driven instrument's DriveState force and torque (raw and
// low-passed). `couplings` are the step's, with their contacts; inner instruments are evaluated
// before the outer ones that carry them, whose hands feel their reactions.
void hand_feedback(std::span<Instrument> insts, std::span<const Coupling> couplings,
                   const SolverSettings& settings);

}  // namespace vcsim::internal
