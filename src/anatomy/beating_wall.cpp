#include "vcsim/beating_wall.h"

#include <algorithm>
#include <cmath>

namespace vcsim {

BeatingWall::BeatingWall(BeatingLumen& lumen) : lumen_(&lumen) {
  // The waveforms' largest rates, sampled finely over a cardiac period and a respiratory cycle
  // (both are C1 piecewise cubics or sinusoids: 2000 samples bound them to well under 1 %), with
  // 5 % added for what the sampling misses.
  const CardiacMotion& m = lumen.motion();
  double rc = 0.0, rr = 0.0;
  const int n = 2000;
  const double resp_period = m.settings().respiratory_rate_per_min > 0.0
                                 ? 60.0 / m.settings().respiratory_rate_per_min
                                 : 1.0;
  for (int k = 0; k < n; ++k) {
    const double f = (k + 0.5) / n;
    rc = std::max(rc, std::abs(m.cardiac_rate(f * m.period())));
    rr = std::max(rr, std::abs(m.respiratory_rate(f * resp_period)));
  }
  speed_bound_ =
      1.05 * (lumen.max_cardiac_amplitude() * rc + lumen.max_respiratory_amplitude() * rr);
  set_time(0.0);
}

void BeatingWall::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                                std::span<SphereContact> out) {
  lumen_->move_and_query(time_, centres, radii, {}, 0.0, out);
}

void BeatingWall::query_spheres(std::span<const Vec3> centres, std::span<const double> radii,
                                std::span<LeafCache* const> caches, double slack,
                                std::span<SphereContact> out) {
  lumen_->move_and_query(time_, centres, radii, caches, slack, out);
}

SegmentCrossings BeatingWall::segment_crossings(const Vec3& a, const Vec3& b) {
  return lumen_->segment_crossings(time_, a, b);
}

bool BeatingWall::moves_near(const Vec3& centre, double radius) const {
  return lumen_->moves_near(centre, radius);
}

void BeatingWall::set_time(double t) {
  time_ = t;
  const CardiacMotion& m = lumen_->motion();
  c_ = m.cardiac_waveform(t);
  r_ = m.respiratory_waveform(t);
  c_rate_ = m.cardiac_rate(t);
  r_rate_ = m.respiratory_rate(t);
}

Vec3 BeatingWall::velocity(const SphereContact& hit) const {
  const CardiacMotion& m = lumen_->motion();
  // The rest point under the contact: one fixed-point step X = x - u(x) (the field is smooth and
  // its gradient small, so the error is second order in the displacement gradient). The
  // displacement and velocity of CardiacMotion, with the step's waveforms evaluated once.
  Vec3 a_c, a_r;
  m.amplitudes(hit.point, a_c, a_r);
  const Vec3 rest = hit.point - (c_ * a_c + r_ * a_r);
  m.amplitudes(rest, a_c, a_r);
  return c_rate_ * a_c + r_rate_ * a_r;
}

}  // namespace vcsim
