#include "lighting/environment.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>

#include "core/error.h"
#include "core/numbers.h"

namespace compose::lighting {

void Environment::buildTables() {
  rowSolidAngle_.resize(size_t(height_));
  sinLat_.resize(size_t(height_));
  cosLat_.resize(size_t(height_));
  const double dPhi = 2.0 * kPi / width_;
  for (int y = 0; y < height_; ++y) {
    const double top = kPi * (0.5 - double(y) / height_);
    const double bottom = kPi * (0.5 - double(y + 1) / height_);
    const double centre = kPi * (0.5 - (y + 0.5) / height_);
    rowSolidAngle_[size_t(y)] = dPhi * (std::sin(top) - std::sin(bottom));
    sinLat_[size_t(y)] = float(std::sin(centre));
    cosLat_[size_t(y)] = float(std::cos(centre));
  }
  sinLon_.resize(size_t(width_));
  cosLon_.resize(size_t(width_));
  for (int x = 0; x < width_; ++x) {
    const double lon = kPi * (1.0 - 2.0 * (x + 0.5) / width_);
    sinLon_[size_t(x)] = float(std::sin(lon));
    cosLon_[size_t(x)] = float(std::cos(lon));
  }
}

double Environment::belowOverAbove() const {
  double sum[2] = {0.0, 0.0}, area[2] = {0.0, 0.0};  // above, below
  for (int y = 0; y < height_; ++y) {
    // Row y spans latitudes π(1/2 - [y, y+1]/H): above the horizon for y + 1 <= H/2.
    const int half = 2 * (y + 1) <= height_ ? 0 : 2 * y >= height_ ? 1 : -1;
    if (half < 0) continue;
    double row = 0.0;
    const float* p = texels_.data() + size_t(y) * size_t(width_) * 3;
    for (size_t i = 0; i < size_t(width_) * 3; ++i) row += double(p[i]);
    sum[half] += row / 3.0 * rowSolidAngle(y);
    area[half] += double(width_) * rowSolidAngle(y);
  }
  if (!(sum[0] > 0.0) || !(area[1] > 0.0)) return std::numeric_limits<double>::quiet_NaN();
  return (sum[1] / area[1]) / (sum[0] / area[0]);
}

glm::vec3 Environment::direction(int x, int y) const {
  const float cl = cosLat_[size_t(y)];
  return {sinLon_[size_t(x)] * cl, sinLat_[size_t(y)], cosLon_[size_t(x)] * cl};
}

bool SanitizeReport::take(const float src[3], float dst[3], float& bad) {
  bool negative = false;
  for (int c = 0; c < 3; ++c) {
    float v = src[c];
    if (!std::isfinite(v) || v > kMaxRadiance) {
      bad = v;
      return false;
    }
    if (v < 0.0f) {
      mostNegative = std::min(mostNegative, v);
      negative = true;
      if (!keepNegative) v = 0.0f;
    }
    dst[c] = v;
  }
  if (negative) ++negativeTexels;
  return true;
}

std::string SanitizeReport::negativeNote(const std::string& kind) const {
  if (negativeTexels == 0) return {};
  return std::to_string(negativeTexels) + " " + kind + (negativeTexels == 1 ? "texel" : "texels") +
         " had negative values (as low as " + numberText(mostNegative) + ")" +
         (keepNegative ? ": kept (out-of-gamut colours; light is clamped at 0 where it is used)"
                       : ": clamped to 0");
}

std::string SanitizeReport::badRadiance(float value, const std::string& where) {
  if (std::isnan(value)) return "NaN radiance" + where;
  if (std::isinf(value)) return "infinite radiance" + where;
  return "radiance " + numberText(value) + where +
         " is beyond any light (more than 1e32): a damaged file?";
}

Environment Environment::fromLatLong(const Image& image, const std::filesystem::path& file,
                                     SanitizeReport* report) {
  if (image.channels < 3) {
    throw Error("lighting",
                "environment needs RGB channels, the image has " + std::to_string(image.channels),
                file);
  }
  if (image.height < 1 || image.width != 2 * image.height) {
    throw Error("lighting",
                "not a lat-long (equirectangular) map: it is " + std::to_string(image.width) + "x" +
                    std::to_string(image.height) +
                    ", and a lat-long map is twice as wide as it is high",
                file);
  }
  Environment env;
  env.width_ = image.width;
  env.height_ = image.height;
  env.colorSpace_ = image.colorSpace;
  env.texels_.resize(image.pixelCount() * 3);
  SanitizeReport local;
  local.keepNegative = report && report->keepNegative;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const float* src = image.at(x, y);
      float* dst = env.texels_.data() + (size_t(y) * size_t(image.width) + size_t(x)) * 3;
      float bad = 0.0f;
      if (!local.take(src, dst, bad)) {
        throw Error("lighting",
                    SanitizeReport::badRadiance(
                        bad, " at texel (" + std::to_string(x) + ", " + std::to_string(y) + ")"),
                    file);
      }
    }
  }
  if (report) *report = local;
  env.buildTables();
  return env;
}

Environment Environment::constant(glm::vec3 value, int width) {
  COMPOSE_CHECK(width >= 2 && width % 2 == 0);  // 2x1 is the smallest lat-long map
  Environment env;
  env.width_ = width;
  env.height_ = width / 2;
  env.texels_.resize(size_t(env.width_) * size_t(env.height_) * 3);
  for (size_t i = 0; i < env.texels_.size(); i += 3) {
    env.texels_[i] = value.x;
    env.texels_[i + 1] = value.y;
    env.texels_[i + 2] = value.z;
  }
  env.buildTables();
  return env;
}

glm::vec3 Environment::lookup(const glm::vec3& d) const {
  const double len = std::sqrt(double(d.x) * d.x + double(d.y) * d.y + double(d.z) * d.z);
  COMPOSE_CHECK(len > 0.0);
  const double lat = std::asin(std::clamp(d.y / len, -1.0, 1.0));
  const double lon = std::atan2(double(d.x), double(d.z));
  // Continuous coordinates with texel centres at integer + 0.5.
  const double u = (1.0 - lon / kPi) * 0.5 * width_ - 0.5;
  const double v = (0.5 - lat / kPi) * height_ - 0.5;
  const int x0 = int(std::floor(u)), y0 = int(std::floor(v));
  const float fx = float(u - x0), fy = float(v - y0);
  // Longitude wraps around; x is within one width of the map (lon ∈ [-π, π]), so a compare
  // does what a modulo would, without the division.
  auto texel = [&](int x, int y) {
    if (x < 0) x += width_;
    if (x >= width_) x -= width_;
    if (x < 0 || x >= width_) x = ((x % width_) + width_) % width_;
    y = std::clamp(y, 0, height_ - 1);
    return radiance(x, y);
  };
  return (texel(x0, y0) * (1 - fx) + texel(x0 + 1, y0) * fx) * (1 - fy) +
         (texel(x0, y0 + 1) * (1 - fx) + texel(x0 + 1, y0 + 1) * fx) * fy;
}

}  // namespace compose::lighting
