#include "ingest/image_io.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>

#include <Imath/half.h>
#include <OpenImageIO/imageio.h>

#include "core/channels.h"
#include "core/output_files.h"
#include "ingest/exif.h"
#include "ingest/pixel_util.h"
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

// A WebP's EXIF orientation and ICC profile, in its RIFF chunks, which OpenImageIO 2.4's WebP
// reader does not give: read here (a WebP with Orientation 6 came out sideways, one with a
// Display P3 profile was read as sRGB "as the file says").
TEST(ImageIo, AWebpsExifAndIccProfileAreRead) {
  TempDir dir;
  const auto plain = dir / "plain.webp";
  {
    std::vector<uint8_t> px(8 * 4 * 3, 0);
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 8; ++x) px[size_t(y * 8 + x) * 3 + (x < 4 ? 0 : 2)] = 255;
    auto out = OIIO::ImageOutput::create(plain.string());
    ASSERT_TRUE(out);
    OIIO::ImageSpec spec(8, 4, 3, OIIO::TypeDesc::UINT8);
    spec.attribute("compression", "lossless");
    ASSERT_TRUE(out->open(plain.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px.data()));
    out->close();
  }
  std::ifstream in(plain, std::ios::binary);
  const std::string webp((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_EQ(webp.substr(8, 4), "WEBP");
  const std::string image = webp.substr(12);  // the image's chunk (VP8 or VP8L)
  auto le32 = [](uint32_t v) {
    return std::string{char(v), char(v >> 8), char(v >> 16), char(v >> 24)};
  };
  auto chunk = [&](const std::string& kind, std::string payload) {
    const uint32_t size = uint32_t(payload.size());
    if (size & 1) payload += '\0';
    return kind + le32(size) + payload;
  };
  // A profile of a header and its 'desc' tag alone: what names it.
  std::string icc(128, '\0');
  const std::string name = "Display P3";
  auto be32 = [](uint32_t v) {
    return std::string{char(v >> 24), char(v >> 16), char(v >> 8), char(v)};
  };
  icc += be32(1) + "desc" + be32(144) + be32(uint32_t(12 + name.size() + 1));
  icc += "desc" + be32(0) + be32(uint32_t(name.size() + 1)) + name + '\0';
  const std::vector<unsigned char> exifBlock = exif::encode({{"Orientation", 6}});
  const std::string extended = std::string{char(0x28), 0, 0, 0} +  // ICC and EXIF present
                               std::string{7, 0, 0, 3, 0, 0};      // 8 x 4, less one
  std::string body = "WEBP" + chunk("VP8X", extended) + chunk("ICCP", icc) + image +
                     chunk("EXIF", std::string(exifBlock.begin(), exifBlock.end()));
  const auto tagged = dir / "tagged.webp";
  std::ofstream(tagged, std::ios::binary) << "RIFF" + le32(uint32_t(body.size())) + body;
  const LoadedImage img = readImage(tagged);
  EXPECT_EQ(img.info.orientation, 6);
  ASSERT_EQ(img.image.width, 4);
  ASSERT_EQ(img.image.height, 8);
  EXPECT_GT(img.image.at(0, 0)[0], 0.9f) << "the stored left (red) half at the top once turned";
  EXPECT_GT(img.image.at(0, 7)[2], 0.9f);
  EXPECT_EQ(img.info.iccProfile, "Display P3");
  EXPECT_EQ(img.info.fileColorSpace, "Display P3");
  // Without them: sRGB by the format's convention, upright as stored.
  const LoadedImage bare = readImage(plain);
  EXPECT_EQ(bare.image.width, 8);
  EXPECT_TRUE(bare.info.colorSpaceByConvention);
}

// An OpenEXR whose data window is not its display window is read as the display window: the
// stored pixels where the data window puts them, 0 around them, overscan left out, and a note.
TEST(ImageIo, AnExrIsItsDisplayWindow) {
  TempDir dir;
  auto write = [&](const std::string& name, int x, int y, int w, int h, int fw, int fh) {
    OIIO::ImageSpec spec(w, h, 3, OIIO::TypeDesc::FLOAT);
    spec.x = x;
    spec.y = y;
    spec.full_x = 0;
    spec.full_y = 0;
    spec.full_width = fw;
    spec.full_height = fh;
    std::vector<float> px(size_t(w) * size_t(h) * 3);
    for (int j = 0; j < h; ++j)
      for (int i = 0; i < w; ++i)
        for (int c = 0; c < 3; ++c)
          px[(size_t(j) * size_t(w) + size_t(i)) * 3 + size_t(c)] =
              float(1000 * (x + i) + (y + j) + c * 0.25);
    auto out = OIIO::ImageOutput::create((dir / name).string());
    ASSERT_TRUE(out && out->open((dir / name).string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  };
  // Shifted inside the frame: pixel (X, Y) of the frame holds 1000 X + Y where it is stored.
  write("shift.exr", 3, 2, 4, 3, 8, 6);
  LoadedImage shifted = readImage(dir / "shift.exr");
  ASSERT_EQ(shifted.image.width, 8);
  ASSERT_EQ(shifted.image.height, 6);
  EXPECT_EQ(shifted.image.at(3, 2)[0], 3002.0f);
  EXPECT_EQ(shifted.image.at(6, 4)[1], 6004.25f);
  EXPECT_EQ(shifted.image.at(2, 2)[0], 0.0f);
  EXPECT_EQ(shifted.image.at(3, 5)[0], 0.0f);
  ASSERT_EQ(shifted.notes.size(), 1u);
  EXPECT_NE(shifted.notes[0].find("0 where no pixel is stored"), std::string::npos)
      << shifted.notes[0];
  // Overscan around the frame: the frame's pixels only.
  write("overscan.exr", -2, -1, 10, 8, 6, 5);
  LoadedImage framed = readImage(dir / "overscan.exr");
  ASSERT_EQ(framed.image.width, 6);
  ASSERT_EQ(framed.image.height, 5);
  EXPECT_EQ(framed.image.at(0, 0)[0], 0.0f);
  EXPECT_EQ(framed.image.at(5, 4)[0], 5004.0f);
  ASSERT_EQ(framed.notes.size(), 1u);
  EXPECT_NE(framed.notes[0].find("the overscan outside it left out"), std::string::npos);
  // The same windows: nothing to say.
  write("plain.exr", 0, 0, 4, 3, 4, 3);
  EXPECT_TRUE(readImage(dir / "plain.exr").notes.empty());
}

// A minimal ICC profile: the header, a tag table of one 'desc' tag, and the tag, version 2
// (ASCII) or 4 ('mluc', UTF-16).
std::vector<unsigned char> iccProfileDescribed(const std::string& text, bool v4) {
  std::vector<unsigned char> p(128, 0);
  auto be32 = [&](uint32_t v) {
    for (int s = 24; s >= 0; s -= 8) p.push_back((unsigned char)(v >> s));
  };
  be32(1);
  p.insert(p.end(), {'d', 'e', 's', 'c'});
  be32(144);
  const size_t sizeAt = p.size();
  be32(0);
  const size_t start = p.size();
  if (!v4) {
    p.insert(p.end(), {'d', 'e', 's', 'c', 0, 0, 0, 0});
    be32(uint32_t(text.size() + 1));
    p.insert(p.end(), text.begin(), text.end());
    p.push_back(0);
  } else {
    p.insert(p.end(), {'m', 'l', 'u', 'c', 0, 0, 0, 0});
    be32(1);
    be32(12);
    p.insert(p.end(), {'e', 'n', 'U', 'S'});
    be32(uint32_t(2 * text.size()));
    be32(28);
    for (const char c : text) p.insert(p.end(), {0, (unsigned char)c});
  }
  const uint32_t size = uint32_t(p.size() - start);
  for (int k = 0; k < 4; ++k) p[sizeAt + size_t(k)] = (unsigned char)(size >> (24 - 8 * k));
  const uint32_t total = uint32_t(p.size());
  for (int k = 0; k < 4; ++k) p[size_t(k)] = (unsigned char)(total >> (24 - 8 * k));
  return p;
}

// Values a stage cannot sum: NaN, infinity, and (with a limit) a finite value no light has, such
// as the largest float (a stitch's blend of it overflowed to infinity).
TEST(ImageIo, RequireFiniteNamesThePixel) {
  Image image(3, 2, 3, {"R", "G", "B"});
  for (float& v : image.pixels) v = 0.5f;
  EXPECT_NO_THROW(requireFinite(image, "a.exr", "stitch", "the photo", kMaxPhotoValue));
  image.pixels[3 * (1 * 3 + 2) + 1] = 3.4e38f;
  EXPECT_NO_THROW(requireFinite(image, "a.exr", "stitch", "the photo"));
  try {
    requireFinite(image, "a.exr", "stitch", "the photo", kMaxPhotoValue);
    ADD_FAILURE() << "3.4e38 passed";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("value 3.4e+38 in the photo at pixel (2, 1) is beyond any "
                                         "light (more than 1e+32)"),
              std::string::npos)
        << e.what();
  }
  image.pixels[0] = -std::numeric_limits<float>::infinity();
  try {
    requireFinite(image, "a.exr", "stitch", "the photo");
    ADD_FAILURE() << "infinity passed";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("infinity in the photo at pixel (0, 0)"),
              std::string::npos)
        << e.what();
  }
}

// A photo's embedded ICC profile names its colour space: Display P3 (an iPhone's), Adobe RGB, and
// their linear forms; an sRGB profile changes nothing, and another is named as it is (no config
// knows it: a note).
TEST(ImageIo, AnEmbeddedIccProfileNamesTheColourSpace) {
  EXPECT_EQ(exif::iccDescription(iccProfileDescribed("Display P3", false)), "Display P3");
  EXPECT_EQ(exif::iccDescription(iccProfileDescribed("Adobe RGB (1998)", true)),
            "Adobe RGB (1998)");
  std::vector<unsigned char> broken = iccProfileDescribed("Display P3", false);
  broken.resize(150);
  EXPECT_EQ(exif::iccDescription(broken), "");
  TempDir dir;
  for (const auto& [description, space] : std::vector<std::pair<std::string, std::string>>{
           {"Display P3", "Display P3"},
           {"Adobe RGB (1998)", "Adobe RGB (1998)"},
           {"sRGB IEC61966-2.1", "sRGB"},
           {"Linear Display P3", "Linear P3-D65"},
           {"Adobe RGB (1998) Linear", "Linear Adobe RGB (1998)"},
           {"Linear ProPhoto", "Linear ProPhoto"},
           {"ProPhoto RGB", "ProPhoto RGB"},
           // Theatre white and gamma 2.6, or ACES' D60 white: not Display P3 (a cinema grade
           // was read as a phone's photo, +0.37 stops at code 128); named, so a note says so.
           {"DCI-P3", "DCI-P3"},
           {"P3-D60", "P3-D60"},
           {"SMPTE RP 431-2", "SMPTE RP 431-2"}}) {
    const std::vector<unsigned char> icc = iccProfileDescribed(description, description[0] == 'A');
    const std::filesystem::path file = dir.path() / "photo.jpg";
    OIIO::ImageSpec spec(8, 4, 3, OIIO::TypeDesc::UINT8);
    spec.attribute("ICCProfile", OIIO::TypeDesc(OIIO::TypeDesc::UINT8, int(icc.size())),
                   icc.data());
    std::vector<unsigned char> px(8 * 4 * 3, 128);
    auto out = OIIO::ImageOutput::create(file.string());
    ASSERT_TRUE(out && out->open(file.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px.data()));
    out->close();
    const CaptureInfo info = readCaptureInfo(file);
    EXPECT_EQ(info.iccProfile, description);
    EXPECT_EQ(info.fileColorSpace, space) << description;
    EXPECT_EQ(info.colorSpaceByConvention, space == "sRGB") << description;
  }
}

// A linear 16-bit TIFF says so by its profile (exif::linearRec709Profile, as compose capture-sim
// writes it; a linear export's "sRGB-elle-V4-g10" likewise): read as linear Rec.709, where a
// TIFF without one is left to the config's rules (sRGB codes).
TEST(ImageIo, ALinearIccProfileMakesATiffLinear) {
  const std::vector<unsigned char> profile = exif::linearRec709Profile();
  EXPECT_EQ(exif::iccDescription(profile), exif::kLinearRec709Profile);
  const uint32_t declared = (uint32_t(profile[0]) << 24) | (uint32_t(profile[1]) << 16) |
                            (uint32_t(profile[2]) << 8) | uint32_t(profile[3]);
  EXPECT_EQ(declared, profile.size());
  EXPECT_EQ(profile.size() % 4, 0u);
  TempDir dir;
  Image img(8, 4, 3, {"R", "G", "B"});
  for (float& v : img.pixels) v = 0.25f;
  WriteOptions w;
  w.depth = WriteOptions::Depth::UInt16;
  writeImage(dir / "plain.tif", img, w);
  w.attributes.push_back({"ICCProfile", std::string(profile.begin(), profile.end())});
  writeImage(dir / "linear.tif", img, w);
  const CaptureInfo linear = readCaptureInfo(dir / "linear.tif");
  EXPECT_EQ(linear.iccProfile, exif::kLinearRec709Profile);
  EXPECT_EQ(linear.fileColorSpace, "Linear Rec.709 (sRGB)");
  EXPECT_FALSE(linear.colorSpaceByConvention);
  EXPECT_TRUE(readCaptureInfo(dir / "plain.tif").iccProfile.empty());
  // Another linear description, through OpenImageIO's reader of JPEG profiles as above.
  const std::vector<unsigned char> elle = iccProfileDescribed("sRGB-elle-V4-g10.icc", false);
  OIIO::ImageSpec spec(8, 4, 3, OIIO::TypeDesc::UINT8);
  spec.attribute("ICCProfile", OIIO::TypeDesc(OIIO::TypeDesc::UINT8, int(elle.size())),
                 elle.data());
  std::vector<unsigned char> px(8 * 4 * 3, 128);
  const std::filesystem::path file = dir.path() / "elle.jpg";
  auto out = OIIO::ImageOutput::create(file.string());
  ASSERT_TRUE(out && out->open(file.string(), spec));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px.data()));
  out->close();
  EXPECT_EQ(readCaptureInfo(file).fileColorSpace, "Linear Rec.709 (sRGB)");
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

// The largest finite magnitude, four lanes at a time, against a plain loop: every length up to 40
// (the lanes and the tail), a NaN, an infinity or the largest value at every place, signs mixed;
// and the same of the values scaled (the largest float scaled up is infinite, not counted).
TEST(ImageIo, LargestFiniteMagnitudeMatchesAPlainLoop) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-3.0f, 3.0f);
  auto plain = [](const std::vector<float>& v) {
    float m = 0.0f;
    for (float x : v)
      if (std::isfinite(x)) m = std::max(m, std::abs(x));
    return m;
  };
  auto product = [](const std::vector<float>& v, const std::vector<float>& s) {
    std::vector<float> p(v.size());
    for (size_t i = 0; i < v.size(); ++i) p[i] = v[i] * s[i];
    return p;
  };
  const float specials[] = {
      std::numeric_limits<float>::quiet_NaN(), -std::numeric_limits<float>::infinity(),
      std::numeric_limits<float>::infinity(),  -9.5f,
      std::numeric_limits<float>::max(),       -0.0f};
  for (size_t n = 0; n <= 40; ++n) {
    std::vector<float> v(n), scales(n);
    for (float& x : v) x = u(rng);
    for (float& x : scales) x = std::abs(u(rng)) * 4.0f;
    EXPECT_EQ(detail::largestFinite(v.data(), n), plain(v)) << n;
    EXPECT_EQ(detail::largestFinite(v.data(), scales.data(), n), plain(product(v, scales))) << n;
    for (size_t at = 0; at < n; ++at)
      for (float special : specials) {
        std::vector<float> w = v;
        w[at] = special;
        ASSERT_EQ(detail::largestFinite(w.data(), n), plain(w)) << n << " " << at << " " << special;
        ASSERT_EQ(detail::largestFinite(w.data(), scales.data(), n), plain(product(w, scales)))
            << n << " " << at << " " << special;
      }
  }
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

// Values that exercise every kind of half: ordinary, negative, signed zero, subnormal in half,
// the largest half, infinities and NaN.
Image mixedValues(int w, int h, int c, std::vector<std::string> names, uint32_t seed) {
  Image img(w, h, c, std::move(names));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-4.0f, 4.0f);
  for (float& v : img.pixels) v = u(rng);
  const float specials[] = {-0.0f,
                            1e-7f,
                            -3e-6f,
                            kHalfMax,
                            -kHalfMax,
                            1.0e-20f,
                            0.125f,
                            std::numeric_limits<float>::infinity(),
                            std::numeric_limits<float>::quiet_NaN()};
  for (size_t i = 0; i < std::size(specials); ++i)
    img.pixels[i * 7 % img.pixels.size()] = specials[i];
  return img;
}

struct ReadPart {
  OIIO::ImageSpec spec;
  std::vector<float> pixels;
};

std::vector<ReadPart> readParts(const std::filesystem::path& file) {
  std::vector<ReadPart> parts;
  auto in = OIIO::ImageInput::open(file.string());
  EXPECT_TRUE(in) << OIIO::geterror();
  if (!in) return parts;
  for (int sub = 0; in->seek_subimage(sub, 0); ++sub) {
    ReadPart p;
    p.spec = in->spec();
    p.pixels.resize(p.spec.image_pixels() * size_t(p.spec.nchannels));
    EXPECT_TRUE(
        in->read_image(sub, 0, 0, p.spec.nchannels, OIIO::TypeDesc::FLOAT, p.pixels.data()));
    parts.push_back(std::move(p));
  }
  return parts;
}

// What OpenImageIO stores for `interleaved` float pixels written as `format` with write_image():
// the same file written the plain way, read back.
std::vector<float> plainWriteReadBack(const std::filesystem::path& file, int w, int h,
                                      const std::vector<std::string>& names, OIIO::TypeDesc format,
                                      const std::vector<float>& interleaved) {
  OIIO::ImageSpec spec(w, h, int(names.size()), format);
  spec.channelnames = names;
  spec.attribute("compression", "zip");
  auto out = OIIO::ImageOutput::create(file.string());
  EXPECT_TRUE(out && out->open(file.string(), spec));
  EXPECT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, interleaved.data()));
  out->close();
  return readParts(file).at(0).pixels;
}

bool sameBits(std::span<const float> a, std::span<const float> b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

// The composite's output: a full-frame RGB image with an opaque alpha added on the way out, a
// part of two images interleaved (a beauty and its AOVs) in its own data window, and a float part.
// Each part reads back with its data window and names, and with exactly the values the plain
// OpenImageIO write of the same pixels, interleaved in memory, stores. The full frame is wide and
// tall enough to be written in several bands of rows.
// Channels written as float whatever the depth (an object layer's position and depth) hold
// values beyond half's range without making the part's other channels float: a depth of 80 km
// made the whole object layer float (and said its colours exceeded half's range).
TEST(ImageIo, FloatChannelsBeyondHalfLeaveTheOthersHalf) {
  TempDir dir;
  Image beauty = mixedValues(40, 30, 4, {"R", "G", "B", "A"}, 2);
  Image aovs = mixedValues(40, 30, 2, {"N.X", "depth.Z"}, 3);
  aovs.pixels[1] = 80729.0f;  // depth.Z, beyond half
  ExrPart object{"object", &beauty, 0, 0, 40, 30, {}};
  object.options.depth = WriteOptions::Depth::Half;
  object.moreImages = {&aovs};
  object.channelNames = {"object.R", "object.G", "object.B", "object.A", "N.X", "depth.Z"};
  object.floatChannels = {"depth.Z"};
  {
    OutputFiles outputs("output");
    const std::vector<WriteReport> reports = writeExrParts(outputs, dir / "o.exr", {object});
    outputs.commit();
    ASSERT_EQ(reports.size(), 1u);
    EXPECT_FALSE(reports[0].promotedToFloat) << reports[0].largestMagnitude;
  }
  const std::vector<ReadPart> parts = readParts(dir / "o.exr");
  ASSERT_EQ(parts.size(), 1u);
  const OIIO::ImageSpec& spec = parts[0].spec;
  ASSERT_EQ(spec.nchannels, 6);
  for (int c = 0; c < 6; ++c) {
    const bool depth = spec.channelnames[size_t(c)] == "depth.Z";
    EXPECT_EQ(spec.channelformat(c), depth ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::HALF)
        << spec.channelnames[size_t(c)];
    if (depth) {
      EXPECT_EQ(parts[0].pixels[size_t(c)], 80729.0f);
    }
  }
}

TEST(ImageIo, MultiPartExrReadsBackExactlyAsWritten) {
  TempDir dir;
  const int fullW = 2100, fullH = 700;
  const Image rgb = mixedValues(fullW, fullH, 3, {"R", "G", "B"}, 1);
  const Image beauty = mixedValues(300, 170, 4, {"R", "G", "B", "A"}, 2);
  const Image aovs = mixedValues(300, 170, 3, {"N.X", "N.Y", "N.Z"}, 3);
  Image ratio = mixedValues(50, 40, 3, {"R", "G", "B"}, 4);
  ratio.pixels[3] = 1e6f;  // beyond half: this part is written as float

  ExrPart composite{"composite", &rgb, 0, 0, fullW, fullH, {}};
  composite.options.depth = WriteOptions::Depth::Half;
  composite.options.alphaChannel = 3;
  composite.constantChannels = {{"A", 1.0f}};
  ExrPart object{"object", &beauty, 1700, 513, fullW, fullH, composite.options};
  object.moreImages = {&aovs};
  object.channelNames = {"object.R", "object.G", "object.B", "object.A", "N.X", "N.Y", "N.Z"};
  ExrPart shadow{"shadow", &ratio, 10, 20, fullW, fullH, {}};
  shadow.options.depth = WriteOptions::Depth::Half;
  {
    OutputFiles outputs("output");
    const std::vector<WriteReport> reports =
        writeExrParts(outputs, dir / "parts.exr", {composite, object, shadow});
    outputs.commit();
    ASSERT_EQ(reports.size(), 3u);
    EXPECT_FALSE(reports[0].promotedToFloat);
    EXPECT_FALSE(reports[1].promotedToFloat);
    EXPECT_TRUE(reports[2].promotedToFloat);
  }
  const std::vector<ReadPart> parts = readParts(dir / "parts.exr");
  ASSERT_EQ(parts.size(), 3u);

  struct Expected {
    const char* name;
    int x, y, w, h;
    std::vector<std::string> names;
    OIIO::TypeDesc format;
    std::vector<float> interleaved;
  };
  std::vector<Expected> expected(3);
  expected[0] = {"composite", 0, 0, fullW, fullH, {"R", "G", "B", "A"}, OIIO::TypeDesc::HALF, {}};
  for (size_t i = 0; i < rgb.pixelCount(); ++i) {
    expected[0].interleaved.insert(expected[0].interleaved.end(), rgb.pixels.begin() + 3 * i,
                                   rgb.pixels.begin() + 3 * i + 3);
    expected[0].interleaved.push_back(1.0f);
  }
  expected[1] = {"object", 1700, 513, 300, 170, object.channelNames, OIIO::TypeDesc::HALF, {}};
  for (size_t i = 0; i < beauty.pixelCount(); ++i) {
    expected[1].interleaved.insert(expected[1].interleaved.end(), beauty.pixels.begin() + 4 * i,
                                   beauty.pixels.begin() + 4 * i + 4);
    expected[1].interleaved.insert(expected[1].interleaved.end(), aovs.pixels.begin() + 3 * i,
                                   aovs.pixels.begin() + 3 * i + 3);
  }
  expected[2] = {"shadow",
                 10,
                 20,
                 50,
                 40,
                 {"R", "G", "B"},
                 OIIO::TypeDesc::FLOAT,
                 std::vector<float>(ratio.pixels.begin(), ratio.pixels.end())};

  for (size_t p = 0; p < 3; ++p) {
    SCOPED_TRACE(expected[p].name);
    const OIIO::ImageSpec& spec = parts[p].spec;
    EXPECT_EQ(spec.get_string_attribute("name"), expected[p].name);
    EXPECT_EQ(spec.x, expected[p].x);
    EXPECT_EQ(spec.y, expected[p].y);
    EXPECT_EQ(spec.width, expected[p].w);
    EXPECT_EQ(spec.height, expected[p].h);
    EXPECT_EQ(spec.full_x, 0);
    EXPECT_EQ(spec.full_y, 0);
    EXPECT_EQ(spec.full_width, fullW);
    EXPECT_EQ(spec.full_height, fullH);
    EXPECT_EQ(spec.format, expected[p].format);
    EXPECT_EQ(spec.get_string_attribute("compression"), "zip");
    // OpenEXR stores channels sorted by name; OpenImageIO reads them back in its own order, so
    // compare by name.
    ASSERT_EQ(spec.channelnames.size(), expected[p].names.size());
    const std::vector<float> plain = plainWriteReadBack(
        dir / (std::string("plain_") + expected[p].name + ".exr"), expected[p].w, expected[p].h,
        expected[p].names, expected[p].format, expected[p].interleaved);
    EXPECT_TRUE(sameBits(parts[p].pixels, plain)) << "pixels differ from the plain write";
    // And the plain write keeps the floats themselves where it is float, or their half rounding.
    if (expected[p].format == OIIO::TypeDesc::FLOAT) {
      EXPECT_EQ(spec.channelnames, expected[p].names);
      EXPECT_TRUE(sameBits(parts[p].pixels, expected[p].interleaved));
    }
  }
  // The alpha added on the way out is 1 everywhere.
  const OIIO::ImageSpec& c = parts[0].spec;
  const int alpha = c.channelindex("A");
  ASSERT_GE(alpha, 0);
  for (size_t i = 0; i < size_t(fullW) * fullH; ++i)
    ASSERT_EQ(parts[0].pixels[i * 4 + size_t(alpha)], 1.0f);
}

// Channels named as float in a half part (positions, depth) are written as 32-bit float, the
// rest as half: a point 10.0001 units away keeps its last digit, the colour its half rounding.
TEST(ImageIo, FloatChannelsInAHalfPartKeepTheirPrecision) {
  TempDir dir;
  Image beauty(5, 3, 2, {"R", "G"});
  Image aovs(5, 3, 2, {"P.X", "N.X"});
  for (size_t i = 0; i < beauty.pixelCount(); ++i) {
    beauty.pixels[2 * i] = 0.1f + 0.01f * float(i);
    beauty.pixels[2 * i + 1] = 0.3f;
    aovs.pixels[2 * i] = 10.0001f + float(i);
    aovs.pixels[2 * i + 1] = 0.7f;
  }
  ExrPart part{"object", &beauty, 2, 1, 9, 6, {}};
  part.options.depth = WriteOptions::Depth::Half;
  part.moreImages = {&aovs};
  part.floatChannels = {"P.X"};
  {
    OutputFiles outputs("output");
    writeExrParts(outputs, dir / "mixed.exr", {part});
    outputs.commit();
  }
  auto in = OIIO::ImageInput::open((dir / "mixed.exr").string());
  ASSERT_TRUE(in);
  const OIIO::ImageSpec spec = in->spec();
  ASSERT_EQ(spec.nchannels, 4);
  std::vector<float> pixels(size_t(spec.image_pixels()) * 4);
  ASSERT_TRUE(in->read_image(0, 0, 0, 4, OIIO::TypeDesc::FLOAT, pixels.data()));
  for (int c = 0; c < 4; ++c) {
    const std::string& name = spec.channelnames[size_t(c)];
    const OIIO::TypeDesc type = spec.channelformat(c);
    EXPECT_EQ(type, name == "P.X" ? OIIO::TypeDesc::FLOAT : OIIO::TypeDesc::HALF) << name;
    for (size_t i = 0; i < beauty.pixelCount(); ++i) {
      const float got = pixels[4 * i + size_t(c)];
      const float want = name == "R"     ? beauty.pixels[2 * i]
                         : name == "G"   ? beauty.pixels[2 * i + 1]
                         : name == "P.X" ? aovs.pixels[2 * i]
                                         : aovs.pixels[2 * i + 1];
      EXPECT_EQ(got, name == "P.X" ? want : float(Imath::half(want))) << name << " " << i;
    }
  }
}

// Channels scaled on the way (a render's exposure applied as it is written): a scaled channel
// holds the half of value x factor, the others their own values, a float channel its float; and
// half's range is checked on the scaled values, so that a part is written as float when a scaled
// value exceeds it, and not when only an unscaled value would exceed it scaled.
TEST(ImageIo, ScaledChannelsAreWrittenScaled) {
  TempDir dir;
  Image beauty(5, 3, 2, {"R", "A"});
  Image aovs(5, 3, 2, {"P.X", "E.Y"});
  for (size_t i = 0; i < beauty.pixelCount(); ++i) {
    beauty.pixels[2 * i] = 0.1f + 0.37f * float(i);
    beauty.pixels[2 * i + 1] = 0.25f * float(i % 5);
    aovs.pixels[2 * i] = 10.0001f + float(i);
    aovs.pixels[2 * i + 1] = 1.3f * float(i);
  }
  const float factor = 2.7f;
  auto write = [&](const std::string& name) {
    ExrPart part{"object", &beauty, 2, 1, 9, 6, {}};
    part.options.depth = WriteOptions::Depth::Half;
    part.moreImages = {&aovs};
    part.channelNames = {"object.R", "object.A", "P.X", "E.Y"};
    part.floatChannels = {"P.X"};
    part.channelScales = {{"object.R", factor}, {"E.Y", factor}};
    OutputFiles outputs("output");
    const std::vector<WriteReport> reports = writeExrParts(outputs, dir / name, {part});
    outputs.commit();
    return reports.at(0);
  };
  EXPECT_FALSE(write("scaled.exr").promotedToFloat);
  auto in = OIIO::ImageInput::open((dir / "scaled.exr").string());
  ASSERT_TRUE(in);
  const OIIO::ImageSpec spec = in->spec();
  ASSERT_EQ(spec.nchannels, 4);
  std::vector<float> pixels(size_t(spec.image_pixels()) * 4);
  ASSERT_TRUE(in->read_image(0, 0, 0, 4, OIIO::TypeDesc::FLOAT, pixels.data()));
  for (int c = 0; c < 4; ++c) {
    const std::string& name = spec.channelnames[size_t(c)];
    for (size_t i = 0; i < beauty.pixelCount(); ++i) {
      const float got = pixels[4 * i + size_t(c)];
      const float want = name == "object.R"   ? float(Imath::half(beauty.pixels[2 * i] * factor))
                         : name == "object.A" ? float(Imath::half(beauty.pixels[2 * i + 1]))
                         : name == "P.X"      ? aovs.pixels[2 * i]
                                              : float(Imath::half(aovs.pixels[2 * i + 1] * factor));
      EXPECT_EQ(got, want) << name << " " << i;
    }
  }
  // 30,000 in the unscaled alpha fits half; in a scaled channel (81,000) it does not.
  beauty.pixels[1] = 30000.0f;
  EXPECT_FALSE(write("alpha.exr").promotedToFloat);
  aovs.pixels[1] = 30000.0f;
  const WriteReport promoted = write("irradiance.exr");
  EXPECT_TRUE(promoted.promotedToFloat);
  EXPECT_FLOAT_EQ(promoted.largestMagnitude, 30000.0f * factor);
}

// A multi-part OpenEXR whose first part is not the picture (a depth pass first, as a renderer may
// write it): the part with R, G and B is read, and a note says which; the header-only reading
// agrees. (Part 0 was read: the depth as a grey plate, exit 0.)
TEST(ImageIo, AMultiPartExrIsReadFromItsColourPart) {
  TempDir dir;
  Image depth(8, 4, 1, {"Z"});
  std::fill(depth.pixels.begin(), depth.pixels.end(), 7.0f);
  Image rgba(8, 4, 4, {"R", "G", "B", "A"});
  std::fill(rgba.pixels.begin(), rgba.pixels.end(), 0.25f);
  {
    OutputFiles outputs("output");
    writeExrParts(
        outputs, dir / "mp.exr",
        {ExrPart("depth", &depth, 0, 0, 8, 4, {}), ExrPart("rgba", &rgba, 0, 0, 8, 4, {})});
    outputs.commit();
  }
  const LoadedImage loaded = readImage(dir / "mp.exr", "ingest", {.picturePart = true});
  EXPECT_EQ(loaded.image.channels, 4);
  EXPECT_EQ(loaded.image.pixels[0], 0.25f);
  ASSERT_EQ(loaded.notes.size(), 1u);
  EXPECT_NE(loaded.notes[0].find("an OpenEXR of 2 parts ('depth', 'rgba'): read part 1 'rgba'"),
            std::string::npos)
      << loaded.notes[0];
  // A mask is read from the first part, as before (a matte written before the picture).
  EXPECT_EQ(readImage(dir / "mp.exr").image.channels, 1);
  EXPECT_EQ(readCaptureInfo(dir / "mp.exr").channels, 1);
  EXPECT_EQ(readCaptureInfo(dir / "mp.exr", "ingest", true).channels, 4);  // the pixels' part
  // A layer's colour is a picture too: a depth part first, then beauty.R/G/B.
  Image beauty(8, 4, 3, {"beauty.R", "beauty.G", "beauty.B"});
  std::fill(beauty.pixels.begin(), beauty.pixels.end(), 0.5f);
  Image layeredDepth(8, 4, 1, {"depth.Z"});
  {
    OutputFiles outputs("output");
    writeExrParts(outputs, dir / "layers.exr",
                  {ExrPart("depth", &layeredDepth, 0, 0, 8, 4, {}),
                   ExrPart("beauty", &beauty, 0, 0, 8, 4, {})});
    outputs.commit();
  }
  const LoadedImage layers = readImage(dir / "layers.exr", "ingest", {.picturePart = true});
  EXPECT_EQ(layers.image.channelNames,
            (std::vector<std::string>{"beauty.R", "beauty.G", "beauty.B"}));
  // A picture needs a colour channel: a depth pass alone, or normals, are named errors; a
  // layer's colour and grey are pictures.
  COMPOSE_EXPECT_ERROR(requireColourChannels(depth, "d.exr", "ingest", "the plate"),
                       "the plate has no colour channel (R, G, B or Y): its channels are Z");
  COMPOSE_EXPECT_ERROR(
      requireColourChannels(Image(2, 2, 3, {"N.X", "N.Y", "N.Z"}), "n.exr", "ingest", "the plate"),
      "its channels are N.X, N.Y, N.Z");
  requireColourChannels(Image(2, 2, 3, {"beauty.R", "beauty.G", "beauty.B"}), "b.exr", "ingest",
                        "the plate");
  requireColourChannels(Image(2, 2, 2, {"Y", "A"}), "y.png", "ingest", "the plate");
  // Part of a colour is not a colour (R and G alone were read as a grey R).
  COMPOSE_EXPECT_ERROR(
      requireColourChannels(Image(2, 2, 2, {"R", "G"}), "rg.exr", "ingest", "the environment"),
      "the environment has two of the colour channels R, G, B but not the third (its channels "
      "are R, G)");
  requireColourChannels(Image(2, 2, 1, {"R"}), "r.exr", "ingest", "the environment");  // grey
  COMPOSE_EXPECT_ERROR(
      requireColourChannels(Image(2, 2, 2, {"Y", "RY"}), "yc.exr", "ingest", "the environment"),
      "has luminance-chroma channels without all of Y, RY and BY");
  requireColourChannels(Image(2, 2, 3, {"Y", "RY", "BY"}), "yc.exr", "ingest", "the environment");
}

TEST(ImageIo, EightBitWriteMatchesThePlainWrite) {
  // JPEG and PNG outputs are quantised by OpenImageIO's own conversion, a band of rows at a time:
  // the same codes as a plain write_image() of the floats.
  TempDir dir;
  Image img = mixedValues(1500, 900, 3, {"R", "G", "B"}, 5);
  for (float& v : img.pixels) v = std::isfinite(v) ? std::abs(v) / 4.0f : 0.5f;
  for (const char* ext : {".png", ".jpg"}) {
    SCOPED_TRACE(ext);
    const std::filesystem::path ours = dir / (std::string("ours") + ext);
    const std::filesystem::path plain = dir / (std::string("plain") + ext);
    writeImage(ours, img);
    OIIO::ImageSpec spec(img.width, img.height, 3, OIIO::TypeDesc::UINT8);
    spec.attribute("Compression", "jpeg:95");
    auto out = OIIO::ImageOutput::create(plain.string());
    ASSERT_TRUE(out && out->open(plain.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, img.pixels.data()));
    out->close();
    const LoadedImage a = readImage(ours), b = readImage(plain);
    EXPECT_TRUE(sameBits(a.image.pixels, b.image.pixels));
  }
}

TEST(ImageIo, RadianceHdrKeepsValuesAboveOne) {
  // A Radiance HDR writer stores float (RGBE) whatever depth is asked for: the rows are handed
  // over in the type the writer stores, so nothing is clamped to 8 bits on the way.
  TempDir dir;
  Image img(64, 40, 3, {"R", "G", "B"});
  for (size_t i = 0; i < img.pixels.size(); ++i) img.pixels[i] = float(i % 97) / 10.0f;
  img.pixels[3 * (10 * 64 + 20)] = 5000.0f;
  writeImage(dir / "a.hdr", img);  // default depth: 8 bits for a non-EXR file
  const LoadedImage back = readImage(dir / "a.hdr");
  ASSERT_EQ(back.image.pixels.size(), img.pixels.size());
  for (size_t i = 0; i < img.pixels.size(); ++i) {
    // RGBE: an 8-bit mantissa shared by the pixel's three values.
    const float* p = img.pixels.data() + i / 3 * 3;
    const float largest = std::max({p[0], p[1], p[2]});
    ASSERT_NEAR(back.image.pixels[i], img.pixels[i], largest / 128.0f + 1e-6f) << i;
  }
  // Without bias: the mantissas decoded as Radiance defines them, (m + 1/2) 2^(e - 136), undo
  // the writers' truncation on average (decoded as m 2^(e - 136), every value read 0.4 % low).
  Image smooth(256, 64, 3, {"R", "G", "B"});
  for (size_t i = 0; i < smooth.pixels.size(); ++i)
    smooth.pixels[i] = 0.05f + 3.0f * float((i * 2654435761u) % 10007) / 10007.0f;
  writeImage(dir / "smooth.hdr", smooth);
  const LoadedImage read = readImage(dir / "smooth.hdr");
  double ratio = 0.0;
  for (size_t i = 0; i < smooth.pixels.size(); ++i)
    ratio += double(read.image.pixels[i]) / double(smooth.pixels[i]);
  ratio /= double(smooth.pixels.size());
  EXPECT_NEAR(ratio, 1.0, 0.001) << "mean of read / written";
}

// A portable float map cut short (a copy interrupted) says how many bytes it needs and holds
// (OpenImageIO failed it with "unknown reason").
TEST(ImageIo, ATruncatedFloatMapSaysSo) {
  TempDir dir;
  // PF: colour; a negative scale: little-endian floats.
  std::string bytes = "PF\n32 16\n-1.0\n";
  const std::vector<float> values(32 * 16 * 3, 0.5f);
  bytes.append(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float));
  std::ofstream(dir / "whole.pfm", std::ios::binary) << bytes;
  const LoadedImage whole = readImage(dir / "whole.pfm");
  ASSERT_EQ(whole.image.pixels.size(), values.size());
  EXPECT_EQ(whole.image.pixels[7], 0.5f);
  std::ofstream(dir / "cut.pfm", std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  COMPOSE_EXPECT_ERROR(readImage(dir / "cut.pfm"),
                       "truncated file: a 32x16 portable float map needs " +
                           std::to_string(bytes.size()) + " bytes, the file holds " +
                           std::to_string(bytes.size() / 2));
}

// A Radiance header's EXPOSURE (each one multiplies the exposure the values carry), COLORCORR
// (the same per channel) and PRIMARIES are what the format defines the values by: OpenImageIO
// applies none of them, and a map stored 4 times brighter with EXPOSURE=4 lit the object 4 times
// brighter. A value that is not a number is an error naming it.
TEST(ImageIo, ARadianceHeaderSaysWhatItsValuesAre) {
  TempDir dir;
  Image img(16, 8, 3, {"R", "G", "B"});
  for (size_t i = 0; i < img.pixels.size(); ++i) img.pixels[i] = 8.0f;
  writeImage(dir / "plain.hdr", img);
  const std::vector<uint8_t> bytes = [&] {
    std::ifstream in(dir / "plain.hdr", std::ios::binary);
    return std::vector<uint8_t>((std::istreambuf_iterator<char>(in)), {});
  }();
  const std::string text(bytes.begin(), bytes.end());
  const size_t end = text.find("\n\n");
  ASSERT_NE(end, std::string::npos);
  auto withHeader = [&](const std::string& name, const std::string& lines) {
    std::ofstream out(dir / name, std::ios::binary);
    out << text.substr(0, end + 1) << lines << text.substr(end + 1);
  };
  withHeader("exposed.hdr", "EXPOSURE=2\nEXPOSURE=0.5e1\nCOLORCORR=1 2 4\n");
  const LoadedImage exposed = readImage(dir / "exposed.hdr");
  ASSERT_EQ(exposed.image.channels, 3);
  // 8 is stored as mantissa 128 of step 1/16, which Radiance decodes as 128.5 / 16.
  const float stored = 8.0f + 0.5f / 16.0f;
  EXPECT_NEAR(exposed.image.pixels[0], stored / 10.0f, 1e-6f);
  EXPECT_NEAR(exposed.image.pixels[1], stored / 20.0f, 1e-6f);
  EXPECT_NEAR(exposed.image.pixels[2], stored / 40.0f, 1e-6f);
  ASSERT_EQ(exposed.notes.size(), 1u);
  EXPECT_EQ(exposed.notes[0],
            "exposed.hdr: the EXPOSURE (10) and COLORCORR (1 2 4) of its Radiance header applied: "
            "values divided by them, the radiance the format defines");
  EXPECT_FALSE(exposed.info.chromaticities);
  const LoadedImage plain = readImage(dir / "plain.hdr");
  EXPECT_EQ(plain.image.pixels[0], stored);
  EXPECT_TRUE(plain.notes.empty());

  withHeader("aces.hdr", "PRIMARIES=0.7347 0.2653 0.0 1.0 0.0001 -0.077 0.32168 0.33767\n");
  const LoadedImage aces = readImage(dir / "aces.hdr");
  ASSERT_TRUE(aces.info.chromaticities);
  EXPECT_EQ((*aces.info.chromaticities)[0], 0.7347);
  EXPECT_EQ((*aces.info.chromaticities)[5], -0.077);
  EXPECT_EQ(aces.image.pixels[0], stored);

  withHeader("bad.hdr", "EXPOSURE=bright\n");
  COMPOSE_EXPECT_ERROR(readImage(dir / "bad.hdr"),
                       "the Radiance header's EXPOSURE is not 1 number: 'bright'");
  // A picture in CIE XYZ, which OpenImageIO does not read ("no FORMAT specifier found").
  std::string xyz = text;
  xyz.replace(xyz.find("32-bit_rle_rgbe"), 15, "32-bit_rle_xyze");
  std::ofstream(dir / "xyz.hdr", std::ios::binary) << xyz;
  COMPOSE_EXPECT_ERROR(readImage(dir / "xyz.hdr"),
                       "a Radiance picture in CIE XYZ (FORMAT=32-bit_rle_xyze): compose reads RGB "
                       "ones (FORMAT=32-bit_rle_rgbe); convert it first (Radiance's ra_xyze -r)");
  withHeader("zero.hdr", "EXPOSURE=0\n");
  COMPOSE_EXPECT_ERROR(readImage(dir / "zero.hdr"),
                       "the Radiance header's EXPOSURE is not positive");
}

// A float TIFF whose EXIF ColorSpace is 1 (sRGB), as a raw converter writes it, holds linear
// floats: OpenImageIO calls it sRGB, and it was decoded through the sRGB curve (as the file
// says). The declared space is left to the rules for float samples; an 8-bit one keeps it.
TEST(ImageIo, AFloatTiffIsNotSrgbBecauseItsExifSaysSo) {
  TempDir dir;
  Image img(8, 4, 3, {"R", "G", "B"});
  for (float& v : img.pixels) v = 0.25f;
  WriteOptions options;
  options.depth = WriteOptions::Depth::Float;
  options.attributes.push_back({"Exif:ColorSpace", 1});
  writeImage(dir / "linear.tif", img, options);
  const LoadedImage floats = readImage(dir / "linear.tif");
  EXPECT_EQ(floats.info.fileColorSpace, "");
  options.depth = WriteOptions::Depth::UInt8;
  writeImage(dir / "codes.tif", img, options);
  EXPECT_EQ(readImage(dir / "codes.tif").info.fileColorSpace, "sRGB");
}

// A 16-bit TIFF as a raw converter writes it, built byte by byte (little-endian, uncompressed
// 4 x 2 RGB): its Exif IFD holds ExposureTime 1/100, FNumber 4 and ISO (tag 0x8827) `iso`.
std::vector<unsigned char> tiffWithIso(uint16_t iso) {
  std::vector<unsigned char> b;
  auto u16 = [&](uint32_t v) {
    b.push_back(uint8_t(v));
    b.push_back(uint8_t(v >> 8));
  };
  auto u32 = [&](uint32_t v) {
    u16(v & 0xFFFF);
    u16(v >> 16);
  };
  struct Entry {
    uint16_t tag, type;
    uint32_t count, value;
  };
  auto ifd = [&](const std::vector<Entry>& entries) {
    u16(uint32_t(entries.size()));
    for (const Entry& e : entries) {
      u16(e.tag);
      u16(e.type);
      u32(e.count);
      if (e.type == 3 && e.count == 1) {
        u16(e.value);
        u16(0);
      } else {
        u32(e.value);
      }
    }
    u32(0);
  };
  const uint32_t ifd0 = 8, ifd0Entries = 12, exif = ifd0 + 2 + 12 * ifd0Entries + 4;
  const uint32_t exifEntries = 3, data = exif + 2 + 12 * exifEntries + 4;
  const uint32_t bits = data, exposure = bits + 6, fNumber = exposure + 8, pixels = fNumber + 8;
  const uint32_t pixelBytes = 4 * 2 * 3 * 2;
  b.insert(b.end(), {'I', 'I', 42, 0});
  u32(ifd0);
  ifd({{256, 3, 1, 4},
       {257, 3, 1, 2},
       {258, 3, 3, bits},
       {259, 3, 1, 1},
       {262, 3, 1, 2},
       {273, 4, 1, pixels},
       {274, 3, 1, 1},
       {277, 3, 1, 3},
       {278, 3, 1, 2},
       {279, 4, 1, pixelBytes},
       {284, 3, 1, 1},
       {0x8769, 4, 1, exif}});
  ifd({{0x829A, 5, 1, exposure}, {0x829D, 5, 1, fNumber}, {0x8827, 3, 1, iso}});
  for (int i = 0; i < 3; ++i) u16(16);
  for (uint32_t v : {1u, 100u, 4u, 1u}) u32(v);
  for (uint32_t i = 0; i < pixelBytes / 2; ++i) u16(30000);
  return b;
}

// OpenImageIO 2.4's TIFF reader leaves out the ISO of a TIFF's Exif IFD: the exposure of a
// raw converter's TIFF (time x ISO / N^2) must still take it, from the file and from memory.
TEST(ImageIo, ATiffsIsoIsRead) {
  TempDir dir;
  const std::vector<unsigned char> bytes = tiffWithIso(800);
  {
    std::ofstream out(dir / "iso800.tif", std::ios::binary);
    out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
  }
  const CaptureInfo header = readCaptureInfo(dir / "iso800.tif");
  ASSERT_TRUE(header.exposureTime && header.fNumber);
  EXPECT_NEAR(*header.exposureTime, 0.01, 1e-8);  // OpenImageIO reads it as a float
  ASSERT_TRUE(header.iso);
  EXPECT_EQ(*header.iso, 800.0);
  EXPECT_TRUE(header.exposureAssumptions().empty()) << header.exposureAssumptions();
  const LoadedImage file = readImage(dir / "iso800.tif");
  ASSERT_TRUE(file.info.iso);
  EXPECT_EQ(*file.info.iso, 800.0);
  ASSERT_TRUE(file.info.relativeExposure());
  EXPECT_NEAR(*file.info.relativeExposure(), 0.01 * 800.0 / 16.0, 1e-6);
  ASSERT_EQ(file.image.width, 4);
  EXPECT_NEAR(file.image.pixels[0], 30000.0f / 65535.0f, 1e-6f);
  const LoadedImage memory = readImageFromMemory(bytes, "iso800.tif");
  ASSERT_TRUE(memory.info.iso);
  EXPECT_EQ(*memory.info.iso, 800.0);
}

// A photo resized by a tool that keeps its EXIF keeps the focal-plane resolution of the sensor's
// pixels and the PixelXDimension x PixelYDimension they count: the sensor is that many pixels at
// that resolution (ExifTool's rule), not the resized image's (which gave a sensor a twentieth
// the size for this 64x48 copy of a 1280x960 photo, and a 35 mm equivalent of 461 mm).
TEST(ImageIo, AResizedPhotosSensorIsCountedInItsExifPixels) {
  TempDir dir;
  Image img(64, 48, 3);
  for (float& v : img.pixels) v = 0.5f;
  WriteOptions options;
  options.depth = WriteOptions::Depth::UInt8;
  const double perInch = 1280.0 / (36.0 / 25.4);  // a 36 x 27 mm sensor of 1280 x 960 pixels
  options.attributes = {{"Exif:FocalLength", 24.0},
                        {"Exif:FocalPlaneXResolution", perInch},
                        {"Exif:FocalPlaneYResolution", perInch},
                        {"Exif:FocalPlaneResolutionUnit", 2},
                        {"Exif:PixelXDimension", 1280},
                        {"Exif:PixelYDimension", 960}};
  writeImage(dir / "resized.jpg", img, options);
  const double expected = 24.0 * 43.266615305567875 / 45.0;  // the sensor's diagonal is 45 mm
  for (const CaptureInfo& info :
       {readCaptureInfo(dir / "resized.jpg"), readImage(dir / "resized.jpg").info}) {
    ASSERT_TRUE(info.focalLength35mm);
    EXPECT_NEAR(*info.focalLength35mm, expected, 0.01) << info.focal35mmSource;
  }
  // Without the pixel counts, the image's own size is all there is.
  options.attributes.resize(4);
  writeImage(dir / "plain.jpg", img, options);
  const CaptureInfo plain = readCaptureInfo(dir / "plain.jpg");
  ASSERT_TRUE(plain.focalLength35mm);
  EXPECT_NEAR(*plain.focalLength35mm, expected * 20.0, 0.2);
}

// Luminance-chroma (Y, RY, BY) is made RGB with the weights of the file's primaries, as
// OpenEXR's RgbaYca does: Rec. 709's for an ACES (AP0) file made green 38 % too bright. The
// weights are OpenEXR's computeYw: Rec. 709's and AP0's published luminance rows.
TEST(ImageIo, LuminanceChromaIsDecodedWithTheFilesPrimaries) {
  const std::array<float, 3> rec709 =
      luminanceWeights({0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290});
  EXPECT_NEAR(rec709[0], 0.2126f, 1e-4f);
  EXPECT_NEAR(rec709[1], 0.7152f, 1e-4f);
  EXPECT_NEAR(rec709[2], 0.0722f, 1e-4f);
  const std::array<double, 8> ap0 = {0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.0770, 0.32168, 0.33767};
  const std::array<float, 3> w = luminanceWeights(ap0);
  EXPECT_NEAR(w[0], 0.3439664498f, 1e-6f);
  EXPECT_NEAR(w[1], 0.7281660966f, 1e-6f);
  EXPECT_NEAR(w[2], -0.0721325464f, 1e-6f);

  TempDir dir;
  const float r = 0.5f, g = 0.2f, b = 0.1f;
  const float y = w[0] * r + w[1] * g + w[2] * b;
  Image yc(2, 1, 4, {"A", "BY", "RY", "Y"});
  for (size_t i = 0; i < 2; ++i) {
    const float px[4] = {1.0f, (b - y) / y, (r - y) / y, y};
    std::copy_n(px, 4, &yc.pixels[4 * i]);
  }
  WriteOptions options;
  options.depth = WriteOptions::Depth::Float;
  options.chromaticities = ap0;
  writeImage(dir / "yca.exr", yc, options);
  const LoadedImage read = readImage(dir / "yca.exr");
  const PictureChannels picture = pictureChannels(read.image);
  ASSERT_EQ(picture.kind, PictureChannels::Kind::Rgb);
  const float* p = read.image.at(1, 0);
  EXPECT_NEAR(p[picture.colour[0]], r, 1e-5f);
  EXPECT_NEAR(p[picture.colour[1]], g, 1e-5f);
  EXPECT_NEAR(p[picture.colour[2]], b, 1e-5f);
  EXPECT_EQ(p[picture.alpha], 1.0f);
}

// Which display images hold sRGB codes (and are tagged so): OpenColorIO 2 configs name the encoding
// by the display, version 1 configs by the view (ACES 1.2's "ACES/sRGB" was said not to be sRGB,
// and its JPEG left untagged).
TEST(ImageIo, SrgbDisplaysAreKnownByDisplayOrView) {
  EXPECT_TRUE(isSrgbEncoded("sRGB"));
  EXPECT_TRUE(isSrgbEncoded("sRGB - Display/ACES 1.0 - SDR Video"));
  EXPECT_TRUE(isSrgbEncoded("ACES/sRGB"));
  EXPECT_TRUE(isSrgbEncoded("default/sRGB"));
  EXPECT_FALSE(isSrgbEncoded("sRGB - Display/Raw"));
  EXPECT_FALSE(isSrgbEncoded("default/None"));
  EXPECT_FALSE(isSrgbEncoded("Display P3/Standard"));
  EXPECT_FALSE(isSrgbEncoded("ACEScg"));
}

}  // namespace
}  // namespace compose::ingest
