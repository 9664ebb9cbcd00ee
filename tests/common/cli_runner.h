// Runs the vcsim command line (VCSIM_CLI, set by CMake) and captures its exit status and output.
#pragma once

#include <fcntl.h>
#include <gtest/gtest.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace vcsim::test {

struct CliResult {
  int status = -1;
  std::string out, err;
};

inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

// `args` follow the program name, e.g. "validate torsion --json"; `env` is an optional
// "NAME=value " prefix for the shell.
inline CliResult run_cli(const std::string& args, const std::string& env = "") {
  const auto dir = std::filesystem::temp_directory_path();
  // Built with += : GCC 12 warns falsely (-Wrestrict) on "literal" + std::to_string(...).
  std::string tag = "vcsim_cli_";
  tag += std::to_string(::getpid());
  tag += "_";
  tag += ::testing::UnitTest::GetInstance()->current_test_info()->name();
  const auto out = dir / (tag + ".out");
  const auto err = dir / (tag + ".err");
  std::string cmd = env;
  cmd += VCSIM_CLI;
  cmd += " ";
  cmd += args;
  cmd += " >";
  cmd += out.string();
  cmd += " 2>";
  cmd += err.string();
  const int raw = std::system(cmd.c_str());
  CliResult r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  std::filesystem::remove(out);
  std::filesystem::remove(err);
  return r;
}

// The command line as a child process the test can talk to and signal (a live run): stdout and
// stderr go to files, SIGINT and SIGTERM at their defaults whatever the test inherited.
class CliProcess {
 public:
  CliProcess(const std::vector<std::string>& args, const std::filesystem::path& out,
             const std::filesystem::path& err) {
    std::vector<std::string> argv_s = {VCSIM_CLI};
    argv_s.insert(argv_s.end(), args.begin(), args.end());
    std::vector<char*> argv;
    for (auto& a : argv_s) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 1, out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&fa, 2, err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawnattr_t attr;
    posix_spawnattr_init(&attr);
    sigset_t defaults;
    sigemptyset(&defaults);
    sigaddset(&defaults, SIGINT);
    sigaddset(&defaults, SIGTERM);
    posix_spawnattr_setsigdefault(&attr, &defaults);
    posix_spawnattr_setflags(&attr, POSIX_SPAWN_SETSIGDEF);
    if (posix_spawn(&pid_, argv[0], &fa, &attr, argv.data(), environ) != 0) pid_ = -1;
    posix_spawn_file_actions_destroy(&fa);
    posix_spawnattr_destroy(&attr);
  }
  ~CliProcess() {
    if (pid_ > 0 && status_ < 0 && !killed_) {  // a failed test must not leave a server running
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  CliProcess(const CliProcess&) = delete;
  CliProcess& operator=(const CliProcess&) = delete;

  bool started() const { return pid_ > 0; }
  void signal(int sig) {
    if (pid_ > 0 && status_ < 0) ::kill(pid_, sig);
  }
  // True once the process has ended (exit status in status(), -1 when killed by a signal).
  bool exited() {
    if (pid_ <= 0 || status_ >= 0 || killed_) return true;
    int raw = 0;
    if (::waitpid(pid_, &raw, WNOHANG) != pid_) return false;
    if (WIFEXITED(raw)) {
      status_ = WEXITSTATUS(raw);
    } else {
      killed_ = true;
    }
    return true;
  }
  bool wait(std::chrono::milliseconds limit) {
    const auto end = std::chrono::steady_clock::now() + limit;
    while (!exited()) {
      if (std::chrono::steady_clock::now() > end) return false;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return true;
  }
  int status() const { return status_; }

 private:
  pid_t pid_ = -1;
  int status_ = -1;
  bool killed_ = false;
};

}  // namespace vcsim::test
