// The linearly implicit integrator (physics.md 5.5): a rod with its physical mass at a step 500
// times the explicit limit stays stable and settles where the statics say, and at a step that
// resolves its first mode it swings at the Euler-Bernoulli frequency.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include "test_rods.h"
#include "vcsim/rod.h"

using namespace vcsim;

namespace {

// A 100 mm nitinol-like wire (0.8 mm across, E 5 GPa, 6450 kg/m^3) clamped along +x, gravity
// along -y, at its physical mass.
struct Cantilever {
  RodDef def;
  RodModel md;
  RodState st;
  RodWorkspace ws;
  RodSettings s;
  explicit Cantilever(double dt) {
    def = test::free_rod(0.1, 20, 0.4e-3, 5e9, 6450);
    def.base = BoundaryKind::kClamped;
    def.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
    md = build_rod(def);
    st = make_state(md, def);
    ws.resize(md);
    s.dt = dt;
    s.gravity = Vec3(0, -9.81, 0);
    s.integrator = Integrator::kLinearlyImplicit;
  }
  double area() const { return std::numbers::pi * def.outer_radius * def.outer_radius; }
  double ei() const {
    return def.youngs_modulus * std::numbers::pi * std::pow(def.outer_radius, 4) / 4;
  }
  // Static tip deflection under the own weight, q L^4 / (8 E I).
  double static_deflection() const {
    return def.density * area() * 9.81 * std::pow(def.length, 4) / (8 * ei());
  }
};

}  // namespace

TEST(Implicit, CantileverUnderItsWeightAtFiveHundredTimesTheExplicitStep) {
  Cantilever c(1e-3);
  ASSERT_LT(estimate_stable_dt(c.md, RodSettings{}) * 500, c.s.dt)
      << "the step must be far beyond what the explicit integrator could take";
  for (int k = 0; k < 5000; ++k) {
    rod_step(c.md, c.s, c.st, c.ws);
    ASSERT_TRUE(c.st.x.back().allFinite()) << "step " << k;
  }
  // Settled (the implicit step damps the swing) at the small-deflection answer, within the
  // discretisation's and the geometric nonlinearity's share (4 % of the length).
  EXPECT_NEAR(-c.st.x.back().y(), c.static_deflection(), 0.01 * c.static_deflection());
  // Released straight, it first swings at about omega_1 w = 0.25 m/s.
  EXPECT_LT(max_speed(c.st), 1e-4);
  EXPECT_LT(max_stretch(c.md, c.st), 1e-9) << "the distance constraints still hold";
}

TEST(Implicit, FirstModeSwingsAtTheBeamFrequency) {
  // Released straight, the tip swings about the static deflection at the first bending
  // frequency, (1.8751^2 / 2 pi) sqrt(E I / (rho A L^4)) = 9.9 Hz; 0.05 ms resolves it.
  Cantilever c(5e-5);
  const double f1 = std::pow(1.8751, 2) / (2 * std::numbers::pi) *
                    std::sqrt(c.ei() / (c.def.density * c.area() * std::pow(c.def.length, 4)));
  const double mid = -c.static_deflection();
  std::vector<double> ups;  // times the tip crosses the static deflection going up
  double prev = c.st.x.back().y();
  for (int k = 0; k < 6000 && ups.size() < 3; ++k) {
    rod_step(c.md, c.s, c.st, c.ws);
    const double y = c.st.x.back().y();
    if (prev < mid && y >= mid) ups.push_back(c.st.time - c.s.dt * (y - mid) / (y - prev));
    prev = y;
  }
  ASSERT_EQ(ups.size(), 3u) << "the tip did not swing";
  const double f = 2.0 / (ups[2] - ups[0]);
  RecordProperty("f1_hz_measured", std::to_string(f));
  RecordProperty("f1_hz_beam", std::to_string(f1));
  EXPECT_NEAR(f, f1, 0.01 * f1);
}

// What the implicit step leaves explicit cannot run at the physical mass: refused by name.
TEST(Implicit, SettingsItCannotRunAreRefused) {
  RodSettings s;
  s.integrator = Integrator::kLinearlyImplicit;
  EXPECT_NO_THROW(s.validate("rod"));
  auto field_of = [](const RodSettings& bad) {
    try {
      bad.validate("rod");
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("accepted");
  };
  RodSettings penalty = s;
  penalty.distance = DistanceMethod::kPenalty;
  EXPECT_NE(field_of(penalty).find("distance"), std::string::npos) << field_of(penalty);
  RodSettings damped = s;
  damped.internal_damping = 1e-4;
  EXPECT_NE(field_of(damped).find("internal_damping"), std::string::npos) << field_of(damped);
}
