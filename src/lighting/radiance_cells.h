// RadianceCells: a multi-level view of an Environment for exact, fast cosine-weighted integrals.
//
// Each texel t is treated as what it is, the mean radiance L_t over its lat-long cell, with the
// cell's exact vector moment m_t = ∫_cell ω dω. A texel wholly above the horizon of n adds
// exactly ∫_cell L_t max(0, n·ω) dω = L_t (n·m_t). A texel that the horizon cuts adds the exact
// integral of the cosine's linear model across the texel, clipped at the horizon (clippedMean):
// the only approximation, second order, confined to a band of texels where the cosine is ~0.
//
// Texels are grouped into a pyramid of cells (4x4, 8x8, ... texels). Each cell keeps its vector
// moment V = Σ L_t m_t (per channel) and a cone (axis, half-angle) containing every point of every
// member texel. For a normal n, starting from the coarsest cells:
//  * a cell whose cone lies entirely above n's horizon contributes n·V, with no further work;
//  * a cell entirely below contributes nothing;
//  * a cell the horizon cuts is split into its children, down to single texels.
// The result equals the texel-by-texel sum up to rounding, at a small fraction of its cost (the
// work follows the horizon's great circle). The exact reference and the local bases use it.
//
// Small maps: the clipped linear model is second order in the size of the piece it is applied
// to, so it is only ever applied to pieces at most kMaxPieceExtent across (the texels of a
// 256-wide map). A larger texel cut by the horizon is split into exact lat-long sub-rectangles
// (same radiance, exact vector moments) until its pieces are that small, and a coarse cell is
// only taken as a uniform patch (leafLevel) when it is at most kMaxPatchExtent across. The
// white furnace then holds within 2e-6 at every map size from 2x1 up.
//
// Memory: 12 bytes per texel (its radiance; the geometry comes from per-row and per-column
// tables) plus 96 bytes per 4x4 cell and coarser: about 20 bytes per texel in all.
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "lighting/environment.h"

namespace compose::lighting {

class RadianceCells {
 public:
  // Largest angular extent (radians, along either axis) of a piece integrated with the clipped
  // linear model, and of a coarse cell taken as a uniform patch.
  static constexpr double kMaxPieceExtent = std::numbers::pi / 128.0;
  static constexpr double kMaxPatchExtent = std::numbers::pi / 64.0;
  // Texels per side of the finest cells.
  static constexpr int kFinestFactor = 4;

  RadianceCells() = default;
  // `topFactor`: texels per side of the top-level cells (a power of two, at least 4).
  explicit RadianceCells(const Environment& env, int topFactor = 32);

  // E(n) = Σ_t ∫_t L_t max(0, n·ω) dω, accumulated in double. `leafLevel` > 0 stops refining at
  // cells of 2^leafLevel texels: a cut cell is then integrated with the clipped linear model over
  // the whole cell, as if its radiance were uniform — faster, with an error confined to cells on
  // the horizon (where the cosine is ~0). leafLevel 0 is the texel-exact reference.
  glm::dvec3 irradiance(const glm::vec3& n, int leafLevel = 0) const;

  // Calls visit(direction, value) for pieces of the hemisphere above n whose values sum to E(n):
  // whole cells (direction: their power-weighted centroid) and texels along the horizon
  // (direction: their centre). `value` is the cosine-weighted integral over the piece (RGB).
  // `maxExtent` (radians) opens cells and splits texels wider than that even where the horizon
  // does not cut them, so that a caller who bins the pieces by direction (the local Chebyshev
  // grid) never puts one wide piece into one bin.
  template <class Visit>
  void forEachAbove(const glm::vec3& n, Visit&& visit, int leafLevel = 0,
                    float maxExtent = std::numeric_limits<float>::infinity()) const {
    const int top = int(levels_.size()) - 1;
    const Level& level = levels_[size_t(top)];
    const Walk walk{1 << std::clamp(leafLevel, 0, 20), maxExtent};
    for (int cy = 0; cy < level.height; ++cy) {
      for (int cx = 0; cx < level.width; ++cx) visitCell(top, cx, cy, n, visit, walk);
    }
  }

  size_t cellCount() const;
  size_t floatsStored() const;

  // Mean over s, t ∈ [-1, 1] of max(0, c + s·a + t·b): the exact integral of a linear function
  // clipped at zero over a rectangle, by the corner formula with R(x) = max(0, x)³/6:
  //   ∫∫ max(0, c + s a + t b) ds dt = (1 / (a b)) Σ_{s,t = ±1} s t R(c + s a + t b).
  static float clippedMean(float c, float a, float b);

 private:
  // One level of the pyramid: cells of factor x factor texels (clipped at the map's edges).
  struct Cell {
    glm::vec3 axis;
    float sinRadius;          // sin of the cone's half-angle; 2 for a cone wider than a hemisphere
    glm::vec3 moment[3];      // V per channel
    glm::vec3 centroid;       // unit direction of Σ_channels V
    glm::vec3 power;          // Σ L_t Ω_t
    glm::vec3 meanDirection;  // ∫_cell ω dω / Ω_cell (not unit length)
    glm::vec2 halfExtent;     // half height and half width of the cell, radians of arc
  };
  struct Level {
    int factor = 0, width = 0, height = 0;
    std::vector<Cell> cells;
  };

  // How far a walk refines: cells of at most leafFactor texels per side may be taken as uniform
  // patches on the horizon; pieces wider than maxExtent are always refined.
  struct Walk {
    int leafFactor;
    float maxExtent;
  };

  template <class Visit>
  void visitCell(int level, int cx, int cy, const glm::vec3& n, Visit& visit,
                 const Walk& walk) const {
    const Level& L = levels_[size_t(level)];
    const Cell& cell = L.cells[size_t(cy) * size_t(L.width) + size_t(cx)];
    const float d = glm::dot(n, cell.axis);
    const float extent = 2.0f * std::max(cell.halfExtent.x, cell.halfExtent.y);
    if (d >= cell.sinRadius && extent <= walk.maxExtent) {
      visit(cell.centroid, glm::vec3(glm::dot(n, cell.moment[0]), glm::dot(n, cell.moment[1]),
                                     glm::dot(n, cell.moment[2])));
      return;
    }
    if (d <= -cell.sinRadius) return;
    if (d < cell.sinRadius && L.factor <= walk.leafFactor && extent <= float(kMaxPatchExtent) &&
        extent <= walk.maxExtent) {
      // The cell as one uniform patch: the linear model of n·ω across it, clipped.
      const glm::vec3& a = cell.axis;
      const float h = std::sqrt(a.x * a.x + a.z * a.z);
      const glm::vec3 east = h > 1e-6f ? glm::vec3(a.z / h, 0.0f, -a.x / h) : glm::vec3(1, 0, 0);
      const glm::vec3 north = glm::cross(a, east);
      const float alpha = cell.halfExtent.x * glm::dot(n, north);
      const float beta = cell.halfExtent.y * glm::dot(n, east);
      // The model's centre value is the mean of n·ω over the cell under its true solid-angle
      // density (n·∫ω dω / Ω), which removes the first-order error of the cos λ density.
      visit(a, cell.power * clippedMean(glm::dot(n, cell.meanDirection), alpha, beta));
      return;
    }
    if (level == 0) {
      const int x0 = cx * L.factor, y0 = cy * L.factor;
      const int x1 = std::min(x0 + L.factor, width_), y1 = std::min(y0 + L.factor, height_);
      for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x) visitTexel(x, y, n, visit, walk);
      return;
    }
    const Level& child = levels_[size_t(level - 1)];
    const int x1 = std::min(2 * cx + 2, child.width), y1 = std::min(2 * cy + 2, child.height);
    for (int y = 2 * cy; y < y1; ++y)
      for (int x = 2 * cx; x < x1; ++x) visitCell(level - 1, x, y, n, visit, walk);
  }

  template <class Visit>
  void visitTexel(int x, int y, const glm::vec3& n, Visit& visit, const Walk& walk) const {
    const Row& row = rows_[size_t(y)];
    const Column& col = columns_[size_t(x)];
    const float* L = radiance_.data() + 3 * (size_t(y) * size_t(width_) + size_t(x));
    const glm::vec3 radiance(L[0], L[1], L[2]);
    if (largeTexels_ || 2.0f * std::max(row.halfHeight, row.halfWidth) > walk.maxExtent) {
      // Texels larger than a clipped-model piece: exact sub-rectangles (see the header comment).
      visitPiece(latBounds_[size_t(y + 1)], latBounds_[size_t(y)], lonBounds_[size_t(x + 1)],
                 lonBounds_[size_t(x)], glm::dvec3(radiance), glm::dvec3(n), visit,
                 std::min(double(walk.maxExtent), 1e3));
      return;
    }
    const glm::vec3 w(col.sinLon * row.cosLat, row.sinLat, col.cosLon * row.cosLat);
    const float centre = glm::dot(n, w);
    // Half-ranges of n·ω across the texel along its north and east extents.
    const float alpha =
        row.halfHeight * (n.y * row.cosLat - (n.x * col.sinLon + n.z * col.cosLon) * row.sinLat);
    const float beta = row.halfWidth * (n.x * col.cosLon - n.z * col.sinLon);
    const float spread = std::abs(alpha) + std::abs(beta);
    if (centre >= spread) {
      const glm::vec3 m(col.dCos * row.cos2, dLon_ * row.sinCos, col.dSin * row.cos2);
      visit(w, radiance * glm::dot(n, m));
    } else if (centre > -spread) {
      visit(w, radiance * (row.omega * clippedMean(centre, alpha, beta)));
    }
  }

  // An angle with its sine and cosine, so that the split pieces below need no trigonometry: the
  // midpoint of two angles less than π apart is the direction of the sum of their unit vectors
  // (used up to one radian apart, where that sum is long; wider, as in a map two texels wide,
  // the midpoint's sine and cosine are computed).
  struct Angle {
    double a, s, c;
    static Angle of(double a) { return {a, std::sin(a), std::cos(a)}; }
    static Angle mid(const Angle& x, const Angle& y) {
      if (y.a - x.a > 1.0) return of(0.5 * (x.a + y.a));
      const double c = x.c + y.c, s = x.s + y.s, r = std::sqrt(c * c + s * s);
      return {0.5 * (x.a + y.a), s / r, c / r};
    }
  };

  // The lat-long rectangle [lat0, lat1] x [lon0, lon1] of uniform `radiance`: whole above or
  // below n's horizon by its enclosing cone, by the clipped linear model once it is at most
  // kMaxPieceExtent across, else split.
  template <class Visit>
  void visitPiece(const Angle& lat0, const Angle& lat1, const Angle& lon0, const Angle& lon1,
                  const glm::dvec3& radiance, const glm::dvec3& n, Visit& visit,
                  double maxExtent) const {
    const Angle latMid = Angle::mid(lat0, lat1), lonMid = Angle::mid(lon0, lon1);
    const glm::dvec3 centre(lonMid.s * latMid.c, latMid.s, lonMid.c * latMid.c);
    // Every point is within (half the latitude extent) + (half the longitude extent times the
    // largest cos latitude) of the centre: along the meridian, then along the parallel.
    const double maxCos = (lat0.a <= 0.0 && lat1.a >= 0.0) ? 1.0 : std::max(lat0.c, lat1.c);
    const double height = lat1.a - lat0.a, lonExtent = lon1.a - lon0.a;
    const double radius = 0.5 * height + 0.5 * lonExtent * maxCos + 1e-9;
    const double d = glm::dot(n, centre);
    // ∫cos²λ dλ = (λ + sin λ cos λ) / 2 over [lat0, lat1].
    const double c2 = 0.5 * height + 0.5 * (lat1.s * lat1.c - lat0.s * lat0.c);
    const glm::dvec3 moment((lon0.c - lon1.c) * c2,
                            lonExtent * 0.5 * (lat1.s * lat1.s - lat0.s * lat0.s),
                            (lon1.s - lon0.s) * c2);
    constexpr double kHalfPi = 0.5 * std::numbers::pi;
    const double width = lonExtent * maxCos;
    const bool small = height <= maxExtent && width <= maxExtent;
    const bool cone = radius < kHalfPi;
    const double sinRadius = cone ? std::sin(radius) : 1.0;
    if (cone && d >= sinRadius && small) {
      visit(glm::vec3(centre), glm::vec3(radiance * glm::dot(n, moment)));
      return;
    }
    if (cone && d <= -sinRadius) return;
    const double limit = std::min(maxExtent, kMaxPieceExtent);
    if (height <= limit && width <= limit) {
      const double omega = lonExtent * (lat1.s - lat0.s);
      const glm::dvec3 north(-lonMid.s * latMid.s, latMid.c, -lonMid.c * latMid.s);
      const glm::dvec3 east(lonMid.c, 0.0, -lonMid.s);
      const float alpha = float(0.5 * height * glm::dot(n, north));
      const float beta = float(0.5 * lonExtent * latMid.c * glm::dot(n, east));
      const float mean = float(glm::dot(n, moment) / omega);
      visit(glm::vec3(centre), glm::vec3(radiance * (omega * clippedMean(mean, alpha, beta))));
      return;
    }
    // Split what is too wide for the clipped model (on the horizon) or for the caller's bins.
    const bool above = cone && d >= sinRadius;
    const double target = above ? maxExtent : limit;
    const bool splitLat = height > target, splitLon = width > target;
    const Angle lat[3] = {lat0, splitLat ? latMid : lat1, lat1};
    const Angle lon[3] = {lon0, splitLon ? lonMid : lon1, lon1};
    for (int i = 0; i < (splitLat ? 2 : 1); ++i)
      for (int j = 0; j < (splitLon ? 2 : 1); ++j)
        visitPiece(lat[i], lat[i + 1], lon[j], lon[j + 1], radiance, n, visit, maxExtent);
  }

  // Per row: the centre latitude's sine and cosine, half extents in radians of arc, the solid
  // angle of its texels, and the latitude integrals of the vector moment (∫cos²λ dλ and
  // ∫sin λ cos λ dλ over the row).
  struct Row {
    float sinLat, cosLat, halfHeight, halfWidth, omega, cos2, sinCos;
  };
  // Per column: the centre longitude's sine and cosine, and the longitude integrals of the
  // vector moment (∫sin φ dφ = dCos, ∫cos φ dφ = dSin over the column).
  struct Column {
    float sinLon, cosLon, dCos, dSin;
  };
  int width_ = 0, height_ = 0;
  float dLon_ = 0.0f;
  bool largeTexels_ = false;     // texels larger than kMaxPieceExtent: cut ones are split
  std::vector<Level> levels_;    // finest (kFinestFactor) first
  std::vector<float> radiance_;  // RGB per texel, row-major
  std::vector<Row> rows_;
  std::vector<Column> columns_;
  std::vector<Angle> latBounds_;  // the latitude of the top of row y (y = height: the bottom)
  std::vector<Angle> lonBounds_;  // the longitude of the right of column x (x = width: the left)
};

}  // namespace compose::lighting
