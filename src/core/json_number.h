// Whole numbers from JSON without undefined behaviour.
//
// nlohmann::json converts any number to any arithmetic type: get<int>() of 3e39 is a
// floating-point conversion out of range (undefined behaviour), of 2^40 a silent wrap, of 1.5 a
// silent truncation. Our readers take a whole number only when it is one, within the range they
// can use.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

namespace compose {

// `j` as a whole number within [lo, hi]: an integer, or a floating-point number with no
// fractional part (JSON writers differ: 3 or 3.0). Empty for anything else.
inline std::optional<int64_t> wholeNumber(const nlohmann::json& j,
                                          int64_t lo = std::numeric_limits<int>::min(),
                                          int64_t hi = std::numeric_limits<int>::max()) {
  if (j.is_number_unsigned()) {
    const uint64_t v = j.get<uint64_t>();
    if (v > uint64_t(std::numeric_limits<int64_t>::max()) || int64_t(v) > hi || int64_t(v) < lo)
      return std::nullopt;
    return int64_t(v);
  }
  if (j.is_number_integer()) {
    const int64_t v = j.get<int64_t>();
    if (v < lo || v > hi) return std::nullopt;
    return v;
  }
  if (j.is_number_float()) {
    const double d = j.get<double>();
    // Range first (as doubles: lo and hi are exact enough at the ends that matter), then whole.
    if (!std::isfinite(d) || d < double(lo) || d > double(hi) || d != std::floor(d))
      return std::nullopt;
    return int64_t(d);
  }
  return std::nullopt;
}

// The member `key` of object `j` the same way; empty when it is missing or not such a number.
inline std::optional<int64_t> wholeMember(const nlohmann::json& j, const char* key,
                                          int64_t lo = std::numeric_limits<int>::min(),
                                          int64_t hi = std::numeric_limits<int>::max()) {
  if (!j.is_object()) return std::nullopt;
  const auto it = j.find(key);
  if (it == j.end()) return std::nullopt;
  return wholeNumber(*it, lo, hi);
}

// nlohmann::json's message for a user: without its "[json.exception.parse_error.101]" tag and
// its "syntax error while parsing value -" preamble; an empty file said plainly; NaN and Infinity
// (which Python's json.dumps writes, and JSON does not have) named as the likely cause.
inline std::string jsonMessage(std::string_view what) {
  std::string text(what);
  if (const size_t tag = text.find("[json.exception."); tag != std::string::npos) {
    const size_t close = text.find("] ", tag);
    if (close != std::string::npos) text.erase(tag, close + 2 - tag);
  }
  if (text.find("attempting to parse an empty input") != std::string::npos ||
      text.find("line 1, column 1: syntax error while parsing value - unexpected end of input") !=
          std::string::npos)
    return "the file is empty";
  for (const char* preamble :
       {"syntax error while parsing value - ", "syntax error while parsing object - ",
        "syntax error while parsing array - "}) {
    const size_t at = text.find(preamble);
    if (at != std::string::npos) text.erase(at, std::string_view(preamble).size());
  }
  const size_t last = text.find("last read: '");
  if (text.find("invalid literal") != std::string::npos && last != std::string::npos) {
    // What was read up to the bad character: a value starting "N" or "I" was NaN or Infinity.
    const size_t close = text.rfind('\'');
    const char bad = close > last + 12 ? text[close - 1] : ' ';
    if (bad == 'N' || bad == 'I') text += " (JSON has no NaN or Infinity: write a finite number)";
  }
  return text;
}

}  // namespace compose
