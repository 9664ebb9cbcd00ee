// Centrelines computed from a lumen mesh (docs/anatomy.md, "Centrelines from a mesh"): the
// level-set method of Lazarus and Verroust ("Level set diagrams of polyhedral objects", ACM
// Solid Modeling 1999): the geodesic distance over the surface from the inlet is cut into bands;
// each connected piece of a band is a ring around the vessel, its centroid a centreline point;
// where a band's ring meets two or more rings of the next band the vessel branches.
#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <queue>
#include <string>

#include "vcsim/anatomy.h"
#include "vcsim/collision.h"

namespace vcsim {

namespace {

struct UnionFind {
  std::vector<int> p;
  explicit UnionFind(int n) : p(static_cast<std::size_t>(n)) { std::iota(p.begin(), p.end(), 0); }
  int find(int a) {
    while (p[static_cast<std::size_t>(a)] != a) {
      p[static_cast<std::size_t>(a)] = p[static_cast<std::size_t>(p[static_cast<std::size_t>(a)])];
      a = p[static_cast<std::size_t>(a)];
    }
    return a;
  }
  void join(int a, int b) { p[static_cast<std::size_t>(find(a))] = find(b); }
};

std::uint64_t edge_key(int a, int b) {
  if (a > b) std::swap(a, b);
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(a)) << 32) |
         static_cast<std::uint32_t>(b);
}

struct Ring {
  int band = 0;
  Vec3 centre = Vec3::Zero();
  double area = 0.0;
  double radius = 0.0;
  bool open = false;          // holds boundary edges (an open end of the mesh)
  std::vector<int> next;      // rings of the next bands it touches
  std::vector<int> vertices;  // its triangles' vertices
};

}  // namespace

VesselTree centrelines_from_mesh(const TriangleMesh& mesh, const Vec3& inlet_near,
                                 const std::string& source, double band) {
  const int nv = mesh.num_vertices();
  const int nt = mesh.num_triangles();
  if (nt < 8)
    throw InputError(source, "mesh",
                     "expected a lumen mesh (got " + std::to_string(nt) + " triangles)");
  // Edges: their triangles (for boundary loops and triangle adjacency) and lengths.
  std::map<std::uint64_t, std::vector<int>> edge_tris;
  double longest = 0.0;
  for (int t = 0; t < nt; ++t) {
    const auto& tr = mesh.triangles[static_cast<std::size_t>(t)];
    for (int k = 0; k < 3; ++k) {
      const int a = tr[static_cast<std::size_t>(k)], b = tr[static_cast<std::size_t>((k + 1) % 3)];
      edge_tris[edge_key(a, b)].push_back(t);
      longest = std::max(longest, (mesh.vertices[static_cast<std::size_t>(a)] -
                                   mesh.vertices[static_cast<std::size_t>(b)])
                                      .norm());
    }
  }
  // Boundary vertices, grouped into loops (open ends).
  UnionFind loops(nv);
  std::vector<unsigned char> boundary(static_cast<std::size_t>(nv), 0);
  for (const auto& [key, tris] : edge_tris) {
    if (tris.size() != 1) continue;
    const int a = static_cast<int>(key >> 32), b = static_cast<int>(key & 0xffffffffu);
    boundary[static_cast<std::size_t>(a)] = boundary[static_cast<std::size_t>(b)] = 1;
    loops.join(a, b);
  }
  // The inlet: the open end whose loop passes nearest `inlet_near`.
  int inlet_root = -1;
  double best = std::numeric_limits<double>::infinity();
  for (int v = 0; v < nv; ++v) {
    if (!boundary[static_cast<std::size_t>(v)]) continue;
    const double d = (mesh.vertices[static_cast<std::size_t>(v)] - inlet_near).norm();
    if (d < best) {
      best = d;
      inlet_root = loops.find(v);
    }
  }
  if (inlet_root < 0)
    throw InputError(source, "mesh",
                     "expected an open end to start the centrelines from (the mesh is closed)");
  // Geodesic distance along edges from the inlet loop (Dijkstra).
  std::vector<std::vector<std::pair<int, double>>> adj(static_cast<std::size_t>(nv));
  for (const auto& [key, tris] : edge_tris) {
    const int a = static_cast<int>(key >> 32), b = static_cast<int>(key & 0xffffffffu);
    const double l =
        (mesh.vertices[static_cast<std::size_t>(a)] - mesh.vertices[static_cast<std::size_t>(b)])
            .norm();
    adj[static_cast<std::size_t>(a)].push_back({b, l});
    adj[static_cast<std::size_t>(b)].push_back({a, l});
  }
  std::vector<double> g(static_cast<std::size_t>(nv), std::numeric_limits<double>::infinity());
  using Item = std::pair<double, int>;
  std::priority_queue<Item, std::vector<Item>, std::greater<>> q;
  for (int v = 0; v < nv; ++v)
    if (boundary[static_cast<std::size_t>(v)] && loops.find(v) == inlet_root) {
      g[static_cast<std::size_t>(v)] = 0.0;
      q.push({0.0, v});
    }
  while (!q.empty()) {
    const auto [d, v] = q.top();
    q.pop();
    if (d > g[static_cast<std::size_t>(v)]) continue;
    for (const auto& [w, l] : adj[static_cast<std::size_t>(v)])
      if (d + l < g[static_cast<std::size_t>(w)]) {
        g[static_cast<std::size_t>(w)] = d + l;
        q.push({d + l, w});
      }
  }
  // Bands at least 1.5 edge lengths wide, so that a band's triangles close round the vessel.
  const double h = std::max(band, 1.5 * longest);
  std::vector<int> tband(static_cast<std::size_t>(nt), -1);
  for (int t = 0; t < nt; ++t) {
    const auto& tr = mesh.triangles[static_cast<std::size_t>(t)];
    const double gc = (g[static_cast<std::size_t>(tr[0])] + g[static_cast<std::size_t>(tr[1])] +
                       g[static_cast<std::size_t>(tr[2])]) /
                      3.0;
    if (std::isfinite(gc)) tband[static_cast<std::size_t>(t)] = static_cast<int>(gc / h);
  }
  // Rings: triangles of one band joined across shared edges.
  UnionFind rings_uf(nt);
  for (const auto& [key, tris] : edge_tris)
    for (std::size_t i = 1; i < tris.size(); ++i)
      if (tband[static_cast<std::size_t>(tris[0])] == tband[static_cast<std::size_t>(tris[i])])
        rings_uf.join(tris[0], tris[i]);
  std::map<int, int> ring_of_root;
  std::vector<Ring> rings;
  std::vector<int> tring(static_cast<std::size_t>(nt), -1);
  for (int t = 0; t < nt; ++t) {
    if (tband[static_cast<std::size_t>(t)] < 0) continue;
    const int r = rings_uf.find(t);
    auto [it, fresh] = ring_of_root.emplace(r, static_cast<int>(rings.size()));
    if (fresh) {
      rings.push_back({});
      rings.back().band = tband[static_cast<std::size_t>(t)];
    }
    tring[static_cast<std::size_t>(t)] = it->second;
    Ring& ring = rings[static_cast<std::size_t>(it->second)];
    const auto& tr = mesh.triangles[static_cast<std::size_t>(t)];
    const Vec3 a = mesh.vertices[static_cast<std::size_t>(tr[0])];
    const Vec3 b = mesh.vertices[static_cast<std::size_t>(tr[1])];
    const Vec3 c = mesh.vertices[static_cast<std::size_t>(tr[2])];
    const double area = 0.5 * (b - a).cross(c - a).norm();
    ring.centre += area * (a + b + c) / 3.0;
    ring.area += area;
    for (int k : tr) ring.vertices.push_back(k);
  }
  for (Ring& r : rings) {
    if (r.area > 0.0) r.centre /= r.area;
    std::sort(r.vertices.begin(), r.vertices.end());
    r.vertices.erase(std::unique(r.vertices.begin(), r.vertices.end()), r.vertices.end());
    double sum = 0.0;
    for (int v : r.vertices) {
      sum += (mesh.vertices[static_cast<std::size_t>(v)] - r.centre).norm();
      if (boundary[static_cast<std::size_t>(v)]) r.open = true;
    }
    r.radius = r.vertices.empty() ? 0.0 : sum / static_cast<double>(r.vertices.size());
  }
  // Ring adjacency to later bands across shared edges.
  for (const auto& [key, tris] : edge_tris)
    for (std::size_t i = 0; i < tris.size(); ++i)
      for (std::size_t j = 0; j < tris.size(); ++j) {
        const int ra = tring[static_cast<std::size_t>(tris[i])];
        const int rb = tring[static_cast<std::size_t>(tris[j])];
        if (ra < 0 || rb < 0 || ra == rb) continue;
        if (rings[static_cast<std::size_t>(rb)].band > rings[static_cast<std::size_t>(ra)].band) {
          auto& nx = rings[static_cast<std::size_t>(ra)].next;
          if (std::find(nx.begin(), nx.end(), rb) == nx.end()) nx.push_back(rb);
        }
      }
  // The inlet's ring: the band-0 ring holding the inlet loop.
  int start = -1;
  for (std::size_t i = 0; i < rings.size(); ++i)
    if (rings[i].band == 0 &&
        (start < 0 || rings[i].area > rings[static_cast<std::size_t>(start)].area))
      start = static_cast<int>(i);
  if (start < 0) throw InputError(source, "mesh", "expected a lumen around the inlet");

  // Walk the ring graph from the inlet: a ring with one later ring continues its segment; with
  // two or more, each starts a child segment at the branching ring's centre.
  VesselTree tree;
  tree.name = "centrelines of " + source;
  tree.open_start = true;
  std::vector<unsigned char> seen(rings.size(), 0);
  struct Todo {
    int ring, parent;
    Vec3 from;
    bool has_from;
  };
  std::vector<Todo> todo = {{start, -1, Vec3::Zero(), false}};
  while (!todo.empty()) {
    Todo td = todo.back();
    todo.pop_back();
    VesselSegment seg;
    seg.kind = VesselKind::kArtery;
    seg.parent = td.parent;
    if (td.has_from) {
      seg.points.push_back(td.from);
      seg.radii.push_back(rings[static_cast<std::size_t>(td.ring)].radius);
    }
    int r = td.ring;
    std::vector<int> children;
    std::vector<int> seg_rings;
    for (;;) {
      seen[static_cast<std::size_t>(r)] = 1;
      const Ring& ring = rings[static_cast<std::size_t>(r)];
      seg.points.push_back(ring.centre);
      seg.radii.push_back(ring.radius);
      seg_rings.push_back(r);
      std::vector<int> nx;
      for (int k : ring.next)
        if (!seen[static_cast<std::size_t>(k)]) nx.push_back(k);
      if (nx.size() == 1) {
        r = nx[0];
        continue;
      }
      children = nx;
      seg.closed_end = nx.empty() && !ring.open;
      break;
    }
    // Each ring's radius about the centreline (its vertices spread along the axis too).
    const std::size_t off = seg.points.size() - seg_rings.size();
    for (std::size_t k = 0; k < seg_rings.size(); ++k) {
      const std::size_t pk = off + k;
      const Vec3 a = seg.points[pk > 0 ? pk - 1 : pk];
      const Vec3 b = seg.points[pk + 1 < seg.points.size() ? pk + 1 : pk];
      if ((b - a).norm() <= 0.0) continue;
      const Vec3 t = (b - a).normalized();
      const Ring& ring = rings[static_cast<std::size_t>(seg_rings[k])];
      double sum = 0.0;
      for (int v : ring.vertices) {
        const Vec3 d = mesh.vertices[static_cast<std::size_t>(v)] - ring.centre;
        sum += (d - d.dot(t) * t).norm();
      }
      if (!ring.vertices.empty()) seg.radii[pk] = sum / static_cast<double>(ring.vertices.size());
    }
    if (td.has_from && seg.radii.size() > 1) seg.radii[0] = seg.radii[1];
    // A single ring is not a vessel.
    if (seg.points.size() < 2) continue;
    const int index = tree.num_segments();
    seg.name = index == 0 ? "inlet" : "branch_" + std::to_string(index);
    const Vec3 end = seg.points.back();
    tree.segments.push_back(std::move(seg));
    for (int c : children) todo.push_back({c, index, end, true});
  }
  // Leaves shorter than twice their parent's end radius are the ragged rings of a cut end or a
  // saddle: dropped, and a segment left with one child continues into it.
  for (bool changed = true; changed;) {
    changed = false;
    const int n = tree.num_segments();
    std::vector<int> kids(static_cast<std::size_t>(n), 0);
    for (const VesselSegment& s : tree.segments)
      if (s.parent >= 0) ++kids[static_cast<std::size_t>(s.parent)];
    for (int i = n - 1; i > 0 && !changed; --i) {
      const VesselSegment& s = tree.segments[static_cast<std::size_t>(i)];
      const VesselSegment& p = tree.segments[static_cast<std::size_t>(s.parent)];
      if (kids[static_cast<std::size_t>(i)] == 0 && segment_length(s) < 2.0 * p.radii.back()) {
        tree.segments.erase(tree.segments.begin() + i);
        for (VesselSegment& o : tree.segments)
          if (o.parent > i) --o.parent;
        changed = true;
      }
    }
    if (changed) continue;
    for (int i = 0; i < n && !changed; ++i) {
      if (kids[static_cast<std::size_t>(i)] != 1) continue;
      int c = -1;
      for (int k = 0; k < n; ++k)
        if (tree.segments[static_cast<std::size_t>(k)].parent == i) c = k;
      VesselSegment& p = tree.segments[static_cast<std::size_t>(i)];
      VesselSegment child = tree.segments[static_cast<std::size_t>(c)];
      p.points.insert(p.points.end(), child.points.begin() + 1, child.points.end());
      p.radii.insert(p.radii.end(), child.radii.begin() + 1, child.radii.end());
      p.closed_end = child.closed_end;
      tree.segments.erase(tree.segments.begin() + c);
      for (VesselSegment& o : tree.segments) {
        if (o.parent == c) o.parent = i;
        if (o.parent > c) --o.parent;
      }
      changed = true;
    }
  }
  for (int i = 0; i < tree.num_segments(); ++i)
    tree.segments[static_cast<std::size_t>(i)].name =
        i == 0 ? "inlet" : "branch_" + std::to_string(i);
  // Light smoothing of interior points (the rings' centroids scatter by a fraction of a band).
  for (VesselSegment& s : tree.segments) {
    std::vector<Vec3> p = s.points;
    for (std::size_t k = 1; k + 1 < p.size(); ++k)
      s.points[k] = 0.25 * p[k - 1] + 0.5 * p[k] + 0.25 * p[k + 1];
  }
  const double root_len = segment_length(tree.segments[0]);
  tree.access = {0, std::min(2e-3, 0.25 * root_len)};
  tree.target = {tree.num_segments() - 1, 0.5 * segment_length(tree.segments.back())};
  validate_tree(tree, source);
  return tree;
}

}  // namespace vcsim
