#include "lighting/lighting_cache.h"

#include "core/hash.h"

#include <cstdint>
#include <cstring>
#include <fstream>

namespace compose::lighting {

std::string LightingCache::key(const Environment& env, const DiffuseLighting& basis) {
  Hash128 h;
  h.word(uint32_t(env.width()));
  h.word(uint32_t(env.height()));
  const std::vector<float>& texels = env.texels();
  for (float v : texels) {
    uint32_t w;
    std::memcpy(&w, &v, sizeof w);
    h.word(w);
  }
  h.bytes(basis.parameterKey());
  h.word(uint32_t(kProjectionVersion));
  return h.hex();
}

bool LightingCache::load(const std::string& key, DiffuseLighting& basis,
                         std::vector<std::string>* notes) const {
  const FloatCache::Read r = files_.read(key, basis.parameterKey());
  std::string problem = r.problem;
  if (r.status == FloatCache::Read::Status::Hit) {
    if (basis.importState(r.values)) return true;
    problem = "does not fit the basis (" + std::to_string(r.values.size()) + " values)";
  }
  if (notes && !problem.empty()) {
    notes->push_back("the cached lighting " + pathFor(key).string() + " " + problem +
                     ": ignored, projected again and rewritten");
  }
  return false;
}

bool LightingCache::store(const std::string& key, const DiffuseLighting& basis,
                          std::vector<std::string>* notes) const {
  std::vector<float> state;
  if (!basis.exportState(state)) return false;
  std::string problem;
  if (files_.store(key, basis.parameterKey(), state, &problem)) return true;
  if (notes)
    notes->push_back("the lighting was not cached (" + problem + "): " + files_.folder().string());
  return false;
}

}  // namespace compose::lighting
