#include "lighting/volume.h"

#include <cmath>
#include <numbers>

#include "core/numbers.h"
#include "lighting/sh.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

TEST(LightingVolume, DistantSourceIsProjectedOnceAndEqualEverywhere) {
  Image img(64, 32, 3);
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 64; ++x)
      img.at(x, y)[0] = img.at(x, y)[1] = img.at(x, y)[2] = 1.0f + float(y) / 8.0f;
  const Environment env = Environment::fromLatLong(img);
  VolumeParams params;
  params.basis = "sh";
  params.resolution = {3, 2, 4};
  LightingVolume volume(params);
  volume.build(DistantSource(env));
  ShLighting sh(2);
  sh.project(env);
  EXPECT_EQ(volume.floatsStored(), sh.floatsStored()) << "one shared projection";
  for (const glm::vec3 p : {glm::vec3(0.0f), glm::vec3(0.9f, -0.3f, 0.5f), glm::vec3(5.0f)}) {
    const glm::vec3 n(0.0f, 1.0f, 0.0f);
    EXPECT_NEAR(volume.irradiance(p, n).x, sh.irradiance(n).x, 1e-5f);
  }
}

// Radiance that grows linearly along x: a trilinear volume reproduces it exactly between points,
// and clamps outside the bounds.
TEST(LightingVolume, InterpolatesTrilinearlyAndClampsOutside) {
  VolumeParams params;
  params.basis = "sh";
  params.basisParams = ParamSet::parse("order=0", "t");
  params.boundsMin = glm::vec3(0.0f);
  params.boundsMax = glm::vec3(2.0f, 1.0f, 1.0f);
  params.resolution = {3, 2, 2};
  LightingVolume volume(params);
  int projections = 0;
  volume.build(FunctionSource([&](const glm::vec3& p) {
    ++projections;
    return Environment::constant(glm::vec3(1.0f + p.x), 32);
  }));
  EXPECT_EQ(projections, 12);
  const glm::vec3 n(0.3f, 0.4f, std::sqrt(1.0f - 0.25f));
  for (float x : {0.0f, 0.25f, 1.0f, 1.7f, 2.0f}) {
    EXPECT_NEAR(volume.irradiance({x, 0.5f, 0.3f}, n).x, kPi * (1.0 + x), 1e-4 * kPi * (1.0 + x))
        << x;
  }
  EXPECT_NEAR(volume.irradiance({-3.0f, 0.5f, 0.5f}, n).x, kPi, 1e-4 * kPi);
  EXPECT_NEAR(volume.irradiance({9.0f, 0.5f, 0.5f}, n).x, 3.0 * kPi, 1e-4 * 3.0 * kPi);
}

TEST(LightingVolume, RejectsBadParameters) {
  VolumeParams p;
  p.resolution = {0, 1, 1};
  COMPOSE_EXPECT_ERROR(LightingVolume{p}, "volume resolution must be at least 1");
  VolumeParams q;
  q.boundsMax = glm::vec3(-2.0f);
  COMPOSE_EXPECT_ERROR(LightingVolume{q}, "volume bounds must be finite");
}

}  // namespace
}  // namespace compose::lighting
