#include "lighting/capture_volume.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <glm/geometric.hpp>
#include <glm/matrix.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::lighting {

namespace {

bool finite(const glm::dvec3& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}

// Points on or outside the proxy are pulled this far inside it, so that every ray leaves it.
constexpr double kInset = 1e-6;

}  // namespace

void CaptureProxy::validate() const {
  // Surroundings a thousand kilometres away show no parallax: they are distant. Beyond that the
  // projections onto the proxy lose their precision (and at 1e308 overflow).
  constexpr double kLargest = 1e6;
  auto within = [](const glm::dvec3& v) {
    return std::abs(v.x) <= kLargest && std::abs(v.y) <= kLargest && std::abs(v.z) <= kLargest;
  };
  if (!finite(capturePoint) || !within(capturePoint))
    throw Error("lighting",
                "the capture point must be finite, each of its coordinates within 1e6 (1000 km in "
                "metres) of the world's origin (the ground point below the plate camera, or the "
                "board's centre with --pose)");
  if ((shape == Shape::Box && (!within(boxMin) || !within(boxMax))) ||
      (shape == Shape::Sphere && radius > kLargest)) {
    throw Error("lighting",
                "surroundings reaching more than 1e6 (1000 km in metres) from the world's origin: "
                "use a distant environment (no --room, no --env-radius)");
  }
  switch (shape) {
    case Shape::Distant:
      return;
    case Shape::Box:
      if (!finite(boxMin) || !finite(boxMax) || !(boxMax.x > boxMin.x) || !(boxMax.y > boxMin.y) ||
          !(boxMax.z > boxMin.z)) {
        throw Error("lighting", "the room must have a positive width, height and depth");
      }
      if (!contains(capturePoint)) {
        char s[640];
        std::snprintf(s, sizeof s,
                      "the capture point (%g, %g, %g) is not inside the room (x %g..%g, y %g..%g, "
                      "z %g..%g %s): parallax needs the camera inside (without --capture-at it is "
                      "the plate camera's position: give a taller or larger room, or "
                      "--capture-at)",
                      capturePoint.x, capturePoint.y, capturePoint.z, boxMin.x, boxMax.x, boxMin.y,
                      boxMax.y, boxMin.z, boxMax.z, unit.c_str());
        throw Error("lighting", s);
      }
      return;
    case Shape::Sphere:
      if (!(radius > 0.0) || !std::isfinite(radius))
        throw Error("lighting",
                    "the environment's radius (--env-radius) must be a positive number (of " +
                        unit + "), got " + numberText(radius));
      // As for a room: the photos were taken above the ground the object stands on.
      if (capturePoint.y < 0.0) {
        char s[200];
        std::snprintf(s, sizeof s,
                      "the capture point (%g, %g, %g) is below the ground (y < 0): the "
                      "environment was captured above the ground the object stands on",
                      capturePoint.x, capturePoint.y, capturePoint.z);
        throw Error("lighting", s);
      }
      return;
  }
}

bool CaptureProxy::contains(const glm::dvec3& p) const {
  switch (shape) {
    case Shape::Distant:
      return true;
    case Shape::Box:
      return p.x > boxMin.x && p.x < boxMax.x && p.y > boxMin.y && p.y < boxMax.y &&
             p.z > boxMin.z && p.z < boxMax.z;
    case Shape::Sphere:
      return glm::length(p - capturePoint) < radius;
  }
  return false;
}

std::string CaptureProxy::describe() const {
  char s[200];
  switch (shape) {
    case Shape::Distant:
      return "infinitely distant";
    case Shape::Box:
      std::snprintf(s, sizeof s, "room %g x %g x %g %s, captured at (%g, %g, %g)",
                    boxMax.x - boxMin.x, boxMax.y - boxMin.y, boxMax.z - boxMin.z, unit.c_str(),
                    capturePoint.x, capturePoint.y, capturePoint.z);
      return s;
    case Shape::Sphere:
      std::snprintf(s, sizeof s, "sphere of radius %g %s around (%g, %g, %g)", radius, unit.c_str(),
                    capturePoint.x, capturePoint.y, capturePoint.z);
      return s;
  }
  return {};
}

glm::dvec3 CaptureProxy::exit(const glm::dvec3& position, const glm::dvec3& d,
                              glm::dvec3* normal) const {
  if (shape == Shape::Box) {
    glm::dvec3 p;
    for (int a = 0; a < 3; ++a) {
      const double span = boxMax[a] - boxMin[a];
      p[a] = std::clamp(position[a], boxMin[a] + kInset * span, boxMax[a] - kInset * span);
    }
    double t = std::numeric_limits<double>::infinity();
    int axis = 0;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0.0) continue;
      const double ta = ((d[a] > 0.0 ? boxMax[a] : boxMin[a]) - p[a]) / d[a];
      if (ta < t) {
        t = ta;
        axis = a;
      }
    }
    if (normal) {
      *normal = glm::dvec3(0.0);
      (*normal)[axis] = d[axis] > 0.0 ? 1.0 : -1.0;
    }
    return p + t * d;
  }
  COMPOSE_CHECK(shape == Shape::Sphere);
  glm::dvec3 p = position - capturePoint;
  const double r = glm::length(p);
  if (r > radius * (1.0 - kInset)) p *= radius * (1.0 - kInset) / r;
  // |p + t d| = R with |d| = 1: t = -b + sqrt(b² - (|p|² - R²)), b = p·d.
  const double b = glm::dot(p, d);
  const double t = -b + std::sqrt(std::max(0.0, b * b - (glm::dot(p, p) - radius * radius)));
  const glm::dvec3 q = p + t * d;
  if (normal) *normal = q / radius;
  return capturePoint + q;
}

CaptureVolumeSource::CaptureVolumeSource(Environment environment, CaptureProxy proxy)
    : environment_(std::move(environment)), proxy_(proxy) {
  proxy_.validate();
  if (proxy_.shape != CaptureProxy::Shape::Distant)
    filtered_ = FilteredCube::fromEnvironment(environment_);
}

glm::vec3 CaptureVolumeSource::radiance(const glm::dvec3& position,
                                        const glm::dvec3& direction) const {
  if (isDistant() || position == proxy_.capturePoint) {
    return environment_.lookup(glm::vec3(proxy_.environmentFromWorld * direction));
  }
  const glm::dvec3 q = proxy_.exit(position, direction);
  const glm::dvec3 fromCapture = glm::normalize(q - proxy_.capturePoint);
  return environment_.lookup(glm::vec3(proxy_.environmentFromWorld * fromCapture));
}

Environment CaptureVolumeSource::at(const glm::vec3& position) const {
  const glm::dvec3 p(position);
  // The capture point itself (to a micrometre, float positions): the captured map.
  if (isDistant() || glm::length(p - proxy_.capturePoint) < 1e-6) return environment_;
  const int w = environment_.width(), h = environment_.height();
  const glm::dmat3 worldFromEnvironment = glm::transpose(proxy_.environmentFromWorld);
  Image img(w, h, 3, {"R", "G", "B"});
  img.colorSpace = environment_.colorSpace();
  parallelFor(0, h, [&](int64_t yy) {
    const int y = int(yy);
    const double omega = environment_.rowSolidAngle(y);
    for (int x = 0; x < w; ++x) {
      const glm::dvec3 d = worldFromEnvironment * glm::dvec3(environment_.direction(x, y));
      glm::dvec3 m;
      const glm::dvec3 q = proxy_.exit(p, d, &m);
      const glm::dvec3 v = q - proxy_.capturePoint;
      const double dc2 = glm::dot(v, v);
      const glm::dvec3 dc = v / std::sqrt(dc2);
      const glm::dvec3 qp = q - p;
      // The texel's solid angle seen from the capture point: dA = Ω |q - p|² / cos θ_p, and
      // Ω' = dA cos θ_c / |q - c|².
      const double cosP = std::max(1e-6, std::abs(glm::dot(m, d)));
      const double cosC = std::abs(glm::dot(m, dc));
      const double footprint = omega * glm::dot(qp, qp) * cosC / (dc2 * cosP);
      const glm::vec3 L =
          filtered_.lookup(glm::vec3(proxy_.environmentFromWorld * dc), float(footprint));
      float* out = img.at(x, y);
      out[0] = L.x, out[1] = L.y, out[2] = L.z;
    }
  });
  return Environment::fromLatLong(img);
}

}  // namespace compose::lighting
