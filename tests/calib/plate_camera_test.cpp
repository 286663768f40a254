#include "calib/plate_camera.h"

#include <cmath>

#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "core/error.h"
#include "test_util.h"

namespace compose::calib {
namespace {

TEST(PlateCamera, FocalLengthFromExifElseDefault) {
  ingest::CaptureInfo exif;
  const PlateCamera def = plateCamera(3000, 2000, exif, {});
  EXPECT_EQ(def.focal35mm, 50.0);
  // 50 mm on the 43.27 mm diagonal of a 3000x2000 frame.
  EXPECT_NEAR(def.lens.fx, 50.0 / 43.2666153 * std::hypot(3000.0, 2000.0), 1e-3);
  exif.focalLength35mm = 24.0;
  EXPECT_EQ(plateCamera(3000, 2000, exif, {}).focal35mm, 24.0);
  CameraOptions opt;
  opt.focal35mm = 85.0;
  EXPECT_EQ(plateCamera(3000, 2000, exif, opt).focal35mm, 85.0);
  // A full-frame 36 mm wide sensor at f = 36 mm has a 90° horizontal field for a 3:2 frame.
  exif.focalLength35mm = 18.0;
  const PlateCamera wide = plateCamera(3000, 2000, exif, {});
  EXPECT_NEAR(2.0 * std::atan(1500.0 / wide.lens.fx), std::numbers::pi / 2.0, 1e-6);
}

// A plate pose's lens was estimated on the plate as shown (upright): it is not turned again by
// the plate's EXIF orientation. Orientations 2, 3 and 4 keep the aspect ratio, so the turned lens
// fitted and won: the principal point went to the other side (46 px on a 640x480 plate turned
// 180°, and the board's corners as far off).
TEST(PlateCamera, AnUprightLensIsNotTurnedAgain) {
  Lens lens = Lens::fromFieldOfView(640, 480, 60.0);
  lens.cx = 296.6;
  lens.cy = 243.5;
  ingest::CaptureInfo exif;
  CameraOptions options;
  options.lens = lens;
  options.lensUpright = true;
  for (int orientation : {1, 2, 3, 4}) {
    exif.orientation = orientation;
    const PlateCamera cam = plateCamera(640, 480, exif, options);
    EXPECT_EQ(cam.lens.cx, lens.cx) << orientation;
    EXPECT_EQ(cam.lens.cy, lens.cy) << orientation;
  }
  // A lens in the sensor's frame (a lens file) is turned.
  options.lensUpright = false;
  exif.orientation = 3;
  EXPECT_NEAR(plateCamera(640, 480, exif, options).lens.cx, 640.0 - lens.cx, 1e-9);
}

TEST(PlateCamera, RayAndProjectAreInverse) {
  CameraOptions opt;
  opt.pitchDegrees = 10.0;
  const PlateCamera cam = plateCamera(640, 480, {}, opt);
  for (double px : {0.0, 100.5, 320.0, 639.0}) {
    for (double py : {0.0, 240.0, 479.5}) {
      glm::dvec3 o, d;
      ASSERT_TRUE(cam.ray(px, py, o, d));
      EXPECT_NEAR(glm::length(d), 1.0, 1e-12);
      glm::dvec2 back;
      ASSERT_TRUE(cam.project(o + 7.0 * d, back));
      EXPECT_NEAR(back.x, px, 1e-9);
      EXPECT_NEAR(back.y, py, 1e-9);
    }
  }
  // The centre ray of a level camera looks along -Z; pitching down tilts it below the horizon.
  glm::dvec3 o, d;
  ASSERT_TRUE(plateCamera(640, 480, {}, {}).ray(320, 240, o, d));
  EXPECT_NEAR(d.z, -1.0, 1e-12);
  ASSERT_TRUE(cam.ray(320, 240, o, d));
  EXPECT_NEAR(std::asin(-d.y), 10.0 * std::numbers::pi / 180.0, 1e-12);
}

// The limit is what the message says: ±89 degrees are accepted, beyond them refused.
TEST(PlateCamera, PitchUpTo89DegreesEitherWay) {
  for (const double pitch : {89.0, -89.0}) {
    CameraOptions opt;
    opt.pitchDegrees = pitch;
    EXPECT_NO_THROW(opt.validate()) << pitch;
  }
  CameraOptions opt;
  opt.pitchDegrees = 89.5;
  EXPECT_THROW(opt.validate(), compose::UsageError);
}

TEST(PlateCamera, PlacementStandsOnTheGroundPointAtTheRequestedSize) {
  const PlateCamera cam = plateCamera(1000, 800, {}, {});
  Placement place;
  place.imagePoint = {0.3, 0.8};
  place.heightFraction = 0.25;
  const glm::dvec3 lo(-1, 2, -3), hi(1, 6, 3);  // a 4-unit tall box floating off-centre
  const glm::dmat4 m = placeOnGround(cam, place, lo, hi);
  const glm::dvec3 base = glm::dvec3(m * glm::dvec4(0, 2, 0, 1));
  const glm::dvec3 top = glm::dvec3(m * glm::dvec4(0, 6, 0, 1));
  EXPECT_NEAR(base.y, 0.0, 1e-9) << "base on the ground plane";
  glm::dvec2 px;
  ASSERT_TRUE(cam.project(base, px));
  EXPECT_NEAR(px.x, 300.0, 1e-6);
  EXPECT_NEAR(px.y, 640.0, 1e-6);
  // Height: the world height maps to 25% of the frame at the base's depth.
  const double depth = -(glm::inverse(cam.worldFromCamera) * glm::dvec4(base, 1.0)).z;
  EXPECT_NEAR((top.y - base.y) * cam.lens.fy / depth, 0.25 * 800, 1e-6);
}

// Through a fisheye, a point more than 90° off the axis sees ground behind the image plane: the
// object stands there at the size the lens's angles give it (its depth along the axis is
// negative: it was scaled by a negative number, turned inside out, and the shadows stopped on an
// internal check).
TEST(PlateCamera, AFisheyePlacementBehindTheImagePlaneIsNotTurnedInsideOut) {
  CameraOptions options;
  options.lens = Lens::fromFieldOfView(320, 240, 220.0, Projection::Equidistant);
  const PlateCamera cam = plateCamera(320, 240, {}, options);
  Placement place;
  place.heightFraction = 0.05;
  for (const glm::dvec2 at : {glm::dvec2(0.5, 0.6), glm::dvec2(0.1, 0.9), glm::dvec2(0.02, 0.98)}) {
    place.imagePoint = at;
    const glm::dmat4 m = placeOnGround(cam, place, {0, 0, 0}, {1, 1, 1});
    EXPECT_GT(glm::determinant(glm::dmat3(m)), 0.0) << at.x << "," << at.y;
    // The object's height subtends its share of the frame's height in the lens's angles.
    const glm::dvec3 base = glm::dvec3(m * glm::dvec4(0.5, 0, 0.5, 1));
    const glm::dvec3 top = glm::dvec3(m * glm::dvec4(0.5, 1, 0.5, 1));
    EXPECT_NEAR(glm::length(top - base) / glm::length(base - cam.position()) * cam.lens.fy,
                0.05 * 240, 1e-6);
  }
}

// A direction past where the lens's distortion model turns back is not seen: the polynomial's
// pixel for it is another direction's (k1 = -0.2 peaks at 1.29 focal lengths off axis; a
// fisheye's θ_d(θ) with k1 = -0.3 at 1.054 rad, 60°). Before the turning point the projection
// inverts.
TEST(PlateCamera, DirectionsPastTheDistortionsTurningPointAreNotSeen) {
  for (const Projection projection : {Projection::Rectilinear, Projection::Equidistant}) {
    CameraOptions options;
    options.lens = Lens::fromFieldOfView(640, 480, 90.0, projection);
    options.lens->distortion = projection == Projection::Rectilinear
                                   ? std::vector<double>{-0.2, 0, 0, 0, 0}
                                   : std::vector<double>{-0.3, 0, 0, 0};
    const PlateCamera cam = plateCamera(640, 480, {}, options);
    // Off axis by tan or by the angle: 1.0 and 1.2 before the turn, 1.5 and 2.0 past it.
    const double turn = projection == Projection::Rectilinear ? 1.29 : 1.054;
    for (const double off : {0.3, 1.0, 1.2, 1.5, 2.0}) {
      const double angle = projection == Projection::Rectilinear ? std::atan(off) : off;
      const glm::dvec3 d(std::sin(angle), 0.0, -std::cos(angle));
      const glm::dvec3 world = glm::dvec3(cam.worldFromCamera * glm::dvec4(d, 1.0));
      glm::dvec2 px;
      const bool seen = cam.project(world, px);
      const double ref = projection == Projection::Rectilinear ? off : angle;
      EXPECT_EQ(seen, ref < turn) << int(projection) << " " << off;
      if (!seen) continue;
      glm::dvec3 origin, back;
      ASSERT_TRUE(cam.ray(px.x, px.y, origin, back));
      EXPECT_NEAR(glm::dot(back, glm::normalize(world - origin)), 1.0, 1e-9);
    }
  }
}

// A yaw is an angle whatever its size: 1e308 degrees turns the object as 1e308 mod 360 does (it
// overflowed to NaN before, and Embree aborted on the NaN rays).
TEST(PlateCamera, AYawOfAnySizeIsReducedToATurn) {
  const PlateCamera cam = plateCamera(1000, 800, {}, {});
  Placement place;
  place.imagePoint = {0.5, 0.8};
  for (const double yaw : {400.0, 1e308, -1e300}) {
    place.yawDegrees = yaw;
    const glm::dmat4 huge = placeOnGround(cam, place, {-1, 0, -1}, {1, 2, 1});
    place.yawDegrees = std::fmod(yaw, 360.0);
    const glm::dmat4 reduced = placeOnGround(cam, place, {-1, 0, -1}, {1, 2, 1});
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) {
        ASSERT_TRUE(std::isfinite(huge[c][r])) << yaw;
        EXPECT_EQ(huge[c][r], reduced[c][r]) << yaw;
      }
  }
}

// --scale sizes an object's height, or a flat object's largest extent (its height under 1 % of
// it). A quad with one corner raised by 1e-5 of its width is as large as the flat quad (sized
// by its height, it was 218,000 times as large and filled the frame); one 2 % as high as it is
// wide is sized by its height.
TEST(PlateCamera, AFlatObjectIsSizedByItsLargestExtent) {
  const PlateCamera cam = plateCamera(1000, 800, {}, {});
  Placement place;
  auto scaleOf = [&](double height) {
    const glm::dmat4 m = placeOnGround(cam, place, {-1, 0, -1}, {1, height, 1});
    return glm::length(glm::dvec3(m[0]));
  };
  bool flat = false;
  EXPECT_EQ(sizedExtent({-1, 0, -1}, {1, 0, 1}, &flat), 2.0);
  EXPECT_TRUE(flat);
  EXPECT_EQ(sizedExtent({-1, 0, -1}, {1, 2e-5, 1}, &flat), 2.0);
  EXPECT_TRUE(flat);
  EXPECT_EQ(sizedExtent({-1, 0, -1}, {1, 0.04, 1}, &flat), 0.04);
  EXPECT_FALSE(flat);
  // Exactly 1 % as a mesh's float bounds hold it (0.00999999978): not flat.
  EXPECT_EQ(sizedExtent({0, 0, 0}, {1, double(0.01f), 1}, &flat), double(0.01f));
  EXPECT_FALSE(flat);
  EXPECT_DOUBLE_EQ(scaleOf(2e-5), scaleOf(0.0));
  EXPECT_NEAR(scaleOf(0.04) / scaleOf(1.0), 1.0 / 0.04, 1e-9);
  EXPECT_NEAR(scaleOf(0.0) / scaleOf(1.0), 1.0 / 2.0, 1e-9);
}

TEST(PlateCamera, RejectsImpossiblePlacements) {
  const PlateCamera cam = plateCamera(1000, 800, {}, {});
  Placement sky;
  sky.imagePoint = {0.5, 0.3};
  COMPOSE_EXPECT_ERROR(placeOnGround(cam, sky, {0, 0, 0}, {1, 1, 1}), "above the horizon");
  Placement outside;
  outside.imagePoint = {1.5, 0.8};
  COMPOSE_EXPECT_ERROR(placeOnGround(cam, outside, {0, 0, 0}, {1, 1, 1}),
                       "--place must be within [0,1]");
  CameraOptions bad;
  bad.height = -1.0;
  COMPOSE_EXPECT_ERROR(plateCamera(10, 10, {}, bad), "--camera-height must be a positive");
  EXPECT_THROW(bad.validate(), UsageError) << "an option out of range is a usage error (exit 2)";
  // A pose that puts the camera under the ground plane (a board seen from behind), looking
  // down: the ground point lay behind the camera and the object was mirrored through it (an
  // internal check failed later).
  CameraOptions under;
  glm::dmat4 pose(1.0);
  pose = glm::rotate(pose, -0.3, glm::dvec3(1, 0, 0));  // pitched down
  pose[3] = glm::dvec4(0.0, -0.3, 0.0, 1.0);
  under.worldFromCamera = pose;
  const PlateCamera below = plateCamera(1000, 800, {}, under);
  Placement ground;
  ground.imagePoint = {0.5, 0.8};
  COMPOSE_EXPECT_ERROR(placeOnGround(below, ground, {0, 0, 0}, {1, 1, 1}),
                       "the camera is not above the ground plane (it is 0.3 below it)");
}

}  // namespace
}  // namespace compose::calib
