// Bright sources split off an environment.
//
// A small, very bright light (a lamp, the sun) inside one cell of a lighting grid is where every
// cell-based representation of shadowing fails: the cell's average visibility says "half in
// shadow" where the truth is "in the light" or "in the dark". So the brightest parts of the map
// are taken out as point-like sources, each with its power and direction, to be shadowed by
// exact rays; what remains (the residual) is smooth enough for the moment bases.
//
// Sources are chosen on the map reduced to at most 1024 texels wide (each source a block of
// texels at that scale, at most 0.35° across): the `count` blocks of highest power
// Σ L·Ω (mean of RGB). Their texels are set to zero in the residual, so that
// residual + sources = the map, exactly.
#pragma once

#include <vector>

#include <glm/vec3.hpp>

#include "lighting/environment.h"

namespace compose::lighting {

struct LightSource {
  glm::vec3 direction;  // unit, the power-weighted centre of the block
  glm::vec3 power;      // Σ L Ω over the block (RGB): irradiance at normal incidence
  // The block's extent: half its latitude span and half its longitude span (radians), so that
  // shadows can be traced across the source's area rather than from one direction.
  float halfLatitude = 0.0f, halfLongitude = 0.0f;
};

struct SourceSplit {
  std::vector<LightSource> sources;
  Environment residual;
  double sourceShare = 0.0;  // fraction of the map's power in the sources
};

// At most this many sources are split off (the renderer keeps per-hit state for each).
inline constexpr int kMaxSources = 64;

// `count` in 0..kMaxSources.
SourceSplit splitBrightSources(const Environment& environment, int count);

}  // namespace compose::lighting
