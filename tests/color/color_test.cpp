#include "color/color.h"

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "pipeline/compose_job.h"
#include "pipeline/stages.h"
#include "test_util.h"

namespace compose::color {
namespace {

// IEC 61966-2-1 decode, written out independently of OpenColorIO.
double srgbToLinear(double v) {
  return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
}

// OCIO's lossless CPU path evaluates in float: a few float ulps.
constexpr float kFloatTolerance = 2e-6f;

TEST(ColorConfig, BuiltinWorkingSpaceIsAcescg) {
  const ColorConfig c = ColorConfig::builtin();
  EXPECT_EQ(c.source(), "built-in");
  EXPECT_EQ(c.workingSpace(), "ACEScg");
  EXPECT_EQ(c.resolve("srgb_tx", "test"), "sRGB - Texture");
  EXPECT_EQ(c.resolve("lin_rec709", "test"), "Linear Rec.709 (sRGB)");
  EXPECT_EQ(c.defaultDisplay(), "sRGB");
  EXPECT_EQ(c.defaultView("sRGB"), "Standard") << "the default view leaves the plate as it was";
}

TEST(ColorConfig, DecodesSrgbAndConvertsToAcescg) {
  const ColorConfig c = ColorConfig::builtin();
  Image img(3, 1, 4, {"R", "G", "B", "A"});
  const float values[] = {0.0f, 0.5f, 1.0f};
  for (int x = 0; x < 3; ++x) {
    float* p = img.at(x, 0);
    p[0] = values[x], p[1] = values[x], p[2] = values[x], p[3] = 0.25f;
  }
  img.colorSpace = "sRGB";
  Image lin = img;
  c.convert(lin, "lin_rec709");
  EXPECT_EQ(lin.colorSpace, "Linear Rec.709 (sRGB)");
  for (int x = 0; x < 3; ++x) {
    EXPECT_NEAR(lin.at(x, 0)[0], srgbToLinear(values[x]), kFloatTolerance);
    EXPECT_EQ(lin.at(x, 0)[3], 0.25f) << "alpha must pass through";
  }
  // Grey stays grey in ACEScg (the Bradford-adapted matrix maps D65 white to the ACES white).
  Image cg = lin;
  c.convert(cg, "ACEScg");
  EXPECT_NEAR(cg.at(1, 0)[0], lin.at(1, 0)[0], 1e-6f);
  EXPECT_NEAR(cg.at(1, 0)[2], lin.at(1, 0)[0], 1e-6f);
  // A saturated red: first column of the Rec.709 → AP1 matrix.
  Image red(1, 1, 3);
  red.pixels = {1.0f, 0.0f, 0.0f};
  red.colorSpace = "lin_rec709";
  c.convert(red, "ACEScg");
  EXPECT_NEAR(red.pixels[0], 0.6130973f, kFloatTolerance);
  EXPECT_NEAR(red.pixels[1], 0.0701942f, kFloatTolerance);
  EXPECT_NEAR(red.pixels[2], 0.0206156f, kFloatTolerance);
}

// An 8-bit plate converted from its codes (a table for the sRGB curve, then the matrix) gives the
// values the float path gives on code / 255, for every code in every channel, with the codes'
// fourth channel (alpha) skipped and a width that splits into uneven rows.
TEST(ColorConfig, CodesConvertLikeTheirFloats) {
  const ColorConfig c = ColorConfig::builtin();
  for (const int channels : {3, 4}) {
    SCOPED_TRACE(channels);
    const int width = 97, height = 41;  // 3977 pixels: every code in every channel, many times
    std::vector<uint8_t> codes(size_t(width) * height * size_t(channels));
    Image floats(width, height, 3, {"R", "G", "B"});
    floats.colorSpace = "sRGB - Texture";
    for (size_t p = 0; p < size_t(width) * height; ++p) {
      for (int k = 0; k < channels; ++k) {
        // Each channel its own sequence of codes, so that swapped channels would show.
        const auto code = uint8_t((p * (k + 1) * 37 + size_t(k) * 101) % 256);
        codes[p * size_t(channels) + size_t(k)] = code;
        if (k < 3) floats.pixels[p * 3 + size_t(k)] = float(code) / 255.0f;
      }
    }
    const Image fromCodes =
        c.convertCodes(codes, width, height, channels, "srgb_tx", c.workingSpace());
    c.convert(floats, c.workingSpace());
    ASSERT_EQ(fromCodes.width, width);
    ASSERT_EQ(fromCodes.height, height);
    ASSERT_EQ(fromCodes.channels, 3);
    EXPECT_EQ(fromCodes.colorSpace, "ACEScg");
    for (size_t i = 0; i < floats.pixels.size(); ++i)
      ASSERT_NEAR(fromCodes.pixels[i], floats.pixels[i], kFloatTolerance) << i;
    // And against the sRGB curve written out: code 255 in red alone is AP1's share of red.
    const std::vector<uint8_t> red = {255, 0, 0};
    const Image one = c.convertCodes(red, 1, 1, 3, "srgb_tx", "lin_rec709");
    EXPECT_NEAR(one.pixels[0], srgbToLinear(1.0), kFloatTolerance);
    EXPECT_NEAR(one.pixels[1], 0.0, kFloatTolerance);
  }
}

TEST(ColorConfig, DisplayTransformEncodesSrgbAndClips) {
  const ColorConfig c = ColorConfig::builtin();
  Image img(2, 1, 3);
  img.pixels = {0.214041144f, 0.214041144f, 0.214041144f, 4.0f, 4.0f, 4.0f};
  img.colorSpace = "lin_rec709";
  const Image shown = c.toDisplay(img, "sRGB", "Standard");
  EXPECT_NEAR(shown.pixels[0], 0.5f, 1e-5f);
  EXPECT_NEAR(shown.pixels[3], 1.0f, 1e-6f);
  COMPOSE_EXPECT_ERROR(c.toDisplay(img, "P3", "Standard"),
                       "unknown display 'P3'; the config has: sRGB");
  COMPOSE_EXPECT_ERROR(c.toDisplay(img, "sRGB", "Filmic"),
                       "unknown view 'Filmic' for display 'sRGB'");
}

// Soft Clip: the same as Standard up to linear 0.8 (a plate decoded from sRGB keeps its look), a
// shoulder above it (y = t + (1-t) u/(1+u), u = (x-t)/(1-t), t = 0.8) where Standard clips.
TEST(ColorConfig, SoftClipViewRollsHighlightsOffAndKeepsTheRest) {
  const ColorConfig c = ColorConfig::builtin();
  const float in[] = {0.0f, 0.05f, 0.18f, 0.5f, 0.79f, 1.0f, 2.0f, 10.0f, 1000.0f};
  Image img(9, 1, 3);
  for (int i = 0; i < 9; ++i) img.at(i, 0)[0] = img.at(i, 0)[1] = img.at(i, 0)[2] = in[i];
  img.colorSpace = "lin_rec709";
  const Image soft = c.toDisplay(img, "sRGB", "Soft Clip");
  const Image hard = c.toDisplay(img, "sRGB", "Standard");
  auto encode = [](double v) {
    return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
  };
  auto shoulder = [](double x) {
    const double t = 0.8, u = (x - t) / (1 - t);
    return x <= t ? x : t + (1 - t) * u / (1 + u);
  };
  for (int i = 0; i < 9; ++i) {
    const double got = soft.at(i, 0)[0];
    if (in[i] <= 0.8f) {
      // Identical to Standard below the knee: within float and 1e-5 log-offset rounding.
      EXPECT_NEAR(got, hard.at(i, 0)[0], 2e-5) << "input " << in[i];
    } else {
      // The spline follows the shoulder within 0.001 in linear light.
      EXPECT_NEAR(got, encode(shoulder(in[i])), 2e-3) << "input " << in[i];
      EXPECT_LT(got, 1.0f) << "input " << in[i] << " must not clip";
    }
  }
  EXPECT_LT(soft.at(6, 0)[0], soft.at(7, 0)[0]) << "monotonic: 2 shows darker than 10";
}

TEST(ColorConfig, UnknownSpaceListsTheValidOnes) {
  const ColorConfig c = ColorConfig::builtin();
  COMPOSE_EXPECT_ERROR(
      c.resolve("Rec.2020", "--plate-space"),
      "unknown colour space 'Rec.2020' for --plate-space; the config (built-in) has: "
      "Linear Rec.709 (sRGB), ACEScg");
}

TEST(ColorConfig, PicksInputSpacesFromFileDeclarationsAndRules) {
  const ColorConfig c = ColorConfig::builtin();
  EXPECT_EQ(c.inputSpaceFor("plate.jpg", "sRGB"), "sRGB - Texture");
  EXPECT_EQ(c.inputSpaceFor("sky.exr", ""), "Linear Rec.709 (sRGB)");
  EXPECT_EQ(c.inputSpaceFor("plate.png", "no-such-space"), "sRGB - Texture");
}

// A studio config in the style of the ACES cg-config: no 'sRGB' or 'Linear' names, a default
// file rule that says ACES2065-1, and a display-encoded role that is a gamma of 2.2, not sRGB.
constexpr const char* kStudioConfig = R"(ocio_profile_version: 2.1
roles:
  aces_interchange: ACES2065-1
  scene_linear: ACEScg
  data: Raw
  matte_paint: Gamma 2.2 Rec.709
  texture_paint: sRGB - Texture
file_rules:
  - !<Rule> {name: Default, colorspace: ACES2065-1}
displays:
  sRGB - Display:
    - !<View> {name: Raw, colorspace: Raw}
colorspaces:
  - !<ColorSpace>
    name: ACES2065-1
    isdata: false
  - !<ColorSpace>
    name: ACEScg
    isdata: false
    to_scene_reference: !<BuiltinTransform> {style: ACEScg_to_ACES2065-1}
  - !<ColorSpace>
    name: Linear Rec.709
    isdata: false
    to_scene_reference: !<MatrixTransform> {matrix: [0.4397010, 0.3829780, 0.1773350, 0, 0.0897923, 0.8134230, 0.0967616, 0, 0.0175440, 0.1115440, 0.8707040, 0, 0, 0, 0, 1]}
  - !<ColorSpace>
    name: Gamma 2.2 Rec.709
    isdata: false
    to_scene_reference: !<GroupTransform>
      children:
        - !<ExponentTransform> {value: 2.2}
        - !<MatrixTransform> {matrix: [0.4397010, 0.3829780, 0.1773350, 0, 0.0897923, 0.8134230, 0.0967616, 0, 0.0175440, 0.1115440, 0.8707040, 0, 0, 0, 0, 1]}
  - !<ColorSpace>
    name: sRGB - Texture
    isdata: false
    to_scene_reference: !<GroupTransform>
      children:
        - !<ExponentWithLinearTransform> {gamma: 2.4, offset: 0.055}
        - !<MatrixTransform> {matrix: [0.4397010, 0.3829780, 0.1773350, 0, 0.0897923, 0.8134230, 0.0967616, 0, 0.0175440, 0.1115440, 0.8707040, 0, 0, 0, 0, 1]}
  - !<ColorSpace>
    name: Raw
    isdata: true
)";

// 8- and 16-bit images are display-encoded: where the config's rules would make them linear
// (a studio config's default rule), they are read as its sRGB-encoded space, found by what its
// conversion does (the gamma-2.2 role before it is passed over); float images keep linear rules.
TEST(ColorConfig, IntegerImagesAreReadAsSrgbWhereTheRulesMakeThemLinear) {
  compose::testing::TempDir dir;
  const auto file = dir.path() / "studio.ocio";
  compose::testing::writeText(file, kStudioConfig);
  const ColorConfig c = ColorConfig::fromFile(file);
  EXPECT_EQ(c.srgbEncodedSpace(), "sRGB - Texture");
  EXPECT_TRUE(c.isLinearOrData("ACES2065-1"));
  EXPECT_TRUE(c.isLinearOrData("Raw"));
  EXPECT_FALSE(c.isLinearOrData("Gamma 2.2 Rec.709"));
  InputSpace s = c.inputSpace("plate.jpg", "sRGB", true, true);
  EXPECT_EQ(s.space, "sRGB - Texture");
  EXPECT_TRUE(s.assumed);
  EXPECT_NE(s.how.find("default rule gave 'ACES2065-1'"), std::string::npos) << s.how;
  EXPECT_EQ(c.inputSpace("plate.tif", "", false, true).space, "sRGB - Texture");
  s = c.inputSpace("sky.exr", "Linear", true, false);
  EXPECT_EQ(s.space, "ACES2065-1");
  EXPECT_TRUE(s.assumed);
  // What the file says wins, and is no guess.
  s = c.inputSpace("plate.jpg", "Gamma 2.2 Rec.709", false, true);
  EXPECT_EQ(s.space, "Gamma 2.2 Rec.709");
  EXPECT_FALSE(s.assumed);
  EXPECT_EQ(s.how, "as the file says");

  const ColorConfig builtin = ColorConfig::builtin();
  EXPECT_EQ(builtin.srgbEncodedSpace(), "sRGB - Texture");
  EXPECT_EQ(builtin.inputSpace("plate.tif", "", false, true).space, "sRGB - Texture");
  EXPECT_EQ(builtin.inputSpace("sky.exr", "Linear", true, false).space, "Linear Rec.709 (sRGB)");
  // Float samples are linear where the rules would decode them with the sRGB curve (the built-in
  // default rule, for a float TIFF or a PFM: the sky read 555 times too bright); an explicit
  // declaration still wins.
  for (const char* name : {"sky.tif", "sky.pfm"}) {
    s = builtin.inputSpace(name, "", false, false);
    EXPECT_EQ(s.space, "Linear Rec.709 (sRGB)") << name;
    EXPECT_TRUE(s.assumed);
    EXPECT_NE(s.how.find("float samples, taken as linear"), std::string::npos) << s.how;
  }
  EXPECT_EQ(builtin.inputSpace("sky.tif", "sRGB - Texture", false, false).space, "sRGB - Texture");
  // By extension alone a TIFF may be 8-bit or float: the rules decide (an 8-bit texture stays
  // sRGB); a PFM is float.
  EXPECT_EQ(builtin.inputSpaceFor("texture.tif", ""), "sRGB - Texture");
  EXPECT_EQ(builtin.inputSpaceFor("sky.pfm", ""), "Linear Rec.709 (sRGB)");
}

// The built-in config reads photos with a Display P3 or Adobe RGB profile, encoded or linear:
// their reds are Rec.709's reds and more (P3's red in linear Rec.709 is 1.2249, -0.0421,
// -0.0196).
TEST(ColorConfig, DisplayP3AndAdobeRgbPhotos) {
  const ColorConfig c = ColorConfig::builtin();
  for (const auto& [space, expected] : std::vector<std::pair<std::string, glm::vec3>>{
           {"Display P3", {1.2249402f, -0.0420570f, -0.0196376f}},
           {"Adobe RGB (1998)", {1.3983557f, 0.0f, 0.0f}},
           {"Linear P3-D65", {1.2249402f, -0.0420570f, -0.0196376f}},
           {"Linear Adobe RGB (1998)", {1.3983557f, 0.0f, 0.0f}}}) {
    Image red(2, 1, 3, {"R", "G", "B"});
    red.pixels = {1, 0, 0, 0.5f, 0.5f, 0.5f};
    red.colorSpace = space;
    c.convert(red, "Linear Rec.709 (sRGB)");
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(red.pixels[size_t(k)], expected[k], 1e-4) << space;
    // Grey stays grey: 0.5 through the space's curve.
    const float grey = space == "Display P3"         ? 0.2140411f
                       : space == "Adobe RGB (1998)" ? float(std::pow(0.5, 2.19921875))
                                                     : 0.5f;
    for (int k = 3; k < 6; ++k) EXPECT_NEAR(red.pixels[size_t(k)], grey, 1e-4) << space;
  }
}

// Luminance weights from a space's primaries: Rec.709's are the familiar ones; ACEScg's differ,
// so that a grey's luminance is the same number whichever the working space.
TEST(ColorConfig, LumaWeightsFollowThePrimaries) {
  const ColorConfig c = ColorConfig::builtin();
  const glm::dvec3 rec709 = c.lumaWeights("Linear Rec.709 (sRGB)");
  EXPECT_NEAR(rec709.x, 0.2126, 2e-4);
  EXPECT_NEAR(rec709.y, 0.7152, 2e-4);
  EXPECT_NEAR(rec709.z, 0.0722, 2e-4);
  const glm::dvec3 ap1 = c.lumaWeights("ACEScg");
  EXPECT_NEAR(ap1.x, 0.2722, 1e-3);
  EXPECT_NEAR(ap1.y, 0.6741, 1e-3);
  EXPECT_NEAR(ap1.z, 0.0537, 1e-3);
  EXPECT_NEAR(ap1.x + ap1.y + ap1.z, 1.0, 1e-6);
}

TEST(ColorConfig, MissingConfigFileIsAnError) {
  COMPOSE_EXPECT_ERROR(ColorConfig::fromFile("/nonexistent/config.ocio"),
                       "color: OpenColorIO config not found (/nonexistent/config.ocio)");
  // Named by $OCIO: the error says so.
  ::setenv("OCIO", "/nonexistent/config.ocio", 1);
  try {
    ColorConfig::fromEnvironment();
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("named by $OCIO"), std::string::npos) << e.what();
  }
  ::unsetenv("OCIO");
  // A config without scene_linear: the role is named as missing.
  compose::testing::TempDir dir;
  std::string text = kStudioConfig;
  text.erase(text.find("  scene_linear: ACEScg\n"), std::string("  scene_linear: ACEScg\n").size());
  compose::testing::writeText(dir.path() / "c.ocio", text);
  COMPOSE_EXPECT_ERROR(ColorConfig::fromFile(dir.path() / "c.ocio").workingSpace(),
                       "has no scene_linear role");
}

// $OCIO is honoured: a real third-party config (Blender's, from the sample data).
TEST(ColorConfig, HonoursOcioEnvironmentVariable) {
  const auto blender = pipeline::samplesDirectory() / "ocio" / "blender" / "config.ocio";
  if (!std::filesystem::exists(blender)) GTEST_SKIP() << "sample data not fetched: " << blender;
  ::setenv("OCIO", blender.c_str(), 1);
  const ColorConfig c = ColorConfig::fromEnvironment();
  ::unsetenv("OCIO");
  EXPECT_EQ(c.source(), blender.string());
  EXPECT_NE(c.workingSpace(), "ACEScg");  // Blender's scene_linear is linear Rec.709
  Image img(1, 1, 3);
  img.pixels = {0.5f, 0.5f, 0.5f};
  img.colorSpace = "sRGB";
  c.convert(img, c.workingSpace());
  EXPECT_NEAR(img.pixels[0], srgbToLinear(0.5), 1e-3);  // Blender's sRGB may be a LUT: 1e-3
  // A linear ICC profile's space (ingest names it 'Linear Rec.709 (sRGB)', the built-in
  // config's name) is this config's linear Rec.709, not the rules' sRGB.
  const InputSpace linear = c.inputSpace("photo.tif", "Linear Rec.709 (sRGB)", false, true);
  EXPECT_TRUE(c.isLinearOrData(linear.space)) << linear.space;
  EXPECT_FALSE(linear.assumed) << linear.how;
  Image one(1, 1, 3);
  one.pixels = {0.5f, 0.25f, 0.125f};
  one.colorSpace = linear.space;
  c.convert(one, c.workingSpace());
  EXPECT_NEAR(one.pixels[0], 0.5f, 1e-3);
  EXPECT_NEAR(one.pixels[2], 0.125f, 1e-3);
  // The built-in config knows the name itself.
  const ColorConfig builtin = ColorConfig::builtin();
  EXPECT_TRUE(builtin.isLinearOrData(
      builtin.inputSpace("photo.tif", "Linear Rec.709 (sRGB)", false, true).space));
  // Its 'XYZ' (CIE XYZ of D65 white, adapted to the ACES white through its interchange role) has
  // the chromaticities of XYZ itself: the identity matrix, so that a reader of an EXR written in
  // it (--exr-space XYZ) takes the values for XYZ. Rec.709's white there is D65's XYZ.
  const std::optional<Chromaticities> xyz = c.chromaticities("XYZ");
  ASSERT_TRUE(xyz.has_value());
  const double want[8] = {1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0 / 3.0, 1.0 / 3.0};
  for (int i = 0; i < 8; ++i) EXPECT_NEAR((*xyz)[size_t(i)], want[i], 1e-6) << i;
  Image white(1, 1, 3);
  white.pixels = {1.0f, 1.0f, 1.0f};
  white.colorSpace = linear.space;
  c.convert(white, "XYZ");
  EXPECT_NEAR(white.pixels[0], 0.9505f, 2e-3);
  EXPECT_NEAR(white.pixels[1], 1.0f, 2e-3);
  EXPECT_NEAR(white.pixels[2], 1.089f, 2e-3);
}

}  // namespace
}  // namespace compose::color

namespace compose::color {
namespace {

void expectChromaticities(const std::optional<Chromaticities>& got, const Chromaticities& want) {
  ASSERT_TRUE(got.has_value());
  for (size_t i = 0; i < want.size(); ++i) EXPECT_NEAR((*got)[i], want[i], 1e-6) << "entry " << i;
}

TEST(Chromaticities, OfTheBuiltinSpacesThroughTheInterchangeRole) {
  const ColorConfig c = ColorConfig::builtin();
  expectChromaticities(c.chromaticities("ACEScg"), kAcesAp1Chromaticities);
  expectChromaticities(c.chromaticities("lin_rec709"), kRec709Chromaticities);
  expectChromaticities(c.chromaticities("ACES2065-1"), kAcesAp0Chromaticities);
  EXPECT_FALSE(c.chromaticities("sRGB - Texture").has_value()) << "an encoded space is not linear";
  EXPECT_FALSE(c.chromaticities("Raw").has_value());
  EXPECT_EQ(c.spaceWithChromaticities(kAcesAp1Chromaticities), "ACEScg");
  EXPECT_EQ(c.spaceWithChromaticities(kRec709Chromaticities), "Linear Rec.709 (sRGB)");
  Chromaticities odd = kRec709Chromaticities;
  odd[0] = 0.66;
  EXPECT_EQ(c.spaceWithChromaticities(odd), "");
}

// An encoded space's linear counterpart is the linear space of its primaries: what an 8-bit
// photo's camera RGB is once its response is undone (Display P3 photos were taken as Rec.709's).
TEST(Chromaticities, AnEncodedSpacesLinearSpaceHasItsPrimaries) {
  const ColorConfig c = ColorConfig::builtin();
  EXPECT_EQ(c.linearSpaceWithPrimariesOf("sRGB - Texture"), "Linear Rec.709 (sRGB)");
  EXPECT_EQ(c.linearSpaceWithPrimariesOf("ACEScg"), "ACEScg");
  EXPECT_EQ(c.linearSpaceWithPrimariesOf("Raw"), "");
  const std::string p3 = c.linearSpaceWithPrimariesOf("Display P3");
  ASSERT_FALSE(p3.empty());
  EXPECT_TRUE(c.samePrimaries("Display P3", p3));
  EXPECT_FALSE(c.samePrimaries("Display P3", "Linear Rec.709 (sRGB)"));
  EXPECT_FALSE(c.samePrimaries("sRGB - Texture", "ACEScg"));
}

TEST(Chromaticities, OfAThirdPartyConfig) {
  const auto file = pipeline::samplesDirectory() / "ocio" / "blender" / "config.ocio";
  if (!std::filesystem::exists(file)) GTEST_FAIL() << "sample data missing: " << file;
  const ColorConfig c = ColorConfig::fromFile(file);
  expectChromaticities(c.chromaticities("Linear"), kRec709Chromaticities);
  expectChromaticities(c.chromaticities("Linear ACEScg"), kAcesAp1Chromaticities);
}

// An OCIO v1 config (nuke-default, ACES 1.x) has no interchange role: it says no primaries.
// Its linear spaces of the usual names are known by them, so that an OpenEXR with
// chromaticities (compose's own output among them) is read; a space of another name cannot be.
std::string v1Config(const std::string& linearName) {
  return "ocio_profile_version: 1\nroles:\n  default: raw\n  reference: raw\n  data: raw\n"
         "  scene_linear: " +
         linearName +
         "\n  texture_paint: sRGB\ndisplays:\n  default:\n"
         "    - !<View> {name: sRGB, colorspace: sRGB}\ncolorspaces:\n"
         "  - !<ColorSpace>\n    name: " +
         linearName +
         "\n    isdata: false\n  - !<ColorSpace>\n    name: sRGB\n    isdata: false\n"
         "    to_reference: !<ExponentTransform> {value: [2.2, 2.2, 2.2, 1]}\n"
         "  - !<ColorSpace>\n    name: raw\n    isdata: true\n";
}

TEST(Chromaticities, OfAConfigThatSaysNoPrimariesByTheirNames) {
  compose::testing::TempDir dir;
  compose::testing::writeText(dir / "nuke.ocio", v1Config("linear"));
  const ColorConfig c = ColorConfig::fromFile(dir / "nuke.ocio");
  expectChromaticities(c.chromaticities("linear"), kRec709Chromaticities);
  EXPECT_FALSE(c.chromaticities("sRGB").has_value());
  EXPECT_EQ(c.spaceWithChromaticities(kRec709Chromaticities), "linear");
  EXPECT_EQ(c.spaceWithChromaticities(kAcesAp1Chromaticities), "");

  // ACEScg pixels with their chromaticities, as compose writes them: converted by matrix.
  const ColorConfig builtin = ColorConfig::builtin();
  Image ap1(2, 1, 3, {"R", "G", "B"});
  const float px[6] = {0.2f, 0.5f, 0.9f, 3.0f, 0.01f, 0.4f};
  std::copy(px, px + 6, ap1.pixels.begin());
  ap1.colorSpace = "ACEScg";
  Image expected = ap1;
  builtin.convert(expected, "Linear Rec.709 (sRGB)");
  ingest::CaptureInfo info;
  info.chromaticities = kAcesAp1Chromaticities;
  Image read = ap1;
  const std::string how =
      pipeline::toWorkingSpace(read, dir / "plate.exr", info, "", "--plate-space", c);
  EXPECT_NE(how.find("chromaticities"), std::string::npos) << how;
  for (size_t i = 0; i < 6; ++i)
    EXPECT_NEAR(read.pixels[i], expected.pixels[i], 2e-4 * (1 + std::abs(expected.pixels[i])));

  // A working space of no usual name: the file and the option that says its space.
  compose::testing::writeText(dir / "studio.ocio", v1Config("lnf"));
  const ColorConfig studio = ColorConfig::fromFile(dir / "studio.ocio");
  read = ap1;
  COMPOSE_EXPECT_ERROR(
      pipeline::toWorkingSpace(read, dir / "plate.exr", info, "", "--plate-space", studio),
      "give --plate-space to say its space (" + (dir / "plate.exr").string() + ")");
  read = ap1;
  EXPECT_EQ(pipeline::toWorkingSpace(read, dir / "plate.exr", info, "lnf", "--plate-space", studio),
            "'lnf' (--plate-space)");
}

// The space a format implies (OpenImageIO's 'Linear' for every OpenEXR) gives way to a file rule
// of the config's own: a config that reads OpenEXRs as ACEScg means it, even where it also knows
// a space called 'Linear'. What a file declares itself still wins.
TEST(ColorConfig, AFileRuleOfTheConfigsOwnWinsOverTheFormatsUsualSpace) {
  compose::testing::TempDir dir;
  compose::testing::writeText(dir / "c.ocio", R"(ocio_profile_version: 2.1
roles:
  aces_interchange: ACES2065-1
  scene_linear: ACEScg
  data: Raw
file_rules:
  - !<Rule> {name: OpenEXR, pattern: "*", extension: "exr", colorspace: ACEScg}
  - !<Rule> {name: Default, colorspace: Raw}
displays:
  sRGB:
    - !<View> {name: Raw, colorspace: Raw}
colorspaces:
  - !<ColorSpace>
    name: ACES2065-1
  - !<ColorSpace>
    name: ACEScg
    to_scene_reference: !<BuiltinTransform> {style: ACEScg_to_ACES2065-1}
  - !<ColorSpace>
    name: Linear Rec.709
    aliases: [Linear, linear]
    to_scene_reference: !<MatrixTransform> {matrix: [0.4397010, 0.3829780, 0.1773350, 0, 0.0897923, 0.8134230, 0.0967616, 0, 0.0175440, 0.1115440, 0.8707040, 0, 0, 0, 0, 1]}
  - !<ColorSpace>
    name: Raw
    isdata: true
)");
  const ColorConfig c = ColorConfig::fromFile(dir / "c.ocio");
  InputSpace s = c.inputSpace("sky.exr", "Linear", /*declaredByConvention=*/true, false);
  EXPECT_EQ(s.space, "ACEScg");
  EXPECT_EQ(s.how, "the config's file rule for it");
  s = c.inputSpace("sky.exr", "Linear", /*declaredByConvention=*/false, false);
  EXPECT_EQ(s.space, "Linear Rec.709");
  EXPECT_EQ(s.how, "as the file says");
}

TEST(Chromaticities, ConversionAgreesWithTheConfigsOwn) {
  const ColorConfig c = ColorConfig::builtin();
  Image a(2, 1, 3, {"R", "G", "B"});
  const float px[6] = {0.2f, 0.5f, 0.9f, 3.0f, 0.01f, 0.4f};
  std::copy(px, px + 6, a.pixels.begin());
  a.colorSpace = "lin_rec709";
  Image b = a;
  c.convert(a, "ACEScg");
  c.convertFromChromaticities(b, kRec709Chromaticities, "ACEScg");
  EXPECT_EQ(b.colorSpace, "ACEScg");
  // The config's matrix is printed to 7 digits: agreement to ~1e-6 relative.
  for (size_t i = 0; i < 6; ++i) EXPECT_NEAR(a.pixels[i], b.pixels[i], 2e-6 * (1 + a.pixels[i]));
}

// CIE XYZ as OpenEXR tags it (red 1,0, green 0,1, blue 0,0, white E): its X and Z primaries have
// y = 0, and the primary matrix divided by it (every pixel NaN, the JPEG black, exit 0). The
// expected ACEScg value is the textbook one: Bradford from E to the ACES white, then the inverse
// of AP1's normalised primary matrix (SMPTE RP 177), computed apart with numpy. Chromaticities
// that describe no space are an error naming the file.
TEST(Chromaticities, CieXyzConvertsAndDegenerateOnesAreErrors) {
  const ColorConfig c = ColorConfig::builtin();
  const Chromaticities xyz = {1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0 / 3.0, 1.0 / 3.0};
  EXPECT_EQ(chromaticitiesProblem(xyz), "");
  Image a(2, 1, 3, {"R", "G", "B"});
  const float px[6] = {0.4f, 0.5f, 0.6f, 0.25f, 0.25f, 0.25f};
  std::copy(px, px + 6, a.pixels.begin());
  c.convertFromChromaticities(a, xyz, "ACEScg");
  EXPECT_NEAR(a.pixels[0], 0.31794096, 1e-5);
  EXPECT_NEAR(a.pixels[1], 0.57087344, 1e-5);
  EXPECT_NEAR(a.pixels[2], 0.59844799, 1e-5);
  for (size_t i = 3; i < 6; ++i) EXPECT_NEAR(a.pixels[i], 0.25f, 1e-6) << "white stays white";
  const Chromaticities zeros{};
  const Chromaticities equal = {0.3, 0.6, 0.3, 0.6, 0.3, 0.6, 0.3127, 0.329};
  const Chromaticities flatWhite = {0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.0};
  for (const Chromaticities& bad : {zeros, equal, flatWhite}) {
    EXPECT_NE(chromaticitiesProblem(bad), "");
    Image b = a;
    try {
      c.convertFromChromaticities(b, bad, "ACEScg", "plate.exr");
      ADD_FAILURE() << "converted by chromaticities that describe no space";
    } catch (const Error& e) {
      EXPECT_EQ(e.file(), "plate.exr");
      EXPECT_NE(std::string(e.what()).find("describe no RGB space"), std::string::npos) << e.what();
    }
  }
}

// A LUT the config names, edited in place (its time stamp even put back): the config's identity,
// which keys the caches, changes with it (OpenColorIO's own cache ID does not), and stays the same
// while nothing changes. The LUT sits in a group and in a look, where it is found too.
TEST(ColorConfig, IdentityChangesWhenALutTheConfigNamesIsEdited) {
  compose::testing::TempDir dir;
  compose::testing::writeText(dir / "c.ocio", R"(ocio_profile_version: 2.1
search_path: luts
roles:
  scene_linear: linear
  data: Raw
file_rules:
  - !<Rule> {name: Default, colorspace: linear}
displays:
  sRGB:
    - !<View> {name: Raw, colorspace: Raw}
looks:
  - !<Look>
    name: grade
    process_space: linear
    transform: !<FileTransform> {src: grade.spi1d}
colorspaces:
  - !<ColorSpace>
    name: linear
  - !<ColorSpace>
    name: camera
    to_scene_reference: !<GroupTransform>
      children:
        - !<MatrixTransform> {}
        - !<FileTransform> {src: cam.spi1d, interpolation: linear}
  - !<ColorSpace>
    name: Raw
    isdata: true
)");
  auto lut = [](double power) {
    std::string text = "Version 1\nFrom 0 1\nLength 16\nComponents 1\n{\n";
    char line[32];
    for (int i = 0; i < 16; ++i) {
      std::snprintf(line, sizeof line, "  %.6f\n", std::pow(i / 15.0, power));
      text += line;
    }
    return text + "}\n";
  };
  std::filesystem::create_directories(dir / "luts");
  compose::testing::writeText(dir / "luts" / "cam.spi1d", lut(2.2));
  compose::testing::writeText(dir / "luts" / "grade.spi1d", lut(1.0));
  const std::string first = ColorConfig::fromFile(dir / "c.ocio").identity();
  EXPECT_EQ(ColorConfig::fromFile(dir / "c.ocio").identity(), first);
  for (const char* name : {"cam.spi1d", "grade.spi1d"}) {
    const auto stamp = std::filesystem::last_write_time(dir / "luts" / name);
    compose::testing::writeText(dir / "luts" / name, lut(1.8));
    std::filesystem::last_write_time(dir / "luts" / name, stamp);
    EXPECT_NE(ColorConfig::fromFile(dir / "c.ocio").identity(), first) << name;
    compose::testing::writeText(dir / "luts" / name,
                                name == std::string("cam.spi1d") ? lut(2.2) : lut(1.0));
    std::filesystem::last_write_time(dir / "luts" / name, stamp);
    EXPECT_EQ(ColorConfig::fromFile(dir / "c.ocio").identity(), first) << name;
  }
}

}  // namespace
}  // namespace compose::color
