// The lumen mesh of a vessel tree: plan (which pieces on which grid, where to cut), mesh, stitch,
// cache; then vertex ownership, lesions, checks and measurements.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <future>
#include <limits>
#include <numbers>
#include <unordered_map>

#include "field.h"
#include "mesher.h"
#include "vcsim/anatomy.h"

namespace vcsim {

namespace {

using internal::ClipPlane;
using internal::Piece;
using internal::PieceGrid;

// Bump when the mesher changes, so that old cache files are not reused.
constexpr std::uint32_t kMesherVersion = 4;

// ---------------------------------------------------------------------------------------------
// Plan

// Pieces of segment si restricted to arc lengths [sa, sb], extended straight (same radius) by
// ext_start before sa and ext_end after sb.
void add_pieces(const VesselTree& tree, int si, double sa, double sb, double ext_start,
                double ext_end, std::vector<Piece>& out) {
  const VesselSegment& seg = tree.segments[si];
  const auto cum = arc_lengths(seg);
  std::vector<Vec3> p;
  std::vector<double> r, s;
  auto push = [&](double sv) {
    p.push_back(point_at(seg, sv));
    r.push_back(radius_at(seg, sv));
    s.push_back(sv);
  };
  push(sa);
  for (std::size_t i = 0; i < cum.size(); ++i)
    if (cum[i] > sa + 1e-9 && cum[i] < sb - 1e-9) push(cum[i]);
  push(sb);
  if (ext_start > 0.0) {
    const Vec3 t = tangent_at(seg, sa);
    p.insert(p.begin(), p.front() - ext_start * t);
    r.insert(r.begin(), r.front());
    s.insert(s.begin(), sa - ext_start);
  }
  if (ext_end > 0.0) {
    const Vec3 t = tangent_at(seg, sb);
    p.push_back(p.back() + ext_end * t);
    r.push_back(r.back());
    s.push_back(sb + ext_end);
  }
  for (std::size_t i = 0; i + 1 < p.size(); ++i)
    out.push_back(Piece{p[i], p[i + 1], r[i], r[i + 1], si, s[i]});
}

struct Cut {
  int segment = -1;
  double s_cut = 0.0;  // coarse mesh ends here; the fine mesh starts at s_cut + gap
  double gap = 0.0;
};

struct Plan {
  std::vector<Piece> coarse, fine;
  std::vector<ClipPlane> coarse_clips, fine_clips;
  std::vector<Cut> cuts;
};

ClipPlane end_clip(const Vec3& c, const Vec3& n, double r, double ext, double h) {
  ClipPlane pl;
  pl.centre = c;
  pl.normal = n;
  pl.radius = r;
  pl.radius_limit = 1.3 * r + 2.0 * h;
  pl.axial_lo = -3.0 * h;
  pl.axial_hi = ext + r + 3.0 * h;
  return pl;
}

Plan make_plan(const VesselTree& tree, const LumenSettings& st) {
  Plan plan;
  const double hc = st.coarse_voxel, hf = st.fine_voxel;
  const double ext_c = 3.0 * hc, ext_f = 3.0 * hf;
  auto fine = [&](int i) { return tree.segments[i].kind == VesselKind::kCoronary; };
  const auto ends = open_ends(tree);
  auto end_open = [&](int i) {
    for (const auto& e : ends)
      if (e.segment == i && !e.at_start) return true;
    return false;
  };
  // Coarse pieces of everything but coronaries.
  for (int i = 0; i < tree.num_segments(); ++i) {
    if (fine(i)) continue;
    const double len = segment_length(tree.segments[i]);
    const bool open_start = i == 0 && tree.open_start;
    add_pieces(tree, i, 0.0, len, open_start ? ext_c : 0.0, end_open(i) ? ext_c : 0.0, plan.coarse);
  }
  const std::vector<Piece> aorta_only = plan.coarse;
  auto coarse_field = [&](const Vec3& p) {
    double f = std::numeric_limits<double>::infinity();
    for (const Piece& pc : aorta_only) f = std::min(f, internal::eval_piece(pc, p).f);
    return f;
  };
  for (const auto& e : ends) {
    if (fine(e.segment)) continue;
    plan.coarse_clips.push_back(end_clip(e.centre, e.outward, e.radius, ext_c, hc));
  }
  // Coronaries: a stub on the coarse grid from the aorta to a cut well clear of the aortic wall;
  // the fine grid from a little beyond the cut.
  for (int i = 0; i < tree.num_segments(); ++i) {
    if (!fine(i)) continue;
    const VesselSegment& seg = tree.segments[i];
    const double len = segment_length(seg);
    const bool root_of_fine = seg.parent >= 0 && !fine(seg.parent);
    double s_start = 0.0;
    if (root_of_fine) {
      const double s_ost = ostium_distance(tree, i);
      Cut cut;
      cut.segment = i;
      cut.gap = std::max(2.0 * hc, 0.8e-3);
      double s = s_ost + std::max(2.0 * radius_at(seg, s_ost), 2.5e-3);
      for (; s < len - 4.0 * cut.gap; s += 0.25e-3) {
        // The cut circle must be clear of the aorta by more than the coarse cells.
        const Vec3 c = point_at(seg, s), t = tangent_at(seg, s);
        const Vec3 u = internal::any_perpendicular(t), w = t.cross(u);
        const double r = radius_at(seg, s);
        bool clear = true;
        for (int k = 0; k < 24 && clear; ++k) {
          const double a = 2.0 * std::numbers::pi * k / 24;
          clear = coarse_field(c + r * (std::cos(a) * u + std::sin(a) * w)) > 0.5e-3 + 2.0 * hc;
        }
        if (clear) break;
      }
      if (s >= len - 4.0 * cut.gap)
        throw InputError("build_lumen", "segments." + seg.name,
                         "expected the coronary to run clear of the aorta after its ostium");
      cut.s_cut = s;
      plan.cuts.push_back(cut);
      add_pieces(tree, i, 0.0, s, 0.0, ext_c, plan.coarse);
      ClipPlane pl = end_clip(point_at(seg, s), tangent_at(seg, s), radius_at(seg, s), ext_c, hc);
      pl.axial_lo = -std::min(3.0 * hc, 0.4 * (s - s_ost));
      plan.coarse_clips.push_back(pl);
      s_start = s + cut.gap;
      const double sf = s_start;
      plan.fine_clips.push_back(
          end_clip(point_at(seg, sf), -tangent_at(seg, sf), radius_at(seg, sf), ext_f, hf));
    }
    add_pieces(tree, i, s_start, len, root_of_fine ? ext_f : 0.0, end_open(i) ? ext_f : 0.0,
               plan.fine);
  }
  for (const auto& e : ends)
    if (fine(e.segment))
      plan.fine_clips.push_back(end_clip(e.centre, e.outward, e.radius, ext_f, hf));
  return plan;
}

// Per-vertex simplification bounds from the owning segment (docs/anatomy.md): surface error and
// longest edge (about the vessel radius, so that triangles follow bends, lesions and motion).
void vertex_bounds(const TriangleMesh& m, const PieceGrid& g, const VesselTree& tree,
                   const LumenSettings& st, std::vector<double>& err, std::vector<double>& edge) {
  std::vector<double> seg_err(tree.num_segments()), seg_edge(tree.num_segments());
  for (int i = 0; i < tree.num_segments(); ++i) {
    const VesselSegment& s = tree.segments[i];
    const double rmin = *std::min_element(s.radii.begin(), s.radii.end());
    switch (s.kind) {
      case VesselKind::kCoronary:
        seg_err[i] = st.coronary_error;
        break;
      case VesselKind::kArtery:
        seg_err[i] = std::min(st.aorta_error, 0.04 * rmin);
        break;
      default:
        seg_err[i] = st.aorta_error;
    }
    seg_edge[i] = std::clamp(0.8 * rmin, 0.6e-3, 6e-3);
  }
  err.assign(m.vertices.size(), st.coronary_error);
  edge.assign(m.vertices.size(), 0.6e-3);
  for (std::size_t v = 0; v < m.vertices.size(); ++v) {
    const auto r = g.eval(m.vertices[v]);
    if (r.piece < 0) continue;
    const Piece& pc = g.pieces()[r.piece];
    err[v] = seg_err[pc.segment];
    edge[v] = seg_edge[pc.segment];
    const double s = pc.s0 + r.t * (pc.b - pc.a).norm();
    for (const Lesion& l : tree.lesions) {
      if (l.segment != pc.segment) continue;
      const double s0 = ostium_distance(tree, l.segment) + l.distance;
      if (s > s0 - 2e-3 && s < s0 + l.length + 2e-3) {
        err[v] = std::min(err[v], st.lesion_error);
        edge[v] = std::min(edge[v], std::max(0.3e-3, 0.04 * l.length));
      }
    }
  }
}

TriangleMesh mesh_part(const std::vector<Piece>& pieces, const std::vector<ClipPlane>& clips,
                       double h, const VesselTree& tree, const LumenSettings& st) {
  if (pieces.empty()) return {};
  const PieceGrid grid(pieces, std::max(4.0 * h, 1e-3), 4.0 * h);
  TriangleMesh m = internal::marching_tetrahedra(grid, h);
  internal::project_to_surface(m, grid, h);
  for (const ClipPlane& pl : clips) internal::clip(m, pl, 0.1 * h);
  internal::compact(m);
  std::vector<double> err, edge;
  vertex_bounds(m, grid, tree, st, err, edge);
  internal::simplify(m, grid, err, edge);
  return m;
}

TriangleMesh build_healthy(const VesselTree& tree, const LumenSettings& st) {
  const Plan plan = make_plan(tree, st);
  // The two grids are independent: mesh them on two threads.
  auto fine_job = std::async(std::launch::async, [&] {
    return mesh_part(plan.fine, plan.fine_clips, st.fine_voxel, tree, st);
  });
  TriangleMesh m = mesh_part(plan.coarse, plan.coarse_clips, st.coarse_voxel, tree, st);
  const TriangleMesh f = fine_job.get();
  const int off = m.num_vertices();
  m.vertices.insert(m.vertices.end(), f.vertices.begin(), f.vertices.end());
  for (auto t : f.triangles) m.triangles.push_back({t[0] + off, t[1] + off, t[2] + off});
  for (const Cut& c : plan.cuts) {
    const VesselSegment& seg = tree.segments[c.segment];
    const double s1 = c.s_cut + c.gap;
    const Vec3 ca = point_at(seg, c.s_cut), cb = point_at(seg, s1);
    const double lim = 1.5 * radius_at(seg, c.s_cut) + 1e-3;
    const auto a = internal::boundary_loop_on_plane(m, ca, tangent_at(seg, c.s_cut), lim);
    const auto b = internal::boundary_loop_on_plane(m, cb, tangent_at(seg, s1), lim);
    if (a.size() < 3 || b.size() < 3)
      throw std::runtime_error("build_lumen: no clean cut loop on " + seg.name);
    internal::zip_loops(m, a, b, 0.5 * (ca + cb), tangent_at(seg, c.s_cut + 0.5 * c.gap));
  }
  // Where swept spheres overlap in a concave corner the level set can hold a speck of a closed
  // surface (a micro-cavity); nothing of the lumen is that small.
  internal::drop_small_components(m, 100);
  return m;
}

// ---------------------------------------------------------------------------------------------
// Cache

std::uint64_t cache_key(const VesselTree& tree, const LumenSettings& st) {
  std::string s = "vcsim-lumen ";
  s += std::to_string(kMesherVersion);
  for (double v :
       {st.coarse_voxel, st.fine_voxel, st.coronary_error, st.aorta_error, st.lesion_error}) {
    char buf[40];
    std::snprintf(buf, sizeof buf, " %.17g", v);
    s += buf;
  }
  s += vessel_tree_to_json(tree);
  return internal::hash_bytes(s.data(), s.size(), 1469598103934665603ull);
}

std::filesystem::path cache_dir(const LumenSettings& st) {
  if (!st.cache_dir.empty()) return st.cache_dir;
  if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x)
    return std::filesystem::path(x) / "vcsim" / "anatomy";
  if (const char* h = std::getenv("HOME"); h && *h)
    return std::filesystem::path(h) / ".cache" / "vcsim" / "anatomy";
  return {};
}

constexpr char kMagic[8] = {'V', 'C', 'S', 'I', 'M', 'L', 'U', 'M'};

// Reads a cached mesh; returns false with the reason if the file is absent, stale or corrupt.
bool read_cache(const std::filesystem::path& path, std::uint64_t key, TriangleMesh& m,
                std::string& why) {
  std::ifstream f(path, std::ios::binary);
  if (!f) {
    why = "absent";
    return false;
  }
  std::vector<char> buf((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  constexpr std::size_t head = 8 + 4 + 4 + 8 + 8 + 8;
  if (buf.size() < head + 8) {
    why = "truncated";
    return false;
  }
  std::uint32_t version = 0;
  std::uint64_t k = 0, nv = 0, nt = 0, sum = 0;
  std::memcpy(&version, buf.data() + 8, 4);
  std::memcpy(&k, buf.data() + 16, 8);
  std::memcpy(&nv, buf.data() + 24, 8);
  std::memcpy(&nt, buf.data() + 32, 8);
  if (std::memcmp(buf.data(), kMagic, 8) != 0) {
    why = "not a vcsim lumen cache file";
    return false;
  }
  if (version != kMesherVersion || k != key) {
    why = "stale (different anatomy or mesher version)";
    return false;
  }
  if (nv > (1u << 28) || nt > (1u << 28) || buf.size() != head + nv * 24 + nt * 12 + 8) {
    why = "truncated or wrong size";
    return false;
  }
  std::memcpy(&sum, buf.data() + buf.size() - 8, 8);
  if (internal::hash_bytes(buf.data(), buf.size() - 8, 1469598103934665603ull) != sum) {
    why = "checksum mismatch";
    return false;
  }
  m = TriangleMesh{};
  m.vertices.resize(nv);
  m.triangles.resize(nt);
  const char* p = buf.data() + head;
  for (auto& v : m.vertices) {
    std::memcpy(v.data(), p, 24);
    p += 24;
  }
  for (auto& t : m.triangles) {
    std::int32_t ix[3];
    std::memcpy(ix, p, 12);
    p += 12;
    for (int a = 0; a < 3; ++a) {
      if (ix[a] < 0 || static_cast<std::uint64_t>(ix[a]) >= nv) {
        why = "index out of range";
        return false;
      }
      t[a] = ix[a];
    }
  }
  return true;
}

void write_cache(const std::filesystem::path& path, std::uint64_t key, const TriangleMesh& m) {
  std::vector<char> buf;
  auto put = [&](const void* d, std::size_t n) {
    const std::size_t at = buf.size();
    buf.resize(at + n);
    std::memcpy(buf.data() + at, d, n);
  };
  const std::uint32_t version = kMesherVersion, zero = 0;
  const std::uint64_t nv = m.vertices.size(), nt = m.triangles.size();
  put(kMagic, 8);
  put(&version, 4);
  put(&zero, 4);
  put(&key, 8);
  put(&nv, 8);
  put(&nt, 8);
  for (const auto& v : m.vertices) put(v.data(), 24);
  for (const auto& t : m.triangles) {
    const std::int32_t ix[3] = {t[0], t[1], t[2]};
    put(ix, 12);
  }
  const std::uint64_t sum = internal::hash_bytes(buf.data(), buf.size(), 1469598103934665603ull);
  put(&sum, 8);
  // Write beside and rename, so that a reader never sees half a file.
  const auto tmp = path.string() + ".tmp" + std::to_string(static_cast<long long>(nv ^ key));
  {
    std::ofstream f(tmp, std::ios::binary);
    if (!f) return;
    f.write(buf.data(), static_cast<std::streamsize>(buf.size()));
    if (!f) return;
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) std::filesystem::remove(tmp, ec);
}

}  // namespace

// ---------------------------------------------------------------------------------------------

Lumen build_lumen(const VesselTree& tree, const LumenSettings& st) {
  const auto t0 = std::chrono::steady_clock::now();
  validate_tree(tree, "build_lumen");
  require_positive(st.coarse_voxel, "LumenSettings", "coarse_voxel");
  require_positive(st.fine_voxel, "LumenSettings", "fine_voxel");
  require_positive(st.coronary_error, "LumenSettings", "coronary_error");
  require_positive(st.aorta_error, "LumenSettings", "aorta_error");
  require_positive(st.lesion_error, "LumenSettings", "lesion_error");
  // Every vessel needs two voxels per radius on its grid (coronary ostia sit on the coarse one).
  for (int i = 0; i < tree.num_segments(); ++i) {
    const auto& s = tree.segments[i];
    const bool fine = s.kind == VesselKind::kCoronary;
    const bool ostial =
        fine && s.parent >= 0 && tree.segments[s.parent].kind != VesselKind::kCoronary;
    const double h = fine && !ostial ? st.fine_voxel : st.coarse_voxel;
    const double r = ostial ? s.radii.front() : *std::min_element(s.radii.begin(), s.radii.end());
    if (r < 2.0 * h ||
        (fine && *std::min_element(s.radii.begin(), s.radii.end()) < 2.0 * st.fine_voxel))
      throw InputError("build_lumen", "segments." + s.name + ".radii_mm",
                       "expected radii of at least 2 voxels (" + std::to_string(2e3 * h) +
                           " mm); lower the LumenSettings voxel sizes");
  }
  if (const double n = estimated_lumen_triangles(tree, st); n > kMaxLumenTriangles)
    throw InputError("build_lumen", "LumenSettings",
                     "expected a lumen of at most " +
                         std::to_string(static_cast<long long>(kMaxLumenTriangles)) +
                         " triangles; these voxel sizes would make about " +
                         std::to_string(static_cast<long long>(n)));
  Lumen lu;
  const std::uint64_t key = cache_key(tree, st);
  std::filesystem::path file;
  bool have = false;
  if (st.use_cache) {
    const auto dir = cache_dir(st);
    if (!dir.empty()) {
      char name[40];
      std::snprintf(name, sizeof name, "lumen-%016llx.bin", static_cast<unsigned long long>(key));
      file = dir / name;
      std::string why;
      have = read_cache(file, key, lu.mesh, why);
      lu.cache_status = have              ? "hit"
                        : why == "absent" ? "miss"
                                          : "rebuilt: " + file.string() + " " + why;
    } else {
      lu.cache_status = "off: no cache directory";
    }
  } else {
    lu.cache_status = "off";
  }
  // The report of a fresh build says what repair changed; a cached mesh was stored repaired.
  if (!have) lu.mesh = build_healthy(tree, st);
  lu.report = check_and_repair(lu.mesh, "lumen of " + tree.name);
  if (!have && !file.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(file.parent_path(), ec);
    write_cache(file, key, lu.mesh);
  }
  lu.ends = open_ends(tree);

  // Ownership: the piece whose surface holds the vertex.
  const PieceGrid grid(internal::make_pieces(tree, {}), 2e-3, 1e-3);
  const int nv = lu.mesh.num_vertices();
  lu.vertex_segment.assign(nv, 0);
  lu.vertex_arc.assign(nv, 0.0);
  for (int v = 0; v < nv; ++v) {
    auto r = grid.eval(lu.mesh.vertices[v]);
    const Piece* best = r.piece >= 0 ? &grid.pieces()[r.piece] : nullptr;
    double t = r.t;
    if (!best) {  // farther than the grid's reach (should not happen): brute force
      double fb = std::numeric_limits<double>::infinity();
      for (const Piece& pc : grid.pieces()) {
        const auto e = internal::eval_piece(pc, lu.mesh.vertices[v]);
        if (std::abs(e.f) < fb) {
          fb = std::abs(e.f);
          best = &pc;
          t = e.t;
        }
      }
    }
    lu.vertex_segment[v] = best->segment;
    lu.vertex_arc[v] = best->s0 + t * (best->b - best->a).norm();
  }
  internal::finish_lumen(tree, lu);
  lu.build_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return lu;
}

namespace internal {

void finish_lumen(const VesselTree& tree, Lumen& lu) {
  lu.triangle_segment.resize(lu.mesh.triangles.size());
  for (std::size_t t = 0; t < lu.mesh.triangles.size(); ++t)
    lu.triangle_segment[t] = lu.vertex_segment[lu.mesh.triangles[t][0]];
  // Lesions move vertices toward the residual lumen; topology is unchanged.
  lu.healthy_vertices = lu.mesh.vertices;
  const int nv = lu.mesh.num_vertices();
  for (const Lesion& les : tree.lesions) {
    const VesselSegment& seg = tree.segments[les.segment];
    const double ost = ostium_distance(tree, les.segment);
    for (int v = 0; v < nv; ++v) {
      if (lu.vertex_segment[v] != les.segment) continue;
      const double s = lu.vertex_arc[v];
      const LesionProfile p = lesion_profile(les, ost, radius_at(seg, s), s);
      if (p.factor == 1.0) continue;
      const Vec3 c = point_at(seg, s);
      const Vec3 e = lu.healthy_vertices[v] - c;
      lu.mesh.vertices[v] = c - p.shift * plaque_direction(tree, les, s) + p.factor * e;
    }
  }
  lu.mesh.recompute_normals();
}

}  // namespace internal

// ---------------------------------------------------------------------------------------------
// Checks and measurements

LumenCheck check_lumen(const TriangleMesh& m, const std::vector<OpenEnd>& ends) {
  LumenCheck c;
  c.triangles = m.num_triangles();
  c.vertices = m.num_vertices();
  c.open_ends = static_cast<int>(ends.size());
  auto ekey = [](int a, int b) {
    const auto [lo, hi] = std::minmax(a, b);
    return (static_cast<std::uint64_t>(lo) << 32) | static_cast<std::uint32_t>(hi);
  };
  std::unordered_map<std::uint64_t, int> uses;
  uses.reserve(m.triangles.size() * 2);
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e) ++uses[ekey(t[e], t[(e + 1) % 3])];
  for (auto& [k, n] : uses) c.non_manifold_edges += n > 2;

  // Triangle components and vertex fans by union-find over edges.
  std::vector<int> parent(m.triangles.size());
  for (std::size_t i = 0; i < parent.size(); ++i) parent[i] = static_cast<int>(i);
  auto find = [&](int x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  std::unordered_map<std::uint64_t, int> first_tri;
  first_tri.reserve(uses.size());
  for (int t = 0; t < m.num_triangles(); ++t)
    for (int e = 0; e < 3; ++e) {
      const auto k = ekey(m.triangles[t][e], m.triangles[t][(e + 1) % 3]);
      auto [it, fresh] = first_tri.try_emplace(k, t);
      if (!fresh) parent[find(t)] = find(it->second);
    }
  for (int t = 0; t < m.num_triangles(); ++t) c.components += find(t) == t;

  // A manifold vertex's triangles form one fan: connected through edges at the vertex.
  std::vector<std::vector<int>> vt(m.vertices.size());
  for (int t = 0; t < m.num_triangles(); ++t)
    for (int v : m.triangles[t]) vt[v].push_back(t);
  for (int v = 0; v < m.num_vertices(); ++v) {
    const auto& ts = vt[v];
    if (ts.size() < 2) continue;
    std::vector<int> fan(ts.size());
    for (std::size_t i = 0; i < fan.size(); ++i) fan[i] = static_cast<int>(i);
    auto ff = [&](int x) {
      while (fan[x] != x) x = fan[x] = fan[fan[x]];
      return x;
    };
    std::unordered_map<int, int> by_other;
    for (std::size_t i = 0; i < ts.size(); ++i)
      for (int w : m.triangles[ts[i]]) {
        if (w == v) continue;
        auto [it, fresh] = by_other.try_emplace(w, static_cast<int>(i));
        if (!fresh) fan[ff(static_cast<int>(i))] = ff(it->second);
      }
    int groups = 0;
    for (std::size_t i = 0; i < fan.size(); ++i)
      groups += ff(static_cast<int>(i)) == static_cast<int>(i);
    c.non_manifold_vertices += groups > 1;
  }

  // Boundary loops, each matched to the designated open end it lies on.
  std::unordered_map<int, int> next;
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e)
      if (uses[ekey(t[e], t[(e + 1) % 3])] == 1) next[t[e]] = t[(e + 1) % 3];
  std::vector<int> end_hits(ends.size(), 0);
  std::unordered_map<int, char> seen;
  for (auto& [start, nx] : next) {
    if (seen.count(start)) continue;
    std::vector<int> loop;
    int v = start;
    while (!seen.count(v)) {
      seen[v] = 1;
      loop.push_back(v);
      auto it = next.find(v);
      if (it == next.end()) break;
      v = it->second;
    }
    ++c.boundary_loops;
    Vec3 centroid = Vec3::Zero();
    for (int w : loop) centroid += m.vertices[w];
    centroid /= static_cast<double>(loop.size());
    int match = -1;
    for (std::size_t e = 0; e < ends.size(); ++e) {
      if ((centroid - ends[e].centre).norm() > 0.25 * ends[e].radius) continue;
      bool planar = true;
      for (int w : loop)
        planar = planar && std::abs((m.vertices[w] - ends[e].centre).dot(ends[e].outward)) < 1e-6;
      if (planar) match = static_cast<int>(e);
    }
    if (match < 0) {
      ++c.unmatched_loops;
    } else {
      ++end_hits[match];
    }
  }
  c.manifold = c.non_manifold_edges == 0 && c.non_manifold_vertices == 0;
  c.watertight = c.unmatched_loops == 0 &&
                 std::all_of(end_hits.begin(), end_hits.end(), [](int n) { return n == 1; });
  return c;
}

namespace {

// Nearest hit of the ray o + t d (t > 0) with the mesh, by walking the tree's flat nodes
// (Moller-Trumbore for triangles, slabs for boxes); +inf if none.
double ray_hit(const TriangleMesh& m, const AabbTree& tree, const Vec3& o, const Vec3& d) {
  double best = std::numeric_limits<double>::infinity();
  if (tree.empty()) return best;
  const auto& nodes = tree.nodes();
  const auto& order = tree.triangle_order();
  int stack[AabbTree::kMaxDepth * 2];
  int sp = 0;
  stack[sp++] = 0;
  while (sp > 0) {
    const AabbNode& n = nodes[stack[--sp]];
    double t0 = 0.0, t1 = best;
    for (int a = 0; a < 3; ++a) {
      const double inv = 1.0 / d[a];
      double ta = (n.box.lo[a] - o[a]) * inv, tb = (n.box.hi[a] - o[a]) * inv;
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    if (t0 > t1) continue;
    if (!n.is_leaf()) {
      stack[sp++] = n.first;
      stack[sp++] = n.first + 1;
      continue;
    }
    for (int k = n.first; k < n.first + n.count; ++k) {
      const auto& tr = m.triangles[order[k]];
      const Vec3 &a = m.vertices[tr[0]], &b = m.vertices[tr[1]], &c = m.vertices[tr[2]];
      const Vec3 e1 = b - a, e2 = c - a, p = d.cross(e2);
      const double det = e1.dot(p);
      if (std::abs(det) < 1e-30) continue;
      const Vec3 s = o - a;
      const double u = s.dot(p) / det;
      if (u < 0.0 || u > 1.0) continue;
      const Vec3 q = s.cross(e1);
      const double v = d.dot(q) / det;
      if (v < 0.0 || u + v > 1.0) continue;
      const double t = e2.dot(q) / det;
      if (t > 0.0 && t < best) best = t;
    }
  }
  return best;
}

}  // namespace

RadiusSample measure_radius(const TriangleMesh& mesh, const AabbTree& tree,
                            const VesselSegment& seg, double s, int rays) {
  const Vec3 c = point_at(seg, s), t = tangent_at(seg, s);
  const Vec3 u = internal::any_perpendicular(t), w = t.cross(u);
  RadiusSample r;
  r.min = std::numeric_limits<double>::infinity();
  r.max = 0.0;
  for (int k = 0; k < rays; ++k) {
    const double a = 2.0 * std::numbers::pi * (k + 0.5) / rays;
    const double d = ray_hit(mesh, tree, c, std::cos(a) * u + std::sin(a) * w);
    r.mean += d / rays;
    r.min = std::min(r.min, d);
    r.max = std::max(r.max, d);
  }
  return r;
}

}  // namespace vcsim
