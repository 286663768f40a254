// What a stitching command needs to know about a photo before decoding it: its size as a person
// sees it (EXIF orientation applied) and the EXIF focal lengths, read from the file header only.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

namespace compose::cubemap {

struct PhotoHeader {
  int width = 0, height = 0;              // after the EXIF orientation
  std::optional<double> focalLength35mm;  // EXIF FocalLengthIn35mmFilm
  std::optional<double> focalLengthMm;    // EXIF FocalLength
  bool floatingPoint = false;             // float or half samples (HDR), else integer (LDR)
  std::string format;                     // reader name, e.g. "jpeg", "openexr"
};

// Throws compose::Error (stage "ingest", naming the file) if the file is missing or unreadable.
PhotoHeader readPhotoHeader(const std::filesystem::path& file);

}  // namespace compose::cubemap
