// Numerical stress: a sun 1e5 times brighter than the sky through every basis, float against
// double accumulation of moments, and the limits of N and k.
#include <cmath>
#include <limits>
#include <numbers>
#include <random>

#include <glm/geometric.hpp>

#include "lighting/exact.h"
#include "lighting/lighting.h"
#include "lighting/sh.h"
#include "lighting/tchebichef.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

std::vector<glm::vec3> fibonacciNormals(int count) {
  std::vector<glm::vec3> out;
  const double golden = std::numbers::pi * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < count; ++i) {
    const double y = 1.0 - 2.0 * (i + 0.5) / count, r = std::sqrt(1.0 - y * y);
    out.emplace_back(float(r * std::cos(golden * i)), float(y), float(r * std::sin(golden * i)));
  }
  return out;
}

// Sky of radiance 1 and a 3 x 3-texel sun 1e5 times brighter (about 40x the sky's irradiance).
Environment sunOfHundredThousand(int width) {
  Image img(width, width / 2, 3);
  std::fill(img.pixels.begin(), img.pixels.end(), 1.0f);
  for (int dy = -1; dy <= 1; ++dy) {
    for (int dx = -1; dx <= 1; ++dx) {
      float* sun = img.at(width / 3 + dx, width / 8 + dy);
      sun[0] = sun[1] = sun[2] = 1e5f;
    }
  }
  return Environment::fromLatLong(img);
}

TEST(Stress, SunOfHundredThousandGivesFiniteIrradianceEverywhere) {
  const Environment env = sunOfHundredThousand(512);
  ExactLighting exact;
  exact.project(env);
  const auto normals = fibonacciNormals(500);
  for (const std::string& name : lightingNames()) {
    ParamSet params;
    if (name == "mc") params = ParamSet::parse("samples=256", "t");
    auto basis = createLighting(name, params);
    basis->project(env);
    float lowest = std::numeric_limits<float>::max();
    for (const auto& n : normals) {
      const glm::vec3 e = basis->irradiance(n);
      const bool finite = std::isfinite(e.x) && std::isfinite(e.y) && std::isfinite(e.z);
      ASSERT_TRUE(finite) << name;
      lowest = std::min(lowest, e.x);
    }
    // Exact and the local basis are sums of non-negative terms; SH rings below zero on the far
    // side of the sun (the renderer clamps E at 0, see render/renderer.h). Report the lobe.
    if (name == "exact" || name == "cheb-local" || name == "mc") {
      EXPECT_GE(lowest, 0.0f) << name;
    }
    const float sky = float(std::numbers::pi);  // the sky alone gives π to every normal
    RecordProperty(name + "_min_irradiance_over_sky", std::to_string(lowest / sky));
    std::printf("%-13s min E / E_sky = %+.3f\n", name.c_str(), double(lowest / sky));
  }
  // SH9 really does ring negative here: the clamp in the renderer is needed, not decorative.
  ShLighting sh(2);
  sh.project(env);
  float lowest = 0.0f;
  for (const auto& n : normals) lowest = std::min(lowest, sh.irradiance(n).x);
  EXPECT_LT(lowest, 0.0f);
}

// Moments of a high-dynamic-range image accumulated from float input against double input: the
// float path loses ~1e-7 relative per term; the moments must agree to a few float ulps of the
// largest moment.
TEST(Stress, FloatAndDoubleMomentAccumulationAgree) {
  constexpr int kN = 256, kK = 16;
  std::mt19937 rng(5);
  std::lognormal_distribution<double> hdr(0.0, 3.0);  // values spanning ~8 decades
  std::vector<double> image(size_t(kN) * kN);
  for (double& v : image) v = hdr(rng);
  std::vector<float> imageF(image.begin(), image.end());
  const TchebichefBasis basis(kN, kK);
  const std::vector<double> fromDouble = moments2d(basis, basis, image, kK);
  const std::vector<double> fromFloat = moments2d(basis, basis, imageF, kK);
  double largest = 0.0, worst = 0.0;
  for (size_t i = 0; i < fromDouble.size(); ++i) {
    largest = std::max(largest, std::abs(fromDouble[i]));
    worst = std::max(worst, std::abs(fromDouble[i] - fromFloat[i]));
  }
  // Input rounding to float (2^-24 relative per pixel), summed in double: ≤ 1e-6 of the largest.
  EXPECT_LT(worst / largest, 1e-6);
  RecordProperty("float_vs_double_relative", std::to_string(worst / largest));
  std::printf("moments from float vs double input: max difference %.3g of the largest moment\n",
              worst / largest);
}

TEST(Stress, OrdersAndSizesAtTheirLimits) {
  // N = 1 and K = N, and the largest N at low order.
  EXPECT_NEAR(TchebichefBasis(1, 1)(0, 0), 1.0, 1e-15);
  const TchebichefBasis big(16384, 4);
  EXPECT_LE(orthonormalityError(big.matrix(), 4, 16384), 1e-10);
  EXPECT_THROW(TchebichefBasis(16385, 1), std::invalid_argument);
  EXPECT_THROW(TchebichefBasis(8, 9), std::invalid_argument);
  // Bases at their order limits still give finite, furnace-correct answers.
  const Environment env = Environment::constant(glm::vec3(1.0f), 128);
  for (const char* spec : {"sh:order=8", "cheb-latlong:order=32,samples=32,rows=9,cols=16",
                           "cheb-local:order=8,samples=8,rows=9,cols=16",
                           "cheb-face:order=1,samples=1,rows=9,cols=16"}) {
    const std::string s(spec);
    auto basis =
        createLighting(s.substr(0, s.find(':')), ParamSet::parse(s.substr(s.find(':') + 1), "t"));
    basis->project(env);
    for (const auto& n : fibonacciNormals(50)) {
      const float e = basis->irradiance(n).x;
      const bool finite = std::isfinite(e);
      ASSERT_TRUE(finite) << spec;
      // The coarse global grids integrate the cosine by a midpoint rule; 5% bounds that at s = 1.
      EXPECT_NEAR(e, std::numbers::pi, 0.05 * std::numbers::pi) << spec;
    }
  }
}

}  // namespace
}  // namespace compose::lighting
