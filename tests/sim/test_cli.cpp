// `vcsim run` end to end: a short scripted scenario writes frames and metrics; bad scenarios and
// options exit with status 2 and a message naming the file and field; a target that is not
// reached ends the run with a report (status 3), never a hang.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>

#include "../common/cli_runner.h"

namespace vcsim::test {
namespace {

namespace fs = std::filesystem;

fs::path scratch(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vcsim_sim_cli_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

void write(const fs::path& p, const std::string& text) {
  std::ofstream(p) << text;
}

// A J wire pushed 120 mm in 1.2 s by a timeline, with a landmark it reaches and one it cannot.
std::string scenario(const std::string& extra_landmark, const std::string& fluoro) {
  return R"({"format": "vcsim-scenario", "version": 1, "name": "push",
    "motion": {"beating": false}, "dt_ms": 0.5, "time_limit_s": 1.4,
    "instruments": [{"name": "wire", "catalogue": "wire-035-j3-hydrophilic", "tip_segment_mm": 2}],
    "input": {"type": "timeline", "file": "timeline.json"},
    "landmarks": [{"name": "external iliac", "instrument": "wire",
                   "segment": "right_external_iliac"})" +
         extra_landmark + R"(],
    "fluoroscopy": )" +
         fluoro + "}";
}

const char* kTimeline = R"({"keyframes": [
  {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
  {"t_s": 1.2, "instruments": {"wire": {"translation_mm": 120, "rotation_deg": 0}}}]})";

TEST(RunCli, ScriptedRunWritesFramesAndMetrics) {
  const fs::path d = scratch("ok");
  write(d / "timeline.json", kTimeline);
  write(d / "s.json", scenario("", R"({"fps": 10, "follow_tip": true, "fov_mm": 250})"));
  const CliResult r = run_cli("run " + (d / "s.json").string() + " --out " + (d / "out").string() +
                              " --force-log " + (d / "force.csv").string());
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  EXPECT_NE(r.out.find("all landmarks reached"), std::string::npos) << r.out;
  // The force log: its header, then one row per step (time, depth, force, torque), the last at
  // the end of the push.
  std::ifstream log(d / "force.csv");
  std::string line, last;
  std::getline(log, line);
  EXPECT_EQ(line, "time_s,wire_depth_mm,wire_force_n,wire_torque_nmm");
  int rows = 0;
  while (std::getline(log, line)) {
    ++rows;
    last = line;
  }
  EXPECT_EQ(rows, 2400);
  ASSERT_EQ(last.rfind("1.2000,", 0), 0u) << last;
  EXPECT_NEAR(std::stod(last.substr(7)), 120.0, 0.1) << last;  // mm inserted
  int frames = 0;
  for (const auto& e : fs::directory_iterator(d / "out" / "frames"))
    frames += e.path().extension() == ".png";
  EXPECT_EQ(frames, 13);  // after the first step, then every 0.1 s through 1.2 s
  const auto j = nlohmann::json::parse(slurp(d / "out" / "metrics.json"));
  for (const char* key : {"sim_time_s", "wall_time_s", "real_time_factor", "fluoroscopy_time_s",
                          "landmarks", "instruments", "outcome", "steps"})
    EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_NEAR(j["sim_time_s"].get<double>(), 1.2, 1e-3);
  EXPECT_EQ(j["steps"].get<int>(), 2400);  // 2 kHz
  EXPECT_TRUE(j["landmarks"][0]["reached"].get<bool>());
  const auto& w = j["instruments"][0];
  EXPECT_NEAR(w["inserted_mm"].get<double>(), 120.0, 0.5);
  EXPECT_GT(w["tip_path_mm"].get<double>(), 90.0);
  EXPECT_GT(w["final_shape_mm"].size(), 10u);
}

TEST(RunCli, UnreachedTargetEndsWithAReport) {
  const fs::path d = scratch("missed");
  write(d / "timeline.json", kTimeline);
  write(d / "s.json",
        scenario(R"(, {"name": "LAD", "instrument": "wire", "segment": "lad"})", R"({"fps": 5})"));
  const CliResult r =
      run_cli("run " + (d / "s.json").string() + " --no-frames --out " + (d / "out").string());
  EXPECT_EQ(r.status, 3) << r.out << r.err;
  EXPECT_NE(r.out.find("not reached: 'LAD'"), std::string::npos) << r.out;
  const auto j = nlohmann::json::parse(slurp(d / "out" / "metrics.json"));
  EXPECT_FALSE(j["success"].get<bool>());
  EXPECT_FALSE(j["landmarks"][1]["reached"].get<bool>());
}

// An open cylinder of radius 2 mm from z = 0 to 200 mm as an STL file (mm), normals into the
// lumen: a mesh whose openings are its exits.
void write_tube_stl(const fs::path& file) {
  std::ofstream f(file);
  f << "solid tube\n";
  constexpr int kAround = 32, kAlong = 100;
  auto p = [](int a, int z) {
    const double phi = 2.0 * 3.141592653589793 * a / kAround;
    return std::to_string(2.0 * std::cos(phi)) + " " + std::to_string(2.0 * std::sin(phi)) + " " +
           std::to_string(2.0 * z);
  };
  auto tri = [&](const std::string& a, const std::string& b, const std::string& c) {
    f << "facet normal 0 0 0\nouter loop\nvertex " << a << "\nvertex " << b << "\nvertex " << c
      << "\nendloop\nendfacet\n";
  };
  for (int z = 0; z < kAlong; ++z)
    for (int a = 0; a < kAround; ++a) {
      tri(p(a, z), p(a, z + 1), p(a + 1, z));
      tri(p(a + 1, z), p(a, z + 1), p(a + 1, z + 1));
    }
  f << "endsolid tube\n";
}

// No silent escape (physics.md 6.3): a straight tube open at its start (a mesh file: a tree's cut
// ends are closed, physics.md 6.4, a mesh's openings stay open), the access 190 mm along it
// heading there, and a timeline pushing a 0.014" wire 210 mm in 2.1 s, out of the open start.
// The escape is reported once on the console and in metrics.json, and the run exits with status
// 4; with --stop-on-escape (or the scenario's stop_on_escape) it ends at that step.
TEST(RunCli, AnEscapeIsReportedAndCanStopTheRun) {
  const fs::path d = scratch("escape");
  write_tube_stl(d / "tube.stl");
  write(d / "tube.json", R"({"format": "vcsim-anatomy", "version": 1, "name": "tube",
    "coordinates": "LPS", "open_start": true, "access": {"segment": "tube", "distance_mm": 190},
    "segments": [{"name": "tube", "kind": "artery", "parent": null,
                  "points_mm": [[0, 0, 0], [0, 0, 100], [0, 0, 200]], "radius_mm": 2}]})");
  write(d / "timeline.json", R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 2.1, "instruments": {"wire": {"translation_mm": 210, "rotation_deg": 0}}}]})");
  write(d / "s.json", R"({"format": "vcsim-scenario", "version": 1, "name": "inlet",
    "anatomy": "tube.stl", "centrelines": "tube.json", "mesh_unit_mm": 1,
    "motion": {"beating": false}, "dt_ms": 0.5, "time_limit_s": 3,
    "sheath_length_mm": 10,
    "instruments": [{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 160,
                     "tip_segment_mm": 1}],
    "input": {"type": "timeline", "file": "timeline.json"}})");
  // The same scene stopping on it by the scenario's key.
  std::string keyed = slurp(d / "s.json");
  keyed.insert(keyed.find("\"time_limit_s\""), "\"stop_on_escape\": true, ");
  write(d / "keyed.json", keyed);
  const std::string where = "open end of 'tube' (start)";
  for (const int how : {0, 1, 2}) {  // --stop-on-escape, the scenario's key, neither
    const bool stop = how < 2;
    const fs::path out = d / ("out" + std::to_string(how));
    const CliResult r = run_cli("run " + (d / (how == 1 ? "keyed.json" : "s.json")).string() +
                                " --no-frames --no-report " +
                                (how == 0 ? "--stop-on-escape " : "") + "--out " + out.string());
    EXPECT_EQ(r.status, 4) << r.out << r.err;
    const std::size_t at = r.err.find("run: ESCAPE: ");
    ASSERT_NE(at, std::string::npos) << r.err;
    EXPECT_EQ(r.err.find("run: ESCAPE: ", at + 1), std::string::npos) << "reported once: " << r.err;
    EXPECT_NE(r.err.find("'wire' node", at), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(where, at), std::string::npos) << r.err;
    const auto j = nlohmann::json::parse(slurp(out / "metrics.json"));
    EXPECT_FALSE(j["success"].get<bool>());
    EXPECT_EQ(j["stopped_on_escape"].get<bool>(), stop);
    const auto& e = j["instruments"][0]["escape"];
    ASSERT_TRUE(e.is_object()) << j["instruments"][0].dump();
    EXPECT_EQ(e["where"].get<std::string>(), where);
    // Which vessel it was near: the tube, at its start (the wire left by its inlet).
    EXPECT_EQ(e["nearest_segment"].get<std::string>(), "tube");
    EXPECT_LT(e["nearest_distance_mm"].get<double>(), 1.0);
    EXPECT_NE(r.err.find("nearest vessel 'tube'", at), std::string::npos) << r.err;
    EXPECT_GT(e["distance_mm"].get<double>(), 0.17);  // the wire's radius
    // The tip passes the open start at 190 mm inserted, 1.9 s in.
    EXPECT_GT(e["first_time_s"].get<double>(), 1.9);
    EXPECT_LT(e["first_time_s"].get<double>(), 1.95);
    if (stop) {
      EXPECT_EQ(j["escape_steps"].get<int>(), 1);
      EXPECT_NEAR(j["sim_time_s"].get<double>(), e["first_time_s"].get<double>(), 1e-9);
    } else {
      EXPECT_GT(j["escape_steps"].get<int>(), 1);
      EXPECT_NEAR(j["sim_time_s"].get<double>(), 2.1, 1e-3);
    }
  }
}

// An imported mesh's own openings are its exits (issue 29, part 2): the same tube as a mesh file
// open at z = 0, with centrelines that start 20 mm inside it. The tree's open start lies 20 mm
// short of the mesh's opening, where the wire is still inside the tube; the escape is seen where
// the wire leaves the mesh, 20 mm later, and still named by the tree's end.
TEST(RunCli, AMeshsOwnOpeningIsItsExit) {
  const fs::path d = scratch("mesh-exit");
  write_tube_stl(d / "tube.stl");
  write(d / "tube.json", R"({"format": "vcsim-anatomy", "version": 1, "name": "tube",
    "coordinates": "LPS", "open_start": true, "access": {"segment": "tube", "distance_mm": 170},
    "segments": [{"name": "tube", "kind": "artery", "parent": null,
                  "points_mm": [[0, 0, 20], [0, 0, 110], [0, 0, 200]], "radius_mm": 2}]})");
  write(d / "timeline.json", R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 2.1, "instruments": {"wire": {"translation_mm": 210, "rotation_deg": 0}}}]})");
  write(d / "s.json", R"({"format": "vcsim-scenario", "version": 1, "name": "mesh-exit",
    "anatomy": "tube.stl", "centrelines": "tube.json", "mesh_unit_mm": 1,
    "motion": {"beating": false}, "dt_ms": 0.5, "time_limit_s": 2.1, "sheath_length_mm": 10,
    "instruments": [{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 160,
                     "tip_segment_mm": 1}],
    "input": {"type": "timeline", "file": "timeline.json"}})");
  const fs::path out = d / "out";
  const CliResult r =
      run_cli("run " + (d / "s.json").string() + " --no-frames --no-report --out " + out.string());
  EXPECT_EQ(r.status, 4) << r.out << r.err;
  const auto j = nlohmann::json::parse(slurp(out / "metrics.json"));
  const auto& e = j["instruments"][0]["escape"];
  ASSERT_TRUE(e.is_object()) << j["instruments"][0].dump();
  EXPECT_EQ(e["where"].get<std::string>(), "open end of 'tube' (start)");
  // The tip reaches the tree's end (z = 20 mm) at 170 mm inserted, 1.7 s in, and the mesh's
  // opening (z = 0) at 190 mm, 1.9 s in.
  EXPECT_GT(e["first_time_s"].get<double>(), 1.88);
  EXPECT_LT(e["first_time_s"].get<double>(), 1.95);
}

TEST(RunCli, BadInputExitsWithTwo) {
  const fs::path d = scratch("bad");
  write(d / "timeline.json", kTimeline);
  struct Case {
    std::string file_text, expect;
  };
  const Case cases[] = {
      {scenario("", R"({"primary_deg": 150})"), "fluoroscopy.primary_deg"},
      {scenario("", R"({"secondary_deg": -80})"), "fluoroscopy.secondary_deg"},
      {scenario("", R"({"dose": -5})"), "fluoroscopy.dose"},
      {scenario("", R"({"zoom": 2})"), "fluoroscopy.zoom"},
      {scenario(R"(, {"name": "x", "instrument": "wire", "segment": "nowhere"})", "{}"),
       "landmarks[1].segment"},
  };
  for (const Case& c : cases) {
    write(d / "s.json", c.file_text);
    const CliResult r =
        run_cli("run " + (d / "s.json").string() + " --no-frames --out " + (d / "out").string());
    EXPECT_EQ(r.status, 2) << c.expect << "\n" << r.out << r.err;
    EXPECT_NE(r.err.find(c.expect), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("s.json"), std::string::npos) << r.err;
  }
  // A missing timeline file and a missing scenario.
  write(d / "s.json", scenario("", "{}"));
  fs::remove(d / "timeline.json");
  CliResult r =
      run_cli("run " + (d / "s.json").string() + " --no-frames --out " + (d / "o").string());
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("timeline.json"), std::string::npos) << r.err;
  // A timeline that inflates a balloon in a scene without one.
  write(d / "timeline.json", R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 0.5, "balloon_pressure_atm": 8}]})");
  r = run_cli("run " + (d / "s.json").string() + " --no-frames --out " + (d / "o").string());
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("balloon_pressure_atm"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("timeline.json"), std::string::npos) << r.err;
  r = run_cli("run no_such_scenario");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("SCENARIO"), std::string::npos) << r.err;
}

// A scenario nested 100,000 deep overflowed the stack; it is now one line naming the file.
TEST(RunCli, DeeplyNestedScenarioExitsWithTwo) {
  const fs::path d = scratch("deep");
  std::string text = R"({"format": "vcsim-scenario", "version": 1, "name": )";
  text += std::string(100000, '[');
  text += std::string(100000, ']');
  text += "}";
  write(d / "s.json", text);
  const CliResult r =
      run_cli("run " + (d / "s.json").string() + " --no-frames --out " + (d / "out").string());
  EXPECT_EQ(r.status, 2) << r.err.substr(0, 300);
  EXPECT_EQ(r.err.rfind("vcsim: error: " + (d / "s.json").string() + ": json: ", 0), 0u) << r.err;
  EXPECT_NE(r.err.find("levels of nesting"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find('\n'), r.err.size() - 1) << r.err;  // one line
}

// An anatomy without a heart (it is optional) filmed: the frame writer aborted the run (exit 134,
// std::terminate from its constructor with its thread joinable). Now frames without a body.
TEST(RunCli, FramesOfAnAnatomyWithoutAHeart) {
  const fs::path d = scratch("heartless");
  fs::copy_file(fs::path(VCSIM_SCENARIOS) / ".." / "anatomy" / "bifurcation_example.json",
                d / "tree.json");
  write(d / "timeline.json", R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 0.2, "instruments": {"wire": {"translation_mm": 10, "rotation_deg": 0}}}]})");
  write(d / "s.json", R"({"format": "vcsim-scenario", "version": 1, "name": "heartless",
    "anatomy": "tree.json", "motion": {"beating": false}, "dt_ms": 0.5, "time_limit_s": 0.3,
    "instruments": [{"name": "wire", "catalogue": "wire-014-floppy", "tip_segment_mm": 2}],
    "input": {"type": "timeline", "file": "timeline.json"},
    "fluoroscopy": {"fps": 10, "fov_mm": 100}})");
  const CliResult r = run_cli("run " + (d / "s.json").string() + " --out " + (d / "out").string());
  ASSERT_EQ(r.status, 0) << r.out << r.err;
  int frames = 0;
  for (const auto& e : fs::directory_iterator(d / "out" / "frames"))
    frames += e.path().extension() == ".png";
  EXPECT_GE(frames, 3);
  EXPECT_TRUE(fs::exists(d / "out" / "metrics.json"));
}

// Reproducers from fuzzing, through the CLI: each exits 2 with one line naming the file and the
// field (1e999 exited 1 with a library message; dt_ms 1e-5 ran for days; a 42 m branch built a
// 4.7 M triangle lumen for a minute and exited 0; 1000 mm/s was capped silently).
TEST(RunCli, HostileValuesExitWithTwoNamingTheField) {
  const fs::path d = scratch("hostile");
  write(d / "timeline.json", kTimeline);
  const std::string base = scenario("", "{}");
  auto with = [&](const std::string& from, const std::string& to) {
    std::string s = base;
    const auto at = s.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return s.replace(at, from.size(), to);
  };
  std::string tree = R"({"format": "vcsim-anatomy", "version": 1, "segments": [
    {"name": "main", "points_mm": [[0, 0, 0], [0, 0, 50]], "radius_mm": 3},
    {"name": "far", "parent": "main", "points_mm": [[0, 0, 40], [42000, 0, 40]], "radius_mm": 2}]})";
  write(d / "far.json", tree);
  const struct {
    std::string scenario;
    std::string file, field;
  } cases[] = {
      {with("\"dt_ms\": 0.5", "\"dt_ms\": 1e999"), "s.json", "json"},
      {with("\"dt_ms\": 0.5", "\"dt_ms\": 1e-5"), "s.json", "dt_ms"},
      {with("\"dt_ms\": 0.5", "\"dt_ms\": 0.5, \"anatomy\": \"far.json\""), "far.json",
       "segments[1].points_mm[1]"},
  };
  for (const auto& c : cases) {
    write(d / "s.json", c.scenario);
    const CliResult r =
        run_cli("run " + (d / "s.json").string() + " --no-frames --out " + (d / "out").string());
    EXPECT_EQ(r.status, 2) << c.field << "\n" << r.out << r.err;
    // The error is the last line (a tree is read when the scene is built, after a progress line).
    ASSERT_FALSE(r.err.empty());
    const std::string last = r.err.substr(r.err.rfind('\n', r.err.size() - 2) + 1);
    EXPECT_EQ(last.rfind("vcsim: error: " + (d / c.file).string() + ": " + c.field + ": ", 0), 0u)
        << r.err;
  }
  write(d / "s.json", base);
  write(d / "timeline.json", R"({"keyframes": [{"t_s": 0, "instruments": {"wire":
    {"mode": "velocity", "translation_mm": 1000, "rotation_deg": 0}}}]})");
  const CliResult r =
      run_cli("run " + (d / "s.json").string() + " --no-frames --out " + (d / "out").string());
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("timeline.json: keyframes[0].instruments.wire.translation_mm: expected a "
                       "speed the drive follows, within +-500 mm/s"),
            std::string::npos)
      << r.err;
}

}  // namespace
}  // namespace vcsim::test
