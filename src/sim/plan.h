// The instruments in the scene along an autopilot plan whose add and remove phases change them.
// Internal to src/sim (the scenario's checks, the model's).
#pragma once

#include <cstddef>
#include <functional>
#include <vector>

#include "vcsim/sim.h"

namespace vcsim::internal {

// Calls visit(k, scene) for each phase k of the scenario's plan, `scene` the instruments in the
// scene when the phase starts: the scenario's, then as the add and remove phases before it left
// them. Throws InputError(source, "autopilot[k]") for a phase naming an instrument not in the
// scene then, an add of a name in it, or a remove of one not in it.
void walk_plan(
    const Scenario& scenario,
    const std::function<void(std::size_t, const std::vector<ScenarioInstrument>&)>& visit);

// The names the plan's add phases bring in.
std::vector<std::string> plan_additions(const Scenario& scenario);

}  // namespace vcsim::internal
