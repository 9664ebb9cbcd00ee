// Mesh checks and repair: degenerate triangles, manifoldness, consistent orientation and
// lumen-facing normals. Runs once when a mesh enters the engine (file import or generator).
#include "vcsim/collision.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <numbers>
#include <sstream>

namespace vcsim {

namespace {

std::string str(const Vec3& p) {
  std::ostringstream os;
  os << "(" << p.x() << ", " << p.y() << ", " << p.z() << ")";
  return os.str();
}

// One triangle side, keyed by its undirected edge so that sorting groups the sides of an edge.
struct Side {
  std::uint64_t key;  // (min vertex << 32) | max vertex
  int tri;
  int slot;  // edge slot k: from triangles[tri][k] to triangles[tri][(k + 1) % 3]
};

std::uint64_t edge_key(int u, int v) {
  const auto lo = static_cast<std::uint64_t>(std::min(u, v));
  const auto hi = static_cast<std::uint64_t>(std::max(u, v));
  return (lo << 32) | hi;
}

void flip(std::array<int, 3>& t) {
  std::swap(t[1], t[2]);
}

// Drops repeated-index and zero-area triangles. Zero area is judged relative to the longest
// edge, so that the test does not depend on the unit or size of the mesh.
int remove_degenerate(TriangleMesh& m) {
  const auto before = m.triangles.size();
  std::erase_if(m.triangles, [&](const std::array<int, 3>& t) {
    if (t[0] == t[1] || t[1] == t[2] || t[2] == t[0]) return true;
    const Vec3& a = m.vertices[t[0]];
    const Vec3& b = m.vertices[t[1]];
    const Vec3& c = m.vertices[t[2]];
    const double e2 =
        std::max({(b - a).squaredNorm(), (c - b).squaredNorm(), (a - c).squaredNorm()});
    return (b - a).cross(c - a).norm() <= 1e-12 * e2;
  });
  return static_cast<int>(before - m.triangles.size());
}

// Drops repeated triangles (same three vertices, either winding): a copy would make its edges
// non-manifold, and a copy with the other winding a zero-volume pocket. Keeps the first.
int remove_duplicates(TriangleMesh& m) {
  std::vector<std::pair<std::array<int, 3>, int>> keyed(m.triangles.size());
  for (std::size_t t = 0; t < m.triangles.size(); ++t) {
    auto k = m.triangles[t];
    std::sort(k.begin(), k.end());
    keyed[t] = {k, static_cast<int>(t)};
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<char> drop(m.triangles.size(), 0);
  for (std::size_t i = 1; i < keyed.size(); ++i)
    if (keyed[i].first == keyed[i - 1].first) drop[keyed[i].second] = 1;
  std::size_t next = 0;
  for (std::size_t t = 0; t < m.triangles.size(); ++t)
    if (!drop[t]) m.triangles[next++] = m.triangles[t];
  const auto removed = static_cast<int>(m.triangles.size() - next);
  m.triangles.resize(next);
  return removed;
}

int remove_unused_vertices(TriangleMesh& m) {
  std::vector<int> remap(m.vertices.size(), -1);
  for (const auto& t : m.triangles)
    for (int v : t) remap[v] = 0;
  int next = 0;
  for (std::size_t v = 0; v < remap.size(); ++v) {
    if (remap[v] < 0) continue;
    remap[v] = next;
    m.vertices[next++] = m.vertices[v];
  }
  const int removed = static_cast<int>(m.vertices.size()) - next;
  m.vertices.resize(next);
  for (auto& t : m.triangles)
    for (int& v : t) v = remap[v];
  return removed;
}

// Finite coordinates and vertex indices in range, or an InputError naming the first bad one.
void check_indices_and_coordinates(const TriangleMesh& m, const std::string& source) {
  const int nv = m.num_vertices();
  for (int v = 0; v < nv; ++v) {
    if (!m.vertices[v].allFinite())
      throw InputError(source, "vertex " + std::to_string(v),
                       "finite coordinates, got " + str(m.vertices[v]));
  }
  for (int t = 0; t < m.num_triangles(); ++t) {
    for (int v : m.triangles[t]) {
      if (v < 0 || v >= nv)
        throw InputError(
            source, "triangle " + std::to_string(t),
            "vertex indices in [0, " + std::to_string(nv) + "), got " + std::to_string(v));
    }
  }
}

}  // namespace

std::string MeshReport::summary() const {
  std::ostringstream os;
  os << vertices << " vertices, " << triangles << " triangles, " << components << " component(s)\n";
  os << boundary_loops.size() << " open boundary loop(s) (" << boundary_edges << " edges)\n";
  if (degenerate_removed) os << degenerate_removed << " degenerate triangle(s) removed\n";
  if (duplicates_removed) os << duplicates_removed << " duplicate triangle(s) removed\n";
  if (unused_vertices_removed) os << unused_vertices_removed << " unused vertices removed\n";
  if (flipped_for_consistency)
    os << flipped_for_consistency << " triangle(s) flipped for consistent orientation\n";
  if (flipped_for_lumen) os << flipped_for_lumen << " triangle(s) flipped to face the lumen\n";
  for (std::size_t c = 0; c < component_volumes.size(); ++c)
    os << "component " << c << ": lumen volume " << component_volumes[c] << " m^3\n";
  return os.str();
}

MeshReport check_and_repair(TriangleMesh& m, const std::string& source) {
  MeshReport r;

  // 1. Indices and coordinates.
  check_indices_and_coordinates(m, source);

  // 2. Degenerate triangles and unused vertices.
  r.degenerate_removed = remove_degenerate(m);
  r.duplicates_removed = remove_duplicates(m);
  if (m.triangles.empty())
    throw InputError(source, "triangles", "at least one triangle with non-zero area");
  r.unused_vertices_removed = remove_unused_vertices(m);
  const int nt = m.num_triangles();

  // 3. Edge adjacency by sorting triangle sides; more than two sides on an edge is an error.
  std::vector<Side> sides;
  sides.reserve(3 * static_cast<std::size_t>(nt));
  for (int t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k)
      sides.push_back({edge_key(m.triangles[t][k], m.triangles[t][(k + 1) % 3]), t, k});
  std::sort(sides.begin(), sides.end(), [](const Side& a, const Side& b) {
    return a.key != b.key ? a.key < b.key : a.tri < b.tri;
  });
  // neighbour[3 t + k]: triangle across side k (-1 on a boundary); same_dir: both triangles run
  // the shared edge the same way, i.e. their orientations disagree.
  std::vector<int> neighbour(3 * static_cast<std::size_t>(nt), -1);
  std::vector<char> same_dir(3 * static_cast<std::size_t>(nt), 0);
  std::vector<Side> boundary;
  int non_manifold = 0;
  std::uint64_t first_bad = 0;
  for (std::size_t i = 0; i < sides.size();) {
    std::size_t j = i + 1;
    while (j < sides.size() && sides[j].key == sides[i].key) ++j;
    if (j - i == 1) {
      boundary.push_back(sides[i]);
    } else if (j - i == 2) {
      const Side& a = sides[i];
      const Side& b = sides[i + 1];
      const bool same = m.triangles[a.tri][a.slot] == m.triangles[b.tri][b.slot];
      neighbour[3 * a.tri + a.slot] = b.tri;
      neighbour[3 * b.tri + b.slot] = a.tri;
      same_dir[3 * a.tri + a.slot] = same_dir[3 * b.tri + b.slot] = same;
    } else {
      if (non_manifold++ == 0) first_bad = sides[i].key;
    }
    i = j;
  }
  if (non_manifold > 0) {
    const int u = static_cast<int>(first_bad >> 32);
    const int v = static_cast<int>(first_bad & 0xffffffffu);
    throw InputError(source, "edges",
                     "a manifold surface (each edge shared by at most two triangles); " +
                         std::to_string(non_manifold) + " edge(s) are shared by more, the first " +
                         "between vertices " + std::to_string(u) + " " + str(m.vertices[u]) +
                         " and " + std::to_string(v) + " " + str(m.vertices[v]) +
                         "; run 'vcsim anatomy repair IN OUT' to keep two triangles on each");
  }

  // 4. Consistent orientation: flood fill from a seed per component, deciding for each
  // neighbour whether it must be flipped relative to the seed. A contradiction means the
  // component is not orientable.
  std::vector<int> comp(nt, -1);
  std::vector<char> flip_rel(nt, 0);
  std::vector<int> members;
  std::vector<std::vector<int>> comp_members;
  std::deque<int> queue;
  for (int seed = 0; seed < nt; ++seed) {
    if (comp[seed] >= 0) continue;
    const int c = r.components++;
    members.clear();
    comp[seed] = c;
    queue.push_back(seed);
    while (!queue.empty()) {
      const int t = queue.front();
      queue.pop_front();
      members.push_back(t);
      for (int k = 0; k < 3; ++k) {
        const int u = neighbour[3 * t + k];
        if (u < 0) continue;
        const char want = static_cast<char>(flip_rel[t] ^ same_dir[3 * t + k]);
        if (comp[u] < 0) {
          comp[u] = c;
          flip_rel[u] = want;
          queue.push_back(u);
        } else if (flip_rel[u] != want) {
          throw InputError(source, "orientation",
                           "an orientable surface; the component containing triangle " +
                               std::to_string(seed) + " cannot be oriented consistently " +
                               "(Moebius-like)");
        }
      }
    }
    // Flip the minority, so that the count says how many triangles were wrong.
    const auto n_rel =
        std::count_if(members.begin(), members.end(), [&](int t) { return flip_rel[t] != 0; });
    const bool invert = 2 * n_rel > static_cast<long>(members.size());
    for (int t : members) {
      if ((flip_rel[t] != 0) != invert) {
        flip(m.triangles[t]);
        ++r.flipped_for_consistency;
      }
    }
    comp_members.push_back(members);
  }

  // Boundary loops from the now consistently directed boundary sides.
  struct Directed {
    int from, to;
  };
  std::vector<Directed> bedges;
  bedges.reserve(boundary.size());
  for (const Side& s : boundary) {
    const auto& t = m.triangles[s.tri];
    for (int k = 0; k < 3; ++k) {
      if (edge_key(t[k], t[(k + 1) % 3]) == s.key) bedges.push_back({t[k], t[(k + 1) % 3]});
    }
  }
  r.boundary_edges = static_cast<int>(bedges.size());
  std::sort(bedges.begin(), bedges.end(), [](const Directed& a, const Directed& b) {
    return a.from != b.from ? a.from < b.from : a.to < b.to;
  });
  std::vector<char> used(bedges.size(), 0);
  auto next_unused = [&](int from) -> int {
    auto it = std::lower_bound(bedges.begin(), bedges.end(), from,
                               [](const Directed& e, int f) { return e.from < f; });
    for (; it != bedges.end() && it->from == from; ++it) {
      const auto idx = static_cast<std::size_t>(it - bedges.begin());
      if (!used[idx]) return static_cast<int>(idx);
    }
    return -1;
  };
  std::vector<int> loop_comp;
  for (std::size_t e = 0; e < bedges.size(); ++e) {
    if (used[e]) continue;
    std::vector<int> loop;
    int cur = static_cast<int>(e);
    while (cur >= 0) {
      used[cur] = 1;
      loop.push_back(bedges[cur].from);
      if (bedges[cur].to == loop.front()) break;
      cur = next_unused(bedges[cur].to);
    }
    r.boundary_loops.push_back(std::move(loop));
  }
  // Vertex -> component, for assigning loops (boundary vertices lie in one component).
  std::vector<int> vcomp(m.vertices.size(), -1);
  for (int t = 0; t < nt; ++t)
    for (int v : m.triangles[t]) vcomp[v] = comp[t];

  // 5. Lumen orientation. Volume of each component closed with a fan cap from the centroid of
  // each boundary loop: sum over triangles of a . (b x c) / 6 (divergence theorem), positive
  // for outward normals. Coordinates relative to the mesh centroid limit cancellation.
  Vec3 origin = Vec3::Zero();
  for (const Vec3& p : m.vertices) origin += p;
  origin /= static_cast<double>(m.vertices.size());
  auto rel = [&](int v) -> Vec3 { return m.vertices[v] - origin; };
  std::vector<double> outward(r.components, 0.0);
  for (int t = 0; t < nt; ++t) {
    const auto& tri = m.triangles[t];
    outward[comp[t]] += rel(tri[0]).dot(rel(tri[1]).cross(rel(tri[2]))) / 6.0;
  }
  for (const auto& loop : r.boundary_loops) {
    Vec3 centre = Vec3::Zero();
    for (int v : loop) centre += rel(v);
    centre /= static_cast<double>(loop.size());
    double cap = 0.0;
    for (std::size_t i = 0; i < loop.size(); ++i) {
      const int u = loop[i];
      const int v = loop[(i + 1) % loop.size()];
      cap += rel(v).dot(rel(u).cross(centre)) / 6.0;  // cap triangle (v, u, centre)
    }
    outward[vcomp[loop.front()]] += cap;
  }
  for (int c = 0; c < r.components; ++c) {
    if (outward[c] > 0.0) {
      for (int t : comp_members[c]) flip(m.triangles[t]);
      r.flipped_for_lumen += static_cast<int>(comp_members[c].size());
      for (auto& loop : r.boundary_loops)
        if (vcomp[loop.front()] == c) std::reverse(loop.begin(), loop.end());
    }
    r.component_volumes.push_back(std::abs(outward[c]));
  }

  // 6. Normals.
  m.recompute_normals();
  r.vertices = m.num_vertices();
  r.triangles = m.num_triangles();
  return r;
}

namespace {

// The sides of the kept triangles, grouped by undirected edge (sorted by key, then triangle).
std::vector<Side> sorted_sides(const TriangleMesh& m, const std::vector<char>& dropped) {
  std::vector<Side> sides;
  sides.reserve(3 * m.triangles.size());
  for (int t = 0; t < m.num_triangles(); ++t) {
    if (dropped[t]) continue;
    for (int k = 0; k < 3; ++k)
      sides.push_back({edge_key(m.triangles[t][k], m.triangles[t][(k + 1) % 3]), t, k});
  }
  std::sort(sides.begin(), sides.end(), [](const Side& a, const Side& b) {
    return a.key != b.key ? a.key < b.key : a.tri < b.tri;
  });
  return sides;
}

// How many sides each undirected edge has, looked up by key in the sorted sides.
int sides_on(const std::vector<Side>& sides, std::uint64_t key) {
  const auto lo = std::lower_bound(sides.begin(), sides.end(), key,
                                   [](const Side& s, std::uint64_t k) { return s.key < k; });
  auto hi = lo;
  while (hi != sides.end() && hi->key == key) ++hi;
  return static_cast<int>(hi - lo);
}

// Angle of triangle t's third vertex about the edge (u -> v), in [0, 2 pi): where its sheet
// leaves the edge.
double sheet_angle(const TriangleMesh& m, int t, int slot, const Vec3& axis, const Vec3& e1) {
  const Vec3& a = m.vertices[m.triangles[t][slot]];
  const Vec3& w = m.vertices[m.triangles[t][(slot + 2) % 3]];
  Vec3 d = w - a;
  d -= axis * axis.dot(d);
  const double ang = std::atan2(axis.cross(e1).dot(d), e1.dot(d));
  return ang < 0 ? ang + 2.0 * std::numbers::pi : ang;
}

}  // namespace

std::string MeshRepairReport::summary() const {
  std::ostringstream os;
  os << triangles_before << " triangles in, " << triangles_after << " out\n";
  os << non_manifold_edges << " non-manifold edge(s); " << non_manifold_dropped
     << " triangle(s) dropped so that each edge has at most two\n";
  if (degenerate_removed) os << degenerate_removed << " degenerate triangle(s) removed\n";
  if (duplicates_removed) os << duplicates_removed << " duplicate triangle(s) removed\n";
  if (components_dropped)
    os << components_dropped << " small component(s) dropped (" << component_triangles_dropped
       << " triangles)\n";
  if (unused_vertices_removed) os << unused_vertices_removed << " unused vertices removed\n";
  return os.str();
}

MeshRepairReport repair_mesh(TriangleMesh& m, const std::string& source,
                             const MeshRepairSettings& settings) {
  MeshRepairReport r;
  r.triangles_before = m.num_triangles();
  check_indices_and_coordinates(m, source);
  r.degenerate_removed = remove_degenerate(m);
  r.duplicates_removed = remove_duplicates(m);

  // Non-manifold edges. Dropping a triangle changes the counts on its other edges, so each pass
  // decides every crowded edge against the sides as they were, then passes repeat (a few).
  std::vector<char> dropped(m.triangles.size(), 0);
  for (int pass = 0; pass < 16; ++pass) {
    const std::vector<Side> sides = sorted_sides(m, dropped);
    bool any = false;
    for (std::size_t i = 0; i < sides.size();) {
      std::size_t j = i + 1;
      while (j < sides.size() && sides[j].key == sides[i].key) ++j;
      if (j - i <= 2) {
        i = j;
        continue;
      }
      if (pass == 0) ++r.non_manifold_edges;
      // The edge's frame: axis along it, e1 where the first sheet leaves it.
      const int u = static_cast<int>(sides[i].key >> 32);
      const int v = static_cast<int>(sides[i].key & 0xffffffffu);
      const Vec3 axis = (m.vertices[v] - m.vertices[u]).normalized();
      Vec3 e1 = m.vertices[m.triangles[sides[i].tri][(sides[i].slot + 2) % 3]] - m.vertices[u];
      e1 = (e1 - axis * axis.dot(e1)).normalized();
      // Per side: runs u -> v, how many of its other edges are manifold, its sheet's angle.
      struct Cand {
        int tri;
        bool forward;
        int embedded;
        double angle;
      };
      std::vector<Cand> cand;
      for (std::size_t s = i; s < j; ++s) {
        if (dropped[sides[s].tri]) continue;  // by another edge of this pass
        const auto& t = m.triangles[sides[s].tri];
        const int k = sides[s].slot;
        int embedded = 0;
        for (int o = 1; o < 3; ++o)
          if (sides_on(sides, edge_key(t[(k + o) % 3], t[(k + o + 1) % 3])) == 2) ++embedded;
        cand.push_back(
            {sides[s].tri, t[k] == u, embedded, sheet_angle(m, sides[s].tri, k, axis, e1)});
      }
      const std::size_t n = cand.size();
      if (n <= 2) {
        i = j;
        continue;
      }
      any = true;
      // The best pair: opposite windings (a consistently oriented surface), then the most
      // embedded, then the dihedral nearest a flat continuation (pi between the two sheets).
      double best = -1e300;
      std::size_t ba = 0, bb = 1;
      for (std::size_t a = 0; a < n; ++a) {
        for (std::size_t b = a + 1; b < n; ++b) {
          const double gap = std::abs(cand[a].angle - cand[b].angle);
          const double dihedral = std::min(gap, 2.0 * std::numbers::pi - gap);
          const double score = 100.0 * (cand[a].forward != cand[b].forward) +
                               10.0 * (cand[a].embedded + cand[b].embedded) + dihedral;
          if (score > best) best = score, ba = a, bb = b;
        }
      }
      for (std::size_t a = 0; a < n; ++a) {
        if (a == ba || a == bb) continue;
        dropped[cand[a].tri] = 1;
        ++r.non_manifold_dropped;
      }
      i = j;
    }
    if (!any) break;
  }

  // Small components: edge-connected over the kept triangles (union-find over shared edges).
  {
    const std::vector<Side> sides = sorted_sides(m, dropped);
    std::vector<int> parent(m.triangles.size());
    for (std::size_t t = 0; t < parent.size(); ++t) parent[t] = static_cast<int>(t);
    auto find = [&](int x) {
      while (parent[x] != x) x = parent[x] = parent[parent[x]];
      return x;
    };
    for (std::size_t s = 1; s < sides.size(); ++s)
      if (sides[s].key == sides[s - 1].key) parent[find(sides[s].tri)] = find(sides[s - 1].tri);
    std::vector<int> size(m.triangles.size(), 0);
    for (int t = 0; t < m.num_triangles(); ++t)
      if (!dropped[t]) ++size[find(t)];
    const int largest = *std::max_element(size.begin(), size.end());
    const double keep = settings.min_component_fraction * largest;
    for (int t = 0; t < m.num_triangles(); ++t) {
      if (dropped[t] || size[find(t)] >= keep) continue;
      if (find(t) == t) ++r.components_dropped;
      dropped[t] = 1;
      ++r.component_triangles_dropped;
    }
  }

  std::size_t next = 0;
  for (std::size_t t = 0; t < m.triangles.size(); ++t)
    if (!dropped[t]) m.triangles[next++] = m.triangles[t];
  m.triangles.resize(next);
  if (m.triangles.empty())
    throw InputError(source, "triangles", "at least one triangle left after repair");
  r.unused_vertices_removed = remove_unused_vertices(m);
  m.recompute_normals();
  r.triangles_after = m.num_triangles();
  return r;
}

std::vector<WallExit> mesh_exits(const TriangleMesh& mesh,
                                 const std::vector<std::vector<int>>& loops) {
  std::vector<WallExit> out;
  // Which loop each boundary vertex belongs to, and, per loop, the mean of the vertices of the
  // triangles touching it: a point on the mesh's side of the opening.
  std::vector<int> loop_of(mesh.vertices.size(), -1);
  for (std::size_t l = 0; l < loops.size(); ++l)
    for (int v : loops[l])
      if (v >= 0 && v < mesh.num_vertices())
        loop_of[static_cast<std::size_t>(v)] = static_cast<int>(l);
  std::vector<Vec3> side(loops.size(), Vec3::Zero());
  std::vector<int> side_count(loops.size(), 0);
  for (const auto& tri : mesh.triangles) {
    int l = -1;
    for (int v : tri)
      if (loop_of[static_cast<std::size_t>(v)] >= 0) l = loop_of[static_cast<std::size_t>(v)];
    if (l < 0) continue;
    for (int v : tri)
      side[static_cast<std::size_t>(l)] += mesh.vertices[static_cast<std::size_t>(v)];
    side_count[static_cast<std::size_t>(l)] += 3;
  }
  for (std::size_t l = 0; l < loops.size(); ++l) {
    const std::vector<int>& loop = loops[l];
    if (loop.size() < 3 || side_count[l] == 0 || std::any_of(loop.begin(), loop.end(), [&](int v) {
          return v < 0 || v >= mesh.num_vertices();
        }))
      continue;
    Vec3 centre = Vec3::Zero();
    for (int v : loop) centre += mesh.vertices[static_cast<std::size_t>(v)];
    centre /= static_cast<double>(loop.size());
    Vec3 n = Vec3::Zero();
    for (std::size_t i = 0; i < loop.size(); ++i) {
      const Vec3 a = mesh.vertices[static_cast<std::size_t>(loop[i])] - centre;
      const Vec3 b = mesh.vertices[static_cast<std::size_t>(loop[(i + 1) % loop.size()])] - centre;
      n += a.cross(b);
    }
    if (n.norm() <= 0.0) continue;
    n.normalize();
    const Vec3 inside = side[l] / static_cast<double>(side_count[l]);
    if (n.dot(centre - inside) < 0.0) n = -n;
    double radius = 0.0;
    for (int v : loop) {
      const Vec3 d = mesh.vertices[static_cast<std::size_t>(v)] - centre;
      radius = std::max(radius, (d - d.dot(n) * n).norm());
    }
    out.push_back({centre, n, radius});
  }
  return out;
}

}  // namespace vcsim
