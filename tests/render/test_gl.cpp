// The renderer against analytic answers (path length through spheres, Beer-Lambert), and a
// default-patient frame, through a headless EGL context (Mesa llvmpipe: no display, no GPU).
#include <gtest/gtest.h>

#include <cmath>
#include <memory>

#include "gl_fixture.h"
#include "vcsim/render.h"

namespace vcsim {
namespace {

constexpr double kPi = 3.14159265358979323846;

class RenderGl : public test::GlSuite {};

// A latitude-longitude sphere wound outward.
TriangleMesh sphere(const Vec3& c, double r, int rings = 96, int sectors = 192) {
  TriangleMesh m;
  m.vertices.push_back(c + Vec3(0, 0, -r));
  for (int i = 1; i < rings; ++i) {
    const double th = kPi * i / rings - 0.5 * kPi;
    for (int j = 0; j < sectors; ++j) {
      const double ph = 2 * kPi * j / sectors;
      m.vertices.push_back(
          c + r * Vec3(std::cos(th) * std::cos(ph), std::cos(th) * std::sin(ph), std::sin(th)));
    }
  }
  m.vertices.push_back(c + Vec3(0, 0, r));
  auto at = [&](int i, int j) { return 1 + (i - 1) * sectors + (j % sectors); };
  const int top = m.num_vertices() - 1;
  for (int j = 0; j < sectors; ++j) m.triangles.push_back({0, at(1, j + 1), at(1, j)});
  for (int i = 1; i + 1 < rings; ++i)
    for (int j = 0; j < sectors; ++j) {
      m.triangles.push_back({at(i, j), at(i, j + 1), at(i + 1, j + 1)});
      m.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i + 1, j)});
    }
  for (int j = 0; j < sectors; ++j)
    m.triangles.push_back({top, at(rings - 1, j), at(rings - 1, j + 1)});
  m.recompute_normals();
  return m;
}

// Chord of the ray through pixel (i, j) in a sphere.
double chord(const CArmPose& p, int size, int i, int j, const Vec3& c, double r) {
  const CArmFrame f = carm_frame(p);
  const double x = ((j + 0.5) / size - 0.5) * p.fov, y = (0.5 - (i + 0.5) / size) * p.fov;
  const Vec3 dir = (f.detector_centre + x * f.image_right + y * f.image_up - f.source).normalized();
  const Vec3 w = c - f.source;
  const double d2 = (w - w.dot(dir) * dir).squaredNorm();
  return d2 < r * r ? 2.0 * std::sqrt(r * r - d2) : 0.0;
}

constexpr int kSize = 128;

// The inscribed polyhedron (96 rings) lies inside the sphere by up to r (1 - cos(pi / 96)) at
// each crossing; where the chord is short the ray meets the faces obliquely and the gap grows
// as 2r / chord. Short chords (< 0.3 r) are not checked.
double tessellation_tolerance(double r, double chord_length) {
  if (chord_length <= 0.0) return 1e-6;
  const double gap = r * (1.0 - std::cos(kPi / 96.0));
  return 2.0 * gap * (2.0 * r / chord_length) * 1.5 + 1e-5;
}
bool near_silhouette(double r, double chord_length) {
  return chord_length > 0.0 && chord_length < 0.3 * r;
}

TEST_F(RenderGl, EmptySceneTransmitsEverything) {
  FluoroRenderer r(kSize);
  r.render(CArmPose{});
  std::vector<float> p;
  r.read_line_integral(p);
  for (float v : p) ASSERT_EQ(v, 0.0f);  // I = I0 exp(0) = I0
}

TEST_F(RenderGl, SpherePathLengthIsTheChordAndBeerLambertHolds) {
  for (double primary : {0.0, 40.0, -90.0}) {
    CArmPose pose;
    pose.primary_deg = primary;
    pose.secondary_deg = -20.0;
    pose.isocentre = Vec3(0.02, 0.01, -0.03);
    pose.fov = 0.2;
    const double R = 0.05;
    const Vec3 c = pose.isocentre + Vec3(0.005, -0.004, 0.003);
    FluoroRenderer r(kSize);
    r.add_mesh({"sphere", sphere(c, R), XrayMaterial::kBone, 1.0f, {}});
    r.render(pose, FluoroOutput::kPathLengths);
    std::vector<float> L, p;
    r.read_path_lengths(L);
    r.read_line_integral(p);
    const double w_bone = line_integral_weights(BeamEnergy::k60keV)[2];
    int checked = 0;
    for (int i = 0; i < kSize; i += 7)
      for (int j = 0; j < kSize; j += 5) {
        const double want = chord(pose, kSize, i, j, c, R);
        const std::size_t k = static_cast<std::size_t>(i * kSize + j);
        if (want < 0.3 * R) continue;  // near the silhouette the chord is steep in d
        // The inscribed polyhedron is thinner than the sphere by about r (1 - cos(pi/96)).
        const double got = L[k * kNumXrayMaterials + 2];
        EXPECT_NEAR(got, want, tessellation_tolerance(R, want))
            << "primary " << primary << " pixel " << i << "," << j;
        for (int m = 0; m < kNumXrayMaterials; ++m)
          if (m != 2) {
            ASSERT_NEAR(L[k * kNumXrayMaterials + m], 0.0, 1e-6);
          }
        // Beer-Lambert: I / I0 = exp(-mu L), on the rendered and on the analytic path length.
        EXPECT_NEAR(std::exp(-p[k]), std::exp(-w_bone * got), 1e-5);
        EXPECT_NEAR(std::exp(-p[k]), std::exp(-w_bone * want),
                    w_bone * tessellation_tolerance(R, want));
        ++checked;
      }
    EXPECT_GT(checked, 100);
  }
}

TEST_F(RenderGl, OverlappingObjectsAddPathLengths) {
  CArmPose pose;
  const double R = 0.03;
  const Vec3 a = Vec3(0.0, 0.0, 0.0), b = Vec3(0.01, 0.02, 0.0);  // b behind a, overlapping
  FluoroRenderer r(kSize);
  r.add_mesh({"a", sphere(a, R), XrayMaterial::kSoftTissue, 1.0f, {}});
  r.add_mesh({"b", sphere(b, R), XrayMaterial::kSoftTissue, 1.0f, {}});
  r.add_mesh({"c", sphere(a, 0.5 * R), XrayMaterial::kSteel, 0.5f, {}});  // fill scales
  r.render(pose, FluoroOutput::kPathLengths);
  std::vector<float> L, p, p_direct;
  r.read_path_lengths(L);
  r.read_line_integral(p);
  r.render(pose, FluoroOutput::kLineIntegral);
  r.read_line_integral(p_direct);
  const auto w = line_integral_weights(BeamEnergy::k60keV);
  for (int i = 40; i < 90; i += 3)
    for (int j = 40; j < 90; j += 3) {
      const std::size_t k = static_cast<std::size_t>(i * kSize + j);
      const double la = chord(pose, kSize, i, j, a, R), lb = chord(pose, kSize, i, j, b, R);
      const double lc = chord(pose, kSize, i, j, a, 0.5 * R);
      if (near_silhouette(R, la) || near_silhouette(R, lb) || near_silhouette(0.5 * R, lc))
        continue;
      const double soft = la + lb, steel = 0.5 * lc;
      EXPECT_NEAR(L[k * kNumXrayMaterials + 0], soft,
                  tessellation_tolerance(R, la) + tessellation_tolerance(R, lb));
      EXPECT_NEAR(L[k * kNumXrayMaterials + 6], steel, 0.5 * tessellation_tolerance(0.5 * R, lc));
      // The line integral is the weighted sum of the rendered channels.
      const double want = w[0] * L[k * kNumXrayMaterials + 0] + w[6] * L[k * kNumXrayMaterials + 6];
      EXPECT_NEAR(p[k], want, 1e-5 * want + 1e-5);
      EXPECT_NEAR(p_direct[k], p[k], 1e-4 * p[k] + 1e-5);  // both outputs agree
    }
}

TEST_F(RenderGl, StaticMeshesCachedPerPoseGiveTheSameFrame) {
  FluoroRenderer cached(kSize), direct(kSize);
  for (FluoroRenderer* r : {&cached, &direct}) {
    const int body =
        r->add_mesh({"body", sphere(Vec3::Zero(), 0.05), XrayMaterial::kSoftTissue, 1.0f, {}});
    r->add_mesh({"wire", sphere(Vec3(0.01, 0, 0), 0.005), XrayMaterial::kSteel, 1.0f, {}});
    if (r == &cached) r->set_static(body, true);
  }
  for (double primary : {0.0, 30.0, 30.0, -45.0}) {
    CArmPose pose;
    pose.primary_deg = primary;
    std::vector<float> a, b;
    cached.render(pose);
    cached.read_line_integral(a);
    direct.render(pose);
    direct.read_line_integral(b);
    ASSERT_EQ(a.size(), b.size());
    double worst = 0.0;
    for (std::size_t k = 0; k < a.size(); ++k)
      worst = std::max(worst, double(std::abs(a[k] - b[k])));
    EXPECT_LT(worst, 1e-5) << "primary " << primary;
  }
}

TEST_F(RenderGl, GroupConcentrationWeightsIodine) {
  CArmPose pose;
  XrayMesh x{"vessel", sphere(Vec3::Zero(), 0.01), XrayMaterial::kBlood, 1.0f, {}};
  x.vertex_group.assign(x.mesh.vertices.size(), 3);
  FluoroRenderer r(kSize);
  r.add_mesh(x);
  const std::vector<float> c = {0, 0, 0, 0.5f};
  r.set_group_concentration(c);
  r.render(pose, FluoroOutput::kPathLengths);
  std::vector<float> L;
  r.read_path_lengths(L);
  const std::size_t k = static_cast<std::size_t>(64 * kSize + 64);
  const double want = chord(pose, kSize, 64, 64, Vec3::Zero(), 0.01);
  EXPECT_NEAR(L[k * kNumXrayMaterials + 3], want, 1e-3 * want);
  EXPECT_NEAR(L[k * kNumXrayMaterials + 4], 0.5 * want, 1e-3 * want);
}

TEST_F(RenderGl, DefaultPatientVesselsAreDarkerThanBackground) {
  const VesselTree tree = default_patient();
  LumenSettings ls;
  ls.cache_dir = VCSIM_RENDER_TEST_CACHE;
  const Lumen lumen = build_lumen(tree, ls);
  const int n = 512;
  FluoroRenderer r(n);
  r.add_mesh(lumen_xray_mesh(lumen));
  for (const XrayMesh& m : body_xray_meshes(build_body_context(tree))) r.add_mesh(m);
  for (const InstrumentVisual& inst : demo_instruments(tree))
    for (const XrayMesh& m : instrument_xray_meshes(inst)) r.add_mesh(m);
  CArmPose pose;
  pose.primary_deg = 40;
  pose.secondary_deg = -30;
  pose.isocentre = tree.heart->centre;
  // Where the contrast projects: the line integral rises when the left tree is filled.
  std::vector<float> p0, p1;
  r.set_group_concentration(left_coronary_contrast(tree, 0.0f));
  r.render(pose);
  r.read_line_integral(p0);
  r.set_group_concentration(left_coronary_contrast(tree, 1.0f));
  r.render(pose);
  r.read_line_integral(p1);
  std::vector<std::uint8_t> img0, img1;
  ImageChainSettings s;
  image_chain(p1, n, s, img1);
  image_chain(p0, n, s, img0);
  double vessel = 0, vessel_before = 0, background = 0;
  int nv = 0, nb = 0;
  const double c = 0.5 * (n - 1), rad = 0.45 * n;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      if ((i - c) * (i - c) + (j - c) * (j - c) > rad * rad) continue;
      const std::size_t k = static_cast<std::size_t>(i * n + j);
      if (p1[k] - p0[k] > 0.3) {
        vessel += img1[k];
        vessel_before += img0[k];
        ++nv;
      } else if (p1[k] - p0[k] == 0.0f) {
        background += img1[k];
        ++nb;
      }
    }
  ASSERT_GT(nv, 500) << "the left coronaries should cover a visible area";
  vessel /= nv;
  vessel_before /= nv;
  background /= nb;
  EXPECT_LT(vessel, 0.7 * background) << "vessel " << vessel << " background " << background;
  EXPECT_LT(vessel, vessel_before - 20.0);
}

}  // namespace
}  // namespace vcsim
