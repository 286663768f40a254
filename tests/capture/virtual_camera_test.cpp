// The virtual camera: view orientations, where a known direction lands in the picture,
// determinism, the files it writes and what ingest reads back from them.
#include "capture/virtual_camera.h"

#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>

#include <glm/geometric.hpp>

#include "hdr/response.h"
#include "ingest/capture.h"
#include "test_util.h"

namespace compose::capture {
namespace {

using compose::testing::TempDir;

// An environment of constant radiance 0.1 with one bright texel nearest to `direction`.
lighting::Environment spotEnvironment(const glm::vec3& direction, float bright = 50.0f) {
  Image img(128, 64, 3);
  std::fill(img.pixels.begin(), img.pixels.end(), 0.1f);
  const auto probe = lighting::Environment::fromLatLong(img);
  int bx = 0, by = 0;
  float best = -2.0f;
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 128; ++x) {
      const float d = glm::dot(probe.direction(x, y), glm::normalize(direction));
      if (d > best) best = d, bx = x, by = y;
    }
  float* p = img.at(bx, by);
  p[0] = p[1] = p[2] = bright;
  return lighting::Environment::fromLatLong(img);
}

VirtualCameraParams tiny() {
  VirtualCameraParams p;
  p.width = 96;
  p.height = 72;
  p.supersample = 2;
  p.brackets = 3;
  return p;
}

glm::ivec2 brightest(const Image& img) {
  glm::ivec2 at(0);
  float best = -1.0f;
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x)
      if (img.at(x, y)[1] > best) best = img.at(x, y)[1], at = {x, y};
  return at;
}

TEST(VirtualCamera, SixViewsAreHeldAsAPhotographerHoldsThem) {
  const auto views = viewDirections(6);
  ASSERT_EQ(views.size(), 6u);
  auto forward = [](const glm::dmat3& m) { return -m[2]; };
  auto top = [](const glm::dmat3& m) { return m[1]; };
  const std::vector<std::tuple<std::string, glm::dvec3, glm::dvec3>> want = {
      {"px", {1, 0, 0}, {0, 1, 0}},   {"nx", {-1, 0, 0}, {0, 1, 0}}, {"py", {0, 1, 0}, {0, 0, 1}},
      {"ny", {0, -1, 0}, {0, 0, -1}}, {"pz", {0, 0, 1}, {0, 1, 0}},  {"nz", {0, 0, -1}, {0, 1, 0}}};
  for (size_t i = 0; i < 6; ++i) {
    EXPECT_EQ(views[i].first, std::get<0>(want[i]));
    EXPECT_NEAR(glm::length(forward(views[i].second) - std::get<1>(want[i])), 0.0, 1e-12);
    EXPECT_NEAR(glm::length(top(views[i].second) - std::get<2>(want[i])), 0.0, 1e-12);
    EXPECT_NEAR(glm::determinant(views[i].second), 1.0, 1e-12);
  }
  // The up and down views are the -Z view tilted: they share its right-hand direction.
  EXPECT_NEAR(glm::length(views[2].second[0] - views[5].second[0]), 0.0, 1e-12);
  EXPECT_NEAR(glm::length(views[3].second[0] - views[5].second[0]), 0.0, 1e-12);
  // Any other count: a ring around the horizon, starting at -Z.
  const auto ring = viewDirections(4);
  EXPECT_EQ(ring[1].first, "yaw090");
  EXPECT_NEAR(glm::length(forward(ring[1].second) - glm::dvec3(-1, 0, 0)), 0.0, 1e-12);
}

TEST(VirtualCamera, ABrightDirectionLandsWhereTheViewLooks) {
  VirtualCameraParams p = tiny();
  p.noise = false;
  p.views = 6;
  p.exposureTime = 1.0 / 64;
  // Above the +Z view's centre, and seen by the up view towards its image top (+Z).
  const auto env = spotEnvironment({0.0f, 0.35f, 1.0f});
  const SimulatedCapture c = simulateCapture(env, p);
  const auto pz = brightest(c.views[4].truth);
  EXPECT_NEAR(pz.x, p.width / 2, 2);
  EXPECT_LT(pz.y, p.height / 2 - 5);
  const auto up = spotEnvironment({0.0f, 1.0f, 0.35f});
  const SimulatedCapture u = simulateCapture(up, p);
  const auto py = brightest(u.views[2].truth);
  EXPECT_NEAR(py.x, p.width / 2, 2);
  EXPECT_LT(py.y, p.height / 2 - 5) << "the up view's image top points to +Z";
  const auto ny = brightest(u.views[3].truth);  // the down view does not see it
  EXPECT_LT(u.views[3].truth.at(ny.x, ny.y)[1], 1.0f);
}

TEST(VirtualCamera, SameSeedSamePhotosOtherSeedOtherNoise) {
  const auto env = spotEnvironment({1, 0, 0});
  VirtualCameraParams p = tiny();
  p.views = 1;
  const SimulatedCapture a = simulateCapture(env, p), b = simulateCapture(env, p);
  EXPECT_EQ(a.views[0].shots[1].codes.pixels, b.views[0].shots[1].codes.pixels);
  p.seed = 2;
  const SimulatedCapture c = simulateCapture(env, p);
  EXPECT_NE(a.views[0].shots[1].codes.pixels, c.views[0].shots[1].codes.pixels);
  // Exposures 2 EV apart around the middle one.
  EXPECT_NEAR(a.views[0].shots[2].exposureTime / a.views[0].shots[1].exposureTime, 4.0, 1e-12);
  EXPECT_NEAR(a.views[0].shots[1].exposureTime, a.middleExposureTime, 0.0);
}

TEST(VirtualCamera, FisheyeSeesNothingOutsideItsImageCircle) {
  const auto env = spotEnvironment({0, 0, -1});
  VirtualCameraParams p = tiny();
  p.views = 1;
  p.noise = false;
  p.projection = calib::Projection::Equidistant;
  p.fovDegrees = 180.0;
  const SimulatedCapture c = simulateCapture(env, p);
  EXPECT_EQ(c.views[0].truth.at(0, 0)[0], 0.0f);  // the corner is beyond 90 degrees
  EXPECT_GT(c.views[0].truth.at(48, 36)[0], 0.0f);
}

// Without --supersample the camera takes as many rays per pixel as the environment's detail
// needs: several when a pixel spans more than a texel (one ray would alias the map's detail), one
// when the photo is finer than the map (its bilinear lookups are smooth already).
TEST(VirtualCamera, AutomaticSupersamplingFollowsTheEnvironmentsDetail) {
  // Stripes one texel wide: the finest detail a map holds.
  auto stripes = [](int width) {
    Image img(width, width / 2, 3);
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) std::fill_n(img.at(x, y), 3, x % 2 ? 1.0f : 0.02f);
    return lighting::Environment::fromLatLong(img);
  };
  auto truthOf = [](const lighting::Environment& env, int size, std::optional<int> s) {
    VirtualCameraParams p = tiny();
    p.width = p.height = size;
    p.views = 1;
    p.brackets = 1;
    p.noise = false;
    p.blurPixels = 0.0;
    p.supersample = s;
    return simulateCapture(env, p);
  };
  auto rms = [](const Image& a, const Image& b) {
    double sum = 0.0;
    for (size_t i = 0; i < a.pixels.size(); ++i) sum += std::pow(a.pixels[i] - b.pixels[i], 2.0);
    return std::sqrt(sum / double(a.pixels.size()));
  };
  // A 32-pixel photo across 100° of a 256-texel map: a pixel spans about three texels.
  const lighting::Environment fine = stripes(256);
  const SimulatedCapture chosen = truthOf(fine, 32, std::nullopt);
  const SimulatedCapture one = truthOf(fine, 32, 1), many = truthOf(fine, 32, 16);
  EXPECT_GE(chosen.supersample, 3);
  EXPECT_LE(chosen.supersample, 8);
  const double chosenError = rms(chosen.views[0].truth, many.views[0].truth);
  const double oneError = rms(one.views[0].truth, many.views[0].truth);
  EXPECT_LT(chosenError, 0.25 * oneError) << "S = " << chosen.supersample;
  // A 256-pixel photo of a 64-texel map: one ray, and it agrees with many.
  const lighting::Environment coarse = stripes(64);
  const SimulatedCapture single = truthOf(coarse, 256, std::nullopt);
  EXPECT_EQ(single.supersample, 1);
  EXPECT_LT(rms(single.views[0].truth, truthOf(coarse, 256, 16).views[0].truth), 0.02);
  std::printf(
      "[ figures ] 32-pixel photo of 1-texel stripes: RMS error vs 16x16 rays %.4f with "
      "S = %d (automatic), %.4f with S = 1\n",
      chosenError, chosen.supersample, oneError);
}

// The codes by search among the boundaries are the codes of rounding the curve: on both sides of
// every boundary, and over the range (linearly and logarithmically spaced), for every kind of
// curve. At a boundary itself, within a few units of the last place, the curve evaluated in
// floating point is not monotone (filmic:0.5 crosses code 167 at two adjacent doubles), and
// either code is as right.
TEST(VirtualCamera, CodesBySearchAreTheRoundedCurve) {
  for (const char* text :
       {"filmic", "filmic:0.5", "filmic:1e-4", "srgb", "gamma:2.2", "gamma:0.5"}) {
    const CameraCurve curve = CameraCurve::parse(text);
    const CodeThresholds codeOf(curve);
    auto rounded = [&](double s) { return int(std::round(255.0 * curve.encode(s))); };
    int checked = 0;
    for (int k = 1; k <= 255; ++k) {
      // Where the rounded curve reaches code k, by bisection (the test's own), then a millionth
      // of a percent to either side.
      double lo = 0.0, hi = 1.0;
      if (rounded(0.0) >= k) continue;
      while (std::nextafter(lo, hi) < hi) {
        const double m = lo + 0.5 * (hi - lo);
        (rounded(m) >= k ? hi : lo) = m;
      }
      for (double s : {hi * (1.0 + 1e-8), lo * (1.0 - 1e-8)}) {
        EXPECT_EQ(codeOf(s), rounded(s)) << text << " at s = " << s << " (code " << k << ")";
        ++checked;
      }
      EXPECT_LE(std::abs(codeOf(hi) - rounded(hi)), 1) << text;
    }
    for (int i = 0; i <= 100000; ++i) {
      const double linear = i / 100000.0, logarithmic = std::exp2(-30.0 * i / 100000.0);
      EXPECT_EQ(codeOf(linear), rounded(linear)) << text << " at s = " << linear;
      EXPECT_EQ(codeOf(logarithmic), rounded(logarithmic)) << text << " at s = " << logarithmic;
    }
    EXPECT_GT(checked, 2 * 200) << text;
  }
}

TEST(VirtualCamera, CurvesInvertAndParse) {
  for (const char* text : {"filmic", "filmic:0.5", "srgb", "gamma:2.4"}) {
    const CameraCurve c = CameraCurve::parse(text);
    double previous = -1.0;
    for (int i = 0; i <= 1000; ++i) {
      const double s = i / 1000.0;
      const double v = c.encode(s);
      EXPECT_GT(v, previous) << text;
      previous = v;
      EXPECT_NEAR(c.decode(v), s, 1e-9) << text;
    }
    EXPECT_NEAR(c.encode(1.0), 1.0, 1e-12) << text;
  }
  COMPOSE_EXPECT_ERROR(CameraCurve::parse("log"), "unknown response curve 'log'");
  COMPOSE_EXPECT_ERROR(CameraCurve::parse("gamma:-1"), "bad number");
}

TEST(VirtualCamera, FilesCarryExifTheDescriptionAndTheGroundTruth) {
  TempDir dir;
  const auto env = spotEnvironment({0, 0, -1});
  VirtualCameraParams p = tiny();
  p.views = 6;
  p.write35mm = false;  // as many phones: ingest derives it from the focal-plane resolution
  const SimulatedCapture c = simulateCapture(env, p);
  const CaptureFiles f = writeCapture(dir / "shots", c);
  EXPECT_EQ(f.photos.size(), 18u);
  ingest::Capture back = ingest::readCaptureDescription(f.description);
  ASSERT_EQ(back.views.size(), 6u);
  EXPECT_EQ(back.lensFile, f.lens);
  EXPECT_EQ(back.groundTruth, f.truth);
  EXPECT_EQ(back.views[2].name, "py");
  ASSERT_TRUE(back.views[2].worldFromCamera);
  EXPECT_NEAR(glm::length((*back.views[2].worldFromCamera)[1] - glm::dvec3(0, 0, 1)), 0.0, 1e-12);
  // EXIF as a camera writes it.
  const ingest::CaptureInfo& exif = back.views[0].shots[0].info;
  ASSERT_TRUE(exif.exposureTime && exif.fNumber && exif.iso && exif.focalLengthMm);
  EXPECT_NEAR(*exif.exposureTime, c.views[0].shots[0].exposureTime,
              1e-4 * c.views[0].shots[0].exposureTime + 1e-6);
  EXPECT_EQ(*exif.fNumber, 8.0);
  EXPECT_EQ(*exif.iso, 100.0);
  EXPECT_EQ(exif.camera(), "compose virtual camera");
  ASSERT_TRUE(exif.focalLength35mm);
  const double fov35 = 2.0 * std::atan(43.266615305567875 * 0.8 / 2.0 / *exif.focalLength35mm);
  EXPECT_NEAR(fov35 * 180.0 / 3.14159265358979, 100.0, 0.5)
      << "the derived 35 mm equivalent gives back the horizontal field of view (4:3 frame)";
  EXPECT_NE(exif.focal35mmSource.find("derived"), std::string::npos);
  // Grouping by EXIF times alone finds the six views too.
  const auto grouped =
      ingest::groupByExif(ingest::scanShots({dir / "shots"}), ingest::ExifGrouping{});
  EXPECT_EQ(grouped.views.size(), 6u);
  // The true response, as a response file.
  const hdr::ResponseCurve truth = hdr::readResponse(f.response);
  EXPECT_NEAR(truth.inverse[1][128], p.curve.decode(128.0 / 255.0), 1e-6);
  // Nothing but the outputs in the folder.
  int files = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir / "shots")) {
    EXPECT_NE(e.path().filename().string()[0], '.') << e.path();
    ++files;
  }
  EXPECT_EQ(files, 18 + 4);
}

// A shot's capture time is a time of day: 125 views half a minute apart end at 13:02, which was
// written 12:62:00 (no time, so that ingest could not group the photos by their times).
TEST(VirtualCamera, CaptureTimesCarryIntoTheHours) {
  VirtualCameraParams p = tiny();
  p.width = 16;
  p.height = 16;
  p.supersample = 1;
  p.brackets = 1;
  p.fovDegrees = 20.0;
  p.views = 125;
  const SimulatedCapture c =
      simulateCapture(lighting::Environment::constant(glm::vec3(0.5f), 16), p);
  ASSERT_EQ(c.views.size(), 125u);
  EXPECT_EQ(c.views[1].shots[0].exif.dateTimeOriginal, "2024:06:01 12:00:30");
  EXPECT_EQ(c.views[124].shots[0].exif.dateTimeOriginal, "2024:06:01 13:02:00");
}

TEST(VirtualCamera, BadParametersAreRefused) {
  VirtualCameraParams p = tiny();
  p.brackets = 0;
  COMPOSE_EXPECT_ERROR(p.validate(), "brackets");
  p = tiny();
  p.fovDegrees = 180.0;
  COMPOSE_EXPECT_ERROR(p.validate(), "field of view");
  p = tiny();
  p.evStep = -1;
  COMPOSE_EXPECT_ERROR(p.validate(), "--ev-step");
  // EXIF's ISO is whole (150.5 was written as 151); infinite noise is no camera (it wrote white
  // or pure noise); every shot of a bracket is within a shutter's range, not only the middle one
  // (3600 s, 6 EV apart, 5 shots wrote a shot of 14,745,600 s).
  p = tiny();
  p.iso = 150.5;
  COMPOSE_EXPECT_ERROR(p.validate(), "ISO must be a whole number");
  p = tiny();
  p.fullWellElectrons = std::numeric_limits<double>::infinity();
  COMPOSE_EXPECT_ERROR(p.validate(), "both finite");
  p = tiny();
  p.readNoiseElectrons = std::numeric_limits<double>::infinity();
  COMPOSE_EXPECT_ERROR(p.validate(), "both finite");
  p = tiny();
  p.exposureTime = 3600.0;
  p.evStep = 6.0;
  p.brackets = 5;
  COMPOSE_EXPECT_ERROR(p.validate(), "the bracket's exposures (0.879 s to 1.47e+07 s)");
  p.exposureTime = 2e-9;
  p.brackets = 3;
  COMPOSE_EXPECT_ERROR(p.validate(), "must be between 1 ns and 3600 s");
  p.exposureTime = 1.0;
  EXPECT_NO_THROW(p.validate());
}

}  // namespace
}  // namespace compose::capture
