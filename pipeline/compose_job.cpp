#include "pipeline/compose_job.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <numbers>

#include <glm/gtc/matrix_transform.hpp>

#include "calib/lens.h"
#include "composite/composite.h"
#include "core/error.h"
#include "core/output_files.h"
#include "cubemap/environment_io.h"
#include "ingest/image_io.h"
#include "lighting/capture_volume.h"
#include "lighting/environment.h"
#include "lighting/lighting.h"
#include "lighting/lighting_cache.h"
#include "lighting/order_selector.h"
#include "pipeline/materials.h"
#include "pipeline/shadows.h"
#include "render/embree_scene.h"
#include "render/mesh.h"
#include "render/renderer.h"
#include "render/transfer.h"

namespace compose::pipeline {

namespace fs = std::filesystem;

const std::vector<std::string>& stageNames() {
  static const std::vector<std::string> names = {"ingest",     "merge",  "stitch",    "color",
                                                 "precompute", "render", "composite", "output"};
  return names;
}

fs::path samplesDirectory() {
  if (const char* dir = std::getenv("COMPOSE_SAMPLES_DIR"); dir && *dir) return dir;
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg)
    return fs::path(xdg) / "compose" / "samples";
  if (const char* home = std::getenv("HOME"); home && *home)
    return fs::path(home) / ".cache" / "compose" / "samples";
  return fs::path(".cache") / "compose" / "samples";
}

fs::path defaultEnvironment() {
  return samplesDirectory() / "forest.exr";
}

fs::path cacheDirectory() {
  if (const char* dir = std::getenv("COMPOSE_CACHE_DIR"); dir && *dir) return dir;
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg)
    return fs::path(xdg) / "compose";
  if (const char* home = std::getenv("HOME"); home && *home)
    return fs::path(home) / ".cache" / "compose";
  return fs::path(".cache") / "compose";
}

namespace {

fs::path outputBase(const ComposeJob& job) {
  fs::path base = job.output;
  std::error_code ec;
  if (!base.empty() && (!base.has_filename() || fs::is_directory(base, ec))) {
    return base / "compose";
  }
  std::string ext = base.extension().string();
  for (auto& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".exr" || ext == ".jpg" || ext == ".jpeg" || ext == ".png") base.replace_extension();
  return base;
}

fs::path environmentPath(const ComposeJob& job) {
  return job.environment.empty() ? defaultEnvironment() : job.environment;
}

// Makes any image RGB: grey is replicated, extra channels (alpha) are dropped.
Image toRgb(const Image& in) {
  if (in.channels == 3) return in;
  Image out(in.width, in.height, 3, {"R", "G", "B"});
  out.colorSpace = in.colorSpace;
  for (size_t i = 0; i < in.pixelCount(); ++i) {
    const float* s = in.pixels.data() + i * size_t(in.channels);
    float* d = out.pixels.data() + i * 3;
    if (in.channels < 3) {
      d[0] = d[1] = d[2] = s[0];
    } else {
      d[0] = s[0];
      d[1] = s[1];
      d[2] = s[2];
    }
  }
  return out;
}

bool isHdrFormat(const std::string& format) {
  return format == "openexr" || format == "hdr" || format == "tiff" || format == "raw";
}

// Automatic exposure: a mid-grey ball standing where the object stands, lit by the environment,
// should look as bright in the composite as middle grey looks in the plate. The plate's middle
// grey is its log-average (the key that a camera's reflected-light meter exposes for); the ball's
// brightness is the mean radiance of its visible half, each normal weighted by its projected
// area towards the camera. Unlike matching what the environment shows in the camera's field of
// view, this follows the light that falls on the object, wherever it comes from (a softbox behind
// the camera, a dark backdrop in view).
struct ExposureMatch {
  double scale = 1.0;         // plate units per environment unit
  double plateKey = 0.0;      // log-average of the plate's RGB mean
  double ballRadiance = 0.0;  // 0.18 × mean E/π over the ball's visible half (environment units)
};

ExposureMatch autoExposure(const Image& plateLinear, const lighting::DiffuseLighting& lighting,
                           const glm::dvec3& towardCamera, const glm::mat3& envFromWorld) {
  ExposureMatch m;
  // Plate: log-average over an even spread of pixels, with a floor well below any 8-bit level.
  constexpr double kFloor = 1e-4;
  double logSum = 0.0;
  int64_t count = 0;
  const int step = std::max(1, int(std::sqrt(double(plateLinear.pixelCount()) / 65536.0)));
  for (int y = step / 2; y < plateLinear.height; y += step) {
    for (int x = step / 2; x < plateLinear.width; x += step) {
      const float* p = plateLinear.at(x, y);
      logSum += std::log(std::max(kFloor, (double(p[0]) + p[1] + p[2]) / 3.0));
      ++count;
    }
  }
  m.plateKey = std::exp(logSum / double(std::max<int64_t>(count, 1)));
  // Ball: normals on the hemisphere facing the camera (a Fibonacci spiral, evenly spread).
  const glm::dvec3 c = glm::normalize(towardCamera);
  const glm::dvec3 helper = std::abs(c.y) < 0.9 ? glm::dvec3(0, 1, 0) : glm::dvec3(1, 0, 0);
  const glm::dvec3 u = glm::normalize(glm::cross(helper, c)), v = glm::cross(c, u);
  constexpr int kNormals = 256;
  double weighted = 0.0, weights = 0.0;
  for (int i = 0; i < kNormals; ++i) {
    const double z = 1.0 - (i + 0.5) / kNormals;  // cos of the angle to the camera, (0, 1]
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    const double phi = double(i) * 2.399963229728653;  // golden angle
    const glm::dvec3 n = z * c + r * std::cos(phi) * u + r * std::sin(phi) * v;
    const glm::vec3 e = glm::max(lighting.irradiance(envFromWorld * glm::vec3(n)), glm::vec3(0.0f));
    weighted += z * (double(e.x) + e.y + e.z) / 3.0;
    weights += z;
  }
  m.ballRadiance = 0.18 * weighted / weights / std::numbers::pi;
  if (m.ballRadiance > 0.0 && m.plateKey > 0.0) m.scale = m.plateKey / m.ballRadiance;
  return m;
}

// Brings an input image to the working space and says how it was read. An explicit colour space
// (--plate-space, --env-space) wins; an OpenEXR file that carries chromaticities is taken by
// them (as the colour space of the config with those primaries, or converted by matrix);
// otherwise the space the file declares, else the config's file rules.
std::string toWorkingSpace(Image& image, const fs::path& file, const ingest::CaptureInfo& info,
                           const std::string& explicitSpace, const std::string& option,
                           const color::ColorConfig& colors) {
  const std::string working = colors.workingSpace();
  if (!explicitSpace.empty()) {
    image.colorSpace = colors.resolve(explicitSpace, option);
    colors.convert(image, working);
    return "'" + image.colorSpace + "' (" + option + ")";
  }
  if (info.chromaticities) {
    const std::string named = colors.spaceWithChromaticities(*info.chromaticities);
    if (!named.empty()) {
      image.colorSpace = named;
      colors.convert(image, working);
      return "'" + named + "' (by the chromaticities in its header)";
    }
    colors.convertFromChromaticities(image, *info.chromaticities, working);
    return "the RGB space of the chromaticities in its header (converted by matrix)";
  }
  image.colorSpace = colors.inputSpaceFor(file, info.fileColorSpace);
  const std::string read = image.colorSpace;
  colors.convert(image, working);
  return "'" + read + "'";
}

// The proxy of the surroundings the job describes (distant when it describes none).
lighting::CaptureProxy captureProxy(const ComposeJob& job) {
  lighting::CaptureProxy proxy;
  proxy.capturePoint = job.captureAt ? *job.captureAt : glm::dvec3(0.0, job.camera.height, 0.0);
  if (job.room) {
    proxy.shape = lighting::CaptureProxy::Shape::Box;
    proxy.boxMin = glm::dvec3(-0.5 * job.room->x, 0.0, -0.5 * job.room->z);
    proxy.boxMax = glm::dvec3(0.5 * job.room->x, job.room->y, 0.5 * job.room->z);
  } else if (job.environmentRadius) {
    proxy.shape = lighting::CaptureProxy::Shape::Sphere;
    proxy.radius = *job.environmentRadius;
  }
  return proxy;
}

// A holdout mask: the first channel of any image the plate's size, as stored (no colour
// management: it is data).
Image loadHoldout(const fs::path& file, int width, int height) {
  ingest::LoadedImage m = ingest::readImage(file, "composite");
  if (m.image.width != width || m.image.height != height) {
    throw Error("composite",
                "the holdout mask is " + std::to_string(m.image.width) + "x" +
                    std::to_string(m.image.height) + ", the plate " + std::to_string(width) + "x" +
                    std::to_string(height) + ": it must be the plate's size",
                file);
  }
  return std::move(m.image);
}

class StageTimer {
 public:
  explicit StageTimer(StageRecord& record)
      : record_(record), start_(std::chrono::steady_clock::now()) {}
  ~StageTimer() {
    record_.seconds +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  StageRecord& record_;
  std::chrono::steady_clock::time_point start_;
};

StageRecord& stage(std::vector<StageRecord>& stages, const std::string& name) {
  for (auto& s : stages) {
    if (s.name == name) return s;
  }
  COMPOSE_CHECK(false);
  return stages.front();
}

}  // namespace

fs::path exrPathFor(const ComposeJob& job) {
  fs::path p = outputBase(job);
  p += ".exr";
  return p;
}

fs::path displayPathFor(const ComposeJob& job) {
  std::string ext = job.output.extension().string();
  for (auto& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
  fs::path p = outputBase(job);
  p += (ext == ".png") ? ".png" : ".jpg";
  return p;
}

void validate(const ComposeJob& job) {
  if (job.plate.empty()) throw UsageError("--plate is required");
  if (job.object.empty()) throw UsageError("--object is required");
  if (job.output.empty()) throw UsageError("--out must not be empty");
  if (job.samplesPerAxis < 1 || job.samplesPerAxis > 64) {
    throw UsageError("--samples must be in 1..64, got " + std::to_string(job.samplesPerAxis));
  }
  if (!std::isfinite(job.environmentYawDegrees))
    throw UsageError("--env-yaw must be a finite number of degrees");
  for (int c = 0; job.albedo && c < 3; ++c) {
    if (!((*job.albedo)[c] >= 0.0f && (*job.albedo)[c] <= 1.0f))
      throw UsageError("--albedo must be within [0, 1]");
  }
  if (!(job.creaseDegrees >= 0.0 && job.creaseDegrees <= 180.0))
    throw UsageError("--crease must be an angle within [0, 180] degrees");
  if (job.exposureStops && !(std::abs(*job.exposureStops) <= 64.0)) {
    throw UsageError("--exposure must be a number of stops within ±64");
  }
  job.camera.validate();
  job.placement.validate();
  ShadowPlan::parse(job.shadowParams);
  if (job.room && job.environmentRadius) throw UsageError("give either --room or --env-radius");
  if (job.captureAt && !job.room && !job.environmentRadius)
    throw UsageError(
        "--capture-at needs --room or --env-radius (a distant environment has no "
        "position)");
  try {
    captureProxy(job).validate();
  } catch (const UsageError&) {
    throw;
  } catch (const Error& e) {
    throw UsageError(e.what(), e.stage());
  }
  // The lighting basis and its parameters: a misspelt name fails before any pixel is read.
  try {
    ParamSet params = ParamSet::parse(job.lightingParams, "lighting");
    if (params.has("order") && params.getString("order", "") == "auto") {
      params.getDouble("target", 45.0, "lighting");
      params.erase("order");
      params.erase("target");
    } else if (params.has("target")) {
      throw Error("lighting", "target=... needs order=auto");
    }
    lighting::createLighting(job.lighting, params);
  } catch (const UsageError&) {
    throw;
  } catch (const Error& e) {
    throw UsageError(e.what(), e.stage());
  }
}

std::vector<StageRecord> plan(const ComposeJob& job) {
  const fs::path env = environmentPath(job);
  std::vector<StageRecord> s;
  s.push_back({"ingest", true,
               "read the plate " + job.plate.string() + ", the object " + job.object.string() +
                   " and the environment " + env.string()});
  s.push_back(
      {"merge", false, "the environment is a single HDR image, no exposure bracket to merge"});
  std::error_code ec;
  if (fs::is_directory(env, ec) || env.string().find('%') != std::string::npos) {
    s.push_back({"stitch", true,
                 "assemble the six cube faces and resample them exactly to a lat-long map (photos "
                 "are stitched with compose stitch)"});
  } else {
    s.push_back({"stitch", false,
                 "one environment image (lat-long, OpenEXR cube or cross): nothing to stitch; a "
                 "cube is resampled to lat-long on loading"});
  }
  s.push_back({"color", true, "plate and environment to the working space (role scene_linear)"});
  s.push_back(
      {"precompute", true,
       "project the environment onto the '" + job.lighting + "' lighting basis" +
           (job.cache.empty()
                ? std::string(" (cache off)")
                : ", or reuse the cached projection in " + lightingCacheFolder(job.cache).string() +
                      " if this environment and these parameters were seen before")});
  if (job.shadows) {
    s.push_back({"shadows", true,
                 "self-shadowing by " + ShadowPlan::parse(job.shadowParams).describe() +
                     ", unless the object is convex; the visibility pass is reused from " +
                     (job.cache.empty() ? std::string("nowhere (cache off)")
                                        : visibilityCacheFolder(job.cache).string()) +
                     " when this mesh was seen with these parameters"});
  } else {
    s.push_back({"shadows", false, "--shadows off"});
  }
  if (job.groundShadow) {
    s.push_back({"ground", true,
                 "the object's shadow on the ground: the plate times E_with / E_without where it "
                 "can fall (the same transfer at ground points)"});
  } else {
    s.push_back({"ground", false, "--no-shadow"});
  }
  s.push_back({"render", true,
               "ray-cast the object with " +
                   std::to_string(job.samplesPerAxis * job.samplesPerAxis) + " samples per pixel"});
  s.push_back({"composite", true,
               "premultiplied over, in scene-linear light" +
                   std::string(job.holdout.empty() ? "" : ", the holdout mask's plate in front")});
  s.push_back({"output", true,
               "write " + exrPathFor(job).string() + " and " + displayPathFor(job).string()});
  return s;
}

ComposeResult runCompose(const ComposeJob& job, const color::ColorConfig& colors,
                         const Progress& progress) {
  ComposeResult result;
  result.stages = plan(job);
  result.exrPath = exrPathFor(job);
  result.displayPath = displayPathFor(job);
  const fs::path envPath = environmentPath(job);
  validate(job);

  // Lighting basis first: a misspelt name should fail before any pixel is read. order=auto (with
  // an optional target=dB, default 45) defers the order to the environment's own tail energy.
  ParamSet lightingParams = ParamSet::parse(job.lightingParams, "lighting");
  const bool autoOrder =
      lightingParams.has("order") && lightingParams.getString("order", "") == "auto";
  double targetDb = 45.0;
  if (autoOrder) {
    targetDb = lightingParams.getDouble("target", targetDb, "lighting");
    lightingParams.erase("order");
    lightingParams.erase("target");
  } else if (lightingParams.has("target")) {
    throw Error("lighting", "target=... needs order=auto");
  }
  auto lighting = lighting::createLighting(job.lighting, lightingParams);

  // ingest
  ingest::LoadedImage plate;
  cubemap::LoadedEnvironment env;
  render::Mesh mesh;
  {
    StageTimer t(stage(result.stages, "ingest"));
    if (job.environment.empty() && !fs::exists(envPath)) {
      throw Error("ingest",
                  "no --env given and the sample environment is missing; run samples/fetch.sh",
                  envPath);
    }
    plate = ingest::readImage(job.plate, "ingest");
    env = cubemap::loadEnvironment(envPath, {}, progress);  // any layout, as a lat-long map
    for (const std::string& n : env.notes) result.notes.push_back(n);
    mesh = render::loadMesh(job.object, {.creaseDegrees = job.creaseDegrees});
    report(progress, "ingest", 1.0);
  }
  result.width = plate.image.width;
  result.height = plate.image.height;
  if (!mesh.normalsFromFile) result.notes.push_back("object normals: " + mesh.normalsSource);
  for (const std::string& w : mesh.warnings) result.notes.push_back("object: " + w);
  if (!isHdrFormat(env.info.format)) {
    result.notes.push_back(
        "the environment is a " + env.info.format +
        " file, not HDR: bright light sources are clipped and the lighting will be too dark");
  }

  // color
  Image plateLinear = toRgb(plate.image);
  Image envLinear = toRgb(env.image);
  const std::string working = colors.workingSpace();
  {
    StageTimer t(stage(result.stages, "color"));
    const std::string plateRead =
        toWorkingSpace(plateLinear, job.plate, plate.info, job.plateSpace, "--plate-space", colors);
    const std::string envRead =
        toWorkingSpace(envLinear, env.file, env.info, job.environmentSpace, "--env-space", colors);
    result.notes.push_back("plate read as " + plateRead + ", environment as " + envRead +
                           ", working space '" + working + "' (config: " + colors.source() + ")");
    if (job.albedo && mesh.hasMaterials()) {
      result.notes.push_back("object: --albedo replaces the materials of the mesh");
    } else if (const std::string read = materialsToWorkingSpace(mesh, colors); !read.empty()) {
      result.notes.push_back(read);
    }
  }

  // precompute
  lighting::Environment environment;
  {
    StageTimer t(stage(result.stages, "precompute"));
    lighting::SanitizeReport sanitized;
    environment = lighting::Environment::fromLatLong(envLinear, envPath, &sanitized);
    if (sanitized.negativeTexels > 0) {
      result.notes.push_back(std::to_string(sanitized.negativeTexels) +
                             " environment texels had negative values (as low as " +
                             std::to_string(sanitized.mostNegative) + "): clamped to 0");
    }
    if (const lighting::CaptureProxy proxy = captureProxy(job);
        proxy.shape != lighting::CaptureProxy::Shape::Distant) {
      // Parallax: the environment as seen from the object's centre (camera and placement as the
      // render stage will have them).
      calib::CameraOptions cameraOptions = job.camera;
      if (!job.lensFile.empty()) cameraOptions.lens = calib::readLens(job.lensFile);
      const calib::PlateCamera camera =
          calib::plateCamera(plate.image.width, plate.image.height, plate.info, cameraOptions);
      const glm::dmat4 worldFromObject = calib::placeOnGround(
          camera, job.placement, glm::dvec3(mesh.boundsMin()), glm::dvec3(mesh.boundsMax()));
      const glm::dvec3 centre(
          worldFromObject * glm::dvec4(0.5 * glm::dvec3(mesh.boundsMin() + mesh.boundsMax()), 1.0));
      lighting::CaptureProxy placed = proxy;
      const double yaw = -job.environmentYawDegrees * std::numbers::pi / 180.0;
      placed.environmentFromWorld =
          glm::dmat3(glm::rotate(glm::dmat4(1.0), yaw, glm::dvec3(0, 1, 0)));
      environment = lighting::CaptureVolumeSource(environment, placed).at(glm::vec3(centre));
      char line[300];
      std::snprintf(line, sizeof line,
                    "parallax: the environment as seen from the object's centre "
                    "(%.2f, %.2f, %.2f) m; surroundings: ",
                    centre.x, centre.y, centre.z);
      result.notes.push_back(line + proxy.describe());
      if (!proxy.contains(centre)) {
        result.notes.push_back(
            "the object's centre is outside the surroundings given: it is lit as from the "
            "nearest point inside them");
      }
    }
    StageRecord& record = stage(result.stages, "precompute");
    if (autoOrder) {
      const auto estimates = lighting::estimateOrders(job.lighting, environment, lightingParams);
      const lighting::OrderEstimate pick = lighting::selectOrder(estimates, targetDb);
      ParamSet chosen = lightingParams;
      chosen.set("order", std::to_string(pick.order));
      lighting = lighting::createLighting(job.lighting, chosen);
      char line[200];
      std::snprintf(line, sizeof line,
                    "order=auto: %s order %d, estimated truncation SNR %.1f dB (target %.1f dB)",
                    job.lighting.c_str(), pick.order, pick.estimatedSnrDb, targetDb);
      result.notes.push_back(line);
    }
    bool reused = false;
    if (!job.cache.empty()) {
      const lighting::LightingCache cache(lightingCacheFolder(job.cache));
      const std::string key = lighting::LightingCache::key(environment, *lighting);
      reused = cache.load(key, *lighting);
      if (reused) {
        record.reason = "reused the cached projection " + cache.pathFor(key).string() +
                        " (same environment pixels and basis parameters)";
      } else {
        lighting->project(environment, progress);
        record.reason = "projected the environment";
        if (cache.store(key, *lighting))
          record.reason += " and cached it in " + cache.pathFor(key).string();
      }
    } else {
      lighting->project(environment, progress);
      record.reason = "projected the environment (cache off)";
    }
    record.reason += ": " + lighting->describe();
  }

  // The plate camera and where the object stands.
  calib::CameraOptions cameraOptions = job.camera;
  if (!job.lensFile.empty()) cameraOptions.lens = calib::readLens(job.lensFile);
  const calib::PlateCamera camera =
      calib::plateCamera(plateLinear.width, plateLinear.height, plate.info, cameraOptions);
  result.notes.push_back("camera: " + std::to_string(int(std::lround(camera.focal35mm))) +
                         " mm equivalent, " + camera.focalSource);
  const glm::dmat4 worldFromObject = calib::placeOnGround(
      camera, job.placement, glm::dvec3(mesh.boundsMin()), glm::dvec3(mesh.boundsMax()));
  const double envYaw = -job.environmentYawDegrees * std::numbers::pi / 180.0;
  const glm::mat3 envFromWorld =
      glm::mat3(glm::rotate(glm::dmat4(1.0), envYaw, glm::dvec3(0, 1, 0)));
  // The rotation part of the placement (a yaw and a uniform scale), normalised.
  glm::mat3 worldFromObjectRotation = glm::mat3(worldFromObject);
  for (int c = 0; c < 3; ++c)
    worldFromObjectRotation[c] = glm::normalize(worldFromObjectRotation[c]);
  const render::EmbreeScene objectScene(mesh.positions, mesh.indices);

  // shadows: on the object itself, then on the ground, with one shadow lighting for both.
  const ShadowPlan shadowPlan = ShadowPlan::parse(job.shadowParams);
  const glm::mat3 envFromObject = envFromWorld * worldFromObjectRotation;
  std::optional<ShadowLighting> shadowLighting;
  auto needShadowLighting = [&]() -> const ShadowLighting& {
    if (!shadowLighting) {
      shadowLighting = prepareShadowLighting(environment, shadowPlan, job.cache, progress);
    }
    return *shadowLighting;
  };
  pipeline::ShadowResult shadows;
  bool shadowed = false;
  {
    StageRecord& record = stage(result.stages, "shadows");
    StageTimer t(record);
    if (!job.shadows) {
      record.runs = false;
      record.reason = "--shadows off";
    } else if (render::isConvex(mesh)) {
      record.runs = false;
      record.reason = "the object is closed and convex: it cannot shadow itself";
    } else {
      const ShadowLighting& sl = needShadowLighting();
      shadows = computeSelfShadowing(mesh, objectScene, sl, envFromObject, shadowPlan, job.cache,
                                     progress);
      record.reason = shadowPlan.describe() + ": " + shadows.reason + "; " + sl.reason;
      if (shadows.irradiance.clamped > 0) {
        result.notes.push_back(std::to_string(shadows.irradiance.clamped) +
                               " vertices' shadowed irradiance rang outside [0, unshadowed] "
                               "(truncation) and was clamped");
      }
      shadowed = true;
    }
  }

  GroundShadowResult ground;
  bool grounded = false;
  {
    StageRecord& record = stage(result.stages, "ground");
    StageTimer t(record);
    if (!job.groundShadow) {
      record.runs = false;
      record.reason = "--no-shadow";
    } else {
      const ShadowLighting& sl = needShadowLighting();
      ground = computeGroundShadow(mesh, objectScene, worldFromObject, camera, sl, envFromWorld,
                                   envFromObject, shadowPlan, progress);
      record.reason = ground.reason;
      grounded = !ground.grid.empty();
    }
  }

  // render
  render::RenderOutput rendered;
  {
    StageTimer t(stage(result.stages, "render"));
    render::RenderSettings settings;
    settings.samplesPerAxis = job.samplesPerAxis;
    settings.albedo = job.albedo.value_or(glm::vec3(render::kDefaultAlbedo));
    settings.overrideMaterials = job.albedo.has_value();
    settings.envFromWorld = envFromWorld;
    if (shadowed) {
      settings.points = &shadows.points;
      settings.shadows = &shadows.irradiance;
      settings.occlusion = &shadows.occlusion;
    }
    if (job.exposureStops) {
      settings.exposure = float(std::exp2(*job.exposureStops));
    } else {
      const glm::dvec3 objectBase(worldFromObject[3]);
      const ExposureMatch match = autoExposure(
          plateLinear, *lighting, camera.position() - objectBase, settings.envFromWorld);
      settings.exposure = float(match.scale);
      char line[300];
      std::snprintf(line, sizeof line,
                    "auto exposure: %+.2f stops: a mid-grey ball at the object (%.4g in the "
                    "environment's units) matched to the plate's log-average (%.4g); override with "
                    "--exposure",
                    std::log2(match.scale), match.ballRadiance, match.plateKey);
      result.notes.push_back(line);
    }
    result.exposure = settings.exposure;
    rendered = render::renderDiffuse(mesh, objectScene, worldFromObject, camera, *lighting,
                                     settings, progress);
    rendered.beauty.colorSpace = working;
    if (!(rendered.coverage > 0.0)) {
      throw Error("render",
                  "the object covers no pixel of the plate (--scale " +
                      std::to_string(job.placement.heightFraction) +
                      " of the plate height at --place " +
                      std::to_string(job.placement.imagePoint.x) + "," +
                      std::to_string(job.placement.imagePoint.y) +
                      "): make it larger or place it inside the frame",
                  job.object);
    }
    result.objectPixels = rendered.coverage;
  }

  // composite: the plate darkened by the ground shadow (in linear light), the object over it,
  // and the holdout's pixels of the plate back in front.
  Image composite;
  {
    StageTimer t(stage(result.stages, "composite"));
    Image shadowedPlate = plateLinear;
    if (grounded) composite::multiply(shadowedPlate, ground.ratio, ground.grid.x0, ground.grid.y0);
    composite = composite::over(rendered.beauty, rendered.x0, rendered.y0, shadowedPlate);
    if (!job.holdout.empty()) {
      const Image mask = loadHoldout(job.holdout, composite.width, composite.height);
      composite = composite::holdout(composite, plateLinear, mask);
    }
  }

  // output: the composite (one part, the full frame) and the object with its AOVs (a second part
  // whose data window is the traced rectangle), and the display image.
  {
    StageTimer t(stage(result.stages, "output"));
    Image compositeRgba(composite.width, composite.height, 4, {"R", "G", "B", "A"});
    compositeRgba.colorSpace = working;
    for (size_t i = 0; i < composite.pixelCount(); ++i) {
      std::copy_n(composite.pixels.data() + 3 * i, 3, compositeRgba.pixels.data() + 4 * i);
      compositeRgba.pixels[4 * i + 3] = 1.0f;
    }
    const std::vector<std::string>& aovNames = render::aovChannelNames();
    const int objectChannels = 4 + int(aovNames.size());
    std::vector<std::string> objectNames = {"object.R", "object.G", "object.B", "object.A"};
    objectNames.insert(objectNames.end(), aovNames.begin(), aovNames.end());
    Image object(rendered.beauty.width, rendered.beauty.height, objectChannels, objectNames);
    object.colorSpace = working;
    for (size_t i = 0; i < object.pixelCount(); ++i) {
      float* d = object.pixels.data() + i * size_t(objectChannels);
      std::copy_n(rendered.beauty.pixels.data() + 4 * i, 4, d);
      std::copy_n(rendered.aovs.pixels.data() + i * aovNames.size(), aovNames.size(), d + 4);
    }
    ingest::ExrPart compositePart{"composite",     &compositeRgba,   0, 0,
                                  composite.width, composite.height, {}};
    compositePart.options.depth = ingest::WriteOptions::Depth::Half;
    compositePart.options.alphaChannel = 3;
    compositePart.options.chromaticities = colors.chromaticities(working);
    ingest::ExrPart objectPart{"object",        &object,          rendered.x0,          rendered.y0,
                               composite.width, composite.height, compositePart.options};
    if (!compositePart.options.chromaticities) {
      result.notes.push_back("the config (" + colors.source() +
                             ") does not say what the primaries of the working space '" + working +
                             "' are: the EXR carries its name but no chromaticities");
    }
    // The camera and the placement, so that another tool can rebuild the scene.
    ingest::ExrHeader header;
    auto asImath = [](const glm::dmat4& m) {
      // glm stores columns of a column-vector matrix: the same numbers, in the same order, as
      // Imath's rows of the row-vector matrix (translation in the last row).
      std::array<float, 16> out;
      for (int c = 0; c < 4; ++c)
        for (int r = 0; r < 4; ++r) out[size_t(4 * c + r)] = float(m[c][r]);
      return out;
    };
    // OpenEXR's camera space looks along +Z (left-handed): flip our -Z.
    const glm::dmat4 flipZ = glm::scale(glm::dmat4(1.0), glm::dvec3(1.0, 1.0, -1.0));
    const glm::dmat4 cameraFromWorld = camera.cameraFromWorld();
    glm::dmat4 ndcFromCamera(0.0);  // pinhole part of the lens (distortion is not a matrix)
    const calib::Lens& lens = camera.lens;
    ndcFromCamera[0][0] = lens.fx / camera.width;
    ndcFromCamera[2][0] = -lens.cx / camera.width;
    ndcFromCamera[1][1] = -lens.fy / camera.height;
    ndcFromCamera[2][1] = -lens.cy / camera.height;
    ndcFromCamera[2][2] = -1.0;
    ndcFromCamera[2][3] = -1.0;
    header.matrices.emplace_back("worldtocamera", asImath(flipZ * cameraFromWorld));
    header.matrices.emplace_back("worldToNDC", asImath(ndcFromCamera * cameraFromWorld));
    header.matrices.emplace_back("compose:worldFromObject", asImath(worldFromObject));
    header.strings.emplace_back("compose:object", fs::absolute(job.object).string());
    if (lens.hasDistortion()) {
      header.strings.emplace_back("compose:lens",
                                  "distorted lens: worldToNDC holds its pinhole part only");
    }

    const std::string display = job.display.empty() ? colors.defaultDisplay() : job.display;
    const std::string view = job.view.empty() ? colors.defaultView(display) : job.view;
    Image shown = colors.toDisplay(composite, display, view);
    {
      // Object pixels that the display image shows as clipped white: their shading is lost.
      int64_t covered = 0, clipped = 0;
      for (int y = 0; y < rendered.beauty.height; ++y) {
        for (int x = 0; x < rendered.beauty.width; ++x) {
          if (rendered.beauty.at(x, y)[3] < 0.5f) continue;
          ++covered;
          const float* d = shown.at(x + rendered.x0, y + rendered.y0);
          if (std::max({d[0], d[1], d[2]}) >= 0.999f) ++clipped;
        }
      }
      constexpr double kClippedShare = 0.02;
      if (covered > 0 && double(clipped) > kClippedShare * double(covered)) {
        char line[240];
        std::snprintf(line, sizeof line,
                      "warning: %.1f%% of the object's pixels are clipped to white in %s "
                      "(view %s): lower --exposure to keep their shading",
                      100.0 * double(clipped) / double(covered),
                      result.displayPath.filename().string().c_str(), view.c_str());
        result.notes.push_back(line);
      }
    }
    // Both files appear together or not at all: a failure keeps every previous output.
    OutputFiles outputs("output");
    std::vector<ingest::ExrPart> parts = {compositePart, objectPart};
    if (grounded) {
      // The ground shadow's ratio, in its own data window: 1 where the plate is unchanged.
      ingest::ExrPart shadowPart{
          "shadow",        &ground.ratio,    ground.grid.x0,       ground.grid.y0,
          composite.width, composite.height, compositePart.options};
      shadowPart.options.alphaChannel = -1;
      parts.push_back(shadowPart);
    }
    const std::vector<ingest::WriteReport> written =
        ingest::writeExrParts(outputs, result.exrPath, parts, header);
    ingest::writeImage(outputs, result.displayPath, shown, {});
    outputs.commit();
    for (const ingest::WriteReport& w : written) {
      if (!w.promotedToFloat) continue;
      char line[200];
      std::snprintf(line, sizeof line,
                    "values up to %g exceed half float's range (65504): that part of the EXR is "
                    "written as 32-bit float",
                    double(w.largestMagnitude));
      result.notes.push_back(line);
    }
    report(progress, "output", 1.0);
  }
  return result;
}

}  // namespace compose::pipeline
