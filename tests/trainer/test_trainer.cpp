// The trainer (apps/trainer, `vcsim trainer`): its controls without a window, its scripts, and
// the app end to end under a virtual X server (ctest runs this binary under `xvfb-run -a`): a
// scripted sequence of input events through the keyboard's path pushes a wire, presses the pedal,
// injects and turns the C-arm; the window's screenshots are checked; the session's recording
// replays through `vcsim run --replay` to the same state hash; the app survives a device that
// connects and drops, a resize, a close during an injection, and bad input. Nothing asserts on
// timing: a loaded machine (or the sanitizer build) only makes the sessions coarser.
#include <gtest/gtest.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <stb_image.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <thread>

#include "../common/cli_runner.h"
#include "../common/igtl_client.h"
#include "controls.h"
#include "film.h"
#include "physics.h"
#include "script.h"
#include "vcsim/units.h"

namespace vcsim::test {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using trainer::Controls;

const bool kIgnoreSigpipe = (std::signal(SIGPIPE, SIG_IGN), true);

fs::path scratch(const std::string& name) {
  // Per process: a release and a sanitizer run, or two checkouts, may run at once.
  std::string dir = "vcsim_trainer_";
  dir += std::to_string(::getpid());
  dir += "_";
  dir += name;
  const fs::path d = fs::temp_directory_path() / dir;
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// A scratch folder removed when its test passes (kept to look at when it fails).
struct Scratch {
  fs::path d;
  explicit Scratch(const std::string& name) : d(scratch(name)) {}
  ~Scratch() {
    if (!::testing::Test::HasFailure()) {
      std::error_code ec;
      fs::remove_all(d, ec);
    }
  }
};

nlohmann::json read_json(const fs::path& p) {
  std::ifstream in(p);
  return nlohmann::json::parse(in);
}

Scenario default_scenario() {
  return load_scenario(fs::path(VCSIM_SCENARIOS) / "default.json");
}

std::vector<std::string> names_of(const Scenario& sc) {
  std::vector<std::string> n;
  for (const auto& si : sc.instruments) n.push_back(si.name);
  return n;
}

// ---- the controls, without a window ----

TEST(TrainerControls, AHeldKeyPushesTheSelectedInstrumentFasterTheLongerItIsHeld) {
  const Scenario sc = default_scenario();
  Controls c(names_of(sc), sc);
  EXPECT_EQ(c.name(c.selected()), "j_wire");  // the wire leads out of its guide
  const double t0 = 1e6;
  c.key(GLFW_KEY_W, GLFW_PRESS, 0, t0);
  const int s = c.selected();
  const double v0 = c.commands().drive[static_cast<std::size_t>(s)].translation;
  EXPECT_GT(v0, 0.0);
  EXPECT_EQ(c.commands().seq, 1u);
  c.update(t0 + 1.0e6);
  const double v1 = c.commands().drive[static_cast<std::size_t>(s)].translation;
  EXPECT_GT(v1, v0);
  c.update(t0 + 5.0e6);
  EXPECT_NEAR(c.commands().drive[static_cast<std::size_t>(s)].translation, 50e-3, 1e-12);
  for (std::size_t i = 0; i < c.commands().drive.size(); ++i) {
    if (static_cast<int>(i) != s) {
      EXPECT_EQ(c.commands().drive[i].translation, 0.0);
    }
  }
  c.key(GLFW_KEY_W, GLFW_RELEASE, 0, t0 + 6e6);
  EXPECT_EQ(c.commands().drive[static_cast<std::size_t>(s)].translation, 0.0);
  EXPECT_EQ(c.commands().seq, 2u);  // press and release are events; the ramp is not
}

// After an exchange the controls follow the scene: an added instrument is selected, a kept one
// keeps its selection by name, every hand lets go (nothing keeps moving into the new scene), and
// Enter inflates to the stent system's nominal pressure.
TEST(TrainerControls, FollowTheSceneAcrossAnExchange) {
  const Scenario sc = default_scenario();
  Controls c(names_of(sc), sc);
  const double t0 = 1e6;
  c.key(GLFW_KEY_W, GLFW_PRESS, 0, t0);  // pushing j_wire
  std::vector<std::string> next = names_of(sc);
  next.push_back("balloon-sc-2.5x15");
  c.set_instruments(next, t0 + 1e5);
  ASSERT_EQ(c.num_instruments(), static_cast<int>(next.size()));
  EXPECT_EQ(c.name(c.selected()), "balloon-sc-2.5x15") << "the added instrument";
  ASSERT_EQ(c.commands().drive.size(), next.size());
  c.select(1, t0 + 2e5);
  const std::string kept = c.name(1);
  next.pop_back();
  next.erase(next.begin());  // and the first removed
  c.set_instruments(next, t0 + 3e5);
  EXPECT_EQ(c.name(c.selected()), kept) << "kept by its name";
  c.key(GLFW_KEY_W, GLFW_RELEASE, 0, t0 + 4e5);
  for (const DriveCommand& d : c.commands().drive) EXPECT_EQ(d.translation, 0.0);
  c.set_deploy_pressure(12.0 * kAtm);
  c.key(GLFW_KEY_ENTER, GLFW_PRESS, 0, t0 + 5e5);
  EXPECT_DOUBLE_EQ(c.commands().balloon_pressure, 12.0 * kAtm);
}

TEST(TrainerControls, PedalsSyringeSelectionAndTheCArm) {
  const Scenario sc = default_scenario();
  Controls c(names_of(sc), sc);
  c.key(GLFW_KEY_SPACE, GLFW_PRESS, 0, 0.0);
  c.key(GLFW_KEY_E, GLFW_PRESS, 0, 0.0);
  EXPECT_EQ(c.commands().buttons & trainer::kButtonFluoro, trainer::kButtonFluoro);
  EXPECT_GT(c.commands().syringe_flow, 0.0);
  c.key(GLFW_KEY_E, GLFW_RELEASE, 0, 0.0);
  EXPECT_EQ(c.commands().syringe_flow, 0.0);
  c.key(GLFW_KEY_1, GLFW_PRESS, 0, 0.0);
  EXPECT_EQ(c.selected(), 0);
  c.key(GLFW_KEY_TAB, GLFW_PRESS, 0, 0.0);
  EXPECT_EQ(c.selected(), 1);
  const double start = sc.fluoro.primary_deg;  // the C-arm starts at the scenario's angles
  EXPECT_DOUBLE_EQ(c.primary_deg(), start);
  c.update(1e6);
  c.key(GLFW_KEY_L, GLFW_PRESS, 0, 1e6);
  for (int k = 1; k <= 10; ++k) c.update(1e6 + 5e4 * k);  // frames of 50 ms
  EXPECT_NEAR(c.primary_deg(), start + 10.0, 1e-9);       // 20 deg/s for 0.5 s
  c.key(GLFW_KEY_F1, GLFW_PRESS, 0, 2e6);
  EXPECT_EQ(c.primary_deg(), 0.0);
  EXPECT_EQ(c.secondary_deg(), 0.0);
  const double fov = c.fov();
  c.key(GLFW_KEY_EQUAL, GLFW_PRESS, 0, 2e6);
  EXPECT_LT(c.fov(), fov);
  // A gamepad's left stick drives the selected instrument.
  trainer::GamepadState pad;
  pad.axes[GLFW_GAMEPAD_AXIS_LEFT_Y] = -1.0f;
  c.gamepad(pad, 3e6);
  EXPECT_NEAR(c.commands().drive[1].translation, 50e-3, 1e-12);
  c.gamepad_lost(3.1e6);
  EXPECT_EQ(c.commands().drive[1].translation, 0.0);
  // The window losing the keyboard lets every key go: nothing keeps moving, the beam goes off.
  c.key(GLFW_KEY_W, GLFW_PRESS, 0, 4e6);
  c.key(GLFW_KEY_SPACE, GLFW_PRESS, 0, 4e6);
  c.release_all(4.1e6);
  EXPECT_EQ(c.commands().drive[1].translation, 0.0);
  EXPECT_EQ(c.commands().buttons, 0u);
}

// What a rewind and a restart rely on: a state restored after other steps (here, the wire pushed
// in) steps on exactly as a fresh simulator would, also for instruments parked outside (whose
// contact lists the solver does not refresh).
TEST(TrainerPhysics, ARestoredStateStepsOnAsAFreshOne) {
  Scenario sc = default_scenario();
  sc.autopilot.clear();
  Simulator fresh(sc), used(fresh.shared_model());
  const SimState initial = used.snapshot();
  StepCommands c;
  c.reset(static_cast<std::size_t>(fresh.num_instruments()));
  c.drive[1].translation = 0.02;
  for (int k = 0; k < 600; ++k) used.step(c);
  used.restore(initial);
  c.drive[1].translation = -0.01;  // pulling at the sheath: parked
  for (int k = 0; k < 50; ++k) {
    fresh.step(c);
    used.step(c);
    ASSERT_EQ(fresh.state().hash(), used.state().hash()) << "step " << k;
  }
}

// The session's film without a window: one image a second plus key moments, a rewind drops the
// frames after it, and the files left are numbered in order as `vcsim run`'s film.
TEST(TrainerFilm, KeepsOneImageASecondAndKeyMomentsAndGoesBackWithARewind) {
  const Scratch scratch_dir("film");
  const fs::path dir = scratch_dir.d / "frames";
  fs::create_directories(dir);
  std::ofstream(dir / "frame_00007.png") << "an earlier session's";
  const int n = 8;
  auto image = [&](int shade) {
    return std::vector<std::uint8_t>(static_cast<std::size_t>(n) * n,
                                     static_cast<std::uint8_t>(shade));
  };
  std::vector<double> times;
  std::vector<CArmPose> poses;
  auto pose = [](const Vec3& pan, double primary_deg = 0.0) {
    CArmPose p;
    p.isocentre = pan;
    p.primary_deg = primary_deg;
    return p;
  };
  {
    trainer::SessionFilm film(dir, n);
    EXPECT_FALSE(fs::exists(dir / "frame_00007.png"));
    // Images shown every 0.1 s for 3 s: kept at 0 and 1.0 s (a second apart), at the key moment
    // 1.4 s, and at 2.4 s (a second after it).
    for (int k = 0; k <= 30; ++k) {
      const double t = 0.1 * k;
      if (film.due(t, k == 14)) film.keep(image(k), t, pose(Vec3(0.001 * k, 0, 0), 2.0 * k));
    }
    EXPECT_EQ(film.kept(), 4);
    EXPECT_NEAR(film.last_time(), 2.4, 1e-9);
    film.keep(image(99), 2.4, pose(Vec3::Zero()));  // the same state shown again: kept once
    EXPECT_EQ(film.kept(), 4);
    film.rewound(1.2);  // the state back at 1.2 s: 1.4 and 2.4 dropped
    EXPECT_EQ(film.kept(), 2);
    film.keep(image(200), 1.3, pose(Vec3(0, 0.002, 0), -30.0));
    film.finish(times, poses);
  }
  ASSERT_EQ(times.size(), 3u);
  EXPECT_NEAR(times[0], 0.0, 1e-9);
  EXPECT_NEAR(times[1], 1.0, 1e-9);
  EXPECT_NEAR(times[2], 1.3, 1e-9);
  EXPECT_NEAR(poses[1].isocentre.x(), 0.010, 1e-12);
  EXPECT_NEAR(poses[2].isocentre.y(), 0.002, 1e-12);
  EXPECT_EQ(poses[1].primary_deg, 20.0);  // each frame keeps the C-arm it was made through
  EXPECT_EQ(poses[2].primary_deg, -30.0);
  for (std::size_t k = 0; k < times.size(); ++k) {
    char name[32];
    std::snprintf(name, sizeof name, "frame_%05zu.png", k);
    int w = 0, h = 0, c = 0;
    unsigned char* px = stbi_load((dir / name).string().c_str(), &w, &h, &c, 1);
    ASSERT_NE(px, nullptr) << name;
    EXPECT_EQ(w, n);
    // The second file is the image of 1.0 s (shade 10); the third the one kept after the rewind.
    EXPECT_EQ(static_cast<int>(px[0]), k == 2 ? 200 : 10 * static_cast<int>(k));
    stbi_image_free(px);
  }
  std::size_t files = 0;
  for (const auto& e : fs::directory_iterator(dir)) files += e.path().extension() == ".png";
  EXPECT_EQ(files, times.size());
}

TEST(TrainerScript, ABadScriptIsAnErrorNamingTheField) {
  EXPECT_EQ(
      trainer::parse_script(R"({"events": [{"t_s": 1, "key": "W", "action": "press"}]})", "s.json")
          .size(),
      1u);
  try {
    trainer::parse_script(R"({"events": [{"t_s": 1, "key": "NOPE", "action": "press"}]})",
                          "s.json");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "events[0].key");
  }
  EXPECT_THROW(
      trainer::parse_script(R"({"events": [{"t_s": 1, "key": "W", "action": "hold"}]})", "s.json"),
      InputError);
}

// ---- the app under a virtual X server ----

struct Image {
  int w = 0, h = 0;
  std::vector<unsigned char> rgb;
  bool load(const fs::path& p) {
    int n = 0;
    unsigned char* d = stbi_load(p.string().c_str(), &w, &h, &n, 3);
    if (!d) return false;
    rgb.assign(d, d + static_cast<std::size_t>(w) * h * 3);
    stbi_image_free(d);
    return true;
  }
  const unsigned char* at(int x, int y) const {
    return rgb.data() + (static_cast<std::size_t>(y) * w + x) * 3;
  }
};

// Means of 16 x 16 blocks of the middle of the fluoroscopy panel (grey), which averages the
// quantum noise away.
std::vector<double> block_means(const Image& im, const nlohmann::json& overlay) {
  const int x0 = overlay["fluoro_panel"][0].get<int>(), y0 = overlay["fluoro_panel"][1].get<int>();
  const int side = overlay["fluoro_panel"][2].get<int>();
  std::vector<double> m;
  for (int by = side / 4; by + 16 <= 3 * side / 4; by += 16)
    for (int bx = side / 4; bx + 16 <= 3 * side / 4; bx += 16) {
      double s = 0;
      for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) s += im.at(x0 + bx + x, y0 + by + y)[0];
      m.push_back(s / 256.0);
    }
  return m;
}

// Amber pixels (the overlay's fluoroscopy clock) in the top right corner of the panel.
std::vector<int> amber_pixels(const Image& im, const nlohmann::json& overlay) {
  const int x0 = overlay["fluoro_panel"][0].get<int>(), y0 = overlay["fluoro_panel"][1].get<int>();
  const int side = overlay["fluoro_panel"][2].get<int>();
  std::vector<int> px;
  for (int y = y0 + 4; y < y0 + 28; ++y)
    for (int x = x0 + side - 140; x < x0 + side - 4; ++x) {
      const unsigned char* p = im.at(x, y);
      if (p[0] > 180 && p[2] < 140 && p[0] > p[2] + 80) px.push_back((y - y0) * 10000 + (x - x0));
    }
  return px;
}

std::vector<unsigned char> from_base64(const std::string& text) {
  auto value = [](char c) -> int {
    if (c >= 'A' && c <= 'Z') return c - 'A';
    if (c >= 'a' && c <= 'z') return c - 'a' + 26;
    if (c >= '0' && c <= '9') return c - '0' + 52;
    if (c == '+') return 62;
    if (c == '/') return 63;
    return -1;
  };
  std::vector<unsigned char> out;
  unsigned bits = 0;
  int have = 0;
  for (char c : text) {
    const int v = value(c);
    if (v < 0) continue;  // '=' padding
    bits = (bits << 6) | static_cast<unsigned>(v);
    have += 6;
    if (have >= 8) {
      have -= 8;
      out.push_back(static_cast<unsigned char>((bits >> have) & 0xffu));
    }
  }
  return out;
}

// The key frames of a session report (report.html's "Key fluoroscopy frames"): the PNGs of its
// data URIs, decoded to grey pixels.
std::vector<std::vector<unsigned char>> report_key_frames(const fs::path& page, int& size) {
  const std::string html = slurp(page);
  std::vector<std::vector<unsigned char>> frames;
  const std::size_t section = html.find("id=\"frames-section\"");
  if (section == std::string::npos) return frames;
  const std::size_t end = html.find("<h2", section + 1);
  const std::string key = "src=\"data:image/png;base64,";
  for (std::size_t at = html.find(key, section); at != std::string::npos && at < end;
       at = html.find(key, at + 1)) {
    const std::size_t from = at + key.size(), to = html.find('"', from);
    const std::vector<unsigned char> png = from_base64(html.substr(from, to - from));
    int w = 0, h = 0, c = 0;
    unsigned char* px =
        stbi_load_from_memory(png.data(), static_cast<int>(png.size()), &w, &h, &c, 1);
    if (!px) continue;
    size = w;
    frames.emplace_back(px, px + static_cast<std::size_t>(w) * h);
    stbi_image_free(px);
  }
  return frames;
}

std::string replay_hash(const fs::path& dir, const std::string& scenario = "default") {
  const fs::path out = dir / "replay";
  const CliResult r = run_cli("run " + scenario + " --replay " + (dir / "recording.json").string() +
                              " --no-frames --quiet --out " + out.string());
  EXPECT_TRUE(r.status == 0 || r.status == 3) << r.err;
  EXPECT_NE(r.out.find("state hash equal to the recording's"), std::string::npos) << r.out;
  if (!fs::exists(out / "metrics.json")) return "missing";
  return read_json(out / "metrics.json")["state_hash"].get<std::string>();
}

TEST(TrainerApp, AScriptedSessionDrivesTheWireAndItsRecordingReplaysToTheSameState) {
  const Scratch scratch_dir("session");
  const fs::path& d = scratch_dir.d;
  // The spider view (F2, LAO 45 CAU 30), the pedal, a push of the J wire, an injection, then the
  // C-arm to AP.
  std::ofstream(d / "s.json") << R"({"events": [
    {"t_s": 0.1, "key": "F2", "action": "press"},
    {"t_s": 0.2, "key": "F2", "action": "release"},
    {"t_s": 0.3, "key": "SPACE", "action": "press"},
    {"t_s": 0.4, "key": "W", "action": "press"},
    {"t_s": 1.6, "key": "W", "action": "release"},
    {"t_s": 1.7, "key": "E", "action": "press"},
    {"t_s": 2.2, "screenshot": "lao.png"},
    {"t_s": 2.6, "key": "E", "action": "release"},
    {"t_s": 2.7, "key": "F1", "action": "press"},
    {"t_s": 2.8, "key": "F1", "action": "release"},
    {"t_s": 3.4, "screenshot": "ap.png"},
    {"t_s": 3.5, "key": "SPACE", "action": "release"},
    {"t_s": 3.9, "screenshot": "held.png"},
    {"t_s": 4.0, "close": true}]})";
  const CliResult r =
      run_cli("trainer --script " + (d / "s.json").string() + " --out " + d.string());
  ASSERT_EQ(r.status, 0) << r.err;
  for (const char* f : {"lao.png", "ap.png", "held.png", "recording.json", "metrics.json"})
    ASSERT_TRUE(fs::exists(d / f)) << f;
  const nlohmann::json lao = read_json(d / "lao.json"), ap = read_json(d / "ap.json"),
                       held = read_json(d / "held.json");
  Image a, b, c;
  ASSERT_TRUE(a.load(d / "lao.png"));
  ASSERT_TRUE(b.load(d / "ap.png"));
  ASSERT_TRUE(c.load(d / "held.png"));
  EXPECT_EQ(a.w, 1280);
  EXPECT_EQ(a.h, 800);
  // The overlay's values, as it drew them: angles, the fluoroscopy clock running, the wire in.
  EXPECT_EQ(lao["angles"].get<std::string>().substr(0, 3), "LAO");
  EXPECT_EQ(ap["primary_deg"].get<double>(), 0.0);
  EXPECT_GT(lao["fluoroscopy_time_s"].get<double>(), 0.0);
  EXPECT_GT(ap["fluoroscopy_time_s"].get<double>(), lao["fluoroscopy_time_s"].get<double>());
  EXPECT_TRUE(held["image_held"].get<bool>());
  EXPECT_GT(ap["contrast_used_ml"].get<double>(), 0.0);
  EXPECT_GT(ap["instruments"][1]["depth_mm"].get<double>(), 1.0);
  // The fluoroscopy panel is not blank, and the C-arm's turn changed it.
  const std::vector<double> ma = block_means(a, lao), mb = block_means(b, ap);
  ASSERT_EQ(ma.size(), mb.size());
  ASSERT_FALSE(ma.empty());
  double mean = 0, var = 0, diff = 0;
  for (double v : ma) mean += v / static_cast<double>(ma.size());
  for (double v : ma) var += (v - mean) * (v - mean) / static_cast<double>(ma.size());
  for (std::size_t k = 0; k < ma.size(); ++k)
    diff += std::abs(ma[k] - mb[k]) / static_cast<double>(ma.size());
  EXPECT_GT(mean, 15.0);
  EXPECT_LT(mean, 240.0);
  EXPECT_GT(std::sqrt(var), 3.0) << "a flat panel";
  EXPECT_GT(diff, 4.0) << "LAO 45 CAU 30 and AP look the same";
  // The overlay's fluoroscopy clock is drawn (amber text) and reads differently in the two.
  const std::vector<int> ta = amber_pixels(a, lao), tb = amber_pixels(b, ap);
  EXPECT_GT(ta.size(), 20u);
  EXPECT_GT(tb.size(), 20u);
  EXPECT_NE(ta, tb);
  // The session's metrics and its replay: the same final state.
  const nlohmann::json m = read_json(d / "metrics.json");
  EXPECT_EQ(m["input"]["type"], "trainer");
  EXPECT_GT(m["fluoroscopy_time_s"].get<double>(), 0.0);
  // The session's assessment counts the same pedal time, and its report is written
  // (docs/assessment.md).
  EXPECT_EQ(m["assessment"]["beam"]["source"], "pedals");
  EXPECT_NEAR(m["assessment"]["beam"]["fluoroscopy_time_s"].get<double>(),
              m["fluoroscopy_time_s"].get<double>(), 1e-6);
  EXPECT_GT(m["assessment"]["contrast"]["volume_ml"].get<double>(), 0.0);
  EXPECT_TRUE(fs::exists(d / "report.html"));
  EXPECT_GT(m["contrast_volume_ml"].get<double>(), 0.0);
  // The session's film (docs/trainer.md): images shown, one a second of simulated time and at
  // key moments, as frames/ and frames.csv in the format of `vcsim run`'s film.
  const int filmed = m["trainer"]["film_frames"].get<int>();
  EXPECT_GE(filmed, 3);  // the first image shown, a second later, the injection's end, the held
  const std::string csv = slurp(d / "frames.csv");
  std::istringstream lines(csv);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line,
            "frame,time_s,isocentre_x_mm,isocentre_y_mm,isocentre_z_mm,primary_deg,secondary_deg,"
            "sid_mm,sod_mm,fov_mm");
  std::vector<double> times;
  std::set<std::pair<double, double>> angles;  // the C-arm's (primary, secondary) of the frames
  while (std::getline(lines, line)) {
    int k = -1;
    double t = 0, x = 0, y = 0, z = 0, pa = 0, sa = 0, sid = 0, sod = 0, fov = 0;
    ASSERT_EQ(std::sscanf(line.c_str(), "%d,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &k, &t, &x, &y,
                          &z, &pa, &sa, &sid, &sod, &fov),
              10)
        << line;
    angles.insert({pa, sa});
    EXPECT_EQ(k, static_cast<int>(times.size()));
    if (!times.empty()) {
      EXPECT_GT(t, times.back());
    }
    char name[32];
    std::snprintf(name, sizeof name, "frame_%05d.png", k);
    EXPECT_TRUE(fs::exists(d / "frames" / name)) << name;
    times.push_back(t);
  }
  EXPECT_EQ(static_cast<int>(times.size()), filmed);
  // The film kept the views the trainee turned to: the oblique one and AP at the end.
  EXPECT_GE(angles.size(), 2u);
  EXPECT_EQ(angles.count({0.0, 0.0}), 1u);
  // A key moment: the image shown when the injection ended (the angiograms the report picks).
  ASSERT_FALSE(m["assessment"]["contrast"]["injections"].empty());
  const double injected = m["assessment"]["contrast"]["injections"][0]["end_s"].get<double>();
  EXPECT_TRUE(std::any_of(times.begin(), times.end(),
                          [&](double t) { return t >= injected - 1e-3 && t <= injected + 0.5; }))
      << "no frame at the injection's end, " << injected << " s";
  // The report built from the session's folder shows key frames, and they are not blank.
  int size = 0;
  const auto keys = report_key_frames(d / "report.html", size);
  ASSERT_FALSE(keys.empty()) << "no key frames in the session's report";
  EXPECT_EQ(size, 512);
  for (const auto& px : keys) {
    double key_mean = 0, key_var = 0;
    bool level[256] = {};
    for (unsigned char v : px) {
      key_mean += v / static_cast<double>(px.size());
      level[v] = true;
    }
    for (unsigned char v : px)
      key_var += (v - key_mean) * (v - key_mean) / static_cast<double>(px.size());
    EXPECT_GT(key_mean, 15.0);
    EXPECT_LT(key_mean, 240.0);
    EXPECT_GT(std::sqrt(key_var), 3.0) << "a flat key frame";
    EXPECT_GT(std::count(std::begin(level), std::end(level), true), 20);
  }
  EXPECT_EQ(replay_hash(d), m["state_hash"].get<std::string>());
}

TEST(TrainerApp, CinePauseResizeRewindAndTheEducatorsViewKeepTheSessionReplayable) {
  const Scratch scratch_dir("resize");
  const fs::path& d = scratch_dir.d;
  std::ofstream(d / "s.json") << R"({"events": [
    {"t_s": 0.2, "key": "C", "action": "press"},
    {"t_s": 1.0, "key": "C", "action": "release"},
    {"t_s": 1.1, "key": "V", "action": "press"},
    {"t_s": 1.15, "key": "V", "action": "release"},
    {"t_s": 1.3, "screenshot": "review.png"},
    {"t_s": 1.35, "key": "P", "action": "press"},
    {"t_s": 1.4, "key": "P", "action": "release"},
    {"t_s": 1.6, "screenshot": "paused.png"},
    {"t_s": 1.7, "key": "P", "action": "press"},
    {"t_s": 1.75, "key": "P", "action": "release"},
    {"t_s": 1.8, "key": "SPACE", "action": "press"},
    {"t_s": 1.9, "key": "W", "action": "press"},
    {"t_s": 3.0, "key": "W", "action": "release"},
    {"t_s": 3.1, "resize": [900, 600]},
    {"t_s": 3.2, "key": "G", "action": "press"},
    {"t_s": 3.25, "key": "G", "action": "release"},
    {"t_s": 3.7, "screenshot": "small.png"},
    {"t_s": 3.8, "key": "B", "action": "press"},
    {"t_s": 3.85, "key": "B", "action": "release"},
    {"t_s": 4.0, "key": "S", "action": "press"},
    {"t_s": 4.4, "key": "S", "action": "release"},
    {"t_s": 4.5, "key": "S", "action": "press", "mods": ["ctrl"]},
    {"t_s": 4.55, "key": "S", "action": "release", "mods": ["ctrl"]},
    {"t_s": 4.6, "resize": [1400, 900]},
    {"t_s": 5.1, "screenshot": "large.png"},
    {"t_s": 5.2, "close": true}]})";
  const CliResult r = run_cli("trainer --script " + (d / "s.json").string() + " --out " +
                              d.string() + " --width 1024 --height 700");
  ASSERT_EQ(r.status, 0) << r.err;
  // A cine run recorded while C was held, reviewed in the window, saved as PNGs.
  const nlohmann::json review = read_json(d / "review.json");
  EXPECT_TRUE(review["review"].get<bool>());
  EXPECT_GE(review["cine_frames"].get<int>(), 2);
  EXPECT_TRUE(fs::exists(d / "cine" / "run_01" / "frame_00000.png"));
  EXPECT_TRUE(read_json(d / "paused.json")["paused"].get<bool>());
  Image s, l;
  ASSERT_TRUE(s.load(d / "small.png"));
  ASSERT_TRUE(l.load(d / "large.png"));
  EXPECT_EQ(s.w, 900);
  EXPECT_EQ(s.h, 600);
  EXPECT_EQ(l.w, 1400);
  EXPECT_EQ(l.h, 900);
  // The panel follows the window.
  EXPECT_LT(read_json(d / "small.json")["fluoro_panel"][2].get<double>(),
            read_json(d / "large.json")["fluoro_panel"][2].get<double>());
  const nlohmann::json m = read_json(d / "metrics.json");
  EXPECT_EQ(m["trainer"]["rewinds"].get<int>(), 1);
  EXPECT_EQ(m["trainer"]["cine_runs"].get<int>(), 1);
  EXPECT_EQ(replay_hash(d), m["state_hash"].get<std::string>());
}

TEST(TrainerApp, ClosingDuringAnInjectionSavesTheSession) {
  const Scratch scratch_dir("close");
  const fs::path& d = scratch_dir.d;
  std::ofstream(d / "s.json") << R"({"events": [
    {"t_s": 0.2, "key": "E", "action": "press"},
    {"t_s": 1.5, "close": true}]})";
  const CliResult r =
      run_cli("trainer --script " + (d / "s.json").string() + " --out " + d.string());
  ASSERT_EQ(r.status, 0) << r.err;
  const nlohmann::json m = read_json(d / "metrics.json");
  EXPECT_GT(m["contrast_volume_ml"].get<double>(), 0.0);
  EXPECT_EQ(replay_hash(d), m["state_hash"].get<std::string>());
}

// Waits for "listening on 127.0.0.1:PORT" in the trainer's stderr; 0 when it never comes.
int wait_for_port(CliProcess& p, const fs::path& err) {
  const auto end = std::chrono::steady_clock::now() + 120s;
  const std::string key = "listening on 127.0.0.1:";
  while (std::chrono::steady_clock::now() < end) {
    const std::string text = slurp(err);
    const auto at = text.find(key);
    if (at != std::string::npos && text.find('\n', at) != std::string::npos)
      return std::atoi(text.c_str() + at + key.size());
    if (p.exited()) return 0;
    std::this_thread::sleep_for(20ms);
  }
  return 0;
}

// The port of a session's device once its physics is ready, 0 if it never listened. The server
// listens before the window opens and the physics starts once it is ready (a slow machine takes
// a while): commands sent before would be overtaken by a disconnect's.
int wait_until_ready(CliProcess& p, const fs::path& err) {
  const int port = wait_for_port(p, err);
  if (port <= 0) return 0;
  const auto ready_by = std::chrono::steady_clock::now() + 120s;
  while (slurp(err).find(" ready in ") == std::string::npos && !p.exited() &&
         std::chrono::steady_clock::now() < ready_by)
    std::this_thread::sleep_for(20ms);
  return port;
}

TEST(TrainerApp, ADeviceConnectsDropsAndReconnectsBesideTheKeyboard) {
  const Scratch scratch_dir("device");
  const fs::path& d = scratch_dir.d;
  std::ofstream(d / "s.json") << R"({"events": [
    {"t_s": 0.2, "key": "W", "action": "press"},
    {"t_s": 1.0, "key": "W", "action": "release"},
    {"t_s": 60, "close": true}]})";
  CliProcess p({"trainer", "--script", (d / "s.json").string(), "--out", d.string(), "--device",
                "igtl", "--port", "0"},
               d / "out.txt", d / "err.txt");
  ASSERT_TRUE(p.started());
  const int port = wait_until_ready(p, d / "err.txt");
  ASSERT_GT(port, 0) << slurp(d / "err.txt");
  {
    IgtlClient c;
    ASSERT_TRUE(c.connect(port, 10000ms));
    ASSERT_TRUE(c.send_transform("catheter", 20.0, 0.0));  // the catheter, by position
    std::vector<double> f;
    EXPECT_TRUE(c.read_sensor("force_catheter", f, 10000ms));
    c.close();  // dropped without a word
  }
  std::this_thread::sleep_for(300ms);
  {
    IgtlClient c;
    ASSERT_TRUE(c.connect(port, 10000ms));
    ASSERT_TRUE(c.send_sensor("vel_catheter", {10.0, 0.0}));
    std::this_thread::sleep_for(500ms);
    c.close();
  }
  std::this_thread::sleep_for(300ms);
  p.signal(SIGTERM);  // ends the session as a close does
  ASSERT_TRUE(p.wait(120s));
  ASSERT_EQ(p.status(), 0) << slurp(d / "err.txt");
  const nlohmann::json m = read_json(d / "metrics.json");
  EXPECT_EQ(m["trainer"]["device"]["connections"].get<int>(), 2);
  EXPECT_GE(m["trainer"]["device"]["disconnections"].get<int>(), 2);
  EXPECT_GT(m["instruments"][0]["inserted_mm"].get<double>(), 1.0);  // the device's catheter
  EXPECT_GT(m["instruments"][1]["inserted_mm"].get<double>(), 1.0);  // the keyboard's wire
  EXPECT_EQ(replay_hash(d), m["state_hash"].get<std::string>());
}

// A device exchanges instruments during a session (docs/devices.md, "Instrument exchange"): a
// balloon catheter added over the coronary wire inside the guide, then removed; an unknown
// catalogue entry is refused and answered. The session's recording holds both exchanges and
// replays to the same state.
TEST(TrainerApp, ADeviceExchangesInstrumentsAndTheSessionReplays) {
  const Scratch scratch_dir("exchange");
  const fs::path& d = scratch_dir.d;
  std::ofstream(d / "s.json") << R"({"events": [
    {"t_s": 0.2, "key": "W", "action": "press"},
    {"t_s": 0.8, "key": "W", "action": "release"},
    {"t_s": 60, "close": true}]})";
  CliProcess p({"trainer", "--script", (d / "s.json").string(), "--out", d.string(), "--device",
                "igtl", "--port", "0"},
               d / "out.txt", d / "err.txt");
  ASSERT_TRUE(p.started());
  const int port = wait_until_ready(p, d / "err.txt");
  ASSERT_GT(port, 0) << slurp(d / "err.txt");
  {
    IgtlClient c;
    ASSERT_TRUE(c.connect(port, 10000ms));
    std::string reply;
    ASSERT_TRUE(c.send_string("exchange",
                              "add predil balloon-sc-2.5x15 inside=catheter "
                              "over=coronary_wire"));
    ASSERT_TRUE(c.read_string("exchange", reply, 20000ms));
    EXPECT_EQ(reply.rfind("done: add predil", 0), 0u) << reply;
    ASSERT_TRUE(c.send_sensor("vel_predil", {0.0, 0.0}));  // the new instrument, by name
    std::this_thread::sleep_for(300ms);
    ASSERT_TRUE(c.send_string("exchange", "add x no-such-balloon"));
    ASSERT_TRUE(c.read_string("exchange", reply, 20000ms));
    EXPECT_EQ(reply.rfind("refused: ", 0), 0u) << reply;
    EXPECT_NE(reply.find("no-such-balloon"), std::string::npos) << reply;
    ASSERT_TRUE(c.send_string("exchange", "remove predil"));
    ASSERT_TRUE(c.read_string("exchange", reply, 20000ms));
    EXPECT_EQ(reply.rfind("done: remove predil", 0), 0u) << reply;
    c.close();
  }
  p.signal(SIGTERM);
  ASSERT_TRUE(p.wait(120s));
  ASSERT_EQ(p.status(), 0) << slurp(d / "err.txt");
  const nlohmann::json m = read_json(d / "metrics.json");
  EXPECT_EQ(m["trainer"]["exchanges"].get<int>(), 2);
  EXPECT_EQ(m["trainer"]["device"]["exchanges_refused"].get<int>(), 1);
  const nlohmann::json rec = read_json(d / "recording.json");
  ASSERT_TRUE(rec.contains("exchanges")) << "the recording carries the exchanges";
  EXPECT_EQ(rec["exchanges"].size(), 2u);
  EXPECT_EQ(replay_hash(d), m["state_hash"].get<std::string>());
}

// The window's exchange path (the Instruments menu calls PhysicsThread::exchange): a request is
// made between two steps, shows in the view, is recorded; one the engine refuses leaves the scene
// as it was and says why; the recording replays to the session's state.
TEST(TrainerPhysics, AnExchangeFromTheWindowIsMadeRecordedAndReplayed) {
  const Scratch scratch_dir("physics_exchange");
  Scenario sc = default_scenario();
  sc.autopilot.clear();
  trainer::PhysicsThread ph(sc, nullptr);
  InstrumentChange add;
  add.kind = InstrumentChange::Kind::kAdd;
  add.name = "predil";
  add.catalogue = "balloon-sc-2.5x15";
  add.inside = "catheter";
  add.over = "coronary_wire";
  add.rim = false;
  InstrumentChange bad = add;
  bad.name = "j_wire";  // a name in use
  ph.start();
  ph.exchange(add);
  ph.exchange(bad);
  trainer::ViewState v;
  const auto until = std::chrono::steady_clock::now() + 60s;
  while (std::chrono::steady_clock::now() < until &&
         (v.instruments.size() != sc.instruments.size() + 1 || v.time < 0.2)) {
    ph.latest(v);
    std::this_thread::sleep_for(5ms);
  }
  ph.stop();
  ASSERT_EQ(v.instruments.size(), sc.instruments.size() + 1);
  EXPECT_EQ(v.instruments.back(), "predil");
  EXPECT_EQ(ph.exchanges(), 1);
  EXPECT_NE(v.message.find("refused"), std::string::npos) << v.message;
  EXPECT_EQ(ph.simulator().num_instruments(), static_cast<int>(sc.instruments.size()) + 1);
  CommandRecording& rec = ph.recording();
  ASSERT_EQ(rec.exchanges().size(), 1u);
  rec.state_hash = ph.simulator().state().hash();
  rec.save(scratch_dir.d / "recording.json");
  char hex[19];
  std::snprintf(hex, sizeof hex, "%016llx",
                static_cast<unsigned long long>(ph.simulator().state().hash()));
  EXPECT_EQ(replay_hash(scratch_dir.d), std::string(hex));
}

TEST(TrainerApp, BadInputIsAClearErrorAndNothingIsLost) {
  const Scratch scratch_dir("bad");
  const fs::path& d = scratch_dir.d;
  // An earlier session's files in the output folder stay as they were.
  fs::create_directories(d / "out");
  std::ofstream(d / "out" / "recording.json") << "earlier";
  std::ofstream(d / "bad.json") << R"({"format": "vcsim-scenario", "version": 1, "name": "bad",
    "dt_ms": 0.5, "instruments": [{"name": "wire", "catalogue": "no-such-wire"}],
    "input": {"type": "autopilot"}})";
  CliResult r = run_cli("trainer " + (d / "bad.json").string() + " --out " + (d / "out").string());
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("bad.json"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_EQ(slurp(d / "out" / "recording.json"), "earlier");
  std::ofstream(d / "s.json") << R"({"events": [{"t_s": 1, "key": "NOPE", "action": "press"}]})";
  r = run_cli("trainer --script " + (d / "s.json").string() + " --out " + (d / "out").string());
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("events[0].key"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(d / "out" / "recording.json"), "earlier");
  // No display: one line naming xvfb-run.
  r = run_cli("trainer --out " + (d / "out").string(), "env -u DISPLAY -u WAYLAND_DISPLAY ");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("xvfb-run"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  // A recording of another scene is refused by the replay.
  std::ofstream(d / "rec.json") << R"({"format": "vcsim-recording", "version": 1,
    "dt_s": 0.0005, "instruments": ["wire"], "model_hash": "0", "state_hash": "0", "steps": 1,
    "runs": [[1, 0, 0, 0, "v", 0, 0]]})";
  r = run_cli("run default --no-frames --replay " + (d / "rec.json").string() + " --out " +
              (d / "replay").string());
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("instruments"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace vcsim::test
