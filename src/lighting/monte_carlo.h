// The Monte Carlo gold standard ("mc"): irradiance by importance sampling, with optional
// visibility.
//
//   E(n) = ∫ L(ω) max(0, n·ω) V(ω) dω
//
// estimated from `samples` directions per query: half drawn from the environment (a piecewise-
// constant distribution proportional to luminance × texel solid angle), half from the cosine lobe
// around n, combined with multiple importance sampling (balance heuristic); the first dimension of
// each technique is stratified. The derivation and the references are in monte_carlo.cpp.
//
// What it integrates: the environment as a piecewise-constant function, each texel constant over
// its whole lat-long cell (the same function ExactLighting sums, except that ExactLighting takes
// the cosine at the texel centre). The estimate is unbiased: a constant map of radiance 1 gives
// E = π up to sampling noise, and the noise falls as 1/sqrt(samples) (3 dB of SNR per doubling).
//
// Units: irradiance() and estimate() return IRRADIANCE (no 1/π), like every DiffuseLighting.
//
// Determinism and threading: the random stream of a query depends only on the seed and the bits
// of the normal, so the same (seed, n, samples) gives the same result on any thread, in any order,
// on any run. After project(), every query is const and may run concurrently. A visibility
// callback must itself be safe to call concurrently if queries are.
//
// Storage: the basis keeps the map itself (RGB float per texel) and its sampling tables, so
// coefficientsPerChannel() is 0 (there is no truncated coefficient vector; the per-query cost is
// samples()) and floatsStored() counts everything kept: 3 floats per texel, plus the marginal
// (H+1) and conditional (H×(W+1)) CDFs and the H+1 row edges, all double (2 floats each).
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "lighting/lighting.h"

namespace compose::lighting {

inline constexpr int kMaxMcSamples = 1 << 24;  // 16777216

class MonteCarloLighting final : public DiffuseLighting {
 public:
  // Returns true if direction (unit, world space, pointing away from the surface) reaches the
  // environment. Only called for directions that would contribute (cosine and radiance > 0).
  using VisibilityFn = std::function<bool(const glm::vec3& direction)>;

  // samples in 1..kMaxMcSamples, else compose::Error (stage "lighting").
  MonteCarloLighting(int samples, uint64_t seed);

  std::string name() const override { return "mc"; }
  // e.g. "mc samples=1024 (env+cosine MIS)".
  std::string describe() const override;

  // Copies the radiance and builds the sampling tables. An all-zero map is valid (E = 0).
  void project(const Environment& environment, const Progress& progress = {}) override;

  // Unshadowed irradiance at unit normal n with samples() samples.
  glm::vec3 irradiance(const glm::vec3& n) const override;
  using DiffuseLighting::irradiance;  // the view-dependent form, not hidden by the one below
  // Irradiance counting only directions for which visible(direction) is true.
  glm::vec3 irradiance(const glm::vec3& n, const VisibilityFn& visible) const;
  // The same estimator with another sample count (1..kMaxMcSamples, else compose::Error); no
  // visibility when `visible` is null. n need not be exactly unit length (it is normalised).
  glm::vec3 estimate(const glm::vec3& n, int samples, const VisibilityFn* visible = nullptr) const;

  int coefficientsPerChannel() const override { return 0; }
  size_t floatsStored() const override;

  int samples() const { return samples_; }
  uint64_t seed() const { return seed_; }

 private:
  int samples_;
  uint64_t seed_;
  int width_ = 0, height_ = 0;
  bool projected_ = false;
  std::vector<float> radiance_;  // RGB, row-major, as in the environment
  std::vector<double> zEdge_;    // sin(latitude) at row edges: zEdge_[y] top, zEdge_[y+1] bottom
  std::vector<double> rowCdf_;   // marginal over rows, H+1 entries, 0 .. 1
  std::vector<double> colCdf_;   // conditional over columns, per row W+1 entries, 0 .. 1
  double invTotal_ = 0.0;        // 1 / Σ luminance·Ω; 0 for an all-zero map

  glm::vec3 texel(int x, int y) const {
    const float* p = radiance_.data() + (size_t(y) * size_t(width_) + size_t(x)) * 3;
    return {p[0], p[1], p[2]};
  }
};

}  // namespace compose::lighting
