#include "lighting/exact.h"

#include "core/error.h"

namespace compose::lighting {

std::string ExactLighting::describe() const {
  return "exact (quadrature over " + std::to_string(directions_.size()) + " non-zero texels)";
}

void ExactLighting::project(const Environment& env, const Progress& progress) {
  directions_.clear();
  weighted_.clear();
  for (int y = 0; y < env.height(); ++y) {
    const double omega = env.rowSolidAngle(y);
    for (int x = 0; x < env.width(); ++x) {
      const glm::vec3 L = env.radiance(x, y);
      if (L.x == 0.0f && L.y == 0.0f && L.z == 0.0f) continue;
      directions_.push_back(env.direction(x, y));
      weighted_.push_back(glm::vec3(glm::dvec3(L) * omega));
    }
    if (y % 64 == 0) report(progress, "lighting", double(y) / env.height());
  }
  report(progress, "lighting", 1.0);
}

glm::vec3 ExactLighting::irradiance(const glm::vec3& n) const {
  glm::dvec3 e(0.0);
  for (size_t i = 0; i < directions_.size(); ++i) {
    const glm::vec3& d = directions_[i];
    const float c = n.x * d.x + n.y * d.y + n.z * d.z;
    if (c > 0.0f) e += glm::dvec3(weighted_[i]) * double(c);
  }
  return glm::vec3(e);
}

}  // namespace compose::lighting
