#include "ingest/image_io.h"

#include <OpenImageIO/imageio.h>

#include "test_util.h"

namespace compose::ingest {
namespace {

using compose::testing::TempDir;

Image gradient(int w, int h, int c) {
  Image img(w, h, c);
  for (size_t i = 0; i < img.pixels.size(); ++i) img.pixels[i] = float(i % 97) / 96.0f;
  return img;
}

TEST(ImageIo, ExrRoundTripIsExactInFloat) {
  TempDir dir;
  Image img = gradient(7, 5, 4);
  img.channelNames = {"R", "G", "B", "A"};
  img.pixels[3] = 1234.5f;  // HDR values survive
  WriteOptions opt;
  opt.depth = WriteOptions::Depth::Float;
  writeImage(dir / "a.exr", img, opt);
  const LoadedImage back = readImage(dir / "a.exr");
  EXPECT_EQ(back.image.width, 7);
  EXPECT_EQ(back.image.height, 5);
  EXPECT_EQ(back.image.channels, 4);
  EXPECT_EQ(back.image.pixels, img.pixels);
  EXPECT_EQ(back.info.format, "openexr");
}

TEST(ImageIo, EightBitRoundTripWithinHalfAStep) {
  TempDir dir;
  const Image img = gradient(16, 8, 3);
  writeImage(dir / "a.png", img);
  const LoadedImage back = readImage(dir / "a.png");
  ASSERT_EQ(back.image.pixels.size(), img.pixels.size());
  for (size_t i = 0; i < img.pixels.size(); ++i) {
    EXPECT_NEAR(back.image.pixels[i], img.pixels[i], 0.501f / 255.0f);  // half an 8-bit step
  }
}

TEST(ImageIo, AppliesExifOrientation) {
  TempDir dir;
  // A 4x2 image whose top-left pixel is red, stored with Orientation 6 ("rotate 90° clockwise to
  // view"): the upright picture is 2x4 and the red pixel lands at the top-right.
  const auto path = dir / "rotated.tif";
  {
    std::vector<float> px(4 * 2 * 3, 0.0f);
    px[0] = 1.0f;
    auto out = OIIO::ImageOutput::create(path.string());
    OIIO::ImageSpec spec(4, 2, 3, OIIO::TypeDesc::FLOAT);
    spec.attribute("Orientation", 6);
    ASSERT_TRUE(out->open(path.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  const LoadedImage img = readImage(path);
  EXPECT_EQ(img.info.orientation, 6);
  ASSERT_EQ(img.image.width, 2);
  ASSERT_EQ(img.image.height, 4);
  EXPECT_EQ(img.image.at(1, 0)[0], 1.0f);
  EXPECT_EQ(img.image.at(0, 0)[0], 0.0f);
}

TEST(ImageIo, ReadErrorsNameTheFile) {
  TempDir dir;
  COMPOSE_EXPECT_ERROR(readImage(dir / "missing.jpg"), "ingest: file not found");
  COMPOSE_EXPECT_ERROR(readImage(dir.path()), "is a folder");
  // A JPEG header followed by garbage.
  compose::testing::writeText(dir / "corrupt.jpg",
                              std::string("\xFF\xD8\xFF\xE0", 4) + std::string(200, 'x'));
  COMPOSE_EXPECT_ERROR(readImage(dir / "corrupt.jpg", "plate"), "corrupt.jpg)");
  COMPOSE_EXPECT_ERROR(readImage(dir / "corrupt.jpg", "plate"), "plate: cannot");
  compose::testing::writeText(dir / "empty.exr", "");
  COMPOSE_EXPECT_ERROR(readImage(dir / "empty.exr"), "empty.exr)");
}

TEST(ImageIo, FailedWriteLeavesNothingBehindAndKeepsTheOldFile) {
  TempDir dir;
  const Image img = gradient(4, 4, 3);
  writeImage(dir / "keep.png", img);
  const auto before = std::filesystem::file_size(dir / "keep.png");
  // Overwriting with an image whose extension has no writer fails before touching the file.
  COMPOSE_EXPECT_ERROR(writeImage(dir / "keep.nosuchformat", img), "no image writer");
  // A destination folder that is a file cannot be created.
  compose::testing::writeText(dir / "blocker", "x");
  COMPOSE_EXPECT_ERROR(writeImage(dir / "blocker" / "out.png", img), "output: cannot");
  EXPECT_EQ(std::filesystem::file_size(dir / "keep.png"), before);
  int entries = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir.path())) {
    (void)e;
    ++entries;
  }
  EXPECT_EQ(entries, 2) << "only keep.png and blocker: no temporary files left";
}

}  // namespace
}  // namespace compose::ingest

namespace compose::ingest {
namespace {

TEST(ImageIo, ExrCarriesChromaticitiesAndTheColourSpaceName) {
  TempDir dir;
  Image img = gradient(4, 3, 3);
  img.channelNames = {"R", "G", "B"};
  img.colorSpace = "ACEScg";
  WriteOptions opt;
  opt.chromaticities =
      std::array<double, 8>{0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767};
  writeImage(dir / "a.exr", img, opt);
  // Read by OpenImageIO directly: the standard attribute, as other tools see it.
  auto in = OIIO::ImageInput::open((dir / "a.exr").string());
  ASSERT_TRUE(in);
  const OIIO::ParamValue* c = in->spec().find_attribute("chromaticities");
  ASSERT_NE(c, nullptr) << "no chromaticities attribute in the header";
  EXPECT_EQ(c->type(), OIIO::TypeDesc(OIIO::TypeDesc::FLOAT, 8));
  in->close();
  const LoadedImage back = readImage(dir / "a.exr");
  ASSERT_TRUE(back.info.chromaticities.has_value());
  for (size_t i = 0; i < 8; ++i)
    EXPECT_NEAR((*back.info.chromaticities)[i], (*opt.chromaticities)[i], 1e-7);
  EXPECT_EQ(back.info.fileColorSpace, "ACEScg");
}

TEST(ImageIo, ValuesBeyondHalfRangeAreWrittenAsFloatNotInf) {
  TempDir dir;
  Image img = gradient(4, 4, 3);
  img.pixels[5] = 1e30f;
  WriteOptions opt;
  opt.depth = WriteOptions::Depth::Half;
  const WriteReport report = writeImage(dir / "big.exr", img, opt);
  EXPECT_TRUE(report.promotedToFloat);
  EXPECT_EQ(report.largestMagnitude, 1e30f);
  const LoadedImage back = readImage(dir / "big.exr");
  EXPECT_EQ(back.image.pixels[5], 1e30f);
  for (float v : back.image.pixels) EXPECT_TRUE(std::isfinite(v));
  // Within range: half as asked.
  img.pixels[5] = 60000.0f;
  EXPECT_FALSE(writeImage(dir / "ok.exr", img, opt).promotedToFloat);
}

}  // namespace
}  // namespace compose::ingest
