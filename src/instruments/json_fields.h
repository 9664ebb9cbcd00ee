// Reading a JSON object field by field with errors that name the file and the field path
// ("tip_sections[2].arc.radius_mm"). Every key looked up is remembered, so that finish() can
// reject keys nobody asked for: a typo in a data file is an error, not a silent default.
// Internal to vcsim (used by the instrument catalogue and the scripted device timeline).
#pragma once

#include <nlohmann/json.hpp>

#include <cmath>
#include <set>
#include <string>
#include <string_view>

#include "vcsim/core.h"

namespace vcsim::internal {

using Json = nlohmann::json;

// Concatenates strings with += (GCC 12 warns falsely on "literal" + std::string).
template <typename... A>
std::string cat(const A&... parts) {
  std::string s;
  ((s += parts), ...);
  return s;
}

// A short, printable rendering of a JSON value for "got ..." in messages.
inline std::string describe_json(const Json& v) {
  std::string s = v.dump();
  if (s.size() > 40) {
    s.resize(37);
    s += "...";
  }
  return s;
}

// Parses text; a syntax error becomes InputError(source, "json", ...).
inline Json parse_json_text(std::string_view text, const std::string& source) {
  try {
    return Json::parse(text.begin(), text.end());
  } catch (const Json::parse_error& e) {
    std::string what = "expected valid JSON (";
    what += e.what();
    what += ")";
    throw InputError(source, "json", what);
  }
}

inline std::string join_path(const std::string& parent, std::string_view key) {
  std::string p = parent;
  if (!p.empty()) p += '.';
  p += key;
  return p;
}

inline std::string index_path(const std::string& parent, std::size_t i) {
  std::string p = parent;
  p += '[';
  p += std::to_string(i);
  p += ']';
  return p;
}

class JsonFields {
 public:
  // `path` is this object's field path ("" for the document root).
  JsonFields(const Json& j, std::string source, std::string path)
      : j_(j), source_(std::move(source)), path_(std::move(path)) {
    if (!j_.is_object()) {
      std::string what = "expected an object, got ";
      what += describe_json(j_);
      throw InputError(source_, path_.empty() ? "(root)" : path_, what);
    }
  }

  const std::string& source() const { return source_; }
  const std::string& path() const { return path_; }
  std::string field(std::string_view key) const { return join_path(path_, key); }

  bool has(const char* key) {
    asked_.insert(key);
    return j_.contains(key);
  }
  // The value or nullptr when absent.
  const Json* get(const char* key) {
    asked_.insert(key);
    auto it = j_.find(key);
    return it == j_.end() ? nullptr : &*it;
  }
  const Json& require(const char* key) {
    const Json* v = get(key);
    if (!v) throw InputError(source_, field(key), "expected this key (it is required)");
    return *v;
  }

  double number(const char* key) { return as_number(require(key), field(key)); }
  double number_or(const char* key, double fallback) {
    const Json* v = get(key);
    return v ? as_number(*v, field(key)) : fallback;
  }
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
  std::string string_or(const char* key, const std::string& fallback) {
    const Json* v = get(key);
    return v ? as_string(*v, field(key)) : fallback;
  }
  // A string that must not be empty (names, identifiers).
  std::string text(const char* key) {
    std::string s = string(key);
    if (s.empty()) fail(key, "expected a non-empty string");
    return s;
  }
  std::string text_or(const char* key, const std::string& fallback) {
    return has(key) ? text(key) : fallback;
  }
  // An integer in [lo, hi] (inclusive).
  int integer_or(const char* key, int lo, int hi, int fallback) {
    const Json* v = get(key);
    if (!v) return fallback;
    if (!v->is_number_integer() || v->get<long long>() < lo || v->get<long long>() > hi)
      fail(key, cat("expected an integer in [", std::to_string(lo), ", ", std::to_string(hi),
                    "], got ", describe_json(*v)));
    return static_cast<int>(v->get<long long>());
  }
  bool boolean_or(const char* key, bool fallback) {
    const Json* v = get(key);
    if (!v) return fallback;
    if (!v->is_boolean()) fail(key, cat("expected true or false, got ", describe_json(*v)));
    return v->get<bool>();
  }
  const Json& array(const char* key) {
    const Json& v = require(key);
    if (!v.is_array()) fail(key, cat("expected an array, got ", describe_json(v)));
    return v;
  }
  JsonFields object(const char* key) { return JsonFields(require(key), source_, field(key)); }

  [[noreturn]] void fail(std::string_view key, const std::string& expected) const {
    throw InputError(source_, field(key), expected);
  }

  // Rejects the first key that was never looked up.
  void finish() const {
    for (auto it = j_.begin(); it != j_.end(); ++it) {
      if (asked_.count(it.key())) continue;
      std::string what = "unknown key (expected one of: ";
      bool first = true;
      for (const auto& k : asked_) {
        if (!first) what += ", ";
        what += k;
        first = false;
      }
      what += ")";
      throw InputError(source_, field(it.key()), what);
    }
  }

  double as_number(const Json& v, const std::string& f) const {
    if (!v.is_number()) {
      std::string what = "expected a number, got ";
      what += describe_json(v);
      throw InputError(source_, f, what);
    }
    return require_finite(v.get<double>(), source_, f);
  }
  std::string as_string(const Json& v, const std::string& f) const {
    if (!v.is_string()) {
      std::string what = "expected a string, got ";
      what += describe_json(v);
      throw InputError(source_, f, what);
    }
    return v.get<std::string>();
  }

 private:
  const Json& j_;
  std::string source_;
  std::string path_;
  std::set<std::string, std::less<>> asked_;
};

}  // namespace vcsim::internal
