#include "lighting/radiance_cells.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::lighting {

RadianceCells::RadianceCells(const Environment& env, int topFactor)
    : width_(env.width()), height_(env.height()) {
  COMPOSE_CHECK(topFactor >= kFinestFactor && (topFactor & (topFactor - 1)) == 0);
  const int w = width_, h = height_;
  dLon_ = float(2.0 * kPi / w);
  largeTexels_ =
      kPi / h > kMaxPieceExtent * (1.0 + 1e-9) || 2.0 * kPi / w > kMaxPieceExtent * (1.0 + 1e-9);
  radiance_ = env.texels();
  for (int y = 0; y <= h; ++y) latBounds_.push_back(Angle::of(kPi * (0.5 - double(y) / h)));
  for (int x = 0; x <= w; ++x) lonBounds_.push_back(Angle::of(kPi * (1.0 - 2.0 * x / w)));

  // Per column and per row, the closed forms of the texel's vector moment m_t = ∫_texel ω dω:
  // with dω = cos λ dλ dφ, m = (∫sin φ dφ ∫cos²λ dλ, ∫dφ ∫sin λ cos λ dλ, ∫cos φ dφ ∫cos²λ dλ).
  columns_.resize(size_t(w));
  for (int x = 0; x < w; ++x) {
    const double left = kPi * (1.0 - 2.0 * x / w), right = kPi * (1.0 - 2.0 * (x + 1) / w);
    const double lon = kPi * (1.0 - 2.0 * (x + 0.5) / w);
    columns_[size_t(x)] =
        Column{float(std::sin(lon)), float(std::cos(lon)), float(std::cos(right) - std::cos(left)),
               float(std::sin(left) - std::sin(right))};
  }
  // Every point of a texel of row y lies within rowBound[y] of its centre (along the meridian,
  // then along the parallel).
  std::vector<double> rowBound(static_cast<size_t>(h));
  rows_.resize(size_t(h));
  for (int y = 0; y < h; ++y) {
    const double top = kPi * (0.5 - double(y) / h), bottom = kPi * (0.5 - double(y + 1) / h);
    const double lat = kPi * (0.5 - (y + 0.5) / h);
    const double cos2 =
        0.5 * (top - bottom) + 0.25 * (std::sin(2.0 * top) - std::sin(2.0 * bottom));
    const double sinCos =
        0.5 * (std::sin(top) * std::sin(top) - std::sin(bottom) * std::sin(bottom));
    rows_[size_t(y)] = Row{float(std::sin(lat)),
                           float(std::cos(lat)),
                           float(0.5 * kPi / h),
                           float(kPi / w * std::cos(lat)),
                           float(env.rowSolidAngle(y)),
                           float(cos2),
                           float(sinCos)};
    const double maxCos =
        (top >= 0.0 && bottom <= 0.0) ? 1.0 : std::max(std::cos(top), std::cos(bottom));
    rowBound[size_t(y)] = 0.5 * kPi / h + kPi / w * maxCos;
  }

  // Construction-time extras per cell of the level below: solid angle, ∫ω dω, cone half-angle.
  std::vector<double> omega, childOmega;
  std::vector<glm::dvec3> geometric, childGeometric;
  std::vector<double> radius, childRadius;
  auto finish = [&](Cell& cell, const glm::dvec3& geo, double om, double rad, int x0, int y0,
                    int x1, int y1) {
    cell.sinRadius = rad >= 0.5 * kPi ? 2.0f : float(std::sin(rad));
    const glm::dvec3 total = glm::dvec3(cell.moment[0] + cell.moment[1] + cell.moment[2]);
    const double totalLen = glm::length(total);
    cell.centroid = totalLen > 0.0 ? glm::vec3(total / totalLen) : cell.axis;
    cell.meanDirection = glm::vec3(geo / om);
    const double midLat = kPi * (0.5 - 0.5 * (y0 + y1) / double(h));
    cell.halfExtent =
        glm::vec2(float(0.5 * kPi * (y1 - y0) / h), float(kPi * (x1 - x0) / w * std::cos(midLat)));
  };
  auto axisOf = [](const glm::dvec3& geo) {
    const double len = glm::length(geo);
    return len > 1e-12 ? geo / len : glm::dvec3(0.0, 1.0, 0.0);
  };

  for (int factor = kFinestFactor; factor <= topFactor; factor *= 2) {
    Level level;
    level.factor = factor;
    level.width = (w + factor - 1) / factor;
    level.height = (h + factor - 1) / factor;
    const size_t count = size_t(level.width) * size_t(level.height);
    level.cells.resize(count);
    omega.assign(count, 0.0);
    geometric.assign(count, glm::dvec3(0.0));
    radius.assign(count, 0.0);
    const bool fromTexels = factor == kFinestFactor;
    const Level* finer = fromTexels ? nullptr : &levels_.back();
    parallelFor(0, int64_t(count), [&](int64_t ii) {
      const size_t i = size_t(ii);
      const int cx = int(i % size_t(level.width)), cy = int(i / size_t(level.width));
      const int x0 = cx * factor, y0 = cy * factor;
      const int x1 = std::min(x0 + factor, w), y1 = std::min(y0 + factor, h);
      Cell& cell = level.cells[i];
      glm::dvec3 power(0.0), moment[3] = {glm::dvec3(0.0), glm::dvec3(0.0), glm::dvec3(0.0)};
      glm::dvec3 geo(0.0);
      double om = 0.0, rad = 0.0;
      if (fromTexels) {
        for (int y = y0; y < y1; ++y) {
          const Row& row = rows_[size_t(y)];
          for (int x = x0; x < x1; ++x) {
            const Column& col = columns_[size_t(x)];
            const glm::dvec3 m(double(col.dCos) * row.cos2, double(dLon_) * row.sinCos,
                               double(col.dSin) * row.cos2);
            const float* L = radiance_.data() + 3 * (size_t(y) * size_t(w) + size_t(x));
            for (int k = 0; k < 3; ++k) {
              moment[k] += m * double(L[k]);
              power[k] += double(L[k]) * row.omega;
            }
            geo += m;
            om += row.omega;
          }
        }
        const glm::dvec3 a = axisOf(geo);
        for (int y = y0; y < y1; ++y) {
          const Row& row = rows_[size_t(y)];
          for (int x = x0; x < x1; ++x) {
            const Column& col = columns_[size_t(x)];
            const glm::dvec3 c(col.sinLon * row.cosLat, row.sinLat, col.cosLon * row.cosLat);
            const double angle = std::acos(std::clamp(glm::dot(glm::normalize(c), a), -1.0, 1.0));
            rad = std::max(rad, angle + rowBound[size_t(y)]);
          }
        }
        cell.axis = glm::vec3(a);
      } else {
        const int c1x = std::min(2 * cx + 2, finer->width),
                  c1y = std::min(2 * cy + 2, finer->height);
        for (int y = 2 * cy; y < c1y; ++y) {
          for (int x = 2 * cx; x < c1x; ++x) {
            const size_t c = size_t(y) * size_t(finer->width) + size_t(x);
            const Cell& child = finer->cells[c];
            for (int k = 0; k < 3; ++k) moment[k] += glm::dvec3(child.moment[k]);
            power += glm::dvec3(child.power);
            geo += childGeometric[c];
            om += childOmega[c];
          }
        }
        const glm::dvec3 a = axisOf(geo);
        for (int y = 2 * cy; y < c1y; ++y) {
          for (int x = 2 * cx; x < c1x; ++x) {
            const size_t c = size_t(y) * size_t(finer->width) + size_t(x);
            const double angle =
                std::acos(std::clamp(glm::dot(glm::dvec3(finer->cells[c].axis), a), -1.0, 1.0));
            rad = std::max(rad, angle + childRadius[c]);
          }
        }
        cell.axis = glm::vec3(a);
      }
      for (int k = 0; k < 3; ++k) cell.moment[k] = glm::vec3(moment[k]);
      cell.power = glm::vec3(power);
      // Pad by 1e-5 rad so that float rounding in the horizon test cannot misclassify a texel.
      rad += 1e-5;
      omega[i] = om;
      geometric[i] = geo;
      radius[i] = rad;
      finish(cell, geo, om, rad, x0, y0, x1, y1);
    });
    levels_.push_back(std::move(level));
    std::swap(omega, childOmega);
    std::swap(geometric, childGeometric);
    std::swap(radius, childRadius);
  }
}

size_t RadianceCells::cellCount() const {
  size_t n = 0;
  for (const auto& l : levels_) n += l.cells.size();
  return n;
}

size_t RadianceCells::floatsStored() const {
  return cellCount() * (sizeof(Cell) / sizeof(float)) + radiance_.size() +
         rows_.size() * (sizeof(Row) / sizeof(float)) +
         columns_.size() * (sizeof(Column) / sizeof(float));
}

float RadianceCells::clippedMean(float c, float a, float b) {
  a = std::abs(a);
  b = std::abs(b);
  if (a < b) std::swap(a, b);
  auto ramp = [](double x) { return x > 0.0 ? x : 0.0; };
  if (a < 1e-7f) return float(ramp(c));
  if (b < 1e-4f * a) {
    // One-dimensional: mean of max(0, c + s a) over s ∈ [-1, 1].
    const double hi = ramp(double(c) + a), lo = ramp(double(c) - a);
    return float((hi * hi - lo * lo) / (4.0 * a));
  }
  auto r = [&](double x) {
    const double p = ramp(x);
    return p * p * p / 6.0;
  };
  const double cd = c, ad = a, bd = b;
  return float((r(cd + ad + bd) - r(cd + ad - bd) - r(cd - ad + bd) + r(cd - ad - bd)) /
               (4.0 * ad * bd));
}

glm::dvec3 RadianceCells::irradiance(const glm::vec3& n, int leafLevel) const {
  glm::dvec3 total(0.0);
  forEachAbove(
      n, [&](const glm::vec3&, const glm::vec3& v) { total += glm::dvec3(v); }, leafLevel);
  return total;
}

}  // namespace compose::lighting
