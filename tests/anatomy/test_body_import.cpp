// Body context meshes (closed, outward, registered to the tree) and patient mesh import (STL with
// our JSON, SimVascular .pth paths), with clear errors for bad files.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <numbers>
#include <unordered_map>

#include "anatomy_test_util.h"
#include "vcsim/mesh_io.h"

namespace vcsim {
namespace {

using test::patient;
constexpr double mm = 1e-3;

double signed_volume(const TriangleMesh& m) {
  double v = 0.0;
  for (const auto& t : m.triangles)
    v += m.vertices[t[0]].dot(m.vertices[t[1]].cross(m.vertices[t[2]])) / 6.0;
  return v;
}

// Every edge used exactly twice, once in each direction: closed and consistently oriented.
void expect_closed(const TriangleMesh& m, const std::string& name) {
  std::unordered_map<std::uint64_t, int> directed;
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e)
      ++directed[(static_cast<std::uint64_t>(t[e]) << 32) |
                 static_cast<std::uint32_t>(t[(e + 1) % 3])];
  int bad = 0;
  for (auto& [k, n] : directed) {
    const std::uint64_t rev = (k << 32) | (k >> 32);
    bad += n != 1 || directed.count(rev) == 0 || directed.at(rev) != 1;
  }
  EXPECT_EQ(bad, 0) << name;
}

TEST(AnatomyBody, PartsAreClosedOutwardTaggedAndRegistered) {
  const VesselTree& t = patient();
  const auto parts = build_body_context(t);
  std::vector<std::string> names;
  for (const auto& p : parts) {
    names.push_back(p.name);
    expect_closed(p.mesh, p.name);
    EXPECT_GT(signed_volume(p.mesh), 0.0) << p.name;  // outward normals
    EXPECT_EQ(p.mesh.normals.size(), p.mesh.triangles.size());
  }
  EXPECT_EQ(names, (std::vector<std::string>{"torso", "lung_left", "lung_right", "heart", "spine",
                                             "ribs", "sternum", "diaphragm"}));
  auto part = [&](const std::string& n) -> const BodyPart& {
    return *std::find_if(parts.begin(), parts.end(), [&](auto& p) { return p.name == n; });
  };
  EXPECT_EQ(part("heart").material, Material::kHeart);
  EXPECT_EQ(part("lung_left").material, Material::kLung);
  EXPECT_EQ(part("spine").material, Material::kBone);
  EXPECT_EQ(part("ribs").material, Material::kBone);
  EXPECT_EQ(part("torso").material, Material::kSoftTissue);
  // The heart is the tree's ellipsoid: volume 4/3 pi abc (within the facet error).
  const Vec3 r = t.heart->radii;
  EXPECT_NEAR(signed_volume(part("heart").mesh),
              4.0 / 3.0 * std::numbers::pi * r.x() * r.y() * r.z(),
              0.03 * 4.0 / 3.0 * std::numbers::pi * r.x() * r.y() * r.z());
  // The torso contains every vessel point; the spine lies behind the descending aorta.
  Vec3 lo = Vec3::Constant(1e9), hi = Vec3::Constant(-1e9);
  for (const Vec3& v : part("torso").mesh.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  for (const auto& s : t.segments)
    for (const Vec3& p : s.points)
      EXPECT_TRUE((p.array() > lo.array()).all() && (p.array() < hi.array()).all()) << s.name;
  double spine_y = 0.0;
  for (const Vec3& v : part("spine").mesh.vertices)
    spine_y += v.y() / part("spine").mesh.num_vertices();
  EXPECT_GT(spine_y, t.segments[t.find("thoracic_aorta")].points[40].y());
}

std::filesystem::path temp(const std::string& name) {
  return std::filesystem::temp_directory_path() /
         ("vcsim_anat_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "_" +
          name);
}

TEST(AnatomyImport, StlWithJsonCentrelines) {
  // A bent tube phantom written in mm, and its centreline as a one-segment tree.
  BentTubeSpec spec;
  spec.radius = 2.0 * mm;
  const TriangleMesh tube = make_bent_tube(spec);
  const auto stl = temp("tube.stl");
  write_stl(tube, stl.string(), true, 1e-3);
  VesselTree t;
  t.name = "tube";
  VesselSegment s;
  s.name = "tube";
  s.points =
      bent_centreline(spec.straight1, spec.bend_radius, spec.bend_angle, spec.straight2, 1 * mm);
  s.radii.assign(s.points.size(), spec.radius);
  t.segments = {s};
  t.open_start = true;
  t.access = {0, 0.0};
  t.target = {0, 10 * mm};
  t.lesions.push_back({0, 10 * mm, 6 * mm, 0.5, 0.0, 0.0});
  const Lumen lu = import_lumen(stl.string(), t, 1e-3);
  EXPECT_EQ(lu.mesh.num_triangles(), tube.num_triangles());
  EXPECT_EQ(lu.ends.size(), 2u);
  const LumenCheck c = check_lumen(lu.mesh, lu.ends);
  EXPECT_TRUE(c.manifold);
  EXPECT_EQ(c.boundary_loops, 2);
  // The lesion narrows the imported wall too: half the radius at the throat.
  AabbTree tree;
  tree.build(lu.mesh);
  EXPECT_NEAR(measure_radius(lu.mesh, tree, t.segments[0], 13 * mm, 32).mean, 1.0 * mm, 0.05 * mm);
  std::filesystem::remove(stl);
}

TEST(AnatomyImport, PthPathsWithRadiiMeasuredOnTheMesh) {
  // A straight tube (r 3 mm) and its path in cm, as in Vascular Model Repository files. The path
  // runs just off the axis: on the exact axis of a make_tube mesh the collision query reports
  // the centre outside (a tie between equidistant facets; reported to the collision layer).
  TubeSpec a;
  a.centreline = {Vec3(0, 0, 0), Vec3(0, 0, 60 * mm)};
  a.radius = 3 * mm;
  const TriangleMesh ma = make_tube(a);
  const auto pth = temp("paths.pth");
  {
    std::ofstream f(pth);
    f << "<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<format version=\"1.0\" />\n";
    f << "<path id=\"1\" method=\"0\">\n <timestep id=\"0\">\n  <path_element method=\"0\">\n"
      << "   <path_points>\n";
    for (int k = 0; k <= 10; ++k)
      f << "    <path_point id=\"" << k << "\">\n     <pos x=\"0.01\" y=\"0.02\" z=\""
        << 0.5 + 0.5 * k << "\" />\n     <tangent x=\"0\" y=\"0\" z=\"1\" />\n    </path_point>\n";
    f << "   </path_points>\n  </path_element>\n </timestep>\n</path>\n";
  }
  VesselTree t = load_pth_paths(pth.string(), 10e-3);  // cm
  ASSERT_EQ(t.num_segments(), 1);
  EXPECT_EQ(t.segments[0].points.size(), 11u);
  EXPECT_NEAR(t.segments[0].points.back().z(), 55 * mm, 1e-12);
  EXPECT_TRUE(t.segments[0].radii.empty());
  measure_radii_on_mesh(t, ma, "tube");
  // The closest wall is the radius less the path's offset from the axis (0.1, 0.2 mm) and the
  // 32-sided tube's facet depth.
  const double expected =
      3 * mm - std::hypot(0.1 * mm, 0.2 * mm) - 3 * mm * (1 - std::cos(std::numbers::pi / 32));
  for (double r : t.segments[0].radii) EXPECT_NEAR(r, expected, 0.01 * mm);
  // Malformed: a point without z.
  {
    std::ofstream f(pth);
    f << "<path id=\"1\"><path_point id=\"0\"><pos x=\"0\" y=\"0\" /></path_point></path>";
  }
  try {
    load_pth_paths(pth.string());
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "path_point[0].pos.z");
  }
  {
    std::ofstream f(pth);
    f << "<format version=\"1.0\" />";
  }
  EXPECT_THROW(load_pth_paths(pth.string()), InputError);
  std::filesystem::remove(pth);
}

TEST(AnatomyImport, BadMeshFilesGiveClearErrors) {
  const auto bad = temp("bad.stl");
  {
    std::ofstream f(bad, std::ios::binary);
    f << "solid x\nfacet normal 0 0 1\nouter loop\n";
  }
  VesselTree t = test::patient();
  try {
    import_lumen(bad.string(), t);
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), bad.string());
  }
  std::filesystem::remove(bad);
  EXPECT_THROW(import_lumen("/nonexistent/lumen.obj", t), InputError);
}

}  // namespace
}  // namespace vcsim
