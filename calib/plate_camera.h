// The plate camera: the camera that took the background photograph (its lens and its pose), and
// where a synthetic object stands in front of it.
//
// Frames (see docs/design.md §2): world is right-handed, +Y up, the ground plane is y = 0. The
// camera sits at (0, height, 0) and looks along -Z, tilted down by `pitch`. Image pixel (px, py)
// has its origin at the top-left corner of the picture, +y down (calib/lens.h).
//
// The lens, in order of preference: a calibration file (`compose calib lens`, calib::readLens;
// its intrinsics and distortion, scaled to the plate's size when the plate was resized); else
// --focal35; else EXIF FocalLengthIn35mmFilm; else a stated 50 mm default. A 35 mm-equivalent
// focal length f maps to the image diagonal: focal_px = f / 43.27 mm * diagonal_px (43.27 mm is
// the 36 x 24 mm frame's diagonal), with the principal point at the image centre.
#pragma once

#include <optional>
#include <string>

#include <glm/mat4x4.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "calib/lens.h"
#include "ingest/image_io.h"

namespace compose::calib {

inline constexpr double kFullFrameDiagonalMm = 43.266615305567875;  // sqrt(36² + 24²)
inline constexpr double kDefaultFocal35mm = 50.0;

struct PlateCamera {
  int width = 0, height = 0;
  Lens lens;                // intrinsics and distortion, at the plate's size
  double focal35mm = 0.0;   // the focal length as a 35 mm equivalent (across the diagonal)
  std::string focalSource;  // where the focal length came from, for the notes
  // A stored pixel's width over its height as shown (an anamorphic plate's 2): fx = fy / it for
  // a lens not calibrated on the plate's own pixels.
  double pixelAspect = 1.0;
  glm::dmat4 worldFromCamera{1.0};

  // World-space ray through continuous pixel position (px, py); direction is unit length. Returns
  // false where the lens has no ray (outside a distortion model's valid range).
  bool ray(double px, double py, glm::dvec3& origin, glm::dvec3& direction) const;
  // Projects a world point to continuous pixel coordinates; returns false if the lens cannot see
  // it (behind the camera, or past where its distortion model turns back).
  bool project(const glm::dvec3& world, glm::dvec2& pixel) const;
  glm::dvec3 position() const { return glm::dvec3(worldFromCamera[3]); }
  glm::dmat4 cameraFromWorld() const;
};

struct CameraOptions {
  std::optional<Lens> lens;  // from a calibration file; overrides everything else
  // The lens is in the plate's upright frame (a plate pose's, estimated on the plate as it is
  // shown): not turned by the plate's EXIF orientation, as a lens in the sensor's frame is.
  bool lensUpright = false;
  std::optional<double> focal35mm;  // overrides EXIF
  double height = 1.6;              // metres above the ground
  double pitchDegrees = 0.0;        // positive tilts the camera down
  // The camera's pose in a world whose ground is y = 0 (a plate pose from `compose calib pose`:
  // the board's frame); overrides height and pitch.
  std::optional<glm::dmat4> worldFromCamera;

  // Throws compose::UsageError naming the option when a value is out of range.
  void validate() const;
};

// Validates options and builds the plate camera. Throws compose::Error (stage "camera") when a
// calibration file does not fit the plate (another aspect ratio).
PlateCamera plateCamera(int width, int height, const ingest::CaptureInfo& exif,
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

// What --scale sizes of an object with these bounds: its height, or for a flat object (its height
// under 1 % of its largest extent: a rug, a sheet, a coin lying down) its largest extent; `flat`
// is set to which. (Sized by its height, a quad with one corner raised by 1e-5 of its width
// filled the frame, where the flat quad beside it took a tenth of it.)
double sizedExtent(const glm::dvec3& lo, const glm::dvec3& hi, bool* flat = nullptr);

// worldFromObject for a mesh with the given object-space bounds. Throws compose::Error (stage
// "camera") if the point is above the horizon or the numbers are out of range.
glm::dmat4 placeOnGround(const PlateCamera& camera, const Placement& placement,
                         const glm::dvec3& boundsMin, const glm::dvec3& boundsMax);

}  // namespace compose::calib
