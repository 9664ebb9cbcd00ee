#include "run_support.h"

#include "vcsim/units.h"

namespace vcsim::app {

namespace {

std::atomic<bool> g_stop{false};
static_assert(std::atomic<bool>::is_always_lock_free);

extern "C" void on_stop_signal(int) {
  g_stop.store(true, std::memory_order_relaxed);
}

}  // namespace

StopOnSignal::StopOnSignal() {
  g_stop.store(false);
  struct sigaction sa {};
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESETHAND;
  sigaction(SIGINT, &sa, &old_int_);
  sigaction(SIGTERM, &sa, &old_term_);
}

StopOnSignal::~StopOnSignal() {
  sigaction(SIGINT, &old_int_, nullptr);
  sigaction(SIGTERM, &old_term_, nullptr);
}

const std::atomic<bool>& StopOnSignal::flag() const {
  return g_stop;
}

std::unique_ptr<IgtlServer> open_device(const DeviceOptions& o, const Scenario& sc) {
  if (o.device.empty()) {
    if (o.port_given) throw InputError(o.command, "--port", "expected only with --device igtl");
    if (o.address_given)
      throw InputError(o.command, "--address", "expected only with --device igtl");
    return nullptr;
  }
  if (o.device != "igtl")
    throw InputError(o.command, "--device", "expected igtl (OpenIGTLink), got '" + o.device + "'");
  if (o.port < 0 || o.port > 65535)
    throw InputError(
        o.command, "--port",
        "expected a TCP port 0-65535 (0: any free port), got " + std::to_string(o.port));
  IgtlServerOptions io;
  io.address = o.address;
  io.port = o.port;
  // A device faster than the drive is followed at the drive's speed, and told so once.
  io.drive_max_speed_mm_s = Sheath{}.max_speed / kMm;
  io.drive_max_spin_deg_s = Sheath{}.max_spin / kDeg;
  io.instruments.clear();
  for (const ScenarioInstrument& si : sc.instruments) io.instruments.push_back(si.name);
  try {
    return std::make_unique<IgtlServer>(io);
  } catch (const InputError& e) {
    const std::string what = e.what();
    const std::string expected = what.substr(
        std::min(what.size(), e.source().size() + e.field().size() + 4));  // "src: field: "
    if (e.field() == "port") throw InputError(o.command, "--port", expected);
    if (e.field() == "address") throw InputError(o.command, "--address", expected);
    // instruments[i]: a scenario's instrument name the protocol cannot carry.
    throw InputError(sc.source, e.field() + ".name", expected + " (an OpenIGTLink device name)");
  }
}

}  // namespace vcsim::app
