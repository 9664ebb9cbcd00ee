// TreeLocator: locate() through a bounding-volume hierarchy of the centreline edges
// (docs/anatomy.md, "Where things are in the tree").
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "vcsim/anatomy.h"

namespace vcsim {

namespace {

constexpr int kLeafEdges = 4;
constexpr int kMaxDepth = 64;  // median splits: depth about log2(edges / kLeafEdges) + 1

// Rounding in an edge's distance is about 1e-16 of the coordinates (under a metre): a bound lowered
// by a nanometre can never skip an edge whose computed distance ties or beats the best.
constexpr double kBoundSlack = 1e-9;

double distance_to_box(const Aabb& b, const Vec3& p) {
  const Vec3 d = (b.lo - p).cwiseMax(p - b.hi).cwiseMax(0.0);
  return d.norm();
}

}  // namespace

TreeLocator::TreeLocator(const VesselTree& tree) {
  for (int si = 0; si < tree.num_segments(); ++si) {
    const VesselSegment& seg = tree.segments[si];
    double s0 = 0.0;
    // The same arithmetic as locate()'s search, in the same order (s0 accumulates edge by edge).
    for (std::size_t k = 0; k + 1 < seg.points.size(); ++k) {
      Edge e;
      e.a = seg.points[k];
      e.d = seg.points[k + 1] - e.a;
      e.len2 = e.d.squaredNorm();
      e.len = std::sqrt(e.len2);
      e.s0 = s0;
      e.r0 = seg.radii[k];
      e.dr = seg.radii[k + 1] - seg.radii[k];
      e.segment = si;
      edges_.push_back(e);
      s0 += e.len;
    }
  }
  order_.resize(edges_.size());
  std::iota(order_.begin(), order_.end(), 0);
  if (edges_.empty()) return;
  // Median splits along the longest axis of the edges' midpoints: a balanced tree.
  std::vector<Vec3> mid(edges_.size());
  for (std::size_t i = 0; i < edges_.size(); ++i) mid[i] = edges_[i].a + 0.5 * edges_[i].d;
  std::vector<int> idx = order_;
  nodes_.reserve(2 * edges_.size() / kLeafEdges + 2);
  nodes_.push_back({});
  struct Job {
    int node, first, count;
  };
  std::vector<Job> jobs{{0, 0, static_cast<int>(idx.size())}};
  while (!jobs.empty()) {
    const Job j = jobs.back();
    jobs.pop_back();
    Node& n = nodes_[static_cast<std::size_t>(j.node)];
    n.box.lo = Vec3::Constant(std::numeric_limits<double>::infinity());
    n.box.hi = -n.box.lo;
    n.r_max = 0.0;
    Aabb centres{n.box.lo, n.box.hi};
    for (int i = j.first; i < j.first + j.count; ++i) {
      const Edge& e = edges_[static_cast<std::size_t>(idx[static_cast<std::size_t>(i)])];
      const Vec3 b = e.a + e.d;
      n.box.lo = n.box.lo.cwiseMin(e.a).cwiseMin(b);
      n.box.hi = n.box.hi.cwiseMax(e.a).cwiseMax(b);
      n.r_max = std::max({n.r_max, e.r0, e.r0 + e.dr});
      const Vec3& m = mid[static_cast<std::size_t>(idx[static_cast<std::size_t>(i)])];
      centres.lo = centres.lo.cwiseMin(m);
      centres.hi = centres.hi.cwiseMax(m);
    }
    if (j.count <= kLeafEdges) {
      n.first = j.first;
      n.count = j.count;
      continue;
    }
    int axis = 0;
    (centres.hi - centres.lo).maxCoeff(&axis);
    const int half = j.count / 2;
    auto* b = idx.data() + j.first;
    std::nth_element(b, b + half, b + j.count, [&](int x, int y) {
      return mid[static_cast<std::size_t>(x)][axis] < mid[static_cast<std::size_t>(y)][axis];
    });
    const int left = static_cast<int>(nodes_.size());
    n.first = left;
    n.count = 0;
    nodes_.push_back({});
    nodes_.push_back({});
    jobs.push_back({left, j.first, half});
    jobs.push_back({left + 1, j.first + half, j.count - half});
  }
  // Edges stored in leaf order, each remembering its place in the brute-force order.
  std::vector<Edge> sorted(edges_.size());
  for (std::size_t i = 0; i < idx.size(); ++i) {
    sorted[i] = edges_[static_cast<std::size_t>(idx[i])];
    order_[i] = idx[i];
  }
  edges_ = std::move(sorted);
}

TreeHit TreeLocator::locate(const Vec3& p) const {
  TreeHit best;
  best.outside = std::numeric_limits<double>::infinity();
  if (nodes_.empty()) return best;
  int best_order = std::numeric_limits<int>::max();
  int stack[kMaxDepth];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& n = nodes_[static_cast<std::size_t>(stack[--top])];
    // Every edge below lies in the box with a radius at most r_max: none is nearer than this.
    if (distance_to_box(n.box, p) - n.r_max - kBoundSlack > best.outside) continue;
    if (n.count > 0) {
      for (int i = n.first; i < n.first + n.count; ++i) {
        const Edge& e = edges_[static_cast<std::size_t>(i)];
        const double t = e.len2 > 0.0 ? std::clamp((p - e.a).dot(e.d) / e.len2, 0.0, 1.0) : 0.0;
        const double r = e.r0 + t * e.dr;
        const double out = (p - (e.a + t * e.d)).norm() - r;
        const int o = order_[static_cast<std::size_t>(i)];
        // (A tie with nothing found yet, an infinite distance, is no hit: locate() keeps none.)
        if (out < best.outside ||
            (out == best.outside && best.loc.segment >= 0 && o < best_order)) {
          best.outside = out;
          best.loc = {e.segment, e.s0 + t * e.len};
          best_order = o;
        }
      }
      continue;
    }
    // The nearer child last on the stack, so it is searched first and tightens the bound.
    const int l = n.first, r = n.first + 1;
    const bool left_first = distance_to_box(nodes_[static_cast<std::size_t>(l)].box, p) <=
                            distance_to_box(nodes_[static_cast<std::size_t>(r)].box, p);
    stack[top++] = left_first ? r : l;
    stack[top++] = left_first ? l : r;
  }
  return best;
}

}  // namespace vcsim
