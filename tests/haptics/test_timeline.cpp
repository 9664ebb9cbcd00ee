// The scripted timeline: interpolation rules, deterministic replay, no allocation once warm,
// and bad files named by file and field.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <new>
#include <numbers>
#include <string>
#include <vector>

#include "vcsim/core.h"
#include "vcsim/haptics.h"
#include "vcsim/solver.h"

#include "counting_new.h"

using vcsim::test::g_allocations;

namespace {

using vcsim::CommandLimits;
using vcsim::DriveCommand;
using vcsim::ScriptedTimeline;
using vcsim::Sheath;
using vcsim::StepCommands;
using Mode = DriveCommand::Mode;
constexpr double kMm = 1e-3;
constexpr double kDeg = std::numbers::pi / 180.0;

const std::filesystem::path kExample =
    std::filesystem::path(VCSIM_HAPTICS_TEST_DIR) / "example_timeline.json";

// The scene's instruments: the timeline's two and one it does not name.
const std::vector<std::string> kScene = {"guidewire", "catheter", "snare"};
enum { kGuidewire, kCatheter, kSnare };

ScriptedTimeline bound_example() {
  ScriptedTimeline tl = ScriptedTimeline::load(kExample);
  tl.bind(kScene);
  return tl;
}

StepCommands at(ScriptedTimeline& tl, double t) {
  StepCommands c;
  tl.poll(t, c);
  return c;
}

TEST(Timeline, FollowsTheDocumentedRules) {
  ScriptedTimeline tl = bound_example();
  EXPECT_DOUBLE_EQ(tl.duration(), 6.5);
  ASSERT_EQ(tl.instrument_names(), (std::vector<std::string>{"catheter", "guidewire"}));

  // Position keyframes: linear in between, held after the last; in SI, in the scene's order.
  auto c = at(tl, 1.0);
  ASSERT_EQ(c.drive.size(), 3u);
  EXPECT_EQ(c.drive[kGuidewire].mode, Mode::kPosition);
  EXPECT_DOUBLE_EQ(c.drive[kGuidewire].translation, 25.0 * kMm);
  EXPECT_DOUBLE_EQ(c.drive[kGuidewire].rotation, 45.0 * kDeg);
  c = at(tl, 10.0);
  EXPECT_DOUBLE_EQ(c.drive[kGuidewire].translation, 50.0 * kMm);
  EXPECT_DOUBLE_EQ(c.drive[kGuidewire].rotation, 90.0 * kDeg);
  // An instrument the timeline does not name is held still.
  EXPECT_EQ(c.drive[kSnare].mode, Mode::kVelocity);
  EXPECT_EQ(c.drive[kSnare].translation, 0.0);
  EXPECT_EQ(c.drive[kSnare].rotation, 0.0);

  // A position keyframe followed by a velocity one holds; velocity holds its speed.
  EXPECT_DOUBLE_EQ(at(tl, 2.4).drive[kCatheter].translation, 0.0);
  EXPECT_EQ(at(tl, 2.4).drive[kCatheter].mode, Mode::kPosition);
  c = at(tl, 3.0);
  EXPECT_EQ(c.drive[kCatheter].mode, Mode::kVelocity);
  EXPECT_DOUBLE_EQ(c.drive[kCatheter].translation, 10.0 * kMm);
  EXPECT_DOUBLE_EQ(at(tl, 4.49).drive[kCatheter].translation, 10.0 * kMm);
  EXPECT_EQ(at(tl, 4.5).drive[kCatheter].mode, Mode::kPosition);
  EXPECT_DOUBLE_EQ(at(tl, 4.5).drive[kCatheter].translation, 20.0 * kMm);

  // Before the first keyframe: at the script's starting position.
  EXPECT_DOUBLE_EQ(at(tl, -1.0).drive[kGuidewire].translation, 0.0);

  // Flow and buttons hold; balloon pressure ramps between its keyframes, 0 before the first.
  EXPECT_DOUBLE_EQ(at(tl, 2.0).syringe_flow, 0.0);
  EXPECT_DOUBLE_EQ(at(tl, 3.0).syringe_flow, 2.0e-6);  // m^3/s
  EXPECT_EQ(at(tl, 3.0).buttons, 1u);
  EXPECT_DOUBLE_EQ(at(tl, 5.0).syringe_flow, 0.0);
  EXPECT_EQ(at(tl, 5.0).buttons, 0u);
  EXPECT_DOUBLE_EQ(at(tl, 3.0).balloon_pressure, 0.0);
  EXPECT_DOUBLE_EQ(at(tl, 5.5).balloon_pressure, 4.0 * 101325.0);  // Pa
  EXPECT_DOUBLE_EQ(at(tl, 7.0).balloon_pressure, 8.0 * 101325.0);

  // Feedback is kept for inspection.
  const std::vector<vcsim::HandFeedback> fb = {{0.5, 0.001}, {0.0, 0.0}, {0.0, 0.0}};
  tl.publish(fb);
  ASSERT_EQ(tl.last_feedback().size(), 3u);
  EXPECT_EQ(tl.last_feedback()[0].axial_force, 0.5);
}

// A timeline that names an instrument the scene does not have is refused when it is bound, naming
// the timeline and the name.
TEST(Timeline, ANameThatIsNotAnInstrumentIsRefused) {
  ScriptedTimeline tl = ScriptedTimeline::load(kExample);
  try {
    tl.bind(std::vector<std::string>{"guidewire", "sheath"});
    ADD_FAILURE() << "bound a timeline naming 'catheter' to a scene without one";
  } catch (const vcsim::InputError& e) {
    EXPECT_EQ(e.source(), kExample.string());
    EXPECT_NE(std::string(e.what()).find("'catheter'"), std::string::npos) << e.what();
  }
}

bool same(const StepCommands& a, const StepCommands& b) {
  if (a.drive.size() != b.drive.size()) return false;
  for (std::size_t i = 0; i < a.drive.size(); ++i) {
    const auto &x = a.drive[i], &y = b.drive[i];
    if (x.mode != y.mode || std::memcmp(&x.translation, &y.translation, sizeof(double)) != 0 ||
        std::memcmp(&x.rotation, &y.rotation, sizeof(double)) != 0)
      return false;
  }
  return std::memcmp(&a.balloon_pressure, &b.balloon_pressure, sizeof(double)) == 0 &&
         std::memcmp(&a.syringe_flow, &b.syringe_flow, sizeof(double)) == 0 &&
         a.buttons == b.buttons;
}

TEST(Timeline, ReplaysToTheSameCommandsBitForBit) {
  ScriptedTimeline a = bound_example();
  ScriptedTimeline b = bound_example();
  const int steps = 8000;  // 1 kHz over 8 s, past the last keyframe
  std::vector<StepCommands> first(steps);
  for (int i = 0; i < steps; ++i) a.poll(i * 1e-3, first[i]);
  // A second instance, and the same instance polled backwards (state-free: a pure function of t).
  StepCommands c;
  for (int i = 0; i < steps; ++i) {
    b.poll(i * 1e-3, c);
    ASSERT_TRUE(same(first[i], c)) << "step " << i;
  }
  for (int i = steps - 1; i >= 0; --i) {
    a.poll(i * 1e-3, c);
    ASSERT_TRUE(same(first[i], c)) << "step " << i;
  }
}

TEST(Timeline, WarmPollAllocatesNothing) {
#ifdef VCSIM_SANITIZE
  GTEST_SKIP() << "the sanitizer runtime owns operator new";
#else
  ScriptedTimeline tl = bound_example();
  StepCommands c;
  tl.poll(0.0, c);
  const long before = g_allocations.load();
  for (int i = 0; i < 5000; ++i) tl.poll(i * 1e-3, c);
  EXPECT_EQ(g_allocations.load() - before, 0);
#endif
}

std::string error_of(const std::string& text) {
  try {
    ScriptedTimeline::parse(text, "scripts/push.json");
  } catch (const vcsim::InputError& e) {
    EXPECT_EQ(e.source(), "scripts/push.json");
    return std::string(e.field()) + " | " + e.what();
  }
  return "";
}

TEST(Timeline, BadFilesNameFileAndField) {
  struct Case {
    const char* text;
    const char* field;
    const char* expected;
  };
  const Case cases[] = {
      {R"({"keyframes": []})", "keyframes", "at least one"},
      {R"({"keyframe": []})", "keyframes", "required"},
      {R"({"keyframes": [{"t_s": 1}, {"t_s": 1}]})", "keyframes[1].t_s", "after the previous"},
      {R"({"keyframes": [{"t_s": -1}]})", "keyframes[0].t_s", ">= 0"},
      {R"({"keyframes": [{"t": 0}]})", "keyframes[0].t_s", "required"},
      {R"({"keyframes": [{"t_s": 0, "ballon_pressure_atm": 2}]})",
       "keyframes[0].ballon_pressure_atm", "unknown key"},
      {R"({"keyframes": [{"t_s": 0, "instruments": {"gw": {"translation_mm": 1}}}]})",
       "keyframes[0].instruments.gw.rotation_deg", "required"},
      {R"({"keyframes": [{"t_s": 0, "instruments": {"gw": {"translation_mm": 1,
          "rotation_deg": 0, "mode": "torque"}}}]})",
       "keyframes[0].instruments.gw.mode", "velocity"},
      {R"({"keyframes": [{"t_s": 0, "instruments": {"gw": {"translation_mm": 1e9,
          "rotation_deg": 0}}}]})",
       "keyframes[0].instruments.gw.translation_mm", "within"},
      {R"({"keyframes": [{"t_s": 0, "instruments": {"gw": {"translation_mm": 0,
          "rotation_deg": 1e8, "mode": "velocity"}}}]})",
       "keyframes[0].instruments.gw.rotation_deg", "spin"},
      {R"({"keyframes": [{"t_s": 0, "instruments": {"gw": 3}}]})", "keyframes[0].instruments.gw",
       "expected an object"},
      {R"({"keyframes": [{"t_s": 0, "balloon_pressure_atm": 99}]})",
       "keyframes[0].balloon_pressure_atm", "[0, 30]"},
      {R"({"keyframes": [{"t_s": 0, "balloon_pressure_atm": -1}]})",
       "keyframes[0].balloon_pressure_atm", "[0, 30]"},
      {R"({"keyframes": [{"t_s": 0, "syringe_flow_ml_s": "fast"}]})",
       "keyframes[0].syringe_flow_ml_s", "expected a number"},
      {R"({"keyframes": [{"t_s": 0, "buttons": 2.5}]})", "keyframes[0].buttons", "integer"},
      {R"({"keyframes": [{"t_s": 0})", "json", "valid JSON"},
      // Instrument exchange: "add" as a scenario declares an instrument, "remove" a name.
      {R"({"keyframes": [{"t_s": 0, "add": {"name": "b"}}]})", "keyframes[0].add.catalogue",
       "required"},
      {R"({"keyframes": [{"t_s": 0, "add": {"name": "b", "catalogue": "x", "colour": 1}}]})",
       "keyframes[0].add.colour", "unknown key"},
      {R"({"keyframes": [{"t_s": 0, "add": {"name": "b", "catalogue": "x", "rim": false}}]})",
       "keyframes[0].add.rim", "only with"},
      {R"({"keyframes": [{"t_s": 0, "add": {"name": "b", "catalogue": "x", "max_nodes": 9}}]})",
       "keyframes[0].add.max_nodes", ""},
      {R"({"keyframes": [{"t_s": 0, "add": {"name": "a-name-of-twenty-ch", "catalogue": "x"}}]})",
       "keyframes[0].add.name", "1-14"},
      {R"({"keyframes": [{"t_s": 0, "add": "balloon"}]})", "keyframes[0].add",
       "expected an object"},
      {R"({"keyframes": [{"t_s": 0, "remove": 3}]})", "keyframes[0].remove", "string"},
      {R"({"keyframes": [{"t_s": 0, "remove": ""}]})", "keyframes[0].remove", ""},
  };
  for (const auto& c : cases) {
    const std::string err = error_of(c.text);
    EXPECT_EQ(err.rfind(std::string(c.field) + " | scripts/push.json: " + c.field + ": ", 0), 0u)
        << c.text << "\n -> " << err;
    EXPECT_NE(err.find(c.expected), std::string::npos) << c.text << "\n -> " << err;
  }
  EXPECT_THROW(ScriptedTimeline::load("/nonexistent/timeline.json"), vcsim::InputError);
}

// Exchanges are asked for once each, in order, at the first poll at or after their keyframe's time
// (a removal before an addition in one keyframe); names the timeline adds or removes itself bind
// before they are in the scene, and after the exchange the commands follow the new order.
TEST(Timeline, ExchangesAreAskedForOnceInOrderAndRebound) {
  ScriptedTimeline tl = ScriptedTimeline::parse(R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 10, "rotation_deg": 0}}},
    {"t_s": 1, "remove": "old", "add": {"name": "balloon", "catalogue": "balloon-sc-3.0x15",
                                        "over": "wire", "tip_segment_mm": 1.5}},
    {"t_s": 2, "instruments": {"balloon": {"translation_mm": 40, "rotation_deg": 0}}}]})",
                                                "ex.json");
  tl.bind(std::vector<std::string>{"wire", "old"});  // "balloon" comes later: accepted
  ASSERT_EQ(tl.exchanges().size(), 2u);
  vcsim::InstrumentChange c;
  EXPECT_FALSE(tl.poll_exchange(0.5, c));
  ASSERT_TRUE(tl.poll_exchange(1.0 - 1e-12, c)) << "a time summed step by step, a rounding short";
  EXPECT_EQ(c.kind, vcsim::InstrumentChange::Kind::kRemove);
  EXPECT_EQ(c.name, "old");
  EXPECT_EQ(c.field, "keyframes[1].remove");
  ASSERT_TRUE(tl.poll_exchange(1.0, c));
  EXPECT_EQ(c.kind, vcsim::InstrumentChange::Kind::kAdd);
  EXPECT_EQ(c.name, "balloon");
  EXPECT_EQ(c.over, "wire");
  EXPECT_DOUBLE_EQ(c.tip_segment, 1.5 * kMm);
  EXPECT_EQ(c.source, "ex.json");
  EXPECT_EQ(c.field, "keyframes[1].add");
  EXPECT_EQ(vcsim::describe(c), "add balloon balloon-sc-3.0x15 over=wire");
  EXPECT_FALSE(tl.poll_exchange(5.0, c)) << "each once";
  tl.exchanged(c, std::vector<std::string>{"wire", "balloon"});
  const StepCommands s = at(tl, 2.0);
  ASSERT_EQ(s.drive.size(), 2u);
  EXPECT_DOUBLE_EQ(s.drive[0].translation, 10 * kMm);
  EXPECT_DOUBLE_EQ(s.drive[1].translation, 40 * kMm);
  // A name neither in the scene nor exchanged by the timeline is still refused.
  EXPECT_THROW(tl.bind(std::vector<std::string>{"old"}), vcsim::InputError);
}

// 1000 mm/s and 36,000 deg/s passed the plausibility limits and were then capped silently by the
// drive (0.5 m/s, 30 rad/s at the sheath): now refused at load, naming the key and the limit,
// whether asked for in velocity mode or between two position keyframes.
TEST(Timeline, SpeedsBeyondTheDriveAreRefused) {
  const std::string key = R"({"keyframes": [{"t_s": 0, "instruments": {"gw": )";
  const struct {
    std::string text;
    const char* field;
    const char* expected;
  } cases[] = {
      {key + R"({"mode": "velocity", "translation_mm": 1000, "rotation_deg": 0}}}]})",
       "keyframes[0].instruments.gw.translation_mm", "within +-500 mm/s, got 1000"},
      {key + R"({"mode": "velocity", "translation_mm": 0, "rotation_deg": -36000}}}]})",
       "keyframes[0].instruments.gw.rotation_deg", "within +-1718.87 deg/s, got -36000"},
      {key + R"({"translation_mm": 0, "rotation_deg": 0}}},
          {"t_s": 0.1, "instruments": {"gw": {"translation_mm": 100, "rotation_deg": 0}}}]})",
       "keyframes[1].instruments.gw.translation_mm", "got 1000 mm/s from the previous keyframe"},
      {key + R"({"translation_mm": 0, "rotation_deg": 0}}},
          {"t_s": 1, "instruments": {"gw": {"translation_mm": 10, "rotation_deg": 3600}}}]})",
       "keyframes[1].instruments.gw.rotation_deg", "got 3600 deg/s"},
  };
  for (const auto& c : cases) {
    const std::string err = error_of(c.text);
    EXPECT_EQ(err.rfind(std::string(c.field) + " | scripts/push.json: " + c.field + ": ", 0), 0u)
        << c.text << "\n -> " << err;
    EXPECT_NE(err.find(c.expected), std::string::npos) << c.text << "\n -> " << err;
  }
  // At the drive's limits, and a jump after a velocity keyframe (not a rate the file states).
  EXPECT_EQ(error_of(key + R"({"mode": "velocity", "translation_mm": -500, "rotation_deg": 1718}}},
      {"t_s": 1, "instruments": {"gw": {"translation_mm": 900, "rotation_deg": 0}}},
      {"t_s": 3, "instruments": {"gw": {"translation_mm": 0, "rotation_deg": 3437}}}]})"),
            "");
}

// The drive limits the timeline checks are the sheath's, where the step applies them.
TEST(Timeline, DriveLimitsAreTheSheaths) {
  const CommandLimits lim;
  const Sheath sh;
  EXPECT_DOUBLE_EQ(lim.drive_speed_mm_s * kMm, sh.max_speed);
  EXPECT_DOUBLE_EQ(lim.drive_spin_deg_s * kDeg, sh.max_spin);
}

// Nesting 100,000 deep (which overflowed the stack), a number beyond a double and a repeated key
// are input errors naming the file, never a crash or a library's message.
TEST(Timeline, HostileJsonIsAnInputError) {
  const std::string deep = std::string(100000, '[') + std::string(100000, ']');
  const std::string key = R"({"keyframes": [{"t_s": 0, "instruments": {"gw": )";
  const struct {
    std::string text;
    const char* field;
  } cases[] = {
      {deep, "json"},
      {key + deep + "}}]}", "json"},
      {R"({"keyframes": [{"t_s": 1e999}]})", "json"},
      {key + R"({"translation_mm": 1, "rotation_deg": 0, "translation_mm": 2}}}]})",
       "keyframes[0].instruments.gw.translation_mm"},
      {R"({"keyframes": [{"t_s": 0}], "keyframes": []})", "keyframes"},
  };
  for (const auto& c : cases) {
    const std::string err = error_of(c.text);
    EXPECT_EQ(err.rfind(std::string(c.field) + " | scripts/push.json: " + c.field + ": ", 0), 0u)
        << c.text.substr(0, 80) << "\n -> " << err;
  }
}

}  // namespace
