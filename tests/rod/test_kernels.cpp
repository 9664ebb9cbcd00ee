// Each kernel's forces and torques are the negative gradient of its energy (checked by central
// differences), and the energy does not see the sign of a quaternion.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <random>

#include "kernels.h"
#include "test_rods.h"
#include "vcsim/rod.h"

using namespace vcsim;
using namespace vcsim::internal;

namespace {

Quat random_quat(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  Quat q(n(rng), n(rng), n(rng), n(rng));
  q.normalize();
  return q;
}
Vec3 random_vec(std::mt19937& rng, double scale) {
  std::uniform_real_distribution<double> u(-scale, scale);
  return Vec3(u(rng), u(rng), u(rng));
}
// Rotate q by the world rotation vector phi: q <- exp(phi) q.
Quat rotated(const Quat& q, const Vec3& phi) {
  const double a = phi.norm();
  if (a == 0.0) return q;
  return (Quat(Eigen::AngleAxisd(a, phi / a)) * q).normalized();
}

double bend_energy(const Quat& qa, const Quat& qb, double l, const Vec3& K, const Vec3& w0) {
  Vec3 ta = Vec3::Zero(), tb = Vec3::Zero();
  return bend_twist(qa, qa.toRotationMatrix(), qb, l, K, w0, ta, tb);
}

}  // namespace

TEST(RodKernels, BendTwistTorqueIsMinusEnergyGradient) {
  std::mt19937 rng(7);
  const double h = 1e-6;
  for (int trial = 0; trial < 20; ++trial) {
    // Neighbouring frames differ by a moderate rotation, as in a rod.
    const Quat qa = random_quat(rng);
    const Quat qb = rotated(qa, random_vec(rng, 0.4));
    const double l = 0.002;
    const Vec3 K(3e-4, 2e-4, 1.5e-4), w0 = random_vec(rng, 50.0);
    Vec3 ta = Vec3::Zero(), tb = Vec3::Zero();
    bend_twist(qa, qa.toRotationMatrix(), qb, l, K, w0, ta, tb);
    for (int k = 0; k < 3; ++k) {
      const Vec3 d = h * Vec3::Unit(k);
      const double gb =
          (bend_energy(qa, rotated(qb, d), l, K, w0) - bend_energy(qa, rotated(qb, -d), l, K, w0)) /
          (2 * h);
      const double ga =
          (bend_energy(rotated(qa, d), qb, l, K, w0) - bend_energy(rotated(qa, -d), qb, l, K, w0)) /
          (2 * h);
      EXPECT_NEAR(tb[k], -gb, 1e-6 * (1.0 + std::abs(gb)));
      EXPECT_NEAR(ta[k], -ga, 1e-6 * (1.0 + std::abs(ga)));
    }
    // Internal torques cancel: the energy is invariant under a common rotation.
    EXPECT_LT((ta + tb).norm(), 1e-9 * (ta.norm() + 1e-12));
  }
}

TEST(RodKernels, DarbouxOfAPureBendAndTheDoubleCover) {
  const double l = 0.01, theta = 0.3;
  const Quat qa = Quat(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
  const Quat qb = qa * Quat(Eigen::AngleAxisd(theta, Vec3::UnitX()));
  const Vec3 w = darboux(qa, qb, l);
  EXPECT_NEAR(w.x(), 2.0 / l * std::sin(theta / 2), 1e-12);
  EXPECT_NEAR(w.y(), 0.0, 1e-12);
  EXPECT_NEAR(w.z(), 0.0, 1e-12);
  // -qb is the same rotation: same Darboux vector, energy and torques.
  Quat qb_neg = qb;
  qb_neg.coeffs() = -qb.coeffs();
  EXPECT_LT((darboux(qa, qb_neg, l) - w).norm(), 1e-12);
  const Vec3 K(1, 1, 0.7), w0(5, -3, 1);
  Vec3 ta1 = Vec3::Zero(), tb1 = Vec3::Zero(), ta2 = Vec3::Zero(), tb2 = Vec3::Zero();
  const double e1 = bend_twist(qa, qa.toRotationMatrix(), qb, l, K, w0, ta1, tb1);
  const double e2 = bend_twist(qa, qa.toRotationMatrix(), qb_neg, l, K, w0, ta2, tb2);
  EXPECT_NEAR(e1, e2, 1e-12);
  EXPECT_LT((ta1 - ta2).norm(), 1e-12);
}

TEST(RodKernels, ParallelPenaltyForcesAndTorqueAreMinusGradient) {
  std::mt19937 rng(11);
  const double h = 1e-8, l = 0.003, kp = 50.0;
  auto energy = [&](const Vec3& xa, const Vec3& xb, const Quat& q) {
    Vec3 fa = Vec3::Zero(), fb = Vec3::Zero(), t = Vec3::Zero();
    return parallel_penalty(xa, xb, q.toRotationMatrix().col(2), l, kp, fa, fb, t);
  };
  for (int trial = 0; trial < 20; ++trial) {
    const Quat q = random_quat(rng);
    const Vec3 xa = random_vec(rng, 0.01);
    const Vec3 xb = xa + l * (q * Vec3::UnitZ()) + random_vec(rng, 0.3 * l);
    Vec3 fa = Vec3::Zero(), fb = Vec3::Zero(), t = Vec3::Zero();
    parallel_penalty(xa, xb, q.toRotationMatrix().col(2), l, kp, fa, fb, t);
    for (int k = 0; k < 3; ++k) {
      const Vec3 d = h * Vec3::Unit(k);
      const double ga = (energy(xa + d, xb, q) - energy(xa - d, xb, q)) / (2 * h);
      const double gb = (energy(xa, xb + d, q) - energy(xa, xb - d, q)) / (2 * h);
      const double gq =
          (energy(xa, xb, rotated(q, 1e3 * d)) - energy(xa, xb, rotated(q, -1e3 * d))) / (2e3 * h);
      EXPECT_NEAR(fa[k], -ga, 1e-5 * (1 + std::abs(ga)));
      EXPECT_NEAR(fb[k], -gb, 1e-5 * (1 + std::abs(gb)));
      EXPECT_NEAR(t[k], -gq, 1e-5 * (1 + std::abs(gq)));
    }
    // Shear only: a pure stretch along d3 costs nothing.
    const Vec3 d3 = q * Vec3::UnitZ();
    EXPECT_NEAR(energy(xa, xa + 1.3 * l * d3, q), 0.0, 1e-15);
  }
}

TEST(RodKernels, StretchPenaltyIsHookeanSpring) {
  const double l = 0.002, ea = 300.0;
  Vec3 fa = Vec3::Zero(), fb = Vec3::Zero();
  const Vec3 xa(0, 0, 0), xb(0, 0, 1.01 * l);
  const double e = stretch_penalty(xa, xb, l, ea, fa, fb);
  EXPECT_NEAR(fb.z(), -ea * 0.01, 1e-12);  // T = E A strain
  EXPECT_NEAR((fa + fb).norm(), 0.0, 1e-15);
  EXPECT_NEAR(e, 0.5 * ea / l * (0.01 * l) * (0.01 * l), 1e-18);
}

TEST(RodKernels, RotationUpdateStaysUnitAndConvergesToTheExactSpin) {
  const Vec3 w(3.0, -2.0, 5.0);  // body angular velocity (rad/s)
  const double t_end = 0.5;
  double prev_err = 1e9;
  for (int steps : {1000, 2000, 4000}) {
    Quat q = Quat::Identity();
    const double dt = t_end / steps;
    for (int i = 0; i < steps; ++i) {
      q = integrate_rotation(q, w, dt);
      ASSERT_NEAR(q.norm(), 1.0, 1e-14);
    }
    const Quat exact(Eigen::AngleAxisd(w.norm() * t_end, w.normalized()));
    const double err = q.angularDistance(exact);
    EXPECT_LT(err, prev_err * 0.6);  // first order: halves with dt
    prev_err = err;
  }
  EXPECT_LT(prev_err, 2e-3);
}

TEST(RodKernels, SpinOfAFreeSymmetricTopPrecessesExactlyAtAnyStep) {
  // Torque-free symmetric top (I1 = I2): w3 is constant and (w1, w2) turns about the axis at
  // Omega = (I3 - I1) / I1 w3, so |I w| is conserved. Steps of Omega dt = 0.05 .. 0.8 rad: the
  // norm holds to rounding and each step turns by exactly the Cayley angle 2 atan(a / 2), a
  // phase error of a^3 / 12 per step (second order overall).
  const Vec3 inertia(2.0, 2.0, 1.0), inv = inertia.cwiseInverse();
  const Vec3 w0(0.3, 0.0, 2.0);
  const double omega = (inertia.z() - inertia.x()) / inertia.x() * w0.z();  // -1 rad/s
  const double t_end = 8.0;
  double prev_err = 1e300;
  for (double dt : {0.8, 0.4, 0.2, 0.1, 0.05}) {
    Vec3 w = w0;
    const int steps = static_cast<int>(std::lround(t_end / dt));
    for (int i = 0; i < steps; ++i) w = integrate_spin(w, inertia, inv, Vec3::Zero(), dt);
    EXPECT_NEAR(w.z(), w0.z(), 1e-15);
    EXPECT_NEAR(inertia.cwiseProduct(w).norm(), inertia.cwiseProduct(w0).norm(), 1e-12);
    const double phase = std::atan2(w.y(), w.x());
    const double err = std::abs(std::remainder(phase - omega * t_end, 2 * std::numbers::pi));
    const double a = std::abs(omega) * dt;
    EXPECT_NEAR(err, steps * (a - 2 * std::atan(a / 2)), 1e-9) << "dt " << dt;
    EXPECT_LT(err, prev_err * 0.3) << "dt " << dt;  // second order: a quarter per halving
    prev_err = err;
  }
  EXPECT_LT(prev_err, 2e-3);
  // A torque about the axis spins it up at tau / I3.
  const Vec3 w = integrate_spin(Vec3::Zero(), inertia, inv, Vec3(0, 0, 0.5), 0.1);
  EXPECT_NEAR(w.z(), 0.05, 1e-15);
}

// rod_forces writes the kernels' arithmetic out as flat loops over the whole rod (rod_step.cpp):
// on a bent, twisted, moving state with a shaped tip, applied loads, gravity and drag, its
// forces and torques equal the sum of bend_twist and parallel_penalty over the vertices and
// edges, so the gradient checks above hold for the step itself.
TEST(RodKernels, ForcePassEqualsTheSumOfTheKernels) {
  RodDef d = test::free_rod(0.05, 37, 0.4e-3, 30e9);
  d.tip_shape = {TipSection::arc(3e-3, 2.0, 0.4)};
  const RodModel md = build_rod(d);
  RodState st = make_state(md, d);
  std::mt19937 rng(7);
  for (int i = 0; i < md.n; ++i) {
    st.x[i] += random_vec(rng, 2e-4);
    st.v[i] = random_vec(rng, 0.1);
    st.f_ext[i] = random_vec(rng, 1e-3);
  }
  for (int j = 0; j < md.m; ++j) {
    st.q[j] = rotated(st.q[j], random_vec(rng, 0.2));
    if (j % 3 == 0) st.q[j].coeffs() *= -1.0;  // the double cover
    st.tau_ext[j] = random_vec(rng, 1e-5);
  }
  RodSettings s;
  s.gravity = Vec3(0.3, -9.81, 1.0);
  s.drag = 3.0;
  RodWorkspace ws;
  ws.resize(md);
  rod_begin_step(md, ws);
  rod_forces(md, s, st, ws);

  std::vector<Vec3> f(md.n), t(md.m);
  for (int i = 0; i < md.n; ++i)
    f[i] = md.node_mass[i] * (s.gravity - s.drag * st.v[i]) + st.f_ext[i];
  for (int j = 0; j < md.m; ++j) t[j] = st.tau_ext[j];
  for (int j = 0; j < md.m; ++j) {
    const Mat3 R = st.q[j].toRotationMatrix();
    if (j > 0) {
      bend_twist(st.q[j - 1], st.q[j - 1].toRotationMatrix(), st.q[j], md.vertex_length[j],
                 md.vertex_stiffness[j], md.rest_darboux[j], t[j - 1], t[j]);
    }
    parallel_penalty(st.x[j], st.x[j + 1], R.col(2), md.rest_length[j], md.kp[j], f[j], f[j + 1],
                     t[j]);
  }
  double f_scale = 0.0, t_scale = 0.0;
  for (const Vec3& v : f) f_scale = std::max(f_scale, v.norm());
  for (const Vec3& v : t) t_scale = std::max(t_scale, v.norm());
  ASSERT_GT(t_scale, 0.0);
  for (int i = 0; i < md.n; ++i)
    EXPECT_LT((ws.force[i] - f[i]).norm(), 1e-12 * f_scale) << "node " << i;
  for (int j = 0; j < md.m; ++j)
    EXPECT_LT((ws.torque[j] - t[j]).norm(), 1e-12 * t_scale) << "frame " << j;
}

// vertex_moment: frames turning at a steady rate kappa about d1 (a circular arc) carry the bending
// moment E I kappa about d1 at every interior vertex, as a torque on the proximal frame that turns
// it toward the distal one; the free ends carry none.
TEST(VertexMoment, CircularArcCarriesEIKappa) {
  const RodDef d = test::free_rod(0.1, 20, 0.4e-3, 5e9);
  const RodModel md = build_rod(d);
  RodState st = make_state(md, d);
  const double kappa = 20.0;  // 1/m: a 50 mm radius
  const double l = d.length / d.segments;
  for (int j = 0; j < md.m; ++j)
    st.q[j] = Quat(Eigen::AngleAxisd(kappa * l * j, Vec3::UnitX())) * st.q[0];
  const double ei = md.vertex_stiffness[1].x();
  EXPECT_NEAR(ei, d.youngs_modulus * std::numbers::pi * std::pow(d.outer_radius, 4) / 4, 1e-12);
  const Vec3 axis = st.q[0] * Vec3::UnitX();
  for (int k = 1; k < md.m; ++k) {
    const Vec3 g = vertex_moment(md, st, k);
    // cos(a / 2) K 2 sin(a / 2) / l with a = kappa l: E I sin(kappa l) / l, within 0.2 % of E I
    // kappa.
    EXPECT_NEAR(g.dot(axis), ei * std::sin(kappa * l) / l, 1e-9 * ei * kappa) << "vertex " << k;
    EXPECT_NEAR(g.dot(axis), ei * kappa, 2e-3 * ei * kappa);
    EXPECT_NEAR((g - g.dot(axis) * axis).norm(), 0.0, 1e-9 * ei * kappa);
  }
  EXPECT_EQ(vertex_moment(md, st, 0), Vec3::Zero());
  EXPECT_EQ(vertex_moment(md, st, md.m), Vec3::Zero());
}
