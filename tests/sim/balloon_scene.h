// A straight coronary-sized tube (open at both ends, no heart) with a wire and a balloon or stent
// catheter riding on it, both through the sheath, for the procedure tests (test_procedure.cpp):
// the tube runs along +z from the origin for 200 mm, radius `radius_mm`; instruments enter at
// z = 190 mm heading to -z (or at 10 mm heading to +z, TubeSpecs::access_mm); an optional lesion
// sits at 60 .. 72 mm from the tube's start (TubeSpecs::lesion_mm).
#pragma once

#include <filesystem>
#include <fstream>
#include <string>

#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace vcsim::test {

struct TubeSpecs {
  double radius_mm = 1.5;
  double lesion_percent = 0.0;  // 0: none
  std::string catalogue = "balloon-sc-3.0x15";
  std::string lesions_json;  // the scenario's "lesions" key, "" for the defaults
  // Where the sheath enters, mm along the tube (the instruments head for the farther end: from
  // 190 mm toward the start, from 10 mm toward the end), and where the lesion starts, mm.
  double access_mm = 190.0;
  double lesion_mm = 60.0;
};

inline constexpr double kAccessS = 0.190;   // m along the tube
inline constexpr double kLesionS0 = 0.060;  // m
inline constexpr double kLesionS1 = 0.072;  // m

// The rest of a tube scenario after its instruments: the input (and an autopilot plan, if any).
// By default a timeline that is never read: the tests step the simulator themselves.
inline constexpr const char* kUnreadTimeline =
    R"("input": {"type": "timeline", "file": "unused.json"})";

// Writes the tube's anatomy into `dir` and returns a scenario of it with `instruments_json` (the
// scenario's instruments[] array) and `input_json`.
inline Scenario tube_scenario(const std::filesystem::path& dir, const TubeSpecs& t,
                              const std::string& instruments_json,
                              const std::string& input_json = kUnreadTimeline) {
  std::filesystem::create_directories(dir);
  std::string lesion;
  if (t.lesion_percent > 0.0)
    lesion = R"("lesions": [{"segment": "tube", "distance_mm": )" + std::to_string(t.lesion_mm) +
             R"(, "length_mm": 12, "diameter_reduction_percent": )" +
             std::to_string(t.lesion_percent) + R"(, "eccentricity": 0, "angle_deg": 0}],)";
  std::ofstream(dir / "tube.json") << R"({"format": "vcsim-anatomy", "version": 1,
    "name": "tube", "coordinates": "LPS", "open_start": true,
    "access": {"segment": "tube", "distance_mm": )"
                                   << t.access_mm << R"(}, )" << lesion << R"(
    "segments": [{"name": "tube", "kind": "coronary", "parent": null,
      "points_mm": [[0, 0, 0], [0, 0, 50], [0, 0, 100], [0, 0, 150], [0, 0, 200]],
      "radius_mm": )" << t.radius_mm
                                   << R"(}]})";
  const std::string lesions = t.lesions_json.empty() ? "" : ", \"lesions\": " + t.lesions_json;
  return parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "balloon-tube",
    "anatomy": "tube.json", "motion": {"beating": false}, "dt_ms": 0.5,
    "sheath_length_mm": 10,
    "instruments": )" + instruments_json +
                            ",\n" + input_json + lesions + "}",
                        (dir / "tube-scenario.json").string(), dir);
}

// The tube with a wire [0] and a balloon or stent catheter [1] riding on it.
inline Scenario balloon_in_tube(const std::filesystem::path& dir, const TubeSpecs& t,
                                const std::string& input_json = kUnreadTimeline) {
  return tube_scenario(dir, t,
                       R"([
      {"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 160, "tip_segment_mm": 1},
      {"name": "balloon", "catalogue": ")" +
                           t.catalogue +
                           R"(", "over": "wire", "max_nodes": 200,
       "tip_segment_mm": 1}])",
                       input_json);
}

// The inserted depth (m) that puts the middle of a balloon catheter's balloon at arc length s of
// the tube.
inline double balloon_depth(const InstrumentSpec& spec, double s) {
  const BalloonSpec& b = *spec.balloon;
  return (kAccessS - s) + b.distal_offset + 0.5 * b.length;
}

}  // namespace vcsim::test
