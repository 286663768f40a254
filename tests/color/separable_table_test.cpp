#include "color/separable_table.h"

#include <atomic>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "color/color.h"
#include "test_util.h"

namespace compose::color {
namespace {

// An AP1-to-Rec.709-like matrix with an offset, and the sRGB encoding with a clip to [0, 1].
constexpr SeparableTable::Matrix kMatrix = {1.705,  -0.622, -0.083, 0.0,    -0.130, 1.141,
                                            -0.011, 0.001,  -0.024, -0.129, 1.153,  0.0};

double encode(double v) {
  v = std::clamp(v, 0.0, 1.0);
  return v <= 0.0031308 ? 12.92 * v : 1.055 * std::pow(v, 1.0 / 2.4) - 0.055;
}

void encodeAll(float* rgb, int64_t count) {
  for (int64_t i = 0; i < 3 * count; ++i) rgb[i] = float(encode(rgb[i]));
}

void exactPixel(float* rgb) {
  const float r = rgb[0], g = rgb[1], b = rgb[2];
  for (int c = 0; c < 3; ++c) {
    const double* m = &kMatrix[size_t(4 * c)];
    rgb[c] = float(encode(m[0] * r + m[1] * g + m[2] * b + m[3]));
  }
}

// Values across the whole range a frame holds: lognormal radiance, both signs, zero, the grid's
// own points and its edges, values beyond it, infinities and NaN.
Image wideRangeImage(int width, int height) {
  Image image(width, height, 4);
  std::mt19937 rng(5);
  std::lognormal_distribution<float> radiance(-2.0f, 2.5f);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  const float special[] = {0.0f,
                           -0.0f,
                           0x1p-24f,
                           0x1p-14f,
                           0.0031308f,
                           1.0f,
                           65535.0f,
                           65536.0f,
                           1e30f,
                           std::numeric_limits<float>::infinity(),
                           -std::numeric_limits<float>::infinity(),
                           std::numeric_limits<float>::quiet_NaN()};
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    if (i % 4 == 3) {
      image.pixels[i] = 0.5f;  // alpha: never touched
    } else if (i % 97 == 0) {
      image.pixels[i] = special[(i / 97) % std::size(special)];
    } else {
      image.pixels[i] = (unit(rng) < 0.1f ? -0.01f : 1.0f) * radiance(rng);
    }
  }
  return image;
}

TEST(SeparableTable, AgreesWithTheTransformItTabulates) {
  const std::optional<SeparableTable> table = SeparableTable::build(kMatrix, encodeAll, 2e-5);
  ASSERT_TRUE(table);
  EXPECT_EQ(table->exactIntervals(), 0) << "the clip at 1 and 0 falls on grid points";
  const Image in = wideRangeImage(300, 200);
  Image fast = in;
  std::atomic<int64_t> exactCalls{0};
  const int64_t reported = table->apply(fast, [&](float* rgb) {
    ++exactCalls;
    exactPixel(rgb);
  });
  EXPECT_EQ(reported, exactCalls.load());
  EXPECT_GT(reported, 0) << "the image holds values beyond the grid";
  EXPECT_LT(reported, in.width * in.height / 20);
  double worst = 0.0;
  for (int y = 0; y < in.height; ++y) {
    for (int x = 0; x < in.width; ++x) {
      float want[3] = {in.at(x, y)[0], in.at(x, y)[1], in.at(x, y)[2]};
      exactPixel(want);
      for (int c = 0; c < 3; ++c) {
        const float got = fast.at(x, y)[c];
        if (std::isnan(want[c])) {
          EXPECT_TRUE(std::isnan(got)) << x << "," << y;
          continue;
        }
        worst = std::max(worst, std::abs(double(got) - want[c]));
      }
      ASSERT_EQ(fast.at(x, y)[3], 0.5f);
    }
  }
  EXPECT_LE(worst, 2e-5) << "a two-hundredth of an 8-bit step";
  std::printf("table against the exact transform: largest difference %.2e\n", worst);
}

// A kink between grid points (a clip at 0.3) cannot be interpolated: its interval is left to the
// exact transform, and values there come out exact.
TEST(SeparableTable, AKinkBetweenGridPointsIsLeftToTheExactTransform) {
  auto clip = [](float* rgb, int64_t count) {
    for (int64_t i = 0; i < 3 * count; ++i) rgb[i] = std::min(rgb[i], 0.3f);
  };
  const SeparableTable::Matrix identity = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
  const std::optional<SeparableTable> table = SeparableTable::build(identity, clip, 1e-7);
  ASSERT_TRUE(table);
  EXPECT_EQ(table->exactIntervals(), 3) << "one interval per channel, positive side";
  Image image(3, 1, 3);
  image.pixels = {0.29995f, 0.29995f, 0.29995f, 0.30005f, 0.30005f, 0.30005f, 0.25f, 0.5f, 0.3f};
  int calls = 0;
  table->apply(image, [&](float* rgb) {
    ++calls;
    for (int c = 0; c < 3; ++c) rgb[c] = std::min(rgb[c], 0.3f);
  });
  EXPECT_EQ(calls, 2) << "the two pixels inside the kink's interval";
  EXPECT_EQ(image.pixels[0], 0.29995f);
  EXPECT_EQ(image.pixels[3], 0.3f);
  EXPECT_NEAR(image.pixels[6], 0.25f, 1e-7f);
  EXPECT_NEAR(image.pixels[7], 0.3f, 1e-7f);
}

// A curve no table of this grid can follow gets none.
TEST(SeparableTable, ACurveTheGridCannotFollowGetsNoTable) {
  auto jagged = [](float* rgb, int64_t count) {
    for (int64_t i = 0; i < 3 * count; ++i) rgb[i] = std::sin(1e6f * rgb[i]);
  };
  const SeparableTable::Matrix identity = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
  EXPECT_FALSE(SeparableTable::build(identity, jagged, 2e-5));
}

// The built-in views through ColorConfig::toDisplay: a frame large enough for the table agrees
// with the same pixels transformed a row at a time (too few for a table: OpenColorIO itself).
TEST(SeparableTable, DisplayViewsOfTheBuiltinConfigAgreeWithOpenColorIO) {
  const ColorConfig config = ColorConfig::builtin();
  Image frame = wideRangeImage(512, 512);
  frame.colorSpace = "ACEScg";
  for (const char* view : {"Soft Clip", "Standard"}) {
    const Image fast = config.toDisplay(frame, "sRGB", view);
    double worst = 0.0;
    for (int y = 0; y < frame.height; y += 7) {
      Image row(frame.width, 1, 4);
      std::copy(frame.row(y).begin(), frame.row(y).end(), row.pixels.begin());
      row.colorSpace = frame.colorSpace;
      const Image exact = config.toDisplay(row, "sRGB", view);
      for (int x = 0; x < frame.width; ++x) {
        for (int c = 0; c < 3; ++c) {
          const float a = fast.at(x, y)[c], b = exact.at(x, 0)[c];
          if (std::isnan(a) || std::isnan(b)) {
            EXPECT_EQ(std::isnan(a), std::isnan(b)) << view << " at " << x << "," << y;
            continue;
          }
          worst = std::max(worst, std::abs(double(a) - b));
        }
      }
    }
    EXPECT_LE(worst, 2e-5) << view;
    std::printf("%s: table against OpenColorIO, largest difference %.2e\n", view, worst);
  }
}

}  // namespace
}  // namespace compose::color
