// Subcommands of the vcsim command line. Each group lives in its own cmd_*.cpp and registers an
// installer that adds its subcommands and callbacks; a callback stores the exit status. Bad input
// is thrown as InputError (printed on one line by main, exit status 2).
#pragma once

#include <CLI/CLI.hpp>

#include <utility>
#include <vector>

namespace vcsim::app {

using CommandInstaller = void (*)(CLI::App& app, int& status);

// Installers sorted by their order key (the order subcommands appear in --help).
std::vector<std::pair<int, CommandInstaller>>& command_installers();
inline int register_command(int order, CommandInstaller installer) {
  command_installers().emplace_back(order, installer);
  return order;
}

// The `bench` subcommand group, shared by every cmd_*.cpp that adds a benchmark to it.
CLI::App& bench_group(CLI::App& app);

}  // namespace vcsim::app
