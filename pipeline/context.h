// The state of one compose job as its stages see it: the job, the colour config, the keys of
// every artefact, and the artefacts themselves as the stages produce (or reload) them.
//
// An artefact is named by a string (the names stages declare as inputs and outputs, below) and
// held in a typed slot of Artefacts. Its key is a 128-bit hash of everything it depends on: the
// contents of the input files, the parameters of every stage on the way, and the version of each
// stage's numbers. Equal keys mean equal artefacts, so a key found in the stage cache is reused.
#pragma once

#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>

#include "calib/plate_camera.h"
#include "color/color.h"
#include "core/hash.h"
#include "core/progress.h"
#include "cubemap/environment_io.h"
#include "hdr/capture_merge.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"
#include "lighting/capture_volume.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"
#include "pipeline/mesh_summary.h"
#include "pipeline/shadows.h"
#include "render/embree_scene.h"
#include "render/mesh.h"
#include "render/renderer.h"

namespace compose::pipeline {

// Artefact names.
namespace artefact {
inline const std::string kPlate = "plate";                       // the plate as read
inline const std::string kMesh = "mesh";                         // the object as read
inline const std::string kEnvironmentFile = "environment-file";  // an environment image as read
inline const std::string kCapture = "capture";                 // a capture description and headers
inline const std::string kMergedViews = "merged-views";        // HDR views, working space
inline const std::string kStitched = "stitched-environment";   // lat-long, working space
inline const std::string kPlateLinear = "plate-linear";        // RGB, working space
inline const std::string kEnvironment = "environment";         // lat-long, working space
inline const std::string kLighting = "lighting";               // the projected basis
inline const std::string kShadowLighting = "shadow-lighting";  // sources + residual projection
inline const std::string kSelfShadowing = "self-shadowing";    // shadowed irradiance per point
inline const std::string kGroundShadow = "ground-shadow";      // the plate's shadow ratio
inline const std::string kObject = "object";                   // the rendered object and AOVs
inline const std::string kComposite = "composite";             // RGB, working space
inline const std::string kFiles = "files";                     // the written outputs
}  // namespace artefact

// What --env names.
struct EnvironmentInput {
  enum class Kind {
    Image,   // one image or a set of cube faces: read (and resampled to lat-long) by ingest
    Capture  // a capture description (JSON): photos to merge and stitch
  } kind = Kind::Image;
  std::filesystem::path path;
  std::vector<std::filesystem::path> files;  // every file whose content the environment depends on
  bool bracketed = false;                    // Capture: some view holds more than one exposure
  int views = 0;                             // Capture: how many views
  std::string describe() const;
};

// Where things stand in the world: the plate camera, the object's placement, the environment's
// turn. Derived from the plate (size, EXIF), the mesh's bounds and the job's options.
struct Geometry {
  calib::PlateCamera camera;
  glm::dmat4 worldFromObject{1.0};
  glm::mat3 envFromWorld{1.0f};
  glm::mat3 envFromObject{1.0f};  // a turn about +Y: placement yaw and environment yaw
};

struct RenderedObject {
  render::RenderOutput output;
  float exposure = 1.0f;
  // What the output's colour and irradiance AOVs (exposedChannels()) are still to be multiplied
  // by, in the composite and the files: the exposure for the render stage's own render, which is
  // kept in the environment's units so that a new --exposure or plate reuses it; 1 for a layer
  // read from a file, whose values carry their exposure.
  float pending = 1.0f;
  // Whether `exposure` is chosen: a render's is chosen for the plate it is composited on
  // (chooseExposure, stages.h), a layer's came with it.
  bool exposureChosen = false;
  // A mid-grey card lying on the ground under the render's lighting: its radiance 0.18 E(up)/π as
  // luminance, in the environment's units (the automatic exposure matches it to the plate).
  double cardRadiance = 0.0;
  std::vector<std::string> notes;  // how the exposure was chosen
  std::string meshFile;            // the mesh it is made from (absolute), for the EXR header
  glm::dvec3 fileOrigin{0.0};      // render::Mesh::fileOrigin of that mesh
  // Read from an object layer (compose render): the plate it was rendered on (absolute) and the
  // hash of that plate's bytes (contentKey); empty for a layer that does not say.
  std::string layerPlateFile, layerPlateKey;
  // The exposure matched to the plate's pixels (the automatic match, not --exposure or EXIF): set
  // by chooseExposure. A layer records how its plate was decoded for it (the linear plate's key,
  // and --plate-space as given, empty when read as its file says), so that a composite that
  // decodes the plate otherwise says what that does to the match.
  bool exposureMatchedToPlate = false;
  std::string layerPlateDecoded, layerPlateSpace;
  bool fromLayer = false;  // read from an object layer (compose composite), not rendered here
};

// What calib::plateCamera() makes of a plate: its upright size and the header's facts it reads
// (EXIF orientation, the 35 mm equivalent focal length and where it came from), and the sensor's
// orientation of a map compose merged (CaptureInfo::sensorOrientation, for a lens in its frame).
Hash128 plateCameraKey(int uprightWidth, int uprightHeight, const ingest::CaptureInfo& info);
// The same from the header alone, before the plate is decoded (its size turned upright by the
// EXIF orientation, as reading it turns its pixels).
Hash128 plateCameraKey(const ingest::CaptureInfo& header);

// The channels of a rendered object that scale with its exposure, by their names in the files
// (the object's colour, its irradiance with and without self-shadowing).
const std::vector<std::string>& exposedChannels();

struct Artefacts {
  std::optional<ingest::LoadedImage> plate;
  std::optional<render::Mesh> mesh;
  std::optional<cubemap::LoadedEnvironment> environmentFile;
  std::optional<ingest::Capture> capture;
  std::optional<hdr::CaptureMergeResult> mergedViews;
  std::optional<Image> stitched;
  std::optional<Image> plateLinear;
  std::optional<Image> holdout;  // read with the plate, used by the composite
  std::optional<Image> environment;
  std::unique_ptr<lighting::DiffuseLighting> lighting;
  int lightingOrder = 0;  // the order order=auto chose (0: the basis' own)
  std::optional<ShadowLighting> shadowLighting;
  std::optional<ShadowResult> selfShadowing;
  std::optional<GroundShadowResult> groundShadow;
  std::optional<RenderedObject> object;
  std::optional<Image> composite;
};

// The environment's side of the exposure from EXIF (chooseExposure, stages.h): the camera whose
// EXIF exposure unit its radiance is in (a capture description, or a map the photo stages merged
// at their photos' EXIF exposures), else empty and why not; `whose` names it in notes.
struct EnvironmentExif {
  std::string camera;
  std::string whyNot;
  std::string whose = "the environment's";
};

class Context {
 public:
  Context(const ComposeJob& theJob, const color::ColorConfig& theColors, Progress theProgress)
      : job(theJob), colors(theColors), progress(std::move(theProgress)) {}

  const ComposeJob& job;
  const color::ColorConfig& colors;
  Progress progress;

  // Planning only (--explain): stages read what they must to say what would run, and write
  // nothing, not even to the cache.
  bool planning = false;
  // Filled in before any stage runs (runner.cpp).
  EnvironmentInput environmentInput;
  // Read from a lighting file (compose render), which carries it for the environment it was made
  // from; worked out from the environment otherwise.
  std::optional<EnvironmentExif> environmentExif;
  // Where a lighting file made with parallax sees the environment from (compose precompute
  // --room or --env-radius: the object's centre as it placed it), and the surroundings it took.
  struct LightingViewpoint {
    glm::dvec3 point{0.0};
    std::string surroundings;
  };
  std::optional<LightingViewpoint> lightingViewpoint;
  std::map<std::string, Hash128> keys;  // per artefact
  std::set<std::string> needed;         // artefacts some running stage consumes
  std::set<std::string> reachable;      // artefacts the wanted ones may be made from
  std::set<std::string> provided;       // artefacts read from files (RunRequest::inputs)

  Artefacts artefacts;
  std::vector<std::string> notes;  // for the user, in the order they arose

  bool needs(const std::string& name) const { return needed.count(name) > 0; }
  bool mayNeed(const std::string& name) const { return reachable.count(name) > 0; }
  // The key of an artefact; throws compose::UsageError when the job lacks the input it comes from
  // (a plate, an object).
  const Hash128& key(const std::string& name) const;
  bool hasKey(const std::string& name) const { return keys.count(name) > 0; }
  // What the plate camera is made of, from the plate's header (plateCameraKey below); set by
  // ingest with the plate's key.
  std::optional<Hash128> plateCamera;
  // Everything the geometry depends on (the plate camera as the plate's header makes it, not the
  // plate's pixels; the lens and pose files, the camera and placement options, the mesh, the
  // environment's turn): another take from the same camera keeps the geometry, and with it the
  // render and the ground shadow.
  Hash128 geometryKey() const;
  void note(std::string text) { notes.push_back(std::move(text)); }
  // A note about this run rather than about one stage's outputs: its own caching (an entry found
  // damaged, one that could not be written), or what the context works out for whichever stage
  // asks first (the plate camera). Said now, and not kept with a stage's outputs for the runs that
  // reuse them.
  void runNote(std::string text) {
    runNotes.insert(notes.size());
    notes.push_back(std::move(text));
  }
  std::set<size_t> runNotes;  // which of `notes` are run notes
  // A note of a stage that is not cached about what a later, cached stage is made from (ingest's
  // about the environment's file, whose pixels are not read again once the lighting made from
  // them is cached): said now, and kept with that stage's outputs too.
  void noteFor(const std::string& stage, std::string text) {
    keptFor[stage].push_back(text);
    notes.push_back(std::move(text));
  }
  std::map<std::string, std::vector<std::string>> keptFor;  // by stage

  // The world as the plate and the mesh place it (needs the plate and the mesh).
  const Geometry& geometry();
  // Planning (--explain): the geometry as the plate's header makes it, for its errors alone (a
  // --place above the horizon, a lens that cannot see it, a pose of another framing), as the run
  // would give them; nothing when the job has no plate or no object.
  void checkPlacement();
  // The geometry as a file recorded it (compose composite reads it from the object's layer).
  void setGeometry(const Geometry& g) { geometry_ = g; }
  // What ingest knows of the object (its key, bounds, size, convexity), read or cached.
  std::optional<MeshSummary> meshSummary;
  // The object's mesh (ingest reads it, or takes it from the cache).
  const render::Mesh& mesh();
  // The object's ray-tracing scene, built on first use (object space).
  const render::EmbreeScene& objectScene();
  // The proxy of the surroundings (distant when the job describes none), in the world's unit.
  lighting::CaptureProxy captureProxy() const;
  // The world's unit of length, for what is said: metres, or with a pose file whose board's
  // squares were not measured (calib pose without --square), the squares. Read once, on the
  // thread that runs the stages (as geometry() is).
  const std::string& lengthUnit() const;
  // The centre of the object's bounding box in the world (needs the geometry): where parallax
  // sees the environment from.
  glm::dvec3 objectCentre();

 private:
  std::optional<Geometry> geometry_;
  Geometry makeGeometry(int plateWidth, int plateHeight, const ingest::CaptureInfo& info);
  std::unique_ptr<render::EmbreeScene> objectScene_;
  mutable std::optional<std::string> lengthUnit_;
};

}  // namespace compose::pipeline
