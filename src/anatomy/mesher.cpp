// Lumen meshing: sparse marching tetrahedra, projection onto the exact surface, flat cuts at open
// ends, simplification and zipping of two meshes along a common circle.
#include "mesher.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <map>
#include <numbers>
#include <queue>
#include <unordered_map>

namespace vcsim::internal {

namespace {

constexpr int kBlock = 8;                             // cubes per block side
constexpr std::int64_t kOff = std::int64_t{1} << 19;  // lattice index offset (20 bits per axis)

std::uint64_t pack(std::int64_t i, std::int64_t j, std::int64_t k) {
  return (static_cast<std::uint64_t>(i + kOff) << 40) |
         (static_cast<std::uint64_t>(j + kOff) << 20) | static_cast<std::uint64_t>(k + kOff);
}

std::int64_t floor_div(double x, double h) {
  return static_cast<std::int64_t>(std::floor(x / h));
}

// The six tetrahedra of a cube around the diagonal 0-7 (corner bits: x = 1, y = 2, z = 4). Every
// tetrahedron is a chain 0 -> one bit -> two bits -> 7, so each edge joins a corner to a
// superset of its bits and neighbouring cubes split shared faces alike (Freudenthal/Kuhn).
constexpr int kTets[6][4] = {{0, 1, 3, 7}, {0, 3, 2, 7}, {0, 2, 6, 7},
                             {0, 6, 4, 7}, {0, 4, 5, 7}, {0, 5, 1, 7}};

}  // namespace

TriangleMesh marching_tetrahedra(const PieceGrid& field, double h) {
  const double bh = kBlock * h;
  const double half_diag = 0.5 * std::sqrt(3.0) * bh;
  // Blocks a piece's own surface can cross (the union's surface lies on the pieces' surfaces).
  std::vector<std::uint64_t> blocks;
  std::vector<std::array<std::int64_t, 3>> block_ijk;
  {
    std::vector<std::pair<std::uint64_t, std::array<std::int64_t, 3>>> cand;
    for (const Piece& pc : field.pieces()) {
      const double lip = piece_lipschitz(pc) * 1.05;
      const double r = std::max(pc.ra, pc.rb) + bh;
      const Vec3 lo = pc.a.cwiseMin(pc.b).array() - r, hi = pc.a.cwiseMax(pc.b).array() + r;
      for (auto i = floor_div(lo.x(), bh); i <= floor_div(hi.x(), bh); ++i)
        for (auto j = floor_div(lo.y(), bh); j <= floor_div(hi.y(), bh); ++j)
          for (auto k = floor_div(lo.z(), bh); k <= floor_div(hi.z(), bh); ++k) {
            const Vec3 c((static_cast<double>(i) + 0.5) * bh, (static_cast<double>(j) + 0.5) * bh,
                         (static_cast<double>(k) + 0.5) * bh);
            if (std::abs(eval_piece(pc, c).f) <= half_diag * lip)
              cand.push_back({pack(i, j, k), {i, j, k}});
          }
    }
    std::sort(cand.begin(), cand.end(), [](auto& x, auto& y) { return x.first < y.first; });
    for (std::size_t n = 0; n < cand.size(); ++n) {
      if (n > 0 && cand[n].first == cand[n - 1].first) continue;
      blocks.push_back(cand[n].first);
      block_ijk.push_back(cand[n].second);
    }
  }

  TriangleMesh m;
  std::unordered_map<std::uint64_t, int> edge_vertex;
  edge_vertex.reserve(blocks.size() * 256);
  constexpr int S = kBlock + 1;
  std::vector<double> val(S * S * S);
  const double tiny = 1e-3 * h;  // no sample exactly on the surface: keeps the output manifold

  for (const auto& b : block_ijk) {
    const std::int64_t i0 = b[0] * kBlock, j0 = b[1] * kBlock, k0 = b[2] * kBlock;
    for (int k = 0; k < S; ++k)
      for (int j = 0; j < S; ++j)
        for (int i = 0; i < S; ++i) {
          const Vec3 p(static_cast<double>(i0 + i) * h, static_cast<double>(j0 + j) * h,
                       static_cast<double>(k0 + k) * h);
          double f = field.eval(p).f;
          if (f >= 0.0)
            f = std::max(f, tiny);
          else
            f = std::min(f, -tiny);
          val[(k * S + j) * S + i] = f;
        }
    for (int k = 0; k < kBlock; ++k)
      for (int j = 0; j < kBlock; ++j)
        for (int i = 0; i < kBlock; ++i) {
          double f[8];
          int inside = 0;
          for (int c = 0; c < 8; ++c) {
            f[c] = val[((k + (c >> 2)) * S + (j + ((c >> 1) & 1))) * S + (i + (c & 1))];
            inside += f[c] < 0.0;
          }
          if (inside == 0 || inside == 8) continue;
          const std::int64_t gi = i0 + i, gj = j0 + j, gk = k0 + k;
          auto corner = [&](int c) {
            return Vec3(static_cast<double>(gi + (c & 1)) * h,
                        static_cast<double>(gj + ((c >> 1) & 1)) * h,
                        static_cast<double>(gk + (c >> 2)) * h);
          };
          // Vertex on the edge between corners c1, c2 (one's bits a subset of the other's).
          auto vertex = [&](int c1, int c2) {
            if ((c1 & c2) != c1) std::swap(c1, c2);
            const std::uint64_t key =
                pack(gi + (c1 & 1), gj + ((c1 >> 1) & 1), gk + (c1 >> 2)) * 8u +
                static_cast<std::uint64_t>(c1 ^ c2);
            auto [it, fresh] = edge_vertex.try_emplace(key, m.num_vertices());
            if (fresh) {
              const double t = f[c1] / (f[c1] - f[c2]);
              m.vertices.push_back(corner(c1) + t * (corner(c2) - corner(c1)));
            }
            return it->second;
          };
          auto emit = [&](int a, int bb, int c, const Vec3& toward_inside) {
            const Vec3& pa = m.vertices[a];
            const Vec3 n = (m.vertices[bb] - pa).cross(m.vertices[c] - pa);
            if (n.dot(toward_inside) >= 0.0) {
              m.triangles.push_back({a, bb, c});
            } else {
              m.triangles.push_back({a, c, bb});
            }
          };
          for (const auto& tet : kTets) {
            int in[4], out[4], ni = 0, no = 0;
            for (int c : tet) {
              if (f[c] < 0.0)
                in[ni++] = c;
              else
                out[no++] = c;
            }
            if (ni == 0 || no == 0) continue;
            Vec3 ci = Vec3::Zero(), co = Vec3::Zero();
            for (int q = 0; q < ni; ++q) ci += corner(in[q]);
            for (int q = 0; q < no; ++q) co += corner(out[q]);
            const Vec3 dir = ci / ni - co / no;
            if (ni == 1) {
              emit(vertex(in[0], out[0]), vertex(in[0], out[1]), vertex(in[0], out[2]), dir);
            } else if (ni == 3) {
              emit(vertex(out[0], in[0]), vertex(out[0], in[1]), vertex(out[0], in[2]), dir);
            } else {
              // Quad a-c, a-d, b-d, b-c (a, b inside; c, d outside), as two triangles.
              const int ac = vertex(in[0], out[0]), ad = vertex(in[0], out[1]);
              const int bd = vertex(in[1], out[1]), bc = vertex(in[1], out[0]);
              emit(ac, ad, bd, dir);
              emit(ac, bd, bc, dir);
            }
          }
        }
  }
  return m;
}

namespace {

// Newton steps from x onto the exact surface, at most max_move each.
Vec3 onto_surface(const PieceGrid& field, Vec3 x, double max_move) {
  for (int it = 0; it < 4; ++it) {
    const PieceGrid::Result r = field.eval(x);
    if (r.piece < 0 || std::abs(r.f) < 1e-12) break;
    x -= std::clamp(r.f, -max_move, max_move) * r.grad;
  }
  return x;
}

}  // namespace

void project_to_surface(TriangleMesh& m, const PieceGrid& field, double max_move) {
  const std::vector<Vec3> start = m.vertices;
  for (Vec3& v : m.vertices) v = onto_surface(field, v, max_move);
  // Where pieces meet in a crease, the nearest piece's gradient can take neighbouring vertices
  // across each other onto the two tubes, turning a triangle over: a flap folded onto its
  // neighbour, which reads as wall behind a point inside the lumen. The level set's own triangles
  // are never turned over, so a vertex of a triangle that turned (normal more than 90 degrees
  // from its level-set normal) goes back toward its level-set place, half the remaining way each
  // round, until none of its triangles is turned.
  const int nt = m.num_triangles();
  auto normal = [&](const std::vector<Vec3>& x, const std::array<int, 3>& t) {
    return Vec3((x[t[1]] - x[t[0]]).cross(x[t[2]] - x[t[0]]));
  };
  auto turned = [&](int t) {
    const auto& tr = m.triangles[t];
    return normal(m.vertices, tr).dot(normal(start, tr)) <= 0.0;
  };
  std::vector<int> bad;
  for (int t = 0; t < nt; ++t)
    if (turned(t)) bad.push_back(t);
  if (bad.empty()) return;
  std::vector<std::vector<int>> vt(m.vertices.size());
  for (int t = 0; t < nt; ++t)
    for (int v : m.triangles[t]) vt[v].push_back(t);
  for (int round = 0; round < 8 && !bad.empty(); ++round) {
    std::vector<int> verts;
    for (int t : bad)
      for (int v : m.triangles[t]) verts.push_back(v);
    std::sort(verts.begin(), verts.end());
    verts.erase(std::unique(verts.begin(), verts.end()), verts.end());
    for (int v : verts) m.vertices[v] = 0.5 * (m.vertices[v] + start[v]);
    if (round == 6)  // the last round puts them back on the level set
      for (int v : verts) m.vertices[v] = start[v];
    bad.clear();
    for (int v : verts)
      for (int t : vt[v])
        if (turned(t)) bad.push_back(t);
    std::sort(bad.begin(), bad.end());
    bad.erase(std::unique(bad.begin(), bad.end()), bad.end());
  }
}

void clip(TriangleMesh& m, const ClipPlane& pl, double snap) {
  const int nv0 = m.num_vertices();
  std::vector<double> d(nv0);
  std::vector<char> region(nv0, 0), on_plane(nv0, 0);
  for (int i = 0; i < nv0; ++i) {
    const Vec3 e = m.vertices[i] - pl.centre;
    d[i] = e.dot(pl.normal);
    const double radial = (e - d[i] * pl.normal).norm();
    region[i] = radial < pl.radius_limit && d[i] > pl.axial_lo && d[i] < pl.axial_hi;
  }
  // Snap near-plane vertices onto it, so that no sliver is cut off.
  for (int i = 0; i < nv0; ++i) {
    if (region[i] && std::abs(d[i]) < snap) {
      m.vertices[i] -= d[i] * pl.normal;
      d[i] = 0.0;
      on_plane[i] = 1;
    }
  }
  std::map<std::pair<int, int>, int> cut_vertex;
  auto cut = [&](int a, int b) {
    const auto key = std::minmax(a, b);
    auto it = cut_vertex.find(key);
    if (it != cut_vertex.end()) return it->second;
    const double t = d[a] / (d[a] - d[b]);
    Vec3 p = m.vertices[a] + t * (m.vertices[b] - m.vertices[a]);
    p -= (p - pl.centre).dot(pl.normal) * pl.normal;
    m.vertices.push_back(p);
    d.push_back(0.0);
    on_plane.push_back(1);
    const int id = m.num_vertices() - 1;
    cut_vertex.emplace(key, id);
    return id;
  };
  std::vector<std::array<int, 3>> out;
  out.reserve(m.triangles.size());
  for (const auto& t : m.triangles) {
    if (!(region[t[0]] && region[t[1]] && region[t[2]])) {
      out.push_back(t);
      continue;
    }
    // Sutherland-Hodgman against d <= 0, keeping the winding; a triangle with no vertex strictly
    // below the plane is dropped (it would lie in the cut).
    if (d[t[0]] >= 0.0 && d[t[1]] >= 0.0 && d[t[2]] >= 0.0) continue;
    int poly[4], n = 0;
    for (int e = 0; e < 3; ++e) {
      const int a = t[e], b = t[(e + 1) % 3];
      if (d[a] <= 0.0) poly[n++] = a;
      if ((d[a] < 0.0 && d[b] > 0.0) || (d[a] > 0.0 && d[b] < 0.0)) poly[n++] = cut(a, b);
    }
    for (int k = 1; k + 1 < n; ++k) out.push_back({poly[0], poly[k], poly[k + 1]});
  }
  m.triangles = std::move(out);
  // The cut edge on the exact circle.
  for (int i = 0; i < m.num_vertices(); ++i) {
    if (!on_plane[i]) continue;
    const Vec3 e = m.vertices[i] - pl.centre;
    if (e.norm() > 0.0) m.vertices[i] = pl.centre + pl.radius * e.normalized();
  }
}

std::vector<int> compact(TriangleMesh& m) {
  std::vector<int> remap(m.num_vertices(), -1);
  for (const auto& t : m.triangles)
    for (int v : t) remap[v] = 0;
  int n = 0;
  for (int i = 0; i < m.num_vertices(); ++i) {
    if (remap[i] < 0) continue;
    remap[i] = n;
    m.vertices[n++] = m.vertices[i];
  }
  m.vertices.resize(n);
  for (auto& t : m.triangles)
    for (int& v : t) v = remap[v];
  m.normals.clear();
  return remap;
}

namespace {

// Quality 4 sqrt(3) area / (sum of squared edges): 1 for equilateral, 0 for degenerate.
double quality(const Vec3& a, const Vec3& b, const Vec3& c) {
  const double l = (b - a).squaredNorm() + (c - b).squaredNorm() + (a - c).squaredNorm();
  return l > 0.0 ? 2.0 * std::sqrt(3.0) * (b - a).cross(c - a).norm() / l : 0.0;
}

}  // namespace

void simplify(TriangleMesh& m, const PieceGrid& field, const std::vector<double>& vertex_error,
              const std::vector<double>& vertex_max_edge) {
  const int nv = m.num_vertices();
  if (nv == 0) return;
  std::vector<std::vector<int>> vt(nv);
  for (int t = 0; t < m.num_triangles(); ++t)
    for (int v : m.triangles[t]) vt[v].push_back(t);
  std::vector<char> tri_alive(m.triangles.size(), 1), locked(nv, 0);
  std::vector<int> mark(nv, -1);              // stamps for neighbour sets
  std::vector<std::uint32_t> version(nv, 0);  // bumped when a vertex's fan changes
  int stamp = 0;
  auto count_neighbours = [&](int v) {
    ++stamp;
    int n = 0;
    for (int t : vt[v])
      for (int w : m.triangles[t])
        if (w != v && mark[w] != stamp) {
          mark[w] = stamp;
          ++n;
        }
    return n;
  };
  // How a triangle faces the lumen: the cosine between its normal and the exact surface's inward
  // normal (-grad f) at its centroid; 1 where no piece reaches it.
  auto facing = [&](const Vec3& a, const Vec3& b, const Vec3& c) {
    const Vec3 n = (b - a).cross(c - a);
    const auto r = field.eval((a + b + c) / 3.0);
    return r.piece < 0 || n.norm() == 0.0 ? 1.0 : n.normalized().dot(-r.grad);
  };
  // Boundary vertices (open ends, cut circles) stay: their open fan has one more neighbour than
  // triangles.
  for (int v = 0; v < nv; ++v)
    locked[v] = !vt[v].empty() && count_neighbours(v) != static_cast<int>(vt[v].size());
  // Collapse u into v (v keeps its position, so every vertex stays on the exact surface). To
  // untangle, fewer of the triangles around u may face away from the lumen after the collapse
  // than before (the new triangles still within the error bound of the surface and the longest
  // edge), and an edge of the boundary may go (a cut circle's vertices out of order). To
  // remove a triangle turned against all its neighbours, whose own normal is `up`, the new
  // triangles must face along `up` and no more of them away from the lumen.
  auto try_collapse = [&](int u, int v, bool untangle = false, const Vec3& up = Vec3::Zero()) {
    // Link condition (Dey et al. 1999): u and v share exactly the vertices opposite the edge (two
    // inside, one on the boundary), which keeps the surface a manifold.
    int shared_tris = 0;
    for (int t : vt[u])
      for (int w : m.triangles[t]) shared_tris += w == v;
    const bool boundary_edge = untangle && locked[u] && locked[v] && shared_tris == 1;
    if (locked[u] && !boundary_edge) return false;
    if (shared_tris != (boundary_edge ? 1 : 2)) return false;
    count_neighbours(u);  // marks u's neighbours with `stamp`
    int common = 0;
    for (int t : vt[v])
      for (int w : m.triangles[t])
        if (w != v && mark[w] == stamp) {
          mark[w] = -1;  // count each once
          ++common;
        }
    if (common != shared_tris) return false;
    const double err = std::min(vertex_error[u], vertex_error[v]);
    const double max_edge = std::min(vertex_max_edge[u], vertex_max_edge[v]);
    const Vec3& pv = m.vertices[v];
    double worst_old = 1.0;
    int turned_old = 0, turned_new = 0;
    for (int t : vt[u]) {
      const auto& tr = m.triangles[t];
      const Vec3 &a = m.vertices[tr[0]], &b = m.vertices[tr[1]], &c = m.vertices[tr[2]];
      worst_old = std::min(worst_old, quality(a, b, c));
      if (untangle) turned_old += facing(a, b, c) <= 0.0;
    }
    for (int t : vt[u]) {
      const auto& tr = m.triangles[t];
      if (tr[0] == v || tr[1] == v || tr[2] == v) continue;  // removed by the collapse
      Vec3 p[3], q[3];
      for (int k = 0; k < 3; ++k) {
        p[k] = m.vertices[tr[k]];
        q[k] = tr[k] == u ? pv : p[k];
        if (tr[k] != u && (q[k] - pv).norm() > max_edge) return false;
      }
      const Vec3 n_old = (p[1] - p[0]).cross(p[2] - p[0]);
      const Vec3 n_new = (q[1] - q[0]).cross(q[2] - q[0]);
      if (n_new.norm() <= 1e-12 * (q[1] - q[0]).squaredNorm()) return false;
      if (untangle) {
        if (!up.isZero() && n_new.dot(up) <= 0.0) return false;
        turned_new += facing(q[0], q[1], q[2]) <= 0.0;
      } else {
        if (n_new.normalized().dot(n_old.normalized()) < 0.3) return false;  // no folds
        if (quality(q[0], q[1], q[2]) < std::min(0.2, worst_old)) return false;
      }
      // Distance to the exact surface at the centroid and edge midpoints; the normal must agree
      // with the surface's (into the lumen is -grad f).
      // The edge opposite v is unchanged; sample the centroid and the two new edges.
      Vec3 samples[3] = {(q[0] + q[1] + q[2]) / 3.0, Vec3::Zero(), Vec3::Zero()};
      for (int k = 0, n = 1; k < 3; ++k)
        if (tr[k] != u) samples[n++] = 0.5 * (q[k] + pv);
      // A triangle with its vertices on the surface and edges below sqrt(3) err is within err
      // of it everywhere; only longer ones need the field.
      const double longest =
          std::max({(q[1] - q[0]).norm(), (q[2] - q[1]).norm(), (q[0] - q[2]).norm()});
      if (longest <= std::sqrt(3.0) * err) continue;
      for (const Vec3& x : samples) {
        const auto r = field.eval(x);
        if (std::abs(r.f) > err) return false;
        if (!untangle && r.piece >= 0 && n_new.normalized().dot(-r.grad) < 0.5) return false;
      }
    }
    if (untangle && turned_new >= turned_old + (up.isZero() ? 0 : 1)) return false;
    // Apply: triangles on the edge die, the others move from u to v.
    for (int t : vt[u])
      for (int w : m.triangles[t]) ++version[w];
    for (int t : vt[u]) {
      auto& tr = m.triangles[t];
      if (tr[0] == v || tr[1] == v || tr[2] == v) {
        tri_alive[t] = 0;
        for (int w : tr)
          if (w != u) {
            auto& l = vt[w];
            l.erase(std::find(l.begin(), l.end(), t));
          }
      } else {
        for (int& w : tr)
          if (w == u) w = v;
        vt[v].push_back(t);
      }
    }
    vt[u].clear();
    return true;
  };
  // Passes over all edges with a growing length threshold: roughly shortest edges first, which
  // keeps triangles even, without the cost of a global priority queue.
  double longest = 0.0;
  for (double e : vertex_max_edge) longest = std::max(longest, e);
  double shortest = longest;
  for (const auto& t : m.triangles)
    shortest = std::min(shortest, (m.vertices[t[0]] - m.vertices[t[1]]).norm());
  // An edge that failed is retried only after its endpoints' fans changed (version sum).
  std::vector<std::uint32_t> failed_at(3 * m.triangles.size(), 0);
  for (double limit = std::max(shortest, 1e-6) * 2.0;; limit = std::min(limit * 2.0, longest)) {
    for (int t = 0; t < m.num_triangles(); ++t) {
      for (int e = 0; e < 3 && tri_alive[t]; ++e) {
        const int a = m.triangles[t][e], b = m.triangles[t][(e + 1) % 3];
        const std::uint32_t ver = version[a] + version[b] + 1;
        if (failed_at[3 * t + e] == ver) continue;
        const double len = (m.vertices[a] - m.vertices[b]).norm();
        if (len > limit || len > std::min(vertex_max_edge[a], vertex_max_edge[b])) continue;
        if (!try_collapse(a, b) && !try_collapse(b, a)) failed_at[3 * t + e] = ver;
      }
    }
    if (limit >= longest) break;
  }
  // Untangle: where pieces meet in a crease, a few triangles can stay turned against the surface
  // (a flap folded onto its neighbour, which reads as wall behind a point inside the lumen). Each
  // loses one of its edges if fewer triangles around it then face away from the lumen. Across a
  // crease the surface's normal at a centroid can be the other tube's; there, a triangle turned
  // against all three of its neighbours is taken as turned.
  auto unit_normal = [&](int t) {
    const auto& tr = m.triangles[t];
    const Vec3 n =
        (m.vertices[tr[1]] - m.vertices[tr[0]]).cross(m.vertices[tr[2]] - m.vertices[tr[0]]);
    return Vec3(n.norm() > 0.0 ? Vec3(n.normalized()) : Vec3::Zero());
  };
  for (int round = 0; round < 4; ++round) {
    bool changed = false;
    for (int t = 0; t < m.num_triangles(); ++t) {
      if (!tri_alive[t]) continue;
      const auto tr = m.triangles[t];
      Vec3 up = Vec3::Zero();
      int against = 0;
      for (int e = 0; e < 3; ++e)
        for (int s : vt[tr[e]])
          if (s != t && std::find(m.triangles[s].begin(), m.triangles[s].end(), tr[(e + 1) % 3]) !=
                            m.triangles[s].end()) {
            up += unit_normal(s);
            against += unit_normal(s).dot(unit_normal(t)) < 0.0;
          }
      if (against < 3) up.setZero();
      if (up.isZero() && facing(m.vertices[tr[0]], m.vertices[tr[1]], m.vertices[tr[2]]) >= 0.0)
        continue;
      for (int e = 0; e < 3 && tri_alive[t]; ++e) {
        const int a = tr[e], b = tr[(e + 1) % 3];
        changed |= try_collapse(a, b, true, up) || try_collapse(b, a, true, up);
      }
    }
    if (!changed) break;
  }
  std::vector<std::array<int, 3>> out;
  for (int t = 0; t < m.num_triangles(); ++t)
    if (tri_alive[t]) out.push_back(m.triangles[t]);
  m.triangles = std::move(out);
  compact(m);
}

void drop_small_components(TriangleMesh& m, int min_triangles) {
  const int nt = m.num_triangles();
  std::vector<int> parent(nt);
  for (int t = 0; t < nt; ++t) parent[t] = t;
  auto find = [&](int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  std::unordered_map<std::uint64_t, int> first;
  first.reserve(3 * static_cast<std::size_t>(nt));
  for (int t = 0; t < nt; ++t)
    for (int e = 0; e < 3; ++e) {
      const auto [lo, hi] = std::minmax(m.triangles[t][e], m.triangles[t][(e + 1) % 3]);
      const std::uint64_t k =
          (static_cast<std::uint64_t>(lo) << 32) | static_cast<std::uint32_t>(hi);
      auto [it, fresh] = first.try_emplace(k, t);
      if (!fresh) parent[find(t)] = find(it->second);
    }
  std::vector<int> size(nt, 0);
  for (int t = 0; t < nt; ++t) ++size[find(t)];
  std::vector<std::array<int, 3>> out;
  for (int t = 0; t < nt; ++t)
    if (size[find(t)] >= min_triangles) out.push_back(m.triangles[t]);
  m.triangles = std::move(out);
  compact(m);
}

std::vector<int> boundary_loop_on_plane(const TriangleMesh& m, const Vec3& centre,
                                        const Vec3& normal, double radius_limit) {
  auto on = [&](int v) {
    const Vec3 e = m.vertices[v] - centre;
    return std::abs(e.dot(normal)) < 1e-9 && e.norm() < radius_limit;
  };
  std::unordered_map<std::uint64_t, int> uses;
  auto ekey = [](int a, int b) {
    const auto [lo, hi] = std::minmax(a, b);
    return (static_cast<std::uint64_t>(lo) << 32) | static_cast<std::uint32_t>(hi);
  };
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e)
      if (on(t[e]) && on(t[(e + 1) % 3])) ++uses[ekey(t[e], t[(e + 1) % 3])];
  std::unordered_map<int, int> next;
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e) {
      const int a = t[e], b = t[(e + 1) % 3];
      if (on(a) && on(b) && uses[ekey(a, b)] == 1) next[a] = b;
    }
  std::vector<int> loop;
  if (next.empty()) return loop;
  int start = next.begin()->first;
  for (auto& [a, b] : next) start = std::min(start, a);  // deterministic start
  int v = start;
  do {
    loop.push_back(v);
    const auto it = next.find(v);
    if (it == next.end() || loop.size() > next.size()) return {};  // open or tangled
    v = it->second;
  } while (v != start);
  if (loop.size() != next.size()) return {};  // more than one loop on the plane
  return loop;
}

void zip_loops(TriangleMesh& m, const std::vector<int>& a_loop, const std::vector<int>& b_loop,
               const Vec3& centre, const Vec3& axis) {
  const Vec3 u = any_perpendicular(axis), w = axis.cross(u);
  auto angle = [&](int v) {
    const Vec3 e = m.vertices[v] - centre;
    double t = std::atan2(e.dot(w), e.dot(u));
    return t < 0.0 ? t + 2.0 * std::numbers::pi : t;
  };
  // Each loop sorted counter-clockwise about the axis from its smallest angle; `reversed` says
  // whether that order runs against the loop's own (triangle) direction.
  struct Sorted {
    std::vector<int> v;
    std::vector<double> ang;
    bool reversed = false;
  };
  auto prepare = [&](std::vector<int> loop) {
    Sorted s;
    double turn = 0.0;
    for (std::size_t i = 0; i < loop.size(); ++i) {
      double d = angle(loop[(i + 1) % loop.size()]) - angle(loop[i]);
      if (d > std::numbers::pi) d -= 2.0 * std::numbers::pi;
      if (d < -std::numbers::pi) d += 2.0 * std::numbers::pi;
      turn += d;
    }
    if (turn < 0.0) {
      std::reverse(loop.begin(), loop.end());
      s.reversed = true;
    }
    const auto first = std::min_element(loop.begin(), loop.end(),
                                        [&](int x, int y) { return angle(x) < angle(y); });
    std::rotate(loop.begin(), first, loop.end());
    s.v = loop;
    // Unwrapped by the shortest step, so that a tiny backward step along the loop (two cut
    // vertices at almost the same angle) stays tiny instead of adding a turn.
    for (int v : loop) {
      if (s.ang.empty()) {
        s.ang.push_back(angle(v));
        continue;
      }
      double d = angle(v) - std::fmod(s.ang.back(), 2.0 * std::numbers::pi);
      if (d > std::numbers::pi) d -= 2.0 * std::numbers::pi;
      if (d < -std::numbers::pi) d += 2.0 * std::numbers::pi;
      s.ang.push_back(s.ang.back() + d);
    }
    s.ang.push_back(s.ang.front() + 2.0 * std::numbers::pi);
    return s;
  };
  const Sorted A = prepare(a_loop), B = prepare(b_loop);
  const std::size_t na = A.v.size(), nb = B.v.size();
  std::size_t i = 0, j = 0;
  while (i < na || j < nb) {
    const bool advance_a = j == nb || (i < na && A.ang[i + 1] <= B.ang[j + 1]);
    if (advance_a) {
      const int p = A.v[i], q = A.v[(i + 1) % na], r = B.v[j % nb];
      // The existing triangle runs p -> q unless the loop was reversed; use it the other way.
      if (A.reversed)
        m.triangles.push_back({p, q, r});
      else
        m.triangles.push_back({q, p, r});
      ++i;
    } else {
      const int p = B.v[j], q = B.v[(j + 1) % nb], r = A.v[i % na];
      if (B.reversed)
        m.triangles.push_back({p, q, r});
      else
        m.triangles.push_back({q, p, r});
      ++j;
    }
  }
}

}  // namespace vcsim::internal
