// The one-shot command, compose --plate PHOTO --object MESH [--env ENV] [--out BASE], and the
// option groups it shares with the stage commands (compose_options.h).
#include <algorithm>
#include <cstdio>
#include <filesystem>

#include "app/cli.h"
#include "app/compose_options.h"
#include "color/color.h"
#include "core/error.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "ingest/image_io.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"
#include "pipeline/scene.h"
#include "pipeline/stage_util.h"

namespace compose::app {

namespace {

// The stages of a run on stderr: what each did (unless quiet) and, with --timings, its time and
// the peak memory during it.
void printStages(const pipeline::ComposeResult& result, bool quiet, bool timings) {
  // A warning (a note that starts so) is printed even when quiet: what it says may be wrong.
  for (const auto& note : result.notes) {
    if (note.rfind("warning: ", 0) == 0)
      std::fprintf(stderr, "compose: %s\n", printable(note).c_str());
    else if (!quiet)
      std::fprintf(stderr, "compose: note: %s\n", printable(note).c_str());
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
                   s.seconds, memory, quiet ? "" : printable(s.reason).c_str());
    } else if (s.state == pipeline::StageState::Skipped) {
      std::fprintf(stderr, "compose: %-10s skipped  %s\n", s.name.c_str(),
                   printable(s.reason).c_str());
    } else {
      std::fprintf(stderr, "compose: %-10s %7.3f s  %s\n", s.name.c_str(), s.seconds,
                   printable(s.reason).c_str());
    }
  }
  if (timings)
    std::fprintf(stderr, "compose: %-10s %-7s %8.3f s %7.0f MB  peak resident memory\n", "total",
                 "", total, double(peak) / 1e6);
}

}  // namespace

void ComposeOptions::addPlate(CLI::App& app) {
  app.add_option("--plate", job.plate, "Background photograph (JPEG, PNG, TIFF, EXR, ...)");
  app.add_option("--plate-space", job.plateSpace,
                 "Colour space of the plate [default: from the file]");
}

void ComposeOptions::addEnvironment(CLI::App& app, bool parallax) {
  app.add_option(
      "--env", job.environment,
      "HDR environment: a lat-long map, an OpenEXR cube map, a cross, six face files (a folder, a "
      "name with % for the face, or one face file), or a capture description (JSON) of photos to "
      "merge and stitch [default: the forest sample HDRI]");
  app.add_option("--env-space", job.environmentSpace,
                 "Colour space of the environment [default: from the file]");
  app.add_option("--env-yaw", job.environmentYawDegrees,
                 "Turn the environment about the vertical axis, degrees")
      ->capture_default_str();
  if (!parallax) return;
  app.add_option(
      "--room", room,
      "Parallax: the environment is a room of W,H,D metres (floor on the ground, centred "
      "below the plate camera; with --pose, the pose's units and its board's centre) instead "
      "of infinitely distant");
  app.add_option("--env-radius", envRadius,
                 "Parallax: the environment is a sphere of this radius (metres; with --pose, the "
                 "pose's units) around the capture point");
  app.add_option("--capture-at", captureAt,
                 "Where the environment was captured, X,Y,Z metres (with --pose, the pose's units "
                 "and frame) [default: the plate camera]");
}

void ComposeOptions::addLighting(CLI::App& app) {
  app.add_option("--lighting", job.lighting, "Lighting basis: " + join(lighting::lightingNames()))
      ->capture_default_str();
  app.add_option(
      "--lighting-params", lightingParams,
      "Basis parameters as key=value,... (cheb-*: order (or auto, with target=dB), "
      "samples, rows, cols; cheb-latlong and cheb-face: subsamples; cheb-local: "
      "brdf=lambert|oren-nayar, sigma with oren-nayar; sh: order=0..8 (or auto), window; "
      "mc: samples, seed)");
}

void ComposeOptions::addShadows(CLI::App& app, bool parameters) {
  app.add_option("--shadows", shadows,
                 "Self-shadowing of the object: self (by precomputed transfer, with the ground "
                 "beneath darkening it; a convex object only by the ground) or off")
      ->capture_default_str();
  if (parameters) {
    app.add_option(
        "--shadow-params", job.shadowParams,
        "Self-shadowing parameters as key=value,...: method=cheb|sh|ao, order, grid, "
        "boundary, sources, refine, refine-budget, ground=on|off (the ground beneath the "
        "object darkens its underside)");
  }
  app.add_flag("--no-shadow", noShadow,
               "No shadow on the plate's ground (the object's own shadowing stays)");
}

void ComposeOptions::addObject(CLI::App& app, bool shading) {
  app.add_option("--object", job.object,
                 "Mesh to insert: glTF 2.0 (.gltf, .glb), Wavefront OBJ (with its .mtl "
                 "materials) or Geomview bicubic patches (.bez)");
  app.add_option("--crease", job.creaseDegrees,
                 "Crease angle in degrees for normals computed where the mesh has none: edges "
                 "sharper than this stay sharp, but for lines less than 25 degrees sharper that "
                 "end inside a smooth surface (ridges of a scan) (0 flat, 180 fully smooth)")
      ->capture_default_str();
  app.add_option("--place", place,
                 "Image point X,Y in [0,1] where the object stands [default: 0.5,0.72]");
  app.add_option("--scale", job.placement.heightFraction,
                 "Object height as a fraction of the plate height (a flat object's largest extent: "
                 "one whose height is under 1 % of it)")
      ->capture_default_str();
  app.add_option("--yaw", job.placement.yawDegrees,
                 "Turn the object about the vertical axis, degrees")
      ->capture_default_str();
  app.add_option("--focal35", focal35,
                 "35 mm equivalent focal length of the plate [default: EXIF, else 50]");
  app.add_option("--camera-height", job.camera.height, "Camera height above the ground, metres")
      ->capture_default_str();
  app.add_option("--pitch", job.camera.pitchDegrees, "Camera tilt down, degrees")
      ->capture_default_str();
  app.add_option("--calib", job.lensFile,
                 "Lens calibration of the plate's camera (JSON from compose calib lens)");
  app.add_option("--pose", job.poseFile,
                 "Plate pose over a chessboard (JSON from compose calib pose): the object stands "
                 "on the board's plane, the camera where the pose puts it (replaces "
                 "--camera-height and --pitch; lengths in the board's square units)");
  if (!shading) return;
  app.add_option("--albedo", albedo,
                 "Object albedo, one value or R,G,B in the working space, instead of the "
                 "mesh's materials and vertex colours [default: the materials, else 0.5]");
  app.add_option("--exposure", exposure,
                 "Exposure of the object in stops, or 'auto': match the environment to the plate")
      ->capture_default_str();
  app.add_option("--samples", job.samplesPerAxis,
                 "Anti-aliasing: N x N samples per pixel (see --sampling)")
      ->capture_default_str();
  app.add_option_function<std::string>(
         "--sampling", [this](const std::string& v) { job.adaptiveSampling = v == "adaptive"; },
         "adaptive: a pixel whose four corner samples find one smooth surface (no edge, crease, "
         "texture or shadow edge in it) is shaded from them, every other pixel from all N x N; "
         "full: every pixel from all N x N [default: adaptive]")
      ->check(CLI::IsMember({"adaptive", "full"}));
}

void ComposeOptions::addOutput(CLI::App& app) {
  app.add_option("--out", job.output, "Output base path; writes BASE.exr and BASE.jpg (or .png)")
      ->capture_default_str();
  app.add_option("--display", job.display,
                 "OpenColorIO display for the JPEG/PNG [default: the config's]");
  app.add_option("--view", job.view, "OpenColorIO view for the JPEG/PNG [default: the config's]");
  addCompressionOption(app, job.exrCompression);
  app.add_option("--depth", job.exrDepth,
                 "The EXR's samples: half, float, or auto (float for a 32-bit float plate, "
                 "else half; float where a value exceeds half's range)")
      ->check(CLI::IsMember({"auto", "half", "float"}))
      ->capture_default_str();
  app.add_option("--exr-space", job.exrSpace,
                 "Colour space of the EXR's colour channels (composite, object, albedo, "
                 "irradiance), a linear one of the config [default: the working space]");
  app.add_option("--jpeg-quality", job.jpegQuality, "Quality of the JPEG display image, 1-100")
      ->check(CLI::Range(1, 100))
      ->capture_default_str();
  app.add_option("--holdout", job.holdout,
                 "Holdout mask, the plate's size: white where the plate is in front of the object");
}

void ComposeOptions::addRun(CLI::App& app) {
  app.add_option("--cache", job.cache, "Folder of the caches (stage outputs, visibility passes)")
      ->capture_default_str();
  app.add_flag("--no-cache", noCache, "Neither read nor write the caches");
  app.add_option("--threads", job.threads, "Worker threads [default: every core]");
  app.add_flag("--timings", timings,
               "Print each stage's time and the process's peak memory during it");
  app.add_flag("--explain", explain,
               "Say which stages would run, be reused from the cache or be skipped, and why, then "
               "exit (hashes the inputs and reads the mesh, if there is one; decodes no image)");
}

void ComposeOptions::apply(const CLI::App& app) {
  pipeline::ComposeJob& j = job;
  // Whether an option of one of the groups this command took was given.
  auto given = [&app](const char* name) {
    const CLI::Option* option = app.get_option_no_throw(name);
    return option != nullptr && option->count() > 0;
  };
  if (!place.empty()) j.placement.imagePoint = parsePair(place, "--place");
  if (!albedo.empty()) j.albedo = parseColour(albedo, "--albedo");
  if (given("--focal35")) j.camera.focal35mm = focal35;
  if (!room.empty()) j.room = parseTriple(room, "--room", "W,H,D");
  if (given("--env-radius")) j.environmentRadius = envRadius;
  if (!captureAt.empty()) j.captureAt = parseTriple(captureAt, "--capture-at");
  if (!lightingParams.empty()) j.lightingParams = lightingParams;
  if (noCache) j.cache.clear();
  if (noShadow) j.groundShadow = false;
  if (shadows == "off") {
    j.shadows = false;
  } else if (shadows != "self") {
    throw UsageError("--shadows must be self or off, got '" + shadows + "'");
  }
  if (!j.poseFile.empty() && (given("--camera-height") || given("--pitch")))
    throw UsageError(
        "--pose sets the camera's height and tilt: leave out --camera-height and --pitch");
  if (given("--jpeg-quality") && pipeline::displayPathFor(j).extension() == ".png")
    throw UsageError("--jpeg-quality applies to a JPEG display image; --out " + j.output.string() +
                     " writes a PNG (lossless)");
  if (given("--shadow-params") && !j.shadows && !j.groundShadow)
    throw UsageError(
        "--shadow-params: no shadow is drawn (--shadows off and --no-shadow); leave it out");
  if (exposure != "auto") {
    try {
      j.exposureStops = parseNumber(exposure, "--exposure");
    } catch (const UsageError&) {
      throw UsageError("--exposure expects a number of stops or auto, got '" + exposure + "'");
    }
  }
}

void validateJob(const pipeline::ComposeJob& j, const color::ColorConfig& colors) {
  pipeline::validate(j);
  // Names the colour config must know are command-line values like any other: a misspelt one is
  // a usage error, reported before any file is read.
  asUsage([&] {
    if (!j.plateSpace.empty()) colors.resolve(j.plateSpace, "--plate-space");
    if (!j.environmentSpace.empty()) colors.resolve(j.environmentSpace, "--env-space");
    if (!j.exrSpace.empty()) {
      const std::string s = colors.resolve(j.exrSpace, "--exr-space");
      if (colors.isData(s) || !colors.isLinearOrData(s))
        throw UsageError("--exr-space '" + s + "' is not a linear colour space: the EXR holds " +
                         "scene-linear light (premultiplied); name a linear one (the display " +
                         "image takes --view)");
    }
    const std::string display = j.display.empty() ? colors.defaultDisplay() : j.display;
    colors.checkDisplayView(display, j.view.empty() ? colors.defaultView(display) : j.view);
  });
}

color::ColorConfig jobConfig(const pipeline::ComposeJob& job, const Globals& globals,
                             const std::string& namedBy) {
  // A scene's config, unless the command line names one.
  if (!job.ocio.empty() && globals.ocio.empty())
    color::ColorConfig::useConfig(job.ocio.string(), namedBy);
  return color::ColorConfig::fromEnvironment();
}

int runJob(const ComposeOptions& o, const Globals& globals, const pipeline::RunRequest& request,
           bool printOutputs) {
  const color::ColorConfig colors = jobConfig(o.job, globals);
  validateJob(o.job, colors);
  {
    // The command's outputs, checked before any stage runs (and by --explain, so that its plan is
    // not one that fails at once): each one writable, none an input.
    const pipeline::ComposeJob& j = o.job;
    std::vector<std::filesystem::path> outputs = request.outputFiles;
    if (outputs.empty()) outputs = {pipeline::exrPathFor(j), pipeline::displayPathFor(j)};
    std::vector<std::filesystem::path> inputs = {j.plate,   j.object,   j.environment,
                                                 j.holdout, j.lensFile, j.poseFile};
    inputs.insert(inputs.end(), request.inputFiles.begin(), request.inputFiles.end());
    for (const std::filesystem::path& out : outputs) {
      OutputFiles::check(out, "output");
      for (const std::filesystem::path& in : inputs) {
        std::error_code ec;
        if (!in.empty() && std::filesystem::exists(out, ec) &&
            std::filesystem::equivalent(out, in, ec))
          throw Error(
              "output",
              "the output would replace an input (" + in.string() + "): choose another output path",
              out);
      }
    }
  }
  if (o.explain) {
    // Images beyond --max-pixels fail the run when they are read: said now, from their headers.
    for (const auto& [file, stage] :
         {std::pair{o.job.plate, "ingest"}, std::pair{o.job.environment, "ingest"},
          std::pair{o.job.holdout, "composite"}}) {
      std::error_code ec;
      if (file.empty() || !std::filesystem::is_regular_file(file, ec) ||
          !ingest::looksLikeImageFile(file))
        continue;
      // Of a multi-part OpenEXR the part the run reads.
      const ingest::CaptureInfo info = ingest::readCaptureInfo(file, stage, true);
      checkImageSize(info.fileWidth, info.fileHeight, 1, stage, file);
    }
    // A holdout of another size than the plate fails the run when the plate is read: said now,
    // from the two headers (their sizes as shown, after their EXIF orientations).
    if (const pipeline::ComposeJob& j = o.job; !j.holdout.empty() && !j.plate.empty()) {
      const ingest::CaptureInfo plate = ingest::readCaptureInfo(j.plate, "ingest");
      const auto [pw, ph] = plate.shownSize();
      const auto [mw, mh] = ingest::readCaptureInfo(j.holdout, "composite").shownSize();
      if (const std::string why = pipeline::holdoutSizeProblem(mw, mh, pw, ph, plate.orientation);
          !why.empty())
        throw Error("composite", why, j.holdout);
    }
    for (const auto& s : pipeline::plan(o.job, colors, request)) {
      std::printf("%-10s %-7s %s\n", s.name.c_str(), pipeline::stateName(s.state),
                  s.reason.c_str());
    }
    return 0;
  }
  ProgressPrinter printer(globals);
  const auto result = pipeline::runCompose(o.job, colors, printer.callback(), request);
  if (!globals.quiet || o.timings) printStages(result, globals.quiet, o.timings);
  if (printOutputs)
    std::printf("%s\n%s\n", result.exrPath.string().c_str(), result.displayPath.string().c_str());
  return 0;
}

Runner setupCompose(CLI::App& app, const Globals& globals) {
  auto o = std::make_shared<ComposeOptions>();
  o->addPlate(app);
  o->addObject(app);
  o->addEnvironment(app);
  o->addLighting(app);
  o->addShadows(app, true);
  o->addOutput(app);
  o->addRun(app);
  auto saveScene = std::make_shared<std::string>();
  app.add_option("--save-scene", *saveScene,
                 "Write the scene file (JSON) this command line describes, then exit: compose run "
                 "SCENE does the same job");

  return [o, saveScene, &app, &globals]() -> int {
    const pipeline::ComposeJob& j = o->job;
    if ((j.plate.empty() || j.object.empty()) && saveScene->empty()) {
      throw UsageError(
          "the one-shot command needs --plate and --object (or a command; see "
          "compose --help)");
    }
    o->apply(app);
    // The config named on the command line, "builtin" too: a scene saved from it pins it (else
    // `compose run` took $OCIO's).
    if (!globals.ocio.empty())
      o->job.ocio = globals.ocio == "built-in" ? std::string("builtin") : globals.ocio;
    if (!saveScene->empty()) {
      if (o->explain)
        throw UsageError(
            "--save-scene writes the scene and exits; --explain plans a run: give one (compose "
            "run SCENE --explain plans the scene's)");
      // Checked as the run checks it, colour names included (a misspelt --exr-space was saved,
      // and compose run failed on it).
      validateJob(o->job, jobConfig(o->job, globals));
      // The scene is written before any input is read: it must not replace one of them.
      for (const std::filesystem::path& input : {o->job.plate, o->job.object, o->job.environment,
                                                 o->job.holdout, o->job.lensFile, o->job.poseFile})
        protectInput(input);
      pipeline::saveScene(o->job, *saveScene);
      if (!globals.quiet && (j.plate.empty() || j.object.empty()))
        std::fprintf(stderr,
                     "compose: note: the scene gives no %s: compose run needs one (--set "
                     "ingest.%s=FILE)\n",
                     j.plate.empty() ? "plate" : "object", j.plate.empty() ? "plate" : "object");
      std::printf("%s\n", saveScene->c_str());
      return 0;
    }
    return runJob(*o, globals);
  };
}

}  // namespace compose::app
