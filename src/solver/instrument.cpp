// One fine step of instruments driven through a sheath into a lumen: the insertion drive,
// collision detection with per-node coherence, contacts with Coulomb friction and the coaxial
// coupling inside the block iterations (physics.md section 6; docs/architecture.md "The
// instrument step").
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>

#include "scratch.h"
#include "tsan_tasks.h"

namespace vcsim::internal {

namespace {

double clamp_abs(double v, double limit) {
  return std::clamp(v, -limit, limit);
}

// Node radius: the largest outer radius of the adjacent edges.
double node_radius(const RodModel& md, int i) {
  const double a = i > 0 ? md.outer_radius[i - 1] : 0.0;
  const double b = i < md.m ? md.outer_radius[i] : 0.0;
  return std::max(a, b);
}

// --- insertion drive ---------------------------------------------------------------------------

// The farthest a node taken into the hand moves to its place on the axis in one step, beyond the
// hand's own motion (m). A node taken in its place moves some micrometres; one a folded rod
// brings moves there over several steps.
constexpr double kFoldedBack = 1e-3;

// Advances depth and roll from the command and holds every node outside the body on the sheath
// axis: node i (arc length s_i from the proximal end) is outside while s_i <= L - depth, at
// access_point - (L - depth - s_i) axis. Frames between two held nodes are turned by the roll.
void drive_begin(const Inst& in, const DriveCommand& cmd, double dt) {
  const RodModel& md = in.model();
  RodState& st = in.rod();
  RodWorkspace& ws = in.ws();
  DriveState& dr = in.drive();
  const Sheath& sh = in.im->sheath;

  double rate = cmd.mode == DriveCommand::Mode::kPosition ? (cmd.translation - dr.depth) / dt
                                                          : cmd.translation;
  double spin =
      cmd.mode == DriveCommand::Mode::kPosition ? (cmd.rotation - dr.roll) / dt : cmd.rotation;
  rate = clamp_abs(rate, sh.max_speed);
  spin = clamp_abs(spin, sh.max_spin);
  // The grip slips (physics.md 6.5): against a resistance beyond what a hand passes on, the
  // hand's advance or turn is not the instrument's. The command is a velocity (or a position),
  // never limited by force, so without this a rod held by the wall would take whatever force
  // the step needs to move it (149 N in two minutes of the soak, 17 kN in an hour). The last
  // fine step's force decides, so it exceeds the grip by at most one step's rise.
  dr.slipped = false;
  if ((rate > 0.0 && dr.axial_force_raw > sh.grip_force) ||
      (rate < 0.0 && dr.axial_force_raw < -sh.grip_force)) {
    rate = 0.0;
    dr.slipped = true;
  }
  if ((spin > 0.0 && dr.torque_raw > sh.grip_torque) ||
      (spin < 0.0 && dr.torque_raw < -sh.grip_torque)) {
    spin = 0.0;
    dr.slipped = true;
  }
  // Keep the first edge outside so the hand always holds a frame (and can turn the rod).
  const double max_depth = md.length - md.rest_length[0];
  const double depth = std::clamp(dr.depth + dt * rate, 0.0, max_depth);
  dr.depth_rate = (depth - dr.depth) / dt;
  dr.depth = depth;
  dr.roll_rate = spin;
  dr.roll += dt * spin;

  const Vec3 axis = sh.frame * Vec3::UnitZ();
  const Vec3 hand = dr.depth_rate * axis;    // the held part's own motion
  const double outside = md.length - depth;  // arc length still outside the body
  int first_free = md.n;
  for (int i = 0; i < md.n; ++i) {
    if (md.node_s[i] > outside + 1e-12) {
      first_free = i;
      break;
    }
    // Held: the velocity that puts the node on the axis at the end of this step. A node taken
    // into the hand away from its place on the axis (a wire folded back out of the body inside
    // its catheter) goes there at most kFoldedBack a step beyond the hand's motion: put there in
    // one step it would leave at metres per second and kick the chain.
    const Vec3 target = sh.access_point - (outside - md.node_s[i]) * axis;
    st.v[i] = (target - st.x[i]) / dt;
    const Vec3 snap = st.v[i] - hand;
    const double far = snap.norm() * dt;
    if (far > kFoldedBack) st.v[i] = hand + snap * (kFoldedBack / far);
    ws.inv_mass[i] = 0.0;
  }
  dr.first_free = first_free;
  for (int j = 0; j + 1 < first_free && j < md.m; ++j) {
    ws.frame_free[j] = 0.0;
    st.omega[j] = Vec3(0.0, 0.0, spin);  // body frame: d3 is the axis
  }
}

// After positions: held frames take the sheath frame turned by the roll (exactly, no drift).
void drive_end(const Inst& in) {
  const Sheath& sh = in.im->sheath;
  const DriveState& dr = in.drive();
  const Quat held =
      (Quat(Eigen::AngleAxisd(dr.roll, sh.frame * Vec3::UnitZ())) * sh.frame).normalized();
  for (int j = 0; j + 1 < dr.first_free && j < in.model().m; ++j) in.rod().q[j] = held;
}

// --- contacts ------------------------------------------------------------------------------------

// True for a free node inside the introducer sheath (Sheath::length of inserted arc length).
bool in_sheath(const Inst& in, int i) {
  return in.driven() &&
         in.model().node_s[i] - (in.model().length - in.drive().depth) <= in.im->sheath.length;
}

// A node the wall meets: not fixed, not in another instrument's lumen, not held by a balloon, not
// in the introducer sheath (nor, so, held by the drive outside the body).
bool free_node(const Inst& in, int i) {
  return in.w->rod.inv_mass[i] != 0.0 && !in.w->sheathed[i] && !in.held(i) && !in_sheath(in, i);
}

// The introducer sheath (physics.md 6.2): a straight tube on the axis from the access point. Its
// lumen holds the free nodes inside it like a wall (with the instrument's vessel friction); they
// meet neither the vessel wall nor, through it, the tissue around the puncture. Without it the
// first free node is held only by the vessel, and a catheter loaded from its tip (a J wire pulled
// back into it) folds there, at the access point.
void add_sheath_contacts(const Inst& in, const SolverSettings& set) {
  const Sheath& sh = in.im->sheath;
  if (sh.length <= 0.0 || !in.driven()) return;
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  InstrumentScratch& w = *in.w;
  const Vec3 axis = sh.frame * Vec3::UnitZ();
  for (int i = in.drive().first_free; i < md.n && in_sheath(in, i); ++i) {
    if (w.rod.inv_mass[i] == 0.0 || w.sheathed[i] || in.held(i)) continue;
    const Vec3 rel = st.x[i] - sh.access_point;
    const Vec3 radial = rel - rel.dot(axis) * axis;
    const double rho = radial.norm();
    if (rho < 1e-12) continue;  // on the axis: the wall is a lumen radius away all round
    const double depth = node_radius(md, i) - (sh.inner_radius - rho);
    const double reach = set.contact_margin + st.v[i].norm() * set.rod.dt;
    if (depth > -reach)
      w.contacts.push_back({i, -radial / rho, depth, 0.0, Vec3::Zero(), Vec3::Zero()});
  }
}

// How far beyond an open end's plane (m, past the node's radius) a node still counts as having
// left through it. A node is queried again each time it has moved about a millimetre (its
// clearance), so it cannot pass this band unseen; beyond it the plane's far side may hold other
// vessels.
constexpr double kExitBand = 20e-3;

// The access end's plane as a wall for the free nodes (physics.md 6.3): the vessel goes on beyond
// it in a body, as beyond the other cut ends, whose caps are part of the lumen's mesh. This end
// has no cap because the held part of each instrument and the sheath's axis pass through it; the
// nodes there (held, in the sheath or outside the body) are not free and do not meet it.
void add_access_end_contacts(const Inst& in, std::span<const WallExit> exits,
                             const SolverSettings& set) {
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  InstrumentScratch& w = *in.w;
  for (const WallExit& ex : exits) {
    if (!ex.access) continue;
    const int first = in.driven() ? in.drive().first_free : 0;
    for (int i = first; i < md.n; ++i) {
      if (!free_node(in, i)) continue;
      const Vec3 rel = st.x[i] - ex.centre;
      const double beyond = rel.dot(ex.outward);
      const double r = node_radius(md, i);
      const double depth = beyond + r;
      const double reach = set.contact_margin + st.v[i].norm() * set.rod.dt;
      // Near the plane only: a node far beyond it is elsewhere in the body.
      if (depth <= -reach || beyond > r + kExitBand) continue;
      if ((rel - beyond * ex.outward).squaredNorm() >= ex.radius * ex.radius) continue;
      w.contacts.push_back({i, -ex.outward, depth, 0.0, Vec3::Zero(), Vec3::Zero()});
    }
  }
}

// A node in contact meeting a face whose normal is within about 25 degrees of its contact's
// (cosine above this) meets the same wall, which already holds it (catch_late_movers).
constexpr double kSameFace = 0.9;
// The chain and contact iterations run again after late contacts are added (catch_late_movers).
constexpr int kLateIterations = 2;

// The escape check on a node just queried (physics.md 6.3), the cost of a compare per contact
// and a dot product per open end: behind the lumen's wall or a closed end's cap (not a stent's:
// a node between a stent and the wall is in the vessel) by more than its radius r, or through an
// open end's disc beyond its plane by more than r. Keeps the step's farthest.
void note_escape(InstrumentScratch& w, int i, const Vec3& x, double r, const SphereContact& h,
                 std::span<const WallExit> exits) {
  NodeEscape& e = w.escape;
  if (h.touching && h.centre_outside && (h.triangle >= 0 || h.cap >= 0) && h.distance > r &&
      h.distance > e.distance)
    e = {i, h.distance, h.cap};
  for (std::size_t k = 0; k < exits.size(); ++k) {
    const WallExit& ex = exits[k];
    if (ex.closed) continue;  // a node beyond its disc is inside its cap, or behind it (above)
    const Vec3 rel = x - ex.centre;
    const double beyond = rel.dot(ex.outward);
    if (beyond <= r || beyond > r + kExitBand || beyond <= e.distance) continue;
    const double lateral = ex.radius + r;
    if ((rel - beyond * ex.outward).squaredNorm() < lateral * lateral)
      e = {i, beyond, static_cast<int>(k)};
  }
}

// Queries the wall at the scratch's first nq query nodes (points, radii, caches) into its hits.
void query_wall(InstrumentScratch& w, VesselWall& wall, int nq, double slack) {
  wall.query_spheres(std::span<const Vec3>(w.query_points.data(), nq),
                     std::span<const double>(w.query_radii.data(), nq),
                     std::span<LeafCache* const>(w.query_caches.data(), nq), slack,
                     std::span<SphereContact>(w.hits.data(), nq));
}

// Finds the contacts of the free nodes. A node is queried with a radius reaching
// coherence_margin beyond its contact reach; if that finds no wall, the node is skipped until it
// (or the wall) has moved far enough to close the gap.
void detect_contacts(const Inst& in, VesselWall& wall, std::span<const WallExit> exits,
                     const SolverSettings& set, StepProfile* prof) {
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  InstrumentState& s = *in.st;
  InstrumentScratch& w = *in.w;
  const double dt = set.rod.dt;
  w.contacts.clear();
  std::fill(w.room.begin(), w.room.end(), kNoWall);
  std::fill(w.gap.begin(), w.gap.end(), -1.0);
  int nq = 0;
  const double wall_step = wall.speed_bound() * dt;  // the most a moving wall comes this step
  s.wall_travel += wall_step;
  const int first = in.driven() ? in.drive().first_free : 0;
  for (int i = first; i < md.n; ++i) {
    if (!free_node(in, i)) continue;
    const double reach = node_radius(md, i) + set.contact_margin + st.v[i].norm() * dt;
    if (s.clearance[i] > 0.0) {
      // How far the node has gone from where it was queried, and the wall toward it since (none
      // where no moving part of the wall can reach that query's sphere).
      const double travel = s.travel_at[i] < 0.0 ? 0.0 : s.wall_travel - s.travel_at[i];
      const double moved = (st.x[i] - s.query_centre[i]).norm() + travel;
      if (moved + reach < s.clearance[i]) {  // the wall cannot be within reach
        w.room[i] = s.clearance[i] - moved - node_radius(md, i) - wall_step;
        w.gap[i] = s.clearance[i] - moved - wall_step;
        continue;
      }
    }
    w.query_nodes[nq] = i;
    w.query_points[nq] = st.x[i];
    // A node that touched the wall last step is queried again next step anyway: the wider
    // radius that buys skipping is wasted on it.
    const bool was_touching = s.clearance[i] == 0.0 && st.steps > 0;
    w.query_radii[nq] = reach + (was_touching ? 0.0 : set.coherence_margin);
    w.query_caches[nq] = &w.leaf_cache[i];
    ++nq;
  }
  if (nq == 0) return;
  query_wall(w, wall, nq, set.leaf_cache_slack);
  const bool moving = wall.speed_bound() > 0.0;
  for (int k = 0; k < nq; ++k) {
    const int i = w.query_nodes[k];
    const SphereContact& h = w.hits[k];
    const double r = node_radius(md, i);
    note_escape(w, i, st.x[i], r, h, exits);
    s.query_centre[i] = st.x[i];
    // The wall's travel counts from this query on, unless no moving part can reach its sphere.
    auto mark = [&](double clearance) {
      s.clearance[i] = clearance;
      s.travel_at[i] = moving && wall.moves_near(st.x[i], clearance) ? s.wall_travel : -1.0;
    };
    if (!h.touching) {
      mark(w.query_radii[k]);
      w.room[i] = w.query_radii[k] - r - wall_step;
      w.gap[i] = w.query_radii[k] - wall_step;
      continue;
    }
    w.gap[i] = h.centre_outside ? 0.0 : std::max(0.0, h.distance - wall_step);
    const double depth = h.centre_outside ? r + h.distance : r - h.distance;
    const double reach = node_radius(md, i) + set.contact_margin + st.v[i].norm() * dt - r;
    if (!h.centre_outside && depth < -reach) {
      mark(h.distance);  // near, but not within reach this step
      w.room[i] = h.distance - r - wall_step;
      continue;
    }
    s.clearance[i] = 0.0;  // in contact: query again next step
    // Held off this wall only: sliding along it further than its gap and the margin, it may
    // meet another face (the far side of a bend), which the late check looks for.
    w.room[i] = std::max(0.0, -depth) + set.contact_margin;
    w.contact_normal[i] = h.normal;
    w.contacts.push_back({i, h.normal, depth, 0.0, Vec3::Zero(), wall.velocity(h)});
  }
  if (prof) prof->num_queries += nq;
}

// A sample comes nearer the wall than its edge's nodes when its distance is below theirs,
// interpolated at its place, by this fraction of the rod's radius (a ridge between them).
constexpr double kSampleNearer = 0.05;

// The contacts of the collision samples between the nodes (physics.md 6.3). Only nodes collide
// otherwise, and an edge of a long shaft (9-13 mm in the soak's iliacs) can pass a ridge of the
// wall between them: the carina between two branches, the inner side of a bend. Each sample of an
// edge between two free nodes is queried as a sphere of the rod's radius (with its own leaf
// cache) unless the nodes' gaps (InstrumentScratch::gap) keep the wall beyond its reach, or its
// own clearance does: like a node's, a sample is queried coherence_margin wider than its reach
// and skipped until it (or the wall) has moved far enough to close what that query found free.
// The nodes' gaps alone bound the wall only near them (a gap less the distance along the edge),
// which leaves the middle of a 10 mm edge queried every step. A sample nearer the wall than the
// nodes' distances interpolated to it, or behind the wall, gets a contact at its point; along a
// flat or hollow wall (a vessel's straight or outer side) it is not nearer, and the nodes' own
// contacts hold the edge.
void detect_edge_contacts(const Inst& in, VesselWall& wall, const SolverSettings& set,
                          StepProfile* prof) {
  InstrumentScratch& w = *in.w;
  w.edge_contacts.clear();
  const std::size_t ns = w.sample_edge.size();
  if (ns == 0) return;
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  InstrumentState& s = *in.st;
  if (s.sample_clearance.size() != ns || s.sample_centre.size() != ns ||
      s.sample_travel_at.size() != ns) {  // first met, or another spacing: unknown, query all
    s.sample_centre.assign(ns, Vec3::Zero());
    s.sample_clearance.assign(ns, 0.0);
    s.sample_travel_at.assign(ns, 0.0);
  }
  const double dt = set.rod.dt;
  const double wall_step = wall.speed_bound() * dt;
  const int first = in.driven() ? in.drive().first_free : 0;
  int nq = 0;
  for (std::size_t k = 0; k < ns; ++k) {
    const int i = w.sample_edge[k];
    if (i < first || w.gap[i] < 0.0 || w.gap[i + 1] < 0.0) continue;
    const double t = w.sample_along[k];
    const Vec3& a = st.x[i];
    const Vec3& b = st.x[i + 1];
    const double len = (b - a).norm();
    const double r = (1.0 - t) * node_radius(md, i) + t * node_radius(md, i + 1);
    const double reach =
        r + set.contact_margin + ((1.0 - t) * st.v[i] + t * st.v[i + 1]).norm() * dt + wall_step;
    // The sample lies t len from node i and (1 - t) len from node i + 1.
    if (std::max(w.gap[i] - t * len, w.gap[i + 1] - (1.0 - t) * len) > reach) continue;
    const Vec3 p = a + t * (b - a);
    if (s.sample_clearance[k] > 0.0) {
      const double travel =
          s.sample_travel_at[k] < 0.0 ? 0.0 : s.wall_travel - s.sample_travel_at[k];
      if ((p - s.sample_centre[k]).norm() + travel + reach < s.sample_clearance[k]) continue;
    }
    // A sample that touched the wall last step is queried again next step anyway.
    const bool was_touching = s.sample_clearance[k] == 0.0 && st.steps > 0;
    w.sample_query[nq] = static_cast<int>(k);
    w.sample_points[nq] = p;
    w.sample_radii[nq] = reach + (was_touching ? 0.0 : set.coherence_margin);
    w.sample_reach[nq] = reach;
    w.sample_caches[nq] = &w.sample_cache[k];
    ++nq;
  }
  if (nq == 0) return;
  if (prof) prof->num_sample_queries += nq;
  wall.query_spheres(std::span<const Vec3>(w.sample_points.data(), nq),
                     std::span<const double>(w.sample_radii.data(), nq),
                     std::span<LeafCache* const>(w.sample_caches.data(), nq), set.leaf_cache_slack,
                     std::span<SphereContact>(w.sample_hits.data(), nq));
  const bool moving = wall.speed_bound() > 0.0;
  for (int q = 0; q < nq; ++q) {
    const SphereContact& h = w.sample_hits[q];
    const auto k = static_cast<std::size_t>(w.sample_query[q]);
    const int i = w.sample_edge[k];
    const double t = w.sample_along[k];
    const double r = (1.0 - t) * node_radius(md, i) + t * node_radius(md, i + 1);
    const double reach = w.sample_reach[q];
    s.sample_centre[k] = w.sample_points[q];
    auto mark = [&](double clearance) {
      s.sample_clearance[k] = clearance;
      s.sample_travel_at[k] =
          moving && wall.moves_near(w.sample_points[q], clearance) ? s.wall_travel : -1.0;
    };
    if (!h.touching) {
      mark(w.sample_radii[q]);
      continue;
    }
    if (!h.centre_outside && h.distance >= reach) {
      mark(h.distance);  // near, but not within reach this step
      continue;
    }
    s.sample_clearance[k] = 0.0;  // within reach: query again next step
    if (!h.centre_outside) {
      const double between = (1.0 - t) * w.gap[i] + t * w.gap[i + 1];
      if (h.distance > between - kSampleNearer * r) continue;
    }
    NodeContact c;
    c.node = i;
    c.along = t;
    c.normal = h.normal;
    c.depth = h.centre_outside ? r + h.distance : r - h.distance;
    c.wall_velocity = wall.velocity(h);
    w.edge_contacts.push_back(c);
  }
}

// An inflated balloon (BalloonHold): its nodes are held within `play` of the vessel's axis, the
// contact's normal toward the axis, and their friction carries the balloon's pressure on the
// wall (preload), which anchors it axially.
void add_hold_contacts(const Inst& in, const SolverSettings& set) {
  const BalloonHold& h = in.st->hold;
  if (!h.active()) return;
  const RodState& st = in.rod();
  const double dt = set.rod.dt;
  for (int i = std::max(h.first, in.driven() ? in.drive().first_free : 0); i <= h.last; ++i) {
    if (in.ws().inv_mass[i] == 0.0) continue;
    const Vec3& t = h.tangent[i];
    const Vec3 rel = st.x[i] - h.axis[i];
    Vec3 radial = rel - rel.dot(t) * t;
    double rho = radial.norm();
    if (rho < 1e-12) {
      // On the axis: any direction across it (friction needs one; the play decides the rest).
      radial = t.unitOrthogonal();
      rho = 0.0;
    } else {
      radial /= rho;
    }
    const double depth = rho - h.play[i];
    const double reach = set.contact_margin + st.v[i].norm() * dt;
    if (depth <= -reach && h.wall_load[i] <= 0.0) continue;
    NodeContact c{i, -radial, depth, 0.0, Vec3::Zero(), h.axis_velocity[i]};
    c.preload = h.wall_load[i] * dt;
    in.w->contacts.push_back(c);
  }
}

// An edge contact's point, (1 - along) x[node] + along x[node + 1]: its velocity and inverse
// mass from its two nodes' in those weights, and an impulse on it shared in the same weights.
struct EdgePoint {
  EdgePoint(const NodeContact& c, const std::vector<double>& inv_mass)
      : i(c.node),
        u(1.0 - c.along),
        t(c.along),
        wi(u * inv_mass[i]),
        wj(t * inv_mass[i + 1]),
        w(u * wi + t * wj) {}
  Vec3 velocity(const std::vector<Vec3>& vel) const { return u * vel[i] + t * vel[i + 1]; }
  void apply(const Vec3& impulse, std::vector<Vec3>& vel) const {
    vel[i] += wi * impulse;
    vel[i + 1] += wj * impulse;
  }
  int i;
  double u, t, wi, wj, w;
};

// One projected Gauss-Seidel sweep over the contacts: non-penetration (a velocity that closes a
// speculative gap exactly, or removes a fraction of a penetration), then the friction impulse
// clamped to the Coulomb cone (static cone; beyond it, sliding at mu_dynamic).
void solve_contacts(const Inst& in, const SolverSettings& set, std::size_t first = 0) {
  const double dt = set.rod.dt;
  const double beta = set.penetration_correction;
  const double mu_s = in.im->contact.mu_static, mu_d = in.im->contact.mu_dynamic;
  const std::vector<double>& inv_mass = in.ws().inv_mass;
  std::vector<Vec3>& vel = in.rod().v;
  for (std::size_t k = first; k < in.w->contacts.size(); ++k) {
    NodeContact& c = in.w->contacts[k];
    const double w = inv_mass[c.node];
    Vec3& v = vel[c.node];
    // Velocities relative to the wall: a beating wall carries what it touches.
    const double target = c.depth > 0.0 ? beta * c.depth / dt : c.depth / dt;
    const double vn = (v - c.wall_velocity).dot(c.normal);
    const double ln = std::max(0.0, c.lambda_n + (target - vn) / w);
    v += (w * (ln - c.lambda_n)) * c.normal;
    c.lambda_n = ln;
    const Vec3 vr = v - c.wall_velocity;
    const Vec3 vt = vr - vr.dot(c.normal) * c.normal;
    Vec3 lt = c.lambda_t - vt / w;
    const double lt_norm = lt.norm();
    const double pressed = ln + c.preload;
    if (lt_norm > mu_s * pressed) lt *= (mu_d * pressed) / lt_norm;
    v += w * (lt - c.lambda_t);
    c.lambda_t = lt;
  }
  if (first > 0) return;
  for (NodeContact& c : in.w->edge_contacts) {
    const EdgePoint p(c, inv_mass);
    if (p.w <= 0.0) continue;
    const double target = c.depth > 0.0 ? beta * c.depth / dt : c.depth / dt;
    const double vn = (p.velocity(vel) - c.wall_velocity).dot(c.normal);
    const double ln = std::max(0.0, c.lambda_n + (target - vn) / p.w);
    p.apply((ln - c.lambda_n) * c.normal, vel);
    c.lambda_n = ln;
    const Vec3 vr = p.velocity(vel) - c.wall_velocity;
    const Vec3 vt = vr - vr.dot(c.normal) * c.normal;
    Vec3 lt = c.lambda_t - vt / p.w;
    const double lt_norm = lt.norm();
    if (lt_norm > mu_s * ln) lt *= (mu_d * ln) / lt_norm;
    p.apply(lt - c.lambda_t, vel);
    c.lambda_t = lt;
  }
}

// The penetration fix-up velocity moved the node out; it must not stay as a bounce. The impulse
// taken back is kept (lambda_bias): it was a position correction, not a load.
void remove_contact_bias(const Inst& in, const SolverSettings& set) {
  const double dt = set.rod.dt;
  for (NodeContact& c : in.w->contacts) {
    if (c.depth <= 0.0) continue;
    Vec3& v = in.rod().v[c.node];
    const double vn = (v - c.wall_velocity).dot(c.normal);
    const double bias = set.penetration_correction * c.depth / dt;
    if (vn <= 0.0) continue;
    const double removed = std::min(vn, bias);
    v -= removed * c.normal;
    c.lambda_bias = removed / in.ws().inv_mass[c.node];
  }
  // An edge's: its point's normal velocity less the bias, taken from both nodes in the weights
  // that the impulse moved them by.
  const std::vector<double>& inv_mass = in.ws().inv_mass;
  std::vector<Vec3>& vel = in.rod().v;
  for (NodeContact& c : in.w->edge_contacts) {
    if (c.depth <= 0.0) continue;
    const EdgePoint p(c, inv_mass);
    if (p.w <= 0.0) continue;
    const double vn = (p.velocity(vel) - c.wall_velocity).dot(c.normal);
    if (vn <= 0.0) continue;
    const double removed = std::min(vn, set.penetration_correction * c.depth / dt);
    const double l = removed / p.w;
    vel[p.i] -= (p.wi * l) * c.normal;
    vel[p.i + 1] -= (p.wj * l) * c.normal;
    c.lambda_bias = l;
  }
}

// --- coaxial coupling ---------------------------------------------------------------------------

constexpr double kPairWindow = 0.03;  // m of arc length searched either way (offset_from_outer)

// Closest point on the outer instrument's edge k to p: parameter t in [0, 1] and squared
// distance.
double project_on_edge(const RodState& outer, int k, const Vec3& p, double& t) {
  const Vec3& a = outer.x[k];
  const Vec3 ab = outer.x[k + 1] - a;
  t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (a + t * ab - p).squaredNorm();
}

// Offset of p from the closest point of the outer centreline near edge k (the edge at the same
// inserted arc length): walks to the geometrically closest edge, since the two centrelines' arc
// lengths drift apart by more than an edge where the catheter is compressed or the wire takes
// the inside of a bend, and an edge whose projection is clamped at its end would pin the node to
// that vertex along the axis instead of holding it radially. The offset is perpendicular to the
// edge inside it, toward the vertex where the projection is clamped (at a polyline bend).
Vec3 offset_from_outer(const Inst& outer, int k, const Vec3& p, int& best, double& best_t) {
  const RodState& out = outer.rod();
  const RodModel& mo = outer.model();
  const int m = mo.m;
  double t = 0.0;
  best = k;
  double best_d2 = project_on_edge(out, k, p, best_t);
  for (int step : {-1, 1}) {
    for (int kk = best + step; kk >= 0 && kk < m; kk += step) {
      const double d2 = project_on_edge(out, kk, p, t);
      if (d2 >= best_d2) break;
      best_d2 = d2;
      best = kk;
      best_t = t;
    }
  }
  // Not within the lumen there: the walk stopped at a local minimum of the distance, which a
  // catheter folded or bunched up near the access (its arc length centimetres off the wire's) can
  // leave far from the edge the node lies in. The nearest edge within kPairWindow of arc length
  // either way decides; without this the coupling would drag the node across to the wrong part.
  const double lumen = mo.inner_radius[best];
  if (best_d2 > lumen * lumen) {
    auto consider = [&](int kk) {
      const double d2 = project_on_edge(out, kk, p, t);
      if (d2 < best_d2) {
        best_d2 = d2;
        best = kk;
        best_t = t;
      }
    };
    const double s0 = mo.edge_s[k];
    for (int kk = k; kk >= 0 && s0 - mo.edge_s[kk] <= kPairWindow; --kk) consider(kk);
    for (int kk = k + 1; kk < m && mo.edge_s[kk] - s0 <= kPairWindow; ++kk) consider(kk);
  }
  const Vec3& a = out.x[best];
  return p - (a + best_t * (out.x[best + 1] - a));
}

// True when the closest point of the outer centreline (edge `best`, parameter t) is its distal
// end: the inner node lies beyond the outer instrument's tip, outside it. On the inside of the
// curves the wire's path is shorter than the catheter's centreline (by up to the clearance times
// the angle turned), so a node still inside by arc length can lie there. The coupling leaves it to
// the wall: a constraint toward the tip would pin it there along the axis, and yank a shaped wire
// tip being pulled back in.
bool beyond_tip(const RodModel& outer, int best, double t) {
  return best == outer.m - 1 && t >= 1.0;
}

// Calls f(i, k, past) for every free inner node i inside the outer instrument's inserted length,
// with k the outer edge at the same inserted arc length, and for the next ones within
// kMouthSlack beyond it (past = true): the wire's path is longer than the catheter's centreline,
// so such a node can still lie inside the lumen. On the outside of the curves the excess is up to
// the clearance times the angle turned (0.7 mm x 3 pi through the arch), and a pushed wire snakes
// in the lumen: in a variant of the default run the coronary wire had nodes 4.4 mm past the
// guide's inserted length still 0.2 mm short of its mouth. Where the window was 3 mm such a node
// went free, drifted into the wall next to the rim and the rim contact then met it 2 r_w deep in
// one step (physics.md 7.1). Only geometry decides (in the lumen, next to a coupled node, not
// beyond the tip).
constexpr double kMouthSlack = 10e-3;
template <class F>
void for_each_sheathed(const Inst& in, const Inst& out, F&& f) {
  const RodModel& mi = in.model();
  const RodModel& mo = out.model();
  const double in_offset = mi.length - in.drive().depth;    // s at the access point, inner
  const double out_offset = mo.length - out.drive().depth;  // s at the access point, outer
  int k = 0;
  for (int i = in.drive().first_free; i < mi.n; ++i) {
    const double sigma = mi.node_s[i] - in_offset;  // inserted arc length of this node
    if (sigma <= 0.0 || sigma > out.drive().depth + kMouthSlack) continue;
    const double s_out = std::min(sigma + out_offset, mo.length);
    while (k + 1 < mo.m && mo.node_s[k + 1] <= s_out) ++k;
    f(i, k, sigma > out.drive().depth);
  }
}

constexpr int kRimEdges = 3;

// The rim: the inner rod leaves the outer one through its distal opening, so the edge from the
// last sheathed node to the next must pass inside the rim (the ring of the lumen's radius R at the
// outer tip) and wrap round it at no less than its own radius r_w. Node constraints alone let that
// edge cut through the tip's wall: a shaped wire tip pulled back in then enters node by node, each
// node snapping from outside into the lumen, a jump of the shape and of the force at the hand in
// each (physics.md 7.1). The contact point slides along the edge as the wire does, so the
// constraint and its reaction change continuously. In the plane of the axis and the edge's far
// node, with L the rim point on that side and p the edge's point nearest L, the gap is
// sd - r_w with sd = +-|p - L|, + when L lies on the wall's side of the edge (the wire passes in
// front of the rim), - when the edge cuts through the wall.
void add_rim_contact(const Pair& cp, unsigned char me, const Inst& in, const Inst& out,
                     const SolverSettings& set) {
  if (!cp.cm->rim) return;
  const RodModel& mi = in.model();
  const RodModel& mo = out.model();
  const RodState& si = in.rod();
  const RodState& so = out.rod();
  const std::vector<unsigned char>& sheathed = in.w->sheathed;
  int i = mi.n - 2;
  while (i >= in.drive().first_free && !(sheathed[i] == me && sheathed[i + 1] != me)) --i;
  if (i < in.drive().first_free) return;
  const Vec3& tip = so.x[mo.n - 1];
  const Vec3 axis = (tip - so.x[mo.n - 2]).normalized();
  const double rim = mo.inner_radius[mo.m - 1];
  // The edges that leave the lumen and wrap round the rim: a wire edge is shorter than the wrap
  // of a 3 mm J tip round the rim, so it takes up to three.
  for (int j = i; j < std::min(i + kRimEdges, mi.n - 1); ++j) {
    const Vec3& x0 = si.x[j];
    const Vec3& x1 = si.x[j + 1];
    const Vec3 r1 = (x1 - tip) - (x1 - tip).dot(axis) * axis;
    if (r1.norm() < 1e-12) continue;  // straight out along the axis: far from the rim all round
    const Vec3 u = r1.normalized();
    const Vec3 lip = tip + rim * u;
    const Vec3 e = x1 - x0;
    if (e.squaredNorm() < 1e-24) continue;  // a collapsed edge has no direction to wrap
    const double a = std::clamp((lip - x0).dot(e) / e.squaredNorm(), 0.0, 1.0);
    if (a <= 0.0) continue;  // nearest at the edge's first node: that node's own constraint
    const Vec3 away = x0 + a * e - lip;  // from the rim point to the edge
    const double dist = away.norm();
    if (dist < 1e-12) continue;
    // Side: in the (axis, u) plane, (h, rho) about the tip, the edge cuts through the wall when it
    // crosses the wall's line rho = R behind the rim (h < 0). Where it crosses at h = 0 it passes
    // through the rim point itself (dist = 0), so the gap's sign flips only where its size is
    // zero. (The side of the edge's line that the rim point lies on decided before; with the
    // nearest point clamped to x1 that line runs on past x1, and an edge ending inside the lumen
    // just short of the rim read as a cut r_w + dist deep: a 0.35 mm push in one step,
    // physics.md 7.1.)
    const double h0 = (x0 - tip).dot(axis), q0 = (x0 - tip).dot(u);
    const double h1 = (x1 - tip).dot(axis), q1 = r1.norm();
    bool in_front = true;
    if ((q0 - rim) * (q1 - rim) < 0.0) {
      const double s = (rim - q0) / (q1 - q0);
      in_front = h0 + s * (h1 - h0) >= 0.0;
    }
    const double r_w = mi.outer_radius[j];
    if (!in_front && dist > r_w) continue;  // not a shallow cut: far from the rim, or past it
    const double sd = in_front ? dist : -dist;
    const Vec3 normal = in_front ? Vec3(-away / dist) : Vec3(away / dist);  // toward the rim
    const double excess = r_w - sd;
    const Vec3 rel_v = (1 - a) * si.v[j] + a * si.v[j + 1] - so.v[mo.n - 1];
    if (excess < -(set.contact_margin + rel_v.norm() * set.rod.dt)) continue;
    cp.s->contacts.push_back({j, mo.m - 1, 1.0, normal, excess, 0.0, Vec3::Zero(), a});
  }
}

// Pairs every free inner node inside the outer instrument's inserted length with the closest
// outer edge and records the radial excess beyond the clearance. Marks those inner nodes
// sheathed by this coupling, `me` (no wall query); a node an earlier coupling of the same inner
// holds (an outer inside this one) is that one's.
void detect_coupling(const Pair& cp, unsigned char me, const Inst& in, const Inst& out,
                     const SolverSettings& set) {
  CouplingScratch& cs = *cp.s;
  cs.contacts.clear();
  std::vector<unsigned char>& sheathed = in.w->sheathed;
  const RodModel& mo = out.model();
  const RodState& si = in.rod();
  const RodState& so = out.rod();
  cs.clearance = std::max(0.0, mo.inner_radius[mo.m - 1] - in.model().outer_radius[0]);
  const double dt = set.rod.dt;
  for_each_sheathed(in, out, [&](int i, int k, bool past) {
    if (sheathed[i] != 0) return;  // in an outer that lies inside this one
    int best = k;
    double t = 0.0;
    const Vec3 off = offset_from_outer(out, k, si.x[i], best, t);
    if (beyond_tip(mo, best, t)) return;  // outside: the wall's
    const double r = off.norm();
    // Past the inserted length: inside only where it lies in the lumen, next to a node inside.
    if (past && (sheathed[i - 1] != me || r > mo.inner_radius[best])) return;
    sheathed[i] = me;
    if (r < 1e-12) return;
    const Vec3 rel_v = si.v[i] - ((1 - t) * so.v[best] + t * so.v[best + 1]);
    const double excess = r - cs.clearance;
    if (excess < -(set.contact_margin + rel_v.norm() * dt)) return;
    cs.contacts.push_back({i, best, t, off / r, excess, 0.0, Vec3::Zero()});
  });
  add_rim_contact(cp, me, in, out, set);
}

// After the positions: moves every sheathed inner node that ended the step beyond the clearance
// radially back onto it (except past the catheter's tip). The velocity-level constraint bounds only
// the normal part of the relative motion along the normal of the step's start; a fast tangential
// relative motion (a catheter tip whipping round a slow wire: up to 2 clearances per step in the
// pair scene) leaves the node outside by sqrt(c^2 + (v_t dt)^2) - c. The catheter is taken as fixed
// here, so one pass is exact; the velocities are left alone (the next step's constraint sees a node
// at the clearance).
void project_coupling(const Pair& cp, unsigned char me, const Inst& in, const Inst& out) {
  const double clearance = cp.s->clearance;
  RodState& si = in.rod();
  for_each_sheathed(in, out, [&](int i, int k, bool) {
    if (in.w->sheathed[i] != me) return;
    int best = k;
    double t = 0.0;
    const Vec3 off = offset_from_outer(out, k, si.x[i], best, t);
    if (beyond_tip(out.model(), best, t)) return;  // left through the tip
    const double r = off.norm();
    if (r > clearance) si.x[i] -= ((r - clearance) / r) * off;
  });
}

// A concentric contact's inverse masses: the inner point's two nodes' weighted by their shares
// (1 - a, a), the outer edge's two nodes' by theirs (1 - t, t), and k, the inverse of the
// contact's effective mass.
struct CouplingWeights {
  double w0, w1, wa, wb, k;
};
CouplingWeights coupling_weights(const CoaxialContact& c, const Inst& in, const Inst& out) {
  const std::vector<double>& wi = in.ws().inv_mass;
  const std::vector<double>& wo = out.ws().inv_mass;
  const double w0 = wi[c.node] * (1 - c.a);
  const double w1 = c.a > 0.0 ? wi[c.node + 1] * c.a : 0.0;
  const double wa = wo[c.segment] * (1 - c.t);
  const double wb = wo[c.segment + 1] * c.t;
  return {w0, w1, wa, wb, (1 - c.a) * w0 + c.a * w1 + (1 - c.t) * wa + c.t * wb};
}

// The inner point's velocity, and the outer centreline's where it faces it.
Vec3 inner_velocity(const CoaxialContact& c, const Inst& in) {
  const Vec3& v0 = in.rod().v[c.node];
  return c.a > 0.0 ? Vec3((1 - c.a) * v0 + c.a * in.rod().v[c.node + 1]) : v0;
}
Vec3 outer_velocity(const CoaxialContact& c, const Inst& out) {
  return (1 - c.t) * out.rod().v[c.segment] + c.t * out.rod().v[c.segment + 1];
}

// The velocities an impulse at the contact's inner point gives both rods (its reaction on the
// outer), by their weighted inverse masses.
void add_coupling_velocity(const CoaxialContact& c, const CouplingWeights& w, std::vector<Vec3>& vi,
                           std::vector<Vec3>& vo, const Vec3& impulse) {
  vi[c.node] += w.w0 * impulse;
  if (c.a > 0.0) vi[c.node + 1] += w.w1 * impulse;
  vo[c.segment] -= w.wa * impulse;
  vo[c.segment + 1] -= w.wb * impulse;
}

// Adds an impulse at the contact's inner point to InstrumentScratch::coupling_impulse, its
// reaction at the outer point.
void add_coupling_impulse(const CoaxialContact& c, const Inst& in, const Inst& out,
                          const Vec3& impulse) {
  std::vector<Vec3>& ii = in.w->coupling_impulse;
  std::vector<Vec3>& io = out.w->coupling_impulse;
  ii[c.node] += (1 - c.a) * impulse;
  if (c.a > 0.0) ii[c.node + 1] += c.a * impulse;
  io[c.segment] -= (1 - c.t) * impulse;
  io[c.segment + 1] -= c.t * impulse;
}

// One projected Gauss-Seidel sweep over the concentric constraints: the inner node may not move
// further than the clearance from the outer centreline; lumen friction on the relative sliding.
void solve_coupling(const Pair& cp, const Inst& in, const Inst& out, const SolverSettings& set) {
  const double dt = set.rod.dt;
  const double mu = cp.cm->mu;
  std::vector<Vec3>& vi = in.rod().v;
  std::vector<Vec3>& vo = out.rod().v;
  std::vector<Vec3>& ni = in.ws().node_impulse;
  std::vector<Vec3>& no = out.ws().node_impulse;
  for (CoaxialContact& c : cp.s->contacts) {
    const auto [w0, w1, wa, wb, k] = coupling_weights(c, in, out);
    if (k == 0.0) continue;
    auto apply = [&](const Vec3& impulse) {  // impulse on the inner point, reaction on the outer
      add_coupling_velocity(c, {w0, w1, wa, wb, k}, vi, vo, impulse);
      ni[c.node] += (1 - c.a) * impulse;
      if (c.a > 0.0) ni[c.node + 1] += c.a * impulse;
      no[c.segment] -= (1 - c.t) * impulse;
      no[c.segment + 1] -= c.t * impulse;
      add_coupling_impulse(c, in, out, impulse);
    };
    // Radial: v_rel . n <= -beta excess / dt: a fraction beta of a violation is removed by the
    // velocity (as a wall penetration), the rest by project_coupling after the positions, so that
    // a wire outside its catheter is still put back at once; a gap may close exactly.
    const double target =
        c.excess > 0.0 ? -set.penetration_correction * c.excess / dt : -c.excess / dt;
    const Vec3 rel = inner_velocity(c, in) - outer_velocity(c, out);
    const double ln = std::max(0.0, c.lambda_n + (rel.dot(c.normal) - target) / k);
    apply(-(ln - c.lambda_n) * c.normal);
    c.lambda_n = ln;
    if (mu <= 0.0) continue;
    const Vec3 rel2 = inner_velocity(c, in) - outer_velocity(c, out);
    const Vec3 slip = rel2 - rel2.dot(c.normal) * c.normal;
    Vec3 lt = c.lambda_t + slip / k;
    const double lt_norm = lt.norm();
    if (lt_norm > mu * ln) lt *= mu * ln / lt_norm;
    apply(-(lt - c.lambda_t));
    c.lambda_t = lt;
  }
}

// The part of each concentric impulse that removed a violation (beta times the radial excess the
// step began with) is a position fix-up, not a load, like a wall contact's lambda_bias: it is
// taken out of the impulses the hands feel, with the lumen friction it allowed in proportion. Its
// velocity moved the inner point in during the step and must not stay as a bounce (as
// remove_contact_bias for the wall): the relative radial velocity it left, up to beta excess / dt
// inward, is taken back from both rods in proportion to their inverse masses. Kept (and with the
// whole excess removed by the velocity, as until 2026-11-26), it threw the point across the lumen
// at excess / dt, a whip of the outer tip and of the wire beyond it each time a node entered the
// lumen with an excess: in the soak a 0.014" wire node at 20 m/s and a catheter tip at 16 m/s,
// every few millimetres of a catheter pushed over a wire (physics.md 7).
void remove_coupling_bias(const Pair& cp, const Inst& in, const Inst& out, double dt, double beta) {
  std::vector<Vec3>& vi = in.rod().v;
  std::vector<Vec3>& vo = out.rod().v;
  for (const CoaxialContact& c : cp.s->contacts) {
    if (c.excess <= 0.0 || c.lambda_n <= 0.0) continue;
    const auto [w0, w1, wa, wb, k] = coupling_weights(c, in, out);
    if (k == 0.0) continue;
    const double vn = (inner_velocity(c, in) - outer_velocity(c, out)).dot(c.normal);
    if (vn < 0.0) {
      add_coupling_velocity(c, {w0, w1, wa, wb, k}, vi, vo,
                            (std::min(-vn, beta * c.excess / dt) / k) * c.normal);
    }
    // The impulse that changes the relative normal velocity by beta excess / dt, at most all of it.
    const double share = std::min(1.0, beta * c.excess / (dt * k) / c.lambda_n);
    add_coupling_impulse(c, in, out, share * (c.lambda_n * c.normal + c.lambda_t));
  }
}

// Runs f(k) for every instrument k that is not parked: on the TBB threads when `parallel`, else
// in order. Each call must touch only its own instrument, so the results are the same either way.
template <class F>
void for_each_active(std::span<Inst> insts, bool parallel, F&& f) {
  if (parallel) {
#if defined(__SANITIZE_THREAD__)
    tsan_chunks(insts.size(), 1, [&](std::size_t k, std::size_t) {
      if (!insts[k].parked()) f(k);
    });
#else
    tbb::parallel_for(std::size_t{0}, insts.size(), [&](std::size_t k) {
      if (!insts[k].parked()) f(k);
    });
#endif
  } else {
    for (std::size_t k = 0; k < insts.size(); ++k)
      if (!insts[k].parked()) f(k);
  }
}

}  // namespace

void InstrumentScratch::resize(const RodModel& md, double sample_spacing) {
  const int n = md.n;
  // The collision samples: K = ceil(l / spacing) - 1 evenly spaced inside each edge of rest
  // length l.
  sample_edge.clear();
  sample_along.clear();
  if (sample_spacing > 0.0) {
    for (int e = 0; e < md.m; ++e) {
      const double l = md.rest_length[e];
      const int k = std::max(0, static_cast<int>(std::ceil(l / sample_spacing - 1e-9)) - 1);
      for (int j = 1; j <= k; ++j) {
        sample_edge.push_back(e);
        sample_along.push_back(static_cast<double>(j) / (k + 1));
      }
    }
  }
  const std::size_t ns = sample_edge.size();
  sample_query.assign(ns, 0);
  sample_points.assign(ns, Vec3::Zero());
  sample_radii.assign(ns, 0.0);
  sample_reach.assign(ns, 0.0);
  sample_cache.assign(ns, LeafCache{});
  sample_caches.assign(ns, nullptr);
  sample_hits.assign(ns, SphereContact{});
  edge_contacts.clear();
  edge_contacts.reserve(ns);
  gap.assign(n, -1.0);
  edge_contact_of.assign(n, -1);
  rod.resize(md);
  hits.assign(n, SphereContact{});
  query_nodes.assign(n, 0);
  query_points.assign(n, Vec3::Zero());
  query_radii.assign(n, 0.0);
  query_caches.assign(n, nullptr);
  leaf_cache.assign(n, LeafCache{});
  room.assign(n, kNoWall);
  contact_normal.assign(n, Vec3::Zero());
  contacts.clear();
  contacts.reserve(n);
  sheathed.assign(n, 0);
  coupling_impulse.assign(n, Vec3::Zero());
  felt_load.assign(n, Vec3::Zero());
  wall_contact_of.assign(n, -1);
  wall_contact2_of.assign(n, -1);
  coupling_of.assign(n, -1);
  coupling_pair.assign(n, -1);
  rim_of.assign(n, -1);
  rim_pair.assign(n, -1);
}

// A node that the iterations sped up beyond the room its detection checked (a wave down a chain
// of scaled masses, a tip let go) would cross a wall unseen: it is queried again as far as it is
// about to travel, and what it meets becomes a contact. A node in contact, held off its own wall
// only, is queried where it is about to arrive: a face there other than its own (the far side of
// a bend it slides round) becomes a second contact, its depth taken back along its normal to the
// node's present place. The instrument's chain and contacts are then iterated again with them,
// so that the chain carries what stops the node (physics.md 6.3).
void catch_late_movers(const Inst& in, VesselWall& wall, const SolverSettings& set) {
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  InstrumentState& s = *in.st;
  InstrumentScratch& w = *in.w;
  const double dt = set.rod.dt;
  int nq = 0;
  for (int i = 0; i < md.n; ++i) {
    if (w.room[i] == kNoWall) continue;
    const double travel = st.v[i].norm() * dt;
    if (travel <= w.room[i]) continue;
    const bool contact = s.clearance[i] == 0.0;
    w.query_nodes[nq] = i;
    w.query_points[nq] = contact ? Vec3(st.x[i] + st.v[i] * dt) : st.x[i];
    w.query_radii[nq] = node_radius(md, i) + set.contact_margin + (contact ? 0.0 : travel);
    w.query_caches[nq] = &w.leaf_cache[i];
    ++nq;
  }
  if (nq == 0) return;
  query_wall(w, wall, nq, set.leaf_cache_slack);
  const std::size_t first = w.contacts.size();
  for (int k = 0; k < nq; ++k) {
    const SphereContact& h = w.hits[k];
    if (!h.touching) continue;
    const int i = w.query_nodes[k];
    const double r = node_radius(md, i);
    const double depth = h.centre_outside ? r + h.distance : r - h.distance;
    const Vec3 wall_v = wall.velocity(h);
    if (s.clearance[i] == 0.0) {
      // Its own wall (or one facing the same way) holds it already.
      if (h.normal.dot(w.contact_normal[i]) > kSameFace) continue;
      const double now = depth + dt * (st.v[i] - wall_v).dot(h.normal);
      w.contacts.push_back({i, h.normal, now, 0.0, Vec3::Zero(), wall_v});
      continue;
    }
    s.clearance[i] = 0.0;  // in contact: query again next step
    w.contacts.push_back({i, h.normal, depth, 0.0, Vec3::Zero(), wall_v});
  }
  if (w.contacts.size() == first) return;
  solve_contacts(in, set, first);
  for (int it = 0; it < kLateIterations; ++it) {
    if (set.rod.distance != DistanceMethod::kPenalty)
      rod_distance_iteration(in.model(), set.rod, in.rod(), in.ws());
    solve_contacts(in, set);
  }
}

void check_edges(const Inst& in, VesselWall& wall, const SolverSettings& set) {
  InstrumentScratch& w = *in.w;
  w.edge_escape = NodeEscape{};
  if (w.escape.node >= 0) return;  // a node of it was seen out this step
  const RodModel& md = in.model();
  const RodState& st = in.rod();
  const int first = in.driven() ? in.drive().first_free : 0;
  for (int i = first; i + 1 < md.n; ++i) {
    if (!free_node(in, i) || !free_node(in, i + 1)) continue;
    const Vec3& a = st.x[i];
    const Vec3& b = st.x[i + 1];
    const SegmentCrossings c = wall.segment_crossings(a, b);
    if (c.count < 2) continue;  // in and out again, or it is not through
    // Its deepest point: midway between where it goes in and out, queried as far as either.
    const double t = 0.5 * (c.first + c.last);
    const Vec3 p = a + t * (b - a);
    const double r = std::max(node_radius(md, i), node_radius(md, i + 1));
    const double reach = 0.5 * (c.last - c.first) * (b - a).norm() + r + set.contact_margin;
    SphereContact h;
    wall.query_spheres(std::span<const Vec3>(&p, 1), std::span<const double>(&reach, 1),
                       std::span<SphereContact>(&h, 1));
    if (h.touching && h.centre_outside && h.cap < 0 && h.distance > r &&
        h.distance > w.edge_escape.distance)
      w.edge_escape = {i, h.distance, -1, true, t};
  }
}

void fine_step(std::span<Inst> insts, std::span<const Pair> couplings, VesselWall* wall,
               const SolverSettings& set, std::span<const DriveCommand> cmds, StepProfile* prof) {
  const RodSettings& rs = set.rod;
  const bool collide = set.collisions && wall != nullptr;
  StepProfile p;
  auto tick = [&]() { return prof ? now_us() : 0.0; };
  const double t0 = tick();
  // Several instruments of 256 nodes or more: a region's work per instrument is worth a thread
  // (side by side, 2 x 256 nodes gain nothing yet, 2 x 512 run 25 % faster).
  int large = 0;
  for (const Inst& in : insts) large += !in.parked() && in.model().n >= 256 ? 1 : 0;
  const bool parallel = set.parallel_instruments && large >= 2;
  // Stage times of a region: each instrument records its own (InstrumentScratch::stage_us); a
  // parallel region takes as long as its longest instrument, a serial one as their sum.
  auto region = [&](int stage) {
    double r = 0.0;
    for (const Inst& in : insts) {
      if (in.parked()) continue;
      r = parallel ? std::max(r, in.w->stage_us[stage]) : r + in.w->stage_us[stage];
    }
    return r;
  };

  // 1. inputs: the drive holds the outside part; 2. forces, 3. velocities
  for_each_active(insts, parallel, [&](std::size_t k) {
    const Inst& in = insts[k];
    const double a = tick();
    rod_begin_step(in.model(), in.ws());
    std::fill(in.w->coupling_impulse.begin(), in.w->coupling_impulse.end(), Vec3::Zero());
    if (in.driven()) drive_begin(in, cmds[k], rs.dt);
    const double b = tick();
    rod_forces(in.model(), rs, in.rod(), in.ws());
    const double c = tick();
    rod_integrate_velocities(in.model(), rs, in.rod(), in.ws());
    in.w->stage_us = {b - a, c - b, tick() - c};
  });
  p.drive = region(0);
  p.forces = region(1);
  p.integrate_velocities = region(2);
  const double t3 = tick();
  // 4. collision detection: coupling first (sheathed wire nodes skip the wall), each inner's
  // innermost outer first; an inflated balloon's nodes are held to the vessel's axis instead
  for (const Inst& in : insts)
    if (!in.parked()) std::fill(in.w->sheathed.begin(), in.w->sheathed.end(), 0);
  double t_coup = 0.0;  // the coaxial pairs' detection, solve and projection
  for (std::size_t k = 0; k < couplings.size(); ++k) {
    const Pair& c = couplings[k];
    const Inst& in = insts[c.cm->inner];
    const Inst& out = insts[c.cm->outer];
    if (in.parked() || out.parked()) {
      c.s->contacts.clear();
      continue;
    }
    detect_coupling(c, static_cast<unsigned char>(k + 1), in, out, set);
  }
  const double t_detect = tick() - t3;
  t_coup += t_detect;
  const std::span<const WallExit> exits = collide ? wall->exits() : std::span<const WallExit>();
  for (const Inst& in : insts) {
    if (in.parked()) continue;
    if (collide) {
      detect_contacts(in, *wall, exits, set, &p);
      detect_edge_contacts(in, *wall, set, &p);
      add_access_end_contacts(in, exits, set);
    } else {
      in.w->contacts.clear();
      in.w->edge_contacts.clear();
    }
    add_sheath_contacts(in, set);
    add_hold_contacts(in, set);
  }
  const double t4 = tick();
  // 5. block iterations: distance chains and wall contacts with friction (each instrument on its
  // own), then the coaxial coupling between them. Walls before coupling: the wire must end each
  // iteration inside the catheter, and the catheter's wall contacts would otherwise move it away.
  double t_dist = 0.0, t_cont = 0.0;
  for (int it = 0; it < rs.iterations; ++it) {
    for_each_active(insts, parallel, [&](std::size_t k) {
      const Inst& in = insts[k];
      const double a = tick();
      if (rs.distance != DistanceMethod::kPenalty)
        rod_distance_iteration(in.model(), rs, in.rod(), in.ws());
      const double b = tick();
      solve_contacts(in, set);
      // An edge's contact and its nodes' own meet at a ridge from two sides (the carina between
      // the iliacs): one sweep, nodes first, leaves a node pushed back into its wall by the
      // edge's impulse. A second sweep brings them to agree (physics.md 6).
      if (!in.w->edge_contacts.empty()) solve_contacts(in, set);
      in.w->stage_us = {b - a, tick() - b, 0.0};
    });
    const double b = tick();
    for (const Pair& c : couplings)
      if (!c.s->contacts.empty()) solve_coupling(c, insts[c.cm->inner], insts[c.cm->outer], set);
    t_dist += region(0);
    t_cont += region(1);
    t_coup += tick() - b;
  }
  if (collide)
    for (const Inst& in : insts)
      if (!in.parked()) catch_late_movers(in, *wall, set);
  const double t5 = tick();
  // 6. positions, then the coupled wires exactly into their catheters' lumens
  for_each_active(insts, parallel, [&](std::size_t k) {
    rod_integrate_positions(insts[k].model(), rs, insts[k].rod(), insts[k].ws());
    remove_contact_bias(insts[k], set);
  });
  const double t5b = tick();
  for (std::size_t k = 0; k < couplings.size(); ++k) {
    const Pair& c = couplings[k];
    const Inst& in = insts[c.cm->inner];
    const Inst& out = insts[c.cm->outer];
    if (!in.parked() && !out.parked()) {
      project_coupling(c, static_cast<unsigned char>(k + 1), in, out);
      remove_coupling_bias(c, in, out, rs.dt, set.penetration_correction);
    }
  }
  const double t5c = tick();
  t_coup += t5c - t5b;
  for (const Inst& in : insts) {
    if (in.parked()) continue;
    if (in.driven()) drive_end(in);
  }
  // 7. what the hands feel, inner instruments first; then the rods' own end of step
  const double t5d = tick();
  hand_feedback(insts, couplings, set);
  for (const Inst& in : insts)
    if (!in.parked()) rod_end_step(in.model(), rs, in.rod(), in.ws());
  if (prof) {
    const double t6 = tick();
    p.collision = t4 - t3 - t_detect;
    p.constraints = t5 - t4;
    p.distance = t_dist;
    p.contacts = t_cont;
    p.integrate_positions = (t5b - t5) + (t5d - t5c);
    p.coupling = t_coup;
    p.feedback = t6 - t5d;
    p.total = t6 - t0;
    p.num_contacts = 0;
    for (const Inst& in : insts) p.num_contacts += static_cast<int>(in.w->contacts.size());
    *prof = p;
  }
}

}  // namespace vcsim::internal
