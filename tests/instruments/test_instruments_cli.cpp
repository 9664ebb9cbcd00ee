// `vcsim instruments list|show`: JSON with the documented keys; a bad name or folder is one line
// naming the field, exit status 2.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "cli_runner.h"

namespace {

using Result = vcsim::test::CliResult;

// `vcsim instruments ARGS --dir <the test catalogue>`.
Result run(const std::string& args) {
  return vcsim::test::run_cli("instruments " + args + " --dir " + VCSIM_INSTRUMENTS_DATA);
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
