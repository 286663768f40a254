#include "cubemap/render_view.h"

#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::cubemap {

glm::dmat3 cameraRotation(double yaw, double pitch, double roll) {
  const double cy = std::cos(yaw * kDegrees), sy = std::sin(yaw * kDegrees);
  const double cp = std::cos(pitch * kDegrees), sp = std::sin(pitch * kDegrees);
  const double cr = std::cos(roll * kDegrees), sr = std::sin(roll * kDegrees);
  // glm matrices are column-major: glm::dmat3(col0, col1, col2).
  const glm::dmat3 ry(glm::dvec3(cy, 0, -sy), glm::dvec3(0, 1, 0), glm::dvec3(sy, 0, cy));
  const glm::dmat3 rx(glm::dvec3(1, 0, 0), glm::dvec3(0, cp, sp), glm::dvec3(0, -sp, cp));
  const glm::dmat3 rz(glm::dvec3(cr, sr, 0), glm::dvec3(-sr, cr, 0), glm::dvec3(0, 0, 1));
  return ry * rx * rz;
}

glm::dmat3 faceCameraRotation(int face) {
  const lighting::FaceFrame& f = lighting::faceFrame(face);
  // Camera axes in the world: right, up = -down, back = -forward.
  return glm::dmat3(f.right, -f.down, -f.forward);
}

Image renderView(const lighting::FilteredCube& env, const calib::Lens& lens,
                 const glm::dmat3& worldFromCamera, int supersample, const Progress& progress) {
  COMPOSE_CHECK(!env.empty() && lens.width > 0 && lens.height > 0 && supersample >= 1);
  Image out(lens.width, lens.height, 3, {"R", "G", "B"});
  const int s = supersample;
  ParallelProgress shared(progress, "render", lens.height, 16);
  parallelFor(0, lens.height, [&](int64_t yy) {
    const int y = int(yy);
    for (int x = 0; x < lens.width; ++x) {
      // Footprint of one sub-pixel: the solid angle spanned by the pixel's edges, divided up.
      glm::dvec3 c, r, down;
      float footprint = 0.0f;
      if (lens.direction(x + 0.5, y + 0.5, c) && lens.direction(x + 1.5, y + 0.5, r) &&
          lens.direction(x + 0.5, y + 1.5, down)) {
        footprint = float(glm::length(glm::cross(r - c, down - c)) / (s * s));
      }
      glm::vec3 sum(0.0f);
      for (int j = 0; j < s; ++j) {
        for (int i = 0; i < s; ++i) {
          glm::dvec3 ray;
          if (!lens.direction(x + (i + 0.5) / s, y + (j + 0.5) / s, ray)) continue;
          const glm::vec3 d(worldFromCamera * ray);
          // Sub-pixels smaller than a texel take the texel they hit (the map is piecewise
          // constant); larger ones a prefiltered average over their footprint.
          sum += env.levelFor(d, footprint) > 0.0f ? env.lookup(d, footprint) : env.nearest(d);
        }
      }
      float* p = out.at(x, y);
      const glm::vec3 mean = sum / float(s * s);
      p[0] = mean.x, p[1] = mean.y, p[2] = mean.z;
    }
    shared.step();
  });
  report(progress, "render", 1.0);
  return out;
}

}  // namespace compose::cubemap
