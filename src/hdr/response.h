// Camera response curves: how a camera's 8-bit codes relate to the light its sensor collected.
//
// A ResponseCurve stores the *inverse* response per channel, as OpenCV's CalibrateDebevec and
// CalibrateRobertson return it: for every 8-bit code z (0..255) the linear exposure X(z) that
// produces it, up to one unknown scale per curve. Radiance then follows as X(z) / e, with e the
// relative exposure t · ISO / N² of the shot (ingest::CaptureInfo::relativeExposure).
//
// Scale convention: a recovered curve is normalised so that every channel's value at code 128 is
// 1, as OpenCV does. A camera's JPEGs are white-balanced, so the same code in each channel means
// the same light; the merged radiance's unit is then "the light that gives code 128 at relative
// exposure 1". A curve from another source (the virtual camera's ground truth, the sRGB curve)
// keeps its own scale.
//
// Per-camera files: recovered curves are kept in a folder, one JSON file per camera (Make and
// Model from EXIF), so that a later merge with the same camera skips the recovery:
// responseDirectory() is $COMPOSE_RESPONSE_DIR, else $XDG_CACHE_HOME/compose/responses, else
// ~/.cache/compose/responses. File format (version 1):
//
//   {"format": "compose-response", "version": 1, "camera": {"make": ..., "model": ...},
//    "method": "debevec", "created": "2024-06-01T12:00:00Z", "source": "...",
//    "channels": ["R", "G", "B"], "inverse": [[256 numbers], [256 numbers], [256 numbers]]}
//
// Errors: bad files throw compose::Error (stage "merge") naming the file and what is wrong.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "core/image.h"
#include "core/progress.h"

namespace compose::hdr {

inline constexpr int kCodes = 256;

struct ResponseCurve {
  // inverse[c][z]: linear exposure producing code z in channel c (R, G, B). Strictly increasing
  // in z and positive for a usable curve.
  std::array<std::vector<float>, 3> inverse;
  std::string method;  // "debevec", "robertson", "srgb", "linear", "ground truth", ...
  std::string make, model;
  std::string created;  // ISO 8601 UTC time of recovery, empty if unknown
  std::string source;   // where it came from, for messages ("recovered from 18 photos", a file)
  // Per channel, the codes [first, last] the photos showed in enough smooth, unclipped patches
  // to measure the curve there; outside them a recovered curve is extrapolated (by its fit's
  // smoothness, the ends' regression, or the channels that show those codes when the three share
  // one curve). [0, 255] for curves that are not recovered (sRGB, a file without the field).
  std::array<std::array<int, 2>, 3> observed{{{0, 255}, {0, 255}, {0, 255}}};

  bool empty() const { return inverse[0].empty(); }
  // Linear value of a continuous code in [0, 255] (linear interpolation between codes), for
  // encoded inputs deeper than 8 bits.
  float linear(int channel, float code) const;
  // Throws compose::Error (stage "merge", naming `file`) unless every channel has 256 finite,
  // positive values that never decrease.
  void validate(const std::filesystem::path& file = {}) const;

  // The IEC 61966-2-1 sRGB decoding curve (what a JPEG declares when nothing better is known).
  static ResponseCurve srgb();
};

enum class RecoveryMethod { Debevec, Robertson };
const char* methodName(RecoveryMethod method);

struct RecoveryParams {
  RecoveryMethod method = RecoveryMethod::Debevec;
  // Debevec: how many 5 x 5 patches (smooth, unclipped, spread over every shot's range of codes)
  // are handed to OpenCV, and the smoothness weight. OpenCV solves a dense least-squares system
  // with samples × shots rows by SVD, so the cost grows quickly with `samples`.
  int samples = 150;
  double lambda = 20.0;
  // Debevec: Debevec & Malik's model fitted again over every smooth patch of every view (reduced
  // to 256 normal equations per channel, response.cpp refitFromPatches), with this smoothness
  // relative to the data's total weight per code. Off: OpenCV's fit from `samples` patches alone.
  bool refit = true;
  double refitSmoothness = 10.0;
  int maxIterations = 30;   // Robertson
  double threshold = 0.01;  // Robertson: convergence threshold
  int maxPixels = 1 << 20;  // Robertson: views are subsampled (nearest) to about this many pixels
  // The ends of the range (codes up to 32, from 224) refitted by regressing the code on the light
  // that the trusted middle of the next shot says the pixel got (response.cpp, refineEnds).
  bool refineEnds = true;
  // One tone curve for the three channels, as a camera's JPEG engine applies one to them after
  // white balance: at every code, the mean of the channels' curves (each 1 at code 128),
  // weighted by the pixels that show the code in each (response.cpp, shareCurve). Off: a curve
  // per channel, each from its own pixels alone (a film scan, a camera with a curve per channel).
  bool sharedCurve = true;
  void validate() const;  // compose::Error (stage "merge")
};

// 8-bit RGB codes of an image, interleaved, row-major: what an 8-bit file holds. The codes are
// owned (`rgb`) or borrowed (`external`, e.g. ingest::LoadedImage::codes, which must outlive
// this).
struct Codes8 {
  int width = 0, height = 0;
  std::vector<uint8_t> rgb;
  const uint8_t* external = nullptr;
  const uint8_t* data() const { return external ? external : rgb.data(); }
};
// The codes of an image read from an 8-bit file (values code / 255, RGB or more channels: the
// first three are taken). Multi-threaded.
Codes8 toCodes8(const Image& encoded);

// The 8-bit codes of one bracket for recovery, all of one size, with their relative exposures.
struct BracketCodes {
  std::vector<const Codes8*> images;
  std::vector<double> exposures;
};

// Recovers the response with OpenCV from one or more brackets that share the same exposure
// sequence (views of one capture: every view contributes samples). Brackets whose exposures
// differ from the first one's are left out. Needs at least two exposures. The result is made
// non-decreasing and normalised as described above.
//
// Debevec: OpenCV's CalibrateDebevec fits the curve from `samples` patches; Debevec & Malik's model
// is then fitted again over every smooth, unclipped patch (RecoveryParams::refit), and the ends of
// the range are refitted from the adjacent shot (RecoveryParams::refineEnds). `observed` receives
// the codes the patches show.
//
// Accuracy, and its limit: with exposures a fixed ratio apart (2 EV brackets), the data only
// fix the curve up to a ripple that repeats with that ratio (any such ripple is absorbed by the
// unknown radiances); Debevec's smoothness term chooses among them, and noise excites it.
// Measured on the virtual camera's photos (four HDRIs, 3 and 5 exposures), one curve for the
// three channels: 0.27-1.00 % RMS over codes 5-250, 0.9-1.4 % largest deviation over codes
// 16-224 (a curve per channel: 0.5-1.6 % and 1.3-3.0 %: the mean evens out each channel's
// ripple). At the ends the photos' own codes (averaged over pixels that got the same true light)
// depart from the simulated curve by 3-15 % (JPEG), and codes no patch shows are extrapolated.
// Merged radiance is much less sensitive: those codes carry little weight.
// `openCvSeconds`, when given, receives the time spent inside OpenCV's calibration.
ResponseCurve recoverResponse(const std::vector<BracketCodes>& brackets,
                              const RecoveryParams& params, const Progress& progress = {},
                              double* openCvSeconds = nullptr);

// How well `curve` explains the brackets: the median, over pixels and channels of every pair of
// adjacent exposures where both codes are well exposed (16-235), of |ln(X(z1)/e1) - ln(X(z2)/e2)|,
// the disagreement between the two shots' radiance through the curve (a per-channel scale
// cancels). A curve recovered from the photos gives a few per cent (noise, JPEG); another
// camera's or another picture style's, tens of per cent. NaN when no pixel qualifies.
double responseDisagreement(const ResponseCurve& curve, const std::vector<BracketCodes>& brackets);

ResponseCurve readResponse(const std::filesystem::path& file);
void writeResponse(const std::filesystem::path& file, const ResponseCurve& curve);
// The JSON text writeResponse() writes (for OutputFiles users).
std::string responseText(const ResponseCurve& curve);

// The folder of per-camera response files (see above).
std::filesystem::path responseDirectory();
// The file for a camera in `folder`: "<make>_<model>.json", lower case, anything but letters,
// digits, '-' and '.' replaced by '_'; a name with characters beyond ASCII (or control ones) or
// longer than 200 characters ends in a hash of the exact make and model, so that two cameras
// named in another script do not share a file. Empty when the camera has neither make nor model.
std::filesystem::path responseFileFor(const std::filesystem::path& folder, const std::string& make,
                                      const std::string& model);

// Linearises an 8-bit-coded RGB(A) image (codes as floats code/255; other channels are copied)
// through the curve: out = inverse[c][code]. Codes are rounded to the nearest integer; deeper
// inputs use ResponseCurve::linear on the continuous code.
Image linearize(const Image& encoded, const ResponseCurve& curve);

}  // namespace compose::hdr
