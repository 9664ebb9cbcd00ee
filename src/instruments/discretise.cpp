// Catalogue entry -> RodDef, with a bounded node count graded toward the distal tip.
#include <cmath>
#include <string>

#include "vcsim/instruments.h"

namespace vcsim {

void Discretisation::validate(const std::string& source) const {
  if (min_segments < 2 || min_segments > 100000) {
    std::string what = "expected an integer in [2, 100000], got ";
    what += std::to_string(min_segments);
    throw InputError(source, "min_segments", what);
  }
  if (max_nodes < min_segments + 1 || max_nodes > 100001) {
    std::string what = "expected an integer in [min_segments + 1, 100001], got ";
    what += std::to_string(max_nodes);
    throw InputError(source, "max_nodes", what);
  }
  require_positive(tip_segment, source, "tip_segment");
}

namespace {

// Sum of r^k for k = 0 .. m-1 (r >= 1), the length in units of the distal segment when each
// segment is r times its distal neighbour.
double geometric_sum(double r, int m) {
  if (r - 1.0 < 1e-12) return m;
  return (std::pow(r, m) - 1.0) / (r - 1.0);
}

}  // namespace

SegmentPlan plan_segments(double length, const Discretisation& disc) {
  disc.validate();
  require_positive(length, "discretisation", "length");
  SegmentPlan p;
  const int m_max = disc.max_nodes - 1;
  const double want = length / disc.tip_segment;  // segments at the tip resolution everywhere
  if (want <= m_max) {
    p.segments = std::max(disc.min_segments, static_cast<int>(std::ceil(want - 1e-9)));
    p.grading = 1.0;
    p.distal = p.proximal = length / p.segments;
    return p;
  }
  // Too long for uniform segments: grow them geometrically from the tip, ratio r per segment,
  // with the distal one at tip_segment. geometric_sum rises monotonically in r: bisect.
  const int m = m_max;
  double lo = 1.0, hi = std::pow(want, 1.0 / (m - 1));  // at hi the last term alone exceeds want
  for (int it = 0; it < 200 && hi - lo > 1e-15; ++it) {
    const double mid = 0.5 * (lo + hi);
    (geometric_sum(mid, m) < want ? lo : hi) = mid;
  }
  const double r = 0.5 * (lo + hi);
  p.segments = m;
  p.grading = std::pow(r, -(m - 1));
  // The same progression RodDef uses (build_rod): l_j = L ratio^j / sum, ratio = grading^(1/(m-1)).
  const double sum = geometric_sum(r, m);
  p.proximal = length * std::pow(r, m - 1) / sum;
  p.distal = length / sum;
  return p;
}

RodDef to_rod_def(const InstrumentSpec& spec, const Discretisation& disc) {
  const SegmentPlan plan = plan_segments(spec.length, disc);
  RodDef d;
  d.length = spec.length;
  d.segments = plan.segments;
  d.grading = plan.grading;
  d.youngs_modulus = spec.youngs_modulus;
  d.poisson = spec.poisson;
  // 0: from poisson; a braided shaft's G is its torsional rigidity over the annulus' polar moment.
  d.shear_modulus = spec.braid ? spec.torsional_rigidity() / spec.polar_moment() : 0.0;
  d.outer_radius = 0.5 * spec.outer_diameter;
  d.inner_radius = 0.5 * spec.inner_diameter;
  d.density = spec.density;
  d.tip_length = spec.tip_length;
  d.tip_modulus_ratio = spec.tip_modulus_ratio;
  d.core_taper_length = spec.core_taper_length;
  d.taper_length = spec.taper_length;
  d.taper_outer_radius = 0.5 * spec.entry_profile;
  d.tip_shape = spec.tip_shape;
  d.validate(spec.source.empty() ? spec.name : spec.source);
  return d;
}

}  // namespace vcsim
