#include "cubemap/mirror_ball.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "cubemap/render_view.h"
#include "ingest/image_io.h"
#include "lighting/environment_util.h"
#include "lighting/filtered_cube.h"
#include "lighting/sample_environment.h"
#include "lighting/sphere_resample.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::cubemap {
namespace {

namespace fs = std::filesystem;
using lighting::CubeMap;
using lighting::Environment;
using lighting::kCubeFaces;

// A photo of a chrome ball lit by `env`, cropped to the ball (DESIGN.md §4.4, written
// independently of the unwrapper: forward from pixels to directions), 4 x 4 samples per pixel.
Image photographBall(const Environment& env, int size) {
  Image img(size, size, 3, {"R", "G", "B"});
  const int s = 4;
  for (int py = 0; py < size; ++py) {
    for (int px = 0; px < size; ++px) {
      glm::vec3 sum(0.0f);
      for (int j = 0; j < s; ++j) {
        for (int i = 0; i < s; ++i) {
          const double u = 2.0 * (px + (i + 0.5) / s) / size - 1.0;
          const double v = 1.0 - 2.0 * (py + (j + 0.5) / s) / size;
          const double r2 = u * u + v * v;
          if (r2 > 1.0) continue;
          const glm::dvec3 n(u, v, std::sqrt(1.0 - r2)), c(0, 0, 1);
          const glm::dvec3 d = 2.0 * glm::dot(n, c) * n - c;
          sum += env.lookup(glm::vec3(d));
        }
      }
      const glm::vec3 mean = sum / float(s * s);
      img.at(px, py)[0] = mean.x, img.at(px, py)[1] = mean.y, img.at(px, py)[2] = mean.z;
    }
  }
  return img;
}

TEST(MirrorBall, BrightSpotUnwrapsToItsDirection) {
  Image img(256, 128, 3);
  const Environment probe = Environment::constant(glm::vec3(0.0f), 256);
  // A 3 x 3 texel spot up and to the right of the camera's side of the ball.
  const int cx = 90, cy = 40;
  for (int y = cy - 1; y <= cy + 1; ++y)
    for (int x = cx - 1; x <= cx + 1; ++x)
      img.at(x, y)[0] = img.at(x, y)[1] = img.at(x, y)[2] = 100.0f;
  const Environment env = Environment::fromLatLong(img);
  const glm::vec3 spot = probe.direction(cx, cy);
  ASSERT_GT(spot.z, 0.0f);  // on the photographer's side, where the ball is sampled best
  const MirrorBallResult r = unwrapMirrorBall(photographBall(env, 400), {});
  float best = 0.0f;
  glm::vec3 dir(0.0f);
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < r.cube.size(); ++y)
      for (int x = 0; x < r.cube.size(); ++x)
        if (r.cube.radiance(f, x, y).x > best) {
          best = r.cube.radiance(f, x, y).x;
          dir = r.cube.direction(f, x, y);
        }
  const double angle = std::acos(std::min(1.0f, glm::dot(dir, spot))) * 180.0 / kPi;
  // The spot is 1.4° wide; the unwrapped cube has 0.7° texels here.
  EXPECT_LT(angle, 1.5);
}

// The unwrapped sample HDRIs match the ground truth outside the blind spot and its blend ring.
TEST(MirrorBall, UnwrapsTheSampleHdris) {
  for (const char* name : {"sunset", "forest"}) {
    const Environment env = testing::loadSampleEnvironment(name);
    if (env.width() == 0) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
    MirrorBallOptions options;
    const MirrorBallResult r = unwrapMirrorBall(photographBall(env, 500), options);
    // The blind cone: 10°, or wider where the ball's outline (1.5 pixels of a 500-pixel ball, at
    // disc radius 0.994) maps further out; (1 - cos β) / 2 of the sphere, to a texel ring.
    const double rim = kPi - 2.0 * std::asin(1.0 - 1.5 / 250.0);
    const double blind = std::max(10.0 * kPi / 180.0, rim);
    EXPECT_NEAR(r.coverage.uncovered, (1.0 - std::cos(blind)) / 2.0, 1e-3);
    const CubeMap truth = lighting::cubeFromLatLong(env, r.cube.size());
    std::vector<double> rel;
    for (int f = 0; f < kCubeFaces; ++f)
      for (int y = 0; y < truth.size(); ++y)
        for (int x = 0; x < truth.size(); ++x) {
          const glm::vec3 d = truth.direction(f, x, y);
          if (-d.z > std::cos(25.0 * kPi / 180.0)) continue;  // blind spot, ramp and a margin
          const glm::vec3 a = truth.radiance(f, x, y), b = r.cube.radiance(f, x, y);
          rel.push_back(double(glm::length(a - b) / std::max(glm::length(a), 1e-4f)));
        }
    std::nth_element(rel.begin(), rel.begin() + ptrdiff_t(rel.size() / 2), rel.end());
    const double median = rel[rel.size() / 2];
    std::printf("%-8s mirror ball 500 px: median relative error %.4f\n", name, median);
    // The ball photo is a bilinear, 4x4-supersampled view of the map, resampled again onto the
    // cube: texel-scale detail (forest: 38 % between neighbouring texels) is partly lost twice.
    constexpr double kTwoResamplings = 0.15;
    EXPECT_LT(median, kTwoResamplings) << name;
  }
}

TEST(MirrorBall, FilledBlindSpotIsFiniteAndNearItsSurroundings) {
  const Environment env = Environment::constant(glm::vec3(2.0f, 1.0f, 0.5f), 128);
  const MirrorBallResult r = unwrapMirrorBall(photographBall(env, 200), {});
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < r.cube.size(); ++y)
      for (int x = 0; x < r.cube.size(); ++x) {
        const glm::vec3 L = r.cube.radiance(f, x, y);
        // A constant environment stays constant, the filled cone and the ball's outline included
        // (float rounding of weighted means).
        EXPECT_NEAR(L.x, 2.0f, 1e-4f);
        EXPECT_NEAR(L.z, 0.5f, 1e-4f);
      }
}

TEST(MirrorBall, CropMustBeSquare) {
  Image img(100, 90, 3);
  COMPOSE_EXPECT_ERROR(unwrapMirrorBall(img, {}, "ball.jpg"),
                       "must be cropped square to the ball, this one is 100x90 (ball.jpg)");
  MirrorBallOptions bad;
  bad.blindSpotDegrees = 90.0;
  EXPECT_THROW(bad.validate(), UsageError);
}

TEST(RenderView, FaceCamerasSeeTheirFaces) {
  // Rendering each face's camera at 90° with the face's size reproduces the cube's texels where
  // the map is smooth (both are area averages of the same function).
  const Environment env = testing::analyticEnvironment(
      128, [](const glm::vec3& d) { return glm::vec3(1.0f + d.x, 1.0f + d.y, 1.0f + d.z); });
  const lighting::FilteredCube filtered = lighting::FilteredCube::fromEnvironment(env);
  const CubeMap cube = lighting::cubeFromLatLong(env, 16);
  const calib::Lens lens = calib::Lens::fromFieldOfView(16, 16, 90.0);
  for (int f = 0; f < kCubeFaces; ++f) {
    const Image view = renderView(filtered, lens, faceCameraRotation(f), 4);
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x)
        for (int c = 0; c < 3; ++c)
          // Smooth (linear) radiance: two area averages differ by interpolation error only.
          EXPECT_NEAR(view.at(x, y)[c], cube.texel(f, x, y)[c], 0.02f)
              << lighting::faceName(f) << " " << x << "," << y;
  }
  // The photographer's rotations agree with the face frames.
  const glm::dmat3 up = cameraRotation(0, 90, 0), side = cameraRotation(-90, 0, 0);
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(glm::length(up[k] - faceCameraRotation(2)[k]), 0.0, 1e-12);
    EXPECT_NEAR(glm::length(side[k] - faceCameraRotation(0)[k]), 0.0, 1e-12);
  }
}

}  // namespace
}  // namespace compose::cubemap
