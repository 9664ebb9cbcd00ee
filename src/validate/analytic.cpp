// Analytic references for the rod validation (docs/validation.md gives the derivations).
#include <cmath>
#include <functional>
#include <numbers>

#include "vcsim/validate.h"

namespace vcsim::analytic {

namespace {
double bisect(const std::function<double(double)>& f, double lo, double hi, int iters = 200) {
  double flo = f(lo);
  for (int i = 0; i < iters; ++i) {
    const double mid = 0.5 * (lo + hi);
    const double fm = f(mid);
    if ((fm < 0) == (flo < 0)) {
      lo = mid;
      flo = fm;
    } else {
      hi = mid;
    }
  }
  return 0.5 * (lo + hi);
}
}  // namespace

TipPoint elastica_tip_load(double lambda) {
  // sqrt(lambda) = F(pi/2, k) - F(phi0, k), k^2 = (1 + sin t0) / 2, sin phi0 = 1 / (sqrt2 k).
  auto parts = [](double t0, double& k, double& phi0) {
    k = std::sqrt(0.5 * (1.0 + std::sin(t0)));
    phi0 = std::asin(std::min(1.0, 1.0 / (std::sqrt(2.0) * k)));
  };
  const double sl = std::sqrt(lambda);
  auto residual = [&](double t0) {
    double k, phi0;
    parts(t0, k, phi0);
    return std::comp_ellint_1(k) - std::ellint_1(k, phi0) - sl;
  };
  const double t0 = bisect(residual, 1e-14, std::numbers::pi / 2 - 1e-12);
  double k, phi0;
  parts(t0, k, phi0);
  TipPoint p;
  p.angle = t0;
  p.x = std::sqrt(2.0 * std::sin(t0) / lambda);
  p.y = 1.0 - (2.0 / sl) * (std::comp_ellint_2(k) - std::ellint_2(k, phi0));
  return p;
}

TipPoint cantilever_shooting(double mu, double lambda) {
  // theta'' = (mu (1 - s) + lambda) cos(theta) on s in [0, 1] (lengths over L, load downward),
  // theta(0) = 0, theta'(1) = 0. Integrate with RK4 for a trial theta'(0) and bisect.
  constexpr int kSteps = 4000;
  const double h = 1.0 / kSteps;
  auto integrate = [&](double c, TipPoint* tip) {
    double th = 0.0, om = c, x = 0.0, y = 0.0;
    auto acc = [&](double s, double t) { return (mu * (1.0 - s) + lambda) * std::cos(t); };
    for (int i = 0; i < kSteps; ++i) {
      const double s = i * h;
      // State (theta, omega, x, y); x' = cos theta, y' = sin theta.
      const double k1t = om, k1o = acc(s, th);
      const double k2t = om + 0.5 * h * k1o, k2o = acc(s + 0.5 * h, th + 0.5 * h * k1t);
      const double k3t = om + 0.5 * h * k2o, k3o = acc(s + 0.5 * h, th + 0.5 * h * k2t);
      const double k4t = om + h * k3o, k4o = acc(s + h, th + h * k3t);
      const double th1 = th + 0.5 * h * k1t, th2 = th + 0.5 * h * k2t, th3 = th + h * k3t;
      x += h / 6 * (std::cos(th) + 2 * std::cos(th1) + 2 * std::cos(th2) + std::cos(th3));
      y += h / 6 * (std::sin(th) + 2 * std::sin(th1) + 2 * std::sin(th2) + std::sin(th3));
      th += h / 6 * (k1t + 2 * k2t + 2 * k3t + k4t);
      om += h / 6 * (k1o + 2 * k2o + 2 * k3o + k4o);
    }
    // Reported as positive magnitudes (the load direction is a convention).
    if (tip) *tip = {x, -y, -th};
    return om;  // theta'(1), to be zero
  };
  const double c =
      bisect([&](double c0) { return integrate(c0, nullptr); }, -(0.5 * mu + lambda) - 1.0, 0.0);
  TipPoint tip;
  integrate(c, &tip);
  return tip;
}

double postbuckling_deflection(double ratio) {
  // L sqrt(P / EI) = K(k) with k = sin(alpha / 2); tip deflection delta = 2 k sqrt(EI / P).
  if (ratio <= 1.0) return 0.0;
  const double target = 0.5 * std::numbers::pi * std::sqrt(ratio);
  const double k =
      bisect([&](double kk) { return std::comp_ellint_1(kk) - target; }, 0.0, 1.0 - 1e-15);
  return 2.0 * k / target;
}

double cantilever_frequency(int mode, double ei, double rho_a, double length) {
  static constexpr double kBetaL[] = {1.87510407, 4.69409113, 7.85475744, 10.99554073};
  const double bl = kBetaL[mode - 1];
  return bl * bl / (2.0 * std::numbers::pi * length * length) * std::sqrt(ei / rho_a);
}

}  // namespace vcsim::analytic
