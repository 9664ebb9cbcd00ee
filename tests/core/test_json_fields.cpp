// The JSON field reader: what every loader refuses whatever its format (nesting deeper than the
// limit, numbers beyond a double, repeated keys), always as an InputError naming the source, and
// describe_json's bounded work on a value of any depth.
#include <gtest/gtest.h>

#include <string>

#include "json_fields.h"

namespace vcsim::internal {
namespace {

// The field of the InputError that parsing `text` raises, or "accepted".
std::string error_field(const std::string& text) {
  try {
    parse_json_text(text, "in.json");
  } catch (const InputError& e) {
    EXPECT_EQ(e.source(), "in.json");
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();  // one line
    return e.field();
  }
  return "accepted";
}

std::string nested(std::size_t levels) {
  return std::string(levels, '[') + std::string(levels, ']');
}

TEST(JsonReader, NestingIsLimited) {
  EXPECT_EQ(error_field(nested(kMaxJsonDepth)), "accepted");
  EXPECT_EQ(error_field(nested(kMaxJsonDepth + 1)), "json");
  EXPECT_EQ(error_field(nested(100000)), "json");  // overflowed the stack before the limit
  EXPECT_EQ(error_field(cat("{\"a\": ", nested(100000), "}")), "json");
  std::string objects;
  for (int i = 0; i < 100000; ++i) objects += "{\"a\": ";
  objects += '1';
  objects += std::string(100000, '}');
  EXPECT_EQ(error_field(objects), "json");
  try {
    parse_json_text(nested(100000), "in.json");
    ADD_FAILURE() << "accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("at most 64 levels"), std::string::npos) << e.what();
  }
}

TEST(JsonReader, NumbersBeyondADoubleAreInputErrors) {
  for (const char* text : {"1e999", "[-1e999]", "{\"x\": 2e308}"}) {
    EXPECT_EQ(error_field(text), "json") << text;
  }
  try {
    parse_json_text("{\"x\": 1e999}", "in.json");
    ADD_FAILURE() << "accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("1e999"), std::string::npos) << e.what();
  }
  try {  // a long number is cut short in the message
    parse_json_text(cat(std::string(5000, '1'), "e999"), "in.json");
    ADD_FAILURE() << "accepted";
  } catch (const InputError& e) {
    EXPECT_LT(std::string(e.what()).size(), 120u) << e.what();
  }
  // The largest double and integers beyond 64 bits (read as doubles) still parse.
  EXPECT_EQ(error_field("[1.7976931348623157e308, 18446744073709551616]"), "accepted");
}

// A finite number that a unit conversion would take to infinity (1e307 per cm is inf per metre,
// written to metrics.json as null) is refused by as_number, naming its field.
TEST(JsonReader, NumbersThatCouldOverflowInAUnitAreRefused) {
  const Json j = parse_json_text(R"({"a": 1e307, "b": -2e18, "c": 1e18, "d": 9007199254740992,
                                     "e": 18446744073709551615})",
                                 "in.json");
  JsonFields f(j, "in.json", "");
  for (const char* key : {"a", "b", "e"}) {
    try {
      f.number(key);
      ADD_FAILURE() << key << " accepted";
    } catch (const InputError& e) {
      EXPECT_EQ(e.field(), key);
      EXPECT_NE(std::string(e.what()).find("within +-1e18"), std::string::npos) << e.what();
    }
  }
  EXPECT_EQ(f.number("c"), 1e18);
  EXPECT_EQ(f.number("d"), 9007199254740992.0);  // 2^53, the largest seed
}

TEST(JsonReader, SyntaxErrorsAreInputErrors) {
  for (const char* text : {"", "{", "{\"a\": }", "[1, 2", "nul", "{\"a\": 1} x", "\"\xff\""}) {
    EXPECT_EQ(error_field(text), "json") << text;
  }
}

TEST(JsonReader, RepeatedKeysNameTheField) {
  EXPECT_EQ(error_field(R"({"x": 1, "x": 2})"), "x");
  EXPECT_EQ(error_field(R"({"a": [{"b": 1}, {"c": {"d": 1, "d": 2}}]})"), "a[1].c.d");
  EXPECT_EQ(error_field(R"([[0, {"k": 1, "k": 1}]])"), "[0][1].k");
  // The same key in different objects is fine.
  EXPECT_EQ(error_field(R"({"a": {"k": 1}, "b": {"k": 2}, "c": [{"k": 1}, {"k": 2}]})"),
            "accepted");
}

TEST(JsonReader, ParsesTheSameValuesAsTheLibrary) {
  const std::string text = R"({"a": [1, -2, 3.25, 1e-300, 0.1], "b": {"c": "x\u00e9", "d": null},
                               "e": true, "f": 18446744073709551615})";
  EXPECT_EQ(parse_json_text(text, "in.json"), Json::parse(text));
}

TEST(JsonReader, DescribeIsShortAndBoundedAtAnyDepth) {
  EXPECT_EQ(describe_json(Json::parse(R"({"a": [1, 2], "b": "x"})")), R"({"a":[1,2],"b":"x"})");
  EXPECT_EQ(describe_json(Json(nullptr)), "null");
  std::string text = "[";
  for (int i = 0; i < 30; ++i) text += "10, ";
  text += "1]";
  const Json long_array = Json::parse(text);
  const std::string d = describe_json(long_array);
  EXPECT_EQ(d.size(), 40u);
  EXPECT_EQ(d, long_array.dump().substr(0, 37) + "...");
  // A value built in code is not limited by the parser: 100,000 levels, described in 40 characters
  // (dump() recursed once per level and overflowed the stack).
  Json deep = Json::array();
  Json* inner = &deep;
  for (int i = 0; i < 100000; ++i) {
    inner->push_back(Json::array());
    inner = &inner->back();
  }
  EXPECT_EQ(describe_json(deep), std::string(37, '[') + "...");
}

TEST(JsonReader, FieldsNameFileAndPath) {
  const Json j = parse_json_text(R"({"a": {"b": 1, "c": 2}, "n": "x"})", "in.json");
  JsonFields f(j, "in.json", "");
  JsonFields a = f.object("a");
  EXPECT_EQ(a.number("b"), 1.0);
  try {
    a.finish();
    ADD_FAILURE() << "an unread key was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "a.c");
  }
  // keys() refuses an unknown key before any value is read.
  JsonFields g(j, "in.json", "");
  try {
    g.keys({"a"});
    ADD_FAILURE() << "an undeclared key was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "n");
  }
  try {
    JsonFields(j.at("n"), "in.json", "n");
    ADD_FAILURE() << "a string was read as an object";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "n");
    EXPECT_NE(std::string(e.what()).find("expected an object, got \"x\""), std::string::npos);
  }
}

}  // namespace
}  // namespace vcsim::internal
