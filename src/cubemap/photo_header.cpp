#include "cubemap/photo_header.h"

#include <cmath>
#include <cstdio>

#include "core/error.h"
#include "ingest/image_io.h"

namespace compose::cubemap {

PhotoHeader readPhotoHeader(const std::filesystem::path& file) {
  const ingest::CaptureInfo info = ingest::readCaptureInfo(file, "ingest");
  PhotoHeader h;
  h.width = info.fileWidth;
  h.height = info.fileHeight;
  if (info.orientation >= 5 && info.orientation <= 8)
    std::swap(h.width, h.height);  // turned by 90°
  h.focalLength35mm = info.focalLength35mm;
  h.focalLength35mmDerived =
      info.focalLength35mm && info.focal35mmSource != "EXIF FocalLengthIn35mmFilm";
  h.focalLengthMm = info.focalLengthMm;
  h.cameraMake = info.cameraMake;
  h.cameraModel = info.cameraModel;
  h.exposureUnit = info.exposureUnit;
  // The turn from the sensor's frame: the file's own EXIF orientation, or, for a merged view
  // stored upright, the one its photos had.
  h.orientation = info.orientation != 1 ? info.orientation : info.sensorOrientation;
  h.floatingPoint =
      info.sampleType == "float" || info.sampleType == "half" || info.sampleType == "double";
  h.sixteenBit = info.sampleType == "uint16";
  h.format = info.format;
  if (h.width <= 0 || h.height <= 0) throw Error("ingest", "image has no pixels", file);
  return h;
}

calib::Lens photoLens(const std::filesystem::path& file, const PhotoHeader& h,
                      const std::optional<calib::Lens>& lensFile, double fovDegrees, bool fisheye) {
  if (lensFile) {
    // Turned by the photo's EXIF orientation (the lens is in the sensor's frame) and scaled.
    if (const std::optional<calib::Lens> fitted =
            calib::lensForImage(*lensFile, h.width, h.height, h.orientation))
      return *fitted;
    throw Error("stitch",
                "the lens file is for " + std::to_string(lensFile->width) + "x" +
                    std::to_string(lensFile->height) + " images, the photo is " +
                    std::to_string(h.width) + "x" + std::to_string(h.height) +
                    " (another aspect ratio)",
                file);
  }
  if (fovDegrees > 0.0) {
    // Across the sensor's width, as a lens file is in the sensor's frame: a portrait photo of
    // the same camera (turned by its EXIF orientation) has that field of view across its height
    // (it was given it across its width: 25 % off in focal length, its edges 8° out).
    const bool turned = h.orientation >= 5 && h.orientation <= 8;
    const int sensorWidth = turned ? h.height : h.width, sensorHeight = turned ? h.width : h.height;
    const calib::Lens sensor = calib::Lens::fromFieldOfView(
        sensorWidth, sensorHeight, fovDegrees,
        fisheye ? calib::Projection::Equidistant : calib::Projection::Rectilinear);
    std::optional<calib::Lens> lens = calib::lensForImage(sensor, h.width, h.height, h.orientation);
    COMPOSE_CHECK(lens.has_value());
    lens->source = "--fov";
    return *lens;
  }
  if (h.focalLength35mm) {
    // A 35 mm-equivalent focal length refers to the 36 x 24 mm frame's diagonal.
    constexpr double kDiagonalMm = 43.266615305567875;
    calib::Lens lens = calib::Lens::fromFieldOfView(h.width, h.height, 90.0);
    lens.fx = lens.fy = *h.focalLength35mm / kDiagonalMm * std::hypot(h.width, h.height);
    char mm[32];
    std::snprintf(mm, sizeof mm, h.focalLength35mmDerived ? "%.2f mm" : "%.0f mm",
                  *h.focalLength35mm);
    lens.source = (h.focalLength35mmDerived
                       ? "35 mm focal length derived from EXIF FocalLength and the focal-plane "
                         "resolution: "
                       : "EXIF 35 mm focal length ") +
                  std::string(mm);
    return lens;
  }
  throw Error(
      "stitch",
      std::string("no intrinsics for this photo: its EXIF has no 35 mm equivalent "
                  "focal length") +
          (h.focalLengthMm ? " (only the true focal length, without the sensor size)" : "") +
          "; give --fov DEG or --calib LENS.json (a capture description: \"lens\")",
      file);
}

}  // namespace compose::cubemap
