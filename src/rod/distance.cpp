// Distance constraints |x_{j+1} - x_j| = l_j at the velocity level, evaluated at the predicted
// positions p = x + dt v so that one iteration is one Newton step on the nonlinear chain
// (physics.md section 4). Global: the tridiagonal system J W J^T dlambda = -C / dt solved
// directly; local: Gauss-Seidel or Jacobi sweeps over the same constraints.
#include "distance.h"

#include <cmath>

#include "kernels.h"

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

VCSIM_SIMD_CLONES bool distance_global(const RodModel& md, double dt, std::span<const Vec3> xs,
                                       std::span<Vec3> vs, RodWorkspace& ws) {
  const int n = md.n, m = md.m;  // locals: loop bounds must not be re-read after stores
  // Plain arrays and `ivdep` so that the loops vectorise (see rod_step.cpp); each element sees
  // the same operations in the same order as the Vec3 expressions they replace.
  const double* __restrict w = ws.inv_mass.data();
  const double* __restrict rest = md.rest_length.data();
  const double* __restrict X = xs[0].data();
  double* __restrict V = vs[0].data();
  double* __restrict P = ws.pred[0].data();  // predicted positions, then the impulses
  double* __restrict D = ws.dir[0].data();
  double* __restrict diag = ws.diag.data();
  double* __restrict off = ws.offdiag.data();
  double* __restrict rhs = ws.rhs.data();
  double* __restrict NI = ws.node_impulse[0].data();
#pragma GCC ivdep
  for (int i = 0; i < 3 * n; ++i) P[i] = X[i] + dt * V[i];
  const double inv_dt = 1.0 / dt;
  // C_j at the predicted positions, n_j, and the diagonal A_jj = w_j + w_{j+1}.
#pragma GCC ivdep
  for (int j = 0; j < m; ++j) {
    const double ex = P[3 * j + 3] - P[3 * j], ey = P[3 * j + 4] - P[3 * j + 1],
                 ez = P[3 * j + 5] - P[3 * j + 2];
    const double len = std::sqrt(ex * ex + ey * ey + ez * ez);
    const double inv_len = 1.0 / len;
    D[3 * j] = ex * inv_len;
    D[3 * j + 1] = ey * inv_len;
    D[3 * j + 2] = ez * inv_len;
    rhs[j] = (rest[j] - len) * inv_dt;
    diag[j] = (w[j] + w[j + 1]) * (1.0 + kRegularisation);
  }
  // A constraint between two held nodes cannot act (a rare case: a scalar pass keeps the loop
  // above free of branches).
  for (int j = 0; j < m; ++j) {
    if (w[j] + w[j + 1] == 0.0) {
      diag[j] = 1.0 * (1.0 + kRegularisation);
      rhs[j] = 0.0;
    }
  }
  // A_{j,j+1} = -w_{j+1} n_j . n_{j+1}.
#pragma GCC ivdep
  for (int j = 0; j + 1 < m; ++j) {
    off[j] = -w[j + 1] *
             (D[3 * j] * D[3 * j + 3] + D[3 * j + 1] * D[3 * j + 4] + D[3 * j + 2] * D[3 * j + 5]);
  }
  int info = 0;
  const int nrhs = 1;
  dpttrf_(&m, diag, off, &info);
  if (info != 0) return false;
  dpttrs_(&m, &nrhs, diag, off, rhs, &m, &info);
  if (info != 0) return false;
  // dv = W J^T lambda: node k gets w_k (n_{k-1} lambda_{k-1} - n_k lambda_k), added in that
  // order. The impulses lambda_j n_j first, then one pass over the nodes.
  double* __restrict imp = P;
#pragma GCC ivdep
  for (int j = 0; j < m; ++j) {
    imp[3 * j] = rhs[j] * D[3 * j];
    imp[3 * j + 1] = rhs[j] * D[3 * j + 1];
    imp[3 * j + 2] = rhs[j] * D[3 * j + 2];
  }
  for (int c = 0; c < 3; ++c) {
    V[c] -= w[0] * imp[c];
    NI[c] -= imp[c];
  }
#pragma GCC ivdep
  for (int k = 1; k < m; ++k) {
    for (int c = 0; c < 3; ++c) {
      const double a = imp[3 * k - 3 + c], b = imp[3 * k + c];
      V[3 * k + c] = (V[3 * k + c] + w[k] * a) - w[k] * b;
      NI[3 * k + c] = (NI[3 * k + c] + a) - b;
    }
  }
  for (int c = 0; c < 3; ++c) {
    V[3 * m + c] += w[m] * imp[3 * m - 3 + c];
    NI[3 * m + c] += imp[3 * m - 3 + c];
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
