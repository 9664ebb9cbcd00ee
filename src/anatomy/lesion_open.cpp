// Lesions that open: the residual lumen of a lesion opened by t (0 as built, 1 healthy), and the
// lumen vertices a lesion moves (docs/anatomy.md, "Lesions that open").
#include <algorithm>
#include <cmath>
#include <limits>

#include "field.h"
#include "vcsim/anatomy.h"

namespace vcsim {

bool is_descendant(const VesselTree& tree, int seg, int ancestor) {
  for (int s = seg; s >= 0; s = tree.segments[s].parent)
    if (s == ancestor) return true;
  return false;
}

namespace {

// The point of segment si nearest p by lumen distance (distance minus radius), over the polyline's
// edges whose arc range meets [lo, hi]; updates `best`.
void consider_segment(const VesselTree& tree, int si, const Vec3& p, double lo, double hi,
                      TreeHit& best) {
  const VesselSegment& seg = tree.segments[si];
  double s0 = 0.0;
  for (std::size_t k = 0; k + 1 < seg.points.size(); ++k) {
    if (s0 > hi) break;  // s0 only grows: no later edge starts within the range
    const Vec3 a = seg.points[k], d = seg.points[k + 1] - a;
    const double len2 = d.squaredNorm(), len = std::sqrt(len2);
    if (s0 + len >= lo && s0 <= hi) {
      const double t = len2 > 0.0 ? std::clamp((p - a).dot(d) / len2, 0.0, 1.0) : 0.0;
      const double r = seg.radii[k] + t * (seg.radii[k + 1] - seg.radii[k]);
      const double out = (p - (a + t * d)).norm() - r;
      if (out < best.outside) {
        best.outside = out;
        best.loc = {si, s0 + t * len};
      }
    }
    s0 += len;
  }
}

}  // namespace

TreeHit locate(const VesselTree& tree, const Vec3& p) {
  TreeHit best;
  best.outside = std::numeric_limits<double>::infinity();
  constexpr double kAll = std::numeric_limits<double>::infinity();
  for (int si = 0; si < tree.num_segments(); ++si) consider_segment(tree, si, p, -kAll, kAll, best);
  return best;
}

TreeHit locate_near(const VesselTree& tree, const Vec3& p, const TreeLocation& hint,
                    double window) {
  if (hint.segment < 0 || hint.segment >= tree.num_segments()) return locate(tree, p);
  TreeHit best;
  best.outside = std::numeric_limits<double>::infinity();
  const double lo = hint.distance - window, hi = hint.distance + window;
  consider_segment(tree, hint.segment, p, lo, hi, best);
  const int parent = tree.segments[hint.segment].parent;
  if (parent >= 0 && lo < 0.0) consider_segment(tree, parent, p, -1e300, 1e300, best);
  // Children: their first `window` m (a side branch along the window, or one at its end).
  for (int k = 0; k < tree.num_segments(); ++k)
    if (tree.segments[k].parent == hint.segment) consider_segment(tree, k, p, -1e300, window, best);
  return best;
}

double LesionOpening::at(double u) const {
  if (t.empty()) return 0.0;
  if (t.size() == 1) return t[0];
  const double x = std::clamp(u, 0.0, 1.0) * static_cast<double>(t.size() - 1);
  const auto i = std::min(static_cast<std::size_t>(x), t.size() - 2);
  const double f = x - static_cast<double>(i);
  return t[i] + f * (t[i + 1] - t[i]);
}

LesionSpan lesion_span(const VesselTree& tree, const Lesion& lesion) {
  const double ost = ostium_distance(tree, lesion.segment);
  return {ost + lesion.distance, ost + lesion.distance + lesion.length};
}

LumenSection lumen_section(const VesselTree& tree, std::span<const LesionSpan> spans,
                           std::span<const LesionOpening> openings, int segment, double s) {
  const VesselSegment& seg = tree.segments[segment];
  const double r0 = radius_at(seg, s);
  LumenSection out{point_at(seg, s), r0};
  for (std::size_t k = 0; k < tree.lesions.size(); ++k) {
    const Lesion& les = tree.lesions[k];
    if (les.segment != segment || les.length <= 0.0) continue;
    const LesionSpan& sp = spans[k];
    if (s <= sp.s0 || s >= sp.s1) continue;
    const double t = openings.empty() ? 0.0 : openings[k].at((s - sp.s0) / (sp.s1 - sp.s0));
    // lesion_profile with the reduction scaled by (1 - t): the same phi, factor and shift.
    Lesion opened = les;
    opened.diameter_reduction = les.diameter_reduction * (1.0 - t);
    const LesionProfile p = lesion_profile(opened, sp.s0 - les.distance, r0, s);
    out.radius = p.factor * r0;
    out.centre -= p.shift * internal::plaque_direction(tree, les, s);
  }
  return out;
}

double opening_for_radius(const VesselTree& tree, const Lesion& lesion, const LesionSpan& span,
                          double s, double r) {
  if (s <= span.s0 || s >= span.s1 || lesion.diameter_reduction <= 0.0) return 0.0;
  const double r0 = radius_at(tree.segments[lesion.segment], s);
  const LesionProfile full = lesion_profile(lesion, span.s0 - lesion.distance, r0, s);
  const double narrowing = 1.0 - full.factor;  // reduction phi at s
  if (narrowing <= 0.0) return 0.0;
  // r = r0 (1 - narrowing (1 - t))  =>  t = 1 - (1 - r / r0) / narrowing
  return std::max(0.0, 1.0 - (1.0 - r / r0) / narrowing);
}

LesionMorph make_lesion_morph(const VesselTree& tree, const Lumen& lumen) {
  LesionMorph m;
  const int nv = lumen.mesh.num_vertices();
  for (std::size_t k = 0; k < tree.lesions.size(); ++k) {
    const Lesion& les = tree.lesions[k];
    const LesionSpan sp = lesion_span(tree, les);
    if (sp.s1 <= sp.s0) continue;
    for (int v = 0; v < nv; ++v) {
      if (lumen.vertex_segment[v] != les.segment) continue;
      const double s = lumen.vertex_arc[v];
      if (s <= sp.s0 || s >= sp.s1) continue;
      if (lumen.mesh.vertices[v] == lumen.healthy_vertices[v]) continue;
      m.vertices.push_back(v);
      m.lesion.push_back(static_cast<int>(k));
      m.u.push_back((s - sp.s0) / (sp.s1 - sp.s0));
    }
  }
  return m;
}

void morph_positions(const Lumen& lumen, const LesionMorph& morph,
                     std::span<const LesionOpening> openings, std::span<Vec3> out) {
  for (std::size_t i = 0; i < morph.vertices.size(); ++i) {
    const int v = morph.vertices[i];
    const double t = openings[morph.lesion[i]].at(morph.u[i]);
    const Vec3& a = lumen.mesh.vertices[v];
    out[i] = a + t * (lumen.healthy_vertices[v] - a);
  }
}

void morph_positions(const Lumen& lumen, const LesionMorph& morph, double uniform,
                     std::span<Vec3> out) {
  for (std::size_t i = 0; i < morph.vertices.size(); ++i) {
    const int v = morph.vertices[i];
    const Vec3& a = lumen.mesh.vertices[v];
    out[i] = a + uniform * (lumen.healthy_vertices[v] - a);
  }
}

}  // namespace vcsim
