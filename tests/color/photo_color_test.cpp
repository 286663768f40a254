// Colour for the photo stages: 8-bit sRGB codes survive the trip into the working space and back.
#include <cmath>
#include <random>

#include "color/color.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::color {
namespace {

// Half an 8-bit step (pbrt's 0.501/255 for 8-bit round trips), in encoded units.
constexpr float kHalfStep = 0.501f / 255.0f;

// Every grey code, and random colours, as a photo's sRGB values (code / 255).
Image srgbCodes() {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> code(0, 255);
  Image img(256, 17, 3);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x)
      for (int c = 0; c < 3; ++c) img.at(x, y)[c] = float(y == 0 ? x : code(rng)) / 255.0f;
  img.colorSpace = "sRGB";
  return img;
}

void expectRoundTrip(const ColorConfig& colors, const std::string& srgbName) {
  Image img = srgbCodes();
  img.colorSpace = srgbName;
  const Image original = img;
  colors.convert(img, colors.workingSpace());
  EXPECT_EQ(img.colorSpace, colors.workingSpace());
  colors.convert(img, srgbName);
  float worst = 0.0f;
  for (size_t i = 0; i < img.pixels.size(); ++i)
    worst = std::max(worst, std::abs(img.pixels[i] - original.pixels[i]));
  EXPECT_LE(worst, kHalfStep) << colors.source() << ": worst " << worst * 255.0f << " codes";
  // Requantised, every code comes back exactly.
  for (size_t i = 0; i < img.pixels.size(); ++i)
    ASSERT_EQ(std::lround(img.pixels[i] * 255.0f), std::lround(original.pixels[i] * 255.0f));
}

TEST(PhotoColor, SrgbCodesRoundTripThroughTheWorkingSpaceWithinHalfAStep) {
  expectRoundTrip(ColorConfig::builtin(), "sRGB");
}

TEST(PhotoColor, AlsoThroughBlendersConfig) {
  const auto file = pipeline::samplesDirectory() / "ocio" / "blender" / "config.ocio";
  if (!std::filesystem::exists(file)) GTEST_SKIP() << "Blender's OCIO config not fetched";
  expectRoundTrip(ColorConfig::fromFile(file), "sRGB");
}

}  // namespace
}  // namespace compose::color
