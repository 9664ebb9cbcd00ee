// `vcsim instruments list|show`: JSON with the documented keys; a bad name or folder is one line
// naming the field, exit status 2.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

namespace {

struct Result {
  int status = -1;
  std::string out, err;
};

std::string slurp(const std::filesystem::path& p) {
  std::ifstream f(p);
  std::stringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

Result run(const std::string& args) {
  const auto dir = std::filesystem::temp_directory_path();
  std::string tag = std::to_string(::getpid());
  tag += ::testing::UnitTest::GetInstance()->current_test_info()->name();
  const auto out = dir / (tag + "_vcsim_instr.out");
  const auto err = dir / (tag + "_vcsim_instr.err");
  std::string cmd = VCSIM_CLI;
  for (const std::string& part : {std::string(" instruments "), args, std::string(" --dir "),
                                  std::string(VCSIM_INSTRUMENTS_DATA), std::string(" >"),
                                  out.string(), std::string(" 2>"), err.string()}) {
    cmd += part;
  }
  const int raw = std::system(cmd.c_str());
  Result r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  r.out = slurp(out);
  r.err = slurp(err);
  std::filesystem::remove(out);
  std::filesystem::remove(err);
  return r;
}

TEST(InstrumentsCli, ListJson) {
  const Result r = run("list --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_TRUE(j.is_array());
  EXPECT_GE(j.size(), 9u);
  for (const auto& e : j) {
    for (const char* k : {"name", "kind", "length_mm", "od_mm", "id_mm", "youngs_modulus_gpa",
                          "tip_sections", "friction", "radiopacity", "discretisation"}) {
      EXPECT_TRUE(e.contains(k)) << k;
    }
    EXPECT_LE(e["discretisation"]["nodes"].get<int>(), 512);
  }
}

TEST(InstrumentsCli, ShowMarkdownAndJson) {
  Result r = run("show catheter-jl4-6f");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("# catheter-jl4-6f"), std::string::npos);
  r = run("show wire-035-j3-hydrophilic --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_NEAR(j["od_mm"].get<double>(), 0.889, 1e-3);
  EXPECT_EQ(j["tip_sections"][0]["arc"]["radius_mm"].get<double>(), 3.0);
}

TEST(InstrumentsCli, UnknownNameIsOneLine) {
  const Result r = run("show no-such-wire");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("instrument: name: expected one of"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_TRUE(r.out.empty());
}

TEST(InstrumentsCli, BadMaxNodes) {
  const Result r = run("list --max-nodes 2");
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("max_nodes"), std::string::npos) << r.err;
}

}  // namespace
