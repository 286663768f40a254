#include "calib/plate_camera.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <string>

#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "core/error.h"
#include "core/numbers.h"

namespace compose::calib {

namespace {}  // namespace

bool PlateCamera::ray(double px, double py, glm::dvec3& origin, glm::dvec3& direction) const {
  glm::dvec3 camDir;
  if (!lens.direction(px, py, camDir)) return false;
  origin = position();
  direction = glm::normalize(glm::dvec3(worldFromCamera * glm::dvec4(camDir, 0.0)));
  return true;
}

glm::dmat4 PlateCamera::cameraFromWorld() const {
  return glm::inverse(worldFromCamera);
}

bool PlateCamera::project(const glm::dvec3& world, glm::dvec2& pixel) const {
  const glm::dvec3 c = glm::dvec3(cameraFromWorld() * glm::dvec4(world, 1.0));
  if (lens.projection == Projection::Rectilinear && c.z >= -1e-9) return false;
  if (!lens.project(c, pixel)) return false;
  // Past the turning point of a distortion model (a fisheye calibration's θ_d(θ) peaks at 40° or
  // so; k1 = -0.2 turns back at 1.29 of the focal length) the polynomial folds the direction back
  // towards the centre, onto a pixel whose ray is another: not seen. The ground shadow's
  // rectangle, bounded by such pixels, stopped above the object's base.
  if (lens.hasDistortion()) {
    glm::dvec3 back;
    if (!lens.direction(pixel.x, pixel.y, back) ||
        glm::dot(glm::normalize(back), glm::normalize(c)) < 1.0 - 1e-9)
      return false;
  }
  return true;
}

void CameraOptions::validate() const {
  // Below a micrometre the scene's lengths reach the tracer's limits (Embree stopped the process
  // on a camera 1e-19 m high; from 1e-10 m the ground shadow was wrong).
  if (!(height >= 1e-6 && height <= 1e4)) {
    throw UsageError(
        "--camera-height must be a positive number of metres (1 micrometre to 10 km), got " +
        givenText(height));
  }
  if (!(std::abs(pitchDegrees) <= 89.0)) {
    throw UsageError("--pitch must be within ±89 degrees, got " + givenText(pitchDegrees));
  }
  // Below 1 mm a rectilinear view is wider than 172 degrees: no camera's plate.
  if (focal35mm && !(*focal35mm >= 1.0 && *focal35mm <= 1e4)) {
    throw UsageError("--focal35 must be a 35 mm equivalent focal length of 1 to 10000 mm, got " +
                     givenText(*focal35mm));
  }
}

void Placement::validate() const {
  const glm::dvec2 p = imagePoint;
  if (!(p.x >= 0.0 && p.x <= 1.0 && p.y >= 0.0 && p.y <= 1.0)) {
    throw UsageError("--place must be within [0,1] x [0,1] of the plate, got " + givenText(p.x) +
                     "," + givenText(p.y));
  }
  // Below a millionth of the plate's height the object's lengths reach the tracer's limits
  // (Embree stopped the process at 1e-18); it would cover no pixel anyway.
  if (!(heightFraction >= 1e-6 && heightFraction <= 10.0)) {
    throw UsageError("--scale must be in [1e-6, 10], got " + givenText(heightFraction));
  }
  if (!std::isfinite(yawDegrees)) throw UsageError("--yaw must be a finite number of degrees");
}

PlateCamera plateCamera(int width, int height, const ingest::CaptureInfo& exif,
                        const CameraOptions& options) {
  if (width <= 0 || height <= 0) throw Error("camera", "plate has no pixels");
  options.validate();
  PlateCamera cam;
  cam.width = width;
  cam.height = height;
  if (!(exif.pixelAspectRatio >= 0.01 && exif.pixelAspectRatio <= 100.0))
    throw Error("camera", "the plate's pixel aspect ratio " + numberText(exif.pixelAspectRatio) +
                              " is not one a picture has (0.01 to 100)");
  // Of the stored pixels: a quarter turn by the EXIF orientation (5 to 8) inverts it.
  const bool turned = exif.orientation >= 5 && exif.orientation <= 8;
  const double aspect = turned ? 1.0 / exif.pixelAspectRatio : exif.pixelAspectRatio;
  cam.pixelAspect = aspect;
  if (options.lens) {
    // Turned by the plate's EXIF orientation (the lens is in the sensor's frame) and scaled.
    const Lens& file = *options.lens;
    const std::optional<Lens> fitted =
        lensForImage(file, width, height, options.lensUpright ? 1 : exif.orientation);
    if (!fitted) {
      throw Error("camera", "the calibration is for " + std::to_string(file.width) + "x" +
                                std::to_string(file.height) + " images, the plate is " +
                                std::to_string(width) + "x" + std::to_string(height) +
                                " (another aspect ratio: cropped, or turned without an EXIF "
                                "orientation that says so?)");
    }
    cam.lens = *fitted;
    // On the picture as shown (a squeezed plate's stored pixels are `aspect` times as wide).
    cam.focal35mm = 0.5 * (cam.lens.fx * aspect + cam.lens.fy) /
                    std::hypot(width * aspect, double(height)) * kFullFrameDiagonalMm;
    cam.focalSource = cam.lens.source.empty() ? std::string("calibration") : cam.lens.source;
    const bool sameSize = (file.width == width && file.height == height) ||
                          (file.width == height && file.height == width);
    if (!sameSize) cam.focalSource += " (scaled to the plate's size)";
  } else {
    if (options.focal35mm) {
      cam.focal35mm = *options.focal35mm;
      cam.focalSource = "--focal35";
    } else if (exif.focalLength35mm) {
      cam.focal35mm = *exif.focalLength35mm;
      cam.focalSource =
          exif.focal35mmSource.empty() ? "EXIF FocalLengthIn35mmFilm" : exif.focal35mmSource;
    } else {
      cam.focal35mm = kDefaultFocal35mm;
      cam.focalSource = "default (no 35 mm equivalent focal length in EXIF)";
    }
    // The diagonal of the picture as shown: a squeezed plate's stored pixels are wider than high,
    // and the focal length across them shorter by as much.
    const double focalPx =
        cam.focal35mm / kFullFrameDiagonalMm * std::hypot(width * aspect, double(height));
    cam.lens.width = width;
    cam.lens.height = height;
    cam.lens.fy = focalPx;
    cam.lens.fx = focalPx / aspect;
    cam.lens.cx = 0.5 * width;
    cam.lens.cy = 0.5 * height;
    cam.lens.source = cam.focalSource;
  }
  const double pitch = options.pitchDegrees * std::numbers::pi / 180.0;
  cam.worldFromCamera = glm::translate(glm::dmat4(1.0), glm::dvec3(0.0, options.height, 0.0)) *
                        glm::rotate(glm::dmat4(1.0), -pitch, glm::dvec3(1.0, 0.0, 0.0));
  if (options.worldFromCamera) cam.worldFromCamera = *options.worldFromCamera;
  return cam;
}

double sizedExtent(const glm::dvec3& lo, const glm::dvec3& hi, bool* flat) {
  const double height = hi.y - lo.y;
  const double size = std::max({hi.x - lo.x, height, hi.z - lo.z});
  COMPOSE_CHECK(size > 0.0);
  // Bounds are floats: a mesh 0.01 high and 1 wide is 0.00999999978 high.
  const bool isFlat = !(height >= 0.01 * size * (1.0 - 1e-6));
  if (flat) *flat = isFlat;
  return isFlat ? size : height;
}

glm::dmat4 placeOnGround(const PlateCamera& camera, const Placement& placement,
                         const glm::dvec3& lo, const glm::dvec3& hi) {
  placement.validate();
  const glm::dvec2 p = placement.imagePoint;
  glm::dvec3 origin, dir;
  if (!camera.ray(p.x * camera.width, p.y * camera.height, origin, dir)) {
    throw Error("camera", "--place " + givenText(p.x) + "," + givenText(p.y) +
                              (camera.lens.hasDistortion()
                                   ? " is outside what the calibrated lens can see (its "
                                     "distortion folds that part of the frame back: it maps no "
                                     "direction there)"
                                   : " is outside what the lens can see (more than 180° off its "
                                     "axis: it maps no direction there)"));
  }
  if (!(origin.y > 0.0)) {
    // Only a pose (a chessboard seen from behind, or the pose of another photo) puts it there.
    throw Error("camera", "the camera is not above the ground plane (it is " +
                              numberText(-origin.y) +
                              " below it): the object would stand upside down behind the "
                              "camera; the chessboard must face the camera");
  }
  if (!(dir.y < -1e-6)) {
    throw Error(
        "camera",
        "--place " + givenText(p.x) + "," + givenText(p.y) +
            " is at or above the horizon, so it does not see the ground; choose a lower point"
            " or pitch the camera down");
  }
  const glm::dvec3 ground = origin + dir * (-origin.y / dir.y);
  // The world size of one pixel there: a rectilinear image scales with the ground point's depth
  // along the optical axis, a fisheye's (angle = radius / f) with its distance along the ray. (A
  // fisheye sees points more than 90° off its axis, behind the image plane: their depth is
  // negative, and the object came out scaled by a negative number, turned inside out.)
  const glm::dvec3 axis = glm::dvec3(camera.worldFromCamera * glm::dvec4(0, 0, -1, 0));
  const double depth = camera.lens.projection == Projection::Rectilinear
                           ? glm::dot(ground - origin, axis)
                           : glm::length(ground - origin);
  const double worldHeight = placement.heightFraction * camera.height * depth / camera.lens.fy;
  const double scale = worldHeight / sizedExtent(lo, hi);
  const glm::dvec3 base(0.5 * (lo.x + hi.x), lo.y, 0.5 * (lo.z + hi.z));
  // Reduced to a turn first: a finite angle of any size (1e308 degrees) is still an angle.
  const double yaw = std::fmod(placement.yawDegrees, 360.0) * std::numbers::pi / 180.0;
  return glm::translate(glm::dmat4(1.0), ground) *
         glm::rotate(glm::dmat4(1.0), yaw, glm::dvec3(0, 1, 0)) *
         glm::scale(glm::dmat4(1.0), glm::dvec3(scale)) * glm::translate(glm::dmat4(1.0), -base);
}

}  // namespace compose::calib
