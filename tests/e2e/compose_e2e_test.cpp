// End-to-end: runs the compose executable on the real sample data (the meadow plate, the Stanford
// bunny, the forest HDRI) and checks the result against an independently computed reference.
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <numbers>
#include <sstream>

#include <OpenImageIO/imageio.h>
#include <glm/geometric.hpp>
#include <glm/vec3.hpp>

#include "command_util.h"
#include "core/numbers.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;

using RunResult = compose::testing::CommandResult;
using compose::testing::quote;
using compose::testing::runCompose;
using compose::testing::slurp;

struct Raster {
  int width = 0, height = 0, channels = 0;
  std::vector<std::string> names;
  std::vector<float> px;
  int channel(const std::string& name) const {
    for (size_t i = 0; i < names.size(); ++i)
      if (names[i] == name) return int(i);
    ADD_FAILURE() << "no channel " << name;
    return 0;
  }
  float at(int x, int y, int c) const {
    return px[(size_t(y) * size_t(width) + size_t(x)) * size_t(channels) + size_t(c)];
  }
};

// Every part (subimage) of a file, each placed at its data window in the full frame (the
// display window), zero elsewhere: all channels of all parts in one full-frame raster.
Raster readRaster(const fs::path& path) {
  Raster r;
  auto in = OIIO::ImageInput::open(path.string());
  if (!in) {
    ADD_FAILURE() << "cannot open " << path;
    return r;
  }
  std::vector<OIIO::ImageSpec> parts;
  for (int sub = 0; in->seek_subimage(sub, 0); ++sub) parts.push_back(in->spec());
  r.width = parts[0].full_width;
  r.height = parts[0].full_height;
  for (const auto& p : parts)
    r.names.insert(r.names.end(), p.channelnames.begin(), p.channelnames.end());
  r.channels = int(r.names.size());
  r.px.assign(size_t(r.width) * size_t(r.height) * size_t(r.channels), 0.0f);
  int first = 0;
  for (size_t sub = 0; sub < parts.size(); ++sub) {
    const OIIO::ImageSpec& p = parts[sub];
    std::vector<float> buf(size_t(p.width) * size_t(p.height) * size_t(p.nchannels));
    EXPECT_TRUE(in->seek_subimage(int(sub), 0));
    EXPECT_TRUE(in->read_image(int(sub), 0, 0, p.nchannels, OIIO::TypeDesc::FLOAT, buf.data()));
    for (int y = 0; y < p.height; ++y)
      for (int x = 0; x < p.width; ++x)
        for (int c = 0; c < p.nchannels; ++c)
          r.px[(size_t(y + p.y) * size_t(r.width) + size_t(x + p.x)) * size_t(r.channels) +
               size_t(first + c)] =
              buf[(size_t(y) * size_t(p.width) + size_t(x)) * size_t(p.nchannels) + size_t(c)];
    first += p.nchannels;
  }
  return r;
}

// Written out here, independently of src/color: sRGB decode and Rec.709 → ACEScg (Bradford).
double srgbDecode(double v) {
  return v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
}
constexpr double kRec709ToAp1[3][3] = {{0.6130973, 0.3395229, 0.0473793},
                                       {0.0701942, 0.9163556, 0.0134526},
                                       {0.0206156, 0.1095698, 0.8698151}};
void toAp1(const double in[3], double out[3]) {
  for (int i = 0; i < 3; ++i)
    out[i] = kRec709ToAp1[i][0] * in[0] + kRec709ToAp1[i][1] * in[1] + kRec709ToAp1[i][2] * in[2];
}

// Exact irradiance of a lat-long map (OpenEXR axes, texel centres, exact solid angles), Rec.709.
struct ExactReference {
  std::vector<double> dir, weighted;  // per texel: xyz, and L·dω (RGB)
  explicit ExactReference(const Raster& env) {
    const int w = env.width, h = env.height;
    for (int y = 0; y < h; ++y) {
      const double top = kPi * (0.5 - double(y) / h), bottom = kPi * (0.5 - double(y + 1) / h);
      const double lat = kPi * (0.5 - (y + 0.5) / h);
      const double omega = 2.0 * kPi / w * (std::sin(top) - std::sin(bottom));
      for (int x = 0; x < w; ++x) {
        const double lon = kPi * (1.0 - 2.0 * (x + 0.5) / w);
        dir.insert(dir.end(),
                   {std::sin(lon) * std::cos(lat), std::sin(lat), std::cos(lon) * std::cos(lat)});
        for (int c = 0; c < 3; ++c) weighted.push_back(std::max(0.0f, env.at(x, y, c)) * omega);
      }
    }
  }
  void irradiance(const double n[3], double e[3]) const {
    e[0] = e[1] = e[2] = 0.0;
    for (size_t t = 0; t < dir.size() / 3; ++t) {
      const double c = n[0] * dir[3 * t] + n[1] * dir[3 * t + 1] + n[2] * dir[3 * t + 2];
      if (c <= 0.0) continue;
      for (int k = 0; k < 3; ++k) e[k] += weighted[3 * t + size_t(k)] * c;
    }
  }
};

class ComposeEndToEnd : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    samples_ = pipeline::samplesDirectory();
    for (const char* f : {"meadow.jpg", "bunny.obj", "forest.exr"}) {
      if (!fs::exists(samples_ / f)) {
        missing_ = (samples_ / f).string();
        return;
      }
    }
    dir_ = new TempDir();
    // One jittered sample per pixel: the N AOV is then the very normal each pixel was shaded
    // with, and an exact reference at that normal measures the lighting alone.
    run_ = runCompose("--plate " + quote((samples_ / "meadow.jpg").string()) + " --object " +
                          quote((samples_ / "bunny.obj").string()) +
                          " --samples 1 --shadows off --no-shadow --exposure " +
                          std::to_string(kExposureStops) + " --albedo " + std::to_string(kAlbedo) +
                          " --cache " + quote((dir_->path() / "cache").string()) + " --out " +
                          quote((dir_->path() / "comp").string()),
                      dir_->path());
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  void SetUp() override {
    ASSERT_TRUE(missing_.empty()) << "sample data missing (" << missing_
                                  << "): run samples/fetch.sh";
    ASSERT_EQ(run_.status, 0) << "compose failed:\n" << run_.err;
  }

  static constexpr double kExposureStops = -1.0;
  static constexpr double kAlbedo = 0.5;
  static inline fs::path samples_;
  static inline std::string missing_;
  static inline TempDir* dir_ = nullptr;
  static inline RunResult run_;
};

TEST_F(ComposeEndToEnd, WritesBothOutputsAtThePlateSizeAndPrintsTheirPaths) {
  const fs::path exr = dir_->path() / "comp.exr", jpg = dir_->path() / "comp.jpg";
  ASSERT_TRUE(fs::exists(exr));
  ASSERT_TRUE(fs::exists(jpg));
  EXPECT_NE(run_.out.find(exr.string()), std::string::npos) << run_.out;
  EXPECT_NE(run_.out.find(jpg.string()), std::string::npos) << run_.out;
  const Raster plate = readRaster(samples_ / "meadow.jpg");
  const Raster e = readRaster(exr), j = readRaster(jpg);
  EXPECT_EQ(e.width, plate.width);
  EXPECT_EQ(e.height, plate.height);
  EXPECT_EQ(j.width, plate.width);
  EXPECT_EQ(j.height, plate.height);
  for (const char* c : {"R", "G", "B", "A", "object.A", "N.X", "N.Y", "N.Z"})
    EXPECT_GE(e.channel(c), 0);
  // What it wrote, with the sample type, the codec and the JPEG's quality (the defaults here).
  EXPECT_NE(run_.err.find("wrote " + exr.string() + " (half, piz) and " + jpg.string() +
                          " (JPEG quality 95)"),
            std::string::npos)
      << run_.err;
}

TEST_F(ComposeEndToEnd, DiffersFromThePlateOnlyUnderTheObject) {
  const Raster plate = readRaster(samples_ / "meadow.jpg");
  const Raster e = readRaster(dir_->path() / "comp.exr");
  const int r = e.channel("R"), a = e.channel("object.A");
  // The EXR stores half floats: 2^-11 relative rounding, plus float colour maths.
  constexpr double kHalfRelative = 1.5e-3;
  int64_t outside = 0, inside = 0, changedInside = 0;
  double worst = 0.0;
  for (int y = 0; y < e.height; ++y) {
    for (int x = 0; x < e.width; ++x) {
      double enc[3], lin[3], cg[3];
      for (int c = 0; c < 3; ++c) {
        enc[c] = plate.at(x, y, c);
        lin[c] = srgbDecode(enc[c]);
      }
      toAp1(lin, cg);
      double diff = 0.0;
      for (int c = 0; c < 3; ++c)
        diff = std::max(diff, std::abs(e.at(x, y, r + c) - cg[c]) / std::max(cg[c], 1e-2));
      if (e.at(x, y, a) == 0.0f) {
        ++outside;
        worst = std::max(worst, diff);
      } else {
        ++inside;
        if (diff > 0.05) ++changedInside;
      }
    }
  }
  EXPECT_LE(worst, kHalfRelative) << "composite changed the plate outside the object";
  EXPECT_GT(inside, 20000) << "the bunny should cover a sizeable area";
  EXPECT_GT(changedInside, inside / 2);
  EXPECT_GT(outside, int64_t(e.width) * e.height / 2);
}

TEST_F(ComposeEndToEnd, ObjectPixelsMatchTheExactIrradianceReference) {
  const Raster e = readRaster(dir_->path() / "comp.exr");
  const Raster env = readRaster(samples_ / "forest.exr");
  const ExactReference exact(env);
  const int a = e.channel("object.A"), nx = e.channel("N.X"), r = e.channel("object.R");
  // Every fully covered pixel is a candidate; take an even spread of about 400 of them.
  std::vector<std::pair<int, int>> covered;
  for (int y = 0; y < e.height; ++y)
    for (int x = 0; x < e.width; ++x)
      if (e.at(x, y, a) == 1.0f) covered.emplace_back(x, y);
  ASSERT_GT(covered.size(), 10000u);
  const size_t step = covered.size() / 400;
  double signal = 0.0, noise = 0.0;
  const double scale = kAlbedo * std::exp2(kExposureStops) / kPi;
  for (size_t i = 0; i < covered.size(); i += step) {
    const auto [x, y] = covered[i];
    double n[3] = {e.at(x, y, nx), e.at(x, y, nx + 1), e.at(x, y, nx + 2)};
    const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    ASSERT_GT(len, 0.99) << "normal AOV at (" << x << ", " << y << ") is not unit length";
    for (double& v : n) v /= len;
    double e709[3], cg[3];
    exact.irradiance(n, e709);
    toAp1(e709, cg);
    for (int c = 0; c < 3; ++c) {
      const double ref = scale * cg[c], got = e.at(x, y, r + c);
      signal += ref * ref;
      noise += (ref - got) * (ref - got);
    }
  }
  const double snrDb = 10.0 * std::log10(signal / noise);
  // The default lighting is cheb-local (exact per-normal integrals on a 33x64 grid of normals,
  // interpolated), measured at 59.9 dB on these pixels (one sample per pixel, so the N AOV is the
  // shading normal): within 1 dB of the lighting benchmark's sphere figure for this map (59.5 dB).
  // A factor-π slip gives ~3 dB, the environment turned by 90° ~7 dB, a colour-space slip far
  // below the floor.
  constexpr double kDefaultSnrFloorDb = 55.0;
  EXPECT_GT(snrDb, kDefaultSnrFloorDb);
  RecordProperty("snr_db", std::to_string(snrDb));
  std::printf("object pixels vs exact reference: SNR %.2f dB\n", snrDb);
}

// A second run with the same environment and lighting parameters loads the projection from the
// cache instead of recomputing it, and produces the same pixels.
// The line a run printed for a stage ("compose: <stage> ..."), or empty.
std::string stageLine(const std::string& err, const std::string& stage) {
  const std::string prefix = "compose: " + stage + " ";
  size_t at = err.find(prefix);
  if (at == std::string::npos) return {};
  return err.substr(at, err.find('\n', at) - at);
}

TEST(ComposeCache, SecondRunReusesWhatIsUnchanged) {
  const fs::path samples = pipeline::samplesDirectory();
  if (!fs::exists(samples / "meadow.jpg") || !fs::exists(samples / "bunny.obj") ||
      !fs::exists(samples / "forest.exr")) {
    GTEST_FAIL() << "sample data missing in " << samples << ": run samples/fetch.sh";
  }
  TempDir dir;
  auto args = [&](const std::string& out) {
    return "--plate " + quote((samples / "meadow.jpg").string()) + " --object " +
           quote((samples / "bunny.obj").string()) + " --samples 1 --cache " +
           quote((dir.path() / "cache").string()) + " --out " + quote((dir.path() / out).string());
  };
  const RunResult first = runCompose(args("a"), dir.path());
  ASSERT_EQ(first.status, 0) << first.err;
  EXPECT_NE(stageLine(first.err, "precompute").find("projected the environment"), std::string::npos)
      << first.err;
  EXPECT_NE(stageLine(first.err, "precompute").find("cached in"), std::string::npos) << first.err;
  // The same job again: the render and the ground shadow come from the cache, and nothing made
  // from the environment's pixels is computed.
  const RunResult second = runCompose(args("b"), dir.path());
  ASSERT_EQ(second.status, 0) << second.err;
  EXPECT_NE(stageLine(second.err, "render").find("reused"), std::string::npos) << second.err;
  EXPECT_NE(stageLine(second.err, "ground").find("reused"), std::string::npos) << second.err;
  EXPECT_NE(stageLine(second.err, "precompute").find("skipped"), std::string::npos) << second.err;
  const Raster a = readRaster(dir.path() / "a.exr"), b = readRaster(dir.path() / "b.exr");
  ASSERT_EQ(a.px.size(), b.px.size());
  EXPECT_TRUE(a.px == b.px) << "cached stages must give identical pixels";
  // The object elsewhere: rendered again, from the cached projection and self-shadowing.
  const RunResult moved = runCompose(args("m") + " --place 0.45,0.75", dir.path());
  ASSERT_EQ(moved.status, 0) << moved.err;
  EXPECT_NE(stageLine(moved.err, "render").find("rays"), std::string::npos) << moved.err;
  EXPECT_NE(stageLine(moved.err, "precompute").find("reused"), std::string::npos) << moved.err;
  EXPECT_NE(stageLine(moved.err, "shadows").find("reused"), std::string::npos) << moved.err;
  // A different basis parameter is a different entry: projected again, not reused.
  const RunResult third = runCompose(args("c") + " --lighting-params rows=17,cols=32", dir.path());
  ASSERT_EQ(third.status, 0) << third.err;
  EXPECT_NE(stageLine(third.err, "precompute").find("projected the environment"), std::string::npos)
      << third.err;
}

// The self-shadowing read back from the cache belongs to the same surface points as when it was
// computed, those refined where visibility changes fast included: a job that reuses it gives the
// pixels of the same job without a cache. The teapot, whose points are refined where the spout
// and the handle enter the body, in view (a re-render once showed dark streaks there).
TEST(ComposeCache, AJobFromTheCacheGivesThePixelsOfTheSameJobWithout) {
  const fs::path samples = pipeline::samplesDirectory();
  if (!fs::exists(samples / "tabletop.jpg") || !fs::exists(samples / "teapot.bez") ||
      !fs::exists(samples / "interior.exr")) {
    GTEST_FAIL() << "sample data missing in " << samples << ": run samples/fetch.sh";
  }
  TempDir dir;
  auto args = [&](const std::string& out, const std::string& place) {
    return "--plate " + quote((samples / "tabletop.jpg").string()) + " --object " +
           quote((samples / "teapot.bez").string()) + " --env " +
           quote((samples / "interior.exr").string()) + " --samples 1 --scale 0.5 --yaw 60" +
           " --place " + place + " --no-shadow --out " + quote((dir.path() / out).string());
  };
  const std::string cache = " --cache " + quote((dir.path() / "cache").string());
  const RunResult first = runCompose(args("a", "0.5,0.6") + cache, dir.path());
  ASSERT_EQ(first.status, 0) << first.err;
  EXPECT_NE(stageLine(first.err, "shadows").find("more where visibility changes fast"),
            std::string::npos)
      << first.err;
  const RunResult moved = runCompose(args("m", "0.45,0.65") + cache, dir.path());
  ASSERT_EQ(moved.status, 0) << moved.err;
  EXPECT_NE(stageLine(moved.err, "shadows").find("reused"), std::string::npos) << moved.err;
  const RunResult fresh = runCompose(args("f", "0.45,0.65") + " --no-cache", dir.path());
  ASSERT_EQ(fresh.status, 0) << fresh.err;
  const Raster m = readRaster(dir.path() / "m.exr"), f = readRaster(dir.path() / "f.exr");
  ASSERT_EQ(m.px.size(), f.px.size());
  size_t differ = 0;
  for (size_t i = 0; i < m.px.size(); ++i) differ += m.px[i] != f.px[i];
  EXPECT_EQ(differ, 0u) << "values that differ between the job from the cache and without";
}

// --- error paths: clear message naming the file or option, non-zero exit, nothing written ---

// Writes `px` (floats, `channels` per pixel) as an image file stored as `format`.
void writePixels(const fs::path& path, int w, int h, int channels, OIIO::TypeDesc format,
                 const std::vector<float>& px) {
  auto out = OIIO::ImageOutput::create(path.string());
  ASSERT_TRUE(out && out->open(path.string(), OIIO::ImageSpec(w, h, channels, format)));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
  out->close();
}

class ComposeErrors : public ::testing::Test {
 protected:
  void SetUp() override {
    samples_ = pipeline::samplesDirectory();
    if (!fs::exists(samples_ / "meadow.jpg") || !fs::exists(samples_ / "bunny.obj")) {
      GTEST_FAIL() << "sample data missing in " << samples_ << ": run samples/fetch.sh";
    }
  }
  std::string base(const std::string& plate, const std::string& object) const {
    return "--plate " + quote(plate) + " --object " + quote(object) + " --no-cache --out " +
           quote((dir_ / "x").string());
  }
  // The options of base() with a cache folder the job may fill (named input-... so that
  // expectNothingWritten() passes it by) instead of --no-cache, and the object unshadowed.
  std::string cachedBase(const std::string& plate, const std::string& object) const {
    return "--plate " + quote(plate) + " --object " + quote(object) + " --shadows off --cache " +
           quote((dir_ / "input-cache").string()) + " --out " + quote((dir_ / "x").string());
  }
  // Whether a job run with cachedBase() got as far as the render: its stage entry is stored.
  bool rendered() const {
    std::error_code ec;
    const fs::path entries = dir_ / "input-cache" / "stages" / "render";
    return fs::exists(entries, ec) && !fs::is_empty(entries, ec);
  }
  void expectNothingWritten() const {
    for (const auto& entry : fs::directory_iterator(dir_.path())) {
      const std::string name = entry.path().filename().string();
      EXPECT_TRUE(name == "stdout.txt" || name == "stderr.txt" || name.rfind("input", 0) == 0)
          << "unexpected file left behind: " << name;
    }
  }
  fs::path samples_;
  TempDir dir_;
};

TEST_F(ComposeErrors, MissingPlate) {
  const auto r =
      runCompose(base("/no/such/plate.jpg", (samples_ / "bunny.obj").string()), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("compose: error: ingest: file not found (/no/such/plate.jpg)"),
            std::string::npos)
      << r.err;
  expectNothingWritten();
}

TEST_F(ComposeErrors, CorruptPlate) {
  const fs::path bad = dir_ / "input-corrupt.jpg";
  compose::testing::writeText(bad, std::string("\xFF\xD8\xFF\xE0", 4) + std::string(100, '\x13'));
  const auto r = runCompose(base(bad.string(), (samples_ / "bunny.obj").string()), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("compose: error: ingest: cannot"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(bad.string()), std::string::npos) << r.err;
  expectNothingWritten();
}

// A depth pass given as the plate (one channel, Z) is a named error, not a grey plate.
TEST_F(ComposeErrors, APlateWithoutColourChannelsIsANamedError) {
  const fs::path depth = dir_ / "input-depth.exr";
  {
    OIIO::ImageSpec spec(64, 48, 1, OIIO::TypeDesc::FLOAT);
    spec.channelnames = {"Z"};
    std::vector<float> z(64 * 48, 3.0f);
    auto out = OIIO::ImageOutput::create(depth.string());
    ASSERT_TRUE(out->open(depth.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, z.data()));
    out->close();
  }
  const auto r = runCompose(base(depth.string(), (samples_ / "bunny.obj").string()), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(
      r.err.find("ingest: the plate has no colour channel (R, G, B or Y): its channels are Z"),
      std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find(depth.string()), std::string::npos) << r.err;
  expectNothingWritten();
}

TEST_F(ComposeErrors, UnknownOption) {
  const auto r =
      runCompose(base((samples_ / "meadow.jpg").string(), (samples_ / "bunny.obj").string()) +
                     " --frobnicate 3",
                 dir_.path());
  EXPECT_EQ(r.status, 2);
  EXPECT_NE(r.err.find("compose: error: cli:"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--frobnicate"), std::string::npos) << r.err;
  expectNothingWritten();
}

TEST_F(ComposeErrors, AnOutputCodecOrQualityItDoesNotKnowIsAUsageError) {
  const std::string args =
      base((samples_ / "meadow.jpg").string(), (samples_ / "bunny.obj").string());
  for (const char* bad : {"--compression lzw", "--compression zip:10", "--compression piz:2",
                          "--compression dwaa:0", "--jpeg-quality 0", "--jpeg-quality 101"}) {
    const auto r = runCompose(args + " " + bad, dir_.path());
    EXPECT_EQ(r.status, 2) << bad << ": " << r.err;
    EXPECT_NE(r.err.find(std::string(bad).substr(0, std::string(bad).find(' '))), std::string::npos)
        << r.err;
    expectNothingWritten();
  }
  const auto unknown = runCompose(args + " --compression lzw", dir_.path());
  EXPECT_NE(unknown.err.find("unknown OpenEXR compression 'lzw' (known: none, rle, zips, zip, piz"),
            std::string::npos)
      << unknown.err;
}

// --out names a base: one ending in an image format compose does not write there would have
// ended inside the names (x.tif.exr, x.tif.jpg).
TEST_F(ComposeErrors, AnOutputNamedForAnotherImageFormatIsAUsageError) {
  for (const char* name : {"x.tif", "x.HDR", "x.jxl", "x.exr.gz"}) {
    const auto r = runCompose("--plate " + quote((samples_ / "meadow.jpg").string()) +
                                  " --object " + quote((samples_ / "bunny.obj").string()) +
                                  " --no-cache --out " + quote((dir_ / name).string()),
                              dir_.path());
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_NE(r.err.find("compose writes BASE.exr and BASE.jpg (or BASE.png)"), std::string::npos)
        << r.err;
    expectNothingWritten();
  }
}

TEST_F(ComposeErrors, UnknownLightingBasisListsTheValidOnes) {
  const auto r =
      runCompose(base((samples_ / "meadow.jpg").string(), (samples_ / "bunny.obj").string()) +
                     " --lighting wavelets",
                 dir_.path());
  EXPECT_EQ(r.status, 2) << "a misspelt command-line value is a usage error";
  EXPECT_NE(r.err.find("unknown lighting basis 'wavelets'; valid: cheb-local, cheb-latlong, "
                       "cheb-face, sh, mc, exact"),
            std::string::npos)
      << r.err;
  // A parameter the basis does not take is refused: order=... looked at for "auto" counted as
  // read, so exact took order=abc without a word.
  const auto exact =
      runCompose(base((samples_ / "meadow.jpg").string(), (samples_ / "bunny.obj").string()) +
                     " --lighting exact --lighting-params order=abc",
                 dir_.path());
  EXPECT_EQ(exact.status, 2) << exact.err;
  EXPECT_NE(exact.err.find("lighting basis 'exact' does not take parameter(s): order"),
            std::string::npos)
      << exact.err;
}

TEST_F(ComposeErrors, NanEnvironmentIsRejectedAndOldOutputKept) {
  const fs::path env = dir_ / "input-nan.exr";
  {
    std::vector<float> px(16 * 8 * 3, 1.0f);
    px[(2 * 16 + 5) * 3 + 1] = std::nanf("");
    writePixels(env.string(), 16, 8, 3, OIIO::TypeDesc::FLOAT, px);
  }
  compose::testing::writeText(dir_ / "x.exr", "previous result");
  const auto r =
      runCompose(base((samples_ / "meadow.jpg").string(), (samples_ / "bunny.obj").string()) +
                     " --env " + quote(env.string()),
                 dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("lighting: NaN radiance at texel (5, 2) (" + env.string() + ")"),
            std::string::npos)
      << r.err;
  EXPECT_EQ(slurp(dir_ / "x.exr"), "previous result");
  EXPECT_FALSE(fs::exists(dir_ / "x.jpg"));
}

// An environment without light (all zero, or all negative and clamped) lit the object black and
// the automatic exposure "matched" a ball of radiance 0 with exit 0: now a named error.
TEST_F(ComposeErrors, AnEnvironmentWithoutLightIsANamedError) {
  for (const float value : {0.0f, -0.5f}) {
    const fs::path env = dir_ / "input-dark.exr";
    {
      std::vector<float> px(16 * 8 * 3, value);
      writePixels(env.string(), 16, 8, 3, OIIO::TypeDesc::FLOAT, px);
    }
    const auto r =
        runCompose(base((samples_ / "meadow.jpg").string(), (samples_ / "monkey.obj").string()) +
                       " --env " + quote(env.string()),
                   dir_.path());
    EXPECT_EQ(r.status, 1);
    EXPECT_NE(r.err.find("lighting: the environment holds no light: every texel is 0"),
              std::string::npos)
        << r.err;
    EXPECT_EQ(r.err.find(" once its negative values are clamped") != std::string::npos,
              value < 0.0f)
        << r.err;
    EXPECT_NE(r.err.find(env.string()), std::string::npos) << r.err;
    expectNothingWritten();
  }
  // Light too dim for single precision (a uniform 1e-30, a subnormal 1e-44) rendered the object
  // black while the exposure note said it matched the plate: refused. 1e-20 still renders (on a
  // small grey plate, which keeps the test quick).
  const fs::path plate = dir_ / "input-plate.png";
  writePixels(plate, 96, 64, 3, OIIO::TypeDesc::UINT8, std::vector<float>(96 * 64 * 3, 0.4f));
  for (const float value : {1e-30f, 1e-44f, 1e-20f}) {
    const fs::path env = dir_ / "input-dim.exr";
    {
      std::vector<float> px(16 * 8 * 3, value);
      writePixels(env.string(), 16, 8, 3, OIIO::TypeDesc::FLOAT, px);
    }
    const bool dim = value < 1e-20f;
    // The one that renders is self-shadowed from a coarser visibility grid than the default's.
    const auto r =
        runCompose(base(plate.string(), (samples_ / "monkey.obj").string()) + " --env " +
                       quote(env.string()) + (dim ? "" : " --shadow-params order=4,grid=4"),
                   dir_.path());
    EXPECT_EQ(r.status, dim ? 1 : 0) << value << ": " << r.err;
    EXPECT_EQ(r.err.find("too dim to light anything in single precision") != std::string::npos, dim)
        << r.err;
    if (dim) expectNothingWritten();
  }
}

// A holdout of the wrong size was found by the composite, after the whole render: its header is
// checked when the plate is read.
TEST_F(ComposeErrors, AHoldoutOfTheWrongSizeStopsTheJobBeforeTheRender) {
  {
    const std::string file = (dir_ / "input-mask.png").string();
    std::vector<float> px(40 * 30, 1.0f);
    writePixels(file, 40, 30, 1, OIIO::TypeDesc::UINT8, px);
  }
  const auto r = runCompose(
      cachedBase((samples_ / "meadow.jpg").string(), (samples_ / "monkey.obj").string()) +
          " --holdout " + quote((dir_ / "input-mask.png").string()),
      dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("composite: the holdout mask is 40x30, the plate "), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("input-mask.png"), std::string::npos) << r.err;
  EXPECT_FALSE(rendered()) << "rendered first: " << r.err;
  expectNothingWritten();
}

// A holdout mask is data, but NaN in it put NaN in the composite: it is refused, naming the pixel,
// when the plate is read (it was found by the composite, after the whole render).
TEST_F(ComposeErrors, AHoldoutWithNaNIsRefused) {
  const fs::path mask = dir_ / "input-mask.exr";
  {
    std::vector<float> px(64 * 48, 0.0f);
    px[7 * 64 + 5] = std::nanf("");
    writePixels(mask.string(), 64, 48, 1, OIIO::TypeDesc::FLOAT, px);
  }
  {
    const std::string file = (dir_ / "input-plate.png").string();
    std::vector<float> px(64 * 48 * 3, 0.4f);
    writePixels(file, 64, 48, 3, OIIO::TypeDesc::UINT8, px);
  }
  const std::string job =
      cachedBase((dir_ / "input-plate.png").string(), (samples_ / "monkey.obj").string());
  const auto r = runCompose(job + " --holdout " + quote(mask.string()), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("composite: NaN in the holdout mask at pixel (5, 7)"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("input-mask.exr"), std::string::npos) << r.err;
  EXPECT_FALSE(rendered()) << "rendered first: " << r.err;
  expectNothingWritten();
  // The same job without the mask renders, and its render is seen in the cache.
  const auto unmasked = runCompose(job, dir_.path());
  ASSERT_EQ(unmasked.status, 0) << unmasked.err;
  EXPECT_TRUE(rendered());
}

// The holdout puts the plate in front of the object where the mask is white: there the composite
// is the plate, elsewhere the composite without a holdout; of an RGB mask only the first channel
// counts.
TEST_F(ComposeErrors, AHoldoutPutsThePlateInFrontWhereItIsWhite) {
  const int w = 64, h = 48;
  {
    std::vector<float> plate(size_t(w) * h * 3, 0.4f);
    writePixels(dir_ / "input-plate.png", w, h, 3, OIIO::TypeDesc::UINT8, plate);
    std::vector<float> grey(size_t(w) * h), rgb(size_t(w) * h * 3);
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const size_t i = size_t(y) * w + x;
        grey[i] = x < w / 2 ? 1.0f : 0.0f;
        rgb[3 * i] = grey[i];
        rgb[3 * i + 1] = 1.0f - grey[i];  // ignored
        rgb[3 * i + 2] = 0.5f;
      }
    }
    writePixels(dir_ / "input-mask.exr", w, h, 1, OIIO::TypeDesc::FLOAT, grey);
    writePixels(dir_ / "input-mask.png", w, h, 3, OIIO::TypeDesc::UINT8, rgb);
  }
  const auto composite = [&](const std::string& options, const std::string& out) {
    const auto r = runCompose("--plate " + quote((dir_ / "input-plate.png").string()) +
                                  " --object " + quote((samples_ / "monkey.obj").string()) +
                                  " --scale 0.8 --shadows off --no-cache --out " +
                                  quote((dir_ / out).string()) + options,
                              dir_.path());
    EXPECT_EQ(r.status, 0) << r.err;
    std::vector<float> px(size_t(w) * h * 4);
    auto in = OIIO::ImageInput::open((dir_ / (out + ".exr")).string());
    EXPECT_TRUE(in && in->spec().width == w && in->spec().height == h &&
                in->spec().nchannels == 4 &&
                in->read_image(0, 0, 0, 4, OIIO::TypeDesc::FLOAT, px.data()))
        << out;
    return px;
  };
  const std::vector<float> plain = composite("", "plain"),
                           masked = composite(
                               " --holdout " + quote((dir_ / "input-mask.exr").string()), "masked"),
                           rgbMask = composite(
                               " --holdout " + quote((dir_ / "input-mask.png").string()), "rgb");
  // The plate as the composite shows it, where neither the object nor its shadow reaches.
  const float* plate = &plain[0];
  int objectLeft = 0, objectRight = 0, plateLeft = 0, sameRight = 0;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const size_t i = (size_t(y) * w + x) * 4;
      const bool isPlate = std::equal(plate, plate + 4, &masked[i]);
      if (x < w / 2) {
        objectLeft += !std::equal(plate, plate + 4, &plain[i]);
        plateLeft += isPlate;
      } else {
        objectRight += !std::equal(plate, plate + 4, &plain[i]);
        sameRight += std::equal(&plain[i], &plain[i] + 4, &masked[i]);
      }
    }
  }
  EXPECT_GT(objectLeft, w * h / 20) << "the object should cover part of the left half";
  EXPECT_GT(objectRight, w * h / 20) << "and of the right half";
  EXPECT_EQ(plateLeft, w / 2 * h) << "the plate in front where the mask is white";
  EXPECT_EQ(sameRight, w / 2 * h) << "the composite without a holdout where the mask is black";
  EXPECT_EQ(rgbMask, masked) << "only the first channel of an RGB mask counts";
}

// The EXR's parts give the composite again with a holdout in front, soft edges included: the
// plate times the shadow part, the object part over it (they gave the object in front of what
// holds it out, and the shadow where the plate was not darkened); the header names the mask.
TEST_F(ComposeErrors, AHoldoutHoldsOutTheObjectAndShadowPartsToo) {
  const int w = 96, h = 72;
  {
    std::vector<float> plate(size_t(w) * h * 3, 0.4f), ramp(size_t(w) * h);
    writePixels(dir_ / "input-plate.png", w, h, 3, OIIO::TypeDesc::UINT8, plate);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        ramp[size_t(y) * w + x] = std::clamp(float(x - 30) / 36.0f, 0.0f, 1.0f);
    writePixels(dir_ / "input-mask.exr", w, h, 1, OIIO::TypeDesc::FLOAT, ramp);
  }
  const auto r =
      runCompose("--plate " + quote((dir_ / "input-plate.png").string()) + " --object " +
                     quote((samples_ / "monkey.obj").string()) +
                     " --scale 0.7 --samples 1 --depth float --no-cache --holdout " +
                     quote((dir_ / "input-mask.exr").string()) +
                     " --shadow-params order=4,grid=4 --out " + quote((dir_ / "held").string()),
                 dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  // Each part over the whole frame (1 outside its data window for the shadow, 0 for the object).
  auto in = OIIO::ImageInput::open((dir_ / "held.exr").string());
  ASSERT_TRUE(in);
  std::map<std::string, std::vector<float>> frame;  // channel name -> w x h
  for (int sub = 0; in->seek_subimage(sub, 0); ++sub) {
    const OIIO::ImageSpec spec = in->spec();
    const std::string name = spec.get_string_attribute("oiio:subimagename");
    if (sub == 0) {
      EXPECT_EQ(spec.get_string_attribute("compose:holdout"),
                fs::absolute(dir_ / "input-mask.exr").string());
    }
    std::vector<float> px(size_t(spec.width) * spec.height * spec.nchannels);
    ASSERT_TRUE(in->read_image(sub, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, px.data()));
    for (int c = 0; c < spec.nchannels; ++c) {
      const std::string channel = name + ":" + std::string(spec.channel_name(c));
      std::vector<float>& f = frame[channel];
      f.assign(size_t(w) * h, name == "shadow" ? 1.0f : 0.0f);
      for (int y = 0; y < spec.height; ++y)
        for (int x = 0; x < spec.width; ++x)
          f[size_t(y + spec.y) * w + size_t(x + spec.x)] =
              px[(size_t(y) * spec.width + x) * spec.nchannels + c];
    }
  }
  ASSERT_TRUE(frame.count("shadow:shadow.R")) << "the monkey's ground shadow";
  // The plate's grey in linear light: code 102 decoded.
  const float plate = std::pow((102.0f / 255.0f + 0.055f) / 1.055f, 2.4f);
  double worst = 0.0;
  int soft = 0, heldOut = 0;
  for (size_t i = 0; i < size_t(w) * h; ++i) {
    const float a = frame["object:object.A"][i];
    for (const char* c : {"R", "G", "B"}) {
      const float rebuilt = plate * frame[std::string("shadow:shadow.") + c][i] * (1.0f - a) +
                            frame[std::string("object:object.") + c][i];
      worst = std::max(worst, double(std::abs(rebuilt - frame[std::string("composite:") + c][i])));
    }
    const int x = int(i % size_t(w));
    soft += a > 0.0f && x > 30 && x < 66;
    heldOut += x >= 66 && a > 0.0f;
  }
  EXPECT_LT(worst, 2e-3) << "the parts give the composite";
  EXPECT_GT(soft, 50) << "the object should reach the mask's soft edge";
  EXPECT_EQ(heldOut, 0) << "no object where the plate is wholly in front";
}

// A plate whose header names a colour space the config does not have was read as the default
// space without a word: the stage line says what it assumed and how to say otherwise.
TEST_F(ComposeErrors, APlateInAnUnknownSpaceSaysWhatWasAssumed) {
  const fs::path plate = dir_ / "input-plate.exr";
  {
    std::vector<float> px(64 * 48 * 3, 0.3f);
    OIIO::ImageSpec spec(64, 48, 3, OIIO::TypeDesc::HALF);
    spec.attribute("colorSpace", "NoSuchSpace");
    auto out = OIIO::ImageOutput::create(plate.string());
    ASSERT_TRUE(out->open(plate.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  const auto r = runCompose(
      base(plate.string(), (samples_ / "monkey.obj").string()) + " --shadows off", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("(the file says 'NoSuchSpace', which the config does not know; the "
                       "config's file rule for it; give --plate-space to say which it is)"),
            std::string::npos)
      << r.err;
}

// A float plate with NaN or infinity: an error naming the pixel (they went through to the output,
// and an infinite pixel made the automatic exposure +inf stops).
TEST_F(ComposeErrors, NonFinitePlateIsRejectedAndOldOutputKept) {
  const fs::path plate = dir_ / "plate-bad.exr";
  compose::testing::writeText(dir_ / "x.exr", "previous result");
  for (const float bad : {std::nanf(""), std::numeric_limits<float>::infinity()}) {
    std::vector<float> px(64 * 48 * 3, 0.4f);
    px[(7 * 64 + 12) * 3 + 1] = bad;
    writePixels(plate.string(), 64, 48, 3, OIIO::TypeDesc::FLOAT, px);
    const auto r = runCompose(
        base(plate.string(), (samples_ / "monkey.obj").string()) + " --shadows off", dir_.path());
    EXPECT_EQ(r.status, 1);
    EXPECT_NE(r.err.find(std::string("ingest: ") + (std::isnan(bad) ? "NaN" : "infinity") +
                         " in the plate at pixel (12, 7): its values must be finite (" +
                         plate.string() + ")"),
              std::string::npos)
        << r.err;
    EXPECT_EQ(slurp(dir_ / "x.exr"), "previous result");
    EXPECT_FALSE(fs::exists(dir_ / "x.jpg"));
  }
}

}  // namespace
}  // namespace compose

// --- outputs that say what they are, appear together, and never hold Inf ---

namespace compose {
namespace {

void writeExr(const fs::path& path, int w, int h, const std::function<void(float*, int, int)>& f) {
  std::vector<float> px(size_t(w) * size_t(h) * 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) f(&px[(size_t(y) * size_t(w) + size_t(x)) * 3], x, y);
  auto out = OIIO::ImageOutput::create(path.string());
  ASSERT_TRUE(out->open(path.string(), OIIO::ImageSpec(w, h, 3, OIIO::TypeDesc::FLOAT)));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
  out->close();
}

void writeGreyPlate(const fs::path& path, int w, int h, float encoded) {
  std::vector<float> px(size_t(w) * size_t(h) * 3, encoded);
  auto out = OIIO::ImageOutput::create(path.string());
  ASSERT_TRUE(out->open(path.string(), OIIO::ImageSpec(w, h, 3, OIIO::TypeDesc::UINT8)));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
  out->close();
}

class ComposeOutputs : public ::testing::Test {
 protected:
  void SetUp() override {
    samples_ = pipeline::samplesDirectory();
    if (!fs::exists(samples_ / "bunny.obj") || !fs::exists(samples_ / "forest.exr"))
      GTEST_FAIL() << "sample data missing in " << samples_ << ": run samples/fetch.sh";
    writeGreyPlate(dir_ / "input-plate.png", 320, 240, 0.5f);
  }
  std::string args(const std::string& out, const std::string& plate = "input-plate.png") const {
    return "--plate " + quote((dir_ / plate).string()) + " --object " +
           quote((samples_ / "bunny.obj").string()) +
           " --samples 1 --shadows off --no-shadow --no-cache --out " + quote(out);
  }
  fs::path samples_;
  TempDir dir_;
};

// Through a 220° fisheye, the object placed 124° off the axis: depth.Z is the distance along the
// ray to P (it was the depth along the axis: negative, -1.2 to -0.13 where P was 0.9 to 3.6 m
// away).
TEST_F(ComposeOutputs, AFisheyesDepthIsTheDistanceAlongTheRay) {
  compose::testing::writeText(dir_ / "fisheye.json",
                              R"({"model": "equidistant", "width": 320, "height": 240,
                                  "fx": 83.3, "fy": 83.3, "cx": 160, "cy": 120, "dist": [],
                                  "rms": 0.1})");
  const auto r = runCompose(args((dir_ / "fe").string()) + " --scale 0.1 --place 0.05,0.95 " +
                                "--calib " + quote((dir_ / "fisheye.json").string()),
                            dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  const Raster out = readRaster(dir_ / "fe.exr");
  const int a = out.channel("object.A"), depth = out.channel("depth.Z"), px = out.channel("P.X");
  int covered = 0;
  for (int y = 0; y < out.height; ++y)
    for (int x = 0; x < out.width; ++x) {
      if (!(out.at(x, y, a) > 0.99f)) continue;
      ++covered;
      // The camera stands 1.6 m above the origin (no pose).
      const glm::dvec3 p(out.at(x, y, px), out.at(x, y, px + 1) - 1.6, out.at(x, y, px + 2));
      ASSERT_NEAR(out.at(x, y, depth), glm::length(p), 1e-3 * glm::length(p)) << x << "," << y;
    }
  EXPECT_GT(covered, 10);
}

// A lens whose distortion folds the frame where --place points (r - 100 r³ turns back at
// r = 0.058, distorted 0.038: the point, at 0.18, is past it): the error names the lens file and
// the point (it named neither).
TEST_F(ComposeOutputs, APlaceTheCalibratedLensCannotSeeNamesTheLensFile) {
  compose::testing::writeText(dir_ / "folded.json",
                              R"({"model": "rectilinear", "width": 320, "height": 240, "fx": 300,
                                  "fy": 300, "cx": 159.5, "cy": 119.5,
                                  "dist": [-100, 0, 0, 0, 0], "rms": 0.1})");
  const auto r = runCompose(
      args((dir_ / "folded").string()) + " --calib " + quote((dir_ / "folded.json").string()),
      dir_.path());
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("camera: --place 0.5,0.72 is outside what the calibrated lens can see"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("folded.json)"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "folded.exr"));
  // A point the lens sees, above the horizon: --place's doing, not the lens file's (it was
  // named whenever the lens had distortion).
  compose::testing::writeText(dir_ / "mild.json",
                              R"({"model": "rectilinear", "width": 320, "height": 240, "fx": 300,
                                  "fy": 300, "cx": 159.5, "cy": 119.5,
                                  "dist": [-0.1, 0, 0, 0, 0], "rms": 0.1})");
  const auto sky = runCompose(args((dir_ / "sky").string()) + " --place 0.5,0.3 --calib " +
                                  quote((dir_ / "mild.json").string()),
                              dir_.path());
  EXPECT_EQ(sky.status, 1) << sky.err;
  EXPECT_NE(sky.err.find("camera: --place 0.5,0.3 is at or above the horizon"), std::string::npos)
      << sky.err;
  EXPECT_EQ(sky.err.find("mild.json"), std::string::npos) << sky.err;
}

// An anamorphic plate (an OpenEXR whose pixelAspectRatio is 2: each stored pixel shown twice
// as wide as high): the object is seen through a camera whose focal length across is half its
// focal length down, so that it is half as many stored pixels wide as on square pixels and as
// high, and the EXR keeps the ratio (the object came out twice too wide once shown, and the
// output said its pixels were square).
TEST_F(ComposeOutputs, AnAnamorphicPlatesPixelsAreHonoured) {
  for (const float aspect : {1.0f, 2.0f, 1000.0f}) {
    std::vector<float> px(size_t(320) * 240 * 3, 0.2f);
    const fs::path plate = dir_ / (aspect == 1.0f   ? "square.exr"
                                   : aspect == 2.0f ? "squeezed.exr"
                                                    : "stretched.exr");
    auto out = OIIO::ImageOutput::create(plate.string());
    OIIO::ImageSpec spec(320, 240, 3, OIIO::TypeDesc::FLOAT);
    spec.attribute("PixelAspectRatio", aspect);
    ASSERT_TRUE(out->open(plate.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  // A ratio no picture has is refused naming the plate (it named no file).
  const auto stretched = runCompose(args((dir_ / "s").string(), "stretched.exr"), dir_.path());
  EXPECT_EQ(stretched.status, 1) << stretched.err;
  EXPECT_NE(stretched.err.find("pixel aspect ratio 1000 is not one a picture has (0.01 to 100) (" +
                               (dir_ / "stretched.exr").string() + ")"),
            std::string::npos)
      << stretched.err;
  int width[2] = {0, 0}, height[2] = {0, 0};
  for (int i = 0; i < 2; ++i) {
    const std::string name = i == 0 ? "square" : "squeezed";
    const auto r = runCompose(args((dir_ / ("out-" + name)).string(), name + ".exr"), dir_.path());
    ASSERT_EQ(r.status, 0) << r.err;
    if (i == 1) {
      EXPECT_NE(r.err.find("its pixels are 2 times as wide as high"), std::string::npos) << r.err;
    }
    const Raster e = readRaster(dir_ / ("out-" + name + ".exr"));
    const int a = e.channel("object.A");
    int x0 = e.width, x1 = -1, y0 = e.height, y1 = -1;
    for (int y = 0; y < e.height; ++y)
      for (int x = 0; x < e.width; ++x)
        if (e.at(x, y, a) > 0.5f) {
          x0 = std::min(x0, x), x1 = std::max(x1, x);
          y0 = std::min(y0, y), y1 = std::max(y1, y);
        }
    width[i] = x1 - x0 + 1;
    height[i] = y1 - y0 + 1;
    auto in = OIIO::ImageInput::open((dir_ / ("out-" + name + ".exr")).string());
    ASSERT_TRUE(in);
    EXPECT_FLOAT_EQ(in->spec().get_float_attribute("PixelAspectRatio", 1.0f), i == 0 ? 1.0f : 2.0f);
  }
  EXPECT_NEAR(double(width[1]) / width[0], 0.5, 0.05) << width[0] << " " << width[1];
  EXPECT_NEAR(height[1], height[0], 2);
}

TEST_F(ComposeOutputs, AFailedDisplayWriteKeepsThePreviousExr) {
  compose::testing::writeText(dir_ / "x.exr", "previous result");
  fs::create_directory(dir_ / "x.jpg");  // the JPEG cannot be written: a folder has its name
  const auto r = runCompose(args((dir_ / "x").string()), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("x.jpg"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("is an existing folder"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(dir_ / "x.exr"), "previous result") << "the old EXR must survive";
  for (const auto& e : fs::directory_iterator(dir_.path()))
    EXPECT_EQ(e.path().filename().string().find(".partial"), std::string::npos)
        << "temporary left behind: " << e.path();
}

TEST_F(ComposeOutputs, ExrSaysWhatColourSpaceItIsIn) {
  const auto r = runCompose(args((dir_ / "c").string()), dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  auto in = OIIO::ImageInput::open((dir_ / "c.exr").string());
  ASSERT_TRUE(in);
  const OIIO::ImageSpec& spec = in->spec();
  const OIIO::ParamValue* c = spec.find_attribute("chromaticities");
  ASSERT_NE(c, nullptr) << "no chromaticities: every tool would read the EXR as Rec.709";
  const float* xy = static_cast<const float*>(c->data());
  // ACES AP1 (ACEScg), the built-in working space, and the ACES white.
  const float ap1[8] = {0.713f, 0.293f, 0.165f, 0.830f, 0.128f, 0.044f, 0.32168f, 0.33767f};
  for (int i = 0; i < 8; ++i) EXPECT_NEAR(xy[i], ap1[i], 1e-6) << "entry " << i;
  EXPECT_EQ(spec.get_string_attribute("colorSpace"), "ACEScg");
  // The display image is tagged sRGB (EXIF ColorSpace 1), unless its view is Raw.
  auto jpeg = OIIO::ImageInput::open((dir_ / "c.jpg").string());
  ASSERT_TRUE(jpeg);
  EXPECT_EQ(jpeg->spec().get_int_attribute("Exif:ColorSpace", 0), 1);
  const auto raw = runCompose(args((dir_ / "r").string()) + " --view Raw", dir_.path());
  ASSERT_EQ(raw.status, 0) << raw.err;
  auto rawJpeg = OIIO::ImageInput::open((dir_ / "r.jpg").string());
  ASSERT_TRUE(rawJpeg);
  EXPECT_NE(rawJpeg->spec().get_int_attribute("Exif:ColorSpace", 0), 1);
}

// --exr-space writes the colour channels in another linear space, with its chromaticities, for a
// compositor whose working space is not the config's (Nuke's default linear Rec.709): the
// composite, the object and its albedo and irradiance, converted (checked here by the Rec.709 to
// ACEScg matrix written out above); normals, positions and alpha as they were. A space that is not
// linear, or data, is refused before anything is read.
TEST_F(ComposeOutputs, TheExrCanBeWrittenInAnotherLinearSpace) {
  const std::string common = " --depth float --albedo 0.6";
  ASSERT_EQ(runCompose(args((dir_ / "cg").string()) + common, dir_.path()).status, 0);
  const auto r =
      runCompose(args((dir_ / "rec709").string()) + common + " --exr-space 'Linear Rec.709 (sRGB)'",
                 dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  {
    auto in = OIIO::ImageInput::open((dir_ / "rec709.exr").string());
    ASSERT_TRUE(in);
    const OIIO::ParamValue* c = in->spec().find_attribute("chromaticities");
    ASSERT_NE(c, nullptr);
    const float rec709[8] = {0.64f, 0.33f, 0.30f, 0.60f, 0.15f, 0.06f, 0.3127f, 0.3290f};
    for (int i = 0; i < 8; ++i)
      EXPECT_NEAR(static_cast<const float*>(c->data())[i], rec709[i], 1e-4) << i;
    EXPECT_EQ(in->spec().get_string_attribute("colorSpace"), "Linear Rec.709 (sRGB)");
  }
  const Raster cg = readRaster(dir_ / "cg.exr"), lin = readRaster(dir_ / "rec709.exr");
  ASSERT_EQ(cg.names, lin.names);
  auto index = [&](const std::string& name) {
    return int(std::find(cg.names.begin(), cg.names.end(), name) - cg.names.begin());
  };
  int converted = 0;
  for (const char* layer : {"", "object.", "albedo.", "irradiance.", "irradianceShadowed."}) {
    const int first = index(std::string(layer) + "R");
    ASSERT_LT(first, int(cg.names.size())) << layer;
    double worst = 0.0, largest = 0.0;
    for (int y = 0; y < cg.height; ++y)
      for (int x = 0; x < cg.width; ++x) {
        const double in[3] = {lin.at(x, y, first), lin.at(x, y, first + 1),
                              lin.at(x, y, first + 2)};
        double back[3];
        toAp1(in, back);
        for (int k = 0; k < 3; ++k) {
          worst = std::max(worst, std::abs(back[k] - cg.at(x, y, first + k)));
          largest = std::max(largest, double(std::abs(cg.at(x, y, first + k))));
        }
      }
    EXPECT_GT(largest, 0.05) << layer;
    EXPECT_LT(worst, 1e-4 * largest + 1e-6) << layer;
    ++converted;
  }
  EXPECT_EQ(converted, 5);
  for (const char* name : {"A", "object.A", "N.X", "N.Y", "N.Z", "P.X", "depth.Z"}) {
    const int c = index(name);
    ASSERT_LT(c, int(cg.names.size())) << name;
    for (int y = 0; y < cg.height; ++y)
      for (int x = 0; x < cg.width; ++x) ASSERT_EQ(lin.at(x, y, c), cg.at(x, y, c)) << name;
  }
  for (const std::string space : {"sRGB", "Raw"}) {
    const auto bad =
        runCompose(args((dir_ / "bad").string()) + " --exr-space " + space, dir_.path());
    EXPECT_EQ(bad.status, 2) << space;
    EXPECT_NE(bad.err.find("is not a linear colour space"), std::string::npos) << bad.err;
    EXPECT_FALSE(fs::exists(dir_ / "bad.exr"));
  }
}

TEST_F(ComposeOutputs, OutEndingInASlashWritesIntoThatFolder) {
  const auto r = runCompose(args((dir_ / "results").string() + "/"), dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir_ / "results" / "compose.exr"));
  EXPECT_TRUE(fs::exists(dir_ / "results" / "compose.jpg"));
}

TEST_F(ComposeOutputs, RadianceBeyondHalfRangeIsWrittenAsFloatNotInf) {
  writeExr(dir_ / "input-bright.exr", 32, 16,
           [](float* p, int, int) { p[0] = p[1] = p[2] = 1e30f; });
  const auto r = runCompose(args((dir_ / "b").string()) + " --exposure 0 --env " +
                                quote((dir_ / "input-bright.exr").string()),
                            dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("exceed half float's range (65504): that part of the EXR is written as "
                       "32-bit float"),
            std::string::npos)
      << r.err;
  const Raster e = readRaster(dir_ / "b.exr");
  const int objectR = e.channel("object.R");
  double largest = 0.0;
  for (int y = 0; y < e.height; ++y) {
    for (int x = 0; x < e.width; ++x) {
      for (int c = 0; c < e.channels; ++c) ASSERT_TRUE(std::isfinite(e.at(x, y, c)));
      largest = std::max(largest, double(e.at(x, y, objectR)));
    }
  }
  EXPECT_GT(largest, 1e28) << "the object's radiance is kept, not clamped";
}

// The plate's middle grey is taken from its ground, below the horizon: a bright sky above it
// does not change the exposure (it pulled the object a stop too bright on the sample meadow);
// with the camera pitched down so far that the horizon is above the frame, the whole plate is
// the ground.
// An OpenEXR plate whose data window is part of its frame has no picture outside it: the
// automatic exposure and the composite's alpha are those of the same plate with alpha 0 there
// (the zeros outside were read as black ground: -10.78 stops, the object rendered black).
TEST_F(ComposeOutputs, APlatesDataWindowIsItsPicture) {
  constexpr int kW = 320, kH = 240, kX0 = 20, kY0 = 130, kX1 = 300, kY1 = 230;
  auto value = [](int x, int y) { return 0.05f + 0.2f * float((x / 16 + y / 16) % 2); };
  {
    std::vector<float> px;
    for (int y = kY0; y < kY1; ++y)
      for (int x = kX0; x < kX1; ++x)
        for (int c = 0; c < 3; ++c) px.push_back(value(x, y));
    OIIO::ImageSpec spec(kX1 - kX0, kY1 - kY0, 3, OIIO::TypeDesc::FLOAT);
    spec.x = kX0, spec.y = kY0, spec.full_width = kW, spec.full_height = kH;
    auto out = OIIO::ImageOutput::create((dir_ / "window.exr").string());
    ASSERT_TRUE(out->open((dir_ / "window.exr").string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  {
    std::vector<float> px(size_t(kW) * kH * 4, 0.0f);
    for (int y = kY0; y < kY1; ++y)
      for (int x = kX0; x < kX1; ++x) {
        float* p = &px[(size_t(y) * kW + size_t(x)) * 4];
        p[0] = p[1] = p[2] = value(x, y);
        p[3] = 1.0f;
      }
    OIIO::ImageSpec spec(kW, kH, 4, OIIO::TypeDesc::FLOAT);
    auto out = OIIO::ImageOutput::create((dir_ / "alpha.exr").string());
    ASSERT_TRUE(out->open((dir_ / "alpha.exr").string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  auto stops = [](const std::string& err) {
    const size_t at = err.find("auto exposure: ");
    return at == std::string::npos ? 99.0 : std::atof(err.c_str() + at + 15);
  };
  const std::string more = " --plate-space lin_rec709 --depth float --place 0.5,0.85 --scale 0.15";
  const auto window = runCompose(args((dir_ / "w").string(), "window.exr") + more, dir_.path());
  const auto alpha = runCompose(args((dir_ / "a").string(), "alpha.exr") + more, dir_.path());
  ASSERT_EQ(window.status, 0) << window.err;
  ASSERT_EQ(alpha.status, 0) << alpha.err;
  ASSERT_LT(stops(alpha.err), 50.0) << alpha.err;
  EXPECT_NEAR(stops(window.err), stops(alpha.err), 0.01) << window.err;
  const Raster w = readRaster(dir_ / "w.exr");
  EXPECT_EQ(w.at(5, 5, w.channel("A")), 0.0f) << "outside the data window";
  EXPECT_EQ(w.at(kX0 + 2, kY0 + 2, w.channel("A")), 1.0f);
}

// A float plate in other units (here 1e-4 and 1e-6 of the usual ones) is matched by its own
// level: the exposure moves by the units' stops (a fixed floor of 1e-4 was the level of the
// dimmer plate: 2.9 stops off). Black pixels (letterbox bars) say nothing of the scene's level
// and leave the match as it is (they pulled it down to that floor).
TEST_F(ComposeOutputs, AutoExposureFollowsAFloatPlatesUnitsAndSkipsBlack) {
  auto texture = [](int x, int y) { return 0.05f + 0.15f * float((x * 7 + y * 13) % 17) / 16.0f; };
  for (const float units : {1.0f, 1e-4f, 1e-6f})
    writeExr(dir_ / ("units" + std::to_string(int(std::round(-std::log10(units)))) + ".exr"), 320,
             240, [&](float* p, int x, int y) { p[0] = p[1] = p[2] = units * texture(x, y); });
  writeExr(dir_ / "letterbox.exr", 320, 240, [&](float* p, int x, int y) {
    p[0] = p[1] = p[2] = y < 30 || y >= 210 ? 0.0f : texture(x, y);
  });
  auto stops = [](const std::string& err) {
    const size_t at = err.find("auto exposure: ");
    return at == std::string::npos ? 99.0 : std::atof(err.c_str() + at + 15);
  };
  const std::string linear = " --plate-space lin_rec709";
  std::map<std::string, double> got;
  for (const std::string name : {"units0", "units4", "units6", "letterbox"}) {
    const auto r =
        runCompose(args((dir_ / ("out-" + name)).string(), name + ".exr") + linear, dir_.path());
    ASSERT_EQ(r.status, 0) << r.err;
    got[name] = stops(r.err);
    ASSERT_LT(got[name], 50.0) << r.err;
  }
  EXPECT_NEAR(got["units4"] - got["units0"], std::log2(1e-4), 0.02);
  EXPECT_NEAR(got["units6"] - got["units0"], std::log2(1e-6), 0.02);
  // The bars leave rows of the same texture: the same level within the sampling's change.
  EXPECT_NEAR(got["letterbox"], got["units0"], 0.05);
  // A black ground (the sky 0.2, a letterbox bar across the ground): the whole plate's level,
  // and the note says why (it said "almost none of it lies below the horizon").
  writeExr(dir_ / "black-ground.exr", 320, 240,
           [](float* p, int, int y) { p[0] = p[1] = p[2] = y < 120 ? 0.2f : 0.0f; });
  const auto black =
      runCompose(args((dir_ / "out-black").string(), "black-ground.exr") + linear, dir_.path());
  ASSERT_EQ(black.status, 0) << black.err;
  EXPECT_NE(black.err.find("matched to the plate's log-average (0.2) (the whole plate's: the "
                           "ground in view is black, a letterbox bar or codes of 0)"),
            std::string::npos)
      << black.err;
  // The sky's 0.2 against the texture's 0.05-0.2: brighter, within two stops (the floor made
  // it 12 stops darker).
  EXPECT_GT(stops(black.err), got["units0"]) << black.err;
  EXPECT_LT(stops(black.err), got["units0"] + 2.0) << black.err;
}

// An exposure that takes the object's light past what a float holds is refused (an environment
// of 9e31 at --exposure 30 was written as infinity, shown black, exit 0), and nothing is written.
TEST_F(ComposeOutputs, AnExposureBeyondFloatsRangeIsRefused) {
  writeExr(dir_ / "bright-env.exr", 64, 32, [](float* p, int, int) { p[0] = p[1] = p[2] = 9e31f; });
  const std::string env = " --env " + quote((dir_ / "bright-env.exr").string());
  const auto r = runCompose(args((dir_ / "over").string()) + env + " --exposure 30", dir_.path());
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("times its exposure (+30.0 stops, --exposure) exceeds what a float holds"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "over.exr"));
  EXPECT_FALSE(fs::exists(dir_ / "over.jpg"));
  // The environment itself is fine: matched to the plate automatically, it renders.
  const auto matched = runCompose(args((dir_ / "matched").string()) + env, dir_.path());
  EXPECT_EQ(matched.status, 0) << matched.err;
  EXPECT_TRUE(fs::exists(dir_ / "matched.exr"));
}

TEST_F(ComposeOutputs, AutoExposureReadsThePlatesGroundNotItsSky) {
  writeExr(dir_ / "input-sky.exr", 320, 240,
           [](float* p, int, int y) { p[0] = p[1] = p[2] = y < 120 ? 0.9f : 0.1f; });
  writeExr(dir_ / "input-ground.exr", 320, 240,
           [](float* p, int, int) { p[0] = p[1] = p[2] = 0.1f; });
  auto stops = [](const std::string& err) {
    const size_t at = err.find("auto exposure: ");
    return at == std::string::npos ? 99.0 : std::atof(err.c_str() + at + 15);
  };
  const std::string linear = " --plate-space lin_rec709";
  const auto sky = runCompose(args((dir_ / "a").string(), "input-sky.exr") + linear, dir_.path());
  const auto ground =
      runCompose(args((dir_ / "b").string(), "input-ground.exr") + linear, dir_.path());
  ASSERT_EQ(sky.status, 0) << sky.err;
  ASSERT_EQ(ground.status, 0) << ground.err;
  ASSERT_LT(stops(ground.err), 50.0) << ground.err;
  EXPECT_NEAR(stops(sky.err), stops(ground.err), 0.01) << sky.err;
  EXPECT_NE(sky.err.find("below the horizon (47 % of the plate)"), std::string::npos) << sky.err;
  // Pitched down 60°: no horizon in the frame, the key of the whole plate (half 0.9, half 0.1:
  // a log-average 1.58 stops above 0.1).
  const auto pitched = runCompose(
      args((dir_ / "c").string(), "input-sky.exr") + linear + " --pitch 60", dir_.path());
  const auto pitchedGround = runCompose(
      args((dir_ / "d").string(), "input-ground.exr") + linear + " --pitch 60", dir_.path());
  ASSERT_EQ(pitched.status, 0) << pitched.err;
  ASSERT_EQ(pitchedGround.status, 0) << pitchedGround.err;
  EXPECT_NEAR(stops(pitched.err) - stops(pitchedGround.err), 0.5 * std::log2(9.0), 0.02)
      << pitched.err;
  EXPECT_EQ(pitched.err.find("below the horizon"), std::string::npos) << pitched.err;
  // Pitched down 10°, the horizon rises in the frame: more of the plate is ground (each pixel by
  // its own ray), here part of the bright half too.
  const auto ten = runCompose(args((dir_ / "e").string(), "input-sky.exr") + linear + " --pitch 10",
                              dir_.path());
  ASSERT_EQ(ten.status, 0) << ten.err;
  const size_t at = ten.err.find("below the horizon (");
  ASSERT_NE(at, std::string::npos) << ten.err;
  const double share = std::atof(ten.err.c_str() + at + 19);
  EXPECT_GT(share, 60.0) << ten.err;
  EXPECT_LT(share, 99.0) << ten.err;
  EXPECT_GT(stops(ten.err), stops(ground.err) + 0.1) << ten.err;
  EXPECT_LT(stops(ten.err), stops(ground.err) + 0.5 * std::log2(9.0) - 0.1)
      << "the bright half counts only in part";
}

// An OpenEXR plate's premultiplied pixels with alpha 0 and light (a glow, added over what is
// behind) cannot be held by a PNG's straight alpha: they are transparent there, and a note says
// so; the EXR keeps them.
TEST_F(ComposeOutputs, AGlowWithAlphaZeroIsNotedInAPng) {
  {
    std::vector<float> px(size_t(320) * 240 * 4);
    for (size_t i = 0; i < px.size() / 4; ++i) {
      const bool glow = (i % 320) >= 240;
      px[4 * i] = px[4 * i + 1] = px[4 * i + 2] = glow ? 0.5f : 0.2f;
      px[4 * i + 3] = glow ? 0.0f : 1.0f;
    }
    OIIO::ImageSpec spec(320, 240, 4, OIIO::TypeDesc::HALF);
    spec.alpha_channel = 3;
    auto out = OIIO::ImageOutput::create((dir_ / "input-glow.exr").string());
    ASSERT_TRUE(out->open((dir_ / "input-glow.exr").string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  const auto r = runCompose(args((dir_ / "g.png").string(), "input-glow.exr") +
                                " --plate-space lin_rec709 --place 0.3,0.9",
                            dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("19200 pixels carry light with alpha 0 (additive, as a glow)"),
            std::string::npos)
      << r.err;
  const Raster e = readRaster(dir_ / "g.exr");
  EXPECT_NEAR(e.at(300, 10, e.channel("R")), 0.5f, 1e-3) << "the EXR keeps the glow";
  EXPECT_EQ(e.at(300, 10, e.channel("A")), 0.0f);
  // An opaque plate has none to note.
  const auto opaque = runCompose(args((dir_ / "o.png").string()), dir_.path());
  ASSERT_EQ(opaque.status, 0) << opaque.err;
  EXPECT_EQ(opaque.err.find("alpha 0"), std::string::npos) << opaque.err;
}

// The EXR's samples follow the plate: a 32-bit float plate gives float parts, whose untouched
// pixels keep the plate's value to float precision (half rounds 0.1234567 to 0.12341); any other
// plate gives half; --depth says otherwise either way.
TEST_F(ComposeOutputs, AFloatPlateGivesAFloatExr) {
  constexpr float kValue = 0.1234567f;
  writeExr(dir_ / "input-float.exr", 320, 240,
           [](float* p, int, int) { p[0] = p[1] = p[2] = kValue; });
  auto partTypes = [](const fs::path& exr) {
    std::vector<std::string> types;
    auto in = OIIO::ImageInput::open(exr.string());
    if (!in) return types;
    // The colour's samples (the object part's positions and depth are float whatever they are).
    for (int part = 0; in->seek_subimage(part, 0); ++part) {
      const OIIO::ImageSpec& spec = in->spec();
      const int colour = std::max(spec.channelindex("R"), spec.channelindex("object.R"));
      types.push_back(spec.channelformat(colour).c_str());
      if (part == 1) {
        EXPECT_EQ(spec.channelformat(spec.channelindex("P.X")), OIIO::TypeDesc::FLOAT);
        EXPECT_EQ(spec.channelformat(spec.channelindex("depth.Z")), OIIO::TypeDesc::FLOAT);
      }
    }
    return types;
  };
  const std::string floatPlate = " --plate-space lin_rec709";
  auto r = runCompose(args((dir_ / "f").string(), "input-float.exr") + floatPlate, dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(partTypes(dir_ / "f.exr"), (std::vector<std::string>{"float", "float"}));
  // A corner far from the object: the plate as it was, in ACEScg (a grey stays a grey).
  const Raster f = readRaster(dir_ / "f.exr");
  EXPECT_NEAR(f.at(2, 2, f.channel("R")), kValue, 2e-6);
  r = runCompose(args((dir_ / "h").string(), "input-float.exr") + floatPlate + " --depth half",
                 dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(partTypes(dir_ / "h.exr"), (std::vector<std::string>{"half", "half"}));
  const Raster h = readRaster(dir_ / "h.exr");
  EXPECT_GT(std::abs(h.at(2, 2, h.channel("R")) - kValue), 1e-5) << "half cannot hold it";
  r = runCompose(args((dir_ / "p").string()), dir_.path());  // the 8-bit PNG plate
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(partTypes(dir_ / "p.exr"), (std::vector<std::string>{"half", "half"}));
  r = runCompose(args((dir_ / "q").string()) + " --depth float", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(partTypes(dir_ / "q.exr"), (std::vector<std::string>{"float", "float"}));
  r = runCompose(args((dir_ / "z").string()) + " --depth double", dir_.path());
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "z.exr"));
}

// A plate of three channels is read by their names: OpenEXR's luminance-chroma Y, RY, BY is the
// same picture as its R, G, B (it was taken by position, BY as red: the background off by up to
// 1.0).
TEST_F(ComposeOutputs, AThreeChannelPlateIsReadByItsChannelsNames) {
  constexpr float kR = 0.5f, kG = 0.25f, kB = 0.125f;
  // Y by OpenEXR's weights for a file without chromaticities (Imf::computeYw of Rec. 709's).
  const float y = 0.2126390f * kR + 0.7151687f * kG + 0.0721923f * kB;
  writeExr(dir_ / "rgb.exr", 320, 240, [](float* p, int, int) { p[0] = kR, p[1] = kG, p[2] = kB; });
  {
    std::vector<float> px(320 * 240 * 3);
    for (size_t i = 0; i < px.size(); i += 3)
      px[i] = y, px[i + 1] = (kR - y) / y, px[i + 2] = (kB - y) / y;
    OIIO::ImageSpec spec(320, 240, 3, OIIO::TypeDesc::FLOAT);
    spec.channelnames = {"Y", "RY", "BY"};
    auto out = OIIO::ImageOutput::create((dir_ / "yc.exr").string());
    ASSERT_TRUE(out->open((dir_ / "yc.exr").string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  for (const char* name : {"rgb", "yc"}) {
    const auto r = runCompose(
        args((dir_ / (std::string("out-") + name)).string(), std::string(name) + ".exr") +
            " --depth float",
        dir_.path());
    ASSERT_EQ(r.status, 0) << r.err;
  }
  const Raster rgb = readRaster(dir_ / "out-rgb.exr"), yc = readRaster(dir_ / "out-yc.exr");
  for (const char* c : {"R", "G", "B"})
    EXPECT_NEAR(yc.at(2, 2, yc.channel(c)), rgb.at(2, 2, rgb.channel(c)), 1e-5) << c;
}

// The display JPEG keeps its colour at full resolution (4:4:4): a plate's colour edges stay where
// they are (at 4:2:0, the default of cameras and OpenImageIO, red against green moved by up to 43
// codes at quality 95).
TEST_F(ComposeOutputs, TheJpegKeepsThePlatesColourEdges) {
  {
    std::vector<uint8_t> px(size_t(320) * 240 * 3);
    for (int y = 0; y < 240; ++y)
      for (int x = 0; x < 320; ++x) {
        uint8_t* p = &px[(size_t(y) * 320 + size_t(x)) * 3];
        const bool red = (x / 3) % 2 == 0;
        p[0] = red ? 200 : 30, p[1] = red ? 30 : 180, p[2] = 40;
      }
    OIIO::ImageSpec spec(320, 240, 3, OIIO::TypeDesc::UINT8);
    auto out = OIIO::ImageOutput::create((dir_ / "stripes.png").string());
    ASSERT_TRUE(out->open((dir_ / "stripes.png").string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px.data()));
    out->close();
  }
  const auto r = runCompose(
      args((dir_ / "s").string(), "stripes.png") + " --view Standard --place 0.9,0.9 --scale 0.05",
      dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  auto in = OIIO::ImageInput::open((dir_ / "s.jpg").string());
  ASSERT_TRUE(in);
  EXPECT_EQ(in->spec().get_string_attribute("jpeg:subsampling"), "4:4:4");
  std::vector<uint8_t> got(size_t(320) * 240 * 3);
  ASSERT_TRUE(in->read_image(0, 0, 0, 3, OIIO::TypeDesc::UINT8, got.data()));
  int worst = 0;
  for (int y = 0; y < 150; ++y)  // well away from the object, low on the right
    for (int x = 0; x < 320; ++x) {
      const bool red = (x / 3) % 2 == 0;
      const uint8_t* p = &got[(size_t(y) * 320 + size_t(x)) * 3];
      worst = std::max({worst, std::abs(p[0] - (red ? 200 : 30)), std::abs(p[1] - (red ? 30 : 180)),
                        std::abs(p[2] - 40)});
    }
  EXPECT_LE(worst, 8) << "codes off the plate";
}

// A float TIFF environment holds the same linear radiance as an OpenEXR one: it lights the object
// the same (the built-in config's default rule, meant for 8-bit images, decoded it with the sRGB
// curve: 555 times too bright for one texel of 100, -3.10 stops of exposure against +6.02).
TEST_F(ComposeOutputs, AFloatTiffEnvironmentIsLinearAsAnExrIs) {
  auto sky = [](float* p, int x, int y) {
    p[0] = p[1] = p[2] = (x == 20 && y == 6) ? 100.0f : 0.02f;
  };
  writeExr(dir_ / "input-sky.exr", 64, 32, sky);
  writeExr(dir_ / "input-sky.tif", 64, 32, sky);
  auto stops = [](const std::string& err) {
    const size_t at = err.find("auto exposure: ");
    return at == std::string::npos ? 99.0 : std::atof(err.c_str() + at + 15);
  };
  const auto exr =
      runCompose(args((dir_ / "e").string()) + " --env " + quote((dir_ / "input-sky.exr").string()),
                 dir_.path());
  const auto tif =
      runCompose(args((dir_ / "t").string()) + " --env " + quote((dir_ / "input-sky.tif").string()),
                 dir_.path());
  ASSERT_EQ(exr.status, 0) << exr.err;
  ASSERT_EQ(tif.status, 0) << tif.err;
  ASSERT_LT(stops(exr.err), 50.0) << exr.err;
  EXPECT_NEAR(stops(tif.err), stops(exr.err), 0.01) << tif.err;
  EXPECT_EQ(tif.err.find("not HDR"), std::string::npos) << tif.err;
}

// An object burnt to white is warned about, in the Soft Clip view too: it rolls the highlights
// off towards white without reaching it, so "clipped" is the last two 8-bit codes, where no
// shading is left. The share the warning gives is the share of the JPEG's object pixels there
// (within two points: the JPEG's own rounding; measured 1.3), and a well exposed object is not
// warned about.
TEST_F(ComposeOutputs, ABurntOutObjectIsWarnedAboutInTheSoftClipViewToo) {
  const auto r =
      runCompose(args((dir_ / "w").string()) + " --exposure 3 --view 'Soft Clip'", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  const size_t at =
      r.err.find("% of the object's pixels are clipped to white in w.jpg (view Soft Clip)");
  ASSERT_NE(at, std::string::npos) << r.err;
  const size_t start = r.err.rfind("warning: ", at);
  ASSERT_NE(start, std::string::npos) << r.err;
  const double said = std::stod(r.err.substr(start + 9, at - start - 9));
  const Raster e = readRaster(dir_ / "w.exr"), j = readRaster(dir_ / "w.jpg");
  const int a = e.channel("object.A");
  int64_t covered = 0, white = 0;
  for (int y = 0; y < e.height; ++y) {
    for (int x = 0; x < e.width; ++x) {
      if (e.at(x, y, a) < 0.5f) continue;
      ++covered;
      if (std::max({j.at(x, y, 0), j.at(x, y, 1), j.at(x, y, 2)}) >= 253.5 / 255.0) ++white;
    }
  }
  ASSERT_GT(covered, 500);
  EXPECT_GT(said, 10.0);
  EXPECT_NEAR(said, 100.0 * double(white) / double(covered), 2.0);

  // The default view, Standard, clips: the warning offers Soft Clip as well.
  const auto standard = runCompose(args((dir_ / "s").string()) + " --exposure 3", dir_.path());
  ASSERT_EQ(standard.status, 0) << standard.err;
  EXPECT_NE(standard.err.find("clipped to white in s.jpg (view Standard): lower --exposure to keep "
                              "their shading, or --view 'Soft Clip'"),
            std::string::npos)
      << standard.err;

  const auto fine = runCompose(args((dir_ / "f").string()), dir_.path());
  ASSERT_EQ(fine.status, 0) << fine.err;
  EXPECT_EQ(fine.err.find("clipped to white"), std::string::npos) << fine.err;
}

// order=auto at a target no order reaches stops at the highest order and says that it cannot
// tell whether the target is met (it claimed an estimated SNR of inf dB there).
TEST_F(ComposeOutputs, AnAutomaticOrderAtItsHighestDoesNotClaimTheTarget) {
  const auto high = runCompose(
      args((dir_ / "h").string()) + " --lighting sh --lighting-params order=auto,target=90",
      dir_.path());
  ASSERT_EQ(high.status, 0) << high.err;
  EXPECT_NE(high.err.find("order=auto: sh order 8, the highest it takes; whether it reaches the "
                          "target (90.0 dB) cannot be estimated"),
            std::string::npos)
      << high.err;
  EXPECT_EQ(high.err.find("inf dB"), std::string::npos) << high.err;
  const auto low = runCompose(
      args((dir_ / "l").string()) + " --lighting sh --lighting-params order=auto,target=20",
      dir_.path());
  ASSERT_EQ(low.status, 0) << low.err;
  EXPECT_NE(low.err.find("estimated truncation SNR"), std::string::npos) << low.err;
}

// An object so large that the camera stands inside it gives a frame of its inside: said (it was
// written without a word).
TEST_F(ComposeOutputs, ACameraInsideTheObjectIsWarnedAbout) {
  const auto inside =
      runCompose(args((dir_ / "i").string()) + " --scale 8 --place 0.5,0.95", dir_.path());
  ASSERT_EQ(inside.status, 0) << inside.err;
  EXPECT_NE(inside.err.find("warning: the camera is inside the object"), std::string::npos)
      << inside.err;
  const auto outside = runCompose(args((dir_ / "o").string()), dir_.path());
  ASSERT_EQ(outside.status, 0) << outside.err;
  EXPECT_EQ(outside.err.find("inside the object"), std::string::npos) << outside.err;
}

// A stage reused from the cache says again what it said when it ran, and so does one not needed
// because what it fed is reused: the same job a second time warns as the first did (the camera
// inside the object, from the render; the object outside the room, from the lighting; the
// environment's file, from ingest, kept with the lighting). It was silent, and a note the context
// makes for whichever stage asks first is not said twice.
TEST_F(ComposeOutputs, AJobRunAgainFromTheCacheWarnsAgain) {
  // An 8-bit environment: ingest says so when it reads it, and does not read it again once the
  // lighting made from it is cached.
  writeGreyPlate(dir_ / "env.jpg", 64, 32, 0.6f);
  std::string a = args((dir_ / "c").string()) + " --scale 8 --place 0.5,0.95 --room 3,3,3 --env " +
                  quote((dir_ / "env.jpg").string());
  a.replace(a.find("--no-cache"), 10, "--cache " + quote((dir_ / "cache").string()));
  const char* warnings[] = {"warning: the camera is inside the object",
                            "warning: the object's centre is outside the surroundings given",
                            "plate camera: a 35 mm equivalent focal length",
                            "the environment is a jpeg file, not HDR"};
  const auto first = runCompose(a, dir_.path());
  ASSERT_EQ(first.status, 0) << first.err;
  for (const char* w : warnings) EXPECT_NE(first.err.find(w), std::string::npos) << first.err;
  const auto second = runCompose(a, dir_.path());
  ASSERT_EQ(second.status, 0) << second.err;
  EXPECT_NE(stageLine(second.err, "render").find("reused"), std::string::npos) << second.err;
  EXPECT_NE(stageLine(second.err, "precompute").find("skipped"), std::string::npos) << second.err;
  for (const char* w : warnings) {
    EXPECT_NE(second.err.find(w), std::string::npos) << second.err;
    // Once, as the first run said them.
    EXPECT_EQ(second.err.find(w), second.err.rfind(w)) << second.err;
  }
}

// --explain refuses a placement the run would refuse as soon as it places the object, with the
// run's error (it planned "run" for every stage), from the plate's header alone.
TEST_F(ComposeOutputs, ExplainRefusesAPlacementAboveTheHorizon) {
  const std::string above = args((dir_ / "a").string()) + " --place 0.5,0.3";
  const auto run = runCompose(above, dir_.path());
  const auto plan = runCompose(above + " --explain", dir_.path());
  EXPECT_EQ(run.status, 1) << run.err;
  EXPECT_EQ(plan.status, 1) << plan.out << plan.err;
  const std::string error = "camera: --place 0.5,0.3 is at or above the horizon";
  EXPECT_NE(run.err.find(error), std::string::npos) << run.err;
  EXPECT_NE(plan.err.find(error), std::string::npos) << plan.err;
  EXPECT_EQ(plan.out.find("render"), std::string::npos) << "no plan printed: " << plan.out;
  // Below it: planned.
  const auto below =
      runCompose(args((dir_ / "b").string()) + " --place 0.5,0.8 --explain", dir_.path());
  EXPECT_EQ(below.status, 0) << below.err;
  EXPECT_NE(below.out.find("render"), std::string::npos) << below.out;
}

TEST_F(ComposeOutputs, AnObjectCoveringNoPixelIsAnError) {
  const auto r = runCompose(args((dir_ / "n").string()) + " --scale 1e-6", dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("render: the object covers no pixel of the plate"), std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("make it larger"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "n.exr"));
  // So large that the camera stands within its bounds, under Suzanne's chin: smaller (it was
  // told to make it larger).
  std::string huge = args((dir_ / "h").string()) + " --scale 9";
  huge.replace(huge.find(quote((samples_ / "bunny.obj").string())),
               quote((samples_ / "bunny.obj").string()).size(),
               quote((samples_ / "monkey.obj").string()));
  const auto within = runCompose(huge, dir_.path());
  EXPECT_EQ(within.status, 1);
  EXPECT_NE(within.err.find("the camera stands within its bounds, between its parts; make it "
                            "smaller"),
            std::string::npos)
      << within.err;
  EXPECT_FALSE(fs::exists(dir_ / "h.exr"));
}

// The automatic exposure matches a mid-grey card on the ground to the plate's ground: it does not
// change when the environment turns about the vertical (the plate's exposure does not), so a
// studio softbox behind the camera lights the object's front brightly (without clipping it) and,
// turned behind the object, leaves its visible side dark, as a photograph would (a ball facing
// the camera raised a backlit object's exposure by 3 stops and cancelled the turn).
TEST_F(ComposeOutputs, AutoExposureIsTheSameWhicheverWayTheEnvironmentTurns) {
  const int w = 256, h = 128;
  writeExr(dir_ / "input-studio.exr", w, h, [&](float* p, int x, int y) {
    const double lon = kPi * (1.0 - 2.0 * (x + 0.5) / w), lat = kPi * (0.5 - (y + 0.5) / h);
    const double dz = std::cos(lon) * std::cos(lat), dy = std::sin(lat);
    // OpenEXR axes: the centre column looks along +Z, behind the camera.
    const bool softbox = dz > 0.85 && dy > 0.1;
    p[0] = p[1] = p[2] = softbox ? 40.0f : 0.01f;
  });
  auto stops = [](const std::string& err) {
    const size_t at = err.find("auto exposure: ");
    return at == std::string::npos ? 99.0 : std::atof(err.c_str() + at + 15);
  };
  // The object's mean display value and its share of white pixels.
  auto look = [&](const std::string& name, double& mean, double& white) {
    const Raster e = readRaster(dir_ / (name + ".exr")), j = readRaster(dir_ / (name + ".jpg"));
    const int a = e.channel("object.A");
    int64_t covered = 0, whites = 0;
    double sum = 0.0;
    for (int y = 0; y < e.height; ++y) {
      for (int x = 0; x < e.width; ++x) {
        if (e.at(x, y, a) < 1.0f) continue;
        ++covered;
        const double v = (j.at(x, y, 0) + j.at(x, y, 1) + j.at(x, y, 2)) / 3.0;
        sum += v;
        if (v >= 254.5 / 255.0) ++whites;
      }
    }
    ASSERT_GT(covered, 500);
    mean = sum / double(covered);
    white = double(whites) / double(covered);
  };
  double front = 0.0, back = 0.0, frontWhite = 0.0, backWhite = 0.0, turned = 99.0;
  for (const int yaw : {0, 90, 180}) {
    const std::string name = "s" + std::to_string(yaw);
    // Soft Clip: the softbox lights the object's front far more than the ground card the
    // exposure is matched to; plain sRGB (the default view) clips it, and says so.
    const auto r = runCompose(args((dir_ / name).string()) + " --env " +
                                  quote((dir_ / "input-studio.exr").string()) + " --env-yaw " +
                                  std::to_string(yaw) + " --view 'Soft Clip'",
                              dir_.path());
    ASSERT_EQ(r.status, 0) << r.err;
    ASSERT_LT(stops(r.err), 50.0) << r.err;
    if (yaw == 0) turned = stops(r.err);
    EXPECT_NEAR(stops(r.err), turned, 0.005) << "--env-yaw " << yaw << ": " << r.err;
    if (yaw == 0) look(name, front, frontWhite);
    if (yaw == 180) look(name, back, backWhite);
  }
  EXPECT_LT(frontWhite, 0.02) << "lit from the front, not a white silhouette";
  EXPECT_GT(front, 0.25);
  EXPECT_LT(back, 0.5 * front) << "lit from behind, its visible side is darker";
}

// A plate with unassociated alpha (a PNG): its colour is premultiplied in linear light and its
// alpha is the composite's where the object is not; under the object the composite is opaque; the
// automatic exposure reads the visible pixels only. (Alpha was multiplied into the sRGB codes
// before decoding: 0.044 for 0.09 at half alpha; the composite said alpha 1.)
TEST_F(ComposeOutputs, APlateWithAlphaKeepsItInTheComposite) {
  const int w = 320, h = 240;
  {
    std::vector<float> px(size_t(w) * size_t(h) * 4);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        float* p = &px[(size_t(y) * size_t(w) + size_t(x)) * 4];
        p[0] = p[1] = p[2] = 0.5f;  // sRGB code 128: 0.2158 linear
        p[3] = x < w / 3 ? 1.0f : x < 2 * w / 3 ? 0.5f : 0.0f;
      }
    OIIO::ImageSpec spec(w, h, 4, OIIO::TypeDesc::UINT8);
    spec.attribute("oiio:UnassociatedAlpha", 1);
    auto out = OIIO::ImageOutput::create((dir_ / "input-alpha.png").string());
    ASSERT_TRUE(out->open((dir_ / "input-alpha.png").string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  std::string a = args((dir_ / "alpha").string()) + " --place 0.16,0.9 --scale 0.3";
  a.replace(a.find(quote((dir_ / "input-plate.png").string())),
            quote((dir_ / "input-plate.png").string()).size(),
            quote((dir_ / "input-alpha.png").string()));
  const auto r = runCompose(a, dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("has an alpha channel (unassociated"), std::string::npos) << r.err;
  const Raster e = readRaster(dir_ / "alpha.exr");
  const int R = e.channel("R"), A = e.channel("A"), objectA = e.channel("object.A");
  ASSERT_GE(A, 0);
  ASSERT_GE(objectA, 0);
  const float grey = 0.2158605f;  // sRGB 128/255 decoded; ACEScg keeps greys
  auto expectAt = [&](int x, int y, float alpha) {
    if (e.at(x, y, objectA) != 0.0f) return;  // under the object
    EXPECT_NEAR(e.at(x, y, A), alpha, 1e-3) << x << "," << y;
    EXPECT_NEAR(e.at(x, y, R), grey * alpha, 2e-3) << x << "," << y;
  };
  for (const int y : {10, 120})
    for (const int x : {20, 150, 300})
      expectAt(x, y, x < w / 3 ? 1.0f : x < 2 * w / 3 ? 128.0f / 255.0f : 0.0f);
  // Under the object (it stands in the opaque third): opaque.
  int covered = 0;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w / 3; ++x)
      if (e.at(x, y, objectA) == 1.0f) {
        ++covered;
        EXPECT_NEAR(e.at(x, y, A), 1.0f, 1e-3);
      }
  EXPECT_GT(covered, 50);
  // The exposure matches the visible grey: as on the opaque grey plate of the same code.
  const auto opaque =
      runCompose(args((dir_ / "opaque").string()) + " --place 0.16,0.9 --scale 0.3", dir_.path());
  ASSERT_EQ(opaque.status, 0) << opaque.err;
  auto stops = [](const std::string& err) {
    const size_t at = err.find("auto exposure: ");
    return at == std::string::npos ? 99.0 : std::atof(err.c_str() + at + 15);
  };
  ASSERT_LT(stops(r.err), 50.0) << "no automatic exposure in: " << r.err;
  EXPECT_NEAR(stops(r.err), stops(opaque.err), 0.02);

  // The same plate as a TIFF with associated alpha, as oiiotool and Nuke write it: its codes hold
  // colour x alpha in the sRGB encoding, made straight before they are decoded (decoding the
  // product gave 0.051 for 0.108 at half alpha).
  {
    std::vector<float> px(size_t(w) * size_t(h) * 4);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        float* p = &px[(size_t(y) * size_t(w) + size_t(x)) * 4];
        p[3] = x < w / 3 ? 1.0f : x < 2 * w / 3 ? 128.0f / 255.0f : 0.0f;
        // Where alpha is 0, light added over what is behind (a glow): kept as it is.
        p[0] = p[1] = p[2] = p[3] > 0.0f ? 0.5f * p[3] : 0.2f;
      }
    writePixels(dir_ / "input-assoc.tif", w, h, 4, OIIO::TypeDesc::UINT8, px);
    const auto assoc = runCompose(
        args((dir_ / "assoc").string(), "input-assoc.tif") + " --place 0.16,0.9 --scale 0.3",
        dir_.path());
    ASSERT_EQ(assoc.status, 0) << assoc.err;
    EXPECT_NE(assoc.err.find("premultiplied in its encoding: made straight"), std::string::npos)
        << assoc.err;
    const Raster t = readRaster(dir_ / "assoc.exr");
    for (const int x : {150, 200}) {
      if (t.at(x, 10, t.channel("object.A")) != 0.0f) continue;
      EXPECT_NEAR(t.at(x, 10, t.channel("A")), 128.0f / 255.0f, 1e-3);
      EXPECT_NEAR(t.at(x, 10, t.channel("R")), grey * 128.0f / 255.0f, 2e-3) << x;
    }
    const float glow = std::pow((51.0f / 255.0f + 0.055f) / 1.055f, 2.4f);  // code 51 decoded
    EXPECT_NEAR(t.at(300, 10, t.channel("A")), 0.0f, 1e-6);
    EXPECT_NEAR(t.at(300, 10, t.channel("R")), glow, 1e-3);
  }

  // A plate transparent everywhere has no brightness to match: 0 stops, said so (it said the
  // placeholder key 1 was "the whole plate's" and put the object 2.4 stops up).
  {
    writePixels(dir_ / "input-clear.png", w, h, 4, OIIO::TypeDesc::UINT8,
                std::vector<float>(size_t(w) * size_t(h) * 4, 0.0f));
    const auto clearRun = runCompose(
        args((dir_ / "clear").string(), "input-clear.png") + " --place 0.16,0.9 --scale 0.3",
        dir_.path());
    ASSERT_EQ(clearRun.status, 0) << clearRun.err;
    EXPECT_NE(clearRun.err.find("auto exposure: 0 stops (the environment's own units): the plate "
                                "is transparent everywhere"),
              std::string::npos)
        << clearRun.err;
  }

  // A PNG display image keeps the alpha, as PNG stores it: the half-transparent grey is the same
  // code as the opaque grey, its alpha 128; the JPEG, which has no alpha, shows it over black.
  std::string p = a;
  p.replace(p.find(quote((dir_ / "alpha").string())), quote((dir_ / "alpha").string()).size(),
            quote((dir_ / "alpha.png").string()));
  const auto png = runCompose(p, dir_.path());
  ASSERT_EQ(png.status, 0) << png.err;
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  auto in = OIIO::ImageInput::open((dir_ / "alpha.png").string(), &config);
  ASSERT_TRUE(in);
  ASSERT_EQ(in->spec().nchannels, 4);
  std::vector<uint8_t> codes(size_t(w) * size_t(h) * 4);
  ASSERT_TRUE(in->read_image(0, 0, 0, 4, OIIO::TypeDesc::UINT8, codes.data()));
  auto code = [&](int x, int y, int c) {
    return int(codes[(size_t(y) * size_t(w) + size_t(x)) * 4 + size_t(c)]);
  };
  const Raster jpeg = readRaster(dir_ / "alpha.jpg");
  const int y = 10;
  EXPECT_EQ(code(20, y, 3), 255);
  EXPECT_NEAR(code(150, y, 3), 128, 1);
  EXPECT_EQ(code(300, y, 3), 0);
  EXPECT_NEAR(code(150, y, 0), code(20, y, 0), 1) << "the colour is not darkened by its alpha";
  EXPECT_LT(jpeg.at(150, y, 0) * 255.0f, float(code(20, y, 0)) - 20.0f) << "the JPEG: over black";
}

// The automatic exposure's grey ball stands where the object does: the same mesh with its
// vertices moved away from the file's origin (placed the same, since placement takes its bounds)
// gets the same exposure (it got +0.13 to +0.34 stops for one the +0.14 of the original).
TEST_F(ComposeOutputs, AutoExposureDoesNotDependOnTheMeshFilesOrigin) {
  std::ifstream in(samples_ / "monkey.obj");
  std::ofstream out(dir_ / "input-shifted.obj");
  std::string line;
  while (std::getline(in, line)) {
    double x, y, z;
    if (line.rfind("v ", 0) == 0 && std::sscanf(line.c_str(), "v %lf %lf %lf", &x, &y, &z) == 3)
      out << "v " << x + 5.0 << " " << y + 3.0 << " " << z - 5.0 << "\n";
    else
      out << line << "\n";
  }
  out.close();
  auto exposure = [&](const fs::path& mesh, const std::string& name) {
    std::string a = args((dir_ / name).string());
    a.replace(a.find(quote((samples_ / "bunny.obj").string())),
              quote((samples_ / "bunny.obj").string()).size(), quote(mesh.string()));
    const auto r = runCompose(a, dir_.path());
    EXPECT_EQ(r.status, 0) << r.err;
    const size_t at = r.err.find("auto exposure: ");
    return at == std::string::npos ? std::string("none") : r.err.substr(at, 26);
  };
  const std::string original = exposure(samples_ / "monkey.obj", "a");
  EXPECT_NE(original, "none");
  EXPECT_EQ(exposure(dir_ / "input-shifted.obj", "b"), original);
}

// Every out-of-range command-line value is a usage error (exit 2), reported before any file is
// read: the plate named here does not exist, and the error is about the option, not the file.
TEST(ComposeUsage, OutOfRangeValuesExitTwoBeforeReadingFiles) {
  TempDir dir;
  const std::string base = "--plate /no/such/plate.jpg --object /no/such/mesh.obj --out " +
                           quote((dir.path() / "x").string());
  const std::pair<const char*, const char*> cases[] = {
      {"--samples 0", "--samples must be in 1..64"},
      {"--samples 65", "--samples must be in 1..64"},
      {"--scale 0", "--scale must be in [1e-6, 10]"},
      {"--scale 10.0000001", "--scale must be in [1e-6, 10], got 10.0000001"},
      {"--threads 99999999999",
       "--threads cannot take '99999999999': not a number of the kind it takes, or out of its "
       "range"},
      {"--samples 4 --samples 2", "--samples is given 2 times: give it once"},
      {"--place 0.5,1.5", "--place must be within [0,1]"},
      {"--place 0.5", "--place expects two numbers"},
      {"--albedo 1.5", "--albedo must be within [0, 1], got 1.5"},
      {"--albedo 0.1,0.2", "--albedo expects one value or R,G,B"},
      {"--exposure 100", "--exposure must be a number of stops within"},
      {"--exposure bright", "--exposure expects a number of stops or auto, got 'bright'"},
      {"--crease 200", "--crease must be an angle within [0, 180] degrees, got 200"},
      {"--yaw ''", "--yaw is given an empty value"},
      {"--room 4,3", "--room expects three numbers as W,H,D"},
      {"--shadow-params method=ao,order=3", "order does not apply to method=ao"},
      // Parameters nothing would read, refused, not ignored; order=auto where no basis selects.
      {"--shadow-params method=ao,sources=8", "sources does not apply to method=ao"},
      {"--shadows off --no-shadow --shadow-params grid=8", "--shadow-params: no shadow is drawn"},
      {"--lighting-params sigma=1", "sigma (roughness) applies to brdf=oren-nayar only"},
      {"--lighting-params subsamples=2", "subsamples applies to cheb-latlong and cheb-face"},
      {"--lighting mc --lighting-params order=auto", "no order selection for basis 'mc'"},
      {"--lighting-params order=auto,brdf=oren-nayar",
       "order=auto estimates Lambertian truncation only"},
      {"--pitch 95", "--pitch must be within"},
      {"--camera-height -1", "--camera-height must be a positive"},
      // Embree stopped the process (an assertion) on the rays of a scene this small.
      {"--camera-height 1e-19", "(1 micrometre to 10 km), got 1e-19"},
      {"--scale 1e-18", "--scale must be in [1e-6, 10], got 1e-18"},
      {"--focal35 0", "--focal35 must be a 35 mm equivalent focal length of 1 to 10000 mm"},
      {"--focal35 1e-300", "got 1e-300"},
      {"--env-yaw inf", "--env-yaw must be a finite"},
      {"--lighting wavelets", "unknown lighting basis 'wavelets'"},
      {"--lighting-params order=99", "order k must be in"},
      {"--lighting-params frobnicate=1", "does not take parameter(s): frobnicate"},
  };
  for (const auto& [option, message] : cases) {
    const auto r = runCompose(base + " " + option, dir.path());
    EXPECT_EQ(r.status, 2) << option << "\n" << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << option << "\n" << r.err;
    EXPECT_EQ(r.err.find("file not found"), std::string::npos) << option << "\n" << r.err;
  }
  // A JPEG's quality for a PNG display image (it was ignored: the PNG the same byte for byte).
  const auto png = runCompose("--plate /no/such/plate.jpg --object /no/such/mesh.obj --out " +
                                  quote((dir.path() / "x.png").string()) + " --jpeg-quality 10",
                              dir.path());
  EXPECT_EQ(png.status, 2) << png.err;
  EXPECT_NE(png.err.find("--jpeg-quality applies to a JPEG display image"), std::string::npos)
      << png.err;
}

}  // namespace
}  // namespace compose

namespace compose {
namespace {

// The header carries the camera (worldToCamera, worldToNDC) and the placement
// (compose:worldFromObject, mapping the mesh file's own coordinates to world space): rebuilt
// from them and the OBJ alone, the scene projects onto the pixels the object covers.
// The shadow on the plate: the plate is darkened, in linear light, exactly where the shadow
// part's ratio is below 1, by that ratio, and untouched elsewhere (outside the object).
TEST_F(ComposeOutputs, TheGroundShadowDarkensThePlateByItsRatioOnly) {
  const auto r =
      runCompose("--plate " + quote((samples_ / "meadow.jpg").string()) + " --object " +
                     quote((samples_ / "bunny.obj").string()) +
                     " --samples 1 --shadows off --no-cache --out " + quote((dir_ / "g").string()),
                 dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  const Raster e = readRaster(dir_ / "g.exr");
  const Raster plate = readRaster(samples_ / "meadow.jpg");
  const int R = e.channel("R"), a = e.channel("object.A"), s = e.channel("shadow.G");
  int64_t darkened = 0, unchanged = 0;
  double worst = 0.0;
  for (int y = 0; y < e.height; ++y) {
    for (int x = 0; x < e.width; ++x) {
      if (e.at(x, y, a) > 0.0f) continue;
      double lin[3], cg[3];
      for (int c = 0; c < 3; ++c) lin[c] = srgbDecode(plate.at(x, y, c));
      toAp1(lin, cg);
      // Outside the shadow part the raster holds 0: the ratio there is 1.
      const double ratio = e.at(x, y, s) > 0.0f ? e.at(x, y, s) : 1.0;
      const double expected = cg[1] * ratio;
      worst = std::max(worst, std::abs(e.at(x, y, R + 1) - expected) / std::max(expected, 1e-2));
      if (ratio < 0.9) ++darkened;
      if (ratio == 1.0) ++unchanged;
    }
  }
  // Half floats (2^-11) for the composite and for the ratio.
  EXPECT_LT(worst, 3e-3);
  EXPECT_GT(darkened, 500) << "a visible shadow around the base";
  EXPECT_GT(unchanged, int64_t(e.width) * e.height / 2) << "and most of the plate untouched";
  // Without it, only the object changes the plate.
  const auto off = runCompose("--plate " + quote((samples_ / "meadow.jpg").string()) +
                                  " --object " + quote((samples_ / "bunny.obj").string()) +
                                  " --samples 1 --shadows off --no-shadow --no-cache --out " +
                                  quote((dir_ / "n").string()),
                              dir_.path());
  ASSERT_EQ(off.status, 0) << off.err;
  EXPECT_NE(off.err.find("ground     skipped  --no-shadow"), std::string::npos) << off.err;
}

TEST_F(ComposeOutputs, TheHeaderRebuildsTheScene) {
  const auto r = runCompose(args((dir_ / "h").string()) + " --place 0.4,0.8 --yaw 35", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  auto in = OIIO::ImageInput::open((dir_ / "h.exr").string());
  ASSERT_TRUE(in);
  auto matrix = [&](const char* name) {
    std::array<double, 16> m{};
    const OIIO::ParamValue* p = in->spec().find_attribute(name);
    EXPECT_NE(p, nullptr) << name;
    if (p && p->type().basetype == OIIO::TypeDesc::DOUBLE) {
      const double* d = static_cast<const double*>(p->data());
      for (int i = 0; i < 16; ++i) m[size_t(i)] = d[i];
    } else if (p) {
      const float* f = static_cast<const float*>(p->data());
      for (int i = 0; i < 16; ++i) m[size_t(i)] = f[i];
    }
    return m;
  };
  // Imath's convention: row vectors, p' = p M.
  auto apply = [](const std::array<double, 16>& m, const double p[3], double out[4]) {
    for (int c = 0; c < 4; ++c)
      out[c] = p[0] * m[size_t(c)] + p[1] * m[size_t(4 + c)] + p[2] * m[size_t(8 + c)] +
               m[size_t(12 + c)];
  };
  const auto worldFromObject = matrix("compose:worldFromObject");
  const auto worldToNdc = matrix("worldToNDC");
  const auto worldToCamera = matrix("worldToCamera");
  const int width = in->spec().full_width, height = in->spec().full_height;
  in->close();

  // The mesh's vertices, read here from the OBJ text.
  std::ifstream obj(samples_ / "bunny.obj");
  std::string line;
  double lo[2] = {1e30, 1e30}, hi[2] = {-1e30, -1e30};
  int vertices = 0;
  while (std::getline(obj, line)) {
    if (line.rfind("v ", 0) != 0) continue;
    std::istringstream ls(line.substr(2));
    double p[3], w[4], ndc[4];
    ls >> p[0] >> p[1] >> p[2];
    apply(worldFromObject, p, w);
    apply(worldToNdc, w, ndc);
    const double px = ndc[0] / ndc[3] * width, py = ndc[1] / ndc[3] * height;
    lo[0] = std::min(lo[0], px), lo[1] = std::min(lo[1], py);
    hi[0] = std::max(hi[0], px), hi[1] = std::max(hi[1], py);
    ++vertices;
  }
  ASSERT_GT(vertices, 30000);
  const Raster e = readRaster(dir_ / "h.exr");
  const int a = e.channel("object.A"), P = e.channel("P.X"), depth = e.channel("depth.Z");
  int covLo[2] = {e.width, e.height}, covHi[2] = {-1, -1};
  double worstDepth = 0.0;
  for (int y = 0; y < e.height; ++y) {
    for (int x = 0; x < e.width; ++x) {
      if (e.at(x, y, a) <= 0.0f) continue;
      covLo[0] = std::min(covLo[0], x), covLo[1] = std::min(covLo[1], y);
      covHi[0] = std::max(covHi[0], x + 1), covHi[1] = std::max(covHi[1], y + 1);
      if (e.at(x, y, a) < 1.0f) continue;
      const double p[3] = {e.at(x, y, P), e.at(x, y, P + 1), e.at(x, y, P + 2)};
      double c[4];
      apply(worldToCamera, p, c);
      // OpenEXR's camera looks along +Z: its z is the depth.
      worstDepth = std::max(worstDepth, std::abs(c[2] - e.at(x, y, depth)) / c[2]);
    }
  }
  // The silhouette's box and the projected vertices' box agree to within a pixel (plus the
  // half-float rounding of the matrices' effect is far below that).
  EXPECT_NEAR(lo[0], covLo[0], 1.5);
  EXPECT_NEAR(lo[1], covLo[1], 1.5);
  EXPECT_NEAR(hi[0], covHi[0], 1.5);
  EXPECT_NEAR(hi[1], covHi[1], 1.5);
  EXPECT_LT(worstDepth, 2e-3) << "depth.Z against P through worldToCamera (half floats)";
}

}  // namespace
}  // namespace compose
