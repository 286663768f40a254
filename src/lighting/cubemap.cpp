#include "lighting/cubemap.h"

#include <cmath>

#include <OpenEXR/ImfEnvmap.h>
#include <glm/geometric.hpp>

#include "core/error.h"

namespace compose::lighting {

namespace {
// A virtual face of 2 x 2 pixels: OpenEXR maps pixel positions 0..1 linearly onto [-1, 1].
const IMATH_NAMESPACE::Box2i kUnitFaces(IMATH_NAMESPACE::V2i(0, 0), IMATH_NAMESPACE::V2i(1, 11));
}  // namespace

glm::vec3 cubeDirection(int face, double u, double v) {
  COMPOSE_CHECK(face >= 0 && face < kCubeFaces);
  const IMATH_NAMESPACE::V3f d =
      Imf::CubeMap::direction(Imf::CubeMapFace(face), kUnitFaces,
                              IMATH_NAMESPACE::V2f(float(0.5 * (u + 1.0)), float(0.5 * (v + 1.0))));
  return glm::normalize(glm::vec3(d.x, d.y, d.z));
}

void cubeFaceCoordinates(const glm::vec3& direction, int& face, double& u, double& v) {
  Imf::CubeMapFace f;
  IMATH_NAMESPACE::V2f pif;
  Imf::CubeMap::faceAndPixelPosition(IMATH_NAMESPACE::V3f(direction.x, direction.y, direction.z),
                                     kUnitFaces, f, pif);
  face = int(f);
  u = 2.0 * pif.x - 1.0;
  v = 2.0 * pif.y - 1.0;
}

double cubeSolidAngle(double u0, double v0, double u1, double v1) {
  auto a = [](double x, double y) { return std::atan2(x * y, std::sqrt(x * x + y * y + 1.0)); };
  return a(u1, v1) - a(u0, v1) - a(u1, v0) + a(u0, v0);
}

}  // namespace compose::lighting
