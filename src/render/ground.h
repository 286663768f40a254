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
// and transfer (transfer.h) at ground points. Those points are laid on plate pixels over the part
// of the ground where the shadow can fall: the object's footprint widened by `reach` times its
// height, and stretched away from each of the brightest light sources as far as the object's
// shadow reaches (at most `maxReach` heights). Pixels in between are interpolated bilinearly.
//
// The points are placed coarse to fine (a quadtree of plate cells): first every 2^coarseLevels
// base strides, then each cell is split in four where the ratio may change inside it by more than
// bilinear interpolation can follow: its corners' ratios differ by more than `spread`, they see a
// source that matters differently, or a source that matters may cast the object's shadow into it
// (its bounding sphere's shadow reaches the cell: a thin shadow can fall between corners). Cells
// are split down to the base stride there; below it, down to about `fineStride` pixels, only
// across sharp edges (corners differing by more than `sharp`: a lamp's or the sun's shadow,
// which a grid of base cells would draw as a staircase). A source matters when it alone can
// change the ratio by more than the threshold: its irradiance on the ground over the ground's.
// Most of the region (ground the object hardly shades, smooth soft shadow) keeps coarse cells.
// Where a cell meets finer ones, the finer cells' nodes on the shared edge take the coarse
// edge's interpolation, so that the ratio is continuous across the edge.
#pragma once

#include <vector>

#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>

#include "calib/plate_camera.h"
#include "core/image.h"
#include "lighting/sources.h"
#include "render/embree_scene.h"
#include "render/mesh.h"
#include "render/transfer.h"

namespace compose::render {

struct GroundSettings {
  double reach = 3.0;        // how far around the footprint, in object heights
  double maxReach = 15.0;    // the longest shadow followed, in object heights
  size_t maxPoints = 30000;  // the base stride is chosen so that a full grid would be this many
  int coarseLevels = 2;      // the first points are 2^coarseLevels base strides apart
  float spread = 0.01f;      // down to the base stride: split where the ratio may change more
  int fineStride = 4;        // below the base stride: down to about this many pixels (at most 8x)
  float sharp = 0.05f;       // ... where the ratio changes more (a sharp shadow edge)
  size_t maxRefinedPoints = 60000;  // points below the base stride, at most (sharpest first)
};

// Where the ground pass samples: plate pixels on a lattice, their ground points (object space).
struct GroundGrid {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // the plate rectangle [x0, x1) x [y0, y1) it covers
  int stride = 1;                      // base stride: plate pixels between base-level nodes
  int coarse = 0;                      // levels above the base: the first cells are 2^coarse
  int fine = 0;                        // levels below it (sharp edges)
  double unit = 1.0;                   // pixels between lattice nodes: stride / 2^fine
  // The finest level's lattice: node (a, b) at plate pixel (x0 + a·unit, y0 + b·unit) + 0.5.
  int columns = 0, rows = 0;
  std::vector<int> node;         // per lattice node: its point, -1 not ground, -2 not sampled
  std::vector<glm::vec3> ratio;  // per lattice node: E_with / E_without (1 where no point)
  // Per level l < levels(): per cell of 2^(levels() - l) lattice steps, 1 where it is split.
  std::vector<std::vector<uint8_t>> split;
  std::vector<size_t> splitCount;   // per level: cells split
  SurfacePoints points;             // object space, normals the ground's +Y; in order made
  std::vector<uint32_t> pointNode;  // per point: its lattice node
  size_t shaded = 0;                // points [0, shaded) have their ratio
  int level = 0;                    // the level refineGroundGrid examines next
  // What the refinement asks: the region (world), the object's bounding sphere (world), the
  // sources (world frame), the ground's irradiance without the object, which sources each point
  // sees (bits, as VertexIrradiance::sourceSeen).
  double regionX0 = 0.0, regionX1 = 0.0, regionZ0 = 0.0, regionZ1 = 0.0;
  glm::dvec3 sphereCentre{0.0};
  double sphereRadius = 0.0;
  std::vector<lighting::LightSource> sources;
  glm::vec3 open{0.0f};
  std::vector<uint64_t> seen;
  // What each point sees of the sources it sees in part (VertexIrradiance::seenFraction): per
  // point the sources' mask, and their fractions (lowest source first) from partialFirst[p] on.
  std::vector<uint64_t> partial;
  std::vector<uint32_t> partialFirst;
  std::vector<float> partialFraction;
  // What point p sees of source i, in [0, 1].
  float seenFraction(size_t p, int i) const;
  std::vector<int8_t> hidden;  // per lattice node: 1 when the object hides it, 0 not, -1 not asked

  bool empty() const { return points.count() == 0; }
  int levels() const { return coarse + fine; }
  int firstStride() const { return stride << coarse; }  // pixels between the first nodes
  // The points made but not yet shaded: [shaded, points.count()).
  SurfacePoints pending() const;
};

// The grid for an object placed by `worldFromObject` (a yaw, a uniform scale and a translation
// that stands it on y = 0) seen by `camera`, with its first (coarsest) points. `sources` (the
// environment's brightest, in the world frame) stretch the region along their shadows.
GroundGrid groundGrid(const Mesh& mesh, const glm::dmat4& worldFromObject,
                      const calib::PlateCamera& camera,
                      const std::vector<lighting::LightSource>& sources,
                      const GroundSettings& settings = {});

// Takes the irradiance of the pending points (shadeVertices of grid.pending()).
void shadeGroundPoints(GroundGrid& grid, const VertexIrradiance& irradiance);

// Splits the cells of the next level that need it, adding their new points (pending); false when
// every level has been examined. Call after shadeGroundPoints. A cell the object hides from the
// camera (`scene`: the object in its own coordinates) is not split: the composite shows the object
// there, not the ground.
bool refineGroundGrid(GroundGrid& grid, const EmbreeScene& scene, const glm::dmat4& worldFromObject,
                      const calib::PlateCamera& camera, const GroundSettings& settings = {});

// The per-pixel ratio E_with / E_without (RGB, in [0, 1]) over the grid's rectangle. Pixels with
// no ground point around them keep 1.
Image groundRatio(const GroundGrid& grid);

// Where a strong source's shadow edge crosses a finest cell (its corners see the source
// differently), the bilinear ratio draws the edge as the cell's square: stair steps along a
// hard shadow. There each pixel traces those sources itself, 2 x 2 samples across the pixel and
// across the source's extent, and its ratio takes what they see instead of the corners'
// interpolation. Returns the rays traced.
int64_t sharpenGroundEdges(const GroundGrid& grid, Image& ratio, const EmbreeScene& scene,
                           const glm::dmat4& worldFromObject, const calib::PlateCamera& camera,
                           const GroundSettings& settings = {});

}  // namespace compose::render
