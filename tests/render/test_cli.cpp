// `vcsim render` and `vcsim bench render` from the outside: bad values give one line and status 2.
#include <gtest/gtest.h>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "cli_runner.h"

namespace vcsim::test {
namespace {

void expect_input_error(const std::string& args, const std::string& field) {
  const CliResult r = run_cli(args);
  EXPECT_EQ(r.status, 2) << args << "\n" << r.err;
  EXPECT_NE(r.err.find(field), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
}

TEST(RenderCli, BadValuesAreRejected) {
  const std::string out = (std::filesystem::temp_directory_path() / "vcsim_bad.png").string();
  expect_input_error("render --out " + out + " --size 600", "--size");
  expect_input_error("render --out " + out + " --primary 150", "--primary");
  expect_input_error("render --out " + out + " --secondary -70", "--secondary");
  expect_input_error("render --out " + out + " --dose -5", "--dose");
  expect_input_error("render --out " + out + " --contrast 2", "--contrast");
  expect_input_error("render --out /nonexistent-dir/x.png", "--out");
  expect_input_error("bench render --size 100", "--size");
}

TEST(RenderCli, WritesAPng) {
  const auto out = std::filesystem::temp_directory_path() / "vcsim_render_cli.png";
  std::filesystem::remove(out);
  const CliResult r = run_cli("render --out " + out.string() + " --primary -30 --secondary -30");
  ASSERT_EQ(r.status, 0) << r.err;
  ASSERT_TRUE(std::filesystem::exists(out));
  const std::string head = slurp(out).substr(0, 8);
  EXPECT_EQ(head, std::string("\x89PNG\r\n\x1a\n", 8));
  std::filesystem::remove(out);
}

TEST(RenderCli, BenchPrintsFrameTime) {
  const CliResult r = run_cli("bench render --size 512 --frames 3 --json");
  ASSERT_EQ(r.status, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_GT(j.at("frame_ms_median").get<double>(), 0.0);
}

}  // namespace
}  // namespace vcsim::test
