// vcsim command line. Bad input prints one line naming the field and exits with status 2.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "commands.h"
#include "vcsim/validate.h"

namespace {

using namespace vcsim;

std::string fmt_num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

int cmd_validate(const std::vector<std::string>& cases, const ValidationOptions& opt, bool json) {
  std::vector<CaseResult> all;
  const auto& names = cases.empty() ? validation_case_names() : cases;
  for (const auto& name : names) {
    auto r = run_validation_case(name, opt);
    all.insert(all.end(), r.begin(), r.end());
  }
  int failed = 0;
  for (const auto& r : all) failed += r.pass ? 0 : 1;
  if (json) {
    nlohmann::json arr = nlohmann::json::array();
    for (const auto& r : all) {
      arr.push_back({{"case", r.name},
                     {"quantity", r.quantity},
                     {"analytic", r.analytic},
                     {"simulated", r.simulated},
                     {"rel_error", r.rel_error},
                     {"tolerance", r.tolerance},
                     {"pass", r.pass}});
    }
    std::cout << arr.dump(2) << "\n";
  } else {
    std::cout << "| case | quantity | analytic | simulated | error | tolerance | pass |\n"
              << "|---|---|---|---|---|---|---|\n";
    for (const auto& r : all) {
      std::cout << "| " << r.name << " | " << r.quantity << " | " << fmt_num(r.analytic) << " | "
                << fmt_num(r.simulated) << " | " << fmt_num(r.rel_error) << " | "
                << fmt_num(r.tolerance) << " | " << (r.pass ? "yes" : "**NO**") << " |\n";
    }
    std::cout << "\n" << all.size() - failed << " passed, " << failed << " failed\n";
  }
  return failed == 0 ? 0 : 1;
}

int run(int argc, char** argv) {
  CLI::App app{"vcsim: a simulator for training cardiovascular interventions"};
  app.require_subcommand(1);

  // validate
  auto* val = app.add_subcommand("validate", "Check the rod model against analytic answers");
  std::vector<std::string> cases;
  ValidationOptions vo;
  double length_mm = vo.length * 1e3, radius_mm = vo.outer_radius * 1e3;
  double youngs_gpa = vo.youngs_modulus * 1e-9, tip_radius_mm = vo.j_radius * 1e3;
  std::string method = "global";
  bool json = false;
  val->add_option("cases", cases,
                  "Cases to run (default: all): elastica-tip, distributed, "
                  "buckling, frequency, torsion, shaped-tip, stretch");
  val->add_flag("--json", json, "Print a JSON list instead of a Markdown table");
  val->add_option("--length-mm", length_mm, "Rod length (mm)");
  val->add_option("--segments", vo.segments, "Number of segments");
  val->add_option("--radius-mm", radius_mm, "Outer radius (mm)");
  val->add_option("--youngs-gpa", youngs_gpa, "Young modulus (GPa)");
  val->add_option("--density", vo.density, "Density (kg/m^3)");
  val->add_option("--poisson", vo.poisson, "Poisson ratio");
  val->add_option("--dt", vo.dt, "Time step (s); 0 = the stability estimate");
  val->add_option("--iterations", vo.iterations, "Constraint iterations per step");
  val->add_option("--method", method,
                  "Distance constraints: global, local-gs, local-jacobi, penalty");
  auto* load_opt = val->add_option("--load", vo.load,
                                   "elastica-tip: lambda = P L^2 / EI; distributed: q L^3 / EI");
  auto* ratio_opt = val->add_option("--ratio", vo.ratio, "buckling: P / P_cr");
  auto* angle_opt = val->add_option("--angle-deg", vo.angle_deg, "torsion: end rotation (deg)");
  auto* pull_opt = val->add_option("--pull", vo.pull, "stretch: tip force over the rod's weight");
  val->add_option("--mode", vo.mode, "frequency: mode number (default 1 and 2)");
  val->add_option("--tip-radius-mm", tip_radius_mm, "shaped-tip: arc radius (mm)");
  val->add_option("--tip-angle-deg", vo.j_angle_deg, "shaped-tip: arc angle (deg)");
  val->add_option("--tip-ratio", vo.tip_modulus_ratio,
                  "shaped-tip: soft tip modulus ratio alpha = E_tip / E_shaft, in (0, 1]");

  // bench
  auto* bench = app.add_subcommand("bench", "Benchmarks");
  bench->require_subcommand(1);
  auto* brod = bench->add_subcommand("rod", "Time one rod step (no contacts)");
  app::RodBenchOptions bo;
  std::string bench_method = "global";
  brod->add_option("--nodes", bo.nodes, "Number of mass points");
  brod->add_option("--steps", bo.steps, "Timed steps");
  brod->add_option("--iterations", bo.iterations, "Constraint iterations per step");
  brod->add_option("--method", bench_method, "global, local-gs, local-jacobi, penalty");
  brod->add_flag("--json", bo.json, "Print JSON");

  auto* info = app.add_subcommand("info", "Version and build");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);
    const std::string first = argc > 1 ? argv[1] : "";
    if (!first.empty() && first[0] != '-' && first != "validate" && first != "bench" &&
        first != "info") {
      std::cerr << "vcsim: error: command: expected validate, bench or info, got '" << argv[1]
                << "'\n";
    } else {
      std::cerr << "vcsim: error: " << e.what() << "\n";
    }
    return 2;
  }

  if (*val) {
    // NaN means "the case's default set" inside; a NaN typed by the user is an error.
    for (auto [opt, value] : {std::pair{load_opt, vo.load}, std::pair{ratio_opt, vo.ratio},
                              std::pair{angle_opt, vo.angle_deg}, std::pair{pull_opt, vo.pull}}) {
      if (opt->count() > 0) require_finite(value, "validate", opt->get_name());
    }
    vo.length = length_mm * 1e-3;
    vo.outer_radius = radius_mm * 1e-3;
    vo.youngs_modulus = youngs_gpa * 1e9;
    vo.j_radius = tip_radius_mm * 1e-3;
    vo.method = distance_method_from_string(method, "validate --method");
    vo.validate("validate");
    // Reject an unknown case before spending time on the others.
    const auto& known = validation_case_names();
    for (const auto& c : cases) {
      if (std::find(known.begin(), known.end(), c) == known.end()) {
        run_validation_case(c, vo);  // throws the InputError listing the known cases
      }
    }
    return cmd_validate(cases, vo, json);
  }
  if (*brod) {
    bo.method = distance_method_from_string(bench_method, "bench rod --method");
    return app::bench_rod(bo);
  }
  if (*info) {
    std::cout << "vcsim 0.1.0 (C++20, Eigen " << EIGEN_WORLD_VERSION << "." << EIGEN_MAJOR_VERSION
              << "." << EIGEN_MINOR_VERSION << ")\n";
    return 0;
  }
  return 0;
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
