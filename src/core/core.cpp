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

}  // namespace vcsim
