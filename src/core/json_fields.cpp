#include "json_fields.h"

#include <cmath>
#include <vector>

namespace vcsim::internal {

namespace {

// Appends v's compact dump() to out, stopping once out is longer than `limit`: every level of
// nesting adds a character before it descends, so the recursion is at most `limit` deep.
void dump_prefix(const Json& v, std::string& out, std::size_t limit) {
  if (out.size() > limit) return;
  if (v.is_object() || v.is_array()) {
    const bool obj = v.is_object();
    out += obj ? '{' : '[';
    bool first = true;
    for (auto it = v.begin(); it != v.end(); ++it) {
      if (!first) out += ',';
      first = false;
      if (obj) {
        out += Json(it.key()).dump();
        out += ':';
      }
      dump_prefix(it.value(), out, limit);
      if (out.size() > limit) return;
    }
    out += obj ? '}' : ']';
  } else {
    out += v.dump();
  }
}

// A first pass over the text that refuses what Json::parse accepts but the engine should not:
// nesting deeper than kMaxJsonDepth (nlohmann's dump, copy and comparison recurse, and 100,000
// levels overflow the stack) and repeated keys (parse keeps the last one silently). It also turns
// syntax errors and numbers beyond a double into InputError. A parse callback could check the
// depth in the same pass, but nlohmann's callback parser scans the enclosing container each time
// an object closes: quadratic in a long array of objects such as a timeline's keyframes.
class Checker final : public nlohmann::json_sax<Json> {
 public:
  explicit Checker(const std::string& source) : source_(source) {}

  bool null() override { return value(); }
  bool boolean(bool) override { return value(); }
  bool number_integer(number_integer_t) override { return value(); }
  bool number_unsigned(number_unsigned_t) override { return value(); }
  bool number_float(number_float_t, const string_t&) override { return value(); }
  bool string(string_t&) override { return value(); }
  bool binary(binary_t&) override { return value(); }
  bool start_object(std::size_t) override { return open(false); }
  bool end_object() override { return close(); }
  bool start_array(std::size_t) override { return open(true); }
  bool end_array() override { return close(); }

  bool key(string_t& k) override {
    Level& l = levels_.back();
    const auto [it, fresh] = l.keys.insert(k);
    if (!fresh) {
      throw InputError(source_, join_path(path(levels_.size() - 1), k),
                       "expected each key once in an object (a repeated key would replace the "
                       "first silently)");
    }
    l.key = &*it;
    return true;
  }

  bool parse_error(std::size_t, const std::string& last_token, const Json::exception& e) override {
    if (e.id == 406) {  // out_of_range: a number a double cannot hold, e.g. 1e999
      const std::string got =
          last_token.size() > 40 ? cat(last_token.substr(0, 37), "...") : last_token;
      throw InputError(source_, "json",
                       cat("expected numbers within the range of a double, got ", got));
    }
    throw InputError(source_, "json", cat("expected valid JSON (", e.what(), ")"));
  }

 private:
  struct Level {
    bool array = false;
    std::size_t count = 0;             // elements begun so far (arrays)
    const std::string* key = nullptr;  // the key being read (objects)
    std::set<std::string, std::less<>> keys;
  };

  bool value() {
    if (!levels_.empty() && levels_.back().array) ++levels_.back().count;
    return true;
  }
  bool open(bool array) {
    value();
    if (levels_.size() == kMaxJsonDepth) {
      throw InputError(source_, "json",
                       cat("expected at most ", std::to_string(kMaxJsonDepth),
                           " levels of nesting (arrays and objects)"));
    }
    levels_.emplace_back().array = array;
    return true;
  }
  bool close() {
    levels_.pop_back();
    return true;
  }
  // The field path of the value being read in the outermost `n` levels.
  std::string path(std::size_t n) const {
    std::string p;
    for (std::size_t i = 0; i < n; ++i) {
      const Level& l = levels_[i];
      p = l.array ? index_path(p, l.count - 1) : join_path(p, *l.key);
    }
    return p;
  }

  const std::string& source_;
  std::vector<Level> levels_;
};

}  // namespace

std::string describe_json(const Json& v) {
  std::string s;
  dump_prefix(v, s, 40);
  if (s.size() > 40) {
    s.resize(37);
    s += "...";
  }
  return s;
}

Json parse_json_text(std::string_view text, const std::string& source) {
  Checker check(source);
  try {
    Json::sax_parse(text.begin(), text.end(), &check);
    // The checked text, parsed by the library itself: the values are exactly Json::parse's.
    return Json::parse(text.begin(), text.end());
  } catch (const Json::exception& e) {  // not expected after the check; never a library message
    throw InputError(source, "json", cat("expected valid JSON (", e.what(), ")"));
  }
}

std::string join_path(const std::string& parent, std::string_view key) {
  std::string p = parent;
  if (!p.empty()) p += '.';
  p += key;
  return p;
}

std::string index_path(const std::string& parent, std::size_t i) {
  std::string p = parent;
  p += '[';
  p += std::to_string(i);
  p += ']';
  return p;
}

JsonFields::JsonFields(const Json& j, std::string source, std::string path)
    : j_(j), source_(std::move(source)), path_(std::move(path)) {
  if (!j_.is_object()) {
    throw InputError(source_, path_.empty() ? "(root)" : path_,
                     cat("expected an object, got ", describe_json(j_)));
  }
}

void JsonFields::keys(std::initializer_list<const char*> known) {
  for (const char* k : known) asked_.insert(k);
  finish();
}

bool JsonFields::has(const char* key) {
  asked_.insert(key);
  return j_.contains(key);
}

const Json* JsonFields::get(const char* key) {
  asked_.insert(key);
  auto it = j_.find(key);
  return it == j_.end() ? nullptr : &*it;
}

const Json& JsonFields::require(const char* key) {
  const Json* v = get(key);
  if (!v) throw InputError(source_, field(key), "expected this key (it is required)");
  return *v;
}

double JsonFields::number_or(const char* key, double fallback) {
  const Json* v = get(key);
  return v ? as_number(*v, field(key)) : fallback;
}

std::string JsonFields::string_or(const char* key, const std::string& fallback) {
  const Json* v = get(key);
  return v ? as_string(*v, field(key)) : fallback;
}

std::string JsonFields::text(const char* key) {
  std::string s = string(key);
  if (s.empty()) fail(key, "expected a non-empty string");
  return s;
}

int JsonFields::integer_or(const char* key, int lo, int hi, int fallback) {
  const Json* v = get(key);
  if (!v) return fallback;
  if (!v->is_number_integer() || v->get<long long>() < lo || v->get<long long>() > hi)
    fail(key, cat("expected an integer in [", std::to_string(lo), ", ", std::to_string(hi),
                  "], got ", describe_json(*v)));
  return static_cast<int>(v->get<long long>());
}

bool JsonFields::boolean_or(const char* key, bool fallback) {
  const Json* v = get(key);
  if (!v) return fallback;
  if (!v->is_boolean()) fail(key, cat("expected true or false, got ", describe_json(*v)));
  return v->get<bool>();
}

const Json& JsonFields::array(const char* key) {
  const Json& v = require(key);
  if (!v.is_array()) fail(key, cat("expected an array, got ", describe_json(v)));
  return v;
}

void JsonFields::finish() const {
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

double JsonFields::as_number(const Json& v, const std::string& f) const {
  if (!v.is_number())
    throw InputError(source_, f, cat("expected a number, got ", describe_json(v)));
  const double x = require_finite(v.get<double>(), source_, f);
  if (std::abs(x) > kMaxJsonNumber)
    throw InputError(
        source_, f,
        cat("expected a number within +-1e18 (finite in any unit), got ", describe_json(v)));
  return x;
}

std::string JsonFields::as_string(const Json& v, const std::string& f) const {
  if (!v.is_string())
    throw InputError(source_, f, cat("expected a string, got ", describe_json(v)));
  return v.get<std::string>();
}

}  // namespace vcsim::internal
