#include "cubemap/coverage.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <glm/geometric.hpp>

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

  // The rim fill at the level of at most 32 texels per face edge (coverage.h): its well-seen
  // texels as they are, every other one from the well-seen ones, weighted by
  // (nearest distance / distance)^16.
  int coarse = 0;
  while (coarse + 1 < pa.levels() && pa.size(coarse) > 32) ++coarse;
  const int m = pa.size(coarse);
  lighting::CubeMap rim(m);
  struct Source {
    glm::vec3 d, radiance;
    float weight;
  };
  std::vector<Source> sources;
  std::vector<std::array<int, 3>> holes;
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int y = 0; y < m; ++y) {
      for (int x = 0; x < m; ++x) {
        const float b = pb.texel(coarse, f, x, y).x;
        const glm::vec3 mean = b > 0.0f ? pa.texel(coarse, f, x, y) / b : glm::vec3(0.0f);
        float* out = rim.texel(f, x, y);
        for (int c = 0; c < 3; ++c) out[c] = mean[c];
        if (b >= 0.5f) sources.push_back({rim.direction(f, x, y), mean, b});
        if (b < kEnough) holes.push_back({f, x, y});
      }
    }
  }
  const bool rimFill = !sources.empty() && !holes.empty();
  if (rimFill) {
    parallelFor(0, int64_t(holes.size()), [&](int64_t i) {
      const auto [f, x, y] = holes[size_t(i)];
      const glm::vec3 d = rim.direction(f, x, y);
      // Distances as squared chords (the chord measures the angle, and is cheaper); the weight
      // (nearest / distance)^16 keeps the light at the rim: a bright sky twice as far as the
      // ground around a missing down view weighs 1.5e-5 as much per texel.
      float nearest2 = 4.0f;
      for (const Source& s : sources)
        nearest2 = std::min(nearest2, std::max(2.0f - 2.0f * glm::dot(d, s.d), 1e-8f));
      glm::dvec3 sum(0.0);
      double total = 0.0;
      for (const Source& s : sources) {
        const float chord2 = std::max(2.0f - 2.0f * glm::dot(d, s.d), 1e-8f);
        const double r = double(nearest2) / double(chord2);  // (nearest / distance)^2
        const double r2 = r * r, r4 = r2 * r2;
        const double w = double(s.weight) * r4 * r4;
        sum += w * glm::dvec3(s.radiance);
        total += w;
      }
      float* out = rim.texel(f, x, y);
      for (int c = 0; c < 3; ++c) out[c] = float(sum[c] / total);
    });
  }
  const lighting::FilteredCube rimCube =
      rimFill ? lighting::FilteredCube(rim) : lighting::FilteredCube();
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
        if (rimFill && l >= float(coarse)) {  // wider than a texel of the rim's level
          fill = rimCube.lookupLevel(d, 0.0f);
          break;
        }
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
