// Merging a whole capture: every view's bracket → radiance in the working colour space, with one
// response curve and therefore one exposure scale for all views (so that the faces of a cube
// map agree).
//
// Linearisation (issue: colour for the photo stages), decided once per capture and reported in
// the notes:
//  * 8-bit photos (JPEG, 8-bit PNG/TIFF) go through a response curve:
//      - ResponseMode::Auto: the camera's curve from the per-camera folder (hdr/response.h) when
//        there is one, else recovered from the photos with OpenCV (and returned for saving);
//      - Recover: always recovered; File: read from a response file;
//      - ColorSpace: no camera curve, the codes are decoded by the colour space the files declare
//        (an sRGB JPEG by the sRGB curve), through OpenColorIO.
//    The curve's linear values are the camera's linear RGB, taken to be the linear space with
//    the primaries of the declared encoding (for sRGB files: linear Rec.709; see
//    linearSpaceFor()), then converted to the working space.
//  * Deeper photos (16-bit, half, float) are converted from their colour space to the working
//    space by OpenColorIO and merged by our own weighted average.
//
// Units. Radiance from 8-bit photos is the curve's linear value over the relative exposure,
// X(z) / e (hdr/merge.h), rescaled per channel by k_c = sRGB⁻¹(118/255) / X_c(118): code 118 is
// where the sRGB curve puts middle grey (0.18). A unit of the merged radiance is then the light
// that a photo of this camera at relative exposure 1 shows as an sRGB-decoded value of 1 at
// middle grey, whatever the curve's own scale (a recovered curve is 1 at code 128). A plate shot
// with the same camera and decoded as sRGB shows radiance L as about L · e_plate, so the plate's
// EXIF fixes the exposure of an object lit by this capture (pipeline: "exposure from EXIF"). For
// a curve that is the sRGB decoding itself, k = 1. Deeper photos keep their own linear unit over
// the relative exposure.
//
// Errors: compose::Error (stage "merge", or "color" for colour-space names) naming the file.
#pragma once

#include <array>
#include <filesystem>
#include <string>
#include <vector>

#include "color/color.h"
#include "core/progress.h"
#include "hdr/merge.h"
#include "hdr/response.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"

namespace compose::hdr {

enum class ResponseMode { Auto, Recover, File, ColorSpace };

struct CaptureMergeOptions {
  ResponseMode response = ResponseMode::Auto;
  std::filesystem::path responseFile;                          // ResponseMode::File
  std::filesystem::path responseFolder = responseDirectory();  // per-camera curves (Auto)
  RecoveryParams recovery;
  MergeParams merge;
  std::string inputSpace;  // colour space of the photos; empty: from the files / description
  std::string inputSpaceOption = "--input-space";  // the option that gave it, for messages
  std::string linearSpace;  // the camera's linear RGB for 8-bit photos; empty: linearSpaceFor()
  // The recovery options given by name (e.g. "--curve-per-channel"): with ResponseMode::Auto and
  // a stored curve used, a note says they were not applied.
  std::vector<std::string> recoveryOptions;
  void validate() const;  // compose::Error (stage "merge")
};

struct MergedView {
  std::string name;
  Image radiance;     // R, G, B in the working space, and "clipped"
  MergeResult stats;  // counts, shifts, notes (stats.radiance is empty)
  std::vector<double> exposures;
  std::vector<std::filesystem::path> files;
};

struct CaptureMergeResult {
  std::vector<MergedView> views;
  ResponseCurve response;  // the curve used for 8-bit photos (empty if none)
  std::array<double, 3> unitScale{1.0, 1.0, 1.0};  // k_c applied to 8-bit views (see Units)
  bool responseRecovered = false;                  // recovered in this run
  std::filesystem::path responseCacheFile;  // where a recovered curve belongs (empty: nowhere)
  std::string linearisation;                // one sentence: how photos became linear
  std::vector<std::string> notes;
  double seconds = 0.0;          // wall-clock time of mergeCapture
  double openCvSeconds = 0.0;    // of which inside OpenCV (response recovery and merging)
  double recoverySeconds = 0.0;  // response recovery alone (0 when a stored curve was used)
};

// Every photo of the capture decoded as mergeCapture() wants it (8-bit photos as codes),
// `photos[v][s]` for capture.views[v].shots[s]; progress is reported as "read".
std::vector<std::vector<ingest::LoadedImage>> readCapturePhotos(const ingest::Capture& capture,
                                                                const Progress& progress = {});

// `photos[v][s]` is the decoded image of capture.views[v].shots[s] (ingest::readImage; 8-bit
// photos preferably read as codes, ReadOptions::codesForEightBit), with every shot's exposure
// resolved (ingest::resolveExposures).
CaptureMergeResult mergeCapture(const ingest::Capture& capture,
                                const std::vector<std::vector<ingest::LoadedImage>>& photos,
                                const CaptureMergeOptions& options,
                                const color::ColorConfig& colors, const Progress& progress = {});

// The linear colour space that has the primaries of `encodedSpace` (an sRGB-encoded JPEG's
// linear RGB is linear Rec.709): `override` if given, else the first of the usual names for
// linear Rec.709 the config knows ("lin_rec709", "Linear Rec.709 (sRGB)", "Linear", ...), else
// the config's reference role. `why` receives a short explanation.
std::string linearSpaceFor(const color::ColorConfig& colors, const std::string& encodedSpace,
                           const std::string& override, std::string* why = nullptr);

// A 256-entry curve that decodes 8-bit codes of `encodedSpace` to `linearSpace` through
// OpenColorIO (the ResponseMode::ColorSpace curve); the three channels are decoded as greys.
ResponseCurve curveFromColorSpace(const color::ColorConfig& colors, const std::string& encodedSpace,
                                  const std::string& linearSpace);

}  // namespace compose::hdr
