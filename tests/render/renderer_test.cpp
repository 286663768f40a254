#include "render/renderer.h"

#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "lighting/exact.h"
#include "lighting/sh.h"
#include "test_meshes.h"
#include "test_util.h"

namespace compose::render {
namespace {

using testing::uvSphere;

struct Scene {
  Mesh sphere = uvSphere(64, 128);
  EmbreeScene bvh{sphere.positions, sphere.indices};
  calib::PlateCamera camera = calib::plateCamera(200, 150, {}, {});
  glm::dmat4 worldFromObject{1.0};
  Scene() {
    calib::Placement place;
    place.imagePoint = {0.5, 0.8};
    place.heightFraction = 0.5;
    worldFromObject = calib::placeOnGround(camera, place, {-1, -1, -1}, {1, 1, 1});
  }
};

// A 320 x 240 camera at the ground's level looking along -Z, fx = fy = 200 at the centre, with
// `k1` radial distortion (0: none).
calib::PlateCamera levelCamera(double k1) {
  calib::CameraOptions options;
  options.height = 1e-3;
  calib::Lens lens;
  lens.width = 320;
  lens.height = 240;
  lens.fx = lens.fy = 200.0;
  lens.cx = 160.0;
  lens.cy = 120.0;
  if (k1 != 0.0) lens.distortion = {k1, 0.0, 0.0, 0.0, 0.0};
  options.lens = lens;
  return calib::plateCamera(320, 240, {}, options);
}

// The largest difference between two renders' beauty values.
float largestDifference(const RenderOutput& a, const RenderOutput& b) {
  float worst = 0.0f;
  for (size_t i = 0; i < a.beauty.pixels.size() && i < b.beauty.pixels.size(); ++i)
    worst = std::max(worst, std::abs(a.beauty.pixels[i] - b.beauty.pixels[i]));
  return worst;
}

// White furnace through the renderer: a Lambertian surface of albedo ρ under radiance 1 everywhere
// reflects exactly ρ (E = π, divided by π), so any π slip shows as a factor of 3.
TEST(Renderer, WhiteFurnaceGivesTheAlbedo) {
  Scene scene;
  lighting::ShLighting sh(2);
  sh.project(lighting::Environment::constant(glm::vec3(1.0f), 64));
  RenderSettings settings;
  settings.albedo = glm::vec3(0.25f, 0.5f, 0.75f);
  settings.exposure = 2.0f;
  const RenderOutput out =
      renderDiffuse(scene.sphere, scene.bvh, scene.worldFromObject, scene.camera, sh, settings);
  int covered = 0;
  double alphaSum = 0.0;
  for (int y = 0; y < out.beauty.height; ++y) {
    for (int x = 0; x < out.beauty.width; ++x) {
      const float* p = out.beauty.at(x, y);
      alphaSum += p[3];
      if (p[3] < 1.0f) {
        // Premultiplied: colour scales with coverage.
        EXPECT_NEAR(p[1], 1.0f * p[3], 1e-5f);
        continue;
      }
      ++covered;
      EXPECT_NEAR(p[0], 0.5f, 1e-5f);  // float SH evaluation: ~1e-7; 1e-5 is the furnace bound
      EXPECT_NEAR(p[1], 1.0f, 1e-5f);
      EXPECT_NEAR(p[2], 1.5f, 1e-5f);
    }
  }
  EXPECT_GT(covered, 3000);
  // The sphere's silhouette is close to a disc of diameter half the frame height (perspective
  // and tessellation make it differ by a few per cent).
  const double disc = std::numbers::pi * 37.5 * 37.5;
  EXPECT_NEAR(alphaSum, disc, 0.05 * disc);
}

// A semi-transparent sphere (glTF's BLEND, alpha 0.3 everywhere, its back side added as loading
// adds it) in the white furnace: where the opaque sphere covers a pixel, the camera's rays meet
// its front (0.3 of the pixel) and the inside of its back (0.3 of the 0.7 left): 0.51, without
// noise, each layer shaded as the furnace shades it.
TEST(Renderer, SemiTransparentLayersCoverTheirAlphaFrontToBack) {
  Scene scene;
  lighting::ShLighting sh(2);
  sh.project(lighting::Environment::constant(glm::vec3(1.0f), 64));
  RenderSettings settings;
  settings.exposure = 2.0f;
  const RenderOutput opaque =
      renderDiffuse(scene.sphere, scene.bvh, scene.worldFromObject, scene.camera, sh, settings);
  Mesh glass = scene.sphere;
  Material mat;
  mat.baseColor = glm::vec3(0.5f);
  mat.blend = true;
  mat.baseAlpha = 0.3f;
  glass.materials.push_back(mat);
  addBackSides(glass);
  ASSERT_EQ(glass.triangleCount(), 2 * scene.sphere.triangleCount());
  const EmbreeScene bvh(glass);
  const RenderOutput out =
      renderDiffuse(glass, bvh, scene.worldFromObject, scene.camera, sh, settings);
  ASSERT_EQ(out.beauty.width, opaque.beauty.width);
  int inside = 0;
  for (int y = 0; y < out.beauty.height; ++y)
    for (int x = 0; x < out.beauty.width; ++x) {
      const float* p = out.beauty.at(x, y);
      if (opaque.beauty.at(x, y)[3] < 1.0f) {
        EXPECT_LE(p[3], opaque.beauty.at(x, y)[3] + 1e-6f);
        continue;
      }
      ++inside;
      EXPECT_NEAR(p[3], 0.51f, 1e-4f) << x << ", " << y;
      EXPECT_NEAR(p[1], 0.51f, 1e-4f) << x << ", " << y;
    }
  EXPECT_GT(inside, 3000);
  EXPECT_NEAR(out.coverage, 0.51 * opaque.coverage, 0.02 * opaque.coverage);
  // A cut-out material (alpha 0.8, above its cutoff) in a mesh that also has a semi-transparent
  // one is there whole: the camera does not see through it.
  Mesh cut = scene.sphere;
  Material leaf;
  leaf.alphaCutoff = 0.5f;
  leaf.baseAlpha = 0.8f;
  cut.materials = {leaf, mat};
  cut.triangleMaterial.assign(cut.triangleCount(), 0u);
  const EmbreeScene cutBvh(cut);
  const RenderOutput mixed =
      renderDiffuse(cut, cutBvh, scene.worldFromObject, scene.camera, sh, settings);
  for (int y = 0; y < mixed.beauty.height; ++y)
    for (int x = 0; x < mixed.beauty.width; ++x) {
      if (opaque.beauty.at(x, y)[3] >= 1.0f) {
        EXPECT_EQ(mixed.beauty.at(x, y)[3], 1.0f) << x << ", " << y;
      }
    }
}

// Under L(ω) = 1 + b·ω the outgoing radiance is ρ (1 + (2/3) b·n): checks normals, their frame
// and the environment rotation together.
TEST(Renderer, ShadingFollowsTheNormalAov) {
  Scene scene;
  const glm::vec3 b(0.6f, 0.3f, -0.4f);
  Image img(128, 64, 3);
  const auto probe = lighting::Environment::constant(glm::vec3(0.0f), 128);
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 128; ++x) {
      const float v = 1.0f + glm::dot(b, probe.direction(x, y));
      img.at(x, y)[0] = img.at(x, y)[1] = img.at(x, y)[2] = v;
    }
  lighting::ShLighting sh(1);
  sh.project(lighting::Environment::fromLatLong(img));
  RenderSettings settings;
  settings.albedo = glm::vec3(1.0f);
  settings.samplesPerAxis = 1;
  // Turn the environment by 90° about +Y: world +X is environment -Z... check with the matrix.
  const float c = 0.0f, s = 1.0f;
  settings.envFromWorld = glm::mat3(glm::vec3(c, 0, -s), glm::vec3(0, 1, 0), glm::vec3(s, 0, c));
  const RenderOutput out =
      renderDiffuse(scene.sphere, scene.bvh, scene.worldFromObject, scene.camera, sh, settings);
  int checked = 0;
  for (int y = 0; y < out.beauty.height; ++y) {
    for (int x = 0; x < out.beauty.width; ++x) {
      if (out.beauty.at(x, y)[3] < 1.0f) continue;
      const float* n = out.aovs.at(x, y);  // N.X N.Y N.Z come first
      const glm::vec3 nEnv = settings.envFromWorld * glm::vec3(n[0], n[1], n[2]);
      const float expected = 1.0f + 2.0f / 3.0f * glm::dot(b, nEnv);
      // 64x128 tessellation + 128x64 map quadrature: 2e-3.
      EXPECT_NEAR(out.beauty.at(x, y)[0], expected, 2e-3f);
      ++checked;
    }
  }
  EXPECT_GT(checked, 3000);
  // The camera sees the sphere's front: normals of covered pixels point back toward +Z (camera).
  const float* centre = out.aovs.at(100 - out.x0, int(0.8 * 150 - 0.25 * 150) - out.y0);
  EXPECT_GT(centre[2], 0.9f);
}

}  // namespace
}  // namespace compose::render

namespace compose::render {
namespace {

// One square facing the camera (wound counter-clockwise towards it) at `depth` in front of a
// level camera at the origin, with the given vertex normals.
Mesh facingSquare(const glm::vec3 normals[4]) {
  Mesh m;
  m.positions = {{-1, -1, 0}, {1, -1, 0}, {1, 1, 0}, {-1, 1, 0}};
  m.normals.assign(normals, normals + 4);
  m.indices = {0, 1, 2, 0, 2, 3};
  m.normalsFromFile = true;
  return m;
}

// Bright where the camera is (+Z), dark behind the square (-Z).
lighting::Environment frontLit() {
  Image img(64, 32, 3);
  const auto probe = lighting::Environment::constant(glm::vec3(0.0f), 64);
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 64; ++x) {
      const float v = probe.direction(x, y).z > 0.0f ? 1.0f : 0.0f;
      img.at(x, y)[0] = img.at(x, y)[1] = img.at(x, y)[2] = v;
    }
  return lighting::Environment::fromLatLong(img);
}

RenderOutput renderSquare(const Mesh& m, const lighting::DiffuseLighting& lighting) {
  const EmbreeScene bvh(m.positions, m.indices);
  calib::CameraOptions level;
  level.height = 1e-3;
  const calib::PlateCamera camera = calib::plateCamera(64, 48, {}, level);
  // The square 5 units in front of the camera.
  const glm::dmat4 worldFromObject =
      glm::translate(glm::dmat4(1.0), camera.position() + glm::dvec3(0, 0, -5));
  RenderSettings settings;
  settings.albedo = glm::vec3(1.0f);
  settings.samplesPerAxis = 1;
  return renderDiffuse(m, bvh, worldFromObject, camera, lighting, settings);
}

TEST(Renderer, AShadingNormalPointingAwayIsBentTowardsTheViewer) {
  // The file's normals point away from the camera although the face looks at it.
  const glm::vec3 away[4] = {{0, 0, -1}, {0, 0, -1}, {0, 0, -1}, {0, 0, -1}};
  lighting::ExactLighting exact;
  exact.project(frontLit());
  const RenderOutput out = renderSquare(facingSquare(away), exact);
  const float* centre = out.beauty.at(32 - out.x0, 24 - out.y0);
  ASSERT_EQ(centre[3], 1.0f);
  // Bent to the tangent plane, the normal sees half of the bright front: E = π/2... and
  // anything but the dark back (0).
  EXPECT_GT(centre[0], 0.2f) << "shaded from behind the face";
  const float* n = out.aovs.at(32 - out.x0, 24 - out.y0);
  EXPECT_GE(n[2], 0.0f) << "the normal AOV faces the viewer";
}

TEST(Renderer, AZeroInterpolatedNormalFallsBackToTheFace) {
  // Vertex normals that cancel in the middle of the square.
  const glm::vec3 cancelling[4] = {{1, 0, 0}, {0, 1, 0}, {-1, 0, 0}, {0, -1, 0}};
  lighting::ExactLighting exact;
  exact.project(frontLit());
  const RenderOutput out = renderSquare(facingSquare(cancelling), exact);
  for (float v : out.beauty.pixels) ASSERT_TRUE(std::isfinite(v));
  for (float v : out.aovs.pixels) ASSERT_TRUE(std::isfinite(v));
}

TEST(Renderer, ABoundingBoxCornerJustInFrontOfTheCameraIsClamped) {
  // A long wall whose near end ends a hair in front of the camera: its corners project to
  // coordinates far beyond any int.
  Mesh wall;
  wall.positions = {{0.5f, -1, -1e-7f}, {0.5f, -1, -50}, {0.5f, 1, -50}, {0.5f, 1, -1e-7f}};
  wall.normals.assign(4, glm::vec3(-1, 0, 0));
  wall.indices = {0, 1, 2, 0, 2, 3};
  const EmbreeScene bvh(wall.positions, wall.indices);
  const calib::PlateCamera camera = calib::plateCamera(64, 48, {}, {});
  lighting::ExactLighting exact;
  exact.project(lighting::Environment::constant(glm::vec3(1.0f), 16));
  RenderSettings settings;
  settings.samplesPerAxis = 1;
  const glm::dmat4 worldFromObject = glm::translate(glm::dmat4(1.0), camera.position());
  const RenderOutput out = renderDiffuse(wall, bvh, worldFromObject, camera, exact, settings);
  EXPECT_GE(out.x0, 0);
  EXPECT_LE(out.x1, 64);
  EXPECT_GE(out.y0, 0);
  EXPECT_LE(out.y1, 48);
  EXPECT_GT(out.coverage, 0.0) << "the wall is seen";
}

// Pixels no triangle's projection reaches are not traced, and the picture does not change: the
// same values in every channel of every pixel as with every pixel of the rectangle traced, for a
// finely tessellated sphere and for a soup of random triangles (slivers, needles, large ones,
// edges at every angle), with fewer rays. A lens that bends straight edges traces every pixel.
TEST(Renderer, PixelsNoTriangleReachesAreNotTracedAndThePictureIsTheSame) {
  Mesh soup;
  uint32_t state = 12345u;
  auto next = [&] {
    state = state * 1664525u + 1013904223u;
    return float(state >> 8) / float(1u << 24);
  };
  for (int t = 0; t < 300; ++t) {
    const glm::vec3 centre(2.0f * next() - 1.0f, 2.0f * next() - 1.0f, 2.0f * next() - 1.0f);
    const float size = t % 10 == 0 ? 1.0f : 0.02f + 0.2f * next();
    for (int c = 0; c < 3; ++c) {
      const glm::vec3 offset(next() - 0.5f, next() - 0.5f, next() - 0.5f);
      // Every fifth triangle a needle: its corners nearly on one line.
      const glm::vec3 p = t % 5 == 1 ? centre + glm::vec3(0.01f * float(c) * offset.x,
                                                          size * float(c), 0.001f * float(c))
                                     : centre + size * offset;
      soup.positions.push_back(p);
      soup.normals.push_back(glm::normalize(p + glm::vec3(0.0f, 0.0f, 1e-3f)));
    }
    soup.indices.insert(soup.indices.end(),
                        {uint32_t(3 * t), uint32_t(3 * t + 1), uint32_t(3 * t + 2)});
  }
  soup.normalsFromFile = true;
  Scene scene;
  const EmbreeScene soupBvh(soup.positions, soup.indices);
  lighting::ShLighting sh(2);
  sh.project(lighting::Environment::constant(glm::vec3(1.0f), 16));

  auto compare = [&](const Mesh& mesh, const EmbreeScene& bvh, const calib::PlateCamera& camera,
                     bool fewer, const glm::dmat4& worldFromObject) {
    RenderSettings all, covered;
    all.skipUncoveredPixels = false;
    all.adaptive = covered.adaptive = false;  // adaptive sampling needs the mask: compared below
    const RenderOutput a = renderDiffuse(mesh, bvh, worldFromObject, camera, sh, all);
    const RenderOutput b = renderDiffuse(mesh, bvh, worldFromObject, camera, sh, covered);
    ASSERT_GT(a.coverage, 100.0);
    ASSERT_EQ(a.beauty.pixels.size(), b.beauty.pixels.size());
    size_t differ = 0;
    for (size_t i = 0; i < a.beauty.pixels.size(); ++i)
      differ += a.beauty.pixels[i] != b.beauty.pixels[i];
    for (size_t i = 0; i < a.aovs.pixels.size(); ++i)
      differ += a.aovs.pixels[i] != b.aovs.pixels[i];
    EXPECT_EQ(differ, 0u) << "values that differ";
    EXPECT_EQ(a.coverage, b.coverage);
    if (fewer) {
      EXPECT_LT(double(b.rays), 0.9 * double(a.rays));
    } else {
      EXPECT_EQ(b.rays, a.rays);
    }
  };
  compare(scene.sphere, scene.bvh, scene.camera, true, scene.worldFromObject);
  compare(soup, soupBvh, scene.camera, true, scene.worldFromObject);
  // A mesh far from its own origin (a georeferenced scan): the rays start from the camera's
  // centre rounded to float there, and the mask must see the triangles from the same point.
  Mesh far = scene.sphere;
  const glm::vec3 offset(3e5f, 3e5f, 3e5f);
  for (glm::vec3& p : far.positions) p += offset;
  const EmbreeScene farBvh(far.positions, far.indices);
  calib::Placement place;
  place.imagePoint = {0.5, 0.8};
  place.heightFraction = 0.5;
  compare(far, farBvh, scene.camera, true,
          calib::placeOnGround(scene.camera, place, glm::dvec3(far.boundsMin()),
                               glm::dvec3(far.boundsMax())));

  calib::CameraOptions options;
  calib::Lens lens;
  lens.width = 200;
  lens.height = 150;
  lens.fx = lens.fy = 180.0;
  lens.cx = 100.0;
  lens.cy = 75.0;
  lens.distortion = {-0.2, 0.0, 0.0, 0.0, 0.0};
  options.lens = lens;
  const calib::PlateCamera distorted = calib::plateCamera(200, 150, {}, options);
  compare(soup, soupBvh, distorted, false, scene.worldFromObject);
}

// Adaptive sampling: a pixel shaded from its four corner samples looks as it does from all 4 x 4,
// and every pixel that holds an edge gets all of them. On a sphere under light that varies with
// direction: coverage equal in every pixel (the silhouette's pixels are traced in full, with the
// same samples), colour within 1 % of the largest value, at half the rays or fewer.
TEST(Renderer, AdaptiveSamplingLooksLikeFullSampling) {
  Scene scene;
  Image sky(64, 32, 3);
  for (int y = 0; y < sky.height; ++y)
    for (int x = 0; x < sky.width; ++x)
      for (int c = 0; c < 3; ++c)
        sky.at(x, y)[c] = 0.1f + 2.0f * float(sky.height - y) / float(sky.height) +
                          0.5f * float(c) * float(x) / float(sky.width);
  lighting::ShLighting sh(2);
  sh.project(lighting::Environment::fromLatLong(sky));
  RenderSettings full, adaptive;
  full.adaptive = false;
  // Fewer triangles than the traced rectangle has pixels (a finer mesh is traced in full).
  const Mesh sphere = uvSphere(32, 64);
  const EmbreeScene bvh(sphere.positions, sphere.indices);
  const RenderOutput a = renderDiffuse(sphere, bvh, scene.worldFromObject, scene.camera, sh, full);
  const RenderOutput b =
      renderDiffuse(sphere, bvh, scene.worldFromObject, scene.camera, sh, adaptive);
  ASSERT_LT(sphere.triangleCount(), size_t((b.x1 - b.x0) * (b.y1 - b.y0)));
  const RenderOutput fine =
      renderDiffuse(scene.sphere, scene.bvh, scene.worldFromObject, scene.camera, sh, adaptive);
  EXPECT_EQ(fine.pixelsPlain, 0) << "more triangles than pixels: traced in full";
  ASSERT_EQ(a.beauty.pixels.size(), b.beauty.pixels.size());
  EXPECT_EQ(a.pixelsPlain, 0);
  EXPECT_GT(b.pixelsPlain, b.pixelsTraced / 2);
  EXPECT_LT(double(b.rays), 0.5 * double(a.rays));
  float largest = 0.0f, worst = 0.0f;
  size_t alphaDiffers = 0;
  for (int y = 0; y < a.beauty.height; ++y) {
    for (int x = 0; x < a.beauty.width; ++x) {
      const float* p = a.beauty.at(x, y);
      const float* q = b.beauty.at(x, y);
      alphaDiffers += p[3] != q[3];
      for (int c = 0; c < 3; ++c) {
        largest = std::max(largest, p[c]);
        worst = std::max(worst, std::abs(p[c] - q[c]));
      }
    }
  }
  EXPECT_EQ(alphaDiffers, 0u);
  ASSERT_GT(largest, 0.0f);
  EXPECT_LT(worst, 0.01f * largest);
}

// A texture much finer than the pixels (a checker of single texels, 2048 around the sphere's
// equator: about 14 texels a pixel at the middle, ever more towards the rim) in the white furnace:
// every covered pixel shows the checker's mean, 0.5, with its footprint averaged; picking single
// texels (the same mesh without mip levels: bilinear at full size) leaves grain of 0.04 (RMS).
TEST(Renderer, AFineTextureIsAveragedOverTheFootprintNotSampledIntoGrain) {
  Scene scene;
  lighting::ShLighting sh(2);
  sh.project(lighting::Environment::constant(glm::vec3(1.0f), 64));
  RenderSettings settings;
  settings.exposure = 1.0f;  // beauty = albedo
  Mesh textured = scene.sphere;
  const int rings = 64, segments = 128;
  for (int r = 0; r <= rings; ++r)
    for (int s = 0; s <= segments; ++s)
      textured.texcoords.emplace_back(float(s) / float(segments), 1.0f - float(r) / float(rings));
  Texture checker;
  checker.image = Image(2048, 1024, 3, {"R", "G", "B"});
  for (int y = 0; y < 1024; ++y)
    for (int x = 0; x < 2048; ++x)
      for (int c = 0; c < 3; ++c) checker.image.at(x, y)[c] = float((x + y) % 2);
  Material mat;
  mat.texture = 0;
  textured.materials.push_back(mat);
  // The spread of the covered pixels' green about the checker's mean.
  auto spread = [&](const Mesh& mesh, double* mean) {
    const RenderOutput out =
        renderDiffuse(mesh, scene.bvh, scene.worldFromObject, scene.camera, sh, settings);
    double sum = 0.0, squares = 0.0;
    int covered = 0;
    for (int y = 0; y < out.beauty.height; ++y)
      for (int x = 0; x < out.beauty.width; ++x) {
        const float* p = out.beauty.at(x, y);
        if (p[3] < 1.0f) continue;
        ++covered;
        sum += p[1];
        squares += (p[1] - 0.5) * (p[1] - 0.5);
      }
    EXPECT_GT(covered, 3000);
    *mean = sum / std::max(covered, 1);
    return std::sqrt(squares / std::max(covered, 1));
  };
  textured.textures.push_back(checker);
  double pickedMean = 0.0, filteredMean = 0.0;
  const double picked = spread(textured, &pickedMean);
  buildMipLevels(textured.textures[0]);
  ASSERT_EQ(textured.textures[0].levels.size(), 11u);  // 1024 x 512 ... 1 x 1
  const double filtered = spread(textured, &filteredMean);
  EXPECT_GT(picked, 0.03) << "the unfiltered render shows the grain the test looks for";
  EXPECT_LT(filtered, 0.005);
  EXPECT_NEAR(filteredMean, 0.5, 0.005);
  EXPECT_NEAR(pickedMean, 0.5, 0.02);
  // The texture with alpha 0 on its black texels, on an opaque material: the alpha plays no part
  // (it weighted the levels: white).
  Texture& withAlpha = textured.textures[0];
  withAlpha.alpha = Image(2048, 1024, 1, {"A"});
  for (int y = 0; y < 1024; ++y)
    for (int x = 0; x < 2048; ++x) withAlpha.alpha.at(x, y)[0] = float((x + y) % 2);
  buildMipLevels(withAlpha);
  double opaqueMean = 0.0;
  EXPECT_LT(spread(textured, &opaqueMean), 0.005);
  EXPECT_NEAR(opaqueMean, 0.5, 0.005);
}

// A part thinner than the corner samples' spacing in front of a surface: a red strip a third of a
// pixel wide, 1 unit in front of a grey wall 5 units away, lying between the corner samples of
// the pixels it crosses. They all see the wall, but the strip is nearer in those pixels: they are
// traced in full and show it as full sampling does. And a gap as thin between two walls.
TEST(Renderer, AdaptiveSamplingKeepsThinPartsAndGapsTheCornerSamplesMiss) {
  const calib::PlateCamera camera = levelCamera(0.0);
  // At 4 units from the camera a pixel is 0.02 units wide: the strip spans x = 160.35..160.65
  // in pixels (the corner samples of 4 x 4 lie at 160.125 and 160.875).
  Mesh m;
  m.positions = {{-2, -1, 0},        {2, -1, 0},         {2, 1, 0},         {-2, 1, 0},
                 {0.007f, -0.5f, 1}, {0.013f, -0.5f, 1}, {0.013f, 0.5f, 1}, {0.007f, 0.5f, 1}};
  m.normals.assign(8, glm::vec3(0, 0, 1));
  m.indices = {0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7};
  m.normalsFromFile = true;
  Material grey, red;
  grey.baseColor = glm::vec3(0.5f);
  red.baseColor = glm::vec3(1.0f, 0.0f, 0.0f);
  m.materials = {grey, red};
  m.triangleMaterial = {0, 0, 1, 1};
  const EmbreeScene bvh(m.positions, m.indices);
  const glm::dmat4 worldFromObject =
      glm::translate(glm::dmat4(1.0), camera.position() + glm::dvec3(0, 0, -5));
  lighting::ShLighting sh(2);
  sh.project(lighting::Environment::constant(glm::vec3(1.0f), 16));
  RenderSettings full, adaptive;
  full.adaptive = false;
  full.jitter = adaptive.jitter = false;
  const RenderOutput a = renderDiffuse(m, bvh, worldFromObject, camera, sh, full);
  const RenderOutput b = renderDiffuse(m, bvh, worldFromObject, camera, sh, adaptive);
  ASSERT_EQ(a.x0, b.x0);
  ASSERT_EQ(a.beauty.pixels.size(), b.beauty.pixels.size());
  EXPECT_GT(b.pixelsPlain, b.pixelsTraced / 2);
  // The strip's column: half its pixels' samples red (the sample columns at 160.375 and
  // 160.625), red (1, 0, 0) over grey 0.5 under the furnace's light.
  ASSERT_TRUE(160 >= a.x0 && 160 < a.x1 && 120 >= a.y0 && 120 < a.y1);
  const float* middle = a.beauty.at(160 - a.x0, 120 - a.y0);
  EXPECT_NEAR(middle[0] - middle[1], 0.5f, 1e-4f);
  EXPECT_LT(largestDifference(a, b), 1e-5f);

  // The other way round: a gap a third of a pixel wide between two walls, nothing behind it. The
  // corner samples all hit a wall and nothing is nearer; the gap's edges are the walls' open
  // edges, a contour: those pixels are traced in full and let half their samples through.
  Mesh gap;
  gap.positions = {{-2, -1, 0},     {0.007f, -1, 0}, {0.007f, 1, 0}, {-2, 1, 0},
                   {0.013f, -1, 0}, {2, -1, 0},      {2, 1, 0},      {0.013f, 1, 0}};
  for (glm::vec3& p : gap.positions) p.z = 1.0f;  // 4 units away, as the strip
  gap.normals.assign(8, glm::vec3(0, 0, 1));
  gap.indices = {0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7};
  gap.normalsFromFile = true;
  const EmbreeScene gapBvh(gap.positions, gap.indices);
  const RenderOutput c = renderDiffuse(gap, gapBvh, worldFromObject, camera, sh, full);
  const RenderOutput d = renderDiffuse(gap, gapBvh, worldFromObject, camera, sh, adaptive);
  ASSERT_EQ(c.beauty.pixels.size(), d.beauty.pixels.size());
  EXPECT_GT(d.pixelsPlain, d.pixelsTraced / 2);
  EXPECT_NEAR(c.beauty.at(160 - c.x0, 120 - c.y0)[3], 0.5f, 1e-6f);
  EXPECT_LT(largestDifference(c, d), 1e-5f);

  // A stripe of another material as thin, in the plane of one wall (three bands sharing their
  // edges' vertices): the change of material is an edge, and the stripe shows.
  Mesh bands;
  bands.positions = {{-2, -1, 1}, {0.007f, -1, 1}, {0.013f, -1, 1}, {2, -1, 1},
                     {-2, 1, 1},  {0.007f, 1, 1},  {0.013f, 1, 1},  {2, 1, 1}};
  bands.normals.assign(8, glm::vec3(0, 0, 1));
  bands.indices = {0, 1, 5, 0, 5, 4, 1, 2, 6, 1, 6, 5, 2, 3, 7, 2, 7, 6};
  bands.normalsFromFile = true;
  bands.materials = {grey, red};
  bands.triangleMaterial = {0, 0, 1, 1, 0, 0};
  const EmbreeScene bandsBvh(bands.positions, bands.indices);
  const RenderOutput e = renderDiffuse(bands, bandsBvh, worldFromObject, camera, sh, full);
  const RenderOutput f = renderDiffuse(bands, bandsBvh, worldFromObject, camera, sh, adaptive);
  ASSERT_EQ(e.beauty.pixels.size(), f.beauty.pixels.size());
  EXPECT_GT(f.pixelsPlain, f.pixelsTraced / 2);
  const float* striped = e.beauty.at(160 - e.x0, 120 - e.y0);
  EXPECT_NEAR(striped[0] - striped[1], 0.5f, 1e-4f);
  EXPECT_LT(largestDifference(e, f), 1e-5f);
}

// The normals are compared where they are shaded, in world space. A flat wall whose normals (from
// the file) tilt by +4° and -4° in a pattern that repeats every pixel is within 10° in object
// space; squeezed ten times across by its placement, the world normals tilt by ±35°. The corner
// samples (at 1/8 and 7/8 of the pixel) see +4° and -4°, the middle ones (3/8, 5/8) -4°: shaded
// from the corners under light from one side, a pixel would be a quarter of the two tilts'
// difference off.
TEST(Renderer, AdaptiveSamplingComparesNormalsInWorldSpace) {
  const calib::PlateCamera camera = levelCamera(0.0);
  // At 4 units from the camera a pixel is 0.02 units wide; ten times that in object space. The
  // wall spans pixels 150..170 across and 110..130 up, a column of vertices every quarter pixel
  // at the samples' positions (pixel + 1/8 + k/4, a hundredth of a pixel aside: a ray along an
  // edge shared by two triangles may miss both).
  Mesh m;
  const float tilt = float(4.0 * std::numbers::pi / 180.0);
  // Columns k = -2..81 (the wall's ends between samples, not on them).
  const int columns = 84;
  for (int k = -2; k < columns - 2; ++k) {
    const float x = 0.2f * (-10.0f + 0.135f + 0.25f * float(k));
    const float side = (k + 4) % 4 == 0 ? 1.0f : -1.0f;
    const glm::vec3 normal(side * std::sin(tilt), 0.0f, std::cos(tilt));
    for (float y : {-0.2f, 0.2f}) {
      m.positions.push_back({x, y, 0.0f});
      m.normals.push_back(normal);
    }
  }
  for (uint32_t k = 0; k + 1 < uint32_t(columns); ++k)
    m.indices.insert(m.indices.end(), {2 * k, 2 * k + 2, 2 * k + 3, 2 * k, 2 * k + 3, 2 * k + 1});
  m.normalsFromFile = true;
  const EmbreeScene bvh(m.positions, m.indices);
  const glm::dmat4 worldFromObject =
      glm::scale(glm::translate(glm::dmat4(1.0), camera.position() + glm::dvec3(0, 0, -4)),
                 glm::dvec3(0.1, 1.0, 1.0));
  // Light from one side: the sky bright over half the azimuths.
  Image sky(64, 32, 3);
  for (int y = 0; y < sky.height; ++y)
    for (int x = 0; x < sky.width; ++x)
      for (int c = 0; c < 3; ++c) sky.at(x, y)[c] = x < sky.width / 2 ? 2.0f : 0.1f;
  lighting::ShLighting sh(2);
  sh.project(lighting::Environment::fromLatLong(sky));
  RenderSettings full, adaptive;
  full.adaptive = false;
  full.jitter = adaptive.jitter = false;
  const RenderOutput a = renderDiffuse(m, bvh, worldFromObject, camera, sh, full);
  const RenderOutput b = renderDiffuse(m, bvh, worldFromObject, camera, sh, adaptive);
  ASSERT_EQ(a.beauty.pixels.size(), b.beauty.pixels.size());
  ASSERT_GT(a.beauty.width, 10);
  // The tilts shade differently: the wall's pixels are not flat.
  const float* p = a.beauty.at(a.beauty.width / 2, a.beauty.height / 2);
  ASSERT_GT(p[3], 0.99f);
  EXPECT_LT(largestDifference(a, b), 1e-5f);
}

// The plate's lens distortion applies to the object's rays: the straight top edge of a wall bends
// in the render exactly as the lens model bends a straight line of the scene (a ruler held in front
// of the camera), and not as a pinhole would draw it.
TEST(Renderer, AStraightEdgeBendsLikeThePlatesLens) {
  // Barrel distortion, as a wide zoom at its short end.
  const calib::PlateCamera camera = levelCamera(-0.2);

  // A wall 5 units in front of the camera, wider than the view, its top edge 1.5 units above the
  // optical axis and its bottom below the frame.
  Mesh wall;
  wall.positions = {{-8, -3, 0}, {8, -3, 0}, {8, 1.5f, 0}, {-8, 1.5f, 0}};
  wall.normals.assign(4, glm::vec3(0, 0, 1));
  wall.indices = {0, 1, 2, 0, 2, 3};
  wall.normalsFromFile = true;
  const EmbreeScene bvh(wall.positions, wall.indices);
  const glm::dvec3 centre = camera.position() + glm::dvec3(0, 0, -5);
  const glm::dmat4 worldFromObject = glm::translate(glm::dmat4(1.0), centre);
  lighting::ShLighting sh(2);  // only the coverage matters here
  sh.project(lighting::Environment::constant(glm::vec3(1.0f), 16));
  RenderSettings settings;
  settings.samplesPerAxis = 4;
  const RenderOutput out = renderDiffuse(wall, bvh, worldFromObject, camera, sh, settings);
  ASSERT_GT(out.coverage, 0.0);

  // Where the lens puts the edge in column x: the point of the edge's line that projects to the
  // column's centre (found by bisection: the projection's x grows with the point's x).
  auto expectedEdge = [&](int x) {
    double lo = -8.0, hi = 8.0;
    glm::dvec2 px;
    for (int i = 0; i < 60; ++i) {
      const double mid = 0.5 * (lo + hi);
      EXPECT_TRUE(camera.project(centre + glm::dvec3(mid, 1.5, 0), px));
      (px.x < x + 0.5 ? lo : hi) = mid;
    }
    camera.project(centre + glm::dvec3(0.5 * (lo + hi), 1.5, 0), px);
    return px.y;
  };
  // Where the render puts it: the uncovered part of the column above row 150 (the edge lies in
  // rows 60-70 and nearly level, so a partly covered pixel holds the edge's sub-pixel position).
  auto renderedEdge = [&](int x) {
    double uncovered = 0.0;
    for (int y = 0; y < 150; ++y) {
      const bool inside = x >= out.x0 && x < out.x1 && y >= out.y0 && y < out.y1;
      uncovered += 1.0 - (inside ? double(out.beauty.at(x - out.x0, y - out.y0)[3]) : 0.0);
    }
    return uncovered;
  };
  double worst = 0.0, bow = 0.0;
  const double middle = expectedEdge(160);
  // Above the principal point the radial term already acts: r² = 0.3², 1 + k1 r² = 0.982.
  EXPECT_NEAR(middle, 120.0 - 200.0 * 0.3 * (1.0 - 0.2 * 0.09), 0.01);
  for (int x = 8; x < 312; x += 8) {
    const double expected = expectedEdge(x), rendered = renderedEdge(x);
    worst = std::max(worst, std::abs(rendered - expected));
    bow = std::max(bow, std::abs(expected - middle));
  }
  EXPECT_LT(worst, 0.25) << "pixels between the rendered edge and the lens model's";
  // The test can tell: a pinhole would draw the edge level, this lens bends it by this much.
  EXPECT_GT(bow, 6.0);
}

}  // namespace
}  // namespace compose::render
