// Small numeric helpers for hot loops.
#pragma once

#include <algorithm>
#include <cmath>

namespace compose {

// atan2 to float precision without library calls: Abramowitz & Stegun 4.4.49 (|error| <= 2e-8
// on [0, 1]) plus octant folding. Used on the hot paths that locate a direction on a grid.
inline float fastAtan2(float y, float x) {
  const float ax = std::abs(x), ay = std::abs(y);
  const float mx = std::max(ax, ay), mn = std::min(ax, ay);
  if (mx == 0.0f) return 0.0f;
  const float a = mn / mx, s = a * a;
  float r =
      a *
      (1.0f +
       s * (-0.3333314528f +
            s * (0.1999355085f +
                 s * (-0.1420889944f +
                      s * (0.1065626393f + s * (-0.0752896400f +
                                                s * (0.0429096138f + s * (-0.0161657367f +
                                                                          s * 0.0028662257f))))))));
  if (ay > ax) r = 1.57079637f - r;
  if (x < 0.0f) r = 3.14159274f - r;
  return y < 0.0f ? -r : r;
}

}  // namespace compose
