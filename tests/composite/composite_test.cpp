#include "composite/composite.h"

#include "test_util.h"

namespace compose::composite {
namespace {

TEST(Over, PremultipliedPorterDuff) {
  Image fg(2, 1, 4), bg(2, 1, 3);
  fg.pixels = {0.2f, 0.1f, 0.0f, 0.5f, /* second pixel transparent */ 0, 0, 0, 0};
  bg.pixels = {1.0f, 2.0f, 4.0f, 0.3f, 0.6f, 0.9f};
  const Image out = over(fg, bg);
  ASSERT_EQ(out.channels, 3);
  EXPECT_FLOAT_EQ(out.pixels[0], 0.2f + 1.0f * 0.5f);
  EXPECT_FLOAT_EQ(out.pixels[1], 0.1f + 2.0f * 0.5f);
  EXPECT_FLOAT_EQ(out.pixels[2], 0.0f + 4.0f * 0.5f);
  EXPECT_EQ(out.pixels[3], 0.3f);
  EXPECT_EQ(out.pixels[5], 0.9f);
}

TEST(Over, BackgroundAlphaAccumulates) {
  Image fg(1, 1, 4), bg(1, 1, 4);
  fg.pixels = {0.1f, 0.1f, 0.1f, 0.25f};
  bg.pixels = {0.0f, 0.0f, 0.0f, 0.5f};
  EXPECT_FLOAT_EQ(over(fg, bg).pixels[3], 0.25f + 0.5f * 0.75f);
}

TEST(Over, MismatchesAreErrors) {
  Image fg(2, 2, 4), bg(3, 2, 3);
  COMPOSE_EXPECT_ERROR(over(fg, bg), "size mismatch: foreground is 2x2, background is 3x2");
  Image bg2(2, 2, 3);
  fg.colorSpace = "ACEScg";
  bg2.colorSpace = "sRGB - Texture";
  COMPOSE_EXPECT_ERROR(over(fg, bg2), "colour-space mismatch");
}

}  // namespace
}  // namespace compose::composite

namespace compose::composite {
namespace {

TEST(Over, AForegroundRectangleInsideTheBackground) {
  Image fg(1, 1, 4), bg(3, 2, 3);
  fg.pixels = {0.5f, 0.5f, 0.5f, 1.0f};
  std::fill(bg.pixels.begin(), bg.pixels.end(), 0.25f);
  const Image out = over(fg, 2, 1, bg);
  EXPECT_EQ(out.at(2, 1)[0], 0.5f);
  EXPECT_EQ(out.at(1, 1)[0], 0.25f) << "outside the rectangle the background is unchanged";
  EXPECT_EQ(out.at(2, 0)[0], 0.25f);
  COMPOSE_EXPECT_ERROR(over(fg, 3, 0, bg), "does not lie inside the background");
}

}  // namespace
}  // namespace compose::composite
