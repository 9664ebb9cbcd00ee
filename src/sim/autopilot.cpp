// The autopilot: a closed-loop operator that acts only through the hands' commands at the sheath
// (insertion depth and roll per instrument), reading tip positions as a trainee reads the screen
// (docs/scenarios.md). Navigation follows the centreline route to a goal: the shaped tip is
// turned toward where the route goes next, the instrument advances while the tip makes progress,
// and it backs off and retries with the tip turned when it stops or enters a wrong branch.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "vcsim/sim.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

constexpr double kSpacing = 1e-3;         // m between route points
constexpr double kProgressStep = 1e-3;    // m of progress that counts as moving on
constexpr double kPlaceApproach = 70e-3;  // m of route before a lesion: out of the guide (place)
constexpr double kPlacedTime = 0.5;       // s a place's watch of the markers lasts on a still heart
constexpr double kPlacePast =
    3e-3;  // m past the lesion's middle a stent is taken before drawn back
constexpr double kDrawSpeed = 1e-3;   // m/s: the hand draws a stent back
constexpr double kDrawSlack = 5e-3;   // m/s: the hand takes up the shaft's slack first
constexpr double kDrawSeen = 0.5e-3;  // m the markers come back from past before the slack is up
constexpr double kDrawMost =
    40e-3;  // m drawn back without the markers reaching the middle: give up
constexpr double kMostAdjust = 2e-3;           // m: the most the hand moves between two watches
constexpr int kMaxWatches = 8;                 // watches before a place is taken as it is
constexpr double kPlaceBeyond = 20e-3;         // m the place route runs on past the lesion's middle
constexpr double kPositionCheck = 4.0 * kAtm;  // Pa: markers watched while inflating below it
constexpr double kNudgeSpeed = 2e-3;           // m/s: the hand's correction then
constexpr double kLookAhead = 12e-3;           // m along the route the tip is aimed at
constexpr double kBranchAhead = 40e-3;         // m: a branch this close ahead is aimed at
constexpr double kHoldLost = 1.5;       // s out of reach before a held tip counts as fallen out
constexpr double kHoldReach = 8e-3;     // m: a held tip farther than this from its route is lost
constexpr double kHoldDeadband = 2e-3;  // m of tip displacement the hand lets pass
constexpr double kHoldGain = 3.0;       // 1/s: depth correction per metre of tip displacement
constexpr double kHoldRange = 15e-3;    // m either way of the seated depth
constexpr double kApproach = 30e-3;     // m before the goal where the advance slows down
constexpr double kDeadband = 10.0 * kPi / 180.0;
constexpr double kInOuter = 10e-3;     // m: an inner instrument this far short of its outer's depth
constexpr double kEngageNear = 20e-3;  // m: within this of an ostium, brought to its level
constexpr double kMaxRoll = kPi / 2;   // steering stays within a quarter turn of the phase start

// Distal direction of the instrument's shaft just proximal to its shaped tip, and of the tip.
// Index of the point nearest X (the first of equals). With `s`, only the points whose s lies
// within `window` of `centre` count; if none does, 0.
std::size_t nearest_point(const std::vector<Vec3>& pts, const Vec3& X,
                          const std::vector<double>* s = nullptr, double centre = 0.0,
                          double window = 0.0) {
  std::size_t best = 0;
  double best_d = 1e300;
  for (std::size_t k = 0; k < pts.size(); ++k) {
    if (s && std::abs((*s)[k] - centre) > window) continue;
    const double d = (pts[k] - X).squaredNorm();
    if (d < best_d) {
      best_d = d;
      best = k;
    }
  }
  return best;
}

// How far p lies outside segment seg's lumen as the tree locator measures it (its distance to
// the nearest centreline edge less the radius there; negative inside).
double tube_outside(const VesselSegment& seg, const Vec3& p) {
  double best = 1e300;
  for (std::size_t k = 0; k + 1 < seg.points.size(); ++k) {
    const Vec3 d = seg.points[k + 1] - seg.points[k];
    const double len2 = d.squaredNorm();
    const double t = len2 > 0.0 ? std::clamp((p - seg.points[k]).dot(d) / len2, 0.0, 1.0) : 0.0;
    const double r = seg.radii[k] + t * (seg.radii[k + 1] - seg.radii[k]);
    best = std::min(best, (p - (seg.points[k] + t * d)).norm() - r);
  }
  return best;
}

// Arc length along segment i (not the root) where its centreline leaves its parent's lumen: up
// to there the two overlap (a junction), and a tip the locator puts in i may as well be in the
// parent (at the aortic bifurcation the iliacs' first millimetres, about the aorta's radius
// there, lie in its end).
double junction_exit(const VesselTree& tree, int i) {
  const VesselSegment& seg = tree.segments[static_cast<std::size_t>(i)];
  const VesselSegment& parent = tree.segments[static_cast<std::size_t>(seg.parent)];
  double s = 0.0;
  for (std::size_t k = 0; k < seg.points.size(); ++k) {
    if (k > 0) s += (seg.points[k] - seg.points[k - 1]).norm();
    if (tube_outside(parent, seg.points[k]) > 0.0) return s;
  }
  return s;
}

void tip_directions(const RodModel& md, const InstrumentState& in, double shaped, Vec3& shaft,
                    Vec3& tipdir) {
  const auto& x = in.rod.x;
  const int n = md.n;
  tipdir = (x[n - 1] - x[n - 2]).normalized();
  // Nodes about shaped + 5 mm and shaped + 15 mm from the tip.
  auto node_at = [&](double from_tip) {
    const double s = md.length - from_tip;
    int i = n - 1;
    while (i > 0 && md.node_s[i] > s) --i;
    return std::max(i, in.drive.first_free);
  };
  const int a = node_at(shaped + 15e-3), b = node_at(shaped + 5e-3);
  shaft = a < b ? Vec3((x[b] - x[a]).normalized()) : tipdir;
}

}  // namespace

Autopilot::Autopilot(const SimModel& md, const SimState& st)
    : plan_(md.scenario.autopilot), source_(md.scenario.source) {
  for (std::size_t k = 0; k < plan_.size(); ++k) origin_.push_back(static_cast<int>(k));
  for (int i = 0; i < md.num_instruments(); ++i) names_.push_back(md.instrument_name(i));
  const int n = md.num_instruments();
  depth_.assign(n, 0.0);
  roll_.assign(n, 0.0);
  roll_target_.assign(n, 0.0);
  for (int i = 0; i < n; ++i) {
    depth_[i] = st.solver.instruments[i].drive.depth;
    roll_[i] = roll_target_[i] = st.solver.instruments[i].drive.roll;
  }
  phase_ = 0;
  if (!plan_.empty()) start_phase(md, st);
}

void Autopilot::start_phase(const SimModel& md, const SimState& st) {
  phase_start_ = st.time();
  pull_speed_ = 0.0;
  retries_ = 0;
  backing_off_ = false;
  if (finished()) {
    status_ = "done";
    return;
  }
  const AutopilotPhase& ph = plan_[phase_];
  const Scenario& sc = md.scenario;
  leader_ = ph.instrument.empty() ? -1 : sc.find_instrument(ph.instrument);
  if (leader_ >= 0 && leader_ == placed_) placed_ = -1;  // moved on: no longer watched
  // An instrument this phase moves is no longer held where an earlier phase left it.
  std::erase_if(holds_, [&](const Hold& h) {
    return h.instrument == leader_ || h.instrument == sc.find_instrument(ph.follower);
  });
  follower_ = ph.follower.empty() ? -1 : sc.find_instrument(ph.follower);
  relative_ = ph.relative_to.empty() ? -1 : sc.find_instrument(ph.relative_to);
  status_ = std::string(to_string(ph.kind)) + (ph.instrument.empty() ? "" : " " + ph.instrument);
  place_stage_ = PlaceStage::kPast;
  still_watches_ = watches_ = 0;
  if (ph.kind == AutopilotPhase::Kind::kAdd || ph.kind == AutopilotPhase::Kind::kRemove) {
    // The runner makes the change before the next step (exchange_wanted); the hands hold.
    if (ph.kind == AutopilotPhase::Kind::kAdd) status_ += " (" + ph.added.catalogue + ")";
    return;
  }
  if (ph.kind == AutopilotPhase::Kind::kPlace) {
    // The route to the lesion's middle, which the markers' midpoint is brought to.
    const VesselTree& tree = md.tree;
    const LesionModel& lm = md.procedure.lesions[static_cast<std::size_t>(ph.lesion)];
    // The route runs on past the lesion's middle (so that markers past it read a negative
    // distance to go, and are pulled back), as far as the segment allows.
    const int seg = tree.lesions[static_cast<std::size_t>(lm.lesion)].segment;
    const double mid = 0.5 * (lm.span.s0 + lm.span.s1);
    // Which way the route runs through the lesion: from the segment's start (down it, as into a
    // coronary from its ostium) or from its end (up it: an access below the lesion). Read from
    // the route to the middle itself (a branch holding the access can join the lesion's vessel
    // on either side of it), then the route is laid on past the middle that way.
    route_ = route(tree, tree.access, TreeLocation{seg, mid}, kSpacing);
    place_direction_ = 1;
    if (route_.size() >= 2) {
      const TreeHit before =
          locate_near(tree, route_[route_.size() - 2], TreeLocation{seg, mid}, 2.0 * kSpacing);
      if (before.loc.segment == seg && before.loc.distance > mid) place_direction_ = -1;
    }
    const double beyond =
        std::clamp(mid + place_direction_ * kPlaceBeyond, 0.0, segment_length(tree.segments[seg]));
    route_ = route(tree, tree.access, TreeLocation{seg, beyond}, kSpacing);
    route_s_.assign(route_.size(), 0.0);
    for (std::size_t k = 1; k < route_.size(); ++k)
      route_s_[k] = route_s_[k - 1] + (route_[k] - route_[k - 1]).norm();
    place_goal_ = route_s_.back() - std::abs(beyond - mid);
    place_target_ = TreeLocation{seg, mid};
    progress_ = best_progress_ = 0.0;
    best_time_ = st.time();
    depth_at_best_ = -1.0;
    status_ += " across lesion " + std::to_string(ph.lesion);
    return;
  }
  if (ph.kind != AutopilotPhase::Kind::kNavigate) return;
  const VesselTree& tree = md.tree;
  goal_segment_ = tree.find(ph.goal_segment);
  status_ += " to " + ph.goal_segment;
  goal_distance_ = ostium_distance(tree, goal_segment_) + ph.goal_distance;
  const TreeLocation goal{goal_segment_, goal_distance_};
  route_ = route(tree, tree.access, goal, kSpacing);
  route_s_.assign(route_.size(), 0.0);
  for (std::size_t k = 1; k < route_.size(); ++k)
    route_s_[k] = route_s_[k - 1] + (route_[k] - route_[k - 1]).norm();
  on_route_.assign(tree.num_segments(), 0);
  route_segment_.clear();
  for (const Vec3& p : route_) {
    const TreeHit h = md.locator.locate(p);
    on_route_[h.loc.segment] = 1;
    route_segment_.push_back(h.loc.segment);
  }
  for (int s = goal_segment_; s >= 0; s = tree.segments[s].parent) on_route_[s] = 1;
  // Where the route climbs out of a vessel into its parent through the bifurcation at the
  // parent's end (from the access up to the vessel the goal lies below), a tip in the other
  // branch of that bifurcation counts as in it (off the route) only once past the junction: a J
  // wire coming up one iliac swings its end across the other's mouth. Elsewhere (side branches,
  // the way down) the first step into a wrong branch is already a wrong turn.
  entry_.assign(tree.num_segments(), 0.0);
  for (int a = tree.access.segment; a >= 0 && !is_descendant(tree, goal_segment_, a);
       a = tree.segments[a].parent) {
    const int p = tree.segments[a].parent;
    if (p < 0) break;
    const double end = segment_length(tree.segments[p]);
    for (int s = 0; s < tree.num_segments(); ++s)
      if (tree.segments[s].parent == p && !on_route_[s] && attach_distance(tree, s) >= end)
        entry_[s] = junction_exit(tree, s);
  }
  progress_ = best_progress_ = 0.0;
  best_time_ = st.time();
  roll_start_ = roll_[leader_];
  depth_at_best_ = -1.0;
  phase_best_progress_ = 0.0;
  phase_best_depth_ = st.solver.instruments[leader_].drive.depth;
}

void Autopilot::navigate(const SimModel& md, const SimState& st, const AutopilotPhase& ph) {
  const double dt = md.dt();
  const double t = st.time();
  const int L = leader_;
  const InstrumentState& in = st.solver.instruments[L];
  auto depth = [&](int i) { return st.solver.instruments[i].drive.depth; };
  const Vec3 X = tip_rest(md, st, L);
  const TreeHit hit = md.locator.locate(X);

  // Progress: the nearest route point within a window around the last progress.
  const std::size_t best =
      nearest_point(route_, X, progress_ == 0.0 ? nullptr : &route_s_, progress_, 0.06);
  progress_ = route_s_[best];
  // A wire still in the lumen of the instrument it runs inside (a 0.014" wire in its guiding
  // catheter): its inserted length short of that instrument's by more than kInOuter, the rule
  // the solver's coupling holds it by. The guide decides where its tip is: lying along the
  // arch's outer curve it is put in the left subclavian's mouth or a few millimetres outside the
  // lumen, and turning it there does nothing. It is only pushed on (issue 28: the coronary
  // environment's wire, started 300 mm short of the guide's tip, was taken for a wrong turn at
  // the left subclavian and spent its 16 retries in the arch, never out of the guide).
  const int outer = md.scenario.find_instrument(md.scenario.instruments[L].inside);
  const bool in_outer = outer >= 0 && depth(L) < depth(outer) - kInOuter;
  // Out of a seated guide (a coronary wire): a branch's first millimetres lie in the lumen of
  // the vessel it leaves (a side branch's in its parent's, each branch of a bifurcation in the
  // other's), and a tip there that is still inside the route's vessel where it has got to is not
  // yet in the branch. The LCx's wire was put 0.7-1.3 mm into the first obtuse marginal's mouth
  // while inside the LCx and pulled back four times; at the left main's end it was put 1.6-2.2
  // mm into the LAD, 0.2 mm inside its wall, and pulled back before it had taken either branch,
  // 16 times in a row (issue 28).
  const bool guided = outer >= 0 && std::ranges::any_of(holds_, [&](const Hold& h) {
                        return h.instrument == outer;
                      });
  bool in_route_vessel = false;
  if (guided && !on_route_[hit.loc.segment]) {
    const std::size_t ahead = std::min(route_.size() - 1, best + 3);
    for (const int rs : {route_segment_[best], route_segment_[ahead]})
      if (tube_outside(md.tree.segments[rs], X) < 0.0) in_route_vessel = true;
  }
  // Off the route: in a branch past its junction (or out of the lumen) is a wrong turn to back
  // out of; once backing out, the tip is pulled until it is out of that branch altogether.
  const bool strayed =
      !in_outer && ((!on_route_[hit.loc.segment] && !in_route_vessel) || hit.outside > 2e-3);
  const bool off_route = !in_outer && ((!on_route_[hit.loc.segment] && !in_route_vessel &&
                                        hit.loc.distance > entry_[hit.loc.segment]) ||
                                       hit.outside > 2e-3);
  const bool reached = hit.loc.segment == goal_segment_ &&
                       hit.loc.distance >= goal_distance_ - ph.tolerance && hit.outside < 0.5e-3;
  if (reached) {
    // Seat it: a little more insertion keeps a gentle forward load on the tip (a guiding
    // catheter stays engaged in an ostium that way); later phases keep it there.
    depth_[L] = depth(L) + ph.seat;
    Hold h;
    h.instrument = L;
    h.seen = t;
    h.phase = ph;
    h.depth = depth_[L];
    // Its route runs on past the goal, so that a tip that dives in is seen to.
    const VesselTree& tree = md.tree;
    const double beyond =
        std::min(segment_length(tree.segments[goal_segment_]), goal_distance_ + ph.seat + 0.03);
    const std::vector<Vec3> r = route(tree, tree.access, {goal_segment_, beyond}, kSpacing);
    double s_k = 0.0;
    for (std::size_t k = 0; k < r.size(); ++k) {
      if (k > 0) s_k += (r[k] - r[k - 1]).norm();
      if (s_k < progress_ - 0.1) continue;
      h.route.push_back(r[k]);
      h.route_s.push_back(s_k);
    }
    h.target = ph.seat;
    if (!h.route.empty()) h.target += h.route_s[nearest_point(h.route, X)];
    holds_.push_back(std::move(h));
    ++phase_;
    start_phase(md, st);
    return;
  }
  // Slack: insertion since the tip last made progress (a loop forming in a wide vessel).
  if (depth_at_best_ < 0.0) depth_at_best_ = depth(L);
  const double slack = depth(L) - depth_at_best_;

  // A wire out of a seated guiding catheter turns freely inside it (the guide, not the vessel
  // wall, holds its shaft): its tip may be turned a whole turn either way, where a catheter's
  // stops at a quarter turn (held at half a turn, the steering of a wire that had to go further
  // round to face the LCx pinned it there), and its retries try quarter and half turns.
  // A catheter engaging a coronary ostium (a guide's goal just inside a coronary) that missed it
  // on its first approach: a braided shaft carries the hand's turn to its tip (docs/
  // instruments.md, "Braid"), and a JR4 has to go round the aortic root to face the right
  // coronary, so from the first retry it may be turned half a turn either way (and is brought to
  // the ostium's level, below). A quarter turn started none of 8 RCA seeds, half a turn from the
  // start 7 of 8, from the first retry 8 of 8; from the start, the JL4 of the unvaried patient
  // missed the left main, which it finds on its first approach (docs/measurements.md).
  const bool engaging = md.specs[L].kind == InstrumentKind::kCatheter &&
                        md.tree.segments[goal_segment_].kind == VesselKind::kCoronary &&
                        ph.goal_distance < kApproach && route_s_.back() - progress_ < kApproach &&
                        retries_ > 0;
  const double max_roll = guided ? 2.0 * kPi : engaging ? kPi : kMaxRoll;
  // Steer: turn the tip's bend toward the route ahead (about the shaft's axis).
  auto steer = [&]() {
    std::size_t k = best;
    while (k + 1 < route_.size() && route_s_[k] < progress_ + kLookAhead) ++k;
    // A branch to enter ahead: aim at its ostium instead (a shaped tip is turned toward the
    // side branch while it is still above it, then the instrument advances onto it).
    const VesselTree& tree = md.tree;
    for (std::size_t j = best; j < route_.size() && route_s_[j] < progress_ + kBranchAhead; ++j) {
      const int sj = route_segment_[j];
      if (sj != hit.loc.segment && tree.segments[sj].parent == hit.loc.segment) {
        k = std::min(route_.size() - 1, j + 2);
        break;
      }
    }
    Vec3 shaft, tipdir;
    tip_directions(md.solver.instruments[L].rod(), in, md.specs[L].shaped_length(), shaft, tipdir);
    const Vec3 want = route_[k] - X;
    aim_distance_ = want.norm();
    aim_angle_ = std::acos(std::clamp(tipdir.dot(want.normalized()), -1.0, 1.0));
    aim_along_ = want.dot(shaft);
    const Vec3 b = tipdir - tipdir.dot(shaft) * shaft;
    const Vec3 d = want - want.dot(shaft) * shaft;
    if (b.norm() > 0.15 && d.norm() > 0.25 * want.norm()) {
      const double phi = std::atan2(shaft.dot(b.cross(d)), b.dot(d));
      // Within a quarter turn either way of where the phase started: a tip that does not follow
      // the hand is held by the wall, and winding the shaft up further only stores torque.
      if (std::abs(phi) > kDeadband)
        roll_target_[L] = std::clamp(roll_[L] + steer_gain * phi * dt, roll_start_ - max_roll,
                                     roll_start_ + max_roll);
    }
  };
  // Near a goal at an ostium in a beating heart (a guide to engage), the tip is given a beat and
  // a half before it counts as stuck: the ostium moves past a tip waiting below it once a beat,
  // and below 75 bpm a beat outlasts stuck_time (a JL4 sliding into the left sinus at 65.5 bpm
  // was pulled back 0.8 s after its last progress, before the beat brought the left main to it;
  // issue 28).
  double patience = stuck_time;
  if (md.motion && ph.goal_distance < kApproach && route_s_.back() - progress_ < kApproach)
    patience = std::max(patience, 1.5 * md.motion->period());
  if (backing_off_) {
    // Out of a wrong branch slowly: a shaped tip pulled back past the ostium it missed (a
    // Judkins tip in the sinus below the left main) often drops into it on the way.
    depth_[L] = std::max(0.0, depth_[L] - (strayed ? 0.25 : 1.0) * ph.speed * dt);
    // A tip in a wrong branch is pulled until it is back on the route, then a little more.
    if (strayed) {
      backoff_until_ = std::min(backoff_until_, depth(L) - 0.01);
      steer();  // keep the tip turned toward the ostium it is being pulled past
    }
    if (depth_[L] <= backoff_until_ && !strayed) {
      backing_off_ = false;
      best_progress_ = progress_;
      best_time_ = t;
      depth_at_best_ = depth(L);
    }
  } else if (in_outer) {
    // Pushed on through the guide: its lumen, not the anatomy, decides where the tip goes.
    best_progress_ = std::max(best_progress_, progress_);
    best_time_ = t;
    depth_at_best_ = depth(L);
    // From where it is (a wire brought up the guide by other hands since the phase began).
    depth_[L] = std::min(std::max(depth_[L], depth(L)) + ph.speed * dt, depth(L) + 0.01);
  } else if (off_route || t - best_time_ > patience || slack > max_slack) {
    if (++retries_ > max_retries) {
      failed_ = true;
      status_ = "gave up: " + ph.instrument + " stuck before " + ph.goal_segment + " after " +
                std::to_string(max_retries) + " retries";
      return;
    }
    ++retries_total_;
    if (trace)
      std::fprintf(stderr, "autopilot t %.3f retry %d: %s\n", t, retries_,
                   off_route ? ("off the route in " + md.tree.segments[hit.loc.segment].name +
                                " at " + std::to_string(hit.loc.distance * 1e3) + " mm, " +
                                std::to_string(hit.outside * 1e3) + " mm outside")
                                   .c_str()
                   : slack > max_slack ? "slack"
                                       : "no progress");
    backing_off_ = true;
    // Back from where the last progress was, but not more than two back-offs behind where the
    // tip got furthest in this phase: retries that each start a back-off lower walked a guide
    // that did not respond at once 150 mm back up into the arch.
    backoff_until_ = std::max({0.0, std::min(depth(L), depth_at_best_) - backoff,
                               std::min(depth(L), phase_best_depth_) - 2.0 * backoff});
    depth_[L] = depth(L);
    // Turn the tip a quarter turn before the next try, so that the tries cover every direction.
    // Turn the tip before the next try, to the next of a few directions around where the phase
    // started (+1, -1, +2, -2, 0 eighths of a turn): an operator does not wind a catheter up
    // by whole turns, which stores torque that releases as a whip.
    constexpr double kTries[] = {1.0, -1.0, 2.0, -2.0, 0.0};
    // A wire out of a seated guide: quarter and half turns.
    roll_target_[L] = roll_start_ + (guided ? 2.0 : 1.0) * retry_turn * kTries[(retries_ - 1) % 5];
  } else {
    if (progress_ > phase_best_progress_) {
      phase_best_progress_ = progress_;
      phase_best_depth_ = depth(L);
    }
    if (progress_ > best_progress_ + kProgressStep) {
      best_progress_ = progress_;
      best_time_ = t;
      depth_at_best_ = depth(L);
    }
    // Slow down toward the goal and keep the commanded depth near the real one (the drive can
    // lag behind a position command when the hand pushes against resistance).
    const double to_goal = route_s_.back() - progress_;
    steer();
    // Slow down over the last few centimetres (an ostium is found at a walking pace).
    double v = std::clamp(to_goal / kApproach, 0.25, 1.0) * ph.speed;
    // Engaging an ostium from close by: the tip is brought to the ostium's level, pulled back
    // when the ostium lies behind it along the shaft (a Judkins tip that has dropped into the
    // sinus below it) and advanced when ahead, while it is turned to face it: the JR4's way into
    // the right coronary, turned while drawn back a little. Pushed on regardless, the tip went
    // deeper into the sinus floor 10 mm below the ostium, facing it within 25-35 deg.
    if (engaging && aim_distance_ < kEngageNear)
      v = 0.5 * std::clamp(aim_along_ / aim_distance_, -0.5, 1.0) * ph.speed;
    depth_[L] = std::max(0.0, std::min(depth_[L] + v * dt, depth(L) + 0.01));
  }
  // The follower keeps its tip behind the leader's (a catheter tracking over its wire).
  if (follower_ >= 0) depth_[follower_] = std::max(0.0, depth_[L] - ph.follow_gap);
}

// How far the markers' midpoint of instrument L (a balloon or stent catheter: the balloon's
// middle as fluoroscopy shows it), at rest, still has to go along the route to the lesion's
// middle (m; negative when past it).
double Autopilot::markers_remaining(const SimModel& md, const SimState& st, int L) {
  const RodModel& rod = md.solver.instruments[static_cast<std::size_t>(L)].rod();
  const std::vector<double>& markers = md.specs[static_cast<std::size_t>(L)].radiopacity.markers;
  double from_tip = 0.0;
  for (double m : markers) from_tip += m / static_cast<double>(markers.size());
  const double s_mid = rod.length - from_tip;
  int i = rod.n - 1;
  while (i > 0 && rod.node_s[i] > s_mid) --i;
  const auto& x = st.solver.instruments[static_cast<std::size_t>(L)].rod.x;
  const int j = std::min(i + 1, rod.n - 1);
  const double span = j > i ? rod.node_s[j] - rod.node_s[i] : 1.0;
  const Vec3 p = x[i] + std::clamp((s_mid - rod.node_s[i]) / span, 0.0, 1.0) * (x[j] - x[i]);
  Vec3 X = p;
  if (md.motion)
    for (int k = 0; k < 3; ++k) X = p - md.motion->displacement(X, st.time());
  const std::size_t best =
      nearest_point(route_, X, progress_ == 0.0 ? nullptr : &route_s_, progress_, 0.03);
  progress_ = route_s_[best];
  // In the lesion's segment, along that segment's own arc length (as the outcome measures the
  // stent against the lesion), else along the route.
  const double along_route = place_goal_ - progress_;
  if (std::abs(along_route) > kPlaceBeyond) return along_route;
  const TreeHit hit = locate_near(md.tree, X, place_target_, 2.0 * kPlaceBeyond);
  if (hit.loc.segment == place_target_.segment && hit.outside < 0.0)
    return place_direction_ * (place_target_.distance - hit.loc.distance);
  return along_route;
}

// The markers brought to the lesion's middle as a cardiologist positions a stent: advanced
// past it, then drawn back onto it. Pushed across the lesion, the delivery shaft stores push in
// the guide's curves (it lies along their outer sides; the stent crosses the throat in slips of
// about a millimetre), so the markers move on after the hand stops and a pull does not reach
// them until it has taken up that slack, more than 10 mm in the default scene (docs/
// measurements.md, 2026-11-27). Drawing back first takes up the slack and then moves the stent
// with the hand. So: advanced until kPlacePast beyond the middle; drawn back (at kDrawSlack until
// the markers start to come back, then at kDrawSpeed) until they are within half the tolerance
// of it; then the hand is held still and the markers
// watched over a beat (kPlacedTime on a still heart), as judged on cine: placed when the mean of
// a second watch in a row is within the tolerance; off by more, the hand moves by the difference
// (at most kMostAdjust) and watches again; after kMaxWatches the place is taken as it is.
void Autopilot::place(const SimModel& md, const SimState& st, const AutopilotPhase& ph) {
  const int L = leader_;
  const double dt = md.dt();
  const double t = st.time();
  const double remaining = markers_remaining(md, st, L);
  const double depth = st.solver.instruments[static_cast<std::size_t>(L)].drive.depth;
  const double near = 0.5 * ph.tolerance;
  const double past = std::min(kPlacePast, 0.5 * (route_s_.back() - place_goal_));
  auto watch = [&] {
    place_stage_ = PlaceStage::kWatch;
    watch_since_ = t;
    watch_sum_ = 0.0;
    watch_n_ = 0;
  };
  if (place_stage_ == PlaceStage::kAdjust) {
    depth_[L] += std::clamp(place_limit_ - depth_[L], -kDrawSpeed * dt, kDrawSpeed * dt);
    if (std::abs(place_limit_ - depth_[L]) < 1e-9) watch();
    return;
  }
  if (place_stage_ == PlaceStage::kDrawBack) {
    if (remaining >= -near) {
      watch();
      return;
    }
    if (draw_from_ - depth_[L] > kDrawMost) {
      failed_ = true;
      status_ = "gave up: " + ph.instrument + " does not come back onto lesion " +
                std::to_string(ph.lesion);
      return;
    }
    // Quickly until the markers start to come back (the slack taken up), then slowly.
    const bool slack = remaining < kDrawSeen - past;
    depth_[L] -= (slack ? kDrawSlack : kDrawSpeed) * dt;
    return;
  }
  if (place_stage_ == PlaceStage::kWatch) {
    watch_sum_ += remaining;
    ++watch_n_;
    const double window = md.motion ? std::max(kPlacedTime, md.motion->period()) : kPlacedTime;
    if (t - watch_since_ < window) return;
    const double mean = watch_sum_ / watch_n_;
    ++watches_;
    ++still_watches_;
    if (trace)
      std::fprintf(stderr, "autopilot t %.2f [place] markers %.2f mm to go over a beat (%d)\n", t,
                   mean * 1e3, watches_);
    if ((std::abs(mean) < ph.tolerance && still_watches_ >= 2) || watches_ >= kMaxWatches) {
      placed_ = L;
      ++phase_;
      start_phase(md, st);
    } else if (std::abs(mean) >= ph.tolerance) {
      // Off by more than the tolerance: the hand moves by the difference (the shaft drawn taut
      // passes it on either way), then watches again.
      place_stage_ = PlaceStage::kAdjust;
      const double off = mean > 0.0 ? mean - near : mean + near;
      place_limit_ = depth_[L] + std::clamp(off, -kMostAdjust, kMostAdjust);
      still_watches_ = 0;
    } else {
      watch();  // within the tolerance: once more with the hand still
    }
    return;
  }
  // Past the middle: once there, drawn back.
  if (remaining <= -past) {
    place_stage_ = PlaceStage::kDrawBack;
    draw_from_ = depth_[L];
    return;
  }
  // Stuck (a lesion the catheter does not cross, a guide it pushes out): the hand gives no more
  // than max_slack of insertion without the markers moving on, then gives up.
  if (progress_ > best_progress_ + kProgressStep) {
    best_progress_ = progress_;
    best_time_ = st.time();
    depth_at_best_ = depth;
  }
  if (depth_at_best_ < 0.0) depth_at_best_ = depth;
  if (remaining > 0.0 && depth - depth_at_best_ > max_slack &&
      st.time() - best_time_ > stuck_time) {
    failed_ = true;
    status_ = "gave up: " + ph.instrument + " does not advance across lesion " +
              std::to_string(ph.lesion);
    depth_[L] = depth_at_best_;
    return;
  }
  // At the approach speed once out of the guide in the coronary (the last kApproach of the
  // route), slower still over the last 10 mm; the command kept near the real depth (the catheter
  // may lag).
  const double to_go = remaining + past;
  const double v = std::clamp(std::abs(to_go) / 10e-3, 0.2, 1.0) *
                   (std::abs(to_go) > kPlaceApproach ? ph.speed : ph.approach_speed);
  depth_[L] = std::clamp(depth_[L] + std::min(to_go, v * dt), depth - 0.005, depth + 0.005);
}

void Autopilot::command(const SimModel& md, const SimState& st, StepCommands& out) {
  const Scenario& sc = md.scenario;
  const int n = md.num_instruments();
  const double dt = md.dt();
  const double t = st.time();
  auto depth = [&](int i) { return st.solver.instruments[i].drive.depth; };
  out.syringe_flow = 0.0;
  out.balloon_pressure = 0.0;
  if (!finished()) {
    const AutopilotPhase& ph = plan_[phase_];
    switch (ph.kind) {
      case AutopilotPhase::Kind::kWait:
        if (t - phase_start_ >= ph.duration) {
          ++phase_;
          start_phase(md, st);
        }
        break;
      case AutopilotPhase::Kind::kInject:
        out.syringe_flow = ph.flow;
        if (t - phase_start_ >= ph.duration) {
          ++phase_;
          start_phase(md, st);
        }
        break;
      case AutopilotPhase::Kind::kWithdraw: {
        const double target =
            std::max(0.0, relative_ >= 0 ? depth(relative_) - ph.depth : ph.depth);
        // A hand speeds up and slows down over a few centimetres rather than in one step.
        const double left = std::abs(target - depth_[leader_]);
        double v = ph.speed;
        if (max_accel > 0.0)
          v = std::min({v, pull_speed_ + max_accel * dt, std::sqrt(2.0 * max_accel * left)});
        pull_speed_ = v;
        const double step = v * dt;
        depth_[leader_] += std::clamp(target - depth_[leader_], -step, step);
        if (std::abs(depth(leader_) - target) < 0.5e-3) {
          ++phase_;
          start_phase(md, st);
        }
        break;
      }
      case AutopilotPhase::Kind::kNavigate:
        navigate(md, st, ph);
        break;
      case AutopilotPhase::Kind::kPlace:
        place(md, st, ph);
        break;
      case AutopilotPhase::Kind::kInflate: {
        // The indeflator turned up to the pressure over the ramp, then held. While the balloon
        // is still soft (below kPositionCheck) the markers placed just before are watched and
        // the catheter nudged back onto the lesion's middle, as a cardiologist checks the
        // position at the first atmospheres.
        const double since = t - phase_start_;
        pressure_ = ph.ramp > 0.0 ? ph.pressure * std::min(1.0, since / ph.ramp) : ph.pressure;
        if (placed_ >= 0 && pressure_ < kPositionCheck) {
          const double remaining = markers_remaining(md, st, placed_);
          const double v = kNudgeSpeed * dt;
          const double d = st.solver.instruments[static_cast<std::size_t>(placed_)].drive.depth;
          depth_[placed_] =
              std::clamp(depth_[placed_] + std::clamp(remaining, -v, v), d - 0.005, d + 0.005);
        }
        if (since >= ph.ramp + ph.duration) {
          ++phase_;
          start_phase(md, st);
        }
        break;
      }
      case AutopilotPhase::Kind::kDeflate:
        pressure_ = 0.0;
        if (t - phase_start_ >= ph.duration) {
          ++phase_;
          start_phase(md, st);
        }
        break;
      case AutopilotPhase::Kind::kAdd:
      case AutopilotPhase::Kind::kRemove:
        break;  // the exchange is asked for before the next step (exchange_wanted)
    }
  }
  out.balloon_pressure = pressure_;
  if (trace && t >= next_trace_) {
    next_trace_ = t + 0.25;
    std::fprintf(stderr,
                 "autopilot t %.2f [%s] progress %.1f mm retries %d%s aim %.1f mm %.0f deg\n", t,
                 status_.c_str(), progress_ * 1e3, retries_, backing_off_ ? " backing off" : "",
                 aim_distance_ * 1e3, aim_angle_ * 180 / kPi);
    for (int i = 0; i < n; ++i) {
      if (depth(i) <= 0.0) continue;
      const TreeHit h = tip_location(md, st, i);
      std::fprintf(stderr, "    %-14s depth %6.1f mm (cmd %6.1f) roll %5.0f deg tip %s %.1f mm%s\n",
                   sc.instruments[i].name.c_str(), depth(i) * 1e3, depth_[i] * 1e3,
                   roll_[i] * 180 / kPi, md.tree.segments[h.loc.segment].name.c_str(),
                   h.loc.distance * 1e3, h.outside > 0 ? " OUTSIDE" : "");
    }
  }
  // Held instruments: the hand keeps the tip where it was seated, a little deeper when it
  // backs out, a little less when it dives in, within a centimetre and a half.
  for (std::size_t hi = 0; hi < holds_.size(); ++hi) {
    const Hold& h = holds_[hi];
    const Vec3 X = tip_rest(md, st, h.instrument);
    const std::size_t best = nearest_point(h.route, X);
    if ((h.route[best] - X).norm() <= kHoldReach) holds_[hi].seen = t;
    if (t - h.seen > kHoldLost) {
      // The tip fell out (a guiding catheter backing out of the ostium as the wire pushes).
      // Re-engage it, with an instrument this phase drives inside it pulled back in first,
      // then go on with this phase; at most max_reengage times per run.
      if (!finished() && reengaged_ < max_reengage) {
        ++reengaged_;
        std::vector<AutopilotPhase> again;
        const int inner = leader_;
        if (inner >= 0 && sc.instruments[inner].inside == sc.instruments[h.instrument].name) {
          AutopilotPhase w;
          w.kind = AutopilotPhase::Kind::kWithdraw;
          w.instrument = sc.instruments[inner].name;
          w.relative_to = sc.instruments[h.instrument].name;
          w.depth = 0.05;
          w.speed = 0.05;
          again.push_back(w);
        }
        // The inner instrument rides along 50 mm inside the guide's tip while it is re-seated:
        // left where it was, a wire stuck out of a guide that backed off to find the ostium
        // again (by up to 95 mm in the default scene), and a Judkins tip cannot take its shape
        // round a wire. 50 mm (the JL4's 40 mm segment between its curves) rather than 20 mm:
        // of the eleven variants of the default run (validation.md 4), 9 finished against 5, the
        // rest mostly failing to re-seat (not a mechanism found, an outcome measured).
        AutopilotPhase seat = h.phase;
        if (!again.empty()) {
          seat.follower = again.front().instrument;
          seat.follow_gap = again.front().depth;
        }
        again.push_back(seat);
        plan_.insert(plan_.begin() + phase_, again.begin(), again.end());
        origin_.insert(origin_.begin() + phase_, again.size(), -1);
        holds_.erase(holds_.begin() + static_cast<std::ptrdiff_t>(hi));
        start_phase(md, st);
        break;
      }
    }
    // Out of reach (for a moment: a tip at an ostium slips in and out with the beat): the hand
    // holds the shaft where it is rather than chase the tip with it.
    if ((h.route[best] - X).norm() > kHoldReach) continue;
    double err = h.target - h.route_s[best];
    err = std::abs(err) < kHoldDeadband ? 0.0 : err - std::copysign(kHoldDeadband, err);
    depth_[h.instrument] = std::clamp(depth_[h.instrument] + kHoldGain * err * dt,
                                      h.depth - kHoldRange, h.depth + kHoldRange);
  }
  out.drive.resize(n);
  for (int i = 0; i < n; ++i) {
    // The hand turns at a bounded rate toward the roll it wants.
    roll_[i] += std::clamp(roll_target_[i] - roll_[i], -max_spin * dt, max_spin * dt);
    DriveCommand& c = out.drive[i];
    c.mode = DriveCommand::Mode::kPosition;
    c.translation = depth_[i];
    c.rotation = roll_[i];
  }
}

bool Autopilot::exchange_wanted(InstrumentChange& out) const {
  if (finished()) return false;
  const AutopilotPhase& ph = plan_[static_cast<std::size_t>(phase_)];
  const int k = origin_[static_cast<std::size_t>(phase_)];
  const std::string field = "autopilot[" + std::to_string(k) + "].instrument";
  if (ph.kind == AutopilotPhase::Kind::kAdd) {
    const ScenarioInstrument& si = ph.added;
    out.kind = InstrumentChange::Kind::kAdd;
    out.name = si.name;
    out.catalogue = si.catalogue;
    out.inside = si.inside;
    out.over = si.over;
    out.rim = si.rim;
    out.max_nodes = si.max_nodes;
    out.tip_segment = si.tip_segment;
  } else if (ph.kind == AutopilotPhase::Kind::kRemove) {
    out.kind = InstrumentChange::Kind::kRemove;
    out.name = ph.instrument;
  } else {
    return false;
  }
  out.source = source_;
  out.field = field;
  return true;
}

void Autopilot::rebind(const SimModel& md, const SimState& st) {
  // The per-instrument commands follow the instruments by name; one added starts where it is.
  const int n = md.num_instruments();
  std::vector<double> depth(n), roll(n), target(n);
  std::vector<int> was(n, -1);
  for (int j = 0; j < n; ++j) {
    const auto it = std::find(names_.begin(), names_.end(), md.instrument_name(j));
    was[j] = it == names_.end() ? -1 : static_cast<int>(it - names_.begin());
    const DriveState& d = st.solver.instruments[j].drive;
    depth[j] = was[j] >= 0 ? depth_[was[j]] : d.depth;
    roll[j] = was[j] >= 0 ? roll_[was[j]] : d.roll;
    target[j] = was[j] >= 0 ? roll_target_[was[j]] : d.roll;
  }
  auto now = [&](int i) {
    if (i < 0) return -1;
    const auto it = std::find(was.begin(), was.end(), i);
    return it == was.end() ? -1 : static_cast<int>(it - was.begin());
  };
  leader_ = now(leader_);
  follower_ = now(follower_);
  relative_ = now(relative_);
  placed_ = now(placed_);
  for (Hold& h : holds_) h.instrument = now(h.instrument);
  std::erase_if(holds_, [](const Hold& h) { return h.instrument < 0; });  // removed
  depth_ = std::move(depth);
  roll_ = std::move(roll);
  roll_target_ = std::move(target);
  names_.clear();
  for (int j = 0; j < n; ++j) names_.push_back(md.instrument_name(j));
  // A phase that asked for this change is done.
  if (finished()) return;
  const AutopilotPhase& ph = plan_[static_cast<std::size_t>(phase_)];
  const bool present = md.instrument_index(ph.instrument) >= 0;
  if ((ph.kind == AutopilotPhase::Kind::kAdd && present) ||
      (ph.kind == AutopilotPhase::Kind::kRemove && !present)) {
    ++phase_;
    start_phase(md, st);
  } else if (!present && !ph.instrument.empty() && ph.kind != AutopilotPhase::Kind::kAdd) {
    failed_ = true;  // another source removed the instrument this phase drives
    status_ = "gave up: '" + ph.instrument + "' was removed from the scene";
  }
}

void Autopilot::refused(const InputError& why) {
  failed_ = true;
  status_ = std::string("gave up: ") + why.what();
}

void AutopilotInput::poll(double, StepCommands& out) {
  pilot_.command(sim_, out);
}

bool AutopilotInput::poll_exchange(double, InstrumentChange& out) {
  return pilot_.exchange_wanted(out);
}

void AutopilotInput::exchanged(const InstrumentChange&, std::span<const std::string>) {
  pilot_.rebind(sim_.model(), sim_.state());
}

void AutopilotInput::exchange_refused(const InstrumentChange&, const InputError& why) {
  pilot_.refused(why);
}

}  // namespace vcsim
