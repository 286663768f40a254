// OpenEXR and JPEG read and written without OpenImageIO (exr_io.h, jpeg_io.h, exif.h) give what
// OpenImageIO gives: the same pixels, channel order and metadata, and files OpenImageIO reads as
// it reads its own. OpenImageIO is the reference here (the tests link it; compose's programs load
// it only for other formats).
#include <sys/wait.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>
#include <random>

#include <Imath/half.h>
#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <jpeglib.h>

#include "core/output_files.h"
#include "ingest/exif.h"
#include "ingest/exr_io.h"
#include "ingest/image_io.h"
#include "ingest/jpeg_io.h"
#include "test_util.h"

namespace compose::ingest {
namespace {

using compose::testing::TempDir;

// A picture with detail at every scale (JPEG's blocks see edges, gradients and noise).
std::vector<float> photoLike(int w, int h, int c, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> noise(-0.08f, 0.08f);
  std::vector<float> px(size_t(w) * size_t(h) * size_t(c));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (int k = 0; k < c; ++k) {
        const float v = 0.5f + 0.4f * std::sin(0.07f * float(x * (k + 1)) + 0.05f * float(y)) +
                        (((x / 9 + y / 7) % 2) ? 0.1f : -0.1f) + noise(rng);
        px[(size_t(y) * size_t(w) + size_t(x)) * size_t(c) + size_t(k)] = std::clamp(v, 0.0f, 1.0f);
      }
  return px;
}

// Writes with OpenImageIO.
void oiioWrite(const std::filesystem::path& file, int w, int h, int c, OIIO::TypeDesc type,
               const std::vector<float>& px, const std::vector<ImageAttribute>& attributes = {},
               const char* compression = nullptr) {
  auto out = OIIO::ImageOutput::create(file.string());
  ASSERT_TRUE(out);
  OIIO::ImageSpec spec(w, h, c, type);
  if (compression) spec.attribute("Compression", compression);
  for (const ImageAttribute& a : attributes) {
    if (const int* i = std::get_if<int>(&a.value)) spec.attribute(a.name, *i);
    // OpenImageIO 2.4's JPEG EXIF writer turns exact binary fractions (1/64 s) into an infinite
    // rational; one step up in float avoids that, as compose's writer did when it used it.
    if (const double* d = std::get_if<double>(&a.value))
      spec.attribute(a.name, std::nextafter(float(*d), std::numeric_limits<float>::infinity()));
    if (const std::string* t = std::get_if<std::string>(&a.value)) spec.attribute(a.name, *t);
  }
  ASSERT_TRUE(out->open(file.string(), spec));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
  ASSERT_TRUE(out->close());
}

// Reads with OpenImageIO: floats, and the spec.
std::vector<float> oiioRead(const std::filesystem::path& file, OIIO::ImageSpec* specOut = nullptr,
                            int subimage = 0) {
  auto in = OIIO::ImageInput::open(file.string());
  EXPECT_TRUE(in) << OIIO::geterror();
  if (!in) return {};
  EXPECT_TRUE(in->seek_subimage(subimage, 0));
  const OIIO::ImageSpec spec = in->spec();
  std::vector<float> px(size_t(spec.width) * size_t(spec.height) * size_t(spec.nchannels));
  EXPECT_TRUE(in->read_image(subimage, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, px.data()));
  if (specOut) *specOut = spec;
  return px;
}

TEST(NativeJpeg, DecodesTheSamePixelsAsOpenImageIO) {
  TempDir dir;
  for (const auto& [w, h, c] : {std::tuple{97, 61, 3}, std::tuple{64, 33, 1}}) {
    const auto file = dir / ("photo" + std::to_string(c) + ".jpg");
    oiioWrite(file, w, h, c, OIIO::TypeDesc::UINT8, photoLike(w, h, c, 7), {}, "jpeg:90");
    const std::vector<float> reference = oiioRead(file);
    const LoadedImage ours = readImage(file);
    EXPECT_EQ(ours.info.format, "jpeg");
    EXPECT_EQ(ours.image.colorSpace, "sRGB");
    ASSERT_EQ(ours.image.channels, c);
    // Bit for bit, floats included (code · (1/255) as OpenImageIO rounds it).
    ASSERT_EQ(ours.image.pixels.size(), reference.size());
    EXPECT_TRUE(std::equal(reference.begin(), reference.end(), ours.image.pixels.begin()));
    const std::vector<std::string> names =
        c == 1 ? std::vector<std::string>{"Y"} : std::vector<std::string>{"R", "G", "B"};
    EXPECT_EQ(ours.image.channelNames, names);
    ReadOptions codes;
    codes.codesForEightBit = true;
    const LoadedImage asCodes = readImage(file, "ingest", codes);
    ASSERT_EQ(asCodes.codes.size(), reference.size());
    for (size_t i = 0; i < reference.size(); ++i)
      ASSERT_EQ(asCodes.codes[i], int(std::lround(reference[i] * 255.0f))) << i;
  }
}

TEST(NativeJpeg, EncodesAsOpenImageIODoes) {
  // The same quality, subsampling and rounding: OpenImageIO's and our files decode to the same
  // pixels.
  TempDir dir;
  const int w = 83, h = 57;
  Image img(w, h, 3, {"R", "G", "B"});
  const std::vector<float> px = photoLike(w, h, 3, 11);
  std::copy(px.begin(), px.end(), img.pixels.begin());
  img.pixels[5] = -0.2f;  // clamped
  img.pixels[8] = 1.7f;
  WriteOptions options;
  options.jpegQuality = 87;
  writeImage(dir / "ours.jpg", img, options);
  std::vector<float> same(img.pixels.begin(), img.pixels.end());
  oiioWrite(dir / "theirs.jpg", w, h, 3, OIIO::TypeDesc::UINT8, same, {}, "jpeg:87");
  EXPECT_EQ(oiioRead(dir / "ours.jpg"), oiioRead(dir / "theirs.jpg"));
}

TEST(NativeJpeg, ExifWrittenByEitherIsReadTheSameByBoth) {
  TempDir dir;
  CaptureInfo info;
  info.exposureTime = 1.0 / 64.0;
  info.fNumber = 5.6;
  info.iso = 400;
  info.focalLengthMm = 4.25;
  info.focalPlaneXResolution = 16.0 / (4.8 / 25.4);  // a 4.8 mm wide sensor, in pixels per inch
  info.focalPlaneYResolution = *info.focalPlaneXResolution;
  info.focalPlaneResolutionUnit = 2;
  info.cameraMake = "Virtual";
  info.cameraModel = "Camera 3";
  info.dateTimeOriginal = "2024:06:01 12:30:05.25";
  const std::vector<ImageAttribute> attributes = exifAttributes(info);
  Image img(16, 8, 3);
  WriteOptions options;
  options.attributes = attributes;
  writeImage(dir / "ours.jpg", img, options);
  oiioWrite(dir / "theirs.jpg", 16, 8, 3, OIIO::TypeDesc::UINT8,
            std::vector<float>(16 * 8 * 3, 0.0f), attributes);
  for (const char* name : {"ours.jpg", "theirs.jpg"}) {
    SCOPED_TRACE(name);
    const CaptureInfo ours = readCaptureInfo(dir / name);
    OIIO::ImageSpec spec;
    oiioRead(dir / name, &spec);
    ASSERT_TRUE(ours.exposureTime && ours.fNumber && ours.iso && ours.focalLengthMm);
    EXPECT_NEAR(*ours.exposureTime, spec.get_float_attribute("ExposureTime"), 1e-7);
    EXPECT_NEAR(*ours.exposureTime, 1.0 / 64.0, 1e-6);
    EXPECT_NEAR(*ours.fNumber, spec.get_float_attribute("FNumber"), 1e-5);
    EXPECT_EQ(*ours.iso, 400.0);
    EXPECT_NEAR(*ours.focalLengthMm, 4.25, 1e-5);
    EXPECT_EQ(ours.cameraMake, "Virtual");
    EXPECT_EQ(ours.cameraModel, "Camera 3");
    EXPECT_EQ(ours.dateTimeOriginal, "2024:06:01 12:30:05");
    EXPECT_EQ(ours.dateTimeOriginal, spec.get_string_attribute("Exif:DateTimeOriginal"));
    ASSERT_TRUE(ours.focalLength35mm);  // derived from the focal-plane resolution
    ASSERT_TRUE(ours.captureSeconds);
    EXPECT_NEAR(std::fmod(*ours.captureSeconds, 60.0), 5.25, 1e-6);
    EXPECT_NEAR(*ours.focalPlaneXResolution, spec.get_float_attribute("Exif:FocalPlaneXResolution"),
                1e-2);
  }
  // Exposure times are exact fractions in our files (1/64 s is 1/64, not a float's rational).
  std::ifstream in(dir / "ours.jpg", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string oneOver64 = {0, 0, 0, 1, 0, 0, 0, 64};
  EXPECT_NE(bytes.find(oneOver64), std::string::npos);
}

// Values EXIF's plain tags cannot hold as such: ISO above 65535 goes to ISOSpeed (the 16-bit tag
// holds 65535, as cameras write ISO 102400; it was dropped, and read as ISO 100), and exposure
// times below a microsecond or not 1/n are the closest 32-bit fraction (1.5e-7 s was written as
// 0, 3e-6 s as 2e-6 s), in our JPEGs and as OpenImageIO reads them. A TIFF keeps the ISO in
// ISOSpeed (OpenImageIO 2.4's TIFF writer drops PhotographicSensitivity: capture-sim's 16-bit
// photos were read as ISO 100).
TEST(NativeJpeg, ExifHoldsHighIsoAndShortExposures) {
  TempDir dir;
  int n = 0;  // a file each: one read is not written over
  for (const double iso : {100.0, 400.0, 65535.0, 102400.0, 409600.0}) {
    for (const double t : {1.5e-7, 3e-6, 1e-9, 1.0 / 3.0, 2.5, 3600.0}) {
      for (const char* format : {".jpg", ".tif"}) {
        const bool tiff = std::string(format) == ".tif";
        if (tiff && t < 1e-3) continue;  // OpenImageIO's own rationals
        CaptureInfo info;
        info.exposureTime = t;
        info.iso = iso;
        WriteOptions options;
        options.attributes = exifAttributes(info);
        const std::filesystem::path file = dir / (std::to_string(n++) + format);
        writeImage(file, Image(8, 8, 3), options);
        SCOPED_TRACE(std::string(format) + ", ISO " + std::to_string(iso) + ", " +
                     std::to_string(t) + " s");
        const CaptureInfo back = readCaptureInfo(file);
        ASSERT_TRUE(back.iso && back.exposureTime);
        EXPECT_EQ(*back.iso, iso);
        EXPECT_NEAR(*back.exposureTime, t, (tiff ? 1e-6 : 1e-9) * t);
        if (tiff) continue;
        OIIO::ImageSpec spec;
        oiioRead(file, &spec);
        EXPECT_NEAR(spec.get_float_attribute("ExposureTime"), t, 1e-6 * t);
      }
    }
  }
}

// Orientations 1-4, 6 and 8 as OpenImageIO turns them. 5 and 7 as EXIF defines them (5: the
// stored rows are the picture's columns, a transpose; 7: the transverse): OpenImageIO 2.4 has the
// two swapped (fixed upstream in OpenImageIO #5350, "reorient() cases for transpose and
// transverse"), so that a mirrored portrait came out mirrored the other way.
TEST(NativeJpeg, OrientationTurnsThePictureAsExifSays) {
  TempDir dir;
  const int w = 5, h = 3;
  std::vector<float> px(size_t(w) * h * 3);
  for (size_t i = 0; i < px.size(); ++i) px[i] = float(i % 251) / 250.0f;
  for (int orientation = 1; orientation <= 8; ++orientation) {
    SCOPED_TRACE(orientation);
    const auto file = dir / ("o" + std::to_string(orientation) + ".jpg");
    oiioWrite(file, w, h, 3, OIIO::TypeDesc::UINT8, px, {{"Orientation", orientation}}, "jpeg:100");
    OIIO::ImageBuf stored(file.string());
    ASSERT_TRUE(stored.read(0, 0, true, OIIO::TypeDesc::FLOAT));
    OIIO::ImageBuf upright;
    if (orientation == 5 || orientation == 7) {
      // Transpose, then for 7 turn by 180°: the transverse.
      OIIO::ImageBuf turned = OIIO::ImageBufAlgo::rotate90(stored);
      upright = OIIO::ImageBufAlgo::flop(turned);
      if (orientation == 7) upright = OIIO::ImageBufAlgo::rotate180(upright);
    } else {
      upright = OIIO::ImageBufAlgo::reorient(stored);
    }
    const LoadedImage ours = readImage(file);
    ASSERT_EQ(ours.image.width, upright.spec().width);
    ASSERT_EQ(ours.image.height, upright.spec().height);
    std::vector<float> want(ours.image.pixels.size());
    ASSERT_TRUE(upright.get_pixels(upright.roi(), OIIO::TypeDesc::FLOAT, want.data()));
    EXPECT_TRUE(std::equal(want.begin(), want.end(), ours.image.pixels.begin()));
    // The stored top-left pixel lands where EXIF says: the picture's top-left for 1 and 5, top
    // right for 2 and 6, bottom right for 3 and 7, bottom left for 4 and 8.
    const int W = ours.image.width, H = ours.image.height;
    const int corner[9][2] = {{0, 0}, {0, 0},     {W - 1, 0},     {W - 1, H - 1}, {0, H - 1},
                              {0, 0}, {W - 1, 0}, {W - 1, H - 1}, {0, H - 1}};
    const float* at = ours.image.at(corner[orientation][0], corner[orientation][1]);
    EXPECT_NEAR(at[0], px[0], 0.02f);
    EXPECT_NEAR(at[1], px[1], 0.02f);
  }
}

// A CMYK JPEG, which libjpeg does not convert, is OpenImageIO's: its header too, so that
// readCaptureInfo() gives the facts readImage() does (OpenImageIO hands EXIF rationals over as
// floats; the plate's camera is keyed by the header and checked against the decoded plate).
TEST(NativeJpeg, ACmykFilesHeaderGivesWhatReadingItGives) {
  TempDir dir;
  const std::filesystem::path file = dir / "cmyk.jpg";
  {
    const std::vector<unsigned char> tiff = exif::encode({{"Exif:FocalLength", 5.6},
                                                          {"Exif:FocalPlaneXResolution", 3333.3},
                                                          {"Exif:FocalPlaneYResolution", 3333.3},
                                                          {"Exif:FocalPlaneResolutionUnit", 2}});
    std::vector<unsigned char> app1 = {'E', 'x', 'i', 'f', 0, 0};
    app1.insert(app1.end(), tiff.begin(), tiff.end());
    jpeg_compress_struct c{};
    jpeg_error_mgr e{};
    c.err = jpeg_std_error(&e);
    jpeg_create_compress(&c);
    unsigned char* bytes = nullptr;
    unsigned long size = 0;
    jpeg_mem_dest(&c, &bytes, &size);
    c.image_width = 64;
    c.image_height = 48;
    c.input_components = 4;
    c.in_color_space = JCS_CMYK;
    jpeg_set_defaults(&c);
    jpeg_start_compress(&c, TRUE);
    jpeg_write_marker(&c, JPEG_APP0 + 1, app1.data(), unsigned(app1.size()));
    std::vector<unsigned char> row(64 * 4);
    for (size_t i = 0; i < row.size(); ++i) row[i] = i % 4 == 3 ? 40 : 100;
    while (c.next_scanline < c.image_height) {
      JSAMPROW r = row.data();
      jpeg_write_scanlines(&c, &r, 1);
    }
    jpeg_finish_compress(&c);
    jpeg_destroy_compress(&c);
    std::ofstream(file, std::ios::binary).write(reinterpret_cast<const char*>(bytes), long(size));
    std::free(bytes);
  }
  ASSERT_FALSE(jpeg::readFile(file, true, "test").header.native);
  const CaptureInfo header = readCaptureInfo(file);
  const LoadedImage read = readImage(file);
  ASSERT_TRUE(read.info.focalLength35mm.has_value());
  EXPECT_EQ(header.focalLength35mm, read.info.focalLength35mm);
  EXPECT_EQ(header.focal35mmSource, read.info.focal35mmSource);
  EXPECT_EQ(header.focalLengthMm, read.info.focalLengthMm);
  EXPECT_EQ(header.fileWidth, read.image.width);
  EXPECT_EQ(header.fileHeight, read.image.height);
}

TEST(NativeJpeg, DamagedFilesAreErrorsNamingThem) {
  TempDir dir;
  oiioWrite(dir / "good.jpg", 64, 64, 3, OIIO::TypeDesc::UINT8, photoLike(64, 64, 3, 3), {},
            "jpeg:90");
  std::ifstream in(dir / "good.jpg", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  {
    std::ofstream(dir / "cut.jpg", std::ios::binary) << bytes.substr(0, bytes.size() * 2 / 3);
    try {
      readImage(dir / "cut.jpg");
      FAIL() << "a truncated JPEG was read";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("truncated file"), std::string::npos) << e.what();
      EXPECT_EQ(e.file(), dir / "cut.jpg");
    }
  }
  {
    std::ofstream(dir / "header.jpg", std::ios::binary) << bytes.substr(0, 40);
    EXPECT_THROW(readImage(dir / "header.jpg"), Error);
  }
}

// EXIF blocks from anywhere: no prefix, offset or count makes the decoder read outside the block.
TEST(Exif, DamagedBlocksYieldWhatCameBeforeTheDamage) {
  const std::vector<ImageAttribute> attributes = {
      {"Make", std::string("Maker")},
      {"Model", std::string("M1")},
      {"Orientation", 6},
      {"ExposureTime", 0.004},
      {"FNumber", 2.8},
      {"Exif:PhotographicSensitivity", 200},
      {"Exif:FocalLength", 35.0},
      {"Exif:FocalLengthIn35mmFilm", 50},
      {"Exif:DateTimeOriginal", std::string("2020:01:02 03:04:05")}};
  const std::vector<unsigned char> block = exif::encode(attributes);
  const std::vector<ImageAttribute> whole = exif::decode(block);
  ASSERT_EQ(whole.size(), attributes.size());
  for (const ImageAttribute& a : attributes) {
    const auto it = std::find_if(whole.begin(), whole.end(),
                                 [&](const ImageAttribute& b) { return b.name == a.name; });
    ASSERT_NE(it, whole.end()) << a.name;
    if (const double* d = std::get_if<double>(&a.value)) {
      EXPECT_NEAR(std::get<double>(it->value), *d, 1e-9) << a.name;
    } else {
      EXPECT_EQ(it->value, a.value) << a.name;
    }
  }
  // Every prefix, and every byte changed to 0xFF, decodes to a subset of the entries.
  for (size_t n = 0; n < block.size(); ++n) {
    const std::vector<ImageAttribute> part =
        exif::decode(std::span<const unsigned char>(block.data(), n));
    EXPECT_LE(part.size(), whole.size());
    std::vector<unsigned char> broken = block;
    broken[n] = 0xFF;
    EXPECT_LE(exif::decode(broken).size(), whole.size());
  }
  // An Exif pointer that points back to IFD0 is not followed round: the Exif IFD's entries are
  // then simply missing. (The block is big-endian: IFD0 at 8, entries of 12 bytes after a count.)
  std::vector<unsigned char> loop = block;
  const size_t entries = size_t(loop[8]) << 8 | loop[9];
  bool patched = false;
  for (size_t e = 0; e < entries; ++e) {
    unsigned char* entry = loop.data() + 10 + 12 * e;
    if (entry[0] == 0x87 && entry[1] == 0x69) {
      entry[8] = entry[9] = entry[10] = 0;
      entry[11] = 8;
      patched = true;
    }
  }
  ASSERT_TRUE(patched);
  const std::vector<ImageAttribute> once = exif::decode(loop);
  EXPECT_EQ(once.size(), 3u);  // Make, Model, Orientation
}

// Other writers: the Exif pointer typed IFD (13) rather than LONG, and an Exif tag in IFD0.
TEST(Exif, ReadsWhatOtherWritersLayOutDifferently) {
  std::vector<unsigned char> block =
      exif::encode({{"Make", std::string("M")}, {"ExposureTime", 0.5}});
  const size_t entries = size_t(block[8]) << 8 | block[9];
  for (size_t e = 0; e < entries; ++e) {
    unsigned char* entry = block.data() + 10 + 12 * e;
    if (entry[0] == 0x87 && entry[1] == 0x69) entry[3] = 13;  // type IFD
  }
  std::vector<ImageAttribute> got = exif::decode(block);
  ASSERT_EQ(got.size(), 2u);
  EXPECT_EQ(got[1].name, "ExposureTime");
  // "MM", 42, IFD0 at 8: one entry (ExposureTime, RATIONAL, 1, value at 26), no next IFD, 1/250.
  const std::vector<unsigned char> inZero = {'M', 'M', 0, 42, 0, 0, 0, 8, 0, 1,  0x82, 0x9A,
                                             0,   5,   0, 0,  0, 1, 0, 0, 0, 26, 0,    0,
                                             0,   0,   0, 0,  0, 1, 0, 0, 0, 250};
  got = exif::decode(inZero);
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].name, "ExposureTime");
  EXPECT_DOUBLE_EQ(std::get<double>(got[0].value), 1.0 / 250.0);
}

TEST(NativeExr, IntegerChannelsAndTypesAsOpenImageIOReadsThem) {
  TempDir dir;
  const auto file = dir / "ids.exr";
  {
    auto out = OIIO::ImageOutput::create(file.string());
    ASSERT_TRUE(out);
    OIIO::ImageSpec spec(3, 2, 4, OIIO::TypeDesc::HALF);
    spec.channelnames = {"R", "G", "B", "id"};
    spec.channelformats = {OIIO::TypeDesc::HALF, OIIO::TypeDesc::HALF, OIIO::TypeDesc::HALF,
                           OIIO::TypeDesc::UINT};
    ASSERT_TRUE(out->open(file.string(), spec));
    std::vector<unsigned char> native;
    for (int p = 0; p < 6; ++p) {
      for (int c = 0; c < 3; ++c) {
        const Imath::half h(0.25f * float(p + c));
        const auto* b = reinterpret_cast<const unsigned char*>(&h);
        native.insert(native.end(), b, b + 2);
      }
      const uint32_t id = p == 5 ? 4294967295u : uint32_t(p * 1000);
      const auto* b = reinterpret_cast<const unsigned char*>(&id);
      native.insert(native.end(), b, b + 4);
    }
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UNKNOWN, native.data()));
    ASSERT_TRUE(out->close());
  }
  OIIO::ImageSpec spec;
  const std::vector<float> want = oiioRead(file, &spec);
  const LoadedImage ours = readImage(file);
  EXPECT_EQ(ours.info.sampleType, "float");  // half and uint merge to float, as in OpenImageIO
  EXPECT_EQ(ours.info.sampleType, spec.format.c_str());
  ASSERT_EQ(ours.image.pixels.size(), want.size());
  for (size_t i = 0; i < want.size(); ++i)
    EXPECT_NEAR(ours.image.pixels[i], want[i], 1e-6f * std::max(1.0f, std::abs(want[i]))) << i;
  EXPECT_EQ(ours.image.pixels[5 * 4 + 3], 1.0f);  // the largest id is 1.0
}

TEST(NativeIo, TooShortOrUnreadableFilesAreNamedErrors) {
  TempDir dir;
  compose::testing::writeText(dir / "two.jpg", "\xff\xd8");
  COMPOSE_EXPECT_ERROR(readImage(dir / "two.jpg"), "not an image file (2 bytes)");
}

// Writes a multi-part OpenEXR with OpenImageIO: channel names out of order, a layer with X Y Z,
// a data window inside the display window, and metadata under OpenImageIO's names.
void writeOiioMultiPart(const std::filesystem::path& file) {
  auto out = OIIO::ImageOutput::create(file.string());
  ASSERT_TRUE(out);
  OIIO::ImageSpec a(6, 4, 5, OIIO::TypeDesc::HALF);
  a.channelnames = {"B", "A", "G", "R", "Z"};
  a.attribute("name", "beauty");
  a.attribute("ExposureTime", 0.125f);
  a.attribute("colorSpace", "ACEScg");
  const float xy[8] = {0.713f, 0.293f, 0.165f, 0.83f, 0.128f, 0.044f, 0.32168f, 0.33767f};
  a.attribute("chromaticities", OIIO::TypeDesc(OIIO::TypeDesc::FLOAT, 8), xy);
  OIIO::ImageSpec b(3, 2, 7, OIIO::TypeDesc::FLOAT);
  b.x = 2;
  b.y = 1;
  b.full_width = 6;
  b.full_height = 4;
  b.channelnames = {"N.Z", "N.X", "N.Y", "depth.Z", "obj.A", "obj.R", "AO"};
  b.attribute("name", "aovs");
  OIIO::ImageSpec specs[2] = {a, b};
  ASSERT_TRUE(out->open(file.string(), 2, specs));
  std::vector<float> pa(6 * 4 * 5), pb(3 * 2 * 7);
  for (size_t i = 0; i < pa.size(); ++i) pa[i] = float(i) * 0.25f;
  for (size_t i = 0; i < pb.size(); ++i) pb[i] = 1000.0f + float(i);
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, pa.data()));
  ASSERT_TRUE(out->open(file.string(), b, OIIO::ImageOutput::AppendSubimage));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, pb.data()));
  ASSERT_TRUE(out->close());
}

TEST(NativeExr, ReadsOpenImageIOsFilesAsOpenImageIODoes) {
  TempDir dir;
  const auto file = dir / "parts.exr";
  writeOiioMultiPart(file);
  const ExrReader reader(file, "ingest");
  ASSERT_EQ(reader.parts(), 2);
  for (int part = 0; part < 2; ++part) {
    SCOPED_TRACE(part);
    OIIO::ImageSpec spec;
    const std::vector<float> want = oiioRead(file, &spec, part);
    const ExrPartHeader& h = reader.header(part);
    EXPECT_EQ(h.name, spec.get_string_attribute("name"));
    EXPECT_EQ(h.channelNames, spec.channelnames);
    EXPECT_EQ(h.x, spec.x);
    EXPECT_EQ(h.y, spec.y);
    EXPECT_EQ(h.width, spec.width);
    EXPECT_EQ(h.fullWidth, spec.full_width);
    EXPECT_EQ(h.fullHeight, spec.full_height);
    const Image got = reader.read(part);
    ASSERT_EQ(got.pixels.size(), want.size());
    EXPECT_TRUE(std::equal(want.begin(), want.end(), got.pixels.begin()));
  }
  // The first part's metadata through readImage, as CaptureInfo reads it.
  const LoadedImage image = readImage(file);
  EXPECT_EQ(image.image.channelNames, (std::vector<std::string>{"R", "G", "B", "A", "Z"}));
  EXPECT_EQ(image.info.fileColorSpace, "ACEScg");
  ASSERT_TRUE(image.info.exposureTime);
  EXPECT_EQ(*image.info.exposureTime, 0.125);
  ASSERT_TRUE(image.info.chromaticities);
  EXPECT_NEAR((*image.info.chromaticities)[6], 0.32168, 1e-6);
  EXPECT_EQ(image.info.sampleType, "half");
}

TEST(NativeExr, WritesFilesOpenImageIOReadsAsWritten) {
  TempDir dir;
  const auto file = dir / "ours.exr";
  Image beauty(4, 3, 3, {"R", "G", "B"});
  Image aovs(4, 3, 2, {"N.X", "N.Y"});
  for (size_t i = 0; i < beauty.pixels.size(); ++i) beauty.pixels[i] = 0.1f * float(i);
  for (size_t i = 0; i < aovs.pixels.size(); ++i) aovs.pixels[i] = -0.5f * float(i);
  beauty.colorSpace = "ACEScg";
  Image big(2, 2, 1, {"Y"});
  big.pixels = {1.0f, 70000.0f, 2.0f, 3.0f};  // beyond half: the part is written as float
  ExrPart first("object", &beauty, 5, 7, 20, 10);
  first.moreImages = {&aovs};
  first.constantChannels = {{"A", 1.0f}};
  first.options.exrCompression = "piz";
  first.options.chromaticities =
      std::array<double, 8>{0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329};
  ExrPart second("big", &big, 0, 0, 20, 10);  // the parts of a file share the display window
  ExrHeader header;
  header.strings = {{"compose:note", "hello"}};
  std::array<float, 16> m{};
  for (size_t i = 0; i < 16; ++i) m[i] = float(i);
  header.matrices = {{"worldToCamera", m}};
  OutputFiles outputs("output");
  const std::vector<WriteReport> reports = writeExrParts(outputs, file, {first, second}, header);
  outputs.commit();
  ASSERT_EQ(reports.size(), 2u);
  EXPECT_FALSE(reports[0].promotedToFloat);
  EXPECT_TRUE(reports[1].promotedToFloat);

  OIIO::ImageSpec spec;
  const std::vector<float> got = oiioRead(file, &spec, 0);
  EXPECT_EQ(spec.channelnames, (std::vector<std::string>{"R", "G", "B", "A", "N.X", "N.Y"}));
  EXPECT_EQ(spec.x, 5);
  EXPECT_EQ(spec.y, 7);
  EXPECT_EQ(spec.full_width, 20);
  EXPECT_EQ(spec.get_string_attribute("name"), "object");
  EXPECT_EQ(spec.get_string_attribute("colorSpace"), "ACEScg");
  EXPECT_EQ(spec.get_string_attribute("compression"), "piz");
  EXPECT_EQ(spec.get_string_attribute("compose:note"), "hello");
  EXPECT_NE(spec.find_attribute("worldToCamera", OIIO::TypeMatrix), nullptr);
  EXPECT_NE(spec.find_attribute("chromaticities"), nullptr);
  ASSERT_EQ(got.size(), size_t(4 * 3 * 6));
  for (size_t p = 0; p < 12; ++p) {
    for (size_t c = 0; c < 3; ++c)
      EXPECT_EQ(got[p * 6 + c], float(Imath::half(beauty.pixels[p * 3 + c])));
    EXPECT_EQ(got[p * 6 + 3], 1.0f);
    for (size_t c = 0; c < 2; ++c)
      EXPECT_EQ(got[p * 6 + 4 + c], float(Imath::half(aovs.pixels[p * 2 + c])));
  }
  const std::vector<float> second_ = oiioRead(file, &spec, 1);
  EXPECT_EQ(spec.format, OIIO::TypeDesc::FLOAT);
  EXPECT_EQ(second_, (std::vector<float>{1.0f, 70000.0f, 2.0f, 3.0f}));
}

TEST(NativeExr, EveryCompressionIsWrittenAsNamedAndTheLosslessOnesKeepEveryValue) {
  TempDir dir;
  // A smooth ramp with noise, in half's range: what every codec meets in a composite.
  Image image(67, 41, 3, {"R", "G", "B"});
  uint32_t state = 12345u;
  for (size_t i = 0; i < image.pixels.size(); ++i) {
    state = state * 1664525u + 1013904223u;
    image.pixels[i] = 0.05f + 2.0f * float(i % 67) / 67.0f + float(state >> 8) * 1e-8f;
  }
  const std::vector<std::pair<std::string, std::string>> codecs = {
      {"none", "none"}, {"rle", "rle"},   {"zips", "zips"},    {"zip", "zip"},
      {"zip:1", "zip"}, {"zip:9", "zip"}, {"piz", "piz"},      {"pxr24", "pxr24"},
      {"b44", "b44"},   {"b44a", "b44a"}, {"dwaa:45", "dwaa"}, {"DWAB", "dwab"}};
  for (const auto& [given, stored] : codecs) {
    SCOPED_TRACE(given);
    std::string why;
    const std::optional<ExrCompression> codec = parseExrCompression(given, &why);
    ASSERT_TRUE(codec) << why;
    const std::filesystem::path file = dir / ("c_" + stored + ".exr");
    WriteOptions options;
    options.depth = WriteOptions::Depth::Half;
    options.exrCompression = given;
    writeImage(file, image, options);
    OIIO::ImageSpec spec;
    const std::vector<float> got = oiioRead(file, &spec, 0);
    EXPECT_EQ(spec.get_string_attribute("compression"), stored);
    ASSERT_EQ(got.size(), image.pixels.size());
    double worst = 0.0;
    for (size_t i = 0; i < got.size(); ++i) {
      const float written = float(Imath::half(image.pixels[i]));
      worst = std::max(worst, double(std::abs(got[i] - written)) / double(written));
    }
    // pxr24 keeps half channels whole (it rounds float ones to 24 bits).
    if (!codec->lossy() || stored == "pxr24")
      EXPECT_EQ(worst, 0.0);
    else
      EXPECT_LT(worst, 0.25);  // lossy, but a picture of the same thing
  }
  // The levels reach the codec: zip:0 stores, zip:9 deflates; DWA at 500 keeps less than at 5.
  auto sizeWith = [&](const std::string& codec) {
    WriteOptions options;
    options.depth = WriteOptions::Depth::Half;
    options.exrCompression = codec;
    const std::filesystem::path file = dir / "level.exr";
    writeImage(file, image, options);
    return std::filesystem::file_size(file);
  };
  EXPECT_LT(sizeWith("zip:9"), sizeWith("zip:0"));
  EXPECT_LT(sizeWith("dwaa:500"), sizeWith("dwaa:5"));
  // Names and levels it does not know are refused with what is wrong.
  for (const char* bad :
       {"lzw", "", "zip:10", "zip:-1", "zip:1.5", "zip:", "zip:4x", "piz:2", "dwaa:0", "dwaa:-3",
        "dwaa:abc", "pi z", "zip:+4", "zip:0x9", "dwaa:1e-50", "dwaa:nan", "dwaa:1e7"}) {
    std::string why;
    EXPECT_FALSE(parseExrCompression(bad, &why)) << bad;
    EXPECT_FALSE(why.empty()) << bad;
  }
  Image rgb(4, 4, 3, {"R", "G", "B"});
  WriteOptions options;
  options.exrCompression = "lzw";
  const std::filesystem::path refused = dir / "refused.exr";
  try {
    writeImage(refused, rgb, options);
    ADD_FAILURE() << "an unknown compression was written";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("unknown OpenEXR compression 'lzw'"), std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(std::filesystem::exists(refused));
}

TEST(NativeExr, DamagedFilesAreErrorsNotPartialPictures) {
  TempDir dir;
  Image img(64, 64, 3, {"R", "G", "B"});
  for (size_t i = 0; i < img.pixels.size(); ++i) img.pixels[i] = float(i % 1000);
  writeImage(dir / "good.exr", img);
  std::ifstream in(dir / "good.exr", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  for (const double keep : {0.1, 0.5, 0.9}) {
    SCOPED_TRACE(keep);
    std::ofstream(dir / "cut.exr", std::ios::binary)
        << bytes.substr(0, size_t(double(bytes.size()) * keep));
    try {
      readImage(dir / "cut.exr");
      FAIL() << "a truncated OpenEXR file was read";
    } catch (const Error& e) {
      EXPECT_EQ(e.file(), dir / "cut.exr");
    }
  }
}

// The executable starts without OpenImageIO: it loads the module only for other formats.
TEST(OiioModule, ComposeDoesNotLinkOpenImageIO) {
  const std::string command = std::string("readelf -d '") + COMPOSE_EXECUTABLE + "'";
  FILE* pipe = popen(command.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  std::string dynamic;
  char buffer[4096];
  while (size_t n = std::fread(buffer, 1, sizeof buffer, pipe)) dynamic.append(buffer, n);
  ASSERT_EQ(pclose(pipe), 0) << "readelf failed";
  EXPECT_NE(dynamic.find("NEEDED"), std::string::npos);
  EXPECT_EQ(dynamic.find("libOpenImageIO"), std::string::npos) << dynamic;
}

TEST(OiioModule, OtherFormatsGoThroughIt) {
  TempDir dir;
  Image img(5, 4, 3, {"R", "G", "B"});
  for (size_t i = 0; i < img.pixels.size(); ++i) img.pixels[i] = float(i) / 59.0f;
  WriteOptions sixteen;
  sixteen.depth = WriteOptions::Depth::UInt16;
  writeImage(dir / "a.tif", img, sixteen);
  const LoadedImage back = readImage(dir / "a.tif");
  EXPECT_EQ(back.info.format, "tiff");
  EXPECT_EQ(back.info.bitsPerSample, 16);
  ASSERT_EQ(back.image.pixels.size(), img.pixels.size());
  for (size_t i = 0; i < img.pixels.size(); ++i)
    EXPECT_NEAR(back.image.pixels[i], img.pixels[i], 0.501f / 65535.0f);
}

}  // namespace
}  // namespace compose::ingest
