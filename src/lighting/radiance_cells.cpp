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

RadianceCells::RadianceCells(const Environment& env, int factor) : width_(env.width()) {
  COMPOSE_CHECK(factor >= 1);
  const int w = env.width(), h = env.height();
  // Per texel, the exact vector moment m_t = ∫_texel ω dω of its lat-long cell, in closed form:
  // with dω = cos λ dλ dφ, m = (∫sin φ dφ ∫cos²λ dλ, ∫dφ ∫sin λ cos λ dλ, ∫cos φ dφ ∫cos²λ dλ).
  // A texel wholly above the horizon of n then contributes L_t (n·m_t): the exact integral of the
  // box-filtered map, not a midpoint rule. directions_ holds m̂_t and weighted_ holds L_t |m_t|.
  directions_.resize(size_t(w) * size_t(h));
  weighted_.resize(directions_.size());
  centres_.resize(directions_.size());
  power_.resize(directions_.size());
  rows_.resize(size_t(h));
  sinLon_.resize(size_t(w));
  cosLon_.resize(size_t(w));
  for (int x = 0; x < w; ++x) {
    const double lon = kPi * (1.0 - 2.0 * (x + 0.5) / w);
    sinLon_[size_t(x)] = float(std::sin(lon));
    cosLon_[size_t(x)] = float(std::cos(lon));
  }
  for (int y = 0; y < h; ++y) {
    const double centreLat = kPi * (0.5 - (y + 0.5) / h);
    rows_[size_t(y)] = Row{float(std::sin(centreLat)), float(std::cos(centreLat)), float(0.5 * kPi / h),
                           float(kPi / w * std::cos(centreLat))};
    const double top = kPi * (0.5 - double(y) / h), bottom = kPi * (0.5 - double(y + 1) / h);
    const double cos2 = 0.5 * (top - bottom) + 0.25 * (std::sin(2.0 * top) - std::sin(2.0 * bottom));
    const double sincos = 0.5 * (std::sin(top) * std::sin(top) - std::sin(bottom) * std::sin(bottom));
    for (int x = 0; x < w; ++x) {
      const double left = kPi * (1.0 - 2.0 * x / w), right = kPi * (1.0 - 2.0 * (x + 1) / w);
      const glm::dvec3 m((std::cos(right) - std::cos(left)) * cos2, (left - right) * sincos,
                         (std::sin(left) - std::sin(right)) * cos2);
      const double len = glm::length(m);
      const size_t t = size_t(y) * size_t(w) + size_t(x);
      directions_[t] = glm::vec3(m / len);
      weighted_[t] = glm::vec3(glm::dvec3(env.radiance(x, y)) * len);
      centres_[t] = env.direction(x, y);
      power_[t] = glm::vec3(glm::dvec3(env.radiance(x, y)) * env.rowSolidAngle(y));
    }
  }
  // Half the angular diagonal of the largest texel: every point of a texel lies within this angle
  // of its centre.
  const double halfDiagonal = 0.5 * std::hypot(kPi / h, 2.0 * kPi / w);
  const int cw = (w + factor - 1) / factor, ch = (h + factor - 1) / factor;
  cells_.resize(size_t(cw) * size_t(ch));
  parallelFor(0, int64_t(cells_.size()), [&](int64_t i) {
    Cell& c = cells_[size_t(i)];
    c.x0 = int(i % cw) * factor;
    c.y0 = int(i / cw) * factor;
    c.x1 = std::min(c.x0 + factor, w);
    c.y1 = std::min(c.y0 + factor, h);
    glm::dvec3 axis(0.0), centroid(0.0), moment[3] = {glm::dvec3(0.0), glm::dvec3(0.0), glm::dvec3(0.0)};
    for (int y = c.y0; y < c.y1; ++y) {
      for (int x = c.x0; x < c.x1; ++x) {
        const size_t t = size_t(y) * size_t(w) + size_t(x);
        const glm::dvec3 d(directions_[t]);
        const glm::dvec3 lw(weighted_[t]);
        axis += glm::dvec3(centres_[t]);
        centroid += d * (lw.x + lw.y + lw.z);
        for (int k = 0; k < 3; ++k) moment[k] += d * lw[k];
      }
    }
    const double axisLen = glm::length(axis);
    c.axis = axisLen > 0.0 ? glm::vec3(axis / axisLen) : glm::vec3(0, 1, 0);
    const double centroidLen = glm::length(centroid);
    c.centroid = centroidLen > 0.0 ? glm::vec3(centroid / centroidLen) : c.axis;
    for (int k = 0; k < 3; ++k) c.moment[k] = glm::vec3(moment[k]);
    // Half-angle of the cone around the axis that holds every member direction.
    double minCos = 1.0;
    for (int y = c.y0; y < c.y1; ++y) {
      for (int x = c.x0; x < c.x1; ++x) {
        minCos = std::min(minCos, double(glm::dot(glm::dvec3(centres_[size_t(y) * size_t(w) + size_t(x)]),
                                                  glm::dvec3(c.axis))));
      }
    }
    const double radius = std::acos(std::clamp(minCos, -1.0, 1.0)) + halfDiagonal;
    // Pad by 1e-5 rad so float rounding in the horizon test can never misclassify a texel; a
    // cone wider than a hemisphere is always refined.
    c.sinRadius = radius + 1e-5 >= 1.5707963 ? 2.0f : float(std::sin(radius + 1e-5));
  });
}

float RadianceCells::clippedMean(float c, float a, float b) {
  a = std::abs(a);
  b = std::abs(b);
  if (a < b) std::swap(a, b);
  auto ramp = [](double x) { return x > 0.0 ? x : 0.0; };
  if (a < 1e-7f) return float(ramp(c));
  if (b < 1e-4f * a) {
    // One-dimensional: mean of max(0, c + s a) over s ∈ [-1, 1].
    const double hi = ramp(double(c) + a);
    const double lo = ramp(double(c) - a);
    return float((hi * hi - lo * lo) / (4.0 * a));
  }
  auto r = [&](double x) {
    const double p = ramp(x);
    return p * p * p / 6.0;
  };
  const double cd = c, ad = a, bd = b;
  const double sum = r(cd + ad + bd) - r(cd + ad - bd) - r(cd - ad + bd) + r(cd - ad - bd);
  return float(sum / (4.0 * ad * bd));
}

glm::vec3 RadianceCells::irradiance(const glm::vec3& n) const {
  glm::vec3 e(0.0f);
  forEachAbove(n, [&](const glm::vec3&, const glm::vec3& v) { e += v; });
  return e;
}

}  // namespace compose::lighting
