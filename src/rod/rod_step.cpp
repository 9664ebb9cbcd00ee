// The rod step: forces, semi-implicit velocity integration, constraint iterations, position
// integration (physics.md section 5). Reads the model, writes the state; allocates nothing.
#include <algorithm>
#include <cmath>
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
}

namespace {

void accumulate_forces(const RodModel& md, const RodSettings& s, RodState& st, RodWorkspace& ws) {
  const int n = md.n, m = md.m;
  // Raw pointers: Eigen's SIMD stores may alias anything, so through std::vector the compiler
  // would reload every array's address after each store.
  Vec3* __restrict force = ws.force.data();
  Vec3* __restrict torque = ws.torque.data();
  Mat3* __restrict rot = ws.rot.data();
  const Vec3* __restrict x = st.x.data();
  const Vec3* __restrict v = st.v.data();
  const Quat* __restrict q = st.q.data();
  const double* __restrict mass = md.node_mass.data();
  const double* __restrict lv = md.vertex_length.data();
  const double* __restrict rest = md.rest_length.data();
  const double* __restrict kp = md.kp.data();
  const Vec3* __restrict kv = md.vertex_stiffness.data();
  const Vec3* __restrict w0 = md.rest_darboux.data();
  // Gravity, applied loads and mass-proportional drag on the nodes.
  const Vec3 g = s.gravity;
  const double drag = s.drag;
  for (int i = 0; i < n; ++i) force[i] = mass[i] * (g - drag * v[i]) + st.f_ext[i];
  for (int j = 0; j < m; ++j) torque[j] = st.tau_ext[j];
  // One pass over the edges: the frame as a matrix (reused by every rotation of this step),
  // bending and twisting at the vertex before the edge, and the edge's parallel penalty.
  for (int j = 0; j < m; ++j) {
    rot[j] = q[j].toRotationMatrix();
    if (j > 0) {
      bend_twist(q[j - 1], rot[j - 1], q[j], lv[j], kv[j], w0[j], torque[j - 1], torque[j]);
    }
    parallel_penalty(x[j], x[j + 1], rot[j].col(2), rest[j], kp[j], force[j], force[j + 1],
                     torque[j]);
  }
  if (s.angular_drag > 0.0) {
    for (int j = 0; j < m; ++j) {
      torque[j] -= s.angular_drag * (rot[j] * md.inertia[j].cwiseProduct(st.omega[j]));
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
    bend_twist(st.q[m - 1], ws.rot[m - 1], st.tip_frame, md.vertex_length[m],
               md.vertex_stiffness[m], md.rest_darboux[m], ws.torque[m - 1], st.tip_torque);
  }
  // Stiffness-proportional internal damping (Rayleigh beta): resists the rates of bending,
  // twisting and of the parallel-constraint strain, never rigid motion.
  if (s.internal_damping > 0.0) {
    const double beta = s.internal_damping;
    for (int k = 1; k < m; ++k) {  // vertex k between frames k-1 and k
      const Vec3 rel_w = ws.rot[k] * st.omega[k] - ws.rot[k - 1] * st.omega[k - 1];
      const Vec3 rel_a = ws.rot[k - 1].transpose() * rel_w;
      const Vec3 t = ws.rot[k - 1] *
                     ((beta / md.vertex_length[k]) * md.vertex_stiffness[k].cwiseProduct(rel_a));
      ws.torque[k - 1] += t;
      ws.torque[k] -= t;
    }
    for (int j = 0; j < m; ++j) {
      const Vec3 d3 = ws.rot[j].col(2);
      const Vec3 wd3 = (ws.rot[j] * st.omega[j]).cross(d3);
      Vec3 rate = (st.v[j + 1] - st.v[j]) / md.rest_length[j] - wd3;
      rate -= rate.dot(d3) * d3;  // shear rate only, like the penalty itself
      const Vec3 f = beta * md.kp[j] * rate;
      ws.force[j] += f;
      ws.force[j + 1] -= f;
      ws.torque[j] += (beta * md.kp[j] * md.rest_length[j]) * d3.cross(rate);
    }
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

void rod_integrate_velocities(const RodModel& md, const RodSettings& s, RodState& st,
                              RodWorkspace& ws) {
  // Semi-implicit: velocities first from the forces at the current positions (held nodes and
  // prescribed frames have zero inverse mass and keep their prescribed velocities).
  const double dt = s.dt;
  Vec3* __restrict vel = st.v.data();
  Vec3* __restrict w = st.omega.data();
  const Vec3* __restrict f = ws.force.data();
  const Vec3* __restrict tau = ws.torque.data();
  const Mat3* __restrict rot = ws.rot.data();
  const double* __restrict inv_m = ws.inv_mass.data();
  const double* __restrict free = ws.frame_free.data();
  const Vec3* __restrict inertia = md.inertia.data();
  const Vec3* __restrict inv_inertia = md.inv_inertia.data();
  for (int i = 0; i < md.n; ++i) vel[i] += (dt * inv_m[i]) * f[i];
  for (int j = 0; j < md.m; ++j) {
    const Vec3 tau_body = rot[j].transpose() * tau[j];
    w[j] += (dt * free[j]) * euler_rhs(w[j], inertia[j], inv_inertia[j], tau_body);
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

void rod_integrate_positions(const RodModel& md, const RodSettings& s, RodState& st,
                             RodWorkspace&) {
  const double dt = s.dt;
  Vec3* __restrict x = st.x.data();
  const Vec3* __restrict v = st.v.data();
  Quat* __restrict q = st.q.data();
  const Vec3* __restrict w = st.omega.data();
  for (int i = 0; i < md.n; ++i) x[i] += dt * v[i];
  for (int j = 0; j < md.m; ++j) q[j] = integrate_rotation(q[j], w[j], dt);
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

}  // namespace vcsim
