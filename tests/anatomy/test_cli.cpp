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

TEST(AnatomyCli, BenchJsonHasItsKeys) {
  const Result r = run("bench anatomy --json --steps 200");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_GT(j["step_us_median"].get<double>(), 0.0);
  EXPECT_GT(j["triangles"].get<int>(), 10000);
  EXPECT_GT(j["triangles_updated_median"].get<double>(), 0.0);
}

}  // namespace
