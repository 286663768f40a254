#include "lighting/cubemap.h"

#include <algorithm>
#include <cmath>
#include <string>

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

const FaceFrame& faceFrame(int face) {
  // From Imf::CubeMap::direction and Imf::CubeMap::pixelPosition: the image x and y of each face
  // in OpenEXR's cube layout, expressed as world axes.
  static const FaceFrame kFrames[kCubeFaces] = {
      {{1, 0, 0}, {0, 0, 1}, {0, -1, 0}},    // +X: right is +Z, image top +Y
      {{-1, 0, 0}, {0, 0, -1}, {0, -1, 0}},  // -X: right is -Z
      {{0, 1, 0}, {1, 0, 0}, {0, 0, -1}},    // +Y: right is +X, image top +Z
      {{0, -1, 0}, {1, 0, 0}, {0, 0, 1}},    // -Y: right is +X, image top -Z
      {{0, 0, 1}, {-1, 0, 0}, {0, -1, 0}},   // +Z: right is -X
      {{0, 0, -1}, {1, 0, 0}, {0, -1, 0}},   // -Z: right is +X
  };
  COMPOSE_CHECK(face >= 0 && face < kCubeFaces);
  return kFrames[face];
}

const char* faceName(int face) {
  static const char* kNames[kCubeFaces] = {"+X", "-X", "+Y", "-Y", "+Z", "-Z"};
  COMPOSE_CHECK(face >= 0 && face < kCubeFaces);
  return kNames[face];
}

void faceImageCoordinates(const glm::dvec3& d, int& face, double& a, double& b) {
  const double ax = std::abs(d.x), ay = std::abs(d.y), az = std::abs(d.z);
  if (ax >= ay && ax >= az) {
    face = d.x > 0 ? 0 : 1;
  } else if (ay >= az) {
    face = d.y > 0 ? 2 : 3;
  } else {
    face = d.z > 0 ? 4 : 5;
  }
  const FaceFrame& f = faceFrame(face);
  const double depth = glm::dot(d, f.forward);
  COMPOSE_CHECK(depth > 0.0);
  a = glm::dot(d, f.right) / depth;
  b = glm::dot(d, f.down) / depth;
}

double faceTexelSolidAngle(int size, int x, int y) {
  const double step = 2.0 / size;
  return cubeSolidAngle(-1.0 + step * x, -1.0 + step * y, -1.0 + step * (x + 1),
                        -1.0 + step * (y + 1));
}

CubeMap::CubeMap(int size) : size_(size) {
  COMPOSE_CHECK(size >= 1);
  for (auto& f : faces_) f.assign(size_t(size) * size_t(size) * 3, 0.0f);
}

CubeMap CubeMap::fromFaces(const std::array<const Image*, kCubeFaces>& faces,
                           const std::filesystem::path& file, SanitizeReport* report,
                           const std::array<std::filesystem::path, kCubeFaces>* faceFiles) {
  auto where = [&](int f) { return faceFiles ? (*faceFiles)[size_t(f)] : file; };
  const int n = faces[0]->width;
  for (int f = 0; f < kCubeFaces; ++f) {
    const Image& img = *faces[size_t(f)];
    if (img.width != img.height) {
      throw Error("ingest",
                  std::string("cube face ") + faceName(f) + " is not square: " +
                      std::to_string(img.width) + "x" + std::to_string(img.height),
                  where(f));
    }
    if (img.width != n) {
      throw Error("ingest",
                  std::string("cube faces differ in size: ") + faceName(f) + " is " +
                      std::to_string(img.width) + "x" + std::to_string(img.height) + ", " +
                      faceName(0) + " is " + std::to_string(n) + "x" + std::to_string(n),
                  where(f));
    }
    if (img.channels != 1 && img.channels < 3) {
      throw Error("ingest",
                  std::string("cube face ") + faceName(f) + " needs RGB channels, it has " +
                      std::to_string(img.channels),
                  where(f));
    }
  }
  if (n < 1) throw Error("ingest", "cube faces have no pixels", file);
  CubeMap cube(n);
  cube.colorSpace = faces[0]->colorSpace;
  SanitizeReport local;
  local.keepNegative = report && report->keepNegative;
  for (int f = 0; f < kCubeFaces; ++f) {
    const Image& img = *faces[size_t(f)];
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        const float* src = img.at(x, y);
        const int step = img.channels == 1 ? 0 : 1;  // a grey face: its one channel thrice
        const float rgb[3] = {src[0], src[step], src[2 * step]};
        float bad = 0.0f;
        if (!local.take(rgb, cube.texel(f, x, y), bad)) {
          throw Error("ingest",
                      SanitizeReport::badRadiance(bad, std::string(" in cube face ") + faceName(f) +
                                                           " at texel (" + std::to_string(x) +
                                                           ", " + std::to_string(y) + ")"),
                      where(f));
        }
      }
    }
  }
  if (report) *report = local;
  return cube;
}

Image CubeMap::faceImage(int f) const {
  Image img(size_, size_, 3, {"R", "G", "B"});
  img.colorSpace = colorSpace;
  img.pixels.assign(faces_[size_t(f)].begin(), faces_[size_t(f)].end());
  return img;
}

glm::vec3 CubeMap::direction(int face, int x, int y) const {
  const double a = -1.0 + (2.0 * x + 1.0) / size_, b = -1.0 + (2.0 * y + 1.0) / size_;
  return glm::vec3(glm::normalize(faceImageDirection(face, a, b)));
}

glm::dvec3 CubeMap::integral() const {
  glm::dvec3 total(0.0);
  for (int y = 0; y < size_; ++y) {
    for (int x = 0; x < size_; ++x) {
      const double omega = faceTexelSolidAngle(size_, x, y);
      for (int f = 0; f < kCubeFaces; ++f) total += omega * glm::dvec3(radiance(f, x, y));
    }
  }
  return total;
}

glm::dvec3 integral(const Environment& env) {
  glm::dvec3 total(0.0);
  for (int y = 0; y < env.height(); ++y) {
    glm::dvec3 row(0.0);
    for (int x = 0; x < env.width(); ++x) row += glm::dvec3(env.radiance(x, y));
    total += row * env.rowSolidAngle(y);
  }
  return total;
}

}  // namespace compose::lighting
