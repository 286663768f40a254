// Cube-map geometry and the CubeMap raster.
//
// Faces and their orientation follow OpenEXR's Imf::CubeMap: face order +X -X +Y -Y +Z -Z, and
// each face image is stored as OpenEXR's cube layout holds it (Imf::CubeMap::pixelPosition). Seen
// as pictures, the faces are what a 90° camera at the cube's centre sees looking at them: the four
// side faces upright (image top = +Y), the +Y face with its top towards +Z and the -Y face with
// its top towards -Z (the photographer's convention: tilt the camera up or down from the -Z
// view). FaceFrame writes this down once: a face image point (a, b) ∈ [-1, 1]², a from the left
// edge to the right, b from the top edge to the bottom, looks along forward + a·right + b·down.
//
// Texel grid: texel (x, y) of an N x N face covers a ∈ [-1 + 2x/N, -1 + 2(x+1)/N] and likewise b,
// so the texels of the six faces tile the sphere exactly once, and the exact solid angle of a texel
// comes from the corner formula A(x, y) = atan2(x·y, sqrt(x² + y² + 1)) (four-corner inclusion-
// exclusion; the 6N² texels sum to 4π). OpenEXR's own tools (exrenvmap) put the first and last
// texel centres ON the face edges instead (a = -1 + 2x/(N-1)), so their faces overlap by half a
// texel along every edge; the orientation and layout are the same, the sampling grid differs by
// that half texel.
//
// The older (u, v) functions below are OpenEXR's face-local "position in face" coordinates, used
// by the cheb-face basis; the mapping is delegated to libOpenEXR so that it cannot drift, and the
// tests check that FaceFrame agrees with it.
#pragma once

#include <array>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "lighting/environment.h"

namespace compose::lighting {

inline constexpr int kCubeFaces = 6;

// Unit direction through OpenEXR face-local coordinates (u, v) ∈ [-1, 1]².
glm::vec3 cubeDirection(int face, double u, double v);
// Face and face-local coordinates of a direction (any length > 0).
void cubeFaceCoordinates(const glm::vec3& direction, int& face, double& u, double& v);
// Exact solid angle of the face rectangle [u0, u1] x [v0, v1] (four-corner formula,
// A(x, y) = atan2(x y, sqrt(x² + y² + 1))). Over a whole face it is 4π/6. The formula is
// symmetric, so it serves image coordinates (a, b) as well.
double cubeSolidAngle(double u0, double v0, double u1, double v1);

// The camera of one face: direction = forward + a·right + b·down (see the header comment). Every
// face is a right-handed view: right × up = -forward, up = -down.
struct FaceFrame {
  glm::dvec3 forward, right, down;
};
const FaceFrame& faceFrame(int face);
// "+X", "-X", "+Y", "-Y", "+Z", "-Z".
const char* faceName(int face);

// Direction (not unit length) through face image coordinates (a, b).
inline glm::dvec3 faceImageDirection(int face, double a, double b) {
  const FaceFrame& f = faceFrame(face);
  return f.forward + a * f.right + b * f.down;
}
// Face and image coordinates (a, b) ∈ [-1, 1]² of a direction (length > 0). Ties between faces go
// as in OpenEXR (x before y before z).
void faceImageCoordinates(const glm::dvec3& direction, int& face, double& a, double& b);
// Exact solid angle of texel (x, y) of a size x size face.
double faceTexelSolidAngle(int size, int x, int y);

// Six square faces of RGB radiance, each stored row-major, top row first, in the orientation
// described above. Values are whatever the caller stores (radiance, normally); the same
// colour-space rule as Image applies.
class CubeMap {
 public:
  CubeMap() = default;
  explicit CubeMap(int size);  // black

  // Validates six RGB (or RGBA: alpha dropped; one channel: grey) face images of equal square
  // size, as Environment::fromLatLong does for a lat-long map: NaN or infinite texels throw
  // compose::Error naming `file` and the face; negative values are clamped and counted. `faceFiles`
  // (optional) names the file of each face for errors.
  static CubeMap fromFaces(
      const std::array<const Image*, kCubeFaces>& faces, const std::filesystem::path& file = {},
      SanitizeReport* report = nullptr,
      const std::array<std::filesystem::path, kCubeFaces>* faceFiles = nullptr);

  int size() const { return size_; }
  bool empty() const { return size_ == 0; }

  float* texel(int face, int x, int y) {
    return faces_[size_t(face)].data() + (size_t(y) * size_t(size_) + size_t(x)) * 3;
  }
  const float* texel(int face, int x, int y) const {
    return faces_[size_t(face)].data() + (size_t(y) * size_t(size_) + size_t(x)) * 3;
  }
  glm::vec3 radiance(int face, int x, int y) const {
    const float* p = texel(face, x, y);
    return {p[0], p[1], p[2]};
  }
  std::vector<float>& face(int f) { return faces_[size_t(f)]; }
  const std::vector<float>& face(int f) const { return faces_[size_t(f)]; }
  // Face f as an RGB image (a copy).
  Image faceImage(int f) const;

  // Unit direction of the centre of texel (x, y) of a face.
  glm::vec3 direction(int face, int x, int y) const;
  // ∫ L dω over the sphere with exact texel solid angles, per channel, accumulated in double.
  glm::dvec3 integral() const;

  std::string colorSpace;

 private:
  int size_ = 0;
  std::array<std::vector<float>, kCubeFaces> faces_;
};

// ∫ L dω over a lat-long environment (exact row solid angles), per channel, in double.
glm::dvec3 integral(const Environment& environment);

}  // namespace compose::lighting
