// A balloon's free diameter and working length at a pressure (BalloonSpec::diameter_at,
// length_at) against the chart they interpolate.
#include <gtest/gtest.h>

#include <cmath>

#include "vcsim/instruments.h"
#include "vcsim/units.h"

namespace {

using vcsim::BalloonSpec;
using vcsim::kAtm;
using vcsim::kMm;

// A semi-compliant 3.0 mm balloon with a chart of uneven steps (not one straight line, so that
// interpolating the wrong pair of entries shows).
BalloonSpec sample() {
  BalloonSpec b;
  b.nominal_diameter = 3.0e-3;
  b.length = 15e-3;
  b.nominal_pressure = 8 * kAtm;
  b.rated_burst_pressure = 14 * kAtm;
  b.crossing_profile = 0.9e-3;
  b.lengthening = 1.2e-3;
  for (auto [atm, mm] :
       {std::pair{4.0, 2.80}, {6.0, 2.92}, {8.0, 3.00}, {11.0, 3.15}, {12.0, 3.17}, {14.0, 3.30}}) {
    b.chart_pressure.push_back(atm * kAtm);
    b.chart_diameter.push_back(mm * kMm);
  }
  return b;
}

TEST(BalloonDiameter, ExactAtEveryChartEntry) {
  const BalloonSpec b = sample();
  for (std::size_t i = 0; i < b.chart_pressure.size(); ++i) {
    EXPECT_DOUBLE_EQ(b.diameter_at(b.chart_pressure[i]), b.chart_diameter[i]) << "entry " << i;
  }
}

TEST(BalloonDiameter, LinearBetweenNeighbouringEntries) {
  const BalloonSpec b = sample();
  for (std::size_t i = 0; i + 1 < b.chart_pressure.size(); ++i) {
    const double pa = b.chart_pressure[i], pb = b.chart_pressure[i + 1];
    const double da = b.chart_diameter[i], db = b.chart_diameter[i + 1];
    for (double t : {0.1, 0.25, 0.5, 0.9}) {
      const double p = pa + t * (pb - pa);
      EXPECT_NEAR(b.diameter_at(p), da + t * (db - da), 1e-15) << "entry " << i << " t " << t;
    }
  }
  // 10 atm lies in the 8..11 atm step: two thirds of the way from 3.00 to 3.15 mm.
  EXPECT_NEAR(b.diameter_at(10 * kAtm), 3.10e-3, 1e-15);
}

TEST(BalloonDiameter, HeldBeyondTheLastEntry) {
  const BalloonSpec b = sample();
  for (double atm : {14.0, 14.5, 20.0, 1e6}) {
    EXPECT_DOUBLE_EQ(b.diameter_at(atm * kAtm), 3.30e-3) << atm;
  }
}

TEST(BalloonDiameter, UnfoldsFromTheCrossingProfileAtZero) {
  const BalloonSpec b = sample();
  EXPECT_DOUBLE_EQ(b.diameter_at(0.0), b.crossing_profile);
  EXPECT_DOUBLE_EQ(b.diameter_at(-2 * kAtm), b.crossing_profile);  // vacuum: folded
  // Linear from (0, crossing) to the first entry (4 atm, 2.80 mm).
  EXPECT_NEAR(b.diameter_at(1 * kAtm), 0.9e-3 + 0.25 * (2.80e-3 - 0.9e-3), 1e-15);
  EXPECT_NEAR(b.diameter_at(2 * kAtm), 0.5 * (0.9e-3 + 2.80e-3), 1e-15);
}

TEST(BalloonDiameter, NeverShrinksAsThePressureRises) {
  const BalloonSpec b = sample();
  double prev = b.diameter_at(0.0);
  for (double atm = 0.0; atm <= 20.0; atm += 0.05) {
    const double d = b.diameter_at(atm * kAtm);
    EXPECT_GE(d, prev) << atm;
    prev = d;
  }
}

TEST(BalloonDiameter, WithoutAChartTheNominalDiameter) {
  BalloonSpec b;
  b.nominal_diameter = 2.5e-3;
  EXPECT_DOUBLE_EQ(b.diameter_at(8 * kAtm), 2.5e-3);
}

TEST(BalloonLength, NominalUpToNominalPressureThenLinearToRatedBurst) {
  const BalloonSpec b = sample();
  EXPECT_DOUBLE_EQ(b.length_at(0.0), 15e-3);
  EXPECT_DOUBLE_EQ(b.length_at(4 * kAtm), 15e-3);
  EXPECT_DOUBLE_EQ(b.length_at(8 * kAtm), 15e-3);
  EXPECT_NEAR(b.length_at(11 * kAtm), 15e-3 + 0.5 * 1.2e-3, 1e-15);  // half way, 8 -> 14 atm
  EXPECT_NEAR(b.length_at(14 * kAtm), 16.2e-3, 1e-15);
  EXPECT_NEAR(b.length_at(30 * kAtm), 16.2e-3, 1e-15);  // held beyond rated burst
}

}  // namespace
