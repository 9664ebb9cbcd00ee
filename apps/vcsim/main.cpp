// vcsim command line. Subcommands register themselves (commands.h). Bad input prints one line
// naming the field and exits with status 2.
#include <algorithm>
#include <iostream>

#include "commands.h"
#include "vcsim/core.h"

namespace vcsim::app {

std::vector<std::pair<int, CommandInstaller>>& command_installers() {
  static std::vector<std::pair<int, CommandInstaller>> installers;
  return installers;
}

CLI::App& bench_group(CLI::App& app) {
  for (auto* sub : app.get_subcommands([](CLI::App* s) { return s->get_name() == "bench"; })) {
    return *sub;
  }
  auto* bench = app.add_subcommand("bench", "Benchmarks (JSON with --json)");
  bench->require_subcommand(1);
  return *bench;
}

}  // namespace vcsim::app

namespace {

int run(int argc, char** argv) {
  using namespace vcsim::app;
  CLI::App app{"vcsim: a simulator for training cardiovascular interventions"};
  app.require_subcommand(1);
  int status = 0;
  auto installers = command_installers();
  std::sort(installers.begin(), installers.end());
  for (auto& [order, install] : installers) install(app, status);
  app.add_subcommand("info", "Version and build")->callback([] {
    std::cout << "vcsim 0.1.0 (C++20, Eigen " << EIGEN_WORLD_VERSION << "." << EIGEN_MAJOR_VERSION
              << "." << EIGEN_MINOR_VERSION << ")\n";
  });
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);
    const std::string first = argc > 1 ? argv[1] : "";
    const auto subs = app.get_subcommands([&](CLI::App* s) { return s->get_name() == first; });
    if (!first.empty() && first[0] != '-' && subs.empty()) {
      std::string names;
      for (auto* s : app.get_subcommands({})) names += (names.empty() ? "" : ", ") + s->get_name();
      std::cerr << "vcsim: error: command: expected one of " << names << ", got '" << first
                << "'\n";
    } else {
      std::cerr << "vcsim: error: " << e.what() << "\n";
    }
    return 2;
  }
  return status;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const vcsim::InputError& e) {
    std::cerr << "vcsim: error: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "vcsim: error: " << e.what() << "\n";
    return 1;
  }
}
