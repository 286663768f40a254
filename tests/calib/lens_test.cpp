#include "calib/lens.h"

#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "test_util.h"

namespace compose::calib {
namespace {

using compose::testing::TempDir;

// Round trips are exact up to the iterative inversions' convergence (1e-12 normalised).
constexpr double kPixelTolerance = 1e-6;

void expectRoundTrip(const Lens& lens) {
  for (double px : {0.5, 100.25, 0.5 * lens.width, lens.width - 0.5}) {
    for (double py : {0.5, 0.5 * lens.height, lens.height - 3.0}) {
      glm::dvec3 d;
      ASSERT_TRUE(lens.direction(px, py, d)) << px << ", " << py;
      EXPECT_NEAR(glm::length(d), 1.0, 1e-12);
      glm::dvec2 back;
      ASSERT_TRUE(lens.project(d * 3.0, back));
      EXPECT_NEAR(back.x, px, kPixelTolerance);
      EXPECT_NEAR(back.y, py, kPixelTolerance);
    }
  }
}

TEST(Lens, FieldOfViewAndAxes) {
  const Lens lens = Lens::fromFieldOfView(800, 600, 90.0);
  EXPECT_NEAR(lens.fx, 400.0, 1e-9);
  EXPECT_NEAR(lens.horizontalFovDegrees(), 90.0, 1e-9);
  glm::dvec3 d;
  ASSERT_TRUE(lens.direction(400.0, 300.0, d));
  EXPECT_NEAR(d.z, -1.0, 1e-12);  // the centre looks along -Z
  ASSERT_TRUE(lens.direction(800.0, 300.0, d));
  EXPECT_GT(d.x, 0.0);  // the right edge looks right (+X)
  EXPECT_NEAR(std::atan2(d.x, -d.z), std::numbers::pi / 4, 1e-12);
  ASSERT_TRUE(lens.direction(400.0, 0.0, d));
  EXPECT_GT(d.y, 0.0);  // the top row looks up (+Y)
  glm::dvec2 px;
  EXPECT_FALSE(lens.project(glm::dvec3(0, 0, 1), px)) << "behind a rectilinear lens";
}

TEST(Lens, RectilinearWithDistortionRoundTrips) {
  Lens lens = Lens::fromFieldOfView(640, 480, 70.0);
  expectRoundTrip(lens);
  // The opencv-doc left camera's calibration is of this size: barrel distortion.
  lens.distortion = {-0.29, 0.11, 0.001, -0.0006, 0.0};
  expectRoundTrip(lens);
  // Distortion moves a corner pixel's ray away from the ideal one.
  Lens ideal = lens;
  ideal.distortion.clear();
  glm::dvec3 a, b;
  ASSERT_TRUE(lens.direction(0.5, 0.5, a));
  ASSERT_TRUE(ideal.direction(0.5, 0.5, b));
  EXPECT_GT(std::acos(glm::dot(a, b)), 0.02);
  // Strong pincushion, r + k1 r³ with k1 up to 1.5, is invertible everywhere (its slope is
  // positive), though OpenCV's fixed-point iteration diverges where the slope passes 2: the
  // corners were "outside what the lens can see".
  for (const double k1 : {1.0, 1.5}) {
    SCOPED_TRACE(k1);
    lens.distortion = {k1, 0.0, 0.0, 0.0, 0.0};
    expectRoundTrip(lens);
  }
}

// A portrait photo turned upright by EXIF orientation 6 or 8, from a lens calibrated in
// landscape: the turned lens sees a direction (in the upright photo's camera frame) at the pixel
// where the stored photo shows it, turned. Off-centre principal point and tangential distortion
// make every term count.
TEST(Lens, TurnedForAnExifOrientationSeesWhatTheStoredPhotoShows) {
  Lens lens = Lens::fromFieldOfView(640, 480, 70.0);
  lens.fy = lens.fx * 1.01;
  lens.cx = 330.0;
  lens.cy = 228.0;
  lens.distortion = {-0.29, 0.11, 0.004, -0.003, 0.02};
  for (const int orientation : {6, 8, 3, 2, 4, 5, 7}) {
    SCOPED_TRACE(orientation);
    const Lens turned = lens.turnedFor(orientation);
    const bool across = orientation >= 5;  // width and height swap
    EXPECT_EQ(turned.width, across ? 480 : 640);
    EXPECT_EQ(turned.height, across ? 640 : 480);
    int checked = 0;
    for (double a = -0.5; a <= 0.5; a += 0.125) {
      for (double b = -0.4; b <= 0.4; b += 0.1) {
        const glm::dvec3 d = glm::normalize(glm::dvec3(a, b, -1.0));
        glm::dvec2 stored, seen;
        ASSERT_TRUE(lens.project(d, stored));
        // The upright photo's camera frame: for 6 its right is the stored up (+Y) and its up
        // the stored left (-X); for 8 the other way round. The mirrored ones (EXIF: 2 flips
        // left to right, 4 top to bottom, 5 transposes, 7 transposes the other way) see the
        // world mirrored, and so does their frame.
        glm::dvec3 upright;
        glm::dvec2 expected;
        switch (orientation) {
          case 6:
            upright = {d.y, -d.x, d.z}, expected = {480.0 - stored.y, stored.x};
            break;
          case 8:
            upright = {-d.y, d.x, d.z}, expected = {stored.y, 640.0 - stored.x};
            break;
          case 3:
            upright = {-d.x, -d.y, d.z}, expected = {640.0 - stored.x, 480.0 - stored.y};
            break;
          case 2:
            upright = {-d.x, d.y, d.z}, expected = {640.0 - stored.x, stored.y};
            break;
          case 4:
            upright = {d.x, -d.y, d.z}, expected = {stored.x, 480.0 - stored.y};
            break;
          case 5:
            upright = {-d.y, -d.x, d.z}, expected = {stored.y, stored.x};
            break;
          default:  // 7
            upright = {d.y, d.x, d.z}, expected = {480.0 - stored.y, 640.0 - stored.x};
        }
        ASSERT_TRUE(turned.project(upright, seen));
        EXPECT_NEAR(seen.x, expected.x, 1e-6);
        EXPECT_NEAR(seen.y, expected.y, 1e-6);
        ++checked;
      }
    }
    EXPECT_GT(checked, 50);
  }
  // Orientation 1 (and a value EXIF does not define) leaves the lens as it is.
  EXPECT_EQ(lens.turnedFor(1).cx, lens.cx);
  EXPECT_EQ(lens.turnedFor(9).cx, lens.cx);
  // A portrait tagged 5 or 7 (transposed) fits a landscape lens, as 6 and 8 do (it was refused:
  // "another aspect ratio").
  EXPECT_TRUE(lensForImage(lens, 480, 640, 5));
  EXPECT_TRUE(lensForImage(lens, 480, 640, 7));
  // lensForImage: turned and scaled for a portrait of half the size; a lens already in the
  // upright frame is taken as it is; another aspect is none.
  const std::optional<Lens> half = lensForImage(lens, 240, 320, 6);
  ASSERT_TRUE(half);
  EXPECT_NEAR(half->cx, lens.turnedFor(6).cx / 2.0, 1e-9);
  const std::optional<Lens> asIs = lensForImage(lens.turnedFor(6), 480, 640, 6);
  ASSERT_TRUE(asIs);
  EXPECT_EQ(asIs->cx, lens.turnedFor(6).cx);
  EXPECT_FALSE(lensForImage(lens, 500, 500, 1));
  // A resized plate's sides are rounded to whole pixels: 640x480 at 101 px wide is 101x76, a
  // 0.33 % change of aspect; a resizer that truncates makes a pixel of it (a 7952x5304 lens on a
  // 640x426 plate); a crop of four rows of 480, 0.84 %, moves the principal point and is refused
  // (it was scaled, 1.5 px off at the board's corners on the sample plate).
  ASSERT_EQ(lens.width, 640);
  ASSERT_EQ(lens.height, 480);
  EXPECT_TRUE(lensForImage(lens, 101, 76, 1));
  EXPECT_TRUE(lensForImage(lens, 1280, 960, 1));
  Lens large = lens;
  large.width = 7952;
  large.height = 5304;
  EXPECT_TRUE(lensForImage(large, 640, 426, 1));  // 426.9 truncated
  large.width = 1001;
  large.height = 667;
  EXPECT_TRUE(lensForImage(large, 500, 334, 1));  // 333.5 rounded up
  EXPECT_FALSE(lensForImage(lens, 640, 476, 1));
  EXPECT_FALSE(lensForImage(lens, 1280, 956, 1));
}

TEST(Lens, EquidistantFisheye) {
  Lens lens = Lens::fromFieldOfView(1000, 1000, 180.0, Projection::Equidistant);
  glm::dvec3 d;
  ASSERT_TRUE(lens.direction(1000.0, 500.0, d));  // the right edge is 90° off axis
  EXPECT_NEAR(d.x, 1.0, 1e-12);
  EXPECT_NEAR(d.z, 0.0, 1e-12);
  glm::dvec2 px;
  ASSERT_TRUE(lens.project(glm::dvec3(0.0, 1.0, 0.0), px));  // straight up: top edge
  EXPECT_NEAR(px.x, 500.0, 1e-9);
  EXPECT_NEAR(px.y, 0.0, 1e-9);
  expectRoundTrip(lens);
  lens.distortion = {0.02, -0.01, 0.002, 0.0};
  expectRoundTrip(lens);
}

TEST(Lens, FileRoundTripUsesOpenCvPixelCentres) {
  TempDir dir;
  Lens lens = Lens::fromFieldOfView(640, 480, 60.0);
  lens.cx = 342.5;
  lens.distortion = {-0.3, 0.1, 0.0, 0.0, 0.0};
  lens.rms = 0.41;
  writeLens(dir / "camera.json", lens);
  std::ifstream in(dir / "camera.json");
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"cx\": 342.0"), std::string::npos) << text;
  const Lens back = readLens(dir / "camera.json");
  EXPECT_DOUBLE_EQ(back.cx, lens.cx);
  EXPECT_DOUBLE_EQ(back.fx, lens.fx);
  EXPECT_EQ(back.distortion, lens.distortion);
  EXPECT_DOUBLE_EQ(back.rms, 0.41);
}

TEST(Lens, BadFilesNameTheProblem) {
  TempDir dir;
  COMPOSE_EXPECT_ERROR(readLens(dir / "none.json"), "lens file not found");
  compose::testing::writeText(dir / "a.json", "{\"width\": 640}");
  COMPOSE_EXPECT_ERROR(readLens(dir / "a.json"), "needs a number 'height'");
  compose::testing::writeText(dir / "b.json", "not json");
  COMPOSE_EXPECT_ERROR(readLens(dir / "b.json"), "not a valid JSON lens file");
  compose::testing::writeText(
      dir / "c.json",
      R"({"model":"pinhole","width":640,"height":480,"fx":500,"fy":500,"cx":320,"cy":240})");
  COMPOSE_EXPECT_ERROR(readLens(dir / "c.json"), "unknown lens model 'pinhole'");
  compose::testing::writeText(dir / "d.json",
                              R"({"width":640,"height":480,"fx":-5,"fy":500,"cx":320,"cy":240})");
  COMPOSE_EXPECT_ERROR(readLens(dir / "d.json"), "focal lengths fx, fy must be positive");
  // Finite but no lens's: fx = 1e308 overflowed the camera and was blamed on --place.
  compose::testing::writeText(
      dir / "e.json", R"({"width":640,"height":480,"fx":1e308,"fy":500,"cx":320,"cy":240})");
  COMPOSE_EXPECT_ERROR(readLens(dir / "e.json"),
                       "focal length 1e+308 px is not one of a 640x480 image's lens");
  compose::testing::writeText(dir / "f.json",
                              R"({"width":640,"height":480,"fx":500,"fy":2,"cx":320,"cy":240})");
  COMPOSE_EXPECT_ERROR(readLens(dir / "f.json"), "focal length 2 px");
  compose::testing::writeText(dir / "g.json",
                              R"({"width":640,"height":480,"fx":500,"fy":500,"cx":1e9,"cy":240})");
  COMPOSE_EXPECT_ERROR(readLens(dir / "g.json"), "lies far outside the image");
}

}  // namespace
}  // namespace compose::calib
