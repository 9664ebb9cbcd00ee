// Building a rod model: input checks, graded segments, soft tip, hollow sections, masses and the
// designed rest shape of a shaped tip.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include "vcsim/rod.h"

using namespace vcsim;

namespace {

// Expects InputError whose message names `field`.
template <typename F>
void expect_input_error(F&& f, const std::string& field) {
  try {
    f();
    FAIL() << "expected an InputError naming " << field;
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), field) << e.what();
    EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
  }
}

double circumradius(const Vec3& a, const Vec3& b, const Vec3& c) {
  const double ab = (b - a).norm(), bc = (c - b).norm(), ca = (a - c).norm();
  return ab * bc * ca / (2.0 * (b - a).cross(c - a).norm());
}

}  // namespace

TEST(RodBuild, BadDefinitionsNameTheField) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  auto with = [](auto mutate) {
    RodDef d;
    mutate(d);
    return [d] { build_rod(d); };
  };
  expect_input_error(with([](RodDef& d) { d.length = 0.0; }), "length");
  expect_input_error(with([](RodDef& d) { d.length = -1.0; }), "length");
  expect_input_error(with([&](RodDef& d) { d.length = nan; }), "length");
  expect_input_error(with([](RodDef& d) { d.outer_radius = 0.0; }), "outer_radius");
  expect_input_error(with([](RodDef& d) { d.inner_radius = d.outer_radius; }), "inner_radius");
  expect_input_error(with([](RodDef& d) { d.tip_modulus_ratio = 0.0; }), "tip_modulus_ratio");
  expect_input_error(with([](RodDef& d) { d.tip_modulus_ratio = 1.5; }), "tip_modulus_ratio");
  expect_input_error(with([&](RodDef& d) { d.tip_modulus_ratio = nan; }), "tip_modulus_ratio");
  expect_input_error(with([](RodDef& d) { d.segments = 1; }), "segments");
  expect_input_error(with([](RodDef& d) { d.youngs_modulus = -1e9; }), "youngs_modulus");
  expect_input_error(with([](RodDef& d) { d.tip_length = 2.0 * d.length; }), "tip_length");
  expect_input_error(with([](RodDef& d) { d.core_taper_length = -1e-3; }), "core_taper_length");
  expect_input_error(with([](RodDef& d) {
                       d.tip_length = 0.5 * d.length;
                       d.core_taper_length = 0.6 * d.length;
                     }),
                     "core_taper_length");
  expect_input_error(with([](RodDef& d) { d.taper_length = 2.0 * d.length; }), "taper_length");
  expect_input_error(with([](RodDef& d) {
                       d.taper_length = 0.01;
                       d.taper_outer_radius = 2.0 * d.outer_radius;
                     }),
                     "taper_outer_radius");
  expect_input_error(with([](RodDef& d) {
                       d.inner_radius = 0.2e-3;
                       d.taper_length = 0.01;
                       d.taper_outer_radius = 0.2e-3;
                     }),
                     "taper_outer_radius");
  expect_input_error(with([](RodDef& d) { d.tip_shape = {TipSection::arc(-1e-3, 1.0)}; }),
                     "tip_shape[0].radius");
  expect_input_error(with([](RodDef& d) { d.tip_shape = {TipSection::arc(1.0, 3.0)}; }),
                     "tip_shape");
}

TEST(RodBuild, GradedSegmentsSumToTheLengthAndRefineTowardTheTip) {
  RodDef d;
  d.length = 0.25;
  d.segments = 100;
  d.grading = 0.1;
  const RodModel md = build_rod(d);
  double sum = 0.0;
  for (double l : md.rest_length) sum += l;
  EXPECT_NEAR(sum, d.length, 1e-12);
  EXPECT_NEAR(md.rest_length.back() / md.rest_length.front(), 0.1, 1e-9);
  for (int j = 1; j < md.m; ++j) EXPECT_LT(md.rest_length[j], md.rest_length[j - 1]);
}

TEST(RodBuild, SoftTipScalesTheModulusOverTheTipOnly) {
  RodDef d;
  d.length = 0.1;
  d.segments = 50;
  d.tip_length = 0.02;
  d.tip_modulus_ratio = 0.21;
  const RodModel md = build_rod(d);
  for (int j = 0; j < md.m; ++j) {
    const bool tip = md.edge_s[j] >= d.length - d.tip_length;
    EXPECT_DOUBLE_EQ(md.youngs[j], tip ? 0.21 * d.youngs_modulus : d.youngs_modulus);
  }
}

// A ground core: proximal to the soft tip the modulus rises from the tip's to the shaft's as the
// fourth power of a core diameter growing linearly (E I of a solid core ~ d^4), monotonically;
// the soft tip and the shaft beyond the taper are untouched.
TEST(RodBuild, CoreTaperRaisesTheModulusAsTheFourthPowerOfALinearCore) {
  RodDef d;
  d.length = 0.2;
  d.segments = 200;
  d.tip_length = 0.03;
  d.tip_modulus_ratio = 0.02;
  d.core_taper_length = 0.1;
  const RodModel md = build_rod(d);
  const double a = std::pow(0.02, 0.25), soft_from = d.length - d.tip_length;
  int in_taper = 0;
  for (int j = 0; j < md.m; ++j) {
    const double s = md.edge_s[j];
    double want = d.youngs_modulus;
    if (s >= soft_from) {
      want *= 0.02;
    } else if (s > soft_from - d.core_taper_length) {
      const double u = (soft_from - s) / d.core_taper_length, core = a + (1.0 - a) * u;
      want *= core * core * core * core;
      ++in_taper;
    }
    EXPECT_NEAR(md.youngs[j], want, 1e-12 * d.youngs_modulus) << "edge " << j;
    if (j > 0) {
      EXPECT_LE(md.youngs[j], md.youngs[j - 1]) << "edge " << j;
    }
    EXPECT_NEAR(md.shear[j] / md.youngs[j], md.shear[0] / md.youngs[0], 1e-12);
  }
  EXPECT_EQ(in_taper, 100);
  // Half way along the taper the core is (1 + a) / 2 of the shaft's: E = ((1 + a) / 2)^4 E_shaft.
  const int mid = static_cast<int>(
      std::lower_bound(md.edge_s.begin(), md.edge_s.end(), soft_from - 0.5 * d.core_taper_length) -
      md.edge_s.begin());
  EXPECT_NEAR(md.youngs[mid] / d.youngs_modulus, std::pow(0.5 * (1.0 + a), 4), 0.01);
}

// A taper (a balloon catheter's tip): over the distal taper_length each edge's outer radius falls
// linearly (at its midpoint) to the entry profile, and its section, bending stiffness and mass
// follow; proximal edges are untouched.
TEST(RodBuild, TaperedTipNarrowsTheSectionLinearly) {
  RodDef d;
  d.length = 0.1;
  d.segments = 50;
  d.outer_radius = 0.35e-3;
  d.inner_radius = 0.2e-3;
  d.taper_length = 0.01;
  d.taper_outer_radius = 0.23e-3;
  const RodModel md = build_rod(d);
  const double pi = std::numbers::pi;
  int tapered = 0;
  for (int j = 0; j < md.m; ++j) {
    const double u = (md.edge_s[j] - (d.length - d.taper_length)) / d.taper_length;
    const double ro = u > 0.0 ? 0.35e-3 + u * (0.23e-3 - 0.35e-3) : 0.35e-3;
    tapered += u > 0.0 ? 1 : 0;
    EXPECT_NEAR(md.outer_radius[j], ro, 1e-15) << "edge " << j;
    EXPECT_NEAR(md.area[j], pi * (ro * ro - 0.04e-6), 1e-18);
    EXPECT_NEAR(md.bend_inertia[j], pi * (std::pow(ro, 4) - std::pow(0.2e-3, 4)) / 4.0, 1e-24);
  }
  EXPECT_EQ(tapered, 5);
  EXPECT_LT(md.node_mass.back(), md.node_mass[md.n / 2]);
}

TEST(RodBuild, HollowSectionStiffnessAndMass) {
  RodDef d;
  d.outer_radius = 1.0e-3;
  d.inner_radius = 0.6e-3;
  d.youngs_modulus = 2e9;
  d.shear_modulus = 0.7e9;
  d.density = 1200;
  const RodModel md = build_rod(d);
  const double pi = std::numbers::pi;
  const double i = pi * (std::pow(1.0e-3, 4) - std::pow(0.6e-3, 4)) / 4.0;
  const double a = pi * (1.0e-6 - 0.36e-6);
  EXPECT_NEAR(md.bend_inertia[0], i, 1e-24);
  const Vec3 k = md.vertex_stiffness[md.m / 2];
  EXPECT_NEAR(k.x(), 2e9 * i, 1e-12);
  EXPECT_NEAR(k.y(), 2e9 * i, 1e-12);
  EXPECT_NEAR(k.z(), 0.7e9 * 2.0 * i, 1e-12);  // K3 = G J, J = 2 I
  double mass = 0.0;
  for (double mi : md.node_mass) mass += mi;
  EXPECT_NEAR(mass, 1200 * a * d.length, 1e-12);
}

TEST(RodBuild, SeriesStiffnessAcrossTheSoftTipBoundary) {
  // A vertex straddling shaft and tip behaves as two half-edges in series.
  RodDef d;
  d.segments = 10;
  d.tip_length = 0.5 * d.length;
  d.tip_modulus_ratio = 0.25;
  const RodModel md = build_rod(d);
  const int v = 5;  // between edge 4 (shaft) and edge 5 (tip)
  const double ka = md.youngs[4] * md.bend_inertia[4], kb = md.youngs[5] * md.bend_inertia[5];
  EXPECT_NEAR(md.vertex_stiffness[v].x(), 2.0 / (1.0 / ka + 1.0 / kb), 1e-12 * ka);
}

TEST(RodBuild, JTipRestShapeLiesOnItsCircle) {
  RodDef d;
  d.length = 0.1;
  d.segments = 80;
  d.grading = 0.3;
  const double r = 3e-3;
  d.tip_shape = {TipSection::arc(r, std::numbers::pi, 0.4), TipSection::straight(2e-3)};
  const RodModel md = build_rod(d);
  const double arc_start = d.length - 2e-3 - r * std::numbers::pi;
  int checked = 0;
  for (int i = 1; i + 1 < md.n; ++i) {
    if (md.node_s[i - 1] >= arc_start - 1e-12 &&
        md.node_s[i + 1] <= arc_start + r * std::numbers::pi + 1e-12) {
      EXPECT_NEAR(
          circumradius(md.rest_position[i - 1], md.rest_position[i], md.rest_position[i + 1]), r,
          1e-9);
      ++checked;
    }
  }
  EXPECT_GT(checked, 5);
  // The J turns the tip back: after 180 degrees the straight end points opposite the shaft.
  const Vec3 shaft = (md.rest_position[1] - md.rest_position[0]).normalized();
  const Vec3 end = (md.rest_position[md.n - 1] - md.rest_position[md.n - 2]).normalized();
  EXPECT_NEAR(shaft.dot(end), -1.0, 1e-9);
  // Rest frames follow the chords, and the rest Darboux vector bends about the plane's axis.
  for (int j = 0; j < md.m; ++j) {
    const Vec3 chord = (md.rest_position[j + 1] - md.rest_position[j]).normalized();
    EXPECT_NEAR((md.rest_frame[j] * Vec3::UnitZ()).dot(chord), 1.0, 1e-12);
  }
  const int v = md.m - 8;
  const Vec3 w0 = md.rest_darboux[v];
  EXPECT_NEAR(std::atan2(w0.y(), w0.x()), 0.4, 1e-9);
  EXPECT_NEAR(w0.z(), 0.0, 1e-9);
}

TEST(RodBuild, NegativeArcBendsTheOtherWay) {
  RodDef d;
  d.tip_shape = {TipSection::arc(5e-3, -std::numbers::pi / 2)};
  const RodModel md = build_rod(d);
  const Vec3 end = md.rest_position.back();
  // Bending about +x by a negative angle moves the tip toward +y (d3 x d1 = d2 reversed).
  RodDef p = d;
  p.tip_shape = {TipSection::arc(5e-3, std::numbers::pi / 2)};
  const Vec3 end_p = build_rod(p).rest_position.back();
  EXPECT_NEAR(end.y(), -end_p.y(), 1e-12);
  EXPECT_NEAR(end.z(), end_p.z(), 1e-12);
  EXPECT_NEAR(std::abs(end.y()), 5e-3, 1e-9);
}
