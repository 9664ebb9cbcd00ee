// The command recording of a session (CommandRecording) and its replay as an input source
// (RecordingReplay): the exact StepCommands of every step, run-length encoded, as JSON whose
// numbers read back to the same bits (docs/trainer.md "The command recording").
#include <algorithm>
#include <bit>
#include <cassert>
#include <cctype>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "json_fields.h"
#include "vcsim/haptics.h"

namespace vcsim {

using internal::cat;
using internal::Json;
using internal::JsonFields;

namespace {

// Equal bit for bit (so that -0.0 and 0.0 stay apart and a replay gets the very bits).
bool same(double a, double b) {
  return std::bit_cast<std::uint64_t>(a) == std::bit_cast<std::uint64_t>(b);
}

bool same_drive(const DriveCommand& a, const DriveCommand& b) {
  return a.mode == b.mode && same(a.translation, b.translation) && same(a.rotation, b.rotation);
}

// 17 significant digits read back to the same double (IEEE 754 binary64); -0.0 keeps its sign
// as "-0.0" (a JSON reader takes "-0" for the integer 0).
void put_number(std::string& out, double v) {
  if (v == 0.0) {
    out += std::signbit(v) ? "-0.0" : "0";
    return;
  }
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  out += buf;
}

std::string hex64(std::uint64_t v) {
  char buf[24];
  std::snprintf(buf, sizeof buf, "%016" PRIx64, v);
  return buf;
}

std::uint64_t parse_hex64(const std::string& s, const std::string& source,
                          const std::string& field) {
  if (s.empty() || s.size() > 16 || !std::all_of(s.begin(), s.end(), [](char c) {
        return std::isxdigit(static_cast<unsigned char>(c));
      }))
    throw InputError(source, field, cat("expected up to 16 hexadecimal digits, got '", s, "'"));
  return std::stoull(s, nullptr, 16);
}

}  // namespace

std::size_t CommandRecording::scene_size() const {
  std::size_t n = instruments.size();
  for (const Exchange& e : exchanges_)
    n = e.change.kind == InstrumentChange::Kind::kAdd ? n + 1 : n - 1;
  return n;
}

void CommandRecording::append(const StepCommands& c) {
  const std::size_t n = c.drive.size();
  assert(n == scene_size());
  // A run never spans an exchange: the scene's instruments differ on either side.
  const bool exchanged = !exchanges_.empty() && exchanges_.back().step == total_;
  if (!runs_.empty() && !exchanged) {
    Run& last = runs_.back();
    const DriveCommand* d = drive_.data() + start_.back();
    bool equal = same(last.syringe_flow, c.syringe_flow) &&
                 same(last.balloon_pressure, c.balloon_pressure) && last.buttons == c.buttons;
    for (std::size_t i = 0; equal && i < n; ++i) equal = same_drive(d[i], c.drive[i]);
    if (equal) {
      ++last.steps;
      ++end_.back();
      ++total_;
      return;
    }
  }
  runs_.push_back({1, c.syringe_flow, c.balloon_pressure, c.buttons});
  start_.push_back(drive_.size());
  width_.push_back(n);
  drive_.insert(drive_.end(), c.drive.begin(), c.drive.begin() + static_cast<std::ptrdiff_t>(n));
  ++total_;
  end_.push_back(total_);
}

void CommandRecording::append_exchange(const InstrumentChange& c) {
  exchanges_.push_back({total_, c});
}

void CommandRecording::truncate(std::int64_t steps) {
  steps = std::clamp<std::int64_t>(steps, 0, total_);
  // The first run ending at or after `steps` is the last one kept, shortened.
  const auto it = std::lower_bound(end_.begin(), end_.end(), steps);
  std::size_t keep = static_cast<std::size_t>(it - end_.begin());
  if (steps > 0 && it != end_.end()) {
    ++keep;
    runs_[keep - 1].steps -= *it - steps;
    end_[keep - 1] = steps;
  }
  runs_.resize(keep);
  end_.resize(keep);
  drive_.resize(keep > 0 ? start_[keep - 1] + width_[keep - 1] : 0);
  start_.resize(keep);
  width_.resize(keep);
  // An exchange made before step `steps` happened after the state those steps lead to.
  std::erase_if(exchanges_, [&](const Exchange& e) { return e.step >= steps; });
  total_ = steps;
}

std::span<const DriveCommand> CommandRecording::run_drive(std::size_t r) const {
  return {drive_.data() + start_[r], width_[r]};
}

void CommandRecording::at(std::int64_t step, StepCommands& out) const {
  assert(step >= 0 && step < total_);
  const auto it = std::upper_bound(end_.begin(), end_.end(), step);
  const std::size_t r = static_cast<std::size_t>(it - end_.begin());
  const Run& run = runs_[r];
  out.drive.resize(width_[r]);
  const std::span<const DriveCommand> d = run_drive(r);
  std::copy(d.begin(), d.end(), out.drive.begin());
  out.syringe_flow = run.syringe_flow;
  out.balloon_pressure = run.balloon_pressure;
  out.buttons = run.buttons;
}

std::string CommandRecording::to_json() const {
  std::string s;
  s.reserve(256 + runs_.size() * (40 + 48 * instruments.size()));
  // Version 2 when the scene's instruments change during it (exchanges).
  s += exchanges_.empty() ? "{\"format\": \"vcsim-recording\", \"version\": 1,\n"
                          : "{\"format\": \"vcsim-recording\", \"version\": 2,\n";
  s += " \"made_by\": " + Json(made_by).dump() + ",\n";
  s += " \"scenario\": " + Json(scenario).dump() + ",\n";
  s += " \"scenario_file\": " + Json(scenario_file).dump() + ",\n";
  s += " \"dt_s\": ";
  put_number(s, dt);
  s += ",\n \"instruments\": " + Json(instruments).dump() + ",\n";
  s += " \"model_hash\": \"" + hex64(model_hash) + "\",\n";
  s += " \"state_hash\": \"" + hex64(state_hash) + "\",\n";
  s += " \"steps\": " + std::to_string(total_) + ",\n";
  s += " \"columns\": [\"steps\", \"syringe_flow_m3_s\", \"balloon_pressure_pa\", \"buttons\"";
  for (const std::string& name : instruments)
    s += ", " + Json(name + ".mode").dump() + ", " + Json(name + ".translation").dump() + ", " +
         Json(name + ".rotation").dump();
  s += "],\n";
  s += " \"units\": \"SI. mode p: translation m (inserted depth), rotation rad (roll); mode v: m/s "
       "and rad/s\",\n";
  if (!exchanges_.empty()) {
    // Made before step `step`; the runs from there on have the scene's instruments then.
    s += " \"exchanges\": [";
    for (std::size_t k = 0; k < exchanges_.size(); ++k) {
      const Exchange& e = exchanges_[k];
      s += k == 0 ? "\n  " : ",\n  ";
      s += "{\"step\": " + std::to_string(e.step) +
           ", \"change\": " + Json(describe(e.change)).dump();
      if (e.change.kind == InstrumentChange::Kind::kAdd) {
        s += std::string(", \"rim\": ") + (e.change.rim ? "true" : "false");
        s += ", \"max_nodes\": " + std::to_string(e.change.max_nodes) + ", \"tip_segment_m\": ";
        put_number(s, e.change.tip_segment);
      }
      s += "}";
    }
    s += "],\n";
  }
  s += " \"runs\": [";
  for (std::size_t r = 0; r < runs_.size(); ++r) {
    const Run& run = runs_[r];
    s += r == 0 ? "\n  [" : ",\n  [";
    s += std::to_string(run.steps);
    s += ", ";
    put_number(s, run.syringe_flow);
    s += ", ";
    put_number(s, run.balloon_pressure);
    s += ", " + std::to_string(run.buttons);
    for (const DriveCommand& d : run_drive(r)) {
      s += d.mode == DriveCommand::Mode::kPosition ? ", \"p\", " : ", \"v\", ";
      put_number(s, d.translation);
      s += ", ";
      put_number(s, d.rotation);
    }
    s += "]";
  }
  s += "]}\n";
  return s;
}

void CommandRecording::save(const std::filesystem::path& file) const {
  // Written beside and renamed over: a session ended while saving never leaves half a file.
  const std::filesystem::path tmp = file.string() + ".part";
  {
    std::ofstream out(tmp, std::ios::binary);
    out << to_json();
    if (!out) throw InputError(file.string(), "file", "expected a writable recording file");
  }
  std::error_code ec;
  std::filesystem::rename(tmp, file, ec);
  if (ec) throw InputError(file.string(), "file", "expected a writable recording file");
}

CommandRecording CommandRecording::parse(std::string_view json_text, const std::string& source) {
  const Json doc = internal::parse_json_text(json_text, source);
  JsonFields root(doc, source, "");
  root.keys({"format", "version", "made_by", "scenario", "scenario_file", "dt_s", "instruments",
             "model_hash", "state_hash", "steps", "columns", "units", "exchanges", "runs"});
  if (root.string("format") != "vcsim-recording")
    root.fail("format",
              cat("expected \"vcsim-recording\", got ", internal::describe_json(doc["format"])));
  const int version = root.integer_or("version", 1, 2, 1);
  CommandRecording rec;
  rec.made_by = root.string_or("made_by", "");
  rec.scenario = root.string_or("scenario", "");
  rec.scenario_file = root.string_or("scenario_file", "");
  rec.dt = root.positive("dt_s");
  const Json& names = root.array("instruments");
  for (std::size_t i = 0; i < names.size(); ++i)
    rec.instruments.push_back(root.as_string(names[i], internal::index_path("instruments", i)));
  if (rec.instruments.empty()) root.fail("instruments", "expected at least one instrument");
  rec.model_hash = parse_hex64(root.string("model_hash"), source, "model_hash");
  rec.state_hash = parse_hex64(root.string("state_hash"), source, "state_hash");
  const double steps = root.nonnegative("steps");
  root.get("columns");
  root.get("units");
  if (root.has("exchanges")) {
    if (version < 2) root.fail("exchanges", "expected only in version 2");
    const Json& list = root.array("exchanges");
    for (std::size_t k = 0; k < list.size(); ++k) {
      JsonFields e(list[k], source, internal::index_path("exchanges", k));
      Exchange x;
      const double step = e.nonnegative("step");
      if (step != std::floor(step) || step > 9.0e15) e.fail("step", "expected a whole number");
      x.step = static_cast<std::int64_t>(step);
      if (!rec.exchanges_.empty() && x.step < rec.exchanges_.back().step)
        e.fail("step", "expected the exchanges in the order of their steps");
      const std::string why = parse_exchange_request(e.string("change"), x.change);
      if (!why.empty()) e.fail("change", why);
      if (x.change.kind == InstrumentChange::Kind::kAdd) {
        x.change.rim = e.boolean_or("rim", true);
        x.change.max_nodes = e.integer_or("max_nodes", 16, 512, 256);
        x.change.tip_segment = e.positive_or("tip_segment_m", 1.0e-3);
      }
      e.finish();
      x.change.source = source;
      x.change.field = e.path();
      rec.exchanges_.push_back(std::move(x));
      if (rec.scene_size() == 0) e.fail("change", "expected an instrument left in the scene");
    }
  }
  const Json& runs = root.array("runs");
  root.finish();

  // Each run has one drive command per instrument in the scene then (the exchanges before it).
  std::size_t n = rec.instruments.size();
  std::size_t next_exchange = 0;
  StepCommands c;
  std::int64_t total = 0;
  for (std::size_t r = 0; r < runs.size(); ++r) {
    const std::string field = internal::index_path("runs", r);
    for (; next_exchange < rec.exchanges_.size() && rec.exchanges_[next_exchange].step <= total;
         ++next_exchange)
      n = rec.exchanges_[next_exchange].change.kind == InstrumentChange::Kind::kAdd ? n + 1 : n - 1;
    c.reset(n);
    const Json& row = runs[r];
    if (!row.is_array() || row.size() != 4 + 3 * n)
      throw InputError(source, field,
                       cat("expected an array of ", std::to_string(4 + 3 * n),
                           " values (steps, syringe, balloon, buttons, then mode, translation and "
                           "rotation per instrument), got ",
                           internal::describe_json(row)));
    auto number = [&](std::size_t k) {
      const double v = root.as_number(row[k], internal::index_path(field, k));
      if (!std::isfinite(v))
        throw InputError(source, internal::index_path(field, k), "expected a finite number");
      return v;
    };
    const double count = number(0);
    if (count < 1 || count > 9.0e15 || count != std::floor(count))
      throw InputError(source, internal::index_path(field, 0),
                       "expected a whole number of steps >= 1");
    c.syringe_flow = number(1);
    c.balloon_pressure = number(2);
    const double buttons = number(3);
    if (buttons < 0 || buttons > 4294967295.0 || buttons != std::floor(buttons))
      throw InputError(source, internal::index_path(field, 3),
                       "expected a bit mask (an integer 0 .. 2^32-1)");
    c.buttons = static_cast<std::uint32_t>(buttons);
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t k = 4 + 3 * i;
      const std::string mode = root.as_string(row[k], internal::index_path(field, k));
      if (mode != "p" && mode != "v")
        throw InputError(source, internal::index_path(field, k),
                         cat("expected \"p\" (position) or \"v\" (velocity), got '", mode, "'"));
      c.drive[i].mode = mode == "p" ? DriveCommand::Mode::kPosition : DriveCommand::Mode::kVelocity;
      c.drive[i].translation = number(k + 1);
      c.drive[i].rotation = number(k + 2);
    }
    const auto k = static_cast<std::int64_t>(count);
    if (k > static_cast<std::int64_t>(9.0e15) - total)  // the sum must not overflow
      throw InputError(source, internal::index_path(field, 0),
                       "expected at most 9e15 steps in all the runs");
    if (next_exchange < rec.exchanges_.size() && rec.exchanges_[next_exchange].step < total + k)
      throw InputError(
          source, field,
          cat("expected the run to end at step ",
              std::to_string(rec.exchanges_[next_exchange].step), ", where an exchange is made"));
    // Appended run by run, not step by step; equal neighbours are kept as written.
    rec.runs_.push_back({k, c.syringe_flow, c.balloon_pressure, c.buttons});
    rec.start_.push_back(rec.drive_.size());
    rec.width_.push_back(n);
    rec.drive_.insert(rec.drive_.end(), c.drive.begin(), c.drive.end());
    total += k;
    rec.end_.push_back(total);
  }
  if (!rec.exchanges_.empty() && rec.exchanges_.back().step > total)
    root.fail("exchanges", "expected every exchange within the recording's steps");
  rec.total_ = total;
  if (static_cast<double>(total) != steps)
    root.fail("steps", cat("expected the sum of the runs' steps, ", std::to_string(total), ", got ",
                           internal::describe_json(doc["steps"])));
  return rec;
}

CommandRecording CommandRecording::load(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  if (!in) throw InputError(file.string(), "file", "expected a readable recording file");
  std::stringstream ss;
  ss << in.rdbuf();
  return parse(ss.str(), file.string());
}

RecordingReplay::RecordingReplay(CommandRecording recording,
                                 std::span<const std::string> instruments, double dt,
                                 std::uint64_t model_hash, const std::string& source)
    : rec_(std::move(recording)), scene_size_(rec_.instruments.size()) {
  if (!std::equal(instruments.begin(), instruments.end(), rec_.instruments.begin(),
                  rec_.instruments.end())) {
    std::string want;
    for (const std::string& s : instruments) want += (want.empty() ? "" : ", ") + s;
    throw InputError(source, "instruments",
                     cat("expected the scene's instruments in its order (", want, ")"));
  }
  if (!same(rec_.dt, dt)) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.17g s", dt);
    throw InputError(source, "dt_s", cat("expected the scene's step, ", buf));
  }
  if (model_hash != 0 && rec_.model_hash != 0 && model_hash != rec_.model_hash)
    throw InputError(source, "model_hash",
                     cat("expected the scene's model hash ", hex64(model_hash),
                         " (the recording was made with another scenario, anatomy or catalogue)"));
}

void RecordingReplay::poll(double sim_time, StepCommands& out) {
  const auto step = static_cast<std::int64_t>(std::llround(sim_time / rec_.dt));
  if (step >= 0 && step < rec_.steps()) {
    rec_.at(step, out);
    return;
  }
  out.reset(scene_size_);
}

bool RecordingReplay::poll_exchange(double sim_time, InstrumentChange& out) {
  const auto step = static_cast<std::int64_t>(std::llround(sim_time / rec_.dt));
  const auto& ex = rec_.exchanges();
  if (next_exchange_ >= ex.size() || ex[next_exchange_].step > step) return false;
  out = ex[next_exchange_++].change;
  return true;
}

void RecordingReplay::exchanged(const InstrumentChange&, std::span<const std::string> instruments) {
  scene_size_ = instruments.size();
}

}  // namespace vcsim
