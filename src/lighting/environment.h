// Environment: distant incoming radiance L(ω) stored as a lat-long (equirectangular) map.
//
// Conventions (written down once, here; tests/lighting/environment_test.cpp pins them with a map
// that has one bright texel):
//  * World frame: right-handed, +Y up, the camera looks along -Z.
//  * Axes follow OpenEXR's Imf::LatLongMap: longitude φ = atan2(x, z), latitude λ = asin(y);
//    direction(λ, φ) = (sin φ cos λ, sin λ, cos φ cos λ). The top row is straight up (+Y), the
//    centre column looks along +Z, and longitude decreases from +π at the left edge to -π at the
//    right edge (so +X is a quarter of the way in from the left).
//  * Texel (x, y) covers φ ∈ π(1 - 2[x, x+1]/W) and λ ∈ π(1/2 - [y, y+1]/H); its value is the
//    mean radiance over that cell and its direction is the cell centre. The solid angle of a
//    texel is exact: Δφ (sin λ_top - sin λ_bottom); the sum over the map is 4π.
//
// Values are radiance (W sr^-1 m^-2 or any consistent scale), RGB, in the working colour space.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "core/image.h"

namespace compose::lighting {

// The largest radiance an environment texel may hold: 10^32, far beyond any light (the sun is
// 1.6·10^9 cd/m²) and still leaving the lighting integrals room below single precision's
// 3.4·10^38 (the end-to-end tests light an object with 10^30, a little more after colour
// conversion, to check float EXR output). Beyond it is damage, not light: a texel of 3·10^38
// (found by fuzzing) gave infinite irradiance. Such a texel is an error, like NaN and infinity.
inline constexpr float kMaxRadiance = 1e32f;

// What fromLatLong() did to make the data usable.
struct SanitizeReport {
  int64_t negativeTexels = 0;  // texels with a negative channel, clamped to 0
  float mostNegative = 0.0f;
  // Set by the caller: negative values are counted but kept (a conversion between layouts,
  // which changes no value: out-of-gamut colours keep their negative channels).
  bool keepNegative = false;

  // Copies one texel's RGB `src` to `dst`, a negative value clamped to 0 and counted. False,
  // with the value in `bad`, when a value cannot be radiance (NaN, infinite, beyond
  // kMaxRadiance): the caller throws badRadiance() naming the texel.
  bool take(const float src[3], float dst[3], float& bad);
  // The note for the user about the clamped texels, "<n> <kind> texel(s) had negative values (as
  // low as <v>): clamped to 0" (kind: "environment ", "cube ", or ""); empty when there were none.
  std::string negativeNote(const std::string& kind) const;
  // What is wrong with `value`, placing `where` (" at texel (3, 4)") in the sentence.
  static std::string badRadiance(float value, const std::string& where);
};

class Environment {
 public:
  Environment() = default;

  // Takes an RGB (or RGBA: alpha is dropped) lat-long image of radiance. The width must be twice
  // the height. NaN, infinite or larger than kMaxRadiance texels are rejected (compose::Error
  // naming `file` and the first bad texel); negative values, which lossy HDR codecs produce near
  // zero, are clamped to 0 and counted in `report`.
  static Environment fromLatLong(const Image& image, const std::filesystem::path& file = {},
                                 SanitizeReport* report = nullptr);

  // A constant environment of radiance `value` (the white-furnace test).
  static Environment constant(glm::vec3 value, int width = 64);

  int width() const { return width_; }
  int height() const { return height_; }
  const std::string& colorSpace() const { return colorSpace_; }

  glm::vec3 radiance(int x, int y) const {
    const float* p = texels_.data() + (size_t(y) * size_t(width_) + size_t(x)) * 3;
    return {p[0], p[1], p[2]};
  }
  // The radiance, RGB interleaved, row-major (for hashing and copying).
  const std::vector<float>& texels() const { return texels_; }
  // Changes one texel (non-negative, finite radiance).
  void setRadiance(int x, int y, const glm::vec3& L) {
    float* p = texels_.data() + (size_t(y) * size_t(width_) + size_t(x)) * 3;
    p[0] = L.x;
    p[1] = L.y;
    p[2] = L.z;
  }

  // Direction of the centre of texel (x, y).
  glm::vec3 direction(int x, int y) const;
  // Solid angle of any texel of row y (all texels of a row have the same).
  double rowSolidAngle(int y) const { return rowSolidAngle_[size_t(y)]; }

  // Direction → (continuous) texel coordinates, and a bilinear radiance lookup with wrap-around in
  // longitude. Used by sampling bases; not prefiltered.
  glm::vec3 lookup(const glm::vec3& direction) const;

  // The mean radiance (the mean of R, G and B) over the lower hemisphere over that over the upper
  // one, each by solid angle (rows wholly above or below the horizon); NaN when the upper one is
  // black. Below 1 for a map the right way up: ground lit by the sky reflects at most what falls
  // on it (the sample maps: 0.08-0.44).
  double belowOverAbove() const;

 private:
  int width_ = 0, height_ = 0;
  std::vector<float> texels_;  // RGB, row-major
  std::vector<double> rowSolidAngle_;
  std::vector<float> sinLon_, cosLon_, sinLat_, cosLat_;
  std::string colorSpace_;
  void buildTables();
};

}  // namespace compose::lighting
