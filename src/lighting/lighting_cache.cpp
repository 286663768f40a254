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

bool LightingCache::load(const std::string& key, DiffuseLighting& basis) const {
  const std::optional<std::vector<float>> state = files_.load(key, basis.parameterKey());
  return state && basis.importState(*state);
}

bool LightingCache::store(const std::string& key, const DiffuseLighting& basis) const {
  std::vector<float> state;
  if (!basis.exportState(state)) return false;
  return files_.store(key, basis.parameterKey(), state);
}

}  // namespace compose::lighting
