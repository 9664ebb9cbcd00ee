// The simulation of a scenario: its state and workspace (the model is model.cpp's), and the sim
// step of docs/architecture.md: the instruments (solver_step), contrast transport, metrics and
// landmarks (docs/scenarios.md).
#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

#include "sim_scratch.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

// Cardiac output at rest, 5 l/min (clinical.md): what dilutes contrast injected into the aorta.
constexpr double kCardiacOutput = 83.0e-6;  // m^3/s
constexpr double kContrastFill = 0.1;       // s, time constant of filling a segment once it arrives
constexpr double kLandmarkInterval = 0.005;  // s between landmark checks

}  // namespace

// --- state ---------------------------------------------------------------------------------------

ContrastState make_contrast_state(const VesselTree& tree, double dt) {
  ContrastState s;
  s.concentration.assign(tree.num_segments(), 0.0f);
  s.arrival.assign(tree.num_segments(), -1.0);
  s.history.assign(static_cast<std::size_t>(std::ceil(2.0 / dt)) + 1, 0.0f);
  return s;
}

void contrast_step(const VesselTree& tree, const ContrastSettings& set, double dt, double flow,
                   const TreeLocation& at, ContrastState& s) {
  const std::size_t nh = s.history.size();
  if (flow > 0.0 && s.segment < 0 && at.segment >= 0) {
    s.segment = at.segment;
    // Transport delay: the centreline distance from the injection point to each segment's
    // start, for the injected segment and everything below it (parents precede children).
    std::fill(s.arrival.begin(), s.arrival.end(), -1.0);
    s.arrival[at.segment] = 0.0;
    for (int k = at.segment + 1; k < tree.num_segments(); ++k) {
      const int p = tree.segments[k].parent;
      if (p < 0 || s.arrival[p] < 0.0) continue;
      const double from = p == at.segment ? at.distance : 0.0;
      s.arrival[k] =
          s.arrival[p] + std::max(0.0, attach_distance(tree, k) - from) / set.blood_speed;
    }
  }
  if (flow > 0.0) s.volume += flow * dt;
  s.pos = (s.pos + 1) % nh;
  s.history[s.pos] = static_cast<float>(std::max(0.0, flow));
  if (s.segment < 0) return;
  const bool coronary = tree.segments[s.segment].kind == VesselKind::kCoronary;
  const double blood = coronary ? set.blood_flow : kCardiacOutput;
  bool any = false;
  for (int k = 0; k < tree.num_segments(); ++k) {
    if (s.arrival[k] < 0.0) continue;
    const std::size_t lag = std::min(nh - 1, static_cast<std::size_t>(s.arrival[k] / dt));
    const double q = s.history[(s.pos + nh - lag) % nh];
    const double target = set.concentration * q / (q + blood);
    const double c = s.concentration[k];
    const double tau = target > c ? kContrastFill : set.washout;
    s.concentration[k] = static_cast<float>(c + (target - c) * (1.0 - std::exp(-dt / tau)));
    any = any || s.concentration[k] > 1e-4f || q > 0.0;
  }
  if (!any) s.segment = -1;  // washed out: the next injection starts afresh
}

SimState make_sim_state(const SimModel& md) {
  SimState st;
  std::vector<InstrumentState> insts;
  for (const InstrumentModel& im : md.solver.instruments)
    insts.push_back(make_instrument_state(im, 0.0));
  st.solver = make_solver_state(md.solver, std::move(insts));
  st.contrast = make_contrast_state(md.tree, md.dt());
  const std::size_t n = md.solver.instruments.size();
  SimMetrics& m = st.metrics;
  m.tip_path.assign(n, 0.0);
  m.peak_wall_force.assign(n, 0.0);
  m.peak_axial_force.assign(n, 0.0);
  m.peak_axial_jump.assign(n, 0.0);
  m.peak_torque.assign(n, 0.0);
  m.last_axial_force.assign(n, std::nan(""));
  m.landmarks.assign(md.scenario.landmarks.size(), LandmarkRecord{});
  m.escapes.assign(n, EscapeRecord{});
  m.edge_crossings.assign(n, EscapeRecord{});
  st.procedure = make_procedure_state(md.procedure, st.solver);
  st.random.state = md.scenario.seed;
  return st;
}

std::uint64_t SimState::hash() const {
  StateHasher h;
  solver.hash_into(h);
  const ContrastState& c = contrast;
  h.add(c.concentration);
  h.add(c.arrival);
  h.add(c.history);
  h.add_value(c.pos);
  h.add_value(c.segment);
  h.add_value(c.volume);
  const SimMetrics& m = metrics;
  h.add_value(m.steps);
  for (const std::vector<double>* v : {&m.tip_path, &m.peak_wall_force, &m.peak_axial_force,
                                       &m.peak_axial_jump, &m.peak_torque, &m.last_axial_force})
    h.add(*v);
  for (const LandmarkRecord& l : m.landmarks) {
    h.add_value(l.reached);
    h.add_value(l.time);
  }
  h.add_value(m.next_landmark_check);
  h.add_value(m.rollbacks);
  h.add_value(m.resplit_steps);
  // Only when there were any: the hashes pinned before the guard stay valid.
  if (m.runaway_steps > 0) {
    h.add_value(m.runaway_steps);
    h.add_value(m.calmed_steps);
  }
  auto add_records = [&h](const std::vector<EscapeRecord>& records) {
    for (const EscapeRecord& e : records) {
      h.add_value(e.steps);
      h.add_value(e.time);
      h.add_value(e.node);
      h.add_value(e.distance);
      h.add_value(e.exit);
      h.add_value(e.max_distance);
      h.add_value(e.position);
      h.add_value(e.near.segment);
      h.add_value(e.near.distance);
    }
  };
  if (m.escape_steps > 0) {
    h.add_value(m.escape_steps);
    add_records(m.escapes);
  }
  if (m.edge_crossing_checks > 0) {
    h.add_value(m.edge_crossing_checks);
    add_records(m.edge_crossings);
  }
  procedure.hash_into(h);
  h.add_value(random.state);
  return h.value();
}

namespace {

template <class T>
std::size_t bytes_of(const std::vector<T>& v) {
  return v.capacity() * sizeof(T);
}

}  // namespace

std::size_t SimState::bytes() const {
  std::size_t b = sizeof(SimState);
  for (const InstrumentState& in : solver.instruments) {
    const RodState& r = in.rod;
    b += sizeof(InstrumentState) + bytes_of(r.x) + bytes_of(r.v) + bytes_of(r.q) +
         bytes_of(r.omega) + bytes_of(r.f_ext) + bytes_of(r.tau_ext) + bytes_of(in.query_centre) +
         bytes_of(in.clearance) + bytes_of(in.travel_at) + bytes_of(in.sample_centre) +
         bytes_of(in.sample_clearance) + bytes_of(in.sample_travel_at);
  }
  b += bytes_of(contrast.concentration) + bytes_of(contrast.arrival) + bytes_of(contrast.history);
  const SimMetrics& m = metrics;
  b += bytes_of(m.tip_path) + bytes_of(m.peak_wall_force) + bytes_of(m.peak_axial_force) +
       bytes_of(m.peak_axial_jump) + bytes_of(m.peak_torque) + bytes_of(m.last_axial_force) +
       bytes_of(m.landmarks) + bytes_of(m.escapes) + bytes_of(m.edge_crossings);
  for (const BalloonState& bs : procedure.balloons)
    b += bytes_of(bs.radius) + bytes_of(bs.s) + bytes_of(bs.hold_excess);
  for (const StentState& ss : procedure.stents)
    b += bytes_of(ss.expanded) + bytes_of(ss.ring_s) + bytes_of(ss.ring_radius);
  for (const auto* v :
       {&procedure.opening, &procedure.max_opening, &procedure.stent_hold, &procedure.pushed})
    for (const LesionOpening& o : *v) b += bytes_of(o.t);
  b += bytes_of(procedure.events);
  return b;
}

// --- workspace -----------------------------------------------------------------------------------

SimWorkspace::SimWorkspace(const SimModel& md)
    : s_(std::make_unique<internal::SimScratch>(md, nullptr)) {}
SimWorkspace::SimWorkspace(const SimModel& md, SimWorkspace&& old)
    : s_(std::make_unique<internal::SimScratch>(md, old.s_.get())) {}
SimWorkspace::~SimWorkspace() = default;
SolverWorkspace& SimWorkspace::solver() {
  return s_->solver;
}
const SolverWorkspace& SimWorkspace::solver() const {
  return s_->solver;
}
VesselWall& SimWorkspace::wall() {
  return s_->wall;
}

internal::SimScratch::SimScratch(const SimModel& md, SimScratch* reuse) : solver(md.solver) {
  const LesionMorph& morph = md.procedure.morph;
  const bool morphs = !morph.vertices.empty();
  const std::size_t balloons = md.procedure.balloons.size();
  if (reuse) {
    // The same anatomy: its wall as the old workspace last showed it (the lumen at the lesions'
    // opening, the stents' tubes by balloon index, which an exchange keeps).
    beating = std::move(reuse->beating);
    beating_wall = std::move(reuse->beating_wall);
    static_mesh = std::move(reuse->static_mesh);
    static_tree = std::move(reuse->static_tree);
    if (beating_wall) {
      wall.lumen = beating_wall.get();
    } else {
      static_wall = morphs ? std::make_unique<StaticWall>(static_mesh, static_tree)
                           : std::make_unique<StaticWall>(md.lumen.mesh, md.static_tree);
      wall.lumen = static_wall.get();
    }
    wall.motion = md.motion ? &*md.motion : nullptr;
    wall.exits_rest = std::move(reuse->wall.exits_rest);
    wall.exit_amp_c = std::move(reuse->wall.exit_amp_c);
    wall.exit_amp_r = std::move(reuse->wall.exit_amp_r);
    wall.stents = std::move(reuse->wall.stents);
    wall.stents.resize(balloons);
    shown_stents = std::move(reuse->shown_stents);
    shown_stents.resize(balloons, 0);
    morph_triangles = std::move(reuse->morph_triangles);
    shown_opening = std::move(reuse->shown_opening);
    morphed = std::move(reuse->morphed);
    old_tips.resize(md.solver.instruments.size());
    return;
  }
  if (md.motion) {
    beating = std::make_unique<BeatingLumen>(md.lumen.mesh, *md.motion, morph.vertices,
                                             md.procedure.morph_limit);
    beating_wall = std::make_unique<BeatingWall>(*beating);
    wall.lumen = beating_wall.get();
  } else if (morphs) {
    // The lumen's own copy, to morph in place.
    static_mesh = md.lumen.mesh;
    static_tree = md.static_tree;
    static_wall = std::make_unique<StaticWall>(static_mesh, static_tree);
    wall.lumen = static_wall.get();
  } else {
    static_wall = std::make_unique<StaticWall>(md.lumen.mesh, md.static_tree);
    wall.lumen = static_wall.get();
  }
  wall.motion = md.motion ? &*md.motion : nullptr;
  if (is_mesh_file(md.scenario.anatomy)) {
    make_exits(md.tree, wall.motion, wall, &md.lumen);
  } else {
    make_exits(md.tree, wall.motion, wall, nullptr, &md.sheath);
  }
  if (morphs && !md.motion) {
    std::vector<unsigned char> moved(md.lumen.mesh.vertices.size(), 0);
    for (int v : morph.vertices) moved[v] = 1;
    for (int t = 0; t < md.lumen.mesh.num_triangles(); ++t)
      for (int v : md.lumen.mesh.triangles[t])
        if (moved[v]) {
          morph_triangles.push_back(t);
          break;
        }
  }
  LesionOpening zero;
  zero.t.assign(kLesionSamples, 0.0);
  shown_opening.assign(md.tree.lesions.size(), zero);
  morphed.resize(morph.vertices.size());
  shown_stents.assign(balloons, 0);
  wall.stents.resize(balloons);
  old_tips.resize(md.solver.instruments.size());
}

// --- step ----------------------------------------------------------------------------------------

Vec3 tip(const SimState& st, int i) {
  return st.solver.instruments[i].rod.x.back();
}

Vec3 tip_rest(const SimModel& md, const SimState& st, int i) {
  const Vec3 p = tip(st, i);
  return md.motion ? md.motion->rest_point(p, st.time()) : p;
}

TreeHit tip_location(const SimModel& md, const SimState& st, int i) {
  return md.locator.locate(tip_rest(md, st, i));
}

bool all_landmarks_reached(const SimState& st) {
  for (const LandmarkRecord& l : st.metrics.landmarks)
    if (!l.reached) return false;
  return true;
}

namespace {

// Tip paths and peak forces of the step just taken; `old_tips` where the tips were before it.
void update_metrics(const SimModel& md, SimState& st, const SolverWorkspace& ws,
                    std::span<const Vec3> old_tips) {
  // The last (fine) step's dt: the contact impulses are its.
  const double dt = md.solver.settings[st.solver.split - 1].rod.dt;
  SimMetrics& m = st.metrics;
  bool escaped = false, edge_crossed = false;
  for (std::size_t i = 0; i < st.solver.instruments.size(); ++i) {
    const InstrumentState& in = st.solver.instruments[i];
    if (in.drive.depth > 0.0) m.tip_path[i] += (in.rod.x.back() - old_tips[i]).norm();
    double f = 0.0;
    // A parked instrument was not stepped: its contact list is an earlier step's (before a
    // restore, another run's), so it has none this step.
    if (!in.parked)
      for (const auto& list :
           {ws.contacts(static_cast<int>(i)), ws.edge_contacts(static_cast<int>(i))})
        for (const NodeContact& c : list) f = std::max(f, c.lambda_n / dt);
    m.peak_wall_force[i] = std::max(m.peak_wall_force[i], f);
    // A node outside the vessel (physics.md 6.3), as this step's contact queries saw it, and an
    // edge through the wall, as the step's edge check (if any) saw it.
    auto record = [&](const NodeEscape& e, EscapeRecord& rec) {
      if (e.node < 0) return false;
      if (rec.steps == 0) {
        rec.time = st.time();
        rec.node = e.node;
        rec.distance = e.distance;
        rec.exit = e.exit;
        rec.edge = e.edge;
        // Where, for the person reading the report: the node's place (an edge's deepest point)
        // and the vessel nearest it.
        const auto k = static_cast<std::size_t>(e.node);
        rec.position =
            e.edge ? Vec3(in.rod.x[k] + e.along * (in.rod.x[k + 1] - in.rod.x[k])) : in.rod.x[k];
        rec.near =
            md.locator
                .locate(md.motion ? md.motion->rest_point(rec.position, st.time()) : rec.position)
                .loc;
      }
      ++rec.steps;
      rec.max_distance = std::max(rec.max_distance, e.distance);
      return true;
    };
    if (!in.parked) {
      escaped = record(ws.escape(static_cast<int>(i)), m.escapes[i]) || escaped;
      edge_crossed =
          record(ws.edge_escape(static_cast<int>(i)), m.edge_crossings[i]) || edge_crossed;
    }
    m.peak_axial_force[i] = std::max(m.peak_axial_force[i], std::abs(in.drive.axial_force));
    m.peak_torque[i] = std::max(m.peak_torque[i], std::abs(in.drive.torque));
    // NaN while outside: no jump is counted across an insertion or a withdrawal.
    double& last = m.last_axial_force[i];
    if (in.drive.depth > 0.0) {
      const double jump = std::abs(in.drive.axial_force - last);
      if (jump > m.peak_axial_jump[i]) m.peak_axial_jump[i] = jump;
      last = in.drive.axial_force;
    } else {
      last = std::nan("");
    }
  }
  m.escape_steps += escaped ? 1 : 0;
  m.edge_crossing_checks += edge_crossed ? 1 : 0;
}

void check_landmarks(const SimModel& md, SimState& st) {
  SimMetrics& m = st.metrics;
  if (st.time() < m.next_landmark_check) return;
  m.next_landmark_check = st.time() + kLandmarkInterval;
  for (std::size_t k = 0; k < m.landmarks.size(); ++k) {
    LandmarkRecord& rec = m.landmarks[k];
    if (rec.reached) continue;
    const auto [i, seg] = md.landmark_ids[k];
    // (an instrument not in the scene: added later, or removed before it got there)
    if (i < 0 || st.solver.instruments[i].drive.depth <= 0.0) continue;
    const TreeHit h = tip_location(md, st, i);
    if (h.loc.segment == seg &&
        h.loc.distance >= ostium_distance(md.tree, seg) + md.scenario.landmarks[k].distance &&
        h.outside < 0.5e-3) {
      rec.reached = true;
      rec.time = st.time();
    }
  }
}

}  // namespace

void sim_step(const SimModel& md, SimState& st, SimWorkspace& ws, const StepCommands& cmds,
              SimStepProfile* prof) {
  assert(cmds.drive.size() == md.solver.instruments.size());
  internal::SimScratch& s = ws.scratch();
  auto tick = [&]() { return prof ? now_us() : 0.0; };
  const double t0 = tick();
  const std::size_t n = st.solver.instruments.size();
  const double dt = md.dt();
  const CardiacMotion* motion = md.motion ? &*md.motion : nullptr;
  for (std::size_t i = 0; i < n; ++i) s.old_tips[i] = tip(st, static_cast<int>(i));
  // 1. procedure: balloon pressures, the lesions they open, their holds on the nodes; the wall
  // brought to the lesions and stents of the state
  if (!md.procedure.balloons.empty())
    procedure_before_step(md.procedure, md.solver, md.tree, motion, cmds, st.time(), dt,
                          st.procedure, st.solver);
  internal::sync_wall(md, st, s, st.time() + dt);
  if (!md.procedure.balloons.empty())
    procedure_fit(md.procedure, md.solver, md.tree, motion, *s.wall.lumen, st.time() + dt,
                  st.procedure, st.solver);
  const double t1 = tick();
  // 2. instruments: sub-steps, the wall at each fine step's time, rollback
  const StepInfo info = solver_step(md.solver, st.solver, s.solver, &s.wall, cmds.drive,
                                    prof ? &prof->instruments : nullptr);
  st.metrics.resplit_steps += info.resplit ? 1 : 0;
  st.metrics.rollbacks += info.rolled_back ? 1 : 0;
  st.metrics.runaway_steps += info.runaway ? 1 : 0;
  st.metrics.calmed_steps += info.calmed ? 1 : 0;
  const double t2 = tick();
  // 3. procedure: stents released, gripped, carried
  if (!md.procedure.balloons.empty())
    procedure_after_step(md.procedure, md.solver, md.tree, motion, st.time(), dt, st.procedure,
                         st.solver, s.solver);
  const double t2b = tick();
  // 4. contrast: an injection enters where the outermost instrument's tip is (the guide)
  TreeLocation at;
  if (cmds.syringe_flow > 0.0 && st.contrast.segment < 0) {
    int outer = 0;
    for (std::size_t i = 0; i < n; ++i)
      if (md.outer_of[i] < 0 &&
          st.solver.instruments[i].drive.depth > st.solver.instruments[outer].drive.depth)
        outer = static_cast<int>(i);
    at = tip_location(md, st, outer).loc;
  }
  contrast_step(md.tree, md.scenario.contrast, dt, cmds.syringe_flow, at, st.contrast);
  const double t3 = tick();
  // 5. metrics, 6. landmarks
  update_metrics(md, st, s.solver, s.old_tips);
  st.metrics.steps += 1;
  const double t4 = tick();
  check_landmarks(md, st);
  if (prof) {
    const double t5 = tick();
    prof->procedure = (t1 - t0) + (t2b - t2);
    prof->solver = t2 - t1;
    prof->contrast = t3 - t2b;
    prof->metrics = t4 - t3;
    prof->landmarks = t5 - t4;
    prof->total = t5 - t0;
  }
}

// --- profile -------------------------------------------------------------------------------------

const char* to_string(SimStage s) {
  switch (s) {
    case SimStage::kProcedure:
      return "procedure";
    case SimStage::kWall:
      return "wall";
    case SimStage::kDrive:
      return "drive";
    case SimStage::kForces:
      return "forces";
    case SimStage::kVelocities:
      return "velocities";
    case SimStage::kCollision:
      return "collision";
    case SimStage::kCoupling:
      return "coupling";
    case SimStage::kDistance:
      return "distance";
    case SimStage::kContacts:
      return "contacts";
    case SimStage::kPositions:
      return "positions";
    case SimStage::kFeedback:
      return "feedback";
    case SimStage::kSubsteps:
      return "substeps";
    case SimStage::kContrast:
      return "contrast";
    case SimStage::kMetrics:
      return "metrics";
    case SimStage::kLandmarks:
      return "landmarks";
    case SimStage::kTotal:
      return "total";
    case SimStage::kCount:
      break;
  }
  return "?";
}

std::array<double, kNumSimStages> stage_times(const SimStepProfile& p) {
  const StepProfile& i = p.instruments;
  std::array<double, kNumSimStages> t{};
  auto at = [&](SimStage s) -> double& { return t[static_cast<std::size_t>(s)]; };
  at(SimStage::kProcedure) = p.procedure;
  at(SimStage::kWall) = i.wall;
  at(SimStage::kDrive) = i.drive;
  at(SimStage::kForces) = i.forces;
  at(SimStage::kVelocities) = i.integrate_velocities;
  at(SimStage::kCollision) = i.collision;
  at(SimStage::kCoupling) = i.coupling;
  at(SimStage::kDistance) = i.distance;
  at(SimStage::kContacts) = i.contacts;
  at(SimStage::kPositions) = i.integrate_positions;
  at(SimStage::kFeedback) = i.feedback;
  at(SimStage::kSubsteps) = std::max(0.0, p.solver - i.total - i.wall);
  at(SimStage::kContrast) = p.contrast;
  at(SimStage::kMetrics) = p.metrics;
  at(SimStage::kLandmarks) = p.landmarks;
  at(SimStage::kTotal) = p.total;
  return t;
}

std::string SimProfile::table() const {
  std::string out = "| stage | mean (us) | p50 (us) | p99 (us) | share |\n|---|---|---|---|---|\n";
  const double total = stages[static_cast<std::size_t>(SimStage::kTotal)].mean();
  char line[160];
  for (int k = 0; k < kNumSimStages; ++k) {
    const DurationHistogram& h = stages[static_cast<std::size_t>(k)];
    std::snprintf(line, sizeof line, "| %s | %.1f | %.1f | %.1f | %.0f %% |\n",
                  to_string(static_cast<SimStage>(k)), h.mean(), h.quantile(0.5), h.quantile(0.99),
                  total > 0.0 ? 100.0 * h.mean() / total : 0.0);
    out += line;
  }
  return out;
}

// --- Simulator -----------------------------------------------------------------------------------

Simulator::Simulator(Scenario scenario) : Simulator(build_sim_model(std::move(scenario))) {}

Simulator::Simulator(std::shared_ptr<const SimModel> model)
    : model_(std::move(model)),
      state_(make_sim_state(*model_)),
      ws_(std::make_unique<SimWorkspace>(*model_)) {
  state_.model = model_;
}

Simulator::~Simulator() = default;

void Simulator::step(const StepCommands& cmds) {
  const std::size_t n = state_.solver.instruments.size();
  if (cmds.drive.size() != n)
    throw InputError("commands", "drive",
                     "expected one command per instrument (" + std::to_string(n) + "), got " +
                         std::to_string(cmds.drive.size()));
  for (std::size_t i = 0; i < n; ++i)
    if (!std::isfinite(cmds.drive[i].translation) || !std::isfinite(cmds.drive[i].rotation))
      throw InputError("commands", "drive[" + std::to_string(i) + "]",
                       "expected finite translation and rotation");
  if (!std::isfinite(cmds.syringe_flow) || !std::isfinite(cmds.balloon_pressure))
    throw InputError("commands", "syringe_flow", "expected finite flow and pressure");
  const double t0 = now_us();
  SimStepProfile p;
  sim_step(*model_, state_, *ws_, cmds, &p);
  profile_.wall_time += (now_us() - t0) * 1e-6;
  profile_.steps += 1;
  SimStepProfile& sum = profile_.sum;
  sum.procedure += p.procedure;
  sum.solver += p.solver;
  sum.contrast += p.contrast;
  sum.metrics += p.metrics;
  sum.landmarks += p.landmarks;
  sum.total += p.total;
  const std::array<double, kNumSimStages> st = stage_times(p);
  for (int k = 0; k < kNumSimStages; ++k)
    profile_.stages[static_cast<std::size_t>(k)].add(st[static_cast<std::size_t>(k)]);
  StepProfile& a = sum.instruments;
  const StepProfile& b = p.instruments;
  a.drive += b.drive;
  a.forces += b.forces;
  a.integrate_velocities += b.integrate_velocities;
  a.collision += b.collision;
  a.constraints += b.constraints;
  a.distance += b.distance;
  a.contacts += b.contacts;
  a.integrate_positions += b.integrate_positions;
  a.total += b.total;
  a.wall += b.wall;
  a.coupling += b.coupling;
  a.feedback += b.feedback;
  a.num_contacts += b.num_contacts;
  a.num_queries += b.num_queries;
  a.num_sample_queries += b.num_sample_queries;
}

void Simulator::restore(const SimState& snap) {
  if (snap.model && snap.model != model_ && snap.model->anatomy == model_->anatomy) {
    // A snapshot of this run's scene before (or after) an exchange of instruments: back to that
    // scene, the wall taken over. (A state of another run's model is only checked for its sizes
    // below, as ever.)
    auto ws = std::make_unique<SimWorkspace>(*snap.model, std::move(*ws_));
    model_ = snap.model;
    ws_ = std::move(ws);
    state_ = make_sim_state(*model_);
    state_.model = model_;
  }
  const SimModel& md = *model_;
  auto refuse = [](const std::string& why) {
    throw InputError("snapshot", "state",
                     "expected a state of this simulator's model (" + why + ")");
  };
  if (snap.solver.instruments.size() != md.solver.instruments.size()) refuse("instrument count");
  for (std::size_t i = 0; i < snap.solver.instruments.size(); ++i) {
    const InstrumentState& in = snap.solver.instruments[i];
    const RodModel& r = md.solver.instruments[i].rod();
    if (in.rod.x.size() != static_cast<std::size_t>(r.n) ||
        in.rod.q.size() != static_cast<std::size_t>(r.m) ||
        in.clearance.size() != static_cast<std::size_t>(r.n) ||
        in.travel_at.size() != static_cast<std::size_t>(r.n))
      refuse("node count of instrument " + std::to_string(i));
  }
  if (snap.solver.split < 1 || snap.solver.split > md.solver.max_split()) refuse("split");
  if (snap.contrast.concentration.size() != static_cast<std::size_t>(md.tree.num_segments()) ||
      snap.contrast.history.size() != state_.contrast.history.size())
    refuse("contrast");
  if (snap.procedure.balloons.size() != md.procedure.balloons.size() ||
      snap.procedure.opening.size() != md.procedure.lesions.size())
    refuse("procedure");
  if (snap.metrics.landmarks.size() != md.landmark_ids.size() ||
      snap.metrics.tip_path.size() != md.solver.instruments.size())
    refuse("metrics");
  state_ = snap;  // same sizes: the copy reuses the state's storage
  state_.model = model_;
}

std::span<const NodeContact> Simulator::contacts(int i) const {
  return ws_->solver().contacts(i);
}

void Simulator::feedback(std::vector<HandFeedback>& out) const {
  out.resize(state_.solver.instruments.size());
  for (std::size_t i = 0; i < out.size(); ++i) {
    const DriveState& d = state_.solver.instruments[i].drive;
    out[i] = {d.axial_force, d.torque};
  }
}

std::vector<Vec3> Simulator::route_to(const TreeLocation& to, double spacing) const {
  return route(model_->tree, model_->tree.access, to, spacing);
}

}  // namespace vcsim
