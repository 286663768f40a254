// Area-exact resampling between lat-long maps and cube maps.
//
// Both layouts are piecewise-constant radiance on cells that tile the sphere (environment.h,
// cubemap.h). Resampling here is the box filter taken literally: a destination texel receives the
// mean of the source over its own footprint, weighted by the solid angle each source cell shares
// with it, and those shared solid angles are computed EXACTLY (in closed form, not by
// supersampling). So:
//  * energy is preserved: ∫ L dω of the result equals that of the source to rounding (about 1e-12
//    relative), whatever the resolutions, because every source cell hands out exactly its own solid
//    angle and every destination texel divides by exactly its own;
//  * a constant map stays constant, and no direction is sampled twice or skipped;
//  * nothing aliases: a bright texel (a sun) keeps its power however small it is.
// Upsampling is a box reconstruction (each source cell's value spread over what it covers); use a
// destination resolution at or below the source's for sharp results.
//
// Threading: the conversions use every core (core/parallel.h); results do not depend on the number
// of threads. Progress goes to stage "resample".
#pragma once

#include <functional>
#include <vector>

#include "core/progress.h"
#include "lighting/cubemap.h"
#include "lighting/environment.h"

namespace compose::lighting {

// A lat-long cell (x, y) and the solid angle (sr) it shares with some cube texel.
struct CellOverlap {
  int x = 0, y = 0;
  double solidAngle = 0.0;
};

// The exact overlaps between the texels of a cubeSize² cube map and the cells of a
// latLongWidth x latLongWidth/2 lat-long map.
class CubeLatLongOverlaps {
 public:
  CubeLatLongOverlaps(int cubeSize, int latLongWidth);

  // Replaces `out` with every lat-long cell that texel (x, y) of `face` overlaps, with the shared
  // solid angle. The solid angles sum to the texel's own (faceTexelSolidAngle) and, over all
  // texels, to each cell's. Const and thread-safe.
  void texel(int face, int x, int y, std::vector<CellOverlap>& out) const;

  // Calls visit(face, x, y, overlaps) once for every texel of the cube, in parallel (visit must
  // be safe to call concurrently for different texels). Only a sixth of the texels is computed:
  // the rest follow by the symmetries that map the lat-long grid onto itself: the mirror
  // x -> -x (columns mirrored), quarter turns about +Y (the side faces; columns shift by a quarter
  // of the width, when the width is a multiple of 4), and the mirror y -> -y (+Y onto -Y; rows
  // mirrored). `progress` gets stage "resample".
  void forEachTexel(
      const std::function<void(int face, int x, int y, const std::vector<CellOverlap>&)>& visit,
      const Progress& progress = {}) const;

  int cubeSize() const { return cubeSize_; }
  int latLongWidth() const { return width_; }
  int latLongHeight() const { return height_; }

 private:
  int cubeSize_, width_, height_;
  std::vector<double> rowTop_;  // sin(latitude) of the top edge of row y, y = 0..height (1 .. -1)
  std::vector<double> tanTop_;  // tan(latitude) of the same edges (inner edges only)
};

// The cube map of a lat-long environment: each texel is the solid-angle-weighted mean of the cells
// it overlaps. `size` is the face edge in texels (>= 1). A size of width/4 matches the lat-long's
// resolution along the equator.
CubeMap cubeFromLatLong(const Environment& environment, int size, const Progress& progress = {});

// The lat-long map (width x width/2, width even and >= 2) of a cube map, each cell the
// solid-angle-weighted mean of the texels it overlaps.
Environment latLongFromCube(const CubeMap& cube, int width, const Progress& progress = {});

// The cube map at another face size: each texel the solid-angle-weighted mean of the source texels
// it overlaps (face rectangles; exact solid angles by the corner formula).
CubeMap resizeCube(const CubeMap& cube, int size);

// The lat-long map at another width (even): each cell the solid-angle-weighted mean of the cells
// it overlaps (cells are rectangles in longitude and sin(latitude), so the weights are exact).
Environment resizeLatLong(const Environment& environment, int width);

}  // namespace compose::lighting
