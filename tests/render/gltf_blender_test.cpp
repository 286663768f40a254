// "A glTF exported by Blender renders like the same mesh as OBJ": meshes exported by Blender 3.4
// (tests/data/make_suzanne.py) rendered through the real renderer with one placement and one
// lighting, the glTF against the OBJ.
#include <cmath>
#include <cstdio>
#include <numbers>

#include "lighting/environment.h"
#include "lighting/sh.h"
#include "pipeline/compose_job.h"
#include "render/embree_scene.h"
#include "render/mesh.h"
#include "render/renderer.h"
#include "test_util.h"

namespace compose::render {
namespace {

namespace fs = std::filesystem;

const fs::path kData = COMPOSE_TEST_DATA_DIR;

// Directional light to make normals matter: a sky brighter towards the zenith, a warm sun 40°
// up, a dark ground; projected to SH order 4.
const lighting::ShLighting& sunAndSky() {
  static const lighting::ShLighting lighting = [] {
    Image img(128, 64, 3, {"R", "G", "B"});
    for (int y = 0; y < img.height; ++y) {
      const double elevation = std::numbers::pi * (0.5 - (y + 0.5) / img.height);
      for (int x = 0; x < img.width; ++x) {
        const double azimuth = 2.0 * std::numbers::pi * ((x + 0.5) / img.width - 0.5);
        float* p = img.at(x, y);
        const float sky = elevation > 0 ? float(0.3 + 0.7 * std::sin(elevation)) : 0.05f;
        p[0] = sky * 0.8f;
        p[1] = sky * 0.9f;
        p[2] = sky;
        const double dElevation = elevation - 40.0 * std::numbers::pi / 180.0;
        const double dAzimuth = azimuth - 0.6;
        if (dElevation * dElevation + dAzimuth * dAzimuth < 0.04) {
          p[0] += 40.0f;
          p[1] += 32.0f;
          p[2] += 24.0f;
        }
      }
    }
    lighting::ShLighting sh(4);
    sh.project(lighting::Environment::fromLatLong(img));
    return sh;
  }();
  return lighting;
}

struct Render {
  Image beauty;  // RGBA, premultiplied
  int x0 = 0, y0 = 0;
};

// Renders `mesh` at the placement computed from `reference`'s bounds (so that both meshes of a
// pair stand exactly in the same place), 2x2 samples at the strata centres.
Render render(const Mesh& mesh, const Mesh& reference, const RenderSettings& base) {
  const calib::PlateCamera camera = calib::plateCamera(320, 240, {}, {});
  calib::Placement place;
  place.imagePoint = {0.5, 0.85};
  place.heightFraction = 0.7;
  place.yawDegrees = 25.0;
  const glm::dmat4 worldFromObject = calib::placeOnGround(
      camera, place, glm::dvec3(reference.boundsMin()), glm::dvec3(reference.boundsMax()));
  const EmbreeScene scene(mesh.positions, mesh.indices);
  RenderSettings settings = base;
  settings.samplesPerAxis = 2;
  settings.jitter = false;
  const RenderOutput out =
      renderDiffuse(mesh, scene, worldFromObject, camera, sunAndSky(), settings);
  return {out.beauty, out.x0, out.y0};
}

struct Difference {
  double coverage = 0.0;      // |Σα_a − Σα_b| / Σα_b
  double meanRelative = 0.0;  // mean |Δ luminance| / mean luminance, over pixels covered by both
  double largest = 0.0;       // the largest |Δ luminance| / luminance of those pixels
  int pixels = 0;
};

Difference compare(const Render& a, const Render& b) {
  Difference d;
  double alphaA = 0.0, alphaB = 0.0, diff = 0.0, sum = 0.0;
  // Both renders use the same camera and world box: the same rectangle.
  EXPECT_EQ(a.x0, b.x0);
  EXPECT_EQ(a.y0, b.y0);
  EXPECT_EQ(a.beauty.width, b.beauty.width);
  EXPECT_EQ(a.beauty.height, b.beauty.height);
  if (a.beauty.pixelCount() != b.beauty.pixelCount()) return d;
  auto luminance = [](const float* p) { return 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]; };
  for (int y = 0; y < a.beauty.height; ++y) {
    for (int x = 0; x < a.beauty.width; ++x) {
      const float* pa = a.beauty.at(x, y);
      const float* pb = b.beauty.at(x, y);
      alphaA += pa[3];
      alphaB += pb[3];
      if (pa[3] < 1.0f || pb[3] < 1.0f) continue;  // silhouette pixels: coverage above
      const double la = luminance(pa), lb = luminance(pb);
      diff += std::abs(la - lb);
      sum += lb;
      d.largest = std::max(d.largest, std::abs(la - lb) / lb);
      ++d.pixels;
    }
  }
  d.coverage = std::abs(alphaA - alphaB) / alphaB;
  d.meanRelative = diff / sum;
  return d;
}

// The tolerances. Both files hold the same vertices, normals and texture coordinates, and
// Blender's glTF exporter splits each quad along its 0-2 diagonal as our OBJ loader does, so the
// only difference is the OBJ's text: 6 decimals, a rounding of up to 5e-7 in every number
// (measured: no sample changes coverage, mean luminance difference 2.5e-5, largest 4.6e-4).
// Coverage: a tenth of a percent of the covered area, a few dozen of the ~80,000 samples falling
// on the other side of a silhouette. Luminance: 0.1 % on average and 1 % at any one pixel,
// twice the effect of the normals' rounding on the cosine at grazing angles and far below what
// a flipped texture gives (16 %) or splitting the textured Suzanne's quads along their other
// diagonal (5 % on average, measured).
constexpr double kCoverageTolerance = 1e-3;
constexpr double kMeanRelativeTolerance = 1e-3;
constexpr double kLargestRelativeTolerance = 1e-2;

TEST(GltfFromBlender, RendersLikeTheSampleObj) {
  const fs::path obj = pipeline::samplesDirectory() / "monkey.obj";
  if (!fs::exists(obj)) GTEST_FAIL() << "sample data missing: " << obj;
  const Mesh fromObj = loadMesh(obj);
  const Mesh fromGlb = loadMesh(kData / "suzanne_clay.glb");
  EXPECT_TRUE(fromObj.normalsFromFile);
  EXPECT_TRUE(fromGlb.normalsFromFile);
  EXPECT_TRUE(fromGlb.warnings.empty()) << fromGlb.warnings[0];
  EXPECT_EQ(fromObj.triangleCount(), fromGlb.triangleCount());
  for (int k = 0; k < 3; ++k) {
    EXPECT_NEAR(fromObj.boundsMin()[k], fromGlb.boundsMin()[k], 1e-5f);
    EXPECT_NEAR(fromObj.boundsMax()[k], fromGlb.boundsMax()[k], 1e-5f);
  }
  // The glTF's material (Blender's linear base colour) against the same colour given as the
  // renderer's albedo for the OBJ, which has no material.
  ASSERT_EQ(fromGlb.materials.size(), 1u);
  EXPECT_EQ(fromGlb.materials[0].name, "Clay");
  const glm::vec3 clay(0.8f, 0.35f, 0.2f);
  EXPECT_LT(glm::length(fromGlb.materials[0].baseColor - clay), 1e-6f);
  RenderSettings withMaterials;
  RenderSettings asAlbedo;
  asAlbedo.albedo = clay;
  asAlbedo.overrideMaterials = true;
  const Difference d =
      compare(render(fromGlb, fromObj, withMaterials), render(fromObj, fromObj, asAlbedo));
  std::printf(
      "sample OBJ vs Blender glTF: coverage %.2e, mean |dL|/L %.2e, largest %.2e over %d "
      "pixels\n",
      d.coverage, d.meanRelative, d.largest, d.pixels);
  EXPECT_GT(d.pixels, 10000);
  EXPECT_LT(d.coverage, kCoverageTolerance);
  EXPECT_LT(d.meanRelative, kMeanRelativeTolerance);
  EXPECT_LT(d.largest, kLargestRelativeTolerance);
}

TEST(GltfFromBlender, TexturedRendersLikeBlendersObjExport) {
  const Mesh fromObj = loadMesh(kData / "suzanne_checker.obj");
  const Mesh fromGlb = loadMesh(kData / "suzanne_checker.glb");
  EXPECT_TRUE(fromObj.warnings.empty()) << fromObj.warnings[0];
  EXPECT_TRUE(fromGlb.warnings.empty()) << fromGlb.warnings[0];
  ASSERT_EQ(fromObj.textures.size(), 1u);
  ASSERT_EQ(fromGlb.textures.size(), 1u);
  EXPECT_EQ(fromObj.materials[0].baseColor, glm::vec3(1.0f)) << "no Kd: the texture alone";
  EXPECT_EQ(fromGlb.materials[0].baseColor, glm::vec3(1.0f));
  const Difference d = compare(render(fromGlb, fromObj, {}), render(fromObj, fromObj, {}));
  std::printf(
      "Blender OBJ vs Blender glTF, textured: coverage %.2e, mean |dL|/L %.2e, largest "
      "%.2e over %d pixels\n",
      d.coverage, d.meanRelative, d.largest, d.pixels);
  EXPECT_GT(d.pixels, 10000);
  EXPECT_LT(d.coverage, kCoverageTolerance);
  EXPECT_LT(d.meanRelative, kMeanRelativeTolerance);
  EXPECT_LT(d.largest, kLargestRelativeTolerance);
  // A texture turned upside down in either loader would swap the checker's colours over much of
  // the head; here it must not: the flipped glTF differs by far more than the tolerance.
  Mesh flipped = fromGlb;
  for (glm::vec2& uv : flipped.texcoords) uv.y = 1.0f - uv.y;
  const Difference wrong = compare(render(flipped, fromObj, {}), render(fromObj, fromObj, {}));
  std::printf("the same with the glTF's texture upside down: mean |dL|/L %.2e\n",
              wrong.meanRelative);
  EXPECT_GT(wrong.meanRelative, 20.0 * kMeanRelativeTolerance);
}

}  // namespace
}  // namespace compose::render
