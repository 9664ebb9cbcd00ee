// A balloon's free diameter and working length at a pressure (BalloonSpec::diameter_at,
// length_at) against the chart they interpolate, and the shipped balloons and stent systems
// against their own labels: the chart gives the nominal diameter at the nominal pressure.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "vcsim/instruments.h"
#include "vcsim/units.h"

namespace {

using vcsim::BalloonSpec;
using vcsim::InstrumentKind;
using vcsim::kAtm;
using vcsim::kMm;

const std::filesystem::path kData = VCSIM_INSTRUMENTS_DATA;

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

// ---- the shipped balloons and stent systems ----

std::vector<vcsim::InstrumentSpec> shipped_with_balloons() {
  std::vector<vcsim::InstrumentSpec> out;
  for (auto& s : vcsim::load_catalogue(kData).items) {
    if (s.balloon) out.push_back(std::move(s));
  }
  return out;
}

TEST(ShippedBalloons, TheIssueAsksForTheseSizes) {
  std::set<std::string> names;
  int sc = 0, nc = 0, stents = 0;
  double d_min = 1, d_max = 0, l_min = 1, l_max = 0;
  for (const auto& s : shipped_with_balloons()) {
    names.insert(s.name);
    const BalloonSpec& b = *s.balloon;
    if (s.kind == InstrumentKind::kStent) {
      ++stents;
      ASSERT_TRUE(s.stent.has_value()) << s.name;
      continue;
    }
    EXPECT_EQ(s.kind, InstrumentKind::kBalloon) << s.name;
    EXPECT_FALSE(s.stent.has_value()) << s.name;
    (b.compliance == BalloonSpec::Compliance::kSemiCompliant ? sc : nc)++;
    d_min = std::min(d_min, b.nominal_diameter);
    d_max = std::max(d_max, b.nominal_diameter);
    l_min = std::min(l_min, b.length);
    l_max = std::max(l_max, b.length);
  }
  EXPECT_GE(sc, 5);
  EXPECT_GE(nc, 4);
  EXPECT_GE(stents, 3);
  EXPECT_NEAR(d_min, 2.0e-3, 1e-12);
  EXPECT_NEAR(d_max, 4.0e-3, 1e-12);
  EXPECT_NEAR(l_min, 8e-3, 1e-12);
  EXPECT_NEAR(l_max, 30e-3, 1e-12);
  for (const char* n : {"balloon-sc-3.0x15", "balloon-nc-3.0x15", "stent-cocr-3.0x18"}) {
    EXPECT_TRUE(names.count(n)) << n;
  }
}

TEST(ShippedBalloons, NominalPressureGivesTheNominalDiameterWithinOnePercent) {
  for (const auto& s : shipped_with_balloons()) {
    const BalloonSpec& b = *s.balloon;
    EXPECT_NEAR(b.diameter_at(b.nominal_pressure), b.nominal_diameter, 0.01 * b.nominal_diameter)
        << s.name;
    // The chart covers the clinical range: from at most nominal to at least rated burst.
    EXPECT_LE(b.chart_pressure.front(), b.nominal_pressure) << s.name;
    EXPECT_GE(b.chart_pressure.back(), b.rated_burst_pressure) << s.name;
  }
}

// Each file's chart, read as plain JSON, is what diameter_at returns at its pressures: the
// conversion to SI and the interpolation lose nothing.
TEST(ShippedBalloons, DiameterAtReproducesTheFileChart) {
  for (const auto& s : shipped_with_balloons()) {
    std::ifstream in(kData / (s.name + ".json"));
    const auto doc = nlohmann::json::parse(in);
    const auto& chart = doc.at("balloon").at("chart");
    ASSERT_EQ(chart.size(), s.balloon->chart_pressure.size()) << s.name;
    for (const auto& e : chart) {
      const double atm = e[0].get<double>(), mm = e[1].get<double>();
      EXPECT_NEAR(s.balloon->diameter_at(atm * kAtm), mm * kMm, 1e-12) << s.name << " " << atm;
    }
  }
}

TEST(ShippedBalloons, NonCompliantGrowsLessThanSemiCompliant) {
  double sc_growth = 1, nc_growth = 0;  // the least semi-compliant, the most non-compliant
  for (const auto& s : shipped_with_balloons()) {
    const BalloonSpec& b = *s.balloon;
    // Growth per atm from nominal to rated burst, relative to the nominal diameter.
    const double g = (b.diameter_at(b.rated_burst_pressure) - b.nominal_diameter) /
                     b.nominal_diameter / ((b.rated_burst_pressure - b.nominal_pressure) / kAtm);
    EXPECT_GT(g, 0.0) << s.name;
    if (b.compliance == BalloonSpec::Compliance::kSemiCompliant) {
      sc_growth = std::min(sc_growth, g);
    } else {
      nc_growth = std::max(nc_growth, g);
    }
  }
  EXPECT_LT(nc_growth, sc_growth);
}

// Two marker bands mark the balloon's working length (a balloon catheter) or the stent on it (a
// stent system, the stent centred on its balloon), so that they can be placed across a lesion.
TEST(ShippedBalloons, MarkersAtTheEndsOfTheBalloonOrStent) {
  for (const auto& s : shipped_with_balloons()) {
    const BalloonSpec& b = *s.balloon;
    const auto& m = s.radiopacity.markers;
    ASSERT_EQ(m.size(), 2u) << s.name;
    double distal = b.distal_offset, proximal = b.distal_offset + b.length;
    if (s.stent) {
      const double margin = 0.5 * (b.length - s.stent->length);
      distal += margin;
      proximal -= margin;
    }
    EXPECT_NEAR(m[0], distal, 1e-9) << s.name;
    EXPECT_NEAR(m[1], proximal, 1e-9) << s.name;
    EXPECT_LE(proximal, s.length) << s.name;
  }
}

TEST(ShippedBalloons, StentsMatchTheirBalloons) {
  for (const auto& s : shipped_with_balloons()) {
    if (!s.stent) continue;
    const auto& t = *s.stent;
    const BalloonSpec& b = *s.balloon;
    EXPECT_NEAR(t.nominal_diameter, b.nominal_diameter, 0.05e-3) << s.name;
    EXPECT_LE(t.length, b.length) << s.name;
    EXPECT_DOUBLE_EQ(t.strut_thickness, 81e-6) << s.name;     // clinical.md
    EXPECT_DOUBLE_EQ(t.attenuation_60kev, 1480.0) << s.name;  // CoCr 14.8 /cm
    EXPECT_GT(t.crimped_profile, b.crossing_profile) << s.name;
    EXPECT_GT(t.acute_recoil, 0.0) << s.name;  // about 5 % (clinical.md)
    EXPECT_LT(t.acute_recoil, 0.1) << s.name;
  }
}

TEST(ShippedBalloons, UnitsConvertToSi) {
  const auto cat = vcsim::load_catalogue(kData);
  const auto& nc = cat.get("balloon-nc-3.0x15");
  ASSERT_TRUE(nc.balloon.has_value());
  EXPECT_EQ(nc.kind, InstrumentKind::kBalloon);
  EXPECT_EQ(nc.balloon->compliance, BalloonSpec::Compliance::kNonCompliant);
  EXPECT_DOUBLE_EQ(nc.balloon->nominal_pressure, 14 * 101325.0);
  EXPECT_DOUBLE_EQ(nc.balloon->rated_burst_pressure, 24 * 101325.0);
  EXPECT_DOUBLE_EQ(nc.balloon->nominal_diameter, 3.0e-3);
  EXPECT_DOUBLE_EQ(nc.balloon->length, 15e-3);
  EXPECT_NEAR(nc.inner_diameter, 0.017 * 25.4e-3, 1e-12);  // the wire lumen
  const auto& st = cat.get("stent-cocr-3.0x18");
  ASSERT_TRUE(st.stent.has_value());
  EXPECT_EQ(st.kind, InstrumentKind::kStent);
  EXPECT_DOUBLE_EQ(st.stent->length, 18e-3);
  EXPECT_DOUBLE_EQ(st.stent->crimped_profile, 0.99e-3);
  EXPECT_STREQ(vcsim::to_string(InstrumentKind::kBalloon), "balloon");
  EXPECT_STREQ(vcsim::to_string(InstrumentKind::kStent), "stent");
}

}  // namespace
