// libFuzzer target: the OpenIGTLink byte stream (IgtlStream framing, then the SENSOR, TRANSFORM
// and STRING decoders on every message's content), as the server reads it from a socket. The
// first byte sets the size of the pieces the rest arrives in; the stream fed whole and fed in
// pieces must yield the same messages and errors (else a trap: a finding).
#include <cstdlib>
#include <span>
#include <string>
#include <vector>

#include "fuzz_common.h"
#include "igtl_stream.h"

namespace {

using vcsim::internal::IgtlFrame;

struct Seen {
  IgtlFrame::Kind kind;
  std::uint16_t version;
  std::string type, device, error, decoded;
  std::uint64_t body_size;
  std::vector<unsigned char> content;
  bool operator==(const Seen&) const = default;
};

// Every frame of `stream` fed in pieces of `piece` bytes (0: whole), decoded as each type.
std::vector<Seen> run(std::span<const unsigned char> bytes, std::size_t piece) {
  vcsim::internal::IgtlStream stream;
  std::vector<Seen> seen;
  std::vector<double> values;
  std::string text;
  const auto sink = [&](const IgtlFrame& f) {
    Seen s{f.kind,  f.version, f.type,      f.device,
           f.error, {},        f.body_size, {f.content.begin(), f.content.end()}};
    if (f.kind == IgtlFrame::Kind::kMessage) {
      double depth = 0.0, angle = 0.0;
      s.decoded = vcsim::internal::decode_igtl_sensor(f.content, values) + "|" +
                  vcsim::internal::decode_igtl_transform(f.content, depth, angle) + "|" +
                  vcsim::internal::decode_igtl_string(f.content, text);
      if (values.size() > 255 || text.size() > f.content.size()) std::abort();
    }
    seen.push_back(std::move(s));
  };
  if (piece == 0) piece = bytes.size() + 1;
  for (std::size_t off = 0; off < bytes.size(); off += piece) {
    const std::size_t n = std::min(piece, bytes.size() - off);
    if (!stream.feed(bytes.subspan(off, n), sink)) break;
  }
  // Nothing beyond one incomplete message is held (a body is at most kIgtlMaxBody).
  if (stream.buffered() >= vcsim::internal::kIgtlHeaderSize + vcsim::internal::kIgtlMaxBody)
    std::abort();
  return seen;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  const std::size_t piece = std::size_t{data[0]} + 1;  // 1-256 bytes
  const std::span<const unsigned char> bytes(data + 1, size - 1);
  if (run(bytes, 0) != run(bytes, piece)) std::abort();  // framing depends on the pieces
  return 0;
}
