// Cardiac and respiratory motion as a smooth displacement field, and the lumen split into
// patches so that a physics step moves and refits only what instruments can touch.
#include <algorithm>
#include <cassert>
#include <cmath>
#include <limits>
#include <numbers>

#include "vcsim/anatomy.h"

namespace vcsim {

namespace {

double smoothstep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * (3.0 - 2.0 * x);
}

// Cardiac waveform over one cycle (phase 0 = end-diastole, the R wave) as a C1 cubic Hermite
// through (phase, value, slope per cycle) knots: ejection to the end-systolic peak at 0.30,
// rapid filling, a slowing diastole and the atrial kick. Shaped so that, for the default
// patient's 4-5 mm coronary excursion at 70 bpm, motion stays within 1 mm for about 100 ms
// around end-systole and 110 ms in mid-diastole (clinical.md: RCA 76 +- 34 ms at end-systole,
// left tree 112 +- 42 ms in mid-diastole; docs/anatomy.md).
constexpr double kKnots[][3] = {{0.0, 0.0, 0.0},   {0.15, 0.5, 6.0},  {0.30, 1.0, 0.0},
                                {0.42, 0.6, -4.0}, {0.56, 0.3, -2.6}, {0.75, 0.05, -0.6},
                                {0.90, 0.0, 0.0},  {1.0, 0.0, 0.0}};

}  // namespace

void MotionSettings::validate(const std::string& src) const {
  require_in_range(heart_rate_bpm, 20.0, 250.0, src, "heart_rate_bpm");
  require_in_range(radial_contraction, -1.0, 0.5, src, "radial_contraction");
  require_in_range(longitudinal_contraction, -1.0, 0.5, src, "longitudinal_contraction");
  require_finite(twist, src, "twist");
  require_finite(translation, src, "translation");
  require_in_range(respiratory_rate_per_min, 0.0, 60.0, src, "respiratory_rate_per_min");
  require_finite(respiratory_shift, src, "respiratory_shift");
  require_finite(respiratory_rotation, src, "respiratory_rotation");
}

CardiacMotion::CardiacMotion(const VesselTree& tree, const MotionSettings& settings)
    : settings_(settings) {
  settings.validate("MotionSettings");
  if (!tree.heart)
    throw InputError(tree.name, "heart", "a heart model is needed for cardiac motion");
  heart_ = *tree.heart;
  valve_ = tree.segments.front().points.front();
}

double CardiacMotion::cardiac_waveform(double t) const {
  double ph = t / period();
  ph -= std::floor(ph);
  for (std::size_t k = 0; k + 1 < std::size(kKnots); ++k) {
    if (ph <= kKnots[k + 1][0]) {
      const double h = kKnots[k + 1][0] - kKnots[k][0], x = (ph - kKnots[k][0]) / h;
      const double x2 = x * x, x3 = x2 * x;
      const double v = (2 * x3 - 3 * x2 + 1) * kKnots[k][1] + (x3 - 2 * x2 + x) * h * kKnots[k][2] +
                       (-2 * x3 + 3 * x2) * kKnots[k + 1][1] + (x3 - x2) * h * kKnots[k + 1][2];
      return std::clamp(v, 0.0, 1.0);  // the cubic undershoots 0 by < 1 % near the atrial kick
    }
  }
  return 0.0;
}

double CardiacMotion::cardiac_rate(double t) const {
  double ph = t / period();
  ph -= std::floor(ph);
  for (std::size_t k = 0; k + 1 < std::size(kKnots); ++k) {
    if (ph <= kKnots[k + 1][0]) {
      const double h = kKnots[k + 1][0] - kKnots[k][0], x = (ph - kKnots[k][0]) / h;
      const double x2 = x * x;
      // d/dx of the Hermite basis, then dx/dt = 1 / (h period).
      const double dv = (6 * x2 - 6 * x) * kKnots[k][1] + (3 * x2 - 4 * x + 1) * h * kKnots[k][2] +
                        (-6 * x2 + 6 * x) * kKnots[k + 1][1] +
                        (3 * x2 - 2 * x) * h * kKnots[k + 1][2];
      return dv / (h * period());
    }
  }
  return 0.0;
}

double CardiacMotion::respiratory_rate(double t) const {
  if (!settings_.respiration) return 0.0;
  const double w = std::numbers::pi * settings_.respiratory_rate_per_min / 60.0;
  return w * std::sin(2.0 * w * t);  // d/dt sin^2(w t)
}

double CardiacMotion::respiratory_waveform(double t) const {
  if (!settings_.respiration) return 0.0;
  const double s = std::sin(std::numbers::pi * t * settings_.respiratory_rate_per_min / 60.0);
  return s * s;
}

void CardiacMotion::amplitudes(const Vec3& X, Vec3& a_c, Vec3& a_r) const {
  const HeartModel& h = heart_;
  const Vec3 e2 = h.axis.cross(h.anterior);
  const Vec3 d = X - h.centre;
  const double xa = d.dot(h.axis), x1 = d.dot(h.anterior), x2 = d.dot(e2);
  const Vec3 perp = d - xa * h.axis;
  // Normalised ellipsoidal radius: 1 on the epicardium.
  const double g =
      std::sqrt(xa * xa / (h.radii.x() * h.radii.x()) + x1 * x1 / (h.radii.y() * h.radii.y()) +
                x2 * x2 / (h.radii.z() * h.radii.z()));
  // The heart and what lies on it move; the aortic root is held by the aorta.
  const double w_heart = 1.0 - smoothstep((g - 1.1) / 0.15);
  const double w_root = smoothstep(((X - valve_).norm() - 12e-3) / 25e-3);
  const double w = w_heart * w_root;
  const double twist = settings_.twist * xa / h.radii.x();
  a_c = w * (settings_.translation * h.axis - settings_.radial_contraction * perp -
             settings_.longitudinal_contraction * xa * h.axis + twist * h.axis.cross(d));
  // Respiration: the heart and its surroundings shift caudally and turn about left-right.
  if (!settings_.respiration) {
    a_r.setZero();
    return;
  }
  const double w_r = 1.0 - smoothstep((d.norm() - 80e-3) / 100e-3);
  a_r = w_r * (Vec3(0.0, 0.0, -settings_.respiratory_shift) +
               settings_.respiratory_rotation * Vec3::UnitX().cross(d));
}

Vec3 CardiacMotion::displacement(const Vec3& X, double t) const {
  Vec3 a_c, a_r;
  amplitudes(X, a_c, a_r);
  return cardiac_waveform(t) * a_c + respiratory_waveform(t) * a_r;
}

Vec3 CardiacMotion::rest_point(const Vec3& p, double t) const {
  Vec3 X = p;
  for (int k = 0; k < 3; ++k) X = p - displacement(X, t);
  return X;
}

Vec3 CardiacMotion::velocity(const Vec3& X, double t) const {
  Vec3 a_c, a_r;
  amplitudes(X, a_c, a_r);
  return cardiac_rate(t) * a_c + respiratory_rate(t) * a_r;
}

VesselTree CardiacMotion::moved_tree(const VesselTree& rest, double t) const {
  VesselTree out = rest;
  for (auto& seg : out.segments)
    for (auto& p : seg.points) p += displacement(p, t);
  return out;
}

// ---------------------------------------------------------------------------------------------

namespace {

Aabb box_of(const std::vector<Vec3>& pts) {
  Aabb b{Vec3::Constant(1e300), Vec3::Constant(-1e300)};
  for (const Vec3& p : pts) {
    b.lo = b.lo.cwiseMin(p);
    b.hi = b.hi.cwiseMax(p);
  }
  return b;
}

bool overlaps(const Aabb& b, const Vec3& c, double r) {
  const Vec3 q = c.cwiseMax(b.lo).cwiseMin(b.hi);
  return (q - c).squaredNorm() <= r * r;
}

// Triangles split by centroid medians along the longest axis into patches of at most n.
void split(const TriangleMesh& m, const std::vector<Vec3>& centroid, std::vector<int>& idx,
           std::size_t lo, std::size_t hi, int n, std::vector<std::vector<int>>& out) {
  if (hi - lo <= static_cast<std::size_t>(n)) {
    out.emplace_back(idx.begin() + static_cast<std::ptrdiff_t>(lo),
                     idx.begin() + static_cast<std::ptrdiff_t>(hi));
    return;
  }
  Vec3 a = Vec3::Constant(1e300), b = Vec3::Constant(-1e300);
  for (std::size_t k = lo; k < hi; ++k) {
    a = a.cwiseMin(centroid[idx[k]]);
    b = b.cwiseMax(centroid[idx[k]]);
  }
  int axis = 0;
  (b - a).maxCoeff(&axis);
  const std::size_t mid = (lo + hi) / 2;
  std::nth_element(idx.begin() + static_cast<std::ptrdiff_t>(lo),
                   idx.begin() + static_cast<std::ptrdiff_t>(mid),
                   idx.begin() + static_cast<std::ptrdiff_t>(hi),
                   [&](int x, int y) { return centroid[x][axis] < centroid[y][axis]; });
  split(m, centroid, idx, lo, mid, n, out);
  split(m, centroid, idx, mid, hi, n, out);
}

}  // namespace

BeatingLumen::BeatingLumen(const TriangleMesh& rest, const CardiacMotion& motion,
                           const BeatingLumenSettings& settings)
    : BeatingLumen(rest, motion, {}, {}, settings) {}

BeatingLumen::BeatingLumen(const TriangleMesh& rest, const CardiacMotion& motion,
                           std::span<const int> morph_vertices, std::span<const Vec3> morph_limit,
                           const BeatingLumenSettings& settings)
    : motion_(motion) {
  if (morph_limit.size() != morph_vertices.size())
    throw InputError("BeatingLumen", "morph_limit", "expected one position per morph vertex");
  std::vector<int> morph_index(rest.vertices.size(), -1);
  for (std::size_t k = 0; k < morph_vertices.size(); ++k) {
    const int v = morph_vertices[k];
    if (v < 0 || v >= rest.num_vertices())
      throw InputError("BeatingLumen", "morph_vertices", "expected vertices of the mesh");
    morph_index[v] = static_cast<int>(k);
  }
  std::vector<std::vector<std::pair<int, int>>> places(morph_vertices.size());
  if (settings.patch_triangles < 8)
    throw InputError("BeatingLumenSettings", "patch_triangles", "expected at least 8");
  num_triangles_ = rest.num_triangles();
  num_vertices_ = rest.num_vertices();
  margin_ = settings.tree.margin;
  std::vector<Vec3> ac(rest.vertices.size()), ar(rest.vertices.size());
  for (std::size_t v = 0; v < rest.vertices.size(); ++v)
    motion_.amplitudes(rest.vertices[v], ac[v], ar[v]);
  // Triangles that never move go into one static part with one tree; the others into patches.
  std::vector<Vec3> centroid(rest.triangles.size());
  std::vector<int> moving_tris, static_tris;
  for (std::size_t t = 0; t < rest.triangles.size(); ++t) {
    const auto& tr = rest.triangles[t];
    centroid[t] = (rest.vertices[tr[0]] + rest.vertices[tr[1]] + rest.vertices[tr[2]]) / 3.0;
    double amp = 0.0;
    for (int v : tr) amp = std::max(amp, ac[v].norm() + ar[v].norm());
    (amp > 1e-9 ? moving_tris : static_tris).push_back(static_cast<int>(t));
  }
  std::vector<std::vector<int>> groups;
  if (!moving_tris.empty())
    split(rest, centroid, moving_tris, 0, moving_tris.size(), settings.patch_triangles, groups);
  std::vector<int> local(rest.vertices.size(), -1);
  auto make_patch = [&](const std::vector<int>& tris, int index) {
    Patch p;
    for (int t : tris) {
      std::array<int, 3> lt{};
      for (int k = 0; k < 3; ++k) {
        const int v = rest.triangles[t][k];
        if (local[v] < 0) {
          local[v] = static_cast<int>(p.global_vertex.size());
          p.global_vertex.push_back(v);
        }
        lt[k] = local[v];
      }
      p.mesh.triangles.push_back(lt);
      p.global_triangle.push_back(t);
    }
    double amp = 0.0;
    std::vector<Vec3> limits;  // the morph vertices' farthest positions
    for (std::size_t k = 0; k < p.global_vertex.size(); ++k) {
      const int v = p.global_vertex[k];
      local[v] = -1;
      p.rest.push_back(rest.vertices[v]);
      p.a_cardiac.push_back(ac[v]);
      p.a_resp.push_back(ar[v]);
      amp = std::max(amp, ac[v].norm() + ar[v].norm());
      if (const int m = morph_index[v]; m >= 0) {
        places[m].push_back({index, static_cast<int>(k)});
        limits.push_back(morph_limit[m]);
      }
    }
    p.mesh.vertices = p.rest;
    p.mesh.recompute_normals();
    p.tree.build(p.mesh, settings.tree);
    p.moving = amp > 1e-9;
    p.box = p.tree.nodes().front().box;
    if (p.moving) {
      // A moving patch is a few triangles queried one by one (query_sphere_each), stored in its
      // tree's visit order so that the answer is the tree's to the last bit, without the tree's
      // refit at every move.
      const std::vector<int> order = p.tree.visit_order();
      std::vector<std::array<int, 3>> sorted(order.size());
      std::vector<int> global(order.size());
      for (std::size_t k = 0; k < order.size(); ++k) {
        sorted[k] = p.mesh.triangles[order[k]];
        global[k] = p.global_triangle[order[k]];
      }
      p.mesh.triangles = std::move(sorted);
      p.global_triangle = std::move(global);
      p.mesh.recompute_normals();
      p.tree = AabbTree{};
    }
    p.rest_box = p.box;
    p.amp_c_box = box_of(p.a_cardiac);
    p.amp_r_box = box_of(p.a_resp);
    p.reach = box_of(p.rest);
    if (!limits.empty()) {
      // A lesion opened later moves these vertices at rest as far as their limits.
      Aabb lb = box_of(limits);
      lb.lo.array() -= settings.tree.margin;
      lb.hi.array() += settings.tree.margin;
      p.rest_box.lo = p.rest_box.lo.cwiseMin(lb.lo);
      p.rest_box.hi = p.rest_box.hi.cwiseMax(lb.hi);
      const Aabb l = box_of(limits);
      p.reach.lo = p.reach.lo.cwiseMin(l.lo);
      p.reach.hi = p.reach.hi.cwiseMax(l.hi);
    }
    const double grow = amp + settings.tree.margin;
    p.reach.lo.array() -= grow;
    p.reach.hi.array() += grow;
    for (std::size_t v = 0; v < p.a_cardiac.size(); ++v) {
      max_amp_c_ = std::max(max_amp_c_, p.a_cardiac[v].norm());
      max_amp_r_ = std::max(max_amp_r_, p.a_resp[v].norm());
    }
    return p;
  };
  if (!static_tris.empty()) static_ = make_patch(static_tris, -1);
  for (const auto& g : groups) patches_.push_back(make_patch(g, static_cast<int>(patches_.size())));
  morph_start_.assign(1, 0);
  for (const auto& pl : places) {
    for (const auto& [patch, lv] : pl) {
      morph_patch_.push_back(patch);
      morph_local_.push_back(lv);
    }
    morph_start_.push_back(static_cast<int>(morph_patch_.size()));
  }
  constexpr int kPhases = 9;
  phase_grids_.resize(kPhases);
  for (int k = 0; k < kPhases; ++k) {
    const double ck = static_cast<double>(k) / (kPhases - 1), half = 0.5 / (kPhases - 1);
    build_grid(phase_grids_[k], true, [&](const Patch& p) {
      // Box anywhere in [ck - half, ck + half] and any respiration.
      Aabb b = box_at(p, std::max(0.0, ck - half), 0.0);
      const Aabb e = box_at(p, std::min(1.0, ck + half), 1.0);
      const Aabb f = box_at(p, std::max(0.0, ck - half), 1.0);
      const Aabb g = box_at(p, std::min(1.0, ck + half), 0.0);
      for (const Aabb* o : {&e, &f, &g}) {
        b.lo = b.lo.cwiseMin(o->lo);
        b.hi = b.hi.cwiseMax(o->hi);
      }
      return b;
    });
  }
  build_grid(reach_grid_, true, [](const Patch& p) { return p.reach; });
  seen_.assign(patches_.size(), 0);
}

bool BeatingLumen::moves_near(const Vec3& centre, double radius) const {
  bool near = false;
  for_each_candidate(reach_grid_, centre, radius, [&](int pi) {
    near = near || overlaps(patches_[static_cast<std::size_t>(pi)].reach, centre, radius);
  });
  return near;
}

Aabb BeatingLumen::box_at(const Patch& p, double c, double r) const {
  return {p.rest_box.lo + c * p.amp_c_box.lo + r * p.amp_r_box.lo,
          p.rest_box.hi + c * p.amp_c_box.hi + r * p.amp_r_box.hi};
}

template <typename BoxOf>
void BeatingLumen::build_grid(PatchGrid& g, bool moving_only, BoxOf&& box_fn) {
  // Cells about twice the median patch size, at most about a million of them.
  Aabb all{Vec3::Constant(1e300), Vec3::Constant(-1e300)};
  std::vector<double> sizes;
  std::vector<Aabb> boxes(patches_.size());
  for (std::size_t pi = 0; pi < patches_.size(); ++pi) {
    const Patch& p = patches_[pi];
    if (moving_only && !p.moving) continue;
    boxes[pi] = box_fn(p);
    all.lo = all.lo.cwiseMin(boxes[pi].lo);
    all.hi = all.hi.cwiseMax(boxes[pi].hi);
    sizes.push_back((boxes[pi].hi - boxes[pi].lo).maxCoeff());
  }
  if (sizes.empty()) return;
  std::nth_element(sizes.begin(), sizes.begin() + static_cast<std::ptrdiff_t>(sizes.size() / 2),
                   sizes.end());
  g.cell = std::max(2.0 * sizes[sizes.size() / 2], 1e-3);
  const Vec3 ext = all.hi - all.lo;
  while (ext.x() / g.cell * ext.y() / g.cell * ext.z() / g.cell > 1e6) g.cell *= 1.5;
  g.origin = all.lo;
  g.nx = static_cast<int>(ext.x() / g.cell) + 1;
  g.ny = static_cast<int>(ext.y() / g.cell) + 1;
  g.nz = static_cast<int>(ext.z() / g.cell) + 1;
  std::vector<std::vector<int>> cells(static_cast<std::size_t>(g.nx) * g.ny * g.nz);
  for (int pi = 0; pi < num_patches(); ++pi) {
    if (moving_only && !patches_[pi].moving) continue;
    const Aabb& b = boxes[pi];
    const Eigen::Vector3i a = ((b.lo - g.origin) / g.cell).cast<int>();
    const Eigen::Vector3i c = ((b.hi - g.origin) / g.cell).cast<int>();
    for (int k = a.z(); k <= std::min(c.z(), g.nz - 1); ++k)
      for (int j = a.y(); j <= std::min(c.y(), g.ny - 1); ++j)
        for (int i = a.x(); i <= std::min(c.x(), g.nx - 1); ++i)
          cells[(static_cast<std::size_t>(k) * g.ny + j) * g.nx + i].push_back(pi);
  }
  g.start.assign(cells.size() + 1, 0);
  for (std::size_t c = 0; c < cells.size(); ++c)
    g.start[c + 1] = g.start[c] + static_cast<int>(cells[c].size());
  for (const auto& c : cells) g.list.insert(g.list.end(), c.begin(), c.end());
}

template <typename F>
void BeatingLumen::for_each_candidate(const PatchGrid& g, const Vec3& centre, double radius,
                                      F&& f) const {
  if (g.start.empty()) return;
  if (++stamp_ == 0) {  // wrapped: reset the stamps
    std::fill(seen_.begin(), seen_.end(), 0u);
    stamp_ = 1;
  }
  const Vec3 lo = (centre.array() - radius - g.origin.array()) / g.cell;
  const Vec3 hi = (centre.array() + radius - g.origin.array()) / g.cell;
  const int i0 = std::max(0, static_cast<int>(std::floor(lo.x())));
  const int j0 = std::max(0, static_cast<int>(std::floor(lo.y())));
  const int k0 = std::max(0, static_cast<int>(std::floor(lo.z())));
  const int i1 = std::min(g.nx - 1, static_cast<int>(std::floor(hi.x())));
  const int j1 = std::min(g.ny - 1, static_cast<int>(std::floor(hi.y())));
  const int k1 = std::min(g.nz - 1, static_cast<int>(std::floor(hi.z())));
  for (int k = k0; k <= k1; ++k)
    for (int j = j0; j <= j1; ++j)
      for (int i = i0; i <= i1; ++i) {
        const std::size_t c = (static_cast<std::size_t>(k) * g.ny + j) * g.nx + i;
        for (int n = g.start[c]; n < g.start[c + 1]; ++n) {
          const int pi = g.list[n];
          if (seen_[pi] == stamp_) continue;
          seen_[pi] = stamp_;
          f(pi);
        }
      }
}

void BeatingLumen::move_patch(Patch& p, double c, double r, double t) {
  const std::size_t n = p.rest.size();
  Vec3* x = p.mesh.vertices.data();
  const Vec3 *x0 = p.rest.data(), *ac = p.a_cardiac.data(), *ar = p.a_resp.data();
  // The box as the tree's root had it: the vertices' box grown by the fat margin.
  constexpr double kInf = std::numeric_limits<double>::infinity();
  double lo[3] = {kInf, kInf, kInf}, hi[3] = {-kInf, -kInf, -kInf};
  for (std::size_t i = 0; i < n; ++i) {
    x[i] = x0[i] + c * ac[i] + r * ar[i];
    const double* v = x[i].data();
    for (int a = 0; a < 3; ++a) {
      lo[a] = v[a] < lo[a] ? v[a] : lo[a];
      hi[a] = v[a] > hi[a] ? v[a] : hi[a];
    }
  }
  p.mesh.recompute_normals();
  const Vec3 m = Vec3::Constant(margin_);
  p.box = {Vec3(lo[0], lo[1], lo[2]) - m, Vec3(hi[0], hi[1], hi[2]) + m};
  p.time = t;
}

BeatingLumenProfile BeatingLumen::update(double t, std::span<const Vec3> centres,
                                         std::span<const double> radii) {
  const double t0 = now_us();
  BeatingLumenProfile prof;
  const double c = motion_.cardiac_waveform(t), r = motion_.respiratory_waveform(t);
  last_time_ = t;
  if (phase_grids_.empty()) return prof;
  const auto k =
      static_cast<std::size_t>(std::lround(c * static_cast<double>(phase_grids_.size() - 1)));
  last_grid_ = std::min(k, phase_grids_.size() - 1);
  last_time_ = t;
  const PatchGrid& grid = phase_grids_[last_grid_];
  for (std::size_t i = 0; i < centres.size(); ++i) {
    const double rad = radii.size() == 1 ? radii[0] : radii[i];
    for_each_candidate(grid, centres[i], rad, [&](int pi) {
      Patch& p = patches_[pi];
      if (p.time == t) return;
      // Where the patch is now (a box containing it, from the waveforms alone).
      if (!overlaps(box_at(p, c, r), centres[i], rad)) return;
      move_patch(p, c, r, t);
      ++prof.patches_updated;
      prof.triangles_updated += p.mesh.num_triangles();
    });
  }
  prof.us = now_us() - t0;
  return prof;
}

BeatingLumenProfile BeatingLumen::update_all(double t) {
  const double t0 = now_us();
  last_time_ = t;
  if (!phase_grids_.empty()) {
    const double c = motion_.cardiac_waveform(t);
    last_grid_ = std::min(
        static_cast<std::size_t>(std::lround(c * static_cast<double>(phase_grids_.size() - 1))),
        phase_grids_.size() - 1);
  }
  BeatingLumenProfile prof;
  const double c = motion_.cardiac_waveform(t), r = motion_.respiratory_waveform(t);
  for (Patch& p : patches_) {
    if (!p.moving || p.time == t) continue;
    move_patch(p, c, r, t);
    ++prof.patches_updated;
    prof.triangles_updated += p.mesh.num_triangles();
  }
  prof.us = now_us() - t0;
  return prof;
}

void BeatingLumen::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                                 std::span<SphereContact> out,
                                 const SphereQuerySettings& settings) const {
  query_spheres(centres, radii, {}, 0.0, out, settings);
}

void BeatingLumen::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                                 std::span<LeafCache* const> caches, double slack,
                                 std::span<SphereContact> out,
                                 const SphereQuerySettings& settings) const {
  const PatchGrid* grid = phase_grids_.empty() ? nullptr : &phase_grids_[last_grid_];
  for (std::size_t i = 0; i < centres.size(); ++i) {
    const double rad = radii.size() == 1 ? radii[0] : radii[i];
    // The patches' answers merged into the whole wall's: the closest wall point decides the
    // side, with the pseudo-normal of every patch it belongs to (a seam vertex or edge).
    SphereContactMerge merge;
    auto consider = [&](const Patch& p) {
      const SphereContact sc = p.moving ? query_sphere_each(p.mesh, centres[i], rad, settings)
                                        : p.tree.query_sphere(p.mesh, centres[i], rad, settings);
      if (sc.triangle >= 0) merge.add(sc, p.global_triangle[sc.triangle]);
    };
    if (!static_.global_triangle.empty()) {
      // The part that never moves keeps its leaves: a sphere that stays within its cache's
      // reach skips the traversal of this, the largest tree.
      if (!caches.empty() && caches[i] != nullptr) {
        const SphereContact sc =
            static_.tree.query_sphere(static_.mesh, centres[i], rad, slack, *caches[i], settings);
        if (sc.triangle >= 0) merge.add(sc, static_.global_triangle[sc.triangle]);
      } else {
        consider(static_);
      }
    }
    if (grid) {
      for_each_candidate(*grid, centres[i], rad + settings.escape_distance, [&](int pi) {
        const Patch& p = patches_[pi];
        // Only patches moved at the last update: any other cannot be touched now.
        if (p.time != last_time_ || !overlaps(p.box, centres[i], rad + settings.escape_distance))
          return;
        consider(p);
      });
    }
    const SphereContact merged = merge.result(centres[i], rad);
    // As before the merge: a sphere that overlaps no triangle is not in contact.
    out[i] = merged.num_touching > 0 ? merged : SphereContact{};
  }
}

void BeatingLumen::move_and_query(double t, std::span<const Vec3> centres,
                                  std::span<const double> radii, std::span<LeafCache* const> caches,
                                  double slack, std::span<SphereContact> out) {
  const double c = motion_.cardiac_waveform(t), r = motion_.respiratory_waveform(t);
  last_time_ = t;
  const PatchGrid* grid = nullptr;
  if (!phase_grids_.empty()) {
    last_grid_ = std::min(
        static_cast<std::size_t>(std::lround(c * static_cast<double>(phase_grids_.size() - 1))),
        phase_grids_.size() - 1);
    grid = &phase_grids_[last_grid_];
  }
  for (std::size_t i = 0; i < centres.size(); ++i) {
    const double rad = radii.size() == 1 ? radii[0] : radii[i];
    SphereContactMerge merge;
    if (!static_.global_triangle.empty()) {
      const SphereContact sc =
          !caches.empty() && caches[i] != nullptr
              ? static_.tree.query_sphere(static_.mesh, centres[i], rad, slack, *caches[i])
              : static_.tree.query_sphere(static_.mesh, centres[i], rad);
      if (sc.triangle >= 0) merge.add(sc, static_.global_triangle[sc.triangle]);
    }
    if (grid) {
      for_each_candidate(*grid, centres[i], rad, [&](int pi) {
        Patch& p = patches_[pi];
        // update()'s rule: moved when its box from the waveforms overlaps the sphere. A moved
        // patch's box lies inside that box, so one that did not pass cannot be touched.
        if (!overlaps(box_at(p, c, r), centres[i], rad)) return;
        if (p.time != t) move_patch(p, c, r, t);
        if (!overlaps(p.box, centres[i], rad)) return;
        const SphereContact sc = query_sphere_each(p.mesh, centres[i], rad);
        if (sc.triangle >= 0) merge.add(sc, p.global_triangle[sc.triangle]);
      });
    }
    const SphereContact merged = merge.result(centres[i], rad);
    out[i] = merged.num_touching > 0 ? merged : SphereContact{};
  }
}

SegmentCrossings BeatingLumen::segment_crossings(double t, const Vec3& a, const Vec3& b) {
  SegmentCrossings out;
  auto merge = [&](const SegmentCrossings& part) {
    if (part.count == 0) return;
    out.count += part.count;
    out.first = std::min(out.first, part.first);
    out.last = std::max(out.last, part.last);
  };
  if (!static_.global_triangle.empty()) merge(static_.tree.segment_crossings(static_.mesh, a, b));
  if (phase_grids_.empty()) return out;
  const double c = motion_.cardiac_waveform(t), r = motion_.respiratory_waveform(t);
  const auto k =
      static_cast<std::size_t>(std::lround(c * static_cast<double>(phase_grids_.size() - 1)));
  const PatchGrid& grid = phase_grids_[std::min(k, phase_grids_.size() - 1)];
  // The sphere round the segment: every patch it may cross lies within reach of it.
  const Vec3 mid = 0.5 * (a + b);
  const double half = 0.5 * (b - a).norm();
  for_each_candidate(grid, mid, half, [&](int pi) {
    Patch& p = patches_[static_cast<std::size_t>(pi)];
    if (!overlaps(box_at(p, c, r), mid, half)) return;
    if (p.time != t) move_patch(p, c, r, t);
    merge(segment_crossings_each(p.mesh, a, b));
  });
  return out;
}

void BeatingLumen::morph(std::span<const Vec3> rest_positions) {
  assert(rest_positions.size() + 1 == morph_start_.size());
  bool static_moved = false;
  for (std::size_t k = 0; k < rest_positions.size(); ++k) {
    for (int j = morph_start_[k]; j < morph_start_[k + 1]; ++j) {
      const int pi = morph_patch_[j];
      Patch& p = pi < 0 ? static_ : patches_[pi];
      p.rest[morph_local_[j]] = rest_positions[k];
      if (pi < 0) {
        p.mesh.vertices[morph_local_[j]] = rest_positions[k];
        static_moved = true;
      } else {
        p.time = -1.0;  // moved again at its next update
      }
    }
  }
  if (static_moved) {
    static_.mesh.recompute_normals();
    static_.tree.refit(static_.mesh);
    static_.box = static_.tree.nodes().front().box;
  }
}

void BeatingLumen::gather(TriangleMesh& out) const {
  out.vertices.resize(num_vertices_);
  for (std::size_t k = 0; k < static_.global_vertex.size(); ++k)
    out.vertices[static_.global_vertex[k]] = static_.mesh.vertices[k];
  for (const Patch& p : patches_)
    for (std::size_t k = 0; k < p.global_vertex.size(); ++k)
      out.vertices[p.global_vertex[k]] = p.mesh.vertices[k];
  out.recompute_normals();
}

}  // namespace vcsim
