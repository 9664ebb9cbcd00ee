// Vessel tree: centreline geometry, ostia, open ends, validation, lesion profiles.
#include <algorithm>
#include <cmath>
#include <numbers>

#include "field.h"
#include "vcsim/anatomy.h"

namespace vcsim {

namespace internal {

Vec3 any_perpendicular(const Vec3& t) {
  const Vec3 axis = std::abs(t.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY();
  return (axis - axis.dot(t) * t).normalized();
}

std::uint64_t hash_bytes(const void* data, std::size_t n, std::uint64_t h) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
  return h;
}

std::vector<Piece> make_pieces(const VesselTree& tree, const std::vector<int>& segments) {
  std::vector<Piece> out;
  auto add = [&](int si) {
    const auto& seg = tree.segments[si];
    double s = 0.0;
    for (std::size_t i = 0; i + 1 < seg.points.size(); ++i) {
      Piece pc{seg.points[i], seg.points[i + 1], seg.radii[i], seg.radii[i + 1], si, s};
      s += (pc.b - pc.a).norm();
      out.push_back(pc);
    }
  };
  if (segments.empty()) {
    for (int i = 0; i < tree.num_segments(); ++i) add(i);
  } else {
    for (int i : segments) add(i);
  }
  return out;
}

PieceGrid::PieceGrid(std::vector<Piece> pieces, double cell, double reach)
    : pieces_(std::move(pieces)), cell_(cell), reach_(reach) {
  if (pieces_.empty()) return;
  const double half_diag = 0.5 * std::sqrt(3.0) * cell_;
  auto margin_of = [&](const Piece& pc) { return reach_ + half_diag * piece_lipschitz(pc) * 1.05; };
  Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
  for (const Piece& pc : pieces_) {
    const double r = std::max(pc.ra, pc.rb) + margin_of(pc);
    lo = lo.cwiseMin(pc.a.cwiseMin(pc.b) - Vec3::Constant(r));
    hi = hi.cwiseMax(pc.a.cwiseMax(pc.b) + Vec3::Constant(r));
  }
  origin_ = lo;
  nx_ = static_cast<int>(std::ceil((hi.x() - lo.x()) / cell_)) + 1;
  ny_ = static_cast<int>(std::ceil((hi.y() - lo.y()) / cell_)) + 1;
  nz_ = static_cast<int>(std::ceil((hi.z() - lo.z()) / cell_)) + 1;
  const std::size_t ncell = static_cast<std::size_t>(nx_) * ny_ * nz_;
  deep_.assign(ncell, 0);
  std::vector<std::pair<int, int>> pairs;  // (cell, piece)
  for (int k = 0; k < static_cast<int>(pieces_.size()); ++k) {
    const Piece& pc = pieces_[k];
    // A cell whose centre value is within `margin` of the band may hold band points.
    const double margin = margin_of(pc);
    const double r = std::max(pc.ra, pc.rb) + margin;
    const Vec3 a = (pc.a.cwiseMin(pc.b) - Vec3::Constant(r) - origin_) / cell_;
    const Vec3 b = (pc.a.cwiseMax(pc.b) + Vec3::Constant(r) - origin_) / cell_;
    const int i0 = std::max(0, static_cast<int>(a.x())),
              i1 = std::min(nx_ - 1, static_cast<int>(b.x()));
    const int j0 = std::max(0, static_cast<int>(a.y())),
              j1 = std::min(ny_ - 1, static_cast<int>(b.y()));
    const int k0 = std::max(0, static_cast<int>(a.z())),
              k1 = std::min(nz_ - 1, static_cast<int>(b.z()));
    for (int l = k0; l <= k1; ++l)
      for (int j = j0; j <= j1; ++j)
        for (int i = i0; i <= i1; ++i) {
          const Vec3 c = origin_ + cell_ * Vec3(i + 0.5, j + 0.5, l + 0.5);
          const double f = eval_piece(pc, c).f;
          if (f > margin) continue;
          const int id = (l * ny_ + j) * nx_ + i;
          if (f < -margin) {
            deep_[id] = 1;
          } else {
            pairs.emplace_back(id, k);
          }
        }
  }
  // Per cell keep only pieces that can attain the minimum somewhere in it: lower bound
  // f_k(c) - hd L_k against the best upper bound min_j f_j(c) + hd L_j.
  {
    std::sort(pairs.begin(), pairs.end());
    std::vector<std::pair<int, int>> kept;
    kept.reserve(pairs.size());
    std::vector<double> fc;
    for (std::size_t n = 0; n < pairs.size();) {
      std::size_t e = n;
      while (e < pairs.size() && pairs[e].first == pairs[n].first) ++e;
      const int id = pairs[n].first;
      const Vec3 c =
          origin_ + cell_ * Vec3(id % nx_ + 0.5, (id / nx_) % ny_ + 0.5, id / (nx_ * ny_) + 0.5);
      double best_upper = 1e300;
      fc.clear();
      for (std::size_t q = n; q < e; ++q) {
        const Piece& pc = pieces_[pairs[q].second];
        fc.push_back(eval_piece(pc, c).f);
        best_upper = std::min(best_upper, fc.back() + half_diag * piece_lipschitz(pc));
      }
      if (deep_[id]) best_upper = std::min(best_upper, -reach_);
      for (std::size_t q = n; q < e; ++q)
        if (fc[q - n] - half_diag * piece_lipschitz(pieces_[pairs[q].second]) <= best_upper)
          kept.push_back(pairs[q]);
      n = e;
    }
    pairs = std::move(kept);
  }
  start_.assign(ncell + 1, 0);
  for (const auto& pr : pairs) ++start_[pr.first + 1];
  for (std::size_t c = 0; c < ncell; ++c) start_[c + 1] += start_[c];
  list_.resize(pairs.size());
  std::vector<int> fill(start_.begin(), start_.end() - 1);
  for (const auto& pr : pairs) list_[fill[pr.first]++] = pr.second;  // pieces in index order
}

int PieceGrid::cell_of(const Vec3& p) const {
  const Vec3 q = (p - origin_) / cell_;
  if (!(q.x() >= 0.0 && q.y() >= 0.0 && q.z() >= 0.0)) return -1;
  const int i = static_cast<int>(q.x()), j = static_cast<int>(q.y()), l = static_cast<int>(q.z());
  if (i >= nx_ || j >= ny_ || l >= nz_) return -1;
  return (l * ny_ + j) * nx_ + i;
}

PieceGrid::Result PieceGrid::eval(const Vec3& p) const {
  Result r;
  r.f = reach_;
  const int c = pieces_.empty() ? -1 : cell_of(p);
  if (c < 0) return r;
  for (int n = start_[c]; n < start_[c + 1]; ++n) {
    const PieceEval e = eval_piece(pieces_[list_[n]], p);
    if (e.f < r.f) {
      r.f = e.f;
      r.grad = e.grad;
      r.piece = list_[n];
      r.t = e.t;
    }
  }
  if (deep_[c] && r.f > -reach_) {
    r.f = -reach_;
    r.piece = -1;
  }
  return r;
}

double segment_field(const VesselSegment& seg, const Vec3& p) {
  double f = 1e300;
  for (std::size_t i = 0; i + 1 < seg.points.size(); ++i) {
    const Piece pc{seg.points[i], seg.points[i + 1], seg.radii[i], seg.radii[i + 1], 0, 0.0};
    f = std::min(f, eval_piece(pc, p).f);
  }
  return f;
}

Vec3 plaque_direction(const VesselTree& tree, const Lesion& lesion, double s) {
  const VesselSegment& seg = tree.segments[lesion.segment];
  const Vec3 t = tangent_at(seg, s);
  Vec3 ref = tree.heart ? Vec3(point_at(seg, s) - tree.heart->centre) : Vec3(0.0, -1.0, 0.0);
  ref -= ref.dot(t) * t;
  if (ref.norm() < 1e-9) ref = any_perpendicular(t);
  const Vec3 u0 = ref.normalized();
  return std::cos(lesion.angle) * u0 + std::sin(lesion.angle) * t.cross(u0);
}

bool continues_parent(const VesselTree& tree, int i) {
  const VesselSegment& seg = tree.segments[i];
  if (seg.parent < 0) return false;
  const VesselSegment& par = tree.segments[seg.parent];
  return (seg.points.front() - par.points.back()).norm() < 0.5 * par.radii.back();
}

}  // namespace internal

using internal::continues_parent;

std::string_view to_string(VesselKind kind) {
  switch (kind) {
    case VesselKind::kAorta:
      return "aorta";
    case VesselKind::kArtery:
      return "artery";
    case VesselKind::kCoronary:
      return "coronary";
    case VesselKind::kSinus:
      return "sinus";
  }
  return "artery";
}

int VesselTree::find(std::string_view n) const {
  for (int i = 0; i < num_segments(); ++i)
    if (segments[i].name == n) return i;
  return -1;
}

std::vector<double> arc_lengths(const VesselSegment& seg) {
  std::vector<double> cum(seg.points.size(), 0.0);
  for (std::size_t i = 1; i < seg.points.size(); ++i)
    cum[i] = cum[i - 1] + (seg.points[i] - seg.points[i - 1]).norm();
  return cum;
}

double segment_length(const VesselSegment& seg) {
  double l = 0.0;
  for (std::size_t i = 1; i < seg.points.size(); ++i)
    l += (seg.points[i] - seg.points[i - 1]).norm();
  return l;
}

namespace {

// Piece index and fraction at arc length s.
std::pair<std::size_t, double> locate(const VesselSegment& seg, double s) {
  double acc = 0.0;
  const std::size_t n = seg.points.size();
  if (n < 2) return {0, 0.0};
  s = std::max(s, 0.0);
  for (std::size_t i = 0; i + 1 < n; ++i) {
    const double l = (seg.points[i + 1] - seg.points[i]).norm();
    if (s <= acc + l || i + 2 == n) return {i, l > 0.0 ? std::clamp((s - acc) / l, 0.0, 1.0) : 0.0};
    acc += l;
  }
  return {n - 2, 1.0};
}

}  // namespace

Vec3 point_at(const VesselSegment& seg, double s) {
  if (seg.points.size() == 1) return seg.points[0];
  const auto [i, f] = locate(seg, s);
  return seg.points[i] + f * (seg.points[i + 1] - seg.points[i]);
}

double radius_at(const VesselSegment& seg, double s) {
  if (seg.radii.size() < 2) return seg.radii.empty() ? 0.0 : seg.radii[0];
  const auto [i, f] = locate(seg, s);
  return seg.radii[i] + f * (seg.radii[i + 1] - seg.radii[i]);
}

Vec3 tangent_at(const VesselSegment& seg, double s) {
  // Central difference over about a radius smooths the polyline's corners.
  const double h = std::max(0.25 * radius_at(seg, s), 1e-5);
  const Vec3 d = point_at(seg, s + h) - point_at(seg, s - h);
  return d.norm() > 0.0 ? Vec3(d.normalized()) : Vec3::UnitZ();
}

double ostium_distance(const VesselTree& tree, int i) {
  const VesselSegment& seg = tree.segments[i];
  if (seg.parent < 0 || continues_parent(tree, i)) return 0.0;
  // The parent's lumen includes its sinuses (a coronary ostium sits in a sinus wall).
  std::vector<int> host{seg.parent};
  for (int k = 0; k < tree.num_segments(); ++k)
    if (k != i && tree.segments[k].parent == seg.parent &&
        tree.segments[k].kind == VesselKind::kSinus)
      host.push_back(k);
  auto inside = [&](double s) {
    const Vec3 p = point_at(seg, s);
    for (int k : host)
      if (internal::segment_field(tree.segments[k], p) < 0.0) return true;
    return false;
  };
  const double len = segment_length(seg);
  double step = 0.1 * *std::min_element(seg.radii.begin(), seg.radii.end());
  double s = 0.0;
  while (s < len && inside(s)) s += step;
  if (s >= len) return len;
  // Bisect the exit between s - step and s.
  double lo = std::max(0.0, s - step), hi = s;
  for (int it = 0; it < 40; ++it) {
    const double mid = 0.5 * (lo + hi);
    (inside(mid) ? lo : hi) = mid;
  }
  return hi;
}

double attach_distance(const VesselTree& tree, int i) {
  const VesselSegment& seg = tree.segments[i];
  if (seg.parent < 0) return 0.0;
  const VesselSegment& par = tree.segments[seg.parent];
  if (continues_parent(tree, i)) return segment_length(par);
  const auto cum = arc_lengths(par);
  double best = 1e300, s_best = 0.0;
  for (std::size_t k = 0; k + 1 < par.points.size(); ++k) {
    const Vec3 d = par.points[k + 1] - par.points[k];
    const double t = std::clamp((seg.points[0] - par.points[k]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    const double dist = (par.points[k] + t * d - seg.points[0]).norm();
    if (dist < best) {
      best = dist;
      s_best = cum[k] + t * d.norm();
    }
  }
  return s_best;
}

std::vector<Vec3> route(const VesselTree& tree, const TreeLocation& from, const TreeLocation& to,
                        double spacing) {
  // Legs (segment, s_begin, s_end) from `from` up to the common ancestor, then down to `to`.
  auto chain = [&](int s) {
    std::vector<int> c;
    for (; s >= 0; s = tree.segments[s].parent) c.push_back(s);
    return c;
  };
  const auto ca = chain(from.segment), cb = chain(to.segment);
  int anc = -1;
  for (int a : ca)
    if (std::find(cb.begin(), cb.end(), a) != cb.end()) {
      anc = a;
      break;
    }
  struct Leg {
    int seg;
    double s0, s1;
  };
  std::vector<Leg> up, down;
  double s_up = from.distance, s_down = to.distance;
  for (int a : ca) {
    if (a == anc) break;
    up.push_back({a, s_up, 0.0});
    s_up = attach_distance(tree, a);
  }
  for (int b : cb) {
    if (b == anc) break;
    down.push_back({b, 0.0, s_down});
    s_down = attach_distance(tree, b);
  }
  std::vector<Leg> legs = up;
  legs.push_back({anc, s_up, s_down});
  legs.insert(legs.end(), down.rbegin(), down.rend());
  std::vector<Vec3> out;
  for (const Leg& l : legs) {
    const VesselSegment& seg = tree.segments[l.seg];
    const int n = std::max(1, static_cast<int>(std::ceil(std::abs(l.s1 - l.s0) / spacing)));
    for (int k = 0; k <= n; ++k) {
      const Vec3 p = point_at(seg, l.s0 + (l.s1 - l.s0) * k / n);
      if (out.empty() || (p - out.back()).norm() > 0.25 * spacing) out.push_back(p);
    }
  }
  return out;
}

std::vector<OpenEnd> open_ends(const VesselTree& tree) {
  std::vector<OpenEnd> out;
  for (int i = 0; i < tree.num_segments(); ++i) {
    const VesselSegment& seg = tree.segments[i];
    if (seg.points.size() < 2) continue;
    if (i == 0 && tree.open_start) {
      OpenEnd e;
      e.segment = i;
      e.at_start = true;
      e.centre = seg.points.front();
      e.outward = -tangent_at(seg, 0.0);
      e.radius = seg.radii.front();
      out.push_back(e);
    }
    if (seg.closed_end) continue;
    bool continued = false;
    for (int k = i + 1; k < tree.num_segments(); ++k)
      if (tree.segments[k].parent == i && continues_parent(tree, k)) continued = true;
    if (continued) continue;
    OpenEnd e;
    e.segment = i;
    e.centre = seg.points.back();
    e.outward = tangent_at(seg, segment_length(seg));
    e.radius = seg.radii.back();
    out.push_back(e);
  }
  return out;
}

LesionProfile lesion_profile(const Lesion& lesion, double ostium, double r0, double s) {
  LesionProfile p;
  const double s0 = ostium + lesion.distance;
  if (lesion.length <= 0.0 || s <= s0 || s >= s0 + lesion.length) return p;
  const double phi = 0.5 * (1.0 - std::cos(2.0 * std::numbers::pi * (s - s0) / lesion.length));
  p.factor = 1.0 - lesion.diameter_reduction * phi;
  p.shift = lesion.eccentricity * r0 * (1.0 - p.factor);
  return p;
}

VesselTree stenosed_tree(const VesselTree& tree, double spacing) {
  VesselTree out = tree;
  for (const Lesion& les : tree.lesions) {
    const VesselSegment& seg = out.segments[les.segment];
    const double ost = ostium_distance(tree, les.segment);
    const double s0 = ost + les.distance, s1 = s0 + les.length;
    const auto cum = arc_lengths(seg);
    VesselSegment ns = seg;
    ns.points.clear();
    ns.radii.clear();
    bool inserted = false;
    for (std::size_t i = 0; i < seg.points.size(); ++i) {
      if (cum[i] > s0 - spacing && cum[i] < s1 + spacing) {
        if (!inserted) {
          // The lesion, sampled finely; each sample from the healthy centreline.
          const int n = std::max(2, static_cast<int>(std::ceil((s1 - s0) / spacing)) + 1);
          for (int k = 0; k < n; ++k) {
            const double s = s0 + (s1 - s0) * k / (n - 1);
            const double r0 = radius_at(seg, s);
            const LesionProfile p = lesion_profile(les, ost, r0, s);
            ns.points.push_back(point_at(seg, s) -
                                p.shift * internal::plaque_direction(tree, les, s));
            ns.radii.push_back(r0 * p.factor);
          }
          inserted = true;
        }
        continue;
      }
      ns.points.push_back(seg.points[i]);
      ns.radii.push_back(seg.radii[i]);
    }
    out.segments[les.segment] = std::move(ns);
  }
  return out;
}

namespace {

std::string idx(const std::string& base, std::size_t i) {
  std::string s = base;
  s += '[';
  s += std::to_string(i);
  s += ']';
  return s;
}

}  // namespace

void validate_tree(const VesselTree& tree, const std::string& source) {
  if (tree.segments.empty()) throw InputError(source, "segments", "expected at least one segment");
  for (std::size_t i = 0; i < tree.segments.size(); ++i) {
    const VesselSegment& seg = tree.segments[i];
    const std::string f = idx("segments", i);
    if (seg.name.empty()) throw InputError(source, f + ".name", "expected a non-empty name");
    for (std::size_t k = 0; k < i; ++k)
      if (tree.segments[k].name == seg.name)
        throw InputError(source, f + ".name", "expected a unique name, '" + seg.name + "' repeats");
    if (i == 0 && seg.parent != -1)
      throw InputError(source, f + ".parent",
                       "expected the first segment to be the root (no parent)");
    if (i > 0 && (seg.parent < 0 || seg.parent >= static_cast<int>(i)))
      throw InputError(source, f + ".parent", "expected the name of an earlier segment");
    if (seg.points.size() < 2)
      throw InputError(source, f + ".points_mm", "expected at least 2 points");
    if (seg.radii.size() != seg.points.size())
      throw InputError(source, f + ".radii_mm", "expected one radius per point");
    for (std::size_t k = 0; k < seg.points.size(); ++k) {
      if (!seg.points[k].allFinite())
        throw InputError(source, idx(f + ".points_mm", k), "expected finite coordinates");
      if (k > 0 && (seg.points[k] - seg.points[k - 1]).norm() < 1e-6)
        throw InputError(source, idx(f + ".points_mm", k),
                         "expected distinct consecutive points (at least 0.001 mm apart)");
      const double r = seg.radii[k];
      if (!std::isfinite(r) || r <= 0.0 || r > 0.05)
        throw InputError(source, idx(f + ".radii_mm", k), "expected a radius in (0, 50] mm");
    }
    if (seg.parent >= 0) {
      const VesselSegment& par = tree.segments[seg.parent];
      if (!continues_parent(tree, static_cast<int>(i)) &&
          internal::segment_field(par, seg.points.front()) >= 0.0)
        throw InputError(
            source, idx(f + ".points_mm", 0),
            "expected the first point inside the lumen of parent '" + par.name + "' or at its end");
      if (seg.kind != VesselKind::kSinus &&
          ostium_distance(tree, static_cast<int>(i)) >= segment_length(seg))
        throw InputError(source, f + ".points_mm",
                         "expected the centreline to leave the lumen of parent '" + par.name + "'");
    }
  }
  // The extent: the first point (in file order) that stretches the box of the points before it
  // beyond kMaxTreeExtent is named.
  Vec3 lo = tree.segments[0].points[0], hi = lo;
  for (std::size_t i = 0; i < tree.segments.size(); ++i) {
    const VesselSegment& seg = tree.segments[i];
    for (std::size_t k = 0; k < seg.points.size(); ++k) {
      lo = lo.cwiseMin(seg.points[k]);
      hi = hi.cwiseMax(seg.points[k]);
      if ((hi - lo).maxCoeff() > kMaxTreeExtent)
        throw InputError(source, idx(idx("segments", i) + ".points_mm", k),
                         "expected the centrelines within a box of " +
                             std::to_string(static_cast<int>(kMaxTreeExtent * 1e3)) +
                             " mm a side; this point makes it " +
                             std::to_string(static_cast<long long>((hi - lo).maxCoeff() * 1e3)) +
                             " mm");
    }
  }
  const double triangles = estimated_lumen_triangles(tree, LumenSettings{});
  if (triangles > kMaxLumenTriangles)
    throw InputError(source, "segments",
                     "expected a lumen of at most " +
                         std::to_string(static_cast<long long>(kMaxLumenTriangles)) +
                         " triangles at the default voxel sizes; these vessels' walls would take "
                         "about " +
                         std::to_string(static_cast<long long>(triangles)));
  for (std::size_t i = 0; i < tree.lesions.size(); ++i) {
    const Lesion& l = tree.lesions[i];
    const std::string f = idx("lesions", i);
    if (l.segment < 0 || l.segment >= tree.num_segments())
      throw InputError(source, f + ".segment", "expected the name of a segment");
    require_nonnegative(l.distance, source, f + ".distance_mm");
    require_positive(l.length, source, f + ".length_mm");
    if (!(l.diameter_reduction >= 0.0 && l.diameter_reduction <= 0.95))
      throw InputError(source, f + ".diameter_reduction_percent", "expected a value in [0, 95]");
    if (!(l.eccentricity >= 0.0 && l.eccentricity <= 1.0))
      throw InputError(source, f + ".eccentricity", "expected a value in [0, 1]");
    require_finite(l.angle, source, f + ".angle_deg");
    const VesselSegment& seg = tree.segments[l.segment];
    const double avail = segment_length(seg) - ostium_distance(tree, l.segment);
    if (l.distance + l.length > avail)
      throw InputError(source, f + ".length_mm",
                       "expected the lesion to end within segment '" + seg.name + "' (" +
                           std::to_string(avail * 1e3) + " mm past its ostium)");
  }
  for (auto [loc, name] : {std::pair{tree.access, "access"}, std::pair{tree.target, "target"}}) {
    const std::string f = name;
    if (loc.segment < 0 || loc.segment >= tree.num_segments())
      throw InputError(source, f + ".segment", "expected the name of a segment");
    const double len = segment_length(tree.segments[loc.segment]);
    if (!(loc.distance >= 0.0 && loc.distance <= len))
      throw InputError(source, f + ".distance_mm", "expected a distance within the segment");
  }
  if (tree.heart) {
    const HeartModel& h = *tree.heart;
    if (!h.centre.allFinite())
      throw InputError(source, "heart.centre_mm", "expected finite values");
    if (!(h.radii.array() > 0.0).all() || !h.radii.allFinite())
      throw InputError(source, "heart.radii_mm", "expected three positive radii");
    if (!(std::abs(h.axis.norm() - 1.0) < 1e-6) || !(std::abs(h.anterior.norm() - 1.0) < 1e-6) ||
        std::abs(h.axis.dot(h.anterior)) > 1e-6)
      throw InputError(source, "heart.axis",
                       "expected non-zero axis and anterior vectors, not parallel");
  }
}

double estimated_lumen_triangles(const VesselTree& tree, const LumenSettings& st) {
  double n = 0.0;
  for (const VesselSegment& seg : tree.segments) {
    const double h = seg.kind == VesselKind::kCoronary ? st.fine_voxel : st.coarse_voxel;
    double area = 0.0;  // the wall swept along the centreline (a frustum per piece)
    for (std::size_t k = 0; k + 1 < seg.points.size() && k + 1 < seg.radii.size(); ++k)
      area += (seg.points[k + 1] - seg.points[k]).norm() * std::numbers::pi *
              (seg.radii[k] + seg.radii[k + 1]);
    n += 2.0 * area / (h * h);
  }
  return n;
}

}  // namespace vcsim
