#include "cubemap/coverage.h"

#include "core/error.h"
#include "core/parallel.h"
#include "lighting/filtered_cube.h"

namespace compose::cubemap {

using lighting::kCubeFaces;

CoverageReport measureCoverage(const lighting::CubeMap& cube, const std::vector<float>& weight) {
  const int n = cube.size();
  COMPOSE_CHECK(weight.size() == size_t(kCubeFaces) * size_t(n) * size_t(n));
  CoverageReport r;
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      const double omega = lighting::faceTexelSolidAngle(n, x, y);  // the same on every face
      for (int f = 0; f < kCubeFaces; ++f) {
        const float w = weight[(size_t(f) * size_t(n) + size_t(y)) * size_t(n) + size_t(x)];
        if (w <= 0.0f)
          r.uncovered += omega;
        else if (w < 1.0f)
          r.partial += omega;
      }
    }
  }
  const double sphere = 4.0 * 3.14159265358979323846;
  r.uncovered /= sphere;
  r.partial /= sphere;
  return r;
}

CoverageReport fillUncovered(lighting::CubeMap& cube, const std::vector<float>& weight) {
  const CoverageReport report = measureCoverage(cube, weight);
  if (report.uncovered == 0.0 && report.partial == 0.0) return report;
  COMPOSE_CHECK(report.uncovered < 1.0);
  const int n = cube.size();
  lighting::CubeMap weighted(n), weights(n);
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        const float w = weight[(size_t(f) * size_t(n) + size_t(y)) * size_t(n) + size_t(x)];
        const float* L = cube.texel(f, x, y);
        float* a = weighted.texel(f, x, y);
        float* b = weights.texel(f, x, y);
        for (int c = 0; c < 3; ++c) {
          a[c] = w * L[c];
          b[c] = w;
        }
      }
    }
  }
  const lighting::FilteredCube pa(weighted), pb(weights);
  constexpr float kEnough = 0.25f;  // weight that makes a level's average trustworthy
  constexpr float kStep = 0.25f;    // fractional levels, for a fill without visible level steps
  parallelFor(0, int64_t(kCubeFaces) * n, [&](int64_t task) {
    const int f = int(task / n), y = int(task % n);
    for (int x = 0; x < n; ++x) {
      const float w = weight[(size_t(f) * size_t(n) + size_t(y)) * size_t(n) + size_t(x)];
      if (w >= 1.0f) continue;
      const glm::vec3 d = cube.direction(f, x, y);
      glm::vec3 fill(0.0f);
      for (float level = 0.0f;; level += kStep) {
        const float last = float(pa.levels() - 1);
        const float l = std::min(level, last);
        const float b = pb.lookupLevel(d, l).x;
        if (b >= kEnough || l >= last) {
          if (b > 0.0f) fill = pa.lookupLevel(d, l) / b;
          break;
        }
      }
      float* L = cube.texel(f, x, y);
      const float keep = std::max(w, 0.0f);
      for (int c = 0; c < 3; ++c) L[c] = keep * L[c] + (1.0f - keep) * fill[c];
    }
  });
  return report;
}

}  // namespace compose::cubemap
