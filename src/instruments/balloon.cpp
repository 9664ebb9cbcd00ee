// A balloon's free diameter and working length at an inflation pressure, from its compliance
// chart (BalloonSpec in include/vcsim/instruments.h). The catalogue parser checks the chart once
// (pressures increasing, diameters non-decreasing); these functions only read it.
#include <algorithm>
#include <cassert>

#include "vcsim/instruments.h"

namespace vcsim {

double BalloonSpec::diameter_at(double pressure) const {
  assert(chart_pressure.size() == chart_diameter.size());
  if (chart_pressure.empty()) return nominal_diameter;  // a spec built in code without a chart
  // Folded at zero (or below, a vacuum on the indeflator), unfolding linearly to the first entry.
  if (!(pressure > 0.0)) return crossing_profile;
  const double p0 = chart_pressure.front();
  if (pressure < p0) {
    return crossing_profile + (chart_diameter.front() - crossing_profile) * (pressure / p0);
  }
  if (pressure >= chart_pressure.back()) return chart_diameter.back();
  // First entry above the pressure; the one before it is at or below.
  const auto hi = std::upper_bound(chart_pressure.begin(), chart_pressure.end(), pressure);
  const std::size_t j = static_cast<std::size_t>(hi - chart_pressure.begin());
  const double pa = chart_pressure[j - 1], pb = chart_pressure[j];
  const double da = chart_diameter[j - 1], db = chart_diameter[j];
  return da + (db - da) * ((pressure - pa) / (pb - pa));
}

double BalloonSpec::length_at(double pressure) const {
  const double span = rated_burst_pressure - nominal_pressure;
  if (!(span > 0.0)) return length;
  const double t = std::clamp((pressure - nominal_pressure) / span, 0.0, 1.0);
  return length + lengthening * t;
}

}  // namespace vcsim
