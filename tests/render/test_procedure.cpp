// The angioplasty seen by fluoroscopy (issue 25, docs/rendering.md): what a frame copies of the
// procedure's state, the balloon's and the stent's meshes against their sizes and analytic path
// lengths, the rendered lumen following the lesions' opening, and frames of a balloon holding a
// waist in a lesion, of a deployed stent, and of the lesion before and after it was opened.
// GL-free tests first; the GL ones draw through a headless EGL context (Mesa llvmpipe).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>

#include "gl_fixture.h"
#include "vcsim/render.h"
#include "vcsim/units.h"

#include "balloon_scene.h"

namespace vcsim {
namespace {

namespace fs = std::filesystem;

fs::path scratch(const std::string& name) {
  return fs::temp_directory_path() /
         ("vcsim-test-render-" + name + "-" + std::to_string(::getpid()));
}

// The path length of a ray through a closed, outward-wound mesh, as the renderer sums it (docs/
// rendering.md): +t where the ray leaves a triangle, -t where it enters (Moller-Trumbore hits).
double path_length(const TriangleMesh& m, const Vec3& origin, const Vec3& dir) {
  double sum = 0.0;
  for (const auto& tri : m.triangles) {
    const Vec3 a = m.vertices[tri[0]], e1 = m.vertices[tri[1]] - a, e2 = m.vertices[tri[2]] - a;
    const Vec3 p = dir.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-30) continue;
    const Vec3 s = origin - a;
    const double u = s.dot(p) / det;
    if (u < 0.0 || u > 1.0) continue;
    const Vec3 q = s.cross(e1);
    const double v = dir.dot(q) / det;
    if (v < 0.0 || u + v > 1.0) continue;
    const double t = e2.dot(q) / det;
    if (t <= 0.0) continue;
    sum += (e1.cross(e2).dot(dir) > 0.0 ? t : -t);
  }
  return sum;
}

// Every directed edge has its reverse: closed and consistently wound.
bool closed(const TriangleMesh& m) {
  std::map<std::pair<int, int>, int> e;
  for (const auto& t : m.triangles)
    for (int k = 0; k < 3; ++k) ++e[{t[k], t[(k + 1) % 3]}];
  for (const auto& [key, n] : e)
    if (n != 1 || !e.count({key.second, key.first})) return false;
  return true;
}

StentSpec catalogue_stent() {
  return *load_instrument(default_catalogue_dir() / "stent-cocr-3.0x18.json").stent;
}

// ---------------------------------------------------------------------------------------------
// GL-free

// A balloon on a bent catheter with a waist: every ring of the mesh lies at its node's radius,
// perpendicular to the catheter; the surface is closed and holds diluted contrast.
TEST(BalloonMesh, RingsLieAtTheStateRadiiAroundTheCatheter) {
  std::vector<Vec3> nodes;
  std::vector<double> radii;
  for (int i = 0; i <= 16; ++i) {
    nodes.emplace_back(0.01 * std::sin(0.05 * i), 0.002 * i, 0.001 * i);
    const double u = (i - 8) / 8.0;
    radii.push_back(1.4e-3 - 0.8e-3 * std::exp(-8.0 * u * u));  // shoulders 1.4, waist 0.6 mm
  }
  radii.front() = radii.back() = 0.4e-3;  // the cones down to the shaft
  const int sides = 24;
  const XrayMesh x = balloon_xray_mesh(nodes, radii, kBalloonContrastFraction, sides);
  EXPECT_EQ(x.material, XrayMaterial::kIodine);
  EXPECT_EQ(x.fill, 0.5f);
  EXPECT_TRUE(closed(x.mesh));
  ASSERT_EQ(x.mesh.num_vertices(), 17 * sides + 2);
  for (int i = 0; i <= 16; ++i) {
    const Vec3 t = (nodes[std::min(i + 1, 16)] - nodes[std::max(i - 1, 0)]).normalized();
    for (int j = 0; j < sides; ++j) {
      const Vec3 d = x.mesh.vertices[i * sides + j] - nodes[i];
      EXPECT_NEAR(d.norm(), radii[i], 1e-9 * radii[i]) << "node " << i;
      EXPECT_NEAR(d.dot(t), 0.0, 1e-12);
    }
  }
  // Through the waist and a shoulder across the catheter (in the ring's plane): two radii of
  // contrast, within the 24-gon's cos(pi / 24).
  for (int i : {2, 8, 13}) {
    const Vec3 t = (nodes[i + 1] - nodes[i - 1]).normalized();
    const Vec3 across = t.cross(Vec3(0.3, 0.1, 1.0)).normalized();
    // (1 um off the ring's plane: a ray in it would run along the edges between its triangles)
    const Vec3 o = nodes[i] + 1e-6 * t - 0.01 * across;
    const double L = path_length(x.mesh, o, across);
    EXPECT_NEAR(L, 2.0 * radii[i], 0.02 * radii[i]) << "node " << i;
  }
}

// A stent's wall: a ray through both walls across the axis meets 2 x strut thickness of wall at
// the fill of its metal coverage, so its attenuation is 2 mu t coverage (CoCr L-605, 81 um, 15 %);
// the polygon's facets lie within cos(pi / sides) of the circle.
TEST(StentMesh, ARayThroughBothWallsHasTheAnalyticAttenuation) {
  const StentSpec spec = catalogue_stent();
  const double mu = spec.attenuation_60kev, t = spec.strut_thickness, c = spec.metal_coverage;
  EXPECT_NEAR(mu, 1480.0, 1e-9);
  EXPECT_NEAR(t, 81e-6, 1e-12);
  const float fill = stent_fill(spec, BeamEnergy::k60keV);
  EXPECT_NEAR(fill, c, 1e-6);
  const double want = 2.0 * mu * t * c;  // 0.036
  std::vector<Vec3> rings;
  for (int k = 0; k < 37; ++k) rings.emplace_back(0.0, 0.0, 0.5e-3 * k);
  const std::vector<double> radius(rings.size(), 1.5e-3);
  for (int sides : {16, 64}) {
    const XrayMesh x = stent_xray_mesh(rings, radius, t, fill, sides);
    EXPECT_EQ(x.material, XrayMaterial::kCoCr);
    EXPECT_TRUE(closed(x.mesh));
    const double tol = 1.0 - std::cos(kPi / sides) + 1e-3;
    for (double angle : {0.1, 0.7, 2.0}) {
      const Vec3 dir(std::cos(angle), std::sin(angle), 0.0);
      const Vec3 from = Vec3(0.0, 0.0, 9.1e-3) - 0.01 * dir;
      const double L = path_length(x.mesh, from, dir);
      EXPECT_NEAR(L, 2.0 * t, tol * 2.0 * t) << sides << " sides";
      EXPECT_NEAR(x.fill * attenuation_per_m(XrayMaterial::kCoCr, BeamEnergy::k60keV) * L, want,
                  tol * want);
    }
    // Inside the stent's lumen and beyond its ends: no metal.
    EXPECT_NEAR(path_length(x.mesh, Vec3(0, 0, 9e-3), Vec3::UnitZ()), 0.0, 1e-12);
    EXPECT_NEAR(path_length(x.mesh, Vec3(-0.01, 0, 20e-3), Vec3::UnitX()), 0.0, 1e-12);
  }
}

// The rendered lumen copies the collision lumen's vertices: opened fully, the vertices the
// lesions move reach their healthy positions, every other vertex stays, and each cap stays at the
// centre of its loop.
TEST(LumenXray, FollowsTheLesionsOpeningLikeTheCollisionLumen) {
  const VesselTree tree = default_patient();
  ASSERT_FALSE(tree.lesions.empty());
  LumenSettings ls;
  ls.cache_dir = VCSIM_RENDER_TEST_CACHE;
  const Lumen lumen = build_lumen(tree, ls);
  LumenXraySource src;
  const XrayMesh x = lumen_xray_mesh(lumen, &src);
  ASSERT_EQ(src.vertex.size(), x.mesh.vertices.size());
  ASSERT_EQ(src.cap_start.size(), src.cap_centre.size() + 1);
  for (std::size_t v = 0; v < src.vertex.size(); ++v)
    if (src.vertex[v] >= 0) {
      ASSERT_EQ(x.mesh.vertices[v], lumen.mesh.vertices[src.vertex[v]]);
    }
  const LesionMorph morph = make_lesion_morph(tree, lumen);
  ASSERT_GT(morph.vertices.size(), 20u);
  const LumenXrayMorph rm = make_lumen_xray_morph(src, morph);
  EXPECT_GE(rm.vertex.size(), morph.vertices.size());  // a junction vertex is copied twice
  std::vector<LesionOpening> open(tree.lesions.size());
  for (LesionOpening& o : open) o.t.assign(kLesionSamples, 1.0);
  std::vector<Vec3> morphed(morph.vertices.size());
  morph_positions(lumen, morph, open, morphed);
  std::vector<Vec3> v = x.mesh.vertices;
  apply_lumen_xray_morph(rm, morphed, v);
  std::vector<char> lesion_vertex(lumen.mesh.vertices.size(), 0);
  for (int k : morph.vertices) lesion_vertex[k] = 1;
  int moved = 0;
  for (std::size_t i = 0; i < v.size(); ++i) {
    const int s = src.vertex[i];
    if (s < 0) continue;
    if (lesion_vertex[s]) {
      ASSERT_NEAR((v[i] - lumen.healthy_vertices[s]).norm(), 0.0, 1e-15);
      moved += (v[i] - x.mesh.vertices[i]).norm() > 1e-6;
    } else {
      ASSERT_EQ(v[i], x.mesh.vertices[i]);
    }
  }
  EXPECT_GT(moved, 20);
  for (std::size_t c = 0; c < src.cap_centre.size(); ++c) {
    Vec3 sum = Vec3::Zero();
    for (int k = src.cap_start[c]; k < src.cap_start[c + 1]; ++k) sum += v[src.cap_loop[k]];
    const int n = src.cap_start[c + 1] - src.cap_start[c];
    EXPECT_NEAR((v[src.cap_centre[c]] - sum / n).norm(), 0.0, 1e-12);
  }
}

// The tube scene of the procedure tests (tests/sim/balloon_scene.h): a wire and a balloon or
// stent catheter brought to the 60 % lesion's middle (66 mm along the tube), then held there.
struct TubeRun {
  std::unique_ptr<Simulator> sim;
  StepCommands cmds;
  explicit TubeRun(const std::string& catalogue) {
    test::TubeSpecs t;
    t.radius_mm = 1.5;
    t.lesion_percent = 60;
    t.catalogue = catalogue;
    // Opens from 6 atm, gives back 30 %; the folded balloon does not widen it while crossing.
    t.lesions_json = R"([{"opening_pressure_atm": 6, "recoil": 0.3, "crossing_force_n": 100}])";
    const fs::path dir = scratch(catalogue);
    sim = std::make_unique<Simulator>(test::balloon_in_tube(dir, t));
    fs::remove_all(dir);  // the model is built: its files are no longer read
    cmds.reset(2);
    for (DriveCommand& d : cmds.drive) d.mode = DriveCommand::Mode::kPosition;
    const double target = 0.066;
    const double wire = test::kAccessS - target + 0.03;
    const double balloon = test::balloon_depth(sim->instrument_spec(1), target);
    while (sim->time() < 4.0) {
      cmds.drive[0].translation = std::min(wire, 0.05 * sim->time());
      cmds.drive[1].translation = std::min(balloon, 0.05 * sim->time() - 0.005);
      sim->step(cmds);
    }
  }
  void run(double seconds, double pressure) {
    cmds.balloon_pressure = pressure;
    const double end = sim->time() + seconds;
    while (sim->time() < end - 1e-9) sim->step(cmds);
  }
};

// Distance from p to a polyline.
double to_polyline(const std::vector<Vec3>& x, const Vec3& p) {
  double best = 1e300;
  for (std::size_t k = 0; k + 1 < x.size(); ++k) {
    const Vec3 d = x[k + 1] - x[k];
    const double u = std::clamp((p - x[k]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (x[k] + u * d - p).norm());
  }
  return best;
}

// A balloon catheter added and removed again (an exchange): its balloon keeps its index in the
// procedure, and a frame copies it without a rod to draw it on (the trainer published such a
// frame after a device removed one: it read past the scene's instruments).
TEST(Snapshot, ARemovedBalloonIsCopiedWithoutNodes) {
  test::TubeSpecs t;
  const fs::path dir = scratch("removed");
  Simulator sim(test::tube_scenario(
      dir, t,
      R"([{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 160, "tip_segment_mm": 1}])"));
  fs::remove_all(dir);
  InstrumentChange c;
  c.kind = InstrumentChange::Kind::kAdd;
  c.name = "balloon";
  c.catalogue = "balloon-sc-3.0x15";
  c.over = "wire";
  c.max_nodes = 200;
  c.source = "test";
  sim.exchange(c);
  c.kind = InstrumentChange::Kind::kRemove;
  sim.exchange(c);
  ASSERT_EQ(sim.num_instruments(), 1);
  ASSERT_EQ(sim.model().procedure.balloons.size(), 1u);
  ASSERT_TRUE(sim.model().procedure.balloons[0].removed());
  const FrameSnapshot f = snapshot(sim);
  ASSERT_EQ(f.balloons.size(), 1u);
  EXPECT_TRUE(f.balloons[0].nodes.empty());
  EXPECT_EQ(f.nodes.size(), 1u);
}

// The frame writer on a tree without a heart (a tube): it starts and films; and when its worker
// cannot start (a size the renderer refuses), the constructor joins the worker before the error
// leaves it (a joinable std::thread destroyed in the unwinding called std::terminate: exit 134).
TEST(FrameRecorder, StartsWithoutAHeartAndFailsWithoutTerminating) {
  test::TubeSpecs t;
  const fs::path dir = scratch("recorder");
  Simulator sim(test::tube_scenario(
      dir, t, R"([{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 64}])"));
  ASSERT_FALSE(sim.model().tree.heart.has_value());
  EXPECT_THROW(FrameRecorder(sim.model(), 8, BeamEnergy::k60keV, {}, dir), InputError);
  {
    FrameRecorder rec(sim.model(), 64, BeamEnergy::k60keV, {}, dir);
    rec.push(snapshot(sim), CArmPose{});
    rec.finish();
  }
  EXPECT_TRUE(fs::exists(dir / "frame_00000.png"));
  fs::remove_all(dir);
}

// A frame copies what it needs of the procedure: the balloon's nodes, radii and pressure, the
// stent crimped on the balloon then deployed at its rings on the vessel's axis, the openings.
TEST(Snapshot, CopiesTheBalloonTheStentAndTheLesionsOpening) {
  TubeRun r("stent-cocr-3.0x18");
  const SimModel& md = r.sim->model();
  ASSERT_EQ(md.procedure.balloons.size(), 1u);
  const BalloonModel& bm = md.procedure.balloons[0];
  FrameSnapshot f = snapshot(*r.sim);
  ASSERT_EQ(f.balloons.size(), 1u);
  ASSERT_EQ(f.stents.size(), 1u);
  EXPECT_EQ(f.balloons[0].pressure, 0.0);
  EXPECT_EQ(f.balloons[0].contrast, 0.0f);
  EXPECT_EQ(f.stents[0].phase, StentState::Phase::kCrimped);
  ASSERT_EQ(f.stents[0].rings.size(), r.sim->state().procedure.stents[0].expanded.size());
  for (double rad : f.stents[0].radius) EXPECT_NEAR(rad, 0.5 * bm.stent->crimped_profile, 1e-12);

  r.run(0.3, 10.0 * kAtm);
  f = snapshot(*r.sim);
  const SimState& st = r.sim->state();
  const BalloonState& bs = st.procedure.balloons[0];
  const BalloonFrame& bf = f.balloons[0];
  EXPECT_EQ(bf.pressure, bs.pressure);
  EXPECT_GT(bf.pressure, 0.0);
  EXPECT_EQ(bf.contrast, kBalloonContrastFraction);
  EXPECT_EQ(bf.radius, bs.radius);
  ASSERT_EQ(bf.nodes.size(), static_cast<std::size_t>(bm.nodes()));
  for (int j = 0; j < bm.nodes(); ++j)
    EXPECT_EQ(bf.nodes[j], st.solver.instruments[bm.instrument].rod.x[bm.first + j]);
  EXPECT_EQ(f.opening.size(), st.procedure.opening.size());
  EXPECT_EQ(f.opening[0].t, st.procedure.opening[0].t);
  // Crimped on the balloon, expanded with it: on its nodes, at the rings' largest radius.
  const StentFrame& crimped = f.stents[0];
  EXPECT_EQ(crimped.radius, st.procedure.stents[0].expanded);
  EXPECT_GT(*std::max_element(crimped.radius.begin(), crimped.radius.end()), 1.2e-3);
  for (const Vec3& p : crimped.rings) EXPECT_LT(to_polyline(bf.nodes, p), 1e-12);
  // The stent's ends sit half its length either side of the balloon's middle, within a node.
  EXPECT_NEAR((crimped.rings.front() - crimped.rings.back()).norm(), bm.stent->length, 1.5e-3);

  r.run(0.3, 0.0);
  f = snapshot(*r.sim);
  const StentState& ss = r.sim->state().procedure.stents[0];
  ASSERT_EQ(ss.phase, StentState::Phase::kDeployed);
  const StentFrame& deployed = f.stents[0];
  EXPECT_EQ(deployed.phase, StentState::Phase::kDeployed);
  EXPECT_EQ(deployed.radius, ss.ring_radius);
  ASSERT_EQ(deployed.rings.size(), ss.ring_s.size());
  // The tube runs along +z from the origin and the lesion is concentric: rings on the axis.
  for (std::size_t k = 0; k < ss.ring_s.size(); ++k)
    EXPECT_NEAR((deployed.rings[k] - Vec3(0, 0, ss.ring_s[k])).norm(), 0.0, 1e-9);
  EXPECT_EQ(f.balloons[0].pressure, 0.0);
  EXPECT_EQ(f.balloons[0].contrast, 0.0f);
}

// ---------------------------------------------------------------------------------------------
// GL

class RenderProcedureGl : public test::GlSuite {};

// The ray through pixel (i, j): from the source, unit direction.
Vec3 pixel_ray(const CArmPose& p, int size, int i, int j) {
  const CArmFrame f = carm_frame(p);
  const double x = ((j + 0.5) / size - 0.5) * p.fov, y = (0.5 - (i + 0.5) / size) * p.fov;
  return (f.detector_centre + x * f.image_right + y * f.image_up - f.source).normalized();
}

// Chord of a ray through an infinite cylinder along z at the origin of radius r.
double cylinder_chord(const Vec3& o, const Vec3& d, double r) {
  const double a = d.x() * d.x() + d.y() * d.y();
  const double b = 2.0 * (o.x() * d.x() + o.y() * d.y());
  const double c = o.x() * o.x() + o.y() * o.y() - r * r;
  const double disc = b * b - 4.0 * a * c;
  return disc > 0.0 ? std::sqrt(disc) / a : 0.0;
}

// A stent drawn by the renderer: along the central rows the CoCr channel holds the metal path of
// each pixel's ray through the shell (outer minus inner chord, times the coverage), and its line
// integral is (mu_CoCr - mu_soft) times that: about 2 mu t coverage through both walls.
TEST_F(RenderProcedureGl, StentShellPathLengthIsAnalytic) {
  const StentSpec spec = catalogue_stent();
  std::vector<Vec3> rings;
  for (int k = 0; k <= 20; ++k) rings.emplace_back(0.0, 0.0, -5e-3 + 0.5e-3 * k);
  const double R = 1.5e-3, t = spec.strut_thickness;
  const std::vector<double> radius(rings.size(), R);
  const float fill = stent_fill(spec, BeamEnergy::k60keV);
  CArmPose pose;  // AP: the stent's axis (z) runs up the image
  pose.fov = 0.05;
  const int n = 256;
  FluoroRenderer r(n);
  r.add_mesh(stent_xray_mesh(rings, radius, t, fill, 64));
  r.render(pose, FluoroOutput::kPathLengths);
  std::vector<float> L, p;
  r.read_path_lengths(L);
  r.read_line_integral(p);
  const int cocr = static_cast<int>(XrayMaterial::kCoCr);
  const double w = line_integral_weights(BeamEnergy::k60keV)[cocr];
  const CArmFrame f = carm_frame(pose);
  int checked = 0;
  for (int i = 100; i <= 156; i += 8)
    for (int j = 0; j < n; ++j) {
      const Vec3 d = pixel_ray(pose, n, i, j);
      const double shell = cylinder_chord(f.source, d, R) - cylinder_chord(f.source, d, R - t);
      // Within a pixel of the silhouettes the chord is steep: only where the ray crosses both walls
      // well inside them.
      if (cylinder_chord(f.source, d, R - t - 0.2e-3) <= 0.0) continue;
      const std::size_t k = static_cast<std::size_t>(i * n + j);
      const double want = fill * shell;
      // Each wall is crossed at incidence a (shell = 2 t / cos a); the 64-gon's facets tilt by up
      // to pi / 64 from the circle's tangent, so its path may be 2 t / cos(a + pi / 64).
      const double a = std::acos(std::min(1.0, 2.0 * t / shell));
      const double tol =
          fill * 2.0 * t * (1.0 / std::cos(a + kPi / 64.0) - 1.0 / std::cos(a)) + 0.005 * want;
      EXPECT_NEAR(L[k * kNumXrayMaterials + cocr], want, tol) << i << "," << j;
      EXPECT_NEAR(p[k], w * L[k * kNumXrayMaterials + cocr], 1e-4 * p[k] + 1e-7);
      ++checked;
    }
  EXPECT_GT(checked, 50);
  // The central ray: 2 t coverage of CoCr, a line integral about 2 (mu - mu_soft) t coverage.
  const std::size_t c = static_cast<std::size_t>(128 * n + 128);
  EXPECT_NEAR(L[c * kNumXrayMaterials + cocr], 2.0 * t * fill, 0.02 * 2.0 * t * fill);
}

// Where a rest point lands in the image (row, column in pixels, fractional).
Eigen::Vector2d pixel_of(const CArmPose& pose, int n, const Vec3& p) {
  const Eigen::Vector2d d = project_to_detector(pose, p);
  return {(0.5 - d.y() / pose.fov) * n, (d.x() / pose.fov + 0.5) * n};
}

// The tube scene's frames: AP, the tube's axis (z) up the image, centred on the lesion.
struct TubeFrames {
  static constexpr int kSize = 256;
  CArmPose pose;
  SimFluoroscopy fluoro;
  explicit TubeFrames(const SimModel& md) : fluoro(md, kSize) {
    pose.fov = 0.05;
    pose.isocentre = Vec3(0.0, 0.0, 0.066);
  }
  // The line integral of a snapshot's frame.
  std::vector<float> line_integral(const FrameSnapshot& f) {
    std::vector<std::uint8_t> img;
    ImageChainSettings chain;
    fluoro.frame(f, pose, chain, img);
    std::vector<float> p;
    fluoro.renderer().read_line_integral(p);
    return p;
  }
  // Width (m at the tube) of what `a` adds over `b` on the image row through z: the pixels
  // where the difference passes `threshold`, over the magnification.
  double width(const std::vector<float>& a, const std::vector<float>& b, double z,
               double threshold) const {
    const int row = static_cast<int>(pixel_of(pose, kSize, Vec3(0, 0, z)).x());
    EXPECT_TRUE(row > 0 && row < kSize - 1) << "z " << z << " outside the field";
    if (row <= 0 || row >= kSize - 1) return 0.0;
    int count = 0;
    for (int j = 0; j < kSize; ++j) {
      const std::size_t k = static_cast<std::size_t>(row * kSize + j);
      count += a[k] - b[k] > threshold;
    }
    const double px = pose.fov / kSize / magnification(pose, Vec3(0, 0, z));
    return count * px;
  }
};

// A balloon at 4 atm in the 60 % lesion (below its 6 atm opening pressure): the lesion holds its
// waist. In the frame the balloon's contrast band is narrower across the lesion's throat than
// across its shoulders, and as wide as the balloon is there.
TEST_F(RenderProcedureGl, InflatedBalloonShowsItsWaist) {
  TubeRun r("balloon-sc-3.0x15");
  r.run(0.3, 4.0 * kAtm);
  const BalloonState& bs = r.sim->state().procedure.balloons[0];
  ASSERT_GT(bs.pressure, 0.0);
  TubeFrames tf(r.sim->model());
  const FrameSnapshot inflated = snapshot(*r.sim);
  FrameSnapshot deflated = inflated;
  deflated.balloons[0].pressure = 0.0;  // the same frame without the balloon's contrast
  const std::vector<float> a = tf.line_integral(inflated), b = tf.line_integral(deflated);
  // Thresholds of 0.02 in the line integral: 0.15 mm of diluted contrast.
  const double waist = tf.width(a, b, 0.066, 0.02);
  // Shoulders: 0.5 mm inside the lesion's ends (60 and 72 mm), where it narrows the tube by 1 %.
  const double distal = tf.width(a, b, 0.0605, 0.02), proximal = tf.width(a, b, 0.0715, 0.02);
  const double full = 0.5 * bs.free_diameter;
  EXPECT_GT(distal, 1.6 * full) << "a shoulder about as wide as the free balloon";
  EXPECT_GT(proximal, 1.6 * full);
  EXPECT_LT(waist, 0.6 * std::min(distal, proximal)) << "the waist";
  // The waist as wide as the balloon's narrowest radius (the lesion's throat, 0.6 mm), within
  // two pixels.
  const double rmin = *std::min_element(bs.radius.begin() + 3, bs.radius.end() - 3);
  const double px = tf.pose.fov / TubeFrames::kSize / magnification(tf.pose, tf.pose.isocentre);
  EXPECT_NEAR(waist, 2.0 * rmin, 2.0 * px);
  // The contrast it holds weights it: a quarter-strength mixture shows half the 1:1's.
  FrameSnapshot weaker = inflated;
  weaker.balloons[0].contrast = 0.5f * kBalloonContrastFraction;
  const std::vector<float> c = tf.line_integral(weaker);
  double full_sum = 0.0, weak_sum = 0.0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    full_sum += a[k] - b[k];
    weak_sum += c[k] - b[k];
  }
  EXPECT_GT(full_sum, 0.0);
  EXPECT_NEAR(weak_sum, 0.5 * full_sum, 1e-3 * full_sum);
}

// The final angiogram: contrast in the tube before the balloon and after it opened the lesion at
// 12 atm and was deflated (the lesion gives back 30 %). Across the lesion's throat the contrast
// column is more than 0.8 mm wider after; away from the lesion it is the same.
TEST_F(RenderProcedureGl, FinalAngiogramShowsTheLesionOpened) {
  TubeRun r("balloon-sc-3.0x15");
  TubeFrames tf(r.sim->model());
  auto iodine_widths = [&](double z) {
    FrameSnapshot with = snapshot(*r.sim);
    with.contrast.assign(r.sim->tree().segments.size(), 1.0f);
    FrameSnapshot without = with;
    without.contrast.assign(without.contrast.size(), 0.0f);
    const std::vector<float> a = tf.line_integral(with), b = tf.line_integral(without);
    return tf.width(a, b, z, 0.05);
  };
  // Healthy: 6 mm beyond the lesion's end (the field spans 66 +- 16 mm of the tube).
  const double before_throat = iodine_widths(0.066), before_healthy = iodine_widths(0.078);
  r.run(0.3, 12.0 * kAtm);
  r.run(0.3, 0.0);
  ASSERT_EQ(r.sim->state().procedure.balloons[0].pressure, 0.0);
  const double after_throat = iodine_widths(0.066), after_healthy = iodine_widths(0.078);
  const double px = tf.pose.fov / TubeFrames::kSize / magnification(tf.pose, tf.pose.isocentre);
  EXPECT_NEAR(before_throat, 1.2e-3, 3.0 * px) << "a 60 % stenosis of a 3 mm tube";
  EXPECT_GT(after_throat, before_throat + 0.8e-3);
  EXPECT_NEAR(after_healthy, before_healthy, 1.01 * px);
  EXPECT_NEAR(before_healthy, 3.0e-3, 3.0 * px);
}

// A deployed stent in the frame: its struts' metal along the tube over the stent's length, none
// beyond it; through its middle about 2 t coverage of CoCr.
TEST_F(RenderProcedureGl, DeployedStentIsDrawnAtItsRings) {
  TubeRun r("stent-cocr-3.0x18");
  r.run(0.3, 10.0 * kAtm);
  r.run(0.3, 0.0);
  const StentState& ss = r.sim->state().procedure.stents[0];
  ASSERT_EQ(ss.phase, StentState::Phase::kDeployed);
  TubeFrames tf(r.sim->model());
  tf.line_integral(snapshot(*r.sim));
  FluoroRenderer& fr = tf.fluoro.renderer();
  fr.render(tf.pose, FluoroOutput::kPathLengths);
  std::vector<float> L;
  fr.read_path_lengths(L);
  const int n = TubeFrames::kSize, cocr = static_cast<int>(XrayMaterial::kCoCr);
  const StentSpec& spec = *r.sim->model().procedure.balloons[0].stent;
  auto metal_at = [&](double z) {
    const Eigen::Vector2d px = pixel_of(tf.pose, n, Vec3(0, 0, z));
    const std::size_t k =
        static_cast<std::size_t>(static_cast<int>(px.x()) * n + static_cast<int>(px.y()));
    return L[k * kNumXrayMaterials + cocr];
  };
  const double mid = 0.5 * (ss.ring_s.front() + ss.ring_s.back());
  const double want = 2.0 * spec.strut_thickness * spec.metal_coverage;
  EXPECT_NEAR(metal_at(mid), want, 0.03 * want);
  EXPECT_NEAR(metal_at(ss.ring_s.front() + 2e-3), want, 0.03 * want);
  EXPECT_EQ(metal_at(ss.ring_s.front() - 2e-3), 0.0f);
  EXPECT_EQ(metal_at(ss.ring_s.back() + 2e-3), 0.0f);
}

// A balloon catheter added over the wire in a running scene (issue 25, instrument exchange): the
// renderer built before the exchange draws it inflated, with its waist, after the model it was
// built from is gone (it reads the model the snapshots carry from then on; it read a freed one
// before, and `vcsim run` with frames crashed at the first frame after an exchange).
TEST_F(RenderProcedureGl, ABalloonAddedByAnExchangeIsDrawnAfterTheFirstModelIsGone) {
  test::TubeSpecs t;
  t.radius_mm = 1.5;
  t.lesion_percent = 60;
  t.lesions_json = R"([{"opening_pressure_atm": 6, "recoil": 0.3, "crossing_force_n": 100}])";
  const fs::path dir = scratch("exchange");
  Simulator sim(test::tube_scenario(
      dir, t,
      R"([{"name": "wire", "catalogue": "wire-014-floppy", "max_nodes": 160, "tip_segment_mm": 1}])"));
  fs::remove_all(dir);
  TubeFrames tf(sim.model());
  StepCommands cmds;
  cmds.reset(1);
  cmds.drive[0].mode = DriveCommand::Mode::kPosition;
  const double target = 0.066, wire = test::kAccessS - target + 0.03;
  while (sim.time() < 3.0) {
    cmds.drive[0].translation = std::min(wire, 0.05 * sim.time());
    sim.step(cmds);
  }
  tf.line_integral(snapshot(sim));  // a frame of the first model
  std::weak_ptr<const SimModel> first = sim.state().model;
  InstrumentChange add;
  add.kind = InstrumentChange::Kind::kAdd;
  add.name = "balloon";
  add.catalogue = "balloon-sc-3.0x15";
  add.over = "wire";
  add.max_nodes = 200;
  add.tip_segment = 1e-3;
  add.source = "test";
  add.field = "change";
  sim.exchange(add);
  ASSERT_EQ(sim.num_instruments(), 2);
  cmds.reset(2);
  for (DriveCommand& d : cmds.drive) d.mode = DriveCommand::Mode::kPosition;
  cmds.drive[0].translation = wire;
  const double balloon = test::balloon_depth(sim.instrument_spec(1), target);
  const double start = sim.time();
  while (sim.time() < start + 3.0) {
    cmds.drive[1].translation = std::min(balloon, 0.05 * (sim.time() - start));
    sim.step(cmds);
  }
  cmds.balloon_pressure = 4.0 * kAtm;  // below the lesion's opening pressure: a waist
  const double inflate = sim.time();
  while (sim.time() < inflate + 0.3) sim.step(cmds);
  const FrameSnapshot inflated = snapshot(sim);
  ASSERT_EQ(inflated.balloons.size(), 1u);
  ASSERT_GT(inflated.balloons[0].pressure, 0.0);
  FrameSnapshot deflated = inflated;
  deflated.balloons[0].pressure = 0.0;
  const std::vector<float> a = tf.line_integral(inflated), b = tf.line_integral(deflated);
  // The renderer held the first model while it drew it; from the first frame of the new one
  // nothing does (a renderer still reading it would read freed memory: the sanitizer build).
  EXPECT_TRUE(first.expired()) << "nothing holds the model the renderer was built from";
  const double waist = tf.width(a, b, 0.066, 0.02);
  const double distal = tf.width(a, b, 0.0605, 0.02), proximal = tf.width(a, b, 0.0715, 0.02);
  const BalloonState& bs = sim.state().procedure.balloons[0];
  EXPECT_GT(distal, 1.6 * 0.5 * bs.free_diameter) << "the balloon is drawn";
  EXPECT_GT(proximal, 1.6 * 0.5 * bs.free_diameter);
  EXPECT_LT(waist, 0.6 * std::min(distal, proximal)) << "with its waist";
}

}  // namespace
}  // namespace vcsim
