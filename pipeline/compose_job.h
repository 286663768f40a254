// The compose pipeline: the list of stages and the runner that takes a plate, an object and an
// environment to a composite.
//
// Stage contract (every stage library under src/ follows it):
//  * A stage is a plain function over in-memory data that returns new data; the caller owns both.
//    Nothing in a stage reads options from the command line or prints: long work reports through
//    a Progress callback (core/progress.h), and remarks for the user come back as data.
//  * Images travel as compose::Image, tagged with their colour space; inside the pipeline they
//    are scene-linear in the working space (role scene_linear of the OpenColorIO config).
//  * Stages may use every core (oneTBB, through core/parallel.h); results do not depend on the
//    number of threads.
//  * Bad input or data throws compose::Error with the stage name and the file; a broken invariant
//    is a bug and aborts (COMPOSE_CHECK). Files are written atomically (temp file + rename), so a
//    failed run leaves no half-written output.
//
// The stages, in order (stageNames()): ingest, merge, stitch, color, precompute, render,
// composite, output. A stage a scene does not need is skipped, and plan() says which and why.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "calib/plate_camera.h"
#include "color/color.h"
#include "core/progress.h"
#include "render/renderer.h"

namespace compose::pipeline {

const std::vector<std::string>& stageNames();

// Folder of the fetched sample data: $COMPOSE_SAMPLES_DIR, else $XDG_CACHE_HOME/compose/samples,
// else ~/.cache/compose/samples (samples/fetch.sh fills it).
std::filesystem::path samplesDirectory();
// The environment used when none is given.
std::filesystem::path defaultEnvironment();
// Root of the on-disk caches (projected lighting in lighting/, visibility passes in visibility/):
// $COMPOSE_CACHE_DIR, else $XDG_CACHE_HOME/compose, else ~/.cache/compose.
std::filesystem::path cacheDirectory();

struct ComposeJob {
  std::filesystem::path plate;
  std::filesystem::path object;
  std::filesystem::path environment;  // empty: defaultEnvironment()
  // Output base path: writes <base>.exr (linear) and <base>.jpg (display). An extension of .exr,
  // .jpg/.jpeg or .png on `output` is taken off first; .png selects PNG for the display image.
  // A path ending in '/' (or an existing folder) writes <folder>/compose.exr and .jpg.
  std::filesystem::path output = "out/compose";

  std::string plateSpace;        // empty: from the file (see ColorConfig::inputSpaceFor)
  std::string environmentSpace;  // empty: from the file
  std::string display, view;     // empty: the config's defaults

  std::string lighting = "cheb-local";
  std::string lightingParams;  // "key=value,..." for the basis
  // Self-shadowing of the object (skipped for a convex object) and its parameters
  // (pipeline/shadows.h).
  bool shadows = true;
  std::string shadowParams;
  // The shadow the object casts on the ground of the plate (differential rendering).
  bool groundShadow = true;
  // A holdout mask (an image the plate's size, white where the plate is in front of the object).
  std::filesystem::path holdout;
  // Root of the caches: projected lighting keyed by the environment's pixels and the basis
  // parameters, visibility passes keyed by the mesh and theirs; empty disables both.
  std::filesystem::path cache = cacheDirectory();
  double environmentYawDegrees = 0.0;
  // A lens calibration (compose calib lens) for the plate; empty: EXIF or --focal35.
  std::filesystem::path lensFile;

  calib::CameraOptions camera;
  calib::Placement placement;
  // Diffuse albedo in the working space for the whole object, overriding the mesh's materials;
  // empty: the materials, and render::kDefaultAlbedo (clay grey) where the mesh has none.
  std::optional<glm::vec3> albedo;
  // Crease angle (degrees, 0..180) for the normals computed where the mesh file has none.
  double creaseDegrees = 60.0;
  // Exposure of the object in stops; empty = auto (the environment's radiance in the camera's
  // field of view is scaled to match the plate's mean linear value).
  std::optional<double> exposureStops;
  int samplesPerAxis = 4;

  // Surroundings at a finite distance, for parallax (lighting/capture_volume.h): a room of
  // W x H x D metres standing on the ground, centred below the plate camera (x in [-W/2, W/2],
  // y in [0, H], z in [-D/2, D/2]), or a sphere of `environmentRadius` metres around the capture
  // point. Neither: the environment is infinitely distant. The object is then lit by the
  // environment as seen from its centre.
  std::optional<glm::dvec3> room;
  std::optional<double> environmentRadius;
  // Where the environment was captured, world metres; default: the plate camera's position.
  std::optional<glm::dvec3> captureAt;
};

struct StageRecord {
  std::string name;
  bool runs = true;
  std::string reason;    // why it runs, is reused or is skipped
  double seconds = 0.0;  // filled in by runCompose
};

struct ComposeResult {
  std::filesystem::path exrPath, displayPath;
  std::vector<StageRecord> stages;
  std::vector<std::string>
      notes;  // things the user should know (assumed colour spaces, clamping, ...)
  int width = 0, height = 0;
  double objectPixels = 0.0;  // sum of alpha
  float exposure = 1.0f;      // linear multiplier applied to the object's radiance
};

// Output paths for a job.
std::filesystem::path exrPathFor(const ComposeJob& job);
std::filesystem::path displayPathFor(const ComposeJob& job);

// Checks every option of the job without reading any file; throws compose::UsageError (exit
// status 2) naming the option. runCompose() calls it first.
void validate(const ComposeJob& job);

// What would run, and why, without reading any pixels.
std::vector<StageRecord> plan(const ComposeJob& job);

ComposeResult runCompose(const ComposeJob& job, const color::ColorConfig& colors,
                         const Progress& progress = {});

}  // namespace compose::pipeline
