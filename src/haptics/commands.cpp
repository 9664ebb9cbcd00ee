// Command types shared by every input source, and the scripted timeline.
#include <algorithm>
#include <cmath>
#include <fstream>
#include <map>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "json_fields.h"
#include "vcsim/haptics.h"
#include "vcsim/units.h"

namespace vcsim {

using internal::cat;
using internal::Json;
using internal::JsonFields;

const char* to_string(InstrumentCommand::Mode m) {
  return m == InstrumentCommand::Mode::kPosition ? "position" : "velocity";
}

namespace {
std::string num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}
}  // namespace

const char* to_string(InstrumentChange::Kind k) {
  return k == InstrumentChange::Kind::kAdd ? "add" : "remove";
}

std::string describe(const InstrumentChange& c) {
  if (c.kind == InstrumentChange::Kind::kRemove) return cat("remove ", c.name);
  std::string s = cat("add ", c.name, " ", c.catalogue);
  if (!c.inside.empty()) s += cat(" inside=", c.inside);
  if (!c.over.empty()) s += cat(" over=", c.over);
  return s;
}

std::string parse_exchange_request(std::string_view text, InstrumentChange& out) {
  std::istringstream in{std::string(text)};
  std::vector<std::string> w;
  for (std::string word; in >> word;) w.push_back(word);
  const std::string grammar =
      "expected \"add NAME CATALOGUE [inside=X] [over=Y]\" or \"remove NAME\"";
  out = InstrumentChange{};
  if (w.size() == 2 && w[0] == "remove") {
    out.kind = InstrumentChange::Kind::kRemove;
    out.name = w[1];
    return {};
  }
  if (w.size() < 3 || w.size() > 5 || w[0] != "add") return grammar;
  out.kind = InstrumentChange::Kind::kAdd;
  out.name = w[1];
  out.catalogue = w[2];
  for (std::size_t k = 3; k < w.size(); ++k) {
    const std::string& o = w[k];
    std::string* to = o.rfind("inside=", 0) == 0 ? &out.inside
                      : o.rfind("over=", 0) == 0 ? &out.over
                                                 : nullptr;
    if (!to || !to->empty()) return cat(grammar, ", got \"", o, "\"");
    *to = o.substr(o.find('=') + 1);
    if (to->empty()) return cat("expected a name after \"", o, "\"");
  }
  return {};
}

DriveCommand to_drive_command(const InstrumentCommand& c) {
  DriveCommand d;
  d.mode = c.mode == InstrumentCommand::Mode::kPosition ? DriveCommand::Mode::kPosition
                                                        : DriveCommand::Mode::kVelocity;
  d.translation = c.translation_mm * kMm;
  d.rotation = c.rotation_deg * kDeg;
  return d;
}

std::string CommandLimits::check(const InstrumentCommand& c) const {
  if (!std::isfinite(c.translation_mm) || !std::isfinite(c.rotation_deg)) {
    return "expected finite numbers";
  }
  const bool pos = c.mode == InstrumentCommand::Mode::kPosition;
  const double lt = pos ? max_translation_mm : max_speed_mm_s;
  const double lr = pos ? max_rotation_deg : max_spin_deg_s;
  if (std::abs(c.translation_mm) > lt) {
    return cat(pos ? "expected a translation within +-" : "expected a speed within +-", num(lt),
               pos ? " mm, got " : " mm/s, got ", num(c.translation_mm));
  }
  if (std::abs(c.rotation_deg) > lr) {
    return cat(pos ? "expected a rotation within +-" : "expected a spin within +-", num(lr),
               pos ? " deg, got " : " deg/s, got ", num(c.rotation_deg));
  }
  return {};
}

// ---- scripted timeline ----

namespace {

// A keyframe's "add": an instrument as a scenario's instruments[] declares it.
InstrumentChange parse_added(JsonFields& a) {
  InstrumentChange c;
  c.kind = InstrumentChange::Kind::kAdd;
  c.name = a.text("name");
  if (c.name.size() > 14) a.fail("name", "expected an instrument name of 1-14 characters");
  c.catalogue = a.text("catalogue");
  c.inside = a.text_or("inside", "");
  c.over = a.text_or("over", "");
  if (a.has("rim")) {
    if (c.inside.empty())
      a.fail("rim", "expected only with \"inside\" (the outer instrument's rim)");
    c.rim = a.boolean_or("rim", true);
  }
  c.max_nodes = a.integer_or("max_nodes", 16, 512, 256);
  c.tip_segment = a.in_range_or("tip_segment_mm", 0.1, 20.0, 1.0) * kMm;
  a.finish();
  c.source = a.source();
  c.field = a.path();
  return c;
}

// The speed (mm/s) and spin (deg/s) a keyframe asks of the drive: its own in velocity mode, or
// in position mode the rate from the instrument's previous position keyframe (`from`, "" when
// there is none), interpolated linearly. Beyond what the drive follows they are refused here: the
// step would cap them silently.
void check_drive(JsonFields& c, double speed, double spin, const std::string& from,
                 const CommandLimits& limits) {
  if (std::abs(speed) > limits.drive_speed_mm_s)
    c.fail("translation_mm",
           cat("expected a speed the drive follows, within +-", num(limits.drive_speed_mm_s),
               " mm/s, got ", num(speed), " mm/s", from));
  if (std::abs(spin) > limits.drive_spin_deg_s)
    c.fail("rotation_deg",
           cat("expected a spin the drive follows, within +-", num(limits.drive_spin_deg_s),
               " deg/s, got ", num(spin), " deg/s", from));
}

}  // namespace

ScriptedTimeline ScriptedTimeline::parse(std::string_view json_text, const std::string& source,
                                         const CommandLimits& limits) {
  const Json doc = internal::parse_json_text(json_text, source);
  JsonFields root(doc, source, "");
  root.get("comment");
  const Json& frames = root.array("keyframes");
  root.finish();
  if (frames.empty()) root.fail("keyframes", "expected at least one keyframe");

  std::map<std::string, std::vector<Key>> tracks;  // sorted by name: a fixed output order
  ScriptedTimeline tl;
  double prev_t = -1.0;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    JsonFields k(frames[i], source, internal::index_path("keyframes", i));
    const double t = k.nonnegative("t_s");
    if (t <= prev_t)
      k.fail("t_s", cat("expected a time after the previous keyframe's ", num(prev_t)));
    prev_t = t;
    if (const Json* inst = k.get("instruments")) {
      const std::string ipath = k.field("instruments");
      JsonFields all(*inst, source, ipath);
      for (auto it = inst->begin(); it != inst->end(); ++it) {
        const std::string& name = it.key();
        JsonFields c(all.require(name.c_str()), source, internal::join_path(ipath, name));
        if (name.empty() || name.size() > 14) {
          throw InputError(source, c.path(), "expected an instrument name of 1-14 characters");
        }
        Key key;
        key.t = t;
        const std::string mode = c.string_or("mode", "position");
        if (mode == "velocity") {
          key.mode = InstrumentCommand::Mode::kVelocity;
        } else if (mode != "position") {
          c.fail("mode", cat("expected \"position\" or \"velocity\", got \"", mode, "\""));
        }
        key.translation = c.number("translation_mm");
        key.rotation = c.number("rotation_deg");
        c.finish();
        const std::string why = limits.check({name, key.mode, key.translation, key.rotation});
        if (!why.empty()) {
          const bool tr = why.find("translation") != std::string::npos ||
                          why.find("speed") != std::string::npos;
          c.fail(tr ? "translation_mm" : "rotation_deg", why);
        }
        const std::vector<Key>& before = tracks[name];
        if (key.mode == InstrumentCommand::Mode::kVelocity) {
          check_drive(c, key.translation, key.rotation, "", limits);
        } else if (!before.empty() && before.back().mode == InstrumentCommand::Mode::kPosition) {
          const Key& a = before.back();
          check_drive(c, (key.translation - a.translation) / (t - a.t),
                      (key.rotation - a.rotation) / (t - a.t),
                      cat(" from the previous keyframe at ", num(a.t), " s"), limits);
        }
        tracks[name].push_back(key);
      }
      all.finish();
    }
    if (k.has("balloon_pressure_atm")) {
      const double p = k.number("balloon_pressure_atm");
      if (p < 0 || p > limits.max_balloon_atm) {
        k.fail("balloon_pressure_atm", cat("expected a pressure in [0, ",
                                           num(limits.max_balloon_atm), "] atm, got ", num(p)));
      }
      tl.balloon_.push_back({t, p});
    }
    if (k.has("syringe_flow_ml_s")) {
      const double q = k.number("syringe_flow_ml_s");
      if (std::abs(q) > limits.max_syringe_ml_s) {
        k.fail("syringe_flow_ml_s", cat("expected a flow within +-", num(limits.max_syringe_ml_s),
                                        " ml/s, got ", num(q)));
      }
      tl.syringe_.push_back({t, q});
    }
    if (k.has("remove")) {
      InstrumentChange c;
      c.kind = InstrumentChange::Kind::kRemove;
      c.name = k.text("remove");
      c.source = source;
      c.field = k.field("remove");
      tl.exchanges_.push_back({t, c});
    }
    if (k.has("add")) {
      JsonFields a = k.object("add");
      tl.exchanges_.push_back({t, parse_added(a)});
    }
    if (k.has("buttons")) {
      const double b = k.number("buttons");
      if (b < 0 || b > 4294967295.0 || b != std::floor(b)) {
        k.fail("buttons", cat("expected an integer bit mask in [0, 2^32 - 1], got ", num(b)));
      }
      tl.buttons_.push_back({t, b});
    }
    k.finish();
  }
  for (auto& [name, keys] : tracks) {
    tl.names_.push_back(name);
    tl.tracks_.push_back(std::move(keys));
  }
  tl.duration_ = prev_t;
  tl.source_ = source;
  return tl;
}

ScriptedTimeline ScriptedTimeline::load(const std::filesystem::path& file,
                                        const CommandLimits& limits) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string(), "file", "expected a readable file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse(ss.str(), file.string(), limits);
}

double ScriptedTimeline::duration() const {
  return duration_;
}

bool ScriptedTimeline::inflates() const {
  for (const ScalarKey& k : balloon_)
    if (k.value > 0.0) return true;
  return false;
}

namespace {

// Index of the last key with time <= t, or -1.
template <typename K>
std::ptrdiff_t last_at(const std::vector<K>& keys, double t) {
  auto it =
      std::upper_bound(keys.begin(), keys.end(), t, [](double v, const K& k) { return v < k.t; });
  return (it - keys.begin()) - 1;
}

double lerp(double a, double b, double u) {
  return a + (b - a) * u;
}

}  // namespace

void ScriptedTimeline::bind(std::span<const std::string> instruments) {
  auto exchanged_here = [&](const std::string& name) {
    return std::any_of(exchanges_.begin(), exchanges_.end(),
                       [&](const TimedChange& e) { return e.change.name == name; });
  };
  for (const std::string& name : names_)
    if (std::find(instruments.begin(), instruments.end(), name) == instruments.end() &&
        !exchanged_here(name)) {
      std::string list;
      for (const std::string& n : instruments) list += (list.empty() ? "" : ", ") + n;
      throw InputError(source_, "keyframes",
                       cat("expected instruments of the scenario (", list, "), got '", name, "'"));
    }
  track_of_.assign(instruments.size(), -1);
  for (std::size_t i = 0; i < instruments.size(); ++i) {
    const auto it = std::find(names_.begin(), names_.end(), instruments[i]);
    if (it != names_.end()) track_of_[i] = static_cast<int>(it - names_.begin());
  }
  bound_ = true;
}

void ScriptedTimeline::poll(double sim_time, StepCommands& out) {
  using Mode = InstrumentCommand::Mode;
  if (!bound_) throw std::logic_error("ScriptedTimeline::poll before bind");
  out.drive.resize(track_of_.size());
  for (std::size_t i = 0; i < track_of_.size(); ++i) {
    DriveCommand& c = out.drive[i];
    if (track_of_[i] < 0) {  // not in the timeline: the hand holds it
      c = DriveCommand{};
      continue;
    }
    const auto& keys = tracks_[static_cast<std::size_t>(track_of_[i])];
    const std::ptrdiff_t k = last_at(keys, sim_time);
    double translation = 0.0, rotation = 0.0;
    Mode mode = Mode::kPosition;
    if (k < 0) {
      // Before the first keyframe: at rest where the script starts.
      const Key& first = keys.front();
      mode = first.mode;
      translation = first.mode == Mode::kPosition ? first.translation : 0.0;
      rotation = first.mode == Mode::kPosition ? first.rotation : 0.0;
    } else {
      const Key& a = keys[static_cast<std::size_t>(k)];
      mode = a.mode;
      translation = a.translation;
      rotation = a.rotation;
      const std::size_t next = static_cast<std::size_t>(k) + 1;
      if (a.mode == Mode::kPosition && next < keys.size() && keys[next].mode == Mode::kPosition) {
        const Key& b = keys[next];
        const double u = (sim_time - a.t) / (b.t - a.t);
        translation = lerp(a.translation, b.translation, u);
        rotation = lerp(a.rotation, b.rotation, u);
      }
    }
    c.mode =
        mode == Mode::kPosition ? DriveCommand::Mode::kPosition : DriveCommand::Mode::kVelocity;
    c.translation = translation * kMm;
    c.rotation = rotation * kDeg;
  }
  const std::ptrdiff_t kb = last_at(balloon_, sim_time);
  double balloon_atm = 0.0;
  if (kb < 0) {
    balloon_atm = 0.0;
  } else if (static_cast<std::size_t>(kb) + 1 < balloon_.size()) {
    const auto& a = balloon_[static_cast<std::size_t>(kb)];
    const auto& b = balloon_[static_cast<std::size_t>(kb) + 1];
    balloon_atm = lerp(a.value, b.value, (sim_time - a.t) / (b.t - a.t));
  } else {
    balloon_atm = balloon_.back().value;
  }
  out.balloon_pressure = balloon_atm * kAtm;
  const std::ptrdiff_t ks = last_at(syringe_, sim_time);
  out.syringe_flow = ks < 0 ? 0.0 : syringe_[static_cast<std::size_t>(ks)].value * kMl;
  const std::ptrdiff_t kn = last_at(buttons_, sim_time);
  out.buttons =
      kn < 0 ? 0u : static_cast<std::uint32_t>(buttons_[static_cast<std::size_t>(kn)].value);
}

bool ScriptedTimeline::poll_exchange(double sim_time, InstrumentChange& out) {
  // (1 ns: a time summed step by step lands a rounding short of the keyframe's)
  if (next_exchange_ >= exchanges_.size() || exchanges_[next_exchange_].t > sim_time + 1e-9)
    return false;
  out = exchanges_[next_exchange_++].change;
  return true;
}

void ScriptedTimeline::exchanged(const InstrumentChange&,
                                 std::span<const std::string> instruments) {
  bind(instruments);
}

void ScriptedTimeline::publish(std::span<const HandFeedback> feedback) {
  // Kept for inspection (tests, reports); a script has no device to push back.
  feedback_.assign(feedback.begin(), feedback.end());
}

void FeedbackDecimator::resize(std::size_t instruments) {
  force_sum_.assign(instruments, 0.0);
  torque_sum_.assign(instruments, 0.0);
  force_.assign(instruments, 0.0);
  torque_.assign(instruments, 0.0);
  n_.assign(instruments, 0);
}

void FeedbackDecimator::add(std::size_t i, double force_n, double torque_nm) {
  force_sum_[i] += force_n;
  torque_sum_[i] += torque_nm;
  ++n_[i];
}

void FeedbackDecimator::take(std::size_t i, double& force_n, double& torque_nm) {
  if (n_[i] > 0) {
    const double n = static_cast<double>(n_[i]);
    force_[i] = force_sum_[i] / n;
    torque_[i] = torque_sum_[i] / n;
    force_sum_[i] = torque_sum_[i] = 0.0;
    n_[i] = 0;
  }
  force_n = force_[i];
  torque_nm = torque_[i];
}

}  // namespace vcsim
