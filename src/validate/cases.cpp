// Validation cases: each builds a rod, loads it as the analytic problem prescribes, runs the
// real step to equilibrium (or through free vibration) and compares with the analytic answer.
#include <Eigen/SVD>

#include <cmath>
#include <functional>
#include <map>
#include <stdexcept>

#include "vcsim/units.h"
#include "vcsim/validate.h"

namespace vcsim {

namespace {

constexpr double kG = 9.81;

bool is_set(double v) {
  return !std::isnan(v);
}

CaseResult result(const std::string& name, const std::string& quantity, double analytic,
                  double simulated, double tolerance) {
  CaseResult r{name, quantity, analytic, simulated, 0.0, tolerance, false};
  // Relative error, or absolute where the analytic answer is zero.
  r.rel_error = analytic != 0.0 ? std::abs(simulated - analytic) / std::abs(analytic)
                                : std::abs(simulated - analytic);
  r.pass = std::isfinite(simulated) && r.rel_error <= tolerance;
  return r;
}

// Static cases may scale the frames' rotational inertia: it does not change an equilibrium,
// and it lifts the explicit step limit set by the frames' fast rotation.
constexpr double kStaticInertiaScale = 10.0;

RodDef base_def(const ValidationOptions& o, double inertia_scale = kStaticInertiaScale) {
  RodDef d;
  d.rotational_inertia_scale = inertia_scale;
  d.length = o.length;
  d.segments = o.segments;
  d.outer_radius = o.outer_radius;
  d.youngs_modulus = o.youngs_modulus;
  d.density = o.density;
  d.poisson = o.poisson;
  return d;
}

double bending_stiffness(const RodModel& md) {
  return md.youngs[0] * md.bend_inertia[0];
}

// One rod under test with its settings and scratch memory.
struct Bench {
  RodModel md;
  RodState st;
  RodSettings s;
  RodWorkspace ws;
  std::string name;

  Bench(const std::string& case_name, const RodDef& def, const ValidationOptions& o)
      : md(build_rod(def)), st(make_state(md, def)), name(case_name) {
    s.distance = o.method;
    s.iterations = o.iterations;
    ws.resize(md);
  }
  // Mass per length (uniform section).
  double rho_a() const {
    double mass = 0.0;
    for (double mi : md.node_mass) mass += mi;
    return mass / md.length;
  }
  double omega1() const {
    return 2 * kPi * analytic::cantilever_frequency(1, bending_stiffness(md), rho_a(), md.length);
  }
  // Picks dt (the user's or the stability estimate) once damping is set.
  void finish_settings(const ValidationOptions& o) {
    s.dt = o.dt > 0 ? o.dt : estimate_stable_dt(md, s);
    s.validate(name);
  }
  // Damping for a static case: mode 1 critically damped by drag, the fast modes by a little
  // stiffness-proportional damping.
  void static_damping(double drag_ratio = 1.0) {
    RodSettings undamped = s;
    const double w_max = 1.0 / estimate_stable_dt(md, undamped);
    s.drag = 2.0 * drag_ratio * omega1();
    s.internal_damping = 0.2 / w_max;
  }
  bool finite() const {
    for (const auto& x : st.x)
      if (!x.allFinite()) return false;
    return true;
  }
  // Steps until t_max, or until the rod is still (after t_min) when still_speed > 0.
  void run(double t_max, double t_min = 0.0, double still_speed = 0.0,
           const std::function<void()>& each = {}) {
    const long long steps = static_cast<long long>(std::ceil(t_max / s.dt));
    for (long long k = 0; k < steps; ++k) {
      rod_step(md, s, st, ws);
      if (each) each();
      if (k % 256 == 0) {
        if (!finite()) {
          throw std::runtime_error(
              name + ": the simulation diverged at t = " + std::to_string(st.time) +
              " s (dt = " + std::to_string(s.dt) + " s is above the stability limit)");
        }
        if (still_speed > 0 && st.time >= t_min && max_speed(st) < still_speed) return;
      }
    }
    if (!finite()) throw std::runtime_error(name + ": the simulation diverged");
  }
  // Relax a static problem to equilibrium.
  void relax() {
    const double w1 = omega1();
    run(60.0 / w1, 10.0 / w1, 1e-7 * md.length * w1);
  }
};

Quat along(const Vec3& dir) {
  return Quat::FromTwoVectors(Vec3::UnitZ(), dir);
}

// 1. Large-deflection cantilever with a dead tip load.
std::vector<CaseResult> elastica_tip(const ValidationOptions& o) {
  std::vector<double> loads =
      is_set(o.load) ? std::vector<double>{o.load} : std::vector<double>{0.25, 0.5, 1.0, 2.0};
  std::vector<CaseResult> out;
  for (double lambda : loads) {
    RodDef def = base_def(o);
    def.base_orientation = along(Vec3::UnitX());
    Bench b("elastica-tip", def, o);
    b.static_damping();
    b.finish_settings(o);
    const double ei = bending_stiffness(b.md), l = def.length;
    b.st.f_ext.back() = Vec3(0, -lambda * ei / (l * l), 0);
    b.relax();
    const auto ref = analytic::elastica_tip_load(lambda);
    const Vec3 tip = b.st.x.back();
    const std::string tag = " (lambda=" + std::to_string(lambda).substr(0, 4) + ")";
    out.push_back(result("elastica-tip", "y_tip/L" + tag, ref.y, -tip.y() / l, 0.01));
    out.push_back(result("elastica-tip", "x_tip/L" + tag, ref.x, tip.x() / l, 0.01));
  }
  return out;
}

// 2. Cantilever under its own weight as a uniformly distributed dead load.
std::vector<CaseResult> distributed(const ValidationOptions& o) {
  std::vector<double> loads =
      is_set(o.load) ? std::vector<double>{o.load} : std::vector<double>{0.1, 1.0, 3.0, 5.0};
  std::vector<CaseResult> out;
  for (double mu : loads) {
    RodDef def = base_def(o);
    def.base_orientation = along(Vec3::UnitX());
    Bench b("distributed", def, o);
    const double ei = bending_stiffness(b.md), l = def.length;
    const double q = mu * ei / (l * l * l);  // load per length; as gravity on rho A
    b.s.gravity = Vec3(0, -q / (def.density * b.md.area[0]), 0);
    b.static_damping();
    b.finish_settings(o);
    b.relax();
    const auto ref = analytic::cantilever_shooting(mu, 0.0);
    const Vec3 tip = b.st.x.back();
    const std::string tag = " (qL^3/EI=" + std::to_string(mu).substr(0, 4) + ")";
    out.push_back(result("distributed", "y_tip/L" + tag, ref.y, -tip.y() / l, 0.02));
    out.push_back(result("distributed", "x_tip/L" + tag, ref.x, tip.x() / l, 0.02));
  }
  return out;
}

// 3. Euler buckling of a clamped-free column: straight below P_cr, buckled above it (with the
//    post-buckling elastica deflection as the reference).
std::vector<CaseResult> buckling(const ValidationOptions& o) {
  std::vector<double> ratios =
      is_set(o.ratio) ? std::vector<double>{o.ratio} : std::vector<double>{0.9, 1.1};
  std::vector<CaseResult> out;
  for (double ratio : ratios) {
    RodDef def = base_def(o);
    def.start_in_rest_shape = false;
    Bench b("buckling", def, o);
    const double ei = bending_stiffness(b.md), l = def.length;
    const double p_cr = kPi * kPi * ei / (4.0 * l * l);
    // Perturb along the first buckling mode, y = d0 (1 - cos(pi s / 2L)), frames on the chords.
    const double d0 = 0.01 * l;
    for (int i = 0; i < b.md.n; ++i) {
      b.st.x[i].x() = d0 * (1.0 - std::cos(kPi * b.md.node_s[i] / (2.0 * l)));
    }
    for (int j = 0; j < b.md.m; ++j) b.st.q[j] = along(b.st.x[j + 1] - b.st.x[j]);
    b.st.f_ext.back() = Vec3(0, 0, -ratio * p_cr);
    b.static_damping(0.5);
    b.finish_settings(o);
    const double w1 = b.omega1();
    b.run(400.0 / w1, 60.0 / w1, 1e-7 * l * w1);
    const double defl = std::hypot(b.st.x.back().x(), b.st.x.back().y()) / l;
    const std::string tag = " (P/Pcr=" + std::to_string(ratio).substr(0, 4) + ")";
    if (ratio <= 1.0) {
      // Straight: the 1 % perturbation must have died out.
      out.push_back(
          result("buckling", "lateral tip deflection/L, straight" + tag, 0.0, defl, 1e-4));
    } else {
      out.push_back(result("buckling", "lateral tip deflection/L, buckled" + tag,
                           analytic::postbuckling_deflection(ratio), defl, 0.05));
    }
  }
  return out;
}

// 4. Natural frequencies of a cantilever, from free vibration started in the analytic mode shape.
std::vector<CaseResult> frequency(const ValidationOptions& o) {
  std::vector<int> modes = o.mode > 0 ? std::vector<int>{o.mode} : std::vector<int>{1, 2};
  std::vector<CaseResult> out;
  for (int mode : modes) {
    RodDef def = base_def(o, 1.0);  // dynamics: physical rotary inertia
    Bench b("frequency", def, o);
    b.finish_settings(o);
    const double l = def.length, ei = bending_stiffness(b.md);
    const double rho_a = def.density * b.md.area[0];
    const double f_ref = analytic::cantilever_frequency(mode, ei, rho_a, l);
    static constexpr double kBetaL[] = {1.87510407, 4.69409113, 7.85475744, 10.99554073};
    const double bl = kBetaL[mode - 1];
    const double sigma = (std::cosh(bl) + std::cos(bl)) / (std::sinh(bl) + std::sin(bl));
    auto shape = [&](double s) {
      const double z = bl * s / l;
      return std::cosh(z) - std::cos(z) - sigma * (std::sinh(z) - std::sin(z));
    };
    const double amp = 1e-3 * l / shape(l);
    for (int i = 0; i < b.md.n; ++i) b.st.x[i].x() = amp * shape(b.md.node_s[i]);
    for (int j = 0; j < b.md.m; ++j) b.st.q[j] = along(b.st.x[j + 1] - b.st.x[j]);
    // Zero crossings of the tip's lateral displacement, linearly interpolated.
    std::vector<double> crossings;
    double prev = b.st.x.back().x(), prev_t = 0.0;
    const double periods = 8.0;
    b.run(periods / f_ref, 0, 0, [&] {
      const double cur = b.st.x.back().x();
      if ((cur < 0) != (prev < 0)) {
        crossings.push_back(prev_t + (b.st.time - prev_t) * prev / (prev - cur));
      }
      prev = cur;
      prev_t = b.st.time;
    });
    double f_sim = 0.0;
    if (crossings.size() >= 3) {
      f_sim =
          0.5 * static_cast<double>(crossings.size() - 1) / (crossings.back() - crossings.front());
    }
    std::string quantity = "f";
    quantity += std::to_string(mode);
    quantity += " (Hz)";
    out.push_back(result("frequency", quantity, f_ref, f_sim, 0.03));
  }
  return out;
}

// 5. Torsion: both ends clamped, the tip clamp turned by phi about the axis; end torque G J phi/L.
//    The clamp turns gradually (as a hand does), so twists beyond 180 degrees are well defined.
std::vector<CaseResult> torsion(const ValidationOptions& o) {
  const double phi = (is_set(o.angle_deg) ? o.angle_deg : 90.0) * kPi / 180.0;
  RodDef def = base_def(o);
  def.tip = BoundaryKind::kClamped;
  Bench b("torsion", def, o);
  const Quat tip0 = b.st.tip_frame;
  const double gj = b.md.shear[0] * 2.0 * b.md.bend_inertia[0], l = def.length;
  // First torsional mode of the fixed-fixed rod with the model's axial inertia per length.
  const double w_t = kPi / l * std::sqrt(gj * b.md.rest_length[0] / b.md.inertia[0].z());
  b.s.angular_drag = 2.0 * w_t;
  b.static_damping();
  b.finish_settings(o);
  const double t_ramp = 20.0 / w_t;
  b.run(60.0 / w_t, 0, 0, [&] {
    const double u = std::min(1.0, b.st.time / t_ramp);
    const double smooth = u * u * (3.0 - 2.0 * u);
    b.st.tip_frame = Quat(Eigen::AngleAxisd(phi * smooth, Vec3::UnitZ())) * tip0;
  });
  return {result("torsion", "base torque (N m)", gj * phi / l, b.st.base_torque.z(), 0.01),
          result("torsion", "tip torque (N m)", -gj * phi / l, b.st.tip_torque.z(), 0.01)};
}

// Circle through points by a least-squares (Kasa) fit in their best-fit plane.
double fit_radius(const std::vector<Vec3>& pts) {
  Vec3 c = Vec3::Zero();
  for (const auto& p : pts) c += p;
  c /= static_cast<double>(pts.size());
  Eigen::MatrixXd a(pts.size(), 3);
  for (std::size_t i = 0; i < pts.size(); ++i)
    a.row(static_cast<Eigen::Index>(i)) = (pts[i] - c).transpose();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeThinV);
  const Vec3 u = svd.matrixV().col(0), w = svd.matrixV().col(1);
  Eigen::MatrixXd m(pts.size(), 3);
  Eigen::VectorXd rhs(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const double px = (pts[i] - c).dot(u), py = (pts[i] - c).dot(w);
    const auto r = static_cast<Eigen::Index>(i);
    m(r, 0) = px;
    m(r, 1) = py;
    m(r, 2) = 1.0;
    rhs(r) = px * px + py * py;
  }
  const Eigen::Vector3d sol = m.colPivHouseholderQr().solve(rhs);
  const double cx = 0.5 * sol(0), cy = 0.5 * sol(1);
  return std::sqrt(sol(2) + cx * cx + cy * cy);
}

// Shaped tip: a rod built straight relaxes to its designed arc (a J tip by default).
std::vector<CaseResult> shaped_tip(const ValidationOptions& o) {
  RodDef def = base_def(o);
  const double angle = o.j_angle_deg * kPi / 180.0;
  def.tip_shape = {TipSection::arc(o.j_radius, angle)};
  const double arc = o.j_radius * std::abs(angle);
  def.grading = 0.25;
  def.tip_length = std::min(def.length, 2.0 * arc);
  def.tip_modulus_ratio = o.tip_modulus_ratio;
  Bench b("shaped-tip", def, o);
  b.static_damping();
  b.finish_settings(o);
  b.relax();
  std::vector<Vec3> pts;
  for (int i = 0; i < b.md.n; ++i) {
    if (b.md.node_s[i] >= def.length - arc - 1e-12) pts.push_back(b.st.x[i]);
  }
  if (pts.size() < 3) {
    throw InputError("shaped-tip", "segments",
                     "expected at least 3 nodes on the arc; add segments");
  }
  return {result("shaped-tip", "tip radius (mm)", o.j_radius * 1e3, fit_radius(pts) * 1e3, 0.02)};
}

// Stretch: a hanging rod pulled by `pull` times its weight. Inextensible methods keep every edge
// at rest length; the penalty method stretches by sum T_j l_j / (E A).
std::vector<CaseResult> stretch(const ValidationOptions& o) {
  const double pull = is_set(o.pull) ? o.pull : 10.0;
  std::vector<CaseResult> out;
  for (bool penalty : {false, true}) {
    RodDef def = base_def(o);
    def.base = BoundaryKind::kPinned;
    def.base_orientation = along(-Vec3::UnitZ());
    ValidationOptions oo = o;
    if (penalty)
      oo.method = DistanceMethod::kPenalty;
    else if (o.method == DistanceMethod::kPenalty)
      oo.method = DistanceMethod::kGlobal;
    Bench b("stretch", def, oo);
    b.s.gravity = Vec3(0, 0, -kG);
    double mass = 0.0;
    for (double mi : b.md.node_mass) mass += mi;
    const double f_tip = pull * mass * kG;
    b.st.f_ext.back() = Vec3(0, 0, -f_tip);
    const double c_axial = std::sqrt(def.youngs_modulus / def.density);
    b.s.drag = 2.0 * (kPi / 2.0) * c_axial / def.length;  // critical for the first axial mode
    b.finish_settings(oo);
    double worst = 0.0;
    b.run(60.0 / b.s.drag, 0, 0, [&] { worst = std::max(worst, max_stretch(b.md, b.st)); });
    const std::string method = to_string(oo.method);
    if (!penalty) {
      out.push_back(
          result("stretch",
                 "max edge strain over the run, " + method + " x" + std::to_string(oo.iterations),
                 0.0, worst, 1e-4));
    } else {
      // Tension in edge j carries the tip load and the weight of the nodes below it.
      double elong = 0.0, below = f_tip;
      for (int j = b.md.m - 1; j >= 0; --j) {
        below += b.md.node_mass[j + 1] * kG;
        elong += below * b.md.rest_length[j] / b.md.axial_stiffness[j];
      }
      const double sim = centreline_length(b.st) - def.length;
      out.push_back(result("stretch", "elongation/L, penalty (E A)", elong / def.length,
                           sim / def.length, 0.02));
    }
  }
  return out;
}

using CaseFn = std::vector<CaseResult> (*)(const ValidationOptions&);
const std::map<std::string, CaseFn>& registry() {
  static const std::map<std::string, CaseFn> cases = {{"elastica-tip", elastica_tip},
                                                      {"distributed", distributed},
                                                      {"buckling", buckling},
                                                      {"frequency", frequency},
                                                      {"torsion", torsion},
                                                      {"shaped-tip", shaped_tip},
                                                      {"stretch", stretch}};
  return cases;
}

}  // namespace

void ValidationOptions::validate(const std::string& source) const {
  require_positive(length, source, "--length-mm");
  if (segments < 4 || segments > 4096) {
    throw InputError(source, "--segments", "expected an integer in [4, 4096]");
  }
  require_positive(outer_radius, source, "--radius-mm");
  require_positive(youngs_modulus, source, "--youngs-gpa");
  require_positive(density, source, "--density");
  require_in_range(poisson, -1.0, 0.5, source, "--poisson");
  require_nonnegative(dt, source, "--dt");
  if (iterations < 1 || iterations > 1000) {
    throw InputError(source, "--iterations", "expected an integer in [1, 1000]");
  }
  if (is_set(load)) require_positive(load, source, "--load");
  if (is_set(ratio)) require_positive(ratio, source, "--ratio");
  if (is_set(angle_deg)) require_in_range(angle_deg, -720.0, 720.0, source, "--angle-deg");
  if (is_set(pull)) require_nonnegative(pull, source, "--pull");
  if (mode < 0 || mode > 4) throw InputError(source, "--mode", "expected 1, 2, 3 or 4");
  require_positive(j_radius, source, "--tip-radius-mm");
  require_in_range(j_angle_deg, 0.0, 360.0, source, "--tip-angle-deg");
  require_in_range(tip_modulus_ratio, 0.0, 1.0, source, "--tip-ratio");
}

const std::vector<std::string>& validation_case_names() {
  static const std::vector<std::string> names = {
      "elastica-tip", "distributed", "buckling", "frequency", "torsion", "shaped-tip", "stretch"};
  return names;
}

std::vector<CaseResult> run_validation_case(const std::string& name, const ValidationOptions& o) {
  const auto& reg = registry();
  const auto it = reg.find(name);
  if (it == reg.end()) {
    std::string all;
    for (const auto& n : validation_case_names()) all += (all.empty() ? "" : ", ") + n;
    throw InputError("validate", "case", "expected one of " + all + ", got '" + name + "'");
  }
  o.validate("validate " + name);
  return it->second(o);
}

}  // namespace vcsim
