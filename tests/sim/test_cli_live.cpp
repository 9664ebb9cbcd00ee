// `vcsim run --device igtl` end to end: the run listens, prints where, follows an OpenIGTLink
// client's commands in real time, sends forces back, ends at its time limit or on SIGINT with a
// complete report, and rejects bad device options with status 2. Every wait is bounded and
// generous (a loaded machine); nothing asserts on timing.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "../common/cli_runner.h"
#include "../common/igtl_client.h"

namespace vcsim::test {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

// The library's client sends without MSG_NOSIGNAL: a run that ends must not kill the test.
const bool kIgnoreSigpipe = (std::signal(SIGPIPE, SIG_IGN), true);

fs::path scratch(const std::string& name) {
  const fs::path d = fs::temp_directory_path() / ("vcsim_live_cli_" + name);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

// One J wire in the static anatomy (as RunCli's scripted tests); its timeline is unused when a
// device drives the run.
void write_scenario(const fs::path& d) {
  std::ofstream(d / "timeline.json") << R"({"keyframes": [
    {"t_s": 0, "instruments": {"wire": {"translation_mm": 0, "rotation_deg": 0}}},
    {"t_s": 1, "instruments": {"wire": {"translation_mm": 100, "rotation_deg": 0}}}]})";
  std::ofstream(d / "s.json") << R"({"format": "vcsim-scenario", "version": 1, "name": "live",
    "motion": {"beating": false}, "dt_ms": 0.5, "time_limit_s": 600,
    "instruments": [{"name": "wire", "catalogue": "wire-035-j3-hydrophilic",
                     "tip_segment_mm": 2}],
    "input": {"type": "timeline", "file": "timeline.json"},
    "landmarks": [{"name": "external iliac", "instrument": "wire",
                   "segment": "right_external_iliac"}]})";
}

// Waits for the run's "listening on ADDRESS:PORT" line; 0 when the run ended or never said it.
int wait_for_port(CliProcess& p, const fs::path& err, std::chrono::seconds limit = 180s) {
  const auto end = Clock::now() + limit;
  const std::string key = "listening on 127.0.0.1:";
  while (Clock::now() < end) {
    const std::string text = slurp(err);
    const auto at = text.find(key);
    if (at != std::string::npos && text.find('\n', at) != std::string::npos)
      return std::atoi(text.c_str() + at + key.size());
    if (p.exited()) return 0;
    std::this_thread::sleep_for(20ms);
  }
  return 0;
}

using Client = test::IgtlClient;

TEST(RunCli, LiveDeviceDrivesTheRun) {
  const fs::path d = scratch("drive");
  write_scenario(d);
  CliProcess p({"run", (d / "s.json").string(), "--device", "igtl", "--port", "0", "--no-frames",
                "--quiet", "--time-limit", "3", "--out", (d / "out").string()},
               d / "stdout.txt", d / "stderr.txt");
  ASSERT_TRUE(p.started());
  const int port = wait_for_port(p, d / "stderr.txt");
  ASSERT_GT(port, 0) << slurp(d / "stderr.txt");
  EXPECT_NE(slurp(d / "stderr.txt").find("(instruments: wire)"), std::string::npos);

  // Push the wire to 30 mm and hold it there (a device repeats its position at its own rate),
  // reading forces in between, until the run reaches its 3 s.
  Client c;
  ASSERT_TRUE(c.connect(port));
  int forces = 0;
  std::vector<double> v;
  const auto end = Clock::now() + 300s;
  while (!p.exited() && Clock::now() < end) {
    c.send_transform("wire", 30.0);  // fails harmlessly once the run has closed the connection
    if (c.read_sensor("force_wire", v, 100ms) && v.size() == 2 && std::isfinite(v[0])) ++forces;
  }
  c.close();
  ASSERT_TRUE(p.wait(60s));
  const std::string err = slurp(d / "stderr.txt");
  ASSERT_TRUE(p.status() == 0 || p.status() == 3) << p.status() << "\n" << err;
  EXPECT_GT(forces, 0);

  const auto j = nlohmann::json::parse(slurp(d / "out" / "metrics.json"));
  const auto& in = j["input"];
  EXPECT_EQ(in["type"], "igtl");
  EXPECT_EQ(in["port"].get<int>(), port);
  EXPECT_GE(in["connections"].get<int>(), 1);
  EXPECT_GE(in["messages_accepted"].get<int>(), 1);
  EXPECT_EQ(in["messages_dropped"].get<int>(), 0);
  EXPECT_GT(in["feedback_sent"].get<int>(), 0);
  for (const char* key : {"late_steps", "max_lag_ms"}) EXPECT_TRUE(in.contains(key)) << key;
  EXPECT_FALSE(j["stopped_by_signal"].get<bool>());
  EXPECT_NEAR(j["sim_time_s"].get<double>(), 3.0, 1e-3);
  // The wire went where the device put it (the drive moves at most 0.5 m/s: 30 mm well within
  // the run, even if the client connected late), and its tip moved with it.
  const auto& w = j["instruments"][0];
  EXPECT_NEAR(w["inserted_mm"].get<double>(), 30.0, 0.5);
  EXPECT_GT(w["tip_path_mm"].get<double>(), 20.0);
}

TEST(RunCli, LiveRunEndsCleanlyOnSigint) {
  const fs::path d = scratch("sigint");
  write_scenario(d);
  CliProcess p({"run", (d / "s.json").string(), "--device", "igtl", "--port", "0", "--no-frames",
                "--quiet", "--out", (d / "out").string()},
               d / "stdout.txt", d / "stderr.txt");
  ASSERT_TRUE(p.started());
  const int port = wait_for_port(p, d / "stderr.txt");
  ASSERT_GT(port, 0) << slurp(d / "stderr.txt");
  Client c;
  ASSERT_TRUE(c.connect(port));
  c.send_transform("wire", 10.0);
  std::this_thread::sleep_for(500ms);  // some steps (the time limit is 600 s)
  c.close();
  p.signal(SIGINT);
  ASSERT_TRUE(p.wait(120s)) << "the run did not end on SIGINT";
  ASSERT_TRUE(p.status() == 0 || p.status() == 3) << p.status() << "\n" << slurp(d / "stderr.txt");
  EXPECT_NE(slurp(d / "stderr.txt").find("stopped by a signal"), std::string::npos);

  const auto j = nlohmann::json::parse(slurp(d / "out" / "metrics.json"));  // complete JSON
  EXPECT_TRUE(j["stopped_by_signal"].get<bool>());
  EXPECT_EQ(j["input"]["type"], "igtl");
  EXPECT_GT(j["steps"].get<int>(), 0);
  EXPECT_LT(j["sim_time_s"].get<double>(), 600.0);
  for (const char* key : {"instruments", "landmarks", "outcome", "success"})
    EXPECT_TRUE(j.contains(key)) << key;
  EXPECT_EQ(j["instruments"].size(), 1u);
  EXPECT_NE(slurp(d / "stdout.txt").find("stopped by a signal"), std::string::npos)
      << slurp(d / "stdout.txt");
}

TEST(RunCli, BadDeviceOptionsExitWithTwo) {
  const fs::path d = scratch("bad");
  write_scenario(d);
  // A port another program holds.
  const int busy = ::socket(AF_INET, SOCK_STREAM, 0);
  ASSERT_GE(busy, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::bind(busy, reinterpret_cast<sockaddr*>(&addr), sizeof addr), 0);
  ASSERT_EQ(::listen(busy, 1), 0);
  socklen_t len = sizeof addr;
  ::getsockname(busy, reinterpret_cast<sockaddr*>(&addr), &len);
  const std::string busy_port = std::to_string(ntohs(addr.sin_port));

  struct Case {
    std::string args, expect;
  };
  const Case cases[] = {
      {"--device foo", "--device"},
      {"--device igtl --port 70000", "--port"},
      {"--device igtl --port -1", "--port"},
      {"--device igtl --port abc", "--port"},
      {"--device igtl --port " + busy_port, "--port"},
      {"--device igtl --address not.an.address", "--address"},
      {"--port 5000", "--port"},  // without a device
  };
  for (const Case& c : cases) {
    const CliResult r = run_cli("run " + (d / "s.json").string() + " --no-frames --out " +
                                (d / "out").string() + " " + c.args);
    EXPECT_EQ(r.status, 2) << c.args << "\n" << r.out << r.err;
    EXPECT_NE(r.err.find(c.expect), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << c.args << "\n" << r.err;
  }
  ::close(busy);

  // A scenario instrument name the protocol cannot carry (at most 14 characters).
  std::string text = slurp(d / "s.json");
  for (auto at = text.find("\"wire\""); at != std::string::npos; at = text.find("\"wire\"", at))
    text.replace(at, 6, "\"a_very_long_wire\"");
  std::ofstream(d / "long.json") << text;
  const CliResult r = run_cli("run " + (d / "long.json").string() +
                              " --no-frames --device igtl --port 0 --out " + (d / "out").string());
  EXPECT_EQ(r.status, 2) << r.out << r.err;
  EXPECT_NE(r.err.find("long.json: instruments[0].name"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace vcsim::test
