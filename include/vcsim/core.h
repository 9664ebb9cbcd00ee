// vcsim core: math aliases, user-input errors, state hashing and step timing.
// SI units everywhere inside the engine (m, kg, s, N, Pa, rad).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <chrono>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

namespace vcsim {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Quat = Eigen::Quaterniond;

// Invalid input from outside the engine (file, message, command-line value). The message names
// the source, the field and what was expected; the CLI prints it on one line and exits with 2.
class InputError : public std::runtime_error {
 public:
  InputError(const std::string& source, const std::string& field, const std::string& expected);
  const std::string& source() const { return source_; }
  const std::string& field() const { return field_; }

 private:
  std::string source_;
  std::string field_;
};

// Checks a user-supplied value once at the boundary; throws InputError naming the field.
double require_finite(double v, const std::string& source, const std::string& field);
double require_positive(double v, const std::string& source, const std::string& field);
double require_nonnegative(double v, const std::string& source, const std::string& field);
double require_in_range(double v, double lo_exclusive, double hi_inclusive,
                        const std::string& source, const std::string& field);

// 64-bit FNV-1a over raw bytes; chained so that several arrays hash into one value.
class StateHasher {
 public:
  void add_bytes(const void* data, std::size_t n);
  template <typename T>
  void add(std::span<const T> s) {
    add_bytes(s.data(), s.size_bytes());
  }
  template <typename T>
  void add(const std::vector<T>& v) {
    add(std::span<const T>(v));
  }
  // One scalar (arithmetic types only: a struct's padding bytes would make equal values differ).
  template <typename T>
  void add_value(const T& v) {
    static_assert(std::is_arithmetic_v<T>);
    add_bytes(&v, sizeof v);
  }
  void add_value(const Vec3& v) { add_bytes(v.data(), 3 * sizeof(double)); }
  void add_value(const Quat& q) { add_bytes(q.coeffs().data(), 4 * sizeof(double)); }
  std::uint64_t value() const { return h_; }

 private:
  std::uint64_t h_ = 1469598103934665603ull;
};

// A small deterministic random generator: SplitMix64 (Steele, Lea and Flood, "Fast splittable
// pseudorandom number generators", OOPSLA 2014). Its whole state is one word, so a copy of a
// state that holds it is a snapshot of it.
struct Random {
  std::uint64_t state = 0;
  std::uint64_t next();
  double uniform();  // in [0, 1), 53 bits
};

// Median of a sample (taken by value: reorders a copy). 0 for an empty sample.
double median(std::vector<double> sample);

// Durations (microseconds) counted in log-spaced bins, 5 % wide, from 0.05 us to 10 s: a mean
// exact to the sum, quantiles to within half a bin (2.5 %). Fixed size: adding allocates nothing.
class DurationHistogram {
 public:
  static constexpr int kBins = 400;
  void add(double us);
  std::int64_t count() const { return count_; }
  double mean() const { return count_ > 0 ? sum_ / static_cast<double>(count_) : 0.0; }
  double max() const { return max_; }
  // The q-quantile (0..1), the geometric middle of its bin; 0 when empty.
  double quantile(double q) const;

 private:
  std::array<std::int64_t, kBins> bins_{};
  std::int64_t count_ = 0;
  double sum_ = 0.0, max_ = 0.0;
};

// Monotonic clock in microseconds for step profiling.
inline double now_us() {
  using namespace std::chrono;
  return duration<double, std::micro>(steady_clock::now().time_since_epoch()).count();
}

}  // namespace vcsim
