// The simulator: a scenario's scene (anatomy, beating wall, instruments from the catalogue at the
// femoral sheath) and state, advanced by the step pipeline of docs/architecture.md, with a
// transport model of contrast and the run's metrics (docs/scenarios.md).
#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "vcsim/sim.h"

namespace vcsim {

namespace {

constexpr double kMm = 1e-3;
constexpr double kDeg = std::numbers::pi / 180.0;
// Cardiac output at rest, 5 l/min (clinical.md): what dilutes contrast injected into the aorta.
constexpr double kCardiacOutputMlS = 83.0;
constexpr double kContrastFill = 0.1;  // s, time constant of filling a segment once it arrives
constexpr double kLandmarkInterval = 0.005;  // s between landmark checks

VesselTree load_anatomy(const Scenario& sc) {
  const std::string& a = sc.anatomy;
  const bool file = a.size() > 5 && a.substr(a.size() - 5) == ".json";
  if (!file) return default_patient(patient_variant_from_string(a, sc.source + ": anatomy"));
  const std::filesystem::path p = sc.base_dir / a;
  if (!std::filesystem::exists(p))
    throw InputError(sc.source, "anatomy",
                     "expected an anatomy file, '" + p.string() + "' does not exist");
  return load_vessel_tree(p.string());
}

int segment_named(const VesselTree& t, const std::string& name, const std::string& src,
                  const std::string& field) {
  const int s = t.find(name);
  if (s < 0) throw InputError(src, field, "no segment named '" + name + "' in the anatomy");
  return s;
}

bool finite_state(const RodState& st) {
  for (std::size_t i = 0; i < st.x.size(); ++i)
    if (!st.x[i].allFinite() || !st.v[i].allFinite()) return false;
  for (std::size_t j = 0; j < st.q.size(); ++j)
    if (!st.q[j].coeffs().allFinite() || !st.omega[j].allFinite()) return false;
  return true;
}

}  // namespace

TreeHit locate(const VesselTree& tree, const Vec3& p) {
  TreeHit best;
  best.outside = std::numeric_limits<double>::infinity();
  for (int si = 0; si < tree.num_segments(); ++si) {
    const VesselSegment& seg = tree.segments[si];
    double s0 = 0.0;
    for (std::size_t k = 0; k + 1 < seg.points.size(); ++k) {
      const Vec3 a = seg.points[k], d = seg.points[k + 1] - a;
      const double len2 = d.squaredNorm(), len = std::sqrt(len2);
      const double t = len2 > 0.0 ? std::clamp((p - a).dot(d) / len2, 0.0, 1.0) : 0.0;
      const double r = seg.radii[k] + t * (seg.radii[k + 1] - seg.radii[k]);
      const double out = (p - (a + t * d)).norm() - r;
      if (out < best.outside) {
        best.outside = out;
        best.loc = {si, s0 + t * len};
      }
      s0 += len;
    }
  }
  return best;
}

bool is_descendant(const VesselTree& tree, int seg, int ancestor) {
  for (int s = seg; s >= 0; s = tree.segments[s].parent)
    if (s == ancestor) return true;
  return false;
}

Simulator::Simulator(Scenario scenario) : sc_(std::move(scenario)) {
  const std::string& src = sc_.source;
  tree_ = load_anatomy(sc_);
  // Check every name before the expensive build.
  // Landmarks resolved to indices once (the scenario parser checked the instrument names).
  for (std::size_t i = 0; i < sc_.landmarks.size(); ++i) {
    const int seg = segment_named(tree_, sc_.landmarks[i].segment, src,
                                  "landmarks[" + std::to_string(i) + "].segment");
    const int inst = sc_.find_instrument(sc_.landmarks[i].instrument);
    if (inst < 0)
      throw InputError(
          src, "landmarks[" + std::to_string(i) + "].instrument",
          "expected an instrument of the scenario, got '" + sc_.landmarks[i].instrument + "'");
    landmark_ids_.push_back({inst, seg});
  }
  for (std::size_t i = 0; i < sc_.autopilot.size(); ++i)
    if (sc_.autopilot[i].kind == AutopilotPhase::Kind::kNavigate)
      segment_named(tree_, sc_.autopilot[i].goal_segment, src,
                    "autopilot[" + std::to_string(i) + "].goal.segment");
  const std::filesystem::path cat_dir = default_catalogue_dir();
  const InstrumentCatalogue cat = load_catalogue(cat_dir);
  for (std::size_t i = 0; i < sc_.instruments.size(); ++i) {
    const InstrumentSpec* s = cat.find(sc_.instruments[i].catalogue);
    if (!s)
      throw InputError(src, "instruments[" + std::to_string(i) + "].catalogue",
                       "expected an entry of " + cat_dir.string() + ", got '" +
                           sc_.instruments[i].catalogue + "'");
    specs_.push_back(*s);
  }
  for (std::size_t i = 0; i < sc_.instruments.size(); ++i) {
    const int o = sc_.find_instrument(sc_.instruments[i].inside);
    if (o < 0) continue;
    if (specs_[o].inner_diameter <= specs_[i].outer_diameter)
      throw InputError(src, "instruments[" + std::to_string(i) + "].inside",
                       "expected a lumen wider than the instrument: '" + specs_[o].name +
                           "' has ID " + std::to_string(specs_[o].inner_diameter / kMm) + " mm, '" +
                           specs_[i].name + "' OD " +
                           std::to_string(specs_[i].outer_diameter / kMm) + " mm");
  }

  lumen_ = build_lumen(tree_);
  if (sc_.beating && tree_.heart) {
    motion_.emplace(tree_, sc_.motion);
    beating_ = std::make_unique<BeatingLumen>(lumen_.mesh, *motion_);
    beating_wall_ = std::make_unique<BeatingWall>(*beating_);
    wall_ = beating_wall_.get();
  } else {
    static_tree_.build(lumen_.mesh, AabbTreeSettings::for_static_mesh());
    static_wall_ = std::make_unique<StaticWall>(lumen_.mesh, static_tree_);
    wall_ = static_wall_.get();
  }

  // The sheath: at the tree's access, pointing along the vessel toward the heart (retrograde,
  // against the centreline's flow direction).
  const VesselSegment& acc = tree_.segments[tree_.access.segment];
  Sheath sheath;
  sheath.access_point = point_at(acc, tree_.access.distance);
  const Vec3 axis = -tangent_at(acc, tree_.access.distance);
  sheath.frame = Quat::FromTwoVectors(Vec3::UnitZ(), axis).normalized();
  // The introducer sheath: its straight part in the femoral artery holds what passes through it
  // on the axis (a 6F sheath for a 6F catheter: 0.2 mm of play across).
  sheath.length = sc_.sheath_length;
  double widest = 0.0;
  for (const InstrumentSpec& sp : specs_) widest = std::max(widest, sp.outer_diameter);
  sheath.inner_radius = 0.5 * widest + 0.1e-3;

  SolverSettings& s = settings_;
  s.rod.dt = sc_.dt;
  set_quasi_static_damping(s.rod);
  s.collisions = true;
  s.hand_force = sc_.feedback.hand_force;
  s.feedback_cutoff_hz = sc_.feedback.cutoff_hz;
  const int splits = std::max(1, sc_.fine_steps);
  masses_.resize(static_cast<std::size_t>(splits));
  for (std::size_t i = 0; i < specs_.size(); ++i) {
    Discretisation disc;
    disc.max_nodes = sc_.instruments[i].max_nodes;
    disc.tip_segment = sc_.instruments[i].tip_segment;
    RodDef def = to_rod_def(specs_[i], disc);
    def.base = BoundaryKind::kFree;
    def.tip = BoundaryKind::kFree;
    Instrument inst = make_instrument(
        def, sheath,
        ContactMaterial{specs_[i].friction.vessel_static, specs_[i].friction.vessel_dynamic}, 0.0);
    // Quasi-static: each node and frame only as heavy as the explicit step needs (physics.md 5.4),
    // for the scenario's step and for each split of it a fast hand may use.
    for (int k = 1; k <= splits; ++k) {
      RodModel md = inst.model;
      scale_for_time_step(md, sc_.dt / k, kQuasiStaticKpRatio);
      masses_[k - 1].push_back({std::move(md.node_mass), std::move(md.inv_mass),
                                std::move(md.inertia), std::move(md.inv_inertia)});
    }
    scale_for_time_step(inst.model, sc_.dt, kQuasiStaticKpRatio);
    insts_.push_back(std::move(inst));
  }
  for (std::size_t i = 0; i < sc_.instruments.size(); ++i) {
    const int o = sc_.find_instrument(sc_.instruments[i].inside);
    if (o < 0) continue;
    Coupling c;
    c.inner = static_cast<int>(i);
    c.outer = o;
    c.mu = specs_[i].friction.lumen;
    c.rim = sc_.instruments[i].rim;
    c.contacts.reserve(insts_[i].model.n);
    couplings_.push_back(std::move(c));
  }
  s.validate(src);
  drive_.resize(insts_.size());
  for (DriveCommand& d : drive_) d.mode = DriveCommand::Mode::kPosition;
  sub_drive_.resize(insts_.size());
  fine_force_.assign(insts_.size(), 0.0);
  fine_torque_.assign(insts_.size(), 0.0);
  backup_.resize(insts_.size());
  backup_drive_.resize(insts_.size());
  contrast_ = ContrastModel(tree_, sc_.contrast, sc_.dt);
  const std::size_t n = insts_.size();
  metrics_.tip_path.assign(n, 0.0);
  metrics_.peak_wall_force.assign(n, 0.0);
  metrics_.peak_axial_force.assign(n, 0.0);
  metrics_.peak_axial_jump.assign(n, 0.0);
  metrics_.peak_torque.assign(n, 0.0);
  last_axial_force_.assign(n, std::nan(""));
  for (const Landmark& l : sc_.landmarks) metrics_.landmarks.push_back({l.name, l.instrument});
}

Simulator::~Simulator() = default;

Vec3 Simulator::tip(int i) const {
  return insts_[i].state.x.back();
}

Vec3 Simulator::tip_rest(int i) const {
  // X = p - u(X, t) by fixed-point iteration (u is smooth and small against its length scale).
  const Vec3 p = tip(i);
  Vec3 X = p;
  if (motion_)
    for (int k = 0; k < 3; ++k) X = p - motion_->displacement(X, time_);
  return X;
}

TreeHit Simulator::tip_location(int i) const {
  return locate(tree_, tip_rest(i));
}

std::vector<Vec3> Simulator::route_to(const TreeLocation& to, double spacing) const {
  return route(tree_, tree_.access, to, spacing);
}

std::vector<ForceFeedback> Simulator::feedback() const {
  std::vector<ForceFeedback> out;
  for (std::size_t i = 0; i < insts_.size(); ++i)
    out.push_back({sc_.instruments[i].name, insts_[i].drive.axial_force, insts_[i].drive.torque});
  return out;
}

void Simulator::feedback(std::vector<ForceFeedback>& out) const {
  out.resize(insts_.size());
  for (std::size_t i = 0; i < insts_.size(); ++i) {
    out[i].name = sc_.instruments[i].name;  // same names every step: no allocation
    out[i].axial_force_n = insts_[i].drive.axial_force;
    out[i].torque_nm = insts_[i].drive.torque;
  }
}

bool Simulator::all_landmarks_reached() const {
  for (const LandmarkRecord& l : metrics_.landmarks)
    if (!l.reached) return false;
  return true;
}

void Simulator::step(const DeviceCommands& cmds) {
  const double t0 = now_us();
  const double dt = sc_.dt;
  for (std::size_t i = 0; i < insts_.size(); ++i) {
    DriveCommand& d = drive_[i];
    const InstrumentCommand* c = cmds.find(sc_.instruments[i].name);
    if (!c) {  // no command: the hand holds the instrument where it is
      d.mode = DriveCommand::Mode::kVelocity;
      d.translation = d.rotation = 0.0;
      continue;
    }
    d.mode = c->mode == InstrumentCommand::Mode::kPosition ? DriveCommand::Mode::kPosition
                                                           : DriveCommand::Mode::kVelocity;
    d.translation = c->translation_mm * kMm;
    d.rotation = c->rotation_deg * kDeg;
  }
  for (std::size_t i = 0; i < insts_.size(); ++i) {
    backup_[i] = insts_[i].state;
    backup_drive_[i] = insts_[i].drive;
  }
  std::vector<Vec3>& old_tips = old_tips_;
  old_tips.resize(insts_.size());
  for (std::size_t i = 0; i < insts_.size(); ++i) old_tips[i] = tip(static_cast<int>(i));

  // An instrument lying outside that the hand does not push in is parked (skipped).
  for (std::size_t i = 0; i < insts_.size(); ++i) {
    const DriveCommand& d = drive_[i];
    const DriveState& ds = insts_[i].drive;
    const bool still = d.mode == DriveCommand::Mode::kPosition
                           ? d.translation <= 0.0 && d.rotation == ds.roll
                           : d.translation <= 0.0 && d.rotation == 0.0;
    insts_[i].parked = ds.depth <= 0.0 && still;
  }
  // A fast hand: fine steps with the masses for them (physics.md 5.4).
  use_masses(split_for(hand_speed()));
  advance();
  // A sudden load on a hand (a scaled mass stopped or let go): the step is taken again, split
  // at least twice as finely, and that split held for a while (physics.md 5.4).
  if (split_ < sc_.fine_steps && sc_.fine_step_jump > 0.0) {
    bool sudden = false;
    for (std::size_t i = 0; i < insts_.size(); ++i) {
      const Instrument& in = insts_[i];
      const bool inserted = !in.parked && in.drive.depth > 0.0 && backup_drive_[i].depth > 0.0;
      sudden = sudden ||
               (inserted && std::abs(in.drive.axial_force_raw - backup_drive_[i].axial_force_raw) >
                                sc_.fine_step_jump);
    }
    if (sudden) {
      for (std::size_t i = 0; i < insts_.size(); ++i) {
        insts_[i].state = backup_[i];
        insts_[i].drive = backup_drive_[i];
      }
      hold_until_ = time_ + sc_.fine_step_hold;
      held_split_ = std::min(sc_.fine_steps, std::max(2 * split_, threshold_split()));
      use_masses(split_for(hand_speed()));
      advance();
      ++metrics_.resplit_steps;
    }
  }

  bool finite = true;
  for (const Instrument& in : insts_) finite = finite && finite_state(in.state);
  if (!finite) {
    // Undo the step and hold the instruments still; the caller sees it in the metrics.
    for (std::size_t i = 0; i < insts_.size(); ++i) {
      insts_[i].state = backup_[i];
      insts_[i].drive = backup_drive_[i];
      for (Vec3& v : insts_[i].state.v) v.setZero();
      for (Vec3& w : insts_[i].state.omega) w.setZero();
    }
    ++metrics_.rollbacks;
  }
  time_ += dt;
  // The injection enters where the outermost instrument's tip is (the guiding catheter).
  TreeLocation at;
  if (cmds.syringe_flow_ml_s > 0.0 && contrast_.injected_segment() < 0) {
    int outer = 0;
    for (std::size_t i = 0; i < insts_.size(); ++i)
      if (sc_.instruments[i].inside.empty() && insts_[i].drive.depth > insts_[outer].drive.depth)
        outer = static_cast<int>(i);
    at = tip_location(outer).loc;
  }
  contrast_.step(cmds.syringe_flow_ml_s, at);
  metrics_.contrast_volume = contrast_.volume();
  update_metrics(old_tips);
  metrics_.steps += 1;
  metrics_.sim_time = time_;
  metrics_.wall_time += (now_us() - t0) * 1e-6;
}

ContrastModel::ContrastModel(const VesselTree& tree, const ContrastSettings& settings, double dt)
    : tree_(&tree), s_(settings), dt_(dt) {
  c_.assign(tree.num_segments(), 0.0f);
  arrival_.assign(tree.num_segments(), -1.0);
  history_.assign(static_cast<std::size_t>(std::ceil(2.0 / dt)) + 1, 0.0f);
}

void ContrastModel::step(double flow, const TreeLocation& at) {
  const VesselTree& tree = *tree_;
  const std::size_t nh = history_.size();
  if (flow > 0.0 && segment_ < 0 && at.segment >= 0) {
    segment_ = at.segment;
    // Transport delay: the centreline distance from the injection point to each segment's
    // start, for the injected segment and everything below it (parents precede children).
    std::fill(arrival_.begin(), arrival_.end(), -1.0);
    arrival_[at.segment] = 0.0;
    for (int s = at.segment + 1; s < tree.num_segments(); ++s) {
      const int p = tree.segments[s].parent;
      if (p < 0 || arrival_[p] < 0.0) continue;
      const double from = p == at.segment ? at.distance : 0.0;
      arrival_[s] = arrival_[p] + std::max(0.0, attach_distance(tree, s) - from) / s_.blood_speed;
    }
  }
  if (flow > 0.0) volume_ += flow * dt_;
  pos_ = (pos_ + 1) % nh;
  history_[pos_] = static_cast<float>(std::max(0.0, flow));
  if (segment_ < 0) return;
  const bool coronary = tree.segments[segment_].kind == VesselKind::kCoronary;
  const double blood = coronary ? s_.blood_flow : kCardiacOutputMlS;
  bool any = false;
  for (int s = 0; s < tree.num_segments(); ++s) {
    if (arrival_[s] < 0.0) continue;
    const std::size_t lag = std::min(nh - 1, static_cast<std::size_t>(arrival_[s] / dt_));
    const double q = history_[(pos_ + nh - lag) % nh];
    const double target = s_.concentration * q / (q + blood);
    const double c = c_[s];
    const double tau = target > c ? kContrastFill : s_.washout;
    c_[s] = static_cast<float>(c + (target - c) * (1.0 - std::exp(-dt_ / tau)));
    any = any || c_[s] > 1e-4f || q > 0.0;
  }
  if (!any) segment_ = -1;  // washed out: the next injection starts afresh
}

double Simulator::hand_speed() const {
  double v = 0.0;
  for (std::size_t i = 0; i < insts_.size(); ++i) {
    if (insts_[i].parked) continue;
    const DriveCommand& d = drive_[i];
    const double rate = d.mode == DriveCommand::Mode::kPosition
                            ? (d.translation - insts_[i].drive.depth) / sc_.dt
                            : d.translation;
    v = std::max(v, std::min(std::abs(rate), insts_[i].sheath.max_speed));
  }
  return v;
}

void Simulator::advance() {
  const double dt = sc_.dt;
  const int n = split_;
  settings_.rod.dt = dt / n;
  set_quasi_static_damping(settings_.rod);
  std::fill(fine_force_.begin(), fine_force_.end(), 0.0);
  std::fill(fine_torque_.begin(), fine_torque_.end(), 0.0);
  for (int k = 1; k <= n; ++k) {
    // The hand's command spread evenly over the fine steps: a position k / n of the way there.
    for (std::size_t i = 0; i < insts_.size(); ++i) {
      DriveCommand& c = sub_drive_[i];
      c = drive_[i];
      if (c.mode == DriveCommand::Mode::kPosition && k < n) {
        const DriveState& start = backup_drive_[i];
        c.translation = start.depth + (drive_[i].translation - start.depth) * k / n;
        c.rotation = start.roll + (drive_[i].rotation - start.roll) * k / n;
      }
    }
    if (beating_wall_) beating_wall_->set_time(time_ + dt * k / n);
    step_instruments(insts_, couplings_, wall_, settings_, sub_drive_);
    for (std::size_t i = 0; i < insts_.size(); ++i) {
      fine_force_[i] += insts_[i].drive.axial_force_raw / n;
      fine_torque_[i] += insts_[i].drive.torque_raw / n;
    }
  }
  // The hand force of a split step is its fine steps' mean: the step's impulse over dt, as a
  // sensor that integrates over the step reads it. (The low-pass, if any, ran on the fine steps.)
  if (n > 1) {
    for (std::size_t i = 0; i < insts_.size(); ++i) {
      DriveState& ds = insts_[i].drive;
      ds.axial_force_raw = fine_force_[i];
      ds.torque_raw = fine_torque_[i];
      if (settings_.feedback_cutoff_hz <= 0.0) {
        ds.axial_force = ds.axial_force_raw;
        ds.torque = ds.torque_raw;
      }
    }
  }
}

int Simulator::threshold_split() const {
  return std::clamp(
      static_cast<int>(std::ceil(sc_.fine_step_speed * sc_.dt / sc_.fine_step_travel)), 2,
      std::max(2, sc_.fine_steps));
}

int Simulator::split_for(double speed) const {
  if (sc_.fine_steps <= 1) return 1;
  // For a while after a sudden load: the split it asked for.
  const int held = time_ < hold_until_ ? held_split_ : 1;
  // A fast hand: split from above fine_step_speed until the hands are below half of it.
  const bool fast = speed > (split_ > held ? 0.5 : 1.0) * sc_.fine_step_speed;
  if (!fast) return held;
  // As many fine steps as keep the hand's travel per fine step within fine_step_travel. A split
  // is only made coarser once a quarter more speed would not need it, so a hand whose speed
  // wavers about a boundary does not swap masses back and forth.
  // (A hand's speed is read from its commands: 1e-6 of a step's travel is rounding.)
  const double per = speed * sc_.dt / sc_.fine_step_travel - 1e-6;
  int n = std::clamp(static_cast<int>(std::ceil(per)), 2, sc_.fine_steps);
  if (n < split_ && std::ceil(1.25 * per) >= split_) n = split_;
  return std::max(n, held);
}

void Simulator::use_masses(int n) {
  if (n == split_) return;
  for (std::size_t i = 0; i < insts_.size(); ++i) {
    RodModel& md = insts_[i].model;
    RodState& st = insts_[i].state;
    const MassSet& to = masses_[n - 1][i];
    // Where a mass grows the momentum is kept, where it shrinks the velocity: a change of split
    // takes energy out either way, never puts it in.
    for (int j = 0; j < md.n; ++j)
      if (to.node_mass[j] > md.node_mass[j]) st.v[j] *= md.node_mass[j] / to.node_mass[j];
    for (int j = 0; j < md.m; ++j)
      for (int a = 0; a < 3; ++a)
        if (to.inertia[j][a] > md.inertia[j][a])
          st.omega[j][a] = st.omega[j][a] * md.inertia[j][a] / to.inertia[j][a];
    // Same sizes: the copies reuse the model's storage (no allocation while stepping).
    md.node_mass = to.node_mass;
    md.inv_mass = to.inv_mass;
    md.inertia = to.inertia;
    md.inv_inertia = to.inv_inertia;
  }
  split_ = n;
}

void Simulator::update_metrics(const std::vector<Vec3>& old_tips) {
  const double dt = settings_.rod.dt;  // the last (fine) step's: the impulses are its
  for (std::size_t i = 0; i < insts_.size(); ++i) {
    const Instrument& in = insts_[i];
    if (in.drive.depth > 0.0)
      metrics_.tip_path[i] += (tip(static_cast<int>(i)) - old_tips[i]).norm();
    double f = 0.0;
    for (const NodeContact& c : in.contacts) f = std::max(f, c.lambda_n / dt);
    metrics_.peak_wall_force[i] = std::max(metrics_.peak_wall_force[i], f);
    metrics_.peak_axial_force[i] =
        std::max(metrics_.peak_axial_force[i], std::abs(in.drive.axial_force));
    metrics_.peak_torque[i] = std::max(metrics_.peak_torque[i], std::abs(in.drive.torque));
    // NaN while outside: no jump is counted across an insertion or a withdrawal.
    double& last = last_axial_force_[i];
    if (in.drive.depth > 0.0) {
      const double jump = std::abs(in.drive.axial_force - last);
      if (jump > metrics_.peak_axial_jump[i]) metrics_.peak_axial_jump[i] = jump;
      last = in.drive.axial_force;
    } else {
      last = std::nan("");
    }
  }
  if (time_ < next_landmark_check_) return;
  next_landmark_check_ = time_ + kLandmarkInterval;
  for (std::size_t k = 0; k < sc_.landmarks.size(); ++k) {
    LandmarkRecord& rec = metrics_.landmarks[k];
    if (rec.reached) continue;
    const Landmark& l = sc_.landmarks[k];
    const auto [i, seg] = landmark_ids_[k];
    if (insts_[i].drive.depth <= 0.0) continue;
    const TreeHit h = tip_location(i);
    if (h.loc.segment == seg && h.loc.distance >= ostium_distance(tree_, seg) + l.distance &&
        h.outside < 0.5e-3) {
      rec.reached = true;
      rec.time = time_;
    }
  }
}

}  // namespace vcsim
