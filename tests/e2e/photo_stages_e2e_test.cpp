// End-to-end through the compose executable: the virtual camera's photos are ingested and merged
// as a user would, and every bad input the issue lists gives a named error, a non-zero exit
// status and no output.
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include <OpenImageIO/imageio.h>
#include <nlohmann/json.hpp>

#include "command_util.h"
#include "core/channels.h"
#include "hdr/response.h"
#include "ingest/capture.h"
#include "ingest/exr_io.h"
#include "ingest/image_io.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;

// Runs compose with its response store in `dir` (never the user's).
using CommandRun = compose::testing::CommandResult;
using compose::testing::slurp;

std::string q(const fs::path& p) {
  return compose::testing::quote(p);
}

CommandRun compose(const std::string& args, const TempDir& dir) {
  return compose::testing::runCompose(args, dir.path(),
                                      "COMPOSE_RESPONSE_DIR=" + q(dir / "responses"));
}
// Only the files a test put there: no output and no temporary left behind.
std::vector<std::string> filesIn(const fs::path& dir) {
  std::vector<std::string> names;
  if (!fs::exists(dir)) return names;
  for (const auto& e : fs::directory_iterator(dir)) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

#define EXPECT_FAILS_WITH(run, code, needle)                                 \
  do {                                                                       \
    EXPECT_EQ((run).status, code) << (run).err;                              \
    EXPECT_NE((run).err.find(needle), std::string::npos)                     \
        << "stderr: " << (run).err << "\nexpected to contain: " << (needle); \
  } while (0)

// ctest runs every test in a process of its own: the capture is made by the tests that need it.
class PhotoStages : public ::testing::Test {
 protected:
  // A small capture: two views, three exposures 2 EV apart.
  void makeCapture() {
    const CommandRun r = compose(
        "capture-sim --env " + q(pipeline::samplesDirectory() / "interior.exr") + " --out " +
            q(dir_ / "shots") + " --size 160x120 --views 2 --brackets 3 --seed 4",
        dir_);
    ASSERT_EQ(r.status, 0) << r.err;
  }
  fs::path shot(const std::string& name) const { return dir_ / "shots" / name; }
  TempDir dir_;
};

TEST_F(PhotoStages, IngestThenMergeAsAPhotographerWould) {
  makeCapture();
  // ingest prints the EXIF and the grouping, and writes it for merge.
  {
    TempDir dir;
    const CommandRun r =
        compose("ingest --json " + q(dir / "grouped.json") + " " + q(dir_ / "shots"), dir);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_NE(r.out.find("2 views"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("f/"), std::string::npos);
    EXPECT_NE(r.out.find("compose virtual camera"), std::string::npos);
    EXPECT_TRUE(fs::exists(dir / "grouped.json"));
    // The grouping written is a capture description merge can take.
    const CommandRun m =
        compose("merge --capture " + q(dir / "grouped.json") + " --out " + q(dir / "m"), dir);
    EXPECT_EQ(m.status, 0) << m.err;
    // capture-sim's ring (yaw000_1.jpg ...): the views are named for their turn.
    EXPECT_EQ(filesIn(dir / "m"), (std::vector<std::string>{"yaw000.exr", "yaw180.exr"}));

    // Photos named for the cube face they look at give their views that name, so that the
    // description says where each points (compose --env and stitch read it).
    fs::create_directories(dir / "named");
    for (int b = 1; b <= 3; ++b) {
      fs::copy_file(shot("yaw000_" + std::to_string(b) + ".jpg"),
                    dir / "named" / ("room_nz_" + std::to_string(b) + ".jpg"));
      fs::copy_file(shot("yaw180_" + std::to_string(b) + ".jpg"),
                    dir / "named" / ("room_pz_" + std::to_string(b) + ".jpg"));
    }
    const CommandRun named =
        compose("ingest --json " + q(dir / "named.json") + " " + q(dir / "named"), dir);
    ASSERT_EQ(named.status, 0) << named.err;
    EXPECT_NE(named.out.find("views named for the cube face"), std::string::npos) << named.out;
    EXPECT_NE(named.out.find("  nz: 3 photos"), std::string::npos) << named.out;
    EXPECT_NE(named.out.find("  pz: 3 photos"), std::string::npos) << named.out;
    const ingest::Capture described = ingest::readCaptureDescription(dir / "named.json");
    ASSERT_EQ(described.views.size(), 2u);
    EXPECT_EQ(described.views[0].name, "nz");
    EXPECT_EQ(described.views[1].name, "pz");
    // --json may replace an older description, never a photo named by mistake.
    const std::string photo = slurp(dir / "named" / "room_pz_3.jpg");
    const CommandRun over = compose(
        "ingest --json " + q(dir / "named" / "room_pz_3.jpg") + " " + q(dir / "named"), dir);
    EXPECT_EQ(over.status, 1);
    EXPECT_NE(over.err.find("is not a capture description and would be replaced"),
              std::string::npos)
        << over.err;
    EXPECT_EQ(slurp(dir / "named" / "room_pz_3.jpg"), photo);
    EXPECT_EQ(
        compose("ingest --json " + q(dir / "named.json") + " " + q(dir / "named"), dir).status, 0);
  }
  // merge recovers the response once and reuses it.
  {
    TempDir dir;
    const CommandRun first =
        compose("merge --capture " + q(shot("capture.json")) + " --out " + q(dir / "merged"), dir);
    ASSERT_EQ(first.status, 0) << first.err;
    EXPECT_EQ(filesIn(dir / "merged"), (std::vector<std::string>{"yaw000.exr", "yaw180.exr"}));
    EXPECT_NE(first.err.find("linearised by the camera response recovered"), std::string::npos)
        << first.err;
    EXPECT_TRUE(fs::exists(dir / "responses" / "compose_virtual_camera.json"));
    const auto exr = ingest::readImage(dir / "merged" / "yaw000.exr");
    EXPECT_EQ(exr.image.channels, 4);
    EXPECT_EQ(exr.image.channelNames[3], "clipped");
    EXPECT_EQ(exr.info.sampleType, "float");

    const CommandRun again =
        compose("merge --out " + q(dir / "one.exr") + " " + q(shot("yaw000_1.jpg")) + " " +
                    q(shot("yaw000_2.jpg")) + " " + q(shot("yaw000_3.jpg")),
                dir);
    ASSERT_EQ(again.status, 0) << again.err;
    EXPECT_NE(again.err.find("recovery skipped"), std::string::npos) << again.err;
    EXPECT_TRUE(fs::exists(dir / "one.exr"));
    EXPECT_EQ(again.err.find("not applied"), std::string::npos) << again.err;
    // Recovery options with the stored curve used are said not to apply (they were dropped
    // without a word); with --response recover they do, and nothing is said.
    const std::string bracket =
        q(shot("yaw000_1.jpg")) + " " + q(shot("yaw000_2.jpg")) + " " + q(shot("yaw000_3.jpg"));
    const CommandRun options = compose(
        "merge --curve-per-channel --lambda 20 --out " + q(dir / "two.exr") + " " + bracket, dir);
    ASSERT_EQ(options.status, 0) << options.err;
    EXPECT_NE(
        options.err.find("--lambda, --curve-per-channel were not applied: the curve used is the "
                         "stored response of compose virtual camera ("),
        std::string::npos)
        << options.err;
    const CommandRun recovered =
        compose("merge --response recover --curve-per-channel --response-dir " +
                    q(dir / "other_responses") + " --out " + q(dir / "three.exr") + " " + bracket,
                dir);
    ASSERT_EQ(recovered.status, 0) << recovered.err;
    EXPECT_EQ(recovered.err.find("not applied"), std::string::npos) << recovered.err;
    // ... and --curve-per-channel took effect: the curve stored there differs between channels
    // (one shared curve, as the stored one is, has the three alike).
    const hdr::ResponseCurve perChannel =
        hdr::readResponse(dir / "other_responses" / "compose_virtual_camera.json");
    const hdr::ResponseCurve shared =
        hdr::readResponse(dir / "responses" / "compose_virtual_camera.json");
    EXPECT_EQ(shared.inverse[0], shared.inverse[2]);
    EXPECT_NE(perChannel.inverse[0], perChannel.inverse[2]);

    // Half floats, PIZ, on request: the same radiance within half's precision.
    const CommandRun half = compose("merge --depth half --compression piz --out " +
                                        q(dir / "half.exr") + " " + q(shot("yaw000_1.jpg")) + " " +
                                        q(shot("yaw000_2.jpg")) + " " + q(shot("yaw000_3.jpg")),
                                    dir);
    ASSERT_EQ(half.status, 0) << half.err;
    const auto full = ingest::readImage(dir / "one.exr"),
               small = ingest::readImage(dir / "half.exr");
    EXPECT_EQ(full.info.sampleType, "float");
    EXPECT_EQ(small.info.sampleType, "half");
    ASSERT_EQ(small.image.pixels.size(), full.image.pixels.size());
    double worst = 0.0;
    for (size_t i = 0; i < full.image.pixels.size(); ++i) {
      const double f = full.image.pixels[i], h = small.image.pixels[i];
      if (f > 1e-3) worst = std::max(worst, std::abs(h - f) / f);
    }
    EXPECT_LT(worst, 1.0 / 1024.0);  // half keeps 11 significant bits
    EXPECT_LT(fs::file_size(dir / "half.exr"), fs::file_size(dir / "one.exr"));

    // The same camera set to another tone curve (a picture style): the stored response does not
    // fit its photos, which is found on their brackets; a curve recovered from them is used and
    // the stored one is kept.
    const fs::path stored = dir / "responses" / "compose_virtual_camera.json";
    const std::string before = slurp(stored);
    const CommandRun styled =
        compose("capture-sim --env " + q(pipeline::samplesDirectory() / "interior.exr") +
                    " --out " + q(dir / "styled") +
                    " --size 160x120 --views 2 --brackets 3 --seed 5 --response gamma:1.8",
                dir);
    ASSERT_EQ(styled.status, 0) << styled.err;
    const CommandRun other = compose("merge --capture " + q(dir / "styled" / "capture.json") +
                                         " --out " + q(dir / "styled_merged"),
                                     dir);
    ASSERT_EQ(other.status, 0) << other.err;
    EXPECT_NE(other.err.find("the stored response of compose virtual camera does not fit these "
                             "photos"),
              std::string::npos)
        << other.err;
    EXPECT_EQ(other.err.find("recovery skipped"), std::string::npos) << other.err;
    EXPECT_EQ(slurp(stored), before);
  }
  // An image with no exposure time in the folder of the brackets (a merged EXR saved beside
  // them) is left out and named: the grouping stays by capture time and merge takes the folder.
  {
    TempDir dir;
    Image merged(16, 12, 3, {"R", "G", "B"});
    std::fill(merged.pixels.begin(), merged.pixels.end(), 2.5f);
    ingest::writeImage(shot("merged.exr"), merged);
    const CommandRun r =
        compose("ingest --json " + q(dir / "grouped.json") + " " + q(dir_ / "shots"), dir);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_NE(r.err.find("left out 1 file of the folder with no exposure time in EXIF, where the "
                         "other photos have one"),
              std::string::npos)
        << r.err;
    EXPECT_NE(r.err.find("merged.exr"), std::string::npos) << r.err;
    EXPECT_NE(r.out.find("grouped by EXIF capture times"), std::string::npos) << r.out;
    EXPECT_NE(r.out.find("2 views"), std::string::npos) << r.out;
    EXPECT_EQ(r.out.find("merged.exr"), std::string::npos) << r.out;
    const CommandRun m =
        compose("merge --capture " + q(dir / "grouped.json") + " --out " + q(dir / "m"), dir);
    EXPECT_EQ(m.status, 0) << m.err;
    // merge given a folder of one view's brackets with such an image: the same.
    const fs::path folder = dir / "one view";
    fs::create_directories(folder);
    for (const char* name : {"yaw000_1.jpg", "yaw000_2.jpg", "yaw000_3.jpg", "merged.exr"})
      fs::copy_file(shot(name), folder / name);
    const CommandRun f = compose("merge --out " + q(dir / "one.exr") + " " + q(folder), dir);
    EXPECT_EQ(f.status, 0) << f.err;
    EXPECT_NE(f.err.find("left out 1 file of the folder with no exposure time in EXIF"),
              std::string::npos)
        << f.err;
    EXPECT_TRUE(fs::exists(dir / "one.exr"));
  }
}

// A real camera raw file (a Canon EOS 30D CR2 from Debian's rawtran-doc): its EXIF is read, and
// it is developed to linear light, not to a display rendering.
TEST_F(PhotoStages, ACameraRawFileIsReadWithItsExifAndDevelopedToLinearLight) {
  const fs::path raw = pipeline::samplesDirectory() / "raw" / "IMG_5952.CR2";
  ASSERT_TRUE(fs::exists(raw)) << "sample raw photo missing (samples/fetch.sh)";
  const ingest::LoadedImage img = ingest::readImage(raw);
  EXPECT_EQ(img.info.format, "raw");
  EXPECT_EQ(img.info.camera(), "Canon EOS 30D");
  ASSERT_TRUE(img.info.exposureTime && img.info.fNumber && img.info.iso);
  EXPECT_NEAR(*img.info.exposureTime, 1.0 / 400.0, 1e-6);
  EXPECT_NEAR(*img.info.fNumber, 22.0, 1e-4);
  EXPECT_NEAR(*img.info.iso, 640.0, 1e-3);
  EXPECT_EQ(img.image.width, 3522);
  EXPECT_EQ(img.image.height, 2348);
  ASSERT_EQ(img.image.channels, 3);
  EXPECT_EQ(img.image.colorSpace, "linear");

  // Linear light: the same file as OpenImageIO develops it by default (sRGB-encoded), decoded by
  // the sRGB curve, gives the same values; the encoded values themselves do not.
  auto plain = OIIO::ImageInput::open(raw.string());
  ASSERT_TRUE(plain);
  const OIIO::ImageSpec& spec = plain->spec();
  std::vector<float> encoded(size_t(spec.width) * size_t(spec.height) * 3);
  ASSERT_TRUE(plain->read_image(0, 0, 0, 3, OIIO::TypeDesc::FLOAT, encoded.data()));
  auto decode = [](double v) {
    return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
  };
  std::vector<double> decodedRatio, encodedRatio;
  for (size_t i = 0; i < encoded.size(); i += 997) {
    const double lin = img.image.pixels[i];
    if (lin < 0.01 || encoded[i] > 0.98) continue;  // dark noise and clipped highlights
    decodedRatio.push_back(decode(encoded[i]) / lin);
    encodedRatio.push_back(encoded[i] / lin);
  }
  ASSERT_GT(decodedRatio.size(), 5000u);
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + ptrdiff_t(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  EXPECT_NEAR(median(decodedRatio), 1.0, 0.02);
  EXPECT_GT(median(encodedRatio), 1.5) << "a display encoding would pass for linear";

  // The commands take it as any photo: ingest prints its EXIF, color writes it in the working
  // space.
  TempDir dir;
  const CommandRun r = compose("ingest " + q(raw), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("Canon EOS 30D"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("1/400 s"), std::string::npos) << r.out;
  const CommandRun c = compose("color " + q(raw) + " --out " + q(dir / "raw.exr"), dir);
  ASSERT_EQ(c.status, 0) << c.err;
  const ingest::LoadedImage exr = ingest::readImage(dir / "raw.exr");
  EXPECT_EQ(exr.image.width, 3522);
  EXPECT_EQ(exr.info.fileColorSpace, "ACEScg");
}

// A raw photo held as a portrait (its IFD0 Orientation 6 or 8): read turned upright, as
// OpenImageIO develops it, and known to be turned, as a JPEG's EXIF orientation is (LibRaw turned
// it and OpenImageIO said Orientation 1: the sensor's shape was taken for the other one, the
// camera's lens file refused, and merge wrote no compose:sensorOrientation).
TEST_F(PhotoStages, APortraitRawPhotoIsTurnedAndKnownToBe) {
  const fs::path raw = pipeline::samplesDirectory() / "raw" / "IMG_5952.CR2";
  ASSERT_TRUE(fs::exists(raw)) << "sample raw photo missing (samples/fetch.sh)";
  std::ifstream in(raw, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  ASSERT_GT(bytes.size(), 16u);
  ASSERT_EQ(std::string(bytes.data(), 2), "II") << "a little-endian TIFF";
  auto u16 = [&](size_t at) {
    return unsigned(uint8_t(bytes[at])) | unsigned(uint8_t(bytes[at + 1])) << 8;
  };
  auto u32 = [&](size_t at) { return size_t(u16(at)) | size_t(u16(at + 2)) << 16; };
  const size_t ifd = u32(4);
  size_t orientationAt = 0;
  for (unsigned e = 0; e < u16(ifd); ++e)
    if (u16(ifd + 2 + 12 * e) == 0x0112) orientationAt = ifd + 2 + 12 * e + 8;
  ASSERT_NE(orientationAt, 0u) << "IFD0 has an Orientation entry";
  const ingest::LoadedImage upright = ingest::readImage(raw);
  for (const int orientation : {6, 8}) {
    SCOPED_TRACE(orientation);
    bytes[orientationAt] = char(orientation);
    const fs::path turned = dir_ / ("portrait" + std::to_string(orientation) + ".CR2");
    std::ofstream(turned, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
    const ingest::LoadedImage img = ingest::readImage(turned);
    EXPECT_EQ(img.info.orientation, orientation);
    EXPECT_EQ(img.info.fileWidth, 3522);  // the sensor's shape
    ASSERT_EQ(img.image.width, 2348);
    ASSERT_EQ(img.image.height, 3522);
    // Turned the way the tag says: the top left of the upright picture is at the top right (6,
    // turned a quarter clockwise) or the bottom left (8).
    const int x = orientation == 6 ? 2348 - 1 - 40 : 40, y = orientation == 6 ? 60 : 3522 - 1 - 60;
    for (int c = 0; c < 3; ++c)
      EXPECT_FLOAT_EQ(img.image.at(x, y)[c], upright.image.at(60, 40)[c]) << "channel " << c;
    if (orientation != 6) continue;  // merged once: a raw file takes seconds to develop
    const CommandRun m =
        compose("merge --out " + q(dir_ / ("merged" + std::to_string(orientation) + ".exr")) + " " +
                    q(turned),
                dir_);
    ASSERT_EQ(m.status, 0) << m.err;
    const ingest::LoadedImage merged =
        ingest::readImage(dir_ / ("merged" + std::to_string(orientation) + ".exr"));
    EXPECT_EQ(merged.info.sensorOrientation, orientation);
  }
}

// `color --from` says which space the input was read as (it named the working space instead).
TEST(ColorCommand, SaysTheSpaceGivenWithFrom) {
  TempDir dir;
  Image img(8, 6, 3);
  std::fill(img.pixels.begin(), img.pixels.end(), 0.5f);
  ingest::writeImage(dir / "in.png", img, {});
  const CommandRun c =
      compose("color " + q(dir / "in.png") + " --from \"sRGB - Texture\" --to Raw --out " +
                  q(dir / "out.exr"),
              dir);
  ASSERT_EQ(c.status, 0) << c.err;
  EXPECT_NE(c.err.find("as 'sRGB - Texture' (--from), wrote 'Raw'"), std::string::npos) << c.err;
  // A space the config does not know, and an empty output, are command-line errors (exit 2, as
  // the one-shot command's --plate-space), found before the image is read: the input may be
  // missing.
  for (const std::string& args :
       {std::string(" --from nonesuch --out ") + q(dir / "o.exr"),
        std::string(" --to nonesuch --out ") + q(dir / "o.exr"), std::string(" --out ''")}) {
    const CommandRun bad = compose("color " + q(dir / "missing.png") + args, dir);
    EXPECT_EQ(bad.status, 2) << args << ": " << bad.err;
    EXPECT_EQ(bad.err.find("file not found"), std::string::npos) << bad.err;
    EXPECT_FALSE(fs::exists(dir / "o.exr"));
  }
}

// A PNG's colour is unassociated with its alpha, OpenEXR's premultiplied: `color` multiplies,
// in linear light, as the pipeline reads a plate (it wrote the PNG's colour as it was, and a
// reader took a transparent pixel's colour for light added over the background).
TEST(ColorCommand, AStraightAlphaIsPremultipliedInTheExr) {
  TempDir dir;
  Image img(4, 2, 4, {"R", "G", "B", "A"});
  for (size_t i = 0; i < img.pixelCount(); ++i) {
    const float rgba[4] = {0.8f, 0.2f, 0.4f, i % 2 ? 128.0f / 255.0f : 0.0f};
    std::copy_n(rgba, 4, &img.pixels[4 * i]);
  }
  ingest::WriteOptions straight;  // the colour as the PNG stores it, not divided by its alpha
  straight.alphaChannel = 3;
  straight.attributes.push_back({"oiio:UnassociatedAlpha", 1});
  ingest::writeImage(dir / "in.png", img, straight);
  const CommandRun c =
      compose("color " + q(dir / "in.png") +
                  " --to \"Linear Rec.709 (sRGB)\" --depth float --out " + q(dir / "out.exr"),
              dir);
  ASSERT_EQ(c.status, 0) << c.err;
  EXPECT_NE(c.err.find("premultiplied by its alpha"), std::string::npos) << c.err;
  const ingest::LoadedImage out = ingest::readImage(dir / "out.exr");
  ASSERT_EQ(out.image.channels, 4);
  const PictureChannels picture = pictureChannels(out.image);  // OpenEXR sorts them: A, B, G, R
  ASSERT_EQ(picture.kind, PictureChannels::Kind::Rgb);
  ASSERT_GE(picture.alpha, 0);
  auto linear = [](double v) { return std::pow((v + 0.055) / 1.055, 2.4); };
  const double channel[3] = {0.8, 0.2, 0.4};
  for (int x = 0; x < 2; ++x) {
    const float* p = out.image.at(x, 0);
    const double a = x % 2 ? 128.0 / 255.0 : 0.0;
    EXPECT_NEAR(p[picture.alpha], a, 1e-6);
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(p[picture.colour[size_t(k)]], linear(std::round(channel[k] * 255.0) / 255.0) * a,
                  2e-4)
          << x << k;
    }
  }
}

// A file goes to a reader by its bytes, and its colour follows them, not a name they contradict:
// a PNG named .exr is sRGB codes (the config's rule for .exr read them as linear light: 46 codes
// too bright in the display image).
TEST(ColorCommand, AFilesColourFollowsItsBytesNotItsName) {
  TempDir dir;
  Image img(2, 1, 3, {"R", "G", "B"});
  img.pixels = {0.5f, 0.5f, 0.5f, 1.0f, 0.25f, 0.0f};
  ingest::writeImage(dir / "in.png", img);
  std::filesystem::copy_file(dir / "in.png", dir / "png.exr");
  for (const char* name : {"in.png", "png.exr"}) {
    const CommandRun c =
        compose("color " + q(dir / name) + " --to \"Linear Rec.709 (sRGB)\" --depth float --out " +
                    q(dir / (std::string(name) + ".out.exr")),
                dir);
    ASSERT_EQ(c.status, 0) << c.err;
    EXPECT_NE(c.err.find("as 'sRGB - Texture'"), std::string::npos) << name << ": " << c.err;
    const ingest::LoadedImage out = ingest::readImage(dir / (std::string(name) + ".out.exr"));
    EXPECT_NEAR(out.image.pixels[0], std::pow((128.0 / 255.0 + 0.055) / 1.055, 2.4), 2e-4) << name;
  }
}

// A TIFF's associated alpha (oiiotool's and Nuke's): the codes hold colour x alpha in the sRGB
// encoding, made straight before decoding and premultiplied in linear light (decoding the product
// gave 0.080 for 0.175).
TEST(ColorCommand, AnAssociatedAlphaIsMadeStraightBeforeDecoding) {
  TempDir dir;
  Image img(2, 1, 4, {"R", "G", "B", "A"});
  const float a = 128.0f / 255.0f;
  const float rgba[8] = {0.8f * a, 0.2f * a, 0.4f * a, a, 0.0f, 0.0f, 0.0f, 0.0f};
  std::copy_n(rgba, 8, img.pixels.data());
  ingest::WriteOptions associated;  // as stored: colour x alpha
  associated.alphaChannel = 3;
  ingest::writeImage(dir / "in.tif", img, associated);
  const CommandRun c =
      compose("color " + q(dir / "in.tif") +
                  " --to \"Linear Rec.709 (sRGB)\" --depth float --out " + q(dir / "out.exr"),
              dir);
  ASSERT_EQ(c.status, 0) << c.err;
  const ingest::LoadedImage out = ingest::readImage(dir / "out.exr");
  const PictureChannels picture = pictureChannels(out.image);
  ASSERT_GE(picture.alpha, 0);
  auto linear = [](double v) { return std::pow((v + 0.055) / 1.055, 2.4); };
  const double channel[3] = {0.8, 0.2, 0.4};
  const float* p = out.image.at(0, 0);
  EXPECT_NEAR(p[picture.alpha], a, 1e-6);
  for (int k = 0; k < 3; ++k) {
    // The codes stored: round(colour x alpha x 255), made straight.
    const double code = std::round(channel[k] * a * 255.0) / 255.0 / a;
    EXPECT_NEAR(p[picture.colour[size_t(k)]], linear(code) * a, 2e-4) << k;
  }
}

// `color` converts the picture's colour, taken by channel name, and keeps its alpha: a render
// layer's beauty (object.R, G, B, A) beside its passes (albedo sorts first) is what is converted,
// the passes are left out and named; a file of passes alone is refused, naming the layers.
TEST(ColorCommand, ConvertsThePicturesLayerAndNamesWhatItLeavesOut) {
  TempDir dir;
  Image layered(
      4, 3, 8,
      {"albedo.B", "albedo.G", "albedo.R", "N.X", "object.A", "object.B", "object.G", "object.R"});
  Image plain(4, 3, 4, {"R", "G", "B", "A"});
  for (size_t i = 0; i < layered.pixelCount(); ++i) {
    const float v = 0.1f + 0.05f * float(i);
    const float rgba[4] = {v, 2.0f * v, 0.5f * v, 0.75f};
    const float passes[4] = {0.9f, 0.8f, 0.7f, -1.0f};  // albedo B, G, R and N.X
    std::copy_n(passes, 4, &layered.pixels[8 * i]);
    layered.pixels[8 * i + 4] = rgba[3];
    for (int c = 0; c < 3; ++c) layered.pixels[8 * i + 7 - size_t(c)] = rgba[c];
    std::copy_n(rgba, 4, &plain.pixels[4 * i]);
  }
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "layered.exr", layered, options);
  ingest::writeImage(dir / "plain.exr", plain, options);
  const std::string to = " --from ACEScg --to \"Linear Rec.709 (sRGB)\" --depth float --out ";
  const CommandRun a = compose("color " + q(dir / "layered.exr") + to + q(dir / "a.exr"), dir);
  ASSERT_EQ(a.status, 0) << a.err;
  EXPECT_NE(a.err.find("4 channels not converted and not written (not the image's colour or its "
                       "alpha): "),
            std::string::npos)
      << a.err;
  for (const char* name : {"albedo.R", "albedo.G", "albedo.B", "N.X"})
    EXPECT_NE(a.err.find(name), std::string::npos) << name << ": " << a.err;
  const CommandRun b = compose("color " + q(dir / "plain.exr") + to + q(dir / "b.exr"), dir);
  ASSERT_EQ(b.status, 0) << b.err;
  const ingest::LoadedImage fromLayer = ingest::readImage(dir / "a.exr");
  const ingest::LoadedImage fromPlain = ingest::readImage(dir / "b.exr");
  ASSERT_EQ(fromLayer.image.channels, 4);
  EXPECT_EQ(fromLayer.image.pixels, fromPlain.image.pixels);
  EXPECT_NE(fromLayer.image.pixels[0], plain.pixels[0]) << "converted";
  EXPECT_EQ(fromLayer.image.pixels[3], 0.75f) << "the alpha kept";

  Image passes(4, 3, 6, {"albedo.B", "albedo.G", "albedo.R", "normal.B", "normal.G", "normal.R"});
  ingest::writeImage(dir / "passes.exr", passes, options);
  const CommandRun c = compose("color " + q(dir / "passes.exr") + to + q(dir / "c.exr"), dir);
  EXPECT_FAILS_WITH(c, 1, "has colour in several layers ('albedo', 'normal')");
  EXPECT_NE(c.err.find("passes.exr"), std::string::npos) << c.err;
  EXPECT_FALSE(fs::exists(dir / "c.exr"));
}

// Pictures as other tools write them: of a multi-part OpenEXR the part named as the picture
// (a pass before it was read, with no note), Nuke's long channel names with their alpha (the
// alpha was left out), written as R, G, B, A.
TEST(ColorCommand, ThePicturePartAndNukesChannelNames) {
  TempDir dir;
  Image beauty(4, 3, 4, {"R", "G", "B", "A"}), pass(4, 3, 3, {"R", "G", "B"});
  Image nuke(4, 3, 4, {"rgba.red", "rgba.green", "rgba.blue", "rgba.alpha"});
  for (size_t i = 0; i < beauty.pixelCount(); ++i) {
    const float v = 0.1f + 0.05f * float(i);
    const float rgba[4] = {v, 2.0f * v, 0.5f * v, 0.5f};
    std::copy_n(rgba, 4, &beauty.pixels[4 * i]);
    std::copy_n(rgba, 4, &nuke.pixels[4 * i]);
    for (int c = 0; c < 3; ++c) pass.pixels[3 * i + size_t(c)] = 0.9f - 0.2f * float(c);
  }
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "plain.exr", beauty, options);
  ingest::writeImage(dir / "nuke.exr", nuke, options);
  ingest::writeExrFile(dir / "parts.exr", dir / "parts.exr",
                       {ingest::ExrPart("diffuse", &pass, 0, 0, 4, 3, options),
                        ingest::ExrPart("beauty", &beauty, 0, 0, 4, 3, options)});
  const std::string to = " --from ACEScg --to \"Linear Rec.709 (sRGB)\" --depth float --out ";
  const CommandRun plain = compose("color " + q(dir / "plain.exr") + to + q(dir / "a.exr"), dir);
  ASSERT_EQ(plain.status, 0) << plain.err;
  const ingest::LoadedImage expected = ingest::readImage(dir / "a.exr");
  ASSERT_EQ(expected.image.channelNames, (std::vector<std::string>{"R", "G", "B", "A"}));
  for (const char* name : {"parts", "nuke"}) {
    SCOPED_TRACE(name);
    const fs::path out = dir / (std::string("out_") + name + ".exr");
    const CommandRun r =
        compose("color " + q(dir / (std::string(name) + ".exr")) + to + q(out), dir);
    ASSERT_EQ(r.status, 0) << r.err;
    const ingest::LoadedImage got = ingest::readImage(out);
    EXPECT_EQ(got.image.channelNames, expected.image.channelNames);
    EXPECT_EQ(got.image.pixels, expected.image.pixels);
    if (std::string(name) == "parts") {
      EXPECT_NE(r.err.find("read part 1 'beauty', named as the picture"), std::string::npos)
          << r.err;
    }
  }
}

TEST_F(PhotoStages, EveryBadInputIsANamedErrorAndWritesNothing) {
  makeCapture();
  // Brackets of different sizes.
  {
    TempDir dir;
    // The middle exposure, resized, with its EXIF.
    auto mid = ingest::readImage(shot("yaw000_2.jpg"));
    Image half(80, 60, 3);
    for (int y = 0; y < 60; ++y)
      for (int x = 0; x < 80; ++x)
        for (int c = 0; c < 3; ++c) half.at(x, y)[c] = mid.image.at(2 * x, 2 * y)[c];
    ingest::WriteOptions w;
    w.attributes = ingest::exifAttributes(mid.info);
    ingest::writeImage(dir / "small.jpg", half, w);
    const CommandRun r =
        compose("merge --out " + q(dir / "out" / "hdr.exr") + " " + q(shot("yaw000_1.jpg")) + " " +
                    q(dir / "small.jpg") + " " + q(shot("yaw000_3.jpg")),
                dir);
    EXPECT_FAILS_WITH(r, 1, "must have the same size");
    EXPECT_NE(r.err.find("small.jpg"), std::string::npos) << r.err;
    EXPECT_TRUE(filesIn(dir / "out").empty());
  }
  // A bracket whose exposures are all equal.
  {
    TempDir dir;
    // From the files' EXIF: three copies of one shot (exit 1, the files' fault).
    for (const char* name : {"a.jpg", "b.jpg", "c.jpg"})
      fs::copy_file(shot("yaw000_2.jpg"), dir / name);
    const CommandRun r = compose("merge --out " + q(dir / "hdr.exr") + " " + q(dir / "a.jpg") +
                                     " " + q(dir / "b.jpg") + " " + q(dir / "c.jpg"),
                                 dir);
    EXPECT_FAILS_WITH(r, 1, "ingest: the exposures of view 'hdr' are all equal");
    EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
    // From the command line (exit 2, the command line's fault).
    const CommandRun given = compose("merge --exposures 1,1,1 --out " + q(dir / "hdr.exr") + " " +
                                         q(shot("yaw000_1.jpg")) + " " + q(shot("yaw000_2.jpg")) +
                                         " " + q(shot("yaw000_3.jpg")),
                                     dir);
    EXPECT_FAILS_WITH(given, 2, "--exposures are all equal");
    EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
  }
  // No EXIF and no exposure list.
  {
    TempDir dir;
    for (const char* name : {"yaw000_1.jpg", "yaw000_2.jpg"}) {
      const auto img = ingest::readImage(shot(name));
      ingest::writeImage(dir / (std::string("bare_") + name), img.image);  // no EXIF
    }
    const CommandRun r =
        compose("merge --out " + q(dir / "hdr.exr") + " " + q(dir / "bare_yaw000_1.jpg") + " " +
                    q(dir / "bare_yaw000_2.jpg"),
                dir);
    EXPECT_FAILS_WITH(r, 1, "no exposure time in EXIF and no exposure given");
    EXPECT_NE(r.err.find("bare_yaw000_1.jpg"), std::string::npos);
    EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
    // With a list it merges.
    const CommandRun ok =
        compose("merge --exposures 0.25,1 --response colorspace --out " + q(dir / "hdr.exr") + " " +
                    q(dir / "bare_yaw000_1.jpg") + " " + q(dir / "bare_yaw000_2.jpg"),
                dir);
    EXPECT_EQ(ok.status, 0) << ok.err;
    EXPECT_NE(ok.err.find("not by a camera response"), std::string::npos) << ok.err;
    // With the list in the other order: refused, nothing written.
    fs::remove(dir / "hdr.exr");
    const CommandRun reversed =
        compose("merge --exposures 1,0.25 --response colorspace --out " + q(dir / "hdr.exr") + " " +
                    q(dir / "bare_yaw000_1.jpg") + " " + q(dir / "bare_yaw000_2.jpg"),
                dir);
    EXPECT_FAILS_WITH(reversed, 1,
                      "bare_yaw000_1.jpg is given 2.0 stops more exposure than bare_yaw000_2.jpg "
                      "(--exposures) but is darker in");
    EXPECT_NE(reversed.err.find("are the exposures in the order of the photos?"),
              std::string::npos);
    EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
  }
  // Exposures given in the reverse order of a camera's photos: no merge, and no response stored
  // for the camera (it would linearise its later merges).
  {
    TempDir dir;
    const CommandRun r =
        compose("merge --exposures 16,4,1 --response-dir " + q(dir / "responses") + " --out " +
                    q(dir / "hdr.exr") + " " + q(shot("yaw000_1.jpg")) + " " +
                    q(shot("yaw000_2.jpg")) + " " + q(shot("yaw000_3.jpg")),
                dir);
    EXPECT_FAILS_WITH(r, 1, "yaw000_2.jpg is given 2.0 stops more exposure than yaw000_3.jpg");
    EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
    EXPECT_TRUE(filesIn(dir / "responses").empty());
  }
  // A truncated JPEG.
  {
    TempDir dir;
    const std::string bytes = slurp(shot("yaw000_2.jpg"));
    compose::testing::writeText(dir / "cut.jpg", bytes.substr(0, bytes.size() * 2 / 3));
    const CommandRun r =
        compose("merge --out " + q(dir / "hdr.exr") + " " + q(shot("yaw000_1.jpg")) + " " +
                    q(dir / "cut.jpg") + " " + q(shot("yaw000_3.jpg")),
                dir);
    EXPECT_FAILS_WITH(r, 1, "merge: truncated file");
    EXPECT_NE(r.err.find("cut.jpg"), std::string::npos);
    EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
  }
  // A capture into a folder holding photos it does not replace (an earlier capture with more
  // exposures): ingest would group them with the new ones. Refused, the folder as it was.
  {
    TempDir dir;
    const std::vector<std::string> before = filesIn(dir_ / "shots");
    const CommandRun r = compose(
        "capture-sim --env " + q(pipeline::samplesDirectory() / "interior.exr") + " --out " +
            q(dir_ / "shots") + " --size 160x120 --views 2 --brackets 2 --seed 4",
        dir);
    EXPECT_FAILS_WITH(r, 1, "the output folder holds 2 images this capture does not write");
    EXPECT_NE(r.err.find("yaw000_3.jpg"), std::string::npos) << r.err;
    EXPECT_EQ(filesIn(dir_ / "shots"), before);
  }
  // An unknown colour space, refused before anything is read.
  {
    TempDir dir;
    const CommandRun r = compose("merge --input-space no-such-space --out " + q(dir / "hdr.exr") +
                                     " " + q(dir / "missing.jpg"),
                                 dir);
    EXPECT_FAILS_WITH(r, 2, "no-such-space");
    EXPECT_EQ(r.err.find("missing.jpg"), std::string::npos) << "nothing read yet: " << r.err;
    EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
  }
  // A chessboard size that matches no photo.
  {
    TempDir dir;
    const auto boards = pipeline::samplesDirectory() / "chessboard";
    const CommandRun r = compose("calib lens --board 8x5 --out " + q(dir / "camera.json") + " " +
                                     q(boards / "left01.jpg") + " " + q(boards / "left02.jpg") +
                                     " " + q(boards / "left03.jpg"),
                                 dir);
    EXPECT_FAILS_WITH(r, 1, "calib: no 8x5 chessboard");
    EXPECT_FALSE(fs::exists(dir / "camera.json"));
    // The right size calibrates and writes the lens file.
    const CommandRun ok =
        compose("calib lens --board 9x6 --out " + q(dir / "camera.json") + " " + q(boards), dir);
    EXPECT_EQ(ok.status, 0) << ok.err;
    EXPECT_TRUE(fs::exists(dir / "camera.json"));
    EXPECT_NE(ok.err.find("RMS reprojection"), std::string::npos);
  }
  // A map no shutter time can photograph (the virtual camera wrote photos of 6.9e10 s whose EXIF
  // said 0 s, black frames that no merge could use).
  {
    TempDir dir;
    Image dim(64, 32, 3, {"R", "G", "B"});
    for (float& v : dim.pixels) v = 1e-15f;
    ingest::WriteOptions floats;
    floats.depth = ingest::WriteOptions::Depth::Float;
    ingest::writeImage(dir / "dim.exr", dim, floats);
    const CommandRun r = compose("capture-sim --env " + q(dir / "dim.exr") + " --out " +
                                     q(dir / "shots") + " --size 64x48 --views 1",
                                 dir);
    EXPECT_FAILS_WITH(r, 1, "the environment is too dark for a camera");
    EXPECT_NE(r.err.find("dim.exr"), std::string::npos) << r.err;
    EXPECT_TRUE(filesIn(dir / "shots").empty());
  }
}

// The virtual camera takes an environment in any layout compose --env takes: a cube map's photos
// are the lat-long map's, but for resampling.
TEST_F(PhotoStages, TheVirtualCameraTakesACubeMap) {
  TempDir dir;
  const fs::path latLong = pipeline::samplesDirectory() / "interior.exr";
  ASSERT_EQ(
      compose("convert " + q(latLong) + " --to cube --out " + q(dir / "cube.exr"), dir).status, 0);
  const std::string common = " --size 96x72 --views 2 --brackets 2 --seed 4 --no-noise --out ";
  const CommandRun fromCube =
      compose("capture-sim --env " + q(dir / "cube.exr") + common + q(dir / "a"), dir);
  ASSERT_EQ(fromCube.status, 0) << fromCube.err;
  EXPECT_NE(fromCube.err.find("OpenEXR envmap attribute: cube"), std::string::npos) << fromCube.err;
  const CommandRun fromLatLong =
      compose("capture-sim --env " + q(latLong) + common + q(dir / "b"), dir);
  ASSERT_EQ(fromLatLong.status, 0) << fromLatLong.err;
  const auto a = ingest::readImage(dir / "a" / "yaw000_2.jpg").image;
  const auto b = ingest::readImage(dir / "b" / "yaw000_2.jpg").image;
  ASSERT_EQ(a.pixels.size(), b.pixels.size());
  double sum = 0.0;
  for (size_t i = 0; i < a.pixels.size(); ++i) sum += std::abs(a.pixels[i] - b.pixels[i]);
  EXPECT_LT(sum / double(a.pixels.size()), 0.01) << "mean code difference (of 1)";
}

// The virtual camera's JPEGs keep their chroma at half resolution both ways (4:2:0), as most
// cameras write them, or at full resolution with --jpeg-chroma 4:4:4; the truth file says which.
TEST_F(PhotoStages, TheVirtualCameraWritesTheChromaAskedFor) {
  TempDir dir;
  const std::string common = "capture-sim --env " +
                             q(pipeline::samplesDirectory() / "interior.exr") +
                             " --size 64x48 --views 1 --brackets 2 --seed 3 --no-noise";
  for (const std::string chroma : {"4:2:0", "4:4:4"}) {
    const fs::path out = dir / (chroma == "4:2:0" ? "default" : "full");
    const std::string option = chroma == "4:2:0" ? "" : " --jpeg-chroma " + chroma;
    const CommandRun r = compose(common + option + " --out " + q(out), dir);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_NE(r.err.find("JPEG quality 95, " + chroma + " chroma"), std::string::npos) << r.err;
    for (const char* photo : {"yaw000_1.jpg", "yaw000_2.jpg"}) {
      auto in = OIIO::ImageInput::open((out / photo).string());
      ASSERT_TRUE(in) << photo;
      EXPECT_EQ(in->spec().get_string_attribute("jpeg:subsampling"), chroma) << photo;
    }
    const auto truth = nlohmann::json::parse(slurp(out / "truth.json"));
    EXPECT_EQ(truth.value("jpegChroma", ""), chroma);
  }
  EXPECT_FAILS_WITH(compose(common + " --jpeg-chroma 4:2:2 --out " + q(dir / "c"), dir), 2,
                    "--jpeg-chroma must be 4:2:0 or 4:4:4, got '4:2:2'");
  EXPECT_FAILS_WITH(
      compose(common + " --tiff --no-jpeg --jpeg-chroma 4:4:4 --out " + q(dir / "c"), dir), 2,
      "--jpeg-chroma is for the JPEGs: it does not go with --no-jpeg");
  EXPECT_FAILS_WITH(
      compose(common + " --tiff --no-jpeg --jpeg-quality 80 --out " + q(dir / "c"), dir), 2,
      "--jpeg-quality is for the JPEGs: it does not go with --no-jpeg");
  EXPECT_FALSE(fs::exists(dir / "c"));
}

// A merged view keeps its photos' lens (EXIF focal length, 35 mm equivalent, focal plane): a stitch
// of merged views finds its intrinsics as it does in the photos. 16-bit photos whose files name no
// colour space are read by the config's rules, and the merge says so.
TEST_F(PhotoStages, MergedViewsKeepTheLensAndDeepPhotosSayTheirSpace) {
  TempDir dir;
  CommandRun r =
      compose("capture-sim --env " + q(pipeline::samplesDirectory() / "interior.exr") + " --out " +
                  q(dir / "shots") + " --size 160x120 --views 6 --brackets 3 --tiff --seed 4",
              dir);
  ASSERT_EQ(r.status, 0) << r.err;
  r = compose("merge --capture " + q(dir / "shots" / "capture.json") + " --out " +
                  q(dir / "merged") + "/ --response-dir " + q(dir / "responses"),
              dir);
  ASSERT_EQ(r.status, 0) << r.err;
  const ingest::CaptureInfo photo = ingest::readCaptureInfo(dir / "shots" / "px_1.jpg", "test");
  const ingest::CaptureInfo merged = ingest::readCaptureInfo(dir / "merged" / "px.exr", "test");
  ASSERT_TRUE(photo.focalLength35mm && photo.focalLengthMm);
  ASSERT_TRUE(merged.focalLength35mm && merged.focalLengthMm);
  EXPECT_NEAR(*merged.focalLength35mm, *photo.focalLength35mm, 1e-4);  // float in the EXR
  EXPECT_NEAR(*merged.focalLengthMm, *photo.focalLengthMm, 1e-4);
  std::string views;
  for (const char* v : {"px", "nx", "py", "ny", "pz", "nz"})
    views += " " + q(dir / "merged" / (std::string(v) + ".exr"));
  r = compose("stitch --size 32 --out " + q(dir / "env.exr") + views, dir);
  EXPECT_EQ(r.status, 0) << r.err;
  // The virtual camera's linear TIFFs alone, named one by one: their ICC profile says linear
  // light, and they merge as with the linear space given (they were read as sRGB codes, 4 times
  // too dark in the mean).
  auto tiffs = [&](const std::string& stem) {
    return q(dir / "shots" / (stem + "_1.tif")) + " " + q(dir / "shots" / (stem + "_2.tif")) + " " +
           q(dir / "shots" / (stem + "_3.tif"));
  };
  r = compose("merge --out " + q(dir / "tif.exr") + " " + tiffs("px"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err.find("not applied"), std::string::npos) << r.err;
  // A recovery option for photos no curve is recovered for: said (it was dropped without a word).
  r = compose("merge --lambda 20 --out " + q(dir / "lambda.exr") + " " + tiffs("px"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("--lambda was not applied: the photos are 16-bit or float, linear already"),
            std::string::npos)
      << r.err;
  // 16-bit photos given exposures in the reverse order: refused.
  r = compose("merge --exposures 16,4,1 --out " + q(dir / "reversed.exr") + " " + tiffs("px"), dir);
  EXPECT_FAILS_WITH(r, 1, "px_2.tif is given 2.0 stops more exposure than px_3.tif");
  EXPECT_FALSE(fs::exists(dir / "reversed.exr"));
  EXPECT_EQ(r.err.find("16-bit photos such as"), std::string::npos) << r.err;
  r = compose("merge --input-space 'Linear Rec.709 (sRGB)' --out " + q(dir / "given.exr") + " " +
                  tiffs("px"),
              dir);
  ASSERT_EQ(r.status, 0) << r.err;
  const Image byProfile = ingest::readImage(dir / "tif.exr").image,
              given = ingest::readImage(dir / "given.exr").image;
  ASSERT_EQ(byProfile.pixels.size(), given.pixels.size());
  for (size_t i = 0; i < given.pixels.size(); ++i)
    ASSERT_EQ(byProfile.pixels[i], given.pixels[i]) << i;
  // Without the profile a 16-bit TIFF names no colour space: read as the rules say, and said.
  for (int b = 1; b <= 3; ++b) {
    Image plain = ingest::readImage(dir / "shots" / ("px_" + std::to_string(b) + ".tif")).image;
    ingest::WriteOptions w;
    w.depth = ingest::WriteOptions::Depth::UInt16;
    const ingest::CaptureInfo info =
        ingest::readCaptureInfo(dir / "shots" / ("px_" + std::to_string(b) + ".tif"), "test");
    w.attributes = ingest::exifAttributes(info);
    plain.colorSpace.clear();
    ingest::writeImage(dir / "shots" / ("plain_" + std::to_string(b) + ".tif"), plain, w);
  }
  r = compose("merge --out " + q(dir / "plain.exr") + " " + tiffs("plain"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("16-bit photos such as plain_1.tif read as 'sRGB - Texture' by the "
                       "config's rules (the files name no colour space); linear ones"),
            std::string::npos)
      << r.err;
}

TEST_F(PhotoStages, BadCommandLinesExitTwoBeforeReadingAnything) {
  TempDir dir;
  EXPECT_FAILS_WITH(compose("merge " + q(shot("yaw000_1.jpg")), dir), 2, "--out is required");
  EXPECT_FAILS_WITH(
      compose("merge --exposures 1,2 --out " + q(dir / "h.exr") + " " + q(shot("yaw000_1.jpg")),
              dir),
      2, "--exposures has 2 values for 1 photo");
  EXPECT_FAILS_WITH(compose("merge --exposures 1,x --out h.exr a.jpg b.jpg", dir), 2,
                    "--exposures expects a number");
  EXPECT_FAILS_WITH(compose("capture-sim --env e.exr --out d --brackets 0", dir), 2, "brackets");
  EXPECT_FAILS_WITH(compose("calib lens --board 9by6 --out c.json a.jpg", dir), 2, "9by6");
  // OpenCV finds no board of two corners a side: said in our words; a lens or pose file is JSON.
  EXPECT_FAILS_WITH(compose("calib lens --board 2x2 --out c.json a.jpg", dir), 2,
                    "a chessboard needs 3 to 100 inner corners each way, got 2x2");
  EXPECT_FAILS_WITH(compose("calib lens --board 9x6 --out c.exr a.jpg", dir), 2,
                    "--out must name a JSON file (.json): the lens file is JSON");
  EXPECT_FAILS_WITH(compose("calib pose --board 9x6 --out p.exr plate.jpg", dir), 2,
                    "--out must name a JSON file (.json): the pose file is JSON");
  EXPECT_FAILS_WITH(compose("ingest --max-gap -1 a.jpg", dir), 2, "time gap");
  // Zero is not "not given"; extremes are named; options of a step that does not run are refused.
  EXPECT_FAILS_WITH(compose("ingest --brackets 0 a.jpg", dir), 2,
                    "--brackets: must be a number greater than 0, got 0");
  EXPECT_FAILS_WITH(compose("cache --older-than nan", dir), 2,
                    "--older-than: must be a finite number of 0 or more, got nan");
  EXPECT_FAILS_WITH(compose("merge --exposures 1e-300,1 --out h.exr a.jpg b.jpg", dir), 2,
                    "--exposures must be relative exposures between 1e-12 and 1e12");
  EXPECT_FAILS_WITH(compose("merge --exposures 4,4 --out h.exr a.jpg b.jpg", dir), 2,
                    "--exposures are all equal");
  EXPECT_FAILS_WITH(compose("merge --max-shift 5 --out h.exr a.jpg b.jpg", dir), 2,
                    "--max-shift is the alignment's range: it goes with --align");
  EXPECT_FAILS_WITH(compose("merge --ghost-stops 1 --out h.exr a.jpg b.jpg", dir), 2,
                    "it goes with --deghost");
  EXPECT_FAILS_WITH(
      compose("merge --response colorspace --recovery robertson --out h.exr a.jpg b.jpg", dir), 2,
      "--recovery is for recovering a response, which --response colorspace does not do");
  EXPECT_FAILS_WITH(compose("capture-sim --env e.exr --out d --size 20000x20000", dir), 2,
                    "image size 20000x20000 is more pixels than the limit of 268 megapixels");
  EXPECT_FAILS_WITH(compose("merge --out '' a.jpg b.jpg", dir), 2, "--out is given an empty value");
  EXPECT_FAILS_WITH(compose("merge --capture " + q(shot("capture.json")) + " --out hdr.exr", dir),
                    2, "with --capture, --out is a folder");
  EXPECT_FALSE(fs::exists(dir / "hdr.exr"));
  // Options of a grouping that does not run.
  EXPECT_FAILS_WITH(compose("ingest --max-gap 10 --pattern '{view}_{bracket}.jpg' a.jpg", dir), 2,
                    "--max-gap is the EXIF grouping's");
  EXPECT_FAILS_WITH(compose("ingest --brackets 2 --pattern '{view}_{bracket}.jpg' a.jpg", dir), 2,
                    "--brackets is the EXIF grouping's");
  EXPECT_FAILS_WITH(compose("ingest --group exif --pattern '{view}_{bracket}.jpg' a.jpg", dir), 2,
                    "--pattern goes with --group pattern");
  EXPECT_FAILS_WITH(compose("ingest --capture c.json --max-gap 9", dir), 2,
                    "--max-gap is the EXIF grouping's");
  EXPECT_FAILS_WITH(compose("ingest --pattern 'x_{bracket}.jpg' a.jpg", dir), 2,
                    "--pattern needs a {view} placeholder");
  // A bracket size looks at no pause: a --max-gap beside it was taken and ignored.
  EXPECT_FAILS_WITH(compose("ingest --brackets 3 --max-gap 0.1 a.jpg", dir), 2, "give one of them");
}

// ingest --exposures takes the photos in the order given, as merge does: grouping sorts them by
// capture time, and the list was applied in that order (the shortest exposure of three photos
// given 3, 1, 2 went to the second).
TEST_F(PhotoStages, IngestTakesExposuresInTheOrderOfThePhotos) {
  makeCapture();
  TempDir dir;
  const CommandRun r = compose("ingest --json " + q(dir / "o.json") + " --exposures 16,1,4 " +
                                   q(shot("yaw000_3.jpg")) + " " + q(shot("yaw000_1.jpg")) + " " +
                                   q(shot("yaw000_2.jpg")),
                               dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err.find("order"), std::string::npos) << "no doubt about the order: " << r.err;
  const ingest::Capture c = ingest::readCaptureDescription(dir / "o.json");
  ASSERT_EQ(c.views.size(), 1u);
  ASSERT_EQ(c.views[0].shots.size(), 3u);
  for (const ingest::Shot& s : c.views[0].shots) {
    const std::string name = s.file.filename().string();
    const double want = name == "yaw000_1.jpg" ? 1.0 : name == "yaw000_2.jpg" ? 4.0 : 16.0;
    ASSERT_TRUE(s.exposure) << name;
    EXPECT_EQ(*s.exposure, want) << name;
  }
}

}  // namespace
}  // namespace compose
