// Validation of the rod model against analytic answers (docs/validation.md). Used by
// `vcsim validate` and by the test suite.
#pragma once

#include <limits>
#include <string>
#include <vector>

#include "vcsim/rod.h"

namespace vcsim {

// Parameters of a validation run. NaN for a case parameter means "the case's default set".
struct ValidationOptions {
  double length = 0.1;  // (m)
  int segments = 40;
  double outer_radius = 0.5e-3;   // (m)
  double youngs_modulus = 1.0e9;  // (Pa)
  double density = 1000.0;        // (kg/m^3)
  double poisson = 0.3;
  double dt = 0.0;  // (s), 0: from estimate_stable_dt
  int iterations = 1;
  DistanceMethod method = DistanceMethod::kGlobal;
  // Case parameters.
  double load =
      std::numeric_limits<double>::quiet_NaN();  // elastica-tip lambda, distributed qL^3/EI
  double ratio = std::numeric_limits<double>::quiet_NaN();      // buckling P / P_cr
  double angle_deg = std::numeric_limits<double>::quiet_NaN();  // torsion angle
  double pull = std::numeric_limits<double>::quiet_NaN();       // stretch: tip force / rod weight
  int mode = 0;                                                 // frequency mode (0: 1 and 2)
  double j_radius = 3.0e-3;                                     // (m) shaped-tip radius
  double j_angle_deg = 180.0;                                   // shaped-tip arc
  double tip_modulus_ratio = 0.5;  // shaped-tip: soft tip alpha over twice the arc length

  void validate(const std::string& source) const;
};

struct CaseResult {
  std::string name;      // case
  std::string quantity;  // what is compared
  double analytic = 0.0;
  double simulated = 0.0;
  double rel_error = 0.0;
  double tolerance = 0.0;
  bool pass = false;
};

const std::vector<std::string>& validation_case_names();
// Runs one case (with the case's default parameter set where options leave it NaN).
// Throws InputError for an unknown name or bad options.
std::vector<CaseResult> run_validation_case(const std::string& name, const ValidationOptions& opt);

// Analytic references (docs/validation.md).
namespace analytic {
struct TipPoint {
  double x = 0, y = 0, angle = 0;  // tip position over L, tip slope (rad)
};
// Cantilever with a dead tip load, closed form by elliptic integrals (Bisshopp and Drucker).
TipPoint elastica_tip_load(double lambda);
// Planar cantilever clamped along +x under a distributed dead load mu = q L^3 / EI and a tip
// load lambda = P L^2 / EI, both perpendicular to the undeformed rod; solved by shooting.
TipPoint cantilever_shooting(double mu, double lambda);
// Clamped-free column at P / P_cr = ratio > 1: lateral tip deflection over L (Euler elastica).
double postbuckling_deflection(double ratio);
double cantilever_frequency(int mode, double ei, double rho_a, double length);  // Hz
}  // namespace analytic

}  // namespace vcsim
