#include "lighting/filtered_cube.h"

#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/parallel.h"
#include "lighting/sphere_resample.h"

namespace compose::lighting {

FilteredCube::FilteredCube(const CubeMap& cube) {
  COMPOSE_CHECK(!cube.empty());
  CubeMap current = cube;
  for (;;) {
    Level level;
    level.size = current.size();
    level.stride = level.size + 2;
    level.texels.assign(size_t(kCubeFaces) * size_t(level.stride) * size_t(level.stride) * 3, 0.0f);
    for (int f = 0; f < kCubeFaces; ++f) {
      for (int y = 0; y < level.size; ++y) {
        std::copy_n(current.texel(f, 0, y), size_t(level.size) * 3,
                    level.texels.begin() + ptrdiff_t(level.offset(f, 0, y)));
      }
    }
    fillBorders(level);
    levels_.push_back(std::move(level));
    if (current.size() == 1) break;
    // Exact solid-angle-weighted means, with partial overlaps when the size is odd.
    current = resizeCube(current, (current.size() + 1) / 2);
  }
}

FilteredCube FilteredCube::fromEnvironment(const Environment& env, int size,
                                           const Progress& progress) {
  if (size <= 0) size = std::max(1, env.width() / 4);
  return FilteredCube(cubeFromLatLong(env, size, progress));
}

void FilteredCube::fillBorders(Level& level) const {
  const int n = level.size;
  constexpr double kPast = 1e-7;  // just across the edge, well inside the neighbour's edge texel
  auto copyFrom = [&](int face, int x, int y, double a, double b) {
    int g = 0;
    double ga = 0, gb = 0;
    faceImageCoordinates(faceImageDirection(face, a, b), g, ga, gb);
    const int gx = std::clamp(int(std::floor((ga + 1.0) * 0.5 * n)), 0, n - 1);
    const int gy = std::clamp(int(std::floor((gb + 1.0) * 0.5 * n)), 0, n - 1);
    COMPOSE_CHECK(g != face);
    std::copy_n(level.texels.data() + level.offset(g, gx, gy), 3,
                level.texels.data() + level.offset(face, x, y));
  };
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int i = 0; i < n; ++i) {
      const double c = -1.0 + (2.0 * i + 1.0) / n;
      copyFrom(f, -1, i, -1.0 - kPast, c);
      copyFrom(f, n, i, 1.0 + kPast, c);
      copyFrom(f, i, -1, c, -1.0 - kPast);
      copyFrom(f, i, n, c, 1.0 + kPast);
    }
    // Corners: the three texels meeting at the cube corner (this face's corner texel and the two
    // border texels beside it, which hold the neighbours' corner texels).
    for (int by : {-1, n}) {
      for (int bx : {-1, n}) {
        const int cx = bx < 0 ? 0 : n - 1, cy = by < 0 ? 0 : n - 1;
        const float* own = level.texels.data() + level.offset(f, cx, cy);
        const float* side = level.texels.data() + level.offset(f, bx, cy);
        const float* vertical = level.texels.data() + level.offset(f, cx, by);
        float* corner = level.texels.data() + level.offset(f, bx, by);
        for (int k = 0; k < 3; ++k) corner[k] = (own[k] + side[k] + vertical[k]) / 3.0f;
      }
    }
  }
}

glm::vec3 FilteredCube::bilinear(const Level& level, int face, double a, double b) const {
  const int n = level.size;
  const double u = (a + 1.0) * 0.5 * n - 0.5, v = (b + 1.0) * 0.5 * n - 0.5;
  const int x0 = std::clamp(int(std::floor(u)), -1, n - 1);
  const int y0 = std::clamp(int(std::floor(v)), -1, n - 1);
  const float fx = std::clamp(float(u - x0), 0.0f, 1.0f),
              fy = std::clamp(float(v - y0), 0.0f, 1.0f);
  const float* p00 = level.texels.data() + level.offset(face, x0, y0);
  const float* p10 = p00 + 3;
  const float* p01 = p00 + size_t(level.stride) * 3;
  const float* p11 = p01 + 3;
  const float w00 = (1 - fx) * (1 - fy), w10 = fx * (1 - fy), w01 = (1 - fx) * fy, w11 = fx * fy;
  return {w00 * p00[0] + w10 * p10[0] + w01 * p01[0] + w11 * p11[0],
          w00 * p00[1] + w10 * p10[1] + w01 * p01[1] + w11 * p11[1],
          w00 * p00[2] + w10 * p10[2] + w01 * p01[2] + w11 * p11[2]};
}

float FilteredCube::levelAt(double a, double b, float solidAngle) const {
  const double r2 = 1.0 + a * a + b * b;
  const double n = levels_[0].size;
  const double texel = 4.0 / (n * n) / (r2 * std::sqrt(r2));  // dω = da db / r³
  if (!(solidAngle > texel)) return 0.0f;
  return float(std::min(0.5 * std::log2(solidAngle / texel), double(levels_.size() - 1)));
}

glm::vec3 FilteredCube::sample(int face, double a, double b, float level) const {
  level = std::clamp(level, 0.0f, float(levels_.size() - 1));
  const int l0 = std::min(int(level), int(levels_.size()) - 1);
  const float t = level - float(l0);
  const glm::vec3 c0 = bilinear(levels_[size_t(l0)], face, a, b);
  if (t <= 0.0f || l0 + 1 >= int(levels_.size())) return c0;
  return c0 + t * (bilinear(levels_[size_t(l0) + 1], face, a, b) - c0);
}

float FilteredCube::levelFor(const glm::vec3& d, float solidAngle) const {
  COMPOSE_CHECK(!levels_.empty());
  int face = 0;
  double a = 0, b = 0;
  faceImageCoordinates(glm::dvec3(d), face, a, b);
  return levelAt(a, b, solidAngle);
}

glm::vec3 FilteredCube::lookupLevel(const glm::vec3& d, float level) const {
  COMPOSE_CHECK(!levels_.empty());
  int face = 0;
  double a = 0, b = 0;
  faceImageCoordinates(glm::dvec3(d), face, a, b);
  return sample(face, a, b, level);
}

glm::vec3 FilteredCube::nearest(const glm::vec3& d) const {
  COMPOSE_CHECK(!levels_.empty());
  int face = 0;
  double a = 0, b = 0;
  faceImageCoordinates(glm::dvec3(d), face, a, b);
  const Level& L = levels_[0];
  const int x = std::clamp(int(std::floor((a + 1.0) * 0.5 * L.size)), 0, L.size - 1);
  const int y = std::clamp(int(std::floor((b + 1.0) * 0.5 * L.size)), 0, L.size - 1);
  const float* p = L.texels.data() + L.offset(face, x, y);
  return {p[0], p[1], p[2]};
}

glm::vec3 FilteredCube::lookup(const glm::vec3& d, float solidAngle) const {
  COMPOSE_CHECK(!levels_.empty());
  int face = 0;
  double a = 0, b = 0;
  faceImageCoordinates(glm::dvec3(d), face, a, b);
  return sample(face, a, b, levelAt(a, b, solidAngle));
}

glm::dvec3 FilteredCube::integral(int level) const {
  const Level& L = levels_[size_t(level)];
  glm::dvec3 total(0.0);
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int y = 0; y < L.size; ++y) {
      for (int x = 0; x < L.size; ++x) {
        const float* t = L.texels.data() + L.offset(f, x, y);
        total += faceTexelSolidAngle(L.size, x, y) * glm::dvec3(t[0], t[1], t[2]);
      }
    }
  }
  return total;
}

size_t FilteredCube::bytes() const {
  size_t total = 0;
  for (const Level& L : levels_) total += L.texels.size() * sizeof(float);
  return total;
}

}  // namespace compose::lighting
