#include "lighting/exact.h"

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

}  // namespace compose::lighting
