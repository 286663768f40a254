#include "lighting/filtered_cube.h"

#include <cmath>
#include <numbers>
#include <random>

#include <glm/geometric.hpp>

#include "lighting/environment_util.h"
#include "lighting/sphere_resample.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

// A cube whose texels hold a smooth function of their direction, plus one bright texel.
CubeMap testCube(int n) {
  CubeMap cube(n);
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        const glm::vec3 d = cube.direction(f, x, y);
        float* t = cube.texel(f, x, y);
        t[0] = 1.0f + d.x * d.x;
        t[1] = 2.0f + 0.5f * d.y;
        t[2] = 1.5f + std::sin(3.0f * d.z);
      }
  float* sun = cube.texel(2, n / 3, n / 5);
  sun[0] = sun[1] = sun[2] = 5000.0f;
  return cube;
}

TEST(FilteredCube, EveryLevelKeepsTheEnergy) {
  for (int n : {64, 45}) {  // a power of two, and odd sizes with partial overlaps on the way down
    const FilteredCube filtered{testCube(n)};
    const glm::dvec3 base = filtered.integral(0);
    EXPECT_EQ(filtered.size(filtered.levels() - 1), 1);
    for (int l = 1; l < filtered.levels(); ++l) {
      // Exact solid-angle weights, texels stored in float: float rounding only.
      constexpr double kFloat = 1e-6;
      EXPECT_LT(testing::worstRelative(filtered.integral(l), base), kFloat)
          << "size " << n << " level " << l;
    }
  }
}

TEST(FilteredCube, ConstantStaysConstant) {
  CubeMap cube(37);
  for (int f = 0; f < kCubeFaces; ++f) std::fill(cube.face(f).begin(), cube.face(f).end(), 2.5f);
  const FilteredCube filtered(cube);
  for (const glm::vec3& d : testing::randomNormals(2000, 5)) {
    for (float omega : {0.0f, 1e-4f, 1e-2f, 0.3f, 3.0f}) {
      const glm::vec3 L = filtered.lookup(d, omega);
      EXPECT_NEAR(L.x, 2.5f, 2e-6f);  // float rounding of weights that sum to one
    }
  }
}

// Across every face edge and cube corner the filtered radiance is continuous: the same from both
// sides, at every level and fractional level.
TEST(FilteredCube, SeamlessAcrossFaceEdgesAndCorners) {
  const FilteredCube filtered{testCube(32)};
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> along(-1.0, 1.0);
  double worst = 0.0, typicalStep = 0.0;
  int count = 0;
  for (int face = 0; face < kCubeFaces; ++face) {
    for (int edge = 0; edge < 4; ++edge) {
      for (int i = 0; i < 50; ++i) {
        // A point on the edge, and the points a hair inside this face and inside the neighbour.
        double t = along(rng);
        if (i == 0) t = -1.0;  // a cube corner
        const double a = edge == 0 ? -1.0 : edge == 1 ? 1.0 : t;
        const double b = edge == 2 ? -1.0 : edge == 3 ? 1.0 : t;
        const glm::dvec3 onEdge = faceImageDirection(face, a, b);
        const glm::dvec3 inward = faceImageDirection(face, a * (1.0 - 1e-7), b * (1.0 - 1e-7));
        const glm::dvec3 outward = 2.0 * onEdge - inward;  // across the edge
        for (float level : {0.0f, 0.5f, 1.0f, 2.3f, 4.0f}) {
          const glm::vec3 in = filtered.lookupLevel(glm::vec3(glm::normalize(inward)), level);
          const glm::vec3 out = filtered.lookupLevel(glm::vec3(glm::normalize(outward)), level);
          worst = std::max(worst, double(glm::length(in - out) / glm::length(in)));
          // For scale: the change over one texel inside the face.
          const glm::dvec3 step =
              faceImageDirection(face, a * (1.0 - 2.0 / 32), b * (1.0 - 2.0 / 32));
          const glm::vec3 near = filtered.lookupLevel(glm::vec3(glm::normalize(step)), level);
          typicalStep += double(glm::length(in - near) / glm::length(in));
          ++count;
        }
      }
    }
  }
  typicalStep /= count;
  // Both sides interpolate the same texels with weights 1e-7 apart: float rounding only, far
  // below the texel-to-texel change (reported for scale).
  constexpr double kSeam = 1e-5;
  EXPECT_LT(worst, kSeam) << "mean texel-to-texel change " << typicalStep;
  EXPECT_GT(typicalStep, 100 * kSeam);
}

TEST(FilteredCube, LevelFollowsTheFootprint) {
  const FilteredCube filtered{testCube(64)};
  const glm::vec3 centre(0, 0, -1);  // a face centre: texel solid angle (2/64)²
  const float texel = float(4.0 / (64.0 * 64.0));
  EXPECT_NEAR(filtered.levelFor(centre, texel), 0.0f, 1e-3f);
  EXPECT_NEAR(filtered.levelFor(centre, 4 * texel), 1.0f, 1e-3f);
  EXPECT_NEAR(filtered.levelFor(centre, 64 * texel), 3.0f, 1e-3f);
  EXPECT_EQ(filtered.levelFor(centre, 0.0f), 0.0f);
  EXPECT_EQ(filtered.levelFor(centre, 100.0f), float(filtered.levels() - 1));
  // Near a cube corner, texels are 5.2x smaller: the same footprint spans more of them.
  const glm::vec3 corner = glm::normalize(glm::vec3(0.98f, 0.98f, -1.0f));
  EXPECT_GT(filtered.levelFor(corner, 4 * texel), 1.5f);
}

// Prefiltered lookups keep the power of a single bright texel at every footprint: integrated over
// the sphere, lookup(d, Ω) gives back ∫ L dω.
TEST(FilteredCube, FootprintLookupsKeepTheEnergy) {
  CubeMap cube(64);
  float* sun = cube.texel(4, 20, 41);
  sun[0] = sun[1] = sun[2] = 1e4f;
  const FilteredCube filtered(cube);
  const double energy = filtered.integral(0).x;
  for (float level : {0.0f, 1.0f, 2.5f, 4.0f}) {
    // Integrate over a 256² grid per face with exact solid angles: finer than every level.
    const int m = 256;
    double total = 0.0;
    for (int f = 0; f < kCubeFaces; ++f)
      for (int y = 0; y < m; ++y)
        for (int x = 0; x < m; ++x) {
          const double a = -1.0 + (2.0 * x + 1.0) / m, b = -1.0 + (2.0 * y + 1.0) / m;
          total +=
              faceTexelSolidAngle(m, x, y) *
              filtered.lookupLevel(glm::vec3(glm::normalize(faceImageDirection(f, a, b))), level).x;
        }
    // Bilinear interpolation of box-filtered texels integrates to their sum up to the variation of
    // the texel solid angle across a texel and the corner texels' averaging: measured 1e-4 at
    // level 0, 4e-3 at 2.5 and 3.7e-2 at level 4, where a face is 4 x 4 texels.
    const double tolerance = level < 3.0f ? 0.01 : 0.05;
    EXPECT_NEAR(total / energy, 1.0, tolerance) << "level " << level;
  }
}

TEST(FilteredCube, FromEnvironmentMatchesTheLatLongMap) {
  const Environment env = testing::analyticEnvironment(
      256, [](const glm::vec3& d) { return glm::vec3(1.0f + 0.5f * d.y, 2.0f + d.x, 1.0f); });
  const FilteredCube filtered = FilteredCube::fromEnvironment(env);
  EXPECT_EQ(filtered.size(0), 64);
  double worst = 0.0;
  for (const glm::vec3& d : testing::randomNormals(500, 9)) {
    const glm::vec3 a = filtered.lookup(d, 0.0f), b = env.lookup(d);
    worst = std::max(worst, double(glm::length(a - b) / glm::length(b)));
  }
  // Two bilinear reconstructions of a smooth map at ~1.4° texels: second-order differences.
  constexpr double kSmooth = 2e-3;
  EXPECT_LT(worst, kSmooth);
}

}  // namespace
}  // namespace compose::lighting
