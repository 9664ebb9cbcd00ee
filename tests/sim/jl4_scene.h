// A Judkins left 4 (6F) with the 0.035" J wire in its lumen, both at the right femoral sheath of
// the default patient, driven by commands (test_sim.cpp, test_sim_noalloc.cpp). `nodes` per
// instrument (tip segments 2 mm). Commands: instruments[0] the catheter, [1] the wire.
#pragma once

#include <string>

#include "vcsim/sim.h"

namespace vcsim::test {

inline Scenario jl4_with_j_wire(int nodes, bool beating) {
  const std::string n = std::to_string(nodes);
  return parse_scenario(
      std::string(R"({"format": "vcsim-scenario", "version": 1, "name": "jl4-j", "dt_ms": 0.5,
    "motion": {"beating": )") +
          (beating ? "true" : "false") + R"(}, "instruments": [
      {"name": "catheter", "catalogue": "catheter-jl4-6f", "max_nodes": )" +
          n + R"(, "tip_segment_mm": 2},
      {"name": "wire", "catalogue": "wire-035-j3-hydrophilic", "inside": "catheter",
       "max_nodes": )" +
          n + R"(, "tip_segment_mm": 2}],
    "input": {"type": "timeline", "file": "unused.json"}})",
      "jl4-j.json");
}

// Both hands in position mode at depth 0: [0] the catheter, [1] the wire.
inline StepCommands jl4_with_j_wire_commands() {
  StepCommands cmds;
  cmds.reset(2);
  for (DriveCommand& d : cmds.drive) d.mode = DriveCommand::Mode::kPosition;
  return cmds;
}

}  // namespace vcsim::test
