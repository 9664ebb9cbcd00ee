// The session report end to end: `vcsim run` writes the report; `vcsim report` writes it again
// from the folder; headless Chromium opens it without errors, its plots and frames are drawn
// (checked in the page and on a screenshot); compare and CSV; bad run folders exit with 2 and
// name the file, the field and what was expected.
#include <gtest/gtest.h>
#include <stb_image.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "../common/cli_runner.h"

namespace vcsim::test {
namespace {

namespace fs = std::filesystem;

fs::path scratch(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vcsim_report_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

void write(const fs::path& p, const std::string& text) {
  std::ofstream(p) << text;
}

// A J wire pushed 120 mm in 1.2 s with the fluoroscopy pedal down and one injection, filmed at
// 10 fps: a small run folder with every file the report reads.
fs::path make_run(const std::string& name, double depth_mm = 120) {
  const fs::path d = scratch(name);
  write(d / "timeline.json", R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}, "buttons": 1},
    {"t_s": 0.6, "syringe_flow_ml_s": 4}, {"t_s": 0.9, "syringe_flow_ml_s": 0},
    {"t_s": 1.2, "instruments": {"wire": {"translation_mm": )" +
                                 std::to_string(depth_mm) + R"(, "rotation_deg": 0}}}]})");
  write(d / "s.json", R"({"format": "vcsim-scenario", "version": 1, "name": "push",
    "motion": {"beating": false}, "dt_ms": 0.5, "time_limit_s": 1.4,
    "instruments": [{"name": "wire", "catalogue": "wire-035-j3-hydrophilic", "tip_segment_mm": 2}],
    "input": {"type": "timeline", "file": "timeline.json"},
    "landmarks": [{"name": "external iliac", "instrument": "wire",
                   "segment": "right_external_iliac"}],
    "fluoroscopy": {"fps": 10, "follow_tip": true, "fov_mm": 250}})");
  const CliResult r =
      run_cli("run " + (d / "s.json").string() + " --quiet --out " + (d / "out").string());
  EXPECT_EQ(r.status, 0) << r.out << r.err;
  return d / "out";
}

TEST(ReportCli, RunWritesTheReportAndReportWritesItAgain) {
  const fs::path run = make_run("again");
  ASSERT_TRUE(fs::exists(run / "report.html"));
  ASSERT_TRUE(fs::exists(run / "series.csv"));
  ASSERT_TRUE(fs::exists(run / "frames.csv"));
  const CliResult r = run_cli("report " + run.string() + " --out " + (run / "r2.html").string());
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string html = slurp(run / "r2.html");
  EXPECT_NE(html.find("Session report: push"), std::string::npos);
  // Self-contained: no file or network reference besides data URIs.
  EXPECT_EQ(html.find("src=\"http"), std::string::npos);
  EXPECT_EQ(html.find("<script src="), std::string::npos);
  EXPECT_NE(html.find("data:image/png;base64,"), std::string::npos);
  // The metrics table holds the known figures of this run: 1.2 s of pedal, 1.2 ml of contrast.
  EXPECT_NE(html.find("<td>Fluoroscopy time</td><td class=\"num\">1.2</td>"), std::string::npos);
  EXPECT_NE(html.find("<td>Contrast volume</td><td class=\"num\">1.2</td>"), std::string::npos);
}

// Headless Chromium: `args` then the page; returns its standard output.
std::string chromium(const std::string& args, const fs::path& page) {
  const fs::path profile = fs::temp_directory_path() / "vcsim_report_chromium_profile";
  const fs::path out = fs::temp_directory_path() / "vcsim_report_chromium.out";
  const std::string cmd =
      "chromium --headless --no-sandbox --disable-gpu --user-data-dir=" + profile.string() + " " +
      args + " file://" + page.string() + " > " + out.string() + " 2>/dev/null";
  const int status = std::system(cmd.c_str());
  EXPECT_EQ(status, 0) << "chromium failed (scripts/install-deps installs it): " << cmd;
  return slurp(out);
}

TEST(ReportCli, OpensInChromiumWithoutErrorsWithItsPlotsAndFramesDrawn) {
  ASSERT_EQ(std::system("command -v chromium > /dev/null 2>&1"), 0)
      << "chromium is missing: run scripts/install-deps";
  const fs::path run = make_run("chromium");
  const fs::path page = run / "report.html";
  // The page checks itself once loaded (data/report/report.html.mustache, #selfcheck): errors
  // caught, plot canvases and frames with more than a few distinct pixel values.
  const std::string dom = chromium("--dump-dom", page);
  // The self-check's element: its opening tag (the counts as attributes) and its text (errors).
  // Plain string search: GCC 12's <regex> trips -Wmaybe-uninitialized under the sanitizers.
  const std::size_t at = dom.find("<div id=\"selfcheck\"");
  ASSERT_NE(at, std::string::npos) << dom.substr(0, 2000);
  const std::size_t gt = dom.find('>', at);
  ASSERT_NE(gt, std::string::npos);
  const std::string tag = dom.substr(at, gt - at + 1);
  const std::size_t end = dom.find('<', gt);
  const std::string text = dom.substr(gt + 1, end == std::string::npos ? 0 : end - gt - 1);
  auto attr = [&](const std::string& name) {
    const std::size_t a = tag.find(name + "=\"");
    EXPECT_NE(a, std::string::npos) << name << tag;
    if (a == std::string::npos) return -1;
    const std::size_t v = a + name.size() + 2;
    const std::size_t e = tag.find('"', v);
    const std::string digits = tag.substr(v, e == std::string::npos ? 0 : e - v);
    const bool number =
        !digits.empty() && digits.find_first_not_of("0123456789") == std::string::npos;
    EXPECT_TRUE(number) << name << tag;
    return number ? std::stoi(digits) : -1;
  };
  EXPECT_EQ(attr("data-errors"), 0) << "page errors: " << text;
  EXPECT_EQ(attr("data-plots"), 5);
  EXPECT_EQ(attr("data-plots-drawn"), 5);
  EXPECT_GE(attr("data-frames"), 1);
  EXPECT_EQ(attr("data-frames-shown"), attr("data-frames"));
  EXPECT_EQ(attr("data-paths"), 1);
  // A screenshot of the page is not blank: many grey levels, a good part of it not white.
  const fs::path shot = run / "shot.png";
  chromium("--window-size=1200,3000 --screenshot=" + shot.string(), page);
  int w = 0, h = 0, n = 0;
  unsigned char* px = stbi_load(shot.string().c_str(), &w, &h, &n, 3);
  ASSERT_NE(px, nullptr) << "no screenshot at " << shot;
  EXPECT_EQ(w, 1200);
  std::size_t not_white = 0;
  bool level[256] = {};
  for (int k = 0; k < w * h; ++k) {
    const unsigned char* p = px + 3 * k;
    not_white += (p[0] < 240 || p[1] < 240 || p[2] < 240) ? 1 : 0;
    level[(p[0] + p[1] + p[2]) / 3] = true;
  }
  stbi_image_free(px);
  int levels = 0;
  for (bool l : level) levels += l ? 1 : 0;
  EXPECT_GT(static_cast<double>(not_white) / (w * h), 0.05);
  EXPECT_GT(levels, 100);
}

TEST(ReportCli, ARunWhosePageCannotBeMadeKeepsItsStatusAndSaysSo) {
  const fs::path d = make_run("no_template");
  // Written again from the run's scenario, this time with the page template missing.
  const CliResult r = run_cli(
      "run " + (d.parent_path() / "s.json").string() + " --quiet --no-frames --out " + d.string(),
      "VCSIM_REPORT_TEMPLATE=/nonexistent/report.html.mustache ");
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("report not written: /nonexistent/report.html.mustache: file: expected"),
            std::string::npos)
      << r.err;
  EXPECT_TRUE(fs::exists(d / "metrics.json"));
}

TEST(ReportCli, CompareAndCsvListEveryRun) {
  const fs::path a = make_run("cmp_a", 100), b = make_run("cmp_b", 120);
  const fs::path out = scratch("cmp");
  CliResult r = run_cli("report compare " + a.string() + " " + b.string() + " --out " +
                        (out / "c.html").string());
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string html = slurp(out / "c.html");
  EXPECT_NE(html.find("Progress over sessions"), std::string::npos);
  r = run_cli("report csv " + a.string() + " " + b.string() + " --out " + (out / "m.csv").string());
  ASSERT_EQ(r.status, 0) << r.err;
  std::ifstream csv(out / "m.csv");
  std::string header, l1, l2, extra;
  std::getline(csv, header);
  std::getline(csv, l1);
  std::getline(csv, l2);
  EXPECT_FALSE(std::getline(csv, extra));
  EXPECT_EQ(header.rfind("run,scenario,input,procedure_time_s,fluoroscopy_time_s", 0), 0u)
      << header;
  EXPECT_EQ(l1.rfind(a.string() + ",push,timeline,", 0), 0u) << l1;
  EXPECT_EQ(l2.rfind(b.string() + ",push,timeline,", 0), 0u) << l2;
}

// Bad run folders: each an exit status of 2 and a message naming what is wrong.
void expect_refused(const std::string& args, const std::string& needle) {
  const CliResult r = run_cli(args);
  EXPECT_EQ(r.status, 2) << args << "\n" << r.out << r.err;
  EXPECT_NE(r.err.find(needle), std::string::npos) << args << "\n" << r.err;
}

TEST(ReportCli, BadRunFoldersAreRefusedWithExitStatusTwo) {
  const fs::path run = make_run("bad_base");
  const std::string metrics = slurp(run / "metrics.json");
  const fs::path d = scratch("bad");
  // Missing folder, folder without metrics.json
  expect_refused("report " + (d / "nowhere").string(), "expected the folder of a run");
  fs::create_directories(d / "empty");
  expect_refused("report " + (d / "empty").string(), "metrics.json: expected a run folder");
  // Corrupt metrics.json
  auto variant = [&](const std::string& name, const std::string& text) {
    const fs::path v = d / name;
    fs::create_directories(v);
    fs::copy(run / "series.csv", v / "series.csv", fs::copy_options::overwrite_existing);
    write(v / "metrics.json", text);
    return v;
  };
  expect_refused("report " + variant("corrupt", metrics.substr(0, metrics.size() / 2)).string(),
                 "metrics.json: json: ");
  // Another schema: version 1 had no format; a future version 3.
  nlohmann::json j = nlohmann::json::parse(metrics);
  nlohmann::json v1 = j;
  v1.erase("format");
  v1.erase("version");
  v1.erase("assessment");
  expect_refused("report " + variant("v1", v1.dump()).string(),
                 "metrics.json: format: expected \"vcsim-metrics\"");
  nlohmann::json v3 = j;
  v3["version"] = 3;
  expect_refused("report " + variant("v3", v3.dump()).string(),
                 "metrics.json: version: expected 2, got 3");
  nlohmann::json noa = j;
  noa.erase("assessment");
  expect_refused("report " + variant("noassess", noa.dump()).string(),
                 "metrics.json: assessment: expected");
  nlohmann::json badinst = j;
  badinst["assessment"]["instruments"][0] = 7;
  expect_refused("report " + variant("badinst", badinst.dump()).string(),
                 "assessment.instruments[0]: expected an object");
  nlohmann::json noview = j;
  noview["assessment"].erase("view");
  expect_refused("report " + variant("noview", noview.dump()).string(),
                 "assessment.view: expected an object");
  nlohmann::json badsum = j;
  badsum["assessment"]["summary"]["fluoroscopy_time_s"] = "long";
  expect_refused("report " + variant("badsum", badsum.dump()).string(),
                 "assessment.summary.fluoroscopy_time_s: expected a number or null");
  // Corrupt and missing series.csv
  const fs::path cs = variant("series", metrics);
  write(cs / "series.csv", slurp(run / "series.csv") + "1.5,x,,\n");
  expect_refused("report " + cs.string(), "series.csv: line ");
  fs::remove(cs / "series.csv");
  expect_refused("report " + cs.string(), "series.csv: file: expected series.csv");
  // compare and csv check every folder the same way
  expect_refused("report compare " + run.string() + " " + (d / "empty").string(),
                 "metrics.json: expected a run folder");
  expect_refused("report csv " + (d / "v1").string(), "format: expected \"vcsim-metrics\"");
}

// frames.csv with column `col` of every frame set to `value` (`col` < 0: the first five columns
// only, as runs wrote it before the poses were recorded).
std::string frames_with(const std::string& csv, int col, const std::string& value) {
  std::istringstream in(csv);
  std::ostringstream out;
  std::string line;
  for (int n = 0; std::getline(in, line); ++n) {
    std::vector<std::string> cells;
    std::stringstream ss(line);
    for (std::string c; std::getline(ss, c, ',');) cells.push_back(c);
    if (col < 0) cells.resize(5);
    if (col >= 0 && n > 0) cells.at(static_cast<std::size_t>(col)) = value;
    for (std::size_t k = 0; k < cells.size(); ++k) out << (k ? "," : "") << cells[k];
    out << '\n';
  }
  return out.str();
}

// The points of the report's tip path (the angiogram's overlay).
std::string path_points(const fs::path& html_file) {
  const std::string html = slurp(html_file);
  const std::size_t a = html.find("<polyline");
  EXPECT_NE(a, std::string::npos);
  const std::size_t p = html.find("points='", a);
  EXPECT_NE(p, std::string::npos);
  if (a == std::string::npos || p == std::string::npos) return {};
  return html.substr(p + 8, html.find('\'', p + 8) - p - 8);
}

// A trainee turns and zooms the C-arm: each frame keeps the pose it was made through, and the
// report draws the tip's path over a frame through that frame's pose. A run written before the
// poses were recorded (the pan alone) is still read; a pose the C-arm cannot take is refused.
TEST(ReportCli, TheTipPathIsDrawnThroughTheFramesOwnCArmPose) {
  const fs::path run = make_run("pose");
  const std::string csv = slurp(run / "frames.csv");
  EXPECT_EQ(csv.substr(0, csv.find('\n')),
            "frame,time_s,isocentre_x_mm,isocentre_y_mm,isocentre_z_mm,primary_deg,secondary_deg,"
            "sid_mm,sod_mm,fov_mm");
  // The scenario's field (250 mm) in every frame.
  EXPECT_EQ(frames_with(csv, 9, "250.000"), csv);
  auto report = [&](const std::string& frames, const std::string& name) {
    write(run / "frames.csv", frames);
    const CliResult r = run_cli("report " + run.string() + " --out " + (run / name).string());
    EXPECT_EQ(r.status, 0) << r.err;
    return path_points(run / name);
  };
  const std::string as_run = report(csv, "as_run.html");
  ASSERT_FALSE(as_run.empty());
  EXPECT_EQ(report(frames_with(csv, -1, ""), "pan_only.html"), as_run);
  const std::string lao = report(frames_with(csv, 5, "60.000"), "lao.html");
  const std::string zoomed = report(frames_with(csv, 9, "120.000"), "zoomed.html");
  EXPECT_NE(lao, as_run);
  EXPECT_NE(zoomed, as_run);
  EXPECT_NE(zoomed, lao);
  write(run / "frames.csv", frames_with(csv, 5, "500"));
  expect_refused("report " + run.string() + " --out " + (run / "bad.html").string(),
                 "frames.csv frame 0: primary_deg");
  write(run / "frames.csv", frames_with(csv, 7, ""));
  expect_refused("report " + run.string() + " --out " + (run / "bad.html").string(),
                 "frames.csv frame 0: sid_mm: expected a number");
}

}  // namespace
}  // namespace vcsim::test
