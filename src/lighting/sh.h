// Real spherical harmonics up to band 8, and the Ramamoorthi–Hanrahan irradiance environment map
// ("An Efficient Representation for Irradiance Environment Maps", SIGGRAPH 2001).
//
// The SH frame has its pole on world +Y: (x_sh, y_sh, z_sh) = (z_w, x_w, y_w), a cyclic (so
// right-handed) relabelling of the world axes. The basis is orthonormal over the sphere, without
// the Condon–Shortley phase. Coefficients are indexed l(l+1)+m.
#pragma once

#include <array>
#include <vector>

#include "lighting/lighting.h"

namespace compose::lighting {

inline constexpr int kMaxShOrder = 8;
inline constexpr int shCount(int order) {
  return (order + 1) * (order + 1);
}

// Evaluates all Y_lm, l ≤ order, at unit world direction d into `out` (size ≥ shCount(order)).
void evalSh(int order, const glm::vec3& d, float* out);
void evalSh(int order, const glm::dvec3& d, double* out);

// Ramamoorthi–Hanrahan convolution weight A_l of the clamped cosine: E_lm = A_l L_lm.
double shCosineLobe(int l);

// Optional windowing (deringing) of the irradiance bands, reported separately from raw SH: each
// band l is scaled by w_l before evaluation. "hanning": w_l = (1 + cos(π l / (L + 1))) / 2;
// "lanczos": w_l = sinc(l / (L + 1)). A window damps the higher bands (less overshoot in the
// reconstruction) at a cost in accuracy; it does not guarantee non-negative irradiance.
enum class ShWindow { None, Hanning, Lanczos };

class ShLighting final : public DiffuseLighting {
 public:
  explicit ShLighting(int order, ShWindow window = ShWindow::None);

  std::string name() const override { return "sh"; }
  // w_l for this basis' order and window.
  double windowWeight(int l) const;
  std::string describe() const override;
  void project(const Environment& environment, const Progress& progress = {}) override;
  glm::vec3 irradiance(const glm::vec3& n) const override;
  int coefficientsPerChannel() const override { return shCount(order_); }
  size_t floatsStored() const override { return size_t(3 * shCount(order_)); }

  // The projection for the caches and lighting files: the irradiance coefficients as evaluated,
  // then each radiance coefficient as three floats whose sum is the double (SH transfer reads
  // them in double).
  bool exportState(std::vector<float>& out) const override;
  bool importState(std::span<const float> in) override;

  // Radiance coefficients L_lm per channel (double), after project().
  const std::vector<glm::dvec3>& radianceCoefficients() const { return radiance_; }

 private:
  int order_;
  ShWindow window_;
  std::vector<glm::dvec3> radiance_;   // L_lm
  std::vector<glm::vec3> irradiance_;  // A_l L_lm, float for evaluation
};

}  // namespace compose::lighting
