#include "lighting/sh.h"

#include <cmath>
#include <numbers>
#include <random>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "environment_util.h"
#include "lighting/exact.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

using compose::testing::randomNormals;

using compose::testing::analyticEnvironment;

TEST(Sh, CosineLobeWeightsMatchRamamoorthiHanrahan) {
  EXPECT_DOUBLE_EQ(shCosineLobe(0), kPi);
  EXPECT_DOUBLE_EQ(shCosineLobe(1), 2.0 * kPi / 3.0);
  EXPECT_NEAR(shCosineLobe(2), kPi / 4.0, 1e-15);
  EXPECT_EQ(shCosineLobe(3), 0.0);
  EXPECT_NEAR(shCosineLobe(4), -kPi / 24.0, 1e-15);
  EXPECT_NEAR(shCosineLobe(6), kPi / 64.0, 1e-15);
}

TEST(Sh, BasisIsOrthonormalOverTheSphere) {
  // Quadrature on a fine lat-long grid: exact solid angles, midpoint rule, error ~1e-5 at order 8.
  const int order = kMaxShOrder, count = shCount(order);
  const Environment grid = Environment::constant(glm::vec3(1.0f), 1024);
  std::vector<double> gram(size_t(count * count), 0.0);
  auto y = std::vector<double>(size_t(count));
  for (int r = 0; r < grid.height(); ++r) {
    for (int c = 0; c < grid.width(); ++c) {
      evalSh(order, glm::dvec3(grid.direction(c, r)), y.data());
      for (int i = 0; i < count; ++i)
        for (int j = 0; j <= i; ++j)
          gram[size_t(i * count + j)] += y[size_t(i)] * y[size_t(j)] * grid.rowSolidAngle(r);
    }
  }
  constexpr double kQuadratureTolerance = 2e-4;  // midpoint rule on 1024x512 at band 8
  for (int i = 0; i < count; ++i)
    for (int j = 0; j <= i; ++j)
      EXPECT_NEAR(gram[size_t(i * count + j)], i == j ? 1.0 : 0.0, kQuadratureTolerance)
          << i << "," << j;
}

TEST(Sh, FirstBandsHaveTheTextbookForm) {
  // Y_00 = 1/(2√π); Y_1m ∝ (world x, y, z) with the pole on +Y: index 2 (m=0) is y.
  const glm::dvec3 d = glm::normalize(glm::dvec3(0.3, -0.5, 0.8));
  std::vector<double> y(9);
  evalSh(2, d, y.data());
  const double k1 = std::sqrt(3.0 / (4.0 * kPi));
  EXPECT_NEAR(y[0], 0.5 / std::sqrt(kPi), 1e-15);
  EXPECT_NEAR(y[2], k1 * d.y, 1e-15);
  EXPECT_NEAR(y[3], k1 * d.z, 1e-15);
  EXPECT_NEAR(y[1], k1 * d.x, 1e-15);
}

// White furnace: radiance 1 everywhere gives E = π for every normal.
TEST(WhiteFurnace, ShAndExactGivePi) {
  const Environment env = Environment::constant(glm::vec3(1.0f), 256);
  constexpr double kRelative = 1e-6;  // the bound; float evaluation gives ~1e-7
  for (int order : {0, 1, 2, 4, 8}) {
    ShLighting sh(order);
    sh.project(env);
    for (const auto& n : randomNormals(200, 1)) {
      EXPECT_NEAR(sh.irradiance(n).y, kPi, kRelative * kPi) << "order " << order;
    }
  }
  ExactLighting exact;
  exact.project(env);
  for (const auto& n : randomNormals(50, 2)) {
    // A constant map is not exactly constant in cos: the midpoint rule leaves ~1e-5 at 256x128.
    EXPECT_NEAR(exact.irradiance(n).x, kPi, 1e-4 * kPi);
  }
}

// L(ω) = a + b·ω lies in bands 0 and 1, so E(n) = π a + (2π/3) b·n exactly; SH of any order ≥ 1
// and the exact quadrature must both find it.
TEST(Irradiance, LinearRadianceHasAClosedForm) {
  const glm::vec3 b(0.3f, 0.5f, -0.2f);
  const Environment env =
      analyticEnvironment(512, [&](glm::vec3 w) { return glm::vec3(1.0f + glm::dot(b, w)); });
  ShLighting sh(2);
  sh.project(env);
  ExactLighting exact;
  exact.project(env);
  for (const auto& n : randomNormals(100, 3)) {
    const double expected = kPi + 2.0 * kPi / 3.0 * glm::dot(b, n);
    constexpr double kQuadrature = 2e-4;  // midpoint rule on 512x256, relative
    EXPECT_NEAR(sh.irradiance(n).x, expected, kQuadrature * expected);
    EXPECT_NEAR(exact.irradiance(n).x, expected, kQuadrature * expected);
  }
}

// Windowing scales band l by w_l: band 0 is untouched, so the furnace still holds.
TEST(Sh, WindowingDeringsAndKeepsTheFurnace) {
  ShLighting hanning(2, ShWindow::Hanning), lanczos(2, ShWindow::Lanczos);
  EXPECT_DOUBLE_EQ(hanning.windowWeight(0), 1.0);
  EXPECT_NEAR(hanning.windowWeight(1), 0.5 * (1.0 + std::cos(kPi / 3.0)), 1e-15);
  EXPECT_NEAR(lanczos.windowWeight(2), std::sin(2.0 * kPi / 3.0) / (2.0 * kPi / 3.0), 1e-15);
  const Environment white = Environment::constant(glm::vec3(1.0f), 64);
  hanning.project(white);
  EXPECT_NEAR(hanning.irradiance({0, 1, 0}).x, kPi, 1e-6 * kPi);
  // On a bright cap at +Y the windowed irradiance is Σ_l w_l A_l L_lm Y_lm(n), recomputed here from
  // the raw coefficients.
  const Environment cap =
      analyticEnvironment(256, [](glm::vec3 w) { return glm::vec3(w.y > 0.98f ? 1000.0f : 0.0f); });
  ShLighting windowed(4, ShWindow::Lanczos);
  windowed.project(cap);
  std::vector<double> y(size_t(shCount(4)));
  for (const auto& n : randomNormals(50, 8)) {
    evalSh(4, glm::dvec3(n), y.data());
    double expected = 0.0;
    for (int l = 0; l <= 4; ++l)
      for (int m = -l; m <= l; ++m) {
        const size_t i = size_t(l * (l + 1) + m);
        expected += windowed.windowWeight(l) * shCosineLobe(l) *
                    windowed.radianceCoefficients()[i].x * y[i];
      }
    EXPECT_NEAR(windowed.irradiance(n).x, expected, 1e-4 * std::abs(expected) + 1e-3);
  }
  COMPOSE_EXPECT_ERROR(createLighting("sh", ParamSet::parse("window=gauss", "t")),
                       "sh window must be none, hanning or lanczos");
}

// The projection kept in caches and lighting files comes back exactly: the irradiance as
// evaluated and the radiance coefficients SH transfer reads in double (a lighting file of
// compose precompute --shadow-params method=sh could not be written: the basis kept no state).
TEST(Sh, ItsStateComesBackExactly) {
  const Environment sky = analyticEnvironment(128, [](glm::vec3 w) {
    return glm::vec3(1.0f + 30.0f * std::max(0.0f, w.x), 0.7f + 1e-7f * w.z, 0.2f + w.y * w.y);
  });
  ShLighting projected(4);
  std::vector<float> state;
  EXPECT_FALSE(projected.exportState(state)) << "nothing projected yet";
  projected.project(sky);
  ASSERT_TRUE(projected.exportState(state));
  ShLighting read(4), other(3);
  EXPECT_FALSE(other.importState(state)) << "another order's state";
  ASSERT_TRUE(read.importState(state));
  for (size_t i = 0; i < projected.radianceCoefficients().size(); ++i)
    for (int c = 0; c < 3; ++c)
      EXPECT_EQ(read.radianceCoefficients()[i][c], projected.radianceCoefficients()[i][c]) << i;
  for (const auto& n : randomNormals(20, 3)) EXPECT_EQ(read.irradiance(n), projected.irradiance(n));
}

TEST(Lighting, CreatesByNameAndReportsMistakes) {
  EXPECT_EQ(createLighting("sh")->coefficientsPerChannel(), 9);
  EXPECT_EQ(createLighting("sh", ParamSet::parse("order=4", "t"))->coefficientsPerChannel(), 25);
  COMPOSE_EXPECT_ERROR(createLighting("chebyshev"),
                       "unknown lighting basis 'chebyshev'; valid: cheb-local, cheb-latlong, "
                       "cheb-face, sh, mc, exact");
  COMPOSE_EXPECT_ERROR(createLighting("sh", ParamSet::parse("ordr=4", "t")),
                       "does not take parameter(s): ordr");
  COMPOSE_EXPECT_ERROR(createLighting("sh", ParamSet::parse("order=9", "t")),
                       "sh order must be in 0..8");
  // A negative seed would wrap to 2^32 - 1 and stand for a seed nobody asked for.
  COMPOSE_EXPECT_ERROR(createLighting("mc", ParamSet::parse("seed=-1", "t")),
                       "parameter seed=-1 must be 0 or more");
}

}  // namespace
}  // namespace compose::lighting
