#include "cubemap/mirror_ball.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::cubemap {

using lighting::kCubeFaces;

namespace {

// Bilinear sample of an image at continuous pixel coordinates (origin at the top-left corner),
// clamped at the borders.
glm::vec3 bilinear(const Image& img, double px, double py) {
  const double u = px - 0.5, v = py - 0.5;
  const int x0 = std::clamp(int(std::floor(u)), 0, img.width - 1);
  const int y0 = std::clamp(int(std::floor(v)), 0, img.height - 1);
  const int x1 = std::min(x0 + 1, img.width - 1), y1 = std::min(y0 + 1, img.height - 1);
  const float fx = std::clamp(float(u - std::floor(u)), 0.0f, 1.0f);
  const float fy = std::clamp(float(v - std::floor(v)), 0.0f, 1.0f);
  auto at = [&](int x, int y) {
    const float* p = img.at(x, y);
    return img.channels >= 3 ? glm::vec3(p[0], p[1], p[2]) : glm::vec3(p[0]);
  };
  return (at(x0, y0) * (1 - fx) + at(x1, y0) * fx) * (1 - fy) +
         (at(x0, y1) * (1 - fx) + at(x1, y1) * fx) * fy;
}

}  // namespace

void MirrorBallOptions::validate() const {
  if (faceSize < 0 || faceSize > 16384)
    throw UsageError("the cube face size must be 0 (automatic) to 16384");
  if (!(blindSpotDegrees >= 0.0 && blindSpotDegrees <= 60.0))
    throw UsageError("--blind-spot must be within 0..60 degrees");
}

MirrorBallResult unwrapMirrorBall(const Image& ball, const MirrorBallOptions& options,
                                  const std::filesystem::path& file, const Progress& progress) {
  options.validate();
  if (ball.width != ball.height) {
    throw Error("ingest",
                "a mirror-ball photo must be cropped square to the ball, this one is " +
                    std::to_string(ball.width) + "x" + std::to_string(ball.height),
                file);
  }
  if (ball.width < 8)
    throw Error("ingest", "the mirror-ball crop is too small (under 8 pixels)", file);
  const int s = ball.width;
  // Disc area π s²/4 pixels covers 4π sr; 6 N² texels at about the same density: N = s sqrt(π/24).
  const int n = options.faceSize > 0 ? options.faceSize
                                     : std::max(8, int(std::lround(s * std::sqrt(kPi / 24.0))));
  MirrorBallResult out;
  out.cube = lighting::CubeMap(n);
  out.cube.colorSpace = ball.colorSpace;
  std::vector<float> weight(size_t(kCubeFaces) * size_t(n) * size_t(n), 0.0f);
  // Pixels within 1.5 pixels of the ball's outline mix the ball with what is around it: directions
  // that map there (the ring at disc radius r, r = sin(θ/2) for θ the angle from the camera) are
  // treated like the blind spot.
  const double rimRadius = std::max(0.0, 1.0 - 1.5 / (0.5 * s));
  const double rimBlind = kPi - 2.0 * std::asin(rimRadius);
  const double blind = std::max(options.blindSpotDegrees * kPi / 180.0, rimBlind);
  // Angle from straight behind the ball (-Z) below which nothing is read, and up to which the
  // weight ramps (smoothstep) to 1.
  const double cosBlind = std::cos(blind), cosFull = std::cos(std::min(2.0 * blind, kPi));
  constexpr int kSub = 3;  // samples per texel side
  ParallelProgress shared(progress, "unwrap", int64_t(kCubeFaces) * n);
  parallelFor(0, int64_t(kCubeFaces) * n, [&](int64_t task) {
    const int f = int(task / n), y = int(task % n);
    for (int x = 0; x < n; ++x) {
      glm::dvec3 sum(0.0);
      double wsum = 0.0, weightSum = 0.0;
      for (int j = 0; j < kSub; ++j) {
        for (int i = 0; i < kSub; ++i) {
          const double a = -1.0 + (2.0 * x + (i + 0.5) * 2.0 / kSub) / n;
          const double b = -1.0 + (2.0 * y + (j + 0.5) * 2.0 / kSub) / n;
          const glm::dvec3 d = glm::normalize(lighting::faceImageDirection(f, a, b));
          // How far from straight behind the ball: -d.z is the cosine of that angle.
          const double behind = -d.z;
          double w = 1.0;
          if (blind > 0.0) {  // at least the rim's width
            if (behind >= cosBlind) {
              w = 0.0;
            } else if (behind > cosFull) {
              const double t = (cosBlind - behind) / (cosBlind - cosFull);
              w = t * t * (3.0 - 2.0 * t);
            }
          }
          weightSum += w;
          if (w <= 0.0) continue;
          // The normal is the half vector of d and c = +Z.
          const glm::dvec3 nrm = glm::normalize(d + glm::dvec3(0, 0, 1));
          const double px = (nrm.x + 1.0) * 0.5 * s, py = (1.0 - nrm.y) * 0.5 * s;
          sum += glm::dvec3(bilinear(ball, px, py));
          wsum += 1.0;
        }
      }
      float* t = out.cube.texel(f, x, y);
      if (wsum > 0.0) {
        const glm::dvec3 mean = sum / wsum;
        t[0] = float(mean.x), t[1] = float(mean.y), t[2] = float(mean.z);
      }
      weight[(size_t(f) * size_t(n) + size_t(y)) * size_t(n) + size_t(x)] =
          float(weightSum / (kSub * kSub));
    }
    shared.step();
  });
  out.coverage = fillUncovered(out.cube, weight);
  report(progress, "unwrap", 1.0);
  return out;
}

}  // namespace compose::cubemap
