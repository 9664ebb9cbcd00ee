// The rod step: forces, semi-implicit velocity integration, constraint iterations, position
// integration (physics.md section 5). Reads the model, writes the state; allocates nothing.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <stdexcept>

#include "distance.h"
#include "kernels.h"
#include "vcsim/rod.h"

namespace vcsim {

using namespace internal;

const char* to_string(DistanceMethod m) {
  switch (m) {
    case DistanceMethod::kGlobal:
      return "global";
    case DistanceMethod::kLocalGS:
      return "local-gs";
    case DistanceMethod::kLocalJacobi:
      return "local-jacobi";
    case DistanceMethod::kPenalty:
      return "penalty";
  }
  return "?";
}

DistanceMethod distance_method_from_string(const std::string& s, const std::string& source) {
  for (auto m : {DistanceMethod::kGlobal, DistanceMethod::kLocalGS, DistanceMethod::kLocalJacobi,
                 DistanceMethod::kPenalty}) {
    if (s == to_string(m)) return m;
  }
  throw InputError(source, "method",
                   "expected one of global, local-gs, local-jacobi, penalty, got '" + s + "'");
}

void RodSettings::validate(const std::string& source) const {
  require_positive(dt, source, "dt");
  for (int k = 0; k < 3; ++k) require_finite(gravity[k], source, "gravity");
  if (iterations < 1 || iterations > 10000) {
    throw InputError(source, "iterations",
                     "expected an integer in [1, 10000], got " + std::to_string(iterations));
  }
  require_nonnegative(drag, source, "drag");
  require_nonnegative(angular_drag, source, "angular_drag");
  require_nonnegative(internal_damping, source, "internal_damping");
  require_positive(penalty_modulus_scale, source, "penalty_modulus_scale");
  if (integrator == Integrator::kLinearlyImplicit) {
    // physics.md 5.5: only the bending, twisting and parallel-penalty forces are implicit.
    if (distance == DistanceMethod::kPenalty) {
      throw InputError(source, "distance",
                       "expected distance constraints with the linearly implicit step (its "
                       "Hessian has no stretch term), got penalty");
    }
    if (internal_damping > 0.0) {
      throw InputError(source, "internal_damping",
                       "expected 0 with the linearly implicit step (that damping is explicit and "
                       "unstable at the physical mass; backward Euler damps the stiff modes)");
    }
  }
}

namespace {

// a where the mask is all ones, b where it is zero, bit for bit.
inline double select_bits(std::uint64_t mask, double a, double b) {
  return std::bit_cast<double>((std::bit_cast<std::uint64_t>(a) & mask) |
                               (std::bit_cast<std::uint64_t>(b) & ~mask));
}

VCSIM_SIMD_CLONES void accumulate_forces(const RodModel& md, const RodSettings& s, RodState& st,
                                         RodWorkspace& ws) {
  const int n = md.n, m = md.m;
  // Raw pointers: Eigen's SIMD stores may alias anything, so through std::vector the compiler
  // would reload every array's address after each store. GCC's dependence analysis does not use
  // __restrict on local pointers, so the loops that must vectorise say `ivdep` (no iteration
  // reads what another one writes).
  Vec3* force = ws.force.data();
  Vec3* torque = ws.torque.data();
  const Vec3* __restrict x = st.x.data();
  const Vec3* __restrict v = st.v.data();
  const Quat* __restrict q = st.q.data();
  const double* __restrict mass = md.node_mass.data();
  const double* __restrict lv = md.vertex_length.data();
  const double* __restrict rest = md.rest_length.data();
  const double* __restrict kp = md.kp.data();
  const Vec3* __restrict kv = md.vertex_stiffness.data();
  const Vec3* __restrict w0 = md.rest_darboux.data();
  // The frames, bending and twisting, and the parallel penalty as flat loops over plain arrays
  // (quaternion and vector coefficients addressed directly, the rotation matrices as nine
  // arrays); each vertex's and edge's contribution is written once and the sums per node and
  // frame are formed afterwards, so no loop carries a dependency and every loop vectorises
  // (GCC does not vectorise stores in interleaved groups of nine, so the matrices are not kept
  // as Mat3s). Vectorised or not, each element sees the same operations in the same order.
  static_assert(sizeof(Quat) == 4 * sizeof(double) && sizeof(Vec3) == 3 * sizeof(double));
  const double* __restrict Q = q[0].coeffs().data();  // (x, y, z, w) per frame
  double* __restrict r0 = ws.rot.data();              // entry (r, c) of frame j: r{3c + r}[j]
  double* __restrict r1 = r0 + m;
  double* __restrict r2 = r1 + m;
  double* __restrict r3 = r2 + m;
  double* __restrict r4 = r3 + m;
  double* __restrict r5 = r4 + m;
  double* __restrict r6 = r5 + m;
  double* __restrict r7 = r6 + m;
  double* __restrict r8 = r7 + m;
  const double* __restrict X = x[0].data();
  const double* __restrict K = kv[0].data();
  const double* __restrict W0 = w0[0].data();
  // Scratch: bending torques G per vertex (0..m) and parallel forces P per edge, stored at
  // edge + 1 so that P[0] = P[m + 1] = 0 close the node sums.
  double* __restrict gx = ws.scratch.data();
  double* __restrict gy = gx + (m + 2);
  double* __restrict gz = gy + (m + 2);
  double* __restrict px = gz + (m + 2);
  double* __restrict py = px + (m + 2);
  double* __restrict pz = py + (m + 2);
  // 1. Frame j as a rotation matrix (material -> world), kept for the rest of the step.
#pragma GCC ivdep
  for (int j = 0; j < m; ++j) {
    const double qx = Q[4 * j], qy = Q[4 * j + 1], qz = Q[4 * j + 2], qw = Q[4 * j + 3];
    const double tx = 2 * qx, ty = 2 * qy, tz = 2 * qz;
    const double twx = tx * qw, twy = ty * qw, twz = tz * qw;
    const double txx = tx * qx, txy = ty * qx, txz = tz * qx;
    const double tyy = ty * qy, tyz = tz * qy, tzz = tz * qz;
    r0[j] = 1 - (tyy + tzz);
    r1[j] = txy + twz;
    r2[j] = txz - twy;
    r3[j] = txy - twz;
    r4[j] = 1 - (txx + tzz);
    r5[j] = tyz + twx;
    r6[j] = txz + twy;
    r7[j] = tyz - twx;
    r8[j] = 1 - (txx + tyy);
  }
  // 2. Bending and twisting at interior vertex k between frames a = k - 1 and b = k
  // (kernels.h bend_twist, physics.md eqs. 2-5): G_k = R_a g, added to frame a, taken from b.
  gx[0] = gy[0] = gz[0] = 0.0;
  gx[m] = gy[m] = gz[m] = 0.0;
#pragma GCC ivdep
  for (int k = 1; k < m; ++k) {
    const double* a = Q + 4 * (k - 1);
    const double* b = Q + 4 * k;
    const double aw = a[3], ax = -a[0], ay = -a[1], az = -a[2];
    const double bw = b[3], bx = b[0], by = b[1], bz = b[2];
    const double w = aw * bw - ax * bx - ay * by - az * bz;
    const double sg = w < 0.0 ? -1.0 : 1.0;  // the double cover: r.w >= 0
    const double rw = sg * w;
    const double rx = sg * (aw * bx + ax * bw + ay * bz - az * by);
    const double ry = sg * (aw * by - ax * bz + ay * bw + az * bx);
    const double rz = sg * (aw * bz + ax * by - ay * bx + az * bw);
    const double two_l = 2.0 / lv[k];
    const double kx = K[3 * k] * (two_l * rx - W0[3 * k]);
    const double ky = K[3 * k + 1] * (two_l * ry - W0[3 * k + 1]);
    const double kz = K[3 * k + 2] * (two_l * rz - W0[3 * k + 2]);
    const double g0 = rw * kx + (ry * kz - rz * ky);
    const double g1 = rw * ky + (rz * kx - rx * kz);
    const double g2 = rw * kz + (rx * ky - ry * kx);
    const int ja = k - 1;
    gx[k] = r0[ja] * g0 + r3[ja] * g1 + r6[ja] * g2;
    gy[k] = r1[ja] * g0 + r4[ja] * g1 + r7[ja] * g2;
    gz[k] = r2[ja] * g0 + r5[ja] * g1 + r8[ja] * g2;
  }
  // 3. The parallel penalty of edge j (kernels.h parallel_penalty, eq. 6) and the frame torques.
  px[0] = py[0] = pz[0] = 0.0;
  px[m + 1] = py[m + 1] = pz[m + 1] = 0.0;
  const double* __restrict te = st.tau_ext[0].data();
  double* T = torque[0].data();  // not __restrict: the clamps below add through ws.torque
#pragma GCC ivdep
  for (int j = 0; j < m; ++j) {
    const double ex = X[3 * j + 3] - X[3 * j], ey = X[3 * j + 4] - X[3 * j + 1],
                 ez = X[3 * j + 5] - X[3 * j + 2];
    const double dx = r6[j], dy = r7[j], dz = r8[j];  // d3
    const double l = rest[j];
    const double ux = ex / l, uy = ey / l, uz = ez / l;
    const double axial = ux * dx + uy * dy + uz * dz;
    const double k = kp[j];
    px[j + 1] = k * (ux - axial * dx);
    py[j + 1] = k * (uy - axial * dy);
    pz[j + 1] = k * (uz - axial * dz);
    const double ka = k * axial;
    T[3 * j] = te[3 * j] + (gx[j + 1] - gx[j]) + ka * (dy * ez - dz * ey);
    T[3 * j + 1] = te[3 * j + 1] + (gy[j + 1] - gy[j]) + ka * (dz * ex - dx * ez);
    T[3 * j + 2] = te[3 * j + 2] + (gz[j + 1] - gz[j]) + ka * (dx * ey - dy * ex);
  }
  // 4. Node forces: gravity, applied loads, mass-proportional drag, the penalty of both edges.
  const double* __restrict V = v[0].data();
  const double* __restrict fe = st.f_ext[0].data();
  double* F = force[0].data();  // not __restrict: the stretch penalty adds through ws.force
  const double g0 = s.gravity.x(), g1 = s.gravity.y(), g2 = s.gravity.z();
  const double drag = s.drag;
  for (int i = 0; i < n; ++i) {
    F[3 * i] = mass[i] * (g0 - drag * V[3 * i]) + fe[3 * i] + (px[i + 1] - px[i]);
    F[3 * i + 1] = mass[i] * (g1 - drag * V[3 * i + 1]) + fe[3 * i + 1] + (py[i + 1] - py[i]);
    F[3 * i + 2] = mass[i] * (g2 - drag * V[3 * i + 2]) + fe[3 * i + 2] + (pz[i + 1] - pz[i]);
  }
  const double* __restrict Wb = st.omega[0].data();  // body-frame angular velocities
  if (s.angular_drag > 0.0) {
    // tau -= c R (I omega), as Eigen evaluated it: (c R) u, row 2 summed as p0 + (p1 + p2).
    const double c = s.angular_drag;
    const double* __restrict I = md.inertia[0].data();
#pragma GCC ivdep
    for (int j = 0; j < m; ++j) {
      const double u0 = I[3 * j] * Wb[3 * j], u1 = I[3 * j + 1] * Wb[3 * j + 1],
                   u2 = I[3 * j + 2] * Wb[3 * j + 2];
      T[3 * j] -= (c * r0[j]) * u0 + (c * r3[j]) * u1 + (c * r6[j]) * u2;
      T[3 * j + 1] -= (c * r1[j]) * u0 + (c * r4[j]) * u1 + (c * r7[j]) * u2;
      T[3 * j + 2] -= (c * r2[j]) * u0 + ((c * r5[j]) * u1 + (c * r8[j]) * u2);
    }
  }
  // Clamps: half vertices between the clamp frames and the end frames.
  st.base_torque.setZero();
  st.tip_torque.setZero();
  if (md.vertex_active[0]) {
    bend_twist(st.base_frame, st.base_frame.toRotationMatrix(), st.q[0], md.vertex_length[0],
               md.vertex_stiffness[0], md.rest_darboux[0], st.base_torque, ws.torque[0]);
  }
  if (md.vertex_active[m]) {
    bend_twist(st.q[m - 1], ws.frame_rotation(m - 1), st.tip_frame, md.vertex_length[m],
               md.vertex_stiffness[m], md.rest_darboux[m], ws.torque[m - 1], st.tip_torque);
  }
  // Stiffness-proportional internal damping (Rayleigh beta): resists the rates of bending,
  // twisting and of the parallel-constraint strain, never rigid motion.
  if (s.internal_damping > 0.0) {
    const double beta = s.internal_damping;
    // Vertex k between frames a = k - 1 and b = k: t_k = R_a ((beta / l) K (R_a^T (R_b w_b -
    // R_a w_a))), added to frame a and taken from frame b. Stored per vertex (in gx, gy, gz,
    // free again after the bending pass), then summed per frame in the loop's order. Products
    // R v sum row 2 as p0 + (p1 + p2), as Eigen's 3 x 3 product did before this was written on
    // arrays, so that the results (and the chaotic default scenario) stayed bit for bit.
#pragma GCC ivdep
    for (int k = 1; k < m; ++k) {
      const int ja = k - 1, jb = k;
      const double* wa = Wb + 3 * ja;
      const double* wb = Wb + 3 * jb;
      const double rw0 = (r0[jb] * wb[0] + r3[jb] * wb[1] + r6[jb] * wb[2]) -
                         (r0[ja] * wa[0] + r3[ja] * wa[1] + r6[ja] * wa[2]);
      const double rw1 = (r1[jb] * wb[0] + r4[jb] * wb[1] + r7[jb] * wb[2]) -
                         (r1[ja] * wa[0] + r4[ja] * wa[1] + r7[ja] * wa[2]);
      const double rw2 = (r2[jb] * wb[0] + (r5[jb] * wb[1] + r8[jb] * wb[2])) -
                         (r2[ja] * wa[0] + (r5[ja] * wa[1] + r8[ja] * wa[2]));
      const double ra0 = r0[ja] * rw0 + r1[ja] * rw1 + r2[ja] * rw2;
      const double ra1 = r3[ja] * rw0 + r4[ja] * rw1 + r5[ja] * rw2;
      const double ra2 = r6[ja] * rw0 + r7[ja] * rw1 + r8[ja] * rw2;
      const double c = beta / lv[k];
      const double s0 = c * (K[3 * k] * ra0), s1 = c * (K[3 * k + 1] * ra1),
                   s2 = c * (K[3 * k + 2] * ra2);
      gx[k] = r0[ja] * s0 + r3[ja] * s1 + r6[ja] * s2;
      gy[k] = r1[ja] * s0 + r4[ja] * s1 + r7[ja] * s2;
      gz[k] = r2[ja] * s0 + (r5[ja] * s1 + r8[ja] * s2);
    }
    if (m >= 2) {
      T[0] += gx[1];
      T[1] += gy[1];
      T[2] += gz[1];
#pragma GCC ivdep
      for (int j = 1; j + 1 < m; ++j) {
        T[3 * j] = (T[3 * j] - gx[j]) + gx[j + 1];
        T[3 * j + 1] = (T[3 * j + 1] - gy[j]) + gy[j + 1];
        T[3 * j + 2] = (T[3 * j + 2] - gz[j]) + gz[j + 1];
      }
      T[3 * (m - 1)] -= gx[m - 1];
      T[3 * (m - 1) + 1] -= gy[m - 1];
      T[3 * (m - 1) + 2] -= gz[m - 1];
    }
    // Edge j: the shear rate (v_{j+1} - v_j) / l - (R w) x d3 without its d3 part, damped by
    // beta K_p as a force pair on the nodes (stored per edge in px, py, pz, then summed per node
    // in the loop's order) and a torque on the frame.
#pragma GCC ivdep
    for (int j = 0; j < m; ++j) {
      const double dx = r6[j], dy = r7[j], dz = r8[j];
      const double* w = Wb + 3 * j;
      const double q0 = r0[j] * w[0] + r3[j] * w[1] + r6[j] * w[2];
      const double q1 = r1[j] * w[0] + r4[j] * w[1] + r7[j] * w[2];
      const double q2 = r2[j] * w[0] + (r5[j] * w[1] + r8[j] * w[2]);
      const double l = rest[j];
      double e0 = (V[3 * j + 3] - V[3 * j]) / l - (q1 * dz - q2 * dy);
      double e1 = (V[3 * j + 4] - V[3 * j + 1]) / l - (q2 * dx - q0 * dz);
      double e2 = (V[3 * j + 5] - V[3 * j + 2]) / l - (q0 * dy - q1 * dx);
      const double along = e0 * dx + e1 * dy + e2 * dz;  // shear rate only, like the penalty
      e0 -= along * dx;
      e1 -= along * dy;
      e2 -= along * dz;
      const double bk = beta * kp[j];
      px[j] = bk * e0;
      py[j] = bk * e1;
      pz[j] = bk * e2;
      const double bkl = bk * l;
      T[3 * j] += bkl * (dy * e2 - dz * e1);
      T[3 * j + 1] += bkl * (dz * e0 - dx * e2);
      T[3 * j + 2] += bkl * (dx * e1 - dy * e0);
    }
    F[0] += px[0];
    F[1] += py[0];
    F[2] += pz[0];
#pragma GCC ivdep
    for (int i = 1; i < m; ++i) {
      F[3 * i] = (F[3 * i] - px[i - 1]) + px[i];
      F[3 * i + 1] = (F[3 * i + 1] - py[i - 1]) + py[i];
      F[3 * i + 2] = (F[3 * i + 2] - pz[i - 1]) + pz[i];
    }
    F[3 * m] -= px[m - 1];
    F[3 * m + 1] -= py[m - 1];
    F[3 * m + 2] -= pz[m - 1];
  }
  if (s.distance == DistanceMethod::kPenalty) {
    for (int j = 0; j < m; ++j) {
      stretch_penalty(st.x[j], st.x[j + 1], md.rest_length[j],
                      s.penalty_modulus_scale * md.axial_stiffness[j], ws.force[j],
                      ws.force[j + 1]);
    }
  }
}

}  // namespace

void rod_begin_step(const RodModel& md, RodWorkspace& ws) {
  std::copy(md.inv_mass.begin(), md.inv_mass.end(), ws.inv_mass.begin());
  std::fill(ws.frame_free.begin(), ws.frame_free.end(), 1.0);
  std::fill(ws.node_impulse.begin(), ws.node_impulse.end(), Vec3::Zero());
}

void rod_forces(const RodModel& md, const RodSettings& s, RodState& st, RodWorkspace& ws) {
  accumulate_forces(md, s, st, ws);
}

VCSIM_SIMD_CLONES void rod_integrate_velocities(const RodModel& md, const RodSettings& s,
                                                RodState& st, RodWorkspace& ws) {
  if (s.integrator == Integrator::kLinearlyImplicit) return implicit_velocities(md, s, st, ws);
  // Semi-implicit: velocities first from the forces at the current positions (held nodes and
  // prescribed frames have zero inverse mass and keep their prescribed velocities).
  const double dt = s.dt;
  const int n = md.n, m = md.m;  // locals: the loop bounds must not be re-read after stores
  double* __restrict V = st.v[0].data();
  double* __restrict W = st.omega[0].data();
  const double* __restrict F = ws.force[0].data();
  const double* __restrict T = ws.torque[0].data();
  const double* __restrict inv_m = ws.inv_mass.data();
  const double* __restrict free = ws.frame_free.data();
  const double* __restrict I = md.inertia[0].data();
  const double* __restrict IL = md.inv_inertia[0].data();
  const double* __restrict r0 = ws.rot.data();  // layout: RodWorkspace::rot
  const double* __restrict r1 = r0 + m;
  const double* __restrict r2 = r1 + m;
  const double* __restrict r3 = r2 + m;
  const double* __restrict r4 = r3 + m;
  const double* __restrict r5 = r4 + m;
  const double* __restrict r6 = r5 + m;
  const double* __restrict r7 = r6 + m;
  const double* __restrict r8 = r7 + m;
#pragma GCC ivdep
  for (int i = 0; i < n; ++i) {
    const double h = dt * inv_m[i];
    V[3 * i] += h * F[3 * i];
    V[3 * i + 1] += h * F[3 * i + 1];
    V[3 * i + 2] += h * F[3 * i + 2];
  }
  // All ones for a free frame (a scalar loop: SSE2 has no 64-bit integer compare).
  std::uint64_t* __restrict keep_new = ws.frame_mask.data();
  for (int j = 0; j < m; ++j) {
    keep_new[j] = free[j] != 0.0 ? ~std::uint64_t{0} : 0;
  }
  // Per frame: the torque in body coordinates (R^T tau), then integrate_spin.
#pragma GCC ivdep
  for (int j = 0; j < m; ++j) {
    const double t0 = T[3 * j], t1 = T[3 * j + 1], t2 = T[3 * j + 2];
    const double tau_body[3] = {r0[j] * t0 + r1[j] * t1 + r2[j] * t2,
                                r3[j] * t0 + r4[j] * t1 + r5[j] * t2,
                                r6[j] * t0 + r7[j] * t1 + r8[j] * t2};
    const double w0 = W[3 * j], w1 = W[3 * j + 1], w2 = W[3 * j + 2];
    double wn[3];
    integrate_spin_scalar(W + 3 * j, I + 3 * j, IL + 3 * j, tau_body, dt, wn);
    // Prescribed frames (free = 0) keep their angular velocity. The choice is a bit mask, not a
    // branch: GCC sinks the work of a ?: into a branch it then cannot vectorise.
    W[3 * j] = select_bits(keep_new[j], wn[0], w0);
    W[3 * j + 1] = select_bits(keep_new[j], wn[1], w1);
    W[3 * j + 2] = select_bits(keep_new[j], wn[2], w2);
  }
}

void rod_distance_iteration(const RodModel& md, const RodSettings& s, RodState& st,
                            RodWorkspace& ws) {
  switch (s.distance) {
    case DistanceMethod::kGlobal:
      if (!distance_global(md, s.dt, st.x, st.v, ws)) distance_local_gs(md, s.dt, st.x, st.v, ws);
      break;
    case DistanceMethod::kLocalGS:
      distance_local_gs(md, s.dt, st.x, st.v, ws);
      break;
    case DistanceMethod::kLocalJacobi:
      distance_local_jacobi(md, s.dt, st.x, st.v, ws);
      break;
    case DistanceMethod::kPenalty:
      break;  // stretch is a force (rod_forces)
  }
}

VCSIM_SIMD_CLONES void rod_integrate_positions(const RodModel& md, const RodSettings& s,
                                               RodState& st, RodWorkspace&) {
  const double dt = s.dt;
  const int n = md.n, m = md.m;
  double* __restrict X = st.x[0].data();
  const double* __restrict V = st.v[0].data();
  Quat* __restrict q = st.q.data();
  const Vec3* __restrict w = st.omega.data();
#pragma GCC ivdep
  for (int i = 0; i < 3 * n; ++i) X[i] += dt * V[i];
  for (int j = 0; j < m; ++j) q[j] = integrate_rotation(q[j], w[j], dt);
}

void rod_end_step(const RodModel& md, const RodSettings& s, RodState& st, const RodWorkspace& ws) {
  st.time += s.dt;
  ++st.steps;
  // What the supports feel: the held node's force balance (internal forces plus constraint
  // impulses over dt), in the rod-on-support sense.
  const int last = md.n - 1;
  st.base_force =
      md.inv_mass[0] == 0.0 ? Vec3(ws.force[0] + ws.node_impulse[0] / s.dt) : Vec3::Zero();
  st.tip_force =
      md.inv_mass[last] == 0.0 ? Vec3(ws.force[last] + ws.node_impulse[last] / s.dt) : Vec3::Zero();
}

void rod_step(const RodModel& md, const RodSettings& s, RodState& st, RodWorkspace& ws,
              RodProfile* profile) {
  const double t0 = profile ? now_us() : 0.0;
  rod_begin_step(md, ws);
  rod_forces(md, s, st, ws);
  const double t1 = profile ? now_us() : 0.0;
  rod_integrate_velocities(md, s, st, ws);
  const double t2 = profile ? now_us() : 0.0;
  if (s.distance != DistanceMethod::kPenalty) {
    for (int it = 0; it < s.iterations; ++it) rod_distance_iteration(md, s, st, ws);
  }
  const double t3 = profile ? now_us() : 0.0;
  rod_integrate_positions(md, s, st, ws);
  rod_end_step(md, s, st, ws);
  if (profile) {
    const double t4 = now_us();
    profile->forces = t1 - t0;
    profile->integrate_velocities = t2 - t1;
    profile->constraints = t3 - t2;
    profile->integrate_positions = t4 - t3;
    profile->total = t4 - t0;
  }
}

double estimate_stable_dt(const RodModel& md, const RodSettings& s) {
  // Gershgorin-style bound on the highest frequency of each node and frame (physics.md 5.3).
  double w2max = 0.0;
  for (int i = 0; i < md.n; ++i) {
    if (md.inv_mass[i] == 0.0) continue;
    double k = 0.0;
    for (int j : {i - 1, i}) {
      if (j < 0 || j >= md.m) continue;
      k += md.kp[j] / md.rest_length[j];
      if (s.distance == DistanceMethod::kPenalty) {
        k += s.penalty_modulus_scale * md.axial_stiffness[j] / md.rest_length[j];
      }
    }
    w2max = std::max(w2max, 2.0 * k * md.inv_mass[i]);
  }
  for (int j = 0; j < md.m; ++j) {
    // The K_p torque is perpendicular to d3: it loads the bending axes only.
    Vec3 k(md.kp[j] * md.rest_length[j], md.kp[j] * md.rest_length[j], 0.0);
    for (int v : {j, j + 1}) {
      if (md.vertex_active[v]) k += md.vertex_stiffness[v] / md.vertex_length[v];
    }
    w2max = std::max(w2max, 2.0 * k.cwiseProduct(md.inv_inertia[j]).maxCoeff());
  }
  double dt = 1.0 / std::sqrt(w2max);  // half of the symplectic-Euler limit 2 / omega
  // Explicit damping is stable for c dt < 2; keep a margin. Stiffness-proportional damping
  // multiplies the top frequency: beta w^2 dt < 1 as well.
  if (s.drag > 0) dt = std::min(dt, 1.0 / s.drag);
  if (s.angular_drag > 0) dt = std::min(dt, 1.0 / s.angular_drag);
  if (s.internal_damping > 0) dt = std::min(dt, 1.0 / (s.internal_damping * w2max));
  return dt;
}

Vec3 vertex_moment(const RodModel& md, const RodState& st, int k) {
  if (k <= 0 || k >= md.m || !md.vertex_active[k]) return Vec3::Zero();
  Vec3 on_a = Vec3::Zero(), on_b = Vec3::Zero();
  bend_twist(st.q[k - 1], st.q[k - 1].toRotationMatrix(), st.q[k], md.vertex_length[k],
             md.vertex_stiffness[k], md.rest_darboux[k], on_a, on_b);
  return on_a;
}

double elastic_energy(const RodModel& md, const RodState& st) {
  double e = 0.0;
  for (int k = 1; k < md.m; ++k) {
    if (!md.vertex_active[k]) continue;
    const Vec3 w = darboux(st.q[k - 1], st.q[k], md.vertex_length[k]) - md.rest_darboux[k];
    e += 0.5 * md.vertex_length[k] * w.dot(md.vertex_stiffness[k].cwiseProduct(w));
  }
  for (int j = 0; j < md.m; ++j) {
    const double l = md.rest_length[j];
    const Vec3 u = (st.x[j + 1] - st.x[j]) / l;
    const Vec3 d3 = st.q[j] * Vec3::UnitZ();
    e += 0.5 * md.kp[j] * l * (u - u.dot(d3) * d3).squaredNorm();
  }
  return e;
}

double scale_for_time_step(RodModel& md, double dt, double kp_ratio) {
  for (int j = 0; j < md.m; ++j) {
    const double l = md.rest_length[j];
    md.kp[j] = std::min(md.kp[j], kp_ratio * md.youngs[j] * md.bend_inertia[j] / (l * l));
  }
  // The same per-node and per-frame stiffness bounds as estimate_stable_dt, with w dt <= 1.
  const double dt2 = dt * dt * 1.0001;
  double added = 0.0;
  for (int i = 0; i < md.n; ++i) {
    if (md.inv_mass[i] == 0.0) continue;
    double k = 0.0;
    for (int j : {i - 1, i})
      if (j >= 0 && j < md.m) k += md.kp[j] / md.rest_length[j];
    const double need = 2.0 * k * dt2;
    if (need > md.node_mass[i]) {
      added += need - md.node_mass[i];
      md.node_mass[i] = need;
      md.inv_mass[i] = 1.0 / need;
    }
  }
  for (int j = 0; j < md.m; ++j) {
    Vec3 k(md.kp[j] * md.rest_length[j], md.kp[j] * md.rest_length[j], 0.0);
    for (int v : {j, j + 1})
      if (md.vertex_active[v]) k += md.vertex_stiffness[v] / md.vertex_length[v];
    for (int a = 0; a < 3; ++a) md.inertia[j][a] = std::max(md.inertia[j][a], 2.0 * k[a] * dt2);
    md.inv_inertia[j] = md.inertia[j].cwiseInverse();
  }
  return added;
}

void set_quasi_static_damping(RodSettings& s) {
  s.drag = 0.5;
  s.angular_drag = 0.5;
  s.internal_damping = 0.4 * s.dt;
}

}  // namespace vcsim
