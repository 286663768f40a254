// The one-shot command: compose --plate PHOTO --object MESH [--env ENV] [--out BASE].
#include <algorithm>
#include <cstdio>

#include "app/cli.h"
#include "color/color.h"
#include "core/error.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"

namespace compose::app {

namespace {

struct ComposeOptions {
  pipeline::ComposeJob job;
  std::string place, albedo, lightingParams, exposure = "auto", shadows = "self", room, captureAt;
  double focal35 = 0.0, envRadius = 0.0;
  bool explain = false, noCache = false, noShadow = false, timings = false;
};

// The stages of a run on stderr: what each did (unless quiet) and, with --timings, its time and
// the peak memory during it.
void printStages(const pipeline::ComposeResult& result, bool quiet, bool timings) {
  if (!quiet) {
    for (const auto& note : result.notes) std::fprintf(stderr, "compose: note: %s\n", note.c_str());
  }
  double total = 0.0;
  int64_t peak = 0;
  for (const auto& s : result.stages) {
    total += s.seconds;
    peak = std::max(peak, s.peakBytes);
    const char* state = pipeline::stateName(s.state);
    if (timings) {
      char memory[32] = "";
      if (s.peakBytes > 0)
        std::snprintf(memory, sizeof memory, "%7.0f MB", double(s.peakBytes) / 1e6);
      std::fprintf(stderr, "compose: %-10s %-7s %8.3f s %10s  %s\n", s.name.c_str(), state,
                   s.seconds, memory, quiet ? "" : s.reason.c_str());
    } else if (s.state == pipeline::StageState::Skipped) {
      std::fprintf(stderr, "compose: %-10s skipped  %s\n", s.name.c_str(), s.reason.c_str());
    } else {
      std::fprintf(stderr, "compose: %-10s %7.3f s  %s\n", s.name.c_str(), s.seconds,
                   s.reason.c_str());
    }
  }
  if (timings)
    std::fprintf(stderr, "compose: %-10s %-7s %8.3f s %7.0f MB  peak resident memory\n", "total",
                 "", total, double(peak) / 1e6);
}

}  // namespace

Runner setupCompose(CLI::App& app, const Globals& globals) {
  auto o = std::make_shared<ComposeOptions>();
  pipeline::ComposeJob& job = o->job;
  app.add_option("--plate", job.plate, "Background photograph (JPEG, PNG, TIFF, EXR, ...)");
  app.add_option("--object", job.object,
                 "Mesh to insert: glTF 2.0 (.gltf, .glb), Wavefront OBJ (with its .mtl "
                 "materials) or Geomview bicubic patches (.bez)");
  app.add_option("--crease", job.creaseDegrees,
                 "Crease angle in degrees for normals computed where the mesh has none: edges "
                 "sharper than this stay sharp (0 flat, 180 fully smooth)")
      ->capture_default_str();
  app.add_option(
      "--env", job.environment,
      "HDR environment: a lat-long map, an OpenEXR cube map, a cross, or six face files (a folder, "
      "a name with % for the face, or one face file) [default: the forest sample HDRI]");
  app.add_option("--out", job.output, "Output base path; writes BASE.exr and BASE.jpg (or .png)")
      ->capture_default_str();
  app.add_option("--lighting", job.lighting, "Lighting basis: " + join(lighting::lightingNames()))
      ->capture_default_str();
  app.add_option("--lighting-params", o->lightingParams,
                 "Basis parameters as key=value,... (cheb-*: order, samples, rows, cols, "
                 "subsamples; sh: order=0..8; mc: samples, seed)");
  app.add_option("--place", o->place,
                 "Image point X,Y in [0,1] where the object stands [default: 0.5,0.72]");
  app.add_option("--scale", job.placement.heightFraction,
                 "Object height as a fraction of the plate height")
      ->capture_default_str();
  app.add_option("--yaw", job.placement.yawDegrees,
                 "Turn the object about the vertical axis, degrees")
      ->capture_default_str();
  app.add_option("--env-yaw", job.environmentYawDegrees,
                 "Turn the environment about the vertical axis, degrees")
      ->capture_default_str();
  app.add_option(
      "--room", o->room,
      "Parallax: the environment is a room of W,H,D metres (floor on the ground, centred "
      "below the plate camera) instead of infinitely distant");
  app.add_option("--env-radius", o->envRadius,
                 "Parallax: the environment is a sphere of this radius (metres) around the capture "
                 "point");
  app.add_option("--capture-at", o->captureAt,
                 "Where the environment was captured, X,Y,Z metres [default: the plate camera]");
  app.add_option("--focal35", o->focal35,
                 "35 mm equivalent focal length of the plate [default: EXIF, else 50]");
  app.add_option("--camera-height", job.camera.height, "Camera height above the ground, metres")
      ->capture_default_str();
  app.add_option("--pitch", job.camera.pitchDegrees, "Camera tilt down, degrees")
      ->capture_default_str();
  app.add_option("--albedo", o->albedo,
                 "Object albedo, one value or R,G,B in the working space, instead of the "
                 "mesh's materials [default: the materials, else 0.5]");
  app.add_option("--exposure", o->exposure,
                 "Exposure of the object in stops, or 'auto': match the environment to the plate")
      ->capture_default_str();
  app.add_option("--samples", job.samplesPerAxis, "Anti-aliasing: N x N samples per pixel")
      ->capture_default_str();
  app.add_option("--plate-space", job.plateSpace,
                 "Colour space of the plate [default: from the file]");
  app.add_option("--env-space", job.environmentSpace,
                 "Colour space of the environment [default: from the file]");
  app.add_option("--display", job.display,
                 "OpenColorIO display for the JPEG/PNG [default: the config's]");
  app.add_option("--view", job.view, "OpenColorIO view for the JPEG/PNG [default: the config's]");
  app.add_option("--cache", job.cache,
                 "Folder of the caches (projected lighting, visibility passes)")
      ->capture_default_str();
  app.add_flag("--no-cache", o->noCache, "Neither read nor write the caches");
  app.add_option("--shadows", o->shadows,
                 "Self-shadowing of the object: self (by precomputed transfer; skipped for a "
                 "convex object) or off")
      ->capture_default_str();
  app.add_option("--shadow-params", job.shadowParams,
                 "Self-shadowing parameters as key=value,...: method=cheb|sh|ao, order, grid, "
                 "boundary, sources");
  app.add_flag("--no-shadow", o->noShadow,
               "No shadow on the plate's ground (the object's own shadowing stays)");
  app.add_option("--holdout", job.holdout,
                 "Holdout mask, the plate's size: white where the plate is in front of the object");
  app.add_option("--calib", job.lensFile,
                 "Lens calibration of the plate's camera (JSON from compose calib lens)");
  app.add_option("--threads", job.threads, "Worker threads [default: every core]");
  app.add_flag("--timings", o->timings,
               "Print each stage's time and the process's peak memory during it");
  app.add_flag("--explain", o->explain,
               "Say which stages would run, be reused from the cache or be skipped, and why, then "
               "exit (reads the mesh and hashes the inputs; decodes no image)");

  return [o, &app, &globals]() -> int {
    pipeline::ComposeJob& j = o->job;
    if (j.plate.empty() || j.object.empty()) {
      throw UsageError(
          "the one-shot command needs --plate and --object (or a command; see "
          "compose --help)");
    }
    if (!o->place.empty()) j.placement.imagePoint = parsePair(o->place, "--place");
    if (!o->albedo.empty()) j.albedo = parseColour(o->albedo, "--albedo");
    if (app.count("--focal35")) j.camera.focal35mm = o->focal35;
    if (!o->room.empty()) j.room = parseTriple(o->room, "--room");
    if (app.count("--env-radius")) j.environmentRadius = o->envRadius;
    if (!o->captureAt.empty()) j.captureAt = parseTriple(o->captureAt, "--capture-at");
    j.lightingParams = o->lightingParams;
    if (o->noCache) j.cache.clear();
    if (o->noShadow) j.groundShadow = false;
    if (o->shadows == "off") {
      j.shadows = false;
    } else if (o->shadows != "self") {
      throw UsageError("--shadows must be self or off, got '" + o->shadows + "'");
    }
    if (o->exposure != "auto") j.exposureStops = parseNumber(o->exposure, "--exposure");
    // Names the colour config must know are command-line values like any other: a misspelt one
    // is a usage error, reported before any file is read.
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    asUsage([&] {
      if (!j.plateSpace.empty()) colors.resolve(j.plateSpace, "--plate-space");
      if (!j.environmentSpace.empty()) colors.resolve(j.environmentSpace, "--env-space");
      const std::string display = j.display.empty() ? colors.defaultDisplay() : j.display;
      colors.checkDisplayView(display, j.view.empty() ? colors.defaultView(display) : j.view);
    });

    if (o->explain) {
      for (const auto& s : pipeline::plan(j, colors)) {
        std::printf("%-10s %-7s %s\n", s.name.c_str(), pipeline::stateName(s.state),
                    s.reason.c_str());
      }
      return 0;
    }

    ProgressPrinter printer(globals);
    const auto result = pipeline::runCompose(j, colors, printer.callback());
    if (!globals.quiet || o->timings) printStages(result, globals.quiet, o->timings);
    std::printf("%s\n%s\n", result.exrPath.string().c_str(), result.displayPath.string().c_str());
    return 0;
  };
}

}  // namespace compose::app
