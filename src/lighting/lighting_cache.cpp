#include "lighting/lighting_cache.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>

#include <glm/geometric.hpp>

#include "core/hash.h"

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

bool LightingCache::finiteIrradiance(const DiffuseLighting& basis) {
  for (int x = -1; x <= 1; ++x)
    for (int y = -1; y <= 1; ++y)
      for (int z = -1; z <= 1; ++z) {
        if (x == 0 && y == 0 && z == 0) continue;
        const glm::vec3 e =
            basis.irradiance(glm::normalize(glm::vec3(float(x), float(y), float(z))));
        if (!(std::isfinite(e.x) && std::isfinite(e.y) && std::isfinite(e.z))) return false;
      }
  return true;
}

bool LightingCache::load(const std::string& key, DiffuseLighting& basis,
                         std::vector<std::string>* notes) const {
  const FloatCache::Read r = files_.read(key, basis.parameterKey());
  std::string problem = r.problem;
  if (r.status == FloatCache::Read::Status::Hit) {
    if (!basis.importState(r.values)) {
      problem = "does not fit the basis (" + std::to_string(r.values.size()) + " values)";
    } else if (!finiteIrradiance(basis)) {
      problem = "holds values that give non-finite irradiance";
    } else {
      return true;
    }
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
