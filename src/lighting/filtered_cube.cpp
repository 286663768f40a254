#include "lighting/filtered_cube.h"

#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/parallel.h"
#include "lighting/sphere_resample.h"

namespace compose::lighting {

namespace {

// Texel range [first, last] of an n-texel face row overlapping [lo, hi] (face coordinates).
void texelRange(int n, double lo, double hi, int& first, int& last) {
  first = std::clamp(int(std::floor((lo + 1.0) * 0.5 * n)), 0, n - 1);
  last = std::clamp(int(std::ceil((hi + 1.0) * 0.5 * n)) - 1, 0, n - 1);
}

}  // namespace

FilteredCube::FilteredCube(const CubeMap& cube) {
  COMPOSE_CHECK(!cube.empty());
  Level base;
  base.size = cube.size();
  base.stride = base.size + 2;
  base.texels.assign(size_t(kCubeFaces) * size_t(base.stride) * size_t(base.stride) * 3, 0.0f);
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int y = 0; y < base.size; ++y) {
      std::copy_n(cube.texel(f, 0, y), size_t(base.size) * 3,
                  base.texels.begin() + ptrdiff_t(base.offset(f, 0, y)));
    }
  }
  fillBorders(base);
  levels_.push_back(std::move(base));

  while (levels_.back().size > 1) {
    const Level& child = levels_.back();
    const int n = child.size, m = (n + 1) / 2;
    Level parent;
    parent.size = m;
    parent.stride = m + 2;
    parent.texels.assign(size_t(kCubeFaces) * size_t(parent.stride) * size_t(parent.stride) * 3,
                         0.0f);
    parallelFor(0, int64_t(kCubeFaces) * m, [&](int64_t task) {
      const int f = int(task / m), py = int(task % m);
      const double b0 = -1.0 + 2.0 * py / m, b1 = -1.0 + 2.0 * (py + 1) / m;
      int y0, y1;
      texelRange(n, b0, b1, y0, y1);
      for (int px = 0; px < m; ++px) {
        const double a0 = -1.0 + 2.0 * px / m, a1 = -1.0 + 2.0 * (px + 1) / m;
        int x0, x1;
        texelRange(n, a0, a1, x0, x1);
        glm::dvec3 sum(0.0);
        double area = 0.0;
        for (int y = y0; y <= y1; ++y) {
          const double cb0 = std::max(b0, -1.0 + 2.0 * y / n),
                       cb1 = std::min(b1, -1.0 + 2.0 * (y + 1) / n);
          if (!(cb1 > cb0)) continue;
          for (int x = x0; x <= x1; ++x) {
            const double ca0 = std::max(a0, -1.0 + 2.0 * x / n),
                         ca1 = std::min(a1, -1.0 + 2.0 * (x + 1) / n);
            if (!(ca1 > ca0)) continue;
            const double omega = cubeSolidAngle(ca0, cb0, ca1, cb1);
            const float* t = child.texels.data() + child.offset(f, x, y);
            sum += omega * glm::dvec3(t[0], t[1], t[2]);
            area += omega;
          }
        }
        const glm::dvec3 mean = sum / area;
        float* out = parent.texels.data() + parent.offset(f, px, py);
        out[0] = float(mean.x);
        out[1] = float(mean.y);
        out[2] = float(mean.z);
      }
    });
    fillBorders(parent);
    levels_.push_back(std::move(parent));
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
