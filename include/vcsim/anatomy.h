// vcsim anatomy: the patient's vessel tree (centrelines and radii), the lumen surface built from
// it, lesions, cardiac and respiratory motion, and closed body meshes for imaging.
// SI units inside (m, s, rad). Patient coordinates are DICOM LPS: +x toward the patient's left,
// +y posterior, +z toward the head, so C-arm angles mean what clinicians expect.
// Data files carry units in their key names (points_mm, radius_mm) and are converted at load.
#pragma once

#include "vcsim/collision.h"

#include <cctype>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace vcsim {

// ---------------------------------------------------------------------------------------------
// Vessel tree

// What a segment is; decides mesh resolution (coronaries on a fine grid, 0.1 mm radius error),
// and which body region moves with the heart.
enum class VesselKind : std::uint8_t { kAorta, kArtery, kCoronary, kSinus };
std::string_view to_string(VesselKind kind);

struct VesselSegment {
  std::string name;
  VesselKind kind = VesselKind::kArtery;
  int parent = -1;            // index of the parent segment, -1 for the root
  std::vector<Vec3> points;   // (np) centreline in flow direction (proximal first), m, LPS
  std::vector<double> radii;  // (np) lumen radius at each point, m
  // The distal end is a rounded dead end (an aortic sinus, the aortic valve side of the root).
  // Otherwise a distal end not continued by a child is an open outlet.
  bool closed_end = false;
};

// A place in the tree: `distance` m along a segment's centreline from its first point.
struct TreeLocation {
  int segment = -1;
  double distance = 0.0;
};

// A stenosis. The residual lumen is a circle whose radius follows
//   r(s) = r0(s) (1 - reduction * phi(s)),  phi = (1 - cos(2 pi (s - s0) / length)) / 2,
// and whose centre moves by eccentricity * (r0 - r) away from the plaque side, so at
// eccentricity 1 the residual lumen touches the healthy wall opposite the plaque.
struct Lesion {
  int segment = -1;
  double distance = 0.0;            // m from the segment's ostium to the lesion's start
  double length = 10e-3;            // m
  double diameter_reduction = 0.5;  // fraction in [0, 0.95] at the throat
  double eccentricity = 0.0;        // [0, 1]
  double angle = 0.0;  // rad: plaque side around the centreline, 0 = toward the heart's outside
};

// The heart as an ellipsoid, for placing coronaries on its surface, for motion and imaging.
struct HeartModel {
  Vec3 centre = Vec3::Zero();              // m, LPS
  Vec3 axis = Vec3::UnitZ();               // unit, base -> apex
  Vec3 anterior = Vec3::UnitY();           // unit, perpendicular to axis
  Vec3 radii = Vec3(60e-3, 45e-3, 40e-3);  // m: half-length along axis, along anterior, third
};

struct VesselTree {
  std::string name;
  std::vector<VesselSegment> segments;  // a parent always comes before its children
  std::vector<Lesion> lesions;
  TreeLocation access;      // where instruments enter (e.g. the right common femoral)
  TreeLocation target;      // the treatment site (e.g. a coronary stenosis)
  bool open_start = false;  // the root's first point is an open end (else a rounded dead end)
  std::optional<HeartModel> heart;

  int find(std::string_view name) const;  // index or -1
  int num_segments() const { return static_cast<int>(segments.size()); }
};

// Cumulative arc length at each centreline point, m (front() = 0).
std::vector<double> arc_lengths(const VesselSegment& seg);
double segment_length(const VesselSegment& seg);
// Centreline point, radius and unit tangent at arc length s (clamped to the segment).
Vec3 point_at(const VesselSegment& seg, double s);
double radius_at(const VesselSegment& seg, double s);
Vec3 tangent_at(const VesselSegment& seg, double s);

// Arc length along segment i where its centreline leaves its parent's lumen (0 for the root and
// for a segment continuing its parent's end). Lesion distances are measured from here.
double ostium_distance(const VesselTree& tree, int i);

// Arc length along the parent where segment i's first point projects (the parent's length for
// a continuation); 0 for the root.
double attach_distance(const VesselTree& tree, int i);

// Centreline route between two places (up to their common ancestor and down), as points about
// `spacing` apart, m. The path an instrument follows from the access to the target.
std::vector<Vec3> route(const VesselTree& tree, const TreeLocation& from, const TreeLocation& to,
                        double spacing);

// An open vessel end: a single boundary loop of the lumen mesh.
struct OpenEnd {
  int segment = -1;
  bool at_start = false;  // the segment's first point (only the root with open_start)
  Vec3 centre;            // m
  Vec3 outward;           // unit, pointing out of the vessel
  double radius = 0.0;    // m
};
std::vector<OpenEnd> open_ends(const VesselTree& tree);

// Limits of a vessel tree (docs/anatomy.md), checked by validate_tree: its centrelines fit in a
// box of kMaxTreeExtent a side (a body is under 1 m from groin to heart), and its lumen meshed at
// the default voxel sizes would have at most kMaxLumenTriangles triangles, estimated from the
// wall's area before meshing (a branch 42 m long built 4.7 M triangles in a minute and 1.6 GB).
inline constexpr double kMaxTreeExtent = 2.0;            // m
inline constexpr double kMaxLumenTriangles = 2'000'000;  // estimated, before simplification

// Checks names, topology, point and radius arrays, lesions, access and target, and the limits
// above; throws InputError naming `source` and the offending field.
void validate_tree(const VesselTree& tree, const std::string& source);

// JSON format (data/anatomy/*.json, docs/anatomy.md): units in key names, converted at load.
VesselTree parse_vessel_tree(std::string_view json_text, const std::string& source);
VesselTree load_vessel_tree(const std::string& path);
std::string vessel_tree_to_json(const VesselTree& tree);
void save_vessel_tree(const VesselTree& tree, const std::string& path);

// The built-in patients, generated from clinical dimensions (docs/anatomy.md).
enum class PatientVariant : std::uint8_t {
  kRightDominant,         // the default: right-dominant coronaries, typical arch
  kLeftDominantTortuous,  // left-dominant coronaries, an elongated tortuous arch
};
VesselTree default_patient(PatientVariant variant = PatientVariant::kRightDominant);
// "default" / "right-dominant", "left-dominant"; throws InputError for other names.
PatientVariant patient_variant_from_string(const std::string& name, const std::string& source);

// Variations of a built-in patient for domain randomisation (docs/anatomy.md, "Variations").
struct AnatomyVariation {
  double aorta_radius_scale = 1.0;     // aorta and sinuses' radii times this, 0.5..1.5
  double artery_radius_scale = 1.0;    // other arteries' (branches, iliacs), 0.5..1.5
  double coronary_radius_scale = 1.0;  // coronaries', 0.7..1.3
  // m (0..40 mm): the ascending aorta and arch lengthened upward, the arch top rising by this
  // (an elongated arch, as with age and in type II/III arches); the branches move with it.
  double arch_elongation = 0.0;
  // m (0..8 mm): rms amplitude of a smooth random displacement field bending every centreline,
  // with wavelengths 0.75..1.5 times tortuosity_wavelength (40..400 mm).
  double tortuosity = 0.0;
  double tortuosity_wavelength = 80e-3;
  std::uint64_t seed = 1;                          // of the displacement field
  void validate(const std::string& source) const;  // InputError naming the field
};
// The tree varied: calibre always; shape (elongation, tortuosity) only for a tree without a heart
// (InputError otherwise: coronaries ride on the heart). The access and target keep their arc
// length.
VesselTree vary_anatomy(const VesselTree& tree, const AnatomyVariation& variation);
// The aortic-arch navigation anatomy: the built-in patient's aorta from the valve to the
// diaphragm with its sinuses and the three supra-aortic branches (no heart, no coronaries), the
// access in the descending thoracic aorta 60 % down its length.
VesselTree arch_anatomy(PatientVariant variant = PatientVariant::kRightDominant);

// The tree with each lesion's residual lumen on the centreline: points are resampled at
// `spacing` inside lesions, radii reduced and centres shifted as the lesion mesh is.
VesselTree stenosed_tree(const VesselTree& tree, double spacing = 0.25e-3);

// Healthy radius r0, residual radius and centre offset (toward -plaque direction) of a lesion at
// arc length s of its segment; 1 - r / r0 is the local diameter reduction.
struct LesionProfile {
  double factor = 1.0;  // r / r0
  double shift = 0.0;   // m, centre offset, = eccentricity (r0 - r)
};
LesionProfile lesion_profile(const Lesion& lesion, double ostium, double r0, double s);

// ---------------------------------------------------------------------------------------------
// Where things are in the tree

// The tree location nearest a point: the segment whose lumen (centreline distance minus radius)
// is nearest, and the arc length of the projection.
struct TreeHit {
  TreeLocation loc;
  double outside = 0.0;  // m beyond the lumen radius (< 0 inside)
};
TreeHit locate(const VesselTree& tree, const Vec3& p);

// locate() for a tree searched many times (every step's tip location): its centreline edges in a
// bounding-volume hierarchy whose boxes, less the largest radius below them, bound every edge's
// lumen distance from below, so a search visits only the edges that can beat the best found.
// The answer is locate()'s bit for bit: each edge's distance is computed by the same arithmetic,
// and equal distances go to the edge the brute-force search meets first (segment, then edge).
class TreeLocator {
 public:
  TreeLocator() = default;
  explicit TreeLocator(const VesselTree& tree);
  // Allocates nothing; thread-safe.
  TreeHit locate(const Vec3& p) const;
  int num_edges() const { return static_cast<int>(edges_.size()); }

 private:
  struct Edge {
    Vec3 a, d;         // first point, second minus first
    double len2, len;  // |d|^2, |d|
    double s0;         // arc length of the first point along its segment
    double r0, dr;     // radius at the first point, second minus first
    int segment;
  };
  struct Node {
    Aabb box;  // of the edges' end points
    double r_max = 0.0;
    int first = 0;  // leaf: first edge; internal: left child (right = left + 1)
    int count = 0;  // leaf: edges (> 0); internal: 0
  };
  std::vector<Edge> edges_;  // in a leaf order; `order_` maps back to the brute-force order
  std::vector<int> order_;   // (edge) its index in the brute-force search's order
  std::vector<Node> nodes_;
};
// The same searched only near a known location: its segment, parent and children, within
// `window` m of arc length of it (a point that moved little since; the answer depends only on
// the point and the hint).
TreeHit locate_near(const VesselTree& tree, const Vec3& p, const TreeLocation& hint, double window);
// True when `seg` is `ancestor` or lies below it.
bool is_descendant(const VesselTree& tree, int seg, int ancestor);

// ---------------------------------------------------------------------------------------------
// Lesions that open (docs/anatomy.md, "Lesions that open")

// How far a lesion is opened along its length: 0 as built (stenosed), 1 the healthy lumen, above 1
// stretched beyond it where the plaque was. With opening t the residual lumen is the lesion's with
// its diameter reduction scaled by (1 - t): radius r0 (1 - reduction phi (1 - t)), the centre
// shifted by eccentricity (r0 - r) away from the plaque; the lumen's vertices at the lesion move
// linearly from their stenosed (t = 0) to their healthy (t = 1) positions.
struct LesionOpening {
  std::vector<double> t;  // (samples) evenly from the lesion's start to its end
  // The opening at u in [0, 1] along the lesion (linear between samples).
  double at(double u) const;
};
inline constexpr int kLesionSamples = 65;
// A lesion's start and end as arc lengths of its segment (m).
struct LesionSpan {
  double s0 = 0.0, s1 = 0.0;
};
LesionSpan lesion_span(const VesselTree& tree, const Lesion& lesion);

// The lumen's cross-section at arc length s of a segment: its centre (at rest) and radius.
struct LumenSection {
  Vec3 centre = Vec3::Zero();
  double radius = 0.0;
};
// With the tree's lesions opened as given (`spans` and `openings` one per tree lesion; empty
// `openings`: as built).
LumenSection lumen_section(const VesselTree& tree, std::span<const LesionSpan> spans,
                           std::span<const LesionOpening> openings, int segment, double s);
// The opening at which lesion k's lumen at arc length s has radius r (0 where the plaque does not
// narrow it or r is below its stenosed radius).
double opening_for_radius(const VesselTree& tree, const Lesion& lesion, const LesionSpan& span,
                          double s, double r);

// ---------------------------------------------------------------------------------------------
// Lumen surface

struct LumenSettings {
  double coarse_voxel = 0.6e-3;     // m, lattice spacing for aorta and arteries
  double fine_voxel = 0.2e-3;       // m, lattice spacing for coronaries
  double coronary_error = 0.06e-3;  // m, simplification error bound in coronaries
  double aorta_error = 0.25e-3;     // m, in the aorta (arteries: min of this and 4 % of r)
  double lesion_error = 0.02e-3;    // m, around lesions (the balloon morphs this region)
  bool use_cache = true;
  std::string cache_dir;  // empty: $XDG_CACHE_HOME/vcsim/anatomy or ~/.cache/vcsim/anatomy
};

// The triangles marching tetrahedra would make of the tree's wall at these voxel sizes (its
// swept area over the voxel's square, twice): what build_lumen refuses above kMaxLumenTriangles.
double estimated_lumen_triangles(const VesselTree& tree, const LumenSettings& st);

struct Lumen {
  TriangleMesh mesh;                   // the lumen wall, normals into the lumen (lesions applied)
  std::vector<Vec3> healthy_vertices;  // (nv) the same vertices without lesions, m
  std::vector<int> vertex_segment;     // (nv) segment whose swept sphere holds the vertex
  std::vector<double> vertex_arc;      // (nv) arc length of the vertex along that segment, m
  std::vector<int> triangle_segment;   // (nt) segment of the triangle's first vertex
  std::vector<OpenEnd> ends;           // the open vessel ends
  MeshReport report;                   // check_and_repair of the final mesh
  double build_seconds = 0.0;
  std::string cache_status;  // "off", "hit", "miss", or "rebuilt: <why the cache was refused>"
};

// Builds the lumen: the union of spheres swept along every centreline, meshed by sparse marching
// tetrahedra (aorta and coronaries on separate grids joined by a strip), projected onto the exact
// surface, cut flat at open ends, simplified by edge collapses within the error bounds of the
// exact surface, then lesions applied (docs/anatomy.md). Uses two threads. Cached on disk by a
// hash of the tree and settings; a stale or corrupt cache file is never used (cache_status says
// why it was rebuilt). Throws InputError for an invalid tree.
Lumen build_lumen(const VesselTree& tree, const LumenSettings& settings = {});

// The lumen vertices the lesions move, and where each lies along its lesion (built once).
struct LesionMorph {
  std::vector<int> vertices;  // lumen vertices whose stenosed and healthy positions differ
  std::vector<int> lesion;    // (vertices) which lesion moves it
  std::vector<double> u;      // (vertices) its position along that lesion, 0 .. 1
};
LesionMorph make_lesion_morph(const VesselTree& tree, const Lumen& lumen);
// The morph's vertices at the given openings (one per tree lesion): stenosed + t (healthy -
// stenosed), into `out` (one per morph vertex). With `uniform` >= 0 every lesion at that opening.
void morph_positions(const Lumen& lumen, const LesionMorph& morph,
                     std::span<const LesionOpening> openings, std::span<Vec3> out);
void morph_positions(const Lumen& lumen, const LesionMorph& morph, double uniform,
                     std::span<Vec3> out);

// Lumen radius of a segment measured on the mesh at arc length s: distances from the centreline
// point to the wall along `rays` rays in the normal plane; their mean, min and max.
struct RadiusSample {
  double mean = 0.0, min = 0.0, max = 0.0;  // m
};
RadiusSample measure_radius(const TriangleMesh& mesh, const AabbTree& tree,
                            const VesselSegment& seg, double s, int rays = 16);

// Mesh quality in the terms of the issue: closed except at the designated open ends (each one
// clean boundary loop), manifold edges and vertices.
struct LumenCheck {
  int triangles = 0, vertices = 0;
  int boundary_loops = 0;
  int open_ends = 0;
  int unmatched_loops = 0;  // loops not at a designated open end
  int non_manifold_edges = 0;
  int non_manifold_vertices = 0;  // vertices whose triangles do not form one fan
  int components = 0;
  bool watertight = false;  // every loop is one designated open end and every end has one loop
  bool manifold = false;
};
LumenCheck check_lumen(const TriangleMesh& mesh, const std::vector<OpenEnd>& ends);

// A patient mesh (STL, OBJ, PLY in `unit_scale` m per file unit) with its centrelines (our JSON
// or a Vascular Model Repository .pth file): the mesh is checked and repaired, vertices are
// assigned to the nearest segment. Radii missing from a .pth file are measured on the mesh.
Lumen import_lumen(const std::string& mesh_path, const VesselTree& centrelines,
                   double unit_scale = 1e-3);
// Reads the paths of a SimVascular .pth file (XML, coordinates in `unit_scale` m per unit) as
// segments without parents; radii are left empty for measure_radii_on_mesh.
VesselTree load_pth_paths(const std::string& path, double unit_scale = 1e-3);
// The same from the file's text; `source` names it in errors.
VesselTree parse_pth_paths(const std::string& text, const std::string& source,
                           double unit_scale = 1e-3);
// Fills empty radii from the mesh (closest-wall distance), links each segment to the segment
// whose lumen holds its first point, and validates the tree.
void measure_radii_on_mesh(VesselTree& tree, const TriangleMesh& mesh, const std::string& source);
// The centrelines of an imported lumen mesh: a vcsim-anatomy JSON, or a SimVascular .pth whose
// radii are measured on the mesh (`mesh_path`, read with `unit_scale` m per file unit, as the
// .pth's points are).
VesselTree load_mesh_centrelines(const std::string& centrelines_path, const std::string& mesh_path,
                                 double unit_scale);
// Centrelines computed from a lumen mesh by geodesic level sets (Lazarus and Verroust 1999;
// docs/anatomy.md, "Centrelines from a mesh"): from the open end nearest `inlet_near`, bands of
// geodesic distance at least `band` m wide (and 1.5 edge lengths) cut into rings whose centroids
// and mean radii make the segments; a ring meeting several later rings branches. Segments are
// named inlet, branch_1, ...; the access is 2 mm into the inlet (open_start). InputError naming
// `source` for a closed mesh or one too small.
VesselTree centrelines_from_mesh(const TriangleMesh& mesh, const Vec3& inlet_near,
                                 const std::string& source, double band = 0.0);
// Is `path` a lumen mesh file (.stl, .obj, .ply, any case)?
inline bool is_mesh_file(std::string_view path) {
  const std::size_t dot = path.rfind('.');
  if (dot == std::string_view::npos || path.size() - dot != 4) return false;
  std::string e(path.substr(dot));
  for (char& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return e == ".stl" || e == ".obj" || e == ".ply";
}

// ---------------------------------------------------------------------------------------------
// Cardiac and respiratory motion

struct MotionSettings {
  double heart_rate_bpm = 70.0;
  // End-diastole -> end-systole displacement of the heart: a swing along the long axis, radial
  // contraction toward the axis and longitudinal shortening toward the centre (fractions of the
  // distance), and a twist growing toward the apex (docs/anatomy.md: coronaries move 3-7 mm,
  // more distally; the vessel calibre shrinks by about the contraction fractions).
  double translation = 0.0;  // m, along the base -> apex axis
  double radial_contraction = 0.085;
  double longitudinal_contraction = 0.075;
  double twist = 0.05;  // rad at the apex, end-systole
  bool respiration = false;
  double respiratory_rate_per_min = 15.0;
  double respiratory_shift = 4.9e-3;    // m, caudal at full inspiration (clinical.md)
  double respiratory_rotation = 0.026;  // rad (1.5 deg) about the left-right axis

  void validate(const std::string& source) const;
};

// Smooth displacement field u(X, t) = w_h(X) c(t) U_c(X) + w_r(X) r(t) U_r(X): c(t) in [0, 1] is
// the cardiac waveform (0 at end-diastole, 1 at end-systole, rest plateaus at end-systole and in
// diastasis), r(t) in [0, 1] the respiratory one (0 at end-expiration); w_h is 1 on the heart
// away from the aortic root and fades to 0 at the root and away from the heart, so proximal
// coronaries move less than distal ones and the aorta stays still.
class CardiacMotion {
 public:
  CardiacMotion() = default;
  // Needs tree.heart (InputError otherwise); the root's first point is the aortic valve.
  CardiacMotion(const VesselTree& tree, const MotionSettings& settings);

  double cardiac_waveform(double t) const;      // c(t), t in s
  double respiratory_waveform(double t) const;  // r(t)
  double cardiac_rate(double t) const;          // dc/dt, 1/s
  double respiratory_rate(double t) const;      // dr/dt, 1/s
  double period() const { return 60.0 / settings_.heart_rate_bpm; }

  // Per-point amplitudes: u(X, t) = a_cardiac c(t) + a_resp r(t).
  void amplitudes(const Vec3& X, Vec3& a_cardiac, Vec3& a_resp) const;
  Vec3 displacement(const Vec3& X, double t) const;
  Vec3 velocity(const Vec3& X, double t) const;  // du/dt at the rest point X, m/s
  // The rest point X of a point p seen at time t: X = p - u(X, t) by three fixed-point steps (u is
  // smooth and small against its length scale).
  Vec3 rest_point(const Vec3& p, double t) const;

  // The tree's centrelines moved to time t (the same field as the mesh vertices).
  VesselTree moved_tree(const VesselTree& rest, double t) const;

  const MotionSettings& settings() const { return settings_; }
  const HeartModel& heart() const { return heart_; }

 private:
  HeartModel heart_;
  Vec3 valve_ = Vec3::Zero();
  MotionSettings settings_;
};

// The lumen split into patches, each a small mesh with its own AABB tree, so that a step moves
// and refits only the patches instruments can touch. Static patches (no motion) never update.
struct BeatingLumenSettings {
  // Triangles per patch at most: small patches are partial rings whose boxes a node in the middle
  // of the lumen does not overlap, so only the wall near the instruments moves each step.
  int patch_triangles = 16;
  AabbTreeSettings tree;
};

struct BeatingLumenProfile {
  int patches_updated = 0;
  int triangles_updated = 0;
  double us = 0.0;  // wall time of the update
};

class BeatingLumen {
 public:
  BeatingLumen() = default;
  BeatingLumen(const TriangleMesh& rest, const CardiacMotion& motion,
               const BeatingLumenSettings& settings = {});
  // A lumen whose `morph_vertices` may later move at rest (a lesion opened, morph()) as far as
  // `morph_limit` (one per morph vertex): the patches' boxes cover both.
  BeatingLumen(const TriangleMesh& rest, const CardiacMotion& motion,
               std::span<const int> morph_vertices, std::span<const Vec3> morph_limit,
               const BeatingLumenSettings& settings = {});

  // Moves the morph vertices at rest (one position per vertex of the constructor's list, between
  // their rest and limit positions); the patches holding them are moved again at their next
  // update. Allocates nothing.
  void morph(std::span<const Vec3> rest_positions);

  // Moves to time t (s) the moving patches that any sphere (centres, radii; radii may hold one
  // value) may touch at t, recomputes their normals and refits their trees. A patch is touched
  // if the sphere overlaps a box that holds the patch at t (its rest box plus the waveforms times
  // the boxes of its vertices' amplitudes). Other patches keep their last pose until touched. Radii
  // should include any escape distance the queries will use. Allocates nothing.
  BeatingLumenProfile update(double t, std::span<const Vec3> centres,
                             std::span<const double> radii);
  // update(t, centres, radii) then query_spheres(centres, radii, caches, slack, out) in one pass:
  // each sphere moves the patches it may touch as it meets them. The same patches move and the
  // same contacts come out as from the two calls (a patch whose moved box overlaps a sphere is
  // one whose box from the waveforms does), without walking the grid twice. Allocates nothing.
  void move_and_query(double t, std::span<const Vec3> centres, std::span<const double> radii,
                      std::span<LeafCache* const> caches, double slack,
                      std::span<SphereContact> out);
  // Where segment a-b crosses the wall at t: the static part's tree and the moving patches near
  // it, moved to t as move_and_query moves them. Allocates nothing.
  SegmentCrossings segment_crossings(double t, const Vec3& a, const Vec3& b);
  // Moves every patch (rendering, tests); the same as update() with spheres everywhere.
  BeatingLumenProfile update_all(double t);

  // Contact of each sphere with the wall as last updated: the closest contact over the patches
  // whose boxes the sphere overlaps (triangle in the rest mesh's numbering; num_touching summed).
  // Allocates nothing; not thread-safe (shared scratch).
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<SphereContact> out, const SphereQuerySettings& settings = {}) const;
  // The same with a leaf cache per sphere for the part that never moves (see LeafCache; the
  // moving patches are traversed as above, their leaves move). The caches must be cleared when
  // the lumen is morphed. Results equal the uncached query's exactly.
  void query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                     std::span<LeafCache* const> caches, double slack, std::span<SphereContact> out,
                     const SphereQuerySettings& settings = {}) const;

  // The whole wall at the last update of each patch: `out` holds a copy of the rest mesh, whose
  // vertices and normals are overwritten.
  void gather(TriangleMesh& out) const;

  // Whether any moving part of the wall can ever (any phase, any breath, any lesion opening) come
  // within `radius` of `centre`: false lets a contact query's clearance there stay valid while
  // the heart beats. Allocates nothing; not thread-safe (shared scratch).
  bool moves_near(const Vec3& centre, double radius) const;

  int num_patches() const { return static_cast<int>(patches_.size()); }  // moving patches
  const CardiacMotion& motion() const { return motion_; }
  // Largest displacement amplitudes over the moving vertices (m): |a_cardiac|, |a_resp|.
  double max_cardiac_amplitude() const { return max_amp_c_; }
  double max_respiratory_amplitude() const { return max_amp_r_; }
  int num_static_triangles() const { return static_.mesh.num_triangles(); }
  int num_triangles() const { return num_triangles_; }

 private:
  struct Patch {
    TriangleMesh mesh;  // a moving patch's triangles in its build tree's visit order
    AabbTree tree;      // the static part's only: a moving patch is queried triangle by triangle
    std::vector<int> global_vertex;             // local vertex -> rest mesh vertex
    std::vector<int> global_triangle;           // local triangle -> rest mesh triangle
    std::vector<Vec3> rest, a_cardiac, a_resp;  // (nv local)
    Aabb reach;  // rest box grown by the largest displacement: where it can ever be
    Aabb box;    // box at the last update (fat margin included)
    // Vertices move linearly in the waveforms, so the box at (c, r) lies within
    // rest_box + c * box(a_cardiac) + r * box(a_resp) (Minkowski sums of boxes).
    Aabb rest_box, amp_c_box, amp_r_box;
    bool moving = false;
    double time = -1.0;  // time of the last update
  };
  // Broad phase: a uniform grid whose cells list the patches whose reach boxes overlap them.
  struct PatchGrid {
    Vec3 origin = Vec3::Zero();
    double cell = 0.01;
    int nx = 0, ny = 0, nz = 0;
    std::vector<int> start, list;
  };
  template <typename BoxOf>
  void build_grid(PatchGrid& g, bool moving_only, BoxOf&& box_of);
  Aabb box_at(const Patch& p, double c, double r) const;
  void move_patch(Patch& p, double c, double r, double t);
  // Calls f(patch index) once for each patch of the grid whose reach box overlaps the sphere.
  template <typename F>
  void for_each_candidate(const PatchGrid& g, const Vec3& centre, double radius, F&& f) const;

  Patch static_;                // every triangle that never moves, one tree
  std::vector<Patch> patches_;  // the moving triangles
  CardiacMotion motion_;
  std::size_t last_grid_ = 0;
  double last_time_ = -1.0;
  int num_triangles_ = 0;
  int num_vertices_ = 0;
  double max_amp_c_ = 0.0, max_amp_r_ = 0.0;
  double margin_ = 0.0;  // m, the fat margin of a moving patch's box
  // Moving patches binned by their box at cardiac phases c = k / (n - 1), each grown to cover
  // half a bin either side and any respiration, so a node is looked up in the grid of its phase.
  std::vector<PatchGrid> phase_grids_;
  PatchGrid reach_grid_;  // moving patches binned by their reach boxes (moves_near)
  // Morph vertices: their places in the patches (patch index, -1 for the static part; local
  // vertex), listed from morph_start_[k] to morph_start_[k + 1] for morph vertex k.
  std::vector<int> morph_start_, morph_patch_, morph_local_;
  mutable std::vector<std::uint32_t> seen_;  // per-patch stamps (scratch, no allocation)
  mutable std::uint32_t stamp_ = 0;
};

// ---------------------------------------------------------------------------------------------
// Body context for imaging

enum class Material : std::uint8_t { kSoftTissue, kLung, kHeart, kBone, kBlood };
std::string_view to_string(Material m);

struct BodyPart {
  std::string name;  // torso, lung_left, lung_right, heart, spine, ribs, sternum, diaphragm
  Material material = Material::kSoftTissue;
  TriangleMesh mesh;  // closed, normals outward (away from the part's interior), m, LPS
};

// Closed meshes registered to the tree: the heart is the tree's HeartModel, the spine sits behind
// the descending aorta, the diaphragm dome under the heart. Needs tree.heart.
std::vector<BodyPart> build_body_context(const VesselTree& tree);

}  // namespace vcsim
