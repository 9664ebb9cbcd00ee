// Triangle-level geometry: normals and the closest point on a triangle.
#include "vcsim/collision.h"

#include <cmath>

namespace vcsim {

void TriangleMesh::recompute_normals() {
  normals.resize(triangles.size());
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    const auto& tri = triangles[t];
    const Vec3 n = (vertices[tri[1]] - vertices[tri[0]]).cross(vertices[tri[2]] - vertices[tri[0]]);
    const double len = n.norm();
    normals[t] = len > 0.0 ? Vec3(n / len) : Vec3::Zero();
  }
}

// Ericson, Real-Time Collision Detection (2005), 5.1.5: test the Voronoi regions of the three
// vertices, then of the three edges, using only dot products; what remains is the face, whose
// barycentric coordinates follow from the same dot products (no square roots, no normal).
ClosestPoint closest_point_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  const Vec3 ab = b - a;
  const Vec3 ac = c - a;
  const Vec3 ap = p - a;
  const double d1 = ab.dot(ap);
  const double d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return {a, TriangleRegion::kVertexA};

  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp);
  const double d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return {b, TriangleRegion::kVertexB};

  // Edge AB: p projects inside the edge and lies outside the triangle across AB.
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);
    return {a + v * ab, TriangleRegion::kEdgeAB};
  }

  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp);
  const double d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return {c, TriangleRegion::kVertexC};

  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return {a + w * ac, TriangleRegion::kEdgeCA};
  }

  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {b + w * (c - b), TriangleRegion::kEdgeBC};
  }

  // Inside the face: barycentric (u, v, w) proportional to (va, vb, vc).
  const double sum = va + vb + vc;
  if (!(sum > 0.0)) return {a, TriangleRegion::kVertexA};  // zero-area triangle: any vertex
  const double denom = 1.0 / sum;
  const double v = vb * denom;
  const double w = vc * denom;
  return {a + v * ab + w * ac, TriangleRegion::kFace};
}

// Moller and Trumbore, "Fast, minimum storage ray-triangle intersection" (1997): the crossing's
// barycentric coordinates and parameter from one determinant, for either face.
double segment_triangle_crossing(const Vec3& a, const Vec3& b, const Vec3& v0, const Vec3& v1,
                                 const Vec3& v2) {
  const Vec3 d = b - a;
  const Vec3 e1 = v1 - v0, e2 = v2 - v0;
  const Vec3 p = d.cross(e2);
  const double det = e1.dot(p);
  // Parallel to the plane (or a degenerate triangle): no crossing. Relative to the sizes, so
  // that it holds in metres and millimetres alike.
  if (std::abs(det) <= 1e-12 * d.norm() * e1.norm() * e2.norm()) return -1.0;
  const double inv = 1.0 / det;
  const Vec3 s = a - v0;
  const double u = s.dot(p) * inv;
  if (u < 0.0 || u > 1.0) return -1.0;
  const Vec3 q = s.cross(e1);
  const double v = d.dot(q) * inv;
  if (v < 0.0 || u + v > 1.0) return -1.0;
  const double t = e2.dot(q) * inv;
  return t >= 0.0 && t <= 1.0 ? t : -1.0;
}

SegmentCrossings segment_crossings_each(const TriangleMesh& mesh, const Vec3& a, const Vec3& b) {
  SegmentCrossings c;
  for (const auto& tri : mesh.triangles) {
    const double t = segment_triangle_crossing(a, b, mesh.vertices[tri[0]], mesh.vertices[tri[1]],
                                               mesh.vertices[tri[2]]);
    if (t >= 0.0) c.add(t);
  }
  return c;
}

}  // namespace vcsim
