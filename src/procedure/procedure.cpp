// Balloons, lesions and stents (docs/procedure.md): the model of which nodes carry a balloon, the
// steps before and after the solver's, and the outcomes.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "vcsim/procedure.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

constexpr double kCone = 1.0e-3;           // m: a balloon's cone, from the shaft to its full radius
constexpr double kLocateWindow = 25e-3;    // m of arc length searched around the last location
constexpr double kDeflated = 1.0 * kAtm;   // Pa: below it a balloon lets its stent go
constexpr double kGrip = 0.95;             // a balloon this close to a stent's radius grips it
constexpr double kOverExpansion = 1.2;     // free diameter over reference diameter: an event
constexpr double kCrossingReach = 0.5e-3;  // m either side of a node a crossing widens
constexpr double kCrossingReachRadius = 2.0;  // the lumen a crossing makes, in its radii

// The balloon's free radius at a node `from_distal` m from its distal end, at working length
// `length`: full along the working length, tapering over the cones to the folded shaft.
double profile_radius(double full, double shaft, double from_distal, double length) {
  double f = 1.0;
  if (from_distal < 0.0) f = 1.0 + from_distal / kCone;
  if (from_distal > length) f = 1.0 - (from_distal - length) / kCone;
  f = std::clamp(f, 0.0, 1.0);
  return shaft + f * std::max(0.0, full - shaft);
}

std::size_t node_edges(const RodModel& md) {
  return static_cast<std::size_t>(md.m);
}

// Where ring k of a stent's n rings sits on its balloon: m from the balloon's distal end, the
// stent centred on the nominal working length (k = 0 at the stent's distal end).
double ring_from_distal(const BalloonModel& bm, std::size_t k, std::size_t n) {
  const double ls = bm.stent->length;
  return 0.5 * (bm.spec.length - ls) + ls * static_cast<double>(k) / static_cast<double>(n - 1);
}

// Linear interpolation of ys over xs at x, xs increasing or decreasing (clamped at the ends).
double interpolate(std::span<const double> xs, std::span<const double> ys, double x) {
  const std::size_t n = xs.size();
  if (n == 0) return 0.0;
  const bool down = n > 1 && xs.front() > xs.back();
  auto at = [&](std::span<const double> v, std::size_t i) { return down ? v[n - 1 - i] : v[i]; };
  if (x <= at(xs, 0)) return at(ys, 0);
  if (x >= at(xs, n - 1)) return at(ys, n - 1);
  std::size_t i = 0;
  while (i + 2 < n && at(xs, i + 1) < x) ++i;
  const double x0 = at(xs, i), x1 = at(xs, i + 1);
  const double f = x1 > x0 ? (x - x0) / (x1 - x0) : 0.0;
  return at(ys, i) + f * (at(ys, i + 1) - at(ys, i));
}

// The range of xs (increasing or decreasing).
std::pair<double, double> span_of(std::span<const double> xs) {
  return {std::min(xs.front(), xs.back()), std::max(xs.front(), xs.back())};
}

// The rest-anatomy point of p at time t (CardiacMotion::rest_point; p itself without motion).
Vec3 rest_point(const CardiacMotion* motion, const Vec3& p, double t) {
  return motion ? motion->rest_point(p, t) : p;
}

void hash_opening(StateHasher& h, const std::vector<LesionOpening>& v) {
  for (const LesionOpening& o : v) h.add(o.t);
}

// The instrument's inserted arc length of node i (m).
double inserted(const RodModel& md, const DriveState& dr, int i) {
  return md.node_s[i] - (md.length - dr.depth);
}

}  // namespace

const char* to_string(ProcedureEvent::Kind k) {
  switch (k) {
    case ProcedureEvent::Kind::kRupture:
      return "balloon rupture";
    case ProcedureEvent::Kind::kOverExpansion:
      return "over-expansion";
    case ProcedureEvent::Kind::kStentDeployed:
      return "stent deployed";
    case ProcedureEvent::Kind::kPressureRefused:
      return "pressure refused: no balloon in the patient";
  }
  return "?";
}

// --- model ---------------------------------------------------------------------------------------

BalloonModel make_balloon_model(const SolverModel& solver, std::span<const InstrumentSpec> specs,
                                int instrument) {
  const auto i = static_cast<std::size_t>(instrument);
  const BalloonSpec& b = *specs[i].balloon;
  const RodModel& md = solver.instruments[i].rod();
  BalloonModel bm;
  bm.instrument = instrument;
  bm.catalogue = specs[i].name;
  bm.spec = b;
  bm.stent = specs[i].stent;
  bm.shaft_radius = 0.5 * b.crossing_profile;
  for (const CouplingModel& c : solver.couplings)
    if (c.inner == instrument) bm.outers.push_back(c.outer);
  const double distal = md.length - b.distal_offset;  // arc length of its distal end
  const double longest = b.length_at(b.rated_burst_pressure);
  bm.first = md.n;
  for (int j = 0; j < md.n; ++j) {
    const double from_distal = distal - md.node_s[j];
    if (from_distal < -kCone || from_distal > longest + kCone) continue;
    bm.first = std::min(bm.first, j);
    bm.last = j;
  }
  if (bm.nodes() < 3)
    throw InputError(specs[i].source, "balloon",
                     "expected at least 3 rod nodes along the balloon (a finer tip_segment_mm)");
  for (int j = bm.first; j <= bm.last; ++j) {
    bm.from_distal.push_back(distal - md.node_s[j]);
    const double lo = j > 0 ? 0.5 * (md.node_s[j - 1] + md.node_s[j]) : md.node_s[j];
    const double hi = j + 1 < md.n ? 0.5 * (md.node_s[j] + md.node_s[j + 1]) : md.node_s[j];
    bm.node_length.push_back(hi - lo);
  }
  return bm;
}

double stent_ring_from_distal(const BalloonModel& balloon, std::size_t k, std::size_t n) {
  return ring_from_distal(balloon, k, n);
}

ProcedureModel make_procedure_model(const VesselTree& tree, const Lumen& lumen,
                                    const SolverModel& solver,
                                    std::span<const InstrumentSpec> specs,
                                    std::span<const LesionMechanics> mechanics) {
  ProcedureModel m;
  for (std::size_t i = 0; i < specs.size(); ++i)
    if (specs[i].balloon)
      m.balloons.push_back(make_balloon_model(solver, specs, static_cast<int>(i)));
  if (!mechanics.empty() && mechanics.size() != tree.lesions.size())
    throw InputError("procedure", "lesions", "expected mechanics for every lesion of the tree");
  for (std::size_t k = 0; k < tree.lesions.size(); ++k) {
    const Lesion& les = tree.lesions[k];
    LesionModel lm;
    lm.lesion = static_cast<int>(k);
    lm.span = lesion_span(tree, les);
    if (!mechanics.empty()) lm.mechanics = mechanics[k];
    const VesselSegment& seg = tree.segments[les.segment];
    lm.reference_diameter = radius_at(seg, lm.span.s0) + radius_at(seg, lm.span.s1);
    m.spans.push_back(lm.span);
    m.lesions.push_back(lm);
  }
  m.morph = make_lesion_morph(tree, lumen);
  m.morph_limit.resize(m.morph.vertices.size());
  morph_positions(lumen, m.morph, ProcedureModel::kMaxOpening, m.morph_limit);
  return m;
}

// --- state ---------------------------------------------------------------------------------------

ProcedureState make_procedure_state(const ProcedureModel& m, SolverState& solver) {
  ProcedureState s;
  extend_procedure_state(m, s, solver);
  LesionOpening zero;
  zero.t.assign(kLesionSamples, 0.0);
  s.opening.assign(m.lesions.size(), zero);
  s.max_opening.assign(m.lesions.size(), zero);
  s.stent_hold.assign(m.lesions.size(), zero);
  s.pushed.assign(m.lesions.size(), zero);
  s.crossed.assign(m.lesions.size(), zero);
  s.wall_opening.assign(m.lesions.size(), zero);
  s.events.reserve(64);
  return s;
}

void extend_procedure_state(const ProcedureModel& m, ProcedureState& s, SolverState& solver) {
  const std::size_t from = s.balloons.size();
  s.balloons.resize(m.balloons.size());
  s.stents.resize(m.balloons.size());
  for (std::size_t b = from; b < m.balloons.size(); ++b) {
    const BalloonModel& bm = m.balloons[b];
    s.balloons[b].radius.assign(bm.nodes(), bm.shaft_radius);
    s.balloons[b].s.assign(bm.nodes(), 0.0);
    s.balloons[b].lumen.assign(bm.nodes(), 1.0);
    s.balloons[b].lumen_s.assign(bm.nodes(), -1.0);
    s.balloons[b].centre.segment = -1;
    s.balloons[b].hold_excess.assign(bm.nodes(), -1.0);
    if (bm.stent) {
      const int rings = std::max(2, static_cast<int>(std::ceil(bm.stent->length / 0.5e-3)) + 1);
      s.stents[b].expanded.assign(rings, 0.5 * bm.stent->crimped_profile);
      s.stents[b].ring_s.assign(rings, 0.0);
      s.stents[b].ring_radius.assign(rings, 0.0);
    }
    if (bm.removed()) continue;
    // The hold's arrays sized once: inflating allocates nothing.
    InstrumentState& in = solver.instruments[bm.instrument];
    const std::size_t n = in.rod.x.size();
    BalloonHold& h = in.hold;
    h.axis.assign(n, Vec3::Zero());
    h.tangent.assign(n, Vec3::UnitZ());
    h.axis_velocity.assign(n, Vec3::Zero());
    h.play.assign(n, 0.0);
    h.wall_load.assign(n, 0.0);
    h.clear();
  }
}

void ProcedureState::hash_into(StateHasher& h) const {
  for (const BalloonState& b : balloons) {
    for (double v : {b.pressure, b.max_pressure, b.free_diameter, b.centre.distance, b.max_ratio,
                     b.mid_rest.x(), b.mid_rest.y(), b.mid_rest.z()})
      h.add_value(v);
    h.add_value(b.centre.segment);
    h.add_value(b.ruptured);
    h.add_value(b.over_expanded);
    h.add(b.radius);
    h.add(b.lumen);
    h.add(b.lumen_s);
    h.add_value(b.lumen_time);
    h.add_value(b.lumen_epoch);
    h.add(b.s);
    h.add(b.hold_excess);
  }
  for (const StentState& s : stents) {
    h.add_value(static_cast<int>(s.phase));
    h.add(s.expanded);
    h.add_value(s.segment);
    h.add(s.ring_s);
    h.add(s.ring_radius);
    h.add_value(s.deployed_at);
  }
  hash_opening(h, opening);
  hash_opening(h, max_opening);
  hash_opening(h, stent_hold);
  hash_opening(h, pushed);
  hash_opening(h, crossed);
  hash_opening(h, wall_opening);
  h.add_value(wall_epoch);
  for (const ProcedureEvent& e : events) {
    h.add_value(static_cast<int>(e.kind));
    h.add_value(e.time);
    h.add_value(e.balloon);
    h.add_value(e.value);
  }
  h.add_value(refusing);
}

double lumen_radius_now(const ProcedureModel& m, const VesselTree& tree, const ProcedureState& s,
                        int segment, double arc) {
  return lumen_section(tree, m.spans, s.opening, segment, arc).radius;
}

// --- step ----------------------------------------------------------------------------------------

namespace {

// The stenosed-to-opened mapping of one lesion sample's balloon push: where the balloon's free
// radius along its nodes (rs over ss, increasing s) covers the sample.
void push_lesions(const ProcedureModel& m, const VesselTree& tree, int segment,
                  std::span<const double> ss, std::span<const double> rs, double pressure,
                  ProcedureState& ps) {
  const auto [lo, hi] = span_of(ss);
  for (std::size_t k = 0; k < m.lesions.size(); ++k) {
    const LesionModel& lm = m.lesions[k];
    const Lesion& les = tree.lesions[lm.lesion];
    if (les.segment != segment || pressure < lm.mechanics.opening_pressure) continue;
    std::vector<double>& pushed = ps.pushed[k].t;
    const auto n = static_cast<double>(pushed.size() - 1);
    for (std::size_t u = 0; u < pushed.size(); ++u) {
      const double s = lm.span.s0 + (lm.span.s1 - lm.span.s0) * static_cast<double>(u) / n;
      if (s < lo || s > hi) continue;
      const double r = interpolate(ss, rs, s);
      const double t =
          std::min(ProcedureModel::kMaxOpening, opening_for_radius(tree, les, lm.span, s, r));
      pushed[u] = std::max(pushed[u], t);
    }
  }
}

// The stent's hold on the lesions under its rings: the opening at which the lumen is the ring's.
void hold_lesions(const ProcedureModel& m, const VesselTree& tree, const StentState& stent,
                  ProcedureState& ps) {
  for (std::size_t k = 0; k < m.lesions.size(); ++k) {
    const LesionModel& lm = m.lesions[k];
    const Lesion& les = tree.lesions[lm.lesion];
    if (les.segment != stent.segment) continue;
    std::vector<double>& hold = ps.stent_hold[k].t;
    const auto n = static_cast<double>(hold.size() - 1);
    for (std::size_t u = 0; u < hold.size(); ++u) {
      const double s = lm.span.s0 + (lm.span.s1 - lm.span.s0) * static_cast<double>(u) / n;
      if (s < stent.ring_s.front() || s > stent.ring_s.back()) continue;
      const double r = interpolate(stent.ring_s, stent.ring_radius, s);
      hold[u] = std::max(hold[u], std::min(ProcedureModel::kMaxOpening,
                                           opening_for_radius(tree, les, lm.span, s, r)));
    }
  }
}

// The Dotter effect: a node pressing a lesion's plaque beyond its crossing force widens the lumen
// there at the crossing rate (plastic: the plaque stays compressed). Without it a rigid plaque
// stopped a 0.70 mm balloon shaft in a 70 % stenosis (MLD 0.85 mm) it geometrically fits through
// (docs/procedure.md, crossing).
void cross_lesions(const ProcedureModel& m, const SolverModel& sm, const VesselTree& tree,
                   const CardiacMotion* motion, double time, double dt, ProcedureState& ps,
                   const SolverState& solver, const SolverWorkspace& sws) {
  if (m.lesions.empty()) return;
  const double fine_dt = sm.settings[static_cast<std::size_t>(solver.split - 1)].rod.dt;
  for (std::size_t i = 0; i < solver.instruments.size(); ++i) {
    const InstrumentState& in = solver.instruments[i];
    if (in.parked || in.hold.active()) continue;
    for (const NodeContact& c : sws.contacts(static_cast<int>(i))) {
      for (std::size_t k = 0; k < m.lesions.size(); ++k) {
        const LesionModel& lm = m.lesions[k];
        if (c.lambda_n < lm.mechanics.crossing_force * fine_dt) continue;
        const Lesion& les = tree.lesions[static_cast<std::size_t>(lm.lesion)];
        const Vec3 x = rest_point(motion, in.rod.x[static_cast<std::size_t>(c.node)], time);
        const TreeLocation mid{les.segment, 0.5 * (lm.span.s0 + lm.span.s1)};
        const TreeHit hit = locate_near(tree, x, mid, lm.span.s1 - lm.span.s0);
        if (hit.loc.segment != les.segment) continue;
        const double s = hit.loc.distance;
        if (s <= lm.span.s0 || s >= lm.span.s1) continue;
        // Compressed by a channel at most the instrument's diameter deep into the plaque: the
        // concentric lumen at most twice its radius (the node presses one side).
        const RodModel& md = sm.instruments[i].rod();
        const auto node = static_cast<std::size_t>(c.node);
        const double own = std::max(md.outer_radius[std::min(node, node_edges(md) - 1)],
                                    node > 0 ? md.outer_radius[node - 1] : 0.0);
        const double now = lumen_radius_now(m, tree, ps, les.segment, s);
        if (now >= kCrossingReachRadius * own) continue;
        const double r =
            std::min(now + lm.mechanics.crossing_rate * dt, kCrossingReachRadius * own);
        const double t =
            std::min(ProcedureModel::kMaxOpening, opening_for_radius(tree, les, lm.span, s, r));
        // The node's neighbourhood (its sphere's length along the vessel) widens with it.
        std::vector<double>& cr = ps.crossed[k].t;
        const auto n = static_cast<double>(cr.size() - 1);
        for (std::size_t u = 0; u < cr.size(); ++u) {
          const double su = lm.span.s0 + (lm.span.s1 - lm.span.s0) * static_cast<double>(u) / n;
          if (std::abs(su - s) <= kCrossingReach) cr[u] = std::max(cr[u], t);
        }
      }
    }
  }
}

void add_event(ProcedureState& ps, ProcedureEvent::Kind kind, double time, int balloon,
               double value) {
  ps.events.push_back({kind, time, balloon, value});
}

}  // namespace

void procedure_before_step(const ProcedureModel& m, const SolverModel& sm, const VesselTree& tree,
                           const CardiacMotion* motion, const StepCommands& cmds, double t, double,
                           ProcedureState& ps, SolverState& solver) {
  const double p_cmd = std::max(0.0, cmds.balloon_pressure);
  for (LesionOpening& o : ps.pushed) std::fill(o.t.begin(), o.t.end(), 0.0);
  bool any_inside = false;
  // 1. pressure, rupture, location, the free radius along the balloon; the lesions it pushes
  for (std::size_t b = 0; b < m.balloons.size(); ++b) {
    const BalloonModel& bm = m.balloons[b];
    BalloonState& st = ps.balloons[b];
    if (bm.removed()) continue;  // outside the patient, uninflated, since its removal
    InstrumentState& in = solver.instruments[bm.instrument];
    const RodModel& md = sm.instruments[bm.instrument].rod();
    const BalloonSpec& spec = bm.spec;
    // In the patient: the whole balloon past the access point.
    const bool inside = !in.parked && inserted(md, in.drive, bm.first) > 0.0;
    any_inside = any_inside || inside;
    double p = inside && !st.ruptured ? p_cmd : 0.0;
    if (p > spec.rated_burst_pressure) {
      st.ruptured = true;
      add_event(ps, ProcedureEvent::Kind::kRupture, t, static_cast<int>(b), p);
      p = 0.0;
    }
    st.pressure = p;
    st.max_pressure = std::max(st.max_pressure, p);
    st.free_diameter = p > 0.0 ? spec.diameter_at(p) : spec.crossing_profile;
    in.hold.clear();
    std::fill(st.radius.begin(), st.radius.end(), bm.shaft_radius);
    if (p <= 0.0) {
      st.centre.segment = -1;
      std::fill(st.hold_excess.begin(), st.hold_excess.end(), -1.0);
      continue;
    }
    // Inside the guide (its middle within an outer's inserted length): the guide holds it.
    const int mid = bm.first + bm.nodes() / 2;
    bool in_guide = false;
    for (int o : bm.outers)
      in_guide = in_guide || inserted(md, in.drive, mid) < solver.instruments[o].drive.depth;
    if (in_guide) {
      st.centre.segment = -1;
      std::fill(st.hold_excess.begin(), st.hold_excess.end(), -1.0);
      continue;
    }
    st.mid_rest = rest_point(motion, in.rod.x[mid], t);
    const TreeHit hit = locate_near(tree, st.mid_rest, st.last, kLocateWindow);
    st.centre = st.last = hit.loc;
    const VesselSegment& seg = tree.segments[hit.loc.segment];
    const double len = segment_length(seg);
    const double full = 0.5 * st.free_diameter;
    const double working = spec.length_at(p);
    // Along the vessel's flow (a coronary, antegrade) or against it (retrograde).
    const Vec3 along = in.rod.x[bm.last] - in.rod.x[bm.first];
    const double sign = along.dot(tangent_at(seg, hit.loc.distance)) >= 0.0 ? 1.0 : -1.0;
    for (int j = 0; j < bm.nodes(); ++j) {
      const double off = sign * (md.node_s[bm.first + j] - md.node_s[mid]);
      st.s[j] = std::clamp(hit.loc.distance + off, 0.0, len);
      st.radius[j] = profile_radius(full, bm.shaft_radius, bm.from_distal[j], working);
    }
    push_lesions(m, tree, hit.loc.segment, st.s, st.radius, p, ps);
    const double ratio = st.free_diameter / (2.0 * radius_at(seg, hit.loc.distance));
    st.max_ratio = std::max(st.max_ratio, ratio);
    if (ratio > kOverExpansion && !st.over_expanded) {
      st.over_expanded = true;
      add_event(ps, ProcedureEvent::Kind::kOverExpansion, t, static_cast<int>(b), ratio);
    }
  }
  if (p_cmd > 0.0 && !any_inside && !m.balloons.empty() && !ps.refusing)
    add_event(ps, ProcedureEvent::Kind::kPressureRefused, t, -1, p_cmd);
  ps.refusing = p_cmd > 0.0 && !any_inside;
  // 2. each lesion as open as a balloon pushes it, its elastic part of the most it was opened,
  // or its stent holds it
  for (std::size_t k = 0; k < m.lesions.size(); ++k) {
    const double keep = 1.0 - m.lesions[k].mechanics.recoil;
    std::vector<double>& o = ps.opening[k].t;
    std::vector<double>& mx = ps.max_opening[k].t;
    const std::vector<double>& pu = ps.pushed[k].t;
    const std::vector<double>& ho = ps.stent_hold[k].t;
    const std::vector<double>& cr = ps.crossed[k].t;
    for (std::size_t u = 0; u < o.size(); ++u) {
      mx[u] = std::max(mx[u], pu[u]);
      o[u] = std::max({pu[u], keep * mx[u], ho[u], cr[u]});
    }
    std::vector<double>& w = ps.wall_opening[k].t;
    bool moved = false;
    for (std::size_t u = 0; u < o.size() && !moved; ++u)
      moved = std::abs(o[u] - w[u]) > ProcedureState::kWallOpeningStep;
    if (moved) {
      w = o;
      ++ps.wall_epoch;
    }
  }
}

namespace {

// The distance from a point on the vessel's axis to the nearest wall point, as far as it matters
// to a balloon of free radius `free` (beyond it: `free` itself is the answer). The probe starts
// just past the smaller of `free` and the model's section radius `section`, where the wall is
// expected, so that it overlaps only the band of triangles near the nearest point.
double fit_lumen(VesselWall& wall, const Vec3& axis, double free, double section) {
  constexpr double kProbe = 0.05e-3;  // m past the expected wall
  for (double probe : {std::min(free, section) + kProbe, free + kProbe}) {
    SphereContact hit;
    wall.query_spheres(std::span<const Vec3>(&axis, 1), std::span<const double>(&probe, 1),
                       std::span<SphereContact>(&hit, 1));
    if (hit.touching && !hit.centre_outside) return hit.distance;
    if (probe >= free) break;
  }
  return free + kProbe;
}

}  // namespace

void procedure_fit(const ProcedureModel& m, const SolverModel& sm, const VesselTree& tree,
                   const CardiacMotion* motion, VesselWall& wall, double t1, ProcedureState& ps,
                   SolverState& solver) {
  // The balloons fitted to the lumen as the wall now is (its lesions opened): each node's radius
  // stops at the nearest wall point from the vessel's axis; their holds on the nodes, at t1.
  wall.set_time(t1);
  for (std::size_t b = 0; b < m.balloons.size(); ++b) {
    const BalloonModel& bm = m.balloons[b];
    BalloonState& st = ps.balloons[b];
    if (st.centre.segment < 0) continue;
    const RodModel& md = sm.instruments[bm.instrument].rod();
    BalloonHold& h = solver.instruments[bm.instrument].hold;
    const std::vector<Vec3>& x = solver.instruments[bm.instrument].rod.x;
    const double unfold =
        bm.spec.chart_pressure.empty() ? bm.spec.nominal_pressure : bm.spec.chart_pressure.front();
    const VesselSegment& seg = tree.segments[st.centre.segment];
    const double working = bm.spec.length_at(st.pressure);
    const double full = 0.5 * st.free_diameter;
    h.first = md.n;
    h.last = -1;
    for (int j = 0; j < bm.nodes(); ++j) {
      const int node = bm.first + j;
      const auto e = static_cast<std::size_t>(j);
      const double free = profile_radius(full, bm.shaft_radius, bm.from_distal[j], working);
      if (free <= bm.shaft_radius) {
        st.hold_excess[e] = -1.0;
        continue;
      }
      const double arc = st.s[e];
      const LumenSection sec = lumen_section(tree, m.spans, ps.opening, st.centre.segment, arc);
      const Vec3 axis =
          motion ? Vec3(sec.centre + motion->displacement(sec.centre, t1)) : sec.centre;
      // The lumen's radius there on the wall itself: the nearest wall point from the axis
      // (iterative collision detection, VCSim3's fit, by exact queries), measured again when
      // the node has moved on along the vessel, the wall changed shape or kRefit has passed.
      const bool fresh = st.lumen_epoch == ps.wall_epoch &&
                         t1 - st.lumen_time < BalloonState::kRefit &&
                         std::abs(arc - st.lumen_s[e]) < BalloonState::kRefitMove;
      if (!fresh) {
        st.lumen[e] = fit_lumen(wall, axis, free, sec.radius);
        st.lumen_s[e] = arc;
      }
      const double lumen = st.lumen[e];
      const double r = std::min(free, lumen);
      st.radius[e] = r;
      h.first = std::min(h.first, node);
      h.last = std::max(h.last, node);
      const Vec3 tangent = tangent_at(seg, arc);
      h.axis[node] = axis;
      h.tangent[node] = tangent;
      h.axis_velocity[node] = motion ? motion->velocity(sec.centre, t1) : Vec3::Zero();
      // Within lumen - r of the axis once unfolded. A node that lay farther out when the balloon
      // began to press (the folded balloon is wider than the shaft that lay on the wall) is
      // brought in as it unfolds, over the pressure its chart starts at; drawn onto the axis in
      // one step, it jerked the shaft and the guide around it (1.8 N on the guide's hand in the
      // default run as the pressure began to rise).
      const double play = std::max(0.0, lumen - r);
      if (st.hold_excess[e] < 0.0) {
        const Vec3 rel = x[static_cast<std::size_t>(node)] - axis;
        st.hold_excess[e] = std::max(0.0, (rel - rel.dot(tangent) * tangent).norm() - play);
      }
      h.play[node] = play + st.hold_excess[e] * std::clamp(1.0 - st.pressure / unfold, 0.0, 1.0);
      // Pressed on the wall all round: p times the balloon's surface at the node.
      h.wall_load[node] = free >= lumen ? st.pressure * 2.0 * kPi * r * bm.node_length[j] : 0.0;
    }
    if (st.lumen_epoch != ps.wall_epoch || t1 - st.lumen_time >= BalloonState::kRefit) {
      st.lumen_epoch = ps.wall_epoch;
      st.lumen_time = t1;
    }
    // A stent crimped on it expands with it, each ring to the balloon's profile where it sits
    // (centred on the working length) or the lumen there, whichever is smaller.
    if (bm.stent && ps.stents[b].phase == StentState::Phase::kCrimped) {
      std::vector<double>& ex = ps.stents[b].expanded;
      for (std::size_t k = 0; k < ex.size(); ++k) {
        const double fd = ring_from_distal(bm, k, ex.size());
        const double free = profile_radius(full, bm.shaft_radius, fd, working);
        ex[k] = std::max(ex[k], std::min(free, interpolate(bm.from_distal, st.lumen, fd)));
      }
    }
  }
}

void procedure_after_step(const ProcedureModel& m, const SolverModel& sm, const VesselTree& tree,
                          const CardiacMotion* motion, double time, double dt, ProcedureState& ps,
                          const SolverState& solver, const SolverWorkspace& sws) {
  cross_lesions(m, sm, tree, motion, time, dt, ps, solver, sws);
  for (std::size_t b = 0; b < m.balloons.size(); ++b) {
    const BalloonModel& bm = m.balloons[b];
    if (!bm.stent) continue;
    StentState& stent = ps.stents[b];
    const BalloonState& st = ps.balloons[b];
    // Released: its balloon deflated (in a vessel) after expanding it well past its crimp.
    if (stent.phase == StentState::Phase::kCrimped) {
      if (bm.removed()) continue;  // left the scene crimped on its balloon
      const double crimp = 0.5 * bm.stent->crimped_profile;
      const double most = *std::max_element(stent.expanded.begin(), stent.expanded.end());
      // (Passing kDeflated on the way up while inflating is not a release.)
      if (st.pressure >= kDeflated || st.max_pressure < 2.0 * kDeflated || most < 1.2 * crimp)
        continue;
      // Where the balloon last lay inflated in the vessel: each ring stays where it sat on the
      // balloon (its place from the balloon's distal end mapped through the nodes' arc lengths).
      if (st.last.segment < 0) continue;
      stent.phase = StentState::Phase::kDeployed;
      ++ps.wall_epoch;
      stent.segment = st.last.segment;
      stent.deployed_at = time;
      const std::size_t n = stent.ring_s.size();
      const double seg_len = segment_length(tree.segments[stent.segment]);
      const double recoil = 1.0 - bm.stent->acute_recoil;
      for (std::size_t k = 0; k < n; ++k) {
        const double fd = ring_from_distal(bm, k, n);
        stent.ring_s[k] = std::clamp(interpolate(bm.from_distal, st.s, fd), 0.0, seg_len);
        stent.ring_radius[k] = recoil * stent.expanded[k];
      }
      // Along the segment (k = 0 was the distal end: last for a balloon pointing downstream).
      if (stent.ring_s.front() > stent.ring_s.back()) {
        std::reverse(stent.ring_s.begin(), stent.ring_s.end());
        std::reverse(stent.ring_radius.begin(), stent.ring_radius.end());
      }
      hold_lesions(m, tree, stent, ps);
      add_event(ps, ProcedureEvent::Kind::kStentDeployed, time, static_cast<int>(b),
                2.0 * stent.ring_radius[stent.ring_radius.size() / 2]);
      continue;
    }
    // Deployed: a balloon inflated inside it grips it: enlarges it (post-dilation) and carries it.
    for (std::size_t g = 0; g < m.balloons.size(); ++g) {
      const BalloonState& gb = ps.balloons[g];
      if (gb.centre.segment != stent.segment || gb.pressure <= 0.0) continue;
      bool grips = false;
      const double recoil = 1.0 - bm.stent->acute_recoil;
      const auto [lo, hi] = span_of(gb.s);
      for (std::size_t k = 0; k < stent.ring_s.size(); ++k) {
        const double s = stent.ring_s[k];
        if (s < lo || s > hi) continue;
        const double r = interpolate(gb.s, gb.radius, s);
        if (r >= kGrip * stent.ring_radius[k]) {
          grips = true;
          stent.ring_radius[k] = std::max(stent.ring_radius[k], recoil * r);
        }
      }
      if (!grips) continue;
      ++ps.wall_epoch;
      hold_lesions(m, tree, stent, ps);
      // Carried: the balloon's middle moved along the vessel this step.
      const BalloonModel& gm = m.balloons[g];
      const Vec3 now = rest_point(
          motion, solver.instruments[gm.instrument].rod.x[gm.first + gm.nodes() / 2], time);
      const Vec3 tan = tangent_at(tree.segments[stent.segment], gb.centre.distance);
      const double moved = (now - gb.mid_rest).dot(tan);
      for (double& s : stent.ring_s) s += moved;
    }
  }
}

// --- outcomes ------------------------------------------------------------------------------------

ProcedureOutcome procedure_outcome(const ProcedureModel& m, const VesselTree& tree,
                                   const ProcedureState& ps) {
  ProcedureOutcome out;
  constexpr int kSamples = 200;
  for (std::size_t k = 0; k < m.lesions.size(); ++k) {
    const LesionModel& lm = m.lesions[k];
    const int seg = tree.lesions[lm.lesion].segment;
    LesionOutcome o;
    o.reference_diameter = lm.reference_diameter;
    o.mld_before = o.mld_now = 1e300;
    for (int i = 0; i <= kSamples; ++i) {
      const double s = lm.span.s0 + (lm.span.s1 - lm.span.s0) * i / kSamples;
      o.mld_before = std::min(o.mld_before, 2.0 * lumen_section(tree, m.spans, {}, seg, s).radius);
      o.mld_now =
          std::min(o.mld_now, 2.0 * lumen_section(tree, m.spans, ps.opening, seg, s).radius);
    }
    o.stenosis_before = 1.0 - o.mld_before / o.reference_diameter;
    o.stenosis_now = 1.0 - o.mld_now / o.reference_diameter;
    out.lesions.push_back(o);
  }
  for (std::size_t b = 0; b < m.balloons.size(); ++b) {
    const BalloonState& st = ps.balloons[b];
    out.balloons.push_back(
        {m.balloons[b].removed(), st.max_pressure, st.max_ratio, st.ruptured, st.over_expanded});
    if (!m.balloons[b].stent) continue;
    const StentState& stent = ps.stents[b];
    StentOutcome so;
    so.deployed = stent.phase == StentState::Phase::kDeployed;
    if (so.deployed) {
      so.diameter_min = 2.0 * *std::min_element(stent.ring_radius.begin(), stent.ring_radius.end());
      so.diameter_max = 2.0 * *std::max_element(stent.ring_radius.begin(), stent.ring_radius.end());
      so.start = stent.ring_s.front();
      so.end = stent.ring_s.back();
      for (std::size_t k = 0; k < m.lesions.size(); ++k) {
        const LesionModel& lm = m.lesions[k];
        if (tree.lesions[lm.lesion].segment != stent.segment) continue;
        if (so.end < lm.span.s0 - 10e-3 || so.start > lm.span.s1 + 10e-3) continue;
        so.lesion = static_cast<int>(k);
        so.longitudinal_offset = 0.5 * (so.start + so.end) - 0.5 * (lm.span.s0 + lm.span.s1);
        so.geographic_miss = so.start > lm.span.s0 - 2e-3 || so.end < lm.span.s1 + 2e-3;
      }
      for (std::size_t k = 0; k < stent.ring_s.size(); ++k) {
        const double lumen =
            lumen_section(tree, m.spans, ps.opening, stent.segment, stent.ring_s[k]).radius;
        so.malapposition = std::max(so.malapposition, lumen - stent.ring_radius[k]);
      }
    }
    out.stents.push_back(so);
  }
  return out;
}

}  // namespace vcsim
