#include "lighting/environment.h"

#include <cmath>
#include <limits>
#include <numbers>

#include "core/numbers.h"
#include "lighting/exact.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

Image blackLatLong(int width) {
  Image img(width, width / 2, 3, {"R", "G", "B"});
  img.colorSpace = "ACEScg";
  return img;
}

TEST(Environment, SolidAnglesSumToFourPi) {
  for (int w : {4, 16, 1024}) {
    const Environment env = Environment::constant(glm::vec3(1.0f), w);
    double total = 0.0;
    for (int y = 0; y < env.height(); ++y) total += env.rowSolidAngle(y) * env.width();
    // Exact per-row formula: only double rounding remains.
    EXPECT_NEAR(total, 4.0 * kPi, 1e-12) << "width " << w;
  }
}

// Mean radiance below the horizon over that above it, each by solid angle: a map of 1 above and
// 0.25 below gives 0.25, upside down 4, whatever the rows' solid angles; an odd number of rows
// leaves the one across the horizon out.
TEST(Environment, BelowOverAboveIsTheHalvesMeanRatio) {
  for (const int h : {8, 9, 64}) {
    Image img(2 * h, h, 3, {"R", "G", "B"});
    Image flipped = img;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < 2 * h; ++x)
        for (int c = 0; c < 3; ++c) {
          const float above = c == 1 ? 3.0f : 0.0f, below = 0.25f;  // means 1 and 0.25
          const float v = 2 * y + 1 < h ? above : 2 * y + 1 > h ? below : 100.0f;
          img.at(x, y)[c] = v;
          flipped.at(x, h - 1 - y)[c] = v;
        }
    EXPECT_NEAR(Environment::fromLatLong(img).belowOverAbove(), 0.25, 1e-12) << h;
    EXPECT_NEAR(Environment::fromLatLong(flipped).belowOverAbove(), 4.0, 1e-12) << h;
  }
  EXPECT_TRUE(std::isnan(Environment::constant(glm::vec3(0.0f), 16).belowOverAbove()));
}

TEST(Environment, AxesFollowOpenExrLatLong) {
  const Environment env = Environment::constant(glm::vec3(1.0f), 64);
  const int w = env.width(), h = env.height();
  // Centre column looks along +Z, a quarter in from the left along +X, three quarters along -X.
  // Texel centres sit half a texel off the exact axis: allow that angle.
  const float halfTexel = float(std::sin(kPi / h));
  EXPECT_NEAR(env.direction(w / 2, h / 2).z, 1.0f, halfTexel);
  EXPECT_NEAR(env.direction(w / 4, h / 2).x, 1.0f, halfTexel);
  EXPECT_NEAR(env.direction(3 * w / 4, h / 2).x, -1.0f, halfTexel);
  EXPECT_NEAR(env.direction(0, h / 2).z, -1.0f, halfTexel);
  EXPECT_GT(env.direction(w / 2, 0).y, 0.99f);       // top row is up
  EXPECT_LT(env.direction(w / 2, h - 1).y, -0.99f);  // bottom row is down
}

TEST(Environment, OneBrightTexelLightsTheNormalFacingIt) {
  // One texel of radiance 1000 a quarter in from the left on the equator: direction +X.
  Image img = blackLatLong(256);
  const int x = 256 / 4, y = 128 / 2;
  img.at(x, y)[0] = img.at(x, y)[1] = img.at(x, y)[2] = 1000.0f;
  const Environment env = Environment::fromLatLong(img);
  ExactLighting exact;
  exact.project(env);
  const glm::vec3 d = env.direction(x, y);
  const double expected = 1000.0 * env.rowSolidAngle(y) * d.x;  // cos between +X and the texel
  // The reference integrates the cosine exactly over the texel; the centre-point value above
  // differs by the midpoint rule's error, ~Δ²/24 = 3e-5 of it at 256x128.
  constexpr double kMidpoint = 1e-4;
  EXPECT_NEAR(exact.irradiance({1, 0, 0}).x, expected, kMidpoint * expected);
  EXPECT_EQ(exact.irradiance({-1, 0, 0}).x, 0.0f);
  const double alsoZ = 1000.0 * env.rowSolidAngle(y) * std::max(0.0f, d.z);
  EXPECT_NEAR(exact.irradiance({0, 0, 1}).x, alsoZ, kMidpoint * alsoZ);
  // The bilinear lookup finds the texel in that direction.
  EXPECT_NEAR(env.lookup(d).x, 1000.0f, 1e-3f);
}

TEST(Environment, RejectsNonFiniteRadianceNamingTheTexel) {
  Image img = blackLatLong(16);
  img.at(3, 2)[1] = std::numeric_limits<float>::quiet_NaN();
  COMPOSE_EXPECT_ERROR(Environment::fromLatLong(img, "sky.exr"),
                       "NaN radiance at texel (3, 2) (sky.exr)");
  img.at(3, 2)[1] = std::numeric_limits<float>::infinity();
  COMPOSE_EXPECT_ERROR(Environment::fromLatLong(img, "sky.exr"),
                       "infinite radiance at texel (3, 2)");
  // Finite but beyond any light: damage, not radiance.
  img.at(3, 2)[1] = 3e38f;
  COMPOSE_EXPECT_ERROR(Environment::fromLatLong(img, "sky.exr"),
                       "at texel (3, 2) is beyond any light (more than 1e32)");
  img.at(3, 2)[1] = 1e30f;
  EXPECT_NO_THROW(Environment::fromLatLong(img, "sky.exr"));
}

TEST(Environment, ClampsAndCountsNegativeRadiance) {
  Image img = blackLatLong(16);
  img.at(0, 0)[0] = -0.5f;
  img.at(0, 0)[2] = -0.25f;
  img.at(5, 3)[1] = -0.125f;
  SanitizeReport report;
  const Environment env = Environment::fromLatLong(img, {}, &report);
  EXPECT_EQ(report.negativeTexels, 2);
  EXPECT_EQ(report.mostNegative, -0.5f);
  EXPECT_EQ(env.radiance(0, 0), glm::vec3(0.0f));
}

TEST(Environment, RejectsMapsThatAreNotLatLong) {
  Image img(30, 20, 3);
  COMPOSE_EXPECT_ERROR(Environment::fromLatLong(img, "cross.exr"),
                       "not a lat-long (equirectangular) map: it is 30x20, and a lat-long map is "
                       "twice as wide as it is high");
  Image grey(32, 16, 1);
  COMPOSE_EXPECT_ERROR(Environment::fromLatLong(grey, "grey.exr"), "needs RGB channels");
}

TEST(Environment, TheSmallestLatLongMapIsTwoByOne) {
  // Two texels, the western and the eastern half of the sphere: a valid map.
  Image img(2, 1, 3);
  img.at(0, 0)[0] = 1.0f;  // the left texel is the +X half (longitude 0..π)
  const Environment env = Environment::fromLatLong(img);
  EXPECT_EQ(env.width(), 2);
  EXPECT_NEAR(env.rowSolidAngle(0), 2.0 * std::numbers::pi, 1e-12);
  EXPECT_GT(env.direction(0, 0).x, 0.99f);
}

}  // namespace
}  // namespace compose::lighting
