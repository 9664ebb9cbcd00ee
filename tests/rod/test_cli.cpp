// The command line: JSON output with the documented keys, and bad input as one line naming the
// field with exit status 2.
#include <gtest/gtest.h>

#include <algorithm>
#include <nlohmann/json.hpp>

#include "cli_runner.h"

namespace {

using Result = vcsim::test::CliResult;
Result run(const std::string& args) {
  return vcsim::test::run_cli(args);
}

void expect_bad_input(const std::string& args, const std::string& names) {
  const Result r = run(args);
  EXPECT_EQ(r.status, 2) << args << "\n" << r.err;
  EXPECT_NE(r.err.find(names), std::string::npos) << args << " -> " << r.err;
  // One line.
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_TRUE(r.out.empty()) << r.out;
}

}  // namespace

TEST(Cli, ValidateJsonHasTheDocumentedKeys) {
  const Result r = run("validate torsion --segments 20 --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_TRUE(j.is_array());
  ASSERT_EQ(j.size(), 2u);
  for (const auto& row : j) {
    for (const char* key :
         {"case", "quantity", "analytic", "simulated", "rel_error", "tolerance", "pass"}) {
      EXPECT_TRUE(row.contains(key)) << key;
    }
    EXPECT_EQ(row["case"], "torsion");
    EXPECT_TRUE(row["pass"].get<bool>());
  }
}

TEST(Cli, ValidateTakesCaseParameters) {
  const Result r = run("validate elastica-tip --load 0.75 --segments 16 --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  // lambda = 0.75 is not tabulated: the reference is computed for it.
  EXPECT_NE(j[0]["quantity"].get<std::string>().find("lambda=0.75"), std::string::npos);
  EXPECT_GT(j[0]["analytic"].get<double>(), 0.16214);
  EXPECT_LT(j[0]["analytic"].get<double>(), 0.30172);
}

TEST(Cli, BenchRodWritesJson) {
  const Result r = run("bench rod --nodes 64 --steps 200 --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["nodes"], 64);
  EXPECT_GT(j["step_us_median"].get<double>(), 0.0);
  for (const char* k : {"forces", "integrate_velocities", "constraints", "integrate_positions"}) {
    EXPECT_TRUE(j["stages_us"].contains(k)) << k;
  }
}

TEST(Cli, BadInputIsOneLineAndExitStatusTwo) {
  expect_bad_input("validate no-such-case", "case");
  expect_bad_input("validate elastica-tip --load nan", "--load");
  expect_bad_input("validate elastica-tip --load -1", "--load");
  expect_bad_input("validate torsion --length-mm 0", "--length-mm");
  expect_bad_input("validate torsion --radius-mm -0.5", "--radius-mm");
  expect_bad_input("validate shaped-tip --tip-ratio 0", "--tip-ratio");
  expect_bad_input("validate shaped-tip --tip-ratio 1.2", "--tip-ratio");
  expect_bad_input("validate torsion --method newton", "method");
  expect_bad_input("validate torsion --segments abc", "--segments");
  expect_bad_input("bench rod --nodes 2", "--nodes");
  expect_bad_input("frobnicate", "frobnicate");
}
