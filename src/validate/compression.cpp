// The paper's compression experiment (Table 1): scene, protocol and measurements.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "vcsim/experiments.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {
double segment_distance(const Vec3& a, const Vec3& b, const Vec3& p) {
  const Vec3 ab = b - a;
  const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (a + t * ab - p).norm();
}
}  // namespace

void CompressionOptions::validate(const std::string& source) const {
  if (nodes < 8 || nodes > 4096) throw InputError(source, "--nodes", "expected 8 .. 4096");
  require_positive(rod_length, source, "rod_length");
  require_positive(lumen_radius, source, "lumen_radius");
  require_nonnegative(dt, source, "--dt");
  require_positive(push_speed, source, "--speed-mm-s");
  require_nonnegative(start_depth, source, "start_depth");
  if (end_depth <= start_depth || end_depth >= rod_length) {
    throw InputError(source, "--end-depth-mm", "expected between the start depth and the length");
  }
  require_nonnegative(mu, source, "--mu");
}

std::vector<std::pair<DistanceMethod, int>> compression_table_rows() {
  using M = DistanceMethod;
  return {{M::kPenalty, 1},     {M::kGlobal, 1},       {M::kGlobal, 5},       {M::kGlobal, 10},
          {M::kGlobal, 25},     {M::kLocalGS, 1},      {M::kLocalGS, 10},     {M::kLocalGS, 100},
          {M::kLocalJacobi, 1}, {M::kLocalJacobi, 10}, {M::kLocalJacobi, 100}};
}

double outside_tube(const std::vector<Vec3>& line, double radius, const Vec3& p) {
  double d = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k + 1 < line.size(); ++k)
    d = std::min(d, segment_distance(line[k], line[k + 1], p));
  return d - radius;
}

CompressionScene make_compression_scene(const CompressionOptions& o, DistanceMethod method,
                                        int iterations) {
  o.validate("bench compression");
  CompressionScene sc;
  BentTubeSpec tube;
  tube.straight1 = o.straight1;
  tube.bend_radius = o.bend_radius;
  tube.bend_angle = o.bend_angle_deg * kPi / 180.0;
  tube.straight2 = o.straight2;
  tube.radius = o.lumen_radius;
  tube.sides = 24;
  tube.ring_spacing = 1.5e-3;
  tube.cap_end = true;
  sc.mesh = make_bent_tube(tube);
  check_and_repair(sc.mesh, "compression tube");
  sc.tree.build(sc.mesh, AabbTreeSettings::for_static_mesh());

  RodDef def;
  def.length = o.rod_length;
  def.segments = o.nodes - 1;
  def.outer_radius = o.outer_radius;
  def.inner_radius = o.inner_radius;
  def.youngs_modulus = o.youngs_modulus;
  def.density = o.density;
  def.base = BoundaryKind::kFree;
  def.tip = BoundaryKind::kFree;
  // The tube starts at the origin along +z: the sheath is there.
  Sheath sheath;
  sheath.access_point = Vec3::Zero();
  sheath.frame = Quat::Identity();

  SolverSettings s;
  s.rod.distance = method;
  s.rod.iterations = iterations;
  s.rod.gravity = Vec3::Zero();
  // Quasi-static mass scaling: the explicit step at the physical density is about a
  // microsecond; to run at dt the density (hence every inertia) is scaled by (dt_stable/dt)^-2.
  {
    ContactMaterial probe_contact;
    const InstrumentModel probe = make_instrument_model(def, sheath, probe_contact);
    RodSettings inext = s.rod;
    inext.distance = DistanceMethod::kGlobal;
    const double dt_phys = estimate_stable_dt(probe.rod(), inext);
    sc.mass_scale = o.dt > 0 ? std::max(1.0, std::pow(o.dt / dt_phys, 2)) : 1.0;
    def.density = o.density * sc.mass_scale;
    s.rod.dt = o.dt > 0 ? o.dt : dt_phys;
  }
  ContactMaterial contact;
  contact.mu_static = o.mu;
  contact.mu_dynamic = o.mu;
  sc.model.instruments = {make_instrument_model(def, sheath, contact)};
  const RodModel& rod = sc.model.instruments[0].rod();
  // Damping of free motion; the contacts and friction do the rest.
  s.rod.drag = 20.0;  // 1/s, mass-proportional: settles the heavy (quasi-static) rod
  if (method == DistanceMethod::kPenalty) {
    // As in the paper: the largest stretching modulus that is stable at this step.
    double lo = 1e-9, hi = 1.0;
    s.rod.penalty_modulus_scale = hi;
    if (estimate_stable_dt(rod, s.rod) < s.rod.dt) {
      for (int k = 0; k < 60; ++k) {
        const double mid = std::sqrt(lo * hi);
        s.rod.penalty_modulus_scale = mid;
        (estimate_stable_dt(rod, s.rod) >= s.rod.dt ? lo : hi) = mid;
      }
      s.rod.penalty_modulus_scale = lo;
    }
  }
  sc.model.settings = {s};
  sc.model.validate("bench compression");
  sc.state =
      make_solver_state(sc.model, {make_instrument_state(sc.model.instruments[0], o.start_depth)});
  return sc;
}

long long compression_steps(const CompressionOptions& o, double dt) {
  const double push_time = (o.end_depth - o.start_depth) / o.push_speed;
  return static_cast<long long>(std::ceil((push_time + o.settle_time) / dt));
}

double compression_depth(const CompressionOptions& o, long long k, double dt) {
  const double t = static_cast<double>(k) * dt;
  return std::min(o.end_depth, o.start_depth + o.push_speed * t);
}

CompressionRow run_compression(const CompressionOptions& o, DistanceMethod method, int iterations) {
  CompressionScene sc = make_compression_scene(o, method, iterations);
  const RodModel& md = sc.model.instruments[0].rod();
  const InstrumentState& inst = sc.state.instruments[0];
  SolverWorkspace ws(sc.model);
  StaticWall wall = sc.wall();
  const double dt = sc.model.dt();
  const auto centreline = bent_centreline(o.straight1, o.bend_radius,
                                          o.bend_angle_deg * kPi / 180.0, o.straight2);
  DriveCommand cmd;
  cmd.mode = DriveCommand::Mode::kPosition;
  const long long steps = compression_steps(o, dt);
  std::vector<double> total, cons, forces, integ, coll, dist, cont;
  total.reserve(steps);
  CompressionRow row;
  row.method = to_string(method);
  row.iterations = iterations;
  row.dt = dt;
  row.mass_scale = sc.mass_scale;
  row.penalty_modulus_scale = sc.model.settings[0].rod.penalty_modulus_scale;
  StepProfile prof;
  for (long long k = 0; k < steps; ++k) {
    cmd.translation = compression_depth(o, k + 1, dt);
    const StepInfo info =
        solver_step(sc.model, sc.state, ws, &wall, std::span<const DriveCommand>(&cmd, 1), &prof);
    if (info.rolled_back) throw std::runtime_error("compression: diverged (a non-finite step)");
    total.push_back(prof.total);
    cons.push_back(prof.constraints);
    forces.push_back(prof.forces);
    integ.push_back(prof.integrate_velocities + prof.integrate_positions);
    coll.push_back(prof.collision);
    dist.push_back(prof.distance);
    cont.push_back(prof.contacts);
    row.max_compression_percent =
        std::max(row.max_compression_percent, 100.0 * compression(md, inst.rod));
  }
  row.compression_percent = 100.0 * compression(md, inst.rod);
  row.step_us = median(total);
  row.constraints_us = median(cons);
  row.forces_us = median(forces);
  row.integration_us = median(integ);
  row.collision_us = median(coll);
  row.distance_us = median(dist);
  row.contacts_us = median(cont);
  row.axial_force = inst.drive.axial_force;
  row.contacts = prof.num_contacts;
  for (int i = inst.drive.first_free; i < md.n; ++i) {
    const double r = md.outer_radius[std::min(i, md.m - 1)];
    row.max_outside =
        std::max(row.max_outside, outside_tube(centreline, o.lumen_radius, inst.rod.x[i]) / r);
  }
  return row;
}

}  // namespace vcsim
