// `vcsim soak`: seeded random hands on every instrument in a built-in patient with the heart
// beating, for a long simulated time (docs/scenarios.md, "Soak"). The engine does the work
// (soak(), src/sim/soak.cpp); this is options and the report.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "commands.h"
#include "vcsim/core.h"
#include "vcsim/sim.h"

namespace vcsim::app {

namespace {

struct SoakOptions {
  std::vector<std::string> patients = {"default"};
  double minutes = 60.0;
  std::uint64_t seed = 1;
  std::string json;
  std::string force_log;
  bool quiet = false;
};

// The default scenario's settings and its first three instruments (guide, J wire, 0.014" wire)
// in `patient`, no plan, no landmarks.
Scenario soak_scenario(const std::string& patient) {
  Scenario sc = load_scenario(find_scenario("default", "soak", "scenario"));
  sc.name = "soak-" + patient;
  sc.anatomy = patient;
  sc.beating = true;
  sc.instruments.resize(3);
  sc.autopilot.clear();
  sc.landmarks.clear();
  sc.targets = {};
  sc.time_limit = 1e9;
  return sc;
}

// What a person running a soak for an hour or two sees as it goes: a line each simulated minute
// (wall time, real-time factor, resident size, rollbacks, escape steps so far) and each
// instrument's first escape when it happens (as `vcsim run` reports it), both on the console;
// every step passed on to the force log, if any.
class SoakConsole : public RunObserver {
 public:
  SoakConsole(RunObserver* log, bool progress) : log_(log), progress_(progress), t0_(now_us()) {}
  bool before_step(const Simulator& sim, const StepCommands& commands) override {
    return log_ ? log_->before_step(sim, commands) : true;
  }
  void after_step(const Simulator& sim) override {
    if (log_) log_->after_step(sim);
    for (const std::string& line : escapes_.fresh(sim)) std::cerr << "soak: " << line << std::endl;
    const SimMetrics& m = sim.metrics();
    if (progress_ && sim.time() >= next_minute_) {
      next_minute_ += 60.0;
      const double wall = (now_us() - t0_) * 1e-6;
      std::cout << std::fixed << std::setprecision(0) << "  " << sim.time() / 60.0
                << " min simulated in " << wall << " s (" << std::setprecision(2)
                << (wall > 0 ? sim.time() / wall : 0.0) << " x real time); resident "
                << resident_megabytes() << " MB; rollbacks " << m.rollbacks << "; runaway steps "
                << m.runaway_steps << "; escape steps " << m.escape_steps << std::endl;
    }
  }

 private:
  RunObserver* log_;
  bool progress_;
  double t0_;
  double next_minute_ = 60.0;
  EscapeReporter escapes_;
};

nlohmann::json to_json(const SoakReport& r, const std::string& patient, const SimModel& md) {
  nlohmann::json inst = nlohmann::json::array();
  for (std::size_t k = 0; k < r.instruments.size(); ++k) {
    const auto& i = r.instruments[k];
    nlohmann::json escape = nullptr;
    if (i.escape.steps > 0)
      escape = {{"steps", i.escape.steps},
                {"first_time_s", i.escape.time},
                {"max_distance_mm", i.escape.max_distance * 1e3},
                {"first", describe_escape(md, static_cast<int>(k), i.escape)}};
    inst.push_back({{"name", i.name},
                    {"checked_steps", i.checked_steps},
                    {"steps_over_1n_off_median", i.departures},
                    {"largest_departure_n", i.largest_departure},
                    {"largest_force_n", i.largest_force},
                    {"deepest_mm", i.deepest * 1e3},
                    {"withdrawals", i.withdrawals},
                    {"slipped_steps", i.slipped_steps},
                    {"escape", escape}});
  }
  return {{"patient", patient},
          {"steps", r.steps},
          {"simulated_s", r.simulated},
          {"wall_s", r.wall},
          {"realtime_factor", r.wall > 0 ? r.simulated / r.wall : 0.0},
          {"rollbacks", r.rollbacks},
          {"runaway_steps", r.runaway_steps},
          {"calmed_steps", r.calmed_steps},
          {"finite", r.finite},
          {"resident_start_mb", r.resident_start_mb},
          {"resident_after_first_minute_mb", r.resident_after_first_minute_mb},
          {"resident_end_mb", r.resident_end_mb},
          {"resident_samples_mb", r.resident_samples_mb},
          {"memory_growth", r.memory_growth()},
          {"instruments", inst},
          {"passed", r.passed()}};
}

int cmd_soak(const SoakOptions& o) {
  if (!(o.minutes > 0.0 && o.minutes <= 24 * 60.0))
    throw InputError("soak", "--minutes", "expected a simulated time in (0, 1440] minutes");
  for (const std::string& p : o.patients) (void)patient_variant_from_string(p, "soak: --patient");
  nlohmann::json out = nlohmann::json::array();
  bool all = true;
  for (const std::string& patient : o.patients) {
    Simulator sim(soak_scenario(patient));
    SoakSettings s;
    s.duration = o.minutes * 60.0;
    s.seed = o.seed;
    std::unique_ptr<ForceLog> log;
    if (!o.force_log.empty()) {
      // Several patients: one log each, the patient's name before the file's (in its folder).
      const std::filesystem::path given(o.force_log);
      const std::filesystem::path file =
          o.patients.size() > 1 ? given.parent_path() / (patient + "-" + given.filename().string())
                                : given;
      log = std::make_unique<ForceLog>(file, sim.model());
    }
    if (!o.quiet)
      std::cout << "soak: " << patient << ", " << o.minutes << " min simulated, seed " << o.seed
                << std::endl;
    SoakConsole console(log.get(), !o.quiet);
    const SoakReport r = soak(sim, s, &console);
    all = all && r.passed();
    out.push_back(to_json(r, patient, sim.model()));
    if (!o.quiet) {
      std::cout << std::fixed << std::setprecision(2) << "  " << r.steps << " steps, "
                << r.simulated << " s in " << r.wall << " s; rollbacks " << r.rollbacks
                << "; runaway steps " << r.runaway_steps << " (" << r.calmed_steps << " from rest)"
                << ", finite " << (r.finite ? "yes" : "NO") << "; resident "
                << r.resident_after_first_minute_mb << " MB after 1 min, " << r.resident_end_mb
                << " MB at the end (" << std::setprecision(3) << 100 * r.memory_growth() << " %)\n";
      for (const auto& i : r.instruments)
        std::cout << "  " << i.name << ": " << std::setprecision(0) << i.deepest * 1e3
                  << " mm deepest, " << i.withdrawals << " withdrawals; largest hand force "
                  << std::setprecision(2) << i.largest_force << " N, " << i.departures << " of "
                  << i.checked_steps << " steps more than 1 N off their local median (largest "
                  << i.largest_departure << " N); the grip slipped in " << i.slipped_steps
                  << " steps\n";
      for (std::size_t k = 0; k < r.instruments.size(); ++k)
        if (r.instruments[k].escape.steps > 0)
          std::cout << "  ESCAPE (a failure): " << r.instruments[k].escape.steps << " steps; first "
                    << describe_escape(sim.model(), static_cast<int>(k), r.instruments[k].escape)
                    << "\n";
      std::cout << "  " << (r.passed() ? "passed" : "FAILED") << "\n";
    }
  }
  if (!o.json.empty()) {
    std::ofstream f(o.json);
    if (!f) throw InputError("soak", "--json", "cannot write '" + o.json + "'");
    f << out.dump(1) << "\n";
  }
  return all ? 0 : 3;
}

void install(CLI::App& app, int& status) {
  auto o = std::make_shared<SoakOptions>();
  auto* cmd = app.add_subcommand(
      "soak",
      "Seeded random hands on every instrument in a beating patient: no NaN, no rollback, flat "
      "memory (exit 3 when a check fails)");
  cmd->add_option("--patient", o->patients,
                  "Built-in patients (default, left-dominant; several run one after another)");
  cmd->add_option("--minutes", o->minutes, "Simulated minutes per patient (default 60)");
  cmd->add_option("--seed", o->seed, "Seed of the random hands (default 1)");
  cmd->add_option("--json", o->json, "Write the figures to this JSON file");
  cmd->add_option(
      "--force-log", o->force_log,
      "Every step's hand force per instrument to this CSV (vcsim run --force-log); with "
      "several patients one file each, the patient's name before the file's");
  cmd->add_flag("--quiet", o->quiet, "No output but errors");
  cmd->callback([o, &status] { status = cmd_soak(*o); });
}

const int kRegistered = register_command(8, install);

}  // namespace

}  // namespace vcsim::app
