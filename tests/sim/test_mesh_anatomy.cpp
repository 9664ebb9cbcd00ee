// A patient or phantom mesh in a run (issue 29, part 1): the instruments collide with the mesh as
// given, enter at its inlet along its axis and stay inside; a mesh without centrelines is refused
// with the key named.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "vcsim/collision.h"
#include "vcsim/mesh_io.h"
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

// The phantom's exits are its mesh's three openings, each facing the way of the tree's open end
// nearest it, on the mesh's cut plane and as wide as the vessel there.
TEST(MeshAnatomy, ThePhantomsOpeningsAreItsExits) {
  const Scenario sc = load_scenario(find_scenario("phantom", "test", "scenario"));
  Simulator sim(sc);
  const std::vector<WallExit> exits =
      mesh_exits(sim.lumen().mesh, sim.lumen().report.boundary_loops);
  const std::vector<OpenEnd> ends = open_ends(sim.tree());
  ASSERT_EQ(exits.size(), 3u);
  ASSERT_EQ(ends.size(), 3u);
  for (const OpenEnd& e : ends) {
    double best = 1e9;
    const WallExit* near = nullptr;
    for (const WallExit& x : exits)
      if ((x.centre - e.centre).norm() < best) {
        best = (x.centre - e.centre).norm();
        near = &x;
      }
    ASSERT_NE(near, nullptr);
    EXPECT_LT(best, 2e-3) << sim.tree().segments[static_cast<std::size_t>(e.segment)].name;
    EXPECT_GT(near->outward.dot(e.outward), 0.95);
    EXPECT_NEAR(near->radius, e.radius, 0.3 * e.radius);
  }
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

// Median distance from `a`'s centreline points (every 0.5 mm) to `b`'s centrelines (m).
double median_distance(const VesselTree& a, const VesselTree& b) {
  std::vector<Vec3> ref;
  for (const VesselSegment& s : b.segments)
    for (double t = 0.0; t <= segment_length(s); t += 0.25e-3) ref.push_back(point_at(s, t));
  std::vector<double> d;
  for (const VesselSegment& s : a.segments)
    for (double t = 0.0; t <= segment_length(s); t += 0.5e-3) {
      double best = 1e9;
      for (const Vec3& q : ref) best = std::min(best, (point_at(s, t) - q).norm());
      d.push_back(best);
    }
  return median(d);
}

TEST(MeshAnatomy, CentrelinesFromThePhantomsMeshFollowItsOwn) {
  const std::string dir = default_scenarios_dir().string() + "/../anatomy/phantom/";
  const VesselTree truth = load_vessel_tree(dir + "y_phantom.json");
  MeshLoadOptions mm;
  mm.unit_scale = 1e-3;
  const VesselTree got =
      centrelines_from_mesh(load_mesh(dir + "y_phantom.stl", mm), Vec3::Zero(), "y_phantom.stl");
  ASSERT_EQ(got.num_segments(), 3);  // the inlet and its two branches
  EXPECT_EQ(got.segments[1].parent, 0);
  EXPECT_EQ(got.segments[2].parent, 0);
  EXPECT_TRUE(got.open_start);
  EXPECT_LT(median_distance(got, truth), 0.2e-3);
  // Radii (3.0 mm inlet; 2.2 and 2.0 mm branches) within 10 % along the middle of each.
  const double r0 = got.segments[0].radii[got.segments[0].radii.size() / 2];
  EXPECT_NEAR(r0, 3.0e-3, 0.3e-3);
  std::vector<double> branch = {got.segments[1].radii[got.segments[1].radii.size() / 2],
                                got.segments[2].radii[got.segments[2].radii.size() / 2]};
  std::sort(branch.begin(), branch.end());
  EXPECT_NEAR(branch[0], 2.0e-3, 0.2e-3);
  EXPECT_NEAR(branch[1], 2.2e-3, 0.22e-3);
  // A closed mesh has no inlet.
  TriangleMesh closed = load_mesh(dir + "y_phantom.stl", mm);
  closed.triangles.resize(4);
  EXPECT_THROW(centrelines_from_mesh(closed, Vec3::Zero(), "tiny.stl"), InputError);
}

// The issue's check: on the built-in patient's own lumen, against its own centrelines.
TEST(MeshAnatomy, CentrelinesFromTheBuiltInPatientsLumenAreWithinHalfAMillimetre) {
  const VesselTree truth = default_patient();
  const Lumen lumen = build_lumen(truth);
  const VesselSegment& fem =
      truth.segments[static_cast<std::size_t>(truth.find("right_common_femoral"))];
  const VesselTree got = centrelines_from_mesh(lumen.mesh, fem.points.back(), "patient lumen");
  EXPECT_GE(got.num_segments(), 20);
  EXPECT_LT(median_distance(got, truth), 0.5e-3);
}

TEST(MeshAnatomy, AMeshWithoutCentrelinesRunsOnCentrelinesComputedFromIt) {
  Scenario sc = parse_scenario(R"({"format": "vcsim-scenario", "version": 1, "name": "y",
    "anatomy": "../anatomy/phantom/y_phantom.stl", "inlet_mm": [0, 0, -1],
    "motion": {"beating": false}, "dt_ms": 0.5, "sheath_length_mm": 10,
    "instruments": [{"name": "wire", "catalogue": "wire-035-angled-hydrophilic",
                     "max_nodes": 128, "tip_segment_mm": 1}],
    "input": {"type": "timeline", "file": "unused.json"}})",
                               "y.json", default_scenarios_dir());
  Simulator sim(sc);
  EXPECT_EQ(sim.tree().num_segments(), 3);
  EXPECT_EQ(sim.tree().segments[0].name, "inlet");
  StepCommands cmd;
  cmd.reset(1);
  cmd.drive[0] = {DriveCommand::Mode::kVelocity, 0.04, 0.0};
  for (int k = 0; k < 4000; ++k) sim.step(cmd);  // 80 mm in: up to the bifurcation
  EXPECT_NEAR(sim.depth(0), 0.08, 1e-3);
  EXPECT_LT(worst_outside(sim), 0.3e-3);
  EXPECT_EQ(sim.metrics().rollbacks, 0);
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
  expect_refused(R"("anatomy": "default", "inlet_mm": [0, 0, 0])", "inlet_mm");
  expect_refused(R"("anatomy": "p.stl", "inlet_mm": [0, 0])", "inlet_mm");
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
