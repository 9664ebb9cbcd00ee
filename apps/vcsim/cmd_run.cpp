// `vcsim run SCENARIO --out DIR`: a procedure headless. Loads the scenario, steps physics at its
// dt, films fluoroscopy at its frame rate into DIR/frames/*.png (and DIR/run.mp4 when ffmpeg is
// installed), writes DIR/metrics.json, and shows a progress bar on a terminal. The input is the
// scenario's timeline or autopilot, or a live device (`--device igtl`: an OpenIGTLink server,
// paced to the wall clock), or a command recording (`--replay FILE`: a trainer session, replayed
// to the same state). SIGINT and SIGTERM end a run cleanly, with its report. The engine
// does the work (src/sim: run_loop, the report; src/render: the film); this file is options.
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "commands.h"
#include "run_support.h"
#include "vcsim/assess.h"
#include "vcsim/render.h"
#include "vcsim/sim.h"

namespace vcsim::app {

namespace {

namespace fs = std::filesystem;
// Exit status of a run that went well but did not reach every landmark (2 is bad input).
constexpr int kNotReached = 3;
// Exit status of a run in which an instrument was seen outside the vessel (physics.md 6.3),
// whether it went on (the default) or stopped there (--stop-on-escape).
constexpr int kEscaped = 4;

struct RunOptions {
  std::string scenario = "default";
  std::string out;
  bool no_frames = false;
  bool quiet = false;
  bool profile = false;  // print the step's stages (mean, p50, p99)
  int threads = 0;       // at most this many threads for the physics (0: as many as pay)
  bool trace = false;
  double time_limit_s = 0.0;  // 0: the scenario's
  std::string device;         // "" (the scenario's input) or "igtl"
  int port = 18944;
  bool port_given = false;
  std::string address = "127.0.0.1";
  bool address_given = false;
  bool realtime = false;
  std::string force_log;        // CSV of the hand forces, every step ("" = none)
  std::string replay;           // a command recording to replay (a trainer session), "" = none
  std::string record;           // where to write the run's command recording, "" = none
  bool no_report = false;       // skip DIR/report.html (the assessment is written all the same)
  bool stop_on_escape = false;  // end the run at the first node seen outside the vessel
};

// What the command line does around each step: the autopilot's log, the force log, the command
// recording, the film and the progress bar (on a terminal).
class RunDisplay : public RunObserver {
 public:
  RunDisplay(const RunOptions& o, Autopilot* pilot, RunObserver* film, RunObserver* force_log,
             RunObserver* recorder, double end_time, std::string label)
      : o_(o),
        pilot_(pilot),
        film_(film),
        force_log_(force_log),
        recorder_(recorder),
        end_time_(end_time),
        label_(std::move(label)),
        bar_(!o.quiet && isatty(STDERR_FILENO)),
        loop0_(now_us()) {}
  bool before_step(const Simulator& sim, const StepCommands& cmds) override {
    if (pilot_ && pilot_->finished()) return false;
    if (pilot_ && pilot_->status() != last_status_) {
      last_status_ = pilot_->status();
      if (!isatty(STDERR_FILENO) && !o_.quiet)
        std::cerr << "run: t = " << sim.time() << " s: " << last_status_ << "\n";
    }
    if (recorder_) recorder_->before_step(sim, cmds);  // the step is taken
    return true;
  }
  void exchanged(const Simulator& sim, const InstrumentChange& change) override {
    if (force_log_) force_log_->exchanged(sim, change);
    if (recorder_) recorder_->exchanged(sim, change);
    if (!o_.quiet && !bar_)
      std::cerr << "run: t = " << sim.time() << " s: exchange: " << describe(change) << "\n";
  }
  void after_step(const Simulator& sim) override {
    for (const std::string& line : escapes_.fresh(sim)) {
      if (bar_) std::fprintf(stderr, "\n");
      std::cerr << "run: " << line << "\n";
    }
    if (film_) film_->after_step(sim);
    if (force_log_) force_log_->after_step(sim);
    if (bar_ && sim.metrics().steps % 50 == 0) {
      const double wall = (now_us() - loop0_) * 1e-6;
      const std::string what = pilot_ ? pilot_->status() : label_;
      std::string fill(static_cast<std::size_t>(30 * std::min(1.0, sim.time() / end_time_)), '#');
      fill.resize(30, '.');
      std::fprintf(stderr, "\r[%s] %6.2f s  %5.1fx real time  %-48.48s", fill.c_str(), sim.time(),
                   wall > 0 ? sim.time() / wall : 0.0, what.c_str());
      std::fflush(stderr);
    }
  }
  void done() {
    if (bar_) std::fprintf(stderr, "\n");
  }

 private:
  const RunOptions& o_;
  Autopilot* pilot_;
  RunObserver *film_, *force_log_, *recorder_;
  double end_time_;
  std::string label_;
  bool bar_;
  double loop0_;
  std::string last_status_;
  EscapeReporter escapes_;
};

// True when one of the scenario's instruments, or one the timeline adds, is a balloon catheter
// or a stent system.
bool has_balloon(const Scenario& sc, const ScriptedTimeline& tl) {
  const InstrumentCatalogue cat = load_catalogue(default_catalogue_dir());
  auto balloon = [&](const std::string& entry) {
    const InstrumentSpec* s = cat.find(entry);
    return s && s->balloon;
  };
  for (const ScenarioInstrument& si : sc.instruments)
    if (balloon(si.catalogue)) return true;
  for (const ScriptedTimeline::TimedChange& e : tl.exchanges())
    if (e.change.kind == InstrumentChange::Kind::kAdd && balloon(e.change.catalogue)) return true;
  return false;
}

int cmd_run(const RunOptions& o) {
  const fs::path file = find_scenario(o.scenario, "run", "SCENARIO");
  Scenario sc = load_scenario(file);
  if (o.time_limit_s != 0.0) {
    sc.time_limit = require_in_range(o.time_limit_s, 0.0, 3600.0, "run", "--time-limit");
    check_run_steps(sc.dt, sc.time_limit, "run", "--time-limit");
  }
  scenario_pose(sc);  // a bad C-arm setting fails before the scene is built
  std::optional<ThreadLimit> threads;
  if (o.threads != 0)
    threads.emplace(static_cast<int>(require_in_range(o.threads, 1, 256, "run", "--threads")));
  if (!o.replay.empty() && !o.device.empty())
    throw InputError("run", "--replay", "expected either --replay or --device, not both");
  // A recording to replay is read before the scene is built: a bad file fails at once.
  std::optional<CommandRecording> recording;
  if (!o.replay.empty()) recording = CommandRecording::load(o.replay);
  // A live device replaces the scenario's timeline or autopilot.
  std::unique_ptr<IgtlServer> device =
      open_device({o.device, o.port, o.port_given, o.address, o.address_given}, sc);
  const fs::path out = o.out.empty() ? fs::path("out") / sc.name : fs::path(o.out);
  const fs::path frames_dir = out / "frames";
  std::error_code ec;
  fs::create_directories(frames_dir, ec);
  if (ec)
    throw InputError("run", "--out", "expected a writable folder, got '" + out.string() + "'");
  // Frames of an earlier run in the same folder would mix with this one's.
  for (const auto& e : fs::directory_iterator(frames_dir))
    if (e.path().extension() == ".png") fs::remove(e.path());

  std::vector<std::string> names;
  for (const ScenarioInstrument& si : sc.instruments) names.push_back(si.name);
  std::optional<ScriptedTimeline> timeline;
  if (!device && !recording && !sc.timeline.empty()) {
    timeline = ScriptedTimeline::load(sc.base_dir / sc.timeline);
    timeline->bind(names);
    if (timeline->inflates() && !has_balloon(sc, *timeline))
      throw InputError(timeline->source(), "balloon_pressure_atm",
                       "expected a balloon or stent catheter in the scenario to inflate");
  }
  const StopOnSignal stop_on_signal;

  std::cerr << "run: " << sc.name << " (" << file.string() << "): building the scene\n";
  const double wall0 = now_us();
  Simulator sim(sc);
  std::unique_ptr<RecordingReplay> replay;
  if (recording)  // checked against the scene: instruments, step, model hash
    replay = std::make_unique<RecordingReplay>(std::move(*recording), names, sim.dt(),
                                               sim.model().hash(), o.replay);
  std::unique_ptr<Autopilot> pilot;
  std::unique_ptr<AutopilotInput> pilot_input;
  if (!device && !timeline && !replay) {
    pilot = std::make_unique<Autopilot>(sim);
    pilot->trace = o.trace;
    pilot_input = std::make_unique<AutopilotInput>(*pilot, sim);
  }
  InputSource& input = device     ? static_cast<InputSource&>(*device)
                       : replay   ? static_cast<InputSource&>(*replay)
                       : timeline ? static_cast<InputSource&>(*timeline)
                                  : static_cast<InputSource&>(*pilot_input);
  RunReport report;
  report.scenario_file = file.string();
  report.input_type = device ? "igtl" : replay ? "replay" : timeline ? "timeline" : "autopilot";
  report.realtime = device || o.realtime;
  report.autopilot = pilot.get();
  report.end_time = timeline ? std::min(sc.time_limit, timeline->duration()) : sc.time_limit;
  // A recording is replayed whole, however long the session was: its steps and no more (the
  // loop stops once the time passes half a step before the last step's end).
  if (replay) report.end_time = (static_cast<double>(replay->recording().steps()) - 0.5) * sim.dt();

  ImageChainSettings chain;
  chain.dose = sc.fluoro.dose;
  std::unique_ptr<FrameRecorder> recorder;
  std::unique_ptr<RunFilm> film;
  if (!o.no_frames) {
    recorder = std::make_unique<FrameRecorder>(
        sim.model(), sc.fluoro.size,
        sc.fluoro.energy_kev == 80 ? BeamEnergy::k80keV : BeamEnergy::k60keV, chain, frames_dir);
    film = std::make_unique<RunFilm>(sim.model(), *recorder);
  }
  std::unique_ptr<ForceLog> force_log;
  if (!o.force_log.empty()) force_log = std::make_unique<ForceLog>(o.force_log, sim.model());
  std::unique_ptr<CommandRecorder> commands;
  if (!o.record.empty()) commands = std::make_unique<CommandRecorder>(sim, "vcsim run");
  if (device) {
    std::string list;
    for (const std::string& n : names) list += (list.empty() ? "" : ", ") + n;
    std::cerr << "run: OpenIGTLink server listening on " << o.address << ":" << device->port()
              << " (instruments: " << list << ")" << std::endl;  // flushed: a client waits on it
  }
  RunDisplay display(o, pilot.get(), film.get(), force_log.get(), commands.get(), report.end_time,
                     report.input_type);
  // The assessment watches the run from outside its state (docs/assessment.md).
  Assessment assessment(sim);
  assessment.follow(pilot.get());
  ObserverList observers;
  observers.add(&display);
  observers.add(&assessment);
  RunLoopSettings loop_settings;
  loop_settings.end_time = report.end_time;
  loop_settings.realtime = report.realtime;
  loop_settings.stop = &stop_on_signal.flag();
  loop_settings.stop_on_escape = o.stop_on_escape || sc.stop_on_escape;
  const double loop0 = now_us();
  report.loop = run_loop(sim, input, loop_settings, &observers);
  if (device) device->stop();        // the connection closes with the run; the counts are final
  if (recorder) recorder->finish();  // the last frames are written before the clock stops
  report.frames = recorder ? recorder->frames() : 0;
  report.render_time = recorder ? recorder->render_seconds() : 0.0;
  display.done();
  if (report.loop.stopped) std::cerr << "run: stopped by a signal at t = " << sim.time() << " s\n";
  if (report.loop.stopped_on_escape)
    std::cerr << "run: stopped on an escape at t = " << sim.time() << " s (--stop-on-escape)\n";
  report.wall_time = (now_us() - loop0) * 1e-6;
  report.setup_time = (now_us() - wall0) * 1e-6 - report.wall_time;
  if (device) {
    report.device = device->stats();
    report.device_address = o.address;
    report.device_port = device->port();
  }
  // Video, when ffmpeg is there (optional; the frames are the primary output).
  if (report.frames > 0 && std::system("command -v ffmpeg > /dev/null 2>&1") == 0) {
    const std::string cmd = "ffmpeg -y -loglevel error -framerate " +
                            std::to_string(sc.fluoro.fps) + " -i '" +
                            (frames_dir / "frame_%05d.png").string() +
                            "' -pix_fmt yuv420p -vf scale=trunc(iw/2)*2:trunc(ih/2)*2 '" +
                            (out / "run.mp4").string() + "'";
    if (std::system(cmd.c_str()) == 0) report.video = (out / "run.mp4").string();
  }
  const fs::path metrics = out / "metrics.json";
  write_run_metrics(metrics, sim, report);
  assessment.write(out, sim,
                   film ? std::span<const CArmPose>(film->poses()) : std::span<const CArmPose>());
  if (commands) commands->finish(sim).save(o.record);
  print_run_summary(std::cout, sim, report, frames_dir, metrics);
  if (o.profile)
    std::cout << "  the step by stage over " << sim.profile().steps << " steps:\n"
              << sim.profile().table();
  if (!o.no_report) {
    // The run's files are written: a page that cannot be made is reported, not the run's status.
    try {
      const double t0 = now_us();
      const fs::path html = write_report(out);
      std::cout << "  report:  " << html.string() << " (" << (now_us() - t0) * 1e-6 << " s)\n";
    } catch (const std::exception& e) {
      std::cerr << "run: report not written: " << e.what() << "\n";
    }
  }
  if (replay && replay->recording().state_hash != 0) {
    const bool same = replay->recording().state_hash == sim.state().hash();
    std::cout << "  replay:  " << replay->recording().steps() << " steps, state hash "
              << (same ? "equal to the recording's" : "DIFFERENT from the recording's") << "\n";
  }
  const RunOutcome outcome = run_outcome(sim, report);
  return outcome.escaped ? kEscaped : outcome.success ? 0 : kNotReached;
}

void install(CLI::App& app, int& status) {
  auto o = std::make_shared<RunOptions>();
  auto* cmd = app.add_subcommand("run", "Run a scenario headless: frames, metrics, landmarks");
  cmd->add_option("scenario", o->scenario,
                  "Scenario file, or a name in data/scenarios (default: default)");
  cmd->add_option("--out", o->out, "Output folder (default: out/<scenario name>)");
  cmd->add_flag("--no-frames", o->no_frames, "Physics only: no fluoroscopy frames");
  cmd->add_flag("--quiet", o->quiet, "No progress output");
  cmd->add_option("--threads", o->threads,
                  "At most this many threads for the physics (1: all on one core; the results "
                  "are the same with any count)");
  cmd->add_flag("--profile", o->profile,
                "Print the step's stages (mean, median, 99th percentile per step; also in "
                "metrics.json, \"profile\")");
  cmd->add_flag("--trace", o->trace, "Print what the autopilot sees and does");
  cmd->add_option("--time-limit", o->time_limit_s, "Simulated seconds before giving up");
  cmd->add_option("--device", o->device,
                  "Live input instead of the scenario's: igtl (an OpenIGTLink server; real time)");
  cmd->add_option("--port", o->port, "TCP port of --device igtl (default 18944; 0: any free)");
  cmd->add_option("--address", o->address,
                  "IPv4 address --device igtl listens on (default 127.0.0.1)");
  cmd->add_option("--force-log", o->force_log,
                  "Write every step's hand force (N) and torque (N mm) per instrument to this CSV");
  cmd->add_flag("--realtime", o->realtime, "Pace the run to the wall clock (implied by --device)");
  cmd->add_option("--replay", o->replay,
                  "Replay a command recording (a trainer session's recording.json) instead of "
                  "the scenario's input, to the same final state");
  cmd->add_option("--record", o->record,
                  "Write the run's commands and instrument exchanges to this command recording "
                  "(replayed by --replay to the same final state)");
  cmd->add_flag("--stop-on-escape", o->stop_on_escape,
                "End the run at the first step with a node outside the vessel (behind the wall "
                "or beyond an open end; exit status 4 either way; the scenario's "
                "stop_on_escape does the same)");
  cmd->add_flag("--no-report", o->no_report,
                "Do not write DIR/report.html (metrics.json, series.csv are written all the same)");
  cmd->callback([o, &status, cmd] {
    o->port_given = cmd->count("--port") > 0;
    o->address_given = cmd->count("--address") > 0;
    status = cmd_run(*o);
  });
}

const int kRegistered = register_command(5, install);

}  // namespace

}  // namespace vcsim::app
