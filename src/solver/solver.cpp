// The solver's model, state and workspace, and its step: the split of a step into fine steps
// with the masses for them (physics.md 5.4), a step taken again split finer after a sudden load,
// and the rollback of a step that produced a non-finite value.
#include <algorithm>
#include <cmath>

#include "scratch.h"

namespace vcsim {

using internal::Inst;
using internal::Pair;
using internal::SolverScratch;

namespace {

bool finite_state(const RodState& st) {
  for (std::size_t i = 0; i < st.x.size(); ++i)
    if (!st.x[i].allFinite() || !st.v[i].allFinite()) return false;
  for (std::size_t j = 0; j < st.q.size(); ++j)
    if (!st.q[j].coeffs().allFinite() || !st.omega[j].allFinite()) return false;
  return true;
}

void add(StepProfile& to, const StepProfile& p) {
  to.drive += p.drive;
  to.forces += p.forces;
  to.integrate_velocities += p.integrate_velocities;
  to.collision += p.collision;
  to.constraints += p.constraints;
  to.distance += p.distance;
  to.contacts += p.contacts;
  to.integrate_positions += p.integrate_positions;
  to.total += p.total;
  to.wall += p.wall;
  to.coupling += p.coupling;
  to.feedback += p.feedback;
  to.num_contacts = p.num_contacts;  // the last fine step's
  to.num_queries += p.num_queries;
  to.num_sample_queries += p.num_sample_queries;
}

void hash_settings(StateHasher& h, const SolverSettings& s) {
  const RodSettings& r = s.rod;
  h.add_value(r.dt);
  h.add_value(static_cast<int>(r.integrator));
  h.add_value(r.gravity);
  h.add_value(static_cast<int>(r.distance));
  h.add_value(r.iterations);
  h.add_value(r.drag);
  h.add_value(r.angular_drag);
  h.add_value(r.internal_damping);
  h.add_value(r.penalty_modulus_scale);
  h.add_value(s.collisions);
  h.add_value(s.contact_margin);
  h.add_value(s.penetration_correction);
  h.add_value(s.coherence_margin);
  h.add_value(s.leaf_cache_slack);
  h.add_value(static_cast<int>(s.hand_force));
  h.add_value(s.feedback_cutoff_hz);
  h.add_value(s.parallel_instruments);
  h.add_value(s.edge_sample_spacing);
}

// --- sub-steps (physics.md 5.4) -----------------------------------------------------------------

// The fastest hand the commands ask for (m/s), within each drive's limit.
double hand_speed(const SolverModel& md, const SolverState& st,
                  std::span<const DriveCommand> cmds) {
  double v = 0.0;
  const double dt = md.dt();
  for (std::size_t i = 0; i < st.instruments.size(); ++i) {
    if (st.instruments[i].parked) continue;
    const DriveCommand& d = cmds[i];
    const double rate = d.mode == DriveCommand::Mode::kPosition
                            ? (d.translation - st.instruments[i].drive.depth) / dt
                            : d.translation;
    v = std::max(v, std::min(std::abs(rate), md.instruments[i].sheath.max_speed));
  }
  return v;
}

// The split of a hand at SubStepSettings::speed (at least 2).
int threshold_split(const SolverModel& md) {
  const SubStepSettings& s = md.substeps;
  return std::clamp(static_cast<int>(std::ceil(s.speed * md.dt() / s.travel)), 2,
                    std::max(2, md.max_split()));
}

// How many fine steps a step at this hand speed is split into (1: not split).
int split_for(const SolverModel& md, const SolverState& st, double speed) {
  const int max_split = md.max_split();
  if (max_split <= 1) return 1;
  const SubStepSettings& s = md.substeps;
  // For a while after a sudden load: the split it asked for.
  const int held = st.time < st.hold_until ? st.held_split : 1;
  // A fast hand: split from above the speed until the hands are below half of it.
  const bool fast = speed > (st.split > held ? 0.5 : 1.0) * s.speed;
  if (!fast) return held;
  // As many fine steps as keep the hand's travel per fine step within `travel`. A split is only
  // made coarser once a quarter more speed would not need it, so a hand whose speed wavers about
  // a boundary does not swap masses back and forth.
  // (A hand's speed is read from its commands: 1e-6 of a step's travel is rounding.)
  const double per = speed * md.dt() / s.travel - 1e-6;
  int n = std::clamp(static_cast<int>(std::ceil(per)), 2, max_split);
  if (n < st.split && std::ceil(1.25 * per) >= st.split) n = st.split;
  return std::max(n, held);
}

// Moves the state to the masses of a split of n: where a mass grows the momentum is kept, where
// it shrinks the velocity, so a change of split takes energy out either way, never puts it in.
void use_split(const SolverModel& md, SolverState& st, int n) {
  if (n == st.split) return;
  for (std::size_t i = 0; i < st.instruments.size(); ++i) {
    const RodModel& from = md.instruments[i].rod(st.split);
    const RodModel& to = md.instruments[i].rod(n);
    RodState& rs = st.instruments[i].rod;
    for (int j = 0; j < from.n; ++j)
      if (to.node_mass[j] > from.node_mass[j]) rs.v[j] *= from.node_mass[j] / to.node_mass[j];
    for (int j = 0; j < from.m; ++j)
      for (int a = 0; a < 3; ++a)
        if (to.inertia[j][a] > from.inertia[j][a])
          rs.omega[j][a] = rs.omega[j][a] * from.inertia[j][a] / to.inertia[j][a];
  }
  st.split = n;
}

// Points the scratch's views at the model's rods for the state's split.
void bind(const SolverModel& md, SolverState& st, SolverScratch& s) {
  s.bound.clear();  // capacity kept: no allocation
  for (std::size_t i = 0; i < md.instruments.size(); ++i)
    s.bound.push_back(
        Inst{&md.instruments[i], &md.instruments[i].rod(st.split), &st.instruments[i], &s.inst[i]});
  s.pairs.clear();
  for (std::size_t c = 0; c < md.couplings.size(); ++c)
    s.pairs.push_back(Pair{&md.couplings[c], &s.coupling[c]});
}

// The instruments over one step of dt in st.split fine steps; the hand force is their mean.
void advance(const SolverModel& md, SolverState& st, SolverScratch& s, VesselWall* wall,
             std::span<const DriveCommand> cmds, StepProfile* prof) {
  const double dt = md.dt();
  const int n = st.split;
  const SolverSettings& set = md.settings[n - 1];
  const std::size_t ni = st.instruments.size();
  bind(md, st, s);
  for (internal::InstrumentScratch& w : s.inst) w.escape = NodeEscape{};
  std::fill(s.fine_force.begin(), s.fine_force.end(), 0.0);
  std::fill(s.fine_torque.begin(), s.fine_torque.end(), 0.0);
  for (int k = 1; k <= n; ++k) {
    // The hand's command spread evenly over the fine steps: a position k / n of the way there.
    for (std::size_t i = 0; i < ni; ++i) {
      DriveCommand& c = s.sub_drive[i];
      c = cmds[i];
      if (c.mode == DriveCommand::Mode::kPosition && k < n) {
        const DriveState& start = s.backup_drive[i];
        c.translation = start.depth + (cmds[i].translation - start.depth) * k / n;
        c.rotation = start.roll + (cmds[i].rotation - start.roll) * k / n;
      }
    }
    const double w0 = prof ? now_us() : 0.0;
    if (wall) wall->set_time(st.time + dt * k / n);
    StepProfile p;
    const double w1 = prof ? now_us() : 0.0;
    internal::fine_step(s.bound, s.pairs, wall, set, s.sub_drive, prof ? &p : nullptr);
    if (prof) {
      p.wall = w1 - w0;
      add(*prof, p);
    }
    for (std::size_t i = 0; i < ni; ++i) {
      s.fine_force[i] += st.instruments[i].drive.axial_force_raw / n;
      s.fine_torque[i] += st.instruments[i].drive.torque_raw / n;
    }
  }
  // The hand force of a split step is its fine steps' mean: the step's impulse over dt, as a
  // sensor that integrates over the step reads it. (The low-pass, if any, ran on the fine steps.)
  if (n > 1) {
    for (std::size_t i = 0; i < ni; ++i) {
      DriveState& ds = st.instruments[i].drive;
      ds.axial_force_raw = s.fine_force[i];
      ds.torque_raw = s.fine_torque[i];
      if (set.feedback_cutoff_hz <= 0.0) {
        ds.axial_force = ds.axial_force_raw;
        ds.torque = ds.torque_raw;
      }
    }
  }
}

void restore_start(SolverState& st, const SolverScratch& s) {
  for (std::size_t i = 0; i < st.instruments.size(); ++i) {
    st.instruments[i].rod = s.backup_rod[i];
    st.instruments[i].drive = s.backup_drive[i];
  }
}

// True when a node of an instrument in the body moved more than `limit` (m) over the step.
bool ran_away(const SolverState& st, const SolverScratch& s, double limit) {
  const double limit2 = limit * limit;
  for (std::size_t i = 0; i < st.instruments.size(); ++i) {
    const InstrumentState& in = st.instruments[i];
    if (in.parked) continue;
    const std::vector<Vec3>& x = in.rod.x;
    const std::vector<Vec3>& x0 = s.backup_rod[i].x;
    for (std::size_t k = 0; k < x.size(); ++k)
      if ((x[k] - x0[k]).squaredNorm() > limit2) return true;
  }
  return false;
}

}  // namespace

// --- model ---------------------------------------------------------------------------------------

void ContactMaterial::validate(const std::string& source) const {
  require_nonnegative(mu_static, source, "mu_static");
  require_nonnegative(mu_dynamic, source, "mu_dynamic");
  if (mu_dynamic > mu_static) {
    throw InputError(source, "mu_dynamic", "expected at most mu_static");
  }
}

void SolverSettings::validate(const std::string& source) const {
  rod.validate(source);
  require_nonnegative(contact_margin, source, "contact_margin");
  require_in_range(penetration_correction, 0.0, 1.0, source, "penetration_correction");
  require_nonnegative(coherence_margin, source, "coherence_margin");
  require_nonnegative(leaf_cache_slack, source, "leaf_cache_slack");
  require_nonnegative(feedback_cutoff_hz, source, "feedback_cutoff_hz");
  require_nonnegative(edge_check_period, source, "edge_check_period");
  require_nonnegative(edge_sample_spacing, source, "edge_sample_spacing");
  if (rod.integrator == Integrator::kLinearlyImplicit && collisions) {
    // physics.md 5.5: with the physical mass the projected Gauss-Seidel loop of distance chain,
    // contacts and friction does not converge in a usable number of iterations.
    throw InputError(source, "rod.integrator",
                     "expected symplectic-euler where instruments collide: the linearly implicit "
                     "step runs at the physical mass, which the contact solve cannot take yet");
  }
}

void SolverModel::validate(const std::string& source) const {
  if (settings.empty()) throw InputError(source, "settings", "expected at least one split");
  for (std::size_t k = 0; k < settings.size(); ++k) settings[k].validate(source);
  const int splits = max_split();
  for (std::size_t i = 0; i < instruments.size(); ++i) {
    const InstrumentModel& im = instruments[i];
    const std::string field = "instruments[" + std::to_string(i) + "]";
    if (static_cast<int>(im.rods.size()) != splits)
      throw InputError(source, field + ".rods",
                       "expected one rod per split (" + std::to_string(splits) + "), got " +
                           std::to_string(im.rods.size()));
    for (const RodModel& r : im.rods)
      if (r.n != im.rods[0].n)
        throw InputError(source, field + ".rods", "expected the same node count in every split");
    im.contact.validate(source + ": " + field);
  }
  const auto ni = static_cast<int>(instruments.size());
  if (couplings.size() > 254)
    throw InputError(source, "couplings", "expected at most 254 couplings");
  auto coupled = [&](int inner, int outer, std::size_t before) {
    for (std::size_t k = 0; k < before; ++k)
      if (couplings[k].inner == inner && couplings[k].outer == outer) return true;
    return false;
  };
  for (std::size_t c = 0; c < couplings.size(); ++c) {
    const CouplingModel& cm = couplings[c];
    const std::string field = "couplings[" + std::to_string(c) + "]";
    if (cm.inner < 0 || cm.inner >= ni || cm.outer < 0 || cm.outer >= ni || cm.inner == cm.outer)
      throw InputError(source, field, "expected two different instruments of the model");
    if (coupled(cm.inner, cm.outer, c))
      throw InputError(source, field, "expected each instrument in another's lumen once");
    require_nonnegative(cm.mu, source, field + ".mu");
    // An earlier outer of the same inner must lie inside this one (innermost first), or beside
    // it in a third (two catheters riding one wire in turn, in one guide).
    for (std::size_t k = 0; k < c; ++k) {
      if (couplings[k].inner != cm.inner) continue;
      const int o = couplings[k].outer;
      bool beside = false;
      for (const CouplingModel& x : couplings)
        beside = beside || (x.inner == o && coupled(cm.outer, x.outer, couplings.size()));
      if (!coupled(o, cm.outer, couplings.size()) && !beside)
        throw InputError(source, field,
                         "expected the outers of instrument " + std::to_string(cm.inner) +
                             " innermost first, each inside the next or beside it");
    }
  }
  require_positive(substeps.speed, source, "substeps.speed");
  require_positive(substeps.travel, source, "substeps.travel");
  require_nonnegative(substeps.jump, source, "substeps.jump");
  require_nonnegative(substeps.hold, source, "substeps.hold");
  require_nonnegative(substeps.runaway, source, "substeps.runaway");
}

std::uint64_t SolverModel::hash() const {
  StateHasher h;
  for (const InstrumentModel& im : instruments) {
    for (const RodModel& r : im.rods) r.hash_into(h);
    h.add_value(im.sheath.access_point);
    h.add_value(im.sheath.frame);
    h.add_value(im.sheath.max_speed);
    h.add_value(im.sheath.max_spin);
    h.add_value(im.sheath.length);
    h.add_value(im.sheath.inner_radius);
    h.add_value(im.sheath.grip_force);
    h.add_value(im.sheath.grip_torque);
    h.add_value(im.contact.mu_static);
    h.add_value(im.contact.mu_dynamic);
    h.add_value(im.driven);
  }
  for (const CouplingModel& c : couplings) {
    h.add_value(c.inner);
    h.add_value(c.outer);
    h.add_value(c.mu);
    h.add_value(c.rim);
  }
  for (const SolverSettings& s : settings) hash_settings(h, s);
  h.add_value(substeps.speed);
  h.add_value(substeps.travel);
  h.add_value(substeps.jump);
  h.add_value(substeps.hold);
  h.add_value(substeps.runaway);
  return h.value();
}

InstrumentModel make_instrument_model(const RodDef& def_in, const Sheath& sheath,
                                      const ContactMaterial& contact) {
  RodDef def = def_in;
  if (def.base != BoundaryKind::kFree || def.tip != BoundaryKind::kFree) {
    throw InputError("instrument", "boundary", "expected free ends (the drive holds the rod)");
  }
  contact.validate("instrument");
  for (int k = 0; k < 3; ++k) require_finite(sheath.access_point[k], "sheath", "access_point");
  require_positive(sheath.max_speed, "sheath", "max_speed");
  require_positive(sheath.max_spin, "sheath", "max_spin");
  require_positive(sheath.grip_force, "sheath", "grip_force");
  require_positive(sheath.grip_torque, "sheath", "grip_torque");
  // The rod as it lies on the sheath axis with nothing inserted.
  const Quat frame = sheath.frame.normalized();
  const Vec3 axis = frame * Vec3::UnitZ();
  def.base_orientation = (Quat(Eigen::AngleAxisd(0.0, axis)) * frame).normalized();
  def.base_position = sheath.access_point - def.length * axis;
  def.start_in_rest_shape = false;
  InstrumentModel im;
  im.rods.push_back(build_rod(def));
  im.sheath = sheath;
  im.sheath.frame = frame;
  im.contact = contact;
  return im;
}

InstrumentModel make_free_instrument_model(const RodDef& def, const ContactMaterial& contact) {
  contact.validate("instrument");
  InstrumentModel im;
  im.rods.push_back(build_rod(def));
  im.contact = contact;
  im.driven = false;
  return im;
}

void make_quasi_static(SolverModel& model, int max_split) {
  if (max_split < 1) throw InputError("solver", "max_split", "expected at least 1");
  const SolverSettings base = model.settings.at(0);
  const double dt = base.rod.dt;
  model.settings.assign(static_cast<std::size_t>(max_split), base);
  for (int k = 1; k <= max_split; ++k) {
    RodSettings& rs = model.settings[k - 1].rod;
    rs.dt = dt / k;
    set_quasi_static_damping(rs);
  }
  for (InstrumentModel& im : model.instruments) {
    const RodModel built = im.rods.at(0);
    im.rods.assign(static_cast<std::size_t>(max_split), built);
    // Each node and frame only as heavy as the explicit step needs, for the step and for each
    // split of it a fast hand may use.
    for (int k = 1; k <= max_split; ++k)
      scale_for_time_step(im.rods[k - 1], dt / k, kQuasiStaticKpRatio);
  }
}

// --- state ---------------------------------------------------------------------------------------

namespace {

InstrumentState sized_state(const RodModel& md, RodState rod) {
  InstrumentState s;
  s.rod = std::move(rod);
  s.query_centre.assign(md.n, Vec3::Zero());
  s.clearance.assign(md.n, 0.0);
  s.travel_at.assign(md.n, 0.0);
  return s;
}

}  // namespace

InstrumentState make_instrument_state(const InstrumentModel& im, double depth, double roll) {
  const RodModel& md = im.rod();
  require_nonnegative(depth, "instrument", "depth");
  require_finite(roll, "instrument", "roll");
  if (depth > md.length - md.rest_length[0]) {
    throw InputError("instrument", "depth", "expected at most the length less one segment");
  }
  // Laid on the sheath axis with `depth` beyond the access point, turned by the roll.
  const Sheath& sh = im.sheath;
  const Vec3 axis = sh.frame * Vec3::UnitZ();
  const Quat base = (Quat(Eigen::AngleAxisd(roll, axis)) * sh.frame).normalized();
  const Vec3 start = sh.access_point - (md.length - depth) * axis;
  RodState st;
  const Vec3 d3 = base * Vec3::UnitZ();
  st.x.resize(md.n);
  for (int i = 0; i < md.n; ++i) st.x[i] = start + md.node_s[i] * d3;
  st.q.assign(md.m, base);
  st.v.assign(md.n, Vec3::Zero());
  st.omega.assign(md.m, Vec3::Zero());
  st.f_ext.assign(md.n, Vec3::Zero());
  st.tau_ext.assign(md.m, Vec3::Zero());
  st.base_frame = base;
  st.tip_frame = st.q.back();
  InstrumentState s = sized_state(md, std::move(st));
  s.drive.depth = depth;
  s.drive.roll = roll;
  return s;
}

InstrumentState make_free_instrument_state(const InstrumentModel& im, const RodDef& def) {
  return sized_state(im.rod(), make_state(im.rod(), def));
}

SolverState make_solver_state(const SolverModel& model, std::vector<InstrumentState> instruments) {
  if (instruments.size() != model.instruments.size())
    throw InputError("solver", "instruments",
                     "expected one state per instrument of the model (" +
                         std::to_string(model.instruments.size()) + "), got " +
                         std::to_string(instruments.size()));
  for (std::size_t i = 0; i < instruments.size(); ++i)
    if (instruments[i].rod.x.size() != static_cast<std::size_t>(model.instruments[i].rod().n) ||
        instruments[i].clearance.size() != instruments[i].rod.x.size() ||
        instruments[i].travel_at.size() != instruments[i].rod.x.size())
      throw InputError("solver", "instruments[" + std::to_string(i) + "]",
                       "expected a state of that instrument's model (node count)");
  SolverState st;
  st.instruments = std::move(instruments);
  return st;
}

void SolverState::hash_into(StateHasher& h) const {
  for (const InstrumentState& in : instruments) {
    in.rod.hash_into(h);
    const DriveState& d = in.drive;
    for (double v : {d.depth, d.roll, d.depth_rate, d.roll_rate, d.axial_force, d.torque,
                     d.axial_force_raw, d.torque_raw})
      h.add_value(v);
    h.add_value(d.first_free);
    h.add_value(in.parked);
    h.add(in.query_centre);
    h.add(in.clearance);
    h.add(in.travel_at);
    h.add(in.sample_centre);
    h.add(in.sample_clearance);
    h.add(in.sample_travel_at);
    h.add_value(in.wall_travel);
    const BalloonHold& b = in.hold;
    h.add_value(b.first);
    h.add_value(b.last);
    for (const std::vector<Vec3>* v : {&b.axis, &b.tangent, &b.axis_velocity}) h.add(*v);
    h.add(b.play);
    h.add(b.wall_load);
  }
  h.add_value(time);
  h.add_value(split);
  h.add_value(hold_until);
  h.add_value(held_split);
}

std::uint64_t SolverState::hash() const {
  StateHasher h;
  hash_into(h);
  return h.value();
}

// --- workspace -----------------------------------------------------------------------------------

SolverWorkspace::SolverWorkspace(const SolverModel& model)
    : s_(std::make_unique<internal::SolverScratch>()) {
  SolverScratch& s = *s_;
  const std::size_t n = model.instruments.size();
  s.inst.resize(n);
  for (std::size_t i = 0; i < n; ++i)
    s.inst[i].resize(model.instruments[i].rod(), model.settings[0].edge_sample_spacing);
  s.coupling.resize(model.couplings.size());
  for (std::size_t c = 0; c < model.couplings.size(); ++c)
    s.coupling[c].contacts.reserve(model.instruments[model.couplings[c].inner].rod().n);
  s.bound.reserve(n);
  s.pairs.reserve(model.couplings.size());
  s.sub_drive.resize(n);
  s.fine_force.assign(n, 0.0);
  s.fine_torque.assign(n, 0.0);
  s.backup_rod.resize(n);
  s.backup_drive.resize(n);
}

SolverWorkspace::~SolverWorkspace() = default;
SolverWorkspace::SolverWorkspace(SolverWorkspace&&) noexcept = default;
SolverWorkspace& SolverWorkspace::operator=(SolverWorkspace&&) noexcept = default;

std::span<const NodeContact> SolverWorkspace::contacts(int instrument) const {
  return s_->inst.at(instrument).contacts;
}

std::span<const CoaxialContact> SolverWorkspace::coupling_contacts(int coupling) const {
  return s_->coupling.at(coupling).contacts;
}

std::span<const NodeContact> SolverWorkspace::edge_contacts(int instrument) const {
  return s_->inst.at(instrument).edge_contacts;
}

double SolverWorkspace::coupling_clearance(int coupling) const {
  return s_->coupling.at(coupling).clearance;
}

void SolverWorkspace::clear_caches() {
  for (internal::InstrumentScratch& in : s_->inst) {
    for (LeafCache& c : in.leaf_cache) c.clear();
    for (LeafCache& c : in.sample_cache) c.clear();
  }
}

bool SolverWorkspace::sheathed(int instrument, int node) const {
  return s_->inst.at(instrument).sheathed.at(node) != 0;
}

NodeEscape SolverWorkspace::escape(int instrument) const {
  return s_->inst.at(instrument).escape;
}

NodeEscape SolverWorkspace::edge_escape(int instrument) const {
  return s_->inst.at(instrument).edge_escape;
}

// --- step ----------------------------------------------------------------------------------------

StepInfo solver_step(const SolverModel& md, SolverState& st, SolverWorkspace& ws, VesselWall* wall,
                     std::span<const DriveCommand> cmds, StepProfile* prof) {
  SolverScratch& s = ws.scratch();
  const std::size_t n = st.instruments.size();
  if (prof) *prof = StepProfile{};
  for (std::size_t i = 0; i < n; ++i) {
    s.backup_rod[i] = st.instruments[i].rod;
    s.backup_drive[i] = st.instruments[i].drive;
  }
  // A driven instrument lying outside that the hand does not push in is parked (skipped).
  for (std::size_t i = 0; i < n; ++i) {
    const DriveCommand& d = cmds[i];
    const DriveState& ds = st.instruments[i].drive;
    const bool still = d.mode == DriveCommand::Mode::kPosition
                           ? d.translation <= 0.0 && d.rotation == ds.roll
                           : d.translation <= 0.0 && d.rotation == 0.0;
    st.instruments[i].parked = md.instruments[i].driven && ds.depth <= 0.0 && still;
  }
  StepInfo info;
  // A fast hand: fine steps with the masses for them.
  use_split(md, st, split_for(md, st, hand_speed(md, st, cmds)));
  advance(md, st, s, wall, cmds, prof);
  // A sudden load on a hand (a scaled mass stopped or let go): the step is taken again, split at
  // least twice as finely, and that split held for a while. The contact coherence of the first
  // try is kept (it only decides which nodes are queried, and how wide).
  const SubStepSettings& sub = md.substeps;
  auto retake_finer = [&] {
    restore_start(st, s);
    st.hold_until = st.time + sub.hold;
    st.held_split = std::min(md.max_split(), std::max(2 * st.split, threshold_split(md)));
    use_split(md, st, split_for(md, st, hand_speed(md, st, cmds)));
    advance(md, st, s, wall, cmds, prof);
  };
  auto restore_at_rest = [&] {
    restore_start(st, s);
    for (InstrumentState& in : st.instruments) {
      for (Vec3& v : in.rod.v) v.setZero();
      for (Vec3& w : in.rod.omega) w.setZero();
    }
  };
  if (st.split < md.max_split() && sub.jump > 0.0) {
    bool sudden = false;
    for (std::size_t i = 0; i < n; ++i) {
      const InstrumentState& in = st.instruments[i];
      const bool inserted = !in.parked && in.drive.depth > 0.0 && s.backup_drive[i].depth > 0.0;
      sudden = sudden || (inserted && std::abs(in.drive.axial_force_raw -
                                               s.backup_drive[i].axial_force_raw) > sub.jump);
    }
    if (sudden) {
      retake_finer();
      info.resplit = true;
    }
  }
  // A node that ran away (far faster than any hand or wall moves it): the step is taken again
  // split finer, and if a node still runs away, from rest (its kinetic energy is taken out).
  if (sub.runaway > 0.0 && ran_away(st, s, sub.runaway * md.dt())) {
    info.runaway = true;
    if (st.split < md.max_split()) retake_finer();
    if (ran_away(st, s, sub.runaway * md.dt())) {
      restore_at_rest();
      advance(md, st, s, wall, cmds, prof);
      info.calmed = true;
    }
  }
  bool finite = true;
  for (const InstrumentState& in : st.instruments) finite = finite && finite_state(in.rod);
  if (!finite) {
    // Undo the step and hold the instruments still; the caller sees it in StepInfo.
    restore_at_rest();
    for (internal::InstrumentScratch& w : s.inst) w.escape = NodeEscape{};
    info.rolled_back = true;
  }
  // The edges between free nodes, now and then: one through a ridge of the wall (the carina
  // between the iliacs) with both its nodes inside is out of the vessel where the nodes' queries
  // do not see (physics.md 6.3). Checked at the step's end, the wall at that time.
  for (internal::InstrumentScratch& w : s.inst) w.edge_escape = NodeEscape{};
  const SolverSettings& set = md.settings[static_cast<std::size_t>(st.split - 1)];
  const double period = set.edge_check_period;
  const double t1 = st.time + md.dt();
  if (finite && wall && set.collisions &&
      (period <= 0.0 || std::floor(st.time / period) != std::floor(t1 / period))) {
    wall->set_time(t1);
    for (const internal::Inst& in : s.bound)
      if (!in.parked()) internal::check_edges(in, *wall, set);
  }
  st.time += md.dt();
  info.split = st.split;
  return info;
}

double compression(const RodModel& md, const RodState& st) {
  return (md.length - centreline_length(st)) / md.length;
}

}  // namespace vcsim
