#include "lighting/monte_carlo.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "core/parallel.h"
#include "environment_util.h"
#include "lighting/exact.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

using compose::testing::randomNormals;

using compose::testing::makeEnvironment;

void setTexel(Image& img, int x, int y, glm::vec3 L) {
  img.at(x, y)[0] = L.x;
  img.at(x, y)[1] = L.y;
  img.at(x, y)[2] = L.z;
}

bool finite(const glm::vec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

TEST(MonteCarlo, DescribesItselfAndCountsStorage) {
  MonteCarloLighting mc(1024, 7);
  EXPECT_EQ(mc.name(), "mc");
  EXPECT_EQ(mc.describe(), "mc samples=1024 (env+cosine MIS)");
  EXPECT_EQ(mc.coefficientsPerChannel(), 0);
  mc.project(Environment::constant(glm::vec3(1.0f), 64));
  // 3 floats per texel; marginal (33), conditional (32 x 65) and row edges (33) as doubles.
  EXPECT_EQ(mc.floatsStored(), size_t(64 * 32 * 3 + 2 * (33 + 32 * 65 + 33)));
}

TEST(MonteCarlo, RejectsInvalidSampleCounts) {
  COMPOSE_EXPECT_ERROR(MonteCarloLighting(0, 1),
                       "lighting: mc samples must be in 1..16777216, got 0");
  COMPOSE_EXPECT_ERROR(MonteCarloLighting(-5, 1), "mc samples must be in 1..16777216, got -5");
  COMPOSE_EXPECT_ERROR(MonteCarloLighting(16777217, 1),
                       "mc samples must be in 1..16777216, got 16777217");
  EXPECT_NO_THROW(MonteCarloLighting(1, 1));
  EXPECT_NO_THROW(MonteCarloLighting(kMaxMcSamples, 1));
  MonteCarloLighting mc(16, 1);
  mc.project(Environment::constant(glm::vec3(1.0f), 16));
  COMPOSE_EXPECT_ERROR(mc.estimate(glm::vec3(0, 1, 0), 0),
                       "mc samples must be in 1..16777216, got 0");
  EXPECT_TRUE(finite(mc.estimate(glm::vec3(0, 1, 0), 1)));  // n_c = 0: environment sampling alone
}

// White furnace. For a constant map of radiance 1, p_e = 1/(4π) everywhere and p_c = c⁺/π with
// c = n·ω, so each sample adds g(c) = c⁺ / (n_e/(4π) + n_c c⁺/π). Under p_e, c is uniform on
// [−1, 1]; under p_c it has density 2c on [0, 1]. With i.i.d. samples the variance would be
//   σ² = n_e Var_e[g] + n_c Var_c[g],
// computed here by quadrature. The estimator stratifies one dimension per technique, which can only
// lower the variance, so σ is an upper bound. MC integrates every cell exactly (no midpoint error),
// so the expectation is π exactly and only noise remains.
TEST(MonteCarlo, WhiteFurnaceGivesPiWithinItsNoise) {
  constexpr int kSamples = 1024;
  constexpr int nEnv = kSamples / 2, nCos = kSamples / 2;
  auto g = [&](double c) { return c <= 0.0 ? 0.0 : c / (nEnv / (4.0 * kPi) + nCos * c / kPi); };
  double me = 0, me2 = 0, mc1 = 0, mc2 = 0;
  constexpr int kSteps = 200000;  // midpoint rule on smooth integrands: error far below 1e-6
  for (int i = 0; i < kSteps; ++i) {
    const double c = (i + 0.5) / kSteps, v = g(c);
    me += 0.5 * v / kSteps;  // density 1/2 on [0, 1] (g = 0 on [−1, 0])
    me2 += 0.5 * v * v / kSteps;
    mc1 += 2.0 * c * v / kSteps;
    mc2 += 2.0 * c * v * v / kSteps;
  }
  ASSERT_NEAR(nEnv * me + nCos * mc1, kPi, 1e-9);  // the estimator is unbiased
  const double sigma = std::sqrt(nEnv * (me2 - me * me) + nCos * (mc2 - mc1 * mc1));

  MonteCarloLighting mc(kSamples, 42);
  mc.project(Environment::constant(glm::vec3(1.0f), 64));
  const auto normals = randomNormals(400, 1);
  double sum = 0.0, sumSq = 0.0;
  for (const auto& n : normals) {
    const glm::vec3 e = mc.irradiance(n);
    ASSERT_EQ(e.x, e.y);  // grey map, one stream: the channels are identical
    ASSERT_EQ(e.x, e.z);
    // 4σ per normal: σ bounds the true std-dev, and 4σ is a one-in-16000 Gaussian event.
    EXPECT_NEAR(e.x, kPi, 4.0 * sigma);
    sum += e.x - kPi;
    sumSq += (e.x - kPi) * (e.x - kPi);
  }
  const double count = double(normals.size()), rms = std::sqrt(sumSq / count);
  // The mean over independent normals is 20x tighter: 4σ/√400.
  EXPECT_NEAR(sum / count, 0.0, 4.0 * sigma / std::sqrt(count));
  // The scatter stays below the i.i.d. σ: the sample RMS of 400 draws is within ±3.5% (1σ) of
  // the true std-dev, so 1.15 leaves over 4σ of slack.
  EXPECT_LT(rms, 1.15 * sigma);
  std::printf("white furnace, %d samples: i.i.d. sigma %.3g (%.3g%% of pi), measured rms %.3g\n",
              kSamples, sigma, 100 * sigma / kPi, rms);
}

// A single texel 1e5 times brighter than a dim grey sky: the sun holds ~95% of Σ luminance·Ω. The
// environment technique finds it; the cosine technique alone would hit it a couple of times in
// 4096 samples.
TEST(MonteCarlo, SunTexelConvergesToTheExactReference) {
  constexpr int kWidth = 128, kSunX = 40, kSunY = 22;
  const Environment env = makeEnvironment(
      kWidth, [](glm::vec3) { return glm::vec3(1.0f); },
      [&](Image& img) { setTexel(img, kSunX, kSunY, glm::vec3(1e5f, 0.9e5f, 0.8e5f)); });
  const glm::vec3 sun = env.direction(kSunX, kSunY);
  MonteCarloLighting mc(4096, 3);
  mc.project(env);
  ExactLighting exact;
  exact.project(env);

  // Nearest-texel lookup, as the estimator does, for the cosine-only comparison below.
  auto texelOf = [&](glm::vec3 d) {
    const double lat = std::asin(std::clamp(double(d.y), -1.0, 1.0)),
                 lon = std::atan2(double(d.x), double(d.z));
    const int y = std::clamp(int((0.5 - lat / kPi) * env.height()), 0, env.height() - 1);
    const int x = std::clamp(int((1.0 - lon / kPi) * 0.5 * env.width()), 0, env.width() - 1);
    return env.radiance(x, y);
  };
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> uni(0.0f, 1.0f);
  auto cosineOnly = [&](glm::vec3 n, int samples) {
    const glm::vec3 t = glm::normalize(
        glm::cross(std::abs(n.x) > 0.5f ? glm::vec3(0, 1, 0) : glm::vec3(1, 0, 0), n));
    const glm::vec3 b = glm::cross(n, t);
    glm::dvec3 sum(0.0);
    for (int i = 0; i < samples; ++i) {
      const float u = uni(rng), phi = float(2.0 * kPi) * uni(rng), r = std::sqrt(u);
      sum += glm::dvec3(
          texelOf(t * (r * std::cos(phi)) + b * (r * std::sin(phi)) + n * std::sqrt(1.0f - u)));
    }
    return glm::vec3(sum * (kPi / samples));
  };

  // The exact reference takes the cosine at the texel centre; MC integrates it over the cell. For
  // a sun texel straddling the horizon of n (|n·sun| below about half the 2.8° cell) the two
  // differ by up to an eighth of the cell's angular size relative to the sun term: a reference
  // error, not noise. Those normals are only checked for being finite.
  constexpr float kTerminatorBand = 0.1f;
  // Noise at 4096 samples: i.i.d. sampling would leave ~0.5% (the binomial count of sun hits among
  // 2048 environment samples at p ≈ 0.95; the sky is nearly constant); stratification brings it
  // to ~0.2% RMS. 3% ("a few %") is six times the i.i.d. figure.
  constexpr double kRelative = 0.03;
  double misSq = 0.0, cosSq = 0.0;
  int checked = 0;
  for (const auto& n : randomNormals(100, 4)) {
    const glm::vec3 e = mc.irradiance(n);
    ASSERT_TRUE(finite(e)) << n.x << " " << n.y << " " << n.z;
    if (std::abs(glm::dot(n, sun)) < kTerminatorBand) continue;
    const glm::vec3 ref = exact.irradiance(n);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(e[c], ref[c], kRelative * ref[c]) << "channel " << c;
    const glm::vec3 cos = cosineOnly(n, 4096);
    misSq += double(glm::dot(e - ref, e - ref)) / glm::dot(ref, ref);
    cosSq += double(glm::dot(cos - ref, cos - ref)) / glm::dot(ref, ref);
    ++checked;
  }
  ASSERT_GT(checked, 50);
  const double misRms = std::sqrt(misSq / checked), cosRms = std::sqrt(cosSq / checked);
  std::printf("sun, 4096 samples: rms relative error MIS %.3g%%, cosine-only %.3g%%\n",
              100 * misRms, 100 * cosRms);
  // Cosine sampling alone misses the sun most of the time (~95% RMS error against ~0.2%); ask
  // for a factor of ten.
  EXPECT_GT(cosRms, 10.0 * misRms);
}

// Smooth coloured sky plus a 2x2 sun (about half of Σ luminance·Ω), 64 normals. The error
// variance halves with each doubling of samples: +3.01 dB of SNR. Low sample counts average the
// noise power over several seeds (as many as keep 16384 samples per normal), so that every point
// has about the same statistical weight and the slope is not a matter of luck.
TEST(MonteCarlo, ConvergesAtThreeDecibelsPerDoubling) {
  constexpr int kWidth = 256;
  const Environment env = makeEnvironment(
      kWidth,
      [](glm::vec3 d) {
        const float s =
            0.6f + 0.4f * d.y + 0.15f * std::sin(3.0f * std::atan2(d.x, d.z)) * (1.0f - d.y * d.y);
        return glm::vec3(0.8f, 0.9f, 1.2f) * std::max(s, 0.05f);
      },
      [](Image& img) {
        for (int y = 30; y < 32; ++y)
          for (int x = 170; x < 172; ++x) setTexel(img, x, y, glm::vec3(5000.0f, 4600.0f, 4000.0f));
      });
  ExactLighting exact;
  exact.project(env);
  const auto normals = randomNormals(64, 9);
  std::vector<glm::vec3> ref(normals.size());
  double signal = 0.0;
  for (size_t i = 0; i < normals.size(); ++i) {
    ref[i] = exact.irradiance(normals[i]);
    signal += glm::dot(glm::dvec3(ref[i]), glm::dvec3(ref[i]));
  }

  std::vector<double> snr;
  const std::vector<int> counts = {256, 1024, 4096, 16384, 65536};
  for (int samples : counts) {
    const int repeats = std::max(1, 16384 / samples);
    double noise = 0.0;
    for (int r = 0; r < repeats; ++r) {
      MonteCarloLighting mc(samples, 1000 + uint64_t(r));
      mc.project(env);
      std::vector<double> err(normals.size());
      parallelFor(0, int64_t(normals.size()), [&](int64_t i) {
        const glm::dvec3 d =
            glm::dvec3(ref[size_t(i)]) - glm::dvec3(mc.irradiance(normals[size_t(i)]));
        err[size_t(i)] = glm::dot(d, d);
      });
      for (double e : err) noise += e / repeats;
    }
    snr.push_back(10.0 * std::log10(signal / noise));  // SNR_dB of DESIGN §4.3
    std::printf("convergence: %6d samples  SNR %.1f dB\n", samples, snr.back());
  }
  // 16x the samples is +12.0 dB in expectation; the SNR of 64 normals scatters by ~1 dB, so ask
  // for 9 dB (the brief's bound).
  constexpr double kMinGainFor16x = 9.0;
  EXPECT_GE(snr[2] - snr[0], kMinGainFor16x);
  EXPECT_GE(snr[4] - snr[2], kMinGainFor16x);
  // Each 4x step is +6.0 dB in expectation; [3, 9] rules out stalling (a bias floor, e.g. a pdf
  // that does not match the sampling) and faster-than-1/N behaviour (correlated samples).
  for (size_t i = 1; i < snr.size(); ++i) {
    EXPECT_GT(snr[i] - snr[i - 1], 3.0) << counts[i];
    EXPECT_LT(snr[i] - snr[i - 1], 9.0) << counts[i];
  }
  // The gold standard has to be good enough to judge the bases against (DESIGN §4.3).
  constexpr double kMinSnrAt65536 = 50.0;
  EXPECT_GE(snr.back(), kMinSnrAt65536);
}

TEST(MonteCarlo, IsDeterministicAndThreadSafe) {
  const Environment env = makeEnvironment(
      64, [](glm::vec3 d) { return glm::vec3(1.0f + d.x, 1.0f + d.y, 1.0f + d.z); }, [](Image&) {});
  MonteCarloLighting a(256, 99), b(256, 99), other(256, 100);
  a.project(env);
  b.project(env);
  other.project(env);
  const auto normals = randomNormals(256, 6);
  std::vector<glm::vec3> sequential(normals.size()), concurrent(normals.size());
  for (size_t i = 0; i < normals.size(); ++i) sequential[i] = a.irradiance(normals[i]);
  parallelFor(0, int64_t(normals.size()),
              [&](int64_t i) { concurrent[size_t(i)] = a.irradiance(normals[size_t(i)]); });
  int differentSeed = 0;
  for (size_t i = 0; i < normals.size(); ++i) {
    // Bitwise equality: same seed and normal bits, same stream, same order of summation.
    EXPECT_EQ(a.irradiance(normals[i]), sequential[i]);
    EXPECT_EQ(b.irradiance(normals[i]), sequential[i]);
    EXPECT_EQ(concurrent[i], sequential[i]);
    EXPECT_EQ(a.estimate(normals[i], 256), sequential[i]);
    if (other.irradiance(normals[i]) != sequential[i]) ++differentSeed;
  }
  EXPECT_EQ(differentSeed, int(normals.size()));
}

TEST(MonteCarlo, AllZeroMapGivesZero) {
  MonteCarloLighting mc(1024, 1);
  mc.project(Environment::constant(glm::vec3(0.0f), 64));
  const MonteCarloLighting::VisibilityFn all = [](const glm::vec3&) { return true; };
  for (const auto& n : randomNormals(20, 7)) {
    EXPECT_EQ(mc.irradiance(n), glm::vec3(0.0f));
    EXPECT_EQ(mc.irradiance(n, all), glm::vec3(0.0f));
  }
}

// Visibility on a constant map: with only the upper half-space (y > 0) visible, a normal along
// +X sees the quarter sphere x > 0, y > 0, whose irradiance is ∫ x dω = π/2; a normal along +Y is
// unaffected (E = π). The callback is only asked about contributing directions.
TEST(MonteCarlo, VisibilityMasksDirections) {
  MonteCarloLighting mc(16384, 5);
  mc.project(Environment::constant(glm::vec3(1.0f), 64));
  const glm::vec3 nx(1, 0, 0), ny(0, 1, 0);
  std::atomic<int> calls{0}, behind{0};
  glm::vec3 current = nx;
  const MonteCarloLighting::VisibilityFn upper = [&](const glm::vec3& d) {
    ++calls;
    if (glm::dot(d, current) <= 0.0f) ++behind;
    return d.y > 0.0f;
  };
  // The white-furnace σ at 16384 samples is ~0.3% of π; half the domain masked raises it a
  // little. 2% is a loose noise bound that still separates π/2 from π.
  constexpr double kRelative = 0.02;
  EXPECT_NEAR(mc.irradiance(nx, upper).x, kPi / 2, kRelative * kPi / 2);
  current = ny;
  EXPECT_NEAR(mc.irradiance(ny, upper).x, kPi, kRelative * kPi);
  EXPECT_GT(calls.load(), 0);
  EXPECT_EQ(behind.load(), 0);
  // Everything visible is bitwise the unshadowed estimate; nothing visible is zero.
  const MonteCarloLighting::VisibilityFn all = [](const glm::vec3&) { return true; };
  const MonteCarloLighting::VisibilityFn none = [](const glm::vec3&) { return false; };
  for (const auto& n : randomNormals(10, 8)) {
    EXPECT_EQ(mc.irradiance(n, all), mc.irradiance(n));
    EXPECT_EQ(mc.estimate(n, 100, &none), glm::vec3(0.0f));
  }
}

}  // namespace
}  // namespace compose::lighting
