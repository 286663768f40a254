#include "lighting/capture_volume.h"

#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "lighting/environment_util.h"
#include "lighting/exact.h"
#include "lighting/volume.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

CaptureProxy room() {
  CaptureProxy p;
  p.shape = CaptureProxy::Shape::Box;
  p.boxMin = {-2.0, 0.0, -2.0};
  p.boxMax = {2.0, 3.0, 2.0};
  p.capturePoint = {0.0, 1.5, 0.0};
  return p;
}

// The room as the capture saw it: the +X wall ten times brighter than the rest.
Environment brightWallCapture(const CaptureProxy& proxy, int width) {
  return testing::analyticEnvironment(width, [&](const glm::vec3& d) {
    glm::dvec3 m;
    proxy.exit(proxy.capturePoint, glm::dvec3(d), &m);
    return glm::vec3(m.x > 0.5 ? 10.0f : 1.0f);
  });
}

// Irradiance at p for normal n by brute force over the room's walls: each wall cut into small
// patches, each patch sending the radiance the capture saw in its direction (10 on the +X wall).
double bruteForceIrradiance(const CaptureProxy& proxy, const glm::dvec3& p, const glm::dvec3& n) {
  const int cells = 500;
  double e = 0.0;
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      const double du = (proxy.boxMax[u] - proxy.boxMin[u]) / cells;
      const double dv = (proxy.boxMax[v] - proxy.boxMin[v]) / cells;
      const double L = (axis == 0 && side == 1) ? 10.0 : 1.0;
      for (int i = 0; i < cells; ++i) {
        for (int j = 0; j < cells; ++j) {
          glm::dvec3 q;
          q[axis] = side ? proxy.boxMax[axis] : proxy.boxMin[axis];
          q[u] = proxy.boxMin[u] + (i + 0.5) * du;
          q[v] = proxy.boxMin[v] + (j + 0.5) * dv;
          const glm::dvec3 r = q - p;
          const double d2 = glm::dot(r, r);
          const glm::dvec3 w = r / std::sqrt(d2);
          const double cosN = glm::dot(n, w);
          if (cosN <= 0.0) continue;
          e += L * cosN * std::abs(w[axis]) * du * dv / d2;
        }
      }
    }
  }
  return e;
}

TEST(CaptureVolume, CaptureCentreReproducesThePlainLookupExactly) {
  const CaptureProxy proxy = room();
  const Environment env = brightWallCapture(proxy, 128);
  const CaptureVolumeSource source(env, proxy);
  for (const glm::vec3& d : testing::randomNormals(500, 3)) {
    EXPECT_EQ(source.radiance(proxy.capturePoint, glm::dvec3(d)), env.lookup(d));
  }
  const Environment here = source.at(glm::vec3(proxy.capturePoint));
  EXPECT_EQ(here.texels(), env.texels());
  // And through a lighting volume: a grid point at the capture point gets the distant lighting.
  VolumeParams params;
  params.basis = "exact";
  params.boundsMin = glm::vec3(-1.0f, 1.5f, 0.0f);
  params.boundsMax = glm::vec3(1.0f, 1.5f, 0.0f);
  params.resolution = {3, 1, 1};  // x = -1, 0, 1: the middle point is the capture point
  LightingVolume volume(params), distant(params);
  volume.build(source);
  distant.build(DistantSource(env));
  for (const glm::vec3& n : testing::randomNormals(50, 4)) {
    EXPECT_EQ(volume.irradiance(glm::vec3(proxy.capturePoint), n),
              distant.irradiance(glm::vec3(proxy.capturePoint), n));
  }
}

// A point near the bright wall receives more light from it than the capture point did, as much
// as brute-force integration over the walls says.
TEST(CaptureVolume, NearABrightWallMatchesBruteForceIntegration) {
  const CaptureProxy proxy = room();
  const Environment env = brightWallCapture(proxy, 256);
  const CaptureVolumeSource source(env, proxy);
  const glm::dvec3 n(1.0, 0.0, 0.0);
  // The wall's edge falls inside texels of the 256 x 128 capture (bilinear there), and the
  // re-projected map is a prefiltered resampling: about 1 % on an integral (measured 0.2-0.5 %).
  constexpr double kResampling = 0.02;
  for (const glm::dvec3 p :
       {glm::dvec3(1.5, 1.5, 0.0), glm::dvec3(1.0, 0.8, -1.2), glm::dvec3(-1.2, 2.2, 1.0)}) {
    ExactLighting exact;
    exact.project(source.at(glm::vec3(p)));
    const double parallax = exact.irradiance(glm::vec3(n)).x;
    const double brute = bruteForceIrradiance(proxy, p, n);
    EXPECT_NEAR(parallax / brute, 1.0, kResampling) << "at " << p.x << "," << p.y << "," << p.z;
    std::printf("irradiance at (%.1f, %.1f, %.1f) facing +X: parallax %.4f, brute force %.4f\n",
                p.x, p.y, p.z, parallax, brute);
  }
  ExactLighting atCapture;
  atCapture.project(env);
  const double fromCentre = atCapture.irradiance(glm::vec3(n)).x;
  const double centreBrute = bruteForceIrradiance(proxy, proxy.capturePoint, n);
  EXPECT_NEAR(fromCentre / centreBrute, 1.0, kResampling);
  ExactLighting near;
  near.project(source.at(glm::vec3(1.5f, 1.5f, 0.0f)));
  // Measurably more: the wall fills most of the hemisphere half a metre away.
  EXPECT_GT(near.irradiance(glm::vec3(n)).x, 1.3 * fromCentre);
  std::printf("facing the bright wall: %.3f at the capture point, %.3f half a metre from it\n",
              fromCentre, double(near.irradiance(glm::vec3(n)).x));
}

TEST(CaptureVolume, ConstantSurroundingsStayConstantEverywhere) {
  CaptureProxy sphere;
  sphere.shape = CaptureProxy::Shape::Sphere;
  sphere.radius = 3.0;
  sphere.capturePoint = {0.5, 1.0, 0.0};
  const CaptureVolumeSource source(Environment::constant(glm::vec3(2.0f), 64), sphere);
  ExactLighting exact;
  exact.project(source.at(glm::vec3(2.5f, 1.0f, 1.0f)));
  // Float texels, exact quadrature: rounding only.
  EXPECT_NEAR(exact.irradiance(glm::vec3(0, 1, 0)).x, 2.0 * kPi, 1e-4 * kPi);
}

TEST(CaptureVolume, RejectsACapturePointOutsideTheRoom) {
  CaptureProxy p = room();
  p.capturePoint = {3.0, 1.0, 0.0};
  COMPOSE_EXPECT_ERROR(p.validate(), "the capture point (3, 1, 0) is not inside the room");
  p = room();
  p.boxMax.y = 0.0;
  COMPOSE_EXPECT_ERROR(p.validate(), "positive width, height and depth");
  CaptureProxy s;
  s.shape = CaptureProxy::Shape::Sphere;
  COMPOSE_EXPECT_ERROR(s.validate(), "radius (--env-radius) must be a positive number");
  // Beyond 1000 km the surroundings are distant (and at 1e308 the projections overflowed).
  s.radius = 1e308;
  COMPOSE_EXPECT_ERROR(s.validate(), "more than 1e6 (1000 km in metres) from the world's origin");
  s.radius = 5e5;
  EXPECT_NO_THROW(s.validate());
  // A sphere's capture point below the ground is refused, as a room's is (it was taken).
  s.capturePoint = {0.0, -3.0, 0.0};
  COMPOSE_EXPECT_ERROR(s.validate(), "the capture point (0, -3, 0) is below the ground");
  p = room();
  p.boxMax.x = 1e308;
  COMPOSE_EXPECT_ERROR(p.validate(), "more than 1e6 (1000 km in metres) from the world's origin");
  p = room();
  p.capturePoint.x = -1e300;
  COMPOSE_EXPECT_ERROR(p.validate(), "within 1e6 (1000 km in metres)");
}

}  // namespace
}  // namespace compose::lighting
