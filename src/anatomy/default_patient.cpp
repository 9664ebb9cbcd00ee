// The built-in patients: aorta from the aortic valve to the right common femoral artery, arch
// branches, aortic root with three sinuses, and coronaries drawn on an ellipsoidal heart.
// Dimensions from /shared/reference/clinical.md (cited per value in docs/anatomy.md); positions
// in mm in DICOM LPS (x left, y posterior, z head) with the aortic valve at the origin.
#include <algorithm>
#include <cmath>

#include "field.h"
#include "vcsim/anatomy.h"
#include "vcsim/units.h"

namespace vcsim {

namespace {

// A densely sampled curve with its cumulative arc length.
struct Dense {
  std::vector<Vec3> p;
  std::vector<double> cum;
  std::vector<Vec3> uv;  // optional (u, theta, 0) per sample on the heart surface
};

void finish(Dense& d) {
  d.cum.assign(d.p.size(), 0.0);
  for (std::size_t i = 1; i < d.p.size(); ++i)
    d.cum[i] = d.cum[i - 1] + (d.p[i] - d.p[i - 1]).norm();
}

// Linear interpolation of the dense curve at arc length s.
template <typename T>
T lerp_at(const std::vector<T>& v, const std::vector<double>& cum, double s) {
  s = std::clamp(s, 0.0, cum.back());
  const auto it = std::upper_bound(cum.begin(), cum.end(), s);
  const std::size_t i = std::min<std::size_t>(
      static_cast<std::size_t>(std::max<std::ptrdiff_t>(it - cum.begin() - 1, 0)), v.size() - 2);
  const double l = cum[i + 1] - cum[i];
  const double f = l > 0.0 ? (s - cum[i]) / l : 0.0;
  return v[i] + f * (v[i + 1] - v[i]);
}

// Centripetal Catmull-Rom through the control points (Yuksel et al. 2011: no cusps or
// self-intersections), `sub` samples per span; `knot_s` receives the arc length at each control.
Dense catmull_rom(const std::vector<Vec3>& c, int sub, std::vector<double>* knot_s = nullptr) {
  Dense d;
  const std::size_t n = c.size();
  std::vector<std::size_t> knot_index;
  for (std::size_t i = 0; i + 1 < n; ++i) {
    const Vec3 p0 = i == 0 ? Vec3(2.0 * c[0] - c[1]) : c[i - 1];
    const Vec3 p1 = c[i], p2 = c[i + 1];
    const Vec3 p3 = i + 2 < n ? c[i + 2] : Vec3(2.0 * c[n - 1] - c[n - 2]);
    const double t0 = 0.0;
    const double t1 = t0 + std::sqrt((p1 - p0).norm());
    const double t2 = t1 + std::sqrt((p2 - p1).norm());
    const double t3 = t2 + std::sqrt((p3 - p2).norm());
    knot_index.push_back(d.p.size());
    for (int k = 0; k < sub; ++k) {
      const double t = t1 + (t2 - t1) * k / sub;
      const Vec3 a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1;
      const Vec3 a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2;
      const Vec3 a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3;
      const Vec3 b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2;
      const Vec3 b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3;
      d.p.push_back((t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2);
    }
  }
  knot_index.push_back(d.p.size());
  d.p.push_back(c.back());
  finish(d);
  if (knot_s) {
    knot_s->clear();
    for (std::size_t k : knot_index) knot_s->push_back(d.cum[k]);
  }
  return d;
}

// Points from arc length s0 to s1 at about `spacing`, both ends included.
std::vector<Vec3> resample(const Dense& d, double s0, double s1, double spacing) {
  const int n = std::max(1, static_cast<int>(std::ceil((s1 - s0) / spacing)));
  std::vector<Vec3> out;
  for (int k = 0; k <= n; ++k) out.push_back(lerp_at(d.p, d.cum, s0 + (s1 - s0) * k / n));
  return out;
}

// Radii by linear interpolation over arc-length fraction: knots (fraction, radius in mm).
std::vector<double> radii_by_fraction(const std::vector<Vec3>& pts,
                                      const std::vector<std::pair<double, double>>& knots) {
  std::vector<double> cum(pts.size(), 0.0);
  for (std::size_t i = 1; i < pts.size(); ++i) cum[i] = cum[i - 1] + (pts[i] - pts[i - 1]).norm();
  std::vector<double> r;
  for (double s : cum) {
    const double f = cum.back() > 0.0 ? s / cum.back() : 0.0;
    double v = knots.back().second;
    for (std::size_t k = 0; k + 1 < knots.size(); ++k) {
      if (f <= knots[k + 1].first) {
        const double w = (f - knots[k].first) / (knots[k + 1].first - knots[k].first);
        v = knots[k].second + std::clamp(w, 0.0, 1.0) * (knots[k + 1].second - knots[k].second);
        break;
      }
    }
    r.push_back(v * kMm);
  }
  return r;
}

// Ellipsoidal heart: u in [-1, 1] from base to apex, theta around the long axis from anterior
// (e1) toward e2 = axis x e1 (the patient's right and inferior side).
struct Heart {
  Vec3 c, a, e1, e2;
  double h, r1, r2;  // m
  Vec3 local(double u, double th) const {
    const double w = std::sqrt(std::max(0.0, 1.0 - u * u));
    return h * u * a + w * (r1 * std::cos(th) * e1 + r2 * std::sin(th) * e2);
  }
  Vec3 normal(double u, double th) const {
    const double w = std::sqrt(std::max(0.0, 1.0 - u * u));
    return (u / h * a + w * (std::cos(th) / r1 * e1 + std::sin(th) / r2 * e2)).normalized();
  }
  // Centreline of a vessel of radius r lying on the epicardium (0.2 mm of fat below it).
  Vec3 on_surface(double u, double th, double r) const {
    return c + local(u, th) + (r + 0.2 * kMm) * normal(u, th);
  }
};

struct Builder {
  VesselTree t;
  int add(const std::string& name, VesselKind kind, int parent, std::vector<Vec3> pts,
          std::vector<double> radii, bool closed = false) {
    VesselSegment s;
    s.name = name;
    s.kind = kind;
    s.parent = parent;
    s.points = std::move(pts);
    s.radii = std::move(radii);
    s.closed_end = closed;
    t.segments.push_back(std::move(s));
    return t.num_segments() - 1;
  }
};

// A coronary drawn on the heart through waypoints (u, theta deg), optionally starting at a
// point of its parent; corners rounded by a spline through 3 mm samples; `spacing` apart.
struct CoronaryPath {
  std::vector<Vec3> points;
  Dense surface;  // dense samples with (u, theta) for branches to start from
};

CoronaryPath coronary(const Heart& hs, const std::vector<std::pair<double, double>>& way,
                      const std::vector<std::pair<double, double>>& radius_knots,
                      const std::vector<Vec3>& lead_in, double spacing, double join_deg = 0.0) {
  // Dense (u, theta) path, linear between waypoints, first with a mid radius for lengths.
  Dense d;
  for (std::size_t w = 0; w + 1 < way.size(); ++w) {
    for (int k = 0; k < 60; ++k) {
      const double f = k / 60.0;
      const double u = way[w].first + f * (way[w + 1].first - way[w].first);
      const double th = (way[w].second + f * (way[w + 1].second - way[w].second)) * kDeg;
      d.uv.emplace_back(u, th, 0.0);
    }
  }
  d.uv.emplace_back(way.back().first, way.back().second * kDeg, 0.0);
  for (const Vec3& q : d.uv) d.p.push_back(hs.on_surface(q.x(), q.y(), 1.5 * kMm));
  finish(d);
  // Second pass with the radius at each sample's arc-length fraction.
  const std::vector<double> r = radii_by_fraction(d.p, radius_knots);
  for (std::size_t i = 0; i < d.p.size(); ++i)
    d.p[i] = hs.on_surface(d.uv[i].x(), d.uv[i].y(), r[i]);
  finish(d);
  // Lead-in points (e.g. the path out of an aortic sinus), then a smooth resample.
  std::vector<Vec3> ctrl = lead_in;
  const double step = 3.0 * kMm;
  const int n = std::max(2, static_cast<int>(std::ceil(d.cum.back() / step)));
  // With join_deg: the surface path's first points are skipped until the way from the lead-in's
  // end to one runs within join_deg of the path's own direction there, so that a lead-in that
  // leaves the aorta away from where the groove starts meets the groove without turning back.
  bool joined = lead_in.empty() || join_deg <= 0.0;
  const double min_cos = std::cos(join_deg * kDeg);
  for (int k = 0; k <= n; ++k) {
    const Vec3 q = lerp_at(d.p, d.cum, d.cum.back() * k / n);
    if (!ctrl.empty() && (q - ctrl.back()).norm() < 0.5 * step) continue;
    if (!joined && k < n) {
      const Vec3 ahead = (lerp_at(d.p, d.cum, d.cum.back() * (k + 1) / n) - q).normalized();
      if ((q - ctrl.back()).normalized().dot(ahead) < min_cos) continue;
      joined = true;
    }
    ctrl.push_back(q);
  }
  const Dense sm = catmull_rom(ctrl, 16);
  CoronaryPath out;
  out.points = resample(sm, 0.0, sm.cum.back(), spacing);
  out.surface = d;
  return out;
}

// (u, theta deg) of the surface path at arc-length fraction f.
std::pair<double, double> uv_at(const Dense& d, double f) {
  const Vec3 q = lerp_at(d.uv, d.cum, f * d.cum.back());
  return {q.x(), q.y() / kDeg};
}

VesselTree make_patient(PatientVariant variant) {
  const bool left = variant == PatientVariant::kLeftDominantTortuous;
  Builder b;
  auto mm = [](double x, double y, double z) -> Vec3 { return Vec3(x, y, z) * kMm; };

  // ---- Aorta and the right iliofemoral access route: one spline from the valve to the groin,
  // split at control points into named segments (flow direction).
  std::vector<Vec3> ctrl = {mm(0, 0, 0)};
  const Vec3 d_root = Vec3(-0.2, -0.3, 0.93).normalized();
  ctrl.push_back(25.0 * kMm * d_root);  // sinotubular junction, 25 mm above the annulus
  std::vector<int> cut;                 // control indices that end a segment
  cut.push_back(1);
  if (!left) {
    for (Vec3 p : {mm(-11, -13, 45), mm(-12, -12, 65)}) ctrl.push_back(p);
    cut.push_back(static_cast<int>(ctrl.size()) - 1);
    for (Vec3 p : {mm(-6, -4, 80), mm(5, 12, 88), mm(17, 30, 85), mm(24, 48, 68)})
      ctrl.push_back(p);
    cut.push_back(static_cast<int>(ctrl.size()) - 1);
    for (Vec3 p : {mm(24, 60, 40), mm(18, 66, -30), mm(10, 62, -100), mm(6, 52, -135)})
      ctrl.push_back(p);
  } else {
    // Elongated ascending aorta, high arch and a tortuous (S-shaped) descending aorta.
    for (Vec3 p : {mm(-14, -15, 50), mm(-17, -14, 80)}) ctrl.push_back(p);
    cut.push_back(static_cast<int>(ctrl.size()) - 1);
    for (Vec3 p : {mm(-10, -5, 97), mm(3, 12, 105), mm(17, 31, 101), mm(26, 49, 82)})
      ctrl.push_back(p);
    cut.push_back(static_cast<int>(ctrl.size()) - 1);
    for (Vec3 p :
         {mm(30, 60, 50), mm(12, 67, 0), mm(30, 64, -55), mm(10, 60, -105), mm(6, 52, -135)})
      ctrl.push_back(p);
  }
  cut.push_back(static_cast<int>(ctrl.size()) - 1);  // diaphragm (aortic hiatus)
  for (Vec3 p : {mm(6, 42, -190), mm(8, 30, -250), mm(9, 26, -290)}) ctrl.push_back(p);
  cut.push_back(static_cast<int>(ctrl.size()) - 1);  // aortic bifurcation (L4)
  ctrl.push_back(mm(-22, 34, -340));
  cut.push_back(static_cast<int>(ctrl.size()) - 1);  // common iliac bifurcation
  if (left) {
    for (Vec3 p : {mm(-40, 36, -372), mm(-38, 24, -398), mm(-62, 18, -420), mm(-76, 4, -448)})
      ctrl.push_back(p);
  } else {
    for (Vec3 p : {mm(-45, 30, -385), mm(-66, 14, -425), mm(-76, 4, -448)}) ctrl.push_back(p);
  }
  cut.push_back(static_cast<int>(ctrl.size()) - 1);  // inguinal ligament
  ctrl.push_back(mm(-81, 0, -490));                  // common femoral, 43 mm (clinical.md)
  cut.push_back(static_cast<int>(ctrl.size()) - 1);
  std::vector<double> knot_s;
  const Dense chain = catmull_rom(ctrl, 24, &knot_s);

  struct ChainSeg {
    const char* name;
    VesselKind kind;
    double spacing_mm;
    std::vector<std::pair<double, double>> radius;  // (fraction, mm)
  };
  // Radii: aorta root 30-37, ascending 30-35, arch 25-30, descending 22-28, abdominal 18-25 mm;
  // common iliac 9, external iliac 7.5, common femoral 7.3 mm diameter (clinical.md).
  const std::vector<ChainSeg> chain_segs = {
      {"aortic_root",
       VesselKind::kAorta,
       1.0,
       {{0, 5}, {0.12, 10}, {0.28, 12.5}, {0.5, 13}, {1, 14.5}}},
      {"ascending_aorta", VesselKind::kAorta, 2.0, {{0, 14.5}, {0.3, 16}, {1, 15.5}}},
      {"aortic_arch", VesselKind::kAorta, 2.0, {{0, 15.5}, {0.3, 13.5}, {1, 12.5}}},
      {"thoracic_aorta", VesselKind::kAorta, 2.0, {{0, 12.5}, {1, 11.5}}},
      {"abdominal_aorta", VesselKind::kAorta, 2.0, {{0, 11.5}, {0.8, 9}, {1, 7.5}}},
      {"right_common_iliac", VesselKind::kArtery, 1.5, {{0, 5}, {0.25, 4.5}, {1, 4.5}}},
      {"right_external_iliac", VesselKind::kArtery, 1.5, {{0, 4.2}, {1, 3.75}}},
      {"right_common_femoral", VesselKind::kArtery, 1.5, {{0, 3.7}, {1, 3.65}}},
  };
  int prev = -1;
  std::vector<int> chain_index;
  for (std::size_t k = 0; k < chain_segs.size(); ++k) {
    const double s0 = k == 0 ? 0.0 : knot_s[cut[k - 1]];
    const double s1 = knot_s[cut[k]];
    auto pts = resample(chain, s0, s1, chain_segs[k].spacing_mm * kMm);
    auto r = radii_by_fraction(pts, chain_segs[k].radius);
    // The common iliacs both continue the aorta's end.
    const int parent = k == 5 ? chain_index[4] : prev;
    prev = b.add(chain_segs[k].name, chain_segs[k].kind, parent, pts, r);
    chain_index.push_back(prev);
  }
  const int root = chain_index[0], arch = chain_index[2], abdominal = chain_index[4];
  const int femoral = chain_index[7];
  {
    const auto& ab = b.t.segments[abdominal].points;
    std::vector<Vec3> c = {ab.back(), mm(30, 32, -322), mm(42, 36, -345)};
    const Dense d = catmull_rom(c, 24);
    auto pts = resample(d, 0.0, d.cum.back(), 1.5 * kMm);
    b.add("left_common_iliac", VesselKind::kArtery, abdominal, pts,
          radii_by_fraction(pts, {{0, 5}, {0.25, 4.5}, {1, 4.5}}));
  }

  // ---- Arch branches, each starting on the arch centreline.
  auto branch = [&](const char* name, int parent, double frac, std::vector<Vec3> rest,
                    std::vector<std::pair<double, double>> radius) {
    const VesselSegment& ps = b.t.segments[parent];
    std::vector<Vec3> c = {point_at(ps, frac * segment_length(ps))};
    c.insert(c.end(), rest.begin(), rest.end());
    const Dense d = catmull_rom(c, 24);
    auto pts = resample(d, 0.0, d.cum.back(), 1.5 * kMm);
    return b.add(name, VesselKind::kArtery, parent, pts, radii_by_fraction(pts, radius));
  };
  const double lift = left ? 17.0 : 0.0;  // the tortuous variant's arch sits higher
  branch("brachiocephalic", arch, 0.22,
         {mm(-12, -8, 105 + lift), mm(-18, -6, 125 + lift), mm(-22, -4, 138 + lift)},
         {{0, 6.5}, {0.4, 6}, {1, 5.5}});
  branch("left_common_carotid", arch, 0.42,
         {mm(6, 5, 110 + lift), mm(10, 0, 140 + lift), mm(14, -2, 175 + lift)},
         {{0, 4.2}, {0.3, 3.8}, {1, 3.5}});
  branch("left_subclavian", arch, 0.6,
         {mm(20, 26, 105 + lift), mm(32, 24, 120 + lift), mm(50, 18, 126 + lift),
          mm(65, 15, 122 + lift)},
         {{0, 5}, {0.3, 4.6}, {1, 4.2}});

  // ---- Aortic root sinuses: three lobes (closed) around the root at 10 mm above the annulus,
  // reaching 17 mm from the axis (root diameter 30-37 mm at the sinuses, clinical.md).
  const VesselSegment& rs = b.t.segments[root];
  const Vec3 ax = tangent_at(rs, 10 * kMm);
  auto perp = [&](Vec3 v) { return Vec3((v - v.dot(ax) * ax).normalized()); };
  const Vec3 w_right = perp(Vec3(-0.35, -1, 0));  // right coronary sinus: anterior
  const Vec3 w_left = perp(Vec3(1, 0.35, 0));     // left coronary sinus: left posterior
  const Vec3 w_non = perp(Vec3(-0.75, 0.8, 0));   // non-coronary sinus: right posterior
  const Vec3 a10 = point_at(rs, 10 * kMm);
  for (auto [name, w] :
       {std::pair{"right_coronary_sinus", w_right}, std::pair{"left_coronary_sinus", w_left},
        std::pair{"noncoronary_sinus", w_non}}) {
    b.add(name, VesselKind::kSinus, root, {a10, a10 + 7 * kMm * w}, {10 * kMm, 10 * kMm}, true);
  }

  // ---- Coronaries. The left main leaves the left sinus 14 mm above the annulus and runs
  // 10.5 mm (clinical.md: 10.5 +- 5.3 mm) left, anterior and down to its bifurcation.
  const Vec3 a14 = point_at(rs, 14 * kMm);
  const Vec3 d_lm = (w_left + Vec3(0.0, -0.3, -0.3)).normalized();
  const double r_lm = left ? 2.4 : 2.25;  // LM 4.5 (Dodge) to 5.0 mm (Vieweg) diameter
  const Vec3 bif = a14 + 27.5 * kMm * d_lm;

  // Heart: long axis base -> apex toward left, anterior, inferior; 120 mm long, 84 x 96 mm
  // across; placed so that the left main bifurcation lies on its surface at the base.
  Heart hs;
  hs.a = Vec3(0.6, -0.45, -0.65).normalized();
  hs.e1 = (Vec3(0, -1, 0) - Vec3(0, -1, 0).dot(hs.a) * hs.a).normalized();
  hs.e2 = hs.a.cross(hs.e1);
  hs.h = 60 * kMm;
  hs.r1 = 42 * kMm;
  hs.r2 = 48 * kMm;
  const double u_b = -0.72, th_b = -40 * kDeg;
  hs.c = Vec3::Zero();
  hs.c = bif - hs.on_surface(u_b, th_b, r_lm * kMm);

  // It leaves through the middle of its sinus (where a Judkins left's tip comes to rest) and
  // turns anterior toward the bifurcation.
  const Vec3 d_out = (w_left + Vec3(0.0, 0.0, -0.1)).normalized();
  const int lm = b.add("left_main", VesselKind::kCoronary, root,
                       {a14, a14 + 8 * kMm * d_out, a14 + 16 * kMm * d_out, bif},
                       {r_lm * kMm, r_lm * kMm, r_lm * kMm, r_lm * kMm});
  // Resample the left main at 0.8 mm like the other coronaries.
  {
    VesselSegment& s = b.t.segments[lm];
    Dense d;
    d.p = s.points;
    finish(d);
    s.points = resample(d, 0.0, d.cum.back(), 0.8 * kMm);
    s.radii.assign(s.points.size(), r_lm * kMm);
  }
  const double sp = 0.8 * kMm;
  auto add_cor = [&](const char* name, int parent, const CoronaryPath& p,
                     const std::vector<std::pair<double, double>>& knots) {
    return b.add(name, VesselKind::kCoronary, parent, p.points, radii_by_fraction(p.points, knots));
  };
  // A side branch leaving `parent` at arc fraction f, then through waypoints.
  auto side = [&](const char* name, int parent, const Dense& parent_surface, double f,
                  std::vector<std::pair<double, double>> way,
                  std::vector<std::pair<double, double>> knots) {
    // Start on the parent's centreline next to the parent's surface path at fraction f.
    const VesselSegment& ps = b.t.segments[parent];
    const auto uv = uv_at(parent_surface, f);
    const Vec3 target = hs.on_surface(uv.first, uv.second * kDeg, 1.0 * kMm);
    Vec3 start = ps.points.front();
    for (const Vec3& q : ps.points)
      if ((q - target).norm() < (start - target).norm()) start = q;
    way.insert(way.begin(), uv);
    const CoronaryPath p = coronary(hs, way, knots, {start}, sp);
    return add_cor(name, parent, p, knots);
  };

  // LAD: proximal 3.7, distal 1.9 mm diameter (Dodge); to the apex along the anterior
  // interventricular groove. Diagonals over the anterolateral wall.
  // Leave the bifurcation 75 degrees apart (clinical.md: 75 +- 23), symmetric about the bisector
  // of the apical and the leftward (atrioventricular groove) surface directions.
  const Vec3 n_b = hs.normal(u_b, th_b);
  auto tangential = [&](const Vec3& v) { return Vec3((v - v.dot(n_b) * n_b).normalized()); };
  const Vec3 e_apex = tangential(hs.local(u_b + 1e-3, th_b) - hs.local(u_b, th_b));
  const Vec3 e_left = tangential(hs.local(u_b, th_b - 1e-3) - hs.local(u_b, th_b));
  const Vec3 bis = (e_apex + e_left).normalized();
  const Vec3 side_dir = tangential(e_apex - e_apex.dot(bis) * bis);
  const double half = 37.5 * kDeg;
  const Vec3 lad_dir = std::cos(half) * bis + std::sin(half) * side_dir;
  const Vec3 lcx_dir = std::cos(half) * bis - std::sin(half) * side_dir;

  const std::vector<std::pair<double, double>> lad_r = {
      {0, left ? 1.9 : 1.85}, {0.35, 1.35}, {1, 0.95}};
  const CoronaryPath lad = coronary(hs, {{-0.52, -34}, {0.0, -30}, {0.6, -30}, {0.95, -32}}, lad_r,
                                    {bif, bif + 3 * kMm * lad_dir, bif + 6 * kMm * lad_dir}, sp);
  const int i_lad = add_cor("lad", lm, lad, lad_r);
  side("diagonal_1", i_lad, lad.surface, 0.2, {{0.1, -62}, {0.45, -78}}, {{0, 1.15}, {1, 0.8}});
  side("diagonal_2", i_lad, lad.surface, 0.45, {{0.5, -58}, {0.75, -68}}, {{0, 1.0}, {1, 0.75}});

  // LCx along the left atrioventricular groove: 3.4 mm (right-dominant) or 4.2 mm (left) proximal
  // diameter (Dodge); obtuse marginals down the lateral wall.
  std::vector<std::pair<double, double>> lcx_way = {
      {-0.76, -72}, {-0.74, -85}, {-0.72, -110}, {-0.68, -145}};
  std::vector<std::pair<double, double>> lcx_r = {{0, 1.7}, {0.5, 1.35}, {1, 1.0}};
  if (left) {
    lcx_way.push_back({-0.66, -205});  // on to the crux
    lcx_r = {{0, 2.1}, {0.5, 1.7}, {1, 1.3}};
  }
  const CoronaryPath lcx =
      coronary(hs, lcx_way, lcx_r, {bif, bif + 3 * kMm * lcx_dir, bif + 6 * kMm * lcx_dir}, sp);
  const int i_lcx = add_cor("lcx", lm, lcx, lcx_r);
  side("obtuse_marginal_1", i_lcx, lcx.surface, left ? 0.22 : 0.3, {{-0.2, -80}, {0.35, -80}},
       {{0, 1.15}, {1, 0.8}});
  side("obtuse_marginal_2", i_lcx, lcx.surface, left ? 0.48 : 0.65, {{-0.2, -125}, {0.3, -120}},
       {{0, 1.05}, {1, 0.75}});

  // RCA from the right sinus, down the right atrioventricular groove: 3.9 mm (right-dominant) or
  // 2.8 mm (left-dominant) proximal diameter (Dodge).
  // It runs 5 mm straight out of the sinus's wall (the lumen is cut clear of the aorta there,
  // lumen.cpp), then turns down and back on an arc of 12 mm radius through 130 degrees, and joins
  // the groove where the groove runs on within 25 degrees of the way to it (coronary(),
  // `join_deg`). The groove's start at this height lies behind and below the ostium. Joined at its
  // first point (until 2026-11-28) the RCA ran 23 mm out and came back in two hairpins (curvature
  // radius 2.3 mm for a 1.9 mm lumen); turned down over 8 mm (e1d2dbb), its 5 mm bend stiffened
  // the 0.014" wire's push enough to back the JR4 out of the ostium (docs/anatomy.md).
  const Vec3 rca_exit = a14 + 21 * kMm * w_right;
  const Vec3 rca_down = (Vec3(0, 0, -1) - Vec3(0, 0, -1).dot(w_right) * w_right).normalized();
  std::vector<Vec3> rca_lead = {a14, a14 + 8 * kMm * w_right, rca_exit};
  constexpr double kRcaArcRadius = 12 * kMm;
  constexpr double kRcaArcDeg = 130.0;
  constexpr int kRcaArcPoints = 5;
  for (int k = 1; k <= kRcaArcPoints; ++k) {
    const double f = kRcaArcDeg * kDeg * k / kRcaArcPoints;
    rca_lead.push_back(rca_exit +
                       kRcaArcRadius * (std::sin(f) * w_right + (1 - std::cos(f)) * rca_down));
  }
  constexpr double kRcaJoinDeg = 25.0;
  if (!left) {
    const std::vector<std::pair<double, double>> rca_r = {{0, 1.95}, {0.5, 1.7}, {1, 1.4}};
    const CoronaryPath rca =
        coronary(hs, {{-0.76, 22}, {-0.78, 60}, {-0.75, 100}, {-0.70, 130}, {-0.66, 150}}, rca_r,
                 rca_lead, sp, kRcaJoinDeg);
    const int i_rca = add_cor("rca", root, rca, rca_r);
    // Posterior descending and posterolateral branches from the crux (right dominance).
    const Vec3 crux = b.t.segments[i_rca].points.back();
    const std::vector<std::pair<double, double>> pda_r = {{0, 1.0}, {1, 0.75}};
    const CoronaryPath pda =
        coronary(hs, {{-0.62, 152}, {-0.3, 155}, {0.4, 160}, {0.7, 165}}, pda_r, {crux}, sp);
    add_cor("posterior_descending", i_rca, pda, pda_r);
    const CoronaryPath pl =
        coronary(hs, {{-0.68, 160}, {-0.66, 180}, {-0.55, 200}, {-0.1, 205}}, pda_r, {crux}, sp);
    add_cor("posterolateral", i_rca, pl, pda_r);
  } else {
    const std::vector<std::pair<double, double>> rca_r = {{0, 1.4}, {1, 1.0}};
    const CoronaryPath rca = coronary(hs, {{-0.76, 22}, {-0.78, 60}, {-0.75, 100}, {-0.72, 115}},
                                      rca_r, rca_lead, sp, kRcaJoinDeg);
    b.add("rca", VesselKind::kCoronary, root, rca.points, radii_by_fraction(rca.points, rca_r));
    // The posterior descending artery from the LCx at the crux (left dominance).
    const Vec3 crux = b.t.segments[i_lcx].points.back();
    const std::vector<std::pair<double, double>> pda_r = {{0, 1.0}, {1, 0.75}};
    const CoronaryPath pda =
        coronary(hs, {{-0.62, -203}, {-0.3, -200}, {0.4, -197}, {0.7, -195}}, pda_r, {crux}, sp);
    add_cor("posterior_descending", i_lcx, pda, pda_r);
  }

  VesselTree& t = b.t;
  t.name = left ? "left-dominant" : "default";
  t.open_start = false;  // the root starts at the closed aortic valve
  HeartModel hm;
  hm.centre = hs.c;
  hm.axis = hs.a;
  hm.anterior = hs.e1;
  hm.radii = Vec3(hs.h, hs.r1, hs.r2);
  t.heart = hm;
  // Access 10 mm inside the femoral open end (the sheath); target: the lesion's throat.
  t.access = {femoral, segment_length(t.segments[femoral]) - 10 * kMm};
  Lesion les;
  if (!left) {
    les.segment = i_lad;
    les.distance = 30 * kMm;
    les.length = 12 * kMm;
    les.diameter_reduction = 0.7;
    les.eccentricity = 0.4;
  } else {
    les.segment = i_lcx;
    les.distance = 15 * kMm;
    les.length = 10 * kMm;
    les.diameter_reduction = 0.6;
    les.eccentricity = 0.2;
  }
  t.lesions.push_back(les);
  t.target = {les.segment, ostium_distance(t, les.segment) + les.distance + 0.5 * les.length};
  validate_tree(t, "default_patient");
  return t;
}

}  // namespace

VesselTree default_patient(PatientVariant variant) {
  return make_patient(variant);
}

PatientVariant patient_variant_from_string(const std::string& name, const std::string& source) {
  if (name == "default" || name == "right-dominant") return PatientVariant::kRightDominant;
  if (name == "left-dominant") return PatientVariant::kLeftDominantTortuous;
  throw InputError(source, "patient",
                   "expected default, right-dominant or left-dominant, got '" + name + "'");
}

}  // namespace vcsim
