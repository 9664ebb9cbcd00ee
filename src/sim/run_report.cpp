// A run's report: metrics.json (docs/scenarios.md), the summary printed at the end of `vcsim
// run`, and the per-step force log.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <ostream>

#include "sim_scratch.h"
#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

nlohmann::json shape_json(const RodModel& md, const InstrumentState& in) {
  nlohmann::json pts = nlohmann::json::array();
  for (int i = std::max(0, in.drive.first_free - 1); i < md.n; ++i) {
    const Vec3& x = in.rod.x[i];
    pts.push_back(
        {std::round(x.x() * 1e4) / 10, std::round(x.y() * 1e4) / 10, std::round(x.z() * 1e4) / 10});
  }
  return pts;
}

double real_time_factor(const Simulator& sim, const RunReport& r) {
  return r.wall_time > 0 ? sim.time() / r.wall_time : 0.0;
}

double physics_real_time_factor(const Simulator& sim) {
  const double w = sim.profile().wall_time;
  return w > 0 ? sim.time() / w : 0.0;
}

// Where an escape went out: "wall", the open end as "open end of 'segment' (start|end)", or a
// closed end's cap (physics.md 6.4) as "cap of 'segment' (start|end)".
std::string escape_where(const SimModel& md, int exit) {
  if (exit < 0) return "wall";
  const std::vector<OpenEnd> ends = open_ends(md.tree);
  if (exit >= static_cast<int>(ends.size()))
    return "opening " + std::to_string(exit - static_cast<int>(ends.size()) + 1) +
           " of the mesh that no centreline reaches";
  const OpenEnd& e = ends[static_cast<std::size_t>(exit)];
  const bool closed =
      !is_mesh_file(md.scenario.anatomy) && internal::access_end(md.tree, md.sheath) != exit;
  return std::string(closed ? "cap" : "open end") + " of '" +
         md.tree.segments[static_cast<std::size_t>(e.segment)].name + "' (" +
         (e.at_start ? "start" : "end") + ")";
}

nlohmann::json escape_json(const SimModel& md, const EscapeRecord& e) {
  if (e.steps == 0) return nullptr;
  return {{"steps", e.steps},
          {"first_time_s", e.time},
          {"node", e.node},
          {"edge", e.edge},
          {"distance_mm", e.distance * 1e3},
          {"where", escape_where(md, e.exit)},
          {"max_distance_mm", e.max_distance * 1e3},
          {"position_mm", {e.position.x() * 1e3, e.position.y() * 1e3, e.position.z() * 1e3}},
          {"nearest_segment", e.near.segment >= 0
                                  ? md.tree.segments[static_cast<std::size_t>(e.near.segment)].name
                                  : std::string()},
          {"nearest_distance_mm", e.near.distance * 1e3}};
}

}  // namespace

std::string describe_escape(const SimModel& md, int i, const EscapeRecord& e) {
  char buf[256];
  if (e.edge)
    std::snprintf(buf, sizeof buf,
                  "t = %.4f s: '%s' edge %d-%d passes through the wall between nodes inside the "
                  "vessel, its deepest point ",
                  e.time, md.instrument_name(i).c_str(), e.node, e.node + 1);
  else
    std::snprintf(buf, sizeof buf, "t = %.4f s: '%s' node %d is outside the vessel, ", e.time,
                  md.instrument_name(i).c_str(), e.node);
  std::string s = buf;
  std::snprintf(buf, sizeof buf, "%.2f mm", e.distance * 1e3);
  std::string near;
  if (e.near.segment >= 0) {
    char at[160];
    std::snprintf(at, sizeof at, " (nearest vessel '%s', %.0f mm along it)",
                  md.tree.segments[static_cast<std::size_t>(e.near.segment)].name.c_str(),
                  e.near.distance * 1e3);
    near = at;
  }
  if (e.exit < 0) return s + buf + " behind the wall" + near;
  const std::string where = escape_where(md, e.exit);
  return s + buf + (where.rfind("cap", 0) == 0 ? " behind the " : " beyond the ") + where + near;
}

std::vector<std::string> EscapeReporter::fresh(const Simulator& sim) {
  std::vector<std::string> lines;
  const SimMetrics& m = sim.metrics();
  auto report = [&](const std::vector<EscapeRecord>& records, std::vector<std::string>& reported,
                    const char* label) {
    for (int i = 0; i < sim.num_instruments(); ++i) {
      const EscapeRecord& e = records[static_cast<std::size_t>(i)];
      const std::string& name = sim.model().instrument_name(i);
      if (e.steps == 0 || std::find(reported.begin(), reported.end(), name) != reported.end())
        continue;
      reported.push_back(name);
      lines.push_back(label + describe_escape(sim.model(), i, e));
    }
  };
  if (m.escape_steps != escape_steps_) {
    escape_steps_ = m.escape_steps;
    report(m.escapes, reported_, "ESCAPE: ");
  }
  if (m.edge_crossing_checks != edge_checks_) {
    edge_checks_ = m.edge_crossing_checks;
    report(m.edge_crossings, reported_edges_, "EDGE: ");
  }
  return lines;
}

RunOutcome run_outcome(const Simulator& sim, const RunReport& r) {
  const Scenario& sc = sim.scenario();
  const SimMetrics& m = sim.metrics();
  std::vector<std::string> missed;
  for (std::size_t k = 0; k < m.landmarks.size(); ++k)
    if (!m.landmarks[k].reached) missed.push_back(sc.landmarks[k].name);
  // The treatment's targets.
  const Scenario::Targets& tg = sc.targets;
  const SimModel& md = sim.model();
  if (tg.residual_stenosis >= 0.0 || tg.stent_covers_lesion) {
    const ProcedureOutcome po = procedure_outcome(md.procedure, md.tree, sim.state().procedure);
    for (std::size_t k = 0; k < po.lesions.size(); ++k)
      if (tg.residual_stenosis >= 0.0 && po.lesions[k].stenosis_now >= tg.residual_stenosis)
        missed.push_back("residual stenosis below " +
                         std::to_string(static_cast<int>(std::lround(100 * tg.residual_stenosis))) +
                         " % at lesion " + std::to_string(k));
    if (tg.stent_covers_lesion) {
      bool covered = false;
      for (const StentOutcome& so : po.stents)
        covered = covered || (so.deployed && so.lesion >= 0 && !so.geographic_miss);
      if (!covered) missed.push_back("a stent covering the lesion");
    }
  }
  // An instrument outside the vessel fails the run whatever it reached.
  for (int i = 0; i < sim.num_instruments(); ++i)
    if (m.escapes[static_cast<std::size_t>(i)].steps > 0)
      missed.push_back("every instrument inside the vessel ('" + md.instrument_name(i) +
                       "' left it at t = " + std::to_string(m.escapes[i].time) + " s)");
  if (m.escape_steps > 0 && missed.empty())  // an instrument since removed
    missed.push_back("every instrument inside the vessel");
  RunOutcome o;
  o.success = missed.empty();
  o.escaped = m.escape_steps > 0;
  o.text = "all landmarks reached";
  if (o.success && (tg.residual_stenosis >= 0.0 || tg.stent_covers_lesion))
    o.text = "all landmarks and treatment targets reached";
  if (!o.success) {
    o.text = "not reached:";
    for (const auto& s : missed) o.text += " '" + s + "'";
    o.text +=
        sim.time() >= r.end_time - 1e-9 ? " (time limit " + std::to_string(r.end_time) + " s)" : "";
    if (r.autopilot && r.autopilot->failed()) o.text += " (" + r.autopilot->status() + ")";
  }
  if (r.loop.stopped)
    o.text += " (stopped by a signal at t = " + std::to_string(sim.time()) + " s)";
  if (r.loop.stopped_on_escape)
    o.text += " (stopped on the escape at t = " + std::to_string(sim.time()) + " s)";
  return o;
}

void write_run_metrics(const std::filesystem::path& file, const Simulator& sim,
                       const RunReport& r) {
  const Scenario& sc = sim.scenario();
  const SimMetrics& m = sim.metrics();
  const double frame_dt = 1.0 / sc.fluoro.fps;
  nlohmann::json j;
  // Schema version 2 (docs/assessment.md): version 1 had no format key; 2 adds it and the
  // assessment section (written by the assess layer after this).
  j["format"] = "vcsim-metrics";
  j["version"] = 2;
  j["scenario"] = sc.name;
  j["scenario_file"] = r.scenario_file;
  j["dt_s"] = sc.dt;
  j["sim_time_s"] = sim.time();
  j["wall_time_s"] = r.wall_time;
  j["setup_time_s"] = r.setup_time;
  j["physics_time_s"] = sim.profile().wall_time;
  j["render_time_s"] = r.render_time;
  j["real_time_factor"] = real_time_factor(sim, r);
  j["physics_real_time_factor"] = physics_real_time_factor(sim);
  {
    // The step's stages (us per step): docs/architecture.md, "The sim step".
    nlohmann::json prof;
    for (int k = 0; k < kNumSimStages; ++k) {
      const DurationHistogram& h = sim.profile().stages[static_cast<std::size_t>(k)];
      prof[to_string(static_cast<SimStage>(k))] = {
          {"mean_us", h.mean()}, {"p50_us", h.quantile(0.5)}, {"p99_us", h.quantile(0.99)}};
    }
    j["profile"] = prof;
  }
  j["steps"] = m.steps;
  j["rollbacks"] = m.rollbacks;
  j["escape_steps"] = m.escape_steps;
  j["edge_crossing_checks"] = m.edge_crossing_checks;
  j["stopped_on_escape"] = r.loop.stopped_on_escape;
  j["resplit_steps"] = m.resplit_steps;
  j["runaway_steps"] = m.runaway_steps;
  j["calmed_steps"] = m.calmed_steps;
  j["frames"] = r.frames;
  j["fluoroscopy_time_s"] = r.fluoroscopy_time >= 0.0 ? r.fluoroscopy_time : r.frames * frame_dt;
  j["contrast_volume_ml"] = sim.state().contrast.volume * 1e6;
  j["video"] = r.video;
  char hash[24];
  std::snprintf(hash, sizeof hash, "%016llx", static_cast<unsigned long long>(sim.state().hash()));
  j["state_hash"] = hash;  // hex: JSON readers keep only 53 bits of a number
  nlohmann::json insts = nlohmann::json::array();
  for (int i = 0; i < sim.num_instruments(); ++i) {
    const InstrumentState& in = sim.instrument(i);
    const TreeHit h = sim.tip_location(i);
    insts.push_back(
        {{"name", sc.instruments[i].name},
         {"catalogue", sc.instruments[i].catalogue},
         {"nodes", sim.rod_model(i).n},
         {"inserted_mm", in.drive.depth * 1e3},
         {"tip_path_mm", m.tip_path[i] * 1e3},
         {"peak_wall_force_n", m.peak_wall_force[i]},
         {"peak_axial_force_n", m.peak_axial_force[i]},
         {"peak_axial_jump_n", m.peak_axial_jump[i]},
         {"peak_torque_nmm", m.peak_torque[i] * 1e3},
         {"tip_segment",
          in.drive.depth > 0 ? sim.tree().segments[h.loc.segment].name : std::string("outside")},
         {"tip_distance_mm", h.loc.distance * 1e3},
         {"escape", escape_json(sim.model(), m.escapes[static_cast<std::size_t>(i)])},
         {"edge_crossing", escape_json(sim.model(), m.edge_crossings[static_cast<std::size_t>(i)])},
         {"final_shape_mm", shape_json(sim.rod_model(i), in)}});
  }
  j["instruments"] = insts;
  nlohmann::json lms = nlohmann::json::array();
  for (std::size_t k = 0; k < m.landmarks.size(); ++k) {
    const LandmarkRecord& l = m.landmarks[k];
    lms.push_back({{"name", sc.landmarks[k].name},
                   {"instrument", sc.landmarks[k].instrument},
                   {"reached", l.reached},
                   {"time_s", l.reached ? nlohmann::json(l.time) : nlohmann::json(nullptr)}});
  }
  j["landmarks"] = lms;
  // The treatment (docs/procedure.md): lesions, balloons, stents, events.
  const SimModel& md = sim.model();
  if (!md.procedure.lesions.empty() || !md.procedure.balloons.empty()) {
    const ProcedureOutcome po = procedure_outcome(md.procedure, md.tree, sim.state().procedure);
    nlohmann::json lesions = nlohmann::json::array();
    for (std::size_t k = 0; k < po.lesions.size(); ++k) {
      const LesionOutcome& o = po.lesions[k];
      lesions.push_back({{"segment", md.tree.segments[md.tree.lesions[k].segment].name},
                         {"reference_diameter_mm", o.reference_diameter * 1e3},
                         {"mld_before_mm", o.mld_before * 1e3},
                         {"mld_after_mm", o.mld_now * 1e3},
                         {"diameter_stenosis_before_percent", 100.0 * o.stenosis_before},
                         {"diameter_stenosis_after_percent", 100.0 * o.stenosis_now}});
    }
    nlohmann::json balloons = nlohmann::json::array();
    std::size_t stent_k = 0;
    for (std::size_t b = 0; b < po.balloons.size(); ++b) {
      const BalloonOutcome& o = po.balloons[b];
      const BalloonModel& bm = md.procedure.balloons[b];
      nlohmann::json e = {{"instrument", bm.label},
                          {"catalogue", bm.catalogue},
                          {"removed", o.removed},
                          {"max_pressure_atm", o.max_pressure / kAtm},
                          {"balloon_to_artery_ratio", o.max_ratio},
                          {"ruptured", o.ruptured},
                          {"over_expanded", o.over_expanded}};
      if (md.procedure.balloons[b].stent) {
        const StentOutcome& so = po.stents[stent_k++];
        e["stent"] = {{"deployed", so.deployed},
                      {"diameter_min_mm", so.diameter_min * 1e3},
                      {"diameter_max_mm", so.diameter_max * 1e3},
                      {"lesion", so.lesion},
                      {"longitudinal_offset_mm", so.longitudinal_offset * 1e3},
                      {"geographic_miss", so.geographic_miss},
                      {"malapposition_mm", so.malapposition * 1e3}};
      }
      balloons.push_back(e);
    }
    nlohmann::json events = nlohmann::json::array();
    for (const ProcedureEvent& ev : sim.state().procedure.events)
      events.push_back(
          {{"time_s", ev.time},
           {"event", to_string(ev.kind)},
           {"instrument",
            ev.balloon >= 0
                ? nlohmann::json(md.procedure.balloons[static_cast<std::size_t>(ev.balloon)].label)
                : nlohmann::json(nullptr)}});
    j["procedure"] = {{"lesions", lesions}, {"balloons", balloons}, {"events", events}};
  }
  nlohmann::json input = {{"type", r.input_type},
                          {"realtime", r.realtime},
                          {"exchanges", r.loop.exchanges},
                          {"exchanges_refused", r.loop.refused_exchanges}};
  if (r.input_type == "igtl") {
    input["address"] = r.device_address;
    input["port"] = r.device_port;
    input["connections"] = r.device.connections;
    input["disconnections"] = r.device.disconnections;
    input["messages_accepted"] = r.device.messages_accepted;
    input["messages_dropped"] = r.device.messages_dropped;
    input["feedback_sent"] = r.device.feedback_sent;
    input["clients_refused"] = r.device.clients_refused;
    input["messages_skipped"] = r.device.messages_skipped;
    input["beyond_drive"] = r.device.beyond_drive;
  }
  if (r.realtime) {
    input["late_steps"] = r.loop.late_steps;
    input["max_lag_ms"] = r.loop.max_lag * 1e3;
    input["resyncs"] = r.loop.resyncs;
  }
  j["input"] = input;
  j["stopped_by_signal"] = r.loop.stopped;
  if (r.autopilot)
    j["autopilot"] = {{"finished", r.autopilot->finished() && !r.autopilot->failed()},
                      {"failed", r.autopilot->failed()},
                      {"status", r.autopilot->status()},
                      {"retries", r.autopilot->retries()}};
  const RunOutcome o = run_outcome(sim, r);
  j["outcome"] = o.text;
  j["success"] = o.success;
  std::ofstream out(file);
  out << j.dump(2) << "\n";
  if (!out) throw InputError(file.string(), "file", "expected a writable metrics file");
}

void print_run_summary(std::ostream& out, const Simulator& sim, const RunReport& r,
                       const std::filesystem::path& frames_dir,
                       const std::filesystem::path& metrics) {
  const Scenario& sc = sim.scenario();
  const SimMetrics& m = sim.metrics();
  out << "run: " << sc.name << ": " << run_outcome(sim, r).text << "\n";
  for (std::size_t k = 0; k < m.landmarks.size(); ++k) {
    const LandmarkRecord& l = m.landmarks[k];
    out << "  " << (l.reached ? "reached " : "MISSED  ") << sc.landmarks[k].name << " ("
        << sc.landmarks[k].instrument << ")"
        << (l.reached ? " at " + std::to_string(l.time) + " s" : "") << "\n";
  }
  out << "  simulated " << sim.time() << " s in " << r.wall_time << " s wall ("
      << real_time_factor(sim, r) << "x real time; physics alone " << physics_real_time_factor(sim)
      << "x)\n"
      << "  frames:  " << frames_dir.string() << " (" << r.frames << " PNG at " << sc.fluoro.fps
      << " fps)\n";
  if (!r.video.empty()) out << "  video:   " << r.video << "\n";
  if (r.input_type == "igtl")
    out << "  device:  OpenIGTLink on " << r.device_address << ":" << r.device_port << ", "
        << r.device.connections << " connection(s), " << r.device.messages_accepted
        << " messages accepted (" << r.device.messages_dropped << " dropped), "
        << r.device.feedback_sent << " force messages sent\n";
  if (r.realtime)
    out << "  pacing:  real time, " << r.loop.late_steps << " late steps (worst lag "
        << r.loop.max_lag * 1e3 << " ms, " << r.loop.resyncs << " resyncs)\n";
  if (m.escape_steps > 0) {
    out << "  ESCAPE:  " << m.escape_steps << " step(s) with an instrument outside the vessel\n";
    for (int i = 0; i < sim.num_instruments(); ++i)
      if (m.escapes[static_cast<std::size_t>(i)].steps > 0)
        out << "           " << describe_escape(sim.model(), i, m.escapes[i]) << "\n";
  }
  if (m.edge_crossing_checks > 0) {
    out << "  EDGES:   " << m.edge_crossing_checks
        << " check(s) with an edge through the wall between nodes inside the vessel\n";
    for (int i = 0; i < sim.num_instruments(); ++i)
      if (m.edge_crossings[static_cast<std::size_t>(i)].steps > 0)
        out << "           " << describe_escape(sim.model(), i, m.edge_crossings[i]) << "\n";
  }
  out << "  metrics: " << metrics.string() << "\n";
}

struct ForceLog::File {
  std::ofstream out;
};

ForceLog::ForceLog(const std::filesystem::path& file, const SimModel& model)
    : f_(std::make_unique<File>()) {
  f_->out.open(file);
  if (!f_->out)
    throw InputError("run", "--force-log", "expected a writable file, got '" + file.string() + "'");
  header(model);
}

ForceLog::~ForceLog() = default;

void ForceLog::header(const SimModel& model) {
  f_->out << "time_s";
  for (const ScenarioInstrument& si : model.scenario.instruments)
    f_->out << ',' << si.name << "_depth_mm," << si.name << "_force_n," << si.name << "_torque_nmm";
  f_->out << '\n';
}

void ForceLog::exchanged(const Simulator& sim, const InstrumentChange&) {
  header(sim.model());  // the rows after it have the scene's instruments now
}

void ForceLog::after_step(const Simulator& sim) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.4f", sim.time());
  f_->out << buf;
  for (int i = 0; i < sim.num_instruments(); ++i) {
    const DriveState& dr = sim.instrument(i).drive;
    std::snprintf(buf, sizeof buf, ",%.3f,%.6g,%.6g", dr.depth * 1e3, dr.axial_force,
                  dr.torque * 1e3);
    f_->out << buf;
  }
  f_->out << '\n';
}

CommandRecorder::CommandRecorder(const Simulator& sim, std::string made_by) {
  const Scenario& sc = sim.scenario();
  rec_.scenario = sc.name;
  rec_.scenario_file = sc.source;
  rec_.dt = sim.dt();
  rec_.instruments = sim.instrument_names();
  rec_.model_hash = sim.model().hash();
  rec_.made_by = std::move(made_by);
}

bool CommandRecorder::before_step(const Simulator&, const StepCommands& commands) {
  rec_.append(commands);
  return true;
}

void CommandRecorder::exchanged(const Simulator&, const InstrumentChange& change) {
  rec_.append_exchange(change);
}

const CommandRecording& CommandRecorder::finish(const Simulator& sim) {
  rec_.state_hash = sim.state().hash();
  return rec_;
}

}  // namespace vcsim
