// The assessment of scripted sessions whose answers are known by construction: pedal and cine
// time, three injections of 8 ml, two exchanges; a straight wire that runs into a wrong branch
// and across a lesion at a known depth; a wire pushed into a dead end (one force event above the
// threshold, none below it); and the state hash unchanged by watching.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "vcsim/assess.h"

namespace vcsim::test {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

fs::path scratch(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vcsim_assess_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

Json read_json(const fs::path& p) {
  std::ifstream f(p);
  return Json::parse(f);
}

struct Session {
  Json metrics;
  double end = 0.0;
  std::uint64_t hash = 0;
};

// Runs `scenario` with `timeline_text` to its end, watched by an Assessment (when `watch`), and
// writes the run's metrics into `dir`.
Session run_session(const fs::path& dir, const Scenario& sc, const std::string& timeline_text,
                    const AssessmentSettings& settings = {}, bool watch = true) {
  Simulator sim(sc);
  ScriptedTimeline tl = ScriptedTimeline::parse(timeline_text, (dir / "timeline.json").string());
  tl.bind(sim.instrument_names());
  Assessment assessment(sim, settings);
  RunLoopSettings ls;
  ls.end_time = tl.duration();
  RunReport report;
  report.end_time = ls.end_time;
  report.input_type = "timeline";
  report.loop = run_loop(sim, tl, ls, watch ? &assessment : nullptr);
  write_run_metrics(dir / "metrics.json", sim, report);
  Session s;
  s.end = sim.time();
  s.hash = sim.state().hash();
  if (watch) {
    assessment.write(dir, sim);
    s.metrics = read_json(dir / "metrics.json");
  }
  return s;
}

// The default patient without motion and one J wire that stays outside: only the pedals, the
// syringe and the exchanges act.
Scenario pedal_scenario() {
  return parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "pedals",
    "motion": {"beating": false}, "dt_ms": 1, "time_limit_s": 20,
    "instruments": [{"name": "wire", "catalogue": "wire-035-j3-hydrophilic", "max_nodes": 64}],
    "input": {"type": "timeline", "file": "unused.json"}})",
                        "pedals.json");
}

// Pedal 0.5 -> 12.5 s (12.0 s), injections of 8 ml/s for 1 s at 1, 4 and 7 s (24 ml), an
// instrument added at 3 s and removed at 6 s, cine 12.5 -> 14.5 s (2.0 s: 30 frames), end 15 s.
const char* kPedalTimeline = R"({"keyframes": [
  {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}, "buttons": 0},
  {"t_s": 0.5, "buttons": 1},
  {"t_s": 1, "syringe_flow_ml_s": 8}, {"t_s": 2, "syringe_flow_ml_s": 0},
  {"t_s": 3, "add": {"name": "extra", "catalogue": "wire-014-floppy", "max_nodes": 32}},
  {"t_s": 4, "syringe_flow_ml_s": 8}, {"t_s": 5, "syringe_flow_ml_s": 0},
  {"t_s": 6, "remove": "extra"},
  {"t_s": 7, "syringe_flow_ml_s": 8}, {"t_s": 8, "syringe_flow_ml_s": 0},
  {"t_s": 12.5, "buttons": 2}, {"t_s": 14.5, "buttons": 0},
  {"t_s": 15, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}}]})";

TEST(Session, PedalsSyringeAndExchangesGiveTheirKnownFigures) {
  const fs::path d = scratch("pedals");
  const Session s = run_session(d, pedal_scenario(), kPedalTimeline);
  ASSERT_TRUE(s.metrics.contains("assessment"));
  EXPECT_EQ(s.metrics["format"], "vcsim-metrics");
  EXPECT_EQ(s.metrics["version"], kMetricsVersion);
  const Json& a = s.metrics["assessment"];
  const double dt = 1e-3;  // one step's worth at each edge
  EXPECT_EQ(a["beam"]["source"], "pedals");
  EXPECT_NEAR(a["beam"]["fluoroscopy_time_s"].get<double>(), 12.0, 2 * dt);
  EXPECT_NEAR(a["beam"]["cine_time_s"].get<double>(), 2.0, 2 * dt);
  EXPECT_EQ(a["beam"]["cine_runs"], 1);
  EXPECT_EQ(a["beam"]["cine_frames"], 30);
  EXPECT_NEAR(a["contrast"]["volume_ml"].get<double>(), 24.0, 3 * 8 * dt);
  ASSERT_EQ(a["contrast"]["injections"].size(), 3u);
  for (const Json& inj : a["contrast"]["injections"])
    EXPECT_NEAR(inj["volume_ml"].get<double>(), 8.0, 8 * dt);
  EXPECT_NEAR(a["contrast"]["injections"][1]["start_s"].get<double>(), 4.0, 2 * dt);
  // The assessment's volume is the simulator's.
  EXPECT_NEAR(a["contrast"]["volume_ml"].get<double>(),
              s.metrics["contrast_volume_ml"].get<double>(), 1e-9);
  // The timeline's rows: fluoroscopy 0.5-12.5 s, then cine 12.5-14.5 s.
  std::vector<std::pair<double, double>> fluoro, cine;
  for (const Json& iv : a["intervals"]) {
    const std::pair<double, double> se{iv["start_s"].get<double>(), iv["end_s"].get<double>()};
    if (iv["row"] == "fluoroscopy") fluoro.push_back(se);
    if (iv["row"] == "cine") cine.push_back(se);
  }
  ASSERT_EQ(fluoro.size(), 1u);
  ASSERT_EQ(cine.size(), 1u);
  EXPECT_NEAR(fluoro[0].first, 0.5, 2 * dt);
  EXPECT_NEAR(fluoro[0].second, 12.5, 2 * dt);
  EXPECT_NEAR(cine[0].first, 12.5, 2 * dt);
  EXPECT_NEAR(cine[0].second, 14.5, 2 * dt);
  EXPECT_EQ(a["exchanges"], 2);
  EXPECT_EQ(a["summary"]["exchanges"], 2);
  EXPECT_NEAR(a["procedure_time_s"].get<double>(), 15.0, 2 * dt);
  // Dose: 12 s of fluoroscopy and 30 cine frames through the model.
  const AssessmentSettings set;
  const double kerma = set.fluoro_kerma_rate * 12.0 + set.cine_kerma_per_frame * 30;
  EXPECT_NEAR(a["dose"]["air_kerma_mgy"].get<double>(), kerma * 1e3, 0.01);
  // Both instruments are listed, the added one with its own row; nothing was inserted.
  ASSERT_EQ(a["instruments"].size(), 2u);
  EXPECT_EQ(a["instruments"][1]["name"], "extra");
  EXPECT_EQ(a["summary"]["insertions"], 0);
  // The series has a row per 50 ms and the beam column follows the pedals.
  std::ifstream csv(d / "series.csv");
  std::string header, line;
  std::getline(csv, header);
  EXPECT_EQ(header.rfind("time_s,beam,", 0), 0u) << header;
  int rows = 0, cine_rows = 0;
  while (std::getline(csv, line)) {
    ++rows;
    cine_rows += line.find(",2,") == line.find(',') ? 1 : 0;
  }
  EXPECT_NEAR(rows, 300, 2);
  EXPECT_NEAR(cine_rows, 40, 2);
}

TEST(Session, ACopiedAssessmentRewindsWithTheState) {
  // As the trainer rewinds: the state and the assessment copied at 6 s, the run taken on to
  // 10 s, both put back, and the run finished: the figures are those of one run to the end.
  Simulator sim(pedal_scenario());
  ScriptedTimeline tl = ScriptedTimeline::parse(R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}, "buttons": 0},
    {"t_s": 0.5, "buttons": 1},
    {"t_s": 1, "syringe_flow_ml_s": 8}, {"t_s": 2, "syringe_flow_ml_s": 0},
    {"t_s": 4, "syringe_flow_ml_s": 8}, {"t_s": 5, "syringe_flow_ml_s": 0},
    {"t_s": 7, "syringe_flow_ml_s": 8}, {"t_s": 8, "syringe_flow_ml_s": 0},
    {"t_s": 12.5, "buttons": 0}]})",
                                                "rewind.json");
  tl.bind(sim.instrument_names());
  Assessment assessment(sim);
  RunLoopSettings ls;
  ls.end_time = 6.0;
  run_loop(sim, tl, ls, &assessment);
  const SimState snap = sim.snapshot();
  const Assessment saved = assessment;
  ls.end_time = 10.0;
  run_loop(sim, tl, ls, &assessment);
  EXPECT_EQ(assessment.injections(), 3);
  sim.restore(snap);
  assessment = saved;
  EXPECT_EQ(assessment.injections(), 2);
  ls.end_time = 13.0;
  run_loop(sim, tl, ls, &assessment);
  EXPECT_NEAR(assessment.beam().fluoro_time, 12.0, 2e-3);
  EXPECT_EQ(assessment.injections(), 3);
}

// A straight coronary trunk entered from a continuation ("leg", the access 10 mm inside its open
// end); the target is a side branch at 50 mm; straight ahead beyond the trunk's closed start, a
// branch on the same axis ("side", a wrong branch) holds a lesion 20-26 mm beyond its ostium.
Scenario branch_scenario(const fs::path& dir) {
  std::ofstream(dir / "y.json") << R"({"format": "vcsim-anatomy", "version": 1, "name": "y",
    "coordinates": "LPS", "open_start": false,
    "access": {"segment": "leg", "distance_mm": 90},
    "target": {"segment": "target_branch", "distance_mm": 20},
    "lesions": [{"segment": "side", "distance_mm": 20, "length_mm": 6,
                 "diameter_reduction_percent": 20, "eccentricity": 0, "angle_deg": 0}],
    "segments": [
      {"name": "trunk", "kind": "coronary", "parent": null,
       "points_mm": [[0, 0, 0], [0, 0, 50], [0, 0, 100]], "radius_mm": 2.0},
      {"name": "leg", "kind": "coronary", "parent": "trunk",
       "points_mm": [[0, 0, 100], [0, 0, 150], [0, 0, 200]], "radius_mm": 2.0},
      {"name": "side", "kind": "coronary", "parent": "trunk",
       "points_mm": [[0, 0, 1], [0, 0, -30], [0, 0, -80]], "radius_mm": 2.0},
      {"name": "target_branch", "kind": "coronary", "parent": "trunk",
       "points_mm": [[0, 0, 50], [10, 0, 42], [30, 0, 26]], "radius_mm": 1.5}]})";
  return parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "y",
    "anatomy": "y.json", "motion": {"beating": false}, "dt_ms": 0.5, "sheath_length_mm": 10,
    "instruments": [{"name": "wire", "catalogue": "wire-018-support", "max_nodes": 128,
                     "tip_segment_mm": 1}],
    "input": {"type": "timeline", "file": "unused.json"}})",
                        (dir / "y-scenario.json").string(), dir);
}

TEST(Session, AStraightWireIntoAWrongBranchAndAcrossItsLesionAtKnownTimes) {
  const fs::path d = scratch("branch");
  const Scenario sc = branch_scenario(d);
  // 40 mm/s from depth 0 at t = 0 to 260 mm at 6.5 s, then held to 7 s.
  const double v = 0.040;
  const Session s = run_session(d, sc, R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 6.5, "instruments": {"wire": {"translation_mm": 260, "rotation_deg": 0}}},
    {"t_s": 7, "instruments": {"wire": {"translation_mm": 260, "rotation_deg": 0}}}]})");
  const Json& a = s.metrics["assessment"];
  // The tip is at z = 190 mm - depth on the axis. "side" runs down the axis from z = 1 mm.
  const Simulator probe(sc);
  const VesselTree& tree = probe.tree();
  const int side = tree.find("side");
  const double ostium = ostium_distance(tree, side);  // m along "side"
  const double z_ostium = 1e-3 - ostium, z_lesion_end = 1e-3 - (ostium + 26e-3);
  const double t_enter = (0.190 - z_ostium) / v, t_cross = (0.190 - z_lesion_end) / v;
  // Which segment holds the tip is decided within a lumen's radius of the ostium (2 mm).
  const double tol = 2.5e-3 / v + 0.01;
  const Json& w = a["instruments"][0];
  EXPECT_EQ(w["wrong_branch_entries"], 1);
  EXPECT_NEAR(w["wrong_branch_time_s"].get<double>(), s.end - t_enter, tol);
  ASSERT_EQ(a["lesions"].size(), 1u);
  EXPECT_EQ(a["lesions"][0]["crossed"], true);
  EXPECT_EQ(a["lesions"][0]["crossed_by"], "wire");
  EXPECT_NEAR(a["lesions"][0]["crossed_at_s"].get<double>(), t_cross, 1e-3 / v + 0.01);
  // In a coronary from its first millimetre: time to cross counts from there.
  EXPECT_NEAR(
      a["lesions"][0]["time_to_cross_s"].get<double>(),
      a["lesions"][0]["crossed_at_s"].get<double>() - w["first_in_coronary_s"].get<double>(), 1e-9);
  EXPECT_EQ(w["insertions"], 1);
  // A straight wire running straight never folds back.
  EXPECT_EQ(w["prolapses"], 0);
}

TEST(Session, WatchingDoesNotChangeTheState) {
  const fs::path d1 = scratch("watched"), d2 = scratch("unwatched");
  const Session a = run_session(d1, pedal_scenario(), kPedalTimeline, {}, true);
  const Session b = run_session(d2, pedal_scenario(), kPedalTimeline, {}, false);
  EXPECT_EQ(a.hash, b.hash);
  // A wire in contact with the wall, located in the tree as it goes.
  const std::string push = R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 3, "instruments": {"wire": {"translation_mm": 200, "rotation_deg": 90}}}]})";
  const Session c = run_session(d1, branch_scenario(d1), push, {}, true);
  const Session e = run_session(d2, branch_scenario(d2), push, {}, false);
  EXPECT_EQ(c.hash, e.hash);
}

// A straight wire in a straight coronary tube with a closed end 110 mm from the access.
Scenario dead_end_scenario(const fs::path& dir) {
  std::ofstream(dir / "tube.json") << R"({"format": "vcsim-anatomy", "version": 1,
    "name": "dead-end", "coordinates": "LPS", "open_start": false,
    "access": {"segment": "tube", "distance_mm": 110},
    "segments": [{"name": "tube", "kind": "coronary", "parent": null,
      "points_mm": [[0, 0, 0], [0, 0, 60], [0, 0, 120]], "radius_mm": 1.5}]})";
  return parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "dead-end",
    "anatomy": "tube.json", "motion": {"beating": false}, "dt_ms": 0.5, "sheath_length_mm": 10,
    "instruments": [{"name": "wire", "catalogue": "wire-018-support", "max_nodes": 128,
                     "tip_segment_mm": 1}],
    "input": {"type": "timeline", "file": "unused.json"}})",
                        (dir / "dead-end-scenario.json").string(), dir);
}

std::string push_to(double depth_mm) {
  return R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 2.5, "instruments": {"wire": {"translation_mm": )" +
         std::to_string(depth_mm) + R"(, "rotation_deg": 0}}},
    {"t_s": 3.5, "instruments": {"wire": {"translation_mm": )" +
         std::to_string(depth_mm) + R"(, "rotation_deg": 0}}}]})";
}

TEST(Session, APushIntoTheWallAboveTheThresholdIsOneEventBelowItNone) {
  const fs::path d = scratch("dead_end");
  const Scenario sc = dead_end_scenario(d);
  AssessmentSettings low;
  low.coronary_wire_force = 0.02;  // N
  // Pushed 6 mm beyond the end (at about 111.5 mm): the tip pressed on the wall, held 1 s.
  const Session pushed = run_session(d, sc, push_to(117.5), low);
  const Json& w = pushed.metrics["assessment"]["instruments"][0];
  ASSERT_EQ(w["force_events"].size(), 1u) << w.dump();
  const double peak = w["peak_tip_wall_force_n"].get<double>();
  EXPECT_GT(peak, low.coronary_wire_force);
  // It starts once the tip reaches the end (111.5 mm at 44.6 mm/s: 2.5 s) and lasts to the end.
  EXPECT_GT(w["force_events"][0]["start_s"].get<double>(), 2.0);
  EXPECT_NEAR(w["force_events"][0]["end_s"].get<double>(), pushed.end, 0.01);
  // The same push against a threshold above its peak: none.
  AssessmentSettings high;
  high.coronary_wire_force = 2.0 * peak;
  const Session again = run_session(scratch("dead_end_high"), sc, push_to(117.5), high);
  EXPECT_TRUE(again.metrics["assessment"]["instruments"][0]["force_events"].empty());
  EXPECT_NEAR(again.metrics["assessment"]["instruments"][0]["peak_tip_wall_force_n"].get<double>(),
              peak, 1e-12);
  // Stopped 20 mm short of the end, the straight wire touches nothing: no event at 0.02 N.
  const Session short_of = run_session(scratch("dead_end_short"), sc, push_to(90), low);
  EXPECT_TRUE(short_of.metrics["assessment"]["instruments"][0]["force_events"].empty());
}

}  // namespace
}  // namespace vcsim::test
