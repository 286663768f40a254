// Directions a capture did not see: filling them from their surroundings.
//
// A stitched or unwrapped environment comes with a weight per cube texel in [0, 1]: 1 where the
// photos (or the ball) saw the direction well, 0 where nothing saw it, in between where the view
// fades out (a photo's border, a mirror ball's rim). fillUncovered replaces each texel by
//     w·L + (1 - w)·F,
// where F is a push-pull fill: the weighted radiance Σ w L and the weight Σ w are averaged up a
// seamless mip pyramid (lighting/filtered_cube.h: exact solid angles, filtering across face edges),
// and F at a texel is their ratio at the finest level where the weight around it reaches a
// quarter. Holes are thus filled smoothly with the light around them, with no seams at cube edges.
// A hole wider than a texel of the pyramid's level of at most 32 texels per face edge (a face no
// photo saw) is filled from its rim instead: at that level, each of its texels is the average of
// the well-seen texels weighted by (nearest distance / distance)^16, so that the light at the rim
// counts (the coarser levels average whole faces, sky and ground alike: the nadir of a capture
// without its down view came out 6 times as bright as the ground around it), and F is the
// bilinear lookup of that level.
#pragma once

#include <vector>

#include "lighting/cubemap.h"

namespace compose::cubemap {

struct CoverageReport {
  double uncovered = 0.0;  // fraction of the sphere (by solid angle) with weight 0
  double partial = 0.0;    // fraction with 0 < weight < 1
};

// Per-texel weights in face order (face-major, then rows, then columns): 6 N² values.
CoverageReport measureCoverage(const lighting::CubeMap& cube, const std::vector<float>& weight);

// Fills `cube` where weight < 1 (see above). Every weight 0 is a caller bug (nothing to fill from).
CoverageReport fillUncovered(lighting::CubeMap& cube, const std::vector<float>& weight);

}  // namespace compose::cubemap
