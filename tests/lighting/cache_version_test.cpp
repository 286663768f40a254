// Ties LightingCache::kProjectionVersion to the numbers the cacheable bases produce: a fingerprint
// of a golden projection is recorded here for the current version. When a change moves the
// numbers, this test fails until the version is bumped (so that stale cache entries are never
// read) and the fingerprint below is updated to the printed one.
#include <cmath>
#include <cstdio>
#include <iomanip>

#include <glm/geometric.hpp>

#include "lighting/lighting.h"
#include "lighting/lighting_cache.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

// Sky gradient, warm ground and a small sun: every part of the integrators is exercised.
Environment goldenEnvironment() {
  const int w = 1024, h = 512;
  const Environment probe = Environment::constant(glm::vec3(0.0f), w);
  Image img(w, h, 3);
  const glm::vec3 sun = glm::normalize(glm::vec3(0.4f, 0.6f, -0.5f));
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const glm::vec3 d = probe.direction(x, y);
      glm::vec3 L = d.y > 0 ? glm::vec3(0.3f, 0.5f, 0.9f) * (0.5f + 0.5f * d.y)
                            : glm::vec3(0.25f, 0.2f, 0.1f);
      if (glm::dot(d, sun) > 0.9995f) L += glm::vec3(4000.0f, 3800.0f, 3500.0f);
      img.at(x, y)[0] = L.x, img.at(x, y)[1] = L.y, img.at(x, y)[2] = L.z;
    }
  }
  return Environment::fromLatLong(img);
}

// Sums of magnitudes, so that no cancellation makes a relative tolerance fragile.
struct Fingerprint {
  double sum, sumSquares, weighted;
};

Fingerprint fingerprint(const std::vector<float>& state) {
  Fingerprint f{0, 0, 0};
  for (size_t i = 0; i < state.size(); ++i) {
    const double v = state[i];
    f.sum += std::abs(v);
    f.sumSquares += v * v;
    f.weighted += double(i % 97 + 1) * v * v;
  }
  return f;
}

struct Golden {
  const char* basis;
  const char* params;
  Fingerprint expected;
};

// Fingerprints for kProjectionVersion 3. Moving an internal constant such as the leaf level of
// the local basis' integrator moves the cheb-local sums by ~1e-5: caught.
constexpr int kGoldenVersion = 3;
const Golden kGolden[] = {
    {"cheb-local", "", {3346.60651556, 3578.52026051, 177138.289263}},
    {"cheb-local", "order=3,brdf=oren-nayar", {18368.5655792, 20057.653616, 978621.290879}},
    {"cheb-local", "order=8,samples=16", {58574.2619174, 31115.9934724, 1517508.95171}},
    {"cheb-latlong", "", {1738.39351653, 4355.272777, 136975.534035}},
    {"cheb-face", "", {4316.81588261, 217302.188182, 9449810.15834}},
};

TEST(LightingCache, ProjectionVersionMatchesTheGoldenProjections) {
  ASSERT_EQ(LightingCache::kProjectionVersion, kGoldenVersion)
      << "kProjectionVersion was bumped: update kGoldenVersion and the fingerprints here";
  const Environment env = goldenEnvironment();
  for (const Golden& g : kGolden) {
    auto basis = createLighting(g.basis, ParamSet::parse(g.params, "test"));
    basis->project(env);
    std::vector<float> state;
    ASSERT_TRUE(basis->exportState(state)) << g.basis << " is cached, so it must export";
    const Fingerprint f = fingerprint(state);
    // Float rounding and libm differences between machines stay far below 1e-6 relative; any
    // change to the method moves these sums by much more.
    constexpr double kRelative = 1e-6;
    const bool same =
        std::abs(f.sum - g.expected.sum) <= kRelative * std::abs(g.expected.sum) &&
        std::abs(f.sumSquares - g.expected.sumSquares) <=
            kRelative * std::abs(g.expected.sumSquares) &&
        std::abs(f.weighted - g.expected.weighted) <= kRelative * std::abs(g.expected.weighted);
    EXPECT_TRUE(same) << g.basis << " " << g.params
                      << ": the projection's numbers changed. Bump "
                         "LightingCache::kProjectionVersion, then record here {"
                      << std::setprecision(12) << f.sum << ", " << f.sumSquares << ", "
                      << f.weighted << "}";
  }
}

}  // namespace
}  // namespace compose::lighting
