#include "lighting/monte_carlo.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <numbers>
#include <string>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::lighting {

// Derivation
// ----------
// Integrand: f(ω) = L(ω) max(0, n·ω) V(ω), L piecewise constant over the lat-long cells.
//
// Technique e (environment). Texel t = (x, y) gets weight w_t = Y(L_t) Ω_y, with Y the Rec. 709
// luminance and Ω_y = Δφ (z_top − z_bottom) the exact cell solid angle, z = sin(latitude). A row is
// drawn from the marginal CDF Σ_x w_t, then a column from the row's conditional CDF (pbrt-v3
// §13.6.7, "Piecewise-Constant 2D Distributions"). Inside the cell the direction is uniform in z
// and in longitude: since dω = dz dφ, that is uniform in solid angle, so
//   p_e(ω) = (w_t / W) / Ω_y = Y(L_t) / W,    W = Σ_t w_t,
// exactly, for every ω in cell t. (pbrt's infinite light samples uniformly in the angles and
// divides by sin θ at the sample, §14.2.4; sampling in z removes that factor and makes the density
// match the piecewise-constant integrand cell by cell.) Any positive luminance weights give an
// unbiased estimator, whatever the working colour space; only the variance depends on them.
//
// Technique c (cosine lobe). Malley's method (pbrt-v3 §13.6.3): a uniform point on the unit disc
// lifted to the hemisphere around n, p_c(ω) = max(0, n·ω) / π. The frame around n is the
// branchless one of Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 6(1), 2017.
//
// Combination (Veach 1997, PhD thesis, ch. 9, "multi-sample model"; pbrt-v3 §13.10.1): with n_e
// samples X_i ~ p_e and n_c samples Y_j ~ p_c, and the balance heuristic
//   w_s(ω) = n_s p_s(ω) / (n_e p_e(ω) + n_c p_c(ω)),
// the estimator
//   F = Σ_s (1/n_s) Σ_k w_s f / p_s = Σ_{all samples} f(ω) / (n_e p_e(ω) + n_c p_c(ω))
// is unbiased provided n_e p_e + n_c p_c > 0 wherever f ≠ 0. The cosine technique alone covers the
// whole upper hemisphere; the environment technique covers every texel with L ≠ 0 (Y > 0 there),
// so the estimator stays unbiased for n_c = 0 (samples = 1) as well. Balance weights are provably
// close to optimal (Veach Thm. 9.2): a small bright sun is found by technique e (its share of W),
// broad dim sky near the normal by technique c, and no sample pays for a tiny pdf twice.
// Split: n_e = ceil(N/2), n_c = floor(N/2).
//
// Stratification. In each technique the first random number is jittered: sample k of n_s draws it
// from [k, k+1)/n_s (pbrt-v3 §7.3). For technique e that number picks the row through the marginal
// CDF, i.e. decides between sun and sky; for technique c it is the squared disc radius, i.e. the
// cosine. Each sample then follows p_s only inside its stratum, but the strata partition [0, 1),
// so E[F] is unchanged (the estimator stays unbiased, with the same MIS weights), and with one
// sample per equal stratum the variance never exceeds the i.i.d. one (pbrt-v3 §13.8.1). It removes
// the binomial noise in how many samples land on a small bright source: ~10 dB of SNR at equal
// cost on the sun map of the tests. The rest of the noise (the other dimensions) is still O(1/N),
// so the SNR rises by 3 dB per doubling of N.
//
// For a constant map, with c = n·ω, each sample adds
//   f / (n_e p_e + n_c p_c) = (2/N) c⁺ / (1/(4π) + c⁺/π) ≤ 8π/(5N);
// the test derives the i.i.d. standard deviation from it, an upper bound for this estimator.
//
// Randomness: PCG32 (O'Neill 2014), seeded by splitmix64 (Steele et al. 2014) hashes of the seed
// and the three float bit patterns of n.

namespace {

constexpr float kPiF = std::numbers::pi_v<float>;
constexpr double kBelowOne = 0x1.fffffffffffffp-1;  // largest double < 1
constexpr float kBelowOneF = 0x1.fffffep-1f;

constexpr double luminance(double r, double g, double b) {
  return 0.2126 * r + 0.7152 * g + 0.0722 * b;
}

constexpr uint64_t splitmix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

class Pcg32 {
 public:
  Pcg32(uint64_t seed, uint64_t stream) : inc_((stream << 1u) | 1u) {
    next();
    state_ += seed;
    next();
  }
  uint32_t next() {
    const uint64_t old = state_;
    state_ = old * 6364136223846793005ULL + inc_;
    const auto shifted = uint32_t(((old >> 18u) ^ old) >> 27u);
    const auto rot = uint32_t(old >> 59u);
    return (shifted >> rot) | (shifted << ((0u - rot) & 31u));
  }
  // Uniform in [0, 1).
  float uniformFloat() { return float(next() >> 8) * 0x1p-24f; }
  double uniformDouble() {
    const uint64_t hi = next() >> 5, lo = next() >> 6;  // 27 + 26 = 53 bits
    return double((hi << 26) | lo) * 0x1p-53;
  }

 private:
  uint64_t state_ = 0;
  uint64_t inc_;
};

Pcg32 streamFor(uint64_t seed, const glm::vec3& n) {
  const uint64_t xy =
      uint64_t(std::bit_cast<uint32_t>(n.x)) | (uint64_t(std::bit_cast<uint32_t>(n.y)) << 32);
  const uint64_t z = std::bit_cast<uint32_t>(n.z);
  const uint64_t h = splitmix64(splitmix64(splitmix64(seed) ^ xy) ^ z);
  return Pcg32(h, splitmix64(h ^ 0x6a09e667f3bcc909ULL));
}

// Index i with cdf[i] <= u < cdf[i+1]; cdf has count+1 entries from 0 to 1 and u is in [0, 1), so
// intervals of zero width are never chosen.
int sampleCdf(const double* cdf, int count, double u) {
  const double* it = std::upper_bound(cdf, cdf + count + 1, u);
  return std::clamp(int(it - cdf) - 1, 0, count - 1);
}

void validateSamples(int samples) {
  if (samples < 1 || samples > kMaxMcSamples) {
    throw Error("lighting", "mc samples must be in 1.." + std::to_string(kMaxMcSamples) + ", got " +
                                std::to_string(samples));
  }
}

}  // namespace

MonteCarloLighting::MonteCarloLighting(int samples, uint64_t seed)
    : samples_(samples), seed_(seed) {
  validateSamples(samples);
}

std::string MonteCarloLighting::describe() const {
  return "mc samples=" + std::to_string(samples_) + " (env+cosine MIS)";
}

size_t MonteCarloLighting::floatsStored() const {
  return radiance_.size() + 2 * (zEdge_.size() + rowCdf_.size() + colCdf_.size());
}

void MonteCarloLighting::project(const Environment& env, const Progress& progress) {
  const int w = env.width(), h = env.height();
  COMPOSE_CHECK(w > 0 && h > 0);
  width_ = w;
  height_ = h;
  radiance_.resize(size_t(w) * size_t(h) * 3);
  zEdge_.resize(size_t(h) + 1);
  for (int y = 0; y <= h; ++y) zEdge_[size_t(y)] = std::sin(kPi * (0.5 - double(y) / h));
  zEdge_[0] = 1.0;
  zEdge_[size_t(h)] = -1.0;
  const double dPhi = 2.0 * kPi / w;

  // Per row: copy the radiance, build the conditional CDF over luminance (the solid angle is the
  // same along a row) and the row's weight Σ_x Y Ω.
  colCdf_.assign(size_t(h) * size_t(w + 1), 0.0);
  std::vector<double> rowWeight(size_t(h), 0.0);
  parallelFor(0, h, [&](int64_t yy) {
    const int y = int(yy);
    double* cdf = colCdf_.data() + size_t(y) * size_t(w + 1);
    double sum = 0.0;
    for (int x = 0; x < w; ++x) {
      const glm::vec3 L = env.radiance(x, y);
      float* dst = radiance_.data() + (size_t(y) * size_t(w) + size_t(x)) * 3;
      dst[0] = L.x;
      dst[1] = L.y;
      dst[2] = L.z;
      sum += luminance(L.x, L.y, L.z);
      cdf[x + 1] = sum;
    }
    if (sum > 0.0) {
      for (int x = 1; x < w; ++x) cdf[x] /= sum;
    } else {
      for (int x = 1; x < w; ++x) cdf[x] = double(x) / w;  // never drawn: the row has weight 0
    }
    cdf[w] = 1.0;
    rowWeight[size_t(y)] = sum * dPhi * (zEdge_[size_t(y)] - zEdge_[size_t(y) + 1]);
  });
  report(progress, "lighting", 0.5);

  rowCdf_.assign(size_t(h) + 1, 0.0);
  double total = 0.0;
  for (int y = 0; y < h; ++y) {
    total += rowWeight[size_t(y)];
    rowCdf_[size_t(y) + 1] = total;
  }
  if (total > 0.0) {
    for (int y = 1; y < h; ++y) rowCdf_[size_t(y)] /= total;
    invTotal_ = 1.0 / total;
  } else {
    for (int y = 1; y < h; ++y) rowCdf_[size_t(y)] = double(y) / h;
    invTotal_ = 0.0;
  }
  rowCdf_[size_t(h)] = 1.0;
  projected_ = true;
  report(progress, "lighting", 1.0);
}

glm::vec3 MonteCarloLighting::irradiance(const glm::vec3& n) const {
  return estimate(n, samples_);
}

glm::vec3 MonteCarloLighting::irradiance(const glm::vec3& n, const VisibilityFn& visible) const {
  return estimate(n, samples_, &visible);
}

glm::vec3 MonteCarloLighting::estimate(const glm::vec3& nIn, int samples,
                                       const VisibilityFn* visible) const {
  validateSamples(samples);
  COMPOSE_CHECK(projected_);
  const float len = std::sqrt(nIn.x * nIn.x + nIn.y * nIn.y + nIn.z * nIn.z);
  COMPOSE_CHECK(len > 0.0f && std::isfinite(len));
  if (invTotal_ == 0.0) return glm::vec3(0.0f);  // all-zero map
  const glm::vec3 n = nIn / len;

  Pcg32 rng = streamFor(seed_, nIn);
  const int nEnv = (samples + 1) / 2, nCos = samples - nEnv;
  const double cEnv = nEnv, cCos = double(nCos) / kPi;  // n_e, n_c/π
  const float dPhi = 2.0f * kPiF / float(width_);
  glm::dvec3 sum(0.0);

  // Adds f / (n_e p_e + n_c p_c) for a direction d in texel (x, y) with cosine c > 0.
  auto accumulate = [&](const glm::vec3& d, int x, int y, float c) {
    const glm::vec3 L = texel(x, y);
    const double lum = luminance(L.x, L.y, L.z);
    if (lum <= 0.0) return;
    if (visible && !(*visible)(d)) return;
    const double denom = cEnv * lum * invTotal_ + cCos * double(c);
    sum += glm::dvec3(L) * (double(c) / denom);
  };

  // Samples go in batches: first every direction and its texel (prefetching the texel), then the
  // contributions, in sample order. The radiance lookups are scattered over megabytes, and this
  // lets their cache misses overlap.
  constexpr int kBatch = 32;
  struct Pending {
    glm::vec3 d;
    float c;
    int x, y;
  };
  std::array<Pending, kBatch> batch;
  auto flush = [&](int count) {
    for (int k = 0; k < count; ++k) {
      const Pending& p = batch[size_t(k)];
      if (p.c > 0.0f) accumulate(p.d, p.x, p.y, p.c);
    }
  };
  auto prefetch = [&](int x, int y) {
    __builtin_prefetch(radiance_.data() + (size_t(y) * size_t(width_) + size_t(x)) * 3);
  };

  for (int i0 = 0; i0 < nEnv; i0 += kBatch) {
    const int count = std::min(kBatch, nEnv - i0);
    for (int k = 0; k < count; ++k) {
      const double u0 = std::min((double(i0 + k) + rng.uniformDouble()) / cEnv, kBelowOne);
      const double u1 = rng.uniformDouble();
      const float u2 = rng.uniformFloat(), u3 = rng.uniformFloat();
      const int y = sampleCdf(rowCdf_.data(), height_, u0);
      const int x = sampleCdf(colCdf_.data() + size_t(y) * size_t(width_ + 1), width_, u1);
      prefetch(x, y);
      const double zTop = zEdge_[size_t(y)], zBottom = zEdge_[size_t(y) + 1];
      const float z = float(zBottom + double(u2) * (zTop - zBottom));
      const float phi = kPiF * (1.0f - 2.0f * float(x) / float(width_)) - u3 * dPhi;
      const float r = std::sqrt(std::max(0.0f, 1.0f - z * z));
      const glm::vec3 d(std::sin(phi) * r, z, std::cos(phi) * r);
      batch[size_t(k)] = {d, n.x * d.x + n.y * d.y + n.z * d.z, x, y};
    }
    flush(count);
  }

  if (nCos > 0) {
    // Frame (t, b, n) after Duff et al. 2017.
    const float sign = std::copysign(1.0f, n.z);
    const float a = -1.0f / (sign + n.z);
    const float bxy = n.x * n.y * a;
    const glm::vec3 t(1.0f + sign * n.x * n.x * a, sign * bxy, -sign * n.x);
    const glm::vec3 b(bxy, sign + n.y * n.y * a, -n.y);
    for (int j0 = 0; j0 < nCos; j0 += kBatch) {
      const int count = std::min(kBatch, nCos - j0);
      for (int k = 0; k < count; ++k) {
        const float u0 =
            std::min(float((double(j0 + k) + rng.uniformDouble()) / double(nCos)), kBelowOneF);
        const float u1 = rng.uniformFloat();
        const float c = std::sqrt(1.0f - u0);
        const float rd = std::sqrt(u0), phi = 2.0f * kPiF * u1;
        const glm::vec3 d = t * (rd * std::cos(phi)) + b * (rd * std::sin(phi)) + n * c;
        const float lat = std::asin(std::clamp(d.y, -1.0f, 1.0f));
        const float lon = std::atan2(d.x, d.z);
        const int y = std::clamp(int((0.5f - lat / kPiF) * float(height_)), 0, height_ - 1);
        const int x = std::clamp(int((1.0f - lon / kPiF) * 0.5f * float(width_)), 0, width_ - 1);
        prefetch(x, y);
        batch[size_t(k)] = {d, c, x, y};
      }
      flush(count);
    }
  }
  return glm::vec3(sum);
}

}  // namespace compose::lighting
