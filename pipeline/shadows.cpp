#include "pipeline/shadows.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "core/error.h"
#include "core/float_cache.h"
#include "core/hash.h"
#include "core/params.h"
#include "lighting/chebyshev.h"
#include "lighting/lighting_cache.h"
#include "lighting/sh.h"
#include "lighting/sources.h"
#include "pipeline/stage_util.h"

namespace compose::pipeline {

namespace fs = std::filesystem;

namespace {

double seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// Projects `basis` onto `env`, through the lighting cache when there is one; what was wrong with
// the cache goes to `notes`.
bool projectCached(lighting::DiffuseLighting& basis, const lighting::Environment& env,
                   const fs::path& cacheRoot, const Progress& progress,
                   std::vector<std::string>& notes) {
  if (!cacheRoot.empty()) {
    const lighting::LightingCache cache(lightingCacheFolder(cacheRoot));
    const std::string key = lighting::LightingCache::key(env, basis);
    if (cache.load(key, basis, &notes)) return true;
    basis.project(env, progress);
    cache.store(key, basis, &notes);
    return false;
  }
  basis.project(env, progress);
  return false;
}

}  // namespace

fs::path lightingCacheFolder(const fs::path& root) {
  return root / "lighting";
}
fs::path visibilityCacheFolder(const fs::path& root) {
  return root / "visibility";
}

ShadowPlan ShadowPlan::parse(const std::string& text) {
  ShadowPlan plan;
  try {
    ParamSet p = ParamSet::parse(text, "shadows");
    const std::string method = p.getString("method", "cheb");
    if (method == "cheb") {
      plan.method = render::ShadowMethod::Chebyshev;
    } else if (method == "sh") {
      plan.method = render::ShadowMethod::Harmonics;
    } else if (method == "ao") {
      plan.method = render::ShadowMethod::AmbientOcclusion;
    } else {
      throw UsageError("method must be cheb, sh or ao, got '" + method + "'", "shadows");
    }
    const bool sh = plan.method == render::ShadowMethod::Harmonics;
    if (plan.method == render::ShadowMethod::AmbientOcclusion && p.has("order")) {
      throw UsageError("order does not apply to method=ao: ambient occlusion projects nothing",
                       "shadows");
    }
    if (plan.method == render::ShadowMethod::AmbientOcclusion && p.has("sources")) {
      throw UsageError(
          "sources does not apply to method=ao: ambient occlusion darkens all light alike and "
          "traces no source (method=cheb or sh cast directional shadows)",
          "shadows");
    }
    plan.transfer.grid = p.getInt("grid", 16, "shadows");
    // The default Chebyshev order is 16, or the grid's size on a coarser grid (k <= s).
    plan.lightingOrder =
        p.getInt("order", sh ? 4 : std::clamp(plan.transfer.grid, 1, 16), "shadows");
    plan.transfer.boundaryRays = p.getInt("boundary", 2, "shadows");
    plan.sources = p.getInt("sources", 64, "shadows");
    plan.refine.spread = float(p.getDouble("refine", plan.refine.spread, "shadows"));
    plan.refine.budget = float(p.getDouble("refine-budget", plan.refine.budget, "shadows"));
    if (plan.refine.spread == 0.0f && p.has("refine-budget"))
      throw UsageError("refine-budget does not apply with refine=0 (no refinement)", "shadows");
    const std::string ground = p.getString("ground", "on");
    if (ground != "on" && ground != "off")
      throw UsageError("ground must be on or off, got '" + ground + "'", "shadows");
    plan.ground = ground == "on";
    p.requireAllUsed("shadows",
                     "--shadow-params (method, order, grid, boundary, sources, refine, "
                     "refine-budget, ground)");
  } catch (const UsageError&) {
    throw;
  } catch (const Error& e) {
    throw UsageError(e.what(), "shadows");
  }
  if (plan.sources < 0 || plan.sources > lighting::kMaxSources)
    throw UsageError("sources must be in 0.." + std::to_string(lighting::kMaxSources) + ", got " +
                         std::to_string(plan.sources),
                     "shadows");
  if (plan.method == render::ShadowMethod::Harmonics) {
    if (plan.lightingOrder < 0 || plan.lightingOrder > lighting::kMaxShOrder)
      throw UsageError(
          "order (SH bands) must be in 0..8, got " + std::to_string(plan.lightingOrder), "shadows");
    plan.transfer.shBands = plan.lightingOrder;
    plan.transfer.order = 1;
  } else {
    plan.transfer.shBands = 0;
    plan.transfer.order = plan.method == render::ShadowMethod::Chebyshev ? plan.lightingOrder : 1;
  }
  if (plan.transfer.grid < 2 || plan.transfer.grid > 64) {
    throw UsageError("grid (s) must be in 2..64, got " + std::to_string(plan.transfer.grid),
                     "shadows");
  }
  if (plan.method == render::ShadowMethod::Chebyshev &&
      (plan.lightingOrder < 1 || plan.lightingOrder > std::min(plan.transfer.grid, 32))) {
    throw UsageError(
        "order (k) must be in 1..min(grid, 32), got " + std::to_string(plan.lightingOrder),
        "shadows");
  }
  plan.transfer.validate();
  plan.refine.validate();
  return plan;
}

std::string ShadowPlan::describe() const {
  std::string s = render::shadowMethodName(method);
  if (method == render::ShadowMethod::Chebyshev) {
    s += " k=" + std::to_string(lightingOrder) + " on " + std::to_string(transfer.grid) + "x" +
         std::to_string(transfer.grid) + " cells";
  } else if (method == render::ShadowMethod::Harmonics) {
    s += " up to band " + std::to_string(lightingOrder);
  }
  if (sources > 0 && method != render::ShadowMethod::AmbientOcclusion)
    s += ", " + std::to_string(sources) + " bright sources by rays";
  if (ground) s += ", the ground beneath it darkened";
  if (refine.spread > 0.0f) {
    char line[120];
    std::snprintf(line, sizeof line,
                  ", points %dx finer where their ambient occlusion spans more than %.2g",
                  refine.factor, double(refine.spread));
    s += line;
  }
  return s;
}

std::string ShadowPlan::key() const {
  return std::string(render::shadowMethodName(method)) + " order=" + std::to_string(lightingOrder) +
         " sources=" + std::to_string(sources) + " " + transfer.key() + " " + refine.key() +
         (ground ? " " + groundParams.key() : std::string(" ground=off"));
}

std::string ShadowPlan::lightingKey() const {
  ShadowPlan plan = *this;
  plan.ground = false;
  return plan.key();
}

std::string ShadowPlan::describeLighting() const {
  ShadowPlan plan = *this;
  plan.ground = false;
  return plan.describe();
}

ShadowLighting shadowLightingFor(const ShadowPlan& plan) {
  ShadowLighting out;
  if (plan.method == render::ShadowMethod::Chebyshev) {
    lighting::ChebParams cp;
    cp.order = plan.lightingOrder;
    cp.samples = plan.transfer.grid;
    out.lighting = std::make_unique<lighting::ChebLocalLighting>(cp);
  } else if (plan.method == render::ShadowMethod::Harmonics) {
    out.lighting = std::make_unique<lighting::ShLighting>(plan.lightingOrder);
  } else {
    // Ambient occlusion scales the unshadowed irradiance of the default basis.
    out.lighting = lighting::createLighting("cheb-local");
  }
  return out;
}

ShadowLighting prepareShadowLighting(const lighting::Environment& environment,
                                     const ShadowPlan& plan, const fs::path& cacheRoot,
                                     const Progress& progress) {
  ShadowLighting out = shadowLightingFor(plan);
  // The lighting the transfer applies to: the environment without its brightest sources.
  const int sourceCount = plan.method == render::ShadowMethod::AmbientOcclusion ? 0 : plan.sources;
  out.split = lighting::splitBrightSources(environment, sourceCount);
  const bool reused =
      projectCached(*out.lighting, out.split.residual, cacheRoot, progress, out.notes);
  out.split.residual = {};  // projected: the pixels are not needed any more
  out.reason = std::string(reused ? "reused" : "projected") + " its lighting (" +
               out.lighting->describe() + ")";
  if (plan.method == render::ShadowMethod::AmbientOcclusion) {
    out.reason +=
        "; ambient occlusion alone: no source casts a directional shadow, on the object or the "
        "ground (method=cheb does)";
  }
  if (!out.split.sources.empty()) {
    char line[160];
    std::snprintf(line, sizeof line, "; %zu bright sources (%.1f%% of the light) shadowed by rays",
                  out.split.sources.size(), 100.0 * out.split.sourceShare);
    out.reason += line;
  }
  return out;
}

namespace {

// Shadowed and unshadowed irradiance at `points` from their transfer and the sources they see.
render::VertexIrradiance shadePoints(const render::SurfacePoints& points,
                                     const render::VertexTransfer& transfer,
                                     const render::EmbreeScene& scene,
                                     const ShadowLighting& lighting, const glm::mat3& envFromObject,
                                     const ShadowPlan& plan, int raysPerSource, int64_t& sourceRays,
                                     const render::Mesh* penumbrae = nullptr) {
  render::SourceVisibility seen;
  if (!lighting.split.sources.empty()) {
    seen =
        render::traceSources(points, scene, lighting.split.sources, envFromObject, raysPerSource);
    if (penumbrae)
      render::refineSourcePenumbrae(*penumbrae, points, scene, lighting.split.sources,
                                    envFromObject, seen);
    sourceRays = seen.rays;
  }
  render::ShadowInputs inputs;
  inputs.method = plan.method;
  inputs.transfer = &transfer;
  inputs.shadowLighting = lighting.lighting.get();
  inputs.sources = lighting.split.sources;
  inputs.sourceVisibility = &seen;
  return render::shadeVertices(points, envFromObject, inputs);
}

}  // namespace

ShadowResult computeSelfShadowing(const render::Mesh& mesh, const render::EmbreeScene& scene,
                                  const ShadowLighting& lighting, const glm::mat3& envFromObject,
                                  const ShadowPlan& plan, const fs::path& cacheRoot,
                                  const Progress& progress, bool convex) {
  ShadowResult out;
  render::TransferParams transferParams = plan.transfer;
  transferParams.selfOcclusion = !convex;
  out.points = render::surfacePoints(mesh);
  // The visibility pass, cached by the mesh's content and the parameters. The entry holds the
  // transfer of every point, then the triangles' levels (the points refined where visibility
  // changes fast, render/transfer.h).
  render::VertexTransfer transfer;
  const auto start = std::chrono::steady_clock::now();
  bool reused = false;
  Hash128 h;
  h.bytes(render::meshHash(mesh));
  h.bytes(transferParams.key());
  h.bytes(plan.refine.key());
  const std::string groundKey = plan.ground ? plan.groundParams.key() : "no ground";
  h.bytes(groundKey);
  h.word(uint32_t(out.points.count()));
  const std::string key = h.hex();
  const FloatCache cache(visibilityCacheFolder(cacheRoot), render::kTransferCacheMagic,
                         ".visibility");
  const std::string description = "transfer " + transferParams.key() + " " + plan.refine.key() +
                                  " " + groundKey + " points " + std::to_string(out.points.count());
  const size_t triangles = mesh.triangleCount();
  if (!cacheRoot.empty()) {
    FloatCache::Read r = cache.read(key, description);
    std::string problem = r.problem;
    if (r.status == FloatCache::Read::Status::Hit) {
      const size_t values = r.values.size();
      std::vector<uint8_t> levels;
      if (values >= triangles) {
        levels.reserve(triangles);
        for (size_t t = values - triangles; t < values; ++t) {
          const float v = r.values[t];
          levels.push_back(v >= 1.0f && v <= 32.0f && v == std::floor(v) ? uint8_t(v) : 0);
        }
      }
      render::SurfacePoints refined = out.points;
      if (levels.size() == triangles && render::restoreLevels(mesh, refined, levels)) {
        r.values.resize(values - triangles);
        reused = transfer.importState(transferParams, refined.count(), std::move(r.values));
        if (reused) {
          out.points = std::move(refined);
          render::keepLiftsClear(mesh, scene, out.points);
          out.points.buried = transfer.buried;
        }
      }
      if (!reused) problem = "does not fit the mesh (" + std::to_string(values) + " values)";
    }
    if (!problem.empty()) {
      out.notes.push_back("the cached visibility pass " + cache.pathFor(key).string() + " " +
                          problem + ": ignored, computed again and rewritten");
    }
  }
  if (!reused) {
    const size_t base = out.points.count();
    render::GroundContact ground;
    if (plan.ground) ground = render::groundContact(mesh, scene, plan.groundParams);
    transfer = render::computeRefinedTransfer(mesh, scene, out.points, transferParams, plan.refine,
                                              progress, &ground);
    char line[320];
    std::snprintf(line, sizeof line,
                  "visibility pass at %zu points (%zu vertices, %zu more where visibility changes "
                  "fast): %lld rays (%.0f per point) in %.2f s",
                  out.points.count(), mesh.positions.size(), out.points.count() - base,
                  static_cast<long long>(transfer.rays),
                  double(transfer.rays) / double(out.points.count()), seconds(start));
    out.reason = line;
    if (convex) out.reason += " (closed and convex: no rays to the object itself)";
    if (!ground.empty()) {
      std::snprintf(line, sizeof line,
                    ", the ground beneath it from %zu points (%dx%d near it, %dx%d around less "
                    "the %zu within the first; %lld rays)",
                    ground.nodes() - ground.filled.size(), ground.fine.columns, ground.fine.rows,
                    ground.coarse.columns, ground.coarse.rows, ground.filled.size(),
                    static_cast<long long>(ground.rays));
      out.reason += line;
    }
    std::string problem;
    if (!cacheRoot.empty()) {
      std::vector<float> state = transfer.exportState();
      for (const uint8_t level : out.points.level) state.push_back(float(level));
      if (cache.store(key, description, state, &problem)) {
        out.reason += ", cached in " + cache.pathFor(key).string();
      } else {
        const std::string folder = cacheFolderProblem(cache.folder());
        out.notes.push_back(
            "the visibility pass was not cached (" +
            (folder.empty() ? problem + "): " + cache.folder().string() : folder + ")"));
      }
    }
  } else {
    out.reason =
        "reused the visibility pass " + cache.pathFor(key).string() + " (same mesh and parameters)";
  }
  // One ray per source per point, four where the points of a cell see a source differently:
  // the renderer traces a source again from the hit wherever the points around it see it
  // differently or in part (its shadow's edge and penumbra).
  int64_t sourceRays = 0;
  out.irradiance =
      shadePoints(out.points, transfer, scene, lighting, envFromObject, plan, 1, sourceRays, &mesh);
  out.occlusion = std::move(transfer.ao);
  if (out.irradiance.sourceCount > 0) out.sources = lighting.split.sources;
  return out;
}

namespace {

// How finely a region of the plate is sampled. A small one's shadow changes within a pixel (a
// contact shadow a few rows deep, ground seen at a grazing angle near the horizon): sampled at
// pixel centres, a 12-pixel cube's came out 0.22 to 1.31 times as dark as the mean over the
// ground each pixel shows, as the cube moved by a fraction of a pixel (test: GroundShadow.
// ASmallObjectsShadowIsThePixelsAverage). A region whose every pixel the budget of points would
// sample has its pixels split into 4 x 4 (the grid then spaces its nodes within the same budget)
// and the ratio box-filtered: 0.98-1.01 times. A larger one is sampled a pixel or more apart
// anyway.
int groundSupersampling(const render::GroundGrid& grid, const render::GroundSettings& settings) {
  const double area = double(grid.x1 - grid.x0) * double(grid.y1 - grid.y0);
  return area <= double(settings.maxPoints) ? 4 : 1;
}

// The camera of the plate with each pixel split into s x s.
calib::PlateCamera finerCamera(const calib::PlateCamera& camera, int s) {
  calib::PlateCamera fine = camera;
  fine.width *= s;
  fine.height *= s;
  fine.lens = camera.lens.resized(fine.width, fine.height);
  return fine;
}

// The ratio over the plate's pixels from one over their s x s parts (starting at the finer
// plate's x0, y0): each pixel the mean of its parts, 1 where a part is outside.
Image boxFiltered(const Image& fine, int x0, int y0, int s, int& plateX0, int& plateY0) {
  plateX0 = x0 / s;
  plateY0 = y0 / s;
  const int x1 = (x0 + fine.width + s - 1) / s, y1 = (y0 + fine.height + s - 1) / s;
  Image plate(x1 - plateX0, y1 - plateY0, fine.channels, fine.channelNames);
  plate.colorSpace = fine.colorSpace;
  const float share = 1.0f / float(s * s);
  for (int y = 0; y < plate.height; ++y)
    for (int x = 0; x < plate.width; ++x)
      for (int c = 0; c < plate.channels; ++c) {
        float sum = 0.0f;
        for (int v = 0; v < s; ++v)
          for (int u = 0; u < s; ++u) {
            const int fx = (plateX0 + x) * s + u - x0, fy = (plateY0 + y) * s + v - y0;
            sum += fx >= 0 && fy >= 0 && fx < fine.width && fy < fine.height ? fine.at(fx, fy)[c]
                                                                             : 1.0f;
          }
        plate.at(x, y)[c] = sum * share;
      }
  return plate;
}

}  // namespace

GroundShadowResult computeGroundShadow(const render::Mesh& mesh, const render::EmbreeScene& scene,
                                       const glm::dmat4& worldFromObject,
                                       const calib::PlateCamera& plateCamera,
                                       const ShadowLighting& lighting,
                                       const glm::mat3& envFromWorld,
                                       const glm::mat3& envFromObject, const ShadowPlan& plan,
                                       const Progress& progress) {
  GroundShadowResult out;
  const auto start = std::chrono::steady_clock::now();
  // The sources in the world's frame, to follow their shadows across the ground.
  std::vector<lighting::LightSource> worldSources = lighting.split.sources;
  const glm::mat3 worldFromEnv = glm::transpose(envFromWorld);
  for (auto& s : worldSources) s.direction = worldFromEnv * s.direction;
  const render::GroundSettings settings;
  out.grid = render::groundGrid(mesh, worldFromObject, plateCamera, worldSources, settings);
  if (out.grid.empty()) {
    out.reason = "no ground around the object is in view";
    return out;
  }
  out.supersample = groundSupersampling(out.grid, settings);
  const calib::PlateCamera camera =
      out.supersample > 1 ? finerCamera(plateCamera, out.supersample) : plateCamera;
  if (out.supersample > 1) {
    out.grid = render::groundGrid(mesh, worldFromObject, camera, worldSources, settings);
    if (out.grid.empty()) {  // what the frame shows of the region is under a pixel's parts
      out.reason = "no ground around the object is in view";
      return out;
    }
  }
  render::TransferParams params = plan.transfer;
  params.shBands = plan.method == render::ShadowMethod::Harmonics ? plan.transfer.shBands : 0;
  // Coarse to fine: the points of each level shaded, then the cells that need it split.
  int64_t rays = 0;
  do {
    const render::SurfacePoints batch = out.grid.pending();
    if (batch.count() == 0) continue;
    const render::VertexTransfer transfer = render::computeTransfer(
        mesh, scene, batch, params, out.grid.shaded == 0 ? progress : Progress{});
    int64_t sourceRays = 0;
    render::shadeGroundPoints(out.grid, shadePoints(batch, transfer, scene, lighting, envFromObject,
                                                    plan, 4, sourceRays));
    rays += transfer.rays + sourceRays;
  } while (render::refineGroundGrid(out.grid, scene, worldFromObject, camera, settings));
  out.ratio = render::groundRatio(out.grid);
  rays += render::sharpenGroundEdges(out.grid, out.ratio, scene, worldFromObject, camera, settings);
  out.points = out.grid.points.count();
  out.rays = rays;
  const int fineWidth = out.grid.x1 - out.grid.x0, fineHeight = out.grid.y1 - out.grid.y0;
  if (out.supersample > 1) {
    const int s = out.supersample;
    out.ratio = boxFiltered(out.ratio, out.grid.x0, out.grid.y0, s, out.grid.x0, out.grid.y0);
    out.grid.x1 = out.grid.x0 + out.ratio.width;
    out.grid.y1 = out.grid.y0 + out.ratio.height;
  }
  std::string levels;
  for (size_t l = 0; l < out.grid.splitCount.size(); ++l)
    levels += (l ? "/" : "") + std::to_string(out.grid.splitCount[l]);
  char line[512];
  // Strides in plate pixels.
  const double s = out.supersample;
  char split[80] = "";
  if (out.supersample > 1)
    std::snprintf(split, sizeof split, " (each split into %dx%d, %dx%d in all)", out.supersample,
                  out.supersample, fineWidth, fineHeight);
  std::snprintf(line, sizeof line,
                "ground shadow over %dx%d plate pixels%s from %zu ground points (every %.3g "
                "pixels, cells split where the shadow changes down to %.3g pixels and across "
                "sharp edges to %.3g: %s cells split per level): %lld rays in %.2f s",
                out.grid.x1 - out.grid.x0, out.grid.y1 - out.grid.y0, split,
                out.grid.points.count(), out.grid.firstStride() / s, out.grid.stride / s,
                out.grid.unit / s, levels.c_str(), static_cast<long long>(rays), seconds(start));
  out.reason = line;
  return out;
}

}  // namespace compose::pipeline
