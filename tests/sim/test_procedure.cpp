// A complete angioplasty's physics (issue 25, docs/procedure.md): a balloon inflated by pressure
// follows its compliance chart in a wide vessel and stops at the wall of a narrow one; a lesion
// holds the balloon's waist below its opening pressure, opens with pressure above it and recoils
// by its set fraction; a balloon past its rated burst pressure ruptures; a stent stays where its
// balloon deployed it while the balloon and the wire are pulled back, and moves when an inflated
// balloon grips it.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>

#include "vcsim/sim.h"
#include "vcsim/units.h"

#include "balloon_scene.h"

namespace vcsim {
namespace {

namespace fs = std::filesystem;

fs::path scratch(const std::string& name) {
  return fs::temp_directory_path() / ("vcsim-test-" + name + "-" + std::to_string(::getpid()));
}

// The wire's tip 30 mm past the balloon's target, the balloon catheter brought to it, both in
// position mode at 50 mm/s; then the commands hold them there.
struct BalloonRun {
  Simulator sim;
  StepCommands cmds;
  double wire_depth = 0.0, balloon_depth = 0.0;
  BalloonRun(const Scenario& sc, double target_s) : sim(sc) {
    cmds.reset(2);
    for (DriveCommand& d : cmds.drive) d.mode = DriveCommand::Mode::kPosition;
    wire_depth = test::kAccessS - target_s + 0.03;
    balloon_depth = test::balloon_depth(sim.instrument_spec(1), target_s);
    while (sim.time() < 4.0) {
      cmds.drive[0].translation = std::min(wire_depth, 0.05 * sim.time());
      cmds.drive[1].translation = std::min(balloon_depth, 0.05 * sim.time() - 0.005);
      sim.step(cmds);
    }
  }
  void run(double seconds, double pressure) {
    cmds.balloon_pressure = pressure;
    const double end = sim.time() + seconds;
    while (sim.time() < end - 1e-9) sim.step(cmds);
  }
  const BalloonState& balloon() const { return sim.state().procedure.balloons[0]; }
  // The balloon's radius at its working length's middle node (m).
  double mid_radius() const {
    const BalloonState& b = balloon();
    return b.radius[b.radius.size() / 2];
  }
};

// In a tube wider than the balloon at its rated burst pressure (radius 3 mm), the balloon's radius
// along its working length is the chart's at every listed pressure, within 1 %.
TEST(Balloon, FreeInflationFollowsTheComplianceChart) {
  test::TubeSpecs t;
  t.radius_mm = 3.0;
  BalloonRun r(test::balloon_in_tube(scratch("free"), t), 0.066);
  const BalloonSpec& spec = *r.sim.instrument_spec(1).balloon;
  for (std::size_t k = 0; k < spec.chart_pressure.size(); ++k) {
    r.run(0.05, spec.chart_pressure[k]);
    EXPECT_NEAR(2.0 * r.mid_radius(), spec.chart_diameter[k], 0.01 * spec.chart_diameter[k])
        << spec.chart_pressure[k] / kAtm << " atm";
  }
  EXPECT_EQ(r.sim.metrics().rollbacks, 0);
}

// In a tube narrower than the balloon's nominal diameter (2.5 mm for a 3.0 mm balloon), the
// balloon stops at the wall: measured from where each node of its working length is, the wall is
// the balloon's radius away within 0.05 mm (it holds its catheter on the vessel's axis), and that
// radius is the tube's within the lumen mesh's own error (0.06 mm in coronaries, anatomy.md).
TEST(Balloon, InflationInANarrowTubeStopsAtTheWall) {
  test::TubeSpecs t;
  t.radius_mm = 1.25;
  BalloonRun r(test::balloon_in_tube(scratch("narrow"), t), 0.066);
  r.run(0.5, 6.0 * kAtm);
  const SimState& st = r.sim.state();
  const BalloonState& b = r.balloon();
  const BalloonHold& h = st.solver.instruments[1].hold;
  ASSERT_TRUE(h.active());
  EXPECT_NEAR(r.mid_radius(), 1.25e-3, 0.06e-3);
  // Each inflated node against the wall, measured from where the node is.
  const Lumen& lumen = r.sim.lumen();
  AabbTree tree;
  tree.build(lumen.mesh);
  const BalloonModel& bm = r.sim.model().procedure.balloons[0];
  int checked = 0;
  for (int node = h.first; node <= h.last; ++node) {
    const double radius = b.radius[static_cast<std::size_t>(node - bm.first)];
    if (h.wall_load[node] <= 0.0) continue;  // a cone, short of the wall
    const SphereContact c =
        tree.query_sphere(lumen.mesh, st.solver.instruments[1].rod.x[node], 3e-3);
    ASSERT_TRUE(c.touching);
    EXPECT_FALSE(c.centre_outside);
    EXPECT_NEAR(c.distance, radius, 0.05e-3) << "node " << node;
    ++checked;
  }
  EXPECT_GE(checked, 8);
}

// A 60 % lesion (1.2 mm minimal lumen in a 3 mm tube) and a 3.0 mm balloon: below the lesion's
// opening pressure (6 atm, the default) it holds the balloon's waist; from it on the minimal lumen
// grows with pressure, never shrinking; deflated, the lesion gives back its recoil fraction (0.3)
// of what it gained.
TEST(Balloon, ALesionHoldsThenOpensMonotonicallyAndRecoils) {
  test::TubeSpecs t;
  t.radius_mm = 1.5;
  t.lesion_percent = 60;
  t.lesions_json = R"([{"opening_pressure_atm": 6, "recoil": 0.3}])";
  BalloonRun r(test::balloon_in_tube(scratch("lesion"), t), 0.066);
  const SimModel& md = r.sim.model();
  auto throat = [&] {  // the lumen's radius at the lesion's middle now
    return lumen_radius_now(md.procedure, md.tree, r.sim.state().procedure, 0, 0.066);
  };
  const double before = throat();
  EXPECT_NEAR(before, 0.4 * 1.5e-3, 1e-6);
  r.run(0.3, 4.0 * kAtm);
  EXPECT_EQ(throat(), before) << "held below its opening pressure";
  EXPECT_LT(r.mid_radius(), 0.5 * r.balloon().free_diameter - 0.5e-3) << "a waist";
  double last = before;
  for (double atm : {6.0, 7.0, 8.0, 10.0, 12.0}) {
    r.run(0.1, atm * kAtm);
    const double now = throat();
    EXPECT_GE(now, last) << atm << " atm";
    EXPECT_NEAR(now, 0.5 * r.balloon().free_diameter, 0.01e-3) << "follows the balloon";
    last = now;
  }
  r.run(0.3, 0.0);
  EXPECT_NEAR(throat() - before, 0.7 * (last - before), 1e-3 * (last - before));
  EXPECT_EQ(r.sim.metrics().rollbacks, 0);
}

// Past its rated burst pressure a balloon ruptures: an event, and it holds no pressure after.
TEST(Balloon, PastRatedBurstPressureItRuptures) {
  test::TubeSpecs t;
  t.radius_mm = 3.0;
  BalloonRun r(test::balloon_in_tube(scratch("burst"), t), 0.066);
  const double rbp = r.sim.instrument_spec(1).balloon->rated_burst_pressure;
  r.run(0.05, rbp);
  EXPECT_FALSE(r.balloon().ruptured) << "at rated burst pressure it holds";
  r.run(0.05, rbp + 0.5 * kAtm);
  EXPECT_TRUE(r.balloon().ruptured);
  EXPECT_EQ(r.balloon().pressure, 0.0);
  EXPECT_EQ(r.mid_radius(), 0.5 * r.sim.instrument_spec(1).balloon->crossing_profile);
  const auto& ev = r.sim.state().procedure.events;
  ASSERT_EQ(ev.size(), 1u);
  EXPECT_EQ(ev[0].kind, ProcedureEvent::Kind::kRupture);
  r.run(0.05, 6.0 * kAtm);
  EXPECT_EQ(r.balloon().pressure, 0.0) << "a ruptured balloon holds no pressure";
}

// A pressure with the balloon still outside the patient is refused: one event, no inflation.
TEST(Balloon, APressureWithTheBalloonOutsideIsRefused) {
  test::TubeSpecs t;
  Simulator sim(test::balloon_in_tube(scratch("outside"), t));
  StepCommands cmds;
  cmds.reset(2);
  cmds.balloon_pressure = 8.0 * kAtm;
  for (int k = 0; k < 20; ++k) sim.step(cmds);
  const auto& ev = sim.state().procedure.events;
  ASSERT_EQ(ev.size(), 1u);
  EXPECT_EQ(ev[0].kind, ProcedureEvent::Kind::kPressureRefused);
  EXPECT_EQ(sim.state().procedure.balloons[0].pressure, 0.0);
}

}  // namespace
}  // namespace vcsim
