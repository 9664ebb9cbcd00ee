// Runs the vcsim command line (VCSIM_CLI, set by CMake) and captures its exit status and output.
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

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

}  // namespace vcsim::test
