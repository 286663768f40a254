#include "pipeline/stage_files.h"

#include <variant>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>

#include "calib/lens_json.h"
#include "core/error.h"
#include "core/json_number.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "ingest/exr_io.h"
#include "pipeline/stage.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_util.h"
#include "pipeline/stages.h"

namespace compose::pipeline {

namespace fs = std::filesystem;
using namespace artefact;

namespace {

constexpr int kLayerFormat = 1;
constexpr const char* kLayerAttribute = "compose:layer";

// A key for each output read from `file`: its content and the output's name.
void keyFromFile(Context& ctx, const fs::path& file, const std::vector<std::string>& outputs,
                 const std::string& stage) {
  Hash128 content;
  hashFile(content, file, stage);
  for (const std::string& o : outputs) {
    Hash128 h = content;
    h.bytes(o);
    ctx.keys[o] = h;
  }
}

template <class Matrix>
nlohmann::json matrixToJson(const Matrix& m) {
  nlohmann::json out = nlohmann::json::array();
  for (int c = 0; c < m.length(); ++c)
    for (int r = 0; r < m[c].length(); ++r) out.push_back(m[c][r]);
  return out;
}

template <class Matrix>
Matrix matrixFromJson(const nlohmann::json& j) {
  Matrix m(1.0);
  const int columns = m.length(), rows = m[0].length();
  if (!j.is_array() || int(j.size()) != columns * rows)
    throw nlohmann::json::other_error::create(501, "a matrix of the wrong size", nullptr);
  for (int c = 0; c < columns; ++c)
    for (int r = 0; r < rows; ++r)
      m[c][r] = j.at(size_t(c * rows + r)).template get<typename Matrix::value_type>();
  return m;
}

nlohmann::json geometryToJson(const Geometry& g) {
  const calib::PlateCamera& c = g.camera;
  return {{"camera",
           {{"width", c.width},
            {"height", c.height},
            {"lens", calib::lensToJson(c.lens)},
            {"focal35mm", c.focal35mm},
            {"focalSource", c.focalSource},
            {"pixelAspect", c.pixelAspect},
            {"worldFromCamera", matrixToJson(c.worldFromCamera)}}},
          {"worldFromObject", matrixToJson(g.worldFromObject)},
          {"envFromWorld", matrixToJson(g.envFromWorld)},
          {"envFromObject", matrixToJson(g.envFromObject)}};
}

Geometry geometryFromJson(const nlohmann::json& j, const fs::path& file) {
  Geometry g;
  const nlohmann::json& c = j.at("camera");
  const auto width = wholeMember(c, "width", 1), height = wholeMember(c, "height", 1);
  if (!width || !height)
    throw Error("composite", "the layer's camera needs a whole width and height in pixels", file);
  g.camera.width = int(*width);
  g.camera.height = int(*height);
  g.camera.lens = calib::lensFromJson(c.at("lens"), file);
  g.camera.focal35mm = c.at("focal35mm").get<double>();
  g.camera.focalSource = c.at("focalSource").get<std::string>();
  g.camera.pixelAspect = c.value("pixelAspect", 1.0);  // layers before it: square pixels
  if (!(g.camera.pixelAspect >= 0.01 && g.camera.pixelAspect <= 100.0))
    throw Error("composite", "the layer's camera has a pixel aspect ratio out of range", file);
  g.camera.worldFromCamera = matrixFromJson<glm::dmat4>(c.at("worldFromCamera"));
  g.worldFromObject = matrixFromJson<glm::dmat4>(j.at("worldFromObject"));
  g.envFromWorld = matrixFromJson<glm::mat3>(j.at("envFromWorld"));
  g.envFromObject = matrixFromJson<glm::mat3>(j.at("envFromObject"));
  // The camera's and the object's placements are turned into the header's worldToCamera and
  // worldToNDC: finite and invertible, or they came out NaN in every part (a forged header).
  for (const auto& [name, m] : {std::pair{"worldFromCamera", &g.camera.worldFromCamera},
                                std::pair{"worldFromObject", &g.worldFromObject}}) {
    const double det = glm::determinant(glm::dmat3(*m));
    bool finite = std::isfinite(det);
    for (int col = 0; col < 4; ++col)
      for (int row = 0; row < 4; ++row) finite = finite && std::isfinite((*m)[col][row]);
    if (!finite || std::abs(det) < 1e-300)
      throw Error("composite",
                  std::string("the layer's ") + name +
                      " is not a placement (not finite, or not invertible): the header is damaged",
                  file);
  }
  return g;
}

// The parameters a precompute file fixes for the stages that use it. The environment's turn
// (--env-yaw) is not applied to the moments (they stay in the environment's frame) but to the
// directions the renderer looks them up in: it goes along for the render.
nlohmann::json lightingParameters(const ComposeJob& job) {
  return {{"lighting", job.lighting},
          {"lighting-params", job.lightingParams},
          {"shadow-params", job.shadowParams},
          {"env-yaw", job.environmentYawDegrees}};
}

// The lighting file's shadow parameters as far as this render draws shadows: all of them with
// the object's shadows on itself, the ground shadow's without (method, order, grid, boundary,
// sources), none without either. The one-shot command refuses values that change nothing when the
// user gives them; a lighting file made for shadows served a render without them.
std::string drawnShadowParams(const ComposeJob& job, const std::string& params) {
  if (job.shadows) return params;
  if (!job.groundShadow) return {};
  std::string kept, item;
  std::istringstream in(params);
  while (std::getline(in, item, ',')) {
    std::string key = item.substr(0, item.find('='));
    key.erase(0, key.find_first_not_of(" \t"));
    key.erase(key.find_last_not_of(" \t") + 1);
    if (key == "refine" || key == "refine-budget" || key == "ground") continue;
    kept += (kept.empty() ? "" : ",") + item;
  }
  return kept;
}

}  // namespace

void savePrecompute(Context& ctx, const fs::path& file) {
  // The lighting file never replaces what it was made from.
  std::error_code ec;
  if (fs::exists(file, ec)) {
    for (const fs::path& input : ctx.environmentInput.files) {
      std::error_code same;
      if (fs::equivalent(file, input, same) && !same)
        throw Error("precompute",
                    "the output would replace an input (" + input.string() +
                        "): choose another output path",
                    file);
    }
  }
  StageCache entry = StageCache::atFile(file, "precompute");
  entry.meta()["parameters"] = lightingParameters(ctx.job);
  // With parallax the lighting is the environment as seen from the object's centre: a render
  // that places the object elsewhere is told.
  if (const lighting::CaptureProxy proxy = ctx.captureProxy();
      proxy.shape != lighting::CaptureProxy::Shape::Distant) {
    const glm::dvec3 c = ctx.objectCentre();
    entry.meta()["parallax"] = {{"seenFrom", {c.x, c.y, c.z}}, {"surroundings", proxy.describe()}};
  }
  entry.meta()["environment"] = fs::absolute(ctx.environmentInput.path).string();
  // The working space its numbers are in: a render under another colour config must not read
  // them as its own.
  entry.meta()["workingSpace"] = ctx.colors.workingSpace();
  entry.meta()["colorConfig"] = ctx.colors.source();
  if (const auto c = ctx.colors.chromaticities(ctx.colors.workingSpace()))
    entry.meta()["chromaticities"] = std::vector<double>(c->begin(), c->end());
  // What the exposure from EXIF needs of the environment, for compose render, which reads the
  // lighting from this file and not the environment.
  const EnvironmentExif exif = environmentExif(ctx);
  entry.meta()["environmentExif"] = {
      {"camera", exif.camera}, {"whyNot", exif.whyNot}, {"whose", exif.whose}};
  // What the run said of what the lighting is made from (the environment's file, a merge's
  // clipped pixels, a map upside down), for compose render to say again; not what it said of its
  // own caching.
  // (With parallax the run read the object's mesh to place it: what reading it said is the
  // render's to say, of the mesh it reads.)
  std::vector<std::string> said;
  for (size_t n = 0; n < ctx.notes.size(); ++n) {
    if (ctx.runNotes.count(n)) continue;
    if (ctx.meshSummary && std::find(ctx.meshSummary->notes.begin(), ctx.meshSummary->notes.end(),
                                     ctx.notes[n]) != ctx.meshSummary->notes.end())
      continue;
    said.push_back(ctx.notes[n]);
  }
  entry.meta()["notes"] = said;
  if (!findStage("precompute").store(ctx, entry)) {
    if (!entry.error().empty())
      throw Error("precompute", "cannot write the lighting file: " + entry.error(), file);
    throw Error("precompute",
                "the lighting basis '" + ctx.job.lighting +
                    "' keeps no state that can be saved (it reads the environment while "
                    "shading); choose another with --lighting",
                file);
  }
}

StageInput precomputeInput(const fs::path& file, ComposeJob& job) {
  protectInput(file);
  auto entry = std::make_shared<StageCache>(StageCache::atFile(file, "precompute"));
  requireInputFile(file, "render", "lighting file");
  // Read now and hashed when the job is keyed: the file read must be the file hashed (a
  // precompute writing it again in between left the old lighting cached under the new key).
  const std::string identity = fileIdentity(file);
  if (!entry->open())
    throw Error("render",
                "not a lighting file of compose precompute (or a damaged one" +
                    (entry->problem().empty() ? std::string() : ": it " + entry->problem()) +
                    "): write it again with compose precompute",
                file);
  const nlohmann::json& meta = entry->meta();
  if (!meta.contains("parameters") || !meta["parameters"].is_object())
    throw Error("render", "the lighting file does not say what it was made with", file);
  const nlohmann::json& p = meta["parameters"];
  try {
    job.lighting = p.value("lighting", job.lighting);
    job.lightingParams = p.value("lighting-params", std::string());
    job.shadowParams = drawnShadowParams(job, p.value("shadow-params", std::string()));
    job.environmentYawDegrees = p.value("env-yaw", 0.0);
    if (!std::isfinite(job.environmentYawDegrees))
      throw Error("render", "the lighting file's env-yaw is not a number of degrees", file);
  } catch (const nlohmann::json::exception& e) {
    throw Error("render",
                std::string("the lighting file's parameters are damaged: ") + jsonMessage(e.what()),
                file);
  }

  StageInput in;
  in.stages = {"precompute"};
  in.file = file;
  in.load = [entry, file, identity](Context& ctx) {
    // Made in another working space (another $OCIO): its numbers are not this run's.
    const nlohmann::json& made = entry->meta();
    const std::string working = ctx.colors.workingSpace();
    if (made.contains("workingSpace") && made["workingSpace"].is_string()) {
      const std::string space = made["workingSpace"].get<std::string>();
      bool same = space == working;
      const auto here = ctx.colors.chromaticities(working);
      if (here && made.contains("chromaticities") && made["chromaticities"].is_array() &&
          made["chromaticities"].size() == 8) {
        same = true;
        for (size_t i = 0; i < 8; ++i) {
          const nlohmann::json& v = made["chromaticities"][i];
          same = same && v.is_number() && std::abs(v.get<double>() - (*here)[i]) < 1e-3;
        }
      }
      if (!same) {
        throw Error("render",
                    "the lighting file was made in the working space '" + space +
                        "' (config: " + made.value("colorConfig", std::string("?")) +
                        "); this run's is '" + working + "' (config: " + ctx.colors.source() +
                        "): precompute again under this config, or render under that one (the "
                        "same --ocio or $OCIO)",
                    file);
      }
    } else {
      ctx.note("the lighting file " + file.filename().string() +
               " does not say which working space it was made in (an older compose): taken as "
               "this run's, '" +
               working + "'");
    }
    EnvironmentExif exif;
    exif.whyNot =
        "the lighting file does not say which camera its environment's photos come from (an "
        "older compose)";
    if (const auto e = made.find("environmentExif"); e != made.end() && e->is_object()) {
      auto text = [&](const char* key, std::string& to) {
        if (const auto v = e->find(key); v != e->end() && v->is_string())
          to = v->get<std::string>();
      };
      text("camera", exif.camera);
      text("whyNot", exif.whyNot);
      text("whose", exif.whose);
    }
    ctx.environmentExif = exif;
    if (const auto parallax = made.find("parallax"); parallax != made.end()) {
      const auto from = parallax->is_object() ? parallax->find("seenFrom") : parallax->end();
      bool valid = from != parallax->end() && from->is_array() && from->size() == 3;
      for (size_t i = 0; valid && i < 3; ++i)
        valid = (*from)[i].is_number() && std::isfinite((*from)[i].get<double>());
      if (!valid)
        throw Error("render",
                    "the lighting file's parallax (where it sees the environment from) is damaged",
                    file);
      Context::LightingViewpoint v;
      v.point =
          glm::dvec3((*from)[0].get<double>(), (*from)[1].get<double>(), (*from)[2].get<double>());
      const auto s = parallax->find("surroundings");
      if (s == parallax->end() || !s->is_string())
        throw Error("render",
                    "the lighting file's parallax (the surroundings it sees the environment in) "
                    "is damaged",
                    file);
      v.surroundings = s->get<std::string>();
      ctx.lightingViewpoint = v;
    }
    // What compose precompute said of the lighting's sources, said again for this render.
    if (const auto n = made.find("notes"); n != made.end() && n->is_array())
      for (const nlohmann::json& said : *n)
        if (said.is_string()) ctx.note(said.get<std::string>());
    std::vector<std::string> outputs = {kLighting};
    if (!ctx.job.shadows && !ctx.job.groundShadow) {
      // No shadow drawn: the file's shadow lighting is not read.
    } else if (entry->meta().contains("shadowLighting")) {
      outputs.push_back(kShadowLighting);
    } else {
      throw Error("render",
                  "the lighting file was made with --shadows off --no-shadow: it holds no light "
                  "sources for the shadows (render with --shadows off --no-shadow, or precompute "
                  "again)",
                  file);
    }
    const std::set<std::string> needed = ctx.needed;
    ctx.needed.insert(outputs.begin(), outputs.end());
    bool loaded = false;
    try {
      loaded = findStage("precompute").load(ctx, *entry);
    } catch (const nlohmann::json::exception&) {
      loaded = false;  // a header that does not say what the stage wrote
    } catch (const Error&) {
      loaded = false;  // parameters its basis refuses
    }
    ctx.needed = needed;
    if (!loaded) throw Error("render", "the lighting file's contents do not fit its basis", file);
    keyFromFile(ctx, file, outputs, "render");
    requireSameFile(file, identity, "render");
  };
  return in;
}

void saveObjectLayer(Context& ctx, const fs::path& file, const std::string& compression) {
  RenderedObject& object = *ctx.artefacts.object;
  if (!object.exposureChosen) chooseExposure(ctx, object);  // for the plate it is rendered on
  const render::RenderOutput& r = object.output;
  const Geometry& g = ctx.geometry();
  // A lighting file made with parallax holds the light where it placed the object: said when
  // this render places it elsewhere (by more than a thousandth of its size).
  if (ctx.lightingViewpoint) {
    const glm::dvec3 centre = ctx.objectCentre();
    const glm::dvec3 extent = glm::dmat3(g.worldFromObject) *
                              glm::dvec3(ctx.meshSummary->boundsMax - ctx.meshSummary->boundsMin);
    const double away = glm::length(centre - ctx.lightingViewpoint->point);
    if (away > 1e-3 * glm::length(extent)) {
      const glm::dvec3& p = ctx.lightingViewpoint->point;
      ctx.note(format(
          "warning: the lighting file sees the environment (%s) from (%.3f, %.3f, %.3f), where its "
          "precompute placed the object; this render places the object's centre at (%.3f, %.3f, "
          "%.3f), %.3g %s away: it is lit as from there. For the light where it stands now, "
          "precompute again with this placement (the same --plate, --place, --scale, --yaw and "
          "camera options)",
          ctx.lightingViewpoint->surroundings.c_str(), p.x, p.y, p.z, centre.x, centre.y, centre.z,
          away, ctx.lengthUnit().c_str()));
    }
  }
  const std::vector<std::string>& aovNames = render::aovChannelNames();
  const int channels = 4 + int(aovNames.size());
  // Channels named as in the one-shot command's object part (Nuke's layer.channel).
  std::vector<std::string> names = {"object.R", "object.G", "object.B", "object.A"};
  names.insert(names.end(), aovNames.begin(), aovNames.end());
  Image layer(r.beauty.width, r.beauty.height, channels, names);
  layer.colorSpace = r.beauty.colorSpace;
  // The pending exposure applied: the layer's values are those the one-shot EXR holds.
  std::vector<float> scale(size_t(channels), 1.0f);
  const std::vector<std::string>& exposed = exposedChannels();
  for (size_t c = 0; c < names.size(); ++c)
    if (std::find(exposed.begin(), exposed.end(), names[c]) != exposed.end())
      scale[c] = object.pending;
  for (size_t i = 0; i < layer.pixelCount(); ++i) {
    float* d = layer.pixels.data() + i * size_t(channels);
    std::copy_n(r.beauty.pixels.data() + 4 * i, 4, d);
    std::copy_n(r.aovs.pixels.data() + i * aovNames.size(), aovNames.size(), d + 4);
    if (object.pending != 1.0f)
      for (size_t c = 0; c < size_t(channels); ++c) d[c] *= scale[c];
  }
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;  // the composite reads these numbers back
  options.alphaChannel = 3;
  options.chromaticities = ctx.colors.chromaticities(ctx.colors.workingSpace());
  options.exrCompression = compression;
  std::vector<ingest::ExrPart> parts = {
      {"object", &layer, r.x0, r.y0, g.camera.width, g.camera.height, options}};

  nlohmann::json header = {
      {"format", kLayerFormat},
      {"render",
       {{"x0", r.x0},
        {"y0", r.y0},
        {"x1", r.x1},
        {"y1", r.y1},
        {"rays", r.rays},
        {"coverage", r.coverage},
        {"exposure", object.exposure},
        {"notes", object.notes},
        {"mesh", object.meshFile},
        {"fileOrigin", {object.fileOrigin.x, object.fileOrigin.y, object.fileOrigin.z}},
        {"beautyChannels", r.beauty.channelNames},
        {"aovChannels", r.aovs.channelNames},
        {"colorSpace", r.beauty.colorSpace}}},
      {"geometry", geometryToJson(g)},
      {"plate",
       {{"file", fs::absolute(ctx.job.plate).string()},
        {"content", contentKey(ctx.job.plate, "render")}}},
      {"ground", nullptr}};
  if (object.exposureMatchedToPlate && ctx.hasKey(kPlateLinear)) {
    header["plate"]["decoded"] = ctx.key(kPlateLinear).hex();
    header["plate"]["space"] = ctx.job.plateSpace;
    header["render"]["cardRadiance"] = object.cardRadiance;
  }
  const GroundShadowResult* ground =
      ctx.artefacts.groundShadow && !ctx.artefacts.groundShadow->ratio.empty()
          ? &*ctx.artefacts.groundShadow
          : nullptr;
  if (ground) {
    ingest::WriteOptions ratioOptions = options;
    ratioOptions.alphaChannel = -1;
    parts.push_back({"shadow", &ground->ratio, ground->grid.x0, ground->grid.y0, g.camera.width,
                     g.camera.height, ratioOptions});
    header["ground"] = {{"x0", ground->grid.x0},
                        {"y0", ground->grid.y0},
                        {"x1", ground->grid.x1},
                        {"y1", ground->grid.y1},
                        {"reason", ground->reason},
                        {"channels", ground->ratio.channelNames},
                        {"colorSpace", ground->ratio.colorSpace}};
  } else if (ctx.artefacts.groundShadow) {
    header["ground"] = {{"reason", ctx.artefacts.groundShadow->reason}};
  }
  // The camera and placement as the one-shot command's EXR carries them (for Nuke and other
  // tools), and in full for compose composite.
  ingest::ExrHeader exrHeader = sceneHeader(g, object.meshFile, object.fileOrigin);
  exrHeader.strings.emplace_back(kLayerAttribute, header.dump());
  OutputFiles outputs("render");
  ingest::writeExrParts(outputs, file, parts, exrHeader);
  outputs.commit();
}

StageInput objectLayerInput(const fs::path& file) {
  protectInput(file);
  StageInput in;
  in.stages = {"shadows", "ground", "render"};
  in.file = file;
  in.load = [file](Context& ctx) {
    requireInputFile(file, "composite", "object layer");
    const std::string identity = fileIdentity(file);  // the file read is the file hashed
    const ingest::ExrReader input = [&] {
      if (!ingest::hasExrMagic(file))
        throw Error("composite", "cannot read the object layer: not an OpenEXR file", file);
      return ingest::ExrReader(file, "composite");
    }();
    std::string text;
    if (const ingest::ImageAttribute* a = input.header(0).find(kLayerAttribute))
      if (const std::string* t = std::get_if<std::string>(&a->value)) text = *t;
    const nlohmann::json header = nlohmann::json::parse(text, nullptr, false);
    if (text.empty() || !header.is_object() || !header.contains("format") ||
        header["format"] != kLayerFormat)
      throw Error("composite",
                  "not an object layer of compose render (no compose:layer header of format " +
                      std::to_string(kLayerFormat) + ")",
                  file);
    // The camera the layer was rendered for: every part lies inside its frame.
    Geometry geometry;
    try {
      geometry = geometryFromJson(header.at("geometry"), file);
    } catch (const nlohmann::json::exception& e) {
      throw Error("composite",
                  std::string("the object layer's header is damaged: ") + jsonMessage(e.what()),
                  file);
    }
    const int frameWidth = geometry.camera.width, frameHeight = geometry.camera.height;
    if (frameWidth <= 0 || frameHeight <= 0)
      throw Error("composite", "the object layer's header has no frame size", file);
    checkImageSize(frameWidth, frameHeight, 1, "composite", file);
    // Reads the part of that name, in float, with its data window, which must lie in the frame;
    // `partHeader` is set to the part's header.
    auto readPart = [&](const std::string& name, int& x, int& y,
                        const ingest::ExrPartHeader** partHeader = nullptr) {
      for (int part = 0; part < input.parts(); ++part) {
        const ingest::ExrPartHeader& h = input.header(part);
        if (h.name != name) continue;
        if (h.fullWidth != frameWidth || h.fullHeight != frameHeight)
          throw Error("composite",
                      format("part '%s' of the object layer has a %dx%d display window; the "
                             "camera it was rendered for has a %dx%d frame",
                             name.c_str(), h.fullWidth, h.fullHeight, frameWidth, frameHeight),
                      file);
        if (h.x < 0 || h.y < 0 || int64_t(h.x) + h.width > frameWidth ||
            int64_t(h.y) + h.height > frameHeight)
          throw Error("composite",
                      format("part '%s' of the object layer (%dx%d at %d,%d) does not lie in its "
                             "%dx%d frame",
                             name.c_str(), h.width, h.height, h.x, h.y, frameWidth, frameHeight),
                      file);
        x = h.x;
        y = h.y;
        if (partHeader) *partHeader = &h;
        return input.read(part);
      }
      throw Error("composite", "the object layer has no part '" + name + "'", file);
    };
    // Values a render cannot hold, which would reach every output unseen: NaN or infinity
    // anywhere, an alpha outside 0..1, a negative shadow ratio. Said at the frame's pixel.
    auto requireValid = [&](const Image& image, int x0, int y0, const std::string& part, int alpha,
                            bool nonNegative) {
      for (int yy = 0; yy < image.height; ++yy) {
        const std::span<const float> row = image.row(yy);
        for (int xx = 0; xx < image.width; ++xx) {
          for (int c = 0; c < image.channels; ++c) {
            const float v = row[size_t(xx) * size_t(image.channels) + size_t(c)];
            const bool bad = !std::isfinite(v) ||
                             (c == alpha && !(v >= -1e-3f && v <= 1.0f + 1e-3f)) ||
                             (nonNegative && v < 0.0f);
            if (!bad) continue;
            const std::string channel = c < int(image.channelNames.size())
                                            ? image.channelNames[size_t(c)]
                                            : std::to_string(c);
            throw Error(
                "composite",
                format("%s in channel %s of the %s part at pixel (%d, %d)%s",
                       std::isnan(v)   ? "NaN"
                       : std::isinf(v) ? "infinity"
                       : c == alpha    ? format("alpha %g", double(v)).c_str()
                                       : format("ratio %g", double(v)).c_str(),
                       channel.c_str(), part.c_str(), x0 + xx, y0 + yy,
                       std::isfinite(v) ? (c == alpha ? ": an alpha lies in 0..1"
                                                      : ": a shadow's ratio is not negative")
                                        : ": a layer's values must be finite"),
                file);
          }
        }
      }
    };
    try {
      const nlohmann::json& rj = header.at("render");
      RenderedObject object;
      render::RenderOutput& r = object.output;
      auto whole = [&](const nlohmann::json& j, const char* key,
                       int64_t hi = std::numeric_limits<int>::max()) {
        const std::optional<int64_t> v = wholeMember(j, key, 0, hi);
        if (!v)
          throw Error("composite",
                      std::string("the object layer's header needs a whole number '") + key + "'",
                      file);
        return *v;
      };
      r.x0 = int(whole(rj, "x0"));
      r.y0 = int(whole(rj, "y0"));
      r.x1 = int(whole(rj, "x1"));
      r.y1 = int(whole(rj, "y1"));
      r.rays = whole(rj, "rays", std::numeric_limits<int64_t>::max());
      r.coverage = rj.at("coverage");
      object.exposure = rj.at("exposure");
      object.exposureChosen = true;  // its values carry it: pending stays 1
      object.fromLayer = true;
      object.notes = rj.at("notes").get<std::vector<std::string>>();
      object.meshFile = rj.value("mesh", "");
      if (const auto o = rj.find("fileOrigin"); o != rj.end() && o->is_array() && o->size() == 3)
        object.fileOrigin = {(*o)[0].get<double>(), (*o)[1].get<double>(), (*o)[2].get<double>()};
      if (const auto plate = header.find("plate"); plate != header.end() && plate->is_object()) {
        object.layerPlateFile = plate->value("file", "");
        object.layerPlateKey = plate->value("content", "");
        const auto card = rj.find("cardRadiance");
        if (card != rj.end() && card->is_number() && card->get<double>() > 0.0 &&
            std::isfinite(card->get<double>())) {
          object.cardRadiance = card->get<double>();
          object.layerPlateDecoded = plate->value("decoded", "");
          object.layerPlateSpace = plate->value("space", "");
        }
      }
      int x = 0, y = 0;
      const ingest::ExrPartHeader* objectHeader = nullptr;
      const Image layer = readPart("object", x, y, &objectHeader);
      const auto beautyNames = rj.at("beautyChannels").get<std::vector<std::string>>();
      const auto aovNames = rj.at("aovChannels").get<std::vector<std::string>>();
      if (beautyNames.size() != 4 || layer.channels != int(4 + aovNames.size()))
        throw Error("composite",
                    format("the object part has %d channels; its header lists %zu", layer.channels,
                           beautyNames.size() + aovNames.size()),
                    file);
      // A tool that saved the layer again may have cropped the part to what it holds
      // (oiiotool --autotrim) or padded it to the frame (--croptofull): OpenEXR holds nothing
      // outside a data window, so the part's window is the object's.
      if (x != r.x0 || y != r.y0 || layer.width != r.x1 - r.x0 || layer.height != r.y1 - r.y0) {
        ctx.note(
            format("the object part holds %dx%d pixels at %d,%d, the render wrote %dx%d at "
                   "%d,%d: read as the file holds it (saved again by another tool?)",
                   layer.width, layer.height, x, y, r.x1 - r.x0, r.y1 - r.y0, r.x0, r.y0));
        r.x0 = x;
        r.y0 = y;
        r.x1 = x + layer.width;
        r.y1 = y + layer.height;
      }
      r.beauty = Image(layer.width, layer.height, 4, beautyNames);
      r.aovs = Image(layer.width, layer.height, int(aovNames.size()), aovNames);
      r.beauty.colorSpace = rj.at("colorSpace").get<std::string>();
      if (r.beauty.colorSpace != ctx.colors.workingSpace()) {
        throw Error("composite",
                    "the object layer was rendered in the working space '" + r.beauty.colorSpace +
                        "'; this run's is '" + ctx.colors.workingSpace() +
                        "' (config: " + ctx.colors.source() +
                        "): composite under the colour config the layer was rendered with (the "
                        "same --ocio or $OCIO)",
                    file);
      }
      // OpenEXR keeps channels in its own order: find each by the name it was written under
      // (object.R ...; R ... in layers written before the names followed the one-shot EXR's).
      std::vector<std::string> written = {"object.R", "object.G", "object.B", "object.A"};
      written.insert(written.end(), aovNames.begin(), aovNames.end());
      std::vector<size_t> from;
      for (size_t k = 0; k < written.size(); ++k) {
        const std::string& name = written[k];
        auto it = std::find(layer.channelNames.begin(), layer.channelNames.end(), name);
        if (it == layer.channelNames.end() && k < 4)
          it = std::find(layer.channelNames.begin(), layer.channelNames.end(), name.substr(7));
        if (it == layer.channelNames.end())
          throw Error("composite", "the object part has no channel '" + name + "'", file);
        from.push_back(size_t(it - layer.channelNames.begin()));
      }
      const size_t n = aovNames.size();
      for (size_t i = 0; i < layer.pixelCount(); ++i) {
        const float* s = layer.pixels.data() + i * size_t(layer.channels);
        for (size_t c = 0; c < 4; ++c) r.beauty.pixels[4 * i + c] = s[from[c]];
        for (size_t c = 0; c < n; ++c) r.aovs.pixels[n * i + c] = s[from[4 + c]];
      }
      requireValid(layer, x, y, "object", int(from[3]), false);
      // The colour may have been converted after the render (a compositing tool's working space):
      // the part's chromaticities then differ from the working space's, and the colours (the
      // object's light, its albedo and irradiance) are brought back by matrix, as a plate is.
      if (const ingest::ImageAttribute* a = objectHeader->find("chromaticities")) {
        const auto* v = std::get_if<std::vector<float>>(&a->value);
        const auto working = ctx.colors.chromaticities(ctx.colors.workingSpace());
        if (v && v->size() == 8 && working) {
          color::Chromaticities primaries{};
          double off = 0.0;
          for (size_t i = 0; i < 8; ++i) {
            primaries[i] = double((*v)[i]);
            off = std::max(off, std::abs(primaries[i] - (*working)[i]));
          }
          if (off > 1e-4) {  // float's rounding of the values written is far below
            color::requireRgbSpace(primaries, file);
            auto toWorking = [&](Image& rgb) {
              ctx.colors.convertFromChromaticities(rgb, primaries, ctx.colors.workingSpace(), file);
            };
            convertChannels(r.beauty, 0, toWorking);
            std::vector<std::string> converted = {"object"};
            for (const std::string& aov : colourAovLayers()) {
              const auto at = std::find(aovNames.begin(), aovNames.end(), aov + ".R");
              if (at == aovNames.end()) continue;
              convertChannels(r.aovs, size_t(at - aovNames.begin()), toWorking);
              converted.push_back(aov);
            }
            const std::string named = ctx.colors.spaceWithChromaticities(primaries);
            std::string list;
            for (const std::string& c : converted) list += (list.empty() ? "" : ", ") + c;
            ctx.note("the object part's chromaticities are " +
                     (named.empty() ? std::string("another space's") : "those of '" + named + "'") +
                     ", not those of '" + r.beauty.colorSpace +
                     "' it was rendered in (converted after the render?): " + list +
                     " brought to the working space by matrix");
          }
        }
      }
      // How the render chose the exposure (the layer's own --exposure, if any, was given there).
      for (const auto& note : object.notes) ctx.note("the layer's render: " + note);
      ctx.artefacts.object = std::move(object);

      GroundShadowResult ground;
      const nlohmann::json& gj = header.at("ground");
      if (gj.is_object() && gj.contains("x0")) {
        ground.grid.x0 = int(whole(gj, "x0"));
        ground.grid.y0 = int(whole(gj, "y0"));
        ground.grid.x1 = int(whole(gj, "x1"));
        ground.grid.y1 = int(whole(gj, "y1"));
        ground.ratio = readPart("shadow", x, y);
        ground.ratio.channelNames = gj.at("channels").get<std::vector<std::string>>();
        // Padded by a tool that saved the layer again (oiiotool --croptofull): the grid's pixels
        // are taken from it; outside the grid there is no shadow, whatever the padding holds.
        const int gridWidth = ground.grid.x1 - ground.grid.x0,
                  gridHeight = ground.grid.y1 - ground.grid.y0;
        if ((x != ground.grid.x0 || y != ground.grid.y0 || ground.ratio.width != gridWidth ||
             ground.ratio.height != gridHeight) &&
            x <= ground.grid.x0 && y <= ground.grid.y0 && gridWidth > 0 && gridHeight > 0 &&
            x + ground.ratio.width >= ground.grid.x1 && y + ground.ratio.height >= ground.grid.y1) {
          Image cropped(gridWidth, gridHeight, ground.ratio.channels, ground.ratio.channelNames);
          const size_t rowFloats = size_t(gridWidth) * size_t(ground.ratio.channels);
          for (int yy = 0; yy < gridHeight; ++yy)
            std::memcpy(cropped.row(yy).data(),
                        ground.ratio.row(ground.grid.y0 - y + yy).data() +
                            size_t(ground.grid.x0 - x) * size_t(ground.ratio.channels),
                        rowFloats * sizeof(float));
          ground.ratio = std::move(cropped);
          x = ground.grid.x0;
          y = ground.grid.y0;
        }
        if (x != ground.grid.x0 || y != ground.grid.y0 ||
            ground.ratio.width != ground.grid.x1 - ground.grid.x0 ||
            ground.ratio.height != ground.grid.y1 - ground.grid.y0 || ground.ratio.channels < 3 ||
            int(ground.ratio.channelNames.size()) != ground.ratio.channels)
          throw Error("composite",
                      format("the shadow part holds %dx%d pixels at %d,%d in %d channels; its "
                             "header says %dx%d at %d,%d in %zu (a ratio of 1 is no shadow: "
                             "the part cannot be cropped, only padded)",
                             ground.ratio.width, ground.ratio.height, x, y, ground.ratio.channels,
                             ground.grid.x1 - ground.grid.x0, ground.grid.y1 - ground.grid.y0,
                             ground.grid.x0, ground.grid.y0, ground.ratio.channelNames.size()),
                      file);
        requireValid(ground.ratio, x, y, "shadow", -1, true);
        ground.ratio.colorSpace = gj.value("colorSpace", "");
      }
      if (gj.is_object()) {
        ground.reason = gj.value("reason", "");
        ctx.artefacts.groundShadow = std::move(ground);
      }
      ctx.setGeometry(geometry);
    } catch (const nlohmann::json::exception& e) {
      throw Error("composite",
                  std::string("the object layer's header is damaged: ") + jsonMessage(e.what()),
                  file);
    }
    keyFromFile(ctx, file, {kObject, kGroundShadow, kSelfShadowing}, "composite");
    requireSameFile(file, identity, "composite");
  };
  return in;
}

}  // namespace compose::pipeline
