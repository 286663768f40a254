// Synthetic environments for the lighting tests.
#pragma once

#include <algorithm>
#include <cmath>

#include <glm/vec3.hpp>

#include "lighting/environment.h"

namespace compose::testing {

// A width x width/2 map whose texels hold radiance(direction of the texel centre); `edit` may then
// change single texels.
template <class F, class G>
lighting::Environment makeEnvironment(int width, F radiance, G edit) {
  const lighting::Environment probe = lighting::Environment::constant(glm::vec3(0.0f), width);
  Image img(width, width / 2, 3);
  for (int y = 0; y < img.height; ++y) {
    for (int x = 0; x < img.width; ++x) {
      const glm::vec3 L = radiance(probe.direction(x, y));
      img.at(x, y)[0] = L.x;
      img.at(x, y)[1] = L.y;
      img.at(x, y)[2] = L.z;
    }
  }
  edit(img);
  return lighting::Environment::fromLatLong(img);
}

template <class F>
lighting::Environment analyticEnvironment(int width, F radiance) {
  return makeEnvironment(width, radiance, [](Image&) {});
}

// The largest relative difference of a channel of a from b's.
inline double worstRelative(const glm::dvec3& a, const glm::dvec3& b) {
  double worst = 0.0;
  for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(a[c] - b[c]) / std::abs(b[c]));
  return worst;
}

}  // namespace compose::testing
