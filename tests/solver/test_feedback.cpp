// Force feedback at the hand against the capstan equation (physics.md 6.1): a string pulled
// round a bend against a load at its tip feels the load times exp(mu theta) on the pull and
// exp(-mu theta) on the push, whichever way the hand force is formed: on the vessel wall, and
// running in a catheter's lumen.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <numbers>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include "solver_rig.h"
#include "test_rods.h"
#include "vcsim/solver.h"

using namespace vcsim;

namespace {

using HandForce = SolverSettings::HandForce;
using Params = std::tuple<double, HandForce>;  // friction coefficient, hand-force definition

// Mean over the second half of `steps` calls of `step`, which steps the scene and returns the
// hand force of interest.
template <class Step>
double mean_of_second_half(int steps, Step&& step) {
  double sum = 0.0;
  for (int k = 0; k < steps; ++k) {
    const double f = step();
    if (2 * k >= steps) sum += f;
  }
  return sum / (steps - steps / 2);
}

// Euler-Eytelwein: pulling against the tip load F round the quarter turn the hand feels
// -F exp(mu pi/2), pushing on -F exp(-mu pi/2); within 2 %.
void expect_capstan(double mu, double tip_load, double pull, double push) {
  const double pull_capstan = -tip_load * std::exp(mu * std::numbers::pi / 2);
  const double push_capstan = -tip_load * std::exp(-mu * std::numbers::pi / 2);
  EXPECT_NEAR(pull, pull_capstan, 0.02 * std::abs(pull_capstan));
  EXPECT_NEAR(push, push_capstan, 0.02 * std::abs(push_capstan));
}

std::string param_name(const ::testing::TestParamInfo<Params>& p) {
  const int mu = static_cast<int>(std::lround(std::get<0>(p.param) * 10));
  return std::string(std::get<1>(p.param) == HandForce::kImpulses ? "Impulses" : "QuasiStatic") +
         "Mu0" + std::to_string(mu);
}

const auto kMuAndDefinition =
    ::testing::Combine(::testing::Values(0.0, 0.1, 0.3),
                       ::testing::Values(HandForce::kImpulses, HandForce::kQuasiStatic));

// A 150 mm string (E 10 MPa, 0.6 mm across: its bending length sqrt(EI / T) is 2.5 mm under the
// 0.1 N load, against the bend's 15 mm radius) through a tube of 1.5 mm radius: 30 mm straight,
// a quarter turn of 15 mm radius, 60 mm straight. The tip lies 30 mm into the second straight
// and is pulled along it by kTipLoad. Mass scaling and damping as in scenario runs.
struct CapstanScene {
  static constexpr double kDt = 1e-3;
  static constexpr double kTipLoad = 0.1;  // N
  static constexpr double kAngle = std::numbers::pi / 2;
  TriangleMesh mesh;
  AabbTree tree;
  std::optional<test::Rig> inst;
  SolverSettings s;
  CapstanScene(double mu, HandForce hand_force) {
    BentTubeSpec spec;
    spec.straight1 = 30e-3;
    spec.bend_radius = 15e-3;
    spec.bend_angle = kAngle;
    spec.straight2 = 60e-3;
    spec.radius = 1.5e-3;
    spec.ring_spacing = 1e-3;
    mesh = make_bent_tube(spec);
    check_and_repair(mesh, "capstan tube");
    tree.build(mesh);
    const RodDef d = test::free_rod(0.15, 150, 0.3e-3, 1e7);
    Sheath sheath;
    sheath.access_point = Vec3(0, 0, -5e-3);  // 5 mm before the tube's open end, on its axis
    sheath.max_speed = 0.05;
    inst.emplace(test::driven(d, sheath, ContactMaterial{mu, mu}, 0.0));
    scale_for_time_step(inst->model.instruments[0].rods[0], kDt, kQuasiStaticKpRatio);
    s.rod.dt = kDt;
    set_quasi_static_damping(s.rod);
    s.hand_force = hand_force;
  }
  // Mean hand force over the second half of `steps` steps of the command.
  double mean_force(StaticWall& wall, const DriveCommand& c, int steps) {
    return mean_of_second_half(steps, [&] {
      inst->step(&wall, s, c);
      return inst->drive().axial_force;
    });
  }
};

class Capstan : public ::testing::TestWithParam<Params> {};

}  // namespace

TEST_P(Capstan, HandForceFollowsTheCapstanEquation) {
  const auto [mu, hand_force] = GetParam();
  CapstanScene sc(mu, hand_force);
  StaticWall wall(sc.mesh, sc.tree);
  test::Rig& in = *sc.inst;
  // Unloaded, insert the tip 30 mm past the bend; then load it and let it settle.
  const double depth = 5e-3 + 30e-3 + 15e-3 * CapstanScene::kAngle + 30e-3;
  using Mode = DriveCommand::Mode;
  const double insert = sc.mean_force(wall, {Mode::kPosition, depth, 0.0}, 1800);  // at 50 mm/s
  EXPECT_NEAR(in.drive().depth, depth, 1e-6);
  EXPECT_LT(std::abs(insert), 0.02) << "an unloaded string slides in almost freely";
  in.rod().f_ext.back() = Vec3(CapstanScene::kTipLoad, 0.0, 0.0);
  sc.mean_force(wall, {Mode::kVelocity, 0.0, 0.0}, 1000);
  // The hand pulls the string back at 5 mm/s, then pushes it on: axial force < 0 means the
  // string pulls the hand inward.
  const double pull = sc.mean_force(wall, {Mode::kVelocity, -5e-3, 0.0}, 1500);
  const double push = sc.mean_force(wall, {Mode::kVelocity, 5e-3, 0.0}, 1500);
  expect_capstan(mu, CapstanScene::kTipLoad, pull, push);
  EXPECT_GT(in.rod().x.back().x(), 15e-3) << "the tip stayed past the bend";
}

INSTANTIATE_TEST_SUITE_P(MuAndDefinition, Capstan, kMuAndDefinition, param_name);

namespace {

// The same bend with a catheter held still in it (ID 1.2 mm, OD 2 mm) and a string (E 10 MPa,
// 0.6 mm across) running in its lumen, tip 25 mm past the bend and pulled along the second
// straight by kTipLoad: the lumen friction is the capstan's.
struct LumenCapstanScene {
  static constexpr double kDt = 1e-3;
  CapstanScene tube{0.1, HandForce::kQuasiStatic};
  std::optional<test::Rig> insts;  // [0] string, [1] catheter
  SolverSettings s;
  LumenCapstanScene(double mu, HandForce hand_force) {
    Sheath sheath;
    sheath.access_point = Vec3(0, 0, -5e-3);
    sheath.max_speed = 0.05;
    const RodDef wire = test::free_rod(0.2, 200, 0.3e-3, 1e7);
    RodDef cath = test::free_rod(0.2, 100, 1.0e-3, 1e8);
    cath.inner_radius = 0.6e-3;
    std::vector<InstrumentModel> models;
    models.push_back(make_instrument_model(wire, sheath, ContactMaterial{0.1, 0.1}));
    models.push_back(make_instrument_model(cath, sheath, ContactMaterial{0.1, 0.1}));
    for (InstrumentModel& im : models) scale_for_time_step(im.rods[0], kDt, kQuasiStaticKpRatio);
    std::vector<InstrumentState> states;
    for (const InstrumentModel& im : models) states.push_back(make_instrument_state(im, 0.0));
    CouplingModel c;
    c.inner = 0;
    c.outer = 1;
    c.mu = mu;
    s = tube.s;
    s.hand_force = hand_force;
    insts.emplace(std::move(models), std::move(states), s, std::vector<CouplingModel>{c});
  }
  double mean_wire_force(StaticWall& wall, const std::array<DriveCommand, 2>& c, int steps) {
    return mean_of_second_half(steps, [&] {
      insts->step(&wall, c);
      return insts->drive(0).axial_force;
    });
  }
};

class LumenCapstan : public ::testing::TestWithParam<Params> {};

}  // namespace

TEST_P(LumenCapstan, WireInACatheterFollowsTheCapstanEquation) {
  const auto [mu, hand_force] = GetParam();
  LumenCapstanScene sc(mu, hand_force);
  StaticWall wall(sc.tube.mesh, sc.tube.tree);
  using Mode = DriveCommand::Mode;
  const double bend_end = 5e-3 + 30e-3 + 15e-3 * CapstanScene::kAngle;
  const DriveCommand hold{Mode::kVelocity, 0.0, 0.0};
  // The catheter 45 mm past the bend, then the string 25 mm past it.
  const DriveCommand place_catheter{Mode::kPosition, bend_end + 45e-3, 0.0};
  const DriveCommand place_wire{Mode::kPosition, bend_end + 25e-3, 0.0};
  sc.mean_wire_force(wall, {hold, place_catheter}, 2000);
  sc.mean_wire_force(wall, {place_wire, hold}, 1800);
  sc.insts->rod(0).f_ext.back() = Vec3(CapstanScene::kTipLoad, 0.0, 0.0);
  sc.mean_wire_force(wall, {hold, hold}, 1000);
  const double pull =
      sc.mean_wire_force(wall, {DriveCommand{Mode::kVelocity, -5e-3, 0.0}, hold}, 1500);
  const double push =
      sc.mean_wire_force(wall, {DriveCommand{Mode::kVelocity, 5e-3, 0.0}, hold}, 1500);
  expect_capstan(mu, CapstanScene::kTipLoad, pull, push);
}

INSTANTIATE_TEST_SUITE_P(MuAndDefinition, LumenCapstan, kMuAndDefinition, param_name);
