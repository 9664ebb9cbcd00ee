// OpenIGTLink framing and content decoding (igtl_stream.h). Framing is checked by hand so that a
// hostile header (a body size of 2^63, a truncated field) cannot reach the library; byte order
// and CRC-64 are libopenigtlink's.
#include "igtl_stream.h"

#include <igtl_header.h>
#include <igtl_sensor.h>
#include <igtl_string.h>
#include <igtl_util.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>

#include "json_fields.h"

namespace vcsim::internal {

namespace {

static_assert(kIgtlHeaderSize == IGTL_HEADER_SIZE);

// Big-endian reads (the protocol's byte order) for the version 2 extended header.
std::uint16_t be16(const unsigned char* p) {
  return static_cast<std::uint16_t>((p[0] << 8) | p[1]);
}
std::uint32_t be32(const unsigned char* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) |
         std::uint32_t{p[3]};
}
float be_float(const unsigned char* p) {
  const std::uint32_t u = be32(p);
  float f;
  std::memcpy(&f, &u, sizeof f);
  return f;
}

// A fixed-size name field: printable ASCII, then NUL padding only.
bool clean_name(const char* field, std::size_t n, std::string& out) {
  std::size_t len = 0;
  while (len < n && field[len] != '\0') {
    const auto c = static_cast<unsigned char>(field[len]);
    if (c < 0x20 || c > 0x7e) return false;
    ++len;
  }
  for (std::size_t i = len; i < n; ++i) {
    if (field[i] != '\0') return false;
  }
  out.assign(field, len);
  return true;
}

// A whole framed message: CRC, then (version 2) the extended header around the content.
void yield_message(const igtl_header& h, IgtlFrame& f, const unsigned char* body, std::size_t size,
                   const IgtlStream::Sink& sink) {
  f.kind = IgtlFrame::Kind::kBadMessage;
  // The CRC covers the whole body (extended header and metadata included).
  if (crc64(const_cast<unsigned char*>(body), size, 0) != h.crc) {
    f.error = "CRC mismatch";
    return sink(f);
  }
  // Header version 2 (OpenIGTLink 3): extended header, content, metadata header, metadata.
  const unsigned char* content = body;
  std::size_t csize = size;
  if (h.version == 2) {
    if (size < 12) {
      f.error = "version 2 body shorter than its extended header";
      return sink(f);
    }
    const std::size_t ext = be16(body), meta_head = be16(body + 2), meta = be32(body + 4);
    if (ext < 12 || ext + meta_head + meta > size) {
      f.error = "inconsistent version 2 extended header";
      return sink(f);
    }
    content = body + ext;
    csize = size - ext - meta_head - meta;
  }
  f.kind = IgtlFrame::Kind::kMessage;
  f.content = {content, csize};
  sink(f);
}

}  // namespace

void IgtlStream::reset() {
  rx_.clear();
  skipping_ = 0;
  lost_ = false;
}

bool IgtlStream::feed(std::span<const unsigned char> bytes, const Sink& sink) {
  if (lost_) return false;
  // An oversized body is read past here, piece by piece, not kept.
  std::size_t k = 0;
  if (skipping_ > 0 && rx_.empty()) {
    k = static_cast<std::size_t>(std::min<std::uint64_t>(skipping_, bytes.size()));
    skipping_ -= k;
  }
  rx_.insert(rx_.end(), bytes.begin() + static_cast<std::ptrdiff_t>(k), bytes.end());
  return frame(sink);
}

bool IgtlStream::frame(const Sink& sink) {
  std::size_t off = 0;
  for (;;) {
    if (skipping_ > 0) {
      const std::size_t k =
          static_cast<std::size_t>(std::min<std::uint64_t>(skipping_, rx_.size() - off));
      off += k;
      skipping_ -= k;
      if (skipping_ > 0) break;
    }
    if (rx_.size() - off < kIgtlHeaderSize) break;
    igtl_header h;
    std::memcpy(&h, rx_.data() + off, kIgtlHeaderSize);
    igtl_header_convert_byte_order(&h);
    IgtlFrame f;
    f.version = h.version;
    f.body_size = h.body_size;
    const bool names_ok = clean_name(h.name, IGTL_HEADER_TYPE_SIZE, f.type) &&
                          clean_name(h.device_name, IGTL_HEADER_NAME_SIZE, f.device);
    if ((h.version != 1 && h.version != 2) || !names_ok || f.type.empty() ||
        h.body_size > kIgtlMaxSkip) {
      f.kind = IgtlFrame::Kind::kGarbage;
      f.type.clear();
      f.device.clear();
      f.error = cat("unreadable header (version ", std::to_string(h.version), ", body ",
                    std::to_string(h.body_size), " bytes)");
      rx_.clear();
      skipping_ = 0;
      lost_ = true;
      sink(f);
      return false;
    }
    if (h.body_size > kIgtlMaxBody) {
      // Well-formed but more than we read (an IMAGE): skipped, the stream kept.
      f.kind = IgtlFrame::Kind::kSkipped;
      sink(f);
      skipping_ = h.body_size;
      off += kIgtlHeaderSize;
      continue;
    }
    const std::size_t body = static_cast<std::size_t>(h.body_size);
    if (rx_.size() - off < kIgtlHeaderSize + body) break;  // wait for the rest
    yield_message(h, f, rx_.data() + off + kIgtlHeaderSize, body, sink);
    off += kIgtlHeaderSize + body;
  }
  rx_.erase(rx_.begin(), rx_.begin() + static_cast<std::ptrdiff_t>(off));
  return true;
}

std::string decode_igtl_sensor(std::span<const unsigned char> content,
                               std::vector<double>& values) {
  values.clear();
  if (content.size() < IGTL_SENSOR_HEADER_SIZE) return "SENSOR body too short";
  igtl_sensor_header sh;
  std::memcpy(&sh, content.data(), IGTL_SENSOR_HEADER_SIZE);
  const std::size_t n = sh.larray;  // uint8: at most 255
  if (content.size() != IGTL_SENSOR_HEADER_SIZE + 8 * n)
    return "SENSOR body size does not match its array length";
  double v[255];
  std::memcpy(v, content.data() + IGTL_SENSOR_HEADER_SIZE, 8 * n);
  igtl_sensor_convert_byte_order(&sh, v);
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(v[i])) return "non-finite value";
  }
  values.assign(v, v + n);
  return {};
}

std::string decode_igtl_transform(std::span<const unsigned char> content, double& depth,
                                  double& angle_deg) {
  if (content.size() != 48) return "TRANSFORM body is not 12 floats";
  // Columns of the upper 3x4 matrix: R(:,0), R(:,1), R(:,2), t (big-endian float32).
  double m[12];
  for (int i = 0; i < 12; ++i) {
    m[i] = static_cast<double>(be_float(content.data() + 4 * i));
    if (!std::isfinite(m[i])) return "non-finite value";
  }
  for (int c = 0; c < 3; ++c) {
    const double len =
        std::sqrt(m[3 * c] * m[3 * c] + m[3 * c + 1] * m[3 * c + 1] + m[3 * c + 2] * m[3 * c + 2]);
    if (std::abs(len - 1.0) > 0.05) return "rotation part is not a rotation";
  }
  depth = m[11];
  angle_deg = std::atan2(m[1], m[0]) * 180.0 / std::numbers::pi;
  return {};
}

std::string decode_igtl_string(std::span<const unsigned char> content, std::string& text) {
  text.clear();
  if (content.size() < IGTL_STRING_HEADER_SIZE) return "STRING body too short";
  igtl_string_header sh;
  std::memcpy(&sh, content.data(), IGTL_STRING_HEADER_SIZE);
  igtl_string_convert_byte_order(&sh);
  if (content.size() != std::size_t{IGTL_STRING_HEADER_SIZE} + sh.length)
    return "STRING body size does not match its length";
  const auto* p = reinterpret_cast<const char*>(content.data()) + IGTL_STRING_HEADER_SIZE;
  for (std::size_t i = 0; i < sh.length; ++i) {
    const auto c = static_cast<unsigned char>(p[i]);
    if (c < 0x20 || c > 0x7e) return "expected printable ASCII";
  }
  text.assign(p, sh.length);
  return {};
}

}  // namespace vcsim::internal
