// `vcsim trainer [SCENARIO]`: the interactive trainer (apps/trainer, docs/trainer.md). A window
// where a person performs the procedure with keyboard, mouse and gamepad, or a device over
// OpenIGTLink (`--device igtl`, as `vcsim run`), at real time. At the end the session is saved as
// a command recording (`vcsim run SCENARIO --replay DIR/recording.json` replays it to the same
// state) with its metrics. `--bench` runs the default scene with scripted input and prints the
// frame rate, the physics lag and the input-to-frame latency as JSON. This file is options only.
#include <csignal>
#include <filesystem>
#include <iostream>
#include <memory>
#include <string>

#include "commands.h"
#include "run_support.h"
#include "trainer.h"
#include "vcsim/render.h"
#include "vcsim/sim.h"

namespace vcsim::app {

namespace {

namespace fs = std::filesystem;

struct TrainerCliOptions {
  std::string scenario = "default";
  std::string out;
  int size = 512;
  int width = 1280, height = 800;
  std::string script;
  bool bench = false;
  double bench_time = 20.0;
  std::string device;
  int port = 18944;
  bool port_given = false;
  std::string address = "127.0.0.1";
  bool address_given = false;
};

int cmd_trainer(const TrainerCliOptions& c) {
  // Everything the person gave is checked before a window opens or a file is written.
  const fs::path file = find_scenario(c.scenario, "trainer", "SCENARIO");
  Scenario sc = load_scenario(file);
  sc.autopilot.clear();  // the person drives
  sc.timeline.clear();
  scenario_pose(sc);  // a bad C-arm setting fails before the scene is built
  trainer::TrainerOptions o;
  o.fluoro_size = static_cast<int>(require_in_range(c.size, 63, 2048, "trainer", "--size"));
  o.width = static_cast<int>(require_in_range(c.width, 319, 8192, "trainer", "--width"));
  o.height = static_cast<int>(require_in_range(c.height, 239, 8192, "trainer", "--height"));
  o.bench_time = require_in_range(c.bench_time, 2.0, 3600.0, "trainer", "--bench-time");
  if (!c.script.empty()) {
    if (c.bench) throw InputError("trainer", "--script", "expected either --script or --bench");
    if (!fs::is_regular_file(c.script))
      throw InputError("trainer", "--script", "expected a script file, got '" + c.script + "'");
  }
  o.script = c.script;
  o.bench = c.bench;
  o.write_outputs = !c.bench || !c.out.empty();
  o.out = c.out.empty() ? fs::path("out") / ("trainer-" + sc.name) : fs::path(c.out);
  o.scenario_file = file.string();
  o.device =
      open_device({c.device, c.port, c.port_given, c.address, c.address_given, "trainer"}, sc);
  o.device_address = c.address;
  trainer::require_display();
  if (o.write_outputs) {
    // The folder is made now, so that a session is not lost at its end for want of it.
    std::error_code ec;
    fs::create_directories(o.out, ec);
    if (ec || !fs::is_directory(o.out))
      throw InputError("trainer", "--out",
                       "expected a writable folder, got '" + o.out.string() + "'");
  }
  if (o.device)
    std::cerr << "trainer: OpenIGTLink server listening on " << c.address << ":" << o.device->port()
              << std::endl;  // flushed: a client waits on it
  o.scenario = std::move(sc);
  // A closed pipe on stdout or stderr (a terminal gone, `| head`) must not kill the session
  // before it is saved: a write fails instead.
  std::signal(SIGPIPE, SIG_IGN);
  const StopOnSignal stop;
  o.stop = &stop.flag();
  return trainer::run_trainer(std::move(o));
}

void install(CLI::App& app, int& status) {
  auto o = std::make_shared<TrainerCliOptions>();
  auto* cmd = app.add_subcommand(
      "trainer",
      "The interactive trainer: a window to perform the procedure (xvfb-run -a without a display)");
  cmd->add_option("scenario", o->scenario,
                  "Scenario file, or a name in data/scenarios (default: default; its autopilot is "
                  "not used: you drive)");
  cmd->add_option("--out", o->out,
                  "Folder for the session's recording, metrics, cine runs and screenshots "
                  "(default: out/trainer-<scenario name>)");
  cmd->add_option("--size", o->size, "Fluoroscopy image size in pixels (default 512)");
  cmd->add_option("--width", o->width, "Window width (default 1280)");
  cmd->add_option("--height", o->height, "Window height (default 800)");
  cmd->add_option("--script", o->script,
                  "Scripted input events (JSON, docs/trainer.md): tests, demonstrations");
  cmd->add_flag("--bench", o->bench,
                "Run the scene with scripted input and print fps, physics lag and input-to-frame "
                "latency as JSON");
  cmd->add_option("--bench-time", o->bench_time, "Seconds the benchmark runs (default 20)");
  cmd->add_option("--device", o->device,
                  "A live device beside the keyboard: igtl (an OpenIGTLink server)");
  cmd->add_option("--port", o->port, "TCP port of --device igtl (default 18944; 0: any free)");
  cmd->add_option("--address", o->address,
                  "IPv4 address --device igtl listens on (default 127.0.0.1)");
  cmd->callback([o, &status, cmd] {
    o->port_given = cmd->count("--port") > 0;
    o->address_given = cmd->count("--address") > 0;
    status = cmd_trainer(*o);
  });
}

const int kRegistered = register_command(6, install);

}  // namespace

}  // namespace vcsim::app
