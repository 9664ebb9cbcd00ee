// Instrument exchange during a run (issue 25, docs/scenarios.md "Instrument exchange"): a balloon
// catheter added over the wire already in place rides it and inflates; a wire withdrawn, removed
// and replaced by another reaches the same place; a catheter is exchanged over a wire; what the
// rules refuse changes nothing; a deployed stent stays in the vessel when its delivery system
// leaves the scene; the same exchanges at the same times give the same state; a snapshot taken
// before an exchange restores that scene; the autopilot withdraws, removes, adds and navigates.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>

#include "vcsim/sim.h"
#include "vcsim/units.h"

#include "balloon_scene.h"

namespace vcsim {
namespace {

namespace fs = std::filesystem;

fs::path scratch(const std::string& name) {
  return fs::temp_directory_path() /
         ("vcsim-test-exchange-" + name + "-" + std::to_string(::getpid()));
}

const char* kWireOnly =
    R"([{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 160, "tip_segment_mm": 1}])";

InstrumentChange add(const std::string& name, const std::string& catalogue,
                     const std::string& over = "", int max_nodes = 200, double tip_mm = 1.0) {
  InstrumentChange c;
  c.kind = InstrumentChange::Kind::kAdd;
  c.name = name;
  c.catalogue = catalogue;
  c.over = over;
  c.max_nodes = max_nodes;
  c.tip_segment = tip_mm * kMm;
  c.source = "test";
  c.field = "change";
  return c;
}

InstrumentChange remove(const std::string& name) {
  InstrumentChange c;
  c.kind = InstrumentChange::Kind::kRemove;
  c.name = name;
  c.source = "test";
  c.field = "change";
  return c;
}

// Hands at the hubs in position mode, found by name (the scene's order changes with exchanges):
// each instrument held where it is unless moved.
struct Hands {
  Simulator& sim;
  StepCommands cmds;
  explicit Hands(Simulator& s) : sim(s) { hold(); }
  // After an exchange: one hand per instrument of the scene, holding it where it is.
  void hold() {
    cmds.reset(static_cast<std::size_t>(sim.num_instruments()));
    for (int i = 0; i < sim.num_instruments(); ++i) {
      cmds.drive[i].mode = DriveCommand::Mode::kPosition;
      cmds.drive[i].translation = sim.depth(i);
      cmds.drive[i].rotation = sim.instrument(i).drive.roll;
    }
  }
  int index(const std::string& name) const {
    const int i = sim.model().instrument_index(name);
    EXPECT_GE(i, 0) << name;
    return i;
  }
  // Moves `name` to `depth` (m) at `speed` (m/s), then holds 0.2 s.
  void to(const std::string& name, double depth, double speed = 0.05) {
    const int i = index(name);
    double at = cmds.drive[i].translation;
    const double dt = sim.dt();
    while (std::abs(depth - at) > 1e-12) {
      at += std::clamp(depth - at, -speed * dt, speed * dt);
      cmds.drive[i].translation = at;
      sim.step(cmds);
    }
    run(0.2);
  }
  void run(double seconds, double pressure = 0.0) {
    cmds.balloon_pressure = pressure;
    const double end = sim.time() + seconds;
    while (sim.time() < end - 1e-9) sim.step(cmds);
    cmds.balloon_pressure = 0.0;
  }
  void exchange(const InstrumentChange& c) {
    sim.exchange(c);
    hold();
  }
};

bool same_instrument_state(const InstrumentState& a, const InstrumentState& b) {
  return a.rod.x == b.rod.x && a.rod.v == b.rod.v && a.rod.omega == b.rod.omega &&
         a.drive.depth == b.drive.depth && a.drive.roll == b.drive.roll &&
         a.clearance == b.clearance && a.query_centre == b.query_centre && a.parked == b.parked;
}

// A 3.0 x 15 mm balloon catheter added to a scene where the 0.014" wire is already 154 mm in a
// 6 mm tube: the wire's state is untouched by the exchange; the balloon catheter enters parked
// at the sheath, rides the wire to the target, and inflated it follows its compliance chart
// within 1 % as one declared from the start does (Balloon.FreeInflationFollowsTheComplianceChart).
TEST(Exchange, ABalloonCatheterAddedOverTheWireInPlaceInflates) {
  test::TubeSpecs t;
  t.radius_mm = 3.0;
  Simulator sim(test::tube_scenario(scratch("balloon"), t, kWireOnly));
  Hands h(sim);
  h.to("wire", test::kAccessS - 0.066 + 0.03);
  ASSERT_EQ(sim.num_instruments(), 1);
  const InstrumentState wire = sim.instrument(0);
  const double time = sim.time();
  h.exchange(add("balloon", "balloon-sc-3.0x15", "wire"));
  ASSERT_EQ(sim.num_instruments(), 2);
  EXPECT_TRUE(same_instrument_state(sim.instrument(0), wire)) << "the wire goes on as it was";
  EXPECT_EQ(sim.time(), time);
  EXPECT_EQ(sim.depth(1), 0.0) << "the balloon catheter enters outside, at the sheath";
  ASSERT_EQ(sim.model().procedure.balloons.size(), 1u);
  EXPECT_EQ(sim.model().procedure.balloons[0].instrument, 1);
  EXPECT_EQ(sim.model().procedure.balloons[0].label, "balloon");
  const double wire_tip = sim.tip_location(0).loc.distance;
  h.to("balloon", test::balloon_depth(sim.instrument_spec(1), 0.066));
  EXPECT_NEAR(sim.tip_location(0).loc.distance, wire_tip, 2e-3) << "the wire stays in place";
  // The balloon's middle where it was brought (along the tube, within 2 mm).
  const BalloonSpec& spec = *sim.instrument_spec(1).balloon;
  const double tip = sim.tip_location(1).loc.distance;
  EXPECT_NEAR(tip + spec.distal_offset + 0.5 * spec.length, 0.066, 2e-3);
  for (std::size_t k = 0; k < spec.chart_pressure.size(); ++k) {
    h.cmds.balloon_pressure = spec.chart_pressure[k];
    const double end = sim.time() + 0.05;
    while (sim.time() < end - 1e-9) sim.step(h.cmds);
    const BalloonState& b = sim.state().procedure.balloons[0];
    EXPECT_NEAR(2.0 * b.radius[b.radius.size() / 2], spec.chart_diameter[k],
                0.01 * spec.chart_diameter[k])
        << spec.chart_pressure[k] / kAtm << " atm";
  }
  EXPECT_EQ(sim.metrics().rollbacks, 0);
}

// A 0.014" wire pushed 150 mm into a coronary-sized tube, withdrawn and removed, and a second
// wire (another catalogue entry) added and pushed as far: its tip reaches the same place within
// 1 mm. Its metrics start afresh; the first wire's landmarks and tip path are not its own.
TEST(Exchange, AWireWithdrawnRemovedAndReplacedReachesTheSamePlace) {
  test::TubeSpecs t;
  Simulator sim(test::tube_scenario(scratch("wire"), t, kWireOnly));
  Hands h(sim);
  h.to("wire", 0.150);
  const double first = sim.tip_location(0).loc.distance;
  EXPECT_NEAR(first, test::kAccessS - 0.150, 3e-3);
  h.to("wire", 0.0);
  ASSERT_LT(sim.depth(0), 1e-9);
  // The last instrument cannot leave the scene: the new wire comes in first.
  EXPECT_THROW(sim.exchange(remove("wire")), InputError);
  h.exchange(add("wire2", "wire-014-intermediate", "", 160));
  h.exchange(remove("wire"));
  ASSERT_EQ(sim.num_instruments(), 1);
  EXPECT_EQ(sim.model().instrument_name(0), "wire2");
  EXPECT_EQ(sim.metrics().tip_path[0], 0.0) << "its own metrics";
  h.to("wire2", 0.150);
  EXPECT_NEAR(sim.tip_location(0).loc.distance, first, 1e-3);
  EXPECT_GT(sim.metrics().tip_path[0], 0.14);
  EXPECT_EQ(sim.metrics().rollbacks, 0);
}

// A catheter exchanged over a 0.035" wire in an 8 mm tube: the wire 150 mm in, a JR4 over it to
// 110 mm, withdrawn over the wire and removed, and a JL4 added over the same wire and advanced to
// 110 mm. The wire's tip stays put throughout (within 3 mm), and the JL4's tip lies on the wire
// (the wire in its lumen: within the lumen's radius of the wire's centreline).
TEST(Exchange, ACatheterIsExchangedOverAWire) {
  test::TubeSpecs t;
  t.radius_mm = 4.0;
  Simulator sim(test::tube_scenario(scratch("catheter"), t, R"([
      {"name": "wire", "catalogue": "wire-035-j3-hydrophilic", "max_nodes": 128,
       "tip_segment_mm": 2},
      {"name": "catheter", "catalogue": "catheter-jr4-6f", "over": "wire", "max_nodes": 128,
       "tip_segment_mm": 2}])"));
  Hands h(sim);
  h.to("wire", 0.150, 0.1);
  const double wire_tip = sim.tip_location(0).loc.distance;
  h.to("catheter", 0.110, 0.1);
  EXPECT_NEAR(sim.tip_location(1).loc.distance, test::kAccessS - 0.110, 5e-3);
  h.to("catheter", 0.0, 0.1);
  // The wire cannot go while a catheter rides on it.
  EXPECT_THROW(sim.exchange(remove("wire")), InputError);
  h.exchange(remove("catheter"));
  h.exchange(add("guide", "catheter-jl4-6f", "wire", 128, 2.0));
  h.to("guide", 0.110, 0.1);
  EXPECT_NEAR(sim.tip_location(0).loc.distance, wire_tip, 3e-3) << "the wire stays in place";
  EXPECT_NEAR(sim.tip_location(1).loc.distance, test::kAccessS - 0.110, 5e-3);
  // The guide's tip on the wire.
  const Vec3 g = sim.tip(1);
  const auto& x = sim.instrument(0).rod.x;
  double nearest = 1e300;
  for (std::size_t k = 0; k + 1 < x.size(); ++k) {
    const Vec3 d = x[k + 1] - x[k];
    const double u = std::clamp((g - x[k]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    nearest = std::min(nearest, (x[k] + u * d - g).norm());
  }
  EXPECT_LT(nearest, 0.5 * sim.instrument_spec(1).inner_diameter);
  EXPECT_EQ(sim.metrics().rollbacks, 0);
}

// Each refusal is an InputError naming the change and what was expected, and changes nothing:
// the state's hash, the model and the instruments are those before.
TEST(Exchange, ARefusedChangeChangesNothing) {
  test::TubeSpecs t;
  Simulator sim(test::balloon_in_tube(scratch("refused"), t));
  Hands h(sim);
  auto refused = [&](const std::function<void()>& change, const std::string& field,
                     const std::string& says) {
    const std::uint64_t hash = sim.state().hash();
    const SimModel* model = &sim.model();
    try {
      change();
      ADD_FAILURE() << "accepted: " << says;
    } catch (const InputError& e) {
      EXPECT_EQ(e.source(), "test");
      EXPECT_EQ(e.field(), field);
      EXPECT_NE(std::string(e.what()).find(says), std::string::npos) << e.what();
    }
    EXPECT_EQ(sim.state().hash(), hash);
    EXPECT_EQ(&sim.model(), model);
    EXPECT_EQ(sim.num_instruments(), 2);
  };
  // At depth 0, nothing inserted: the wire carries the balloon catheter.
  refused([&] { sim.exchange(remove("wire")); }, "change", "'balloon' is");
  refused([&] { sim.exchange(remove("guide")); }, "change", "expected an instrument in the scene");
  refused([&] { sim.exchange(add("balloon", "balloon-sc-2.0x12", "wire")); }, "change.name",
          "expected a name not in the scene");
  refused([&] { sim.exchange(add("b2", "balloon-xx-9.9x99", "wire")); }, "change.catalogue",
          "expected an entry of");
  refused([&] { sim.exchange(add("b2", "balloon-sc-2.0x12", "nothing")); }, "change.over",
          "another instrument");
  refused(
      [&] {
        std::vector<ScenarioInstrument> list = sim.model().scenario.instruments;
        list[1].catalogue = "balloon-sc-2.0x12";
        sim.change_instruments(list, "test",
                               [](int i) { return "list[" + std::to_string(i) + "]"; });
      },
      "list[1].catalogue", "another instrument needs another name");
  // Inserted: withdraw it first.
  h.to("wire", 0.05);
  h.to("balloon", 0.01);
  refused([&] { sim.exchange(remove("balloon")); }, "change", "withdraw it first");
  // Withdrawn, it goes.
  h.to("balloon", 0.0);
  sim.exchange(remove("balloon"));
  EXPECT_EQ(sim.num_instruments(), 1);
}

// A stent system deploys its stent across a 60 % lesion (as Stent.StaysWhereDeployed...), is
// withdrawn and removed from the scene: the stent stays deployed where it was, its balloon is
// kept as removed (its outcome reported), the wall still holds the stent (a node inside its radius
// meets it), the lesion stays held open, and the wire pulled back through it leaves it in place.
TEST(Exchange, ADeployedStentStaysWhenItsDeliverySystemIsRemoved) {
  test::TubeSpecs t;
  t.lesion_percent = 60.0;
  t.catalogue = "stent-cocr-3.0x18";
  Simulator sim(test::balloon_in_tube(scratch("stent"), t));
  Hands h(sim);
  h.to("wire", test::kAccessS - 0.066 + 0.03);
  h.to("balloon", test::balloon_depth(sim.instrument_spec(1), 0.066));
  h.run(0.5, 10.0 * kAtm);
  h.run(0.3);
  const StentState deployed = sim.state().procedure.stents[0];
  ASSERT_EQ(deployed.phase, StentState::Phase::kDeployed);
  const std::size_t mid = deployed.ring_s.size() / 2;
  h.to("balloon", 0.0);
  h.exchange(remove("balloon"));
  ASSERT_EQ(sim.num_instruments(), 1);
  const SimModel& md = sim.model();
  ASSERT_EQ(md.procedure.balloons.size(), 1u);
  EXPECT_TRUE(md.procedure.balloons[0].removed());
  const StentState& stent = sim.state().procedure.stents[0];
  EXPECT_EQ(stent.phase, StentState::Phase::kDeployed);
  EXPECT_EQ(stent.ring_s, deployed.ring_s) << "where it was deployed";
  h.run(0.1);
  // The wall: a 0.2 mm node 0.1 mm inside a ring's radius, off the tube's axis, meets the stent.
  const double ring = stent.ring_radius[mid];
  const Vec3 centre = lumen_section(md.tree, md.procedure.spans, sim.state().procedure.opening,
                                    stent.segment, stent.ring_s[mid])
                          .centre;
  const Vec3 p = centre + (ring - 0.1e-3) * Vec3::UnitX();
  const double r = 0.2e-3;
  SphereContact c;
  VesselWall& wall = sim.workspace().wall();
  wall.set_time(sim.time());
  wall.query_spheres(std::span<const Vec3>(&p, 1), std::span<const double>(&r, 1),
                     std::span<SphereContact>(&c, 1));
  EXPECT_TRUE(c.touching);
  EXPECT_FALSE(c.centre_outside);
  EXPECT_NEAR(c.distance, 0.1e-3, 0.02e-3);
  // The outcome reports it, and its balloon as removed.
  const ProcedureOutcome o = procedure_outcome(md.procedure, md.tree, sim.state().procedure);
  ASSERT_EQ(o.stents.size(), 1u);
  EXPECT_TRUE(o.stents[0].deployed);
  EXPECT_EQ(o.stents[0].lesion, 0);
  ASSERT_EQ(o.balloons.size(), 1u);
  EXPECT_TRUE(o.balloons[0].removed);
  EXPECT_GT(o.balloons[0].max_pressure, 9.0 * kAtm);
  EXPECT_GT(lumen_radius_now(md.procedure, md.tree, sim.state().procedure, 0, 0.066), 0.9 * ring)
      << "the lesion held open";
  // The wire pulled back 40 mm through it: the stent stays.
  h.to("wire", sim.depth(0) - 0.04, 0.02);
  EXPECT_NEAR(sim.state().procedure.stents[0].ring_s[mid], deployed.ring_s[mid], 0.2e-3);
  EXPECT_EQ(sim.metrics().rollbacks, 0);
}

// The tube, the wire pushed and a balloon catheter added over it, advanced, inflated, withdrawn
// and removed by a timeline through run_loop.
const char* kExchangeTimeline = R"({"keyframes": [
  {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
  {"t_s": 2, "instruments": {"wire": {"translation_mm": 150, "rotation_deg": 0}}},
  {"t_s": 2.2, "add": {"name": "balloon", "catalogue": "balloon-sc-3.0x15", "over": "wire",
                       "max_nodes": 200}},
  {"t_s": 2.3, "instruments": {"balloon": {"translation_mm": 0, "rotation_deg": 0}}},
  {"t_s": 5, "instruments": {"balloon": {"translation_mm": BALLOON, "rotation_deg": 0}}},
  {"t_s": 5.2, "balloon_pressure_atm": 0},
  {"t_s": 5.5, "balloon_pressure_atm": 6},
  {"t_s": 5.8, "balloon_pressure_atm": 0},
  {"t_s": 7.5, "instruments": {"balloon": {"translation_mm": 0, "rotation_deg": 0}}},
  {"t_s": 7.7, "remove": "balloon"},
  {"t_s": 8}]})";

struct TimelineRun {
  std::uint64_t hash = 0;
  RunLoopStats stats;
  double max_pressure = 0.0;
  int instruments = 0;
  bool removed = false;
};

TimelineRun run_timeline(double balloon_mm) {
  std::string text = kExchangeTimeline;
  text.replace(text.find("BALLOON"), 7, std::to_string(balloon_mm));
  ScriptedTimeline tl = ScriptedTimeline::parse(text, "exchange-timeline.json");
  test::TubeSpecs t;
  Simulator sim(test::tube_scenario(scratch("timeline"), t, kWireOnly));
  tl.bind(sim.instrument_names());
  RunLoopSettings s;
  s.end_time = tl.duration();
  TimelineRun r;
  r.stats = run_loop(sim, tl, s);
  r.hash = sim.state().hash();
  r.instruments = sim.num_instruments();
  r.max_pressure = sim.state().procedure.balloons.at(0).max_pressure;
  r.removed = sim.model().procedure.balloons.at(0).removed();
  return r;
}

// The same timeline with the same exchanges gives the same final state hash; the balloon pushed
// 1 mm further gives another. The exchanges were made (two), the balloon inflated and left.
TEST(Exchange, TheSameExchangesAtTheSameTimesGiveTheSameState) {
  const TimelineRun a = run_timeline(115.0), b = run_timeline(115.0), c = run_timeline(116.0);
  EXPECT_EQ(a.stats.exchanges, 2);
  EXPECT_EQ(a.stats.refused_exchanges, 0);
  EXPECT_EQ(a.instruments, 1);
  EXPECT_TRUE(a.removed);
  EXPECT_NEAR(a.max_pressure, 6.0 * kAtm, 1e-6);
  EXPECT_EQ(a.hash, b.hash);
  EXPECT_NE(a.hash, c.hash);
}

// A run with exchanges recorded (CommandRecorder, as `vcsim run --record` does), written and read
// back, replays to the same state through a fresh simulator: the recording carries the exchanges.
TEST(Exchange, ARecordedRunWithExchangesReplaysToTheSameState) {
  std::string text = kExchangeTimeline;
  text.replace(text.find("BALLOON"), 7, "115");
  ScriptedTimeline tl = ScriptedTimeline::parse(text, "exchange-timeline.json");
  test::TubeSpecs t;
  const Scenario sc = test::tube_scenario(scratch("record"), t, kWireOnly);
  Simulator sim(sc);
  tl.bind(sim.instrument_names());
  CommandRecorder recorder(sim, "test");
  RunLoopSettings s;
  s.end_time = tl.duration();
  run_loop(sim, tl, s, &recorder);
  const CommandRecording& rec = recorder.finish(sim);
  ASSERT_EQ(rec.exchanges().size(), 2u);
  EXPECT_EQ(rec.state_hash, sim.state().hash());

  Simulator again(sc);
  RecordingReplay replay(CommandRecording::parse(rec.to_json(), "rec.json"),
                         again.instrument_names(), again.dt(), again.model().hash(), "rec.json");
  s.end_time = (static_cast<double>(rec.steps()) - 0.5) * again.dt();
  const RunLoopStats st = run_loop(again, replay, s);
  EXPECT_EQ(st.exchanges, 2);
  EXPECT_EQ(again.metrics().steps, rec.steps());
  EXPECT_EQ(again.state().hash(), rec.state_hash);
}

// A timeline that removes an instrument still in the patient is bad input: the refusal is thrown
// on from the run loop, naming the timeline's field.
TEST(Exchange, ATimelineRemovingAnInsertedInstrumentIsAnInputError) {
  ScriptedTimeline tl = ScriptedTimeline::parse(R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 20, "rotation_deg": 0}}},
    {"t_s": 0.2, "add": {"name": "w2", "catalogue": "wire-014-floppy"}},
    {"t_s": 0.3, "remove": "wire"},
    {"t_s": 0.5}]})",
                                                "bad-timeline.json");
  test::TubeSpecs t;
  Simulator sim(test::tube_scenario(scratch("timeline-bad"), t, kWireOnly));
  tl.bind(sim.instrument_names());
  RunLoopSettings s;
  s.end_time = tl.duration();
  try {
    run_loop(sim, tl, s);
    ADD_FAILURE() << "the removal was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), "bad-timeline.json");
    EXPECT_EQ(e.field(), "keyframes[2].remove");
    EXPECT_NE(std::string(e.what()).find("withdraw it first"), std::string::npos) << e.what();
  }
  EXPECT_EQ(sim.num_instruments(), 2) << "the add went through, the removal did not";
}

// A snapshot carries its model: taken before an exchange, restored after it, it brings back that
// scene (its instruments, its hash), and the same exchange and commands after it give the same
// states as the first time.
TEST(Exchange, ASnapshotTakenBeforeAnExchangeRestoresThatScene) {
  test::TubeSpecs t;
  Simulator sim(test::tube_scenario(scratch("snapshot"), t, kWireOnly));
  Hands h(sim);
  h.to("wire", 0.08);
  const SimState snap = sim.snapshot();
  auto after = [&] {
    h.exchange(add("balloon", "balloon-sc-3.0x15", "wire"));
    h.to("balloon", 0.03);
    return sim.state().hash();
  };
  const std::uint64_t first = after();
  ASSERT_EQ(sim.num_instruments(), 2);
  sim.restore(snap);
  EXPECT_EQ(sim.num_instruments(), 1);
  EXPECT_EQ(&sim.model(), snap.model.get());
  EXPECT_EQ(sim.state().hash(), snap.hash());
  h.hold();
  EXPECT_EQ(after(), first);
}

// The autopilot exchanges the 0.035" wire in the default patient (not beating, for speed): the J
// wire leads the JL4 into the ascending aorta and is withdrawn; removed, an angled wire is added
// in the catheter, which the autopilot then navigates by name into the ascending aorta. Both
// landmarks are reached (the second names an instrument the plan adds), and a landmark of the
// removed J wire that it never reached stays missed. Six seconds in release, a minute and a half
// under the sanitizers, where the exchanges are covered by the short tests above: skipped there.
TEST(Exchange, TheAutopilotExchangesAWireAndNavigatesTheNewOne) {
#if defined(VCSIM_SANITIZE)
  GTEST_SKIP() << "a navigation in the default patient; too slow under the sanitizers";
#endif
  Scenario sc =
      parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "wire-exchange",
    "motion": {"beating": false}, "dt_ms": 0.5, "time_limit_s": 30,
    "instruments": [
      {"name": "catheter", "catalogue": "catheter-jl4-6f", "tip_segment_mm": 2},
      {"name": "j_wire", "catalogue": "wire-035-j3-hydrophilic", "inside": "catheter",
       "rim": false, "tip_segment_mm": 2}],
    "autopilot": [
      {"action": "navigate", "instrument": "j_wire",
       "goal": {"segment": "ascending_aorta", "distance_mm": 10},
       "follower": "catheter", "follow_gap_mm": 40, "speed_mm_s": 150},
      {"action": "withdraw", "instrument": "j_wire", "depth_mm": 0, "speed_mm_s": 300},
      {"action": "remove", "instrument": "j_wire"},
      {"action": "add", "instrument": {"name": "wire2", "catalogue": "wire-035-angled-hydrophilic",
                                       "inside": "catheter", "rim": false, "tip_segment_mm": 2}},
      {"action": "navigate", "instrument": "wire2",
       "goal": {"segment": "ascending_aorta", "distance_mm": 20}, "speed_mm_s": 150},
      {"action": "wait", "duration_s": 0.2}],
    "landmarks": [
      {"name": "J wire in the aorta", "instrument": "j_wire", "segment": "ascending_aorta"},
      {"name": "J wire in the arch", "instrument": "j_wire", "segment": "ascending_aorta",
       "distance_mm": 80},
      {"name": "second wire in the aorta", "instrument": "wire2", "segment": "ascending_aorta",
       "distance_mm": 15}]})",
                     "wire-exchange.json");
  Simulator sim(sc);
  ASSERT_EQ(sim.model().landmark_ids[2].first, -1) << "not in the scene yet";
  Autopilot pilot(sim);
  AutopilotInput input(pilot, sim);
  struct Stop : RunObserver {
    Autopilot& p;
    explicit Stop(Autopilot& a) : p(a) {}
    bool before_step(const Simulator&, const StepCommands&) override { return !p.finished(); }
  } stop(pilot);
  RunLoopSettings s;
  s.end_time = sc.time_limit;
  const RunLoopStats st = run_loop(sim, input, s, &stop);
  EXPECT_FALSE(pilot.failed()) << pilot.status();
  EXPECT_EQ(st.exchanges, 2);
  ASSERT_EQ(sim.num_instruments(), 2);
  EXPECT_EQ(sim.model().instrument_name(1), "wire2");
  const auto& lm = sim.metrics().landmarks;
  EXPECT_TRUE(lm[0].reached);
  EXPECT_FALSE(lm[1].reached) << "the J wire left before it got there";
  EXPECT_TRUE(lm[2].reached);
  EXPECT_GT(lm[2].time, lm[0].time);
  EXPECT_GT(sim.depth(1), 0.3);
}

}  // namespace
}  // namespace vcsim
