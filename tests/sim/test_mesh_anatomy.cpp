// A patient or phantom mesh in a run (issue 29, part 1): the instruments collide with the mesh as
// given, enter at its inlet along its axis and stay inside; a mesh without centrelines is refused
// with the key named.
#include <gtest/gtest.h>

#include <string>

#include "vcsim/sim.h"

namespace vcsim {
namespace {

// Every node of every instrument inside the lumen (within `slack` of its radius).
double worst_outside(const Simulator& sim) {
  double worst = -1.0;
  for (int i = 0; i < sim.num_instruments(); ++i) {
    const InstrumentState& st = sim.instrument(i);
    for (std::size_t k = static_cast<std::size_t>(st.drive.first_free); k < st.rod.x.size(); ++k)
      worst = std::max(worst, locate(sim.tree(), st.rod.x[k]).outside);
  }
  return worst;
}

TEST(MeshAnatomy, TheShippedPhantomRunsFromItsMeshAndTheWireStaysInside) {
  const Scenario sc = load_scenario(find_scenario("phantom", "test", "scenario"));
  ASSERT_EQ(sc.centrelines, "../anatomy/phantom/y_phantom.json");
  Simulator sim(sc);
  // The lumen is the mesh file's, not one built from the centrelines.
  EXPECT_EQ(sim.lumen().cache_status, "off");
  EXPECT_EQ(sim.lumen().mesh.num_triangles(), 5470);
  Autopilot pilot(sim);
  StepCommands cmd;
  double worst = -1.0;
  while (!pilot.finished() && sim.time() < 20.0) {
    pilot.command(sim, cmd);
    sim.step(cmd);
    if (sim.metrics().steps % 200 == 0) worst = std::max(worst, worst_outside(sim));
  }
  EXPECT_FALSE(pilot.failed()) << pilot.status();
  EXPECT_TRUE(sim.all_landmarks_reached());
  EXPECT_LT(worst, 0.2e-3);  // never more than 0.2 mm beyond the centreline radius
  EXPECT_EQ(sim.metrics().rollbacks, 0);
}

// The reproducer of the issue: a tree rooted at an open inlet with the access 2 mm inside it.
// The sheath pointed back out of the inlet and the wire went 113 mm into free air; it must go in.
TEST(MeshAnatomy, AnAccessAtAnOpenInletPointsIntoTheVessel) {
  Scenario sc = parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "inlet",
    "anatomy": "../anatomy/bifurcation_example.json", "motion": {"beating": false},
    "dt_ms": 0.5, "sheath_length_mm": 5,
    "instruments": [{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 64,
                     "tip_segment_mm": 1}],
    "input": {"type": "timeline", "file": "unused.json"}})",
                               "inlet.json", default_scenarios_dir());
  Simulator sim(sc);
  const Vec3 axis = sim.instrument_model(0).sheath.frame * Vec3::UnitZ();
  EXPECT_GT(axis.dot(tangent_at(sim.tree().segments[0], 0.002)), 0.99);
  StepCommands cmd;
  cmd.reset(1);
  cmd.drive[0] = {DriveCommand::Mode::kVelocity, 0.03, 0.0};
  for (int k = 0; k < 2000; ++k) sim.step(cmd);  // 30 mm in
  EXPECT_NEAR(sim.depth(0), 0.03, 1e-3);
  EXPECT_LT(worst_outside(sim), 0.2e-3);
  EXPECT_EQ(sim.tip_location(0).loc.segment, 0);
}

void expect_refused(const std::string& extra, const std::string& field) {
  const std::string text = R"({"format": "vcsim-scenario", "version": 1, "name": "m", )" + extra +
                           R"(, "instruments": [{"name": "wire", "catalogue": "wire-014-floppy"}],
    "input": {"type": "timeline", "file": "unused.json"}})";
  try {
    (void)parse_scenario(text, "m.json");
    FAIL() << "accepted: " << extra;
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("m.json"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
  }
}

TEST(MeshAnatomy, AMeshWithoutCentrelinesIsRefusedNamingTheKey) {
  expect_refused(R"("anatomy": "patient.stl")", "centrelines");
  expect_refused(R"("anatomy": "patient.PLY")", "centrelines");
  expect_refused(R"("anatomy": "default", "centrelines": "c.json")", "centrelines");
  expect_refused(R"("anatomy": "p.stl", "centrelines": "c.json", "mesh_unit_mm": 0)",
                 "mesh_unit_mm");
  // Files that do not exist: named when the scene is built.
  Scenario sc = parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "m",
    "anatomy": "missing.stl", "centrelines": "missing.json",
    "instruments": [{"name": "wire", "catalogue": "wire-014-floppy"}],
    "input": {"type": "timeline", "file": "unused.json"}})",
                               "m.json");
  try {
    Simulator sim(sc);
    FAIL() << "built a scene from a missing mesh";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("missing.stl"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace vcsim
