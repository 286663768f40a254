// Mirror-ball (light-probe) unwrapping: a photo of a chrome sphere, cropped to the ball, to an
// environment map, the classic capture of Debevec's light probes.
//
// Geometry (DESIGN.md §4.4). The ball is photographed from afar, so every pixel looks along the
// same direction. In the ball photo's camera frame (+X right, +Y up, the camera looks along -Z,
// so c = +Z points from the ball back to the camera), the image-disc point (u, v), u² + v² ≤ 1
// (u to the right, v up, the ball's rim at radius 1), has the normal n = (u, v, sqrt(1 - u² - v²))
// and reflects the direction d = 2 (n·c) n - c. The environment's frame is that camera frame: the
// middle of the lat-long map (+Z) shows the photographer, the map's left and right edges (-Z) what
// is behind the ball. Turn it afterwards with --env-yaw if the camera faced elsewhere.
//
// Sampling. Solid angle per unit disc area is uniform (dω = 4 dA), but the map from the disc to
// directions stretches without bound towards the rim: there the direction behind the ball is
// squeezed into a thin ring, and a small error in the crop moves it far. So the rim is weighted
// down: the weight falls smoothly from 1 to 0 as the reflected direction comes within
// 2 x blindSpotDegrees of straight behind the ball, and directions within blindSpotDegrees are not
// read at all; both are filled from their surroundings (coverage.h). The blind spot is never
// narrower than the directions that land within 1.5 pixels of the ball's outline, where pixels mix
// the ball with its background. Each texel averages 3 x 3 bilinear samples of the photo.
#pragma once

#include <filesystem>

#include "core/image.h"
#include "core/progress.h"
#include "cubemap/coverage.h"
#include "lighting/cubemap.h"

namespace compose::cubemap {

struct MirrorBallOptions {
  int faceSize = 0;                // cube face size of the result; 0: from the ball's resolution
  double blindSpotDegrees = 10.0;  // cone behind the ball that is filled, not read; in [0, 60]
  void validate() const;           // compose::UsageError on values out of range
};

struct MirrorBallResult {
  lighting::CubeMap cube;  // the unwrapped environment (convert with lighting/sphere_resample.h)
  CoverageReport coverage;
};

// `ball`: the photo cropped to the ball (square; RGB or RGBA or grey), values as the caller wants
// them resampled (linear radiance, normally). Throws compose::Error (stage "ingest", naming `file`)
// if the crop is not square or too small.
MirrorBallResult unwrapMirrorBall(const Image& ball, const MirrorBallOptions& options,
                                  const std::filesystem::path& file = {},
                                  const Progress& progress = {});

}  // namespace compose::cubemap
