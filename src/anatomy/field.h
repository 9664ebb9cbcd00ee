// Internal: the lumen as an implicit function. Each centreline piece (two consecutive points a, b
// with radii ra, rb) contributes f(p) = |p - q(t)| - r(t), where q(t) is the projection of p on
// the piece clamped to it and r(t) the interpolated radius. Its zero set in the plane normal to
// the piece is exactly the circle of radius r(t), so the lumen radius at every centreline point
// is the data's radius; the pieces' minimum is the union of the swept spheres.
#pragma once

#include "vcsim/anatomy.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace vcsim::internal {

struct Piece {
  Vec3 a, b;
  double ra = 0.0, rb = 0.0;
  int segment = -1;
  double s0 = 0.0;  // arc length of a along the segment, m
};

struct PieceEval {
  double f = 0.0;
  double t = 0.0;  // clamped parameter in [0, 1]
  Vec3 grad = Vec3::Zero();
};

inline PieceEval eval_piece(const Piece& pc, const Vec3& p) {
  const Vec3 d = pc.b - pc.a;
  const double len2 = d.squaredNorm();
  double t = len2 > 0.0 ? (p - pc.a).dot(d) / len2 : 0.0;
  t = std::clamp(t, 0.0, 1.0);
  const Vec3 q = pc.a + t * d;
  const Vec3 e = p - q;
  const double n = e.norm();
  PieceEval r;
  r.t = t;
  r.f = n - (pc.ra + t * (pc.rb - pc.ra));
  r.grad = n > 0.0 ? Vec3(e / n) : Vec3::UnitX();
  return r;
}

// Pieces of the given segments (all if `segments` is empty), each segment's centreline in order.
std::vector<Piece> make_pieces(const VesselTree& tree, const std::vector<int>& segments);

// Uniform hash grid over the pieces, so that the field near a point is the minimum over a short
// list. Exact where |f| < reach; farther away only the sign is kept (the value is clamped to
// +-reach), which is all a mesher needs.
class PieceGrid {
 public:
  PieceGrid() = default;
  PieceGrid(std::vector<Piece> pieces, double cell, double reach);

  struct Result {
    double f = 0.0;
    Vec3 grad = Vec3::UnitX();
    int piece = -1;  // the piece attaining the minimum, -1 if none is within reach
    double t = 0.0;
  };
  Result eval(const Vec3& p) const;
  const std::vector<Piece>& pieces() const { return pieces_; }
  double reach() const { return reach_; }

 private:
  // Dense grid over the pieces' bounding box: cell c lists pieces [start[c], start[c + 1]).
  int cell_of(const Vec3& p) const;
  std::vector<Piece> pieces_;
  double cell_ = 1e-3;
  double reach_ = 1e-3;
  Vec3 origin_ = Vec3::Zero();
  int nx_ = 0, ny_ = 0, nz_ = 0;
  std::vector<int> start_, list_;
  std::vector<char> deep_;  // deep inside some piece: the field is below -reach
};

// Lipschitz bound of a piece's field: |grad f| = sqrt(1 + (dr/ds)^2) on the cone part.
inline double piece_lipschitz(const Piece& pc) {
  const double len = (pc.b - pc.a).norm();
  const double slope = len > 0.0 ? (pc.rb - pc.ra) / len : 0.0;
  return std::sqrt(1.0 + slope * slope);
}

// Field of one segment alone (all its pieces), brute force; for validation and ostia.
double segment_field(const VesselSegment& seg, const Vec3& p);

// Direction of a lesion's plaque at arc length s (docs/anatomy.md: angle 0 points away from the
// heart centre, or anterior without a heart model).
Vec3 plaque_direction(const VesselTree& tree, const Lesion& lesion, double s);

// Completes a lumen whose vertex_segment and vertex_arc are set: triangle ownership, the healthy
// vertex copy, lesions applied (same topology), normals. Shared by the built and imported lumen.
void finish_lumen(const VesselTree& tree, Lumen& lumen);
// Segment i starts at its parent's last point (a continuation, not a side branch).
bool continues_parent(const VesselTree& tree, int i);

// Shared helpers.
Vec3 any_perpendicular(const Vec3& t);
std::uint64_t hash_bytes(const void* data, std::size_t n, std::uint64_t h);

}  // namespace vcsim::internal
