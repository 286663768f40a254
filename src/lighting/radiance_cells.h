// RadianceCells: a multi-level view of an Environment for exact, fast cosine-weighted integrals.
//
// Each texel t is treated as what it is, the mean radiance L_t over its lat-long cell, and carries
// the cell's exact vector moment m_t = ∫_cell ω dω. A texel wholly above the horizon of n adds
// exactly ∫_cell L_t max(0, n·ω) dω = L_t (n·m_t). A texel that the horizon cuts adds the exact
// integral of the cosine's linear model across the texel, clipped at the horizon (clippedMean):
// the only approximation, second order, confined to a band of texels where the cosine is ~0.
//
// Texels are grouped into a pyramid of cells (2x2, 4x4, ... texels). Each cell keeps its vector
// moment V = Σ L_t m_t (per channel) and a cone (axis, half-angle) containing every point of every
// member texel. For a normal n, starting from the coarsest cells:
//  * a cell whose cone lies entirely above n's horizon contributes n·V, with no further work;
//  * a cell entirely below contributes nothing;
//  * a cell the horizon cuts is split into its four children, down to single texels.
// The result equals the texel-by-texel sum up to rounding, at a small fraction of its cost (the
// work follows the horizon's great circle). The exact reference and the local bases use it.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include <glm/vec2.hpp>

#include <glm/vec3.hpp>

#include "lighting/environment.h"

namespace compose::lighting {

class RadianceCells {
 public:
  RadianceCells() = default;
  // `topFactor`: texels per side of the top-level cells (a power of two).
  explicit RadianceCells(const Environment& env, int topFactor = 32);

  // E(n) = Σ_t ∫_t L_t max(0, n·ω) dω, accumulated in double. `leafLevel` > 0 stops refining at
  // cells of 2^leafLevel texels: a cut cell is then integrated with the clipped linear model over
  // the whole cell, as if its radiance were uniform — faster, with an error confined to cells on
  // the horizon (where the cosine is ~0). leafLevel 0 is the texel-exact reference.
  glm::dvec3 irradiance(const glm::vec3& n, int leafLevel = 0) const;

  // Calls visit(direction, value) for pieces of the hemisphere above n whose values sum to E(n):
  // whole cells (direction: their power-weighted centroid) and texels along the horizon
  // (direction: their centre). `value` is the cosine-weighted integral over the piece (RGB).
  template <class Visit>
  void forEachAbove(const glm::vec3& n, Visit&& visit, int leafLevel = 0) const {
    const int top = int(levels_.size()) - 1;
    const Level& level = levels_[size_t(top)];
    leafLevel = std::clamp(leafLevel, 0, top);
    for (int cy = 0; cy < level.height; ++cy) {
      for (int cx = 0; cx < level.width; ++cx) visitCell(top, cx, cy, n, visit, leafLevel);
    }
  }

  size_t cellCount() const;
  size_t floatsStored() const;

  // Mean over s, t ∈ [-1, 1] of max(0, c + s·a + t·b): the exact integral of a linear function
  // clipped at zero over a rectangle, by the corner formula with R(x) = max(0, x)³/6:
  //   ∫∫ max(0, c + s a + t b) ds dt = (1 / (a b)) Σ_{s,t = ±1} s t R(c + s a + t b).
  static float clippedMean(float c, float a, float b);

 private:
  // One level of the pyramid: cells of 2^level x 2^level texels (clipped at the map's edges).
  struct Level {
    int width = 0, height = 0;
    std::vector<float> axisX, axisY, axisZ, sinRadius;
    std::vector<float> moment[9];  // V: [3 * channel + axis][cell]
    std::vector<glm::vec3> centroid;
    std::vector<glm::vec3> power;          // Σ L_t Ω_t
    std::vector<glm::vec2> halfExtent;     // half height and half width of the cell, radians of arc
    std::vector<glm::vec3> meanDirection;  // ∫_cell ω dω / Ω_cell (not unit length)
  };

  template <class Visit>
  void visitCell(int level, int cx, int cy, const glm::vec3& n, Visit& visit, int leafLevel) const {
    if (level == 0) {
      visitTexel(cx, cy, n, visit);
      return;
    }
    const Level& L = levels_[size_t(level)];
    const size_t i = size_t(cy) * size_t(L.width) + size_t(cx);
    const float d = n.x * L.axisX[i] + n.y * L.axisY[i] + n.z * L.axisZ[i];
    if (d >= L.sinRadius[i]) {
      visit(L.centroid[i],
            glm::vec3(n.x * L.moment[0][i] + n.y * L.moment[1][i] + n.z * L.moment[2][i],
                      n.x * L.moment[3][i] + n.y * L.moment[4][i] + n.z * L.moment[5][i],
                      n.x * L.moment[6][i] + n.y * L.moment[7][i] + n.z * L.moment[8][i]));
    } else if (d > -L.sinRadius[i]) {
      if (level == leafLevel) {
        // The cell as one uniform patch: the linear model of n·ω across it, clipped.
        const glm::vec3 a(L.axisX[i], L.axisY[i], L.axisZ[i]);
        const float h = std::sqrt(a.x * a.x + a.z * a.z);
        const glm::vec3 east = h > 1e-6f ? glm::vec3(a.z / h, 0.0f, -a.x / h) : glm::vec3(1, 0, 0);
        // north = axis x east
        const glm::vec3 nn(a.y * east.z - a.z * east.y, a.z * east.x - a.x * east.z,
                           a.x * east.y - a.y * east.x);
        const float alpha = L.halfExtent[i].x * (n.x * nn.x + n.y * nn.y + n.z * nn.z);
        const float beta = L.halfExtent[i].y * (n.x * east.x + n.y * east.y + n.z * east.z);
        // The model's centre value is the mean of n·ω over the cell under its true solid-angle
        // density (n·∫ω dω / Ω), which removes the first-order error of the cos λ density.
        const glm::vec3& md = L.meanDirection[i];
        visit(a, L.power[i] * clippedMean(n.x * md.x + n.y * md.y + n.z * md.z, alpha, beta));
        return;
      }
      const Level& child = levels_[size_t(level - 1)];
      const int x1 = std::min(2 * cx + 2, child.width), y1 = std::min(2 * cy + 2, child.height);
      for (int y = 2 * cy; y < y1; ++y) {
        for (int x = 2 * cx; x < x1; ++x) visitCell(level - 1, x, y, n, visit, leafLevel);
      }
    }
  }

  template <class Visit>
  void visitTexel(int x, int y, const glm::vec3& n, Visit& visit) const {
    const Row& row = rows_[size_t(y)];
    const Texel& tx = texels_[size_t(y) * size_t(width_) + size_t(x)];
    const glm::vec3& w = tx.centre;
    const float centre = n.x * w.x + n.y * w.y + n.z * w.z;
    const float sinLon = sinLon_[size_t(x)], cosLon = cosLon_[size_t(x)];
    // Half-ranges of n·ω across the texel along its north and east extents.
    const float alpha =
        row.halfHeight * (n.y * row.cosLat - (n.x * sinLon + n.z * cosLon) * row.sinLat);
    const float beta = row.halfWidth * (n.x * cosLon - n.z * sinLon);
    const float spread = std::abs(alpha) + std::abs(beta);
    if (centre >= spread) {
      const glm::vec3& m = tx.moment;
      visit(w, tx.weighted * (n.x * m.x + n.y * m.y + n.z * m.z));
    } else if (centre > -spread) {
      visit(w, tx.power * clippedMean(centre, alpha, beta));
    }
  }

  struct Row {
    float sinLat, cosLat, halfHeight,
        halfWidth;  // at the texel centre; half extents in radians of arc
  };
  int width_ = 0, height_ = 0;
  std::vector<Level> levels_;  // [0] is unused (texels are below), [1..] coarser and coarser
  // Texels, one record each so that a texel along the horizon costs one cache line.
  struct Texel {
    glm::vec3 centre;    // centre direction
    glm::vec3 moment;    // unit direction of the vector moment m_t
    glm::vec3 weighted;  // L_t |m_t|
    glm::vec3 power;     // L_t Ω_t
  };
  std::vector<Texel> texels_;
  std::vector<Row> rows_;
  std::vector<double> rowMoment_,
      rowOmega_;  // per row: |m_t| and Ω_t (the same for every texel of a row)
  std::vector<float> sinLon_, cosLon_;
};

}  // namespace compose::lighting
