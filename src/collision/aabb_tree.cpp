// Flat AABB tree over the lumen triangles: binned SAH build, in-place refit, sphere queries.
#include "vcsim/collision.h"

#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <limits>
#include <numbers>

namespace vcsim {

namespace {

double half_area(const Aabb& b) {
  const Vec3 d = (b.hi - b.lo).cwiseMax(0.0);
  return d.x() * d.y() + d.y() * d.z() + d.z() * d.x();
}

Aabb empty_box() {
  const double inf = std::numeric_limits<double>::infinity();
  return {Vec3::Constant(inf), Vec3::Constant(-inf)};
}

void grow(Aabb& b, const Aabb& o) {
  b.lo = b.lo.cwiseMin(o.lo);
  b.hi = b.hi.cwiseMax(o.hi);
}

void grow(Aabb& b, const Vec3& p) {
  b.lo = b.lo.cwiseMin(p);
  b.hi = b.hi.cwiseMax(p);
}

// Top-down builder. Split choice: binned surface area heuristic (Wald, "On fast construction of
// SAH-based bounding volume hierarchies", IEEE RT 2007): centroids are binned along each axis,
// and the split between bins minimising A_L N_L + A_R N_R is taken if it beats a leaf.
class Builder {
 public:
  Builder(const TriangleMesh& mesh, const AabbTreeSettings& s, std::vector<AabbNode>& nodes,
          std::vector<int>& order)
      : s_(s), nodes_(nodes), order_(order) {
    const int nt = mesh.num_triangles();
    boxes_.resize(nt);
    centroids_.resize(nt);
    for (int t = 0; t < nt; ++t) {
      Aabb b = empty_box();
      for (int v : mesh.triangles[t]) grow(b, mesh.vertices[v]);
      boxes_[t] = b;
      centroids_[t] = 0.5 * (b.lo + b.hi);
    }
  }

  // Builds the subtree of node `index` over order_[begin, end); returns its depth.
  int build(int index, int begin, int end, int depth) {
    const int n = end - begin;
    Aabb box = empty_box();
    Aabb cbox = empty_box();
    for (int i = begin; i < end; ++i) {
      grow(box, boxes_[order_[i]]);
      grow(cbox, centroids_[order_[i]]);
    }

    // Past this depth only balanced median splits, so the depth stays below kMaxDepth.
    const bool force_median = depth >= AabbTree::kMaxDepth - 40;
    int mid = -1;
    if (!force_median && n > 1) mid = sah_split(box, cbox, begin, end, n <= s_.max_leaf_size);
    if (mid < 0 && n > s_.max_leaf_size) mid = median_split(cbox, begin, end);
    if (mid < 0) {
      nodes_[index].first = begin;
      nodes_[index].count = n;
      return depth;
    }
    const int left = static_cast<int>(nodes_.size());
    nodes_.emplace_back();
    nodes_.emplace_back();
    nodes_[index].first = left;
    nodes_[index].count = 0;
    const int dl = build(left, begin, mid, depth + 1);
    const int dr = build(left + 1, mid, end, depth + 1);
    return std::max(dl, dr);
  }

 private:
  // Returns the partition point of the best binned SAH split, or -1 if there is none (or, when
  // a leaf is allowed, if a leaf is cheaper). Costs: traversal 1, triangle test 1.
  int sah_split(const Aabb& box, const Aabb& cbox, int begin, int end, bool leaf_allowed) {
    const int nb = s_.bins;
    std::vector<Bin>& bins = bins_;
    std::vector<double>& left_cost = left_cost_;
    bins.resize(nb);
    left_cost.resize(nb);
    double best = std::numeric_limits<double>::infinity();
    int best_axis = -1;
    int best_bin = -1;
    for (int axis = 0; axis < 3; ++axis) {
      const double lo = cbox.lo[axis];
      const double extent = cbox.hi[axis] - lo;
      if (!(extent > 0.0)) continue;
      const double scale = nb / extent;
      for (auto& b : bins) b = {empty_box(), 0};
      for (int i = begin; i < end; ++i) {
        const int t = order_[i];
        const int k = std::min(nb - 1, static_cast<int>((centroids_[t][axis] - lo) * scale));
        grow(bins[k].box, boxes_[t]);
        ++bins[k].count;
      }
      // Sweep from the left, then from the right; split k lies between bins k and k + 1.
      Aabb acc = empty_box();
      int count = 0;
      for (int k = 0; k < nb - 1; ++k) {
        grow(acc, bins[k].box);
        count += bins[k].count;
        left_cost[k] = count > 0 ? half_area(acc) * count : 0.0;
      }
      acc = empty_box();
      count = 0;
      for (int k = nb - 1; k > 0; --k) {
        grow(acc, bins[k].box);
        count += bins[k].count;
        const int n_left = (end - begin) - count;
        if (count == 0 || n_left == 0) continue;
        const double cost = left_cost[k - 1] + half_area(acc) * count;
        if (cost < best) {
          best = cost;
          best_axis = axis;
          best_bin = k - 1;
        }
      }
    }
    if (best_axis < 0) return -1;
    const double parent = half_area(box);
    if (leaf_allowed && parent * (end - begin) <= parent + best) return -1;

    const double lo = cbox.lo[best_axis];
    const double scale = nb / (cbox.hi[best_axis] - lo);
    auto* mid = std::partition(order_.data() + begin, order_.data() + end, [&](int t) {
      return std::min(nb - 1, static_cast<int>((centroids_[t][best_axis] - lo) * scale)) <=
             best_bin;
    });
    return static_cast<int>(mid - order_.data());
  }

  // Object median along the widest centroid axis: always splits n > 1 triangles in two halves.
  int median_split(const Aabb& cbox, int begin, int end) {
    if (end - begin < 2) return -1;
    int axis = 0;
    const Vec3 ext = cbox.hi - cbox.lo;
    if (ext.y() > ext[axis]) axis = 1;
    if (ext.z() > ext[axis]) axis = 2;
    const int mid = begin + (end - begin) / 2;
    std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                     [&](int a, int b) { return centroids_[a][axis] < centroids_[b][axis]; });
    return mid;
  }

  const AabbTreeSettings& s_;
  std::vector<AabbNode>& nodes_;
  std::vector<int>& order_;
  std::vector<Aabb> boxes_;
  std::vector<Vec3> centroids_;
  std::vector<double> left_cost_;

  struct Bin {
    Aabb box;
    int count;
  };
  std::vector<Bin> bins_;
};

// Sphere-wall accumulator for one query; see query_sphere for the rules.
struct Accumulator {
  double d_min = std::numeric_limits<double>::infinity();
  Vec3 point = Vec3::Zero();
  int triangle = -1;
  Vec3 pseudo_normal = Vec3::Zero();  // inward direction at the closest feature (sign test)
  int dim = -1;                       // that feature's dimension: 0 vertex, 1 edge, 2 face
  Vec3 weighted_normal = Vec3::Zero();
  double weight_sum = 0.0;
  int touching = 0;
};

// 2 for a face's interior, 1 for an edge, 0 for a vertex.
int feature_dimension(TriangleRegion r) {
  switch (r) {
    case TriangleRegion::kFace:
      return 2;
    case TriangleRegion::kEdgeAB:
    case TriangleRegion::kEdgeBC:
    case TriangleRegion::kEdgeCA:
      return 1;
    default:
      return 0;
  }
}

double vertex_angle(const Vec3& at, const Vec3& p, const Vec3& q) {
  const Vec3 u = p - at;
  const Vec3 v = q - at;
  return std::atan2(u.cross(v).norm(), u.dot(v));
}

[[gnu::always_inline]] inline void test_triangle(const TriangleMesh& mesh, int t,
                                                 const Vec3& centre, double radius, double search2,
                                                 Accumulator& acc) {
  const auto& tri = mesh.triangles[t];
  const Vec3& a = mesh.vertices[tri[0]];
  const Vec3& b = mesh.vertices[tri[1]];
  const Vec3& c = mesh.vertices[tri[2]];
  const Vec3& n = mesh.normals[t];
  // The distance to the triangle's plane bounds the distance to the triangle from below.
  const double h = n.dot(centre - a);
  if (h * h > search2) return;
  const ClosestPoint cp = closest_point_on_triangle(centre, a, b, c);
  const double d2 = (centre - cp.point).squaredNorm();
  if (d2 > search2) return;
  const double d = std::sqrt(d2);

  // Inside/outside from the closest feature's pseudo-normal (Baerentzen and Aanaes, IEEE TVCG
  // 2005): a face's own normal, the sum over the faces of an edge, the angle-weighted sum at a
  // vertex. An edge's or a vertex's sum is whole only when every face at it reports that point, so
  // the faces at the same point (within `tie`) join it. A centre equally far from distinct
  // features (on the axis of a perfectly round tube) must not sum their opposite normals to
  // nothing, so features elsewhere never join. Which one decides among features as near as each
  // other within `tie`: the one of highest dimension. A centre whose foot lies in a face a few
  // nanometres from its edge is farther from that edge, as the other face sees it, by only
  // foot^2 / 2d: within the tie, at another point. That face alone reports the edge, so its sum
  // there lacks the first face; at a sharp ridge (a bifurcation's flow divider) its normal points
  // away from the centre, and the first seen of the two decided (issue 29: the soak's wire read
  // as 0.18 mm behind the wall in front of the LAD / diagonal carina, and kicked by that depth).
  // A face's own normal is always whole, and an edge's two faces both report it, so preferring
  // the higher dimension gives the whole sum.
  const int dim = feature_dimension(cp.region);
  const double tie = 1e-12 + 1e-10 * d;
  if (d < acc.d_min - tie ||
      (d <= acc.d_min + tie && dim > acc.dim && (cp.point - acc.point).squaredNorm() > tie * tie)) {
    acc.d_min = d;
    acc.point = cp.point;
    acc.triangle = t;
    acc.pseudo_normal.setZero();
    acc.dim = dim;
  }
  if (d <= acc.d_min + tie && (cp.point - acc.point).squaredNorm() <= tie * tie) {
    double w = 1.0;
    switch (cp.region) {
      case TriangleRegion::kVertexA:
        w = vertex_angle(a, b, c);
        break;
      case TriangleRegion::kVertexB:
        w = vertex_angle(b, c, a);
        break;
      case TriangleRegion::kVertexC:
        w = vertex_angle(c, a, b);
        break;
      default:
        break;
    }
    acc.pseudo_normal += w * n;
    acc.dim = std::max(acc.dim, dim);
    if (d < acc.d_min) {
      acc.d_min = d;
      acc.point = cp.point;
      acc.triangle = t;
    }
  }

  // Contact normal: normals of the triangles overlapping the sphere, each weighted by its depth
  // times its area inside the sphere (triangle area, at most the disc the sphere cuts from the
  // triangle's plane), so that the result does not depend on how finely the wall is meshed.
  if (d < radius) {
    const double area = 0.5 * (b - a).cross(c - a).norm();
    const double disc = std::numbers::pi * (radius * radius - d2);
    const double w = (radius - d) * std::min(area, disc);
    acc.weighted_normal += w * n;
    acc.weight_sum += w;
    ++acc.touching;
  }
}

// Squared distance from p to the box, in plain scalars: this test is most of a query's work.
inline double box_distance2(const Aabb& b, const Vec3& p) {
  const double* lo = b.lo.data();
  const double* hi = b.hi.data();
  const double* c = p.data();
  double d2 = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double below = lo[a] - c[a];
    const double above = c[a] - hi[a];
    const double out = std::max(std::max(below, above), 0.0);
    d2 += out * out;
  }
  return d2;
}

}  // namespace

void AabbTree::build(const TriangleMesh& mesh, const AabbTreeSettings& settings) {
  if (settings.max_leaf_size < 1)
    throw InputError("AabbTreeSettings", "max_leaf_size", "at least 1");
  if (settings.bins < 2) throw InputError("AabbTreeSettings", "bins", "at least 2");
  require_nonnegative(settings.margin, "AabbTreeSettings", "margin");
  assert(mesh.normals.size() == mesh.triangles.size());
  settings_ = settings;
  num_triangles_ = mesh.num_triangles();
  nodes_.clear();
  order_.resize(num_triangles_);
  for (int t = 0; t < num_triangles_; ++t) order_[t] = t;
  depth_ = 0;
  if (num_triangles_ == 0) return;
  nodes_.reserve(2 * static_cast<std::size_t>(num_triangles_));
  nodes_.emplace_back();
  Builder builder(mesh, settings_, nodes_, order_);
  depth_ = builder.build(0, 0, num_triangles_, 0);
  nodes_.shrink_to_fit();
  refit(mesh);
}

void AabbTree::refit(const TriangleMesh& mesh) {
  assert(mesh.num_triangles() == num_triangles_);
  const Vec3 margin = Vec3::Constant(settings_.margin);
  // Children come after their parents, so one backward pass sees children first.
  for (auto i = static_cast<int>(nodes_.size()) - 1; i >= 0; --i) {
    AabbNode& node = nodes_[i];
    if (node.is_leaf()) {
      // Plain scalars: this loop is the whole cost of a refit.
      const Vec3& p0 = mesh.vertices[mesh.triangles[order_[node.first]][0]];
      double lo[3] = {p0.x(), p0.y(), p0.z()};
      double hi[3] = {p0.x(), p0.y(), p0.z()};
      for (int k = node.first; k < node.first + node.count; ++k) {
        for (int v : mesh.triangles[order_[k]]) {
          const double* p = mesh.vertices[v].data();
          for (int a = 0; a < 3; ++a) {
            lo[a] = p[a] < lo[a] ? p[a] : lo[a];
            hi[a] = p[a] > hi[a] ? p[a] : hi[a];
          }
        }
      }
      node.box.lo = Vec3(lo[0], lo[1], lo[2]) - margin;
      node.box.hi = Vec3(hi[0], hi[1], hi[2]) + margin;
    } else {
      const Aabb& l = nodes_[node.first].box;
      const Aabb& r = nodes_[node.first + 1].box;
      node.box.lo = l.lo.cwiseMin(r.lo);
      node.box.hi = l.hi.cwiseMax(r.hi);
    }
  }
}

// Rules, for a sphere (centre, radius):
//  - every triangle within radius + escape_distance is examined (broad phase: sphere vs box);
//  - the closest one decides which side of the wall the centre is on (pseudo-normal test);
//  - centre in the lumen: contact if the wall is closer than the radius, depth = r - d;
//  - centre behind the wall (it crossed the wall during a step): always a contact, with
//    depth = r + d, so the solver pushes it back across rather than further out (no tunnelling);
//  - normal: weighted mean of the inward normals of the triangles overlapping the sphere, or the
//    closest feature's pseudo-normal if none overlaps (a centre just beyond the radius behind
//    the wall) or if the mean cancels (a sphere wedged between opposite walls).
namespace {

// Side, depth and normal from a query's sums; `fallback` is the normal where both sums vanish.
SphereContact decide(const Accumulator& acc, const Vec3& fallback, const Vec3& centre,
                     double radius) {
  SphereContact out;
  if (acc.triangle < 0) return out;
  out.distance = acc.d_min;
  out.point = acc.point;
  out.triangle = acc.triangle;
  out.num_touching = acc.touching;
  out.side_sum = acc.pseudo_normal;
  out.side_dim = acc.dim;
  out.normal_sum = acc.weighted_normal;
  out.weight_sum = acc.weight_sum;
  // Walls equally near on opposite sides (a centre on a tube's axis) cancel each other's
  // pseudo-normals: such a centre is between walls, hence inside. A centre behind a wall is
  // nearest to that wall alone, whose pseudo-normal does not cancel.
  out.centre_outside =
      acc.pseudo_normal.norm() > 1e-6 && acc.pseudo_normal.dot(centre - acc.point) < 0.0;
  if (!out.centre_outside && acc.d_min >= radius) return out;
  out.touching = true;
  out.depth = out.centre_outside ? radius + acc.d_min : radius - acc.d_min;
  const double wn = acc.weighted_normal.norm();
  if (wn > 1e-6 * acc.weight_sum && wn > 0.0) {
    out.normal = acc.weighted_normal / wn;
  } else if (acc.pseudo_normal.norm() > 0.0) {
    out.normal = acc.pseudo_normal.normalized();
  } else {
    out.normal = fallback;
  }
  return out;
}

SphereContact finish(const TriangleMesh& mesh, const Accumulator& acc, const Vec3& centre,
                     double radius) {
  return decide(acc, acc.triangle >= 0 ? mesh.normals[acc.triangle] : Vec3::Zero(), centre, radius);
}

}  // namespace

namespace {
// Whether segment a + t d, t in [0, 1], passes through box b (the slab test; inv = 1 / d per axis,
// infinite along an axis d does not move on).
bool segment_meets_box(const Aabb& b, const Vec3& a, const Vec3& inv) {
  double lo = 0.0, hi = 1.0;
  for (int k = 0; k < 3; ++k) {
    if (std::isinf(inv[k])) {
      if (a[k] < b.lo[k] || a[k] > b.hi[k]) return false;
      continue;
    }
    double t0 = (b.lo[k] - a[k]) * inv[k], t1 = (b.hi[k] - a[k]) * inv[k];
    if (t0 > t1) std::swap(t0, t1);
    lo = std::max(lo, t0);
    hi = std::min(hi, t1);
    if (lo > hi) return false;
  }
  return true;
}
}  // namespace

SegmentCrossings AabbTree::segment_crossings(const TriangleMesh& mesh, const Vec3& a,
                                             const Vec3& b) const {
  SegmentCrossings c;
  if (nodes_.empty()) return c;
  const Vec3 d = b - a;
  const Vec3 inv(1.0 / d.x(), 1.0 / d.y(), 1.0 / d.z());
  if (!segment_meets_box(nodes_[0].box, a, inv)) return c;
  std::array<int, kMaxDepth + 2> stack;
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const AabbNode& node = nodes_[stack[--top]];
    if (node.is_leaf()) {
      for (int k = node.first; k < node.first + node.count; ++k) {
        const auto& tri = mesh.triangles[static_cast<std::size_t>(order_[k])];
        const double t = segment_triangle_crossing(a, b, mesh.vertices[tri[0]],
                                                   mesh.vertices[tri[1]], mesh.vertices[tri[2]]);
        if (t >= 0.0) c.add(t);
      }
      continue;
    }
    const int l = node.first;
    if (segment_meets_box(nodes_[l].box, a, inv)) stack[top++] = l;
    if (segment_meets_box(nodes_[l + 1].box, a, inv)) stack[top++] = l + 1;
  }
  return c;
}

SphereContact AabbTree::query_sphere(const TriangleMesh& mesh, const Vec3& centre, double radius,
                                     const SphereQuerySettings& settings) const {
  if (nodes_.empty()) return {};
  const double search = radius + settings.escape_distance;
  const double search2 = search * search;
  Accumulator acc;
  // Only nodes whose boxes reach the sphere are pushed: children are tested where their parent
  // is expanded (siblings are adjacent in memory), so far subtrees cost no stack traffic.
  if (box_distance2(nodes_[0].box, centre) > search2) return {};
  std::array<int, kMaxDepth + 2> stack;
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const AabbNode& node = nodes_[stack[--top]];
    if (node.is_leaf()) {
      for (int k = node.first; k < node.first + node.count; ++k)
        test_triangle(mesh, order_[k], centre, radius, search2, acc);
      continue;
    }
    const int l = node.first;
    if (box_distance2(nodes_[l].box, centre) <= search2) stack[top++] = l;
    if (box_distance2(nodes_[l + 1].box, centre) <= search2) stack[top++] = l + 1;
  }
  return finish(mesh, acc, centre, radius);
}

SphereContact AabbTree::query_sphere(const TriangleMesh& mesh, const Vec3& centre, double radius,
                                     double slack, LeafCache& cache,
                                     const SphereQuerySettings& settings) const {
  if (nodes_.empty()) return {};
  const double search = radius + settings.escape_distance;
  const double search2 = search * search;
  Accumulator acc;
  auto test_leaf = [&](const AabbNode& leaf) {
    if (box_distance2(leaf.box, centre) > search2) return;
    for (int k = leaf.first; k < leaf.first + leaf.count; ++k)
      test_triangle(mesh, order_[k], centre, radius, search2, acc);
  };
  if (cache.reach >= 0.0 && (centre - cache.centre).norm() + search <= cache.reach) {
    for (int k = 0; k < cache.count; ++k) test_leaf(nodes_[cache.leaves[k]]);
    return finish(mesh, acc, centre, radius);
  }
  // Refill: every leaf within reach of the centre, listed while the triangles are tested.
  const double reach = search + slack;
  const double reach2 = reach * reach;
  cache.centre = centre;
  cache.reach = reach;
  cache.count = 0;
  if (box_distance2(nodes_[0].box, centre) <= reach2) {
    std::array<int, kMaxDepth + 2> stack;
    int top = 0;
    stack[top++] = 0;
    while (top > 0) {
      const int index = stack[--top];
      const AabbNode& node = nodes_[index];
      if (node.is_leaf()) {
        if (cache.count < LeafCache::kCapacity) {
          cache.leaves[cache.count++] = index;
        } else {
          cache.reach = -1.0;  // too many to list: this sphere is always traversed
        }
        test_leaf(node);
        continue;
      }
      const int l = node.first;
      if (box_distance2(nodes_[l].box, centre) <= reach2) stack[top++] = l;
      if (box_distance2(nodes_[l + 1].box, centre) <= reach2) stack[top++] = l + 1;
    }
  }
  return finish(mesh, acc, centre, radius);
}

std::vector<int> AabbTree::visit_order() const {
  std::vector<int> out;
  out.reserve(order_.size());
  if (nodes_.empty()) return out;
  // query_sphere's traversal with every box reached: children pushed left then right.
  std::vector<int> stack{0};
  while (!stack.empty()) {
    const AabbNode& node = nodes_[stack.back()];
    stack.pop_back();
    if (node.is_leaf()) {
      for (int k = node.first; k < node.first + node.count; ++k) out.push_back(order_[k]);
      continue;
    }
    stack.push_back(node.first);
    stack.push_back(node.first + 1);
  }
  return out;
}

SphereContact query_sphere_each(const TriangleMesh& mesh, const Vec3& centre, double radius,
                                const SphereQuerySettings& settings) {
  const double search = radius + settings.escape_distance;
  const double search2 = search * search;
  Accumulator acc;
  const int n = mesh.num_triangles();
  for (int t = 0; t < n; ++t) test_triangle(mesh, t, centre, radius, search2, acc);
  return finish(mesh, acc, centre, radius);
}

void SphereContactMerge::add(const SphereContact& part, int triangle) {
  if (part.triangle < 0) return;  // nothing of this part within reach
  const double d = part.distance;
  // The parts' closest features tie when they are one seam vertex or edge: the same tolerance
  // and the same rules as between the triangles of one query (test_triangle): the same point's
  // faces join, and among features elsewhere as near within the tie the highest dimension decides.
  const double tie = 1e-12 + 1e-10 * d;
  const bool same_point = (part.point - point_).squaredNorm() <= tie * tie;
  if (d < d_min_ - tie || (d <= d_min_ + tie && part.side_dim > dim_ && !same_point)) {
    side_ = Vec3::Zero();
    point_ = part.point;
    d_min_ = d;
    triangle_ = triangle;
    fallback_ = part.normal;
    dim_ = part.side_dim;
  }
  if (d <= d_min_ + tie && (part.point - point_).squaredNorm() <= tie * tie) {
    side_ += part.side_sum;
    dim_ = std::max(dim_, part.side_dim);
    if (d < d_min_) {
      d_min_ = d;
      point_ = part.point;
      triangle_ = triangle;
      fallback_ = part.normal;
    }
  }
  normal_sum_ += part.normal_sum;
  weight_ += part.weight_sum;
  touching_ += part.num_touching;
}

SphereContact SphereContactMerge::result(const Vec3& centre, double radius) const {
  Accumulator acc;
  acc.d_min = d_min_;
  acc.point = point_;
  acc.triangle = triangle_;
  acc.pseudo_normal = side_;
  acc.dim = dim_;
  acc.weighted_normal = normal_sum_;
  acc.weight_sum = weight_;
  acc.touching = touching_;
  return decide(acc, fallback_, centre, radius);
}

void AabbTree::query_spheres(const TriangleMesh& mesh, std::span<const Vec3> centres,
                             std::span<const double> radii, std::span<SphereContact> out,
                             const SphereQuerySettings& settings) const {
  assert(radii.size() == 1 || radii.size() == centres.size());
  assert(out.size() >= centres.size());
  const bool one_radius = radii.size() == 1;
  for (std::size_t i = 0; i < centres.size(); ++i)
    out[i] = query_sphere(mesh, centres[i], one_radius ? radii[0] : radii[i], settings);
}

}  // namespace vcsim
