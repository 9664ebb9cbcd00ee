#include "vcsim/core.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace vcsim {

namespace {
std::string format_error(const std::string& source, const std::string& field,
                         const std::string& expected) {
  std::ostringstream os;
  os << source << ": " << field << ": " << expected;
  return os.str();
}
std::string num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}
}  // namespace

InputError::InputError(const std::string& source, const std::string& field,
                       const std::string& expected)
    : std::runtime_error(format_error(source, field, expected)), source_(source), field_(field) {}

double require_finite(double v, const std::string& source, const std::string& field) {
  if (!std::isfinite(v)) throw InputError(source, field, "expected a finite number, got " + num(v));
  return v;
}

double require_positive(double v, const std::string& source, const std::string& field) {
  require_finite(v, source, field);
  if (!(v > 0.0)) throw InputError(source, field, "expected a positive number, got " + num(v));
  return v;
}

double require_nonnegative(double v, const std::string& source, const std::string& field) {
  require_finite(v, source, field);
  if (v < 0.0) throw InputError(source, field, "expected a number >= 0, got " + num(v));
  return v;
}

double require_in_range(double v, double lo_exclusive, double hi_inclusive,
                        const std::string& source, const std::string& field) {
  require_finite(v, source, field);
  if (!(v > lo_exclusive && v <= hi_inclusive)) {
    throw InputError(source, field,
                     "expected a value in (" + num(lo_exclusive) + ", " + num(hi_inclusive) +
                         "], got " + num(v));
  }
  return v;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

std::uint64_t Random::next() {
  state += 0x9e3779b97f4a7c15ull;
  std::uint64_t z = state;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

double Random::uniform() {
  return static_cast<double>(next() >> 11) * 0x1.0p-53;
}

void StateHasher::add_bytes(const void* data, std::size_t n) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h_ ^= p[i];
    h_ *= 1099511628211ull;
  }
}

// --- DurationHistogram ---------------------------------------------------------------------------

namespace {
constexpr double kHistogramLow = 0.05;  // us, the lower edge of bin 0
const double kHistogramStep = std::log(1.05);
}  // namespace

void DurationHistogram::add(double us) {
  if (!(us >= 0.0)) us = 0.0;  // NaN as 0
  int b = us > kHistogramLow ? static_cast<int>(std::log(us / kHistogramLow) / kHistogramStep) : 0;
  b = std::clamp(b, 0, kBins - 1);
  ++bins_[static_cast<std::size_t>(b)];
  ++count_;
  sum_ += us;
  max_ = std::max(max_, us);
}

double DurationHistogram::quantile(double q) const {
  if (count_ == 0) return 0.0;
  const auto want =
      static_cast<std::int64_t>(std::ceil(std::clamp(q, 0.0, 1.0) * static_cast<double>(count_)));
  std::int64_t seen = 0;
  for (int b = 0; b < kBins; ++b) {
    seen += bins_[static_cast<std::size_t>(b)];
    if (seen >= std::max<std::int64_t>(want, 1)) {
      if (b == 0) return std::min(max_, kHistogramLow);
      return std::min(max_, kHistogramLow * std::exp((b + 0.5) * kHistogramStep));
    }
  }
  return max_;
}

}  // namespace vcsim
