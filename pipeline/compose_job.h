// The compose pipeline's job: everything one composite is made from, and the runner's entry
// points (the stages themselves are plugins, stage.h; the runner is runner.cpp).
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
// The stages, in order (stage.h, stages()): ingest, merge, stitch, color, precompute, shadows,
// ground, render, composite, output. Each stage's outputs are keyed by the content of the inputs
// they come from and the parameters; a stage whose outputs are in the stage cache is reused, one
// the scene does not need is skipped, and plan() says which and why without reading any pixels.
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "calib/plate_camera.h"
#include "color/color.h"
#include "core/progress.h"
#include "lighting/capture_volume.h"
#include "render/renderer.h"

namespace compose::pipeline {

// Folder of the fetched sample data: $COMPOSE_SAMPLES_DIR, else $XDG_CACHE_HOME/compose/samples,
// else ~/.cache/compose/samples (samples/fetch.sh fills it).
std::filesystem::path samplesDirectory();
// The environment used when none is given.
std::filesystem::path defaultEnvironment();
// Root of the on-disk caches (stage outputs in stages/, visibility passes in visibility/):
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

  // The OpenColorIO config file (--ocio; a scene file's): empty: $OCIO, else the built-in one.
  std::filesystem::path ocio;
  std::string plateSpace;        // empty: from the file (see ColorConfig::inputSpaceFor)
  std::string environmentSpace;  // empty: from the file
  std::string display, view;     // empty: the config's defaults
  // The EXR's compression, as OpenImageIO names it (ingest::parseExrCompression): lossless PIZ by
  // default, of OpenImageIO's codecs the cheapest on these images (a photograph's noise in half
  // floats: about half ZIP's time, files about a fifth larger; compose-bench-pipeline, README).
  std::string exrCompression = "piz";
  // The EXR's sample type: "half", "float", or "auto" (float when the plate is stored as 32-bit
  // float, half otherwise, as Nuke writes; a part with values beyond half's range is float).
  std::string exrDepth = "auto";
  // The colour space of the EXR's colour channels (composite, object, albedo and irradiance):
  // a linear space of the config; empty: the working space.
  std::string exrSpace;
  int jpegQuality = 95;  // of the display image when it is a JPEG, 1-100

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
  // Root of the caches: every expensive stage's outputs under stages/<stage>/, keyed by the
  // contents of the inputs and the parameters; visibility passes keyed by the mesh under
  // visibility/. Empty: no cache.
  std::filesystem::path cache = cacheDirectory();
  // Worker threads (0: every core).
  int threads = 0;
  double environmentYawDegrees = 0.0;
  // A lens calibration (compose calib lens) for the plate; empty: EXIF or --focal35.
  std::filesystem::path lensFile;
  // A plate pose (compose calib pose): the camera's position and tilt over the chessboard's plane,
  // which becomes the ground the object stands on (and its lens, unless lensFile is given).
  std::filesystem::path poseFile;

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
  // Adaptive anti-aliasing (render::RenderSettings::adaptive): plain pixels from their four corner
  // samples, the rest from all n x n. False: every pixel from all n x n.
  bool adaptiveSampling = true;

  // Surroundings at a finite distance, for parallax (lighting/capture_volume.h): a room of
  // W x H x D metres standing on the ground, centred below the plate camera (x in [-W/2, W/2],
  // y in [0, H], z in [-D/2, D/2]), or a sphere of `environmentRadius` metres around the capture
  // point. Neither: the environment is infinitely distant. The object is then lit by the
  // environment as seen from its centre. With a pose file, lengths are the pose's and the
  // world's origin is the board's centre (calib/chessboard.h).
  std::optional<glm::dvec3> room;
  std::optional<double> environmentRadius;
  // Where the environment was captured, in the world (metres, or the pose's units); default: the
  // plate camera's position.
  std::optional<glm::dvec3> captureAt;
};

enum class StageState {
  Run,     // computed in this run
  Reused,  // its outputs were loaded from the stage cache
  Skipped  // the scene does not need it, or nothing downstream needs its outputs
};
const char* stateName(StageState state);  // "run", "reused", "skipped"

struct StageRecord {
  std::string name;
  StageState state = StageState::Run;
  std::string reason;      // what it did, or why it is reused or skipped
  double seconds = 0.0;    // wall-clock time in this run (loading, for a reused stage)
  int64_t peakBytes = 0;   // peak resident memory of the process during the stage (0: unknown)
  std::string cacheEntry;  // the stage cache entry read or written, if any
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

// The environment a job uses (its own, else defaultEnvironment()).
std::filesystem::path environmentPathFor(const ComposeJob& job);

// Output paths for a job.
std::filesystem::path exrPathFor(const ComposeJob& job);
std::filesystem::path displayPathFor(const ComposeJob& job);

// The proxy of the surroundings the job describes (--room, --env-radius, --capture-at; distant
// when it describes none).
lighting::CaptureProxy captureProxy(const ComposeJob& job);

// Checks every option of the job without reading any file; throws compose::UsageError (exit
// status 2) naming the option. runCompose() calls it first.
void validate(const ComposeJob& job);

class Context;

// The outputs of some stages read from a file instead of computed: how the stage-by-stage
// commands chain (compose render reads what compose precompute wrote).
struct StageInput {
  std::vector<std::string> stages;  // the stages whose outputs the file holds
  std::filesystem::path file;
  // Puts the outputs, and a key for each, into the context; throws compose::Error naming the
  // file when it does not hold them.
  std::function<void(Context&)> load;
};

// What a run is for: the artefacts wanted (context.h; by default the written files), the stages
// read from files, and what to do with the context once the stages have run (a stage command
// writes its own file from it).
struct RunRequest {
  std::vector<std::string> targets = {"files"};
  std::vector<StageInput> inputs;
  std::function<void(Context&)> finish;
  // The files the command writes (empty: the job's BASE.exr and BASE.jpg), and the files it
  // reads besides the job's own (a lighting file, a layer): checked before any stage runs, and
  // by --explain, so that no output replaces an input.
  std::vector<std::filesystem::path> outputFiles, inputFiles;
};

// What would run, be reused from the cache, or be skipped, and why, without reading any pixels
// (the input files are hashed and the mesh is read).
std::vector<StageRecord> plan(const ComposeJob& job, const color::ColorConfig& colors,
                              const RunRequest& request = {});

ComposeResult runCompose(const ComposeJob& job, const color::ColorConfig& colors,
                         const Progress& progress = {}, const RunRequest& request = {});

}  // namespace compose::pipeline
