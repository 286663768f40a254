// Capture volumes: lighting that varies with position because the surroundings are not at
// infinity.
//
// An environment is captured at one point. Read as infinitely distant, it gives every position the
// same incoming radiance. A proxy of the surroundings fixes that: a box (a room: its size and where
// the capture point is inside it) or a sphere of some radius around the capture point. Radiance
// arriving at a point p from direction ω is then the radiance that leaves the proxy where the ray
// p + tω meets it, q, and that is what the capture saw looking from the capture point c towards q:
//
//     L(p, ω) = L_env(normalize(q - c))          (parallax correction)
//
// so a point near a bright wall sees that wall under a larger solid angle than the capture point
// did. At p = c, and for the distant proxy, L(p, ω) = L_env(ω) exactly.
//
// Frames: the proxy lives in world coordinates (metres; +Y up); `environmentFromWorld` rotates a
// world direction into the environment's own frame (the pipeline's --env-yaw), and environments
// returned by at() are in the environment's frame, like the distant one.
#pragma once

#include <string>

#include <glm/mat3x3.hpp>
#include <glm/vec3.hpp>

#include "lighting/filtered_cube.h"
#include "lighting/volume.h"

namespace compose::lighting {

struct CaptureProxy {
  enum class Shape { Distant, Box, Sphere } shape = Shape::Distant;
  // In the world's unit of length (`unit`): metres, or a pose file's (calib/chessboard.h).
  glm::dvec3 boxMin{0.0}, boxMax{0.0};  // Box
  double radius = 0.0;                  // Sphere, centred on the capture point
  glm::dvec3 capturePoint{0.0};         // where the environment was captured
  glm::dmat3 environmentFromWorld{1.0};
  std::string unit = "m";  // the world's unit of length, for describe() and errors

  // compose::Error (stage "lighting") on an empty box, a capture point outside it, a radius <= 0
  // or non-finite numbers.
  void validate() const;
  // True if p is strictly inside the proxy (always, for the distant one).
  bool contains(const glm::dvec3& p) const;
  // Where the ray from `position` along unit `direction` leaves the proxy, and the proxy's
  // outward unit normal there. Box or Sphere only. A position outside is first moved to the
  // nearest point just inside.
  glm::dvec3 exit(const glm::dvec3& position, const glm::dvec3& direction,
                  glm::dvec3* normal = nullptr) const;
  // A human-readable summary: "room 6 x 3 x 8 m, captured at (0, 1.6, 0)".
  std::string describe() const;
};

// A RadianceSource (volume.h) for a captured environment and its proxy.
class CaptureVolumeSource final : public RadianceSource {
 public:
  CaptureVolumeSource(Environment environment, CaptureProxy proxy);

  bool isDistant() const override { return proxy_.shape == CaptureProxy::Shape::Distant; }

  // Radiance arriving at world point `position` from world direction `direction` (unit): the
  // environment's bilinear lookup (Environment::lookup) in the parallax-corrected direction.
  glm::vec3 radiance(const glm::dvec3& position, const glm::dvec3& direction) const;

  // The environment seen from `position`, in the environment's frame, at the captured map's size.
  // Each texel is the captured radiance averaged over the proxy patch the texel sees from there:
  // a prefiltered lookup (filtered_cube.h) whose footprint is the texel's solid angle carried
  // through the re-projection, |q - p|² cos θ_c / (|q - c|² cos θ_p). At the capture point, and
  // for the distant proxy, it is the captured environment itself.
  Environment at(const glm::vec3& position) const override;

  const CaptureProxy& proxy() const { return proxy_; }

 private:
  Environment environment_;
  FilteredCube filtered_;
  CaptureProxy proxy_;
};

}  // namespace compose::lighting
