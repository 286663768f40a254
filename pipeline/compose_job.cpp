#include "pipeline/compose_job.h"

#include <charconv>
#include <cmath>
#include <cstdlib>
#include <string>

#include "calib/plate_camera.h"
#include "core/error.h"
#include "core/numbers.h"
#include "core/params.h"
#include "ingest/exr_io.h"
#include "ingest/image_io.h"
#include "lighting/capture_volume.h"
#include "lighting/lighting.h"
#include "pipeline/shadows.h"

namespace compose::pipeline {

namespace fs = std::filesystem;

const char* stateName(StageState state) {
  switch (state) {
    case StageState::Run:
      return "run";
    case StageState::Reused:
      return "reused";
    case StageState::Skipped:
      return "skipped";
  }
  return "?";
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
  const std::string ext = ingest::lowerExtension(base);
  if (ext == ".exr" || ext == ".jpg" || ext == ".jpeg" || ext == ".png") base.replace_extension();
  return base;
}

}  // namespace

fs::path environmentPathFor(const ComposeJob& job) {
  return job.environment.empty() ? defaultEnvironment() : job.environment;
}

fs::path exrPathFor(const ComposeJob& job) {
  fs::path p = outputBase(job);
  p += ".exr";
  return p;
}

fs::path displayPathFor(const ComposeJob& job) {
  const std::string ext = ingest::lowerExtension(job.output);
  fs::path p = outputBase(job);
  p += (ext == ".png") ? ".png" : ".jpg";
  return p;
}

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

void validate(const ComposeJob& job) {
  if (job.output.empty()) throw UsageError("--out must not be empty");
  {
    // The name of an image format compose does not write here would end up inside the names
    // (shot.tif.exr, shot.tif.jpg).
    const std::string ext = ingest::lowerExtension(job.output);
    for (const char* other :
         {".tif", ".tiff", ".hdr", ".pfm", ".ppm", ".pgm", ".bmp",  ".webp", ".gif",
          ".tga", ".dpx",  ".cin", ".jp2", ".jxl", ".psd", ".heic", ".heif", ".avif",
          ".sxr", ".rgbe", ".gz",  ".bz2", ".xz",  ".zst", ".zip"}) {
      if (ext != other) continue;
      throw UsageError("--out " + job.output.string() +
                       ": compose writes BASE.exr and BASE.jpg (or BASE.png); give a base name, or "
                       "one ending in .exr, .jpg or .png");
    }
  }
  if (job.samplesPerAxis < 1 || job.samplesPerAxis > 64) {
    throw UsageError("--samples must be in 1..64, got " + std::to_string(job.samplesPerAxis));
  }
  if (!std::isfinite(job.environmentYawDegrees))
    throw UsageError("--env-yaw must be a finite number of degrees");
  for (int c = 0; job.albedo && c < 3; ++c) {
    if (!((*job.albedo)[c] >= 0.0f && (*job.albedo)[c] <= 1.0f)) {
      // The float as typed (the shortest text that reads back as it): widened to double, 1.01
      // was said as 1.0099999904632568.
      char text[32];
      const auto end = std::to_chars(text, text + sizeof text, (*job.albedo)[c]).ptr;
      throw UsageError("--albedo must be within [0, 1], got " + std::string(text, end));
    }
  }
  if (!(job.creaseDegrees >= 0.0 && job.creaseDegrees <= 180.0))
    throw UsageError("--crease must be an angle within [0, 180] degrees, got " +
                     givenText(job.creaseDegrees));
  if (job.exposureStops && !(std::abs(*job.exposureStops) <= 64.0)) {
    throw UsageError("--exposure must be a number of stops within ±64");
  }
  std::string why;
  if (!ingest::parseExrCompression(job.exrCompression, &why))
    throw UsageError("--compression: " + why);
  if (job.exrDepth != "auto" && job.exrDepth != "half" && job.exrDepth != "float")
    throw UsageError("--depth must be auto, half or float; got '" + job.exrDepth + "'");
  if (job.jpegQuality < 1 || job.jpegQuality > 100)
    throw UsageError("--jpeg-quality must be in 1..100, got " + std::to_string(job.jpegQuality));
  if (job.threads < 0 || job.threads > 4096)
    throw UsageError("--threads must be 0 (every core) or a number of threads up to 4096");
  job.camera.validate();
  job.placement.validate();
  ShadowPlan::parse(job.shadowParams);
  // Values that would change nothing, refused as the one-shot command refuses them, so that a
  // scene (whose values are all present) and a --set say so too.
  if (!job.poseFile.empty() && (job.camera.height != calib::CameraOptions{}.height ||
                                job.camera.pitchDegrees != calib::CameraOptions{}.pitchDegrees))
    throw UsageError(
        "--pose sets the camera's height and tilt: leave out --camera-height and --pitch (in a "
        "scene, render.camera-height and render.pitch at their defaults, 1.6 and 0)");
  if (job.jpegQuality != ComposeJob{}.jpegQuality && displayPathFor(job).extension() == ".png")
    throw UsageError("--jpeg-quality applies to a JPEG display image; --out " +
                     job.output.string() + " writes a PNG (lossless)");
  if (!job.shadowParams.empty()) {
    if (!job.shadows && !job.groundShadow)
      throw UsageError(
          "--shadow-params: no shadow is drawn (--shadows off and --no-shadow); leave it out");
    if (!job.shadows) {
      // The ground shadow takes the method, its order, grid and sources; the rest is the
      // object's shadows on itself.
      ParamSet p = ParamSet::parse(job.shadowParams, "shadows");
      for (const char* key : {"refine", "refine-budget", "ground"})
        if (p.has(key))
          throw UsageError(std::string(key) +
                               " is for the object's shadows on itself, which --shadows off "
                               "leaves out (the ground shadow takes method, order, grid, "
                               "boundary and sources); leave it out",
                           "shadows");
    }
  }
  if (job.room && job.environmentRadius) throw UsageError("give either --room or --env-radius");
  if (job.camera.focal35mm && (!job.lensFile.empty() || !job.poseFile.empty())) {
    throw UsageError(std::string(job.lensFile.empty() ? "--pose" : "--calib") +
                     " gives the plate's lens: leave out --focal35");
  }
  if (!job.poseFile.empty() && (job.room || job.environmentRadius) && !job.captureAt)
    throw UsageError(
        "with --pose, parallax needs --capture-at (in the board's frame and units): where the "
        "environment was captured");
  if (job.captureAt && !job.room && !job.environmentRadius)
    throw UsageError(
        "--capture-at needs --room or --env-radius (a distant environment has no "
        "position)");
  try {
    lighting::CaptureProxy proxy = captureProxy(job);
    // The pose file is not read here: its unit is named as such.
    if (!job.poseFile.empty()) proxy.unit = "the pose's units";
    proxy.validate();
  } catch (const UsageError&) {
    throw;
  } catch (const Error& e) {
    throw UsageError(e.what(), e.stage());
  }
  // The lighting basis and its parameters: a misspelt name fails before any pixel is read.
  try {
    ParamSet params = ParamSet::parse(job.lightingParams, "lighting");
    if (params.is("order", "auto")) {
      // As lighting/order_selector.cpp selects: for sh and cheb-*, Lambertian only.
      if (job.lighting != "sh" && job.lighting.rfind("cheb-", 0) != 0)
        throw Error("lighting",
                    "no order selection for basis '" + job.lighting + "' (sh and cheb-* have one)");
      if (ParamSet probe = params;  // read without marking it used for createLighting
          probe.has("brdf") && probe.getString("brdf", "lambert") != "lambert")
        throw Error("lighting", "order=auto estimates Lambertian truncation only; give brdf=" +
                                    probe.getString("brdf", "") + " an explicit order");
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

}  // namespace compose::pipeline
