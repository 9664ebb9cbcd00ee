// Building a RodModel (the immutable part) and its initial RodState from a RodDef.
#include <cmath>
#include <numbers>

#include "kernels.h"
#include "vcsim/rod.h"

namespace vcsim {

namespace {

constexpr double kShearCorrection = 0.9;  // Timoshenko kappa for a circular section

// Position and frame of the designed centreline at arc length s, in the base frame's
// coordinates (d3 = +z at s = 0). The proximal part is straight; the sections follow.
struct ShapeCurve {
  double straight_until = 0.0;
  const std::vector<TipSection>* sections = nullptr;

  void eval(double s, Vec3& p, Quat& frame) const {
    p = Vec3(0, 0, std::min(s, straight_until));
    frame = Quat::Identity();
    double s0 = straight_until;
    for (const TipSection& sec : *sections) {
      if (s <= s0) break;
      const double ds = std::min(s, s0 + sec.length) - s0;
      if (sec.kind == TipSection::Kind::kStraight) {
        p += frame * Vec3(0, 0, ds);
      } else {
        // The tangent turns about a (in the current frame) by theta = ds / R; the arc is
        // p = p0 + R (e3 sin(theta) + (a x e3)(1 - cos(theta))).
        const Vec3 a(std::cos(sec.plane), std::sin(sec.plane), 0.0);
        const double sign = sec.angle < 0 ? -1.0 : 1.0;
        const double theta = sign * ds / sec.radius;
        const Vec3 local =
            sign * sec.radius *
            (Vec3::UnitZ() * std::sin(theta) + a.cross(Vec3::UnitZ()) * (1.0 - std::cos(theta)));
        p += frame * local;
        frame = frame * Quat(Eigen::AngleAxisd(theta, a));
      }
      s0 += sec.length;
    }
  }
};

void check_section(const TipSection& sec, std::size_t i, const std::string& source) {
  const std::string f = "tip_shape[" + std::to_string(i) + "]";
  if (sec.kind == TipSection::Kind::kStraight) {
    require_positive(sec.length, source, f + ".length");
  } else {
    require_positive(sec.radius, source, f + ".radius");
    require_finite(sec.angle, source, f + ".angle");
    if (sec.angle == 0.0) throw InputError(source, f + ".angle", "expected a non-zero angle");
    require_finite(sec.plane, source, f + ".plane");
    if (std::abs(sec.length - sec.radius * std::abs(sec.angle)) > 1e-9 * sec.length) {
      throw InputError(source, f + ".length", "expected radius * |angle| for an arc");
    }
  }
}

}  // namespace

void RodDef::validate(const std::string& source) const {
  require_positive(length, source, "length");
  if (segments < 2 || segments > 100000) {
    throw InputError(source, "segments",
                     "expected an integer in [2, 100000], got " + std::to_string(segments));
  }
  require_positive(grading, source, "grading");
  require_positive(youngs_modulus, source, "youngs_modulus");
  require_nonnegative(shear_modulus, source, "shear_modulus");
  require_in_range(poisson, -1.0, 0.5, source, "poisson");
  require_positive(outer_radius, source, "outer_radius");
  require_nonnegative(inner_radius, source, "inner_radius");
  if (inner_radius >= outer_radius) {
    throw InputError(source, "inner_radius", "expected less than outer_radius");
  }
  require_positive(density, source, "density");
  require_nonnegative(tip_length, source, "tip_length");
  if (tip_length > length) throw InputError(source, "tip_length", "expected at most length");
  require_in_range(tip_modulus_ratio, 0.0, 1.0, source, "tip_modulus_ratio");
  require_nonnegative(core_taper_length, source, "core_taper_length");
  if (tip_length + core_taper_length > length) {
    throw InputError(source, "core_taper_length", "expected at most length less tip_length");
  }
  require_nonnegative(taper_length, source, "taper_length");
  if (taper_length > length) throw InputError(source, "taper_length", "expected at most length");
  if (taper_length > 0.0 &&
      !(taper_outer_radius > inner_radius && taper_outer_radius <= outer_radius)) {
    throw InputError(source, "taper_outer_radius",
                     "expected more than inner_radius and at most outer_radius");
  }
  double shaped = 0.0;
  for (std::size_t i = 0; i < tip_shape.size(); ++i) {
    check_section(tip_shape[i], i, source);
    shaped += tip_shape[i].length;
  }
  if (shaped > length * (1.0 + 1e-12)) {
    throw InputError(source, "tip_shape", "expected the sections to be no longer than the rod");
  }
  require_nonnegative(parallel_stiffness, source, "parallel_stiffness");
  require_positive(rotational_inertia_scale, source, "rotational_inertia_scale");
  for (int k = 0; k < 3; ++k) require_finite(base_position[k], source, "base_position");
  for (int k = 0; k < 4; ++k)
    require_finite(base_orientation.coeffs()[k], source, "base_orientation");
  if (std::abs(base_orientation.norm() - 1.0) > 1e-6) {
    throw InputError(source, "base_orientation", "expected a unit quaternion");
  }
}

RodModel build_rod(const RodDef& def) {
  def.validate();
  RodModel md;
  const int m = def.segments;
  const int n = m + 1;
  md.n = n;
  md.m = m;
  md.length = def.length;
  md.base = def.base;
  md.tip = def.tip;

  // Graded edges: a geometric progression from proximal to distal with l_last / l_0 = grading.
  md.rest_length.resize(m);
  const double ratio = std::pow(def.grading, 1.0 / std::max(1, m - 1));
  double sum = 0.0;
  for (int j = 0; j < m; ++j) sum += std::pow(ratio, j);
  for (int j = 0; j < m; ++j) md.rest_length[j] = def.length * std::pow(ratio, j) / sum;

  md.node_s.resize(n);
  md.edge_s.resize(m);
  md.node_s[0] = 0.0;
  for (int j = 0; j < m; ++j) {
    md.node_s[j + 1] = md.node_s[j] + md.rest_length[j];
    md.edge_s[j] = md.node_s[j] + 0.5 * md.rest_length[j];
  }
  md.node_s[n - 1] = def.length;

  // Designed rest shape: nodes on the curve, frames along the chords.
  double shaped = 0.0;
  for (const auto& s : def.tip_shape) shaped += s.length;
  const ShapeCurve curve{std::max(0.0, def.length - shaped), &def.tip_shape};
  md.rest_position.resize(n);
  for (int i = 0; i < n; ++i) {
    Vec3 p;
    Quat f;
    curve.eval(md.node_s[i], p, f);
    md.rest_position[i] = p;
  }
  md.rest_frame.resize(m);
  for (int j = 0; j < m; ++j) {
    Vec3 p;
    Quat f;
    curve.eval(md.edge_s[j], p, f);
    const Vec3 chord = (md.rest_position[j + 1] - md.rest_position[j]).normalized();
    md.rest_frame[j] = (Quat::FromTwoVectors(f * Vec3::UnitZ(), chord) * f).normalized();
  }
  // Chord lengths are the rest lengths, so that a rod at rest lies exactly on the design.
  for (int j = 0; j < m; ++j) {
    md.rest_length[j] = (md.rest_position[j + 1] - md.rest_position[j]).norm();
  }
  // Place the shape at the base pose.
  for (auto& p : md.rest_position) p = def.base_position + def.base_orientation * p;
  for (auto& f : md.rest_frame) f = (def.base_orientation * f).normalized();

  // Per-edge material and section (soft tip: E and G scaled by alpha over the distal tip, and
  // from alpha back to 1 over a ground core's taper proximal to it).
  const double core_a = std::pow(def.tip_modulus_ratio, 0.25);
  const double g_shaft =
      def.shear_modulus > 0 ? def.shear_modulus : def.youngs_modulus / (2.0 * (1.0 + def.poisson));
  md.youngs.resize(m);
  md.shear.resize(m);
  md.outer_radius.assign(m, def.outer_radius);
  md.inner_radius.assign(m, def.inner_radius);
  md.area.resize(m);
  md.bend_inertia.resize(m);
  md.kp.resize(m);
  md.axial_stiffness.resize(m);
  md.inertia.resize(m);
  md.inv_inertia.resize(m);
  const double pi = std::numbers::pi;
  for (int j = 0; j < m; ++j) {
    const double soft_from = def.length - def.tip_length;  // arc length where the soft tip starts
    double scale = 1.0;
    if (md.edge_s[j] >= soft_from) {
      scale = def.tip_modulus_ratio;
    } else if (md.edge_s[j] > soft_from - def.core_taper_length) {
      const double u = (soft_from - md.edge_s[j]) / def.core_taper_length;
      const double d = core_a + (1.0 - core_a) * u;  // core diameter / the shaft's
      scale = d * d * d * d;
    }
    md.youngs[j] = def.youngs_modulus * scale;
    md.shear[j] = g_shaft * scale;
    double ro = def.outer_radius;
    const double ri = def.inner_radius;
    if (def.taper_length > 0.0 && md.edge_s[j] > def.length - def.taper_length) {
      const double u = (md.edge_s[j] - (def.length - def.taper_length)) / def.taper_length;
      ro += u * (def.taper_outer_radius - def.outer_radius);
      md.outer_radius[j] = ro;
    }
    md.area[j] = pi * (ro * ro - ri * ri);
    md.bend_inertia[j] = pi * (ro * ro * ro * ro - ri * ri * ri * ri) / 4.0;
    md.kp[j] = def.parallel_stiffness > 0 ? def.parallel_stiffness
                                          : kShearCorrection * md.shear[j] * md.area[j];
    md.axial_stiffness[j] = md.youngs[j] * md.area[j];
    // Segment of a cylinder: I_perp = rho l (I + A l^2 / 12), I_axial = rho l J, J = 2 I.
    const double l = md.rest_length[j];
    const double rho_l = def.density * l;
    const double i_perp = rho_l * (md.bend_inertia[j] + md.area[j] * l * l / 12.0);
    const double i_ax = rho_l * 2.0 * md.bend_inertia[j];
    md.inertia[j] = def.rotational_inertia_scale * Vec3(i_perp, i_perp, i_ax);
    md.inv_inertia[j] = md.inertia[j].cwiseInverse();
  }

  // Lumped node masses; held nodes get zero inverse mass.
  md.node_mass.assign(n, 0.0);
  for (int j = 0; j < m; ++j) {
    const double mass = def.density * md.area[j] * md.rest_length[j];
    md.node_mass[j] += 0.5 * mass;
    md.node_mass[j + 1] += 0.5 * mass;
  }
  md.inv_mass.resize(n);
  for (int i = 0; i < n; ++i) md.inv_mass[i] = 1.0 / md.node_mass[i];
  if (def.base != BoundaryKind::kFree) md.inv_mass[0] = 0.0;
  if (def.tip != BoundaryKind::kFree) md.inv_mass[n - 1] = 0.0;

  // Vertices: Voronoi length, series-averaged stiffness K_v = l_v / sum(l_half / K_edge), rest
  // Darboux vector from the rest frames (the clamp frames at rest equal the end frames).
  md.vertex_length.resize(m + 1);
  md.vertex_stiffness.resize(m + 1);
  md.rest_darboux.assign(m + 1, Vec3::Zero());
  md.vertex_active.assign(m + 1, 1);
  auto edge_k = [&](int j) {
    const double ei = md.youngs[j] * md.bend_inertia[j];
    return Vec3(ei, ei, md.shear[j] * 2.0 * md.bend_inertia[j]);
  };
  for (int v = 0; v <= m; ++v) {
    const double la = v > 0 ? 0.5 * md.rest_length[v - 1] : 0.0;
    const double lb = v < m ? 0.5 * md.rest_length[v] : 0.0;
    md.vertex_length[v] = la + lb;
    Vec3 compliance = Vec3::Zero();
    if (v > 0) compliance += la * edge_k(v - 1).cwiseInverse();
    if (v < m) compliance += lb * edge_k(v).cwiseInverse();
    md.vertex_stiffness[v] = md.vertex_length[v] * compliance.cwiseInverse();
    if (v > 0 && v < m) {
      md.rest_darboux[v] = darboux(md.rest_frame[v - 1], md.rest_frame[v], md.vertex_length[v]);
    }
  }
  md.rest_darboux[0] = darboux(def.base_orientation, md.rest_frame[0], md.vertex_length[0]);
  md.vertex_active[0] = def.base == BoundaryKind::kClamped;
  md.vertex_active[m] = def.tip == BoundaryKind::kClamped;
  return md;
}

RodState make_state(const RodModel& md, const RodDef& def) {
  RodState st;
  st.x.resize(md.n);
  st.q.resize(md.m);
  if (def.start_in_rest_shape) {
    st.x = md.rest_position;
    st.q = md.rest_frame;
  } else {
    const Vec3 d3 = def.base_orientation * Vec3::UnitZ();
    for (int i = 0; i < md.n; ++i) st.x[i] = def.base_position + md.node_s[i] * d3;
    for (int j = 0; j < md.m; ++j) st.q[j] = def.base_orientation;
  }
  st.v.assign(md.n, Vec3::Zero());
  st.omega.assign(md.m, Vec3::Zero());
  st.f_ext.assign(md.n, Vec3::Zero());
  st.tau_ext.assign(md.m, Vec3::Zero());
  st.base_frame = def.base_orientation;
  st.tip_frame = st.q.back();
  return st;
}

void RodWorkspace::resize(const RodModel& md) {
  force.assign(md.n, Vec3::Zero());
  torque.assign(md.m, Vec3::Zero());
  rot.assign(9 * static_cast<std::size_t>(md.m), 0.0);
  dir.assign(md.m, Vec3::Zero());
  diag.assign(md.m, 0.0);
  offdiag.assign(md.m, 0.0);
  rhs.assign(md.m, 0.0);
  lambda.assign(md.m, 0.0);
  dv.assign(md.n, Vec3::Zero());
  pred.assign(md.n, Vec3::Zero());
  inv_mass = md.inv_mass;
  frame_free.assign(md.m, 1.0);
  frame_mask.assign(md.m, 0);
  node_impulse.assign(md.n, Vec3::Zero());
  scratch.assign(6 * static_cast<std::size_t>(md.m + 2), 0.0);
}

Mat3 RodWorkspace::frame_rotation(int j) const {
  const std::size_t m = rot.size() / 9;
  Mat3 r;
  for (int c = 0; c < 3; ++c) {
    for (int i = 0; i < 3; ++i) r(i, c) = rot[(3 * c + i) * m + j];
  }
  return r;
}

Vec3 darboux(const Quat& qa, const Quat& qb, double l) {
  return (2.0 / l) * internal::relative_rotation(qa, qb).vec();
}

void RodState::hash_into(StateHasher& h) const {
  h.add(x);
  h.add(v);
  h.add(q);
  h.add(omega);
  h.add(f_ext);
  h.add(tau_ext);
  h.add_value(base_frame);
  h.add_value(tip_frame);
  h.add_value(time);
  h.add_value(steps);
  h.add_value(base_force);
  h.add_value(base_torque);
  h.add_value(tip_force);
  h.add_value(tip_torque);
}

std::uint64_t RodState::hash() const {
  StateHasher h;
  hash_into(h);
  return h.value();
}

void RodModel::hash_into(StateHasher& h) const {
  h.add_value(n);
  h.add_value(m);
  h.add_value(length);
  h.add_value(static_cast<int>(base));
  h.add_value(static_cast<int>(tip));
  for (const std::vector<double>* a :
       {&rest_length, &edge_s, &node_s, &node_mass, &inv_mass, &kp, &axial_stiffness, &youngs,
        &shear, &outer_radius, &inner_radius, &area, &bend_inertia, &vertex_length})
    h.add(*a);
  for (const std::vector<Vec3>* a :
       {&inertia, &inv_inertia, &vertex_stiffness, &rest_darboux, &rest_position})
    h.add(*a);
  h.add(vertex_active);
  h.add(rest_frame);
}

double centreline_length(const RodState& st) {
  double len = 0.0;
  for (std::size_t i = 0; i + 1 < st.x.size(); ++i) len += (st.x[i + 1] - st.x[i]).norm();
  return len;
}

double max_stretch(const RodModel& md, const RodState& st) {
  double worst = 0.0;
  for (int j = 0; j < md.m; ++j) {
    worst = std::max(worst, std::abs((st.x[j + 1] - st.x[j]).norm() / md.rest_length[j] - 1.0));
  }
  return worst;
}

double max_speed(const RodState& st) {
  double s = 0.0;
  for (const auto& v : st.v) s = std::max(s, v.norm());
  return s;
}

}  // namespace vcsim
