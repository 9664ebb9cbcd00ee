// Linearly implicit Euler for the rod's elastic forces (physics.md 5.5).
//
// Unknowns per node-and-frame pair p: node p's velocity (world) and frame p's angular velocity
// (body), u_p = (v_p, omega_p); the last node has no frame, its rotational rows are identity. The
// generalised forces are the node force and the frame torque in body coordinates, and a frame is
// displaced by q <- q exp(theta) (body), as the position update turns it. One Newton step of
// backward Euler is
//
//     (M + dt^2 H) du = dt (f - dt H u)
//
// with M the nodes' masses and the frames' principal inertias (times 1 + drag dt for the
// mass-proportional drags) and H the Gauss-Newton Hessian of the elastic energy: for each edge's
// parallel penalty E = K_p l / 2 |r|^2, r = u - (u . d3) d3, H = K_p l J^T J over (x_j, x_j+1,
// theta_j); for each vertex's bending and twisting E = l_v / 2 (Omega - Omega0)^T K (...),
// H = l_v J^T K J over (theta_a, theta_b). H is positive semi-definite by construction (it leaves
// out the geometric terms, which make the exact Hessian indefinite when a rod is compressed), so
// M + dt^2 H stays positive definite at any step and with any mass. Forces on pair r come from
// pairs r - 1 .. r + 1 only: a symmetric block-tridiagonal system with 6 x 6 blocks, solved by
// block Cholesky elimination. Held nodes and prescribed frames keep their velocities.

#include "kernels.h"
#include "vcsim/rod.h"

namespace vcsim {

namespace {

using Mat6 = RodWorkspace::Mat6;
using Vec6 = RodWorkspace::Vec6;

// Generalised force of pair p from the workspace's forces: node force (world), frame torque
// (body).
Vec6 pair_force(const RodModel& md, const RodState& st, const RodWorkspace& ws, int p) {
  Vec6 f = Vec6::Zero();
  f.head<3>() = ws.force[p];
  if (p < md.m) f.tail<3>() = st.q[p].conjugate() * ws.torque[p];
  return f;
}

// [v]x, the cross-product matrix: [v]x w = v x w.
Mat3 skew(const Vec3& v) {
  Mat3 m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

Vec6 pair_velocity(const RodModel& md, const RodState& st, int p) {
  Vec6 u = Vec6::Zero();
  u.head<3>() = st.v[p];
  if (p < md.m) u.tail<3>() = st.omega[p];
  return u;
}

void size_implicit(const RodModel& md, RodWorkspace& ws) {
  const auto n = static_cast<std::size_t>(md.n);
  if (ws.imp_diag.size() == n) return;
  ws.imp_diag.assign(n, Mat6::Zero());
  ws.imp_upper.assign(n, Mat6::Zero());
  // Constructed in place: copying an LLT that has not factored anything reads its unset state.
  ws.imp_llt.clear();
  ws.imp_llt.resize(n);
  ws.imp_force.assign(n, Vec6::Zero());
  ws.imp_rhs.assign(n, Vec6::Zero());
}

}  // namespace

namespace internal {

void implicit_velocities(const RodModel& md, const RodSettings& s, RodState& st, RodWorkspace& ws) {
  size_implicit(md, ws);
  const int n = md.n, m = md.m;
  const double dt = s.dt;
  // The forces at the step's start (rod_forces ran before) and the Gauss-Newton Hessian.
  for (int p = 0; p < n; ++p) {
    ws.imp_force[p] = pair_force(md, st, ws, p);
    ws.imp_diag[p].setZero();
    ws.imp_upper[p].setZero();
  }
  // Parallel penalty of edge j: J = [-P / l, P / l, (d3 u^T + (u . d3) I) [d3]x R_j] with
  // P = I - d3 d3^T, over (x_j, x_j+1, theta_j).
  for (int j = 0; j < m; ++j) {
    const double l = md.rest_length[j];
    const Mat3 R = st.q[j].toRotationMatrix();
    const Vec3 d3 = R.col(2);
    const Vec3 u = (st.x[j + 1] - st.x[j]) / l;
    const Mat3 P = Mat3::Identity() - d3 * d3.transpose();
    const Mat3 jt = (d3 * u.transpose() + u.dot(d3) * Mat3::Identity()) * skew(d3) * R;
    const Mat3 jx = P / l;  // d r / d x_j+1 (and minus it for x_j)
    const double w = md.kp[j] * l;
    const Mat3 hxx = w * jx.transpose() * jx;
    const Mat3 hxt = w * jx.transpose() * jt;  // x_j+1 against theta_j
    const Mat3 htt = w * jt.transpose() * jt;
    Mat6& dj = ws.imp_diag[j];
    dj.topLeftCorner<3, 3>() += hxx;
    dj.topRightCorner<3, 3>() -= hxt;
    dj.bottomLeftCorner<3, 3>() -= hxt.transpose();
    dj.bottomRightCorner<3, 3>() += htt;
    ws.imp_diag[j + 1].topLeftCorner<3, 3>() += hxx;
    // Row pair j against column pair j + 1 (x_j+1), and its transpose.
    ws.imp_upper[j].topLeftCorner<3, 3>() -= hxx;
    ws.imp_upper[j].bottomLeftCorner<3, 3>() += hxt.transpose();
  }
  // Bending and twisting at vertex k between frames a = k - 1 and b = k, r = conj(q_a) q_b:
  // d Omega = (1 / l_v) (-(r_w I - [r_v]x) theta_a + (r_w I + [r_v]x) theta_b). At a clamped end
  // the clamp's frame takes the missing side and does not move.
  for (int k = 0; k <= m; ++k) {
    if (!md.vertex_active[k]) continue;
    const Quat& qa = k > 0 ? st.q[k - 1] : st.base_frame;
    const Quat& qb = k < m ? st.q[k] : st.tip_frame;
    const Quat r = relative_rotation(qa, qb);
    const Mat3 rvx = skew(r.vec());
    const double lv = md.vertex_length[k];
    const Mat3 ja = -(r.w() * Mat3::Identity() - rvx) / lv;
    const Mat3 jb = (r.w() * Mat3::Identity() + rvx) / lv;
    const Mat3 kd = md.vertex_stiffness[k].asDiagonal();
    if (k > 0) ws.imp_diag[k - 1].bottomRightCorner<3, 3>() += lv * ja.transpose() * kd * ja;
    if (k < m) ws.imp_diag[k].bottomRightCorner<3, 3>() += lv * jb.transpose() * kd * jb;
    if (k > 0 && k < m) {
      const Mat3 hab = lv * ja.transpose() * kd * jb;
      ws.imp_upper[k - 1].bottomRightCorner<3, 3>() += hab;
    }
  }
  // Right-hand side dt (f - dt H u), then A = M + dt^2 H (symmetric: the block below the
  // diagonal of row r is imp_upper[r - 1]^T).
  for (int r = 0; r < n; ++r) {
    Vec6 hu = ws.imp_diag[r] * pair_velocity(md, st, r);
    if (r > 0) hu += ws.imp_upper[r - 1].transpose() * pair_velocity(md, st, r - 1);
    if (r + 1 < n) hu += ws.imp_upper[r] * pair_velocity(md, st, r + 1);
    ws.imp_rhs[r] = dt * (ws.imp_force[r] - dt * hu);
  }
  for (int r = 0; r < n; ++r) {
    ws.imp_diag[r] *= dt * dt;
    ws.imp_upper[r] *= dt * dt;
    const double node_mass = md.node_mass[r] * (1.0 + s.drag * dt);
    for (int k = 0; k < 3; ++k) ws.imp_diag[r](k, k) += node_mass;
    if (r < m) {
      for (int k = 0; k < 3; ++k)
        ws.imp_diag[r](3 + k, 3 + k) += md.inertia[r][k] * (1.0 + s.angular_drag * dt);
    }
    // A held node or prescribed frame keeps its velocity (du = 0): its row and column leave the
    // system, which stays symmetric; its motion is already in the right-hand side through H u.
    auto hold = [&](int k0) {
      for (int k = k0; k < k0 + 3; ++k) {
        ws.imp_diag[r].row(k).setZero();
        ws.imp_diag[r].col(k).setZero();
        ws.imp_upper[r].row(k).setZero();
        if (r > 0) ws.imp_upper[r - 1].col(k).setZero();
        ws.imp_diag[r](k, k) = 1.0;
        ws.imp_rhs[r][k] = 0.0;
      }
    };
    if (ws.inv_mass[r] == 0.0) hold(0);
    if (r >= m || ws.frame_free[r] == 0.0) hold(3);
  }
  // Block Cholesky elimination: D_r -= U_r-1^T D_r-1^-1 U_r-1, then back substitution.
  ws.imp_llt[0].compute(ws.imp_diag[0]);
  for (int r = 1; r < n; ++r) {
    const Mat6 x = ws.imp_llt[r - 1].solve(ws.imp_upper[r - 1]);
    ws.imp_diag[r] -= ws.imp_upper[r - 1].transpose() * x;
    ws.imp_rhs[r] -= x.transpose() * ws.imp_rhs[r - 1];
    ws.imp_llt[r].compute(ws.imp_diag[r]);
  }
  ws.imp_rhs[n - 1] = ws.imp_llt[n - 1].solve(ws.imp_rhs[n - 1]);
  for (int r = n - 2; r >= 0; --r)
    ws.imp_rhs[r] = ws.imp_llt[r].solve(ws.imp_rhs[r] - ws.imp_upper[r] * ws.imp_rhs[r + 1]);
  for (int r = 0; r < n; ++r) {
    if (ws.inv_mass[r] != 0.0) st.v[r] += ws.imp_rhs[r].head<3>();
    if (r < m && ws.frame_free[r] != 0.0) st.omega[r] += ws.imp_rhs[r].tail<3>();
  }
}

}  // namespace internal

}  // namespace vcsim
