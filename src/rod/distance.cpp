// Distance constraints |x_{j+1} - x_j| = l_j at the velocity level, evaluated at the predicted
// positions p = x + dt v so that one iteration is one Newton step on the nonlinear chain
// (physics.md section 4). Global: the tridiagonal system J W J^T dlambda = -C / dt solved
// directly; local: Gauss-Seidel or Jacobi sweeps over the same constraints.
#include "distance.h"

#include <cmath>

extern "C" {
// LAPACK: factor and solve a symmetric positive definite tridiagonal system.
void dpttrf_(const int* n, double* d, double* e, int* info);
void dpttrs_(const int* n, const int* nrhs, const double* d, const double* e, double* b,
             const int* ldb, int* info);
}

namespace vcsim::internal {

namespace {
// Relative regularisation of the diagonal: keeps the system definite when the chain's length
// is fixed by two held ends (a straight chain between two held nodes has a null direction).
constexpr double kRegularisation = 1e-10;

inline double constraint_at(const Vec3& xa, const Vec3& va, const Vec3& xb, const Vec3& vb,
                            double dt, double rest, Vec3& dir) {
  const Vec3 e = (xb + dt * vb) - (xa + dt * va);
  const double len = e.norm();
  dir = e / len;
  return len - rest;
}
}  // namespace

bool distance_global(const RodModel& md, double dt, std::span<const Vec3> xs, std::span<Vec3> vs,
                     RodWorkspace& ws) {
  const int m = md.m;
  // Raw pointers (see rod_step.cpp: SIMD stores would force address reloads).
  const double* __restrict w = ws.inv_mass.data();
  const double* __restrict rest = md.rest_length.data();
  const Vec3* __restrict x = xs.data();
  Vec3* __restrict v = vs.data();
  Vec3* __restrict p = ws.pred.data();
  Vec3* __restrict dir = ws.dir.data();
  double* __restrict diag = ws.diag.data();
  double* __restrict off = ws.offdiag.data();
  double* __restrict rhs = ws.rhs.data();
  for (int i = 0; i < md.n; ++i) p[i] = x[i] + dt * v[i];
  const double inv_dt = 1.0 / dt;
  // C_j at the predicted positions, n_j, and the diagonal A_jj = w_j + w_{j+1}.
  for (int j = 0; j < m; ++j) {
    const Vec3 e = p[j + 1] - p[j];
    const double len = std::sqrt(e.squaredNorm());
    dir[j] = e * (1.0 / len);
    rhs[j] = (rest[j] - len) * inv_dt;
    double d = w[j] + w[j + 1];
    if (d == 0.0) {  // both ends held: the constraint cannot act
      d = 1.0;
      rhs[j] = 0.0;
    }
    diag[j] = d * (1.0 + kRegularisation);
  }
  // A_{j,j+1} = -w_{j+1} n_j . n_{j+1}.
  for (int j = 0; j + 1 < m; ++j) off[j] = -w[j + 1] * dir[j].dot(dir[j + 1]);
  int info = 0;
  const int nrhs = 1;
  dpttrf_(&m, diag, off, &info);
  if (info != 0) return false;
  dpttrs_(&m, &nrhs, diag, off, rhs, &m, &info);
  if (info != 0) return false;
  // dv = W J^T lambda: node k gets w_k (n_{k-1} lambda_{k-1} - n_k lambda_k).
  Vec3* __restrict node_imp = ws.node_impulse.data();
  for (int j = 0; j < m; ++j) {
    const Vec3 imp = rhs[j] * dir[j];
    v[j] -= w[j] * imp;
    v[j + 1] += w[j + 1] * imp;
    node_imp[j] -= imp;
    node_imp[j + 1] += imp;
  }
  return true;
}

namespace {
// One local sweep: each constraint projected on its own from the current velocities `v`, its
// correction written to `out`. out == v is Gauss-Seidel (seen by the next constraint at once);
// out == a separate accumulator is Jacobi (all constraints see the same velocities).
void local_sweep(const RodModel& md, double dt, std::span<const Vec3> x, std::span<const Vec3> v,
                 Vec3* out, RodWorkspace& ws) {
  const double* w = ws.inv_mass.data();
  for (int j = 0; j < md.m; ++j) {
    const double ws_sum = w[j] + w[j + 1];
    if (ws_sum == 0.0) continue;
    Vec3& n = ws.dir[j];
    const double c = constraint_at(x[j], v[j], x[j + 1], v[j + 1], dt, md.rest_length[j], n);
    const double lambda = -c / (dt * ws_sum);
    out[j] -= w[j] * lambda * n;
    out[j + 1] += w[j + 1] * lambda * n;
    ws.node_impulse[j] -= lambda * n;
    ws.node_impulse[j + 1] += lambda * n;
  }
}
}  // namespace

void distance_local_gs(const RodModel& md, double dt, std::span<const Vec3> x, std::span<Vec3> v,
                       RodWorkspace& ws) {
  local_sweep(md, dt, x, v, v.data(), ws);
}

void distance_local_jacobi(const RodModel& md, double dt, std::span<const Vec3> x,
                           std::span<Vec3> v, RodWorkspace& ws) {
  for (int i = 0; i < md.n; ++i) ws.dv[i].setZero();
  local_sweep(md, dt, x, v, ws.dv.data(), ws);
  // Each node averages the corrections of its (one or two) constraints: plain summation
  // overshoots by up to a factor of two and diverges at one iteration (cf. Mueller et al.'s
  // position-based dynamics, constraint averaging).
  v[0] += ws.dv[0];
  for (int i = 1; i + 1 < md.n; ++i) v[i] += 0.5 * ws.dv[i];
  v[md.n - 1] += ws.dv[md.n - 1];
}

}  // namespace vcsim::internal
