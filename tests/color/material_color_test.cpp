// The object's material colours reach the renderer in the working space
// (pipeline/materials.h): base colours as linear Rec.709, textures as their files declare.
#include <cmath>

#include "color/color.h"
#include "pipeline/compose_job.h"
#include "pipeline/materials.h"
#include "render/mesh.h"
#include "test_util.h"

namespace compose::pipeline {
namespace {

// Linear Rec.709 to ACEScg (AP1), Bradford adaptation D65 → ACES white, as published with ACES
// (rows).
constexpr double kRec709ToAp1[3][3] = {{0.6130974, 0.3395231, 0.0473795},
                                       {0.0701937, 0.9163539, 0.0134524},
                                       {0.0206156, 0.1095698, 0.8698146}};

glm::vec3 toAp1(const glm::vec3& c) {
  glm::vec3 out;
  for (int r = 0; r < 3; ++r)
    out[r] = float(kRec709ToAp1[r][0] * c.x + kRec709ToAp1[r][1] * c.y + kRec709ToAp1[r][2] * c.z);
  return out;
}

// The sRGB decoding (IEC 61966-2-1).
float srgbDecodeFloat(float v) {
  return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
}

render::Mesh twoMaterials() {
  render::Mesh mesh;
  mesh.materials.resize(2);
  mesh.materials[0].baseColor = glm::vec3(1.0f, 0.0f, 0.0f);
  mesh.materials[1].baseColor = glm::vec3(0.2f, 0.4f, 0.6f);
  mesh.materials[1].texture = 0;
  render::Texture texture;
  texture.file = "wood.png";
  texture.image = Image(1, 1, 3, {"R", "G", "B"});
  texture.image.pixels = {0.5f, 0.25f, 1.0f};
  texture.image.colorSpace = "sRGB";
  mesh.textures.push_back(texture);
  return mesh;
}

// Tolerance: the published matrix has 7 digits and configs adapt the white in slightly
// different ways; 1e-3 is a tenth of what a missed conversion (or one applied twice) changes.
constexpr float kTolerance = 1e-3f;

// A float texture is an albedo like a base colour: what lies outside 0..1 is clamped and counted,
// a value that is not a number becomes 0 (it reached the composite as NaN, a huge one as
// infinity).
TEST(MaterialColour, FloatTexturesAreClampedToAlbedos) {
  const color::ColorConfig colors = color::ColorConfig::builtin();
  render::Mesh mesh = twoMaterials();
  render::Texture& t = mesh.textures[0];
  t.file = "paint.exr";
  t.image = Image(2, 1, 3, {"R", "G", "B"});
  t.image.pixels = {0.5f, 0.5f, 0.5f, 3.4e38f, -2.0f, std::nanf("")};
  t.image.colorSpace = "lin_rec709";
  const std::string line = materialsToWorkingSpace(mesh, colors);
  for (const float v : t.image.pixels) {
    EXPECT_GE(v, 0.0f);
    EXPECT_LE(v, 1.0f);
  }
  EXPECT_NEAR(t.image.pixels[0], 0.5f, kTolerance) << "grey stays grey";
  EXPECT_NE(line.find("; 3 texture values outside 0..1 clamped"), std::string::npos) << line;
  // An 8-bit texture in range is left alone, and nothing is said.
  render::Mesh plain = twoMaterials();
  EXPECT_EQ(materialsToWorkingSpace(plain, colors).find("clamped"), std::string::npos);
}

// The note says which materials let light through, and how.
TEST(MaterialColour, TheNoteNamesCutOutsAndSemiTransparentMaterials) {
  const color::ColorConfig colors = color::ColorConfig::builtin();
  render::Mesh mesh = twoMaterials();
  mesh.materials[0].alphaCutoff = 0.5f;
  mesh.materials[1].blend = true;
  const std::string line = materialsToWorkingSpace(mesh, colors);
  EXPECT_NE(line.find("; 1 is cut out where alpha is below the cutoff (MASK)"), std::string::npos)
      << line;
  EXPECT_NE(line.find("; 1 is semi-transparent (BLEND): seen through and from both sides"),
            std::string::npos)
      << line;
}

TEST(MaterialColour, BaseColoursAndTexturesGoToTheWorkingSpace) {
  const color::ColorConfig colors = color::ColorConfig::builtin();
  render::Mesh mesh = twoMaterials();
  mesh.textures[0].srgbByFormat = true;  // a glTF base colour texture
  const std::string line = materialsToWorkingSpace(mesh, colors);
  EXPECT_NE(line.find("2 materials, base colours read as 'Linear Rec.709"), std::string::npos)
      << line;
  EXPECT_NE(line.find("1 texture (1 as 'sRGB"), std::string::npos) << line;
  EXPECT_NE(line.find("converted to 'ACEScg'"), std::string::npos) << line;
  EXPECT_EQ(line.find("MASK"), std::string::npos) << line;
  // glTF multiplies factor x texture x vertex colour in linear Rec.709: the base colours stay
  // there, the texture is decoded into it, and the product goes to ACEScg by the matrix. (Each
  // converted on its own, the product of a texture's pure red under a factor of (0.2, 0.4, 0.8)
  // was 60 % too bright.)
  ASSERT_TRUE(mesh.convertsAlbedo);
  for (int m = 0; m < 2; ++m)
    EXPECT_EQ(mesh.materials[size_t(m)].baseColor, twoMaterials().materials[size_t(m)].baseColor);
  const glm::vec3 decoded(srgbDecodeFloat(0.5f), srgbDecodeFloat(0.25f), srgbDecodeFloat(1.0f));
  const float* p = mesh.textures[0].image.pixels.data();
  EXPECT_LT(glm::length(glm::vec3(p[0], p[1], p[2]) - decoded), kTolerance);
  for (const glm::vec3& rec709 :
       {glm::vec3(1.0f, 0.0f, 0.0f), glm::vec3(0.2f, 0.4f, 0.6f) * decoded,
        glm::vec3(0.2f, 0.4f, 0.8f) * glm::vec3(1.0f, 0.0f, 0.0f)}) {
    EXPECT_LT(glm::length(mesh.albedoToWorking * rec709 - toAp1(rec709)), kTolerance);
  }
  // A second call converts nothing twice.
  const render::Mesh once = mesh;
  materialsToWorkingSpace(mesh, colors);
  EXPECT_EQ(mesh.materials[1].baseColor, once.materials[1].baseColor);
  EXPECT_EQ(mesh.textures[0].image.pixels, once.textures[0].image.pixels);
  EXPECT_EQ(mesh.albedoToWorking, once.albedoToWorking);
}

TEST(MaterialColour, ATextureThatDeclaresNothingFollowsTheFileRules) {
  const color::ColorConfig colors = color::ColorConfig::builtin();
  render::Mesh mesh = twoMaterials();
  mesh.textures[0].image.colorSpace.clear();
  mesh.textures[0].file = "albedo.exr";  // the built-in rules: .exr is linear Rec.709
  const std::string line = materialsToWorkingSpace(mesh, colors);
  EXPECT_NE(line.find("1 texture (1 as 'Linear Rec.709"), std::string::npos) << line;
  // Linear Rec.709, the base colours' space: the product is taken there, the texel as stored.
  EXPECT_TRUE(mesh.convertsAlbedo);
  const float* p = mesh.textures[0].image.pixels.data();
  EXPECT_LT(glm::length(glm::vec3(p[0], p[1], p[2]) - glm::vec3(0.5f, 0.25f, 1.0f)), kTolerance);
}

// An OBJ's map_Kd in sRGB has the base colours' primaries: Kd x texture is multiplied in linear
// Rec.709, as glTF's product is (each converted to ACEScg on its own, Kd (0.2, 0.4, 0.8) over a
// pure red texel gave (0.291, 0.008, 0.010) in Rec.709, not (0.2, 0, 0); and one such texture
// in a file moved the colours of every material). A texture of wider primaries is converted on
// its own, so that the clamp to 0..1 does not cut its gamut.
TEST(MaterialColour, ATextureOfTheBaseColoursPrimariesMultipliesThere) {
  const color::ColorConfig colors = color::ColorConfig::builtin();
  render::Mesh mesh = twoMaterials();  // wood.png, sRGB, not sRGB by its format
  mesh.materials[1].baseColor = glm::vec3(0.2f, 0.4f, 0.8f);
  mesh.textures[0].image.pixels = {1.0f, 0.0f, 0.0f};
  materialsToWorkingSpace(mesh, colors);
  ASSERT_TRUE(mesh.convertsAlbedo);
  const float* p = mesh.textures[0].image.pixels.data();
  const glm::vec3 product = mesh.materials[1].baseColor * glm::vec3(p[0], p[1], p[2]);
  EXPECT_LT(glm::length(mesh.albedoToWorking * product - toAp1({0.2f, 0.0f, 0.0f})), kTolerance);
  // The untextured material's colour is Kd alone, however the others are textured.
  EXPECT_LT(
      glm::length(mesh.albedoToWorking * mesh.materials[0].baseColor - toAp1({1.0f, 0.0f, 0.0f})),
      kTolerance);

  render::Mesh wide = twoMaterials();
  wide.textures[0].file = "paint.exr";
  wide.textures[0].image.colorSpace = "ACEScg";
  materialsToWorkingSpace(wide, colors);
  EXPECT_FALSE(wide.convertsAlbedo);
  const float* w = wide.textures[0].image.pixels.data();
  EXPECT_LT(glm::length(glm::vec3(w[0], w[1], w[2]) - glm::vec3(0.5f, 0.25f, 1.0f)), kTolerance);
  EXPECT_LT(glm::length(wide.materials[1].baseColor - toAp1({0.2f, 0.4f, 0.6f})), kTolerance);
}

TEST(MaterialColour, AMeshWithoutMaterialsIsLeftAlone) {
  render::Mesh mesh;
  EXPECT_EQ(materialsToWorkingSpace(mesh, color::ColorConfig::builtin()), "");
  EXPECT_EQ(mesh.colorSpace, "lin_rec709");
}

TEST(MaterialColour, BlendersConfigWorksInLinearRec709) {
  const auto file = samplesDirectory() / "ocio" / "blender" / "config.ocio";
  if (!std::filesystem::exists(file)) GTEST_FAIL() << "sample data missing: " << file;
  const color::ColorConfig colors = color::ColorConfig::fromFile(file);
  render::Mesh mesh = twoMaterials();
  const std::string line = materialsToWorkingSpace(mesh, colors);
  // Blender's working space is linear Rec.709 itself: the base colours stay as they are, the
  // texture is only decoded.
  EXPECT_LT(glm::length(mesh.materials[1].baseColor - glm::vec3(0.2f, 0.4f, 0.6f)), kTolerance)
      << line;
  const float* p = mesh.textures[0].image.pixels.data();
  EXPECT_LT(glm::length(glm::vec3(p[0], p[1], p[2]) -
                        glm::vec3(srgbDecodeFloat(0.5f), srgbDecodeFloat(0.25f), 1.0f)),
            kTolerance)
      << line;
}

}  // namespace
}  // namespace compose::pipeline
