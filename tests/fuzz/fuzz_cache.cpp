// The on-disk caches as a run finds them in its cache folder: the float caches (core/float_cache.h:
// lighting projections, lighting/lighting_cache.h, and visibility passes, pipeline/shadows.cpp) and
// the stage cache's entries (pipeline/stage_cache.h, with the images stages keep in them).
//
// The first byte chooses how the rest is used: even, as the raw bytes of a cache file (headers,
// versions, truncation, checksums); odd, as the floats of a well-formed entry that the target
// writes itself (so that fuzzing reaches what a loaded state does: importState and evaluation).
#include <cmath>

#include <glm/geometric.hpp>

#include "core/float_cache.h"
#include "core/output_files.h"
#include "core/params.h"
#include "fuzz_util.h"
#include "lighting/lighting.h"
#include "lighting/lighting_cache.h"
#include "pipeline/stage_cache.h"
#include "render/transfer.h"

using namespace compose;

namespace {

// A small cheb-local basis: a 3 x 4 table of normals, so that a well-formed state is short.
std::unique_ptr<lighting::DiffuseLighting> smallBasis() {
  ParamSet p = ParamSet::parse("rows=3,cols=4,samples=2,order=1", "lighting");
  return lighting::createLighting("cheb-local", p);
}

void checkIrradiance(const lighting::DiffuseLighting& basis) {
  for (const glm::vec3 n : {glm::vec3(0, 1, 0), glm::vec3(0, -1, 0), glm::vec3(1, 0, 0),
                            glm::normalize(glm::vec3(0.3f, -0.2f, 0.9f))}) {
    const glm::vec3 e = basis.irradiance(n);
    FUZZ_CHECK(std::isfinite(e.x) && std::isfinite(e.y) && std::isfinite(e.z));
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  if (size == 0) return 0;
  const std::filesystem::path folder = fuzz::scratch() / "cache";
  const lighting::LightingCache lightingCache(folder / "lighting");
  const FloatCache visibilityFiles(folder / "visibility", render::kTransferCacheMagic,
                                   ".visibility");
  const std::string key = "0123456789abcdef0123456789abcdef";
  auto basis = smallBasis();
  // Visibility of 3 points at order 2, SH band 0: 3 x (4 + 1 + 2) values (moments, SH, ambient
  // occlusion and the buried flag).
  render::TransferParams transfer;
  transfer.grid = 2;
  transfer.order = 2;
  transfer.shBands = 0;
  const std::string description = "transfer " + transfer.key() + " points 3";

  if (data[0] % 2 == 0) {
    std::filesystem::create_directories(folder / "lighting");
    std::filesystem::create_directories(folder / "visibility");
    fuzz::writeInput("cache/lighting/" + key + ".lighting", data + 1, size - 1);
    fuzz::writeInput("cache/visibility/" + key + ".visibility", data + 1, size - 1);
    std::filesystem::create_directories(folder / "stages" / "render");
    fuzz::writeInput("cache/stages/render/" + key + ".stage", data + 1, size - 1);
  } else {
    // A state of the basis' own size (or one off it), holding the input's floats.
    static const size_t stateSize = [] {
      auto b = smallBasis();
      b->project(lighting::Environment::constant(glm::vec3(1.0f), 4));
      std::vector<float> s;
      b->exportState(s);
      return s.size();
    }();
    fuzz::Bytes in(data + 1, size - 1);
    const uint8_t shape = in.byte();
    const size_t count = shape < 200 ? stateSize : shape < 228 ? stateSize + 1 : stateSize - 1;
    std::vector<float> values(count, 0.0f);
    for (size_t i = 0; i < count && !in.empty(); ++i) values[i] = in.f32();
    FloatCache(folder / "lighting", "COMPLIT6", ".lighting")
        .store(key, basis->parameterKey(), values);
    values.resize(shape % 2 ? 21 : values.size());  // the visibility state of 3 points: 21 values
    visibilityFiles.store(key, description, values);
    // A well-formed stage entry whose image header says what the input says.
    pipeline::StageCache entry(folder / "stages", "render", key);
    const int width = in.byte() % 9, height = in.byte() % 9, channels = in.byte() % 6;
    entry.meta()["images"]["image"] = {{"width", width},
                                       {"height", height},
                                       {"channels", channels},
                                       {"names", std::vector<std::string>(in.byte() % 5, "R")},
                                       {"colorSpace", "ACEScg"}};
    entry.meta()["clamped"] = int(in.byte());
    entry.put("image", values);
    entry.put("shadowed", std::vector<float>(values.begin(), values.begin() + long(shape % 7)));
    entry.write();
  }

  std::vector<std::string> notes;
  if (lightingCache.load(key, *basis, &notes)) {
    FUZZ_CHECK(notes.empty());
    checkIrradiance(*basis);
  } else {
    for (const std::string& n : notes) FUZZ_CHECK(!n.empty());
  }
  const FloatCache::Read r = visibilityFiles.read(key, description);
  if (r.status == FloatCache::Read::Status::Hit) {
    FUZZ_CHECK(r.problem.empty());
    for (float v : r.values) FUZZ_CHECK(std::abs(v) <= FloatCache::kMaxMagnitude);
    render::VertexTransfer t;
    if (t.importState(transfer, 3, r.values)) FUZZ_CHECK(t.cheb.size() == 12 && t.ao.size() == 3);
  } else if (r.status == FloatCache::Read::Status::Invalid) {
    FUZZ_CHECK(!r.problem.empty());
  }
  pipeline::StageCache entry(folder / "stages", "render", key);
  if (entry.open()) {
    FUZZ_CHECK(entry.problem().empty());
    Image image;
    if (entry.getImage("image", image)) {
      FUZZ_CHECK(image.pixels.size() ==
                 size_t(image.width) * size_t(image.height) * size_t(image.channels));
      FUZZ_CHECK(image.channelNames.empty() || int(image.channelNames.size()) == image.channels);
    }
    entry.get("shadowed");
    entry.get("no such array");
  } else {
    FUZZ_CHECK(std::filesystem::exists(entry.path()) != entry.problem().empty());
  }
  return 0;
}
