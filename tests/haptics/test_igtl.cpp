// The OpenIGTLink server against a client built from the same library, on 127.0.0.1 only, port
// chosen by the kernel (port 0), every wait bounded.
#include <gtest/gtest.h>

#include "igtl_client.h"

#include <igtlClientSocket.h>
#include <igtlMessageHeader.h>
#include <igtlPositionMessage.h>
#include <igtlSensorMessage.h>
#include <igtlTransformMessage.h>
#include <igtl_header.h>
#include <igtl_util.h>

#include <chrono>
#include <cmath>
#include <csignal>
#include <cstring>
#include <functional>
#include <limits>
#include <mutex>
#include <numbers>
#include <thread>

#include "vcsim/core.h"
#include "vcsim/haptics.h"

namespace {

using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;
using vcsim::IgtlServer;
using vcsim::IgtlServerOptions;
using vcsim::StepCommands;
using Mode = vcsim::DriveCommand::Mode;
// The default options' instruments, in their order: poll() gives commands by this index, in SI.
enum { kGuidewire, kCatheter };
double mm(double v) {
  return v * 1e-3;
}
double deg(double v) {
  return v * (std::numbers::pi / 180.0);
}

// The library's client sends without MSG_NOSIGNAL: writing to a socket the server dropped must
// fail, not kill the test.
const bool kIgnoreSigpipe = (std::signal(SIGPIPE, SIG_IGN), true);

bool wait_until(const std::function<bool()>& pred, std::chrono::milliseconds limit = 3000ms) {
  const auto end = Clock::now() + limit;
  while (Clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(2ms);
  }
  return pred();
}

// Log lines arrive on the server thread.
struct LogCapture {
  std::mutex mu;
  std::vector<std::string> lines;
  std::size_t size() {
    std::lock_guard lock(mu);
    return lines.size();
  }
};

IgtlServerOptions quiet_options(LogCapture* log = nullptr) {
  IgtlServerOptions o;
  o.port = 0;
  o.log = [log](const std::string& line) {
    if (!log) return;
    std::lock_guard lock(log->mu);
    log->lines.push_back(line);
  };
  return o;
}

using Client = vcsim::test::IgtlClient;

StepCommands poll(IgtlServer& s) {
  StepCommands c;
  s.poll(0.0, c);
  return c;
}

TEST(Igtl, ClientDrivesInstrumentsAndReceivesForces) {
  IgtlServer server(quiet_options());
  ASSERT_GT(server.port(), 0);
  Client c;
  ASSERT_TRUE(c.connect(server.port()));

  ASSERT_TRUE(c.send_sensor("guidewire", {12.5, 30.0}));
  ASSERT_TRUE(c.send_sensor("vel_catheter", {5.0, -10.0}));
  ASSERT_TRUE(c.send_sensor("balloon", {8.0}));
  ASSERT_TRUE(c.send_sensor("syringe", {2.0}));
  ASSERT_TRUE(c.send_sensor("buttons", {5.0}));
  ASSERT_TRUE(wait_until([&] { return server.stats().messages_accepted >= 5; }));
  const StepCommands cmd = poll(server);
  ASSERT_EQ(cmd.drive.size(), 2u);
  const auto& gw = cmd.drive[kGuidewire];
  const auto& cath = cmd.drive[kCatheter];
  EXPECT_EQ(gw.mode, Mode::kPosition);
  EXPECT_DOUBLE_EQ(gw.translation, mm(12.5));
  EXPECT_DOUBLE_EQ(gw.rotation, deg(30.0));
  EXPECT_EQ(cath.mode, Mode::kVelocity);
  EXPECT_DOUBLE_EQ(cath.translation, mm(5.0));
  EXPECT_DOUBLE_EQ(cath.rotation, deg(-10.0));
  EXPECT_DOUBLE_EQ(cmd.balloon_pressure, 8.0 * 101325.0);  // Pa
  EXPECT_DOUBLE_EQ(cmd.syringe_flow, 2.0e-6);              // m^3/s
  EXPECT_EQ(cmd.buttons, 5u);

  // Force feedback: the published value arrives, at 100 Hz or more.
  const std::vector<vcsim::HandFeedback> fb = {{0.25, 0.002}, {-1.5, 0.0}};
  server.publish(fb);
  std::vector<double> v;
  ASSERT_TRUE(wait_until(
      [&] { return c.read_sensor("force_guidewire", v, 200ms) && v.size() == 2 && v[0] == 0.25; }));
  EXPECT_DOUBLE_EQ(v[1], 0.002);
  ASSERT_TRUE(c.read_sensor("force_catheter", v));
  EXPECT_DOUBLE_EQ(v[0], -1.5);

  int received = 0;
  const auto start = Clock::now();
  while (Clock::now() - start < 500ms) {
    if (c.read_sensor("force_guidewire", v, 100ms)) ++received;
  }
  RecordProperty("force_messages_in_500ms", received);
  EXPECT_GE(received, 50) << "expected 100 force messages per second or more";
  c.close();
}

TEST(Igtl, TransformIsDepthAlongZAndAngleAboutZWithTurnsCounted) {
  IgtlServer server(quiet_options());
  Client c;
  ASSERT_TRUE(c.connect(server.port()));
  ASSERT_TRUE(c.send_transform("guidewire", 40.0, 30.0));
  ASSERT_TRUE(wait_until([&] { return server.stats().messages_accepted >= 1; }));
  auto gw = poll(server).drive[kGuidewire];
  EXPECT_NEAR(gw.translation, mm(40.0), mm(1e-4));
  EXPECT_NEAR(gw.rotation, deg(30.0), deg(1e-4));
  // Turning on past 180 degrees keeps counting instead of jumping back by a turn.
  std::uint64_t n = server.stats().messages_accepted;
  for (double a : {120.0, 210.0, 300.0, 390.0, 480.0}) {
    ASSERT_TRUE(c.send_transform("guidewire", 41.0, a));
    ASSERT_TRUE(wait_until([&] { return server.stats().messages_accepted > n; }));
    n = server.stats().messages_accepted;
    gw = poll(server).drive[kGuidewire];
    EXPECT_NEAR(gw.rotation, deg(a), deg(1e-3));
  }
}

TEST(Igtl, MalformedAndOutOfRangeMessagesAreDroppedAndLogged) {
  LogCapture log;
  IgtlServer server(quiet_options(&log));
  Client c;
  ASSERT_TRUE(c.connect(server.port()));
  ASSERT_TRUE(c.send_sensor("guidewire", {10.0, 0.0}));
  ASSERT_TRUE(wait_until([&] { return server.stats().messages_accepted == 1; }));

  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  ASSERT_TRUE(c.send_sensor("guidewire", {nan, 0.0}));
  ASSERT_TRUE(c.send_sensor("guidewire", {inf, 0.0}));
  ASSERT_TRUE(c.send_sensor("guidewire", {1e9, 0.0}));      // beyond any instrument
  ASSERT_TRUE(c.send_sensor("vel_guidewire", {0.0, 1e7}));  // absurd spin
  ASSERT_TRUE(c.send_sensor("guidewire", {10.0}));          // one value, two expected
  ASSERT_TRUE(c.send_sensor("balloon", {1000.0}));
  ASSERT_TRUE(c.send_sensor("balloon", {-1.0}));
  ASSERT_TRUE(c.send_sensor("syringe", {500.0}));
  ASSERT_TRUE(c.send_sensor("buttons", {1.5}));
  ASSERT_TRUE(c.send_sensor("stent", {1.0, 2.0}));  // unknown name
  // A corrupted body: the CRC no longer matches.
  auto bad = Client::sensor("guidewire", {99.0, 0.0});
  static_cast<unsigned char*>(bad->GetPackBodyPointer())[12] ^= 0x40;
  ASSERT_TRUE(c.send_raw(bad->GetPackPointer(), bad->GetPackSize()));
  // A message type the server does not use.
  auto position = igtl::PositionMessage::New();
  position->SetDeviceName("guidewire");
  position->Pack();
  ASSERT_TRUE(c.send_raw(position->GetPackPointer(), position->GetPackSize()));
  const std::uint64_t kBad = 12;

  ASSERT_TRUE(wait_until([&] { return server.stats().messages_dropped >= kBad; }))
      << server.stats().messages_dropped;
  // Still connected (each message was framed correctly), and nothing moved.
  EXPECT_TRUE(server.stats().connected);
  EXPECT_EQ(server.stats().disconnections, 0u);
  const StepCommands cmd = poll(server);
  EXPECT_DOUBLE_EQ(cmd.drive[kGuidewire].translation, mm(10.0));
  EXPECT_EQ(cmd.drive[kGuidewire].mode, Mode::kPosition);
  EXPECT_DOUBLE_EQ(cmd.balloon_pressure, 0.0 * 101325.0);
  EXPECT_DOUBLE_EQ(cmd.syringe_flow, 0.0 * 1e-6);
  EXPECT_EQ(cmd.buttons, 0u);
  EXPECT_TRUE(wait_until([&] { return log.size() >= kBad; }));  // each drop says why

  // The connection still works.
  ASSERT_TRUE(c.send_sensor("guidewire", {11.0, 0.0}));
  ASSERT_TRUE(wait_until([&] { return poll(server).drive[kGuidewire].translation == mm(11.0); }));
}

TEST(Igtl, GarbageBytesDropTheConnectionNotTheServer) {
  IgtlServer server(quiet_options());
  for (int round = 0; round < 3; ++round) {
    Client c;
    ASSERT_TRUE(c.connect(server.port()));
    ASSERT_TRUE(wait_until([&] { return server.stats().connected; }));
    std::vector<unsigned char> junk;
    if (round == 0) {
      const std::string http = "GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
      junk.assign(http.begin(), http.end());
      junk.resize(200, 0xAB);
    } else if (round == 1) {
      // A plausible header announcing a 2^63-byte body.
      igtl_header h{};
      h.version = 1;
      std::memcpy(h.name, "SENSOR", 6);
      std::memcpy(h.device_name, "guidewire", 9);
      h.body_size = 1ull << 63;
      igtl_header_convert_byte_order(&h);
      junk.resize(sizeof h);
      std::memcpy(junk.data(), &h, sizeof h);
    } else {
      std::uint32_t x = 12345;  // fixed pseudo-random bytes (xorshift)
      for (int i = 0; i < 4096; ++i) {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        junk.push_back(static_cast<unsigned char>(x));
      }
    }
    c.send_raw(junk.data(), static_cast<int>(junk.size()));  // may fail once dropped
    ASSERT_TRUE(wait_until([&] {
      return server.stats().disconnections == std::uint64_t(round + 1);
    })) << "round "
        << round;
    c.close();
  }
  // A good client afterwards is served as usual.
  Client good;
  ASSERT_TRUE(good.connect(server.port()));
  ASSERT_TRUE(good.send_sensor("catheter", {7.0, 45.0}));
  ASSERT_TRUE(wait_until([&] { return poll(server).drive[kCatheter].translation == mm(7.0); }));
  std::vector<double> v;
  EXPECT_TRUE(good.read_sensor("force_catheter", v));
}

TEST(Igtl, DisconnectLeavesInstrumentsWhereTheyAreAndStopsMotion) {
  IgtlServer server(quiet_options());
  {
    Client c;
    ASSERT_TRUE(c.connect(server.port()));
    ASSERT_TRUE(c.send_sensor("guidewire", {20.0, 90.0}));
    ASSERT_TRUE(c.send_sensor("vel_catheter", {5.0, 10.0}));
    ASSERT_TRUE(c.send_sensor("balloon", {6.0}));
    ASSERT_TRUE(c.send_sensor("syringe", {3.0}));
    ASSERT_TRUE(wait_until([&] { return server.stats().messages_accepted == 4; }));
    c.close();
  }
  ASSERT_TRUE(wait_until([&] { return server.stats().disconnections == 1; }));
  EXPECT_FALSE(server.stats().connected);
  const StepCommands cmd = poll(server);
  EXPECT_DOUBLE_EQ(cmd.drive[kGuidewire].translation, mm(20.0));
  EXPECT_DOUBLE_EQ(cmd.drive[kGuidewire].rotation, deg(90.0));
  EXPECT_EQ(cmd.drive[kCatheter].mode, Mode::kVelocity);
  EXPECT_DOUBLE_EQ(cmd.drive[kCatheter].translation, mm(0.0));
  EXPECT_DOUBLE_EQ(cmd.drive[kCatheter].rotation, deg(0.0));
  EXPECT_DOUBLE_EQ(cmd.balloon_pressure, 6.0 * 101325.0);
  EXPECT_DOUBLE_EQ(cmd.syringe_flow, 0.0 * 1e-6);

  // A new client picks up from there; a second one is refused while it is connected.
  Client a, b;
  ASSERT_TRUE(a.connect(server.port()));
  ASSERT_TRUE(wait_until([&] { return server.stats().connections == 2; }));
  ASSERT_TRUE(b.connect(server.port()));  // the kernel accepts; the server closes it at once
  ASSERT_TRUE(wait_until([&] { return server.stats().clients_refused == 1; }));
  b.send_sensor("guidewire", {99.0, 0.0});  // may fail: the connection is closed
  ASSERT_TRUE(a.send_sensor("guidewire", {25.0, 90.0}));
  ASSERT_TRUE(wait_until([&] { return poll(server).drive[kGuidewire].translation == mm(25.0); }));
  EXPECT_EQ(server.stats().connections, 2u);
  EXPECT_EQ(server.stats().disconnections, 1u);
  EXPECT_TRUE(server.stats().connected);
}

// A header version 2 message (OpenIGTLink 3, what recent 3D Slicer sends): extended header,
// content, no metadata.
TEST(Igtl, AcceptsHeaderVersion2) {
  IgtlServer server(quiet_options());
  Client c;
  ASSERT_TRUE(c.connect(server.port()));
  auto v1 = Client::sensor("guidewire", {33.0, -45.0});
  const auto* content = static_cast<const unsigned char*>(v1->GetPackBodyPointer());
  std::vector<unsigned char> body = {0, 12, 0, 0, 0, 0, 0, 0, 0, 0, 0, 7};  // ext 12, msg id 7
  body.insert(body.end(), content, content + v1->GetPackBodySize());
  igtl_header h{};
  std::memcpy(&h, v1->GetPackPointer(), sizeof h);
  igtl_header_convert_byte_order(&h);  // to host order
  h.version = 2;
  h.body_size = body.size();
  h.crc = crc64(body.data(), body.size(), 0);
  igtl_header_convert_byte_order(&h);  // back to network order
  std::vector<unsigned char> msg(sizeof h);
  std::memcpy(msg.data(), &h, sizeof h);
  msg.insert(msg.end(), body.begin(), body.end());
  ASSERT_TRUE(c.send_raw(msg.data(), static_cast<int>(msg.size())));
  ASSERT_TRUE(wait_until([&] { return server.stats().messages_accepted == 1; }));
  EXPECT_DOUBLE_EQ(poll(server).drive[kGuidewire].translation, mm(33.0));
  EXPECT_DOUBLE_EQ(poll(server).drive[kGuidewire].rotation, deg(-45.0));
}

TEST(Igtl, OptionsAreCheckedAndShutdownIsPrompt) {
  auto expect_field = [](IgtlServerOptions o, const std::string& field) {
    try {
      IgtlServer s(std::move(o));
      ADD_FAILURE() << "no error for " << field;
    } catch (const vcsim::InputError& e) {
      EXPECT_EQ(e.source(), "igtl");
      EXPECT_EQ(e.field(), field) << e.what();
    }
  };
  auto o = quiet_options();
  o.address = "localhost";
  expect_field(o, "address");
  o = quiet_options();
  o.instruments = {"guidewire", "balloon"};
  expect_field(o, "instruments[1]");
  o = quiet_options();
  o.instruments = {"a-name-that-is-too-long"};
  expect_field(o, "instruments[0]");
  o = quiet_options();
  o.feedback_rate_hz = 0;
  expect_field(o, "feedback_rate_hz");

  IgtlServer first(quiet_options());
  o = quiet_options();
  o.port = first.port();  // taken
  expect_field(o, "port");

  Client c;
  ASSERT_TRUE(c.connect(first.port()));
  ASSERT_TRUE(wait_until([&] { return first.stats().connected; }));
  const auto t0 = Clock::now();
  first.stop();
  first.stop();  // idempotent
  EXPECT_LT(Clock::now() - t0, 500ms);
  EXPECT_FALSE(first.stats().connected);
  // Publishing and polling after stop are harmless.
  const std::vector<vcsim::HandFeedback> fb = {{1.0, 0.0}};
  first.publish(fb);
  EXPECT_EQ(poll(first).drive.size(), 2u);
}

}  // namespace

// A device's force message carries the mean of the steps since the previous message: a one-step
// spike among ten steps arrives as a tenth of itself, a message period without a step repeats the
// last mean, and each instrument keeps its own.
TEST(FeedbackDecimator, MessagesCarryThePeriodsMean) {
  vcsim::FeedbackDecimator d;
  d.resize(2);
  double f = -1.0, t = -1.0;
  d.take(0, f, t);
  EXPECT_EQ(f, 0.0) << "nothing published yet: zero, not garbage";
  for (int k = 0; k < 10; ++k) d.add(0, k == 4 ? 11.0 : 1.0, k == 4 ? 0.011 : 0.001);
  d.add(1, -3.0, 0.5);
  d.take(0, f, t);
  EXPECT_DOUBLE_EQ(f, 2.0);
  EXPECT_DOUBLE_EQ(t, 0.002);
  d.take(0, f, t);
  EXPECT_DOUBLE_EQ(f, 2.0) << "an empty period repeats the last mean";
  d.add(0, 4.0, 0.0);
  d.take(0, f, t);
  EXPECT_DOUBLE_EQ(f, 4.0) << "a new period starts afresh";
  d.take(1, f, t);
  EXPECT_DOUBLE_EQ(f, -3.0);
  EXPECT_DOUBLE_EQ(t, 0.5);
}
