// The stages that make the picture: render (the object and its AOVs), composite (the plate
// darkened by the ground shadow, the object over it, the holdout in front), output (the files).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <future>
#include <limits>
#include <numbers>
#include <optional>

#include <glm/gtc/matrix_transform.hpp>
#include <glm/vector_relational.hpp>

#include "composite/composite.h"
#include "core/error.h"
#include "core/json_number.h"
#include "core/numbers.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "ingest/exr_io.h"
#include "ingest/image_io.h"
#include "pipeline/context.h"
#include "pipeline/stage.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_util.h"
#include "pipeline/stages.h"

namespace compose::pipeline {

namespace fs = std::filesystem;
using namespace artefact;

namespace {

// Automatic exposure: a mid-grey card lying on the ground, lit by the environment, should look as
// bright in the composite as the plate's ground looks in the plate. The plate's middle grey is
// the log-average of its ground, the pixels whose rays look below the horizon, where the object
// stands and which the same light falls on (the key that a camera's reflected-light meter exposes
// for, without the sky that would pull it up: a bright overcast sky put the object a stop too
// bright); of the whole plate when almost none of it does. The card faces up: its radiance,
// 0.18 E(up)/π, does not change when the environment turns about the vertical, as the plate's
// exposure does not, so that a backlit object is darker than a front-lit one, as in a photograph
// (a ball facing the camera, before, raised the exposure of a backlit object by 3 stops and
// cancelled the turn).
struct ExposureMatch {
  double scale = 1.0;         // plate units per environment unit
  double plateKey = 0.0;      // log-average of the plate's luminance (of its ground)
  double groundShare = 0.0;   // of the plate's pixels, the share whose rays look below the horizon
  bool wholePlate = false;    // too little ground in view: the key is the whole plate's
  bool blackGround = false;   // the ground in view is black: the key is the whole plate's
  bool black = false;         // the whole plate is black: the key is the floor
  double cardRadiance = 0.0;  // 0.18 × E(up)/π (environment units)
  bool nothingVisible = false;  // every pixel of the plate transparent: no key, scale 1
};

// The card's radiance, 0.18 E(up)/π, as luminance (environment units): the unshadowed irradiance
// from above.
double cardRadiance(const lighting::DiffuseLighting& lighting, const glm::mat3& envFromWorld,
                    const glm::dvec3& luma) {
  const glm::vec3 e =
      glm::max(lighting.irradiance(envFromWorld * glm::vec3(0.0f, 1.0f, 0.0f)), glm::vec3(0.0f));
  return 0.18 * (luma.x * e.x + luma.y * e.y + luma.z * e.z) / std::numbers::pi;
}

ExposureMatch autoExposure(const Image& plateLinear, const calib::PlateCamera& camera,
                           double cardRadiance, const glm::dvec3& luma) {
  ExposureMatch m;
  // Plate: log-average over an even spread of pixels, of those whose camera ray looks down by
  // more than a degree (the ground is y = 0: rows are not the horizon for a rolled camera or a
  // distorting lens), unless fewer than 1 % do. Black pixels (a letterbox, a code 0) say nothing
  // of the scene's level and are left out; the others are floored at 1e-4 of the median, so
  // that a few near-black ones do not rule the average, whatever the plate's units (a floor of
  // 1e-4 itself was the level of a dim float plate: 2.9 stops off at 1e-4 of the usual units).
  constexpr double kFloor = 1e-4;
  const double below = -std::sin(std::numbers::pi / 180.0);
  const double sx = double(camera.width) / plateLinear.width,
               sy = double(camera.height) / plateLinear.height;
  const int step = std::max(1, int(std::sqrt(double(plateLinear.pixelCount()) / 65536.0)));
  struct Sample {
    double luminance;
    bool ground;
  };
  std::vector<Sample> samples;
  int64_t visible[2] = {0, 0};  // the whole plate, its ground
  for (int y = step / 2; y < plateLinear.height; y += step) {
    for (int x = step / 2; x < plateLinear.width; x += step) {
      glm::dvec3 origin, direction;
      const bool ground =
          camera.ray((x + 0.5) * sx, (y + 0.5) * sy, origin, direction) && direction.y < below;
      const float* p = plateLinear.at(x, y);
      // A plate with alpha: its visible pixels, their colour unpremultiplied.
      const double a = plateLinear.channels == 4 ? double(p[3]) : 1.0;
      if (!(a >= 0.01)) continue;
      ++visible[0];
      if (ground) ++visible[1];
      const double l = (luma.x * p[0] + luma.y * p[1] + luma.z * p[2]) / a;
      if (l > 0.0) samples.push_back({l, ground});
    }
  }
  if (visible[0] == 0) {
    m.nothingVisible = true;
    return m;
  }
  double floor = kFloor;  // a plate black wherever it is seen: matched to that floor
  if (!samples.empty()) {
    std::vector<double> levels(samples.size());
    for (size_t i = 0; i < samples.size(); ++i) levels[i] = samples[i].luminance;
    std::nth_element(levels.begin(), levels.begin() + ptrdiff_t(levels.size() / 2), levels.end());
    floor = kFloor * levels[levels.size() / 2];
  }
  double logSum[2] = {0.0, 0.0};
  int64_t count[2] = {0, 0};
  for (const Sample& s : samples) {
    const double v = std::log(std::max(floor, s.luminance));
    logSum[0] += v;
    ++count[0];
    if (s.ground) logSum[1] += v, ++count[1];
  }
  int use = visible[1] > 0 && visible[1] >= visible[0] / 100 ? 1 : 0;
  // A ground with no light to match (a letterbox bar across it, black codes): the whole plate's
  // level, and the note says why. (Matched to the floor there, the object was 12 stops dark.)
  m.blackGround = use == 1 && count[1] == 0;
  if (m.blackGround) use = 0;
  m.black = count[use] == 0;
  m.plateKey = m.black ? floor : std::exp(logSum[use] / double(count[use]));
  m.groundShare = double(visible[1]) / double(visible[0]);
  m.wholePlate = use == 0 && !m.blackGround;
  m.cardRadiance = cardRadiance;
  if (m.cardRadiance > 0.0 && m.plateKey > 0.0) m.scale = m.plateKey / m.cardRadiance;
  return m;
}

// Exposure from EXIF: when the environment was merged from 8-bit photos whose exposures are their
// EXIF ones (t · ISO / N²) — a capture description, or a map the photo stages wrote and marked
// (compose:exposureUnit, ingest::kExifExposureUnit) — and the plate is an 8-bit photo of the same
// camera (EXIF Make and Model) with its own exposure in EXIF, the merged radiance is in the
// plate's units at relative exposure 1 (hdr/capture_merge.h, Units): the plate's relative
// exposure is the scale. Empty, with the reason in `why`, when any of that does not hold.
std::optional<double> exifExposure(const Context& ctx, std::string& why) {
  const ingest::CaptureInfo& plate = ctx.artefacts.plate->info;
  const std::optional<double> e = plate.relativeExposure();
  const bool plateReady = e && plate.exposureAssumptions().empty() && plate.bitsPerSample == 8;
  const EnvironmentExif env = ctx.environmentExif ? *ctx.environmentExif : environmentExif(ctx);
  if (env.camera.empty()) {
    why = env.whyNot;
    return std::nullopt;
  }
  if (plate.camera().empty() || plate.camera() != env.camera) {
    why = "the plate's camera (" + (plate.camera().empty() ? "not in EXIF" : plate.camera()) +
          ") is not " + env.whose + " (" + env.camera + ")";
    return std::nullopt;
  }
  if (!plateReady) {
    why = "the plate is not an 8-bit photo with its exposure time, f-number and ISO in EXIF";
    return std::nullopt;
  }
  return *e;
}

// A warning when the display image shows more than 2 % of the object's pixels as clipped white
// (their shading is lost).
std::optional<std::string> clippedObjectNote(const render::RenderOutput& rendered,
                                             const Image& shown, const fs::path& displayPath,
                                             const std::string& view, bool fromLayer) {
  const Image& beauty = rendered.beauty;
  // Within half a code of the top two 8-bit codes: a view that rolls highlights off (Soft Clip)
  // approaches white without reaching it, and its last codes hold no shading any more.
  constexpr float kWhite = 253.5f / 255.0f;
  std::vector<int64_t> covered(size_t(beauty.height), 0), clipped(size_t(beauty.height), 0);
  parallelFor(0, beauty.height, [&](int64_t y) {
    for (int x = 0; x < beauty.width; ++x) {
      if (beauty.at(x, int(y))[3] < 0.5f) continue;
      ++covered[size_t(y)];
      const float* d = shown.at(x + rendered.x0, int(y) + rendered.y0);
      if (std::max({d[0], d[1], d[2]}) >= kWhite) ++clipped[size_t(y)];
    }
  });
  int64_t allCovered = 0, allClipped = 0;
  for (size_t y = 0; y < covered.size(); ++y) {
    allCovered += covered[y];
    allClipped += clipped[y];
  }
  constexpr double kClippedShare = 0.02;
  if (allCovered == 0 || double(allClipped) <= kClippedShare * double(allCovered))
    return std::nullopt;
  return format(
      "warning: %.1f%% of the object's pixels are clipped to white in %s (view %s): %s to keep "
      "their shading%s",
      100.0 * double(allClipped) / double(allCovered), displayPath.filename().string().c_str(),
      view.c_str(),
      // A layer's exposure is in its values: compose composite has no --exposure.
      fromLayer ? "render the layer again with a lower --exposure (compose render)"
                : "lower --exposure",
      view == "Standard" ? ", or --view 'Soft Clip' to roll the highlights off (the plate's "
                           "brightest levels with them)"
                         : "");
}

glm::dvec2 pairOf(const nlohmann::json& v, const std::string& name) {
  if (!v.is_array() || v.size() != 2 || !v[0].is_number() || !v[1].is_number())
    throw UsageError(name + " must be two numbers: [X, Y] in a scene file, X,Y after --set");
  return {v[0].get<double>(), v[1].get<double>()};
}

// ---------------------------------------------------------------------------------------------

class RenderStage final : public Stage {
 public:
  // 3: samples in one surface cell shaded once; 4: the exposure from EXIF for maps the photo
  // stages marked; 5: the automatic exposure matches luminance, with the ball at the object's
  // middle; 6: the plate's key is taken below the horizon; 7: matched by a card on the ground;
  // 9: adaptive sampling; 10: sources no surface point sees kept out of the shadow ratio;
  // 11: sources traced across their penumbrae; 12: textures filtered over each sample's footprint;
  // 13: sources traced from the smooth surface of the vertex normals; 14: that lift bounded and
  // checked for parts in the way; 15: kept in the environment's units, the exposure applied by
  // the composite and the files; 16: the automatic exposure kept whichever is used; 17: the
  // card's radiance kept instead, the composite choosing the exposure for its plate; 18: a
  // material's factor x texture x vertex colour multiplied in their own space, then converted;
  // 19: an OBJ's Kd x map_Kd multiplied in linear Rec.709 when its textures have those primaries;
  // 20: a fisheye's depth along the ray
  static constexpr int kVersion = 20;

  std::string name() const override { return "render"; }
  std::string summary() const override {
    return "ray-cast the object through the plate's lens, shaded by the lighting (and its "
           "self-shadowing), with AOVs";
  }
  std::vector<std::string> inputs() const override {
    // The linear plate for the colour stage, which brings the mesh's materials into the working
    // space (base colours, textures and their mip levels) as it makes it: the render reads the
    // materials, not the plate's pixels, and its key does not hold the linear plate.
    return {kPlate, kMesh, kPlateLinear, kLighting, kSelfShadowing};
  }
  std::vector<std::string> outputs() const override { return {kObject}; }
  std::vector<StageParameter> parameters() const override {
    return {{"place", "image point [X, Y] in [0, 1] where the object stands",
             [](const ComposeJob& j) {
               return nlohmann::json({j.placement.imagePoint.x, j.placement.imagePoint.y});
             },
             [](ComposeJob& j, const nlohmann::json& v) {
               j.placement.imagePoint = pairOf(v, "place");
             }},
            {"scale", "object height as a fraction of the plate height",
             [](const ComposeJob& j) { return nlohmann::json(j.placement.heightFraction); },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (!v.is_number()) throw UsageError("scale must be a number");
               j.placement.heightFraction = v.get<double>();
             }},
            {"yaw", "turn of the object about the vertical, degrees",
             [](const ComposeJob& j) { return nlohmann::json(j.placement.yawDegrees); },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (!v.is_number()) throw UsageError("yaw must be a number of degrees");
               j.placement.yawDegrees = v.get<double>();
             }},
            {"focal35", "35 mm equivalent focal length of the plate, or null (EXIF, else 50)",
             [](const ComposeJob& j) {
               return j.camera.focal35mm ? nlohmann::json(*j.camera.focal35mm)
                                         : nlohmann::json(nullptr);
             },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (v.is_null()) return j.camera.focal35mm.reset();
               if (!v.is_number()) throw UsageError("focal35 must be a number of millimetres");
               j.camera.focal35mm = v.get<double>();
             }},
            {"camera-height", "camera height above the ground, metres",
             [](const ComposeJob& j) { return nlohmann::json(j.camera.height); },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (!v.is_number()) throw UsageError("camera-height must be a number of metres");
               j.camera.height = v.get<double>();
             }},
            {"pitch", "camera tilt down, degrees",
             [](const ComposeJob& j) { return nlohmann::json(j.camera.pitchDegrees); },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (!v.is_number()) throw UsageError("pitch must be a number of degrees");
               j.camera.pitchDegrees = v.get<double>();
             }},
            pathParameter("calib", "lens calibration of the plate's camera (compose calib lens)",
                          &ComposeJob::lensFile),
            pathParameter("pose",
                          "plate pose over a chessboard (compose calib pose): its plane is the "
                          "ground",
                          &ComposeJob::poseFile),
            {"albedo",
             "[R, G, B] albedo in the working space for the whole object, or null (the "
             "mesh's materials, else clay grey)",
             [](const ComposeJob& j) {
               return j.albedo ? nlohmann::json({j.albedo->x, j.albedo->y, j.albedo->z})
                               : nlohmann::json(nullptr);
             },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (v.is_null()) return j.albedo.reset();
               if (v.is_number()) {
                 j.albedo = glm::vec3(v.get<float>());
                 return;
               }
               if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() ||
                   !v[2].is_number())
                 throw UsageError("albedo must be a number or [R, G, B]");
               j.albedo = glm::vec3(v[0].get<float>(), v[1].get<float>(), v[2].get<float>());
             }},
            {"exposure", "exposure of the object in stops, or \"auto\"",
             [](const ComposeJob& j) {
               return j.exposureStops ? nlohmann::json(*j.exposureStops) : nlohmann::json("auto");
             },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (v == "auto") return j.exposureStops.reset();
               if (!v.is_number())
                 throw UsageError("exposure must be a number of stops or \"auto\"");
               j.exposureStops = v.get<double>();
             }},
            {"samples", "anti-aliasing: N x N samples per pixel",
             [](const ComposeJob& j) { return nlohmann::json(j.samplesPerAxis); },
             [](ComposeJob& j, const nlohmann::json& v) {
               const std::optional<int64_t> n = wholeNumber(v);
               if (!n) throw UsageError("samples must be a whole number");
               j.samplesPerAxis = int(*n);
             }},
            {"sampling",
             "\"adaptive\" (plain pixels from their four corner samples) or \"full\" (every "
             "pixel from all N x N)",
             [](const ComposeJob& j) {
               return nlohmann::json(j.adaptiveSampling ? "adaptive" : "full");
             },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (v != "adaptive" && v != "full")
                 throw UsageError("sampling must be \"adaptive\" or \"full\"");
               j.adaptiveSampling = v == "adaptive";
             }}};
  }

  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("object");
    h.word(kVersion);
    h.combine(ctx.geometryKey());
    h.combine(ctx.key(kLighting));
    // The render is kept in the environment's units and the exposure chosen and applied by the
    // composite: neither the exposure nor the plate's pixels are part of its key.
    if (ctx.hasKey(kSelfShadowing)) h.combine(ctx.key(kSelfShadowing));
    h.bytes(ctx.colors.identity());  // the materials' colours
    if (ctx.job.albedo) h.floats(std::span<const float>(&ctx.job.albedo->x, 3));
    h.word(uint32_t(ctx.job.samplesPerAxis));
    h.word(ctx.job.adaptiveSampling ? 1u : 0u);
    ctx.keys[kObject] = h;
  }
  bool cached() const override { return true; }
  // Its outputs are only read once made (by the composite and the output stages), but for the
  // exposure chosen by the composite (RenderedObject::exposure, pending, notes, exposureChosen),
  // which store() does not read.
  bool storesWhileLaterStagesRun() const override { return true; }
  bool load(Context& ctx, StageCache& cache) const override {
    const nlohmann::json& m = cache.meta();
    const auto x0 = wholeMember(m, "x0"), y0 = wholeMember(m, "y0"), x1 = wholeMember(m, "x1"),
               y1 = wholeMember(m, "y1");
    if (!x0 || !y0 || !x1 || !y1) return false;
    RenderedObject r;
    r.output.x0 = int(*x0);
    r.output.y0 = int(*y0);
    r.output.x1 = int(*x1);
    r.output.y1 = int(*y1);
    r.output.rays =
        wholeMember(m, "rays", 0, std::numeric_limits<int64_t>::max()).value_or(int64_t(0));
    r.output.coverage = m.value("coverage", 0.0);
    const auto card = m.find("cardRadiance");
    if (card == m.end() || !card->is_number()) return false;
    r.cardRadiance = card->get<double>();
    if (!cache.takeImage("beauty", r.output.beauty) || !cache.takeImage("aovs", r.output.aovs))
      return false;
    // The rectangle and the images it holds agree (the composite places them by it).
    const int w = r.output.x1 - r.output.x0, h = r.output.y1 - r.output.y0;
    if (r.output.x0 < 0 || r.output.y0 < 0 || r.output.beauty.width != w ||
        r.output.beauty.height != h || r.output.beauty.channels != 4 || r.output.aovs.width != w ||
        r.output.aovs.height != h)
      return false;
    // The mesh of this job: the entry is keyed by the mesh's content, and may have been made
    // from a copy of it elsewhere (the header names the file that was given).
    r.meshFile = fs::absolute(ctx.job.object).string();
    if (const auto o = m.find("fileOrigin"); o != m.end() && o->is_array() && o->size() == 3)
      r.fileOrigin = {(*o)[0].get<double>(), (*o)[1].get<double>(), (*o)[2].get<double>()};
    ctx.artefacts.object = std::move(r);
    return true;
  }
  bool store(const Context& ctx, StageCache& cache) const override {
    const RenderedObject& r = *ctx.artefacts.object;
    cache.meta().update({{"x0", r.output.x0},
                         {"y0", r.output.y0},
                         {"x1", r.output.x1},
                         {"y1", r.output.y1},
                         {"rays", r.output.rays},
                         {"coverage", r.output.coverage},
                         {"cardRadiance", r.cardRadiance},
                         {"mesh", r.meshFile},
                         {"fileOrigin", {r.fileOrigin.x, r.fileOrigin.y, r.fileOrigin.z}}});
    cache.putImage("beauty", r.output.beauty);
    cache.putImage("aovs", r.output.aovs);
    return cache.write();
  }

  std::string run(Context& ctx) const override {
    const ComposeJob& job = ctx.job;
    const Geometry& g = ctx.geometry();
    render::RenderSettings settings;
    settings.samplesPerAxis = job.samplesPerAxis;
    settings.adaptive = job.adaptiveSampling;
    settings.albedo = job.albedo.value_or(glm::vec3(render::kDefaultAlbedo));
    settings.overrideMaterials = job.albedo.has_value();
    settings.envFromWorld = g.envFromWorld;
    if (ctx.artefacts.selfShadowing) {
      const ShadowResult& s = *ctx.artefacts.selfShadowing;
      settings.points = &s.points;
      settings.shadows = &s.irradiance;
      settings.occlusion = &s.occlusion;
      settings.sources = &s.sources;
    }
    RenderedObject r;
    // Rendered in the environment's units: the exposure is chosen for the plate the render is
    // composited on (chooseExposure) and applied by the composite and the files.
    settings.exposure = 1.0f;
    r.cardRadiance = cardRadiance(*ctx.artefacts.lighting, settings.envFromWorld,
                                  ctx.colors.lumaWeights(ctx.colors.workingSpace()));
    // A camera inside the object sees its inside only (a frame of back faces, near black): seven
    // rays from the camera, most of which meet the object from within, say so.
    {
      glm::dvec3 origin, dir;
      if (g.camera.ray(0.5 * g.camera.width, 0.5 * g.camera.height, origin, dir)) {
        const glm::dmat4 objectFromWorld = glm::inverse(g.worldFromObject);
        const glm::vec3 from = glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(origin, 1.0)));
        const glm::vec3 centre = 0.5f * (ctx.mesh().boundsMin() + ctx.mesh().boundsMax());
        const glm::vec3 toCentre = centre - from;
        std::vector<glm::vec3> directions = {{1, 0, 0},  {-1, 0, 0}, {0, 1, 0},
                                             {0, -1, 0}, {0, 0, 1},  {0, 0, -1}};
        if (glm::length(toCentre) > 0.0f) directions.push_back(glm::normalize(toCentre));
        // The mesh's own normals say which side is out (the winding may not).
        const render::Mesh& mesh = ctx.mesh();
        int inside = 0;
        for (const glm::vec3& d : directions) {
          const render::EmbreeScene::Hit hit = ctx.objectScene().intersect(from, d);
          if (!hit.found) continue;
          const uint32_t* c = &mesh.indices[3 * size_t(hit.triangle)];
          const glm::vec3 n = (1.0f - hit.u - hit.v) * mesh.normals[c[0]] +
                              hit.u * mesh.normals[c[1]] + hit.v * mesh.normals[c[2]];
          inside += glm::dot(n, d) > 0.0f;
        }
        if (inside * 2 > int(directions.size())) {
          ctx.note(
              format("warning: the camera is inside the object (%d of %zu rays from it meet "
                     "the object from within): the frame shows its inside; a smaller --scale "
                     "(%s of the plate height now) or a --place higher in the frame (further away)",
                     inside, directions.size(), givenText(job.placement.heightFraction).c_str()));
        }
      }
    }
    r.meshFile = fs::absolute(job.object).string();
    r.fileOrigin = ctx.mesh().fileOrigin;
    const auto start = std::chrono::steady_clock::now();
    r.output = render::renderDiffuse(ctx.mesh(), ctx.objectScene(), g.worldFromObject, g.camera,
                                     *ctx.artefacts.lighting, settings, ctx.progress);
    r.output.beauty.colorSpace = ctx.colors.workingSpace();
    // With a pose too the object's base stands where --place says, in the frame: covering no
    // pixel, it is too small (this blamed the pose file: "the pose of another photo?").
    if (!(r.output.coverage > 0.0) && ctx.meshSummary && ctx.meshSummary->nothingKept) {
      // No placement would show it: say what cuts it away.
      std::string cut;
      for (const render::Material& m : ctx.mesh().materials) {
        if (!m.cutOut()) continue;
        const std::string alpha = format("alpha %.3g%s", double(m.baseAlpha),
                                         m.texture >= 0 ? " times its texture's" : "");
        cut += (cut.empty() ? "" : ", ") +
               (m.blend ? format("'%s' (BLEND, %s)", m.name.c_str(), alpha.c_str())
                        : format("'%s' (MASK, %s, cutoff %.3g)", m.name.c_str(), alpha.c_str(),
                                 double(m.alphaCutoff)));
      }
      throw Error("render",
                  "the object's see-through materials take every surface of it away, so nothing "
                  "is drawn: a MASK material's alpha is below its alphaCutoff everywhere, a BLEND "
                  "material's 0 (" +
                      cut + ")",
                  job.object);
    }
    if (!(r.output.coverage > 0.0)) {
      // So large that the camera stands within its bounds (under the monkey's chin at --scale
      // 9): smaller, not larger.
      bool cameraWithin = false;
      if (ctx.meshSummary) {
        const glm::dvec3 c =
            glm::dvec3(glm::inverse(g.worldFromObject) * glm::dvec4(g.camera.position(), 1.0));
        const glm::dvec3 lo(ctx.meshSummary->boundsMin), hi(ctx.meshSummary->boundsMax);
        cameraWithin =
            glm::all(glm::greaterThanEqual(c, lo)) && glm::all(glm::lessThanEqual(c, hi));
      }
      throw Error("render",
                  "the object covers no pixel of the plate (--scale " +
                      givenText(job.placement.heightFraction) + " of the plate height at " +
                      "--place " + givenText(job.placement.imagePoint.x) + "," +
                      givenText(job.placement.imagePoint.y) +
                      (cameraWithin ? "): the camera stands within its bounds, between its parts; "
                                      "make it smaller or place it further away (higher in the "
                                      "frame)"
                                    : "): make it larger or place it inside the frame"),
                  job.object);
    }
    std::string sampling;
    if (r.output.pixelsPlain > 0) {
      sampling = format(" (%.0f %% of the traced pixels plain, shaded from their 4 corner samples)",
                        100.0 * double(r.output.pixelsPlain) /
                            double(std::max<int64_t>(1, r.output.pixelsTraced)));
    }
    const std::string reason =
        format("%dx%d pixels at %d x %d samples%s: %lld rays in %.2f s", r.output.x1 - r.output.x0,
               r.output.y1 - r.output.y0, job.samplesPerAxis, job.samplesPerAxis, sampling.c_str(),
               static_cast<long long>(r.output.rays), secondsSince(start));
    ctx.artefacts.object = std::move(r);
    return reason;
  }
};

// ---------------------------------------------------------------------------------------------

class CompositeStage final : public Stage {
 public:
  std::string name() const override { return "composite"; }
  std::string summary() const override {
    return "the plate times the ground shadow's ratio, the object over it (premultiplied, in "
           "scene-linear light), the holdout's plate in front";
  }
  std::vector<std::string> inputs() const override {
    return {kPlateLinear, kObject, kGroundShadow};
  }
  std::vector<std::string> outputs() const override { return {kComposite}; }
  std::vector<StageParameter> parameters() const override {
    return {pathParameter("holdout",
                          "holdout mask, the plate's size: white where the plate is in front of "
                          "the object",
                          &ComposeJob::holdout)};
  }
  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("composite");
    h.combine(ctx.key(kPlateLinear));
    h.combine(ctx.key(kObject));
    h.number(ctx.job.exposureStops.value_or(1e300));  // applied here to the render
    if (ctx.hasKey(kGroundShadow)) h.combine(ctx.key(kGroundShadow));
    if (!ctx.job.holdout.empty()) hashFile(h, ctx.job.holdout, "composite");
    ctx.keys[kComposite] = h;
  }
  std::string run(Context& ctx) const override {
    RenderedObject& object = *ctx.artefacts.object;
    if (!object.exposureChosen) chooseExposure(ctx, object);
    {
      const Image& plate = *ctx.artefacts.plateLinear;
      const calib::PlateCamera& camera = ctx.geometry().camera;
      if (camera.width != plate.width || camera.height != plate.height) {
        throw Error("composite",
                    format("the object was rendered for a %dx%d plate; this plate is %dx%d",
                           camera.width, camera.height, plate.width, plate.height),
                    ctx.job.plate);
      }
    }
    // A layer rendered on another plate of the same size (a graded copy, another take) is
    // composited as it is: its exposure and ground shadow were matched to that plate.
    if (!object.layerPlateKey.empty() &&
        object.layerPlateKey != contentKey(ctx.job.plate, "composite")) {
      ctx.note(
          format("the object layer was rendered on another plate (%s): its exposure (%+.2f "
                 "stops, chosen for that plate or given) and its ground shadow, made on that "
                 "plate, are applied here as they are; to match this one, render it again on %s "
                 "(with its automatic exposure)",
                 object.layerPlateFile.c_str(), std::log2(double(object.exposure)),
                 ctx.job.plate.filename().string().c_str()));
    } else if (!object.layerPlateDecoded.empty() && ctx.hasKey(kPlateLinear) &&
               object.layerPlateDecoded != ctx.key(kPlateLinear).hex()) {
      // The same plate decoded otherwise (--plate-space given to one command only, another
      // colour config): the layer's automatic exposure was matched to the other decoding.
      const ExposureMatch here =
          autoExposure(*ctx.artefacts.plateLinear, ctx.geometry().camera, object.cardRadiance,
                       ctx.colors.lumaWeights(ctx.colors.workingSpace()));
      const double off = here.nothingVisible || !(here.scale > 0.0)
                             ? 0.0
                             : std::log2(here.scale / double(object.exposure));
      auto reading = [](const std::string& space) {
        return space.empty() ? std::string("as its file says")
                             : "as '" + space + "' (--plate-space)";
      };
      if (std::abs(off) >= 0.01) {
        ctx.note(format(
            "the object layer's automatic exposure (%+.2f stops) was matched to the plate read "
            "%s; this run reads it %s%s, for which the match is %+.2f stops: the object is %.2f "
            "stops too %s here; give compose render and compose composite the same --plate-space",
            std::log2(double(object.exposure)), reading(object.layerPlateSpace).c_str(),
            reading(ctx.job.plateSpace).c_str(),
            object.layerPlateSpace == ctx.job.plateSpace
                ? " (decoded otherwise: another colour config, a file rule, or another version)"
                : "",
            std::log2(here.scale), std::abs(off), off > 0.0 ? "dark" : "bright"));
      }
    }
    std::string reason = "the object over the plate";
    // Made in place in the linear plate, which no later stage reads; a holdout needs the plate
    // as it was, so it is copied then.
    const bool holdout = !ctx.job.holdout.empty();
    Image out;
    if (holdout) {
      out = *ctx.artefacts.plateLinear;
    } else {
      out = std::move(*ctx.artefacts.plateLinear);
      ctx.artefacts.plateLinear.reset();
    }
    if (ctx.artefacts.groundShadow && !ctx.artefacts.groundShadow->ratio.empty()) {
      const GroundShadowResult& ground = *ctx.artefacts.groundShadow;
      composite::multiply(out, ground.ratio, ground.grid.x0, ground.grid.y0);
      reason = "the plate darkened by the ground shadow, the object over it";
    }
    composite::overInPlace(out, object.output.beauty, object.output.x0, object.output.y0,
                           object.pending);
    if (holdout) {
      // Read with the plate, so that a bad mask stopped the job before the render; kept for the
      // files, whose object and shadow parts it holds out too.
      if (!ctx.artefacts.holdout)
        ctx.artefacts.holdout = loadHoldout(ctx.job.holdout, out.width, out.height);
      out = composite::holdout(out, *ctx.artefacts.plateLinear, *ctx.artefacts.holdout);
      reason += ", the holdout's plate in front";
    }
    ctx.artefacts.composite = std::move(out);
    return reason + " (scene-linear)";
  }
};

// ---------------------------------------------------------------------------------------------

class OutputStage final : public Stage {
 public:
  std::string name() const override { return "output"; }
  std::string summary() const override {
    return "write the multi-part OpenEXR (composite, object with AOVs, shadow) and the display "
           "image (JPEG or PNG) through the config's view";
  }
  std::vector<std::string> inputs() const override { return {kComposite, kObject, kGroundShadow}; }
  std::vector<std::string> outputs() const override { return {kFiles}; }
  std::vector<StageParameter> parameters() const override {
    return {pathParameter("out", "output base path: writes BASE.exr and BASE.jpg (or .png)",
                          &ComposeJob::output),
            textParameter("display", "OpenColorIO display for the JPEG/PNG (empty: the config's)",
                          &ComposeJob::display),
            textParameter("view", "OpenColorIO view for the JPEG/PNG (empty: the config's)",
                          &ComposeJob::view),
            textParameter("compression",
                          std::string("the EXR's compression: ") + ingest::kExrCompressionNames,
                          &ComposeJob::exrCompression),
            textParameter("depth",
                          "the EXR's samples: half, float, or auto (float for a 32-bit float "
                          "plate, else half)",
                          &ComposeJob::exrDepth),
            textParameter("exr-space",
                          "colour space of the EXR's colour channels, a linear one (empty: the "
                          "working space)",
                          &ComposeJob::exrSpace),
            {"jpeg-quality", "quality of the display image when it is a JPEG, 1-100",
             [](const ComposeJob& j) { return nlohmann::json(j.jpegQuality); },
             [](ComposeJob& j, const nlohmann::json& v) {
               const std::optional<int64_t> n = wholeNumber(v);
               if (!n || *n < 1 || *n > 100)
                 throw UsageError("jpeg-quality must be a whole number in 1..100");
               j.jpegQuality = int(*n);
             }}};
  }
  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("files");
    h.combine(ctx.key(kComposite));
    ctx.keys[kFiles] = h;
  }
  std::string run(Context& ctx) const override {
    const ComposeJob& job = ctx.job;
    const fs::path exrPath = exrPathFor(job), displayPath = displayPathFor(job);
    const RenderedObject& object = *ctx.artefacts.object;
    const GroundShadowResult* ground =
        ctx.artefacts.groundShadow && !ctx.artefacts.groundShadow->ratio.empty()
            ? &*ctx.artefacts.groundShadow
            : nullptr;
    // A plate stored as 32-bit float keeps its precision (half would round it to 11 bits).
    const bool floatPlate =
        ctx.artefacts.plate && (ctx.artefacts.plate->info.sampleType == "float" ||
                                ctx.artefacts.plate->info.sampleType == "double");
    const bool floatSamples = job.exrDepth == "float" || (job.exrDepth == "auto" && floatPlate);
    const std::vector<std::string> notes = writeComposeFiles(
        ctx.colors, job, ctx.geometry(), *ctx.artefacts.composite, object, ground, exrPath,
        displayPath, floatSamples, ctx.artefacts.holdout ? &*ctx.artefacts.holdout : nullptr);
    for (const auto& n : notes) ctx.note(n);
    report(ctx.progress, "output", 1.0);
    const std::string ext = ingest::lowerExtension(displayPath);
    const bool jpeg = ext == ".jpg" || ext == ".jpeg";
    return "wrote " + exrPath.string() + " (" + (floatSamples ? "float, " : "half, ") +
           job.exrCompression + ") and " + displayPath.string() +
           (jpeg ? " (JPEG quality " + std::to_string(job.jpegQuality) + ")" : std::string());
  }
};

}  // namespace

ingest::ExrHeader sceneHeader(const Geometry& geometry, const std::string& meshFile,
                              const glm::dvec3& fileOrigin) {
  ingest::ExrHeader header;
  header.pixelAspectRatio = float(geometry.camera.pixelAspect);
  auto asImath = [](const glm::dmat4& m) {
    // glm stores columns of a column-vector matrix: the same numbers, in the same order, as
    // Imath's rows of the row-vector matrix (translation in the last row).
    std::array<float, 16> out;
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) out[size_t(4 * c + r)] = float(m[c][r]);
    return out;
  };
  const calib::PlateCamera& camera = geometry.camera;
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
  // From the mesh file's own coordinates: the object's, moved by its file origin. In double
  // (m44d): a mesh far from its file's origin (a scene exported in place, georeferenced) has a
  // translation that float rounds by centimetres, and the rebuilt object would not stand where
  // it was rendered.
  // The format's turn of axes (a .bez is Z up) comes first.
  const glm::dmat4 worldFromFile = geometry.worldFromObject *
                                   glm::translate(glm::dmat4(1.0), -fileOrigin) *
                                   glm::dmat4(render::meshFromFileAxes(meshFile));
  std::array<double, 16> fromFile;
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r) fromFile[size_t(4 * c + r)] = worldFromFile[c][r];
  header.doubleMatrices.emplace_back("compose:worldFromObject", fromFile);
  // How the environment is turned in the world (--env-yaw): a direction in the world is looked up
  // in the environment map at envFromWorld times it.
  header.matrices.emplace_back("compose:envFromWorld",
                               asImath(glm::dmat4(glm::dmat3(geometry.envFromWorld))));
  if (!meshFile.empty()) header.strings.emplace_back("compose:object", meshFile);
  if (lens.projection != calib::Projection::Rectilinear) {
    header.strings.emplace_back("compose:lens",
                                "equidistant fisheye lens: worldToNDC is the pinhole of its focal "
                                "lengths and principal point, not its projection");
  } else if (lens.hasDistortion()) {
    header.strings.emplace_back("compose:lens",
                                "distorted lens: worldToNDC holds its pinhole part only");
  }
  return header;
}

EnvironmentExif environmentExif(const Context& ctx) {
  EnvironmentExif out;
  if (!ctx.artefacts.capture) {
    // An environment file that the photo stages made (merge, stitch, convert) says its camera
    // and whether its radiance is in that camera's EXIF exposure unit; six faces must all say
    // the same.
    ingest::CaptureInfo env;
    bool first = true, agree = true;
    for (const fs::path& file : ctx.environmentInput.files) {
      std::error_code ec;
      if (!fs::is_regular_file(file, ec)) continue;
      const ingest::CaptureInfo info = ingest::readCaptureInfo(file, "ingest", true);
      if (first) {
        env = info;
        first = false;
      } else if (info.exposureUnit != env.exposureUnit || info.camera() != env.camera()) {
        agree = false;
      }
    }
    if (first || !agree || env.exposureUnit != ingest::kExifExposureUnit) {
      out.whyNot =
          "the environment is not a capture description (compose --env capture.json) nor a map "
          "that compose merged from photos at their EXIF exposures";
    } else if (env.camera().empty()) {
      out.whyNot = "the environment does not say which camera its photos come from";
    } else {
      out.camera = env.camera();
    }
    return out;
  }
  const ingest::Capture& capture = *ctx.artefacts.capture;
  out.whose = "the capture's";
  ingest::CaptureInfo captureCamera;
  captureCamera.cameraMake = capture.cameraMake;
  captureCamera.cameraModel = capture.cameraModel;
  for (const ingest::View& view : capture.views) {
    for (const ingest::Shot& shot : view.shots) {
      if (!ingest::atOwnExifExposure(shot)) {
        out.whyNot = "the capture's photos are not all 8-bit with their exposures from EXIF";
        return out;
      }
    }
  }
  if (captureCamera.camera().empty()) {
    out.whyNot = "the capture does not say which camera its photos come from";
    return out;
  }
  out.camera = captureCamera.camera();
  return out;
}

void chooseExposure(Context& ctx, RenderedObject& object) {
  COMPOSE_CHECK(!object.exposureChosen);
  object.notes.clear();
  object.exposureMatchedToPlate = false;
  if (ctx.job.exposureStops) {
    object.exposure = float(std::exp2(*ctx.job.exposureStops));
  } else {
    const ExposureMatch match =
        autoExposure(*ctx.artefacts.plateLinear, ctx.geometry().camera, object.cardRadiance,
                     ctx.colors.lumaWeights(ctx.colors.workingSpace()));
    std::string why, note;
    if (const std::optional<double> exif = exifExposure(ctx, why)) {
      object.exposure = float(*exif);
      const ingest::CaptureInfo& info = ctx.artefacts.plate->info;
      note = format(
          "exposure from EXIF: %+.2f stops: the plate and the environment's photos come from one "
          "camera "
          "(%s); the plate's relative exposure %.4g (%.4g s, f/%.3g, ISO %.0f) puts the "
          "environment's radiance in the plate's units (the automatic match would give %+.2f "
          "stops); override with --exposure",
          std::log2(*exif), info.camera().c_str(), *exif, *info.exposureTime, *info.fNumber,
          *info.iso, std::log2(match.scale));
    } else if (match.nothingVisible) {
      object.exposure = 1.0f;
      note =
          "auto exposure: 0 stops (the environment's own units): the plate is transparent "
          "everywhere (alpha below 0.01), so it has no brightness to match; override with "
          "--exposure";
    } else {
      object.exposure = float(match.scale);
      object.exposureMatchedToPlate = true;
      note = format(
          "auto exposure: %+.2f stops: a mid-grey card on the ground, lit by the environment "
          "(%.4g in the environment's units), matched to the plate's log-average (%.4g)%s%s%s; "
          "override with --exposure",
          std::log2(match.scale), match.cardRadiance, match.plateKey,
          match.blackGround  ? ""
          : match.wholePlate ? " (the whole plate's: almost none of it lies below the horizon)"
          : match.groundShare < 0.999
              ? format(" below the horizon (%.0f %% of the plate)", 100.0 * match.groundShare)
                    .c_str()
              : "",
          match.black ? " (the plate is black: no light to match, the level taken is a floor)"
          : match.blackGround
              ? " (the whole plate's: the ground in view is black, a letterbox bar or "
                "codes of 0)"
              : "",
          ctx.artefacts.capture || ctx.artefacts.plate->info.relativeExposure()
              ? (" (not from EXIF: " + why + ")").c_str()
              : "");
    }
    ctx.note(note);
    object.notes.push_back(note);
  }
  // The object's light times the exposure must stay a float (an environment of 9e31 at
  // --exposure 30 was written as infinity, shown black, exit 0).
  const render::RenderOutput& r = object.output;
  float peak = 0.0f;
  for (size_t i = 0; i < r.beauty.pixelCount(); ++i)
    for (int c = 0; c < 3; ++c)
      peak = std::max(peak, std::abs(r.beauty.pixels[i * size_t(r.beauty.channels) + size_t(c)]));
  for (const std::string& name : exposedChannels()) {
    const auto at = std::find(r.aovs.channelNames.begin(), r.aovs.channelNames.end(), name);
    if (at == r.aovs.channelNames.end()) continue;
    const size_t c = size_t(at - r.aovs.channelNames.begin());
    for (size_t i = 0; i < r.aovs.pixelCount(); ++i)
      peak = std::max(peak, std::abs(r.aovs.pixels[i * size_t(r.aovs.channels) + c]));
  }
  constexpr double kLargest = double(std::numeric_limits<float>::max());
  if (!(object.exposure > 0.0f)) {
    throw Error("render",
                format("the object's exposure (%s) is below what a float holds: %s",
                       ctx.job.exposureStops ? "--exposure" : "chosen automatically",
                       ctx.job.exposureStops ? "raise --exposure"
                                             : "give --exposure, or bring the plate and the "
                                               "environment to comparable units"));
  }
  if (!std::isfinite(object.exposure) || !(double(peak) * double(object.exposure) <= kLargest)) {
    throw Error("render",
                format("the object's light (up to %g in the environment's units) times its "
                       "exposure (%+.1f stops%s) exceeds what a float holds (%g): %s",
                       double(peak), std::log2(double(object.exposure)),
                       ctx.job.exposureStops ? ", --exposure" : ", chosen automatically", kLargest,
                       ctx.job.exposureStops
                           ? "lower --exposure, or bring the environment to smaller values"
                           : "give --exposure, or bring the plate and the environment to "
                             "comparable units"));
  }
  object.pending = object.exposure;
  object.exposureChosen = true;
}

std::vector<std::string> writeComposeFiles(const color::ColorConfig& colors, const ComposeJob& job,
                                           const Geometry& geometry, const Image& composite,
                                           const RenderedObject& object,
                                           const GroundShadowResult* ground,
                                           const fs::path& exrPath, const fs::path& displayPath,
                                           bool floatSamples, const Image* holdout) {
  const render::RenderOutput& rendered = object.output;
  std::vector<std::string> notes;
  // A holdout in front: the object and the shadow parts are held out as the composite is, so that
  // the plate times the shadow part, the object part over it, gives the composite part (it gave
  // the object in front of what holds it out). With m the mask, a the object's alpha and s the
  // ratio: the object times 1 - m; the ratio (m + (1 - m) s (1 - a)) / (1 - (1 - m) a), the plate
  // then showing through by m + (1 - m) s (1 - a), as in the composite.
  Image heldBeauty, heldRatio;
  const render::RenderOutput* renderedOut = &rendered;
  render::RenderOutput heldOutput;
  if (holdout) {
    COMPOSE_CHECK(holdout->width == composite.width && holdout->height == composite.height &&
                  holdout->channels == 1);
    auto maskAt = [&](int x, int y) { return std::clamp(holdout->at(x, y)[0], 0.0f, 1.0f); };
    auto alphaAt = [&](int x, int y) {
      const int bx = x - rendered.x0, by = y - rendered.y0;
      if (bx < 0 || by < 0 || bx >= rendered.beauty.width || by >= rendered.beauty.height)
        return 0.0f;
      return rendered.beauty.at(bx, by)[3];
    };
    heldOutput.x0 = rendered.x0;
    heldOutput.y0 = rendered.y0;
    heldOutput.beauty = rendered.beauty;
    Image& b = heldOutput.beauty;
    parallelFor(0, int64_t(b.height), [&](int64_t y) {
      for (int x = 0; x < b.width; ++x) {
        const float keep = 1.0f - maskAt(x + rendered.x0, int(y) + rendered.y0);
        for (int c = 0; c < 4; ++c) b.at(x, int(y))[c] *= keep;
      }
    });
    if (ground) {
      heldRatio = ground->ratio;
      const int gx = ground->grid.x0, gy = ground->grid.y0;
      parallelFor(0, int64_t(heldRatio.height), [&](int64_t y) {
        for (int x = 0; x < heldRatio.width; ++x) {
          const float m = maskAt(x + gx, int(y) + gy), a = alphaAt(x + gx, int(y) + gy);
          const float through = 1.0f - (1.0f - m) * a;
          if (!(through > 1e-6f)) continue;  // the object covers it: the ratio is not seen
          float* s = heldRatio.at(x, int(y));
          for (int c = 0; c < heldRatio.channels; ++c)
            s[c] = std::min(1.0f, (m + (1.0f - m) * s[c] * (1.0f - a)) / through);
        }
      });
    }
    renderedOut = &heldOutput;
  }
  const std::string working = colors.workingSpace();
  COMPOSE_CHECK((composite.channels == 3 || composite.channels == 4) &&
                rendered.beauty.channels == 4);
  // The colour channels in the space asked for (--exr-space): converted copies. A linear space,
  // so that premultiplied colour converts as it is.
  const std::string space =
      job.exrSpace.empty() ? working : colors.resolve(job.exrSpace, "--exr-space");
  Image compositeIn, beautyIn, aovsIn;
  const Image* compositeOut = &composite;
  const Image* beautyOut = &renderedOut->beauty;
  const Image* aovsOut = &rendered.aovs;
  float pending = object.pending;  // the exposure still to apply to the object's light
  if (space != working) {
    compositeIn = composite;
    compositeIn.colorSpace = working;
    colors.convert(compositeIn, space);
    beautyIn = renderedOut->beauty;
    aovsIn = rendered.aovs;
    const std::vector<std::string>& names = render::aovChannelNames();
    // The exposure first, then the matrix, as an object layer (which holds its light exposed)
    // is converted by `compose composite`: the chained stages give these files bit for bit.
    if (pending != 1.0f) {
      for (size_t i = 0; i < beautyIn.pixelCount(); ++i)
        for (size_t c = 0; c < 3; ++c) beautyIn.pixels[4 * i + c] *= pending;
      for (const std::string& name : exposedChannels()) {
        const auto it = std::find(names.begin(), names.end(), name);
        if (it == names.end()) continue;  // the object's own light, above
        const size_t at = size_t(it - names.begin()), stride = size_t(aovsIn.channels);
        for (size_t i = 0; i < aovsIn.pixelCount(); ++i) aovsIn.pixels[i * stride + at] *= pending;
      }
      pending = 1.0f;
    }
    beautyIn.colorSpace = working;
    colors.convert(beautyIn, space);
    for (const std::string& layer : colourAovLayers()) {
      const auto first = std::find(names.begin(), names.end(), layer + ".R");
      COMPOSE_CHECK(first != names.end());
      convertChannels(aovsIn, size_t(first - names.begin()), [&](Image& rgb) {
        rgb.colorSpace = working;
        colors.convert(rgb, space);
      });
    }
    compositeOut = &compositeIn;
    beautyOut = &beautyIn;
    aovsOut = &aovsIn;
  }
  // The parts are written from the images as they are, without interleaving them into new ones
  // first: the composite's RGB with an opaque alpha added on the way, the object's RGBA followed
  // by its AOVs.
  ingest::ExrPart compositePart{"composite",     compositeOut,     0, 0,
                                composite.width, composite.height, {}};
  if (composite.channels == 4) {
    compositePart.channelNames = {"R", "G", "B", "A"};  // a plate with alpha
  } else {
    compositePart.channelNames = {"R", "G", "B"};
    compositePart.constantChannels = {{"A", 1.0f}};
  }
  compositePart.colorSpace = space;
  compositePart.options.depth =
      floatSamples ? ingest::WriteOptions::Depth::Float : ingest::WriteOptions::Depth::Half;
  compositePart.options.alphaChannel = 3;
  compositePart.options.chromaticities = colors.chromaticities(space);
  compositePart.options.exrCompression = job.exrCompression;
  ingest::ExrPart objectPart{"object",        beautyOut,        rendered.x0,          rendered.y0,
                             composite.width, composite.height, compositePart.options};
  const std::vector<std::string>& aovNames = render::aovChannelNames();
  COMPOSE_CHECK(rendered.aovs.channels == int(aovNames.size()));
  objectPart.colorSpace = space;
  objectPart.moreImages = {aovsOut};
  objectPart.channelNames = {"object.R", "object.G", "object.B", "object.A"};
  objectPart.channelNames.insert(objectPart.channelNames.end(), aovNames.begin(), aovNames.end());
  // Positions and depth in float whatever the depth of the rest: in half, P put a point 10 m away
  // up to a pixel off where it shows on a 3088-pixel-wide plate.
  objectPart.floatChannels = {"P.X", "P.Y", "P.Z", "depth.Z"};
  if (pending != 1.0f)
    for (const std::string& name : exposedChannels())
      objectPart.channelScales.emplace_back(name, pending);
  if (!compositePart.options.chromaticities) {
    notes.push_back("the config (" + colors.source() + ") does not say what the primaries of " +
                    (space == working ? "the working space" : "--exr-space") + " '" + space +
                    "' are: the EXR carries its name but no chromaticities");
  }
  ingest::ExrHeader header = sceneHeader(geometry, object.meshFile, object.fileOrigin);
  if (holdout) header.strings.emplace_back("compose:holdout", fs::absolute(job.holdout).string());

  const std::string display = job.display.empty() ? colors.defaultDisplay() : job.display;
  const std::string view = job.view.empty() ? colors.defaultView(display) : job.view;
  // Both files appear together or not at all: a failure keeps every previous output.
  OutputFiles outputs("output");
  std::vector<ingest::ExrPart> parts = {compositePart, objectPart};
  Image ratioIn;
  if (ground) {
    // The ground shadow's ratio, in its own data window (where it is below 1): 1 elsewhere.
    ingest::ExrPart shadowPart{"shadow",
                               holdout ? &heldRatio : &ground->ratio,
                               ground->grid.x0,
                               ground->grid.y0,
                               composite.width,
                               composite.height,
                               compositePart.options};
    shadowPart.options.alphaChannel = -1;
    // Labelled as the colour it multiplies, in the space written (it said 'Raw', which tells a
    // colour-managed reader to leave it alone, beside the primaries of the working space).
    shadowPart.colorSpace = space;
    if (space != working) {
      // Per channel of the working space the plate was darkened by it. In other primaries a
      // tinted ratio has no exact counterpart (it would depend on the plate's colour): it is
      // converted as a colour is, exact for a grey ratio (white stays white).
      ratioIn = holdout ? heldRatio : ground->ratio;
      ratioIn.colorSpace = working;
      colors.convert(ratioIn, space);
      shadowPart.image = &ratioIn;
    }
    parts.push_back(shadowPart);
  }
  // The display image (the view transform, the clipping check, the JPEG) is made on a thread of
  // its own while the EXR is written: OpenEXR compresses on its own threads and leaves cores idle
  // between blocks of rows, and the JPEG encoder runs on one core.
  std::future<std::vector<std::string>> displayed = std::async(std::launch::async, [&] {
    std::vector<std::string> displayNotes;
    // A composite with alpha: a PNG keeps it, as PNG stores it (the colour unpremultiplied in
    // linear light, then through the view); a JPEG, which has none, shows it over black (its
    // premultiplied colour).
    const bool keepAlpha = composite.channels == 4 && ingest::lowerExtension(displayPath) == ".png";
    Image shown;
    if (keepAlpha) {
      Image straight = composite;
      std::atomic<int64_t> glow{0};  // light with alpha 0 (additive): straight alpha loses it
      parallelFor(0, int64_t(straight.height), [&](int64_t y) {
        int64_t row = 0;
        for (int x = 0; x < straight.width; ++x) {
          float* p = straight.at(x, int(y));
          if (p[3] > 0.0f && p[3] < 1.0f)
            for (int c = 0; c < 3; ++c) p[c] /= p[3];
          else if (p[3] <= 0.0f && (p[0] > 0.0f || p[1] > 0.0f || p[2] > 0.0f))
            ++row;
        }
        glow += row;
      });
      if (glow > 0) {
        displayNotes.push_back(
            std::to_string(glow.load()) +
            " pixels carry light with alpha 0 (additive, as a glow): the PNG's straight alpha "
            "cannot hold them (they are transparent in " +
            displayPath.filename().string() + "); the EXR keeps them, and a JPEG shows them");
      }
      shown = colors.toDisplay(std::move(straight), display, view);
    } else {
      shown = colors.toDisplay(composite, display, view);
      if (shown.channels == 4) shown = toRgb(shown);
    }
    if (const std::optional<std::string> n =
            clippedObjectNote(*renderedOut, shown, displayPath, view, object.fromLayer))
      displayNotes.push_back(*n);
    // Only sRGB is said in the file (EXIF ColorSpace, PNG's sRGB chunk): another display's codes
    // go untagged, and viewers take them for sRGB (Display P3's red shows duller).
    std::string viewName = view;
    std::transform(viewName.begin(), viewName.end(), viewName.begin(),
                   [](unsigned char c) { return char(std::tolower(c)); });
    if (!ingest::isSrgbEncoded(shown.colorSpace) && viewName != "raw" && viewName != "none") {
      displayNotes.push_back("the display '" + display + "' with the view '" + view +
                             "' is not sRGB: " + displayPath.filename().string() +
                             " holds its codes but carries no colour profile that says so, and "
                             "viewers will show it as sRGB (the EXR's scene-linear colour is "
                             "tagged)");
    }
    ingest::WriteOptions displayOptions;
    displayOptions.jpegQuality = job.jpegQuality;
    // The plate's colour edges stay where they were (4:2:0 moved them by up to 43 codes).
    displayOptions.jpegFullChroma = true;
    if (keepAlpha) {
      displayOptions.alphaChannel = 3;
      // The colour is unassociated already: OpenImageIO is not to divide it by alpha again.
      displayOptions.attributes.push_back({"oiio:UnassociatedAlpha", 1});
    }
    ingest::writeImage(outputs, displayPath, shown, displayOptions);
    return displayNotes;
  });
  std::vector<ingest::WriteReport> written;
  try {
    written = ingest::writeExrParts(outputs, exrPath, parts, header);
  } catch (...) {
    displayed.wait();  // the display thread uses `outputs`: let it finish before unwinding
    throw;
  }
  const std::vector<std::string> displayNotes = displayed.get();
  notes.insert(notes.end(), displayNotes.begin(), displayNotes.end());
  outputs.commit();
  for (const ingest::WriteReport& w : written) {
    if (!w.promotedToFloat) continue;
    notes.push_back(
        format("values up to %g exceed half float's range (65504): that part of the "
               "EXR is written as 32-bit float",
               double(w.largestMagnitude)));
  }
  return notes;
}

std::unique_ptr<Stage> makeRenderStage() {
  return std::make_unique<RenderStage>();
}
std::unique_ptr<Stage> makeCompositeStage() {
  return std::make_unique<CompositeStage>();
}
std::unique_ptr<Stage> makeOutputStage() {
  return std::make_unique<OutputStage>();
}

}  // namespace compose::pipeline
