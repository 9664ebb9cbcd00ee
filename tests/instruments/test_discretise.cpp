// Clinical lengths map to a bounded node count, finer toward the distal tip.
#include <gtest/gtest.h>

#include "vcsim/instruments.h"

namespace {

using vcsim::Discretisation;
using vcsim::plan_segments;

TEST(Discretise, ShortRodsAreUniformAtTheTipResolution) {
  const auto p = plan_segments(0.1, {});
  EXPECT_EQ(p.segments, 100);
  EXPECT_DOUBLE_EQ(p.grading, 1.0);
  EXPECT_DOUBLE_EQ(p.distal, 1e-3);
  // Very short rods keep a minimum number of segments.
  EXPECT_EQ(plan_segments(0.002, {}).segments, Discretisation{}.min_segments);
}

TEST(Discretise, ClinicalLengthsStayWithinTheNodeBudget) {
  for (double length : {0.45, 1.0, 1.5, 1.9, 2.6, 3.0}) {
    SCOPED_TRACE(length);
    const auto p = plan_segments(length, {});
    EXPECT_LE(p.segments + 1, 512);
    EXPECT_NEAR(p.distal, 1e-3, 1e-9);  // the tip keeps its resolution
    EXPECT_GE(p.proximal, p.distal);
    EXPECT_LE(p.grading, 1.0);

    // build_rod reproduces the plan: lengths sum to L, distal segment as planned, monotonic.
    vcsim::RodDef def;
    def.length = length;
    def.segments = p.segments;
    def.grading = p.grading;
    const auto m = vcsim::build_rod(def);
    double sum = 0;
    for (double l : m.rest_length) sum += l;
    EXPECT_NEAR(sum, length, 1e-9);
    EXPECT_NEAR(m.rest_length.back(), p.distal, 1e-9);
    EXPECT_NEAR(m.rest_length.front(), p.proximal, 1e-9);
    for (int j = 1; j < m.m; ++j) EXPECT_LE(m.rest_length[j], m.rest_length[j - 1] * (1 + 1e-12));
    // The distal 3 cm (a typical soft tip) stays below 2 mm per segment.
    for (int j = 0; j < m.m; ++j) {
      if (m.edge_s[j] > length - 0.03) {
        EXPECT_LE(m.rest_length[j], 2e-3);
      }
    }
  }
  // A 3 m wire: 511 segments from 1 mm at the tip to about 2 cm at the hub.
  const auto p = plan_segments(3.0, {});
  EXPECT_EQ(p.segments, 511);
  EXPECT_GT(p.proximal, 10e-3);
  EXPECT_LT(p.proximal, 30e-3);
}

TEST(Discretise, HonoursASmallerBudget) {
  Discretisation d;
  d.max_nodes = 64;
  d.tip_segment = 2e-3;
  const auto p = plan_segments(1.0, d);
  EXPECT_EQ(p.segments, 63);
  EXPECT_NEAR(p.distal, 2e-3, 1e-9);
}

TEST(Discretise, RejectsBadSettings) {
  Discretisation d;
  d.max_nodes = 3;
  EXPECT_THROW(plan_segments(1.0, d), vcsim::InputError);
  d = {};
  d.tip_segment = -1;
  EXPECT_THROW(plan_segments(1.0, d), vcsim::InputError);
  EXPECT_THROW(plan_segments(0.0, {}), vcsim::InputError);
  try {
    d = {};
    d.max_nodes = 1;
    d.validate("sim.json");
    FAIL();
  } catch (const vcsim::InputError& e) {
    EXPECT_EQ(e.field(), "max_nodes");
    EXPECT_EQ(e.source(), "sim.json");
  }
}

}  // namespace
