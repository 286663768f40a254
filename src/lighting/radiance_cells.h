// RadianceCells: a two-level view of an Environment for exact, fast cosine-weighted integrals.
//
// Each texel t is treated as what it is, the mean radiance L_t over its lat-long cell, and carries
// the cell's exact vector moment m_t = ∫_cell ω dω. A texel wholly above the horizon of n adds
// exactly ∫_cell L_t max(0, n·ω) dω = L_t (n·m_t); one that the horizon cuts is the only approximation, confined to a band of texels where the cosine is
// nearly zero; its contribution is the exact integral of the cosine's linear model across the
// texel clipped at the horizon (clippedMean), leaving only second-order error.
//
// Texels are grouped into coarse cells of `factor` x `factor`. Each cell keeps its vector moment
// V = Σ L_t m_t (per channel) and a cone (axis, half-angle) containing every point of every member
// texel. For a normal n:
//  * a cell whose cone lies entirely above n's horizon contributes n·V, with no per-texel work;
//  * a cell entirely below contributes nothing;
//  * only the cells the horizon cuts are refined to their texels.
// The result equals the texel-by-texel sum up to rounding, at a fraction of its cost (about
// 2·width/factor refined cells per query instead of width·height texels). The exact reference and
// the local-hemisphere bases use it.
#pragma once

#include <cmath>
#include <vector>

#include <glm/vec3.hpp>

#include "lighting/environment.h"

namespace compose::lighting {

class RadianceCells {
 public:
  RadianceCells() = default;
  explicit RadianceCells(const Environment& env, int factor = 8);

  // Calls visit(direction, value) for pieces of the hemisphere above n whose values sum to E(n).
  // `value` is the cosine-weighted integral ∫ L max(0, n·ω) dω over the piece (RGB); `direction`
  // is the piece's representative direction: the centroid axis for a whole cell, the texel
  // centre for a refined texel.
  template <class Visit>
  void forEachAbove(const glm::vec3& n, Visit&& visit) const {
    for (const Cell& c : cells_) {
      const float d = n.x * c.axis.x + n.y * c.axis.y + n.z * c.axis.z;
      if (d >= c.sinRadius) {
        const glm::vec3 v(n.x * c.moment[0].x + n.y * c.moment[0].y + n.z * c.moment[0].z,
                          n.x * c.moment[1].x + n.y * c.moment[1].y + n.z * c.moment[1].z,
                          n.x * c.moment[2].x + n.y * c.moment[2].y + n.z * c.moment[2].z);
        visit(c.centroid, v);
      } else if (d > -c.sinRadius) {
        for (int y = c.y0; y < c.y1; ++y) {
          const Row& row = rows_[size_t(y)];
          for (int x = c.x0; x < c.x1; ++x) {
            const size_t t = size_t(y) * size_t(width_) + size_t(x);
            const glm::vec3& w = centres_[t];
            const float centre = n.x * w.x + n.y * w.y + n.z * w.z;
            // Half-ranges of n·ω across the texel, along its north and east extents.
            const float sinLon = sinLon_[size_t(x)], cosLon = cosLon_[size_t(x)];
            const float alpha = row.halfHeight * (-n.x * sinLon * row.sinLat + n.y * row.cosLat - n.z * cosLon * row.sinLat);
            const float beta = row.halfWidth * (n.x * cosLon - n.z * sinLon);
            const float spread = std::abs(alpha) + std::abs(beta);
            if (centre >= spread) {
              const glm::vec3& m = directions_[t];
              visit(m, weighted_[t] * (n.x * m.x + n.y * m.y + n.z * m.z));
            } else if (centre > -spread) {
              visit(w, power_[t] * clippedMean(centre, alpha, beta));
            }
          }
        }
      }
    }
  }

  // Mean over s, t ∈ [-1, 1] of max(0, c + s·a + t·b): the exact integral of a linear function
  // clipped at zero over a rectangle, by the corner formula with R(x) = max(0, x)³/6:
  //   ∫∫ max(0, c + s a + t b) ds dt = (1 / (a b)) Σ_{s,t = ±1} s t R(c + s a + t b).
  // Used for texels the horizon cuts, where n·ω is close to linear across the texel.
  static float clippedMean(float c, float a, float b);

  // E(n) by the two-level sum.
  glm::vec3 irradiance(const glm::vec3& n) const;

  size_t cellCount() const { return cells_.size(); }
  size_t floatsStored() const { return cells_.size() * 19 + directions_.size() * 6; }

 private:
  struct Cell {
    glm::vec3 axis{0.0f};      // cone axis (unit)
    float sinRadius = 1.0f;    // sin of the cone half-angle, padded for rounding
    glm::vec3 centroid{0.0f};  // power-weighted mean direction (unit), or the axis if dark
    glm::vec3 moment[3];       // V per channel: Σ L_c Ω ω
    int x0 = 0, x1 = 0, y0 = 0, y1 = 0;
  };
  int width_ = 0;
  std::vector<Cell> cells_;
  std::vector<glm::vec3> directions_;  // per texel: unit direction of its vector moment m_t
  std::vector<glm::vec3> weighted_;    // per texel: L_t |m_t|
  std::vector<glm::vec3> centres_;     // per texel: centre direction
  std::vector<glm::vec3> power_;       // per texel: L_t Ω_t
  struct Row {
    float sinLat, cosLat, halfHeight, halfWidth;  // at the centre; half extents in radians of arc
  };
  std::vector<Row> rows_;
  std::vector<float> sinLon_, cosLon_;
};

}  // namespace compose::lighting
