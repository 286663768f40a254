// Image input and output over OpenImageIO.
//
// readImage() decodes any format OpenImageIO can read (JPEG, PNG, TIFF, EXR, HDR, camera RAW where
// the plugin is present) to float, applies the EXIF orientation so that pixel (0, 0) is the top
// left of the picture as a person sees it, and returns the capture metadata that later stages need
// (exposure for merging, focal length for the camera). Values are returned as stored: an 8-bit
// sRGB JPEG comes back as encoded values in [0, 1], tagged with the colour space the file declares.
//
// writeImage() never leaves a half-written file at the destination: it writes a temporary file in
// the same folder and renames it into place only when the write has succeeded. Several outputs
// that belong together are written into one OutputFiles set (core/output_files.h) and appear
// together on commit().
//
// OpenEXR files say what their numbers are: the chromaticities of their RGB space (the standard
// `chromaticities` attribute, read back by readImage) and the colour-space name
// (`colorSpace`, a string attribute). Half-float output is checked against half's range: an
// image with a value beyond ±65504 is written as 32-bit float instead of turning into Inf, and
// the write reports it.
//
// Errors (missing file, undecodable data, unwritable folder) throw compose::Error with stage
// "ingest" (or "output" for writes) and the file name.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/image.h"
#include "core/output_files.h"

namespace compose::ingest {

// Capture metadata from EXIF (and the file header). Absent fields are empty.
struct CaptureInfo {
  std::optional<double> exposureTime;  // seconds
  std::optional<double> fNumber;
  std::optional<double> iso;
  std::optional<double> focalLengthMm;    // true focal length
  std::optional<double> focalLength35mm;  // 35 mm equivalent focal length
  int orientation = 1;                    // EXIF orientation of the file (already applied)
  std::string cameraMake, cameraModel;
  std::string fileColorSpace;  // colour space the file or its reader declares
  // CIE xy of red, green, blue, white from an OpenEXR `chromaticities` attribute, if present.
  std::optional<std::array<double, 8>> chromaticities;
  std::string format;                 // reader name, e.g. "jpeg", "openexr"
  int fileWidth = 0, fileHeight = 0;  // as stored, before orientation
};

struct LoadedImage {
  Image image;  // float, channels as stored (1-4 or more), orientation applied
  CaptureInfo info;
};

// Reads an image file. `stage` names the pipeline stage on whose behalf it is read, for errors.
LoadedImage readImage(const std::filesystem::path& path, const std::string& stage = "ingest");

struct WriteOptions {
  enum class Depth {
    Auto,
    UInt8,
    Half,
    Float
  } depth = Depth::Auto;  // Auto: half for EXR, 8 bit otherwise
  int jpegQuality = 95;
  int alphaChannel = -1;  // index of the alpha channel, or -1
  // OpenEXR only: chromaticities of the RGB channels (red, green, blue, white xy).
  std::optional<std::array<double, 8>> chromaticities;
};

struct WriteReport {
  bool promotedToFloat = false;  // half was asked for, a value did not fit, float was written
  float largestMagnitude = 0.0f;
};

// Writes `image` to `path`, format chosen from the extension. Atomic: temp file + rename.
WriteReport writeImage(const std::filesystem::path& path, const Image& image,
                       const WriteOptions& options = {});
// Writes `image` as one of a set of outputs: into a temporary of `outputs`; it appears at `path`
// when the caller commits the set.
WriteReport writeImage(OutputFiles& outputs, const std::filesystem::path& path, const Image& image,
                       const WriteOptions& options = {});

// One part of a multi-part OpenEXR file (as Nuke reads them: each part a layer group with its own
// data window). The image covers [x, x + width) x [y, y + height) of the full frame
// fullWidth x fullHeight (the display window).
struct ExrPart {
  std::string name;
  const Image* image = nullptr;
  int x = 0, y = 0;
  int fullWidth = 0, fullHeight = 0;
  WriteOptions options;
};

// Attributes written on every part of an OpenEXR file: 4x4 matrices (OpenEXR's m44f, stored as
// Imath reads them: row vectors, translation in the last row) and strings.
struct ExrHeader {
  std::vector<std::pair<std::string, std::array<float, 16>>> matrices;
  std::vector<std::pair<std::string, std::string>> strings;
};

// Writes a multi-part OpenEXR into a temporary of `outputs` (it appears at `path` on commit).
// Returns a report per part.
std::vector<WriteReport> writeExrParts(OutputFiles& outputs, const std::filesystem::path& path,
                                       const std::vector<ExrPart>& parts,
                                       const ExrHeader& header = {});

// The largest value half float represents.
inline constexpr float kHalfMax = 65504.0f;

}  // namespace compose::ingest
