// The trainer: one window where a person performs the procedure (issue 26, docs/trainer.md).
// A viewer library after MuJoCo's `simulate`: physics on its own thread at real time
// (physics.h), the window drawing the latest copied state (viewer.cpp), the hands' controls
// (controls.h) and a scripted event feed for tests and the benchmark (script.h). `vcsim trainer`
// (apps/vcsim/cmd_trainer.cpp) is its thin entry: options in, run_trainer out.
#pragma once

#include <atomic>
#include <filesystem>
#include <memory>
#include <string>

#include "vcsim/haptics.h"
#include "vcsim/sim.h"

namespace vcsim::trainer {

struct TrainerOptions {
  Scenario scenario;               // loaded and checked by the caller; its autopilot is not used
  std::string scenario_file;       // as given (the recording and metrics name it)
  std::filesystem::path out;       // recording.json, metrics.json, cine runs, screenshots
  bool write_outputs = true;       // false: nothing written (a benchmark without --out)
  int fluoro_size = 512;           // px of the fluoroscopy image
  int width = 1280, height = 800;  // window (screen coordinates)
  std::filesystem::path script;    // scripted input events (script.h), "" = none
  bool bench = false;              // the built-in benchmark script; JSON on stdout at the end
  double bench_time = 20.0;        // s of the benchmark
  std::unique_ptr<IgtlServer> device;  // a live OpenIGTLink device, or none
  std::string device_address;
  const std::atomic<bool>* stop = nullptr;  // set by a signal: end the session as a close does
};

// Throws InputError naming xvfb-run when the machine has no display to open a window on.
void require_display();

// Runs a session until the window closes (or the script or benchmark ends, or *stop): returns
// the exit status. Throws InputError for bad input (exit 2 in the CLI), including a machine
// without a display, and std::runtime_error for what fails inside (no OpenGL 3.3).
int run_trainer(TrainerOptions options);

}  // namespace vcsim::trainer
