// Invariants of the rod step: momentum of a free rod, unit quaternions, exact inextensibility
// of the global solve, convergence of the local sweeps, determinism and replay.
#include <gtest/gtest.h>

#include <numbers>
#include <random>

#include "vcsim/rod.h"

using namespace vcsim;

namespace {

struct Sim {
  RodModel md;
  RodState st;
  RodSettings s;
  RodWorkspace ws;
  explicit Sim(const RodDef& def) : md(build_rod(def)), st(make_state(md, def)) { ws.resize(md); }
  void steps(int k) {
    for (int i = 0; i < k; ++i) rod_step(md, s, st, ws);
  }
};

RodDef wire() {
  RodDef d;
  d.length = 0.1;
  d.segments = 40;
  d.outer_radius = 0.4e-3;
  d.youngs_modulus = 5e9;
  d.density = 6450;
  d.base_orientation = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3::UnitX());
  d.tip_shape = {TipSection::arc(5e-3, 1.5)};
  return d;
}

Vec3 momentum(const Sim& s) {
  Vec3 p = Vec3::Zero();
  for (int i = 0; i < s.md.n; ++i) p += s.md.node_mass[i] * s.st.v[i];
  return p;
}

}  // namespace

TEST(RodInvariants, FreeRodConservesLinearMomentum) {
  RodDef d = wire();
  d.base = BoundaryKind::kFree;
  Sim sim(d);
  sim.s.dt = 0.5 * estimate_stable_dt(sim.md, sim.s);
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 0.05);
  for (auto& v : sim.st.v) v = Vec3(n(rng), n(rng), n(rng));
  for (auto& w : sim.st.omega) w = Vec3(n(rng), n(rng), n(rng)) * 10.0;
  const Vec3 p0 = momentum(sim);
  sim.steps(20000);  // the shaped tip springs back while the rod tumbles
  EXPECT_LT((momentum(sim) - p0).norm(), 1e-12 + 1e-9 * p0.norm());
  EXPECT_LT(max_stretch(sim.md, sim.st), 1e-6);
}

TEST(RodInvariants, QuaternionsStayUnitAndTheRodInextensible) {
  Sim sim(wire());
  sim.s.gravity = Vec3(0, 0, -9.81);
  sim.s.dt = estimate_stable_dt(sim.md, sim.s);
  for (int k = 0; k < 50; ++k) {
    sim.steps(400);
    for (const auto& q : sim.st.q) ASSERT_NEAR(q.norm(), 1.0, 1e-12);
    ASSERT_LT(max_stretch(sim.md, sim.st), 1e-6) << "at t = " << sim.st.time;
  }
}

TEST(RodInvariants, LocalSweepsImproveWithIterationsAndGlobalIsExactInOne) {
  // A rod swinging down under gravity: the worst edge strain over the run per method.
  auto worst = [](DistanceMethod m, int iterations) {
    RodDef d = wire();
    d.tip_shape.clear();
    d.base = BoundaryKind::kPinned;
    Sim sim(d);
    sim.s.gravity = Vec3(0, 0, -9.81);
    sim.s.distance = m;
    sim.s.iterations = iterations;
    sim.s.dt = estimate_stable_dt(sim.md, sim.s);
    double w = 0.0;
    for (int k = 0; k < 80; ++k) {
      sim.steps(50);
      w = std::max(w, max_stretch(sim.md, sim.st));
    }
    return w;
  };
  const double g1 = worst(DistanceMethod::kGlobal, 1);
  EXPECT_LT(g1, 1e-6);
  for (auto m : {DistanceMethod::kLocalGS, DistanceMethod::kLocalJacobi}) {
    const double w1 = worst(m, 1), w5 = worst(m, 5), w25 = worst(m, 25);
    EXPECT_GT(w1, w5) << to_string(m);
    EXPECT_GT(w5, w25) << to_string(m);
    EXPECT_GT(w1, 10 * g1) << to_string(m);
  }
}

TEST(RodInvariants, SameInputsGiveTheSameStateHash) {
  auto run = [] {
    Sim sim(wire());
    sim.s.gravity = Vec3(0, -9.81, 0);
    sim.s.dt = estimate_stable_dt(sim.md, sim.s);
    sim.steps(3000);
    return sim.st.hash();
  };
  const auto h1 = run();
  EXPECT_EQ(h1, run());
  Sim other(wire());
  EXPECT_NE(h1, other.st.hash());
}

TEST(RodInvariants, RestoringASnapshotReplaysBitForBit) {
  Sim sim(wire());
  sim.s.gravity = Vec3(0, -9.81, 0);
  sim.s.dt = estimate_stable_dt(sim.md, sim.s);
  sim.steps(1000);
  const RodState snapshot = sim.st;
  sim.steps(2000);
  const auto h = sim.st.hash();
  sim.st = snapshot;
  sim.steps(2000);
  EXPECT_EQ(sim.st.hash(), h);
}

TEST(RodInvariants, ClampedRodAtRestInItsRestShapeStaysThere) {
  RodDef d = wire();
  d.start_in_rest_shape = true;
  Sim sim(d);
  sim.s.dt = estimate_stable_dt(sim.md, sim.s);
  sim.steps(5000);
  for (int i = 0; i < sim.md.n; ++i) {
    EXPECT_LT((sim.st.x[i] - sim.md.rest_position[i]).norm(), 1e-9) << "node " << i;
  }
}

TEST(RodInvariants, BadSettingsNameTheField) {
  RodSettings s;
  s.dt = 0.0;
  EXPECT_THROW(s.validate(), InputError);
  s.dt = 1e-3;
  s.iterations = 0;
  try {
    s.validate("scene.json");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "iterations");
    EXPECT_NE(std::string(e.what()).find("scene.json"), std::string::npos);
  }
  EXPECT_THROW(distance_method_from_string("newton", "x"), InputError);
  EXPECT_EQ(distance_method_from_string("local-jacobi", "x"), DistanceMethod::kLocalJacobi);
}

// The elastic energy diagnostic: a straight rod laid on a circular arc, frame j turned by j theta
// about d1 and each edge along its d3, stores the bending energy of its discrete curvature,
// sum over the interior vertices of l / 2 EI (2 sin(theta / 2) / l)^2 (physics.md eq. 5, the
// quaternion Darboux vector), and nothing in the parallel penalty; twisted instead, the twist
// energy with G J.
TEST(RodInvariants, ElasticEnergyOfABentAndOfATwistedRod) {
  RodDef def = wire();
  def.tip_shape.clear();
  def.base_orientation = Quat::Identity();
  const RodModel md = build_rod(def);
  RodState st = make_state(md, def);
  EXPECT_NEAR(elastic_energy(md, st), 0.0, 1e-15) << "straight at rest";
  const double l = md.rest_length[0];
  const double theta = 0.02;  // rad per edge: 0.2 m^-1 of curvature over the 0.1 m
  Vec3 x = Vec3::Zero();
  for (int j = 0; j < md.m; ++j) {
    st.q[j] = Quat(Eigen::AngleAxisd(j * theta, Vec3::UnitX()));
    st.x[j] = x;
    x += l * (st.q[j] * Vec3::UnitZ());
  }
  st.x[md.m] = x;
  const double ei = md.vertex_stiffness[1].x();
  const double omega = 2.0 * std::sin(0.5 * theta) / l;
  EXPECT_NEAR(elastic_energy(md, st), (md.m - 1) * 0.5 * l * ei * omega * omega,
              1e-9 * (md.m - 1) * 0.5 * l * ei * omega * omega);
  // Twisted about the straight axis: frame j turned by j theta about d3.
  RodState tw = make_state(md, def);
  for (int j = 0; j < md.m; ++j)
    tw.q[j] = tw.q[j] * Quat(Eigen::AngleAxisd(j * theta, Vec3::UnitZ()));
  const double gj = md.vertex_stiffness[1].z();
  EXPECT_NEAR(elastic_energy(md, tw), (md.m - 1) * 0.5 * l * gj * omega * omega,
              1e-9 * (md.m - 1) * 0.5 * l * gj * omega * omega);
}
