// OpenIGTLink framing and content decoding, without a socket: bytes in (in any pieces), messages
// or clear errors out. The server (igtl_server.cpp) feeds it what recv() gives; the fuzz target
// (tests/fuzz/fuzz_igtl.cpp) feeds it anything. Protocol: openigtlink.org, "OpenIGTLink
// Protocol" (58-byte header, header version 2's extended header, SENSOR, TRANSFORM, STRING).
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

namespace vcsim::internal {

constexpr std::size_t kIgtlHeaderSize = 58;
// Larger than any message we accept (a SENSOR of 255 values is 2 kB); a well-formed message with
// a bigger body (an IMAGE a 3D Slicer user sends along) is read past, never held whole. A body
// size beyond kIgtlMaxSkip is not a message but garbage.
constexpr std::uint64_t kIgtlMaxBody = 64 * 1024;
constexpr std::uint64_t kIgtlMaxSkip = std::uint64_t{1} << 40;

// One thing the stream yielded.
struct IgtlFrame {
  enum class Kind {
    kMessage,     // a whole message, CRC checked; `content` is its content
    kBadMessage,  // a framed message that cannot be used (CRC, extended header): `error`
    kSkipped,     // a well-formed message over kIgtlMaxBody, read past without keeping it
    kGarbage,     // a header that is not one (version, names, body size): the stream is lost
  };
  Kind kind = Kind::kMessage;
  std::uint16_t version = 0;
  std::string type, device;  // printable ASCII (empty for kGarbage)
  std::uint64_t body_size = 0;
  // kMessage: the content (version 2: without extended header and metadata); valid only during
  // the callback.
  std::span<const unsigned char> content;
  std::string error;  // kBadMessage, kGarbage: why
};

// Splits a byte stream into messages. After kGarbage nothing more is read (there is no way to
// find the next boundary) until reset().
class IgtlStream {
 public:
  using Sink = std::function<void(const IgtlFrame&)>;
  // Takes the next bytes; calls `sink` for each message completed by them, in order. Returns
  // false once the stream is lost (kGarbage given).
  bool feed(std::span<const unsigned char> bytes, const Sink& sink);
  void reset();
  bool lost() const { return lost_; }
  std::size_t buffered() const { return rx_.size(); }  // bytes held of an incomplete message

 private:
  bool frame(const Sink& sink);
  std::vector<unsigned char> rx_;  // bytes received, not yet framed
  std::uint64_t skipping_ = 0;     // bytes of an oversized body still to read past
  bool lost_ = false;
};

// Content decoders: each returns "" and fills its outputs, or says why the content is refused.
// SENSOR: uint8 array length, uint8 status, uint64 unit, then that many big-endian float64, all
// finite. `values` holds at most 255.
std::string decode_igtl_sensor(std::span<const unsigned char> content, std::vector<double>& values);
// TRANSFORM: the upper 3 x 4 of a pose, column by column, big-endian float32, finite, the
// rotation's columns of unit length (5 %). depth = translation z; angle = rotation about z.
std::string decode_igtl_transform(std::span<const unsigned char> content, double& depth,
                                  double& angle_deg);
// STRING: uint16 encoding, uint16 length, then that many bytes of printable ASCII.
std::string decode_igtl_string(std::span<const unsigned char> content, std::string& text);

}  // namespace vcsim::internal
