// The shadow the object casts on the ground it stands on (differential rendering, Debevec 1998;
// what Blender calls a shadow catcher; docs/design.md §11).
//
// The ground is the plane y = 0 of the world. A point g on it, lit by the environment, receives
// E_without(g) with the object absent and E_with(g) with the object in the way; in linear light
// the plate's pixel that shows g is multiplied by E_with / E_without. The ratio is 1 where the
// object blocks nothing, so the plate is untouched away from the object, and the shadow is as
// soft or as sharp as the light that casts it. No estimate of the ground's own albedo is needed.
//
// The ratio is the self-shadowing problem with the normal fixed (+Y): the same visibility pass
// and transfer (transfer.h) at ground points. Those points are laid on a grid of plate pixels
// (every `stride`-th pixel) over the part of the ground where the shadow can fall: the object's
// footprint widened by `reach` times its height, and stretched away from each of the brightest
// light sources as far as the object's shadow reaches (at most `maxReach` heights). Pixels in
// between are interpolated bilinearly from the grid. Where the ratio bends sharply between nodes
// (the edge of a small lamp's or the sun's shadow, which the grid would draw as a staircase of
// `stride`-pixel steps), the grid's cells around it are refined: a finer grid of `steps` x
// `steps` cells inside each, interpolated the same way.
#pragma once

#include <vector>

#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>

#include "calib/plate_camera.h"
#include "core/image.h"
#include "lighting/sources.h"
#include "render/mesh.h"
#include "render/transfer.h"

namespace compose::render {

struct GroundSettings {
  double reach = 3.0;        // how far around the footprint, in object heights
  double maxReach = 15.0;    // the longest shadow followed, in object heights
  size_t maxPoints = 30000;  // the grid is coarsened to stay within this many points
  // Refinement: a cell is refined when one of its corners' ratio differs from the mean of its
  // two neighbours along a row or a column (the second difference) by more than `bend`, in any
  // channel, into steps x steps cells of about `fineStride` pixels (none when the grid is that
  // fine already); at most `maxRefinedPoints` points are added (the sharpest cells first).
  float bend = 0.05f;
  int fineStride = 4;
  size_t maxRefinedPoints = 60000;
};

// Where the ground pass samples: plate pixels of a grid, their ground points (object space).
struct GroundGrid {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // the plate rectangle [x0, x1) x [y0, y1) it covers
  int stride = 1;                      // plate pixels between grid nodes
  int columns = 0, rows = 0;           // grid nodes: (x0 + i·stride, y0 + j·stride) + 0.5
  std::vector<int> node;               // per grid node: its surface point, or -1 (not ground)
  SurfacePoints points;                // object space, normals the ground's +Y
  // Refined cells: per cell of the grid ((columns - 1) x (rows - 1)), the index of its block in
  // `fineNode`, or -1; a block holds (steps + 1)² point indices (or -1), row by row, the fine
  // node (a, b) at (x0 + i·stride + a·stride/steps, y0 + j·stride + b·stride/steps) + 0.5. The
  // points are numbered after the grid's: `points.count()` upwards, in `finePoints`.
  int steps = 0;
  double regionX0 = 0.0, regionX1 = 0.0, regionZ0 = 0.0, regionZ1 = 0.0;  // the ground (world)
  std::vector<int> refinedCell;
  std::vector<int> fineNode;
  SurfacePoints finePoints;
  bool empty() const { return points.count() == 0; }
};

// The grid for an object placed by `worldFromObject` (a yaw, a uniform scale and a translation
// that stands it on y = 0) seen by `camera`. `sources` (the environment's brightest, in the world
// frame) stretch the region along their shadows.
GroundGrid groundGrid(const Mesh& mesh, const glm::dmat4& worldFromObject,
                      const calib::PlateCamera& camera,
                      const std::vector<lighting::LightSource>& sources,
                      const GroundSettings& settings = {});

// Adds the refined cells' points to `grid` (finePoints), given the irradiance at its points
// (shadeVertices of grid.points); returns how many cells were refined.
size_t refineGroundGrid(GroundGrid& grid, const VertexIrradiance& irradiance,
                        const glm::dmat4& worldFromObject, const calib::PlateCamera& camera,
                        const GroundSettings& settings = {});

// The per-pixel ratio E_with / E_without (RGB, in [0, 1]) over the grid's rectangle, from the
// irradiance at its points and, where cells were refined, at its fine points (shadeVertices of
// grid.points and grid.finePoints; `fine` may be empty when nothing was refined). Pixels with no
// ground point around them keep 1.
Image groundRatio(const GroundGrid& grid, const VertexIrradiance& irradiance,
                  const VertexIrradiance& fine = {});

}  // namespace compose::render
