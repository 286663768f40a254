// The plate camera: a pinhole model of the camera that took the background photograph, and where
// a synthetic object stands in front of it.
//
// Frames (see docs/design.md §2): world is right-handed, +Y up, the ground plane is y = 0. The camera
// sits at (0, height, 0) and looks along -Z, tilted down by `pitch`. Image pixel (px, py) has its
// origin at the top-left corner of the picture, +y down; the principal point is the image centre.
//
// Field of view: from EXIF FocalLengthIn35mmFilm when present, else an explicit override, else a
// 50 mm full-frame equivalent. A 35 mm-equivalent focal length f maps to the image diagonal:
// focal_px = f / 43.27 mm * diagonal_px (43.27 mm is the 36 x 24 mm frame's diagonal).
#pragma once

#include <optional>
#include <string>

#include <glm/mat4x4.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "ingest/image_io.h"

namespace compose::calib {

inline constexpr double kFullFrameDiagonalMm = 43.266615305567875;  // sqrt(36² + 24²)
inline constexpr double kDefaultFocal35mm = 50.0;

struct PinholeCamera {
  int width = 0, height = 0;
  double focalPx = 0.0;     // focal length in pixels (square pixels)
  double focal35mm = 0.0;   // the same as a 35 mm equivalent
  std::string focalSource;  // where the focal length came from, for --explain
  glm::dmat4 worldFromCamera{1.0};

  // World-space ray through continuous pixel position (px, py); direction is unit length.
  void ray(double px, double py, glm::dvec3& origin, glm::dvec3& direction) const;
  // Projects a world point to continuous pixel coordinates; returns false if behind the camera.
  bool project(const glm::dvec3& world, glm::dvec2& pixel) const;
  glm::dvec3 position() const { return glm::dvec3(worldFromCamera[3]); }
};

struct CameraOptions {
  std::optional<double> focal35mm;  // overrides EXIF
  double height = 1.6;              // metres above the ground
  double pitchDegrees = 0.0;        // positive tilts the camera down

  // Throws compose::UsageError naming the option when a value is out of range.
  void validate() const;
};

// Validates options (throws compose::Error, stage "camera") and builds the plate camera.
PinholeCamera plateCamera(int width, int height, const ingest::CaptureInfo& exif,
                          const CameraOptions& options);

// Where and how big the object stands. `imagePoint` is in [0, 1]² of the plate (0,0 top-left):
// the object's base (centre of its bounding box's bottom face) stands on the ground point seen
// there. `heightFraction` is the object's height as a fraction of the plate's height; `yawDegrees`
// turns it about +Y (counter-clockwise seen from above).
struct Placement {
  glm::dvec2 imagePoint{0.5, 0.72};
  double heightFraction = 0.3;
  double yawDegrees = 0.0;

  // Throws compose::UsageError naming the option when a value is out of range.
  void validate() const;
};

// worldFromObject for a mesh with the given object-space bounds. Throws compose::Error (stage
// "camera") if the point is above the horizon or the numbers are out of range.
glm::dmat4 placeOnGround(const PinholeCamera& camera, const Placement& placement,
                         const glm::dvec3& boundsMin, const glm::dvec3& boundsMax);

}  // namespace compose::calib
