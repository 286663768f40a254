// Cube-map face geometry. Faces and their orientation follow OpenEXR's Imf::CubeMap (face order
// +X -X +Y -Y +Z -Z; the mapping is delegated to libOpenEXR so that it cannot drift). Texel
// (i, j) of an N x N face covers face coordinates u ∈ [-1 + 2i/N, -1 + 2(i+1)/N], likewise v, and
// its direction is the centre of that square.
#pragma once

#include <glm/vec3.hpp>

namespace compose::lighting {

inline constexpr int kCubeFaces = 6;

// Unit direction through face coordinates (u, v) ∈ [-1, 1]².
glm::vec3 cubeDirection(int face, double u, double v);
// Face and face coordinates of a direction (any length > 0).
void cubeFaceCoordinates(const glm::vec3& direction, int& face, double& u, double& v);
// Exact solid angle of the face rectangle [u0, u1] x [v0, v1] (four-corner formula,
// A(x, y) = atan2(x y, sqrt(x² + y² + 1))). Over a whole face it is 4π/6.
double cubeSolidAngle(double u0, double v0, double u1, double v1);

}  // namespace compose::lighting
