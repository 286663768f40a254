// Small meshes built in code for the render tests.
#pragma once

#include <cmath>
#include <numbers>

#include "render/mesh.h"

namespace compose::render::testing {

// A UV sphere of radius 1 about the origin with exact normals (its lowest point is y = -1).
inline Mesh uvSphere(int rings, int segments) {
  Mesh m;
  for (int r = 0; r <= rings; ++r) {
    const double theta = std::numbers::pi * r / rings;
    for (int s = 0; s <= segments; ++s) {
      const double phi = 2.0 * std::numbers::pi * s / segments;
      const glm::vec3 p(float(std::sin(theta) * std::cos(phi)), float(std::cos(theta)),
                        float(std::sin(theta) * std::sin(phi)));
      m.positions.push_back(p);
      m.normals.push_back(p);
    }
  }
  const int row = segments + 1;
  for (int r = 0; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      const uint32_t a = uint32_t(r * row + s), b = a + 1, c = a + uint32_t(row), d = c + 1;
      m.indices.insert(m.indices.end(), {a, b, c, b, d, c});
    }
  }
  m.normalsFromFile = true;
  return m;
}

}  // namespace compose::render::testing
