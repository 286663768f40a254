// Exposure merging: a bracket of photos of one view → scene-linear radiance.
//
// Stage contract (pipeline/compose_job.h): functions over in-memory images that return new
// images; no printing (progress through a callback, remarks as notes in the result); bad data
// throws compose::Error (stage "merge") naming the file.
//
// What happens, in order:
//  1. Optional alignment (MergeParams::align): the integer translation of every shot relative to
//     the middle exposure, by OpenCV's AlignMTB (median-threshold bitmaps, Ward 2003) and a
//     coarse-to-fine search of the same measure over the whole range (alignBracket); each shot is
//     shifted, and pixels a shot does not cover after shifting are ignored for that shot.
//  2. Merging. 8-bit input goes through OpenCV's MergeDebevec (log-domain average with
//     triangular weights) or MergeRobertson with the camera's response curve. Input deeper than
//     8 bits (16-bit TIFF, float) is merged by our own weighted average of already linear values:
//     weight = relative exposure × a hat that falls to 0 as a channel approaches full scale (1.0),
//     which is the inverse-variance weight for shot noise (Robertson et al. 2003).
//     With ghost suppression (MergeParams::deghost) 8-bit input is merged by the same own kernel
//     (linearised by the response, Debevec's triangular weights), because it needs per-pixel
//     weights that OpenCV's mergers do not take.
//  3. Clipping: a pixel over-exposed (some channel at or above clipHigh) or under-exposed (every
//     channel at or below clipLow) in every shot has no trustworthy value. It is flagged with 1 in
//     the mask channel "clipped" and counted; its value comes from the shortest exposure
//     (over-exposed: a lower bound) or the longest (under-exposed: an upper bound).
//
// Units: radiance = linear / relative exposure (times MergeInput::scale), with "linear" in the
// response curve's unit (see hdr/response.h), so every view merged with the same curve shares one
// exposure scale.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "core/image.h"
#include "core/progress.h"
#include "hdr/response.h"

namespace compose::hdr {

enum class MergeMethod { Debevec, Robertson };
const char* mergeMethodName(MergeMethod method);

struct MergeParams {
  MergeMethod method = MergeMethod::Debevec;  // OpenCV merger for 8-bit input
  bool align = false;
  int maxShift = 32;  // alignment search range in pixels (AlignMTB searches up to 2^bits - 1)
  bool deghost = false;
  // Ghost suppression: a shot whose radiance differs from the reference shot's by more than this
  // many stops at a pixel is left out there.
  double ghostStops = 0.7;
  // Clipping thresholds on encoded values in [0, 1] (8-bit: code / 255).
  double clipHigh = 250.0 / 255.0;
  double clipLow = 4.0 / 255.0;
  void validate() const;  // compose::Error (stage "merge")
};

// One bracket of one view. Images are as read (ingest::readImage): RGB or RGBA, all the same size.
struct Alignment {
  std::vector<std::array<int, 2>> shifts;  // per image: the shift applied, (0, 0) where refused
  std::vector<std::array<int, 2>> found;   // per image: the shift AlignMTB found
  bool refused(size_t i) const { return found[i] != shifts[i]; }
};

struct MergeInput {
  std::vector<const Image*> images;
  std::vector<double> exposures;   // relative exposures, one per image, increasing
  std::vector<std::string> names;  // for messages (file names); may be empty
  // How the values become linear:
  //  * eightBit: values are 8-bit codes / 255, linearised by `response` (required).
  //  * otherwise values are already linear (the caller converted them from their colour space);
  //    full scale is 1.0.
  bool eightBit = true;
  const ResponseCurve* response = nullptr;
  // Optional: the images' 8-bit codes (toCodes8), when the caller has them already (8-bit input
  // only); otherwise they are made here.
  std::vector<const Codes8*> codes;
  // Optional, deeper input only: the images as stored, before the caller converted them (same
  // sizes, RGB first, full scale 1 whatever their encoding). Clipping is judged on them too,
  // each channel at its own full scale: red clipped in the camera's Rec. 709 (1.0, 0.3, 0.1) is
  // (0.72, 0.35, 0.14) in ACEScg, below any threshold, and that shot took the full weight of a
  // good one.
  std::vector<const Image*> stored;
  // Optional, with MergeParams::align: the alignment alignBracket() found already, used instead
  // of searching again.
  std::optional<Alignment> alignment;
  // Multiplies the radiance written, per channel of R, G and B (not "clipped"): a capture's unit
  // (capture_merge.h, Units).
  std::array<double, 3> scale{1.0, 1.0, 1.0};
};

// The translations of each image of a bracket onto the middle one (index n / 2), by AlignMTB's
// measure (median-threshold bitmaps): shifted by (dx, dy), image i's pixel (x, y) moves to
// (x + dx, y + dy) (cv::AlignMTB::shiftMat). A shift beyond `maxShift` in either direction is not
// applied: AlignMTB's own pyramid searches a power-of-two range and, on a shot with little detail
// (the darkest exposure of a plain floor), can land anywhere in it. Time inside OpenCV is added
// to *openCvSeconds when given.
Alignment alignBracket(const std::vector<const Codes8*>& codes, int maxShift,
                       double* openCvSeconds = nullptr);

struct MergeResult {
  // Channels R, G, B (radiance) and "clipped" (1 where every shot was clipped, else 0). The
  // colour space is left empty: the caller knows which linear space the camera's RGB is in.
  Image radiance;
  std::vector<std::array<int, 2>> shifts;  // per input: the (x, y) shift applied, pixels
  int64_t saturated = 0;                   // pixels over-exposed in every shot
  int64_t dark = 0;                        // pixels under-exposed in every shot
  int64_t outside = 0;  // of those, joined to the frame's edge (beyond a fisheye's image circle)
  int64_t ghosted = 0;  // pixels where ghost suppression left a shot out
  std::vector<std::string> notes;
  double seconds = 0.0;        // wall-clock time of mergeBracket
  double openCvSeconds = 0.0;  // of which inside OpenCV calls
};

// Merges one bracket. Checks: at least two shots (one shot is linearised and passed through,
// with a note), same sizes (error naming the odd file), increasing distinct exposures.
MergeResult mergeBracket(const MergeInput& input, const MergeParams& params,
                         const Progress& progress = {});

}  // namespace compose::hdr
