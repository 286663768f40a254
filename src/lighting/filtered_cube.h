// FilteredCube: a cube map with a mip pyramid per face, for radiance lookups by direction and
// footprint ("what arrives from around this direction, averaged over this solid angle").
//
// Pyramid. Level 0 is the cube map. Level l+1 has faces of ceil(size_l / 2) texels, each the
// solid-angle-weighted mean of the level-l texels it covers, with exact texel solid angles (corner
// formula, cubemap.h) and exact partial overlaps when a size is odd; so ∫ L dω is the same at every
// level (to float rounding), and a constant map stays constant.
//
// Seamless filtering. Every level stores each face with a one-texel border copied from the
// neighbouring faces (the texel across the edge, at the same position along it), and each border
// corner holds the mean of the three texels that meet at that cube corner. Bilinear filtering then
// never leaves a face: at a face edge it returns the same value from both faces (no cracks), and
// no texel is stored twice inside the sphere (no doubled texels: borders are read-only copies).
//
// Lookups. lookup(d, Ω) picks the fractional level whose texels have solid angle Ω around d (the
// texel solid angle varies over a face by up to 5.2x between centre and corner, and that is taken
// into account) and filters trilinearly: bilinear in the two nearest levels, linear between them.
// Ω at or below the finest texels gives plain bilinear filtering of level 0. Lookups are const and
// thread-safe; values are radiance, as stored.
#pragma once

#include <vector>

#include <glm/vec3.hpp>

#include "core/progress.h"
#include "lighting/cubemap.h"
#include "lighting/environment.h"

namespace compose::lighting {

class FilteredCube {
 public:
  FilteredCube() = default;
  explicit FilteredCube(const CubeMap& cube);
  // The lat-long environment resampled exactly (sphere_resample.h) to a cube of `size` texels per
  // face edge (0: width / 4, which matches the lat-long's resolution on the equator), then
  // filtered.
  static FilteredCube fromEnvironment(const Environment& environment, int size = 0,
                                      const Progress& progress = {});

  bool empty() const { return levels_.empty(); }
  int levels() const { return int(levels_.size()); }
  int size(int level) const { return levels_[size_t(level)].size; }

  // Mean radiance over a footprint of `solidAngle` steradians around unit direction d.
  glm::vec3 lookup(const glm::vec3& d, float solidAngle) const;
  // The texel of level 0 that d falls in (the map read as piecewise constant, no filtering).
  glm::vec3 nearest(const glm::vec3& d) const;
  // Trilinear lookup at a fractional level (clamped to [0, levels() - 1]).
  glm::vec3 lookupLevel(const glm::vec3& d, float level) const;
  // The fractional level whose texels around d have solid angle `solidAngle`.
  float levelFor(const glm::vec3& d, float solidAngle) const;

  // Texel (x, y) of a face at a level; x or y may be -1 or size (the border).
  glm::vec3 texel(int level, int face, int x, int y) const {
    const Level& L = levels_[size_t(level)];
    const float* p = L.texels.data() + L.offset(face, x, y);
    return {p[0], p[1], p[2]};
  }
  // ∫ L dω at a level, exact texel solid angles, in double.
  glm::dvec3 integral(int level) const;
  // Bytes held by the pyramid.
  size_t bytes() const;

 private:
  struct Level {
    int size = 0;
    int stride = 0;             // size + 2
    std::vector<float> texels;  // 6 faces x stride² x RGB, borders included
    size_t offset(int face, int x, int y) const {
      return ((size_t(face) * size_t(stride) + size_t(y + 1)) * size_t(stride) + size_t(x + 1)) * 3;
    }
  };
  void fillBorders(Level& level) const;
  glm::vec3 bilinear(const Level& level, int face, double a, double b) const;
  float levelAt(double a, double b, float solidAngle) const;
  glm::vec3 sample(int face, double a, double b, float level) const;

  std::vector<Level> levels_;
};

}  // namespace compose::lighting
