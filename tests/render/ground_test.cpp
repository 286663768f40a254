// The shadow an object casts on the ground, against ray tracing.
#include "render/ground.h"

#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "core/numbers.h"
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
  // The lattice below is the plate's own (a small region's is finer: supersample > 1).
  ASSERT_EQ(ground.supersample, 1);
  EXPECT_EQ(ground.ratio.width, ground.grid.x1 - ground.grid.x0);

  // Reference at grid points: exact unshadowed minus Monte Carlo of the blocked light, in world.
  lighting::ExactLighting exact;
  exact.project(env);
  lighting::MonteCarloLighting mc(1, 3);
  mc.project(env);
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  const glm::vec3 up(0, 1, 0);
  const double unshadowed = exact.irradiance(up).y;
  double worst = 0.0, worstEdge = 0.0;
  int shadowed = 0, lit = 0;
  const GroundGrid& grid = ground.grid;
  for (int b = 0; b < grid.rows; b += 3) {
    for (int a = 0; a < grid.columns; a += 3) {
      const int p = grid.node[size_t(b) * size_t(grid.columns) + size_t(a)];
      if (p < 0) continue;
      // Nodes on whole pixels, where the ratio image holds their value.
      const int x = int(std::lround(a * grid.unit)), y = int(std::lround(b * grid.unit));
      if (std::abs(a * grid.unit - x) > 1e-9 || std::abs(b * grid.unit - y) > 1e-9) continue;
      if (x >= ground.ratio.width || y >= ground.ratio.height) continue;
      const glm::vec3 pObj = grid.points.positions[size_t(p)];
      // Not on the cube's own outline, where the ground point lies in the plane of a face and
      // "half the sky" depends on a rounding of its position.
      if (pObj.x > -0.02f && pObj.x < 1.02f && pObj.z > -0.02f && pObj.z < 1.02f) continue;
      // Where a finest cell around the node has the sun's edge the pixel holds the average over
      // its area (sharpenGroundEdges: 2 x 2 points across it), elsewhere the value at its centre.
      bool edge = false;
      for (int db = -1; db <= 1; ++db)
        for (int da = -1; da <= 1; ++da) {
          if (a + da < 0 || b + db < 0 || a + da >= grid.columns || b + db >= grid.rows) continue;
          const int q = grid.node[size_t(b + db) * size_t(grid.columns) + size_t(a + da)];
          if (q >= 0 && grid.seen[size_t(q)] != grid.seen[size_t(p)]) edge = true;
        }
      const glm::mat3 objectFromEnv = glm::mat3(objectFromWorld);
      auto ratioAt = [&](const glm::vec3& at) {
        const glm::vec3 origin = at + glm::vec3(0.0f, 1e-4f, 0.0f);
        const lighting::MonteCarloLighting::VisibilityFn blocked = [&](const glm::vec3& d) {
          return scene.occluded(origin, glm::normalize(objectFromEnv * d), 1e-5f);
        };
        return 1.0 - mc.estimate(up, 8192, &blocked).y / unshadowed;
      };
      double ref = 0.0;
      if (!edge) {
        ref = ratioAt(pObj);
      } else {
        for (int k = 0; k < 4; ++k) {
          glm::dvec3 o, d;
          ASSERT_TRUE(camera.ray(grid.x0 + x + 0.25 + 0.5 * (k % 2),
                                 grid.y0 + y + 0.25 + 0.5 * (k / 2), o, d));
          const glm::dvec3 g = o + d * (-o.y / d.y);
          ref += 0.25 * ratioAt(glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(g, 1.0))));
        }
      }
      const double got = ground.ratio.at(x, y)[1];
      (edge ? worstEdge : worst) = std::max(edge ? worstEdge : worst, std::abs(got - ref));
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
  // At the edge's pixels, 2 x 2 rays across the pixel, each to a quarter of the sun's extent,
  // against the mean of four references: steps of a quarter of the sun's share.
  EXPECT_LT(worstEdge, 0.08);
  std::printf("ground ratio against ray tracing: worst difference %.3f (%.3f at the edge)\n", worst,
              worstEdge);
}

// Shading for the tests below: the default plan's transfer and four rays per bright source, as
// the ground pass shades its points.
struct GroundShading {
  const Mesh& mesh;
  const EmbreeScene& scene;
  const pipeline::ShadowLighting& lighting;
  glm::mat3 envFromObject;
  VertexIrradiance operator()(const SurfacePoints& points) const {
    TransferParams params = pipeline::ShadowPlan::parse("").transfer;
    params.shBands = 0;
    const VertexTransfer transfer = computeTransfer(mesh, scene, points, params);
    const SourceVisibility seen =
        traceSources(points, scene, lighting.split.sources, envFromObject, 4);
    ShadowInputs in;
    in.transfer = &transfer;
    in.shadowLighting = lighting.lighting.get();
    in.sources = lighting.split.sources;
    in.sourceVisibility = &seen;
    return shadeVertices(points, envFromObject, in);
  }

  // The ground pass as the pipeline runs it: the grid's first points shaded, then its cells split
  // a level at a time and the new points shaded. The ratio of the first points alone, their
  // count, and the final ratio.
  struct Passes {
    Image first, last;
    size_t firstPoints = 0;
  };
  Passes coarseToFine(GroundGrid& grid, const Shot& shot, const GroundSettings& settings) const {
    Passes out;
    shadeGroundPoints(grid, (*this)(grid.pending()));
    out.first = groundRatio(grid);
    out.firstPoints = grid.points.count();
    while (refineGroundGrid(grid, scene, shot.worldFromObject, shot.camera, settings))
      shadeGroundPoints(grid, (*this)(grid.pending()));
    out.last = groundRatio(grid);
    return out;
  }
};

// The ratio at the ground point of every `step`-th pixel of the grid's rectangle that shows the
// ground, against the ratio images given: mean |difference| (green) per image, and the pixels.
std::vector<double> againstEachPixel(const GroundGrid& grid, const calib::PlateCamera& camera,
                                     const glm::dmat4& worldFromObject, const GroundShading& shade,
                                     const std::vector<const Image*>& images, int step,
                                     size_t& pixelCount, double shadedBelow = 2.0,
                                     const Image* differing = nullptr, double by = 0.0) {
  SurfacePoints exact;
  exact.size = grid.points.size, exact.centre = grid.points.centre;
  exact.radius = grid.points.radius;
  std::vector<glm::ivec2> pixels;
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  for (int y = 0; y < grid.y1 - grid.y0; y += step) {
    for (int x = 0; x < grid.x1 - grid.x0; x += step) {
      glm::dvec3 origin, dir;
      if (!camera.ray(grid.x0 + x + 0.5, grid.y0 + y + 0.5, origin, dir) || !(dir.y < -1e-9))
        continue;
      const glm::dvec3 o = glm::dvec3(objectFromWorld * glm::dvec4(origin, 1.0));
      const glm::dvec3 d = glm::dvec3(objectFromWorld * glm::dvec4(dir, 0.0));
      if (shade.scene.occluded(glm::vec3(o), glm::vec3(glm::normalize(d)))) continue;
      const glm::dvec3 g = origin + dir * (-origin.y / dir.y);
      exact.positions.push_back(glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(g, 1.0))));
      exact.normals.emplace_back(0.0f, 1.0f, 0.0f);
      pixels.emplace_back(x, y);
    }
  }
  const VertexIrradiance truth = shade(exact);
  std::vector<double> err(images.size(), 0.0);
  pixelCount = 0;
  for (size_t k = 0; k < pixels.size(); ++k) {
    const glm::vec3 un = truth.unshadowed[k], sh = truth.shadowed[k];
    const double ref = un.y > 1e-20f ? std::clamp(sh.y / un.y, 0.0f, 1.0f) : 1.0;
    if (ref >= shadedBelow) continue;
    if (differing && !(std::abs(differing->at(pixels[k].x, pixels[k].y)[1] - ref) > by)) continue;
    ++pixelCount;
    for (size_t i = 0; i < images.size(); ++i)
      err[i] += std::abs(images[i]->at(pixels[k].x, pixels[k].y)[1] - ref);
  }
  for (double& e : err) e /= double(std::max<size_t>(1, pixelCount));
  return err;
}

// A sharp sun shadow sampled coarse to fine: the first grid (every ~50 pixels) draws its edge as
// a staircase of grid-sized steps; the cells across it are split down to a few pixels, and the
// ratio moves towards the ratio computed at each pixel's own point, with far fewer points than a
// grid at the finest spacing.
TEST(GroundShadow, SharpEdgesAreFollowedCoarseToFine) {
  const Mesh box = cube();
  const EmbreeScene scene(box.positions, box.indices);
  // Turned by 30°: the shadow's edges run across the grid's rows and columns.
  const Shot shot = shoot(box, 1200, 900, 35.0, {0.5, 0.5}, 0.25, 30.0);
  const lighting::Environment env = sunAndSky({std::cos(0.7f), std::sin(0.7f), 0.0f});
  const pipeline::ShadowPlan plan = pipeline::ShadowPlan::parse("");
  const pipeline::ShadowLighting lighting = pipeline::prepareShadowLighting(env, plan, {});
  const GroundShading shade{box, scene, lighting, shot.envFromObject};
  GroundSettings settings;
  settings.maxPoints = 6000;  // base stride 8 or more, first points 4x that apart
  GroundGrid grid =
      groundGrid(box, shot.worldFromObject, shot.camera, lighting.split.sources, settings);
  ASSERT_GE(grid.stride, 8);
  ASSERT_EQ(grid.coarse, 2);
  ASSERT_GE(grid.fine, 1);
  const GroundShading::Passes passes = shade.coarseToFine(grid, shot, settings);
  for (int l = 0; l < grid.levels(); ++l) EXPECT_GT(grid.splitCount[size_t(l)], 0u) << l;
  // Far fewer points than the finest lattice holds.
  EXPECT_LT(grid.points.count(), grid.node.size() / 8);

  size_t pixels = 0;
  const std::vector<double> err = againstEachPixel(grid, shot.camera, shot.worldFromObject, shade,
                                                   {&passes.first, &passes.last}, 3, pixels);
  ASSERT_GT(pixels, 5000u);
  std::printf(
      "%zu points first (every %d pixels), %zu in all (down to %.3g pixels): mean "
      "|ratio - per-pixel ratio| %.4f -> %.4f over %zu pixels\n",
      passes.firstPoints, grid.firstStride(), grid.points.count(), grid.unit, err[0], err[1],
      pixels);
  EXPECT_LT(err[1], 0.3 * err[0]);
  EXPECT_LT(err[1], 0.01);

  // The finest cells an edge crosses, traced at their pixels: the edge no longer follows the
  // cells' squares (stair steps along a hard shadow). Measured at the pixels where the
  // interpolation and the pixel's own point disagree by more than 0.1: the edge's pixels.
  Image sharpened = passes.last;
  const int64_t rays =
      sharpenGroundEdges(grid, sharpened, scene, shot.worldFromObject, shot.camera, settings);
  EXPECT_GT(rays, 0);
  size_t edgePixels = 0;
  const std::vector<double> edge =
      againstEachPixel(grid, shot.camera, shot.worldFromObject, shade, {&passes.last, &sharpened},
                       1, edgePixels, 2.0, &passes.last, 0.1);
  ASSERT_GT(edgePixels, 100u);
  std::printf("at the %zu edge pixels: mean |ratio - per-pixel ratio| %.3f -> %.3f (%lld rays)\n",
              edgePixels, edge[0], edge[1], static_cast<long long>(rays));
  EXPECT_LT(edge[1], 0.5 * edge[0]);
}

// A thin post in the sun: its shadow is narrower than the first grid's cells (wider than the base
// stride) and can fall between their corners, which then all see the sun. The cells the post's
// shadow may reach are split all the same, and the shadow is drawn where each pixel's own point
// says.
TEST(GroundShadow, AShadowBetweenTheFirstNodesIsFound) {
  Mesh post = cube();
  for (glm::vec3& p : post.positions) p = glm::vec3(p.x * 0.12f, p.y, p.z * 0.12f);
  const EmbreeScene scene(post.positions, post.indices);
  const Shot shot = shoot(post, 1200, 900, 35.0, {0.5, 0.5}, 0.25, 20.0);
  const lighting::Environment env = sunAndSky({std::cos(0.7f), std::sin(0.7f), 0.3f});
  const pipeline::ShadowPlan plan = pipeline::ShadowPlan::parse("");
  const pipeline::ShadowLighting lighting = pipeline::prepareShadowLighting(env, plan, {});
  const GroundShading shade{post, scene, lighting, shot.envFromObject};
  GroundSettings settings;
  settings.maxPoints = 6000;
  GroundGrid grid =
      groundGrid(post, shot.worldFromObject, shot.camera, lighting.split.sources, settings);
  const GroundShading::Passes passes = shade.coarseToFine(grid, shot, settings);
  // Over the pixels each pixel's own point puts in the post's shadow.
  size_t pixels = 0;
  const std::vector<double> err = againstEachPixel(grid, shot.camera, shot.worldFromObject, shade,
                                                   {&passes.first, &passes.last}, 3, pixels, 0.5);
  ASSERT_GT(pixels, 100u);
  std::printf(
      "the post's shadow (%zu pixels; first nodes every %d pixels): mean |ratio - "
      "per-pixel ratio| %.3f -> %.3f\n",
      pixels, grid.firstStride(), err[0], err[1]);
  EXPECT_GT(err[0], 0.2) << "the first grid misses much of the shadow (the case this is about)";
  EXPECT_LT(err[1], 0.1);
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

// A small object far off, seen at a grazing angle: the ground around it is a band of a few rows.
// Its first nodes were 4 pixels apart: none fell on the band's ground (no shadow at all, and "no
// ground around the object is in view"), or a few did, where the lattice happened to. Every
// row and every second column of the band is sampled now.
TEST(GroundShadow, AThinBandOfGroundIsSampledRowByRow) {
  const Mesh box = cube();
  const Shot shot = shoot(box, 320, 240, 0.0, {0.5, 0.56}, 0.05);
  const GroundGrid grid = groundGrid(box, shot.worldFromObject, shot.camera, {});
  ASSERT_GT(grid.x1 - grid.x0, 20) << "the band is wide";
  ASSERT_LT(grid.y1 - grid.y0, 16) << "and a few rows high";
  ASSERT_FALSE(grid.empty());
  // Each plate row showing the region's ground has nodes on it.
  for (int y = grid.y0; y < grid.y1; ++y) {
    int ground = 0;
    for (int x = grid.x0; x < grid.x1; ++x) {
      glm::dvec3 origin, dir;
      if (!shot.camera.ray(x + 0.5, y + 0.5, origin, dir) || !(dir.y < -1e-9)) continue;
      const glm::dvec3 g = origin + dir * (-origin.y / dir.y);
      ground += g.x >= grid.regionX0 && g.x <= grid.regionX1 && g.z >= grid.regionZ0 &&
                g.z <= grid.regionZ1;
    }
    if (ground == 0) continue;
    int nodes = 0;
    for (const uint32_t n : grid.pointNode)
      nodes += grid.y0 + int(n / size_t(grid.columns)) * grid.unit == y;
    EXPECT_GE(nodes, ground / 2) << "row " << y << ": " << ground << " pixels show the region";
  }
}

// A small object far off (12 pixels high, 20 rows below the horizon): its shadow lies on a few
// rows of ground seen at a grazing angle, and changes within a pixel. Each pixel's ratio is the
// mean over the ground the pixel shows (8 x 8 points across it, each shaded as the ground pass
// shades its points), pixel by pixel and summed, wherever within a pixel the object stands.
TEST(GroundShadow, ASmallObjectsShadowIsThePixelsAverage) {
  const Mesh box = cube();
  const EmbreeScene scene(box.positions, box.indices);
  const lighting::Environment env = sunAndSky({std::cos(0.9f), std::sin(0.9f), 0.5f});
  const pipeline::ShadowPlan plan = pipeline::ShadowPlan::parse("");
  const pipeline::ShadowLighting lighting = pipeline::prepareShadowLighting(env, plan, {});
  constexpr int kParts = 8;
  double worstSum = 0.0, worstPixels = 0.0;
  for (int k = 0; k < 4; ++k) {
    const Shot shot =
        shoot(box, 320, 240, 0.0, {(160.0 + 0.3 * k) / 320.0, (140.0 + 0.25 * k) / 240.0}, 0.05);
    const pipeline::GroundShadowResult g =
        pipeline::computeGroundShadow(box, scene, shot.worldFromObject, shot.camera, lighting,
                                      glm::mat3(1.0f), shot.envFromObject, plan);
    ASSERT_FALSE(g.ratio.empty());
    // The ground each pixel of the ratio's rectangle shows, kParts x kParts points across it;
    // pixels that show the object in part are left out.
    const GroundShading shade{box, scene, lighting, shot.envFromObject};
    SurfacePoints parts;
    parts.size = g.grid.points.size, parts.centre = g.grid.points.centre;
    parts.radius = g.grid.points.radius;
    std::vector<glm::ivec2> pixels;
    const glm::dmat4 objectFromWorld = glm::inverse(shot.worldFromObject);
    for (int y = 0; y < g.ratio.height; ++y)
      for (int x = 0; x < g.ratio.width; ++x) {
        std::vector<glm::vec3> at;
        for (int v = 0; v < kParts; ++v)
          for (int u = 0; u < kParts; ++u) {
            glm::dvec3 origin, dir;
            if (!shot.camera.ray(g.grid.x0 + x + (u + 0.5) / kParts,
                                 g.grid.y0 + y + (v + 0.5) / kParts, origin, dir) ||
                !(dir.y < -1e-9))
              continue;
            const glm::dvec3 o = glm::dvec3(objectFromWorld * glm::dvec4(origin, 1.0));
            const glm::dvec3 d = glm::dvec3(objectFromWorld * glm::dvec4(dir, 0.0));
            if (scene.occluded(glm::vec3(o), glm::vec3(glm::normalize(d)))) continue;
            const glm::dvec3 p = origin + dir * (-origin.y / dir.y);
            at.emplace_back(glm::dvec3(objectFromWorld * glm::dvec4(p, 1.0)));
          }
        if (at.size() != size_t(kParts * kParts)) continue;
        for (const glm::vec3& p : at) {
          parts.positions.push_back(p);
          parts.normals.emplace_back(0.0f, 1.0f, 0.0f);
        }
        pixels.emplace_back(x, y);
      }
    const VertexIrradiance truth = shade(parts);
    double sumGot = 0.0, sumTrue = 0.0, apart = 0.0;
    for (size_t i = 0; i < pixels.size(); ++i) {
      double mean = 0.0;
      for (size_t j = i * kParts * kParts; j < (i + 1) * kParts * kParts; ++j)
        mean += truth.unshadowed[j].y > 1e-20f
                    ? std::clamp(truth.shadowed[j].y / truth.unshadowed[j].y, 0.0f, 1.0f)
                    : 1.0;
      mean /= kParts * kParts;
      const double got = g.ratio.at(pixels[i].x, pixels[i].y)[1];
      sumGot += 1.0 - got;
      sumTrue += 1.0 - mean;
      apart += std::abs(got - mean);
    }
    ASSERT_GT(sumTrue, 5.0) << "a shadow of a few pixels' darkness at least";
    std::printf(
        "placement %d: darkness %.2f pixels against %.2f averaged over each pixel: ratio %.3f; "
        "pixel by pixel %.1f %% of it apart\n",
        k, sumGot, sumTrue, sumGot / sumTrue, 100.0 * apart / sumTrue);
    worstSum = std::max(worstSum, std::abs(sumGot / sumTrue - 1.0));
    worstPixels = std::max(worstPixels, apart / sumTrue);
  }
  // Sampled at pixel centres: 0.22-1.31 times, 34-81 % apart; split into 4 x 4: 0.978-1.014,
  // 6-9 % apart.
  EXPECT_LT(worstSum, 0.05);
  EXPECT_LT(worstPixels, 0.15);
}

// The ground the object stands on lights its underside less next to it (GroundContact): under a
// uniform sky, a side face's lowest points receive less than its highest, which see the ground
// further out; the top sees no ground and is unchanged; ground=off is the object alone.
TEST(ShadowPlan, TheGroundBeneathTheObjectDarkensItsLowerSides) {
  const Mesh box = cube();
  const EmbreeScene scene(box.positions, box.indices);
  const lighting::Environment sky = lighting::Environment::constant(glm::vec3(1.0f), 64);
  const glm::mat3 identity(1.0f);
  const pipeline::ShadowPlan on = pipeline::ShadowPlan::parse("");
  const pipeline::ShadowPlan off = pipeline::ShadowPlan::parse("ground=off");
  EXPECT_TRUE(on.ground);
  EXPECT_FALSE(off.ground);
  EXPECT_NE(on.describe(), off.describe());  // the stages' cache keys tell them apart
  // ... but the shadow lighting and the plate's ground shadow do not depend on it.
  EXPECT_EQ(on.describeLighting(), off.describeLighting());
  const pipeline::ShadowLighting lighting = pipeline::prepareShadowLighting(sky, on, {});
  const pipeline::ShadowResult a =
      pipeline::computeSelfShadowing(box, scene, lighting, identity, on, {});
  const pipeline::ShadowResult b =
      pipeline::computeSelfShadowing(box, scene, lighting, identity, off, {});
  ASSERT_EQ(a.points.count(), b.points.count());
  double low = 0.0, high = 0.0, lowAlone = 0.0;
  int lows = 0, highs = 0, tops = 0;
  for (size_t p = 0; p < a.points.count(); ++p) {
    const glm::vec3 n = a.points.normals[p], x = a.points.positions[p];
    const double e = a.irradiance.shadowed[p].y, alone = b.irradiance.shadowed[p].y;
    if (n.y > 0.99f) {
      EXPECT_NEAR(e, alone, 1e-4 * alone);
      ++tops;
    } else if (std::abs(n.y) < 0.01f && x.y < 0.05f) {
      low += e;
      lowAlone += alone;
      ++lows;
    } else if (std::abs(n.y) < 0.01f && x.y > 0.95f) {
      high += e;
      ++highs;
    }
  }
  ASSERT_GT(lows, 10);
  ASSERT_GT(highs, 10);
  EXPECT_GT(tops, 10);
  low /= lows, high /= highs, lowAlone /= lows;
  // Alone, a side point sees the whole hemisphere of a uniform sky: π. On the ground, its lower
  // half (π/2 of it) sees ground darkened next to the box, fully so at the contact.
  EXPECT_NEAR(lowAlone, kPi, 0.01 * kPi);
  EXPECT_LT(low, 0.85 * lowAlone);
  EXPECT_LT(low, high - 0.05 * kPi);
  EXPECT_LT(high, lowAlone);
  EXPECT_GT(low, 0.5 * lowAlone);  // the upper half of the hemisphere is open sky
  COMPOSE_EXPECT_ERROR(pipeline::ShadowPlan::parse("ground=maybe"),
                       "ground must be on or off, got 'maybe'");
}

// A grid out of range is named as the grid (grid=0 was reported as an order out of 1..0).
TEST(ShadowPlan, TheGridIsCheckedBeforeTheOrderItBounds) {
  COMPOSE_EXPECT_ERROR(pipeline::ShadowPlan::parse("grid=0"), "grid (s) must be in 2..64, got 0");
  COMPOSE_EXPECT_ERROR(pipeline::ShadowPlan::parse("grid=65"), "grid (s) must be in 2..64");
  COMPOSE_EXPECT_ERROR(pipeline::ShadowPlan::parse("grid=8,order=9"),
                       "order (k) must be in 1..min(grid, 32), got 9");
  EXPECT_EQ(pipeline::ShadowPlan::parse("grid=8,order=8").transfer.grid, 8);
  // A coarser grid without an order takes the grid's size as its order (the default 16 was
  // refused as if the user had given it).
  EXPECT_EQ(pipeline::ShadowPlan::parse("grid=4").lightingOrder, 4);
  EXPECT_EQ(pipeline::ShadowPlan::parse("grid=32").lightingOrder, 16);
  EXPECT_EQ(pipeline::ShadowPlan::parse("").lightingOrder, 16);
  // A parameter the method does not take is refused, not ignored.
  COMPOSE_EXPECT_ERROR(pipeline::ShadowPlan::parse("method=ao,order=99"),
                       "order does not apply to method=ao");
  // Sources are not traced with ambient occlusion (sources=0 and sources=8 wrote the same file),
  // nor is a budget spent without refinement.
  COMPOSE_EXPECT_ERROR(pipeline::ShadowPlan::parse("method=ao,sources=8"),
                       "sources does not apply to method=ao");
  COMPOSE_EXPECT_ERROR(pipeline::ShadowPlan::parse("refine=0,refine-budget=3"),
                       "refine-budget does not apply with refine=0");
  EXPECT_EQ(pipeline::ShadowPlan::parse("method=ao").method, ShadowMethod::AmbientOcclusion);
  EXPECT_EQ(pipeline::ShadowPlan::parse("refine=0").refine.spread, 0.0f);
}

}  // namespace
}  // namespace compose::render
