// Diffuse lighting representations behind one interface.
//
// A DiffuseLighting turns an Environment (distant radiance) into a compact set of coefficients
// (project), and then answers irradiance queries for a surface normal (irradiance). Spherical
// harmonics, the Chebyshev (Tchebichef) moment bases and the references all implement it, so the
// renderer and the benchmarks treat them alike. Bases are created by name from one explicit list
// (createLighting); an unknown name is an error that lists the valid ones, and parameters the
// basis did not read are reported.
//
// Units: irradiance() returns IRRADIANCE, E(n) = ∫ L(ω) max(0, n·ω) dω, not radiance. A Lambertian
// surface of albedo ρ reflects radiance ρ·E(n)/π. A constant environment of radiance 1 gives
// E = π for every normal.
//
// Threading: project() may use all cores; after it returns, irradiance() is const and may be
// called concurrently from any number of threads.
#pragma once

#include <cstddef>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "core/params.h"
#include "core/progress.h"
#include "lighting/environment.h"

namespace compose::lighting {

class DiffuseLighting {
 public:
  virtual ~DiffuseLighting() = default;

  virtual std::string name() const = 0;
  // One line for people: the basis and its parameters, e.g. "sh order=2 (9 coefficients/channel)".
  virtual std::string describe() const = 0;

  virtual void project(const Environment& environment, const Progress& progress = {}) = 0;

  // Irradiance at unit world-space normal n. project() must have been called.
  virtual glm::vec3 irradiance(const glm::vec3& n) const = 0;

  // For a view-dependent BRDF (Oren–Nayar), the Lambertian-equivalent irradiance π L_o / ρ seen
  // from unit direction `view` (surface towards the eye), so that the renderer's ρ E / π is the
  // outgoing radiance for every BRDF. Lambertian bases ignore the view.
  virtual glm::vec3 irradiance(const glm::vec3& n, const glm::vec3& /*view*/) const {
    return irradiance(n);
  }

  // Coefficients per colour channel, and the total number of floats stored for the lighting.
  virtual int coefficientsPerChannel() const = 0;
  virtual size_t floatsStored() const = 0;

  // Everything that determines the projection besides the environment ("cheb-local order=1
  // samples=8 ..."): part of the on-disk cache key (lighting_cache.h).
  virtual std::string parameterKey() const { return describe(); }
  // The projected state as plain floats, for the on-disk cache and lighting files. A basis that
  // keeps no projection (it reads the environment while shading) keeps the defaults.
  virtual bool exportState(std::vector<float>& /*out*/) const { return false; }
  // Restores a state written by exportState for the same parameterKey(); false if it does not fit.
  virtual bool importState(std::span<const float> /*in*/) { return false; }
};

// Names accepted by createLighting, in a stable order.
const std::vector<std::string>& lightingNames();

// Creates a basis by name. Parameters (from `params`, e.g. "order=2") are validated here; an
// unknown name or a parameter the basis does not take throws compose::Error (stage "lighting").
std::unique_ptr<DiffuseLighting> createLighting(const std::string& name, ParamSet params = {});

}  // namespace compose::lighting
