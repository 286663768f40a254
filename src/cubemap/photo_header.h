// What a stitching command needs to know about a photo before decoding it: its size as a person
// sees it (EXIF orientation applied) and the EXIF focal lengths, read from the file header only.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "calib/lens.h"

namespace compose::cubemap {

struct PhotoHeader {
  int width = 0, height = 0;  // after the EXIF orientation
  // EXIF FocalLengthIn35mmFilm, or derived from FocalLength and the focal-plane resolution
  // (ingest::CaptureInfo::focalLength35mm; a resized photo's focal-plane tags still describe the
  // sensor's pixels, which makes the derived value wrong by the resize factor: the lens says which
  // it is, and --fov or --calib override it)
  std::optional<double> focalLength35mm;
  bool focalLength35mmDerived = false;
  std::optional<double> focalLengthMm;  // EXIF FocalLength
  bool floatingPoint = false;           // float or half samples (HDR), else integer (LDR)
  bool sixteenBit = false;              // 16-bit integer samples
  std::string format;                   // reader name, e.g. "jpeg", "openexr"
  // EXIF Make and Model, and a merged photo's compose:exposureUnit (ingest::CaptureInfo).
  std::string cameraMake, cameraModel, exposureUnit;
  int orientation = 1;  // EXIF orientation (applied: width and height are as seen)
};

// Throws compose::Error (stage "ingest", naming the file) if the file is missing or unreadable.
PhotoHeader readPhotoHeader(const std::filesystem::path& file);

// The intrinsics of a photo for stitching, in order: a lens file (resized to the photo when the
// aspect ratio agrees), a horizontal field of view (`fovDegrees` > 0; `fisheye`: equidistant),
// the EXIF 35 mm equivalent focal length. Throws compose::Error (stage "stitch") naming the photo
// when none applies or the lens file is for another aspect ratio.
calib::Lens photoLens(const std::filesystem::path& file, const PhotoHeader& header,
                      const std::optional<calib::Lens>& lensFile, double fovDegrees = 0.0,
                      bool fisheye = false);

}  // namespace compose::cubemap
