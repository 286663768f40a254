// The shadow an object casts on the ground, against ray tracing.
#include "render/ground.h"

#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "lighting/exact.h"
#include "lighting/monte_carlo.h"
#include "pipeline/shadows.h"
#include "render/embree_scene.h"
#include "test_util.h"

namespace compose::render {
namespace {

// A closed unit cube with flat normals (four vertices per face), sitting on y = 0.
Mesh cube() {
  Mesh m;
  const glm::vec3 c[8] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0},
                          {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}};
  const int faces[6][4] = {{0, 3, 2, 1}, {4, 5, 6, 7}, {0, 1, 5, 4},
                           {3, 7, 6, 2}, {0, 4, 7, 3}, {1, 2, 6, 5}};
  for (const auto& f : faces) {
    const uint32_t base = uint32_t(m.positions.size());
    const glm::vec3 n = glm::normalize(glm::cross(c[f[1]] - c[f[0]], c[f[2]] - c[f[0]]));
    for (int i = 0; i < 4; ++i) {
      m.positions.push_back(c[f[i]]);
      m.normals.push_back(n);
    }
    m.indices.insert(m.indices.end(), {base, base + 1, base + 2, base, base + 2, base + 3});
  }
  m.normalsFromFile = true;
  return m;
}

// A dim sky and a small, bright sun in direction `sun` (world = environment frame here).
lighting::Environment sunAndSky(const glm::vec3& sun) {
  const int w = 256, h = 128;
  const auto probe = lighting::Environment::constant(glm::vec3(0.0f), w);
  Image img(w, h, 3);
  const glm::vec3 s = glm::normalize(sun);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const glm::vec3 d = probe.direction(x, y);
      glm::vec3 L = d.y > 0.0f ? glm::vec3(0.2f, 0.3f, 0.5f) : glm::vec3(0.05f);
      if (glm::dot(d, s) > 0.9995f) L += glm::vec3(2000.0f, 1900.0f, 1700.0f);
      img.at(x, y)[0] = L.x, img.at(x, y)[1] = L.y, img.at(x, y)[2] = L.z;
    }
  return lighting::Environment::fromLatLong(img);
}

// The plate camera (`pitch` degrees down) and the object stood on the ground at `at` (plate
// fractions), `height` of the plate high, turned by `yaw` degrees.
struct Shot {
  calib::PlateCamera camera;
  glm::dmat4 worldFromObject{1.0};
  glm::mat3 envFromObject{1.0f};  // the placement's rotation (world = environment frame here)
};
Shot shoot(const Mesh& mesh, int width, int height, double pitch, glm::dvec2 at,
           double heightFraction, double yaw = 0.0) {
  calib::CameraOptions co;
  co.pitchDegrees = pitch;
  Shot shot{calib::plateCamera(width, height, {}, co)};
  calib::Placement place;
  place.imagePoint = at;
  place.heightFraction = heightFraction;
  place.yawDegrees = yaw;
  shot.worldFromObject = calib::placeOnGround(shot.camera, place, glm::dvec3(mesh.boundsMin()),
                                              glm::dvec3(mesh.boundsMax()));
  shot.envFromObject = glm::mat3(shot.worldFromObject);
  for (int c = 0; c < 3; ++c) shot.envFromObject[c] = glm::normalize(shot.envFromObject[c]);
  return shot;
}

TEST(GroundShadow, MatchesRayTracingAndFollowsTheSun) {
  const Mesh box = cube();
  const EmbreeScene scene(box.positions, box.indices);
  // Looking down at the ground, 35°.
  const Shot shot = shoot(box, 400, 300, 35.0, {0.5, 0.5}, 0.25);
  const calib::PlateCamera& camera = shot.camera;
  const glm::dmat4& worldFromObject = shot.worldFromObject;
  // The sun 40° up, from +X: the shadow falls towards -X.
  const glm::vec3 sun(std::cos(0.7f), std::sin(0.7f), 0.0f);
  const lighting::Environment env = sunAndSky(sun);
  const pipeline::ShadowPlan plan = pipeline::ShadowPlan::parse("");
  const pipeline::ShadowLighting lighting = pipeline::prepareShadowLighting(env, plan, {});
  const glm::mat3 identity(1.0f);
  const glm::mat3& envFromObject = shot.envFromObject;
  const pipeline::GroundShadowResult ground = pipeline::computeGroundShadow(
      box, scene, worldFromObject, camera, lighting, identity, envFromObject, plan);
  ASSERT_FALSE(ground.grid.empty());
  EXPECT_EQ(ground.ratio.width, ground.grid.x1 - ground.grid.x0);

  // Reference at grid points: exact unshadowed minus Monte Carlo of the blocked light, in world.
  lighting::ExactLighting exact;
  exact.project(env);
  lighting::MonteCarloLighting mc(1, 3);
  mc.project(env);
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  const glm::vec3 up(0, 1, 0);
  const double unshadowed = exact.irradiance(up).y;
  double worst = 0.0;
  int shadowed = 0, lit = 0;
  for (int j = 0; j < ground.grid.rows; j += 3) {
    for (int i = 0; i < ground.grid.columns; i += 3) {
      const int p = ground.grid.node[size_t(j) * size_t(ground.grid.columns) + size_t(i)];
      if (p < 0) continue;
      const int x = i * ground.grid.stride, y = j * ground.grid.stride;
      if (x >= ground.ratio.width || y >= ground.ratio.height) continue;
      const glm::vec3 pObj = ground.grid.points.positions[size_t(p)];
      // Not on the cube's own outline, where the ground point lies in the plane of a face and
      // "half the sky" depends on a rounding of its position.
      if (pObj.x > -0.02f && pObj.x < 1.02f && pObj.z > -0.02f && pObj.z < 1.02f) continue;
      const glm::vec3 origin = pObj + glm::vec3(0.0f, 1e-4f, 0.0f);
      const glm::mat3 objectFromEnv = glm::mat3(objectFromWorld);
      const lighting::MonteCarloLighting::VisibilityFn blocked = [&](const glm::vec3& d) {
        return scene.occluded(origin, glm::normalize(objectFromEnv * d), 1e-5f);
      };
      const double ref = 1.0 - mc.estimate(up, 8192, &blocked).y / unshadowed;
      const double got = ground.ratio.at(x, y)[1];
      worst = std::max(worst, std::abs(got - ref));
      shadowed += ref < 0.5;
      lit += ref > 0.99;
    }
  }
  // The sun is 87 % of the ground's light here: its shadow takes most of it.
  EXPECT_GT(shadowed, 2) << "the sun's shadow is on the grid";
  EXPECT_GT(lit, 20) << "and so is ground the object does not shade";
  // Ratio within 0.06: the sun by four jittered rays per texel (its penumbra is resolved in
  // quarters of a texel: 5 texels, so steps of about 0.05 where the edge passes), the sky by the
  // transfer; the reference's noise (8192 samples on the blocked part) is ~0.01.
  EXPECT_LT(worst, 0.06);
  std::printf("ground ratio against ray tracing: worst difference %.3f\n", worst);
}

// A sharp sun shadow on a coarse grid (every ~25 pixels): bilinear interpolation between the
// nodes draws its edge as a staircase of grid-sized steps. The cells across the edge are refined,
// and the ratio between the nodes moves towards the ratio computed at each pixel's own point.
TEST(GroundShadow, SharpEdgesAreRefinedBetweenGridNodes) {
  const Mesh box = cube();
  const EmbreeScene scene(box.positions, box.indices);
  // Turned by 30°: the shadow's edges run across the grid's rows and columns.
  const Shot shot = shoot(box, 1200, 900, 35.0, {0.5, 0.5}, 0.25, 30.0);
  const calib::PlateCamera& camera = shot.camera;
  const glm::dmat4& worldFromObject = shot.worldFromObject;
  const lighting::Environment env = sunAndSky({std::cos(0.7f), std::sin(0.7f), 0.0f});
  const pipeline::ShadowPlan plan = pipeline::ShadowPlan::parse("");
  const pipeline::ShadowLighting lighting = pipeline::prepareShadowLighting(env, plan, {});
  const glm::mat3& envFromObject = shot.envFromObject;
  TransferParams params = plan.transfer;
  params.shBands = 0;
  auto shade = [&](const SurfacePoints& points) {
    const VertexTransfer transfer = computeTransfer(box, points, params);
    const SourceVisibility seen =
        traceSources(points, scene, lighting.split.sources, envFromObject);
    ShadowInputs in;
    in.transfer = &transfer;
    in.shadowLighting = lighting.lighting.get();
    in.sources = lighting.split.sources;
    in.sourceVisibility = &seen;
    return shadeVertices(points, envFromObject, in);
  };
  GroundSettings settings;
  settings.maxPoints = 1500;
  GroundGrid grid = groundGrid(box, worldFromObject, camera, lighting.split.sources, settings);
  ASSERT_GE(grid.stride, 16);
  const VertexIrradiance coarse = shade(grid.points);
  const Image before = groundRatio(grid, coarse);
  const size_t refined = refineGroundGrid(grid, coarse, worldFromObject, camera, settings);
  EXPECT_GT(refined, 0u);
  EXPECT_EQ(grid.steps, (grid.stride + 3) / 4);
  const Image after = groundRatio(grid, coarse, shade(grid.finePoints));

  // The ratio at each pixel's own ground point, for every 3rd pixel of the refined cells.
  SurfacePoints exact;
  exact.size = grid.points.size, exact.centre = grid.points.centre;
  exact.radius = grid.points.radius;
  std::vector<glm::ivec2> pixels;
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  for (int y = 0; y < before.height; y += 3) {
    for (int x = 0; x < before.width; x += 3) {
      const int i = std::min(x / grid.stride, grid.columns - 2);
      const int j = std::min(y / grid.stride, grid.rows - 2);
      if (grid.refinedCell[size_t(j) * size_t(grid.columns - 1) + size_t(i)] < 0) continue;
      glm::dvec3 origin, dir;
      if (!camera.ray(grid.x0 + x + 0.5, grid.y0 + y + 0.5, origin, dir) || !(dir.y < -1e-9))
        continue;
      const glm::dvec3 g = origin + dir * (-origin.y / dir.y);
      exact.positions.push_back(glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(g, 1.0))));
      exact.normals.emplace_back(0.0f, 1.0f, 0.0f);
      pixels.emplace_back(x, y);
    }
  }
  ASSERT_GT(pixels.size(), 500u);
  const VertexIrradiance truth = shade(exact);
  double errBefore = 0.0, errAfter = 0.0;
  for (size_t k = 0; k < pixels.size(); ++k) {
    const glm::vec3 un = truth.unshadowed[k], sh = truth.shadowed[k];
    const double ref = un.y > 1e-20f ? std::clamp(sh.y / un.y, 0.0f, 1.0f) : 1.0;
    errBefore += std::abs(before.at(pixels[k].x, pixels[k].y)[1] - ref);
    errAfter += std::abs(after.at(pixels[k].x, pixels[k].y)[1] - ref);
  }
  errBefore /= double(pixels.size());
  errAfter /= double(pixels.size());
  std::printf("stride %d, %zu cells refined %d x %d: mean |ratio - per-pixel ratio| %.4f -> %.4f\n",
              grid.stride, refined, grid.steps, grid.steps, errBefore, errAfter);
  EXPECT_LT(errAfter, 0.5 * errBefore);
}

// An object close to the camera: its shadow's region reaches behind it. The grid covers only the
// part of the frame that shows the region, and no pixel outside it shows any of the region.
TEST(GroundShadow, ARegionReachingBehindTheCameraCoversOnlyWhatTheFrameShows) {
  const Mesh box = cube();
  const Shot shot = shoot(box, 800, 600, 5.0, {0.5, 0.97}, 1.0);
  const calib::PlateCamera& camera = shot.camera;
  const glm::dmat4& worldFromObject = shot.worldFromObject;
  const GroundGrid grid = groundGrid(box, worldFromObject, camera, {});
  ASSERT_FALSE(grid.empty());
  // The region does reach behind the camera (the case this is about).
  glm::dvec2 px;
  bool behind = false;
  for (const double x : {grid.regionX0, grid.regionX1})
    for (const double z : {grid.regionZ0, grid.regionZ1})
      behind = behind || !camera.project(glm::dvec3(x, 0.0, z), px);
  ASSERT_TRUE(behind);
  // Not the whole frame (as it used to be): the sky above the horizon is left out.
  glm::dvec3 o, d;
  ASSERT_TRUE(camera.ray(400.5, 0.5, o, d));
  ASSERT_GT(d.y, 0.0) << "the top row sees the sky";
  EXPECT_GT(grid.y0, 0) << "the grid covers " << grid.x1 - grid.x0 << "x" << grid.y1 - grid.y0;
  int outsideShowingRegion = 0, inside = 0;
  for (int y = 0; y < 600; y += 4) {
    for (int x = 0; x < 800; x += 4) {
      glm::dvec3 origin, dir;
      if (!camera.ray(x + 0.5, y + 0.5, origin, dir) || !(dir.y < -1e-9)) continue;
      const glm::dvec3 g = origin + dir * (-origin.y / dir.y);
      const bool inRegion = g.x >= grid.regionX0 && g.x <= grid.regionX1 && g.z >= grid.regionZ0 &&
                            g.z <= grid.regionZ1;
      const bool inGrid = x >= grid.x0 && x < grid.x1 && y >= grid.y0 && y < grid.y1;
      inside += inRegion && inGrid;
      outsideShowingRegion += inRegion && !inGrid;
    }
  }
  EXPECT_GT(inside, 100);
  EXPECT_EQ(outsideShowingRegion, 0);
}

}  // namespace
}  // namespace compose::render
