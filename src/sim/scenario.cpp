// The scenario format (data/scenarios/*.json, docs/scenarios.md): units in key names, converted
// to SI at load; unknown keys are refused so that a typo is not silently ignored.
#include <cstdlib>
#include <fstream>
#include <initializer_list>
#include <nlohmann/json.hpp>
#include <sstream>

#include "vcsim/sim.h"

namespace vcsim {

namespace {

using nlohmann::json;
constexpr double kMm = 1e-3;

// Reads fields of one JSON object, naming them "parent.key" in errors.
class Fields {
 public:
  Fields(const json& j, std::string src, std::string path, std::initializer_list<const char*> keys)
      : j_(j), src_(std::move(src)), path_(std::move(path)) {
    if (!j.is_object()) throw InputError(src_, where(), "expected an object");
    for (auto it = j.begin(); it != j.end(); ++it) {
      bool ok = false;
      std::string list;
      for (const char* k : keys) {
        ok = ok || it.key() == k;
        list += list.empty() ? "" : ", ";
        list += k;
      }
      if (!ok) throw InputError(src_, name(it.key()), "unknown key; expected one of " + list);
    }
  }
  bool has(const char* k) const { return j_.contains(k); }
  std::string name(const std::string& k) const { return path_.empty() ? k : path_ + "." + k; }
  const json& need(const char* k) const {
    if (!has(k)) throw InputError(src_, name(k), "missing");
    return j_.at(k);
  }
  double number(const char* k, double fallback) const { return has(k) ? number(k) : fallback; }
  double number(const char* k) const {
    const json& v = need(k);
    if (!v.is_number()) throw InputError(src_, name(k), "expected a number");
    return require_finite(v.get<double>(), src_, name(k));
  }
  double positive(const char* k, double fallback) const {
    return require_positive(number(k, fallback), src_, name(k));
  }
  double nonnegative(const char* k, double fallback) const {
    return require_nonnegative(number(k, fallback), src_, name(k));
  }
  int integer(const char* k, int fallback, int lo, int hi) const {
    if (!has(k)) return fallback;
    const json& v = need(k);
    if (!v.is_number_integer() || v.get<long long>() < lo || v.get<long long>() > hi)
      throw InputError(
          src_, name(k),
          "expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
    return static_cast<int>(v.get<long long>());
  }
  std::string text(const char* k, const std::string& fallback) const {
    return has(k) ? text(k) : fallback;
  }
  std::string text(const char* k) const {
    const json& v = need(k);
    if (!v.is_string() || v.get<std::string>().empty())
      throw InputError(src_, name(k), "expected a non-empty string");
    return v.get<std::string>();
  }
  bool boolean(const char* k, bool fallback) const {
    if (!has(k)) return fallback;
    if (!need(k).is_boolean()) throw InputError(src_, name(k), "expected true or false");
    return need(k).get<bool>();
  }
  const json& array(const char* k) const {
    const json& v = need(k);
    if (!v.is_array()) throw InputError(src_, name(k), "expected an array");
    return v;
  }
  const std::string& src() const { return src_; }

 private:
  std::string where() const { return path_.empty() ? "json" : path_; }
  const json& j_;
  std::string src_, path_;
};

std::string at(const std::string& base, std::size_t i) {
  return base + "[" + std::to_string(i) + "]";
}

AutopilotPhase parse_phase(const json& j, const std::string& src, const std::string& path) {
  AutopilotPhase p;
  const Fields f(
      j, src, path,
      {"action", "instrument", "goal", "tolerance_mm", "seat_mm", "follower", "follow_gap_mm",
       "depth_mm", "relative_to", "flow_ml_s", "duration_s", "speed_mm_s"});
  const std::string action = f.text("action");
  if (action == "navigate") {
    p.kind = AutopilotPhase::Kind::kNavigate;
    p.instrument = f.text("instrument");
    const Fields g(f.need("goal"), src, f.name("goal"), {"segment", "distance_mm"});
    p.goal_segment = g.text("segment");
    p.goal_distance = g.nonnegative("distance_mm", 0.0) * kMm;
    p.tolerance = f.positive("tolerance_mm", 3.0) * kMm;
    p.seat = f.nonnegative("seat_mm", 0.0) * kMm;
    p.follower = f.text("follower", "");
    p.follow_gap = f.number("follow_gap_mm", 30.0) * kMm;
  } else if (action == "withdraw") {
    p.kind = AutopilotPhase::Kind::kWithdraw;
    p.instrument = f.text("instrument");
    p.depth = f.nonnegative("depth_mm", 0.0) * kMm;
    p.relative_to = f.text("relative_to", "");
  } else if (action == "inject") {
    p.kind = AutopilotPhase::Kind::kInject;
    p.flow = require_in_range(f.number("flow_ml_s"), 0.0, 30.0, src, f.name("flow_ml_s"));
    p.duration = f.positive("duration_s", 2.0);
  } else if (action == "wait") {
    p.kind = AutopilotPhase::Kind::kWait;
    p.duration = f.positive("duration_s", 1.0);
  } else {
    throw InputError(src, f.name("action"),
                     "expected navigate, withdraw, inject or wait, got '" + action + "'");
  }
  p.speed =
      require_in_range(f.number("speed_mm_s", 100.0), 0.0, 500.0, src, f.name("speed_mm_s")) * kMm;
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
  for (std::size_t i = 0; i < instruments.size(); ++i)
    if (instruments[i].name == n) return static_cast<int>(i);
  return -1;
}

Scenario parse_scenario(std::string_view text, const std::string& src,
                        const std::filesystem::path& base_dir) {
  json j;
  try {
    j = json::parse(text.begin(), text.end());
  } catch (const json::parse_error& e) {
    throw InputError(src, "json", std::string("expected valid JSON: ") + e.what());
  }
  const Fields f(
      j, src, "",
      {"format", "version", "name", "description", "anatomy", "motion", "dt_ms", "time_limit_s",
       "instruments", "input", "autopilot", "landmarks", "contrast", "fluoroscopy"});
  if (f.text("format") != "vcsim-scenario")
    throw InputError(src, "format", "expected \"vcsim-scenario\"");
  if (f.number("version") != 1.0) throw InputError(src, "version", "expected 1");
  Scenario sc;
  sc.source = src;
  sc.base_dir = base_dir;
  sc.name = f.text("name");
  sc.description = f.text("description", "");
  sc.anatomy = f.text("anatomy", "default");
  if (f.has("motion")) {
    const Fields m(f.need("motion"), src, "motion",
                   {"beating", "heart_rate_bpm", "respiration", "respiratory_rate_per_min"});
    sc.beating = m.boolean("beating", true);
    sc.motion.heart_rate_bpm = m.number("heart_rate_bpm", sc.motion.heart_rate_bpm);
    sc.motion.respiration = m.boolean("respiration", false);
    sc.motion.respiratory_rate_per_min =
        m.number("respiratory_rate_per_min", sc.motion.respiratory_rate_per_min);
    sc.motion.validate(src + ": motion");
  }
  sc.dt = require_in_range(f.number("dt_ms", 1.0), 0.0, 1.0, src, "dt_ms") * 1e-3;
  sc.time_limit =
      require_in_range(f.number("time_limit_s", 60.0), 0.0, 3600.0, src, "time_limit_s");

  const json& insts = f.array("instruments");
  if (insts.empty()) throw InputError(src, "instruments", "expected at least one instrument");
  for (std::size_t i = 0; i < insts.size(); ++i) {
    const std::string p = at("instruments", i);
    const Fields g(insts[i], src, p,
                   {"name", "catalogue", "inside", "max_nodes", "tip_segment_mm"});
    ScenarioInstrument si;
    si.name = g.text("name");
    si.catalogue = g.text("catalogue");
    si.inside = g.text("inside", "");
    si.max_nodes = g.integer("max_nodes", 256, 16, 512);
    si.tip_segment = require_in_range(g.number("tip_segment_mm", 1.0), 0.1, 20.0, src,
                                      g.name("tip_segment_mm")) *
                     kMm;
    if (sc.find_instrument(si.name) >= 0)
      throw InputError(src, g.name("name"), "expected a unique name, '" + si.name + "' repeats");
    sc.instruments.push_back(si);
  }
  for (std::size_t i = 0; i < sc.instruments.size(); ++i) {
    const std::string& in = sc.instruments[i].inside;
    if (in.empty()) continue;
    const int o = sc.find_instrument(in);
    if (o < 0 || o == static_cast<int>(i))
      throw InputError(src, at("instruments", i) + ".inside",
                       "expected the name of another instrument, got '" + in + "'");
    if (!sc.instruments[o].inside.empty())
      throw InputError(src, at("instruments", i) + ".inside",
                       "expected an outermost instrument ('" + in + "' is itself inside '" +
                           sc.instruments[o].inside + "')");
  }

  std::string input = "autopilot";
  if (f.has("input")) {
    const Fields in(f.need("input"), src, "input", {"type", "file"});
    input = in.text("type");
    if (input == "timeline") {
      sc.timeline = in.text("file");
    } else if (input != "autopilot") {
      throw InputError(src, "input.type", "expected autopilot or timeline, got '" + input + "'");
    }
  }
  if (f.has("autopilot")) {
    const json& ap = f.array("autopilot");
    for (std::size_t i = 0; i < ap.size(); ++i) {
      AutopilotPhase ph = parse_phase(ap[i], src, at("autopilot", i));
      for (const std::string* name : {&ph.instrument, &ph.follower, &ph.relative_to})
        if (!name->empty() && sc.find_instrument(*name) < 0)
          throw InputError(src, at("autopilot", i),
                           "expected an instrument of the scenario, got '" + *name + "'");
      sc.autopilot.push_back(ph);
    }
  }
  if (input == "autopilot" && sc.autopilot.empty())
    throw InputError(src, "autopilot", "expected a plan of at least one phase (input: autopilot)");

  if (f.has("landmarks")) {
    const json& lm = f.array("landmarks");
    for (std::size_t i = 0; i < lm.size(); ++i) {
      const std::string p = at("landmarks", i);
      const Fields g(lm[i], src, p, {"name", "instrument", "segment", "distance_mm"});
      Landmark l;
      l.name = g.text("name");
      l.instrument = g.text("instrument");
      if (sc.find_instrument(l.instrument) < 0)
        throw InputError(src, g.name("instrument"),
                         "expected an instrument of the scenario, got '" + l.instrument + "'");
      l.segment = g.text("segment");
      l.distance = g.nonnegative("distance_mm", 0.0) * kMm;
      sc.landmarks.push_back(l);
    }
  }
  if (f.has("contrast")) {
    const Fields c(f.need("contrast"), src, "contrast",
                   {"blood_flow_ml_s", "blood_speed_mm_s", "washout_s", "concentration"});
    sc.contrast.blood_flow = c.number("blood_flow_ml_s", sc.contrast.blood_flow);
    sc.contrast.blood_speed = c.number("blood_speed_mm_s", sc.contrast.blood_speed / kMm) * kMm;
    sc.contrast.washout = c.number("washout_s", sc.contrast.washout);
    sc.contrast.concentration = c.number("concentration", sc.contrast.concentration);
  }
  sc.contrast.validate(src);
  if (f.has("fluoroscopy")) {
    const Fields v(f.need("fluoroscopy"), src, "fluoroscopy",
                   {"primary_deg", "secondary_deg", "fov_mm", "size", "dose", "energy_kev", "fps",
                    "follow_tip"});
    FluoroSettings& fl = sc.fluoro;
    // Angles and field are checked against the C-arm's limits by the renderer (CArmPose).
    fl.primary_deg = v.number("primary_deg", fl.primary_deg);
    fl.secondary_deg = v.number("secondary_deg", fl.secondary_deg);
    fl.fov_mm = v.number("fov_mm", fl.fov_mm);
    fl.size = v.integer("size", fl.size, 16, 4096);
    if (fl.size != 512 && fl.size != 1024)
      throw InputError(src, "fluoroscopy.size", "expected 512 or 1024");
    fl.dose = v.nonnegative("dose", fl.dose);
    fl.energy_kev = v.integer("energy_kev", fl.energy_kev, 0, 1000);
    if (fl.energy_kev != 60 && fl.energy_kev != 80)
      throw InputError(src, "fluoroscopy.energy_kev", "expected 60 or 80");
    fl.fps = require_in_range(v.number("fps", fl.fps), 0.0, 60.0, src, "fluoroscopy.fps");
    fl.follow_tip = v.boolean("follow_tip", false);
  }
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

}  // namespace vcsim
