// Self-shadowing by precomputed transfer (docs/design.md §10).
//
// The irradiance at a surface point that its own object may shadow is
//
//     E = ∫ V(ω) L(ω) max(0, n·ω) dω,
//
// V the visibility (1 where the environment is seen, 0 where the object itself is in the way).
// On the local altitude/azimuth grid of the cheb-local lighting basis (s x s cells around the
// normal: altitude θ in s equal steps of π/2s from the normal, azimuth φ in s equal steps from
// the tangent `east`), with ℓ_ij = ∫_cell L cos θ dω (what the lighting tabulates per normal) and
// V_ij the visible fraction of the cell seen from the point (one ray per cell, then r x r strata on
// the cells where the shadow's edge passes, the first ray standing for its own stratum),
//
//     E ≈ Σ_ij V_ij ℓ_ij = Σ_mn a_mn b_mn,
//
// a and b the 2D Tchebichef moments of ℓ and V (exact at k = s by orthonormality; truncation to
// k x k is the approximation). This file computes, per mesh vertex, b (k x k), and beside it the
// spherical-harmonic transfer vector of Sloan, Kautz & Snyder 2002 (T_lm = ∫ V max(0, n·ω) Y_lm
// dω, in the object's frame) and the ambient occlusion (1/π) ∫ V cos θ dω, all from the same
// occlusion rays (Embree), uniform in solid angle within each cell.
//
// The tangent frame. Both sides must use one frame per normal: east = ∂n/∂φ normalised (the
// direction of increasing longitude φ = atan2(n.x, n.z)), north = n x east, with φ := 0 where n
// is within 1e-6 of ±Y (the frame field's unavoidable singular point). The frame turns with the
// object about +Y, so the moments are unchanged by yaw: they are computed once in the object's
// own coordinates, and shading looks the lighting up at the vertex's longitude plus the yaw
// (which is also how a vertex exactly at the pole stays consistent). The SH transfer vector is
// rotated by the yaw about the SH pole (+Y).
//
// Where: at surface points (SurfacePoints): the mesh's vertices, and on triangles larger than a
// set fraction of the object a barycentric grid of points, so that a shadow falling across a
// large face is not smeared between its corners, each grid point lifted onto the smooth surface
// of the vertex normals (Mesh::smoothPoint: a coarse mesh's facets do not shadow its own
// terminator). The renderer interpolates linearly between the three points around a hit.
//
// Threading: computeTransfer() uses every core (points in parallel); the result is
// deterministic (per-point jitter from a hash of the point's position and the seed, so that the
// same point on two triangles gets the same answer).
#pragma once

#include <algorithm>
#include <bit>
#include <cstdint>
#include <string>
#include <vector>

#include <glm/mat3x3.hpp>
#include <glm/vec3.hpp>

#include "core/buffer.h"
#include "core/progress.h"
#include "lighting/lighting.h"
#include "lighting/sources.h"
#include "render/mesh.h"

namespace compose::render {

class EmbreeScene;

struct TransferParams {
  int grid = 16;  // s: s x s cells on the hemisphere around the normal
  int order = 8;  // k: k x k Chebyshev moments kept per vertex (k <= s)
  // One ray per cell first; then the cells on a shadow boundary (whose ray disagrees with a
  // neighbour's) get r x r stratified rays: r² - 1 more, the first ray standing for the stratum
  // it fell in (uniform within the cell, it is uniform within that stratum too).
  int boundaryRays = 3;
  int shBands = 4;  // SH transfer up to band 4: 25 coefficients per vertex
  uint32_t seed = 1;
  // False for an object that cannot hide any of itself (closed and convex): no ray is traced to
  // it and every direction counts as open (only a GroundContact then weighs the rays).
  bool selfOcclusion = true;

  // Throws compose::UsageError (stage "shadows") naming the parameter.
  void validate() const;
  // Everything that changes the numbers, for the cache key.
  std::string key() const;
  int firstPassRays() const { return grid * grid; }
};

// The points where the visibility is sampled: first the mesh's vertices (same indices), then for
// each triangle whose longest edge is longer than `maxEdge` a grid of `level` segments per edge
// (level = ceil(longest edge / maxEdge), at most 32), its corners being the triangle's vertices.
// maxEdge is `maxEdgeFraction` of the object's size, widened as needed to keep the number of
// points within `budget` (a finely tessellated mesh keeps its vertices only; back sides of their
// own, Mesh::sides, are not counted: each has the grid of its front). Grid points lie on the
// smooth surface (Mesh::smoothPoint); normals are the interpolated vertex normals, normalised.
struct SurfacePoints {
  std::vector<glm::vec3> positions, normals;  // object space
  std::vector<uint32_t> first;                // per triangle: index of its first own grid point
  std::vector<uint8_t> level;  // per triangle: segments per edge (1: the corners only)
  // Per point: 1 where the point lies inside another part of the object (an eye pushed into its
  // socket, a spout into a teapot's body: every ray from it meets that part from within). Such a
  // point sees nothing, but the surface next to it, where the parts meet, does: locate() leaves
  // it out of a hit's interpolation unless all three points are buried. Empty: none known.
  std::vector<uint8_t> buried;
  // Per point (empty: none), a step along the surface into the triangles the point lies on, of
  // length up to 1 (0 inside a flat fan). Rays leave from origin(): off the surface by the lift
  // along the normal and along this. A point on an edge where two faces meet at a concave hard
  // crease (a box's inner corner, whose floor and wall have vertices of their own) lies in the
  // other face's plane: lifted along its normal only, its rays towards that face start on it and
  // pass behind it, and the point sees through the wall.
  std::vector<glm::vec3> inward;
  float size = 0.0f;       // the object's size: its bounding box's largest extent
  glm::vec3 centre{0.0f};  // the object's bounding sphere (object space), to cull rays
  float radius = 0.0f;

  size_t count() const { return positions.size(); }
  // Where point p's rays leave from, `lift` off the surface.
  glm::vec3 origin(size_t p, float lift) const {
    return positions[p] + lift * (inward.empty() ? normals[p] : normals[p] + inward[p]);
  }
  // The point at grid node (i, j) of triangle t (barycentrics i/L, j/L of its corners 1 and 2;
  // i + j <= L, the triangle's level): a corner is the mesh's vertex.
  uint32_t gridPoint(const Mesh& mesh, uint32_t triangle, int i, int j) const;
  // The three points whose values, with these weights, interpolate at Embree's barycentrics
  // (u for corner 1, v for corner 2) of `triangle`. A buried point among them, with others that
  // are not, is replaced by the one of those with the largest weight, at weight 0, the others'
  // weights scaled to sum to 1.
  void locate(const Mesh& mesh, uint32_t triangle, float u, float v, uint32_t points[3],
              float weights[3]) const;
  // The same without leaving buried points out.
  void locateGrid(const Mesh& mesh, uint32_t triangle, float u, float v, uint32_t points[3],
                  float weights[3]) const;
};

SurfacePoints surfacePoints(const Mesh& mesh, float maxEdgeFraction = 1.0f / 96.0f,
                            size_t budget = 80000);
// Grid points from `from` on go back onto their flat triangle where something of the object lies
// between it and their lifted position (Mesh::smoothPoint): another part closer to the surface
// than the lift, which rays from the lifted point would pass. computeRefinedTransfer() calls it
// for the points it is given and those it adds; restoreLevels() leaves it to its caller.
void keepLiftsClear(const Mesh& mesh, const EmbreeScene& scene, SurfacePoints& points,
                    size_t from = 0);

// Where the visibility changes fast across a triangle (the rim of an eye socket, where a handle
// enters a body), interpolating linearly between its points blurs and facets the shadow. So
// after a first visibility pass the triangles whose points' ambient occlusion spans more than
// `spread` get a grid `factor` times finer (at most 32 segments per edge), those that span most
// first, until the new points reach `budget` times the points there were.
struct RefineParams {
  float spread = 0.35f;  // 0: no refinement
  float budget = 1.0f;
  int factor = 4;
  void validate() const;  // compose::UsageError (stage "shadows")
  std::string key() const;
};
// Raises the levels of the triangles to refine (from each point's ambient occlusion `ao`, one per
// point) and appends their new grid points; returns the index of the first new point (count()
// when none). Their old grid points stay, unused.
size_t refineSurfacePoints(const Mesh& mesh, SurfacePoints& points, const std::vector<float>& ao,
                           const RefineParams& params);
// Gives each triangle the level `levels` holds (one per triangle, as refineSurfacePoints left
// them, read back from a cache), appending grid points in the same order (the order of the
// triangles, in which refineSurfacePoints appends them too); false (points
// unchanged) if the levels do not fit: their count, a level outside 1..32, or one below the
// triangle's own.
bool restoreLevels(const Mesh& mesh, SurfacePoints& points, const std::vector<uint8_t>& levels);

// Per-point transfer of a mesh, in the mesh's own (object) coordinates.
struct VertexTransfer {
  TransferParams params;
  size_t vertexCount = 0;
  FloatBuffer cheb;       // k² per vertex: moments of V on the local grid
  std::vector<float> sh;  // (shBands + 1)² per vertex: Sloan's transfer vector
  std::vector<float> ao;  // per vertex: (1/π) ∫ V cos θ dω, in [0, 1]
  // Per vertex: 1 where the point is inside another part of the object (SurfacePoints::buried):
  // every ray of the first pass was blocked, and at least 12 of 16 of them (4 rows by 4 staggered
  // columns of cells) met the surface that blocked it from behind (its shading normal facing
  // along the ray).
  std::vector<uint8_t> buried;
  // The same without the ground (GroundContact), to refine by; empty without one. Not cached.
  std::vector<float> aoSelf;
  int64_t rays = 0;

  size_t floatsStored() const { return cheb.size() + sh.size() + ao.size() + buried.size(); }
  // Appends the transfer of more points (computed with the same parameters).
  void append(const VertexTransfer& more);
  // Plain floats for the on-disk cache, and back (taking `in`'s storage); false if `in` does not
  // fit these parameters.
  std::vector<float> exportState() const;
  bool importState(const TransferParams& params, size_t vertexCount, FloatBuffer in);
};

// The ground the object stands on, as the object's own points see it (docs/design.md §10). Below
// their horizon the environment shows that ground, lit as it was without the object; but the
// object hides part of the sky from the ground next to it, which then lights the object's
// underside less (what makes a bunny's chin and belly darker where they meet the floor). The
// ground is the plane y = `height` of the object's frame (its lowest point, cut-outs left out
// (Mesh::keptBounds): the pipeline stands every object on the ground, turned only about +Y). A ray
// from a surface point that misses the object and meets the plane at g counts open(g), the ground
// point's (1/π) ∫ V cos θ dω past the object, instead of 1: the ground's radiance scaled by the
// share of its light the object leaves it, that share taken from a uniform sky (it does not depend
// on the lighting, so the pass stays cached per mesh). open(g) is computed on two grids of ground
// points, a fine one over the footprint and just beyond it (where the ground's darkening changes
// over a fraction of the object's height) and a coarse one further out, and interpolated bilinearly
// between the nodes that the object does not cover (a node under the object sees nothing: no ray
// that misses the object reaches it, and it would darken the ground at the object's foot); beyond
// the coarse grid the edge's shortfall falls off as the inverse cube of the distance from the
// footprint's centre (as a sphere's form factor does).
struct GroundGridLevel {
  float x0 = 0.0f, z0 = 0.0f, step = 1.0f;  // node (a, b) at (x0 + a·step, height, z0 + b·step)
  int columns = 0, rows = 0;
  std::vector<float> open;  // per node, row-major (b, then a); 0: covered by the object
  bool empty() const { return open.empty(); }
  bool contains(float x, float z) const {
    return x >= x0 && z >= z0 && x <= x0 + float(columns - 1) * step &&
           z <= z0 + float(rows - 1) * step;
  }
  // Bilinear between the cell's uncovered nodes (0 when all four are covered), at a point
  // clamped to the grid.
  float at(float x, float z) const;
};
struct GroundContact {
  float height = 0.0f;                   // object space
  GroundGridLevel fine, coarse;          // fine may be empty (a coarse step already fine enough)
  float centreX = 0.0f, centreZ = 0.0f;  // the footprint's centre
  int64_t rays = 0;
  // Coarse nodes (indices into coarse.open) inside the fine grid, never read: filled from it
  // instead of traced.
  std::vector<uint32_t> filled;
  bool empty() const { return coarse.empty(); }
  size_t nodes() const { return fine.open.size() + coarse.open.size(); }
  // open(g) at the plane point (x, height, z); 1 for a point that is not finite.
  float openAt(float x, float z) const;
  // The weight of a ray from `origin` along unit `direction` that misses the object: 1 when it
  // does not go down; a ray from below the plane (rounding) meets it at once.
  float weight(const glm::vec3& origin, const glm::vec3& direction) const {
    if (direction.y >= 0.0f || coarse.empty()) return 1.0f;
    const float t = std::max(0.0f, (height - origin.y) / direction.y);
    return openAt(origin.x + t * direction.x, origin.z + t * direction.z);
  }
};
// The coarse grid: the footprint widened by `reach` times the object's size on every side,
// `resolution` nodes along its longer side. The fine grid: the footprint widened by `fineReach`
// times the object's height, nodes `fineSteps` to the height apart, or further apart to keep
// within `fineBudget` nodes.
struct GroundContactParams {
  int resolution = 128;
  float reach = 2.0f;
  float fineReach = 0.5f;
  int fineSteps = 48;
  size_t fineBudget = 16384;
  void validate() const;  // compose::UsageError (stage "shadows")
  std::string key() const;
};
GroundContact groundContact(const Mesh& mesh, const EmbreeScene& scene,
                            const GroundContactParams& params = {});

// The header of the visibility cache's files (core/float_cache.h); its last character is the
// format's version (B: checksums of 64-bit words).
inline constexpr char kTransferCacheMagic[] = "COMPVISB";

// Visibility of every surface point of `mesh` against the mesh itself. Rays leave each point
// from a spot lifted by 1e-4 of the mesh's size (SurfacePoints::origin). `scene` is the mesh's
// own (EmbreeScene(mesh): built from the positions and indices alone it would not know which
// triangles are met from their front only, Mesh::sides); without it one is built. With `ground`,
// rays that miss the object and go down count the ground's open(g) (GroundContact).
VertexTransfer computeTransfer(const Mesh& mesh, const EmbreeScene& scene,
                               const SurfacePoints& points, const TransferParams& params,
                               const Progress& progress = {},
                               const GroundContact* ground = nullptr);
VertexTransfer computeTransfer(const Mesh& mesh, const SurfacePoints& points,
                               const TransferParams& params, const Progress& progress = {});
// The visibility pass, then refineSurfacePoints() and the pass again at the new points: `points`
// gets them (and their buried flags), the transfer covers them all.
VertexTransfer computeRefinedTransfer(const Mesh& mesh, SurfacePoints& points,
                                      const TransferParams& params, const RefineParams& refine,
                                      const Progress& progress = {},
                                      const GroundContact* ground = nullptr);
// The same with the mesh's own scene (as computeTransfer's), instead of building one.
VertexTransfer computeRefinedTransfer(const Mesh& mesh, const EmbreeScene& scene,
                                      SurfacePoints& points, const TransferParams& params,
                                      const RefineParams& refine, const Progress& progress = {},
                                      const GroundContact* ground = nullptr);

// True when the mesh is closed and convex: every edge joins exactly two triangles and no
// triangle's far corner lies above its neighbour's plane. A convex solid cannot shadow itself,
// so the visibility pass is skipped for it. A mesh with cut-outs (Mesh::hasCutouts) is not.
bool isConvex(const Mesh& mesh);

// A 128-bit hash of the mesh's positions, normals and triangles (for cache keys).
std::string meshHash(const Mesh& mesh);

// How the shadowed irradiance is computed.
enum class ShadowMethod {
  Chebyshev,         // Σ a_mn b_mn with the cheb-local lighting's moments (its order k)
  Harmonics,         // Sloan's SH transfer with the sh lighting's radiance coefficients (its order)
  AmbientOcclusion,  // AO x unshadowed irradiance
};
const char* shadowMethodName(ShadowMethod method);

// How much of each bright source (lighting/sources.h) each point sees: visible[p·count + i] in
// [0, 1] for source i. Rays go from the point, lifted as in computeTransfer, to `raysPerSource`
// (1, 2 or 4: 1 x 1, 2 x 1 or 2 x 2) directions across the source's extent (its block of texels,
// stratified and jittered per point), turned into the object's frame, so that a source's shadow
// has a penumbra rather than one hard edge. (The object's own points take one: the renderer
// traces the sources again wherever the points around a hit disagree, renderer.h.)
// From a point outside the object's bounding sphere, a source outside the sphere's cone is seen
// without a ray. Every other source is traced: the visibility pass' one ray per cell can miss a
// thin occluder (a leg, a handle) that a small bright source's shadow must still show.
struct SourceVisibility {
  size_t count = 0;  // sources
  std::vector<float> visible;
  int64_t rays = 0;
};
SourceVisibility traceSources(const SurfacePoints& points, const EmbreeScene& objectScene,
                              const std::vector<lighting::LightSource>& sources,
                              const glm::mat3& envFromObject, int raysPerSource = 4);
// The object's points trace one ray per source: across a source's penumbra (a sun of a few
// degrees behind a roof's edge) each says 0 or 1 at random, so that neighbouring cells of a
// surface would be told they lie wholly in or out of it. Where the three points of a cell
// disagree about a source, each of them traces it again with 2 x 2 stratified rays across its
// extent, which replace its one: what they see of it is then a fraction where the penumbra
// passes. Returns the rays traced.
int64_t refineSourcePenumbrae(const Mesh& mesh, const SurfacePoints& points,
                              const EmbreeScene& objectScene,
                              const std::vector<lighting::LightSource>& sources,
                              const glm::mat3& envFromObject, SourceVisibility& visibility);

// A bright source's extent in the object's frame, for tracing its shadow across it: the
// direction at (a, b) in [-1/2, 1/2]² of its latitude/longitude block.
struct SourceFrame {
  glm::vec3 centre, east, north;  // object space
  float halfLat = 0.0f, halfLon = 0.0f;
  glm::vec3 direction(float a, float b) const {
    return glm::normalize(centre + 2.0f * a * halfLat * north + 2.0f * b * halfLon * east);
  }
};
std::vector<SourceFrame> sourceFrames(const std::vector<lighting::LightSource>& sources,
                                      const glm::mat3& envFromObject);

// What shading with self-shadowing needs besides the mesh.
struct ShadowInputs {
  ShadowMethod method = ShadowMethod::Chebyshev;
  const VertexTransfer* transfer = nullptr;
  // The lighting the transfer is applied to: of the residual when there are sources, else of the
  // whole environment. Chebyshev needs cheb-local (Lambertian) on the transfer's grid with order
  // <= the transfer's; Harmonics sh with order <= its SH bands; ambient occlusion any basis.
  const lighting::DiffuseLighting* shadowLighting = nullptr;
  // Bright sources split off (environment frame) and their per-vertex visibility; may be empty.
  // The unshadowed irradiance is the lighting's plus every source's, the shadowed one the
  // transfer's plus the sources each vertex sees; ambient occlusion scales the unshadowed one.
  std::vector<lighting::LightSource> sources;
  const SourceVisibility* sourceVisibility = nullptr;
};

// Per-point irradiance with and without self-shadowing, in the environment's frame and units.
struct VertexIrradiance {
  std::vector<glm::vec3> shadowed, unshadowed;
  int clamped = 0;  // vertices whose shadowed irradiance left [0, unshadowed] by more than 0.1 %
  // With bright sources (not for ambient occlusion): which sources each point sees, bit i of
  // sourceSeen[p] set when it sees at least half of source i (exactly what it sees when it
  // traced one ray per source, as the object's points do), so that the renderer can tell where a
  // source's shadow edge crosses a triangle and trace the source there (renderer.h). At most
  // 64 sources (lighting::kMaxSources).
  size_t sourceCount = 0;
  std::vector<uint64_t> sourceSeen;
  // Bit i set when the point sees part of source i, neither none nor all of it (its penumbra, a
  // semi-transparent occluder): the renderer traces the source wherever such a point is one of
  // the three around a hit, as where they disagree.
  std::vector<uint64_t> sourcePartial;
  // What those points see of those sources: per point, one value per set bit of sourcePartial
  // (lowest source first), from partialFirst[p] on (partialFirst: count + 1 entries).
  std::vector<float> partialFraction;
  std::vector<uint32_t> partialFirst;
  // What point p sees of source i, in [0, 1]: its fraction where it sees it in part, else 0 or 1.
  float seenFraction(size_t p, int i) const {
    if ((sourcePartial[p] >> i) & 1u)
      return partialFraction[partialFirst[p] +
                             uint32_t(std::popcount(sourcePartial[p] & ((uint64_t(1) << i) - 1)))];
    return float((sourceSeen[p] >> i) & 1u);
  }
  // Makes partialFirst from sourcePartial; false if partialFraction does not fit it.
  bool indexPartial();
};

// `envFromObject` is the rotation from the mesh's coordinates to the environment's; it must be a
// turn about +Y (placement yaw and environment yaw), so that the transfer's frames apply. Throws
// compose::Error (stage "shadows") when the inputs do not fit the method.
VertexIrradiance shadeVertices(const SurfacePoints& points, const glm::mat3& envFromObject,
                               const ShadowInputs& inputs);

}  // namespace compose::render
