// Stitching six virtual photos of the sample HDRIs (the issue's test), orientation refinement,
// exposure gains, coverage, seams.
#include "cubemap/stitch.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <random>

#include <glm/geometric.hpp>
#include <glm/matrix.hpp>

#include "core/numbers.h"
#include "cubemap/coverage.h"
#include "cubemap/photo_header.h"
#include "cubemap/render_view.h"
#include "ingest/image_io.h"
#include "lighting/filtered_cube.h"
#include "lighting/sample_environment.h"
#include "lighting/sphere_resample.h"
#include "pipeline/compose_job.h"
#include "seams.h"
#include "test_util.h"

namespace compose::cubemap {
namespace {

namespace fs = std::filesystem;
using lighting::CubeMap;
using lighting::Environment;
using lighting::kCubeFaces;

double rotationDegrees(const glm::dmat3& a, const glm::dmat3& b) {
  const glm::dmat3 r = glm::transpose(a) * b;
  return std::acos(std::clamp((r[0][0] + r[1][1] + r[2][2] - 1.0) * 0.5, -1.0, 1.0)) * 180.0 / kPi;
}

// The rotation nearest to m (polar decomposition), by iterating q ← (q + q^-T) / 2.
glm::dmat3 polarRotation(glm::dmat3 q) {
  for (int i = 0; i < 50; ++i) q = 0.5 * (q + glm::transpose(glm::inverse(q)));
  return q;
}

struct Capture {
  std::vector<StitchPhoto> photos;
  std::vector<Image> images;
  std::vector<glm::dmat3> truth;  // the orientations the photos were really taken with
};

// Photos through `lens` in the `nominal` directions, each really turned by up to ±`offDegrees`
// about each axis from where the photographer thinks it points.
Capture views(const lighting::FilteredCube& env, const calib::Lens& lens,
              const std::vector<glm::dmat3>& nominal, double offDegrees, uint32_t seed) {
  Capture c;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> off(-offDegrees, offDegrees);
  for (size_t k = 0; k < nominal.size(); ++k) {
    const double roll = off(rng), pitch = off(rng), yaw = off(rng);  // a fixed order (see below)
    c.truth.push_back(nominal[k] * cameraRotation(yaw, pitch, roll));
    c.photos.push_back({"view " + std::to_string(k), lens, nominal[k], 0.0f});
  }
  // The part of the errors common to all photos turns the whole world: nothing in the photos can
  // reveal it, and the stitcher keeps the rough orientations' average. Remove it, so that the
  // result can be compared with the ground truth texel by texel: the real orientations become
  // q·R_i with q = polar(Σ R_rough R_real^T), whose polar factor is then the identity.
  glm::dmat3 m(0.0);
  for (size_t k = 0; k < nominal.size(); ++k)
    m += c.photos[k].worldFromCamera * glm::transpose(c.truth[k]);
  const glm::dmat3 q = polarRotation(m);
  for (size_t k = 0; k < nominal.size(); ++k) {
    c.truth[k] = q * c.truth[k];
    c.images.push_back(renderView(env, lens, c.truth[k], 2));
  }
  return c;
}

// Six square photos in the photographer's convention.
Capture sixViews(const lighting::FilteredCube& env, int size, double fov, double offDegrees,
                 uint32_t seed) {
  std::vector<glm::dmat3> nominal;
  for (int f = 0; f < kCubeFaces; ++f) nominal.push_back(faceCameraRotation(f));
  return views(env, calib::Lens::fromFieldOfView(size, size, fov), nominal, offDegrees, seed);
}

double medianRelative(const CubeMap& truth, const CubeMap& x) {
  std::vector<double> rel;
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < truth.size(); ++y)
      for (int i = 0; i < truth.size(); ++i) {
        const glm::vec3 a = truth.radiance(f, i, y), b = x.radiance(f, i, y);
        rel.push_back(double(glm::length(a - b) / std::max(glm::length(a), 1e-6f)));
      }
  std::nth_element(rel.begin(), rel.begin() + ptrdiff_t(rel.size() / 2), rel.end());
  return rel[rel.size() / 2];
}

// --fov is the field of view across the sensor's width: a portrait photo of the camera (stored
// 320x240, EXIF orientation 6, shown 240x320) has it across its height, as a lens file turned for
// it would (it had it across its 240 pixels: a focal length of 100.7 pixels, not 134.3).
TEST(PhotoLens, AFieldOfViewIsTheSensorsAndTurnsWithThePhoto) {
  PhotoHeader landscape;
  landscape.width = 320;
  landscape.height = 240;
  PhotoHeader portrait = landscape;
  portrait.width = 240;
  portrait.height = 320;
  const double expected = 160.0 / std::tan(50.0 * std::numbers::pi / 180.0);
  const calib::Lens wide = photoLens("a.jpg", landscape, std::nullopt, 100.0, false);
  EXPECT_NEAR(wide.fx, expected, 1e-6);
  for (int orientation : {6, 8, 5, 7}) {
    portrait.orientation = orientation;
    const calib::Lens turned = photoLens("b.jpg", portrait, std::nullopt, 100.0, false);
    EXPECT_NEAR(turned.fx, expected, 1e-6) << "orientation " << orientation;
    EXPECT_NEAR(turned.fy, expected, 1e-6) << "orientation " << orientation;
    EXPECT_EQ(turned.width, 240);
    EXPECT_EQ(turned.height, 320);
    EXPECT_NEAR(turned.cx, 120.0, 1e-6);
    EXPECT_NEAR(turned.cy, 160.0, 1e-6);
  }
}

// The seam measure's own geometry: across every face edge, the first texel beyond is the
// neighbouring face's edge texel and the second is the one next to it, one texel further from the
// edge (the measure compares the step across the edge with those inner steps).
TEST(SeamMeasure, StepsOffAFaceOneTexelAtATime) {
  for (const int n : {16, 128, 256}) {
    for (int f = 0; f < lighting::kCubeFaces; ++f) {
      for (int e = 0; e < 4; ++e) {
        const int dx = e == 0 ? -1 : e == 1 ? 1 : 0, dy = e == 2 ? -1 : e == 3 ? 1 : 0;
        for (int i = 1; i + 1 < n; ++i) {
          const int x = dx < 0 ? 0 : dx > 0 ? n - 1 : i, y = dy < 0 ? 0 : dy > 0 ? n - 1 : i;
          int g1, x1, y1, g2, x2, y2;
          compose::testing::texelBeyondEdge(n, f, x, y, dx, dy, 1, g1, x1, y1);
          compose::testing::texelBeyondEdge(n, f, x, y, dx, dy, 2, g2, x2, y2);
          ASSERT_NE(g1, f);
          ASSERT_EQ(g2, g1) << "n " << n << " face " << f << " edge " << e << " at " << i;
          const bool onEdge = x1 == 0 || x1 == n - 1 || y1 == 0 || y1 == n - 1;
          EXPECT_TRUE(onEdge) << "n " << n << " face " << f << " edge " << e << " at " << i;
          // One step inwards from the neighbour's edge, along one axis (corners left aside).
          if (i >= 2 && i + 2 < n) {
            EXPECT_EQ(std::abs(x2 - x1) + std::abs(y2 - y1), 1)
                << "n " << n << " face " << f << " edge " << e << " at " << i << ": (" << x1 << ", "
                << y1 << ") then (" << x2 << ", " << y2 << ")";
          }
        }
      }
    }
  }
}

// The level step tells a step from a gradient: a map that varies smoothly with direction has
// none, the same map with one face 3 % brighter has one at that face's edges, larger than the
// texel-to-texel variation there.
TEST(SeamMeasure, LevelStepSeesAGainNotAGradient) {
  const int n = 128;
  CubeMap smooth(n);
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) {
        const glm::dvec3 d = glm::normalize(lighting::faceImageDirection(
            f, -1.0 + (2.0 * x + 1.0) / n, -1.0 + (2.0 * y + 1.0) / n));
        float* t = smooth.texel(f, x, y);
        t[0] = float(2.0 + d.x + 0.5 * d.y);
        t[1] = float(2.0 + d.y);
        t[2] = float(2.0 - d.z + 0.3 * d.x * d.y);
      }
  const double smoothStep = compose::testing::worstLevelStep(smooth, smooth);
  EXPECT_LT(smoothStep, 0.1);
  CubeMap gained = smooth;
  for (float& v : gained.face(2)) v *= 1.03f;
  const double gainedStep = compose::testing::worstLevelStep(gained, smooth);
  EXPECT_GT(gainedStep, 2.0);
  std::printf("level step: smooth map %.4f, one face 3 %% brighter %.2f\n", smoothStep, gainedStep);
}

// The issue's test: six views of each sample HDRI, 100° field of view, orientations off by up to
// ±3° about each axis, stitched within 5 % median relative error of the ground truth, with no
// seam at the face edges. The ground truth is the HDRI's exact cube map at the stitch's face size
// (256², the map's resolution on the equator); the virtual camera integrates that cube over its
// pixels (768² per view, 2 x 2 rays per pixel).
class StitchSample : public ::testing::TestWithParam<const char*> {};

TEST_P(StitchSample, SixViewsWithinFivePercentAndSeamless) {
  const char* name = GetParam();
  const Environment env = testing::loadSampleEnvironment(name);
  if (env.width() == 0) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  const int n = 256;
  const CubeMap truth = lighting::cubeFromLatLong(env, n);
  const lighting::FilteredCube scene(truth);
  const Capture capture = sixViews(scene, 768, 100.0, 3.0, 7);
  StitchOptions options;
  options.faceSize = n;
  const auto start = std::chrono::steady_clock::now();
  const StitchResult r = stitch(
      capture.photos, [&](int i) { return capture.images[size_t(i)]; }, options);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  const double median = medianRelative(truth, r.cube);
  // Measured 1.1 / 4.0 / 0.8 / 0.2 % (forest's texels differ from their neighbours by 38 % on
  // average, so that any resampling shows).
  constexpr double kIssueMedian = 0.05;
  EXPECT_LT(median, kIssueMedian) << name;

  // Orientations: every photo that matched a neighbour is put right to well under a texel (0.35°
  // at the face centres); the rough ones were up to 3.2° off.
  double worstRefined = 0.0;
  int refined = 0;
  for (int i = 0; i < kCubeFaces; ++i) {
    if (r.correctionDegrees[size_t(i)] == 0.0) continue;  // matched nothing: kept as given
    ++refined;
    worstRefined = std::max(
        worstRefined, rotationDegrees(r.worldFromCamera[size_t(i)], capture.truth[size_t(i)]));
  }
  EXPECT_GE(refined, 5) << name;
  // Measured within 0.046 / 0.043 / 0.073 / 0.045°. Sunset's featureless sky view matches no
  // other photo and is aligned on the radiance of its overlaps; the group is then put where all
  // six rough orientations say (with five, the sky view's rough error moved the map by 0.65°).
  constexpr double kRefinedDegrees = 0.15;
  EXPECT_LT(worstRefined, kRefinedDegrees) << name;

  // Seams, on 128² faces (the stitch and the truth reduced exactly), where a texel at a face edge
  // is as large as the HDRI's own texels: at every face edge, the step across the edge is no larger
  // than the neighbouring texel-to-texel variation, or than the step the scene itself has there.
  const CubeMap stitched128 = lighting::resizeCube(r.cube, 128);
  const CubeMap truth128 = lighting::resizeCube(truth, 128);
  const double worstSeam = compose::testing::worstSeam(stitched128, truth128);
  const double levelStep = compose::testing::worstLevelStep(stitched128, truth128);
  // Measured 0.99 / 0.94 / 0.99 / 0.996 (sunset was at 1.07 while its map was turned by 0.65°:
  // the scene's own step at an edge is measured on the truth as it lies).
  constexpr double kSeam = 1.0;
  EXPECT_LT(worstSeam, kSeam) << name;
  // The level step across the edges (seams.h: continuity across an edge against beside it, which
  // texture and noise do not sway), measured 0.44 / 0.47 / 0.998 / 0.52; interior's is where an
  // edge cuts its lamp and the scene itself steps as much.
  constexpr double kLevelStep = 1.1;
  EXPECT_LT(levelStep, kLevelStep) << name;
  EXPECT_EQ(r.coverage.uncovered, 0.0) << "six 100° views cover the sphere";
  std::printf(
      "%-10s median relative error %.4f, orientations within %.3f deg (%d refined), worst "
      "seam %.2f, worst level step %.3f, %.2f s\n",
      name, median, worstRefined, refined, worstSeam, levelStep, seconds);
}

INSTANTIATE_TEST_SUITE_P(SampleHdris, StitchSample,
                         ::testing::Values("courtyard", "forest", "interior", "sunset"));

// One photo taken a stop and a half brighter: its gain brings it back.
TEST(Stitch, GainsRecoverAnExposureDifference) {
  const Environment env = testing::loadSampleEnvironment("forest");
  if (env.width() == 0) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  const lighting::FilteredCube scene(lighting::cubeFromLatLong(env, 128));
  Capture capture = sixViews(scene, 384, 100.0, 1.0, 3);
  const float brighter = 2.8f;
  for (float& v : capture.images[4].pixels) v *= brighter;
  StitchOptions options;
  options.faceSize = 64;
  const StitchResult r = stitch(
      capture.photos, [&](int i) { return capture.images[size_t(i)]; }, options);
  double others = 0.0;
  for (int i = 0; i < kCubeFaces; ++i)
    if (i != 4) others += std::log(double(r.gains[size_t(i)])) / 5.0;
  const double relative = std::exp(std::log(double(r.gains[4])) - others);
  // Medians of log ratios at a few hundred matched keypoints: about 1 %.
  EXPECT_NEAR(relative * brighter, 1.0, 0.03) << "gain of the brighter photo " << relative;
}

// Fisheye photos: six 140° equidistant views (each reaching 70° from its axis, well past the
// cube face), with a little barrel distortion in the lens model.
TEST(Stitch, FisheyeViews) {
  const Environment env = testing::loadSampleEnvironment("forest");
  if (env.width() == 0) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  const CubeMap truth = lighting::cubeFromLatLong(env, 64);
  const lighting::FilteredCube scene(truth);
  calib::Lens lens = calib::Lens::fromFieldOfView(560, 560, 140.0, calib::Projection::Equidistant);
  lens.distortion = {-0.02, 0.003, 0.0, 0.0};
  std::vector<glm::dmat3> nominal;
  for (int f = 0; f < kCubeFaces; ++f) nominal.push_back(faceCameraRotation(f));
  const Capture capture = views(scene, lens, nominal, 2.0, 21);
  const std::vector<StitchPhoto>& photos = capture.photos;
  const std::vector<Image>& images = capture.images;
  StitchOptions options;
  options.faceSize = 64;
  const StitchResult r = stitch(
      photos, [&](int i) { return images[size_t(i)]; }, options);
  int refined = 0;
  for (double c : r.correctionDegrees) refined += c > 0.0 ? 1 : 0;
  EXPECT_EQ(refined, 6) << "the wide overlaps match";
  EXPECT_EQ(r.coverage.uncovered, 0.0);
  const double median = medianRelative(truth, r.cube);
  // As the 100° test, at 64² faces.
  constexpr double kIssueMedian = 0.05;
  EXPECT_LT(median, kIssueMedian);
  std::printf("fisheye 140 degrees: median relative error %.4f\n", median);
  for (int i = 0; i < kCubeFaces; ++i) {
    // A tenth of a 64² texel (1.4°).
    EXPECT_LT(rotationDegrees(r.worldFromCamera[size_t(i)], capture.truth[size_t(i)]), 0.2) << i;
  }
}

// Circular fisheyes: three level 180° views 120° apart, black beyond their image circle (a
// quarter of each frame, the corners). The black is no picture: the stitch leaves it to the other
// photos instead of averaging it in, which darkened the map by up to half where two circles meet.
TEST(Stitch, TheBlackAroundAFisheyesImageCircleIsNotPicture) {
  const Environment env = testing::loadSampleEnvironment("interior");
  if (env.width() == 0) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  const CubeMap truth = lighting::cubeFromLatLong(env, 64);
  const lighting::FilteredCube scene(truth);
  const calib::Lens lens =
      calib::Lens::fromFieldOfView(400, 400, 180.0, calib::Projection::Equidistant);
  std::vector<StitchPhoto> photos;
  std::vector<Image> images;
  int black = 0;
  for (int k = 0; k < 3; ++k) {
    const glm::dmat3 r = cameraRotation(120.0 * k, 0.0, 0.0);
    photos.push_back({"view " + std::to_string(k), lens, r, 0.0f});
    Image img = renderView(scene, lens, r, 2);
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) {
        glm::dvec3 d;
        if (lens.direction(x, y, d) && -d.z >= 0.0) continue;  // within 90° of the axis
        for (int c = 0; c < 3; ++c) img.at(x, y)[c] = 0.0f;
        black += k == 0;
      }
    images.push_back(std::move(img));
  }
  ASSERT_GT(black, 400 * 400 / 5) << "the corners are black";
  StitchOptions options;
  options.faceSize = 64;
  options.refine = false;
  options.gains = false;
  const StitchResult r = stitch(
      photos, [&](int i) { return images[size_t(i)]; }, options);
  // Every texel within 60° of the horizon, where the circles meet: no darker than the scene.
  std::vector<double> ratios;
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < truth.size(); ++y)
      for (int i = 0; i < truth.size(); ++i) {
        if (std::abs(glm::normalize(truth.direction(f, i, y)).y) > 0.85) continue;
        const glm::vec3 a = truth.radiance(f, i, y), b = r.cube.radiance(f, i, y);
        if (a.x + a.y + a.z > 1e-3f) ratios.push_back(double(b.x + b.y + b.z) / (a.x + a.y + a.z));
      }
  std::sort(ratios.begin(), ratios.end());
  const double darker =
      double(std::lower_bound(ratios.begin(), ratios.end(), 0.9) - ratios.begin()) /
      double(ratios.size());
  std::printf("fisheye circles: %.2f %% of the texels 10 %% darker than the scene, median %.3f\n",
              100.0 * darker, ratios[ratios.size() / 2]);
  EXPECT_NEAR(ratios[ratios.size() / 2], 1.0, 0.02);
  // Measured: 1.7 % (1.6 % from full frames without the black: the 64² faces' own blur of the
  // lamps); 10.0 % when the black was averaged in.
  EXPECT_LT(darker, 0.03);
}

// More photos with a narrower lens: a ring of six 75° views and straight up and down. The bands
// between the ring and the poles are seen by no photo: filled, and reported.
TEST(Stitch, NarrowLensRingWithHolesFilledAndReported) {
  const Environment env = testing::loadSampleEnvironment("courtyard");
  if (env.width() == 0) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  const lighting::FilteredCube scene(lighting::cubeFromLatLong(env, 128));
  const calib::Lens lens = calib::Lens::fromFieldOfView(320, 320, 75.0);
  std::vector<StitchPhoto> photos;
  std::vector<Image> images;
  std::vector<glm::dmat3> truth;
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> off(-2.0, 2.0);
  auto shoot = [&](double yaw, double pitch) {
    const glm::dmat3 nominal = cameraRotation(yaw, pitch, 0.0);
    // Drawn in a fixed order: C++ leaves the order of a call's argument evaluation unspecified
    // (GCC and clang differ); this is the order GCC builds used for the published figures.
    const double dRoll = off(rng), dPitch = off(rng), dYaw = off(rng);
    const glm::dmat3 real = nominal * cameraRotation(dYaw, dPitch, dRoll);
    truth.push_back(real);
    images.push_back(renderView(scene, lens, real, 2));
    photos.push_back({"yaw " + std::to_string(int(yaw)) + " pitch " + std::to_string(int(pitch)),
                      lens, nominal, 0.0f});
  };
  for (int k = 0; k < 6; ++k) shoot(60.0 * k, 0.0);
  shoot(0.0, 90.0);
  shoot(0.0, -90.0);
  StitchOptions options;
  options.faceSize = 64;
  const StitchResult r = stitch(
      photos, [&](int i) { return images[size_t(i)]; }, options);
  // Bands between 37.5° and 52.5° of elevation (0.18 of the sphere), less what the frames'
  // corners reach: measured 0.16.
  EXPECT_GT(r.coverage.uncovered, 0.05);
  EXPECT_LT(r.coverage.uncovered, 0.19);
  for (int f = 0; f < kCubeFaces; ++f)
    for (float v : r.cube.face(f)) ASSERT_TRUE(std::isfinite(v) && v >= 0.0f);
  // The ring overlaps by 15°: those orientations are found (up to the unobservable common part,
  // well under the 2° the photos were off).
  int refined = 0;
  for (int k = 0; k < 6; ++k) {
    if (r.correctionDegrees[size_t(k)] == 0.0) continue;
    ++refined;
    EXPECT_LT(rotationDegrees(r.worldFromCamera[size_t(k)], truth[size_t(k)]), 1.0) << k;
  }
  EXPECT_GE(refined, 5);
  std::printf("ring of 6 + 2 at 75 degrees: %.3f of the sphere filled\n", r.coverage.uncovered);
}

// A face no photo saw is filled from its rim: a bright sky (10) over dark ground (0.2) with the
// down view missing fills the nadir with the ground's light. (The pyramid's coarse levels average
// whole faces, sky and ground alike: the forest capture's nadir came out 6-7 times too bright.)
TEST(Coverage, AFaceNoPhotoSawIsFilledFromItsRim) {
  const int n = 64;
  CubeMap cube(n);
  std::vector<float> weight(size_t(kCubeFaces) * size_t(n) * size_t(n), 1.0f);
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        float* p = cube.texel(f, x, y);
        const float v = cube.direction(f, x, y).y > 0.0f ? 10.0f : 0.2f;
        p[0] = p[1] = p[2] = v;
        if (f == 3) {  // -Y, the down view
          p[0] = p[1] = p[2] = 0.0f;
          weight[(size_t(f) * size_t(n) + size_t(y)) * size_t(n) + size_t(x)] = 0.0f;
        }
      }
    }
  }
  ASSERT_LT(cube.direction(3, n / 2, n / 2).y, -0.99f);
  const CoverageReport report = fillUncovered(cube, weight);
  EXPECT_NEAR(report.uncovered, 1.0 / 6.0, 1e-6);
  float worst = 0.0f;
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) worst = std::max(worst, cube.texel(3, x, y)[0]);
  EXPECT_NEAR(cube.texel(3, n / 2, n / 2)[0], 0.2f, 0.02f) << "the nadir";
  EXPECT_LT(worst, 0.3f) << "the down face holds the ground's light, not the sky's";
}

}  // namespace
}  // namespace compose::cubemap
