// Internal: from an implicit lumen (field.h) to a clean triangle mesh.
#pragma once

#include <vector>

#include "field.h"
#include "vcsim/collision.h"

namespace vcsim::internal {

// Iso-surface f = 0 by marching tetrahedra on the lattice of spacing h (cubes split into six
// tetrahedra around their main diagonal, the same split in every cube, so neighbours agree).
// Only blocks of 8^3 cubes that a piece's surface can cross are sampled. The result is a closed,
// manifold surface (a piecewise-linear level set of a simplicial complex) with normals toward
// f < 0, i.e. into the lumen.
TriangleMesh marching_tetrahedra(const PieceGrid& field, double h);

// Newton steps onto the exact surface: v <- v - f(v) grad f(v), at most `max_move` per step.
void project_to_surface(TriangleMesh& m, const PieceGrid& field, double max_move);

// Cut the mesh flat: parts of triangles on the +normal side of the plane through `centre` are
// removed, but only for triangles entirely inside the cylinder around the plane's axis
// (radial < radius_limit, axial in (axial_lo, axial_hi)). Vertices within `snap` of the plane
// move onto it; vertices left on the plane are put on the circle of `radius`. The cut edge is a
// single boundary loop when the cylinder holds one tube.
struct ClipPlane {
  Vec3 centre, normal;
  double radius = 0.0;        // tube radius at the plane, m
  double radius_limit = 0.0;  // m
  double axial_lo = 0.0, axial_hi = 0.0;
};
void clip(TriangleMesh& m, const ClipPlane& plane, double snap);

// Drops unused vertices, keeping the order; returns old -> new index (-1 if dropped).
std::vector<int> compact(TriangleMesh& m);

// Edge-collapse simplification: shortest edges first, each collapsed into one of its endpoints
// (half-edge collapse, so vertices stay on the exact surface) if the link condition holds (the
// result stays manifold), no triangle folds or degrades, new edges stay below the endpoints'
// max length and the new triangles stay within the endpoints' error bound of the exact surface
// (|f| at centroid and edge midpoints). Boundary vertices are kept.
void simplify(TriangleMesh& m, const PieceGrid& field, const std::vector<double>& vertex_error,
              const std::vector<double>& vertex_max_edge);

// Drops edge-connected components with fewer than min_triangles triangles.
void drop_small_components(TriangleMesh& m, int min_triangles);

// Boundary loop (ordered as the boundary edges run in their triangles) of the vertices on the
// plane through centre with the given normal, within radius_limit of the centre.
std::vector<int> boundary_loop_on_plane(const TriangleMesh& m, const Vec3& centre,
                                        const Vec3& normal, double radius_limit);

// Joins two boundary loops around a common axis with a strip of triangles, merging them by angle;
// each strip triangle uses its loop edge in the opposite direction to the existing triangle.
void zip_loops(TriangleMesh& m, const std::vector<int>& a, const std::vector<int>& b,
               const Vec3& centre, const Vec3& axis);

}  // namespace vcsim::internal
