// `vcsim anatomy` and `vcsim bench anatomy`: JSON with the documented keys, files written, and bad
// input as one line naming the file with exit status 2.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "cli_runner.h"

#include "vcsim/mesh_io.h"

namespace {

using Result = vcsim::test::CliResult;

std::filesystem::path temp(const std::string& name) {
  return std::filesystem::temp_directory_path() /
         ("vcsim_anat_cli_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) +
          ::testing::UnitTest::GetInstance()->current_test_info()->name() + name);
}

// Runs the CLI with the test cache (the built-in patient's lumen is built once for all tests).
Result run(const std::string& args) {
  return vcsim::test::run_cli(args,
                              std::string("XDG_CACHE_HOME=") + VCSIM_ANATOMY_TEST_CACHE + "/xdg ");
}

TEST(AnatomyCli, InfoJsonDescribesTheDefaultPatient) {
  const Result r = run("anatomy info --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_GT(j["triangles"].get<int>(), 10000);
  EXPECT_TRUE(j["watertight"].get<bool>());
  EXPECT_TRUE(j["manifold"].get<bool>());
  EXPECT_EQ(j["open_ends"], j["boundary_loops"]);
  ASSERT_TRUE(j["segments"].is_array());
  bool lad = false;
  for (const auto& s : j["segments"]) {
    EXPECT_GT(s["length_mm"].get<double>(), 0.0);
    EXPECT_GT(s["radius_min_mm"].get<double>(), 0.0);
    EXPECT_GE(s["radius_max_mm"].get<double>(), s["radius_min_mm"].get<double>());
    lad = lad || s["name"] == "lad";
  }
  EXPECT_TRUE(lad);
}

TEST(AnatomyCli, InfoOfAFileAndExport) {
  const std::string ex = std::string(VCSIM_ANATOMY_DATA) + "/bifurcation_example.json";
  const Result r = run("anatomy info " + ex + " --json --no-cache");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["segments"].size(), 2u);
  EXPECT_EQ(j["open_ends"].get<int>(), 3);
  EXPECT_TRUE(j["watertight"].get<bool>());
  const auto stl = temp(".stl"), obj = temp(".obj"), js = temp(".json");
  ASSERT_EQ(run("anatomy export " + ex + " --no-cache --out " + stl.string()).status, 0);
  ASSERT_EQ(run("anatomy export " + ex + " --no-cache --out " + obj.string()).status, 0);
  vcsim::MeshLoadOptions mm;
  mm.unit_scale = 1e-3;
  const vcsim::TriangleMesh a = vcsim::load_mesh(stl.string(), mm);
  const vcsim::TriangleMesh b = vcsim::load_mesh(obj.string(), mm);
  EXPECT_EQ(a.num_triangles(), j["triangles"].get<int>());
  EXPECT_EQ(b.num_triangles(), j["triangles"].get<int>());
  ASSERT_EQ(run("anatomy export --out " + js.string()).status, 0);
  EXPECT_NE(vcsim::test::slurp(js).find("\"vcsim-anatomy\""), std::string::npos);
  for (const auto& p : {stl, obj, js}) std::filesystem::remove(p);
}

TEST(AnatomyCli, BadInputIsOneLineAndExitTwo) {
  const auto bad = temp(".json");
  {
    std::ofstream f(bad);
    f << "{\"format\": \"vcsim-anatomy\", \"version\": 1, \"segments\": [{\"name\": \"a\"}]}";
  }
  for (const std::string& args :
       {"anatomy info " + bad.string(), std::string("anatomy info /nonexistent/x.json"),
        std::string("anatomy info --patient nobody"), std::string("anatomy export --out x.vtk")}) {
    const Result r = run(args);
    EXPECT_EQ(r.status, 2) << args;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_EQ(r.err.rfind("vcsim: error: ", 0), 0u) << r.err;
  }
  EXPECT_NE(run("anatomy info " + bad.string()).err.find("segments[0].points_mm"),
            std::string::npos);
  std::filesystem::remove(bad);
}

TEST(AnatomyCli, RepairMakesAMeshWithAFinLoadableAndRefusesBadInput) {
  // A closed tetrahedron (mm) with a fin on its edge 0-1: refused on load, naming the repair.
  const auto in = temp("_fin.obj"), out = temp("_fixed.ply"), bad = temp("_bad.stl");
  {
    std::ofstream f(in);
    f << "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nv 5 -5 -5\n"
         "f 1 3 2\nf 1 2 4\nf 2 3 4\nf 1 4 3\nf 1 2 5\n";
  }
  try {
    vcsim::load_mesh(in.string());
    ADD_FAILURE() << "a mesh with a fin loaded";
  } catch (const vcsim::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("vcsim anatomy repair"), std::string::npos) << e.what();
  }
  const Result r = run("anatomy repair " + in.string() + " " + out.string());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("1 non-manifold edge(s); 1 triangle(s) dropped"), std::string::npos)
      << r.out;
  vcsim::MeshReport report;
  const vcsim::TriangleMesh m = vcsim::load_mesh(out.string(), {}, &report);
  EXPECT_EQ(m.num_triangles(), 4);
  EXPECT_EQ(report.boundary_edges, 0);
  // Bad input: one line naming the file, exit 2.
  {
    std::ofstream f(bad);
    f << "solid x\n  facet normal 0 0 1\n    outer loop\n      vertex 0 0\n";
  }
  for (const std::string& args : {"anatomy repair " + bad.string() + " " + out.string(),
                                  "anatomy repair /nonexistent/x.stl " + out.string(),
                                  "anatomy repair " + in.string() + " " + temp(".vtk").string()}) {
    const Result b = run(args);
    EXPECT_EQ(b.status, 2) << args;
    EXPECT_EQ(std::count(b.err.begin(), b.err.end(), '\n'), 1) << b.err;
    EXPECT_EQ(b.err.rfind("vcsim: error: ", 0), 0u) << b.err;
  }
  EXPECT_NE(run("anatomy repair " + bad.string() + " " + out.string()).err.find(bad.string()),
            std::string::npos);
  for (const auto& p : {in, out, bad}) std::filesystem::remove(p);
}

TEST(AnatomyCli, BenchJsonHasItsKeys) {
  const Result r = run("bench anatomy --json --steps 200");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_GT(j["step_us_median"].get<double>(), 0.0);
  EXPECT_GT(j["triangles"].get<int>(), 10000);
  EXPECT_GT(j["triangles_updated_median"].get<double>(), 0.0);
}

}  // namespace
