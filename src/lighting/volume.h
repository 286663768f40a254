// LightingVolume: lighting at the points of a uniform 3D grid spanning a capture volume,
// trilinearly interpolated in between — the irradiance volume of Greger et al. (1998), which the
// paper uses to move a synthetic object through the scene (§1).
//
// Each grid point holds one projected DiffuseLighting, made from the radiance a RadianceSource
// gives for that position. A distant source (the same environment everywhere: a single HDRI) is
// projected once and shared by every point; position-dependent sources (parallax-corrected
// captures: capture_volume.h) are projected per point. Irradiance is linear in the lighting
// coefficients, so interpolating the eight neighbours' irradiance equals interpolating their
// coefficients. Positions outside the volume are clamped to its boundary.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "lighting/lighting.h"

namespace compose::lighting {

// Where incoming radiance comes from, per position.
class RadianceSource {
 public:
  virtual ~RadianceSource() = default;
  // True when every position sees the same environment (a distant source).
  virtual bool isDistant() const = 0;
  virtual Environment at(const glm::vec3& position) const = 0;
};

// The same environment everywhere.
class DistantSource final : public RadianceSource {
 public:
  explicit DistantSource(Environment environment) : environment_(std::move(environment)) {}
  bool isDistant() const override { return true; }
  Environment at(const glm::vec3&) const override { return environment_; }

 private:
  Environment environment_;
};

// A source given by a function of position (for tests and synthetic scenes).
class FunctionSource final : public RadianceSource {
 public:
  explicit FunctionSource(std::function<Environment(const glm::vec3&)> f) : f_(std::move(f)) {}
  bool isDistant() const override { return false; }
  Environment at(const glm::vec3& p) const override { return f_(p); }

 private:
  std::function<Environment(const glm::vec3&)> f_;
};

struct VolumeParams {
  glm::vec3 boundsMin{-1.0f}, boundsMax{1.0f};
  glm::ivec3 resolution{2, 2, 2};  // grid points per axis, >= 1 each
  std::string basis = "cheb-local";
  ParamSet basisParams;
  void validate() const;  // compose::Error (stage "lighting") on empty bounds or resolution < 1
};

class LightingVolume {
 public:
  explicit LightingVolume(VolumeParams params);

  // Projects the source at every grid point (once in all if the source is distant).
  void build(const RadianceSource& source, const Progress& progress = {});

  // Irradiance at `position` for unit normal n (see lighting.h for units).
  glm::vec3 irradiance(const glm::vec3& position, const glm::vec3& n) const;

  glm::vec3 gridPoint(int i, int j, int k) const;
  size_t pointCount() const;
  // Floats stored by all distinct projections (a shared distant projection counts once).
  size_t floatsStored() const;

 private:
  VolumeParams params_;
  std::vector<std::shared_ptr<const DiffuseLighting>> points_;  // x fastest, then y, then z
};

}  // namespace compose::lighting
