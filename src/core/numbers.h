// Constants shared by the numeric code.
#pragma once

#include <numbers>

namespace compose {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kDegrees = kPi / 180.0;  // radians per degree

}  // namespace compose
