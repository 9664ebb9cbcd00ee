// `vcsim run SCENARIO --out DIR`: a procedure headless. Loads the scenario, steps physics at its
// dt, renders fluoroscopy at its frame rate into DIR/frames/*.png (and DIR/run.mp4 when ffmpeg
// is installed), writes DIR/metrics.json, and shows a progress bar on a terminal. The input is
// the scenario's timeline or autopilot, or a live device (`--device igtl`: an OpenIGTLink
// server, paced to the wall clock). SIGINT and SIGTERM end a run cleanly, with its report.
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <condition_variable>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <exception>
#include <filesystem>
#include <fstream>
#include <future>
#include <iostream>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "commands.h"
#include "vcsim/render.h"
#include "vcsim/sim.h"

namespace vcsim::app {

namespace {

namespace fs = std::filesystem;
// Exit status of a run that went well but did not reach every landmark (2 is bad input).
constexpr int kNotReached = 3;

struct RunOptions {
  std::string scenario = "default";
  std::string out;
  bool no_frames = false;
  bool quiet = false;
  bool trace = false;
  double time_limit_s = 0.0;  // 0: the scenario's
  std::string device;         // "" (the scenario's input) or "igtl"
  int port = 18944;
  bool port_given = false;
  std::string address = "127.0.0.1";
  bool address_given = false;
  bool realtime = false;
  std::string force_log;  // CSV of the hand forces, every step ("" = none)
};

// Set by SIGINT/SIGTERM, read by the run loop (lock-free, so the handler only stores a flag).
std::atomic<bool> g_stop{false};
static_assert(std::atomic<bool>::is_always_lock_free);

extern "C" void on_stop_signal(int) {
  g_stop.store(true, std::memory_order_relaxed);
}

// Installs on_stop_signal for the life of a run. SA_RESETHAND: a second Ctrl-C kills at once,
// for a user who does not want to wait for the last frames.
class StopOnSignal {
 public:
  StopOnSignal() {
    g_stop.store(false);
    struct sigaction sa {};
    sa.sa_handler = on_stop_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = SA_RESETHAND;
    sigaction(SIGINT, &sa, &old_int_);
    sigaction(SIGTERM, &sa, &old_term_);
  }
  ~StopOnSignal() {
    sigaction(SIGINT, &old_int_, nullptr);
    sigaction(SIGTERM, &old_term_, nullptr);
  }
  StopOnSignal(const StopOnSignal&) = delete;
  StopOnSignal& operator=(const StopOnSignal&) = delete;

 private:
  struct sigaction old_int_ = {};
  struct sigaction old_term_ = {};
};

// The autopilot as an input source: it reads the simulator as a trainee reads the screen.
class AutopilotInput : public InputSource {
 public:
  AutopilotInput(Autopilot& pilot, const Simulator& sim) : pilot_(pilot), sim_(sim) {}
  void poll(double, DeviceCommands& out) override { pilot_.command(sim_, out); }

 private:
  Autopilot& pilot_;
  const Simulator& sim_;
};

// The live device named by --device, checked before the scene is built so that a bad option or
// a busy port fails at once.
std::unique_ptr<IgtlServer> open_device(const RunOptions& o, const Scenario& sc) {
  if (o.device.empty()) {
    if (o.port_given) throw InputError("run", "--port", "expected only with --device igtl");
    if (o.address_given) throw InputError("run", "--address", "expected only with --device igtl");
    return nullptr;
  }
  if (o.device != "igtl")
    throw InputError("run", "--device", "expected igtl (OpenIGTLink), got '" + o.device + "'");
  if (o.port < 0 || o.port > 65535)
    throw InputError(
        "run", "--port",
        "expected a TCP port 0-65535 (0: any free port), got " + std::to_string(o.port));
  IgtlServerOptions io;
  io.address = o.address;
  io.port = o.port;
  io.instruments.clear();
  for (const ScenarioInstrument& si : sc.instruments) io.instruments.push_back(si.name);
  try {
    return std::make_unique<IgtlServer>(io);
  } catch (const InputError& e) {
    // The server names its own option fields; the user typed command-line options.
    const std::string what = e.what();
    const std::string expected = what.substr(
        std::min(what.size(), e.source().size() + e.field().size() + 4));  // "src: field: "
    if (e.field() == "port") throw InputError("run", "--port", expected);
    if (e.field() == "address") throw InputError("run", "--address", expected);
    // instruments[i]: a scenario's instrument name the protocol cannot carry.
    throw InputError(sc.source, e.field() + ".name", expected + " (an OpenIGTLink device name)");
  }
}

// A name in data/scenarios or a path.
fs::path scenario_path(const std::string& arg) {
  const fs::path p(arg);
  if (fs::exists(p)) return p;
  const fs::path named = default_scenarios_dir() / (arg + ".json");
  if (p.extension().empty() && fs::exists(named)) return named;
  throw InputError("run", "SCENARIO",
                   "expected a scenario file or a name in " + default_scenarios_dir().string() +
                       ", got '" + arg + "'");
}

CArmPose pose_of(const Scenario& sc) {
  CArmPose pose;
  pose.primary_deg = sc.fluoro.primary_deg;
  pose.secondary_deg = sc.fluoro.secondary_deg;
  pose.fov = sc.fluoro.fov_mm * 1e-3;
  try {
    pose.validate(sc.source);
  } catch (const InputError& e) {
    throw InputError(sc.source, "fluoroscopy." + e.field(), e.what());
  }
  return pose;
}

class ProgressBar {
 public:
  explicit ProgressBar(bool on) : on_(on && isatty(STDERR_FILENO)) {}
  void show(double t, double limit, const std::string& what, double rtf) {
    if (!on_) return;
    const int width = 30;
    const int filled = static_cast<int>(width * std::min(1.0, t / limit));
    std::string bar(filled, '#');
    bar.resize(width, '.');
    std::fprintf(stderr, "\r[%s] %6.2f s  %5.1fx real time  %-48.48s", bar.c_str(), t, rtf,
                 what.c_str());
    std::fflush(stderr);
  }
  void done() {
    if (on_) std::fprintf(stderr, "\n");
  }

 private:
  bool on_;
};

// Films the run on a second thread, as the desktop app will draw: the physics thread hands over
// a copied state (FrameSnapshot) at each frame time; the worker owns the GL context, draws, runs
// the image chain and writes the PNG. At most kQueue frames wait, so a slow renderer holds the
// physics back instead of filling memory. The physics stays single-threaded and deterministic;
// each frame's noise seed is its index, so the frames do not depend on timing either.
class FrameWriter {
 public:
  FrameWriter(const Simulator& sim, int size, BeamEnergy energy, ImageChainSettings chain,
              fs::path dir)
      : chain_(chain), dir_(std::move(dir)), size_(size) {
    std::promise<void> ready;
    auto started = ready.get_future();
    worker_ = std::thread([this, &sim, size, energy, &ready] {
      bool signalled = false;  // after this, `ready` (the constructor's) is gone
      try {
        // The GL context is current on the thread that draws; the simulator's anatomy and
        // instrument specs, read here, do not change during the run.
        HeadlessGlContext gl;
        SimFluoroscopy fluoro(sim, size, energy);
        signalled = true;
        ready.set_value();
        run(fluoro);
      } catch (...) {
        std::lock_guard lock(m_);
        if (!error_) error_ = std::current_exception();
        failed_ = true;
        cv_.notify_all();
        if (!signalled) ready.set_value();
      }
    });
    started.wait();
    rethrow();
  }
  ~FrameWriter() {
    {
      std::lock_guard lock(m_);
      closed_ = true;
    }
    cv_.notify_all();
    if (worker_.joinable()) worker_.join();
  }
  FrameWriter(const FrameWriter&) = delete;
  FrameWriter& operator=(const FrameWriter&) = delete;

  void push(FrameSnapshot snap, const CArmPose& pose) {
    std::unique_lock lock(m_);
    cv_.wait(lock, [&] { return queue_.size() < kQueue || failed_; });
    if (failed_) {
      lock.unlock();
      rethrow();
    }
    queue_.push_back({std::move(snap), pose, submitted_++});
    cv_.notify_all();
  }
  // Waits until every frame handed over is written; rethrows the worker's error.
  void finish() {
    {
      std::unique_lock lock(m_);
      cv_.wait(lock, [&] { return (queue_.empty() && busy_ == 0) || failed_; });
    }
    rethrow();
  }
  int frames() const { return submitted_; }
  double render_seconds() const { return render_s_; }

 private:
  static constexpr std::size_t kQueue = 4;
  struct Job {
    FrameSnapshot snap;
    CArmPose pose;
    int index = 0;
  };
  void run(SimFluoroscopy& fluoro) {
    std::vector<std::uint8_t> img;
    for (;;) {
      Job job;
      {
        std::unique_lock lock(m_);
        cv_.wait(lock, [&] { return !queue_.empty() || closed_; });
        if (queue_.empty()) return;
        job = std::move(queue_.front());
        queue_.pop_front();
        ++busy_;
      }
      cv_.notify_all();
      const double t0 = now_us();
      ImageChainSettings chain = chain_;
      chain.seed = static_cast<std::uint64_t>(job.index + 1);
      fluoro.frame(job.snap, job.pose, chain, img);
      char name[32];
      std::snprintf(name, sizeof name, "frame_%05d.png", job.index);
      write_png_grey((dir_ / name).string(), img, size_, size_);
      {
        std::lock_guard lock(m_);
        --busy_;
        render_s_ += (now_us() - t0) * 1e-6;
      }
      cv_.notify_all();
    }
  }
  void rethrow() {
    std::exception_ptr e;
    {
      std::lock_guard lock(m_);
      e = error_;
    }
    if (e) std::rethrow_exception(e);
  }

  ImageChainSettings chain_;
  fs::path dir_;
  int size_;
  std::mutex m_;
  std::condition_variable cv_;
  std::deque<Job> queue_;
  int busy_ = 0;
  int submitted_ = 0;
  bool closed_ = false, failed_ = false;
  double render_s_ = 0.0;
  std::exception_ptr error_;
  std::thread worker_;
};

nlohmann::json shape_json(const Instrument& in) {
  nlohmann::json pts = nlohmann::json::array();
  for (int i = std::max(0, in.drive.first_free - 1); i < in.model.n; ++i) {
    const Vec3& x = in.state.x[i];
    pts.push_back(
        {std::round(x.x() * 1e4) / 10, std::round(x.y() * 1e4) / 10, std::round(x.z() * 1e4) / 10});
  }
  return pts;
}

// What the command line does around each step: film, progress, the autopilot's log.
class RunDisplay : public RunObserver {
 public:
  RunDisplay(const RunOptions& o, const Scenario& sc, Autopilot* pilot, FrameWriter* film,
             CArmPose& pose, Vec3 centre, double frame_dt, double end_time, std::string label)
      : o_(o),
        sc_(sc),
        pilot_(pilot),
        film_(film),
        pose_(pose),
        centre_(centre),
        frame_dt_(frame_dt),
        end_time_(end_time),
        label_(std::move(label)),
        bar_(!o.quiet),
        loop0_(now_us()) {}
  bool before_step(const Simulator& sim, const DeviceCommands&) override {
    if (!pilot_) return true;
    if (pilot_->finished()) return false;
    if (pilot_->status() != last_status_) {
      last_status_ = pilot_->status();
      if (!isatty(STDERR_FILENO) && !o_.quiet)
        std::cerr << "run: t = " << sim.time() << " s: " << last_status_ << "\n";
    }
    return true;
  }
  void after_step(const Simulator& sim) override {
    if (force_log_) log_forces(sim);
    if (film_ && sim.time() >= next_frame_ - 1e-9) {
      if (sc_.fluoro.follow_tip) {
        // The operator pans the table when the leading tip nears the edge of the field (in
        // moves, as at a real table, which also keeps the body's cached image valid), and
        // back to the heart once the tip is there.
        int lead = 0;
        for (int i = 1; i < sim.num_instruments(); ++i)
          if (sim.depth(i) > sim.depth(lead)) lead = i;
        const Vec3 tip = sim.tip(lead);
        const Vec3 want = (tip - centre_).norm() > 0.3 * pose_.fov ? tip : centre_;
        if ((want - pose_.isocentre).norm() > 0.3 * pose_.fov) pose_.isocentre = want;
      }
      film_->push(snapshot(sim), pose_);
      next_frame_ += frame_dt_;
    }
    if (sim.metrics().steps % 50 == 0) {
      const double wall = (now_us() - loop0_) * 1e-6;
      bar_.show(sim.time(), end_time_, pilot_ ? pilot_->status() : label_,
                wall > 0 ? sim.time() / wall : 0.0);
    }
  }
  void done() { bar_.done(); }
  // Every step's hand forces to `file` (CSV; a header names the columns).
  void open_force_log(const fs::path& file, const Scenario& sc) {
    force_log_.open(file);
    if (!force_log_)
      throw InputError("run", "--force-log",
                       "expected a writable file, got '" + file.string() + "'");
    force_log_ << "time_s";
    for (const ScenarioInstrument& si : sc.instruments)
      force_log_ << ',' << si.name << "_depth_mm," << si.name << "_force_n," << si.name
                 << "_torque_nmm";
    force_log_ << '\n';
  }

 private:
  void log_forces(const Simulator& sim) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.4f", sim.time());
    force_log_ << buf;
    for (int i = 0; i < sim.num_instruments(); ++i) {
      const DriveState& dr = sim.instrument(i).drive;
      std::snprintf(buf, sizeof buf, ",%.3f,%.6g,%.6g", dr.depth * 1e3, dr.axial_force,
                    dr.torque * 1e3);
      force_log_ << buf;
    }
    force_log_ << '\n';
  }

  const RunOptions& o_;
  const Scenario& sc_;
  Autopilot* pilot_;
  FrameWriter* film_;
  CArmPose& pose_;
  Vec3 centre_;
  double frame_dt_, end_time_;
  std::string label_;
  double next_frame_ = 0.0;
  ProgressBar bar_;
  std::string last_status_;
  double loop0_;
  std::ofstream force_log_;
};

int cmd_run(const RunOptions& o) {
  const fs::path file = scenario_path(o.scenario);
  Scenario sc = load_scenario(file);
  if (o.time_limit_s != 0.0)
    sc.time_limit = require_in_range(o.time_limit_s, 0.0, 3600.0, "run", "--time-limit");
  CArmPose pose = pose_of(sc);
  // A live device replaces the scenario's timeline or autopilot.
  std::unique_ptr<IgtlServer> device = open_device(o, sc);
  const fs::path out = o.out.empty() ? fs::path("out") / sc.name : fs::path(o.out);
  const fs::path frames_dir = out / "frames";
  std::error_code ec;
  fs::create_directories(frames_dir, ec);
  if (ec)
    throw InputError("run", "--out", "expected a writable folder, got '" + out.string() + "'");
  // Frames of an earlier run in the same folder would mix with this one's.
  for (const auto& e : fs::directory_iterator(frames_dir))
    if (e.path().extension() == ".png") fs::remove(e.path());

  std::optional<ScriptedTimeline> timeline;
  if (!device && !sc.timeline.empty()) timeline = ScriptedTimeline::load(sc.base_dir / sc.timeline);
  const StopOnSignal stop_on_signal;

  std::cerr << "run: " << sc.name << " (" << file.string() << "): building the scene\n";
  const double wall0 = now_us();
  Simulator sim(sc);
  std::unique_ptr<Autopilot> pilot;
  std::unique_ptr<AutopilotInput> pilot_input;
  if (!device && !timeline) {
    pilot = std::make_unique<Autopilot>(sim);
    pilot->trace = o.trace;
    pilot_input = std::make_unique<AutopilotInput>(*pilot, sim);
  }
  InputSource& input = device     ? static_cast<InputSource&>(*device)
                       : timeline ? static_cast<InputSource&>(*timeline)
                                  : static_cast<InputSource&>(*pilot_input);
  const char* input_type = device ? "igtl" : timeline ? "timeline" : "autopilot";

  ImageChainSettings chain;
  chain.dose = sc.fluoro.dose;
  std::unique_ptr<FrameWriter> film;
  if (!o.no_frames)
    film = std::make_unique<FrameWriter>(
        sim, sc.fluoro.size, sc.fluoro.energy_kev == 80 ? BeamEnergy::k80keV : BeamEnergy::k60keV,
        chain, frames_dir);
  // The table centred on the left coronary tree; RunDisplay pans to the tip when it is far.
  const Vec3 centre = left_coronary_centre(sim.tree());
  pose.isocentre = centre;
  const double frame_dt = 1.0 / sc.fluoro.fps;
  const double end_time = timeline ? std::min(sc.time_limit, timeline->duration()) : sc.time_limit;

  if (device) {
    std::string names;
    for (const ScenarioInstrument& si : sc.instruments)
      names += (names.empty() ? "" : ", ") + si.name;
    std::cerr << "run: OpenIGTLink server listening on " << o.address << ":" << device->port()
              << " (instruments: " << names << ")" << std::endl;  // flushed: a client waits on it
  }
  RunDisplay observer(o, sc, pilot.get(), film.get(), pose, centre, frame_dt, end_time, input_type);
  if (!o.force_log.empty()) observer.open_force_log(o.force_log, sc);
  RunLoopSettings loop_settings;
  loop_settings.end_time = end_time;
  loop_settings.realtime = device || o.realtime;
  loop_settings.stop = &g_stop;
  const double loop0 = now_us();
  const RunLoopStats loop = run_loop(sim, input, loop_settings, &observer);
  if (device) device->stop();  // the connection closes with the run; the counts are final
  if (film) film->finish();    // the last frames are written before the clock stops
  const int frames = film ? film->frames() : 0;
  const double render_s = film ? film->render_seconds() : 0.0;
  observer.done();
  if (loop.stopped) std::cerr << "run: stopped by a signal at t = " << sim.time() << " s\n";
  const double wall_total = (now_us() - wall0) * 1e-6;
  const double loop_wall = (now_us() - loop0) * 1e-6;

  // Video, when ffmpeg is there (optional; the frames are the primary output).
  std::string video;
  if (frames > 0 && std::system("command -v ffmpeg > /dev/null 2>&1") == 0) {
    const std::string cmd = "ffmpeg -y -loglevel error -framerate " +
                            std::to_string(sc.fluoro.fps) + " -i '" +
                            (frames_dir / "frame_%05d.png").string() +
                            "' -pix_fmt yuv420p -vf scale=trunc(iw/2)*2:trunc(ih/2)*2 '" +
                            (out / "run.mp4").string() + "'";
    if (std::system(cmd.c_str()) == 0) video = (out / "run.mp4").string();
  }

  const SimMetrics& m = sim.metrics();
  nlohmann::json j;
  j["scenario"] = sc.name;
  j["scenario_file"] = file.string();
  j["dt_s"] = sc.dt;
  j["sim_time_s"] = m.sim_time;
  j["wall_time_s"] = loop_wall;
  j["setup_time_s"] = wall_total - loop_wall;
  j["physics_time_s"] = m.wall_time;
  j["render_time_s"] = render_s;
  j["real_time_factor"] = loop_wall > 0 ? m.sim_time / loop_wall : 0.0;
  j["physics_real_time_factor"] = m.wall_time > 0 ? m.sim_time / m.wall_time : 0.0;
  j["steps"] = m.steps;
  j["rollbacks"] = m.rollbacks;
  j["resplit_steps"] = m.resplit_steps;
  j["frames"] = frames;
  j["fluoroscopy_time_s"] = frames * frame_dt;
  j["contrast_volume_ml"] = m.contrast_volume;
  j["video"] = video;
  nlohmann::json insts = nlohmann::json::array();
  for (int i = 0; i < sim.num_instruments(); ++i) {
    const Instrument& in = sim.instrument(i);
    const TreeHit h = sim.tip_location(i);
    insts.push_back({{"name", sc.instruments[i].name},
                     {"catalogue", sc.instruments[i].catalogue},
                     {"nodes", in.model.n},
                     {"inserted_mm", in.drive.depth * 1e3},
                     {"tip_path_mm", m.tip_path[i] * 1e3},
                     {"peak_wall_force_n", m.peak_wall_force[i]},
                     {"peak_axial_force_n", m.peak_axial_force[i]},
                     {"peak_axial_jump_n", m.peak_axial_jump[i]},
                     {"peak_torque_nmm", m.peak_torque[i] * 1e3},
                     {"tip_segment", in.drive.depth > 0 ? sim.tree().segments[h.loc.segment].name
                                                        : std::string("outside")},
                     {"tip_distance_mm", h.loc.distance * 1e3},
                     {"final_shape_mm", shape_json(in)}});
  }
  j["instruments"] = insts;
  nlohmann::json lms = nlohmann::json::array();
  std::vector<std::string> missed;
  for (const LandmarkRecord& l : m.landmarks) {
    lms.push_back({{"name", l.name},
                   {"instrument", l.instrument},
                   {"reached", l.reached},
                   {"time_s", l.reached ? nlohmann::json(l.time) : nlohmann::json(nullptr)}});
    if (!l.reached) missed.push_back(l.name);
  }
  j["landmarks"] = lms;
  nlohmann::json input_json = {{"type", input_type}, {"realtime", loop_settings.realtime}};
  if (device) {
    const IgtlStats st = device->stats();
    input_json["address"] = o.address;
    input_json["port"] = device->port();
    input_json["connections"] = st.connections;
    input_json["disconnections"] = st.disconnections;
    input_json["messages_accepted"] = st.messages_accepted;
    input_json["messages_dropped"] = st.messages_dropped;
    input_json["feedback_sent"] = st.feedback_sent;
  }
  if (loop_settings.realtime) {
    input_json["late_steps"] = loop.late_steps;
    input_json["max_lag_ms"] = loop.max_lag * 1e3;
    input_json["resyncs"] = loop.resyncs;
  }
  j["input"] = input_json;
  j["stopped_by_signal"] = loop.stopped;
  if (pilot)
    j["autopilot"] = {{"finished", pilot->finished() && !pilot->failed()},
                      {"failed", pilot->failed()},
                      {"status", pilot->status()},
                      {"retries", pilot->retries()}};
  const bool success = missed.empty();
  std::string outcome = "all landmarks reached";
  if (!success) {
    outcome = "not reached:";
    for (const auto& s : missed) outcome += " '" + s + "'";
    outcome +=
        sim.time() >= end_time - 1e-9 ? " (time limit " + std::to_string(end_time) + " s)" : "";
    if (pilot && pilot->failed()) outcome += " (" + pilot->status() + ")";
  }
  if (loop.stopped) outcome += " (stopped by a signal at t = " + std::to_string(sim.time()) + " s)";
  j["outcome"] = outcome;
  j["success"] = success;
  const fs::path metrics = out / "metrics.json";
  std::ofstream(metrics) << j.dump(2) << "\n";

  std::cout << "run: " << sc.name << ": " << outcome << "\n";
  for (const LandmarkRecord& l : m.landmarks)
    std::cout << "  " << (l.reached ? "reached " : "MISSED  ") << l.name << " (" << l.instrument
              << ")" << (l.reached ? " at " + std::to_string(l.time) + " s" : "") << "\n";
  std::cout << "  simulated " << m.sim_time << " s in " << loop_wall << " s wall ("
            << j["real_time_factor"].get<double>() << "x real time; physics alone "
            << j["physics_real_time_factor"].get<double>() << "x)\n"
            << "  frames:  " << frames_dir.string() << " (" << frames << " PNG at " << sc.fluoro.fps
            << " fps)\n";
  if (!video.empty()) std::cout << "  video:   " << video << "\n";
  if (device) {
    const auto& in = j["input"];
    std::cout << "  device:  OpenIGTLink on " << o.address << ":" << device->port() << ", "
              << in["connections"].get<std::uint64_t>() << " connection(s), "
              << in["messages_accepted"].get<std::uint64_t>() << " messages accepted ("
              << in["messages_dropped"].get<std::uint64_t>() << " dropped), "
              << in["feedback_sent"].get<std::uint64_t>() << " force messages sent\n";
  }
  if (loop_settings.realtime)
    std::cout << "  pacing:  real time, " << loop.late_steps << " late steps (worst lag "
              << loop.max_lag * 1e3 << " ms, " << loop.resyncs << " resyncs)\n";
  std::cout << "  metrics: " << metrics.string() << "\n";
  return success ? 0 : kNotReached;
}

void install(CLI::App& app, int& status) {
  auto o = std::make_shared<RunOptions>();
  auto* cmd = app.add_subcommand("run", "Run a scenario headless: frames, metrics, landmarks");
  cmd->add_option("scenario", o->scenario,
                  "Scenario file, or a name in data/scenarios (default: default)");
  cmd->add_option("--out", o->out, "Output folder (default: out/<scenario name>)");
  cmd->add_flag("--no-frames", o->no_frames, "Physics only: no fluoroscopy frames");
  cmd->add_flag("--quiet", o->quiet, "No progress output");
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
  cmd->callback([o, &status, cmd] {
    o->port_given = cmd->count("--port") > 0;
    o->address_given = cmd->count("--address") > 0;
    status = cmd_run(*o);
  });
}

const int kRegistered = register_command(5, install);

}  // namespace

}  // namespace vcsim::app
