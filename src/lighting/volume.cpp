#include "lighting/volume.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <glm/vec3.hpp>

#include "core/error.h"

namespace compose::lighting {

void VolumeParams::validate() const {
  if (resolution.x < 1 || resolution.y < 1 || resolution.z < 1) {
    throw Error("lighting", "volume resolution must be at least 1 point per axis");
  }
  for (int a = 0; a < 3; ++a) {
    if (!(boundsMax[a] >= boundsMin[a]) || !std::isfinite(boundsMin[a]) ||
        !std::isfinite(boundsMax[a])) {
      throw Error("lighting", "volume bounds must be finite with max >= min on every axis");
    }
  }
}

LightingVolume::LightingVolume(VolumeParams params) : params_(std::move(params)) {
  params_.validate();
}

size_t LightingVolume::pointCount() const {
  return size_t(params_.resolution.x) * size_t(params_.resolution.y) * size_t(params_.resolution.z);
}

glm::vec3 LightingVolume::gridPoint(int i, int j, int k) const {
  const glm::ivec3 idx(i, j, k);
  glm::vec3 p;
  for (int a = 0; a < 3; ++a) {
    const int n = params_.resolution[a];
    p[a] = n == 1 ? 0.5f * (params_.boundsMin[a] + params_.boundsMax[a])
                  : params_.boundsMin[a] + (params_.boundsMax[a] - params_.boundsMin[a]) *
                                               float(idx[a]) / float(n - 1);
  }
  return p;
}

void LightingVolume::build(const RadianceSource& source, const Progress& progress) {
  points_.assign(pointCount(), nullptr);
  if (source.isDistant()) {
    auto basis = createLighting(params_.basis, params_.basisParams);
    basis->project(source.at(gridPoint(0, 0, 0)));
    std::shared_ptr<const DiffuseLighting> shared = std::move(basis);
    std::fill(points_.begin(), points_.end(), shared);
    report(progress, "lighting", 1.0);
    return;
  }
  size_t done = 0;
  for (int k = 0; k < params_.resolution.z; ++k) {
    for (int j = 0; j < params_.resolution.y; ++j) {
      for (int i = 0; i < params_.resolution.x; ++i) {
        auto basis = createLighting(params_.basis, params_.basisParams);
        basis->project(source.at(gridPoint(i, j, k)));
        const size_t index =
            (size_t(k) * size_t(params_.resolution.y) + size_t(j)) * size_t(params_.resolution.x) +
            size_t(i);
        points_[index] = std::move(basis);
        report(progress, "lighting", double(++done) / double(points_.size()));
      }
    }
  }
}

glm::vec3 LightingVolume::irradiance(const glm::vec3& position, const glm::vec3& n) const {
  COMPOSE_CHECK(!points_.empty());
  int lo[3];
  float t[3];
  for (int a = 0; a < 3; ++a) {
    const int res = params_.resolution[a];
    if (res == 1) {
      lo[a] = 0;
      t[a] = 0.0f;
      continue;
    }
    const float extent = params_.boundsMax[a] - params_.boundsMin[a];
    const float u =
        extent > 0.0f
            ? std::clamp((position[a] - params_.boundsMin[a]) / extent, 0.0f, 1.0f) * float(res - 1)
            : 0.0f;
    lo[a] = std::min(int(u), res - 2);
    t[a] = u - float(lo[a]);
  }
  glm::vec3 e(0.0f);
  for (int corner = 0; corner < 8; ++corner) {
    float w = 1.0f;
    int idx[3];
    for (int a = 0; a < 3; ++a) {
      const int bit = (corner >> a) & 1;
      w *= bit ? t[a] : 1.0f - t[a];
      idx[a] = std::min(lo[a] + bit, params_.resolution[a] - 1);
    }
    if (w == 0.0f) continue;
    const size_t index = (size_t(idx[2]) * size_t(params_.resolution.y) + size_t(idx[1])) *
                             size_t(params_.resolution.x) +
                         size_t(idx[0]);
    e += w * points_[index]->irradiance(n);
  }
  return e;
}

size_t LightingVolume::floatsStored() const {
  std::set<const DiffuseLighting*> distinct;
  size_t total = 0;
  for (const auto& p : points_) {
    if (p && distinct.insert(p.get()).second) total += p->floatsStored();
  }
  return total;
}

}  // namespace compose::lighting
