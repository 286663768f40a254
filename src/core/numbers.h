// Constants shared by the numeric code.
#pragma once

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>
#include <string>

namespace compose {

// A number as a person writes it ("0.5", "1e+308"), not std::to_string's "0.500000", for
// messages.
inline std::string numberText(double value) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", value);
  return text;
}

// A value the user gave, as it reads back exactly: the shortest of %.6g .. %.17g that does, so
// that a range error does not say "must be at most 10, got 10" of 10.0000001.
inline std::string givenText(double value) {
  char text[32];
  for (int digits = 6; digits <= 17; ++digits) {
    std::snprintf(text, sizeof text, "%.*g", digits, value);
    if (!std::isfinite(value) || std::strtod(text, nullptr) == value) break;
  }
  return text;
}

// The sRGB transfer function (IEC 61966-2-1): a code in 0..1 to linear light, and back.
inline double srgbDecode(double code) {
  return code <= 0.04045 ? code / 12.92 : std::pow((code + 0.055) / 1.055, 2.4);
}
inline double srgbEncode(double linear) {
  return linear <= 0.0031308 ? 12.92 * linear : 1.055 * std::pow(linear, 1.0 / 2.4) - 0.055;
}

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kDegrees = kPi / 180.0;  // radians per degree

}  // namespace compose
