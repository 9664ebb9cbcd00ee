// `vcsim instruments list|show`: JSON with the documented keys; a bad name or folder is one line
// naming the field, exit status 2.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>
#include <set>
#include <string>

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
  EXPECT_EQ(j["core_taper_mm"].get<double>(), 0.0);  // a step from its soft tip to the shaft
  r = run("show wire-014-floppy --json");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NEAR(nlohmann::json::parse(r.out)["core_taper_mm"].get<double>(), 150.0, 1e-9);
}

TEST(InstrumentsCli, ListShowsTheBalloonAndStentKinds) {
  Result r = run("list --json");
  ASSERT_EQ(r.status, 0) << r.err;
  std::set<std::string> kinds;
  for (const auto& e : nlohmann::json::parse(r.out)) {
    const std::string kind = e["kind"].get<std::string>();
    kinds.insert(kind);
    // The sections follow the kind: a balloon on balloons and stents, a stent on stents only.
    EXPECT_EQ(e.contains("balloon"), kind == "balloon" || kind == "stent") << e["name"];
    EXPECT_EQ(e.contains("stent"), kind == "stent") << e["name"];
  }
  EXPECT_EQ(kinds, (std::set<std::string>{"guidewire", "catheter", "balloon", "stent"}));
  r = run("list");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("| balloon-nc-3.0x15 | balloon |"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("| stent-cocr-3.0x18 | stent |"), std::string::npos) << r.out;
}

TEST(InstrumentsCli, ShowPrintsTheBalloonChartAndTheStent) {
  Result r = run("show stent-cocr-3.0x18");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("- kind: \"stent\""), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("## Balloon"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("- compliance: \"semi-compliant\""), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("| pressure (atm) | diameter (mm) | working length (mm) |"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("| 0 | 0.83 (folded) | 19 |"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("| 10 | 3 | 19 |"), std::string::npos) << r.out;       // nominal
  EXPECT_NE(r.out.find("| 16 | 3.34 | 20.1 |"), std::string::npos) << r.out;  // rated burst
  EXPECT_NE(r.out.find("## Stent"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("- strut_thickness_um: 81"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("- material: \"cobalt-chromium L-605\""), std::string::npos) << r.out;

  r = run("show balloon-nc-3.0x15 --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["kind"], "balloon");
  EXPECT_FALSE(j.contains("stent"));
  const auto& b = j["balloon"];
  EXPECT_EQ(b["compliance"], "non-compliant");
  EXPECT_NEAR(b["nominal_pressure_atm"].get<double>(), 14.0, 1e-12);
  EXPECT_NEAR(b["rated_burst_pressure_atm"].get<double>(), 24.0, 1e-12);
  ASSERT_EQ(b["chart"].size(), 10u);
  EXPECT_NEAR(b["chart"][4][0].get<double>(), 14.0, 1e-12);
  EXPECT_NEAR(b["chart"][4][1].get<double>(), 3.0, 1e-12);
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
