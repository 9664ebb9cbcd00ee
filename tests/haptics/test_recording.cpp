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
      // Magnitudes from 1e-20 to 1e17: every vcsim file keeps numbers within +-1e18.
      d.translation = u(gen) * std::pow(10.0, static_cast<double>(gen() % 38) - 20.0);
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

InstrumentChange add_b() {
  InstrumentChange a;
  a.kind = InstrumentChange::Kind::kAdd;
  a.name = "b";
  a.catalogue = "balloon-sc-3.0x15";
  a.over = "i0";
  a.max_nodes = 200;
  a.tip_segment = 1.5e-3;
  return a;
}

// A recording with instrument exchanges: rows after an exchange have the scene's instruments then
// and a run never spans one; the file (version 2) reads back to the same bits and exchanges; a
// truncation keeps the exchanges before the steps it keeps; the replay asks for each exchange
// before the step it was made before.
TEST(Recording, ExchangesChangeTheRowsAndReadBack) {
  CommandRecording r = make(1);
  StepCommands c;
  c.reset(1);
  for (int k = 0; k < 3; ++k) r.append(c);
  r.append_exchange(add_b());
  c.reset(2);
  for (int k = 0; k < 2; ++k) r.append(c);  // the same values, a new run
  InstrumentChange rm;
  rm.kind = InstrumentChange::Kind::kRemove;
  rm.name = "i0";
  r.append_exchange(rm);
  c.reset(1);
  c.drive[0].translation = 0.25;
  for (int k = 0; k < 2; ++k) r.append(c);
  EXPECT_EQ(r.steps(), 7);
  EXPECT_EQ(r.num_runs(), 3u);
  EXPECT_EQ(r.scene_size(), 1u);
  StepCommands got;
  r.at(2, got);
  EXPECT_EQ(got.drive.size(), 1u);
  r.at(3, got);
  EXPECT_EQ(got.drive.size(), 2u);
  r.at(6, got);
  ASSERT_EQ(got.drive.size(), 1u);
  EXPECT_EQ(got.drive[0].translation, 0.25);

  const std::string text = r.to_json();
  EXPECT_NE(text.find("\"version\": 2"), std::string::npos);
  const CommandRecording back = CommandRecording::parse(text, "rec.json");
  ASSERT_EQ(back.exchanges().size(), 2u);
  EXPECT_EQ(back.exchanges()[0].step, 3);
  EXPECT_EQ(describe(back.exchanges()[0].change), "add b balloon-sc-3.0x15 over=i0");
  EXPECT_EQ(back.exchanges()[0].change.max_nodes, 200);
  EXPECT_TRUE(same_bits(back.exchanges()[0].change.tip_segment, 1.5e-3));
  EXPECT_EQ(back.exchanges()[0].change.field, "exchanges[0]");
  EXPECT_EQ(back.exchanges()[1].change.kind, InstrumentChange::Kind::kRemove);
  for (std::int64_t k = 0; k < 7; ++k) {
    StepCommands a, b;
    r.at(k, a);
    back.at(k, b);
    expect_same(a, b);
  }

  RecordingReplay replay(back, std::vector<std::string>{"i0"}, 5e-4, 0, "rec.json");
  InstrumentChange asked;
  EXPECT_FALSE(replay.poll_exchange(2 * 5e-4, asked));
  ASSERT_TRUE(replay.poll_exchange(3 * 5e-4, asked));
  EXPECT_EQ(asked.name, "b");
  EXPECT_FALSE(replay.poll_exchange(3 * 5e-4, asked)) << "once";
  ASSERT_TRUE(replay.poll_exchange(5 * 5e-4, asked));
  EXPECT_EQ(asked.name, "i0");
  replay.exchanged(asked, std::vector<std::string>{"b"});
  replay.poll(100.0, got);  // after the end: one still hand per instrument of the scene now
  EXPECT_EQ(got.drive.size(), 1u);

  CommandRecording cut = back;
  cut.truncate(4);
  EXPECT_EQ(cut.exchanges().size(), 1u);
  EXPECT_EQ(cut.scene_size(), 2u);
  cut.truncate(3);
  EXPECT_TRUE(cut.exchanges().empty()) << "made before step 3: after the state of 3 steps";
  EXPECT_NE(cut.to_json().find("\"version\": 1"), std::string::npos);
}

TEST(Recording, AMalformedExchangeIsAnErrorNamingTheField) {
  CommandRecording r = make(1);
  StepCommands c;
  c.reset(1);
  r.append(c);
  r.append(c);  // one run of two steps
  r.append_exchange(add_b());
  c.reset(2);
  r.append(c);
  const std::string good = r.to_json();
  EXPECT_EQ(CommandRecording::parse(good, "rec.json").steps(), 3);
  auto field_of = [](std::string text) {
    try {
      CommandRecording::parse(text, "rec.json");
    } catch (const InputError& e) {
      return e.field();
    }
    return std::string("(accepted)");
  };
  std::string bad = good;
  bad.replace(bad.find("add b"), 5, "put b");
  EXPECT_EQ(field_of(bad), "exchanges[0].change");
  bad = good;
  bad.replace(bad.find("\"version\": 2"), 12, "\"version\": 1");
  EXPECT_EQ(field_of(bad), "exchanges");
  bad = good;  // the run of two steps over an exchange at step 1
  bad.replace(bad.find("\"step\": 2,"), 10, "\"step\": 1,");
  EXPECT_EQ(field_of(bad), "runs[0]");
  bad = good;
  bad.replace(bad.find("\"max_nodes\": 200"), 16, "\"max_nodes\": 900");
  EXPECT_EQ(field_of(bad), "exchanges[0].max_nodes");
}

}  // namespace
}  // namespace vcsim
