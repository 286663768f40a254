// Stitching: photos taken from one point in roughly known directions, to a cube-map environment.
//
// Input. Each photo comes with its intrinsics (calib::Lens: EXIF, a field of view or the lens file
// of `compose calib lens`) and a rough orientation, worldFromCamera (the camera looks along -Z with
// +Y up; render_view.h has the rotations of the photographer's convention: side views upright, up
// and down views tilted from the -Z view). Pixels are linear radiance (HDR merges, or linearised
// LDR photos). Six photos with a lens of 90° or more cover the sphere; more photos with a narrower
// lens work the same way.
//
// Steps.
//  1. Features. SIFT keypoints on an 8-bit log-luminance rendition of each photo, at most
//     `featureSize` pixels on the long side (one tone mapping for all photos, so that features
//     repeat, then local contrast equalisation, which brings out skies and shadows). Each keypoint
//     becomes a ray through the lens model (distortion included). Everything else works on the
//     float radiance.
//  2. Matching. Only pairs whose rough frusta overlap are matched: descriptors with Lowe's ratio
//     test, kept if the rough orientations put the two rays within the orientation tolerance, then
//     verified by RANSAC on the pair's relative rotation (two rays fix a rotation). A few matches
//     bunched in a small patch of a narrow overlap hardly fix the roll about their direction and
//     can agree, within RANSAC's threshold, on a rotation degrees off: a pair whose matched
//     rotation makes the log luminance of its overlap disagree more (variance, over 1.5 times)
//     than the rough orientations do is not used, and a note says so.
//  3. Orientation. OpenCV's rotation-only bundle adjustment (cv::detail::BundleAdjusterReproj with
//     every intrinsic fixed: focal, principal point and aspect are known) refines all orientations
//     of each connected group of photos on the verified matches, on ideal pinhole coordinates of
//     the rays. Its gauge (one global rotation) is then fixed by aligning the refined orientations
//     to the rough ones as a whole, so the world stays level and facing where the photographer
//     said. A correction larger than `maxCorrectionDegrees` is refused. A photo that shares no
//     features with any other (a clear sky, a blank wall) is aligned directly instead: a pattern
//     search over small rotations that makes the log luminance of its overlaps agree with its
//     aligned neighbours' (up to an exposure offset); a photo with no aligned neighbour keeps its
//     rough orientation. Notes say which photo got what.
//  4. Exposure. Per-photo gains from the radiance at matched keypoints (median log ratio per pair,
//     least squares over pairs, geometric mean 1), so that photos of unequal exposure blend;
//     photos merged to HDR with known exposures get gains of ~1.
//  5. Warping and blending, in the radiance domain. Every cube texel looks up every photo that
//     sees it as 2 x 2 to 4 x 4 sub-texel rays, each prefiltered to its footprint (a mip pyramid
//     per photo, trilinear), which approximates the box average over the texel that a cube texel
//     holds. The photos are averaged with seam-aware weights: each photo's weight falls to 0 at
//     its frame (feathering across the whole overlap, so that no seam remains where one photo
//     ends), and clipped pixels of LDR photos are weighted down by 100.
//  6. Coverage. Directions no photo sees are filled from their surroundings (coverage.h), and the
//     fraction of the sphere that needed it is reported.
//
// Memory: photos are loaded through a callback, once each if `keepPhotos` (all photos are then
// held until warping), or twice (features, then warping) if not, holding one at a time.
// Threading: every core; progress on stages "load", "features", "match", "warp"; the time of each
// step comes back in the result. Errors: compose::Error (stage "stitch") naming the photo.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <glm/mat3x3.hpp>

#include "calib/lens.h"
#include "core/image.h"
#include "core/progress.h"
#include "cubemap/coverage.h"
#include "lighting/cubemap.h"

namespace compose::cubemap {

struct StitchPhoto {
  std::string name;            // for messages, normally the file name
  calib::Lens lens;            // intrinsics for the photo's size
  glm::dmat3 worldFromCamera;  // rough orientation
  float saturation = 0.0f;     // linear value at which the photo clipped; 0: never (HDR)
};

struct StitchOptions {
  int faceSize = 1024;                 // cube face size of the result
  bool refine = true;                  // refine orientations by feature matching
  double maxCorrectionDegrees = 10.0;  // how far the rough orientations may be off
  int featureSize = 800;               // long side of the images features are found on
  bool gains = true;                   // exposure compensation between photos
  bool keepPhotos = true;              // load each photo once and hold it (faster, more memory)
  void validate() const;               // compose::UsageError on values out of range
};

struct StitchResult {
  lighting::CubeMap cube;
  CoverageReport coverage;
  std::vector<glm::dmat3> worldFromCamera;  // refined orientations
  std::vector<double> correctionDegrees;    // angle between refined and rough, per photo
  std::vector<float> gains;                 // per photo
  std::vector<std::string> notes;           // matches per pair, residuals, anything refused
  std::vector<std::string> warnings;        // what is likely wrong with the input
  // Wall-clock seconds per step: "load", "features", "match", "adjust", "warp", "fill".
  std::vector<std::pair<std::string, double>> seconds;
};

// `load(i)` returns photo i as linear RGB (or RGBA: alpha ignored) radiance of the lens's size.
StitchResult stitch(const std::vector<StitchPhoto>& photos, const std::function<Image(int)>& load,
                    const StitchOptions& options, const Progress& progress = {});

}  // namespace compose::cubemap
