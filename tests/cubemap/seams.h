// Seams of a cube map, for the stitch tests: at every face edge, the mean step between the texels
// facing each other across the edge, against the neighbouring texel-to-texel steps.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <glm/geometric.hpp>

#include "lighting/cubemap.h"

namespace compose::testing {

// The texel `k` steps past the edge of face `face` beside edge texel (x, y), stepping off the face
// by (dx, dy) (k = 1: the texel across the edge). The point aimed at lies on this face's plane
// extended past the edge, at 1 + e, where it projects onto the centre of the neighbour's edge
// texel, at 1 - 1/n: 1 / (1 + e) = 1 - 1/n. From there the k-th texel is k - 1 texels inwards on
// the neighbour, along the axis that crosses its edge. (Stepping 2/n per texel on the extended
// plane instead falls short: the projection compresses it, and at n = 128 the second step lands
// in the first texel again.)
inline void texelBeyondEdge(int n, int face, int x, int y, int dx, int dy, int k, int& g, int& gx,
                            int& gy) {
  const double e = 1.0 / (1.0 - 1.0 / n) - 1.0;
  const double past = 1.0 / n + e;  // from the edge texel's centre, at 1 - 1/n
  const double a = -1.0 + (2.0 * x + 1.0) / n + dx * past;
  const double b = -1.0 + (2.0 * y + 1.0) / n + dy * past;
  double ga = 0, gb = 0;
  lighting::faceImageCoordinates(lighting::faceImageDirection(face, a, b), g, ga, gb);
  gx = std::clamp(int(std::floor((ga + 1.0) * 0.5 * n)), 0, n - 1);
  gy = std::clamp(int(std::floor((gb + 1.0) * 0.5 * n)), 0, n - 1);
  if (std::abs(ga) >= std::abs(gb))
    gx += ga > 0.0 ? -(k - 1) : (k - 1);
  else
    gy += gb > 0.0 ? -(k - 1) : (k - 1);
}

// Per face edge (face-major, edges left, right, top, bottom): the mean step between the two
// texels facing each other across the edge ("cross"), and the neighbouring texel-to-texel
// variation ("inner": the mean step from each edge texel to the next texel inside its own face,
// on both faces, which also cancels the change of a smooth gradient over two texels). Corners are
// left out: three faces meet there.
struct EdgeSteps {
  double cross = 0.0, inner = 0.0;
  // The level step: the mean, along the edge, of the signed step across it less the mean of the
  // signed steps just before and just after it (inside → edge texel → across → further), per
  // channel. A gradient steps as much across the edge as beside it and leaves nothing; a gain or
  // an offset between the two sides, or content displaced from one to the other, remains; noise,
  // JPEG blocks and quantisation contours average out along the edge.
  glm::dvec3 jump{0.0};
};
inline std::vector<EdgeSteps> edgeSteps(const lighting::CubeMap& cube) {
  const int n = cube.size();
  std::vector<EdgeSteps> out;
  for (int f = 0; f < lighting::kCubeFaces; ++f) {
    for (int e = 0; e < 4; ++e) {
      const int dx = e == 0 ? -1 : e == 1 ? 1 : 0, dy = e == 2 ? -1 : e == 3 ? 1 : 0;
      EdgeSteps s;
      for (int i = 1; i + 1 < n; ++i) {
        const int x = dx < 0 ? 0 : dx > 0 ? n - 1 : i, y = dy < 0 ? 0 : dy > 0 ? n - 1 : i;
        int g1, x1, y1, g2, x2, y2;
        texelBeyondEdge(n, f, x, y, dx, dy, 1, g1, x1, y1);
        texelBeyondEdge(n, f, x, y, dx, dy, 2, g2, x2, y2);
        const glm::vec3 here = cube.radiance(f, x, y), inside = cube.radiance(f, x - dx, y - dy);
        const glm::vec3 there = cube.radiance(g1, x1, y1), further = cube.radiance(g2, x2, y2);
        s.cross += double(glm::length(here - there)) / (n - 2);
        s.jump +=
            (glm::dvec3(there - here) - 0.5 * glm::dvec3((here - inside) + (further - there))) /
            double(n - 2);
        s.inner +=
            0.5 * double(glm::length(here - inside) + glm::length(there - further)) / (n - 2);
      }
      out.push_back(s);
    }
  }
  return out;
}

// The worst, over the face edges, of the step across the edge against the larger of the
// neighbouring variation and the step the scene itself has there (`scene`: the truth at the
// same size). At most 1: no seam.
inline double worstSeam(const lighting::CubeMap& stitched, const lighting::CubeMap& scene) {
  const std::vector<EdgeSteps> s = edgeSteps(stitched), t = edgeSteps(scene);
  double worst = 0.0;
  for (size_t e = 0; e < s.size(); ++e)
    worst = std::max(worst, s[e].cross / std::max(s[e].inner, t[e].cross));
  return worst;
}

// The worst, over the face edges, of the level step (EdgeSteps::jump) against the larger of the
// neighbouring texel-to-texel variation and the level step the scene itself has there (`scene`:
// the truth at the same size; a bright lamp cut by an edge curves sharply there): at most 1, the
// map is as continuous across its edges as beside them.
inline double worstLevelStep(const lighting::CubeMap& stitched, const lighting::CubeMap& scene) {
  const std::vector<EdgeSteps> s = edgeSteps(stitched), t = edgeSteps(scene);
  double worst = 0.0;
  for (size_t e = 0; e < s.size(); ++e) {
    const double scale = std::max(s[e].inner, glm::length(t[e].jump));
    const double jump = glm::length(s[e].jump);
    // Flat on both sides: any step at all is a seam.
    if (!(scale > 0.0)) {
      if (jump > 0.0) return std::numeric_limits<double>::infinity();
      continue;
    }
    worst = std::max(worst, jump / scale);
  }
  return worst;
}

}  // namespace compose::testing
