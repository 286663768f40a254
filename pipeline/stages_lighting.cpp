// The stages that light the object: precompute (the environment projected onto the lighting
// basis, and the shadow lighting), shadows (on the object itself), ground (its shadow on the
// plate).
#include <algorithm>
#include <numbers>
#include <span>

#include "core/error.h"
#include "core/json_number.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "core/params.h"
#include "lighting/capture_volume.h"
#include "lighting/environment.h"
#include "lighting/lighting_cache.h"
#include "lighting/order_selector.h"
#include "pipeline/context.h"
#include "pipeline/stage.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_util.h"
#include "pipeline/stages.h"
#include "render/transfer.h"

#include <glm/gtc/matrix_transform.hpp>

namespace compose::pipeline {

namespace fs = std::filesystem;
using namespace artefact;

namespace {

bool wantsShadowLighting(const ComposeJob& job) {
  return job.shadows || job.groundShadow;
}

// The job's lighting basis. order=auto (with an optional target=dB, default 45) takes the order
// from the environment's own tail energy (`environment` given) or from `order` (a cached choice).
struct BasisChoice {
  std::unique_ptr<lighting::DiffuseLighting> basis;
  int order = 0;  // the order chosen by order=auto; 0 otherwise
  std::string note;
};
BasisChoice createBasis(const ComposeJob& job, const lighting::Environment* environment,
                        int cachedOrder = 0) {
  ParamSet params = ParamSet::parse(job.lightingParams, "lighting");
  const bool autoOrder = params.is("order", "auto");
  BasisChoice out;
  if (!autoOrder) {
    out.basis = lighting::createLighting(job.lighting, params);
    return out;
  }
  const double targetDb = params.getDouble("target", 45.0, "lighting");
  params.erase("order");
  params.erase("target");
  if (environment) {
    const auto estimates = lighting::estimateOrders(job.lighting, *environment, params);
    const lighting::OrderEstimate pick = lighting::selectOrder(estimates, targetDb);
    out.order = pick.order;
    if (std::isfinite(pick.estimatedSnrDb)) {
      out.note =
          format("order=auto: %s order %d, estimated truncation SNR %.1f dB (target %.1f dB)",
                 job.lighting.c_str(), pick.order, pick.estimatedSnrDb, targetDb);
    } else {
      // The highest order has no tail above it to estimate from.
      out.note = format(
          "order=auto: %s order %d, the highest it takes; whether it reaches the target (%.1f dB) "
          "cannot be estimated (no higher orders to measure the tail with)",
          job.lighting.c_str(), pick.order, targetDb);
    }
  } else {
    out.order = cachedOrder;
  }
  params.set("order", std::to_string(out.order));
  out.basis = lighting::createLighting(job.lighting, params);
  return out;
}

void hashProxy(const Context& ctx, Hash128& h) {
  const lighting::CaptureProxy proxy = ctx.captureProxy();
  h.word(uint32_t(proxy.shape));
  if (proxy.shape == lighting::CaptureProxy::Shape::Distant) return;
  hashVector(h, proxy.capturePoint);
  hashVector(h, proxy.boxMin);
  hashVector(h, proxy.boxMax);
  h.number(proxy.radius);
  // Said in the stage's notes: entries made when every unit was said as metres are not reused
  // (the pose file's bytes are in the geometry's key already).
  h.bytes(proxy.unit);
  h.combine(ctx.geometryKey());  // the object's centre
}

std::vector<float> sourcesToFloats(const std::vector<lighting::LightSource>& sources) {
  std::vector<float> out;
  for (const auto& s : sources) {
    out.insert(out.end(), {s.direction.x, s.direction.y, s.direction.z, s.power.x, s.power.y,
                           s.power.z, s.halfLatitude, s.halfLongitude});
  }
  return out;
}

std::vector<lighting::LightSource> sourcesFromFloats(std::span<const float> v) {
  std::vector<lighting::LightSource> out;
  for (size_t i = 0; i + 8 <= v.size(); i += 8) {
    lighting::LightSource s;
    s.direction = glm::vec3(v[i], v[i + 1], v[i + 2]);
    s.power = glm::vec3(v[i + 3], v[i + 4], v[i + 5]);
    s.halfLatitude = v[i + 6];
    s.halfLongitude = v[i + 7];
    out.push_back(s);
  }
  return out;
}

std::vector<float> vec3sToFloats(const std::vector<glm::vec3>& v) {
  std::vector<float> out(3 * v.size());
  for (size_t i = 0; i < v.size(); ++i) {
    out[3 * i] = v[i].x;
    out[3 * i + 1] = v[i].y;
    out[3 * i + 2] = v[i].z;
  }
  return out;
}

std::vector<glm::vec3> vec3sFromFloats(std::span<const float> v) {
  std::vector<glm::vec3> out(v.size() / 3);
  for (size_t i = 0; i < out.size(); ++i) out[i] = glm::vec3(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
  return out;
}

// ---------------------------------------------------------------------------------------------

class PrecomputeStage final : public Stage {
 public:
  std::string memoryAdvice() const override {
    return "a large environment (--max-pixels refuses larger ones before they are read; a "
           "smaller copy lights the object as well: oiiotool IN --resize 2048x1024 -o OUT), or "
           "the lighting's tables, which grow with its parameters: cheb-local holds order^2 x "
           "rows x cols x 3 floats (--lighting-params order, rows, cols; 1 x 33 x 64 by "
           "default), and the shadows' lighting --shadow-params order^2 x 33 x 64 x 3";
  }
  std::string name() const override { return "precompute"; }
  std::string summary() const override {
    return "project the environment onto the lighting basis (Chebyshev moments by default), and "
           "split off its brightest sources for the shadows";
  }
  // With parallax, what the environment is seen as (--explain said nothing of it).
  std::string planned(const Context& ctx) const override {
    const lighting::CaptureProxy proxy = ctx.captureProxy();
    if (proxy.shape == lighting::CaptureProxy::Shape::Distant) return summary();
    return "project the environment as seen from the object's centre (parallax: " +
           proxy.describe() +
           ") onto the lighting basis (Chebyshev moments by default), and split off its "
           "brightest sources for the shadows";
  }
  std::vector<std::string> inputs() const override { return {kEnvironment, kPlate, kMesh}; }
  std::vector<std::string> inputsFor(const std::string&) const override {
    return {kEnvironment};  // plate and mesh only place the object for parallax; always read
  }
  std::vector<std::string> outputs() const override { return {kLighting, kShadowLighting}; }
  std::vector<StageParameter> parameters() const override {
    return {
        {"lighting",
         "the lighting basis: " +
             [] {
               std::string names;
               for (const auto& n : lighting::lightingNames())
                 names += (names.empty() ? "" : ", ") + n;
               return names;
             }(),
         [](const ComposeJob& j) { return nlohmann::json(j.lighting); },
         [](ComposeJob& j, const nlohmann::json& v) {
           if (!v.is_string()) throw UsageError("lighting must be a basis name (a string)");
           j.lighting = v.get<std::string>();
         }},
        {"lighting-params", "the basis' parameters, key=value,...",
         [](const ComposeJob& j) { return nlohmann::json(j.lightingParams); },
         [](ComposeJob& j, const nlohmann::json& v) {
           if (!v.is_string()) throw UsageError("lighting-params must be a string");
           j.lightingParams = v.get<std::string>();
         }},
        {"env-yaw", "turn of the environment about the vertical, degrees",
         [](const ComposeJob& j) { return nlohmann::json(j.environmentYawDegrees); },
         [](ComposeJob& j, const nlohmann::json& v) {
           if (!v.is_number()) throw UsageError("env-yaw must be a number of degrees");
           j.environmentYawDegrees = v.get<double>();
         }},
        {"room",
         "parallax: a room of [W, H, D] metres around the plate camera (the pose's units "
         "around its board with a pose), or null",
         [](const ComposeJob& j) {
           return j.room ? nlohmann::json({j.room->x, j.room->y, j.room->z})
                         : nlohmann::json(nullptr);
         },
         [](ComposeJob& j, const nlohmann::json& v) {
           if (v.is_null()) return j.room.reset();
           if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() ||
               !v[2].is_number())
             throw UsageError("room must be [W, H, D] in metres");
           j.room = glm::dvec3(v[0].get<double>(), v[1].get<double>(), v[2].get<double>());
         }},
        {"env-radius", "parallax: a sphere of this radius (metres, or the pose's units), or null",
         [](const ComposeJob& j) {
           return j.environmentRadius ? nlohmann::json(*j.environmentRadius)
                                      : nlohmann::json(nullptr);
         },
         [](ComposeJob& j, const nlohmann::json& v) {
           if (v.is_null()) return j.environmentRadius.reset();
           if (!v.is_number()) throw UsageError("env-radius must be a number of metres");
           j.environmentRadius = v.get<double>();
         }},
        {"capture-at",
         "where the environment was captured, [X, Y, Z] metres (the pose's units and frame "
         "with a pose), or null",
         [](const ComposeJob& j) {
           return j.captureAt ? nlohmann::json({j.captureAt->x, j.captureAt->y, j.captureAt->z})
                              : nlohmann::json(nullptr);
         },
         [](ComposeJob& j, const nlohmann::json& v) {
           if (v.is_null()) return j.captureAt.reset();
           if (!v.is_array() || v.size() != 3 || !v[0].is_number() || !v[1].is_number() ||
               !v[2].is_number())
             throw UsageError("capture-at must be [X, Y, Z] in metres");
           j.captureAt = glm::dvec3(v[0].get<double>(), v[1].get<double>(), v[2].get<double>());
         }}};
  }

  // The bright sources split off for the shadows. 2: none from a map whose texels span more than
  // 12°.
  static constexpr int kSourcesVersion = 2;

  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("lighting");
    h.word(lighting::LightingCache::kProjectionVersion);
    h.combine(ctx.key(kEnvironment));
    h.bytes(ctx.job.lighting);
    h.bytes(ctx.job.lightingParams);
    hashProxy(ctx, h);
    ctx.keys[kLighting] = h;
    if (wantsShadowLighting(ctx.job)) {
      Hash128 s;
      s.bytes("shadow-lighting");
      s.word(lighting::LightingCache::kProjectionVersion);
      s.word(kSourcesVersion);
      s.combine(ctx.key(kEnvironment));
      s.bytes(ShadowPlan::parse(ctx.job.shadowParams).lightingKey());
      hashProxy(ctx, s);
      ctx.keys[kShadowLighting] = s;
    }
  }

  bool cached() const override { return true; }

  bool load(Context& ctx, StageCache& cache) const override {
    const nlohmann::json& meta = cache.meta();
    if (ctx.needs(kLighting)) {
      if (!meta.contains("lighting")) return false;
      const nlohmann::json& lj = meta["lighting"];
      const std::optional<int64_t> order = lj.is_object() && lj.contains("order")
                                               ? wholeMember(lj, "order", 0, 4096)
                                               : std::optional<int64_t>(0);
      if (!order) return false;
      BasisChoice choice = createBasis(ctx.job, nullptr, int(*order));
      if (!choice.basis->importState(cache.get("lighting")) ||
          !lighting::LightingCache::finiteIrradiance(*choice.basis))
        return false;
      ctx.artefacts.lighting = std::move(choice.basis);
      // What order=auto chose goes on to the lighting file (compose precompute) and to the
      // next store, as when it is computed.
      ctx.artefacts.lightingOrder = int(*order);
    }
    if (ctx.needs(kShadowLighting)) {
      if (!meta.contains("shadowLighting")) return false;
      ShadowLighting sl = shadowLightingFor(ShadowPlan::parse(ctx.job.shadowParams));
      if (!sl.lighting->importState(cache.get("shadowBasis")) ||
          !lighting::LightingCache::finiteIrradiance(*sl.lighting))
        return false;
      sl.split.sources = sourcesFromFloats(cache.get("sources"));
      sl.split.sourceShare = meta["shadowLighting"].value("sourceShare", 0.0);
      sl.reason = meta["shadowLighting"].value("reason", "");
      ctx.artefacts.shadowLighting = std::move(sl);
    }
    return true;
  }

  bool store(const Context& ctx, StageCache& cache) const override {
    if (ctx.artefacts.lighting) {
      std::vector<float> state;
      if (!ctx.artefacts.lighting->exportState(state)) return false;  // cheaper to project
      cache.put("lighting", std::move(state));
      cache.meta()["lighting"] = {{"order", ctx.artefacts.lightingOrder}};
    }
    if (ctx.artefacts.shadowLighting) {
      const ShadowLighting& sl = *ctx.artefacts.shadowLighting;
      std::vector<float> state;
      if (!sl.lighting->exportState(state)) return false;
      cache.put("shadowBasis", std::move(state));
      cache.put("sources", sourcesToFloats(sl.split.sources));
      cache.meta()["shadowLighting"] = {{"sourceShare", sl.split.sourceShare},
                                        {"reason", sl.reason}};
    }
    return cache.write();
  }

  std::string run(Context& ctx) const override {
    lighting::SanitizeReport sanitized;
    lighting::Environment environment = lighting::Environment::fromLatLong(
        *ctx.artefacts.environment, ctx.environmentInput.path, &sanitized);
    ctx.artefacts.environment.reset();  // nothing after this stage reads the pixels
    if (sanitized.negativeTexels > 0) ctx.note(sanitized.negativeNote("environment "));
    // An environment without light lights nothing: the object would render black and the auto
    // exposure would have nothing to match.
    const std::vector<float>& texels = environment.texels();
    if (std::none_of(texels.begin(), texels.end(), [](float v) { return v > 0.0f; })) {
      throw Error(
          "lighting",
          std::string("the environment holds no light: every texel is 0") +
              (sanitized.negativeTexels > 0 ? " once its negative values are clamped" : "") +
              "; nothing would light the object",
          ctx.environmentInput.path);
    }
    // Light so dim that single precision loses it on the way (products of texels and weights fall
    // below float's 1.2e-38): the object rendered black while the exposure said it matched.
    constexpr float kDimmest = 1e-20f;
    if (const float brightest = *std::max_element(texels.begin(), texels.end());
        brightest < kDimmest) {
      throw Error("lighting",
                  "the environment's brightest texel is " + numberText(brightest) +
                      ", too dim to light anything in single precision (below 1e-20: a scale "
                      "lost on the way?); scale it up (oiiotool IN --mulc 1e20 -o OUT)",
                  ctx.environmentInput.path);
    }
    // A map stored upside down lights the object from below, in silence. Ground lit by the sky
    // reflects at most what falls on it: below the horizon a map is darker on average (the
    // sample maps 0.08-0.44 times; the same maps upside down 2.3-12 times).
    if (const double ratio = environment.belowOverAbove(); ratio > 1.5) {
      ctx.note(format(
          "warning: the environment %s is %.1f times as bright below its horizon as above it (mean "
          "radiance over each half), where the ground reflects at most the sky's light: if it is "
          "upside down, turn it (a lat-long map: oiiotool IN --flip -o OUT), else the object is "
          "lit from below as the map says",
          ctx.environmentInput.path.filename().string().c_str(), ratio));
    }
    if (const lighting::CaptureProxy proxy = ctx.captureProxy();
        proxy.shape != lighting::CaptureProxy::Shape::Distant) {
      // Parallax: the environment as seen from the object's centre.
      const Geometry& g = ctx.geometry();
      const MeshSummary& mesh = *ctx.meshSummary;
      const glm::dvec3 centre = ctx.objectCentre();
      lighting::CaptureProxy placed = proxy;
      placed.environmentFromWorld = glm::dmat3(g.envFromWorld);
      environment = lighting::CaptureVolumeSource(environment, placed).at(glm::vec3(centre));
      ctx.note(format("parallax: the environment as seen from the object's centre (%.2f, %.2f, "
                      "%.2f) %s; surroundings: ",
                      centre.x, centre.y, centre.z, ctx.lengthUnit().c_str()) +
               proxy.describe());
      // The object is inside the surroundings, or it would show through their walls. Its
      // corners are taken a millionth of its size towards its centre: it stands on the floor
      // (y = 0, the room's floor too), which is not outside.
      bool inside = true;
      const glm::dvec3 middle = 0.5 * glm::dvec3(mesh.boundsMin + mesh.boundsMax);
      for (int corner = 0; corner < 8; ++corner) {
        const glm::dvec3 local((corner & 1) ? mesh.boundsMax.x : mesh.boundsMin.x,
                               (corner & 2) ? mesh.boundsMax.y : mesh.boundsMin.y,
                               (corner & 4) ? mesh.boundsMax.z : mesh.boundsMin.z);
        const glm::dvec3 in = local + 1e-6 * (middle - local);
        inside = inside && proxy.contains(glm::dvec3(g.worldFromObject * glm::dvec4(in, 1.0)));
      }
      if (!proxy.contains(centre)) {
        ctx.note(
            "warning: the object's centre is outside the surroundings given: it is lit as from "
            "the nearest point inside them");
      } else if (!inside) {
        ctx.note(
            "warning: the object reaches outside the surroundings given (through a wall, the "
            "ceiling or the sphere): a smaller --scale, or larger surroundings");
      }
    }
    // Every output this job has is computed, so that the cache entry is whole.
    std::string reason;
    {
      BasisChoice choice = createBasis(ctx.job, &environment);
      if (!choice.note.empty()) ctx.note(choice.note);
      // Lambertian cheb-local shading takes the zeroth moment alone (every other moment of the
      // Lambertian BRDF vanishes): a higher order or another grid changes nothing in the picture.
      if (ctx.job.lighting == "cheb-local") {
        ParamSet p = ParamSet::parse(ctx.job.lightingParams, "lighting");
        if (!p.has("brdf") || p.is("brdf", "lambert")) {
          std::string given;
          if (p.has("order") && !p.is("order", "1") && !p.is("order", "auto")) given = "order";
          if (p.has("samples")) given += given.empty() ? "samples" : " and samples";
          if (!given.empty())
            ctx.note(
                "cheb-local with the Lambertian BRDF shades by the zeroth Chebyshev moment "
                "alone (the BRDF's other moments vanish): " +
                given + (given == "order" || given == "samples" ? " changes" : " change") +
                " nothing in the picture, only the table's size; its accuracy is "
                "set by rows and cols (the self-shadowing's order is --shadow-params "
                "order)");
        }
      }
      ctx.artefacts.lightingOrder = choice.order;
      choice.basis->project(environment, ctx.progress);
      reason = "projected the environment: " + choice.basis->describe();
      ctx.artefacts.lighting = std::move(choice.basis);
    }
    if (ctx.hasKey(kShadowLighting)) {
      ctx.artefacts.shadowLighting = prepareShadowLighting(
          environment, ShadowPlan::parse(ctx.job.shadowParams), {}, ctx.progress);
      for (std::string& n : ctx.artefacts.shadowLighting->notes) ctx.runNote(std::move(n));
      ctx.artefacts.shadowLighting->notes.clear();
      reason +=
          (reason.empty() ? "" : "; shadow lighting: ") + ctx.artefacts.shadowLighting->reason;
    }
    return reason;
  }
};

// ---------------------------------------------------------------------------------------------

class ShadowsStage final : public Stage {
 public:
  std::string memoryAdvice() const override {
    return "the visibility pass holds order^2 floats a surface point (--shadow-params order; "
           "refine-budget bounds the points added, --max-triangles the mesh)";
  }
  // 2: the sources' visibility per point kept; 3: points refined where visibility changes fast;
  // 4: refined points in the order of their triangles (entries of 3 held their values in another
  // order than the points read back); 5: a shadow edge's cell keeps its first ray as one of its
  // strata; 6: SH transfer projected cell by cell.
  // 7: the ground beneath a cut-out at what it keeps; 8: sources traced again across their
  // penumbrae, the points that see them in part marked; 9: points inside another part of the
  // object left out of the interpolation; 10: triangles' grid points on the smooth surface of
  // the vertex normals; 11: that lift bounded and checked for parts in the way; 12: keyed by
  // every shadow parameter (sh's and ao's grid, the boundary rays and the refinement's budget
  // reused the shadows of other values); 13: each grid node's lighting moments dotted with the
  // transfer, then interpolated (the same sum in another order: last-bit differences)
  static constexpr int kVersion = 13;

  std::string name() const override { return "shadows"; }
  std::string summary() const override {
    return "the object's shadows on itself: a visibility pass at its surface points (Chebyshev "
           "transfer) and exact rays to the bright sources";
  }
  std::vector<std::string> inputs() const override { return {kMesh, kPlate, kShadowLighting}; }
  std::vector<std::string> outputs() const override { return {kSelfShadowing}; }
  std::vector<StageParameter> parameters() const override {
    return {{"shadows",
             "self (the object shadows itself and the ground beneath darkens it; skipped when it "
             "is convex and ground=off) or off",
             [](const ComposeJob& j) { return nlohmann::json(j.shadows ? "self" : "off"); },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (!v.is_string() || (v != "self" && v != "off"))
                 throw UsageError("shadows must be \"self\" or \"off\"");
               j.shadows = v == "self";
             }},
            {"shadow-params",
             "method=cheb|sh|ao, order, grid, boundary, sources, refine, refine-budget, "
             "ground=on|off",
             [](const ComposeJob& j) { return nlohmann::json(j.shadowParams); },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (!v.is_string()) throw UsageError("shadow-params must be a string");
               j.shadowParams = v.get<std::string>();
             }}};
  }

  std::string skip(const Context& ctx) const override {
    if (!ctx.job.shadows) return "--shadows off";
    if (ctx.meshSummary && ctx.meshSummary->convex &&
        !ShadowPlan::parse(ctx.job.shadowParams).ground)
      return "the object is closed and convex: it cannot shadow itself (and ground=off)";
    return {};
  }
  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("self-shadowing");
    h.word(kVersion);
    h.combine(ctx.key(kMesh));
    h.combine(ctx.key(kShadowLighting));
    h.bytes(ShadowPlan::parse(ctx.job.shadowParams).key());
    h.number(ctx.job.placement.yawDegrees);
    h.number(ctx.job.environmentYawDegrees);
    ctx.keys[kSelfShadowing] = h;
  }
  bool cached() const override { return true; }
  bool load(Context& ctx, StageCache& cache) const override {
    ShadowResult r;
    r.points = render::surfacePoints(ctx.mesh());
    // The triangles' levels, as the visibility pass refined them.
    const std::span<const float> stored = cache.get("levels");
    std::vector<uint8_t> levels;
    for (const float v : stored) {
      if (!(v >= 1.0f && v <= 32.0f) || v != std::floor(v)) return false;
      levels.push_back(uint8_t(v));
    }
    if (!render::restoreLevels(ctx.mesh(), r.points, levels)) return false;
    for (const float v : cache.get("buried")) {
      if (v != 0.0f && v != 1.0f) return false;
      r.points.buried.push_back(uint8_t(v));
    }
    if (r.points.buried.size() != r.points.count()) return false;
    r.irradiance.shadowed = vec3sFromFloats(cache.get("shadowed"));
    r.irradiance.unshadowed = vec3sFromFloats(cache.get("unshadowed"));
    r.irradiance.clamped = int(wholeMember(cache.meta(), "clamped", 0).value_or(0));
    const std::span<const float> occlusion = cache.get("occlusion");
    r.occlusion.assign(occlusion.begin(), occlusion.end());
    const size_t n = r.points.count();
    if (r.irradiance.shadowed.size() != n || r.irradiance.unshadowed.size() != n ||
        r.occlusion.size() != n)
      return false;
    r.sources = sourcesFromFloats(cache.get("sources"));
    if (r.sources.size() > size_t(lighting::kMaxSources)) return false;
    for (const lighting::LightSource& l : r.sources) {
      const bool ok = std::abs(glm::length(l.direction) - 1.0f) < 1e-3f &&
                      glm::all(glm::greaterThanEqual(l.power, glm::vec3(0.0f))) &&
                      std::isfinite(l.power.x + l.power.y + l.power.z) && l.halfLatitude >= 0.0f &&
                      l.halfLatitude <= 4.0f && l.halfLongitude >= 0.0f && l.halfLongitude <= 4.0f;
      if (!ok) return false;
    }
    // Each point's 64 bits of sources seen, and seen in part, in four 16-bit parts (exact in a
    // float).
    r.irradiance.sourceCount = r.sources.size();
    const uint64_t known =
        r.sources.size() >= 64 ? ~uint64_t(0) : (uint64_t(1) << r.sources.size()) - 1;
    for (const auto& [name, bitsOf] :
         {std::pair<const char*, std::vector<uint64_t>*>{"sourceSeen", &r.irradiance.sourceSeen},
          {"sourcePartial", &r.irradiance.sourcePartial}}) {
      const std::span<const float> parts = cache.get(name);
      if (parts.size() != (r.sources.empty() ? 0 : 4 * n)) return false;
      bitsOf->assign(r.sources.empty() ? 0 : n, 0);
      for (size_t i = 0; i < parts.size(); ++i) {
        if (!(parts[i] >= 0.0f && parts[i] <= 65535.0f) || parts[i] != std::floor(parts[i]))
          return false;
        (*bitsOf)[i / 4] |= uint64_t(parts[i]) << (16 * (i % 4));
      }
      for (const uint64_t bits : *bitsOf)
        if (bits & ~known) return false;  // a source that is not there
    }
    const std::span<const float> fractions = cache.get("sourceFraction");
    r.irradiance.partialFraction.assign(fractions.begin(), fractions.end());
    if (!r.sources.empty() && !r.irradiance.indexPartial()) return false;
    ctx.artefacts.selfShadowing = std::move(r);
    return true;
  }
  bool store(const Context& ctx, StageCache& cache) const override {
    const ShadowResult& r = *ctx.artefacts.selfShadowing;
    cache.put("shadowed", vec3sToFloats(r.irradiance.shadowed));
    cache.put("unshadowed", vec3sToFloats(r.irradiance.unshadowed));
    cache.put("occlusion", r.occlusion);
    cache.put("levels", std::vector<float>(r.points.level.begin(), r.points.level.end()));
    cache.put("buried", std::vector<float>(r.points.buried.begin(), r.points.buried.end()));
    cache.put("sources", sourcesToFloats(r.sources));
    for (const auto& [name, bitsOf] : {std::pair<const char*, const std::vector<uint64_t>*>{
                                           "sourceSeen", &r.irradiance.sourceSeen},
                                       {"sourcePartial", &r.irradiance.sourcePartial}}) {
      std::vector<float> parts;
      parts.reserve(4 * bitsOf->size());
      for (const uint64_t bits : *bitsOf)
        for (int part = 0; part < 4; ++part)
          parts.push_back(float((bits >> (16 * part)) & 0xFFFFu));
      cache.put(name, parts);
    }
    cache.put("sourceFraction", r.irradiance.partialFraction);
    cache.meta()["clamped"] = r.irradiance.clamped;
    return cache.write();
  }

  std::string run(Context& ctx) const override {
    const ShadowPlan plan = ShadowPlan::parse(ctx.job.shadowParams);
    ShadowResult r = computeSelfShadowing(
        ctx.mesh(), ctx.objectScene(), *ctx.artefacts.shadowLighting, ctx.geometry().envFromObject,
        plan, ctx.job.cache, ctx.progress, ctx.meshSummary && ctx.meshSummary->convex);
    for (std::string& n : r.notes) ctx.runNote(std::move(n));
    r.notes.clear();
    if (r.irradiance.clamped > 0) {
      ctx.note(std::to_string(r.irradiance.clamped) +
               " vertices' shadowed irradiance rang outside [0, unshadowed] (truncation) and was "
               "clamped");
    }
    const std::string reason = plan.describe() + ": " + r.reason;
    ctx.artefacts.selfShadowing = std::move(r);
    return reason;
  }
};

// ---------------------------------------------------------------------------------------------

// The ratio cut to the rectangle where it is below 1 (the shadow), and the grid's rectangle with
// it; no ratio at all when the object casts no shadow on the ground in the frame. The rest of the
// grid is ground the object does not shade (the sky above the horizon, ground beyond the shadow):
// 1 there, the plate unchanged, nothing to multiply or to write.
void cropToShadow(GroundShadowResult& r) {
  const Image& ratio = r.ratio;
  if (ratio.empty()) return;
  std::vector<int> first(size_t(ratio.height), ratio.width), last(size_t(ratio.height), -1);
  parallelFor(0, ratio.height, [&](int64_t y) {
    const std::span<const float> row = ratio.row(int(y));
    for (int x = 0; x < ratio.width; ++x) {
      const float* p = row.data() + size_t(x) * size_t(ratio.channels);
      bool shaded = false;
      for (int c = 0; c < ratio.channels; ++c) shaded = shaded || p[c] != 1.0f;
      if (!shaded) continue;
      first[size_t(y)] = std::min(first[size_t(y)], x);
      last[size_t(y)] = x;
    }
  });
  int x0 = ratio.width, x1 = -1, y0 = -1, y1 = -1;
  for (int y = 0; y < ratio.height; ++y) {
    if (last[size_t(y)] < 0) continue;
    if (y0 < 0) y0 = y;
    y1 = y;
    x0 = std::min(x0, first[size_t(y)]);
    x1 = std::max(x1, last[size_t(y)]);
  }
  if (y0 < 0) {
    r.ratio = Image();
    return;
  }
  if (x0 == 0 && y0 == 0 && x1 == ratio.width - 1 && y1 == ratio.height - 1) return;
  Image cut(x1 + 1 - x0, y1 + 1 - y0, ratio.channels, ratio.channelNames);
  cut.colorSpace = ratio.colorSpace;
  parallelFor(0, cut.height, [&](int64_t y) {
    const float* s = ratio.at(x0, y0 + int(y));
    std::copy_n(s, size_t(cut.width) * size_t(cut.channels), cut.row(int(y)).data());
  });
  r.grid.x0 += x0;
  r.grid.y0 += y0;
  r.grid.x1 = r.grid.x0 + cut.width;
  r.grid.y1 = r.grid.y0 + cut.height;
  r.ratio = std::move(cut);
}

class GroundStage final : public Stage {
 public:
  // 2: the ratio cut to where it is below 1; 3: refined across sharp shadow edges; 4: the
  // object's rotation normalised in double (pipeline/context.cpp); 5: a shadow edge's cell keeps
  // its first ray as one of its strata; 6: points placed coarse to fine (render/ground.h);
  // 7: a strong source's shadow edge traced at the pixels of the finest cells it crosses;
  // 8: keyed by the boundary rays (--shadow-params boundary), which the ground's points take;
  // 9: keyed by every shadow parameter; 10: a band of ground a few rows high sampled row by row;
  // 11: a small region's pixels split into 4 x 4 and the ratio box-filtered; 12: a region
  // bounded by what the lens sees (not past its distortion's turning point)
  static constexpr int kVersion = 12;

  std::string name() const override { return "ground"; }
  std::string summary() const override {
    return "the object's shadow on the plate's ground, by differential rendering: the plate "
           "times E_with / E_without where the shadow can fall";
  }
  std::vector<std::string> inputs() const override { return {kMesh, kPlate, kShadowLighting}; }
  std::vector<std::string> outputs() const override { return {kGroundShadow}; }
  std::vector<StageParameter> parameters() const override {
    return {{"ground-shadow", "true: the object's shadow darkens the plate's ground",
             [](const ComposeJob& j) { return nlohmann::json(j.groundShadow); },
             [](ComposeJob& j, const nlohmann::json& v) {
               if (!v.is_boolean()) throw UsageError("ground-shadow must be true or false");
               j.groundShadow = v.get<bool>();
             }}};
  }

  std::string skip(const Context& ctx) const override {
    return ctx.job.groundShadow ? std::string() : "--no-shadow";
  }
  void keys(Context& ctx) const override {
    Hash128 h;
    h.bytes("ground-shadow");
    h.word(kVersion);
    h.combine(ctx.key(kShadowLighting));
    const ShadowPlan plan = ShadowPlan::parse(ctx.job.shadowParams);
    h.bytes(plan.lightingKey());
    h.combine(ctx.geometryKey());
    ctx.keys[kGroundShadow] = h;
  }
  bool cached() const override { return true; }
  // Its outputs are only read once made (by the composite and the output stages).
  bool storesWhileLaterStagesRun() const override { return true; }
  bool load(Context& ctx, StageCache& cache) const override {
    GroundShadowResult r;
    const nlohmann::json& m = cache.meta();
    const auto x0 = wholeMember(m, "x0"), y0 = wholeMember(m, "y0"), x1 = wholeMember(m, "x1"),
               y1 = wholeMember(m, "y1");
    if (!x0 || !y0 || !x1 || !y1) return false;
    r.grid.x0 = int(*x0);
    r.grid.y0 = int(*y0);
    r.grid.x1 = int(*x1);
    r.grid.y1 = int(*y1);
    r.reason = m.value("reason", "");
    if (m.value("hasRatio", false)) {
      if (!cache.takeImage("ratio", r.ratio)) return false;
      // The grid and the ratio it holds agree (the composite places the ratio by it).
      if (r.grid.x0 < 0 || r.grid.y0 < 0 || r.ratio.width != r.grid.x1 - r.grid.x0 ||
          r.ratio.height != r.grid.y1 - r.grid.y0 || r.ratio.channels < 3)
        return false;
    }
    ctx.artefacts.groundShadow = std::move(r);
    return true;
  }
  bool store(const Context& ctx, StageCache& cache) const override {
    const GroundShadowResult& r = *ctx.artefacts.groundShadow;
    cache.meta().update({{"x0", r.grid.x0},
                         {"y0", r.grid.y0},
                         {"x1", r.grid.x1},
                         {"y1", r.grid.y1},
                         {"reason", r.reason},
                         {"hasRatio", !r.ratio.empty()}});
    if (!r.ratio.empty()) cache.putImage("ratio", r.ratio);
    return cache.write();
  }

  std::string run(Context& ctx) const override {
    const Geometry& g = ctx.geometry();
    GroundShadowResult r = computeGroundShadow(
        ctx.mesh(), ctx.objectScene(), g.worldFromObject, g.camera, *ctx.artefacts.shadowLighting,
        g.envFromWorld, g.envFromObject, ShadowPlan::parse(ctx.job.shadowParams), ctx.progress);
    if (r.grid.empty()) r.ratio = Image();
    cropToShadow(r);
    std::string reason = r.reason;
    reason += r.ratio.empty()
                  ? "; no shadow falls in the frame"
                  : format("; the shadow covers %dx%d pixels", r.ratio.width, r.ratio.height);
    ctx.artefacts.groundShadow = std::move(r);
    return reason;
  }
};

}  // namespace

std::unique_ptr<Stage> makePrecomputeStage() {
  return std::make_unique<PrecomputeStage>();
}
std::unique_ptr<Stage> makeShadowsStage() {
  return std::make_unique<ShadowsStage>();
}
std::unique_ptr<Stage> makeGroundStage() {
  return std::make_unique<GroundStage>();
}

}  // namespace compose::pipeline
