// `vcsim bench rod`: the cost of one rod step (forces, integration, one global distance
// iteration, no contacts) for a given number of nodes, with the median time of each stage.
#include <algorithm>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.h"
#include "vcsim/rod.h"

namespace vcsim::app {

namespace {

struct RodBenchOptions {
  int nodes = 256;
  int steps = 20000;
  int warmup = 2000;
  int iterations = 1;
  std::string method = "global";
  bool json = false;
};

int bench_rod(const RodBenchOptions& opt) {
  if (opt.nodes < 3 || opt.nodes > 100000) {
    throw InputError("bench rod", "--nodes", "expected an integer in [3, 100000]");
  }
  if (opt.steps < 1) throw InputError("bench rod", "--steps", "expected a positive integer");
  // A 0.035" guidewire-like rod, 255 mm, clamped at the base and swinging under gravity.
  RodDef def;
  def.length = 0.255;
  def.segments = opt.nodes - 1;
  def.outer_radius = 0.445e-3;
  def.youngs_modulus = 40e9;
  def.density = 6450;
  def.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
  const RodModel md = build_rod(def);
  RodState st = make_state(md, def);
  RodSettings s;
  s.gravity = Vec3(0, 0, -9.81);
  s.distance = distance_method_from_string(opt.method, "bench rod --method");
  s.iterations = opt.iterations;
  s.dt = estimate_stable_dt(md, s);
  s.validate("bench rod");
  RodWorkspace ws;
  ws.resize(md);
  RodProfile prof;
  for (int k = 0; k < opt.warmup; ++k) rod_step(md, s, st, ws, &prof);
  std::vector<double> total(opt.steps), forces(opt.steps), integ_v(opt.steps), cons(opt.steps),
      integ_x(opt.steps);
  for (int k = 0; k < opt.steps; ++k) {
    rod_step(md, s, st, ws, &prof);
    total[k] = prof.total;
    forces[k] = prof.forces;
    integ_v[k] = prof.integrate_velocities;
    cons[k] = prof.constraints;
    integ_x[k] = prof.integrate_positions;
  }
  nlohmann::json j = {
      {"nodes", opt.nodes},
      {"method", opt.method},
      {"iterations", opt.iterations},
      {"steps", opt.steps},
      {"dt_s", s.dt},
      {"step_us_median", median(total)},
      {"stages_us",
       {{"forces", median(forces)},
        {"integrate_velocities", median(integ_v)},
        {"constraints", median(cons)},
        {"integrate_positions", median(integ_x)}}},
      {"max_strain", max_stretch(md, st)},
  };
  if (opt.json) {
    std::cout << j.dump(2) << "\n";
  } else {
    std::cout
        << "| nodes | step (us, median) | forces | integrate v | constraints | integrate x |\n"
        << "|---|---|---|---|---|---|\n"
        << "| " << opt.nodes << " | " << j["step_us_median"] << " | " << j["stages_us"]["forces"]
        << " | " << j["stages_us"]["integrate_velocities"] << " | " << j["stages_us"]["constraints"]
        << " | " << j["stages_us"]["integrate_positions"] << " |\n";
  }
  return 0;
}

void install(CLI::App& app, int& status) {
  auto opt = std::make_shared<RodBenchOptions>();
  auto* cmd = bench_group(app).add_subcommand("rod", "Time one rod step (no contacts)");
  cmd->add_option("--nodes", opt->nodes, "Number of mass points");
  cmd->add_option("--steps", opt->steps, "Timed steps");
  cmd->add_option("--iterations", opt->iterations, "Constraint iterations per step");
  cmd->add_option("--method", opt->method, "global, local-gs, local-jacobi, penalty");
  cmd->add_flag("--json", opt->json, "Print JSON");
  cmd->callback([opt, &status] { status = bench_rod(*opt); });
}

const int kRegistered = register_command(20, install);

}  // namespace

}  // namespace vcsim::app
