// Force and torque at the hand (physics.md 6.1).
#include "scratch.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

namespace vcsim::internal {

namespace {

// Below this sliding speed (m/s) Coulomb friction is regularised: mu N v_t / kSlipSpeed. It picks
// the sliding direction of a quasi-static rod; the hand moves 5 to 300 mm/s when it moves at all.
constexpr double kSlipSpeed = 1e-3;
// Weight of the step's own (mass-scaled) reaction where the rod's shape does not decide a
// reaction: a wall across the rod's axis (a dead end), where an inextensible rod can carry any
// compression. Against |d_perp|^2 ~ 1 for a wall beside the rod it changes that reaction by 1 %.
constexpr double kIndeterminateWeight = 1e-2;
// An edge stretched or compressed beyond this is a violated distance constraint (the global solve
// keeps edges within 0.5 %; the default run's first free edge reaches 15 % while a wire is pulled
// out fast, a straight rod crammed into a dead end 57 %): its direction cannot decide a reaction.
constexpr double kMaxStrain = 0.05;

// The shear force edge j carries onto its first node in a rod whose frames have negligible
// inertia: frame j's torque balance, G_{j+1} - G_j + tau_ext_j + e_j x P_j = 0 (the parallel
// penalty's torque on the frame is e x P, its forces on the nodes being the couple P, -P), gives
// the part of P_j across the edge, t x (G_{j+1} - G_j + tau_ext_j) / |e_j| (physics.md 6.1). The
// penalty's own P_j differs from it by the frame's (scaled) angular inertia over |e_j|. This
// returns G_{j+1} - G_j + tau_ext_j; `g_next` holds G_{j+1} on entry and G_j on return.
Vec3 moment_change(const RodModel& md, const RodState& st, int j, Vec3& g_next) {
  const Vec3 g = vertex_moment(md, st, j);
  const Vec3 change = g_next - g + st.tau_ext[j];
  g_next = g;
  return change;
}

// Loads as the step applied them: wall contact impulses less the penetration fix-up, coupling
// impulses less their violation fix-up, applied loads and gravity (SolverSettings::HandForce::
// kImpulses), summed: in equilibrium, the force the inserted part exerts across the boundary.
Vec3 impulse_loads(const Inst& in, const SolverSettings& set, bool coupled) {
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  const double dt = set.rod.dt;
  Vec3 f = Vec3::Zero();
  for (const NodeContact& c : in.w->contacts)
    f += ((c.lambda_n - c.lambda_bias) * c.normal + c.lambda_t) / dt;
  for (const NodeContact& c : in.w->edge_contacts)
    f += ((c.lambda_n - c.lambda_bias) * c.normal + c.lambda_t) / dt;
  if (coupled)
    for (int i = 0; i < md.n; ++i) f += in.w->coupling_impulse[i] / dt;
  // Applied loads one by one; gravity through the free part's mass. The loops skip what adds
  // nothing: in the compression experiment they cost as much as the rod's position update.
  for (int i = in.drive().first_free; i < md.n; ++i)
    if (st.f_ext[i] != Vec3::Zero()) f += st.f_ext[i];
  if (set.rod.gravity != Vec3::Zero()) {
    double mass = 0.0;
    for (int i = in.drive().first_free; i < md.n; ++i) mass += md.node_mass[i];
    f += mass * set.rod.gravity;
  }
  return f;
}

// The reactions s_k >= 0 along d_k (k < n, n <= 2) that leave r + sum s_k d_k closest to the
// edge's direction t: least squares of |r_perp + sum s_k d_k,perp|^2, leaning by
// kIndeterminateWeight on each contact's own reaction where d lies along the edge (a dead end's
// cap) and the shape cannot decide.
template <class Candidates>
void solve_reactions(const Vec3& r_perp, const Vec3& t, const Candidates& c, int n,
                     std::array<double, 2>& s) {
  constexpr double w = kIndeterminateWeight;
  std::array<Vec3, 2> dp;
  for (int k = 0; k < n; ++k) dp[k] = c[k].d - c[k].d.dot(t) * t;
  // One reaction alone (the other held at zero).
  auto single = [&](int k) {
    return std::max(0.0, (w * c[k].heavy - r_perp.dot(dp[k])) / (dp[k].squaredNorm() + w));
  };
  if (n == 1) {
    s[0] = single(0);
    return;
  }
  // Both: the 2 x 2 normal equations; if either comes out negative, the better of the two alone.
  const double a00 = dp[0].squaredNorm() + w, a11 = dp[1].squaredNorm() + w;
  const double a01 = dp[0].dot(dp[1]);
  const double b0 = w * c[0].heavy - r_perp.dot(dp[0]), b1 = w * c[1].heavy - r_perp.dot(dp[1]);
  const double det = a00 * a11 - a01 * a01;
  if (det > 0.0) {
    const double s0 = (b0 * a11 - b1 * a01) / det, s1 = (a00 * b1 - a01 * b0) / det;
    if (s0 >= 0.0 && s1 >= 0.0) {
      s = {s0, s1};
      return;
    }
  }
  auto cost = [&](double s0, double s1) {
    return (r_perp + s0 * dp[0] + s1 * dp[1]).squaredNorm() +
           w * ((s0 - c[0].heavy) * (s0 - c[0].heavy) + (s1 - c[1].heavy) * (s1 - c[1].heavy));
  };
  const double only0 = single(0), only1 = single(1);
  if (cost(only0, 0.0) <= cost(0.0, only1)) {
    s = {only0, 0.0};
  } else {
    s = {0.0, only1};
  }
}

// The reactions a rod of negligible mass would need in this step's shape, walked from the tip to
// the hand (physics.md 6.1, "the quasi-static hand force"). Edge j's internal force on its first
// node is Q_j = T_j t_j + P_j: a tension along the edge and the parallel penalty's shear P_j, which
// the shape decides. Node i's balance without inertia gives Q_{i-1} = Q_i + loads_i + R_i. A wall
// or lumen reaction R_i = s d (d: the normal less mu times the regularised sliding direction) takes
// the s >= 0 that leaves Q_{i-1} - P_{i-1} closest to edge i-1's direction (a tension); what no
// reaction can balance stays in Q, so the result is the sum of the loads and these reactions, the
// boundary force of the part in equilibrium. Gaps the step did not close get no reaction.
// `self`: this rod's index; the couplings holding it in other rods' lumens are those of
// `couplings` whose inner it is (an outer parked is skipped); each outer rod receives the
// reactions as loads (InstrumentScratch::felt_load). An inflated balloon's contacts
// (NodeContact::preload) are anchored by friction the shape cannot decide: their own friction
// reaction is a load. Returns Q at the boundary edge, the force the inserted part exerts on the
// held part.
Vec3 quasi_static_force(std::span<Inst> insts, std::size_t self, std::span<const Pair> couplings,
                        const SolverSettings& set) {
  const Inst& in = insts[self];
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  InstrumentScratch& w = *in.w;
  const double dt = set.rod.dt;
  std::fill(w.wall_contact_of.begin(), w.wall_contact_of.end(), -1);
  std::fill(w.wall_contact2_of.begin(), w.wall_contact2_of.end(), -1);
  for (int k = 0; k < static_cast<int>(w.contacts.size()); ++k) {
    int& first = w.wall_contact_of[w.contacts[k].node];
    (first < 0 ? first : w.wall_contact2_of[w.contacts[k].node]) = k;
  }
  // The edges' wall contacts (physics.md 6.3), each a reaction candidate of the nearer of its two
  // nodes (the one pressing hardest where several share a node).
  std::fill(w.edge_contact_of.begin(), w.edge_contact_of.end(), -1);
  for (int k = 0; k < static_cast<int>(w.edge_contacts.size()); ++k) {
    const NodeContact& c = w.edge_contacts[k];
    int& of = w.edge_contact_of[c.along < 0.5 ? c.node : c.node + 1];
    if (of < 0 || w.edge_contacts[of].lambda_n < c.lambda_n) of = k;
  }
  std::fill(w.coupling_of.begin(), w.coupling_of.end(), -1);
  std::fill(w.rim_of.begin(), w.rim_of.end(), -1);
  for (std::size_t pi = 0; pi < couplings.size(); ++pi) {
    const Pair& pair = couplings[pi];
    if (static_cast<std::size_t>(pair.cm->inner) != self || insts[pair.cm->outer].parked())
      continue;
    const std::vector<CoaxialContact>& coax = pair.s->contacts;
    for (int k = 0; k < static_cast<int>(coax.size()); ++k) {
      const bool rim = coax[k].a > 0.0;
      (rim ? w.rim_of : w.coupling_of)[coax[k].node] = k;
      (rim ? w.rim_pair : w.coupling_pair)[coax[k].node] = static_cast<int>(pi);
    }
  }
  // A reaction candidate: direction d (the normal less mu times the regularised sliding
  // direction), the step's own normal reaction (N), and the lumen or rim contact it belongs to.
  struct Candidate {
    Vec3 d;
    double heavy;
    const CoaxialContact* cc;
    const Inst* outer;
  };
  auto make = [&](const Vec3& n, const Vec3& v_rel, double mu, double heavy,
                  const CoaxialContact* cc, const Inst* outer) {
    const Vec3 vt = v_rel - v_rel.dot(n) * n;
    return Candidate{n - (mu / std::max(vt.norm(), kSlipSpeed)) * vt, heavy, cc, outer};
  };
  // A lumen or rim contact of coupling `pi`; false for a gap the step did not close.
  auto coaxial = [&](int pi, int k, Candidate& out) {
    const Pair& pair = couplings[static_cast<std::size_t>(pi)];
    const CoaxialContact& c = pair.s->contacts[static_cast<std::size_t>(k)];
    if (c.lambda_n <= 0.0) return false;
    const Inst* outer = &insts[pair.cm->outer];
    Vec3 v_in = st.v[c.node];
    if (c.a > 0.0) v_in = (1 - c.a) * v_in + c.a * st.v[c.node + 1];
    const Vec3 v_out = (1 - c.t) * outer->rod().v[c.segment] + c.t * outer->rod().v[c.segment + 1];
    // The catheter pushes the wire back toward its centreline (or off its rim).
    out = make(-c.normal, v_in - v_out, pair.cm->mu, c.lambda_n / dt, &c, outer);
    return true;
  };
  // A wall contact of node i as a reaction candidate; none for a gap the step did not close.
  auto wall_candidate = [&](int i, int wc, std::array<Candidate, 2>& out, int& k) {
    const NodeContact& c = w.contacts[wc];
    if (c.lambda_n > 0.0 || c.depth > 0.0)
      out[k++] = make(c.normal, st.v[i] - c.wall_velocity,
                      c.preload > 0.0 ? 0.0 : in.im->contact.mu_dynamic,
                      (c.lambda_n - c.lambda_bias) / dt, nullptr, nullptr);
  };
  // Node i's reactions (at most two): its wall contacts (a second where it slid round a bend onto
  // another face, catch_late_movers) or its lumen contact, and the rim's where edge i leaves the
  // outer instrument (all of the rim's reaction lies beyond edge i - 1, so node i's balance
  // decides it).
  auto candidates_of = [&](int i, std::array<Candidate, 2>& out) {
    int k = 0;
    if (const int wc = w.wall_contact_of[i]; wc >= 0) {
      wall_candidate(i, wc, out, k);
      if (const int wc2 = w.wall_contact2_of[i]; wc2 >= 0) wall_candidate(i, wc2, out, k);
    } else if (const int c = w.coupling_of[i]; c >= 0 && coaxial(w.coupling_pair[i], c, out[k])) {
      ++k;
    }
    if (const int r = w.rim_of[i]; r >= 0 && k < 2 && coaxial(w.rim_pair[i], r, out[k])) ++k;
    if (const int e = w.edge_contact_of[i]; e >= 0 && k < 2) {
      const NodeContact& c = w.edge_contacts[e];
      const Vec3 v = (1.0 - c.along) * st.v[c.node] + c.along * st.v[c.node + 1];
      if (c.lambda_n > 0.0 || c.depth > 0.0)
        out[k++] = make(c.normal, v - c.wall_velocity, in.im->contact.mu_dynamic,
                        (c.lambda_n - c.lambda_bias) / dt, nullptr, nullptr);
    }
    return k;
  };
  Vec3 q = Vec3::Zero();  // Q_i: the internal force of the edge distal to node i (none at the tip)
  const int first = std::max(1, in.drive().first_free);
  // G at vertex g_at (the distal vertex of the last edge that needed it): the moments are taken
  // only at the nodes with a reaction candidate and their neighbours, most free nodes having none.
  Vec3 g = Vec3::Zero();
  int g_at = -1;
  std::array<Candidate, 2> cand;
  std::array<double, 2> s{};
  for (int i = md.n - 1; i >= first; --i) {
    q += st.f_ext[i] + md.node_mass[i] * set.rod.gravity + w.felt_load[i];
    // An anchored balloon's friction on the wall, as the step applied it.
    if (const int wc = w.wall_contact_of[i]; wc >= 0 && w.contacts[wc].preload > 0.0)
      q += w.contacts[wc].lambda_t / dt;
    const Vec3 e = st.x[i] - st.x[i - 1];
    const double len = e.norm();
    if (len < 1e-12) continue;
    const int nc = candidates_of(i, cand);
    if (nc == 0) continue;
    if (g_at != i) g = vertex_moment(md, st, i);
    const Vec3 dg = moment_change(md, st, i - 1, g);
    g_at = i - 1;
    if (std::abs(len / md.rest_length[i - 1] - 1.0) > kMaxStrain) {
      // A violated edge: its direction is not a rod's. A lumen or rim reaction there is the
      // coupling repairing the violation, a position fix-up that is not felt (as before, c_fix).
      // A wall's is decided as elsewhere, with frame i - 1's director and the edge's rest length
      // standing in for the edge's direction and length: a crammed dead end is still felt (its
      // cap lies across the director, where the step's own reaction decides), and the tip of a
      // wire rammed into a wall by its scaled inertia is not (its step's reaction read up to
      // 12.7 N in the default run, a one-step spike of 3.5 N at the hand).
      const Vec3 t = st.q[i - 1] * Vec3::UnitZ();
      const Vec3 shear = t.cross(dg) / md.rest_length[i - 1];
      const Vec3 r_perp = (q - shear) - (q - shear).dot(t) * t;
      std::array<Candidate, 2> wall;
      int nw = 0;
      for (int k = 0; k < nc; ++k)
        if (!cand[k].cc) wall[nw++] = cand[k];
      std::array<double, 2> sw{};
      if (nw > 0) solve_reactions(r_perp, t, wall, nw, sw);
      for (int k = 0, kw = 0; k < nc; ++k) s[k] = cand[k].cc ? 0.0 : sw[kw++];
    } else {
      const Vec3 t = e / len;
      const Vec3 shear = t.cross(dg) / len;
      const Vec3 r_perp = (q - shear) - (q - shear).dot(t) * t;
      solve_reactions(r_perp, t, cand, nc, s);
    }
    for (int k = 0; k < nc; ++k) {
      const Vec3 reaction = s[k] * cand[k].d;
      q += reaction;
      if (const CoaxialContact* c = cand[k].cc) {
        cand[k].outer->w->felt_load[c->segment] -= (1 - c->t) * reaction;
        cand[k].outer->w->felt_load[c->segment + 1] -= c->t * reaction;
      }
    }
  }
  // Reactions of inner instruments on the held part (a wire near the access point).
  for (int i = 0; i < first; ++i) q += w.felt_load[i];
  return q;
}

// The twisting moment of the rod at the boundary vertex between the last held frame and the first
// free one (physics.md eq. 5, K3 (Omega_3 - Omega0_3)): what a torque sensor at the hub reads. > 0
// when the inserted part lags behind a positive roll of the hand.
double hub_twist_moment(const Inst& in) {
  const RodModel& md = in.model();
  const int k = std::clamp(in.drive().first_free - 1, 1, md.m - 1);
  const Vec3 w = darboux(in.rod().q[k - 1], in.rod().q[k], md.vertex_length[k]);
  return -md.vertex_stiffness[k].z() * (w.z() - md.rest_darboux[k].z());
}

void publish(const Inst& in, const SolverSettings& set, double force, double torque) {
  DriveState& dr = in.drive();
  dr.axial_force_raw = force;
  dr.torque_raw = torque;
  if (set.feedback_cutoff_hz > 0.0 && in.rod().steps > 0) {
    // y += (1 - exp(-2 pi fc dt)) (x - y): the exact step response of a first-order filter.
    const double g = 1.0 - std::exp(-2.0 * std::numbers::pi * set.feedback_cutoff_hz * set.rod.dt);
    dr.axial_force += g * (dr.axial_force_raw - dr.axial_force);
    dr.torque += g * (dr.torque_raw - dr.torque);
  } else {
    dr.axial_force = dr.axial_force_raw;
    dr.torque = dr.torque_raw;
  }
}

}  // namespace

void hand_feedback(std::span<Inst> insts, std::span<const Pair> couplings,
                   const SolverSettings& set) {
  if (set.hand_force == SolverSettings::HandForce::kImpulses) {
    for (const Inst& in : insts) {
      if (in.parked() || !in.driven()) continue;
      // The hand holds the rod against these loads: > 0 when they push the rod back out.
      publish(in, set,
              -impulse_loads(in, set, !couplings.empty()).dot(in.im->sheath.frame * Vec3::UnitZ()),
              hub_twist_moment(in));
    }
    return;
  }
  // Inner instruments first: an outer one feels their reactions. Nesting is a chain of a few
  // instruments, so a pass per level is enough.
  constexpr std::size_t kMax = 64;
  std::array<bool, kMax> done{};
  const std::size_t n = std::min(insts.size(), kMax);
  for (std::size_t k = 0; k < n; ++k) {
    std::fill(insts[k].w->felt_load.begin(), insts[k].w->felt_load.end(), Vec3::Zero());
    done[k] = insts[k].parked() || !insts[k].driven();
  }
  for (std::size_t pass = 0; pass < n; ++pass) {
    bool progress = false;
    for (std::size_t k = 0; k < n; ++k) {
      if (done[k]) continue;
      bool ready = true;
      for (const Pair& c : couplings) {
        const auto inner = static_cast<std::size_t>(c.cm->inner);
        if (static_cast<std::size_t>(c.cm->outer) == k && (inner >= n || !done[inner]))
          ready = false;
      }
      if (!ready) continue;
      const Inst& in = insts[k];
      const Vec3 f = quasi_static_force(insts, k, couplings, set);
      // > 0 when the inserted part pushes the rod back out.
      publish(in, set, -f.dot(in.im->sheath.frame * Vec3::UnitZ()), hub_twist_moment(in));
      done[k] = true;
      progress = true;
    }
    if (!progress) break;
  }
}

}  // namespace vcsim::internal
