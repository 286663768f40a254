// The exact reference: irradiance by brute-force quadrature over every texel of the environment,
//   E(n) = Σ_texels L_t max(0, n·ω_t) Ω_t,
// with ω_t the texel centre and Ω_t its exact solid angle. No truncation and no noise: this is the
// gold standard for the discrete map (unshadowed). It costs O(texels) per query, so it is meant
// for references and tests, not for rendering whole frames.
#pragma once

#include <vector>

#include "lighting/lighting.h"

namespace compose::lighting {

class ExactLighting final : public DiffuseLighting {
 public:
  std::string name() const override { return "exact"; }
  std::string describe() const override;
  void project(const Environment& environment, const Progress& progress = {}) override;
  glm::vec3 irradiance(const glm::vec3& n) const override;
  int coefficientsPerChannel() const override { return int(directions_.size()); }
  size_t floatsStored() const override { return directions_.size() * 6; }

 private:
  std::vector<glm::vec3> directions_;  // texel centres, texels with zero radiance dropped
  std::vector<glm::vec3> weighted_;    // L_t Ω_t
};

}  // namespace compose::lighting
