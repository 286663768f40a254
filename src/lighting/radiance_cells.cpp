#include "lighting/radiance_cells.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::lighting {

namespace {
constexpr double kPi = std::numbers::pi;
}

RadianceCells::RadianceCells(const Environment& env, int topFactor)
    : width_(env.width()), height_(env.height()) {
  COMPOSE_CHECK(topFactor >= 2 && (topFactor & (topFactor - 1)) == 0);
  const int w = width_, h = height_;
  const size_t texels = size_t(w) * size_t(h);
  texels_.resize(texels);
  rows_.resize(size_t(h));
  rowMoment_.resize(size_t(h));
  rowOmega_.resize(size_t(h));
  sinLon_.resize(size_t(w));
  cosLon_.resize(size_t(w));
  for (int x = 0; x < w; ++x) {
    const double lon = kPi * (1.0 - 2.0 * (x + 0.5) / w);
    sinLon_[size_t(x)] = float(std::sin(lon));
    cosLon_[size_t(x)] = float(std::cos(lon));
  }
  // Per texel, the exact vector moment m_t = ∫_texel ω dω of its lat-long cell, in closed form:
  // with dω = cos λ dλ dφ, m = (∫sin φ dφ ∫cos²λ dλ, ∫dφ ∫sin λ cos λ dλ, ∫cos φ dφ ∫cos²λ dλ).
  parallelFor(0, h, [&](int64_t yy) {
    const int y = int(yy);
    const double top = kPi * (0.5 - double(y) / h), bottom = kPi * (0.5 - double(y + 1) / h);
    const double centreLat = kPi * (0.5 - (y + 0.5) / h);
    rows_[size_t(y)] = Row{float(std::sin(centreLat)), float(std::cos(centreLat)),
                           float(0.5 * kPi / h), float(kPi / w * std::cos(centreLat))};
    const double cos2 =
        0.5 * (top - bottom) + 0.25 * (std::sin(2.0 * top) - std::sin(2.0 * bottom));
    const double sincos =
        0.5 * (std::sin(top) * std::sin(top) - std::sin(bottom) * std::sin(bottom));
    const double omega = env.rowSolidAngle(y);
    rowOmega_[size_t(y)] = omega;
    for (int x = 0; x < w; ++x) {
      const double left = kPi * (1.0 - 2.0 * x / w), right = kPi * (1.0 - 2.0 * (x + 1) / w);
      const glm::dvec3 m((std::cos(right) - std::cos(left)) * cos2, (left - right) * sincos,
                         (std::sin(left) - std::sin(right)) * cos2);
      const double len = glm::length(m);
      const size_t t = size_t(y) * size_t(w) + size_t(x);
      const glm::dvec3 L(env.radiance(x, y));
      if (x == 0) rowMoment_[size_t(y)] = len;
      texels_[t] =
          Texel{env.direction(x, y), glm::vec3(m / len), glm::vec3(L * len), glm::vec3(L * omega)};
    }
  });
  // Every point of a texel lies within half its angular diagonal of its centre.
  const double halfDiagonal = 0.5 * std::hypot(kPi / h, 2.0 * kPi / w);

  levels_.resize(1);
  levels_[0].width = w;  // level 0 is the texels themselves (their data lives below)
  levels_[0].height = h;
  for (int size = 2; size <= topFactor; size *= 2) {
    Level level;
    level.width = (w + size - 1) / size;
    level.height = (h + size - 1) / size;
    const size_t cells = size_t(level.width) * size_t(level.height);
    level.axisX.resize(cells);
    level.axisY.resize(cells);
    level.axisZ.resize(cells);
    level.sinRadius.resize(cells);
    for (auto& m : level.moment) m.resize(cells);
    level.centroid.resize(cells);
    level.power.resize(cells);
    level.halfExtent.resize(cells);
    level.meanDirection.resize(cells);
    parallelFor(0, int64_t(cells), [&](int64_t ii) {
      const size_t i = size_t(ii);
      const int x0 = int(i % size_t(level.width)) * size, y0 = int(i / size_t(level.width)) * size;
      const int x1 = std::min(x0 + size, w), y1 = std::min(y0 + size, h);
      glm::dvec3 geometric(0.0);
      double omega = 0.0;
      glm::dvec3 axis(0.0), centroid(0.0), power(0.0),
          moment[3] = {glm::dvec3(0.0), glm::dvec3(0.0), glm::dvec3(0.0)};
      for (int y = y0; y < y1; ++y) {
        for (int x = x0; x < x1; ++x) {
          const size_t t = size_t(y) * size_t(w) + size_t(x);
          const glm::dvec3 m = glm::dvec3(texels_[t].moment);
          const glm::dvec3 lw(texels_[t].weighted);
          power += glm::dvec3(texels_[t].power);
          geometric += m * rowMoment_[size_t(y)];
          omega += rowOmega_[size_t(y)];
          axis += glm::dvec3(texels_[t].centre);
          centroid += m * (lw.x + lw.y + lw.z);
          for (int k = 0; k < 3; ++k) moment[k] += m * lw[k];
        }
      }
      const double axisLen = glm::length(axis);
      const glm::dvec3 a = axisLen > 0.0 ? axis / axisLen : glm::dvec3(0, 1, 0);
      double minCos = 1.0;
      for (int y = y0; y < y1; ++y) {
        for (int x = x0; x < x1; ++x) {
          minCos = std::min(
              minCos, glm::dot(glm::dvec3(texels_[size_t(y) * size_t(w) + size_t(x)].centre), a));
        }
      }
      // Pad by 1e-5 rad so that float rounding in the horizon test cannot misclassify a texel; a
      // cone wider than a hemisphere is always split.
      const double radius = std::acos(std::clamp(minCos, -1.0, 1.0)) + halfDiagonal + 1e-5;
      level.axisX[i] = float(a.x);
      level.axisY[i] = float(a.y);
      level.axisZ[i] = float(a.z);
      level.sinRadius[i] = radius >= 0.5 * kPi ? 2.0f : float(std::sin(radius));
      const double centroidLen = glm::length(centroid);
      level.centroid[i] = glm::vec3(centroidLen > 0.0 ? centroid / centroidLen : a);
      level.power[i] = glm::vec3(power);
      level.meanDirection[i] = glm::vec3(geometric / omega);
      const double midLat = kPi * (0.5 - 0.5 * (y0 + y1) / double(h));
      level.halfExtent[i] = glm::vec2(float(0.5 * kPi * (y1 - y0) / h),
                                      float(kPi * (x1 - x0) / w * std::cos(midLat)));
      for (int k = 0; k < 3; ++k) {
        level.moment[3 * k][i] = float(moment[k].x);
        level.moment[3 * k + 1][i] = float(moment[k].y);
        level.moment[3 * k + 2][i] = float(moment[k].z);
      }
    });
    levels_.push_back(std::move(level));
  }
}

size_t RadianceCells::cellCount() const {
  size_t n = 0;
  for (const auto& l : levels_) n += l.axisX.size();
  return n;
}

size_t RadianceCells::floatsStored() const {
  return cellCount() * 24 + texels_.size() * 12;
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
