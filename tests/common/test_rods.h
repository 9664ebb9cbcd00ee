// Rod definitions the tests share.
#pragma once

#include "vcsim/rod.h"

namespace vcsim::test {

// A straight rod with free ends (the insertion drive, or nothing, holds it).
inline RodDef free_rod(double length, int segments, double outer_radius, double youngs_modulus,
                       double density = 1000.0) {
  RodDef d;
  d.length = length;
  d.segments = segments;
  d.outer_radius = outer_radius;
  d.youngs_modulus = youngs_modulus;
  d.density = density;
  d.base = BoundaryKind::kFree;
  d.tip = BoundaryKind::kFree;
  return d;
}

}  // namespace vcsim::test
