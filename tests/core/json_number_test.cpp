// Whole numbers from JSON: only whole numbers in range, never a conversion out of range.
#include "core/json_number.h"
#include "core/json_keys.h"

#include <gtest/gtest.h>

namespace compose {
namespace {

using nlohmann::json;

TEST(JsonNumber, TakesWholeNumbersWrittenEitherWay) {
  EXPECT_EQ(wholeNumber(json(3)), 3);
  EXPECT_EQ(wholeNumber(json(3.0)), 3);
  EXPECT_EQ(wholeNumber(json(-7)), -7);
  EXPECT_EQ(wholeNumber(json(uint64_t(12))), 12);
  EXPECT_EQ(wholeNumber(json::parse("2147483647")), 2147483647);
}

TEST(JsonNumber, RefusesFractionsOutOfRangeAndOtherTypes) {
  EXPECT_FALSE(wholeNumber(json(3.5)));
  EXPECT_FALSE(wholeNumber(json::parse("3e39")));  // a float far beyond int
  EXPECT_FALSE(wholeNumber(json::parse("-1e20")));
  EXPECT_FALSE(wholeNumber(json(int64_t(1) << 40)));  // would wrap to 0 as an int
  EXPECT_FALSE(wholeNumber(json::parse("18446744073709551615")));
  EXPECT_FALSE(wholeNumber(json("3")));
  EXPECT_FALSE(wholeNumber(json(true)));
  EXPECT_FALSE(wholeNumber(json()));
  EXPECT_FALSE(wholeNumber(json(5), 0, 4)) << "above the caller's range";
  EXPECT_FALSE(wholeNumber(json(-1), 0));
}

TEST(JsonNumber, MembersAreLookedUpOnObjectsOnly) {
  const json j = json::parse(R"({"x0": 4, "y0": 2.5, "big": 1e300})");
  EXPECT_EQ(wholeMember(j, "x0"), 4);
  EXPECT_FALSE(wholeMember(j, "y0"));
  EXPECT_FALSE(wholeMember(j, "big"));
  EXPECT_FALSE(wholeMember(j, "missing"));
  EXPECT_FALSE(wholeMember(json::array({1, 2}), "x0"));
  EXPECT_FALSE(wholeMember(json(4), "x0"));
}

}  // namespace
// The library's messages in a user's words: no "[json.exception...]" tag; an empty file, and NaN
// or Infinity (Python's json.dumps writes them), said plainly. The messages come from the library
// itself, so that a change in its wording shows here.
TEST(JsonMessage, ReadsAsAnErrorForAUser) {
  auto messageOf = [](const std::string& text) {
    try {
      const json parsed = json::parse(text);
      return parsed.dump();
    } catch (const json::exception& e) {
      return jsonMessage(e.what());
    }
  };
  EXPECT_EQ(messageOf(""), "the file is empty");
  const std::string nan = messageOf(R"({"yaw": NaN})");
  EXPECT_EQ(nan.find("[json.exception"), std::string::npos) << nan;
  EXPECT_EQ(nan.find("syntax error while parsing"), std::string::npos) << nan;
  EXPECT_NE(nan.find("line 1, column"), std::string::npos) << nan;
  EXPECT_NE(nan.find("JSON has no NaN or Infinity"), std::string::npos) << nan;
  EXPECT_NE(messageOf(R"({"yaw": Infinity})").find("JSON has no NaN or Infinity"),
            std::string::npos);
  const std::string comma = messageOf(R"({"yaw": 1,})");
  EXPECT_EQ(comma.find("JSON has no NaN"), std::string::npos) << comma;
  EXPECT_EQ(comma.find("[json.exception"), std::string::npos) << comma;
  try {
    const double v = json::parse(R"({"a": "text"})").at("a").get<double>();
    ADD_FAILURE() << v;
  } catch (const json::exception& e) {
    EXPECT_EQ(jsonMessage(e.what()), "type must be number, but is string");
  }
}

// nlohmann keeps the last of a repeated key: a hand-edited file's first setting was lost without
// a word. The first repeat is named with the keys that lead to it; arrays' objects are their own.
TEST(JsonKeys, ARepeatedKeyIsNamedWithItsPath) {
  EXPECT_EQ(repeatedJsonKey(R"({"a": 1, "b": {"c": 2}})"), "");
  EXPECT_EQ(repeatedJsonKey(R"({"a": 1, "a": 2})"), "a");
  EXPECT_EQ(repeatedJsonKey(R"({"stages": {"render": {"scale": 0.2}, "render": {}}})"),
            "stages.render");
  EXPECT_EQ(repeatedJsonKey(R"({"s": {"r": {"scale": 0.2, "x": 1, "scale": 0.5}}})"), "s.r.scale");
  EXPECT_EQ(repeatedJsonKey(R"({"v": [{"f": 1}, {"f": 2}], "w": [{"f": 1, "f": 2}]})"), "w[].f");
  EXPECT_EQ(repeatedJsonKey("{not json"), "");
}

}  // namespace compose
