#include "lighting/exact.h"

#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>

#include "lighting/chebyshev.h"

namespace compose::lighting {

std::string ExactLighting::describe() const {
  return "exact (quadrature over every texel, " + std::to_string(cells_.cellCount()) + " cells)";
}

void ExactLighting::project(const Environment& env, const Progress& progress) {
  cells_ = RadianceCells(env);
  report(progress, "lighting", 1.0);
}

glm::vec3 ExactLighting::irradiance(const glm::vec3& n) const {
  return glm::vec3(cells_.irradiance(n));
}

glm::dvec3 orenNayarReference(const Environment& env, double sigma, const glm::vec3& n,
                              const glm::vec3& view) {
  const float h = std::sqrt(n.x * n.x + n.z * n.z);
  const glm::vec3 east = h > 1e-6f ? glm::vec3(n.z / h, 0.0f, -n.x / h) : glm::vec3(1, 0, 0);
  const glm::vec3 north = glm::cross(n, east);
  const double thetaOut = std::acos(std::clamp(double(glm::dot(n, view)), 0.0, 1.0));
  const double phiOut = std::atan2(double(glm::dot(north, view)), double(glm::dot(east, view)));
  glm::dvec3 e(0.0);
  for (int y = 0; y < env.height(); ++y) {
    for (int x = 0; x < env.width(); ++x) {
      const glm::vec3 w = env.direction(x, y);
      const double c = glm::dot(n, w);
      if (c <= 0.0) continue;
      const double phiIn = std::atan2(double(glm::dot(north, w)), double(glm::dot(east, w)));
      const double f =
          ChebLocalLighting::orenNayar(sigma, std::acos(std::min(c, 1.0)), phiIn, thetaOut, phiOut);
      e += glm::dvec3(env.radiance(x, y)) * env.rowSolidAngle(y) * c * f;
    }
  }
  return e;
}

}  // namespace compose::lighting
