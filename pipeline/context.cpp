#include "pipeline/context.h"

#include <cstdio>
#include <numbers>

#include <glm/gtc/matrix_transform.hpp>

#include "calib/chessboard.h"
#include "calib/lens.h"
#include "core/error.h"
#include "core/numbers.h"
#include "pipeline/stage_util.h"

namespace compose::pipeline {

std::string EnvironmentInput::describe() const {
  if (kind == Kind::Capture)
    return "a capture of " + std::to_string(views) + " views" +
           (bracketed ? " (exposure brackets)" : " (one exposure each)");
  return files.size() == 6 ? "six cube faces" : "one image";
}

const std::vector<std::string>& exposedChannels() {
  static const std::vector<std::string> names = {"object.R",
                                                 "object.G",
                                                 "object.B",
                                                 "irradiance.R",
                                                 "irradiance.G",
                                                 "irradiance.B",
                                                 "irradianceShadowed.R",
                                                 "irradianceShadowed.G",
                                                 "irradianceShadowed.B"};
  return names;
}

const Hash128& Context::key(const std::string& name) const {
  const auto it = keys.find(name);
  if (it != keys.end()) return it->second;
  if (name == artefact::kPlate)
    throw UsageError("this job needs a plate: give --plate (ingest.plate in a scene file)");
  if (name == artefact::kMesh)
    throw UsageError("this job needs an object: give --object (ingest.object in a scene file)");
  COMPOSE_CHECK(it != keys.end());
  return it->second;
}

Hash128 plateCameraKey(int uprightWidth, int uprightHeight, const ingest::CaptureInfo& info) {
  Hash128 h;
  h.bytes("plate camera");
  h.word(uint32_t(uprightWidth));
  h.word(uint32_t(uprightHeight));
  h.word(uint32_t(info.orientation));
  h.word(uint32_t(info.sensorOrientation));
  h.number(info.focalLength35mm.value_or(-1.0));
  h.bytes(info.focal35mmSource);
  h.number(info.pixelAspectRatio);
  return h;
}

Hash128 plateCameraKey(const ingest::CaptureInfo& header) {
  const auto [width, height] = header.shownSize();
  return plateCameraKey(width, height, header);
}

Hash128 Context::geometryKey() const {
  Hash128 h;
  h.bytes("geometry");
  // 2: the plate's 35 mm focal length derived from EXIF where the tag rounds it; 3: a cut-out
  // object stands on what its cut-outs keep (Mesh::keptBounds); 4: the plate camera, not the
  // plate's bytes; 5: a lens mirrored for a plate tagged 2, 4, 5 or 7; 6: a pose's lens is not
  // turned by the plate's orientation, and a lens file fits a plate only to a resize's rounding;
  // 7: a plate's pixel aspect ratio; 8: an object under 1 % as high as it is large sized by its
  // largest extent (calib::sizedExtent)
  h.word(8);
  key(artefact::kPlate);  // a job without a plate has no geometry: the usage error says so
  COMPOSE_CHECK(plateCamera.has_value());
  h.combine(*plateCamera);
  h.combine(key(artefact::kMesh));
  if (!job.lensFile.empty()) hashFile(h, job.lensFile, "camera");
  if (!job.poseFile.empty()) hashFile(h, job.poseFile, "camera");
  h.number(job.camera.focal35mm.value_or(-1.0));
  h.number(job.camera.height);
  h.number(job.camera.pitchDegrees);
  h.number(job.placement.imagePoint.x);
  h.number(job.placement.imagePoint.y);
  h.number(job.placement.heightFraction);
  h.number(job.placement.yawDegrees);
  h.number(job.environmentYawDegrees);
  return h;
}

const Geometry& Context::geometry() {
  if (geometry_) return *geometry_;
  COMPOSE_CHECK(artefacts.plate && meshSummary);
  const ingest::LoadedImage& plate = *artefacts.plate;
  // The stages that use the geometry were keyed by the plate's header: the decoded plate must
  // make the same camera (it does not when the file was replaced while compose ran).
  COMPOSE_CHECK(plateCamera.has_value());
  if (*plateCamera != plateCameraKey(plate.image.width, plate.image.height, plate.info)) {
    throw Error("ingest",
                "the plate's header changed between reading it and decoding its pixels (was the "
                "file replaced while compose ran?): run again",
                job.plate);
  }
  geometry_ = makeGeometry(plate.image.width, plate.image.height, plate.info);
  return *geometry_;
}

void Context::checkPlacement() {
  if (job.plate.empty() || !meshSummary) return;
  const ingest::CaptureInfo header = ingest::readCaptureInfo(job.plate, "ingest", true);
  const auto [width, height] = header.shownSize();
  makeGeometry(width, height, header);
}

Geometry Context::makeGeometry(int plateWidth, int plateHeight, const ingest::CaptureInfo& info) {
  const MeshSummary& mesh = *meshSummary;
  calib::CameraOptions options = job.camera;
  std::filesystem::path lensFrom;  // the file the lens comes from, for errors about it
  if (!job.lensFile.empty()) {
    options.lens = calib::readLens(job.lensFile);
    requireUnchangedSinceHashed(job.lensFile, "camera");
    lensFrom = job.lensFile;
  }
  int poseWidth = 0, poseHeight = 0;  // the plate the pose was estimated on
  if (!job.poseFile.empty()) {
    // The board's plane is the ground; the pose's lens is the plate's unless --calib says else.
    const calib::PlatePose pose = calib::readPose(job.poseFile);
    requireUnchangedSinceHashed(job.poseFile, "camera");
    poseWidth = pose.width;
    poseHeight = pose.height;
    if (!options.lens) {
      options.lens = pose.lens;
      options.lens->source = "the lens of pose file " + job.poseFile.string();
      options.lensUpright = true;
      lensFrom = job.poseFile;
    }
    options.worldFromCamera = pose.worldFromCamera;
  }
  const calib::PlateCamera camera = [&] {
    try {
      return calib::plateCamera(plateWidth, plateHeight, info, options);
    } catch (const UsageError&) {
      throw;
    } catch (const Error& e) {
      if (!e.file().empty()) throw;
      // A plate that does not fit the lens; without a lens file, the plate's own facts (a pixel
      // aspect ratio of 1000).
      throw Error(e.stage(), e.what(), lensFrom.empty() ? job.plate : lensFrom);
    }
  }();
  // A pose is of one shot's framing: another aspect ratio is another framing (a crop); the same
  // at another size is taken as the shot resized.
  if (poseWidth > 0 && poseHeight > 0 &&
      (poseWidth != camera.width || poseHeight != camera.height)) {
    const double ratio = (double(poseWidth) / poseHeight) / (double(camera.width) / camera.height);
    if (std::abs(ratio - 1.0) > 0.01)
      throw Error("camera",
                  "the pose was estimated on a " + std::to_string(poseWidth) + "x" +
                      std::to_string(poseHeight) + " plate; this one is " +
                      std::to_string(camera.width) + "x" + std::to_string(camera.height) +
                      " (another aspect ratio: another framing, or cropped): estimate the pose "
                      "on this plate (compose calib pose)",
                  job.poseFile);
    runNote("the pose was estimated on a " + std::to_string(poseWidth) + "x" +
            std::to_string(poseHeight) + " plate; this one is " + std::to_string(camera.width) +
            "x" + std::to_string(camera.height) + ": taken as the same shot resized");
  }
  Geometry g{camera};
  {
    // Which lens the object is seen through: the plate's facts are untrusted, and a default or
    // a lens taken for another framing is what a user looks for first when the object sits
    // wrongly.
    char text[128];
    std::snprintf(
        text, sizeof text,
        "plate camera: a 35 mm equivalent focal length of %.1f mm (fx %.1f px at %dx%d): ",
        camera.focal35mm, camera.lens.fx, camera.width, camera.height);
    std::string said = text + camera.focalSource;
    if (camera.pixelAspect != 1.0)
      said += "; its pixels are " + numberText(camera.pixelAspect) +
              " times as wide as high (the plate's pixelAspectRatio): fx " +
              numberText(camera.lens.fx) + ", fy " + numberText(camera.lens.fy) +
              " px; the EXR keeps the ratio, the display image shows the stored pixels";
    if (options.lens == std::nullopt && !options.focal35mm && !info.focalLength35mm)
      said += "; give --focal35 or --calib";
    runNote(said);
  }
  try {
    g.worldFromObject = calib::placeOnGround(g.camera, job.placement, glm::dvec3(mesh.boundsMin),
                                             glm::dvec3(mesh.boundsMax));
  } catch (const UsageError&) {
    throw;
  } catch (const Error& e) {
    if (!e.file().empty()) throw;
    // The pose puts the ground there; else the calibration's lens maps the point nowhere (a
    // point it maps, above the horizon, is --place's doing, not the lens file's).
    if (!job.poseFile.empty()) throw Error(e.stage(), e.what(), job.poseFile);
    glm::dvec3 origin, dir;
    const glm::dvec2 at = job.placement.imagePoint;
    if (!job.lensFile.empty() &&
        !g.camera.ray(at.x * g.camera.width, at.y * g.camera.height, origin, dir))
      throw Error(e.stage(), e.what(), job.lensFile);
    throw;
  }
  bool flat = false;
  calib::sizedExtent(glm::dvec3(mesh.boundsMin), glm::dvec3(mesh.boundsMax), &flat);
  if (flat)
    runNote("the object is flat (its height " +
            numberText(double(mesh.boundsMax.y) - double(mesh.boundsMin.y)) +
            " is under 1 % of its largest extent): --scale sizes its largest extent instead");
  // Reduced to a turn first, as the object's yaw: any finite angle is an angle.
  const double envYaw = -std::fmod(job.environmentYawDegrees, 360.0) * std::numbers::pi / 180.0;
  g.envFromWorld = glm::mat3(glm::rotate(glm::dmat4(1.0), envYaw, glm::dvec3(0, 1, 0)));
  // The rotation part of the placement (a yaw and a uniform scale), normalised in double before
  // it is rounded to float: the rotation then does not depend on the scale to the last bit, and
  // what is made from it alone (the self-shadowing, keyed by the yaw) is the same wherever and
  // however large the object stands.
  glm::dmat3 rotation = glm::dmat3(g.worldFromObject);
  for (int c = 0; c < 3; ++c) rotation[c] = glm::normalize(rotation[c]);
  g.envFromObject = g.envFromWorld * glm::mat3(rotation);
  return g;
}

const render::Mesh& Context::mesh() {
  COMPOSE_CHECK(artefacts.mesh);
  return *artefacts.mesh;
}

const render::EmbreeScene& Context::objectScene() {
  if (!objectScene_) {
    const render::Mesh& m = mesh();
    objectScene_ = std::make_unique<render::EmbreeScene>(m);
  }
  return *objectScene_;
}

lighting::CaptureProxy Context::captureProxy() const {
  lighting::CaptureProxy proxy = pipeline::captureProxy(job);
  if (proxy.shape != lighting::CaptureProxy::Shape::Distant) proxy.unit = lengthUnit();
  return proxy;
}

const std::string& Context::lengthUnit() const {
  if (!lengthUnit_) {
    // calib pose writes a square of 1 when --square is not given: lengths in squares.
    bool squares = false;
    if (!job.poseFile.empty()) {
      squares = calib::readPose(job.poseFile).board.square == 1.0;
      requireUnchangedSinceHashed(job.poseFile, "camera");
    }
    lengthUnit_ = squares ? "squares" : "m";
  }
  return *lengthUnit_;
}

glm::dvec3 Context::objectCentre() {
  COMPOSE_CHECK(meshSummary.has_value());
  const glm::dvec3 middle = 0.5 * glm::dvec3(meshSummary->boundsMin + meshSummary->boundsMax);
  return glm::dvec3(geometry().worldFromObject * glm::dvec4(middle, 1.0));
}

}  // namespace compose::pipeline
