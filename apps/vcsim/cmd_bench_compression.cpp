// `vcsim bench compression`: the paper's Table 1 (rod compression per distance-constraint
// method and iteration count) with the time per stage.
#include <cstdio>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "commands.h"
#include "vcsim/experiments.h"

namespace vcsim::app {

namespace {

struct Args {
  CompressionOptions opt;
  double speed_mm_s = 50, end_depth_mm = 250;
  std::string rows = "all";
  bool json = false;
};

int run(const Args& a) {
  CompressionOptions o = a.opt;
  o.push_speed = a.speed_mm_s * 1e-3;
  o.end_depth = a.end_depth_mm * 1e-3;
  o.validate("bench compression");
  std::vector<std::pair<DistanceMethod, int>> rows;
  if (a.rows == "all") {
    rows = compression_table_rows();
  } else {
    // "method:iterations[,method:iterations...]"
    std::size_t pos = 0;
    while (pos < a.rows.size()) {
      const std::size_t end = std::min(a.rows.find(',', pos), a.rows.size());
      const std::string item = a.rows.substr(pos, end - pos);
      const std::size_t colon = item.find(':');
      const std::string method = item.substr(0, colon);
      int iters = 1;
      if (colon != std::string::npos) {
        try {
          iters = std::stoi(item.substr(colon + 1));
        } catch (const std::exception&) {
          throw InputError("bench compression", "--rows",
                           "expected method:iterations, got '" + item + "'");
        }
        if (iters < 1 || iters > 1000) {
          throw InputError("bench compression", "--rows", "expected 1 .. 1000 iterations");
        }
      }
      rows.emplace_back(distance_method_from_string(method, "bench compression --rows"), iters);
      pos = end + 1;
    }
  }
  nlohmann::json out = {{"rows", nlohmann::json::array()}};
  if (!a.json) {
    std::cout << "| method | iterations | compression (%) | max during run (%) | constraints (us) "
                 "| step (us) | forces | integration | collision | axial force (N) |\n"
              << "|---|---|---|---|---|---|---|---|---|---|\n";
  }
  for (auto [method, iters] : rows) {
    const CompressionRow r = run_compression(o, method, iters);
    out["rows"].push_back({{"method", r.method},
                           {"iterations", r.iterations},
                           {"compression_percent", r.compression_percent},
                           {"max_compression_percent", r.max_compression_percent},
                           {"constraints_us", r.constraints_us},
                           {"step_us", r.step_us},
                           {"stages_us",
                            {{"integration", r.integration_us},
                             {"constraints", r.constraints_us},
                             {"distance", r.distance_us},
                             {"contacts", r.contacts_us},
                             {"rod_forces", r.forces_us},
                             {"collision_detection", r.collision_us}}},
                           {"axial_force_n", r.axial_force},
                           {"contacts", r.contacts},
                           {"max_outside_over_radius", r.max_outside},
                           {"dt_s", r.dt},
                           {"mass_scale", r.mass_scale},
                           {"penalty_modulus_scale", r.penalty_modulus_scale}});
    if (!a.json) {
      char line[512];
      std::snprintf(line, sizeof line,
                    "| %s | %d | %.3f | %.3f | %.2f | %.2f | %.2f | %.2f | %.2f | %.3f |\n",
                    r.method.c_str(), r.iterations, r.compression_percent,
                    r.max_compression_percent, r.constraints_us, r.step_us, r.forces_us,
                    r.integration_us, r.collision_us, r.axial_force);
      std::cout << line << std::flush;
    }
  }
  if (a.json) std::cout << out.dump(2) << "\n";
  return 0;
}

void install(CLI::App& app, int& status) {
  auto a = std::make_shared<Args>();
  auto* cmd = bench_group(app).add_subcommand(
      "compression", "The paper's compression experiment (Table 1, Fig. 9)");
  cmd->add_flag("--json", a->json, "Print JSON");
  cmd->add_option("--rows", a->rows, "all, or method:iterations[,...] e.g. global:1,local-gs:10");
  cmd->add_option("--dt", a->opt.dt, "Time step (s); 0 = stable step at the physical density");
  cmd->add_option("--nodes", a->opt.nodes, "Mass points");
  cmd->add_option("--speed-mm-s", a->speed_mm_s, "Push speed (mm/s)");
  cmd->add_option("--end-depth-mm", a->end_depth_mm, "Inserted length at the end of the push");
  cmd->add_option("--mu", a->opt.mu, "Instrument-wall friction coefficient");
  cmd->callback([a, &status] { status = run(*a); });
}

const int kRegistered = register_command(30, install);

}  // namespace

}  // namespace vcsim::app
