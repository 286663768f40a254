// Constants shared by the numeric code.
#pragma once

#include <cstdio>
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

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kDegrees = kPi / 180.0;  // radians per degree

}  // namespace compose
