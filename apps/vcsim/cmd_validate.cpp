// `vcsim validate`: the rod against analytic answers (Markdown table or --json).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>

#include "commands.h"
#include "vcsim/validate.h"

namespace vcsim::app {

namespace {

std::string fmt_num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

int run_validate(const std::vector<std::string>& cases, const ValidationOptions& opt, bool json) {
  // Reject an unknown case before spending time on the others.
  const auto& known = validation_case_names();
  for (const auto& c : cases) {
    if (std::find(known.begin(), known.end(), c) == known.end()) run_validation_case(c, opt);
  }
  std::vector<CaseResult> all;
  for (const auto& name : cases.empty() ? known : cases) {
    auto r = run_validation_case(name, opt);
    all.insert(all.end(), r.begin(), r.end());
  }
  const auto failed = std::count_if(all.begin(), all.end(), [](auto& r) { return !r.pass; });
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
    std::cout << "\n"
              << all.size() - static_cast<std::size_t>(failed) << " passed, " << failed
              << " failed\n";
  }
  return failed == 0 ? 0 : 1;
}

struct Args {
  std::vector<std::string> cases;
  ValidationOptions vo;
  double length_mm = 100, radius_mm = 0.5, youngs_gpa = 1, tip_radius_mm = 3;
  std::string method = "global";
  bool json = false;
};

void install(CLI::App& app, int& status) {
  auto a = std::make_shared<Args>();
  auto* val = app.add_subcommand("validate", "Check the rod model against analytic answers");
  ValidationOptions& vo = a->vo;
  val->add_option("cases", a->cases,
                  "Cases to run (default: all): elastica-tip, distributed, "
                  "buckling, frequency, torsion, shaped-tip, stretch");
  val->add_flag("--json", a->json, "Print a JSON list instead of a Markdown table");
  val->add_option("--length-mm", a->length_mm, "Rod length (mm)");
  val->add_option("--segments", vo.segments, "Number of segments");
  val->add_option("--radius-mm", a->radius_mm, "Outer radius (mm)");
  val->add_option("--youngs-gpa", a->youngs_gpa, "Young modulus (GPa)");
  val->add_option("--density", vo.density, "Density (kg/m^3)");
  val->add_option("--poisson", vo.poisson, "Poisson ratio");
  val->add_option("--dt", vo.dt, "Time step (s); 0 = the stability estimate");
  val->add_option("--iterations", vo.iterations, "Constraint iterations per step");
  val->add_option("--method", a->method,
                  "Distance constraints: global, local-gs, local-jacobi, penalty");
  auto* load = val->add_option("--load", vo.load,
                               "elastica-tip: lambda = P L^2 / EI; distributed: q L^3 / EI");
  auto* ratio = val->add_option("--ratio", vo.ratio, "buckling: P / P_cr");
  auto* angle = val->add_option("--angle-deg", vo.angle_deg, "torsion: end rotation (deg)");
  auto* pull = val->add_option("--pull", vo.pull, "stretch: tip force over the rod's weight");
  val->add_option("--mode", vo.mode, "frequency: mode number (default 1 and 2)");
  val->add_option("--tip-radius-mm", a->tip_radius_mm, "shaped-tip: arc radius (mm)");
  val->add_option("--tip-angle-deg", vo.j_angle_deg, "shaped-tip: arc angle (deg)");
  val->add_option("--tip-ratio", vo.tip_modulus_ratio,
                  "shaped-tip: soft tip modulus ratio alpha = E_tip / E_shaft, in (0, 1]");
  val->callback([a, load, ratio, angle, pull, &status] {
    ValidationOptions& o = a->vo;
    // NaN means "the case's default set" inside; a NaN typed by the user is an error.
    for (auto [opt, value] : {std::pair{load, o.load}, std::pair{ratio, o.ratio},
                              std::pair{angle, o.angle_deg}, std::pair{pull, o.pull}}) {
      if (opt->count() > 0) require_finite(value, "validate", opt->get_name());
    }
    o.length = a->length_mm * 1e-3;
    o.outer_radius = a->radius_mm * 1e-3;
    o.youngs_modulus = a->youngs_gpa * 1e9;
    o.j_radius = a->tip_radius_mm * 1e-3;
    o.method = distance_method_from_string(a->method, "validate --method");
    o.validate("validate");
    status = run_validate(a->cases, o, a->json);
  });
}

const int kRegistered = register_command(10, install);

}  // namespace

}  // namespace vcsim::app
