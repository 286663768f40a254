// The stages that bring the inputs in: ingest, merge, stitch, color.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "core/channels.h"
#include "core/error.h"
#include "core/parallel.h"
#include "cubemap/layouts.h"
#include "cubemap/photo_header.h"
#include "cubemap/render_view.h"
#include "cubemap/stitch.h"
#include "ingest/image_io.h"
#include "lighting/sphere_resample.h"
#include "pipeline/context.h"
#include "pipeline/materials.h"
#include "pipeline/stage.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_util.h"
#include "pipeline/stages.h"
#include "render/transfer.h"

namespace compose::pipeline {

namespace fs = std::filesystem;
using namespace artefact;

namespace {

std::string plural(size_t n, const std::string& word) {
  return std::to_string(n) + " " + word + (n == 1 ? "" : "s");
}

// What --env names: an image (or cube faces), or a capture description of photos.
void prepareEnvironment(Context& ctx) {
  const ComposeJob& job = ctx.job;
  const fs::path envPath = environmentPathFor(job);
  EnvironmentInput& in = ctx.environmentInput;
  in.path = envPath;
  std::error_code ec;
  if (job.environment.empty() && !fs::exists(envPath, ec)) {
    throw Error("ingest",
                "no --env given and the sample environment is missing; run samples/fetch.sh",
                envPath);
  }
  std::string ext = envPath.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  // A folder of photos described by `compose ingest --json` or written by `compose capture-sim`
  // is that capture, when the folder holds no cube faces.
  fs::path capturePath = envPath;
  if (ext != ".json" && fs::is_directory(envPath, ec) &&
      envPath.string().find('%') == std::string::npos) {
    try {
      in.files = cubemap::environmentFiles(envPath);
    } catch (const Error& e) {
      const fs::path described = envPath / "capture.json";
      if (fs::is_regular_file(described, ec)) {
        capturePath = described;
        ctx.note("the folder " + envPath.string() +
                 " holds no cube faces: its capture "
                 "description " +
                 described.string() + " is taken");
      } else {
        size_t images = 0;
        for (const auto& entry : fs::directory_iterator(envPath, ec))
          if (entry.is_regular_file() && ingest::looksLikeImageFile(entry.path())) ++images;
        if (images == 0) throw;
        throw Error("ingest",
                    std::string(e.what()) + "; its " + plural(images, "image") +
                        " are not named as cube faces. Photos? `compose ingest --json " +
                        described.string() + " " + envPath.string() +
                        "` describes them, then --env takes that file",
                    envPath);
      }
    }
  }
  if (ext == ".json" || capturePath != envPath) {
    in.kind = EnvironmentInput::Kind::Capture;
    in.path = capturePath;
    ingest::Capture capture = ingest::readCaptureDescription(capturePath);
    ingest::resolveExposures(capture);
    for (const std::string& w : ingest::captureWarnings(capture))
      ctx.note("warning: " + w + " (" + capturePath.string() + ")");
    in.files = {capturePath};
    for (const ingest::View& v : capture.views) {
      for (const ingest::Shot& s : v.shots) in.files.push_back(s.file);
      if (v.shots.size() > 1) in.bracketed = true;
    }
    if (!capture.lensFile.empty()) in.files.push_back(capture.lensFile);
    in.views = int(capture.views.size());
    ctx.artefacts.capture = std::move(capture);
  } else {
    in.kind = EnvironmentInput::Kind::Image;
    if (in.files.empty()) in.files = cubemap::environmentFiles(envPath);
  }
}

// ---------------------------------------------------------------------------------------------

class IngestStage final : public Stage {
 public:
  std::string name() const override { return "ingest"; }
  std::string summary() const override {
    return "read the plate, the object, and the environment (an image, cube faces, or a capture "
           "description of photos)";
  }
  // The files this job reads, by name, and what the environment is (--explain said "the plate,
  // the object, and the environment (an image, cube faces, or a capture description of photos)"
  // whatever the job read).
  std::string planned(const Context& ctx) const override {
    const ComposeJob& job = ctx.job;
    std::vector<std::string> files;
    if (ctx.mayNeed(kPlate) && !job.plate.empty())
      files.push_back("the plate " + job.plate.filename().string());
    if (ctx.mayNeed(kMesh) && !job.object.empty()) {
      files.push_back("the object " + job.object.filename().string());
      if (ctx.meshSummary)
        files.back() += " (" + plural(ctx.meshSummary->triangles, "triangle") + ")";
    }
    const EnvironmentInput& env = ctx.environmentInput;
    if ((ctx.mayNeed(kEnvironmentFile) || ctx.mayNeed(kCapture)) && !env.path.empty())
      files.push_back("the environment " + env.path.filename().string() + " (" + env.describe() +
                      ")");
    if (files.empty()) return summary();
    std::string text = "read " + files.front();
    for (size_t i = 1; i < files.size(); ++i)
      text += (i + 1 == files.size() ? " and " : ", ") + files[i];
    return text;
  }
  std::vector<std::string> inputs() const override { return {}; }
  std::vector<std::string> outputs() const override {
    return {kPlate, kMesh, kEnvironmentFile, kCapture};
  }
  std::vector<StageParameter> parameters() const override {
    return {pathParameter("plate", "the background photograph", &ComposeJob::plate),
            pathParameter("object", "the mesh (OBJ, glTF, Geomview .bez)", &ComposeJob::object),
            pathParameter("environment",
                          "the environment: a lat-long map, cube faces, or a capture description "
                          "(JSON) of photos to merge and stitch; empty: the forest sample",
                          &ComposeJob::environment),
            {"crease", "crease angle in degrees for normals computed where the mesh has none",
             [](const ComposeJob& job) { return nlohmann::json(job.creaseDegrees); },
             [](ComposeJob& job, const nlohmann::json& v) {
               if (!v.is_number()) throw UsageError("crease must be a number of degrees");
               job.creaseDegrees = v.get<double>();
             }}};
  }

  void prepare(Context& ctx) const override {
    const ComposeJob& job = ctx.job;
    if (ctx.mayNeed(kEnvironmentFile) || ctx.mayNeed(kCapture)) prepareEnvironment(ctx);
    // The mesh's content is part of every later key: it is read here (or taken from the cache,
    // as a previous run read the same file).
    if (ctx.mayNeed(kMesh) && !job.object.empty()) {
      Hash128 contentKey;
      std::string problem;
      std::optional<CachedMesh> cached =
          cachedMesh(job.cache, job.object, job.creaseDegrees, contentKey, problem);
      if (!problem.empty()) {
        ctx.note("the cached reading of the object " + job.object.string() + " " + problem +
                 ": ignored, computed again and rewritten");
      }
      if (cached) {
        ctx.artefacts.mesh = std::move(cached->mesh);
        ctx.meshSummary = std::move(cached->summary);
      } else {
        ctx.artefacts.mesh = render::loadMesh(job.object, {.creaseDegrees = job.creaseDegrees});
        requireUnchangedSinceHashed(job.object, "mesh");
        // Surfaces seen from both sides get a back side of their own (kept in the cache with
        // the mesh).
        render::addBackSides(*ctx.artefacts.mesh);
        ctx.meshSummary = summarize(*ctx.artefacts.mesh, job.creaseDegrees);
        if (!ctx.planning &&
            !storeMesh(job.cache, contentKey, *ctx.artefacts.mesh, *ctx.meshSummary, problem)) {
          const std::string folder = cacheFolderProblem(job.cache / "meshes");
          ctx.note("the object as read was not cached (" + (folder.empty() ? problem : folder) +
                   ")");
        }
      }
      for (const std::string& n : ctx.meshSummary->notes) ctx.note(n);
    }
  }

  void keys(Context& ctx) const override {
    if (ctx.mayNeed(kPlate) && !ctx.job.plate.empty()) {
      Hash128 plate;
      plate.bytes("plate");
      hashFile(plate, ctx.job.plate, "ingest");
      ctx.keys[kPlate] = plate;
      ctx.plateCamera = plateCameraKey(ingest::readCaptureInfo(ctx.job.plate, "ingest", true));
    }
    if (ctx.meshSummary) ctx.keys[kMesh] = ctx.meshSummary->key;
    if (ctx.environmentInput.path.empty()) return;
    Hash128 env;
    env.bytes(ctx.environmentInput.kind == EnvironmentInput::Kind::Capture ? "capture"
                                                                           : "environment");
    for (const fs::path& f : ctx.environmentInput.files) hashFile(env, f, "ingest");
    ctx.keys[ctx.environmentInput.kind == EnvironmentInput::Kind::Capture ? kCapture
                                                                          : kEnvironmentFile] = env;
  }

  std::string run(Context& ctx) const override {
    std::string reason;
    if (ctx.needs(kPlate)) {
      // An 8-bit plate stays as its codes, a quarter of the memory: the colour stage converts
      // them to the working space in one pass.
      ctx.artefacts.plate = ingest::readImage(ctx.job.plate, "ingest",
                                              {.codesForEightBit = true, .picturePart = true});
      const ingest::LoadedImage& p = *ctx.artefacts.plate;
      requireUnchangedSinceHashed(ctx.job.plate, "ingest");
      ingest::requireColourChannels(p.image, ctx.job.plate, "ingest", "the plate");
      for (const std::string& n : p.notes) ctx.note("the plate " + n);
      reason = format("the plate %dx%d (%s)", p.image.width, p.image.height, p.info.format.c_str());
      if (!ctx.job.holdout.empty()) {
        // The holdout is read with the plate, not by the composite at the end: a missing mask,
        // one of the wrong size or one holding NaN stops the job before the long work.
        std::string how;
        ctx.artefacts.holdout =
            loadHoldout(ctx.job.holdout, p.image.width, p.image.height, &how, p.info.orientation);
        requireUnchangedSinceHashed(ctx.job.holdout, "composite");
        if (!how.empty()) ctx.note(how);
      }
    }
    if (ctx.meshSummary) {
      const size_t triangles = ctx.meshSummary->triangles;
      reason += (reason.empty() ? "" : ", ") +
                (ctx.meshSummary->fromCache
                     ? format("the object (%zu triangles, from the cache)", triangles)
                     : format("the object (%zu triangles)", triangles));
    }
    // The colour stage asks for the environment file or the stitched map, whichever this job has:
    // a capture description has no environment file to read.
    if (ctx.needs(kEnvironmentFile) && ctx.hasKey(kEnvironmentFile)) {
      // A cube's faces are made linear in the working space before they are resampled (what
      // the colour stage does to a lat-long map).
      ctx.artefacts.environmentFile = cubemap::loadEnvironment(
          ctx.environmentInput.path, {}, ctx.progress,
          [&](Image& face, const ingest::CaptureInfo& info, const std::filesystem::path& file) {
            face = toRgb(face);
            return toWorkingSpace(face, file, info, ctx.job.environmentSpace, "--env-space",
                                  ctx.colors);
          });
      const cubemap::LoadedEnvironment& env = *ctx.artefacts.environmentFile;
      for (const fs::path& f : ctx.environmentInput.files) requireUnchangedSinceHashed(f, "ingest");
      // The lighting made from the pixels keeps what is said of them (a later run reuses it
      // without reading them).
      for (const std::string& n : env.notes) ctx.noteFor("precompute", n);
      if (env.info.integerSamples() && env.info.format != "raw") {
        ctx.noteFor("precompute",
                    "the environment is a " + env.info.format +
                        " file, not HDR: bright light sources are clipped and the lighting will be "
                        "too dark");
      }
      reason += format(", the environment %dx%d", env.image.width, env.image.height);
    } else if (ctx.environmentInput.kind == EnvironmentInput::Kind::Capture) {
      reason +=
          ", the capture description (" + plural(ctx.artefacts.capture->views.size(), "view") + ")";
    } else if (!ctx.environmentInput.path.empty()) {
      reason += "; the environment's pixels are not needed (everything made from them is cached)";
    }
    report(ctx.progress, "ingest", 1.0);
    if (reason.rfind(", ", 0) == 0) reason.erase(0, 2);  // no plate (compose precompute)
    if (reason.rfind("; ", 0) == 0) reason.erase(0, 2);
    return "read " + reason;
  }
};

// ---------------------------------------------------------------------------------------------

class MergeStage final : public Stage {
 public:
  // Bump when merging gives other numbers for the same photos.
  // 2: a stored response is checked against the photos; 3: aligned before recovery (--align);
  // 4: a bracket's shots turned as its first says, a deeper photo's clipping judged as stored;
  // 5: a TIFF's ISO read, a capture description's ISO or f-number alone taken; 6: ISO above
  // 65535 read from ISOSpeed, a photo's colour by its bytes' format, a WebP's EXIF and ICC read;
  // 7: a photo's missing ISO or f-number taken from the other photos of its bracket; 8: 8-bit
  // photos made linear in the space of their own primaries (Display P3's, not Rec.709's), the
  // photos' space from --env-space; 9: a deep pixel no shot is trusted at bounded and flagged,
  // ghost suppression's reference agrees with the over-exposed shots; 10: Adobe RGB photos'
  // camera RGB in linear Adobe RGB, a portrait raw photo's orientation known; 11: one recovered
  // tone curve for the three channels
  static constexpr int kVersion = 11;

  std::string name() const override { return "merge"; }
  std::string summary() const override {
    return "merge each view's bracketed exposures to scene-linear radiance (one response curve, "
           "one exposure scale for every view)";
  }
  std::vector<std::string> inputs() const override { return {kCapture}; }
  std::vector<std::string> outputs() const override { return {kMergedViews}; }

  std::string skip(const Context& ctx) const override {
    if (ctx.environmentInput.kind != EnvironmentInput::Kind::Capture)
      return "the environment is an image, not photos: no exposure brackets to merge";
    if (!ctx.environmentInput.bracketed)
      return "every view of the capture is a single exposure: nothing to merge";
    return {};
  }
  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("merge");
    h.word(kVersion);
    h.combine(ctx.key(kCapture));
    h.bytes(ctx.colors.identity());
    h.bytes(ctx.job.environmentSpace);  // the photos' space (--env-space)
    // A camera response stored for this camera is used instead of recovering one.
    const ingest::Capture& capture = *ctx.artefacts.capture;
    const fs::path response =
        hdr::responseFileFor(hdr::responseDirectory(), capture.cameraMake, capture.cameraModel);
    std::error_code ec;
    if (!response.empty() && fs::is_regular_file(response, ec)) hashFile(h, response, "merge");
    ctx.keys[kMergedViews] = h;
  }
  bool cached() const override { return true; }
  bool load(Context& ctx, StageCache& cache) const override {
    const nlohmann::json& meta = cache.meta();
    if (!meta.contains("views") || !meta["views"].is_array()) return false;
    hdr::CaptureMergeResult merged;
    for (size_t i = 0; i < meta["views"].size(); ++i) {
      hdr::MergedView view;
      view.name = meta["views"][i].get<std::string>();
      if (!cache.takeImage("view" + std::to_string(i), view.radiance)) return false;
      merged.views.push_back(std::move(view));
    }
    merged.linearisation = meta.value("linearisation", "");
    ctx.artefacts.mergedViews = std::move(merged);
    return true;
  }
  bool store(const Context& ctx, StageCache& cache) const override {
    const hdr::CaptureMergeResult& merged = *ctx.artefacts.mergedViews;
    nlohmann::json names = nlohmann::json::array();
    for (size_t i = 0; i < merged.views.size(); ++i) {
      names.push_back(merged.views[i].name);
      cache.putImage("view" + std::to_string(i), merged.views[i].radiance);
    }
    cache.meta()["views"] = names;
    cache.meta()["linearisation"] = merged.linearisation;
    return cache.write();
  }

  std::string run(Context& ctx) const override {
    const ingest::Capture& capture = *ctx.artefacts.capture;
    const std::vector<std::vector<ingest::LoadedImage>> photos =
        hdr::readCapturePhotos(capture, ctx.progress);
    for (const ingest::View& v : capture.views)
      for (const ingest::Shot& s : v.shots) requireUnchangedSinceHashed(s.file, "merge");
    size_t total = 0;
    for (const auto& v : capture.views) total += v.shots.size();
    hdr::CaptureMergeOptions options;
    // --env-space says the photos' space, over what the description and the files say.
    options.inputSpace = ctx.job.environmentSpace;
    options.inputSpaceOption = "--env-space";
    hdr::CaptureMergeResult merged =
        hdr::mergeCapture(capture, photos, options, ctx.colors, ctx.progress);
    for (const std::string& n : merged.notes) ctx.note("merge: " + n);
    if (merged.responseRecovered) {
      ctx.note(
          "merge: the camera's response was recovered from these photos (compose merge "
          "keeps it per camera for later captures)");
    }
    std::string reason = "merged " + plural(merged.views.size(), "view") + " from " +
                         plural(total, "photo") + " in " + format("%.2f s", merged.seconds);
    if (!merged.linearisation.empty()) reason += "; " + merged.linearisation;
    ctx.artefacts.mergedViews = std::move(merged);
    return reason;
  }
};

// ---------------------------------------------------------------------------------------------

class StitchStage final : public Stage {
 public:
  // 2: the 35 mm focal length derived where EXIF rounds it; 3: float TIFFs linear, a Radiance
  // header applied, a lens mirrored for EXIF orientations 2, 4, 5 and 7; 4: a wide hole filled
  // from its rim; 5: a photo's colour by its bytes' format, not a name they contradict; 6: the
  // photos' space from --env-space; 7: a portrait raw photo turned by its orientation as read
  static constexpr int kVersion = 7;

  std::string name() const override { return "stitch"; }
  std::string summary() const override {
    return "stitch the capture's views into a lat-long environment (orientations refined by "
           "feature matching)";
  }
  std::vector<std::string> inputs() const override { return {kCapture, kMergedViews}; }
  std::vector<std::string> outputs() const override { return {kStitched}; }

  std::string skip(const Context& ctx) const override {
    if (ctx.environmentInput.kind != EnvironmentInput::Kind::Capture)
      return "one environment image (lat-long, OpenEXR cube, cross or cube faces): nothing to "
             "stitch (a cube is resampled to lat-long on reading)";
    return {};
  }
  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("stitch");
    h.word(kVersion);
    h.combine(ctx.keys.count(kMergedViews) ? ctx.key(kMergedViews) : ctx.key(kCapture));
    h.bytes(ctx.colors.identity());
    h.bytes(ctx.job.environmentSpace);
    ctx.keys[kStitched] = h;
  }
  bool cached() const override { return true; }
  bool load(Context& ctx, StageCache& cache) const override {
    Image image;
    if (!cache.takeImage("environment", image)) return false;
    ctx.artefacts.stitched = std::move(image);
    return true;
  }
  bool store(const Context& ctx, StageCache& cache) const override {
    cache.putImage("environment", *ctx.artefacts.stitched);
    return cache.write();
  }

  std::string run(Context& ctx) const override {
    const ingest::Capture& capture = *ctx.artefacts.capture;
    const hdr::CaptureMergeResult* merged =
        ctx.artefacts.mergedViews ? &*ctx.artefacts.mergedViews : nullptr;
    const std::string working = ctx.colors.workingSpace();
    // A view's radiance in the working space: merged, or its one photo converted.
    auto load = [&](int i) -> Image {
      if (merged) {
        Image rgb = toRgb(merged->views[size_t(i)].radiance);
        rgb.colorSpace = working;
        return rgb;
      }
      const ingest::Shot& shot = capture.views[size_t(i)].shots.front();
      ingest::LoadedImage img = ingest::readImage(shot.file, "stitch", {.codesForEightBit = true});
      requireUnchangedSinceHashed(shot.file, "stitch");
      const std::string space =
          !ctx.job.environmentSpace.empty()
              ? ctx.colors.resolve(ctx.job.environmentSpace, "--env-space")
          : shot.colorSpace.empty()
              ? inputSpaceOf(ctx.colors, shot.file, img.info).space
              : ctx.colors.resolve(shot.colorSpace, "the capture's colorSpace");
      Image rgb;
      if (!img.hasPixels() && img.image.channels >= 3) {
        // An 8-bit photo: linearised from its codes (a table of the 256 codes per channel).
        rgb = ctx.colors.convertCodes(img.codes, img.image.width, img.image.height,
                                      img.image.channels, space, working);
      } else {
        if (img.hasPixels())
          ingest::requireFinite(img.image, shot.file, "stitch", "the photo",
                                ingest::kMaxPhotoValue);
        else
          ingest::floatsFromCodes(img);
        rgb = toRgb(img.image);
        rgb.colorSpace = space;
        ctx.colors.convert(rgb, working);
      }
      // Scaled by the shot's exposure, so that views of unequal exposure agree.
      const float scale = shot.exposure ? float(1.0 / *shot.exposure) : 1.0f;
      for (float& v : rgb.pixels) v *= scale;
      ingest::requireFinite(rgb, shot.file, "stitch", "the photo over its exposure",
                            ingest::kMaxPhotoValue);
      return rgb;
    };

    if (capture.views.size() == 1) {
      Image only = load(0);
      if (only.width != 2 * only.height) {
        throw Error("stitch",
                    "a capture of one view must be a lat-long panorama (2:1); this one is " +
                        std::to_string(only.width) + "x" + std::to_string(only.height) +
                        ": stitching needs several views",
                    ctx.environmentInput.path);
      }
      ctx.artefacts.stitched = std::move(only);
      return "one view, a lat-long panorama: used as it is";
    }

    std::optional<calib::Lens> lensFile;
    if (!capture.lensFile.empty()) lensFile = calib::readLens(capture.lensFile);
    std::vector<cubemap::StitchPhoto> photos;
    bool anyLdr = false;
    for (const ingest::View& v : capture.views) {
      const ingest::Shot& first = v.shots.front();
      const cubemap::PhotoHeader header = cubemap::readPhotoHeader(first.file);
      cubemap::StitchPhoto p;
      p.name = v.name;
      if (v.worldFromCamera) {
        p.worldFromCamera = *v.worldFromCamera;
      } else if (const auto token = cubemap::faceFromName(v.name)) {
        p.worldFromCamera = cubemap::faceCameraRotation(token->face);
      } else if (const std::optional<double> yaw = cubemap::yawFromName(v.name)) {
        p.worldFromCamera = cubemap::cameraRotation(*yaw, 0.0, 0.0);  // a level view of a ring
      } else {
        throw Error("stitch",
                    "cannot tell where view '" + v.name +
                        "' points: give it a worldFromCamera rotation in the capture description "
                        "or name it for a cube face (px, nx, py, ny, pz, nz) or a level view's "
                        "turn (yaw120); compose ingest names views so when their photos' names "
                        "say it (px_1.jpg, yaw120_1.jpg)",
                    ctx.environmentInput.path);
      }
      p.lens = cubemap::photoLens(first.file, header, lensFile);
      if (!merged && !header.floatingPoint) {
        anyLdr = true;
        Image white(1, 1, 3, {"R", "G", "B"});
        white.pixels = {1.0f, 1.0f, 1.0f};
        // In the space the photos are decoded in (load above).
        white.colorSpace =
            !ctx.job.environmentSpace.empty()
                ? ctx.colors.resolve(ctx.job.environmentSpace, "--env-space")
            : first.colorSpace.empty()
                ? ctx.colors
                      .inputSpace(ingest::nameForRules(first.file, header.format), "", false, true)
                      .space
                : first.colorSpace;
        ctx.colors.convert(white, working);
        const float scale = first.exposure ? float(1.0 / *first.exposure) : 1.0f;
        p.saturation =
            0.98f * scale * std::min({white.pixels[0], white.pixels[1], white.pixels[2]});
      }
      photos.push_back(p);
    }
    cubemap::StitchOptions options;
    options.gains = anyLdr;
    double fx = 1e9;
    for (const auto& p : photos) fx = std::min(fx, p.lens.fx);
    options.faceSize = std::clamp(int(std::lround(2.0 * fx / 8.0)) * 8, 64, 2048);
    const cubemap::StitchResult result = cubemap::stitch(photos, load, options, ctx.progress);
    for (const std::string& n : result.notes) ctx.note("stitch: " + n);
    for (const std::string& w : result.warnings) ctx.note("warning: stitch: " + w);
    const lighting::Environment env =
        lighting::latLongFromCube(result.cube, 4 * result.cube.size(), ctx.progress);
    Image image(env.width(), env.height(), 3, {"R", "G", "B"});
    image.pixels.assign(env.texels().begin(), env.texels().end());
    image.colorSpace = working;
    ctx.artefacts.stitched = std::move(image);
    double worst = 0.0;
    for (double c : result.correctionDegrees) worst = std::max(worst, c);
    return format(
        "stitched %zu views into %dx%d faces (orientations corrected by up to %.2f "
        "degrees; %.2f %% of the sphere unseen and filled), as a %dx%d lat-long map",
        photos.size(), result.cube.size(), result.cube.size(), worst,
        100.0 * result.coverage.uncovered, env.width(), env.height());
  }
};

// ---------------------------------------------------------------------------------------------

class ColorStage final : public Stage {
 public:
  std::string name() const override { return "color"; }
  std::string summary() const override {
    return "bring the plate, the environment and the object's materials to the working space "
           "(role scene_linear of the OpenColorIO config)";
  }
  std::vector<std::string> inputs() const override { return {kPlate, kEnvironmentFile, kStitched}; }
  std::vector<std::string> inputsFor(const std::string& output) const override {
    if (output == kPlateLinear) return {kPlate};
    return {kEnvironmentFile, kStitched};
  }
  std::vector<std::string> outputs() const override { return {kPlateLinear, kEnvironment}; }
  std::vector<StageParameter> parameters() const override {
    StageParameter ocio =
        pathParameter("ocio",
                      "the OpenColorIO config file (builtin: the built-in config; empty: $OCIO, "
                      "else the built-in one)",
                      &ComposeJob::ocio);
    ocio.literals = {"builtin", "built-in"};
    return {ocio,
            textParameter("plate-space", "colour space of the plate (empty: from the file)",
                          &ComposeJob::plateSpace),
            textParameter("env-space", "colour space of the environment (empty: from the file)",
                          &ComposeJob::environmentSpace)};
  }

  // 2: 8- and 16-bit images that the config's rules make linear are read as sRGB-encoded;
  // 3: a config's file rule before a format's usual space, three channels by name, primaries of
  // configs without an interchange role by their spaces' names; 4: environments' channels by name
  // in every layout, a Radiance header's EXPOSURE, COLORCORR and PRIMARIES, float TIFFs linear
  // whatever their EXIF ColorSpace says; 5: luminance-chroma decoded with the weights of the file's
  // primaries; 6: a premultiplied picture of codes made straight before it is decoded, a file's
  // colour by its bytes' format, not a name they contradict, a WebP's ICC profile read; 7: of a
  // multi-part OpenEXR the part named as the picture, Nuke's long channel names (rgba.red, alpha);
  // 8: a Radiance picture's mantissas decoded as the format defines them (half a step up);
  // 9: a cube's faces made linear before they are resampled to a lat-long map; 10: Adobe RGB's
  // primaries known exactly (they were taken as adapted to the interchange white)
  static constexpr int kColorVersion = 10;

  void keys(Context& ctx) const override {
    if (ctx.mayNeed(kPlateLinear)) {
      Hash128 plate;
      plate.bytes("plate-linear");
      plate.word(kColorVersion);
      plate.combine(ctx.key(kPlate));
      plate.bytes(ctx.job.plateSpace);
      plate.bytes(ctx.colors.identity());
      ctx.keys[kPlateLinear] = plate;
    }
    if (!ctx.mayNeed(kEnvironment)) return;
    Hash128 env;
    env.bytes("environment");
    env.word(kColorVersion);
    env.combine(ctx.keys.count(kStitched) ? ctx.key(kStitched) : ctx.key(kEnvironmentFile));
    env.bytes(ctx.job.environmentSpace);
    env.bytes(ctx.colors.identity());
    ctx.keys[kEnvironment] = env;
  }

  std::string run(Context& ctx) const override {
    const std::string working = ctx.colors.workingSpace();
    std::string reason;
    if (ctx.needs(kPlateLinear)) {
      // No later stage reads the plate as decoded, only its size and header (the camera): its
      // pixels become the linear plate. An 8-bit RGB plate (a JPEG) is converted from its codes
      // into a new float image; any other RGB plate is converted in place.
      ingest::LoadedImage& plate = *ctx.artefacts.plate;
      // A plate's alpha (the A of its picture's layer, core/channels.h, or a channel named
      // Alpha), kept when it is not 1 everywhere.
      std::vector<float> alpha;
      int alphaChannel = plate.image.channelNames.empty() ? -1 : pictureChannels(plate.image).alpha;
      for (size_t c = 0; c < plate.image.channelNames.size() && alphaChannel < 0; ++c) {
        std::string name = plate.image.channelNames[c];
        std::transform(name.begin(), name.end(), name.begin(),
                       [](unsigned char ch) { return char(std::tolower(ch)); });
        if (c > 0 && (name == "a" || name == "alpha")) alphaChannel = int(c);
      }
      if (alphaChannel > 0 && alphaChannel < plate.image.channels) {
        const size_t n = size_t(plate.image.width) * size_t(plate.image.height);
        const size_t stride = size_t(plate.image.channels), at = size_t(alphaChannel);
        alpha.resize(n);
        bool opaque = true;
        for (size_t i = 0; i < n; ++i) {
          alpha[i] = plate.codes.empty()
                         ? std::clamp(plate.image.pixels[i * stride + at], 0.0f, 1.0f)
                         : float(plate.codes[i * stride + at]) / 255.0f;
          opaque = opaque && alpha[i] == 1.0f;
        }
        if (opaque) alpha.clear();
      }
      const bool windowAlpha = alpha.empty() && plate.info.partlyStored;
      if (windowAlpha) {
        // No alpha, and part of the frame holds no stored pixel (an OpenEXR's data window): no
        // picture there, as Nuke takes it (black, alpha 0), so that the automatic exposure and
        // the composite read the picture only.
        const int w = plate.image.width, h = plate.image.height;
        alpha.assign(size_t(w) * size_t(h), 0.0f);
        for (int y = plate.info.storedY0; y < std::min(plate.info.storedY1, h); ++y)
          for (int x = plate.info.storedX0; x < std::min(plate.info.storedX1, w); ++x)
            alpha[size_t(y) * size_t(w) + size_t(x)] = 1.0f;
      }
      // A premultiplied picture of codes (a TIFF whose alpha is associated, as oiiotool and Nuke
      // write it) holds colour x alpha in its encoding: made straight before it is decoded, and
      // premultiplied again in linear light (decoding the product darkened half-covered pixels
      // 2.2 times), as OpenImageIO's colorconvert and Nuke do.
      const bool encodedPremultiplied = !alpha.empty() && !windowAlpha &&
                                        !plate.info.unassociatedAlpha &&
                                        plate.info.integerSamples();
      if (encodedPremultiplied && !plate.codes.empty()) ingest::floatsFromCodes(plate);
      Image linear;
      if (!plate.codes.empty() && plate.image.channels >= 3 && !plate.info.chromaticities) {
        const bool named = !ctx.job.plateSpace.empty();
        const color::InputSpace space =
            named ? color::InputSpace{ctx.colors.resolve(ctx.job.plateSpace, "--plate-space"),
                                      "--plate-space"}
                  : inputSpaceOf(ctx.colors, ctx.job.plate, plate.info);
        linear = ctx.colors.convertCodes(plate.codes, plate.image.width, plate.image.height,
                                         plate.image.channels, space.space, working);
        plate.codes = {};
        reason = "plate read as '" + space.space + "' (" + space.how + ")";
        if (space.assumed) {
          ctx.note("the plate " + ctx.job.plate.filename().string() + " is read as '" +
                   space.space + "' (" + space.how + "); give --plate-space to say which it is");
        }
      } else {
        if (!plate.codes.empty())
          ingest::floatsFromCodes(plate);
        else
          ingest::requireFinite(plate.image, ctx.job.plate, "ingest", "the plate");
        const PictureChannels picture = pictureChannels(plate.image);
        const bool inOrder = picture.kind == PictureChannels::Kind::ByPosition ||
                             (picture.kind == PictureChannels::Kind::Rgb &&
                              picture.colour == std::vector<int>{0, 1, 2});
        if (plate.image.channels == 3 && inOrder) {
          linear = std::move(plate.image);
          plate.image.pixels = {};
          plate.image.width = linear.width;
          plate.image.height = linear.height;
          plate.image.channels = linear.channels;
        } else {
          linear = toRgb(plate.image);
        }
        if (encodedPremultiplied) {
          // Where alpha is 0 the colour is light added over what is behind (a glow): kept as it
          // is, and not multiplied by the alpha below, as OpenImageIO's colorconvert keeps it.
          parallelFor(0, linear.height, [&](int64_t y) {
            for (int x = 0; x < linear.width; ++x) {
              const float a = alpha[size_t(y) * size_t(linear.width) + size_t(x)];
              if (a <= 0.0f) continue;
              float* c = linear.at(x, int(y));
              for (int k = 0; k < 3; ++k) c[k] /= a;
            }
          });
        }
        reason = "plate read as " + toWorkingSpace(linear, ctx.job.plate, plate.info,
                                                   ctx.job.plateSpace, "--plate-space", ctx.colors);
        if (ctx.job.plateSpace.empty() && !plate.info.chromaticities) {
          // As the codes' branch says it: a space guessed is a note, not only a stage record.
          const color::InputSpace space = inputSpaceOf(ctx.colors, ctx.job.plate, plate.info);
          if (space.assumed)
            ctx.note("the plate " + ctx.job.plate.filename().string() + " is read as '" +
                     space.space + "' (" + space.how + "); give --plate-space to say which it is");
        }
      }
      if (!alpha.empty()) {
        // Premultiplied in linear light, as the composite works: a PNG's or TIFF's unassociated
        // colour times its alpha; an OpenEXR's colour is premultiplied already.
        const bool straight = plate.info.unassociatedAlpha || encodedPremultiplied;
        Image rgba(linear.width, linear.height, 4, {"R", "G", "B", "A"});
        rgba.colorSpace = linear.colorSpace;
        parallelFor(0, linear.height, [&](int64_t y) {
          for (int x = 0; x < linear.width; ++x) {
            const size_t i = size_t(y) * size_t(linear.width) + size_t(x);
            const float* c = linear.at(x, int(y));
            float* o = rgba.at(x, int(y));
            const float k =
                !straight || (encodedPremultiplied && alpha[i] <= 0.0f) ? 1.0f : alpha[i];
            o[0] = c[0] * k;
            o[1] = c[1] * k;
            o[2] = c[2] * k;
            o[3] = alpha[i];
          }
        });
        linear = std::move(rgba);
        ctx.note("the plate " + ctx.job.plate.filename().string() +
                 (windowAlpha
                      ? std::string(" has no pixels stored outside its data window: no picture "
                                    "there (alpha 0)")
                      : " has an alpha channel (" +
                            std::string(encodedPremultiplied
                                            ? "premultiplied in its encoding: made straight, "
                                              "decoded and premultiplied in linear light"
                                        : straight ? "unassociated: premultiplied in linear light"
                                                   : "premultiplied") +
                            ")") +
                 ": the composite keeps it (the object over the plate, alpha = the object's + (1 "
                 "- the object's) x the plate's); a PNG display image keeps it, a JPEG shows it "
                 "over black");
      }
      ctx.artefacts.plateLinear = std::move(linear);
    }
    if (ctx.needs(kEnvironment)) {
      if (ctx.artefacts.stitched) {
        ctx.artefacts.environment = std::move(*ctx.artefacts.stitched);
        ctx.artefacts.stitched.reset();
        reason += std::string(reason.empty() ? "" : ", ") +
                  "environment merged and stitched in the working space";
      } else {
        const cubemap::LoadedEnvironment& env = *ctx.artefacts.environmentFile;
        Image linear = toRgb(env.image);
        reason += std::string(reason.empty() ? "" : ", ") + "environment as " +
                  (!env.linearised.empty()
                       ? env.linearised +
                             ", its faces brought to the working space before they were "
                             "resampled"
                       : toWorkingSpace(linear, env.file, env.info, ctx.job.environmentSpace,
                                        "--env-space", ctx.colors));
        ctx.artefacts.environment = std::move(linear);
        ctx.artefacts.environmentFile.reset();
      }
    }
    if (ctx.artefacts.mesh) {
      render::Mesh& mesh = *ctx.artefacts.mesh;
      if (ctx.job.albedo && mesh.hasMaterials()) {
        ctx.note("object: --albedo replaces the materials of the mesh");
      } else if (const std::string read = materialsToWorkingSpace(mesh, ctx.colors);
                 !read.empty()) {
        ctx.note(read);
      }
    }
    return reason + "; working space '" + working + "' (config: " + ctx.colors.source() + ")";
  }
};

}  // namespace

// Brings an input image to the working space and says how it was read. An explicit colour space
// (--plate-space, --env-space) wins; an OpenEXR file that carries chromaticities is taken by
// them (as the colour space of the config with those primaries, or converted by matrix);
// otherwise the space the file declares, else the config's file rules.
std::string toWorkingSpace(Image& image, const std::filesystem::path& file,
                           const ingest::CaptureInfo& info, const std::string& explicitSpace,
                           const std::string& option, const color::ColorConfig& colors) {
  const std::string working = colors.workingSpace();
  if (!explicitSpace.empty()) {
    const std::string space = colors.resolve(explicitSpace, option);
    image.colorSpace = space;
    colors.convert(image, working);  // the image's space is then the working space
    return "'" + space + "' (" + option + ")";
  }
  if (info.chromaticities) {
    color::requireRgbSpace(*info.chromaticities, file);
    const std::string named = colors.spaceWithChromaticities(*info.chromaticities);
    if (!named.empty()) {
      image.colorSpace = named;
      colors.convert(image, working);
      return "'" + named + "' (by the chromaticities in its header)";
    }
    if (!colors.chromaticities(working)) {
      const auto& c = *info.chromaticities;
      char primaries[160];
      std::snprintf(primaries, sizeof primaries,
                    "red %.4g,%.4g green %.4g,%.4g blue %.4g,%.4g white %.4g,%.4g", c[0], c[1],
                    c[2], c[3], c[4], c[5], c[6], c[7]);
      throw Error("color",
                  "its header's chromaticities (" + std::string(primaries) +
                      ") are those of no colour space of the config (" + colors.source() +
                      "), which says no primaries to convert them by (it has no aces_interchange "
                      "or cie_xyz_d65_interchange role): give " +
                      option + " to say its space",
                  file);
    }
    colors.convertFromChromaticities(image, *info.chromaticities, working, file);
    return "the RGB space of the chromaticities in its header (converted by matrix)";
  }
  const color::InputSpace space = inputSpaceOf(colors, file, info);
  image.colorSpace = space.space;
  colors.convert(image, working);
  return "'" + space.space + "' (" + space.how +
         (space.assumed ? "; give " + option + " to say which it is" : std::string()) + ")";
}

color::InputSpace inputSpaceOf(const color::ColorConfig& colors, const std::filesystem::path& file,
                               const ingest::CaptureInfo& info) {
  return color::photoInputSpace(colors, ingest::nameForRules(file, info.format),
                                info.fileColorSpace, info.colorSpaceByConvention,
                                info.integerSamples(), info.iccProfile, info.exifUncalibrated);
}

std::unique_ptr<Stage> makeIngestStage() {
  return std::make_unique<IngestStage>();
}
std::unique_ptr<Stage> makeMergeStage() {
  return std::make_unique<MergeStage>();
}
std::unique_ptr<Stage> makeStitchStage() {
  return std::make_unique<StitchStage>();
}
std::unique_ptr<Stage> makeColorStage() {
  return std::make_unique<ColorStage>();
}

}  // namespace compose::pipeline
