#include "lighting/sources.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/error.h"

namespace compose::lighting {

SourceSplit splitBrightSources(const Environment& env, int count) {
  COMPOSE_CHECK(count >= 0 && count <= kMaxSources);
  SourceSplit out;
  out.residual = env;
  if (count == 0) return out;
  // Blocks of f x f texels, f a power of two, so that the reduced map is at most 1024 wide.
  int f = 1;
  while (env.width() / f > 1024 && f < env.height()) f *= 2;
  // A map so coarse that one texel spans more than 12° (16 x 8: 22.5°) holds no small bright
  // source: a texel is a lit area, and taken as one light from its centre it would light a
  // surface at up to twice its irradiance (cos at the centre times the power of a texel that
  // reaches the horizon). Its light stays with the moments.
  constexpr double kLargestTexel = 12.0 * std::numbers::pi / 180.0;
  if (std::numbers::pi / env.height() > kLargestTexel ||
      2.0 * std::numbers::pi / env.width() > kLargestTexel)
    return out;
  const int bw = (env.width() + f - 1) / f, bh = (env.height() + f - 1) / f;
  struct Block {
    int bx, by;
    double power;
  };
  std::vector<Block> blocks;
  blocks.reserve(size_t(bw) * size_t(bh));
  double total = 0.0;
  for (int by = 0; by < bh; ++by) {
    for (int bx = 0; bx < bw; ++bx) {
      double p = 0.0;
      for (int y = by * f; y < std::min((by + 1) * f, env.height()); ++y) {
        for (int x = bx * f; x < std::min((bx + 1) * f, env.width()); ++x) {
          const glm::vec3 L = env.radiance(x, y);
          p += (double(L.x) + L.y + L.z) / 3.0 * env.rowSolidAngle(y);
        }
      }
      blocks.push_back({bx, by, p});
      total += p;
    }
  }
  const size_t n = std::min(blocks.size(), size_t(count));
  std::partial_sort(blocks.begin(), blocks.begin() + ptrdiff_t(n), blocks.end(),
                    [](const Block& a, const Block& b) { return a.power > b.power; });
  double taken = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const Block& b = blocks[i];
    if (!(b.power > 0.0)) break;
    glm::dvec3 power(0.0), centre(0.0);
    for (int y = b.by * f; y < std::min((b.by + 1) * f, env.height()); ++y) {
      for (int x = b.bx * f; x < std::min((b.bx + 1) * f, env.width()); ++x) {
        const glm::dvec3 p = glm::dvec3(env.radiance(x, y)) * env.rowSolidAngle(y);
        power += p;
        centre += glm::dvec3(env.direction(x, y)) * (p.x + p.y + p.z);
        out.residual.setRadiance(x, y, glm::vec3(0.0f));
      }
    }
    const float halfLat = float(0.5 * f * std::numbers::pi / env.height());
    const float halfLon = float(f * std::numbers::pi / env.width());
    out.sources.push_back({glm::vec3(glm::normalize(centre)), glm::vec3(power), halfLat, halfLon});
    taken += b.power;
  }
  out.sourceShare = total > 0.0 ? taken / total : 0.0;
  return out;
}

}  // namespace compose::lighting
