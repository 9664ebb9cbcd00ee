// IgtlStream and the content decoders, without a socket: messages packed by the OpenIGTLink
// library, fed whole and in pieces.
#include <gtest/gtest.h>

#include <igtlSensorMessage.h>
#include <igtlStringMessage.h>
#include <igtlTransformMessage.h>
#include <igtl_header.h>

#include <cmath>
#include <cstring>
#include <vector>

#include "igtl_stream.h"

namespace {

using vcsim::internal::IgtlFrame;
using vcsim::internal::IgtlStream;
using Bytes = std::vector<unsigned char>;
using Kind = IgtlFrame::Kind;

Bytes packed(igtl::MessageBase* msg) {
  msg->Pack();
  const auto* p = static_cast<const unsigned char*>(msg->GetPackPointer());
  return Bytes(p, p + msg->GetPackSize());
}

Bytes transform(const char* device, float depth_mm, float angle_deg) {
  auto msg = igtl::TransformMessage::New();
  msg->SetDeviceName(device);
  igtl::Matrix4x4 m;
  igtl::IdentityMatrix(m);
  const float a = angle_deg * static_cast<float>(M_PI / 180.0);
  m[0][0] = std::cos(a), m[0][1] = -std::sin(a), m[1][0] = std::sin(a), m[1][1] = std::cos(a);
  m[2][3] = depth_mm;
  msg->SetMatrix(m);
  return packed(msg);
}

Bytes sensor(const char* device, std::vector<double> values) {
  auto msg = igtl::SensorMessage::New();
  msg->SetDeviceName(device);
  msg->SetLength(static_cast<unsigned>(values.size()));
  for (unsigned i = 0; i < values.size(); ++i) msg->SetValue(i, values[i]);
  return packed(msg);
}

Bytes string(const char* device, const char* text) {
  auto msg = igtl::StringMessage::New();
  msg->SetDeviceName(device);
  msg->SetString(text);
  return packed(msg);
}

// A header declaring `body` bytes of type IMAGE, and that many bytes (not a valid IMAGE; it is
// never read).
Bytes oversized(std::size_t body) {
  Bytes b(58 + body, 0);
  b[1] = 1;  // version 1, big-endian
  std::memcpy(&b[2], "IMAGE", 5);
  std::memcpy(&b[14], "volume", 6);
  for (int i = 0; i < 8; ++i) b[42 + i] = static_cast<unsigned char>(body >> (8 * (7 - i)));
  return b;
}

Bytes operator+(Bytes a, const Bytes& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

struct Seen {
  Kind kind;
  std::string type, device, error;
  Bytes content;
};

std::vector<Seen> feed(IgtlStream& s, const Bytes& bytes, std::size_t piece,
                       std::size_t* most_held = nullptr) {
  std::vector<Seen> seen;
  for (std::size_t off = 0; off < bytes.size(); off += piece) {
    const std::size_t n = std::min(piece, bytes.size() - off);
    s.feed({bytes.data() + off, n}, [&](const IgtlFrame& f) {
      seen.push_back({f.kind, f.type, f.device, f.error, {f.content.begin(), f.content.end()}});
    });
    if (most_held) *most_held = std::max(*most_held, s.buffered());
  }
  return seen;
}

TEST(IgtlStream, MessagesComeOutWholeAndDecodedInAnyPieces) {
  const Bytes stream = transform("guidewire", 120.f, 30.f) + sensor("vel_catheter", {5.0, -10.0}) +
                       string("exchange", "add x as y");
  for (std::size_t piece : {std::size_t{1}, std::size_t{7}, std::size_t{58}, stream.size()}) {
    IgtlStream s;
    const auto seen = feed(s, stream, piece);
    ASSERT_EQ(seen.size(), 3u) << "pieces of " << piece;
    EXPECT_EQ(s.buffered(), 0u);
    for (const Seen& m : seen) EXPECT_EQ(m.kind, Kind::kMessage) << m.error;
    EXPECT_EQ(seen[0].type, "TRANSFORM");
    EXPECT_EQ(seen[0].device, "guidewire");
    double depth = 0, angle = 0;
    EXPECT_EQ(vcsim::internal::decode_igtl_transform(seen[0].content, depth, angle), "");
    EXPECT_NEAR(depth, 120.0, 1e-4);
    EXPECT_NEAR(angle, 30.0, 1e-4);
    std::vector<double> v;
    EXPECT_EQ(vcsim::internal::decode_igtl_sensor(seen[1].content, v), "");
    EXPECT_EQ(v, (std::vector<double>{5.0, -10.0}));
    std::string text;
    EXPECT_EQ(vcsim::internal::decode_igtl_string(seen[2].content, text), "");
    EXPECT_EQ(text, "add x as y");
    // Each decoder refuses the others' content with its reason.
    EXPECT_EQ(vcsim::internal::decode_igtl_transform(seen[1].content, depth, angle),
              "TRANSFORM body is not 12 floats");
    EXPECT_EQ(vcsim::internal::decode_igtl_sensor(seen[0].content, v),
              "SENSOR body size does not match its array length");
  }
}

TEST(IgtlStream, OversizedBodyIsReadPastWithoutBeingHeld) {
  const Bytes stream = oversized(200000) + sensor("balloon", {8.0});
  IgtlStream s;
  std::size_t most = 0;
  const auto seen = feed(s, stream, 4096, &most);
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_EQ(seen[0].kind, Kind::kSkipped);
  EXPECT_EQ(seen[0].type, "IMAGE");
  EXPECT_EQ(seen[1].kind, Kind::kMessage);
  EXPECT_EQ(seen[1].device, "balloon");
  EXPECT_LT(most, 4096u);  // never more than one piece, never the body
}

TEST(IgtlStream, BadCrcDropsOneMessageAndTheNextIsRead) {
  Bytes bad = transform("catheter", 5.f, 0.f);
  bad[57] ^= 0x5a;  // the CRC field's last byte
  IgtlStream s;
  const auto seen = feed(s, bad + transform("catheter", 6.f, 90.f), 13);
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_EQ(seen[0].kind, Kind::kBadMessage);
  EXPECT_EQ(seen[0].error, "CRC mismatch");
  EXPECT_EQ(seen[1].kind, Kind::kMessage);
}

TEST(IgtlStream, GarbageHeaderLosesTheStreamUntilReset) {
  Bytes garbage = sensor("balloon", {1.0});
  garbage[1] = 7;  // version 7
  IgtlStream s;
  std::vector<Seen> seen = feed(s, garbage + sensor("balloon", {2.0}), 1000);
  ASSERT_EQ(seen.size(), 1u);
  EXPECT_EQ(seen[0].kind, Kind::kGarbage);
  EXPECT_NE(seen[0].error.find("version 7"), std::string::npos) << seen[0].error;
  EXPECT_TRUE(s.lost());
  EXPECT_TRUE(feed(s, sensor("balloon", {3.0}), 1000).empty());
  s.reset();
  seen = feed(s, sensor("balloon", {3.0}), 1000);
  ASSERT_EQ(seen.size(), 1u);
  EXPECT_EQ(seen[0].kind, Kind::kMessage);
  // A body size beyond any message (2^63) is garbage too, not a skip.
  Bytes huge = oversized(0);
  huge[42] = 0x80;
  s.reset();
  seen = feed(s, huge, 100);
  ASSERT_EQ(seen.size(), 1u);
  EXPECT_EQ(seen[0].kind, Kind::kGarbage);
}

TEST(IgtlStream, DecodersRefuseNonFiniteAndNonPrintable) {
  Bytes nan_sensor = sensor("balloon", {std::nan("")});
  IgtlStream s;
  auto seen = feed(s, nan_sensor + string("exchange", "a\tb"), 64);
  ASSERT_EQ(seen.size(), 2u);
  std::vector<double> v;
  EXPECT_EQ(vcsim::internal::decode_igtl_sensor(seen[0].content, v), "non-finite value");
  std::string text;
  EXPECT_EQ(vcsim::internal::decode_igtl_string(seen[1].content, text), "expected printable ASCII");
}

}  // namespace
