// Self-shadowing for the compose pipeline: which method and parameters, the visibility pass
// (cached on disk), the lighting it needs, and the per-vertex irradiance the renderer uses.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <glm/mat3x3.hpp>

#include "calib/plate_camera.h"
#include "core/progress.h"
#include "lighting/environment.h"
#include "lighting/lighting.h"
#include "lighting/sources.h"
#include "render/embree_scene.h"
#include "render/ground.h"
#include "render/mesh.h"
#include "render/transfer.h"

namespace compose::pipeline {

// --shadow-params: method=cheb|sh|ao (cheb), order (cheb: k, 16; sh: bands, 4), grid (s, 16),
// boundary (r, 2: r x r rays on the cells along a shadow's edge), sources (64: bright sources
// split off and shadowed by exact rays, 0..64), refine (0.35: triangles whose points' ambient
// occlusion spans more get points 4x finer; 0: none) and refine-budget (1: at most as many new
// points as there were).
struct ShadowPlan {
  render::ShadowMethod method = render::ShadowMethod::Chebyshev;
  render::TransferParams transfer;
  int lightingOrder = 16;  // cheb: k; sh: bands
  int sources = 64;
  render::RefineParams refine;  // refine (0.35: the spread), refine-budget (1: as many again)
  // ground=on|off: the ground the object stands on darkens the light its underside gets from
  // below (render::GroundContact); on by default.
  bool ground = true;
  render::GroundContactParams groundParams;

  // Throws compose::UsageError (stage "shadows") naming the bad parameter; unknown ones list the
  // valid ones.
  static ShadowPlan parse(const std::string& params);
  std::string describe() const;
  // What the shadow lighting and the plate's ground shadow depend on: describe() without the
  // ground beneath the object (which changes only the object's own shading).
  std::string describeLighting() const;
  // Every parameter that changes the numbers, for the cache keys (describe() is for people: it
  // leaves out what the method does not show, such as sh's and ao's grid, the boundary rays, the
  // refinement's budget); lightingKey() without the ground beneath the object.
  std::string key() const;
  std::string lightingKey() const;
};

struct ShadowResult {
  render::SurfacePoints points;
  render::VertexIrradiance irradiance;
  // The bright sources whose per-point visibility `irradiance` holds (environment frame), for the
  // renderer to trace where their shadow edges cross a triangle; empty for ambient occlusion.
  std::vector<lighting::LightSource> sources;
  std::vector<float> occlusion;    // per-point ambient occlusion
  std::string reason;              // what ran or was reused, for the stage report
  std::vector<std::string> notes;  // what was wrong with the visibility cache, for the user
};

// The cache folders under a cache root.
std::filesystem::path lightingCacheFolder(const std::filesystem::path& root);
std::filesystem::path visibilityCacheFolder(const std::filesystem::path& root);

// The lighting the shadows use: the environment with its brightest sources split off (each
// shadowed by rays), the rest projected for the method (through the lighting cache).
struct ShadowLighting {
  lighting::SourceSplit split;
  std::unique_ptr<lighting::DiffuseLighting> lighting;
  std::string reason;
  std::vector<std::string> notes;  // what was wrong with the lighting cache, for the user
};
// The shadow lighting's basis for a plan, not yet projected (to be projected, or restored).
ShadowLighting shadowLightingFor(const ShadowPlan& plan);
ShadowLighting prepareShadowLighting(const lighting::Environment& environment,
                                     const ShadowPlan& plan, const std::filesystem::path& cacheRoot,
                                     const Progress& progress = {});

// The visibility pass of `mesh` (object space, traced in `scene`) at its surface points, from the
// cache under `cacheRoot` when it holds this mesh with these parameters (an empty root: no
// cache), then their shadowed and unshadowed irradiance. `envFromObject` turns the mesh into the
// environment's frame (a yaw).
// `convex`: the mesh is closed and convex (render::isConvex): it cannot hide itself, so no ray is
// traced to it and only the ground beneath (plan.ground) weighs the directions.
ShadowResult computeSelfShadowing(const render::Mesh& mesh, const render::EmbreeScene& scene,
                                  const ShadowLighting& lighting, const glm::mat3& envFromObject,
                                  const ShadowPlan& plan, const std::filesystem::path& cacheRoot,
                                  const Progress& progress = {}, bool convex = false);

// The shadow the object casts on the ground (render/ground.h): the ratio E_with / E_without over
// the plate pixels where it can fall, by the same transfer at ground points.
struct GroundShadowResult {
  // The lattice the ratio was computed on; when supersampled, its rectangle is put back in plate
  // pixels (grid.x0 ... grid.y1) and the rest is the finer lattice's.
  render::GroundGrid grid;
  Image ratio;  // RGB over [grid.x0, grid.x1) x [grid.y0, grid.y1) of the plate; 1 = no shadow
  // The plate's pixels were split into supersample x supersample (a small region, whose shadow
  // changes within a pixel) and the ratio box-filtered over them.
  int supersample = 1;
  std::string reason;
  size_t points = 0;  // ground points shaded
  int64_t rays = 0;   // rays traced for them
};
GroundShadowResult computeGroundShadow(
    const render::Mesh& mesh, const render::EmbreeScene& scene, const glm::dmat4& worldFromObject,
    const calib::PlateCamera& camera, const ShadowLighting& lighting, const glm::mat3& envFromWorld,
    const glm::mat3& envFromObject, const ShadowPlan& plan, const Progress& progress = {});

}  // namespace compose::pipeline
