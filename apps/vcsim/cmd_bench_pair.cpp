// `vcsim bench pair`: a wire in a catheter pushed through a bent vessel (paper Fig. 10), time per
// stage for 2 x N nodes with one global iteration, coupling and contacts on.
#include <algorithm>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "commands.h"
#include "vcsim/experiments.h"

namespace vcsim::app {

namespace {

struct Args {
  PairOptions opt;
  int steps = 1000;
  bool json = false;
};

int run(const Args& a) {
  if (a.steps < 10 || a.steps > 1000000) {
    throw InputError("bench pair", "--steps", "expected 10 .. 1000000");
  }
  PairScene sc = make_pair_scene(a.opt);
  SolverWorkspace ws(sc.model);
  StaticWall wall = sc.wall();
  // Both advance at 20 mm/s, the wire leading, turning slowly.
  std::vector<DriveCommand> cmds(2, DriveCommand{DriveCommand::Mode::kVelocity, 0.02, 0.5});
  std::vector<double> total, forces, integ, coll, dist, cont, cons;
  StepProfile p;
  int max_contacts = 0;
  for (int k = 0; k < a.steps; ++k) {
    if (solver_step(sc.model, sc.state, ws, &wall, cmds, &p).rolled_back)
      throw std::runtime_error("bench pair: diverged (a non-finite step)");
    if (k < a.steps / 10) continue;  // warm-up
    total.push_back(p.total);
    forces.push_back(p.forces);
    integ.push_back(p.integrate_velocities + p.integrate_positions);
    coll.push_back(p.collision);
    dist.push_back(p.distance);
    cont.push_back(p.contacts);
    cons.push_back(p.constraints);
    max_contacts = std::max(max_contacts, p.num_contacts);
  }
  nlohmann::json j = {
      {"nodes", a.opt.nodes},
      {"nodes_total", sc.model.instruments[0].rod().n + sc.model.instruments[1].rod().n},
      {"wire", a.opt.wire},
      {"catheter", a.opt.catheter},
      {"dt_s", a.opt.dt},
      {"steps", a.steps},
      {"step_us_median", median(total)},
      {"stages_us",
       {{"rod_forces", median(forces)},
        {"integration", median(integ)},
        {"collision_detection", median(coll)},
        {"constraints", median(cons)},
        {"distance", median(dist)},
        {"coupling_and_contacts", median(cont)}}},
      {"coupled_nodes", static_cast<int>(ws.coupling_contacts(0).size())},
      {"max_wall_contacts", max_contacts},
      {"hand_force_n",
       {sc.state.instruments[0].drive.axial_force, sc.state.instruments[1].drive.axial_force}},
  };
  if (a.json) {
    std::cout << j.dump(2) << "\n";
  } else {
    std::cout << "| nodes | step (us, median) | forces | integration | collision | constraints |\n"
              << "|---|---|---|---|---|---|\n| 2 x " << a.opt.nodes << " | " << j["step_us_median"]
              << " | " << j["stages_us"]["rod_forces"] << " | " << j["stages_us"]["integration"]
              << " | " << j["stages_us"]["collision_detection"] << " | "
              << j["stages_us"]["constraints"] << " |\n";
  }
  return 0;
}

void install(CLI::App& app, int& status) {
  auto a = std::make_shared<Args>();
  auto* cmd = bench_group(app).add_subcommand("pair", "Wire in catheter through a bent vessel");
  cmd->add_option("--nodes", a->opt.nodes, "Mass points per instrument (16 .. 512)");
  cmd->add_option("--steps", a->steps, "Steps to run");
  cmd->add_option("--wire", a->opt.wire, "Catalogue name of the wire");
  cmd->add_option("--catheter", a->opt.catheter, "Catalogue name of the catheter");
  cmd->add_flag("--json", a->json, "Print JSON");
  cmd->callback([a, &status] { status = run(*a); });
}

const int kRegistered = register_command(40, install);

}  // namespace

}  // namespace vcsim::app
