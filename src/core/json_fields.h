// Reading a JSON document field by field with errors that name the file and the field path
// ("tip_sections[2].arc.radius_mm"). Every key looked up is remembered, so that finish() can
// reject keys nobody asked for: a typo in a data file is an error, not a silent default.
// Internal to vcsim: the parsers of every layer (scenario, timeline, vessel tree, catalogue) use
// it through the vcsim_json target, and no header in include/vcsim includes it.
#pragma once

#include <nlohmann/json.hpp>

#include <cstddef>
#include <initializer_list>
#include <set>
#include <string>
#include <string_view>

#include "vcsim/core.h"

namespace vcsim::internal {

using Json = nlohmann::json;

// Deepest nesting of arrays and objects a document may have; the shipped files reach 5. Deeper
// documents are refused while parsing, so nothing that walks a parsed value recurses far.
inline constexpr std::size_t kMaxJsonDepth = 64;

// Largest magnitude of a number a file may give (as_number refuses larger ones, naming the field).
// Far above any quantity vcsim reads in the units of its keys (the largest, a seed, stays below
// 2^53 ~ 9e15), and small enough that no unit conversion (factors up to 101325, atm to Pa) nor a
// product of two such values overflows to infinity: 1e307 per cm would be inf per metre.
inline constexpr double kMaxJsonNumber = 1e18;

// Concatenates strings with += (GCC 12 warns falsely on "literal" + std::string).
template <typename... A>
std::string cat(const A&... parts) {
  std::string s;
  ((s += parts), ...);
  return s;
}

// A short, printable rendering of a JSON value for "got ..." in messages: its compact dump(),
// cut to 40 characters. The work is bounded by that length, however deep the value.
std::string describe_json(const Json& v);

// Parses text. Every problem is an InputError naming `source`: invalid JSON or a number beyond a
// double (field "json"), more than kMaxJsonDepth levels of nesting ("json"), a key repeated in
// one object (the key's field path). No nlohmann exception leaves this function.
Json parse_json_text(std::string_view text, const std::string& source);

std::string join_path(const std::string& parent, std::string_view key);  // "a.b"
std::string index_path(const std::string& parent, std::size_t i);        // "a[2]"

class JsonFields {
 public:
  // `path` is this object's field path ("" for the document root).
  JsonFields(const Json& j, std::string source, std::string path);

  const std::string& source() const { return source_; }
  const std::string& path() const { return path_; }
  std::string field(std::string_view key) const { return join_path(path_, key); }

  // Declares every key the object may have and rejects any other now, before a value is read,
  // so that a misspelt key is reported as unknown rather than as the required key it stood for.
  void keys(std::initializer_list<const char*> known);

  bool has(const char* key);
  // The value or nullptr when absent.
  const Json* get(const char* key);
  const Json& require(const char* key);

  double number(const char* key) { return as_number(require(key), field(key)); }
  double number_or(const char* key, double fallback);
  double positive(const char* key) { return require_positive(number(key), source_, field(key)); }
  double positive_or(const char* key, double fallback) {
    return require_positive(number_or(key, fallback), source_, field(key));
  }
  double nonnegative(const char* key) {
    return require_nonnegative(number(key), source_, field(key));
  }
  double nonnegative_or(const char* key, double fallback) {
    return require_nonnegative(number_or(key, fallback), source_, field(key));
  }
  // In (lo, hi].
  double in_range(const char* key, double lo, double hi) {
    return require_in_range(number(key), lo, hi, source_, field(key));
  }
  double in_range_or(const char* key, double lo, double hi, double fallback) {
    return require_in_range(number_or(key, fallback), lo, hi, source_, field(key));
  }

  std::string string(const char* key) { return as_string(require(key), field(key)); }
  std::string string_or(const char* key, const std::string& fallback);
  // A string that must not be empty (names, identifiers).
  std::string text(const char* key);
  std::string text_or(const char* key, const std::string& fallback) {
    return has(key) ? text(key) : fallback;
  }
  // An integer in [lo, hi] (inclusive).
  int integer_or(const char* key, int lo, int hi, int fallback);
  bool boolean_or(const char* key, bool fallback);
  const Json& array(const char* key);
  JsonFields object(const char* key) { return JsonFields(require(key), source_, field(key)); }

  [[noreturn]] void fail(std::string_view key, const std::string& expected) const {
    throw InputError(source_, field(key), expected);
  }

  // Rejects the first key that was never looked up.
  void finish() const;

  // A number within +-kMaxJsonNumber (finite whatever unit it is converted to).
  double as_number(const Json& v, const std::string& f) const;
  std::string as_string(const Json& v, const std::string& f) const;

 private:
  const Json& j_;
  std::string source_;
  std::string path_;
  std::set<std::string, std::less<>> asked_;
};

}  // namespace vcsim::internal
