// The exact reference: irradiance by brute-force quadrature over every texel of the environment,
//   E(n) = Σ_texels L_t max(0, n·ω_t) Ω_t,
// with ω_t the texel centre and Ω_t its exact solid angle. No truncation and no noise: this is the
// gold standard for the discrete map (unshadowed). The sum is evaluated through RadianceCells
// (whole coarse cells above the horizon in closed form, texels only along the horizon), which
// gives the same number up to rounding at about 1/20 of the brute-force cost; it is still meant
// for references and tests, not for rendering whole frames.
#pragma once

#include <vector>

#include "lighting/lighting.h"
#include "lighting/radiance_cells.h"

namespace compose::lighting {

class ExactLighting final : public DiffuseLighting {
 public:
  std::string name() const override { return "exact"; }
  std::string describe() const override;
  void project(const Environment& environment, const Progress& progress = {}) override;
  glm::vec3 irradiance(const glm::vec3& n) const override;
  int coefficientsPerChannel() const override { return int(cells_.cellCount()); }
  size_t floatsStored() const override { return cells_.floatsStored(); }

 private:
  RadianceCells cells_;
};

// The Oren–Nayar counterpart of the exact reference: π L_o / ρ seen from unit direction `view`,
// by brute force over every texel (texel centres), with the BRDF evaluated per texel in the same
// local frame as ChebLocalLighting (east = ∂n/∂φ, north = n x east). O(texels) per call.
glm::dvec3 orenNayarReference(const Environment& environment, double sigma, const glm::vec3& n,
                              const glm::vec3& view);

}  // namespace compose::lighting
