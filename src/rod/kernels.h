// Stateless rod kernels. Equation numbers refer to docs/physics.md, where each is derived.
#pragma once

#include <cmath>

#include "vcsim/core.h"
#include "vcsim/rod.h"

// The rod's hot loops are compiled twice, for AVX2 and for the x86-64 baseline (SSE2), and the
// loader picks one for the machine. Both give the same bits: the loops are element-wise,
// -ffp-contract=off rules out fused multiply-adds, and division and sqrt are correctly rounded.
// Not under ThreadSanitizer: the clones' resolver runs while the loader relocates the program,
// before TSan's runtime is up, and its instrumented entry crashes there.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_THREAD__)
#define VCSIM_SIMD_CLONES [[gnu::target_clones("avx2", "default")]]
#else
#define VCSIM_SIMD_CLONES
#endif

namespace vcsim::internal {

// Relative rotation r = conj(qa) qb with the double cover resolved (r.w >= 0), so that the
// rod's energy does not see the sign of a quaternion (physics.md eq. 2).
inline Quat relative_rotation(const Quat& qa, const Quat& qb) {
  // conj(qa) qb written out (16 multiplications).
  const double aw = qa.w(), ax = -qa.x(), ay = -qa.y(), az = -qa.z();
  const double bw = qb.w(), bx = qb.x(), by = qb.y(), bz = qb.z();
  const double w = aw * bw - ax * bx - ay * by - az * bz;
  const double s = w < 0.0 ? -1.0 : 1.0;
  return Quat(s * w, s * (aw * bx + ax * bw + ay * bz - az * by),
              s * (aw * by - ax * bz + ay * bw + az * bx),
              s * (aw * bz + ax * by - ay * bx + az * bw));
}

// Bending and twisting at one vertex (physics.md eqs. 2-5).
// E = (l/2) sum_k K_k (Omega_k - Omega0_k)^2 with Omega = (2/l) Im(r) in frame a.
// Adds the world torques on frame a and frame b; returns the energy.
// R_a is qa as a rotation matrix (passed in so that each frame is converted once per step).
[[gnu::always_inline]] inline double bend_twist(const Quat& qa, const Mat3& R_a, const Quat& qb,
                                                double l, const Vec3& K, const Vec3& omega0,
                                                Vec3& tau_a, Vec3& tau_b) {
  const Quat r = relative_rotation(qa, qb);
  const Vec3 rv = r.vec();
  const Vec3 d_omega = (2.0 / l) * rv - omega0;
  const Vec3 k_dw = K.cwiseProduct(d_omega);
  // g = (r_w I + [r_v]x) K dOmega: the energy gradient w.r.t. a rotation of b in a's coordinates.
  const Vec3 g = r.w() * k_dw + rv.cross(k_dw);
  const Vec3 g_world = R_a * g;
  tau_a += g_world;
  tau_b -= g_world;
  return 0.5 * l * d_omega.dot(k_dw);
}

// Parallel constraint (physics.md eq. 6): E = (K_p l / 2) |P (e / l)|^2 with P = I - d3 d3^T,
// e = xb - xa: a shear penalty on the part of the edge off d3 (stretch is left to the distance
// constraints or the stretch penalty). Forces pull the edge toward d3; the torque
// K_p (u . d3) d3 x e turns d3 toward the edge.
[[gnu::always_inline]] inline double parallel_penalty(const Vec3& xa, const Vec3& xb,
                                                      const Vec3& d3, double l, double kp, Vec3& fa,
                                                      Vec3& fb, Vec3& tau) {
  const Vec3 e = xb - xa;
  const Vec3 u = e / l;
  const double axial = u.dot(d3);
  const Vec3 perp = u - axial * d3;
  fa += kp * perp;
  fb -= kp * perp;
  tau += (kp * axial) * d3.cross(e);
  return 0.5 * kp * l * perp.squaredNorm();
}

// Extensible stretch of the original CoRdE (physics.md eq. 7): E = (EA / 2 l) (|e| - l)^2.
inline double stretch_penalty(const Vec3& xa, const Vec3& xb, double l, double ea, Vec3& fa,
                              Vec3& fb) {
  const Vec3 e = xb - xa;
  const double len = e.norm();
  const double ext = len - l;
  const Vec3 f = (ea / l) * ext * (e / len);
  fa += f;
  fb -= f;
  return 0.5 * ea / l * ext * ext;
}

// One step of Euler's equations for a frame with I1 = I2 (every rod section): the torque as an
// explicit kick, then the gyroscopic term, which for a symmetric body only turns (w1, w2) about
// the axis at Omega = (I3 - I1) / I1 w3 (w3 unchanged), as a rotation by the Cayley angle of
// a = Omega dt (cos -> (1 - a^2/4) / (1 + a^2/4), sin -> a / (1 + a^2/4)). Unlike the explicit
// term, which grows |w| by sqrt(1 + a^2) per step and turns a twisting, bending frame into a
// runaway spin, this keeps |I w| exactly for any step (physics.md eq. 9).
// Written on scalars so that the rod step's frame loop, which calls it on plain arrays, vectorises
// (physics.md eq. 9); `integrate_spin` below is the same on vectors.
[[gnu::always_inline]] inline void integrate_spin_scalar(const double w[3], const double inertia[3],
                                                         const double inv_inertia[3],
                                                         const double tau_body[3], double dt,
                                                         double out[3]) {
  const double k0 = w[0] + dt * (inv_inertia[0] * tau_body[0]);
  const double k1 = w[1] + dt * (inv_inertia[1] * tau_body[1]);
  const double k2 = w[2] + dt * (inv_inertia[2] * tau_body[2]);
  const double a = dt * (inertia[2] - inertia[0]) * inv_inertia[0] * k2;
  const double d = 1.0 / (1.0 + 0.25 * a * a);
  const double c = (1.0 - 0.25 * a * a) * d, s = a * d;
  out[0] = c * k0 - s * k1;
  out[1] = s * k0 + c * k1;
  out[2] = k2;
}

inline Vec3 integrate_spin(const Vec3& w, const Vec3& inertia, const Vec3& inv_inertia,
                           const Vec3& tau_body, double dt) {
  Vec3 out;
  integrate_spin_scalar(w.data(), inertia.data(), inv_inertia.data(), tau_body.data(), dt,
                        out.data());
  return out;
}

// q <- normalise(q + dt/2 q (0, w)), the semi-implicit frame update (physics.md eq. 10),
// written out: the product with a pure quaternion needs 12 multiplications, not 16.
inline Quat integrate_rotation(const Quat& q, const Vec3& w, double dt) {
  const double h = 0.5 * dt;
  const double qw = q.w(), qx = q.x(), qy = q.y(), qz = q.z();
  const double nw = qw - h * (qx * w.x() + qy * w.y() + qz * w.z());
  const double nx = qx + h * (qw * w.x() + qy * w.z() - qz * w.y());
  const double ny = qy + h * (qw * w.y() + qz * w.x() - qx * w.z());
  const double nz = qz + h * (qw * w.z() + qx * w.y() - qy * w.x());
  const double s = 1.0 / std::sqrt(nw * nw + nx * nx + ny * ny + nz * nz);
  return Quat(nw * s, nx * s, ny * s, nz * s);
}

// The linearly implicit velocity update (implicit.cpp; physics.md 5.5): replaces the explicit one
// of rod_integrate_velocities when settings.integrator asks for it.
void implicit_velocities(const RodModel& md, const RodSettings& s, RodState& st, RodWorkspace& ws);

}  // namespace vcsim::internal
