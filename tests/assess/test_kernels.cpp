// The assessment's kernels against answers known by construction: pedal time, cine runs and
// frames, threshold events, the dose model, the segments a tip may be in.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "vcsim/assess.h"

namespace vcsim::test {
namespace {

TEST(Beam, PedalHeldTwelveSecondsGivesTwelveSecondsOfFluoroscopy) {
  AssessmentSettings s;
  BeamTally b;
  const double dt = 0.5e-3;
  // 1 s off, 12 s pedal, 2 s off.
  for (int k = 0; k < 2000; ++k) b.step(dt, 0, s.cine_fps);
  for (int k = 0; k < 24000; ++k) b.step(dt, kFluoroPedal, s.cine_fps);
  for (int k = 0; k < 4000; ++k) b.step(dt, 0, s.cine_fps);
  EXPECT_NEAR(b.fluoro_time, 12.0, 1e-9);
  EXPECT_EQ(b.cine_runs, 0);
  EXPECT_EQ(b.cine_frames, 0);
  EXPECT_TRUE(b.pedal_used);
}

TEST(Beam, CineRunsCountFramesAtFifteenPerSecond) {
  AssessmentSettings s;
  BeamTally b;
  const double dt = 1e-3;
  // Two cine runs of 2.0 s and 0.5 s, apart; cine over fluoroscopy while both are held.
  for (int k = 0; k < 2000; ++k) b.step(dt, kCinePedal | kFluoroPedal, s.cine_fps);
  for (int k = 0; k < 300; ++k) b.step(dt, kFluoroPedal, s.cine_fps);
  for (int k = 0; k < 500; ++k) b.step(dt, kCinePedal, s.cine_fps);
  EXPECT_EQ(b.cine_runs, 2);
  // Frames at 0, 1/15, ... of each run: 30 in 2.0 s, 8 in 0.5 s (0 .. 7/15 = 0.467 s).
  EXPECT_EQ(b.cine_frames, 38);
  EXPECT_NEAR(b.cine_time, 2.5, 1e-9);
  EXPECT_NEAR(b.fluoro_time, 0.3, 1e-9);
}

TEST(Beam, NoPedalLeavesItUnused) {
  BeamTally b;
  for (int k = 0; k < 100; ++k) b.step(1e-3, 0, 15.0);
  EXPECT_FALSE(b.pedal_used);
  EXPECT_EQ(b.fluoro_time, 0.0);
}

TEST(ForceEvents, OnePushAboveTheThresholdIsOneEventAndBelowItNone) {
  const double dt = 1e-3, threshold = 0.5, gap = 0.05;
  // A push that ramps to 0.8 N over 0.2 s, holds 0.3 s and ramps back down.
  auto push = [&](double peak, ThresholdEvents& ev) {
    double t = 0.0;
    for (int k = 0; k < 1000; ++k) {
      t += dt;
      const double f = t < 0.2   ? peak * t / 0.2
                       : t < 0.5 ? peak
                       : t < 0.7 ? peak * (0.7 - t) / 0.2
                                 : 0.0;
      ev.step(t, f, threshold, gap);
    }
    ev.close();
  };
  ThresholdEvents above, below;
  push(0.8, above);
  push(0.4, below);
  ASSERT_EQ(above.events.size(), 1u);
  EXPECT_NEAR(above.events[0].peak, 0.8, 1e-12);
  // Above 0.5 N from t = 0.125 s to t = 0.575 s.
  EXPECT_NEAR(above.events[0].start, 0.126, 1.5e-3);
  EXPECT_NEAR(above.events[0].end, 0.574, 1.5e-3);
  EXPECT_TRUE(below.events.empty());
  EXPECT_NEAR(below.peak, 0.4, 1e-12);
}

TEST(ForceEvents, DipsShorterThanTheGapDoNotSplitAnEvent) {
  ThresholdEvents ev;
  double t = 0.0;
  const double dt = 1e-3;
  // Above for 0.1 s, below for 0.02 s (< gap), above 0.1 s, below 0.2 s (> gap), above 0.1 s.
  auto hold = [&](double f, double dur) {
    for (int k = 0; k < static_cast<int>(std::lround(dur / dt)); ++k)
      ev.step(t += dt, f, 1.0, 0.05);
  };
  hold(2.0, 0.1);
  hold(0.0, 0.02);
  hold(2.0, 0.1);
  hold(0.0, 0.2);
  hold(3.0, 0.1);
  ev.close();
  ASSERT_EQ(ev.events.size(), 2u);
  EXPECT_NEAR(ev.events[1].peak, 3.0, 1e-12);
}

TEST(Dose, KermaAndKermaAreaProductFollowTheModel) {
  AssessmentSettings s;
  s.fluoro_kerma_rate = 20e-3 / 60.0;
  s.cine_kerma_per_frame = 0.15e-3;
  s.irp_offset = 0.15;
  // 3 min fluoroscopy and 600 cine frames: 60 + 90 = 150 mGy.
  const DoseEstimate d = estimate_dose(180.0, 600, 0.2, 1.2, 0.78, s);
  EXPECT_NEAR(d.air_kerma, 0.150, 1e-12);
  // The 200 mm field at the detector is 200 * 630 / 1200 = 105 mm wide at the reference point.
  EXPECT_NEAR(d.field_area, 0.105 * 0.105, 1e-12);
  EXPECT_NEAR(d.kerma_area_product * 1e4, 0.150 * 110.25, 1e-9);  // Gy cm^2
}

TEST(WrongBranch, OnlyTheWayToTheTargetAndTheSinusesAreAllowed) {
  const VesselTree tree = default_patient();
  const std::vector<unsigned char> ok = allowed_segments(tree);
  ASSERT_EQ(ok.size(), tree.segments.size());
  auto allowed = [&](const char* name) {
    const int s = tree.find(name);
    EXPECT_GE(s, 0) << name;
    return s >= 0 && ok[static_cast<std::size_t>(s)] == 1;
  };
  for (const char* name : {"right_common_femoral", "right_external_iliac", "abdominal_aorta",
                           "aortic_arch", "ascending_aorta", "aortic_root", "left_main", "lad"})
    EXPECT_TRUE(allowed(name)) << name;
  for (const char* name : {"diagonal_1", "lcx", "rca", "left_common_iliac"})
    EXPECT_FALSE(allowed(name)) << name;
  for (std::size_t s = 0; s < tree.segments.size(); ++s) {
    if (tree.segments[s].kind == VesselKind::kSinus) {
      EXPECT_EQ(ok[s], 1) << tree.segments[s].name;
    }
  }
}

TEST(CoronaryDepth, CountsFromTheOstiumThroughBranchPoints) {
  const VesselTree tree = default_patient();
  const int lm = tree.find("left_main"), lad = tree.find("lad"), root = tree.find("aortic_root");
  ASSERT_GE(lm, 0);
  ASSERT_GE(lad, 0);
  const double ost = ostium_distance(tree, lm);
  EXPECT_NEAR(coronary_depth(tree, {lm, ost + 4e-3}), 4e-3, 1e-12);
  EXPECT_EQ(coronary_depth(tree, {lm, 0.5 * ost}), 0.0);  // still in the ostium's mouth
  // 12 mm down the LAD: the left main up to where the LAD leaves it, and 12 mm more.
  EXPECT_NEAR(coronary_depth(tree, {lad, 12e-3}), attach_distance(tree, lad) - ost + 12e-3, 1e-12);
  EXPECT_GT(coronary_depth(tree, {lad, 12e-3}), 12e-3);
  EXPECT_EQ(coronary_depth(tree, {root, 10e-3}), -1.0);
}

TEST(Prolapse, ATipPointingBackMoreThanTheAngleIsProlapsed) {
  const Vec3 in = Vec3::UnitZ();
  const double a = 120.0 * kDeg;
  EXPECT_FALSE(prolapsed(in, in, a));
  EXPECT_FALSE(prolapsed(Vec3(1, 0, 0), in, a));  // across the vessel: 90 degrees
  EXPECT_FALSE(prolapsed(Vec3(std::sin(115 * kDeg), 0, std::cos(115 * kDeg)), in, a));
  EXPECT_TRUE(prolapsed(Vec3(std::sin(125 * kDeg), 0, std::cos(125 * kDeg)), in, a));
  EXPECT_TRUE(prolapsed(-in, in, a));
}

// Polylines with nodes every 1 mm (0.45 mm radius, a 0.035" wire) that do and do not come back
// onto themselves.
struct Line {
  std::vector<Vec3> x;
  std::vector<double> s, r;
  void add(const Vec3& p) {
    s.push_back(x.empty() ? 0.0 : s.back() + (p - x.back()).norm());
    x.push_back(p);
    if (x.size() > 1) r.push_back(0.45e-3);
  }
  std::pair<int, int> loop(int first = 0) const { return find_loop(x, s, r, first, 30e-3, 0.5e-3); }
};

// A U-turn of radius `bend` between two straight limbs of `limb` m.
Line hairpin(double bend, double limb) {
  Line l;
  for (double z = 0; z <= limb; z += 1e-3) l.add(Vec3(-bend, 0, z));
  const int k = std::max(4, static_cast<int>(kPi * bend / 1e-3));
  for (int i = 1; i <= k; ++i) {
    const double a = kPi - kPi * i / k;
    l.add(Vec3(bend * std::cos(a), 0, limb + bend * std::sin(a)));
  }
  for (double z = limb - 1e-3; z >= 0; z -= 1e-3) l.add(Vec3(bend, 0, z));
  return l;
}

TEST(Loop, AnInstrumentBackOnItselfIsALoopABendIsNot) {
  Line straight;
  for (int i = 0; i < 200; ++i) straight.add(Vec3(0, 0, 1e-3 * i));
  EXPECT_EQ(straight.loop().first, -1);
  // A ring of 60 mm and on: the wire crosses itself where the ring closes (through its own
  // centreline, as a pushed wire buckled in the aortic root would touch itself).
  Line ring;
  const double R = 60e-3 / (2 * kPi);
  for (int i = 0; i <= 80; ++i) {
    const double a = 2 * kPi * i / 60.0;
    ring.add(Vec3(R * std::cos(a), R * std::sin(a), 0.2e-3 * i / 60.0));
  }
  const auto [i, j] = ring.loop();
  ASSERT_GE(i, 0);
  EXPECT_GE(ring.s[j] - ring.s[i], 30e-3);
  EXPECT_LT((ring.x[j] - ring.x[i]).norm(), 1.4e-3);
  // A J tip's 3 mm curve and a catheter's wide U-turn (limbs 20 mm apart) are bends, not loops;
  // a wire folded back with its limbs side by side (1.2 mm between centrelines) is a loop.
  EXPECT_EQ(hairpin(1.5e-3, 2e-3).loop().first, -1);
  EXPECT_EQ(hairpin(10e-3, 60e-3).loop().first, -1);
  const Line folded = hairpin(0.6e-3, 40e-3);
  EXPECT_GE(folded.loop().first, 0);
  // Only the inserted part counts: from a node past the fold's first limb, none.
  EXPECT_EQ(folded.loop(static_cast<int>(folded.x.size()) - 30).first, -1);
  // Not finite, too short, or `first` out of range: none, and no hang.
  Line bad = straight;
  bad.x[50] = Vec3::Constant(std::nan(""));
  EXPECT_EQ(bad.loop().first, -1);
  EXPECT_EQ(straight.loop(500).first, -1);
  EXPECT_EQ(Line{}.loop().first, -1);
}

}  // namespace
}  // namespace vcsim::test
