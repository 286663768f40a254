// Lens: the intrinsics of a camera (focal lengths, principal point, distortion) and the mapping
// between pixels and directions in the camera's frame. Used by the renderer (the plate camera),
// the virtual camera, stitching and lens calibration, so that all of them agree on one model.
//
// Frames and pixels:
//  * Camera frame: +X right, +Y up, the camera looks along -Z (OpenGL / glTF, as the world).
//  * Pixels: continuous coordinates with the origin at the top-left CORNER of the image, +y down;
//    pixel (x, y) covers [x, x+1) x [y, y+1) and its centre is (x + 0.5, y + 0.5).
//  * The principal point (cx, cy) and focal lengths (fx, fy) are stored in this continuous
//    convention. OpenCV puts pixel centres on integers, so cx_opencv = cx - 0.5 (likewise cy);
//    the JSON file (readLens / writeLens) stores OpenCV's convention, as OpenCV users expect.
//
// Projections (r is the distance from the principal point in normalised coordinates, θ the angle
// between the ray and the optical axis):
//  * Rectilinear (pinhole) with the Brown–Conrady distortion of OpenCV's calibrateCamera:
//    x' = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²), and likewise y'
//    (distortion = {k1, k2, p1, p2, k3}).
//  * Equidistant fisheye as OpenCV's fisheye model: r_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)
//    (distortion = {k1, k2, k3, k4}); no distortion gives the ideal equidistant lens r = f θ.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

namespace compose::calib {

enum class Projection { Rectilinear, Equidistant };

struct Lens {
  int width = 0, height = 0;  // image size the intrinsics belong to
  double fx = 0.0, fy = 0.0;  // focal lengths in pixels
  double cx = 0.0, cy = 0.0;  // principal point, continuous pixel coordinates (see above)
  Projection projection = Projection::Rectilinear;
  std::vector<double> distortion;  // see above; empty = none
  double rms = 0.0;                // reprojection error of the calibration, pixels (0: unknown)
  std::string source;              // where the intrinsics came from, for messages

  // An ideal lens (no distortion, principal point at the centre) with the given horizontal field
  // of view in degrees.
  static Lens fromFieldOfView(int width, int height, double horizontalFovDegrees,
                              Projection projection = Projection::Rectilinear);

  // Unit direction in the camera frame of the ray through continuous pixel (px, py). Returns
  // false where no ray exists (beyond a fisheye's 180° or a distortion model's valid range).
  bool direction(double px, double py, glm::dvec3& dir) const;
  // Continuous pixel of a direction in the camera frame (need not be unit). Returns false for a
  // direction the lens cannot see (behind a rectilinear lens, beyond 180° for a fisheye). The
  // pixel may lie outside the image; the caller checks. Past the turning point of a distortion
  // model the pixel is the polynomial's, folded back (PlateCamera::project refuses those).
  bool project(const glm::dvec3& dir, glm::dvec2& pixel) const;

  bool hasDistortion() const;
  // The same lens for the image resized to width x height (focal lengths and principal point
  // scale with the image; distortion is in normalised coordinates and does not change).
  Lens resized(int newWidth, int newHeight) const;
  // The same lens for its image turned as EXIF orientation 6 (turned 90° clockwise to be seen
  // upright), 8 (90° anticlockwise) or 3 (180°) turns it: a portrait photo from a lens calibrated
  // on landscape ones. For 6 and 8 width and height, the focal lengths and the principal point
  // swap; the principal point and the tangential distortion turn with the image (radial terms do
  // not change). The mirrored ones (2, 4, 5, 7) flip the principal point and p2 left to right,
  // then turn as 3, 8 or 6 do; for 2 the image's frame is mirrored, and so are the rays.
  Lens turnedFor(int exifOrientation) const;
  // Horizontal field of view in degrees across the image's width through the principal point.
  double horizontalFovDegrees() const;

  // Throws compose::Error (stage "calib") if a value is not usable; `file` names the source.
  void validate(const std::filesystem::path& file = {}) const;
};

// The lens for an image of width x height seen upright after its EXIF orientation, from a lens
// in the sensor's frame (photos as stored, which is how compose calib lens writes it): turned by
// the orientation and resized. A lens that fits the upright image as it is (a lens file
// calibrated on photos held that way) is taken as it is. Empty when neither fits the aspect
// ratio: a crop. The aspect ratios may differ by what rounding a resized image's sides to whole
// pixels makes of them (a pixel on each side, for resizers that truncate), no more: a crop of a
// few rows moves the principal point, which scaling the lens cannot follow.
std::optional<Lens> lensForImage(const Lens& lens, int width, int height, int exifOrientation);

// Lens file (JSON): {"model": "rectilinear"|"equidistant", "width", "height", "fx", "fy", "cx",
// "cy", "dist": [...], "rms"}, with cx, cy in OpenCV's pixel convention. Errors throw
// compose::Error (stage "calib") naming the file and the field.
Lens readLens(const std::filesystem::path& file);
// Written atomically (temporary file + rename).
void writeLens(const std::filesystem::path& file, const Lens& lens);
// The JSON text writeLens() writes (for writers that commit several files together).
std::string lensText(const Lens& lens);

}  // namespace compose::calib
