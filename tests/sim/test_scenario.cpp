// The scenario format: the shipped default parses to what it says; every kind of bad input is
// refused with an error naming the file and the field.
#include <gtest/gtest.h>

#include <string>

#include "vcsim/sim.h"

namespace vcsim {
namespace {

const char* kMinimal = R"({"format": "vcsim-scenario", "version": 1, "name": "t",
  "instruments": [{"name": "wire", "catalogue": "wire-035-j3-hydrophilic"}],
  "autopilot": [{"action": "navigate", "instrument": "wire",
                 "goal": {"segment": "aortic_arch", "distance_mm": 5}}]})";

// Replaces the first occurrence of `from` in the minimal scenario.
std::string edit(const std::string& from, const std::string& to) {
  std::string s = kMinimal;
  const auto at = s.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  return s.replace(at, from.size(), to);
}

void expect_error(const std::string& text, const std::string& field) {
  try {
    parse_scenario(text, "bad.json");
    ADD_FAILURE() << "accepted; expected an error naming " << field;
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), "bad.json");
    EXPECT_EQ(e.field(), field) << e.what();
  }
}

TEST(Scenario, DefaultParses) {
  const Scenario sc = load_scenario(default_scenarios_dir() / "default.json");
  EXPECT_EQ(sc.name, "default");
  ASSERT_EQ(sc.instruments.size(), 4u);
  EXPECT_EQ(sc.instruments[1].inside, "catheter");
  EXPECT_EQ(sc.instruments[3].over, "coronary_wire");
  EXPECT_TRUE(sc.beating);
  EXPECT_LE(sc.dt, 1e-3);  // 1 kHz or faster
  EXPECT_EQ(sc.landmarks.size(), 4u);
  EXPECT_DOUBLE_EQ(sc.fluoro.fps, 15.0);
  EXPECT_FALSE(sc.autopilot.empty());
  EXPECT_DOUBLE_EQ(sc.sheath_length, 25e-3);
  EXPECT_FALSE(sc.instruments[1].rim) << "why the default keeps the rim off: docs/physics.md 7.1";
  // The default scenario keeps four fine steps at any fast hand and no re-split, for its
  // autopilot (physics.md 5.4, validation.md 4).
  EXPECT_EQ(sc.fine_steps, 4);
  EXPECT_DOUBLE_EQ(sc.fine_step_speed, 0.13);
  EXPECT_DOUBLE_EQ(sc.fine_step_travel, 1e-6);
  EXPECT_EQ(sc.fine_step_jump, 0.0);
}

TEST(Scenario, UnitsAreConverted) {
  const Scenario sc = parse_scenario(kMinimal, "t.json");
  ASSERT_EQ(sc.autopilot.size(), 1u);
  EXPECT_DOUBLE_EQ(sc.autopilot[0].goal_distance, 5e-3);
  EXPECT_EQ(parse_scenario(edit("\"name\": \"t\"", "\"name\": \"t\", \"fine_steps\": 1"), "t.json")
                .fine_steps,
            1);
  EXPECT_DOUBLE_EQ(
      parse_scenario(edit("\"name\": \"t\"", "\"name\": \"t\", \"fine_step_speed_mm_s\": 50"),
                     "t.json")
          .fine_step_speed,
      0.05);
  EXPECT_EQ(sc.fine_steps, 8);  // what a scenario gets without the keys
  EXPECT_DOUBLE_EQ(sc.fine_step_travel, 25e-6);
  EXPECT_DOUBLE_EQ(sc.fine_step_jump, 0.3);
  EXPECT_DOUBLE_EQ(sc.fine_step_hold, 0.02);
  EXPECT_DOUBLE_EQ(sc.runaway_speed, 30.0);
  const Scenario split = parse_scenario(edit("\"name\": \"t\"",
                                             "\"name\": \"t\", \"fine_step_travel_um\": 40, "
                                             "\"fine_step_jump_n\": 0, \"fine_step_hold_ms\": 5"),
                                        "t.json");
  EXPECT_DOUBLE_EQ(split.fine_step_travel, 40e-6);
  EXPECT_EQ(split.fine_step_jump, 0.0);
  EXPECT_DOUBLE_EQ(split.fine_step_hold, 5e-3);
  EXPECT_DOUBLE_EQ(sc.dt, 1e-3);
  EXPECT_EQ(sc.autopilot[0].kind, AutopilotPhase::Kind::kNavigate);
}

TEST(Scenario, BadInputNamesTheField) {
  expect_error("{", "json");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"colour\": 1"), "colour");
  expect_error(edit("vcsim-scenario", "other"), "format");
  expect_error(edit("\"version\": 1", "\"version\": 2"), "version");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"dt_ms\": 2"), "dt_ms");
  expect_error(edit("\"name\": \"wire\", ", "\"name\": \"wire\", \"max_nodes\": 5000, "),
               "instruments[0].max_nodes");
  expect_error(edit("\"name\": \"wire\", ", "\"name\": \"wire\", \"inside\": \"sheath\", "),
               "instruments[0].inside");
  expect_error(edit("\"action\": \"navigate\"", "\"action\": \"fly\""), "autopilot[0].action");
  expect_error(edit("\"distance_mm\": 5", "\"distance_mm\": -5"), "autopilot[0].goal.distance_mm");
  expect_error(edit("\"instrument\": \"wire\"", "\"instrument\": \"balloon\""), "autopilot[0]");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"fluoroscopy\": {\"dose\": -1}"),
               "fluoroscopy.dose");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"fluoroscopy\": {\"size\": 300}"),
               "fluoroscopy.size");
  expect_error(
      edit("\"name\": \"t\"", "\"name\": \"t\", \"fluoroscopy\": {\"primary_deg\": \"LAO\"}"),
      "fluoroscopy.primary_deg");
  expect_error(edit("\"name\": \"t\"",
                    "\"name\": \"t\", \"landmarks\": [{\"name\": \"x\", "
                    "\"instrument\": \"cath\", \"segment\": \"lad\"}]"),
               "landmarks[0].instrument");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"input\": {\"type\": \"joystick\"}"),
               "input.type");
  expect_error(
      edit("\"name\": \"t\"", "\"name\": \"t\", \"feedback\": {\"hand_force\": \"magic\"}"),
      "feedback.hand_force");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"feedback\": {\"cutoff_hz\": -5}"),
               "feedback.cutoff_hz");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"feedback\": {\"cutof_hz\": 5}"),
               "feedback.cutof_hz");
  expect_error(edit("{\"action\": \"navigate\"",
                    "{\"action\": \"inject\", \"flow_ml_s\": 99}, "
                    "{\"action\": \"navigate\""),
               "autopilot[0].flow_ml_s");
  // A key that the phase's action does not use is refused, not ignored.
  expect_error(edit("{\"action\": \"navigate\"",
                    "{\"action\": \"wait\", \"depth_mm\": 5}, {\"action\": \"navigate\""),
               "autopilot[0].depth_mm");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"motion\": {\"beating\": 1}"),
               "motion.beating");
  // A misspelt key is named, not reported as the missing key it was meant to be.
  expect_error(edit("\"autopilot\":", "\"autopilott\":"), "autopilott");
  // The rim belongs to the lumen an instrument runs in: refused without one, and not a number.
  expect_error(edit("\"name\": \"wire\", ", "\"name\": \"wire\", \"rim\": true, "),
               "instruments[0].rim");
  expect_error(edit("\"catalogue\": \"wire-035-j3-hydrophilic\"}",
                    "\"catalogue\": \"wire-035-j3-hydrophilic\"}, {\"name\": \"w2\", "
                    "\"catalogue\": \"wire-014-floppy\", \"inside\": \"wire\", \"rim\": 1}"),
               "instruments[1].rim");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"sheath_length_mm\": 400"),
               "sheath_length_mm");
  // Fine steps: a whole number from 1 to 16, above a positive hand speed.
  for (const char* n : {"0", "2.5", "17", "\"four\""})
    expect_error(edit("\"name\": \"t\"", std::string("\"name\": \"t\", \"fine_steps\": ") + n),
                 "fine_steps");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"fine_step_speed_mm_s\": 0"),
               "fine_step_speed_mm_s");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"fine_step_travel_um\": 0"),
               "fine_step_travel_um");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"fine_step_jump_n\": -1"),
               "fine_step_jump_n");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"fine_step_hold_ms\": 2000"),
               "fine_step_hold_ms");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"runaway_speed_m_s\": -1"),
               "runaway_speed_m_s");
  // The procedure's keys: a pressure out of range, a place without an instrument, lesion
  // mechanics and targets out of range, an over naming no instrument.
  expect_error(edit("{\"action\": \"navigate\"",
                    "{\"action\": \"inflate\", \"pressure_atm\": -1}, "
                    "{\"action\": \"navigate\""),
               "autopilot[0].pressure_atm");
  expect_error(edit("{\"action\": \"navigate\"",
                    "{\"action\": \"place\", \"lesion\": 0}, {\"action\": \"navigate\""),
               "autopilot[0].instrument");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"lesions\": [{\"recoil\": 1.5}]"),
               "lesions[0].recoil");
  expect_error(
      edit("\"name\": \"t\"", "\"name\": \"t\", \"lesions\": [{\"crossing_force_n\": -1}]"),
      "lesions[0].crossing_force_n");
  expect_error(
      edit("\"name\": \"t\"", "\"name\": \"t\", \"targets\": {\"residual_stenosis_percent\": 120}"),
      "targets.residual_stenosis_percent");
  expect_error(edit("\"name\": \"wire\", ", "\"name\": \"wire\", \"over\": \"nothing\", "),
               "instruments[0].over");
  // Instrument exchange in the plan: an add declares an instrument as instruments[] does; phases
  // name instruments in the scene when they start; a removal leaves nothing inside or over it.
  const std::string add_b =
      "{\"action\": \"add\", \"instrument\": {\"name\": \"b\", "
      "\"catalogue\": \"balloon-sc-3.0x15\", \"over\": \"wire\"}}, ";
  const std::string nav = "{\"action\": \"navigate\"";
  expect_error(edit(nav, "{\"action\": \"add\", \"instrument\": \"b\"}, " + nav),
               "autopilot[0].instrument");
  expect_error(edit(nav, "{\"action\": \"add\", \"instrument\": {\"name\": \"b\"}}, " + nav),
               "autopilot[0].instrument.catalogue");
  expect_error(edit(nav,
                    "{\"action\": \"add\", \"instrument\": {\"name\": \"wire\", "
                    "\"catalogue\": \"wire-014-floppy\"}}, " +
                        nav),
               "autopilot[0].instrument.name");
  expect_error(edit(nav,
                    "{\"action\": \"add\", \"instrument\": {\"name\": \"b\", "
                    "\"catalogue\": \"x\", \"over\": \"nothing\"}}, " +
                        nav),
               "autopilot[0].instrument.over");
  expect_error(edit(nav, "{\"action\": \"remove\", \"instrument\": \"b\"}, " + nav),
               "autopilot[0]");
  expect_error(edit(nav, "{\"action\": \"remove\", \"instrument\": \"wire\"}, " + nav),
               "autopilot[0].instrument");  // none left
  const std::string add_w =
      "{\"action\": \"add\", \"instrument\": {\"name\": \"w2\", "
      "\"catalogue\": \"wire-014-floppy\"}}, ";
  expect_error(edit(nav, add_w + "{\"action\": \"remove\", \"instrument\": \"wire\"}, " + nav),
               "autopilot[2]");  // the navigate names a wire no longer there
  expect_error(edit(nav, add_b + "{\"action\": \"remove\", \"instrument\": \"wire\"}, " + nav),
               "autopilot[1].instrument");  // the balloon rides on it
  expect_error(
      edit(nav, "{\"action\": \"remove\", \"instrument\": \"wire\", \"depth_mm\": 0}, " + nav),
      "autopilot[0].depth_mm");
  // A landmark may name an instrument the plan adds; the add is in the plan.
  std::string text = edit(nav, add_b + nav);
  text.replace(text.find("\"name\": \"t\""), 11,
               "\"name\": \"t\", \"landmarks\": [{\"name\": \"x\", \"instrument\": \"b\", "
               "\"segment\": \"lad\"}]");
  const Scenario sc = parse_scenario(text, "ok.json");
  ASSERT_EQ(sc.autopilot.size(), 2u);
  EXPECT_EQ(sc.autopilot[0].kind, AutopilotPhase::Kind::kAdd);
  EXPECT_EQ(sc.autopilot[0].instrument, "b");
  EXPECT_EQ(sc.autopilot[0].added.catalogue, "balloon-sc-3.0x15");
  EXPECT_EQ(sc.landmarks[0].instrument, "b");
  // Duplicated names would make commands ambiguous.
  expect_error(edit("\"catalogue\": \"wire-035-j3-hydrophilic\"}",
                    "\"catalogue\": \"wire-035-j3-hydrophilic\"}, {\"name\": \"wire\", "
                    "\"catalogue\": \"wire-014-floppy\"}"),
               "instruments[1].name");
}

// Nesting 100,000 deep (which overflowed the stack), a number beyond a double and a repeated key
// are input errors naming the file, never a crash or a library's message.
TEST(Scenario, HostileJsonIsAnInputError) {
  const std::string deep = std::string(100000, '[') + std::string(100000, ']');
  expect_error(deep, "json");
  expect_error(edit("\"name\": \"t\"", std::string("\"name\": ") + deep), "json");
  expect_error(edit("\"version\": 1", "\"version\": 1e999"), "json");
  expect_error(edit("\"name\": \"t\"", "\"name\": \"t\", \"name\": \"u\""), "name");
  expect_error(edit("\"distance_mm\": 5", "\"distance_mm\": 5, \"distance_mm\": 6"),
               "autopilot[0].goal.distance_mm");
}

// dt_ms 1e-5 ran for days and 1e-7 died of bad_alloc: a step below kMinScenarioDt, or more than
// kMaxRunSteps steps before the time limit, is refused naming the key.
TEST(Scenario, TinyStepsAndEndlessRunsAreRefused) {
  const std::string head = "\"name\": \"t\"";
  expect_error(edit(head, head + ", \"dt_ms\": 1e-5"), "dt_ms");
  expect_error(edit(head, head + ", \"dt_ms\": 1e-7"), "dt_ms");
  expect_error(edit(head, head + ", \"dt_ms\": 0.001"), "dt_ms");
  // 3600 s at 0.05 ms is 7.2e7 steps; 3600 s at 0.1 ms is the limit itself.
  expect_error(edit(head, head + ", \"dt_ms\": 0.05, \"time_limit_s\": 3600"), "time_limit_s");
  EXPECT_NO_THROW(
      parse_scenario(edit(head, head + ", \"dt_ms\": 0.1, \"time_limit_s\": 3600"), "ok.json"));
  EXPECT_NO_THROW(parse_scenario(edit(head, head + ", \"dt_ms\": 0.01"), "ok.json"));
  EXPECT_THROW(check_run_steps(1e-5, 1000.0, "run", "--time-limit"), InputError);
  EXPECT_NO_THROW(check_run_steps(5e-4, 3600.0, "run", "--time-limit"));
}

TEST(Scenario, MissingFileIsAnInputError) {
  EXPECT_THROW(load_scenario("/nonexistent/scenario.json"), InputError);
}

}  // namespace
}  // namespace vcsim
