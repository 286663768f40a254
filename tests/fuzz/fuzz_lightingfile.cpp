// Lighting files (pipeline/stage_files.h): what compose precompute writes and compose render
// reads, a stage-cache entry whose header says which basis and parameters made it.
//
// A checksum guards the entry's bytes (the cache target fuzzes those), so this target fuzzes what
// lies behind it: a file that checks out but whose header says anything. At start-up the real
// precompute stage writes a lighting file for a small environment; each input replaces that
// file's header (JSON) and keeps its arrays, the first byte choosing whether the render wants
// the shadows' lighting too. The reader either refuses the file with a named error or restores a
// basis whose irradiance is finite.
#include <cmath>

#include <glm/geometric.hpp>

#include "core/output_files.h"
#include "fuzz_util.h"
#include "ingest/image_io.h"
#include "lighting/lighting.h"
#include "pipeline/context.h"
#include "pipeline/stage.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_files.h"

using namespace compose;

namespace {

std::filesystem::path madeFile() {
  return fuzz::scratch() / "made.lighting";
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  Image env(16, 8, 3, {"R", "G", "B"});
  for (int y = 0; y < env.height; ++y)
    for (int x = 0; x < env.width; ++x)
      for (int c = 0; c < 3; ++c)
        env.pixels[(size_t(y) * 16 + size_t(x)) * 3 + size_t(c)] =
            (y < 2 && x == 5 ? 40.0f : 0.5f) + 0.1f * float(c);
  env.colorSpace = "lin_rec709";
  ingest::writeImage(fuzz::scratch() / "env.exr", env);
  pipeline::ComposeJob job;
  job.environment = fuzz::scratch() / "env.exr";
  job.lightingParams = "rows=3,cols=4,samples=2,order=1";
  job.shadowParams = "order=2,grid=2,sources=2";
  job.cache.clear();
  pipeline::RunRequest request;
  request.targets = {pipeline::artefact::kLighting, pipeline::artefact::kShadowLighting};
  request.finish = [](pipeline::Context& ctx) { pipeline::savePrecompute(ctx, madeFile()); };
  pipeline::runCompose(job, color::ColorConfig::builtin(), {}, request);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  if (size < 1) return 0;
  const nlohmann::json meta = nlohmann::json::parse(data + 1, data + size, nullptr, false);
  if (meta.is_discarded()) return 0;  // not JSON: the checksum would have refused it
  const auto file = fuzz::scratch() / "input.lighting";
  {
    pipeline::StageCache made = pipeline::StageCache::atFile(madeFile(), "precompute");
    FUZZ_CHECK(made.open());
    pipeline::StageCache forged = pipeline::StageCache::atFile(file, "precompute");
    for (const char* name : {"lighting", "shadowBasis", "sources"})
      forged.put(name, made.get(name));
    forged.meta() = meta;
    FUZZ_CHECK(forged.write());
  }

  pipeline::ComposeJob job;
  job.cache.clear();
  job.shadows = data[0] & 1;
  job.groundShadow = data[0] & 2;
  try {
    pipeline::StageInput in = pipeline::precomputeInput(file, job);
    pipeline::validate(job);
    const color::ColorConfig colors = color::ColorConfig::builtin();
    pipeline::Context ctx(job, colors, {});
    in.load(ctx);
    FUZZ_CHECK(ctx.artefacts.lighting != nullptr);
    for (const glm::vec3 n :
         {glm::vec3(0, 1, 0), glm::vec3(0, -1, 0), glm::normalize(glm::vec3(0.3f, -0.2f, 0.9f))}) {
      const glm::vec3 e = ctx.artefacts.lighting->irradiance(n);
      FUZZ_CHECK(std::isfinite(e.x) && std::isfinite(e.y) && std::isfinite(e.z));
    }
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
  return 0;
}
