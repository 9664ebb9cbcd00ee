// The command recording: run-length encoding, truncation (a rewind), and a file that reads back
// to the same bits; the replay source's checks against the scene.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <limits>
#include <random>

#include "vcsim/core.h"
#include "vcsim/haptics.h"

namespace vcsim {
namespace {

CommandRecording make(std::size_t n) {
  CommandRecording r;
  r.scenario = "test";
  r.dt = 5e-4;
  for (std::size_t i = 0; i < n; ++i) {
    std::string name = "i";  // += : GCC 12 warns falsely on "literal" + std::to_string
    name += std::to_string(i);
    r.instruments.push_back(name);
  }
  r.model_hash = 0x0123456789abcdefULL;
  return r;
}

bool same_bits(double a, double b) {
  return std::bit_cast<std::uint64_t>(a) == std::bit_cast<std::uint64_t>(b);
}

void expect_same(const StepCommands& a, const StepCommands& b) {
  ASSERT_EQ(a.drive.size(), b.drive.size());
  for (std::size_t i = 0; i < a.drive.size(); ++i) {
    EXPECT_EQ(a.drive[i].mode, b.drive[i].mode);
    EXPECT_TRUE(same_bits(a.drive[i].translation, b.drive[i].translation));
    EXPECT_TRUE(same_bits(a.drive[i].rotation, b.drive[i].rotation));
  }
  EXPECT_TRUE(same_bits(a.syringe_flow, b.syringe_flow));
  EXPECT_TRUE(same_bits(a.balloon_pressure, b.balloon_pressure));
  EXPECT_EQ(a.buttons, b.buttons);
}

TEST(Recording, EqualStepsShareARunAndEveryStepReadsBack) {
  CommandRecording r = make(2);
  StepCommands c;
  c.reset(2);
  std::vector<StepCommands> steps;
  for (int k = 0; k < 100; ++k) {
    if (k == 10) c.drive[0].translation = 0.01;
    if (k == 40) c.syringe_flow = 3e-6;
    if (k == 41) c.buttons = 1;
    if (k == 60) c.drive[1] = {DriveCommand::Mode::kPosition, 0.123, -0.0};
    r.append(c);
    steps.push_back(c);
  }
  EXPECT_EQ(r.steps(), 100);
  EXPECT_EQ(r.num_runs(), 5u);
  StepCommands got;
  for (int k = 0; k < 100; ++k) {
    r.at(k, got);
    expect_same(got, steps[k]);
  }
}

TEST(Recording, TruncateKeepsTheFirstStepsAndAppendsAfterThem) {
  CommandRecording r = make(1);
  StepCommands c;
  c.reset(1);
  for (int k = 0; k < 30; ++k) {
    c.drive[0].translation = k < 10 ? 0.0 : k < 20 ? 0.01 : 0.02;
    r.append(c);
  }
  r.truncate(15);
  EXPECT_EQ(r.steps(), 15);
  EXPECT_EQ(r.num_runs(), 2u);
  EXPECT_EQ(r.run(1).steps, 5);
  c.drive[0].translation = 0.01;  // the same as the last run: it grows
  r.append(c);
  EXPECT_EQ(r.num_runs(), 2u);
  EXPECT_EQ(r.run(1).steps, 6);
  r.truncate(10);
  EXPECT_EQ(r.num_runs(), 1u);
  r.truncate(0);
  EXPECT_EQ(r.num_runs(), 0u);
  EXPECT_EQ(r.steps(), 0);
}

TEST(Recording, TheFileReadsBackToTheSameBits) {
  CommandRecording r = make(3);
  r.state_hash = 0xfedcba9876543210ULL;
  std::mt19937_64 gen(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  StepCommands c;
  c.reset(3);
  for (int k = 0; k < 500; ++k) {
    for (auto& d : c.drive) {
      d.mode = gen() % 2 ? DriveCommand::Mode::kVelocity : DriveCommand::Mode::kPosition;
      d.translation = u(gen) * std::pow(10.0, static_cast<double>(gen() % 40) - 20.0);
      d.rotation = gen() % 5 == 0 ? -0.0 : u(gen) * 1e3;
    }
    c.syringe_flow = u(gen) * 1e-6;
    c.balloon_pressure = gen() % 3 == 0 ? 0.0 : 101325.0 * 8.0 / 3.0;
    c.buttons = static_cast<std::uint32_t>(gen());
    const int repeat = 1 + static_cast<int>(gen() % 3);
    for (int j = 0; j < repeat; ++j) r.append(c);
  }
  const CommandRecording back = CommandRecording::parse(r.to_json(), "rec.json");
  ASSERT_EQ(back.steps(), r.steps());
  EXPECT_EQ(back.num_runs(), r.num_runs());
  EXPECT_EQ(back.model_hash, r.model_hash);
  EXPECT_EQ(back.state_hash, r.state_hash);
  EXPECT_EQ(back.instruments, r.instruments);
  EXPECT_TRUE(same_bits(back.dt, r.dt));
  StepCommands a, b;
  for (std::int64_t k = 0; k < r.steps(); ++k) {
    r.at(k, a);
    back.at(k, b);
    expect_same(a, b);
  }
}

TEST(Recording, AMalformedFileIsAnErrorNamingTheField) {
  CommandRecording r = make(1);
  StepCommands c;
  c.reset(1);
  r.append(c);
  std::string text = r.to_json();
  const auto at = text.find("\"v\"");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 3, "\"x\"");
  try {
    CommandRecording::parse(text, "rec.json");
    FAIL() << "accepted a bad mode";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "runs[0][4]");
  }
  std::string steps = r.to_json();
  steps.replace(steps.find("\"steps\": 1"), 10, "\"steps\": 2");
  EXPECT_THROW(CommandRecording::parse(steps, "rec.json"), InputError);
}

TEST(Recording, TheReplayChecksTheSceneAndGivesEachStepsCommands) {
  CommandRecording r = make(2);
  StepCommands c;
  c.reset(2);
  for (int k = 0; k < 4; ++k) {
    c.drive[0].translation = 0.001 * k;
    r.append(c);
  }
  const std::vector<std::string> names = {"i0", "i1"}, other = {"i1", "i0"};
  EXPECT_THROW({ RecordingReplay bad(r, other, 5e-4, 0, "rec"); }, InputError);
  EXPECT_THROW({ RecordingReplay bad(r, names, 1e-3, 0, "rec"); }, InputError);
  EXPECT_THROW({ RecordingReplay bad(r, names, 5e-4, 42, "rec"); }, InputError);
  RecordingReplay replay(r, names, 5e-4, r.model_hash, "rec");
  StepCommands out;
  double t = 0.0;
  for (int k = 0; k < 4; ++k, t += 5e-4) {
    replay.poll(t, out);
    EXPECT_TRUE(same_bits(out.drive[0].translation, 0.001 * k));
  }
  replay.poll(t, out);  // after the end: every hand still
  EXPECT_EQ(out.drive[0].translation, 0.0);
  EXPECT_EQ(out.drive[0].mode, DriveCommand::Mode::kVelocity);
}

}  // namespace
}  // namespace vcsim
