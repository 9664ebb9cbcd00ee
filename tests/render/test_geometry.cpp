// C-arm geometry, closed meshes, materials and the image chain: everything that needs no GL.
#include <gtest/gtest.h>

#include <cmath>
#include <map>

#include "vcsim/render.h"

namespace vcsim {
namespace {

constexpr double kPi = 3.14159265358979323846;

CArmPose pose_at(double primary, double secondary) {
  CArmPose p;
  p.primary_deg = primary;
  p.secondary_deg = secondary;
  p.isocentre = Vec3(0.01, -0.02, 0.03);
  return p;
}

TEST(CArm, IsocentreProjectsToDetectorCentre) {
  for (double a : {-90.0, -30.0, 0.0, 40.0, 120.0})
    for (double b : {-40.0, 0.0, 30.0}) {
      const CArmPose p = pose_at(a, b);
      const Eigen::Vector2d x = project_to_detector(p, p.isocentre);
      EXPECT_NEAR(x.norm(), 0.0, 1e-12) << a << " " << b;
      const CArmFrame f = carm_frame(p);
      EXPECT_NEAR((f.detector_centre - f.source).norm(), p.sid, 1e-12);
      EXPECT_NEAR((p.isocentre - f.source).norm(), p.sod, 1e-12);
    }
}

TEST(CArm, AnteroposteriorShowsPatientLeftOnTheRight) {
  const CArmFrame f = carm_frame(pose_at(0, 0));
  EXPECT_NEAR((f.beam - Vec3(0, -1, 0)).norm(), 0.0, 1e-12);  // source posterior, under the table
  EXPECT_NEAR((f.image_right - Vec3(1, 0, 0)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((f.image_up - Vec3(0, 0, 1)).norm(), 0.0, 1e-12);
}

TEST(CArm, Lao90LooksAlongTheLeftRightAxis) {
  // LAO 90: the detector on the patient's left, the beam from right to left (+x).
  EXPECT_NEAR((carm_frame(pose_at(90, 0)).beam - Vec3(1, 0, 0)).norm(), 0.0, 1e-12);
  EXPECT_NEAR((carm_frame(pose_at(-90, 0)).beam - Vec3(-1, 0, 0)).norm(), 0.0, 1e-12);
  // LAO views show the spine (posterior) on the image's right.
  EXPECT_GT(carm_frame(pose_at(45, 0)).image_right.y(), 0.5);
}

TEST(CArm, CranialTiltsTheDetectorTowardTheHead) {
  EXPECT_NEAR(carm_frame(pose_at(0, 30)).beam.z(), std::sin(30 * kPi / 180), 1e-12);
  EXPECT_LT(carm_frame(pose_at(40, -30)).beam.z(), 0.0);
}

TEST(CArm, MagnificationIsSidOverSodAtTheIsocentre) {
  for (double a : {-30.0, 0.0, 45.0}) {
    const CArmPose p = pose_at(a, -20);
    const CArmFrame f = carm_frame(p);
    EXPECT_NEAR(magnification(p, p.isocentre), p.sid / p.sod, 1e-12);
    const Eigen::Vector2d x = project_to_detector(p, p.isocentre + 0.01 * f.image_right);
    EXPECT_NEAR(x.x(), 0.01 * p.sid / p.sod, 1e-12);
    EXPECT_NEAR(x.y(), 0.0, 1e-12);
    const Eigen::Vector2d y = project_to_detector(p, p.isocentre + 0.02 * f.image_up);
    EXPECT_NEAR(y.y(), 0.02 * p.sid / p.sod, 1e-12);
  }
}

TEST(CArm, ProjectionMatrixAgreesWithTheDetector) {
  const CArmPose p = pose_at(35, 25);
  const Mat4 M = carm_projection_matrix(p, 0.01, 3.0) * carm_view_matrix(p);
  for (const Vec3& q : {Vec3(0.03, 0.01, -0.02), Vec3(-0.05, 0.04, 0.06)}) {
    const Eigen::Vector4d c = M * (p.isocentre + q).homogeneous();
    const Eigen::Vector2d ndc = c.head<2>() / c.w();
    const Eigen::Vector2d d = project_to_detector(p, p.isocentre + q);
    EXPECT_NEAR(ndc.x() * 0.5 * p.fov, d.x(), 1e-12);
    EXPECT_NEAR(ndc.y() * 0.5 * p.fov, d.y(), 1e-12);
    EXPECT_GT(c.w(), 0.0);
  }
}

TEST(CArm, OutOfRangeValuesNameTheirField) {
  auto field_of = [](const CArmPose& p) {
    try {
      p.validate("test");
    } catch (const InputError& e) {
      return e.field();
    }
    return std::string("none");
  };
  CArmPose p;
  EXPECT_EQ(field_of(p), "none");
  p.primary_deg = 121;
  EXPECT_EQ(field_of(p), "primary_deg");
  p.primary_deg = -120;
  EXPECT_EQ(field_of(p), "none");
  p.secondary_deg = -61;
  EXPECT_EQ(field_of(p), "secondary_deg");
  p.secondary_deg = NAN;
  EXPECT_EQ(field_of(p), "secondary_deg");
  p.secondary_deg = 0;
  p.sid = 2.0;
  EXPECT_EQ(field_of(p), "sid");
  p.sid = 1.2;
  p.sod = 1.19;
  EXPECT_EQ(field_of(p), "sod");
  p.sod = 0.78;
  p.fov = 0.01;
  EXPECT_EQ(field_of(p), "fov");
}

// Signed volume by the divergence theorem: positive for outward winding.
double volume(const TriangleMesh& m) {
  double v = 0.0;
  for (const auto& t : m.triangles)
    v += m.vertices[t[0]].dot(m.vertices[t[1]].cross(m.vertices[t[2]])) / 6.0;
  return v;
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

TEST(Meshes, TubeIsClosedAndWoundOutward) {
  std::vector<Vec3> nodes;
  for (int i = 0; i <= 20; ++i) nodes.emplace_back(0.01 * std::sin(0.1 * i), 0.0, 0.005 * i);
  double len = 0.0;
  for (int i = 0; i < 20; ++i) len += (nodes[i + 1] - nodes[i]).norm();
  const double r = 1e-3;
  const TriangleMesh m = tube_mesh(nodes, std::vector<double>{r}, 32);
  EXPECT_TRUE(closed(m));
  // A 32-gon's area is pi r^2 sin(2 pi / 32) / (2 pi / 32).
  const double area = 0.5 * 32 * r * r * std::sin(2 * kPi / 32);
  EXPECT_NEAR(volume(m), area * len, 0.02 * area * len);
}

TEST(Meshes, CapsCloseAnOpenTube) {
  std::vector<Vec3> nodes = {Vec3(0, 0, 0), Vec3(0, 0, 0.01)};
  TriangleMesh m = tube_mesh(nodes, std::vector<double>{2e-3}, 16);
  const double v = volume(m);
  m.triangles.resize(m.triangles.size() - 32);  // drop both end caps
  EXPECT_FALSE(closed(m));
  EXPECT_EQ(cap_boundary_loops(m), 2);
  EXPECT_TRUE(closed(m));
  EXPECT_NEAR(volume(m), v, 1e-12);
}

TEST(Meshes, InstrumentHasShaftCoilAndMarkers) {
  InstrumentVisual w;
  for (int i = 0; i <= 100; ++i) w.nodes.emplace_back(0, 0, 1e-3 * i);
  w.radii = {0.2e-3};
  w.radiopaque_length = 0.03;
  w.marker_from_tip = {0.01, 0.05};
  const auto meshes = instrument_xray_meshes(w);
  ASSERT_EQ(meshes.size(), 4u);
  for (const auto& m : meshes) EXPECT_TRUE(closed(m.mesh)) << m.name;
  EXPECT_EQ(meshes[1].material, XrayMaterial::kPtIr);
  const double coil = volume(meshes[1].mesh), shaft = volume(meshes[0].mesh);
  EXPECT_NEAR(coil / shaft, 0.3, 0.01);
}

TEST(Materials, WeightsCountWhatEachMaterialAddsOverSoftTissue) {
  for (BeamEnergy e : {BeamEnergy::k60keV, BeamEnergy::k80keV}) {
    const auto w = line_integral_weights(e);
    EXPECT_DOUBLE_EQ(w[0], attenuation_per_m(XrayMaterial::kSoftTissue, e));
    EXPECT_EQ(w[static_cast<int>(XrayMaterial::kBlood)], 0.0f);
    EXPECT_LT(w[static_cast<int>(XrayMaterial::kLung)], 0.0f);
    EXPECT_GT(w[static_cast<int>(XrayMaterial::kBone)], 0.0f);
    EXPECT_GT(w[static_cast<int>(XrayMaterial::kPtIr)], w[static_cast<int>(XrayMaterial::kSteel)]);
  }
  EXPECT_DOUBLE_EQ(attenuation_per_m(XrayMaterial::kIodine, BeamEnergy::k60keV), 265.0);
  // Stent struts: L-605 (clinical.md), above tungsten's K-edge the higher at 80 keV.
  EXPECT_DOUBLE_EQ(attenuation_per_m(XrayMaterial::kCoCr, BeamEnergy::k60keV), 1480.0);
  EXPECT_DOUBLE_EQ(attenuation_per_m(XrayMaterial::kCoCr, BeamEnergy::k80keV), 1540.0);
  EXPECT_EQ(to_string(XrayMaterial::kCoCr), "cocr");
}

TEST(Contrast, LeftCoronaryTreeOnly) {
  const VesselTree t = default_patient();
  const auto c = left_coronary_contrast(t, 0.8f);
  for (const char* s : {"left_main", "lad", "lcx", "diagonal_1", "obtuse_marginal_1"})
    EXPECT_EQ(c[t.find(s)], 0.8f) << s;
  for (const char* s : {"rca", "aortic_root", "ascending_aorta", "posterior_descending"})
    EXPECT_EQ(c[t.find(s)], 0.0f) << s;
}

TEST(ImageChain, DeterministicPerSeedAndDarkWhereAttenuating) {
  const int n = 64;
  std::vector<float> p(n * n, 2.0f);
  for (int i = 28; i < 36; ++i)
    for (int j = 0; j < n; ++j) p[i * n + j] = 3.0f;  // a dark band
  ImageChainSettings s;
  s.window = 2.0;
  s.level = 2.5;
  std::vector<std::uint8_t> a, b, c;
  image_chain(p, n, s, a);
  image_chain(p, n, s, b);
  EXPECT_EQ(a, b);
  s.seed = 2;
  image_chain(p, n, s, c);
  EXPECT_NE(a, c);
  double band = 0, rest = 0;
  for (int j = 20; j < 44; ++j) {
    band += a[32 * n + j];
    rest += a[16 * n + j];
  }
  EXPECT_LT(band, 0.8 * rest);
  EXPECT_EQ(a[0], 0);  // outside the circular field
}

TEST(ImageChain, NoiseFollowsPoisson) {
  // Without blur the detected counts have variance I0 exp(-p): check through the log.
  const int n = 128;
  std::vector<float> p(n * n, 1.0f);
  ImageChainSettings s;
  s.blur_sigma_px = 0.0;
  s.vignetting = 0.0;
  s.dose = 1e4;
  // Window so that grey = 255 (1 - p / 4): 1 grey level is 4/255 in p.
  s.level = 2.0;
  s.window = 4.0;
  std::vector<std::uint8_t> g;
  image_chain(p, n, s, g);
  double sum = 0, sum2 = 0;
  int k = 0;
  for (int i = 44; i < 84; ++i)
    for (int j = 44; j < 84; ++j) {
      const double pe = (1.0 - g[i * n + j] / 255.0) * 4.0;
      sum += pe;
      sum2 += pe * pe;
      ++k;
    }
  const double mean = sum / k, sd = std::sqrt(sum2 / k - mean * mean);
  EXPECT_NEAR(mean, 1.0, 0.01);
  // sd of -ln(N / I0) is 1 / sqrt(lambda); quantisation adds (4/255)^2 / 12.
  const double expected = std::sqrt(1.0 / (1e4 * std::exp(-1.0)) + std::pow(4.0 / 255, 2) / 12);
  EXPECT_NEAR(sd, expected, 0.15 * expected);
}

TEST(ImageChain, SettingsValidated) {
  ImageChainSettings s;
  s.dose = -1;
  EXPECT_THROW(s.validate("t"), InputError);
  s = {};
  s.gamma = 0;
  EXPECT_THROW(s.validate("t"), InputError);
  s = {};
  EXPECT_NO_THROW(s.validate("t"));
}

}  // namespace
}  // namespace vcsim
