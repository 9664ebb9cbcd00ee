// The scenario format (data/scenarios/*.json, docs/scenarios.md): units in key names, converted
// to SI at load; unknown keys are refused so that a typo is not silently ignored.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "json_fields.h"
#include "plan.h"
#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

using internal::cat;
using internal::JsonFields;
using Json = internal::Json;

// A number as a message shows it (%g: 1e-05, 3.6e+07, 0.5).
std::string num(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%g", v);
  return b;
}

// An instrument as instruments[] declares it (and an autopilot's add phase).
ScenarioInstrument parse_instrument(JsonFields& g) {
  ScenarioInstrument si;
  si.name = g.text("name");
  si.catalogue = g.text("catalogue");
  si.inside = g.text_or("inside", "");
  si.over = g.text_or("over", "");
  if (g.has("rim")) {
    if (si.inside.empty())
      g.fail("rim", "expected only with \"inside\" (the outer instrument's rim)");
    si.rim = g.boolean_or("rim", true);
  }
  si.max_nodes = g.integer_or("max_nodes", 16, 512, 256);
  si.tip_segment = g.in_range_or("tip_segment_mm", 0.1, 20.0, 1.0) * kMm;
  g.finish();
  return si;
}

AutopilotPhase parse_phase(const Json& j, const std::string& src, const std::string& path) {
  AutopilotPhase p;
  JsonFields f(j, src, path);
  const std::string action = f.text("action");
  if (action == "navigate") {
    p.kind = AutopilotPhase::Kind::kNavigate;
    p.instrument = f.text("instrument");
    JsonFields g = f.object("goal");
    p.goal_segment = g.text("segment");
    p.goal_distance = g.nonnegative_or("distance_mm", 0.0) * kMm;
    g.finish();
    p.tolerance = f.positive_or("tolerance_mm", 3.0) * kMm;
    p.seat = f.nonnegative_or("seat_mm", 0.0) * kMm;
    p.follower = f.text_or("follower", "");
    p.follow_gap = f.number_or("follow_gap_mm", 30.0) * kMm;
  } else if (action == "withdraw") {
    p.kind = AutopilotPhase::Kind::kWithdraw;
    p.instrument = f.text("instrument");
    p.depth = f.nonnegative_or("depth_mm", 0.0) * kMm;
    p.relative_to = f.text_or("relative_to", "");
  } else if (action == "inject") {
    p.kind = AutopilotPhase::Kind::kInject;
    p.flow = f.in_range("flow_ml_s", 0.0, 30.0) * kMl;
    p.duration = f.positive_or("duration_s", 2.0);
  } else if (action == "wait") {
    p.kind = AutopilotPhase::Kind::kWait;
    p.duration = f.positive_or("duration_s", 1.0);
  } else if (action == "place") {
    p.kind = AutopilotPhase::Kind::kPlace;
    p.instrument = f.text("instrument");
    p.lesion = f.integer_or("lesion", 0, 1000, 0);
    p.tolerance = f.positive_or("tolerance_mm", 1.0) * kMm;
    p.approach_speed = f.positive_or("approach_speed_mm_s", p.approach_speed / kMm) * kMm;
  } else if (action == "inflate") {
    p.kind = AutopilotPhase::Kind::kInflate;
    p.pressure = f.in_range("pressure_atm", 0.0, 30.0) * kAtm;
    p.ramp = f.nonnegative_or("ramp_s", 3.0);
    p.duration = f.nonnegative_or("hold_s", 10.0);
  } else if (action == "deflate") {
    p.kind = AutopilotPhase::Kind::kDeflate;
    p.duration = f.positive_or("duration_s", 3.0);
  } else if (action == "add") {
    p.kind = AutopilotPhase::Kind::kAdd;
    JsonFields g = f.object("instrument");
    p.added = parse_instrument(g);
    p.instrument = p.added.name;
  } else if (action == "remove") {
    p.kind = AutopilotPhase::Kind::kRemove;
    p.instrument = f.text("instrument");
  } else {
    f.fail("action",
           "expected navigate, withdraw, inject, wait, place, inflate, deflate, add or remove, "
           "got '" +
               action + "'");
  }
  p.speed = f.in_range_or("speed_mm_s", 0.0, 500.0, 100.0) * kMm;
  // Keys that the action does not use (a "goal" on a withdrawal) are refused here.
  f.finish();
  return p;
}

}  // namespace

const char* to_string(AutopilotPhase::Kind k) {
  switch (k) {
    case AutopilotPhase::Kind::kNavigate:
      return "navigate";
    case AutopilotPhase::Kind::kWithdraw:
      return "withdraw";
    case AutopilotPhase::Kind::kInject:
      return "inject";
    case AutopilotPhase::Kind::kWait:
      return "wait";
    case AutopilotPhase::Kind::kPlace:
      return "place";
    case AutopilotPhase::Kind::kInflate:
      return "inflate";
    case AutopilotPhase::Kind::kDeflate:
      return "deflate";
    case AutopilotPhase::Kind::kAdd:
      return "add";
    case AutopilotPhase::Kind::kRemove:
      return "remove";
  }
  return "?";
}

void ContrastSettings::validate(const std::string& source) const {
  require_positive(blood_flow, source, "contrast.blood_flow_ml_s");
  require_positive(blood_speed, source, "contrast.blood_speed_mm_s");
  require_positive(washout, source, "contrast.washout_s");
  require_in_range(concentration, 0.0, 1.0, source, "contrast.concentration");
}

int Scenario::find_instrument(std::string_view n) const {
  return find_instrument_in(instruments, n);
}

int find_instrument_in(std::span<const ScenarioInstrument> list, std::string_view name) {
  for (std::size_t i = 0; i < list.size(); ++i)
    if (list[i].name == name) return static_cast<int>(i);
  return -1;
}

void validate_instruments(std::span<const ScenarioInstrument> list, const std::string& src,
                          const std::function<std::string(int)>& field_of) {
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string field = field_of(static_cast<int>(i));
    if (list[i].name.empty()) throw InputError(src, field + ".name", "expected a name");
    if (find_instrument_in(list.first(i), list[i].name) >= 0)
      throw InputError(src, field + ".name",
                       "expected a unique name, '" + list[i].name + "' repeats");
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string& in = list[i].inside;
    if (in.empty()) continue;
    const std::string field = field_of(static_cast<int>(i)) + ".inside";
    const int o = find_instrument_in(list, in);
    if (o < 0 || o == static_cast<int>(i))
      throw InputError(src, field, "expected the name of another instrument, got '" + in + "'");
    if (!list[o].inside.empty())
      throw InputError(src, field,
                       "expected an outermost instrument ('" + in + "' is itself inside '" +
                           list[o].inside + "')");
  }
  for (std::size_t i = 0; i < list.size(); ++i) {
    const ScenarioInstrument& si = list[i];
    if (si.over.empty()) continue;
    const std::string field = field_of(static_cast<int>(i)) + ".over";
    const int w = find_instrument_in(list, si.over);
    if (w < 0 || w == static_cast<int>(i))
      throw InputError(src, field,
                       "expected the name of another instrument, got '" + si.over + "'");
    if (list[w].inside != si.inside)
      throw InputError(src, field,
                       "expected a wire in the same outer instrument as this one ('" + si.over +
                           "' is inside '" + list[w].inside + "', this inside '" + si.inside +
                           "')");
  }
}

namespace internal {

void walk_plan(
    const Scenario& sc,
    const std::function<void(std::size_t, const std::vector<ScenarioInstrument>&)>& visit) {
  std::vector<ScenarioInstrument> scene = sc.instruments;
  for (std::size_t k = 0; k < sc.autopilot.size(); ++k) {
    const AutopilotPhase& ph = sc.autopilot[k];
    const std::string path = index_path("autopilot", k);
    const bool add = ph.kind == AutopilotPhase::Kind::kAdd;
    if (add) {
      if (find_instrument_in(scene, ph.instrument) >= 0)
        throw InputError(sc.source, path + ".instrument.name",
                         "expected a name not in the scene then, got '" + ph.instrument + "'");
      std::vector<ScenarioInstrument> next = scene;
      next.push_back(ph.added);
      validate_instruments(next, sc.source, [&](int i) {
        return i + 1 == static_cast<int>(next.size()) ? path + ".instrument"
                                                      : index_path("instruments", i);
      });
    }
    for (const std::string* name : {&ph.instrument, &ph.follower, &ph.relative_to})
      if (!add && !name->empty() && find_instrument_in(scene, *name) < 0)
        throw InputError(
            sc.source, path,
            "expected an instrument of the scenario (in the scene then), got '" + *name + "'");
    visit(k, scene);
    if (add) scene.push_back(ph.added);
    if (ph.kind == AutopilotPhase::Kind::kRemove) {
      const int r = find_instrument_in(scene, ph.instrument);
      scene.erase(scene.begin() + r);
      if (scene.empty())
        throw InputError(sc.source, path + ".instrument",
                         "expected an instrument left in the scene (add another first)");
      for (const ScenarioInstrument& si : scene)
        if (si.inside == ph.instrument || si.over == ph.instrument)
          throw InputError(
              sc.source, path + ".instrument",
              "expected an instrument nothing is inside or over ('" + si.name + "' is)");
    }
  }
}

std::vector<std::string> plan_additions(const Scenario& sc) {
  std::vector<std::string> names;
  for (const AutopilotPhase& ph : sc.autopilot)
    if (ph.kind == AutopilotPhase::Kind::kAdd) names.push_back(ph.instrument);
  return names;
}

}  // namespace internal

ScenarioInstrument to_scenario_instrument(const InstrumentChange& c) {
  ScenarioInstrument si;
  si.name = c.name;
  si.catalogue = c.catalogue;
  si.inside = c.inside;
  si.over = c.over;
  si.rim = c.rim;
  si.max_nodes = c.max_nodes;
  si.tip_segment = c.tip_segment;
  return si;
}

void check_run_steps(double dt, double time_limit, const std::string& source,
                     const std::string& field) {
  if (time_limit / dt > kMaxRunSteps * (1.0 + 1e-12))  // 3600 s / 0.1 ms is allowed
    throw InputError(source, field,
                     cat("expected at most ", num(kMaxRunSteps), " steps (time limit / dt), got ",
                         num(time_limit), " s / ", num(dt * 1e3), " ms = ", num(time_limit / dt)));
}

Scenario parse_scenario(std::string_view text, const std::string& src,
                        const std::filesystem::path& base_dir) {
  const Json j = internal::parse_json_text(text, src);
  JsonFields f(j, src, "");
  if (f.text("format") != "vcsim-scenario") f.fail("format", "expected \"vcsim-scenario\"");
  if (f.number("version") != 1.0) f.fail("version", "expected 1");
  Scenario sc;
  sc.source = src;
  sc.base_dir = base_dir;
  sc.name = f.text("name");
  sc.description = f.text_or("description", "");
  sc.anatomy = f.text_or("anatomy", "default");
  sc.centrelines = f.text_or("centrelines", "");
  sc.mesh_unit = f.in_range_or("mesh_unit_mm", 1e-3, 1e3, 1.0) * kMm;
  if (f.has("inlet_mm")) {
    const Json& a = f.array("inlet_mm");
    if (a.size() != 3) f.fail("inlet_mm", "expected [x, y, z] in the mesh's unit");
    Vec3 p;
    for (int k = 0; k < 3; ++k)
      p[k] = f.as_number(a[static_cast<std::size_t>(k)], "inlet_mm[" + std::to_string(k) + "]");
    if (!p.allFinite()) f.fail("inlet_mm", "expected finite numbers");
    sc.inlet = p * sc.mesh_unit;
  }
  if (is_mesh_file(sc.anatomy) && sc.centrelines.empty() && !sc.inlet)
    f.fail("centrelines",
           "expected the centrelines of the mesh '" + sc.anatomy +
               "' (a vcsim-anatomy JSON or a SimVascular .pth), or \"inlet_mm\": a point near "
               "the opening where instruments go in, to compute them from the mesh");
  if ((!sc.centrelines.empty() || sc.inlet) && !is_mesh_file(sc.anatomy))
    f.fail(sc.inlet ? "inlet_mm" : "centrelines",
           "expected only with an anatomy that is a mesh (.stl, .obj, .ply)");
  if (f.has("motion")) {
    JsonFields m = f.object("motion");
    sc.beating = m.boolean_or("beating", true);
    sc.motion.heart_rate_bpm = m.number_or("heart_rate_bpm", sc.motion.heart_rate_bpm);
    sc.motion.respiration = m.boolean_or("respiration", false);
    sc.motion.respiratory_rate_per_min =
        m.number_or("respiratory_rate_per_min", sc.motion.respiratory_rate_per_min);
    m.finish();
    sc.motion.validate(src + ": motion");
  }
  sc.dt = f.in_range_or("dt_ms", 0.0, 1.0, 1.0) * 1e-3;
  if (sc.dt < kMinScenarioDt * (1.0 - 1e-12))  // 0.01 ms itself (rounded) is allowed
    f.fail("dt_ms", cat("expected a step of at least ", num(kMinScenarioDt * 1e3), " ms, got ",
                        num(sc.dt * 1e3)));
  sc.time_limit = f.in_range_or("time_limit_s", 0.0, 3600.0, 60.0);
  check_run_steps(sc.dt, sc.time_limit, src, f.has("time_limit_s") ? "time_limit_s" : "dt_ms");
  sc.stop_on_escape = f.boolean_or("stop_on_escape", false);
  if (f.has("seed")) {
    const double seed = f.number("seed");
    if (seed < 0 || seed > 9007199254740992.0 || seed != std::floor(seed))
      f.fail("seed", "expected a whole number from 0 to 2^53");
    sc.seed = static_cast<std::uint64_t>(seed);
  }
  sc.sheath_length = f.in_range_or("sheath_length_mm", 0.0, 300.0, 25.0) * kMm;
  if (f.has("fine_steps")) {
    const double n = f.in_range("fine_steps", 0.0, 16.0);
    if (n != std::floor(n)) f.fail("fine_steps", "expected a whole number from 1 to 16");
    sc.fine_steps = static_cast<int>(n);
  }
  sc.fine_step_speed = f.in_range_or("fine_step_speed_mm_s", 0.0, 1000.0, 130.0) * kMm;
  sc.fine_step_travel = f.in_range_or("fine_step_travel_um", 0.0, 1000.0, 25.0) * kUm;
  sc.fine_step_jump = f.nonnegative_or("fine_step_jump_n", 0.3);
  sc.fine_step_hold = f.in_range_or("fine_step_hold_ms", 0.0, 1000.0, 20.0) * 1e-3;
  sc.runaway_speed = f.in_range_or("runaway_speed_m_s", 0.0, 1000.0, 30.0);

  const Json& insts = f.array("instruments");
  if (insts.empty()) f.fail("instruments", "expected at least one instrument");
  for (std::size_t i = 0; i < insts.size(); ++i) {
    JsonFields g(insts[i], src, internal::index_path("instruments", i));
    sc.instruments.push_back(parse_instrument(g));
  }
  validate_instruments(sc.instruments, src,
                       [](int i) { return internal::index_path("instruments", i); });
  if (f.has("targets")) {
    JsonFields g = f.object("targets");
    if (g.has("residual_stenosis_percent"))
      sc.targets.residual_stenosis = g.in_range("residual_stenosis_percent", 0.0, 100.0) / 100.0;
    sc.targets.stent_covers_lesion = g.boolean_or("stent_covers_lesion", false);
    g.finish();
  }
  if (f.has("lesions")) {
    const Json& ls = f.array("lesions");
    for (std::size_t i = 0; i < ls.size(); ++i) {
      JsonFields g(ls[i], src, internal::index_path("lesions", i));
      LesionMechanics lm;
      lm.opening_pressure =
          g.in_range_or("opening_pressure_atm", 0.0, 30.0, lm.opening_pressure / kAtm) * kAtm;
      lm.recoil = g.number_or("recoil", lm.recoil);
      if (!(lm.recoil >= 0.0 && lm.recoil < 1.0)) g.fail("recoil", "expected a fraction in [0, 1)");
      lm.crossing_force = g.in_range_or("crossing_force_n", 0.0, 100.0, lm.crossing_force);
      lm.crossing_rate =
          g.in_range_or("crossing_rate_mm_s", 0.0, 100.0, lm.crossing_rate / kMm) * kMm;
      g.finish();
      sc.lesions.push_back(lm);
    }
  }

  std::string input = "autopilot";
  if (f.has("input")) {
    JsonFields in = f.object("input");
    input = in.text("type");
    if (input == "timeline") {
      sc.timeline = in.text("file");
    } else if (input != "autopilot") {
      in.fail("type", "expected autopilot or timeline, got '" + input + "'");
    }
    in.finish();
  }
  if (f.has("autopilot")) {
    const Json& ap = f.array("autopilot");
    for (std::size_t i = 0; i < ap.size(); ++i)
      sc.autopilot.push_back(parse_phase(ap[i], src, internal::index_path("autopilot", i)));
    // Each phase names instruments in the scene when it starts (add and remove phases change it).
    internal::walk_plan(sc, [](std::size_t, const std::vector<ScenarioInstrument>&) {});
  }
  const std::vector<std::string> added = internal::plan_additions(sc);
  if (f.has("landmarks")) {
    const Json& lm = f.array("landmarks");
    for (std::size_t i = 0; i < lm.size(); ++i) {
      JsonFields g(lm[i], src, internal::index_path("landmarks", i));
      Landmark l;
      l.name = g.text("name");
      l.instrument = g.text("instrument");
      if (sc.find_instrument(l.instrument) < 0 &&
          std::find(added.begin(), added.end(), l.instrument) == added.end())
        g.fail("instrument",
               "expected an instrument of the scenario (or one its autopilot adds), got '" +
                   l.instrument + "'");
      l.segment = g.text("segment");
      l.distance = g.nonnegative_or("distance_mm", 0.0) * kMm;
      g.finish();
      sc.landmarks.push_back(l);
    }
  }
  if (f.has("contrast")) {
    JsonFields c = f.object("contrast");
    if (c.has("blood_flow_ml_s")) sc.contrast.blood_flow = c.number("blood_flow_ml_s") * kMl;
    sc.contrast.blood_speed = c.number_or("blood_speed_mm_s", sc.contrast.blood_speed / kMm) * kMm;
    sc.contrast.washout = c.number_or("washout_s", sc.contrast.washout);
    sc.contrast.concentration = c.number_or("concentration", sc.contrast.concentration);
    c.finish();
  }
  sc.contrast.validate(src);
  if (f.has("fluoroscopy")) {
    JsonFields v = f.object("fluoroscopy");
    FluoroSettings& fl = sc.fluoro;
    // Angles and field are checked against the C-arm's limits by the renderer (CArmPose).
    fl.primary_deg = v.number_or("primary_deg", fl.primary_deg);
    fl.secondary_deg = v.number_or("secondary_deg", fl.secondary_deg);
    fl.fov_mm = v.number_or("fov_mm", fl.fov_mm);
    fl.size = v.integer_or("size", 16, 4096, fl.size);
    if (fl.size != 512 && fl.size != 1024) v.fail("size", "expected 512 or 1024");
    fl.dose = v.nonnegative_or("dose", fl.dose);
    fl.energy_kev = v.integer_or("energy_kev", 0, 1000, fl.energy_kev);
    if (fl.energy_kev != 60 && fl.energy_kev != 80) v.fail("energy_kev", "expected 60 or 80");
    fl.fps = v.in_range_or("fps", 0.0, 60.0, fl.fps);
    fl.follow_tip = v.boolean_or("follow_tip", false);
    v.finish();
  }
  if (f.has("feedback")) {
    JsonFields fb = f.object("feedback");
    const std::string kind = fb.text_or("hand_force", "quasi-static");
    if (kind == "impulses") {
      sc.feedback.hand_force = SolverSettings::HandForce::kImpulses;
    } else if (kind != "quasi-static") {
      fb.fail("hand_force", "expected quasi-static or impulses, got '" + kind + "'");
    }
    sc.feedback.cutoff_hz = fb.nonnegative_or("cutoff_hz", sc.feedback.cutoff_hz);
    fb.finish();
  }
  // Unknown keys first: a misspelt "autopilot" is named as such, not reported as a missing plan.
  f.finish();
  if (input == "autopilot" && sc.autopilot.empty())
    f.fail("autopilot", "expected a plan of at least one phase (input: autopilot)");
  return sc;
}

Scenario load_scenario(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string(), "file", "expected a readable scenario file");
  std::ostringstream ss;
  ss << in.rdbuf();
  return parse_scenario(ss.str(), file.string(), file.parent_path());
}

std::filesystem::path default_scenarios_dir() {
  if (const char* d = std::getenv("VCSIM_SCENARIOS_DIR"); d && *d) return d;
  return VCSIM_DEFAULT_SCENARIOS_DIR;
}

std::filesystem::path find_scenario(const std::string& arg, const std::string& source,
                                    const std::string& field) {
  const std::filesystem::path p(arg);
  if (std::filesystem::exists(p)) return p;
  const std::filesystem::path named = default_scenarios_dir() / (arg + ".json");
  if (p.extension().empty() && std::filesystem::exists(named)) return named;
  throw InputError(source, field,
                   "expected a scenario file or a name in " + default_scenarios_dir().string() +
                       ", got '" + arg + "'");
}

}  // namespace vcsim
