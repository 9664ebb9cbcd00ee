// vcsim collision: the vessel lumen as a triangle mesh, a flat AABB tree over its triangles
// (built once, refitted when the wall moves) and sphere queries for instrument nodes.
// SI units: lengths in metres. Every triangle normal faces INTO the lumen (the vessel interior),
// so a contact normal is the direction in which to push an instrument node back inside.
#pragma once

#include "vcsim/core.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <utility>
#include <vector>

namespace vcsim {

// ---------------------------------------------------------------------------------------------
// Mesh

// Indexed triangle mesh. The winding of a triangle (a, b, c) defines its normal
// n = (b - a) x (c - a) / |...|, which after check_and_repair faces into the lumen.
struct TriangleMesh {
  std::vector<Vec3> vertices;                 // (nv) positions, m
  std::vector<std::array<int, 3>> triangles;  // (nt) vertex indices
  std::vector<Vec3> normals;                  // (nt) unit normals into the lumen

  int num_vertices() const { return static_cast<int>(vertices.size()); }
  int num_triangles() const { return static_cast<int>(triangles.size()); }

  // Recomputes `normals` from the winding; call after the vertices move.
  // A zero-area triangle gets a zero normal.
  void recompute_normals();
};

// What check_and_repair found and changed.
struct MeshReport {
  int vertices = 0;                 // after repair
  int triangles = 0;                // after repair
  int degenerate_removed = 0;       // zero-area or repeated-index triangles dropped
  int duplicates_removed = 0;       // triangles on the same three vertices as an earlier one
  int unused_vertices_removed = 0;  // vertices no triangle refers to (indices compacted)
  int components = 0;               // edge-connected components
  int boundary_edges = 0;           // edges used by one triangle (open vessel ends)
  std::vector<std::vector<int>> boundary_loops;  // each open end as an ordered vertex loop
  int flipped_for_consistency = 0;  // triangles flipped so neighbours agree across shared edges
  int flipped_for_lumen = 0;        // triangles flipped so that normals face the lumen
  std::vector<double> component_volumes;  // (components) lumen volume, m^3, open ends capped

  // One line per finding, for logs and the CLI.
  std::string summary() const;
};

// Checks the mesh and repairs what can be repaired, in this order:
//  1. indices in range and coordinates finite (else InputError);
//  2. degenerate triangles (repeated index, zero area) and duplicates (same three vertices)
//     removed, unused vertices dropped;
//  3. non-manifold edges (shared by more than two triangles): InputError naming
//     `vcsim anatomy repair` (repair_mesh);
//  4. orientation made consistent by flood fill across shared edges; a non-orientable
//     component (Moebius-like) is refused with InputError;
//  5. each component oriented so that its normals face the lumen: the signed volume of the
//     component closed with fan caps over its boundary loops must be positive inside;
//  6. normals recomputed.
// Open boundary loops are expected at vessel ends and only reported. `source` (a file path or
// a description) names the mesh in error messages.
MeshReport check_and_repair(TriangleMesh& mesh, const std::string& source = "mesh");

// What repair_mesh changed.
struct MeshRepairReport {
  int non_manifold_edges = 0;           // edges shared by more than two triangles, as found
  int non_manifold_dropped = 0;         // triangles dropped so that each edge has at most two
  int degenerate_removed = 0;           // zero-area or repeated-index triangles dropped
  int duplicates_removed = 0;           // triangles on the same three vertices as an earlier one
  int components_dropped = 0;           // small disconnected pieces dropped
  int component_triangles_dropped = 0;  // their triangles
  int unused_vertices_removed = 0;
  int triangles_before = 0, triangles_after = 0;

  // One line per change, for the CLI.
  std::string summary() const;
};

struct MeshRepairSettings {
  // A component (edge-connected) with fewer triangles than this fraction of the largest one is
  // dropped (loose fins, specks left by segmentation).
  double min_component_fraction = 0.01;
};

// Makes a mesh with small defects one that check_and_repair accepts: degenerate and duplicate
// triangles removed; on each edge shared by more than two triangles, the two that best continue
// the surface kept (opposite windings along the edge first, then the most triangles whose other
// edges are manifold, then the flattest dihedral) and the others dropped, repeated until every
// edge has at most two; components below settings.min_component_fraction of the largest
// dropped; unused vertices removed. Throws InputError (naming `source`) for indices out of range,
// non-finite coordinates or nothing left. Does not orient: run check_and_repair after it.
MeshRepairReport repair_mesh(TriangleMesh& mesh, const std::string& source = "mesh",
                             const MeshRepairSettings& settings = {});

// ---------------------------------------------------------------------------------------------
// Geometry kernels

// Which feature of a triangle holds the closest point (Ericson, RTCD 5.1.5).
enum class TriangleRegion : std::uint8_t {
  kFace,
  kEdgeAB,
  kEdgeBC,
  kEdgeCA,
  kVertexA,
  kVertexB,
  kVertexC
};

struct ClosestPoint {
  Vec3 point;
  TriangleRegion region;
};

// Closest point to p on triangle (a, b, c) by Voronoi regions (Ericson, RTCD 5.1.5).
ClosestPoint closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c);

// Where segment a-b crosses triangle (v0, v1, v2), either face: its parameter t in [0, 1] along
// a-b, or -1 when it does not (Moller and Trumbore 1997; a segment in the triangle's plane does
// not cross it).
double segment_triangle_crossing(const Vec3& a, const Vec3& b, const Vec3& v0, const Vec3& v1,
                                 const Vec3& v2);

// The first and last crossings of segment a-b with a mesh's triangles, as parameters along it.
struct SegmentCrossings {
  int count = 0;  // triangles crossed
  double first = 2.0, last = -1.0;
  void add(double t) {
    ++count;
    first = std::min(first, t);
    last = std::max(last, t);
  }
};

// Every triangle of `mesh` tested, without a tree (a beating lumen's small patches).
SegmentCrossings segment_crossings_each(const TriangleMesh& mesh, const Vec3& a, const Vec3& b);

// ---------------------------------------------------------------------------------------------
// AABB tree

struct Aabb {
  Vec3 lo = Vec3::Constant(0.0);
  Vec3 hi = Vec3::Constant(0.0);
  bool contains(const Aabb& o) const {
    return (lo.array() <= o.lo.array()).all() && (o.hi.array() <= hi.array()).all();
  }
};

// One node of the flat tree. Children are allocated in pairs after their parent, so a child's
// index is always larger than its parent's (refit walks the array backwards).
struct AabbNode {
  Aabb box;
  int first = 0;  // leaf: first slot in AabbTree::triangle_order(); internal: left child index
  int count = 0;  // leaf: number of triangles (> 0); internal: 0 (right child = left + 1)
  bool is_leaf() const { return count > 0; }
};

struct AabbTreeSettings {
  int max_leaf_size = 4;  // triangles per leaf at most (a leaf may stop earlier by SAH)
  int bins = 16;          // SAH bins per axis (Wald 2007)
  double margin = 1e-4;   // m, "fat" margin added to every leaf box at build and refit

  // A mesh that never moves needs no fat margin: tight leaf boxes let queries reach fewer
  // leaves. The contacts are the same (a triangle within reach is in a leaf whose tight box is
  // within reach, and leaves are visited in the same order): 9 % fewer query instructions in
  // the compression experiment.
  static AabbTreeSettings for_static_mesh() {
    AabbTreeSettings s;
    s.margin = 0.0;
    return s;
  }
};

// Contact of one sphere (an instrument node) with the lumen wall.
struct SphereContact {
  bool touching = false;
  bool centre_outside = false;  // the centre is behind the wall (outside the lumen)
  double depth = 0.0;           // m: radius - distance inside; radius + distance behind the wall
  double distance = 0.0;        // m: distance from the centre to the closest wall point
  Vec3 normal = Vec3::Zero();   // unit, into the lumen: push direction (zero if not touching)
  Vec3 point = Vec3::Zero();    // closest wall point, m
  int triangle = -1;            // triangle holding `point`
  int num_touching = 0;         // triangles overlapping the sphere
  // The closed end (VesselWall::exits index, WallExit::closed) whose cap holds `point`; -1: the
  // mesh (or a stent). A centre behind a cap is outside the vessel, as behind the mesh.
  int cap = -1;
  // The sums the result came from, so that queries of the parts of one wall can be merged into
  // the query of the whole (SphereContactMerge): the closest feature's pseudo-normal over the
  // part's faces at it, and the overlapping faces' normals weighted by depth times area.
  Vec3 side_sum = Vec3::Zero();
  int side_dim = -1;  // that feature's dimension: 0 a vertex, 1 an edge, 2 a face's interior
  Vec3 normal_sum = Vec3::Zero();
  double weight_sum = 0.0;
};

// One sphere's queries against disjoint parts of one wall (a beating lumen's patches), merged into
// what the query of the whole wall gives. A vertex or edge on the seam between parts has faces in
// each, so each part alone sees only some of them: its pseudo-normal there can point the wrong
// way, and the closest part alone read a centre 1.7 mm inside the lumen as 2.7 mm behind the wall
// (a variant of the default run: its guide at the left main, anatomy.md). Merging sums the parts'
// pseudo-normals at the closest feature (all parts equally close within rounding) and their
// weighted normals, then decides side, depth and normal as one query does.
class SphereContactMerge {
 public:
  // A part's answer; `triangle` replaces part.triangle (the part's local index) in the result.
  void add(const SphereContact& part, int triangle);
  SphereContact result(const Vec3& centre, double radius) const;

 private:
  double d_min_ = std::numeric_limits<double>::infinity();
  Vec3 point_ = Vec3::Zero();
  int triangle_ = -1;
  int dim_ = -1;  // dimension of the closest feature (SphereContact::side_dim)
  Vec3 side_ = Vec3::Zero(), normal_sum_ = Vec3::Zero(), fallback_ = Vec3::Zero();
  double weight_ = 0.0;
  int touching_ = 0;
};

struct SphereQuerySettings {
  // m: a centre up to radius + escape_distance behind the wall still gives a contact (deeper
  // escapes are taken as "not near the wall"). 0 detects whatever the sphere overlaps.
  double escape_distance = 0.0;
};

// The leaves near one sphere, remembered between queries (temporal coherence, as a Verlet list
// of leaves): every leaf whose box lies within `reach` of `centre` is in `leaves`. A later sphere
// of search radius s at c needs no traversal while |c - centre| + s <= reach, since every leaf it
// can touch is listed. Valid for the tree's boxes as they were when it was filled: after a refit
// (a moving wall) call clear(). Plain data, no allocation.
struct LeafCache {
  static constexpr int kCapacity = 32;
  Vec3 centre = Vec3::Zero();
  double reach = -1.0;  // m; < 0: empty
  int count = 0;
  std::array<int, kCapacity> leaves{};
  void clear() { reach = -1.0; }
};

// Contact of one sphere with every triangle of `mesh` in index order, without a tree: for a mesh
// of a few triangles that moves every step (no refit). The same rules as AabbTree::query_sphere;
// with the triangles in the tree's visit_order the result equals the tree's exactly.
SphereContact query_sphere_each(const TriangleMesh& mesh, const Vec3& centre, double radius,
                                const SphereQuerySettings& settings = {});

class AabbTree {
 public:
  AabbTree() = default;

  // Builds the topology with a binned SAH (Wald 2007) and fits the boxes. The mesh must have
  // passed check_and_repair (normals set).
  void build(const TriangleMesh& mesh, const AabbTreeSettings& settings = {});

  // Recomputes every box bottom-up in place after the vertices moved (same triangles, same
  // topology); leaf boxes get the fat margin. No allocation.
  void refit(const TriangleMesh& mesh);

  // Contact of one sphere (centre, radius in m) with the mesh the tree was built on.
  SphereContact query_sphere(const TriangleMesh& mesh, const Vec3& centre, double radius,
                             const SphereQuerySettings& settings = {}) const;

  // The same contact through a leaf cache: reuses `cache` when it covers the sphere, otherwise
  // refills it by a traversal reaching `slack` m further (a sphere that moves less than `slack`
  // between queries then skips the traversal). Results equal query_sphere's exactly.
  SphereContact query_sphere(const TriangleMesh& mesh, const Vec3& centre, double radius,
                             double slack, LeafCache& cache,
                             const SphereQuerySettings& settings = {}) const;

  // The crossings of segment a-b with the mesh the tree was built on (the leaves whose boxes the
  // segment passes through, by the slab test).
  SegmentCrossings segment_crossings(const TriangleMesh& mesh, const Vec3& a, const Vec3& b) const;

  // Batch query for N spheres into preallocated outputs: out[i] for centres[i], radii[i]
  // (radii may hold one value for all). Allocates nothing.
  void query_spheres(const TriangleMesh& mesh, std::span<const Vec3> centres,
                     std::span<const double> radii, std::span<SphereContact> out,
                     const SphereQuerySettings& settings = {}) const;

  // The triangles in the order every query meets them: a query skips the leaves its sphere does
  // not reach but never reorders the rest. A mesh of a few triangles stored in this order can be
  // queried with query_sphere_each and no tree, with the same result.
  std::vector<int> visit_order() const;

  const std::vector<AabbNode>& nodes() const { return nodes_; }
  const std::vector<int>& triangle_order() const { return order_; }  // leaf slots -> triangle
  int depth() const { return depth_; }
  bool empty() const { return nodes_.empty(); }
  const AabbTreeSettings& settings() const { return settings_; }

  // Traversal uses a fixed stack of this size; the build keeps the depth below it.
  static constexpr int kMaxDepth = 96;

 private:
  std::vector<AabbNode> nodes_;
  std::vector<int> order_;
  int depth_ = 0;
  int num_triangles_ = 0;
  AabbTreeSettings settings_;
};

// ---------------------------------------------------------------------------------------------
// The wall instruments collide with

// An end of the lumen the mesh leaves open (the femoral access, the arch branches, the distal
// coronaries): the disc a node crosses when it leaves the vessel there. A `closed` end is a cut
// end of a vessel that goes on in a body (physics.md 6.4): the wall closes it with a cap beyond
// the disc (its contacts carry SphereContact::cap), so it is no way out; a node behind the cap is
// outside the vessel.
struct WallExit {
  Vec3 centre = Vec3::Zero();   // m, the disc's centre (on the vessel's centreline)
  Vec3 outward = Vec3::Zero();  // unit, out of the vessel
  double radius = 0.0;          // m
  bool closed = false;
  // The end the instruments come in by (a built-in or tree lumen's access end): open for the
  // instruments' held part and the sheath on its axis, a cut end like the others for free nodes,
  // which meet its plane as a wall (physics.md 6.3).
  bool access = false;
};

// The openings of a mesh as exits, one per boundary loop (MeshReport::boundary_loops, vertex
// indices of `mesh`): the disc at the loop's centroid, in the plane of its Newell normal (Newell's
// method, as in Sutherland, Sproull and Schumacker 1974), turned away from the mesh's triangles
// next to the loop, reaching the loop's farthest vertex. A loop of fewer than 3 vertices or with
// no area gives no exit.
std::vector<WallExit> mesh_exits(const TriangleMesh& mesh,
                                 const std::vector<std::vector<int>>& loops);

// What instruments collide with: a static lumen (StaticWall) or a moving one (anatomy's
// BeatingWall). The solver sets the time of each (sub-)step, then asks once per step and
// instrument for the contacts of spheres (nodes); a moving wall first brings the part of itself
// those spheres can reach to that time, so the interface is not const. Its answers must depend
// only on the time and the spheres, never on earlier queries, so that a restored state replays
// bit for bit. Owned by the caller; one wall serves every instrument of a step.
class VesselWall {
 public:
  virtual ~VesselWall() = default;
  // Time (s) the next queries see; a static wall ignores it.
  virtual void set_time(double t) { (void)t; }
  // Contact of each sphere with the wall (see AabbTree::query_spheres). Allocates nothing.
  virtual void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                             std::span<SphereContact> out) = 0;
  // The same with a leaf cache per sphere (see LeafCache), refilled reaching `slack` m further.
  // A wall that is not one static tree ignores the caches (the default).
  virtual void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                             std::span<LeafCache* const> caches, double slack,
                             std::span<SphereContact> out) {
    (void)caches;
    (void)slack;
    query_spheres(centres, radii, out);
  }
  // Velocity of the wall (m/s) at a contact the last query returned; zero for a static wall.
  virtual Vec3 velocity(const SphereContact& hit) const {
    (void)hit;
    return Vec3::Zero();
  }
  // Bound on the wall's speed anywhere (m/s), 0 for a static wall. Lets the contact detection
  // skip nodes that cannot have reached the wall since their last query.
  virtual double speed_bound() const { return 0.0; }
  // Whether a moving part of the wall can ever come within `radius` of `centre` (any moving wall
  // anywhere by default). False lets the contact detection keep a clearance measured there
  // while the wall moves elsewhere (a node in the still aorta while the heart beats).
  virtual bool moves_near(const Vec3& centre, double radius) const {
    (void)centre;
    (void)radius;
    return speed_bound() > 0.0;
  }
  // Where segment a-b (an edge between two nodes) crosses the lumen's wall at the time set: the
  // mesh only, not a stent or a cap. Used sparsely, by the escape check of the edges between
  // nodes (physics.md 6.3). Allocates nothing.
  virtual SegmentCrossings segment_crossings(const Vec3& a, const Vec3& b) = 0;
  // The lumen's open ends at the time set (none by default): a node beyond one has left the
  // vessel (the solver's escape check, physics.md 6.3), unless the end is closed (its cap's
  // contacts say so instead). Allocates nothing.
  virtual std::span<const WallExit> exits() { return {}; }
};

// A wall that does not move: a lumen mesh and its AABB tree (owned elsewhere, must outlive it).
// The cached queries of a batch are independent (each writes its own contact and leaf cache), so
// a batch of at least `parallel_min` spheres is split across the TBB worker threads, in chunks of
// at least kParallelChunk; the results do not depend on the number of threads. 0: always serial.
class StaticWall final : public VesselWall {
 public:
  static constexpr int kParallelChunk = 8;
  StaticWall(const TriangleMesh& mesh, const AabbTree& tree, int parallel_min = 2 * kParallelChunk)
      : mesh_(&mesh), tree_(&tree), parallel_min_(parallel_min) {}
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<SphereContact> out) override;
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<LeafCache* const> caches, double slack,
                     std::span<SphereContact> out) override;
  SegmentCrossings segment_crossings(const Vec3& a, const Vec3& b) override {
    return tree_->segment_crossings(*mesh_, a, b);
  }
  // The mesh's open ends (none unless set).
  void set_exits(std::vector<WallExit> exits) { exits_ = std::move(exits); }
  std::span<const WallExit> exits() override { return exits_; }

 private:
  const TriangleMesh* mesh_;
  const AabbTree* tree_;
  int parallel_min_;
  std::vector<WallExit> exits_;
};

// ---------------------------------------------------------------------------------------------
// Procedural tubes (vessel phantoms for tests and experiments)

struct TubeSpec {
  std::vector<Vec3> centreline;  // polyline, m, at least 2 distinct points
  double radius = 2e-3;          // m
  int sides = 32;                // vertices around each ring (>= 3)
  int rings = 64;                // cross-sections along the centreline (>= 2)
  bool cap_end = false;          // close the far end with a flat fan cap (a dead-end tube)
};

// Sweeps a circle along the centreline with rotation-minimising frames; rings are evenly spaced
// by arc length. Normals face the lumen. Throws InputError for a bad spec.
TriangleMesh make_tube(const TubeSpec& spec);

// Centreline: straight1 along +z from the origin, then an arc of bend_radius through
// bend_angle (rad) turning toward +x, then straight2. Points at most max_segment apart.
std::vector<Vec3> bent_centreline(double straight1, double bend_radius, double bend_angle,
                                  double straight2, double max_segment = 5e-4);

struct BentTubeSpec {
  double straight1 = 20e-3;                // m
  double bend_radius = 15e-3;              // m, of the centreline arc
  double bend_angle = 1.5707963267948966;  // rad
  double straight2 = 20e-3;                // m
  double radius = 2e-3;                    // m, lumen radius
  int sides = 32;
  double ring_spacing = 1e-3;  // m, along the centreline
  bool cap_end = false;
};

TriangleMesh make_bent_tube(const BentTubeSpec& spec);

}  // namespace vcsim
