// What the commands that run a simulation share (`vcsim run`, and the trainer to come): ending a
// run cleanly on SIGINT or SIGTERM, and opening the live OpenIGTLink device named by options.
#pragma once

#include <atomic>
#include <csignal>
#include <memory>
#include <string>

#include "vcsim/haptics.h"
#include "vcsim/sim.h"

namespace vcsim::app {

// Sets a flag on SIGINT and SIGTERM for as long as it lives (the run loop reads the flag;
// lock-free, so the handler only stores it). SA_RESETHAND: a second Ctrl-C kills at once, for a
// user who does not want to wait for the last frames.
class StopOnSignal {
 public:
  StopOnSignal();
  ~StopOnSignal();
  StopOnSignal(const StopOnSignal&) = delete;
  StopOnSignal& operator=(const StopOnSignal&) = delete;
  const std::atomic<bool>& flag() const;

 private:
  struct sigaction old_int_ = {};
  struct sigaction old_term_ = {};
};

// The live device options of a command line (--device, --port, --address).
struct DeviceOptions {
  std::string device;  // "" (none) or "igtl"
  int port = 18944;
  bool port_given = false;
  std::string address = "127.0.0.1";
  bool address_given = false;
  std::string command = "run";  // names the command line in errors ("run", "trainer")
};

// The live device named by the options, listening at once (so that a bad option or a busy port
// fails before the scene is built), with the scenario's instruments in its order; nullptr when
// none is named. The server's option errors are renamed to the command line's options.
std::unique_ptr<IgtlServer> open_device(const DeviceOptions& o, const Scenario& scenario);

}  // namespace vcsim::app
