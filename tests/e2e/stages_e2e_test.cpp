// The stage-by-stage commands end to end: compose precompute → render → composite chained by hand
// gives the one-shot command's files bit for bit; a scene file saved from a command line runs the
// same job; --explain and the stage files' errors.
#include <unistd.h>

#include <sys/wait.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include <glm/gtc/matrix_transform.hpp>
#include <nlohmann/json.hpp>

#include "calib/chessboard.h"
#include "calib/plate_camera.h"
#include "color/color.h"
#include "command_util.h"
#include "ingest/exr_io.h"
#include "ingest/image_io.h"
#include "pipeline/compose_job.h"
#include "pipeline/stage_cache.h"
#include "test_util.h"

namespace compose {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;

using RunResult = compose::testing::CommandResult;
using compose::testing::quote;
using compose::testing::slurp;

RunResult run(const std::string& args, const fs::path& scratch) {
  return compose::testing::runCompose(args, scratch);
}
// Every part of an EXR: name, data window, channel names and float pixels.
struct Part {
  std::string name;
  int x = 0, y = 0, width = 0, height = 0;
  std::vector<std::string> channels;
  std::vector<float> pixels;
};

std::vector<Part> readParts(const fs::path& path) {
  std::vector<Part> parts;
  auto in = OIIO::ImageInput::open(path.string());
  if (!in) {
    ADD_FAILURE() << "cannot open " << path;
    return parts;
  }
  for (int sub = 0; in->seek_subimage(sub, 0); ++sub) {
    const OIIO::ImageSpec& s = in->spec();
    Part p{s.get_string_attribute("name"), s.x, s.y, s.width, s.height, s.channelnames, {}};
    p.pixels.resize(size_t(s.width) * size_t(s.height) * size_t(s.nchannels));
    EXPECT_TRUE(in->read_image(sub, 0, 0, s.nchannels, OIIO::TypeDesc::FLOAT, p.pixels.data()));
    parts.push_back(std::move(p));
  }
  return parts;
}

// The same parts, data windows, channels and values, bit for bit, in two EXRs.
void expectSameParts(const std::vector<Part>& a, const std::vector<Part>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    SCOPED_TRACE(a[i].name);
    EXPECT_EQ(a[i].name, b[i].name);
    EXPECT_EQ(a[i].x, b[i].x);
    EXPECT_EQ(a[i].y, b[i].y);
    EXPECT_EQ(a[i].width, b[i].width);
    EXPECT_EQ(a[i].height, b[i].height);
    EXPECT_EQ(a[i].channels, b[i].channels);
    ASSERT_EQ(a[i].pixels.size(), b[i].pixels.size());
    size_t differing = 0;
    for (size_t k = 0; k < a[i].pixels.size(); ++k)
      if (std::memcmp(&a[i].pixels[k], &b[i].pixels[k], sizeof(float)) != 0) ++differing;
    EXPECT_EQ(differing, 0u) << "values differ between the one-shot and the chained stages";
  }
}

class StageCommands : public ::testing::Test {
 protected:
  void SetUp() override {
    samples_ = pipeline::samplesDirectory();
    if (!fs::exists(samples_ / "meadow.jpg") || !fs::exists(samples_ / "forest.exr") ||
        !fs::exists(samples_ / "monkey.obj"))
      GTEST_FAIL() << "sample data missing in " << samples_ << ": run samples/fetch.sh";
    // A small plate keeps the test quick: the meadow at 320 pixels wide.
    plate_ = dir_ / "plate.jpg";
    OIIO::ImageBuf full((samples_ / "meadow.jpg").string());
    OIIO::ImageBuf small =
        OIIO::ImageBufAlgo::resize(full, "", 0.0f, OIIO::ROI(0, 320, 0, 213, 0, 1, 0, 3));
    ASSERT_TRUE(small.write(plate_.string()));
  }
  // The forest at 128 x 64, for tests of what goes around the lighting rather than of it.
  fs::path smallEnvironment() const {
    const fs::path small = dir_ / "forest-small.exr";
    if (!fs::exists(small)) {
      OIIO::ImageBuf full((samples_ / "forest.exr").string());
      OIIO::ImageBuf resized =
          OIIO::ImageBufAlgo::resize(full, "", 0.0f, OIIO::ROI(0, 128, 0, 64, 0, 1, 0, 3));
      EXPECT_TRUE(resized.write(small.string()));
    }
    return small;
  }
  // Self-shadowing as cheap as it comes (order 3 on 4x4 cells, 16 sources, no refinement, no
  // ground beneath the object), for the tests of how the stages chain and reuse their files
  // rather than of the shadows: one run of the one-shot command took 4.7 s under the sanitizers
  // with these, 9.3 s with order=4,grid=4 alone. Each parameter differs from its default (the
  // order's is the grid's size, up to 16), so a file that dropped one would be seen.
  static constexpr const char* kQuickShadows =
      " --shadow-params order=3,grid=4,refine=0,sources=16,ground=off";
  // The options the one-shot and the stages share, the monkey facing the camera at 2x2 samples.
  std::string objectOptions() const {
    return "--object " + quote(samples_ / "monkey.obj") + " --samples 2 --scale 0.4 --yaw 20";
  }

  TempDir dir_;
  fs::path samples_, plate_;
};

TEST(Compose, VersionIsPrintedAndExitsZero) {
  TempDir dir;
  const RunResult r = testing::runCompose("--version", dir.path());
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.out, std::string("compose ") + COMPOSE_VERSION + "\n");
}

TEST_F(StageCommands, ChainedByHandGivesTheOneShotFilesBitForBit) {
  // The environment turned: the lighting file carries the turn to the render (it was dropped,
  // and the chained stages lit the object with the map unturned).
  const std::string env = " --env " + quote(samples_ / "forest.exr") + " --env-yaw 70";
  // The quick parameters, but with the ground beneath the object (its contact darkening goes
  // through the lighting file and the render like the rest).
  const std::string lighting =
      " --lighting-params order=4 --shadow-params order=3,grid=4,refine=0,sources=16";
  const RunResult one =
      run("-q --plate " + quote(plate_) + " " + objectOptions() + env + lighting + " --out " +
              quote(dir_ / "one" / "compose") + " --cache " + quote(dir_ / "cache1"),
          dir_.path());
  ASSERT_EQ(one.status, 0) << one.err;

  const fs::path light = dir_ / "forest.lighting", layer = dir_ / "monkey.exr";
  const RunResult pre = run("-q precompute" + env + lighting + " --out " + quote(light) +
                                " --cache " + quote(dir_ / "cache2"),
                            dir_.path());
  ASSERT_EQ(pre.status, 0) << pre.err;
  const RunResult ren =
      run("-q render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
              quote(light) + " --out " + quote(layer) + " --cache " + quote(dir_ / "cache2"),
          dir_.path());
  ASSERT_EQ(ren.status, 0) << ren.err;
  // Again with the same cache: the render and the ground shadow are reused, and the layer (whose
  // header needs the plate's camera) is written the same.
  const fs::path again = dir_ / "monkey_again.exr";
  const RunResult ren2 =
      run("render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
              quote(light) + " --out " + quote(again) + " --cache " + quote(dir_ / "cache2"),
          dir_.path());
  ASSERT_EQ(ren2.status, 0) << ren2.err;
  const size_t renderLine = ren2.err.find("compose: render ");
  ASSERT_NE(renderLine, std::string::npos) << ren2.err;
  EXPECT_NE(
      ren2.err.substr(renderLine, ren2.err.find('\n', renderLine) - renderLine).find("reused"),
      std::string::npos)
      << ren2.err;
  EXPECT_EQ(slurp(layer), slurp(again));
  const RunResult comp =
      run("-q composite --plate " + quote(plate_) + " --layer " + quote(layer) + " --out " +
              quote(dir_ / "two" / "compose") + " --cache " + quote(dir_ / "cache2"),
          dir_.path());
  ASSERT_EQ(comp.status, 0) << comp.err;

  // The layer carries the camera and placement as the one-shot EXR does (Nuke reads the
  // standard attributes), and names its object channels as it does.
  {
    auto layerIn = OIIO::ImageInput::open(layer.string());
    auto oneIn = OIIO::ImageInput::open((dir_ / "one" / "compose.exr").string());
    ASSERT_TRUE(layerIn && oneIn);
    for (const char* attribute :
         {"worldToCamera", "worldToNDC", "compose:worldFromObject", "compose:envFromWorld"}) {
      SCOPED_TRACE(attribute);
      const OIIO::ParamValue* mine = layerIn->spec().find_attribute(attribute);
      const OIIO::ParamValue* theirs = oneIn->spec().find_attribute(attribute);
      ASSERT_TRUE(mine && theirs);
      // m44f, but the object's placement in double (m44d: a mesh far from its file's origin).
      const bool inDouble = std::string(attribute) == "compose:worldFromObject";
      const OIIO::TypeDesc type =
          inDouble ? OIIO::TypeDesc(OIIO::TypeDesc::DOUBLE, OIIO::TypeDesc::MATRIX44)
                   : OIIO::TypeMatrix44;
      ASSERT_EQ(mine->type(), type);
      ASSERT_EQ(theirs->type(), type);
      EXPECT_EQ(std::memcmp(mine->data(), theirs->data(), type.size()), 0);
    }
    // The environment's turn: --env-yaw 70 about the vertical.
    {
      const OIIO::ParamValue* turn = oneIn->spec().find_attribute("compose:envFromWorld");
      ASSERT_TRUE(turn);
      const float* m = static_cast<const float*>(turn->data());
      const double yaw = 70.0 * 3.14159265358979 / 180.0;
      EXPECT_NEAR(m[5], 1.0, 1e-6);
      EXPECT_NEAR(std::abs(m[0]), std::cos(yaw), 1e-5);
      EXPECT_NEAR(std::abs(m[2]), std::sin(yaw), 1e-5);
      EXPECT_NEAR(m[15], 1.0, 1e-6);
    }
    const auto& names = layerIn->spec().channelnames;
    EXPECT_NE(std::find(names.begin(), names.end(), "object.A"), names.end());
  }

  const std::vector<Part> a = readParts(dir_ / "one" / "compose.exr");
  const std::vector<Part> b = readParts(dir_ / "two" / "compose.exr");
  ASSERT_EQ(a.size(), 3u);  // composite, object, shadow
  expectSameParts(a, b);
  EXPECT_EQ(slurp(dir_ / "one" / "compose.jpg"), slurp(dir_ / "two" / "compose.jpg"));

  // The object moved the plate at all: the comparison above is not of two copies of the plate.
  const Part& object = a[1];
  double alpha = 0.0;
  const size_t stride = object.channels.size();
  for (size_t k = 3; k < object.pixels.size(); k += stride) alpha += object.pixels[k];
  EXPECT_GT(alpha, 100.0);

  // The same in another linear space (--exr-space): the one-shot command exposes the object's
  // light before its matrix, as the layer holds it (the matrix first left a third of the object's
  // pixels a float step off, and some of its half values one half step).
  const RunResult one709 =
      run("-q --plate " + quote(plate_) + " " + objectOptions() + env + lighting +
              " --exr-space lin_rec709 --depth float --out " + quote(dir_ / "one709" / "compose") +
              " --cache " + quote(dir_ / "cache1"),
          dir_.path());
  ASSERT_EQ(one709.status, 0) << one709.err;
  const RunResult comp709 =
      run("-q composite --exr-space lin_rec709 --depth float --plate " + quote(plate_) +
              " --layer " + quote(layer) + " --out " + quote(dir_ / "two709" / "compose") +
              " --cache " + quote(dir_ / "cache2"),
          dir_.path());
  ASSERT_EQ(comp709.status, 0) << comp709.err;
  expectSameParts(readParts(dir_ / "one709" / "compose.exr"),
                  readParts(dir_ / "two709" / "compose.exr"));

  // On another plate of the same size (here the plate darkened, as a grade would) the layer is
  // composited as it is, and a note says that its exposure and shadow were matched to the plate
  // it was rendered on; on its own plate there is no such note.
  const fs::path graded = dir_ / "graded.jpg";
  ASSERT_TRUE(
      OIIO::ImageBufAlgo::mul(OIIO::ImageBuf(plate_.string()), 0.6f).write(graded.string()));
  const std::string note = "the object layer was rendered on another plate (" + plate_.string();
  const RunResult other = run("composite --plate " + quote(graded) + " --layer " + quote(layer) +
                                  " --out " + quote(dir_ / "graded" / "compose") + " --no-cache",
                              dir_.path());
  ASSERT_EQ(other.status, 0) << other.err;
  EXPECT_NE(other.err.find(note), std::string::npos) << other.err;
  const RunResult same = run("composite --plate " + quote(plate_) + " --layer " + quote(layer) +
                                 " --out " + quote(dir_ / "same" / "compose") + " --no-cache",
                             dir_.path());
  ASSERT_EQ(same.status, 0) << same.err;
  EXPECT_EQ(same.err.find("rendered on another plate"), std::string::npos) << same.err;
  // The same plate decoded otherwise by the composite alone (--plate-space): the layer's
  // automatic exposure was matched to the plate read as its file says, and a note says by how
  // much it misses the plate as read here (the match a render reading it so makes). It passed in
  // silence, 1.5 stops off. Read alike by both commands, or with the exposure given, no note.
  const std::string linear = " --plate-space lin_rec709";
  const RunResult reread =
      run("composite --plate " + quote(plate_) + linear + " --layer " + quote(layer) + " --out " +
              quote(dir_ / "reread" / "compose") + " --no-cache",
          dir_.path());
  ASSERT_EQ(reread.status, 0) << reread.err;
  const fs::path linearLayer = dir_ / "linear layer.exr";
  const RunResult linearRender =
      run("render --plate " + quote(plate_) + linear + " " + objectOptions() + " --lighting-file " +
              quote(light) + " --out " + quote(linearLayer) + " --cache " + quote(dir_ / "cache2"),
          dir_.path());
  ASSERT_EQ(linearRender.status, 0) << linearRender.err;
  auto stops = [](const std::string& err, const std::string& before) {
    const size_t at = err.find(before);
    return at == std::string::npos ? std::nan("") : std::stod(err.substr(at + before.size()));
  };
  auto fixed = [](const char* pattern, double v) {
    char text[32];
    std::snprintf(text, sizeof text, pattern, v);
    return std::string(text);
  };
  const double layerStops = stops(same.err, "auto exposure: ");
  const double linearStops = stops(linearRender.err, "auto exposure: ");
  EXPECT_GT(std::abs(linearStops - layerStops), 1.0);  // the two readings do differ
  const std::string said = "the object layer's automatic exposure (" + fixed("%+.2f", layerStops) +
                           " stops) was matched to the plate read as its file says; this run "
                           "reads it as 'lin_rec709' (--plate-space), for which the match is " +
                           fixed("%+.2f", linearStops) + " stops: the object is ";
  EXPECT_NE(reread.err.find(said), std::string::npos) << reread.err;
  EXPECT_NEAR(stops(reread.err, said), std::abs(linearStops - layerStops), 0.011) << reread.err;
  const RunResult alike =
      run("composite --plate " + quote(plate_) + linear + " --layer " + quote(linearLayer) +
              " --out " + quote(dir_ / "alike" / "compose") + " --no-cache",
          dir_.path());
  ASSERT_EQ(alike.status, 0) << alike.err;
  EXPECT_EQ(alike.err.find("was matched to the plate read"), std::string::npos) << alike.err;
  const RunResult backwards =
      run("composite --plate " + quote(plate_) + " --layer " + quote(linearLayer) + " --out " +
              quote(dir_ / "backwards" / "compose") + " --no-cache",
          dir_.path());
  EXPECT_NE(backwards.err.find("read as 'lin_rec709' (--plate-space); this run reads it as its "
                               "file says"),
            std::string::npos)
      << backwards.err;
  // A plate of another size: --explain says the run will refuse it (it approved the job).
  const fs::path larger = dir_ / "larger.jpg";
  ASSERT_TRUE(OIIO::ImageBufAlgo::resize(OIIO::ImageBuf(plate_.string()), "", 0.0f,
                                         OIIO::ROI(0, 640, 0, 426, 0, 1, 0, 3))
                  .write(larger.string()));
  const RunResult explained =
      run("composite --explain --plate " + quote(larger) + " --layer " + quote(layer) + " --out " +
              quote(dir_ / "larger" / "compose") + " --no-cache",
          dir_.path());
  EXPECT_EQ(explained.status, 1) << explained.err;
  EXPECT_NE(
      explained.err.find("the object was rendered for a 320x213 plate; this plate is 640x426"),
      std::string::npos)
      << explained.err;
  // A layer rendered too bright: the warning says how to change it (compose composite has no
  // --exposure, which it advised).
  const fs::path bright = dir_ / "bright.exr";
  ASSERT_EQ(run("-q render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
                    quote(light) + " --exposure 6 --out " + quote(bright) + " --cache " +
                    quote(dir_ / "cache2"),
                dir_.path())
                .status,
            0);
  const RunResult clipped = run("composite --plate " + quote(plate_) + " --layer " + quote(bright) +
                                    " --out " + quote(dir_ / "bright" / "compose") + " --no-cache",
                                dir_.path());
  ASSERT_EQ(clipped.status, 0) << clipped.err;
  EXPECT_NE(clipped.err.find("render the layer again with a lower --exposure (compose render)"),
            std::string::npos)
      << clipped.err;
  // Nor on a copy of it under another name: the bytes are compared, not the names.
  fs::copy_file(plate_, dir_ / "copy of plate.jpg");
  const RunResult copy =
      run("composite --plate " + quote(dir_ / "copy of plate.jpg") + " --layer " + quote(layer) +
              " --out " + quote(dir_ / "copy" / "compose") + " --no-cache",
          dir_.path());
  ASSERT_EQ(copy.status, 0) << copy.err;
  EXPECT_EQ(copy.err.find("rendered on another plate"), std::string::npos) << copy.err;

  // The layer belongs to its plate: another plate size is a named error and writes nothing.
  const fs::path smaller = dir_ / "smaller.jpg";
  OIIO::ImageBuf full(plate_.string());
  ASSERT_TRUE(OIIO::ImageBufAlgo::resize(full, "", 0.0f, OIIO::ROI(0, 160, 0, 106, 0, 1, 0, 3))
                  .write(smaller.string()));
  const RunResult wrong = run("composite --plate " + quote(smaller) + " --layer " + quote(layer) +
                                  " --out " + quote(dir_ / "three" / "compose") + " --no-cache",
                              dir_.path());
  EXPECT_EQ(wrong.status, 1);
  EXPECT_NE(wrong.err.find("rendered for a 320x213 plate"), std::string::npos) << wrong.err;
  EXPECT_FALSE(fs::exists(dir_ / "three" / "compose.exr"));
}

// The render is kept in the environment's units and the exposure chosen and applied after it: a
// given --exposure after the automatic one, another one and the automatic one again reuse the
// cached render, and give the files a run without the cache gives, byte for byte; the object's
// colour and irradiance scale with the exposure, its other channels do not, and the composite
// shows the object's colour where it covers the plate.
TEST_F(StageCommands, ANewExposureReusesTheRender) {
  const std::string job = "--plate " + quote(plate_) + " " + objectOptions() + " --env " +
                          quote(samples_ / "forest.exr") + " --lighting-params order=4" +
                          kQuickShadows;
  auto renderLine = [](const RunResult& r) {
    const size_t at = r.err.find("compose: render ");
    return at == std::string::npos ? std::string() : r.err.substr(at, r.err.find('\n', at) - at);
  };
  auto cached = [&](const std::string& exposure, const std::string& name) {
    return run(job + exposure + " --out " + quote(dir_ / name / "compose") + " --cache " +
                   quote(dir_ / "cache"),
               dir_.path());
  };
  const RunResult automatic = cached("", "auto");
  ASSERT_EQ(automatic.status, 0) << automatic.err;
  ASSERT_FALSE(renderLine(automatic).empty()) << automatic.err;
  EXPECT_EQ(renderLine(automatic).find("reused"), std::string::npos) << automatic.err;
  EXPECT_NE(automatic.err.find("auto exposure: "), std::string::npos) << automatic.err;
  const RunResult first = cached(" --exposure -1", "first");
  ASSERT_EQ(first.status, 0) << first.err;
  EXPECT_NE(renderLine(first).find("reused"), std::string::npos) << first.err;
  EXPECT_EQ(first.err.find("auto exposure: "), std::string::npos) << first.err;
  const RunResult brighter = cached(" --exposure 0.5", "brighter");
  ASSERT_EQ(brighter.status, 0) << brighter.err;
  EXPECT_NE(renderLine(brighter).find("reused"), std::string::npos) << brighter.err;
  const RunResult again = cached("", "again");
  ASSERT_EQ(again.status, 0) << again.err;
  EXPECT_NE(renderLine(again).find("reused"), std::string::npos) << again.err;
  EXPECT_NE(again.err.find("auto exposure: "), std::string::npos) << again.err;
  EXPECT_EQ(slurp(dir_ / "auto" / "compose.exr"), slurp(dir_ / "again" / "compose.exr"));
  const RunResult fresh =
      run(job + " --exposure 0.5 --out " + quote(dir_ / "fresh" / "compose") + " --no-cache",
          dir_.path());
  ASSERT_EQ(fresh.status, 0) << fresh.err;
  EXPECT_EQ(slurp(dir_ / "brighter" / "compose.exr"), slurp(dir_ / "fresh" / "compose.exr"));
  EXPECT_EQ(slurp(dir_ / "brighter" / "compose.jpg"), slurp(dir_ / "fresh" / "compose.jpg"));

  // 1.5 stops apart: the object's colour and irradiance 2^1.5 times as bright (within half's
  // rounding), its alpha, normals, positions, albedo and occlusion the same.
  const std::vector<Part> a = readParts(dir_ / "first" / "compose.exr");
  const std::vector<Part> b = readParts(dir_ / "brighter" / "compose.exr");
  ASSERT_EQ(a.size(), b.size());
  ASSERT_GE(a.size(), 2u);
  const Part &dim = a[1], &bright = b[1];
  ASSERT_EQ(dim.name, "object");
  ASSERT_EQ(dim.channels, bright.channels);
  ASSERT_EQ(dim.pixels.size(), bright.pixels.size());
  const size_t stride = dim.channels.size();
  const float ratio = std::exp2(1.5f);
  for (size_t c = 0; c < stride; ++c) {
    const std::string& name = dim.channels[c];
    SCOPED_TRACE(name);
    const bool exposed = name == "object.R" || name == "object.G" || name == "object.B" ||
                         name.rfind("irradiance", 0) == 0;
    size_t lit = 0, wrong = 0;
    for (size_t k = c; k < dim.pixels.size(); k += stride) {
      const float d = dim.pixels[k], v = bright.pixels[k];
      if (!exposed) {
        wrong += std::memcmp(&d, &v, sizeof d) != 0;
        continue;
      }
      if (d == 0.0f) {
        wrong += v != 0.0f;
        continue;
      }
      ++lit;
      wrong += std::abs(v - ratio * d) > 2e-3f * ratio * std::abs(d) + 1e-4f;  // half subnormals
    }
    EXPECT_EQ(wrong, 0u);
    if (exposed) {
      EXPECT_GT(lit, 100u);
    }
  }
  // Where the object covers a pixel entirely, the composite is the object's colour.
  const Part& composite = b[0];
  ASSERT_EQ(composite.name, "composite");
  const size_t alpha =
      size_t(std::find(bright.channels.begin(), bright.channels.end(), "object.A") -
             bright.channels.begin());
  ASSERT_LT(alpha, stride);
  size_t covered = 0, differing = 0;
  for (int y = 0; y < bright.height; ++y)
    for (int x = 0; x < bright.width; ++x) {
      const float* o = &bright.pixels[(size_t(y) * size_t(bright.width) + size_t(x)) * stride];
      if (o[alpha] != 1.0f) continue;
      ++covered;
      const float* c =
          &composite
               .pixels[(size_t(y + bright.y) * size_t(composite.width) + size_t(x + bright.x)) *
                       composite.channels.size()];
      for (const char* name : {"R", "G", "B"}) {
        const size_t at =
            size_t(std::find(composite.channels.begin(), composite.channels.end(), name) -
                   composite.channels.begin());
        const size_t from = size_t(std::find(bright.channels.begin(), bright.channels.end(),
                                             std::string("object.") + name) -
                                   bright.channels.begin());
        ASSERT_LT(at, composite.channels.size());
        ASSERT_LT(from, stride);
        differing += c[at] != o[from];
      }
    }
  EXPECT_GT(covered, 100u);
  EXPECT_EQ(differing, 0u);
}

// The render and the ground shadow depend on the plate only through the camera it makes (its
// size, EXIF orientation and focal length): another take from the same camera (here the plate
// darkened) reuses both and gives what a run without the cache gives; a plate of the same pixels
// with another focal length in EXIF renders again.
TEST_F(StageCommands, AnotherTakeFromTheSameCameraReusesTheRenderAndTheGroundShadow) {
  const std::string job = objectOptions() + " --env " + quote(samples_ / "forest.exr") +
                          " --lighting-params order=4" + kQuickShadows;
  auto line = [](const RunResult& r, const std::string& stage) {
    const size_t at = r.err.find("compose: " + stage + " ");
    return at == std::string::npos ? std::string() : r.err.substr(at, r.err.find('\n', at) - at);
  };
  auto cached = [&](const fs::path& plate, const std::string& name) {
    return run("--timings --plate " + quote(plate) + " " + job + " --out " +
                   quote(dir_ / name / "compose") + " --cache " + quote(dir_ / "cache"),
               dir_.path());
  };
  const RunResult first = cached(plate_, "first");
  ASSERT_EQ(first.status, 0) << first.err;
  for (const char* stage : {"render", "ground"}) {
    ASSERT_FALSE(line(first, stage).empty()) << first.err;
    EXPECT_EQ(line(first, stage).find("reused"), std::string::npos) << first.err;
  }

  // Another take: the same size and EXIF, other pixels.
  const fs::path take = dir_ / "take.jpg";
  {
    OIIO::ImageBuf original(plate_.string());
    OIIO::ImageBuf darker = OIIO::ImageBufAlgo::mul(original, 0.6f);
    ASSERT_TRUE(darker.write(take.string()));
  }
  ASSERT_NE(slurp(take), slurp(plate_));
  const RunResult second = cached(take, "take");
  ASSERT_EQ(second.status, 0) << second.err;
  for (const char* stage : {"render", "ground"})
    EXPECT_NE(line(second, stage).find("reused"), std::string::npos) << second.err;
  EXPECT_EQ(line(second, "composite").find("reused"), std::string::npos) << second.err;
  const RunResult fresh = run("--plate " + quote(take) + " " + job + " --out " +
                                  quote(dir_ / "fresh" / "compose") + " --no-cache",
                              dir_.path());
  ASSERT_EQ(fresh.status, 0) << fresh.err;
  EXPECT_EQ(slurp(dir_ / "take" / "compose.exr"), slurp(dir_ / "fresh" / "compose.exr"));
  EXPECT_EQ(slurp(dir_ / "take" / "compose.jpg"), slurp(dir_ / "fresh" / "compose.jpg"));
  EXPECT_NE(slurp(dir_ / "take" / "compose.jpg"), slurp(dir_ / "first" / "compose.jpg"));

  // The first plate's pixels with another focal length in EXIF: another camera.
  const fs::path zoomed = dir_ / "zoomed.jpg";
  {
    OIIO::ImageBuf original(plate_.string());
    original.specmod().attribute("Exif:FocalLengthIn35mmFilm", 85);
    ASSERT_TRUE(original.write(zoomed.string()));
  }
  const RunResult third = cached(zoomed, "zoomed");
  ASSERT_EQ(third.status, 0) << third.err;
  for (const char* stage : {"render", "ground"}) {
    ASSERT_FALSE(line(third, stage).empty()) << third.err;
    EXPECT_EQ(line(third, stage).find("reused"), std::string::npos) << third.err;
  }
  // The file's camera has the 85 mm lens (the first plate has no focal length in EXIF: 50 mm).
  auto xScale = [](const fs::path& exr) {
    auto in = OIIO::ImageInput::open(exr.string());
    const OIIO::ParamValue* m = in ? in->spec().find_attribute("worldToNDC") : nullptr;
    return m && m->type() == OIIO::TypeMatrix44 ? static_cast<const float*>(m->data())[0] : 0.0f;
  };
  const float wide = xScale(dir_ / "first" / "compose.exr");
  ASSERT_GT(wide, 0.0f);
  EXPECT_NEAR(xScale(dir_ / "zoomed" / "compose.exr") / wide, 85.0f / 50.0f, 1e-4f);
}

// A textured object (Suzanne with a checker texture, exported by Blender) through compose render
// and compose composite with a given exposure gives the one-shot command's files bit for bit: the
// render command brings the materials into the working space as the one-shot command does (it did
// not with a given exposure, whose render then showed the texture's sRGB codes as linear light).
TEST_F(StageCommands, ATexturedObjectChainedByHandWithAGivenExposure) {
  const fs::path mesh = fs::path(COMPOSE_TEST_DATA_DIR) / "suzanne_checker.obj";
  ASSERT_TRUE(fs::exists(mesh)) << mesh;
  const std::string env = " --env " + quote(samples_ / "forest.exr");
  const std::string lighting = std::string(" --lighting-params order=4") + kQuickShadows;
  const std::string object =
      " --object " + quote(mesh) + " --samples 2 --scale 0.4 --yaw 20 --exposure 0.3";
  const RunResult one =
      run("-q --plate " + quote(plate_) + object + env + lighting + " --out " +
              quote(dir_ / "one" / "compose") + " --cache " + quote(dir_ / "cache1"),
          dir_.path());
  ASSERT_EQ(one.status, 0) << one.err;
  const fs::path light = dir_ / "forest.lighting", layer = dir_ / "suzanne.exr";
  const RunResult pre = run("-q precompute" + env + lighting + " --out " + quote(light) +
                                " --cache " + quote(dir_ / "cache2"),
                            dir_.path());
  ASSERT_EQ(pre.status, 0) << pre.err;
  const RunResult ren =
      run("render --plate " + quote(plate_) + object + " --lighting-file " + quote(light) +
              " --out " + quote(layer) + " --cache " + quote(dir_ / "cache2"),
          dir_.path());
  ASSERT_EQ(ren.status, 0) << ren.err;
  EXPECT_NE(ren.err.find("1 texture (1 as 'sRGB - Texture'), converted to"), std::string::npos)
      << "the materials were not brought into the working space:\n"
      << ren.err;
  const RunResult comp =
      run("-q composite --plate " + quote(plate_) + " --layer " + quote(layer) + " --out " +
              quote(dir_ / "two" / "compose") + " --cache " + quote(dir_ / "cache2"),
          dir_.path());
  ASSERT_EQ(comp.status, 0) << comp.err;
  const std::vector<Part> a = readParts(dir_ / "one" / "compose.exr");
  const std::vector<Part> b = readParts(dir_ / "two" / "compose.exr");
  expectSameParts(a, b);
  EXPECT_EQ(slurp(dir_ / "one" / "compose.jpg"), slurp(dir_ / "two" / "compose.jpg"));
}

// The order order=auto chose travels with a projection reused from the cache: a second
// precompute wrote order 0 into its lighting file, which render then refused ("the lighting
// file's contents do not fit its basis").
TEST_F(StageCommands, AReusedAutomaticOrderIsTheOneChosen) {
  // A small map and a coarse shadow basis keep it quick (under the sanitizers too).
  const std::string env = " --env " + quote(smallEnvironment()) +
                          " --lighting-params order=auto --shadow-params grid=4 --cache " +
                          quote(dir_ / "cache");
  for (const char* name : {"first.lighting", "second.lighting"}) {
    const RunResult pre = run("precompute" + env + " --out " + quote(dir_ / name), dir_.path());
    ASSERT_EQ(pre.status, 0) << pre.err;
  }
  EXPECT_TRUE(slurp(dir_ / "first.lighting") == slurp(dir_ / "second.lighting"))
      << "the reused projection's lighting file differs from the computed one's";
  const RunResult ren = run("-q render --plate " + quote(plate_) + " " + objectOptions() +
                                " --lighting-file " + quote(dir_ / "second.lighting") + " --out " +
                                quote(dir_ / "layer.exr") + " --cache " + quote(dir_ / "cache"),
                            dir_.path());
  EXPECT_EQ(ren.status, 0) << ren.err;
}

// A lighting file with SH transfer for the shadows (its basis kept no state: precompute failed,
// blaming --lighting).
TEST_F(StageCommands, ALightingFileWithShTransfer) {
  const fs::path light = dir_ / "sh.lighting";
  const RunResult pre = run("-q precompute --env " + quote(smallEnvironment()) +
                                " --shadow-params method=sh,order=2,grid=4 --out " + quote(light) +
                                " --cache " + quote(dir_ / "cache"),
                            dir_.path());
  ASSERT_EQ(pre.status, 0) << pre.err;
  const RunResult ren =
      run("-q render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
              quote(light) + " --out " + quote(dir_ / "layer.exr") + " --no-cache",
          dir_.path());
  EXPECT_EQ(ren.status, 0) << ren.err;
}

// A lighting file made with the object's own shadow parameters serves a render that draws fewer
// shadows (it was refused, exit 2, naming --shadow-params, which compose render does not take),
// and what compose precompute warned of the environment is said again by the render that uses
// the file (a map upside down: the render was silent). The render's --out replaces a layer, not
// another OpenEXR (it overwrote any).
TEST_F(StageCommands, ALightingFileServesRendersWithFewerShadowsAndKeepsItsWarnings) {
  const fs::path flipped = dir_ / "flipped.exr";
  OIIO::ImageBuf env(smallEnvironment().string());
  ASSERT_TRUE(OIIO::ImageBufAlgo::flip(env).write(flipped.string()));
  const fs::path light = dir_ / "l.lighting";
  const std::string warning = "times as bright below its horizon as above it";
  const RunResult pre = run("precompute --env " + quote(flipped) +
                                " --shadow-params order=4,grid=4,refine=0.1,ground=off --out " +
                                quote(light) + " --no-cache",
                            dir_.path());
  ASSERT_EQ(pre.status, 0) << pre.err;
  EXPECT_NE(pre.err.find(warning), std::string::npos) << pre.err;
  // An OpenEXR there that is not a layer (an HDRI named by mistake) is not replaced.
  fs::copy_file(smallEnvironment(), dir_ / "hdri.exr");
  const RunResult over =
      run("render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
              quote(light) + " --out " + quote(dir_ / "hdri.exr") + " --no-cache",
          dir_.path());
  EXPECT_EQ(over.status, 1) << over.err;
  EXPECT_NE(over.err.find("render: is not a compose object layer and would be replaced"),
            std::string::npos)
      << over.err;
  EXPECT_EQ(slurp(dir_ / "hdri.exr"), slurp(smallEnvironment())) << "the file is untouched";
  // Layers are (three renders into one file below).
  for (const char* fewer : {"", " --shadows off", " --shadows off --no-shadow"}) {
    const RunResult ren =
        run("render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
                quote(light) + fewer + " --out " + quote(dir_ / "layer.exr") + " --no-cache",
            dir_.path());
    EXPECT_EQ(ren.status, 0) << fewer << ": " << ren.err;
    EXPECT_NE(ren.err.find(warning), std::string::npos) << fewer << ": " << ren.err;
  }
}

// --env-space says the colour space of a capture's photos, as of any environment file (it was
// hashed into the keys and not used: the lighting of 'Display P3' photos was byte for byte that
// of sRGB ones), whether their brackets are merged or each view is one photo.
TEST_F(StageCommands, EnvSpaceSaysTheSpaceOfACapturesPhotos) {
  for (const char* brackets : {"1", "3"}) {
    SCOPED_TRACE(std::string("brackets ") + brackets);
    const fs::path shots = dir_ / (std::string("shots") + brackets);
    const RunResult sim =
        run("-q capture-sim --env " + quote(smallEnvironment()) +
                " --size 64x48 --no-noise --brackets " + brackets + " --out " + quote(shots),
            dir_.path());
    ASSERT_EQ(sim.status, 0) << sim.err;
    std::map<std::string, std::string> bytes;
    for (const char* space : {"", "Display P3"}) {
      const fs::path out =
          dir_ / (std::string("capture") + brackets + (*space ? "p3" : "") + ".lighting");
      const RunResult pre = run("-q precompute --env " + quote(shots / "capture.json") +
                                    (*space ? " --env-space " + quote(space) : std::string()) +
                                    " --out " + quote(out) + " --cache " + quote(dir_ / "cache"),
                                dir_.path());
      ASSERT_EQ(pre.status, 0) << pre.err;
      std::ifstream in(out, std::ios::binary);
      bytes[space] = std::string(std::istreambuf_iterator<char>(in), {});
    }
    EXPECT_TRUE(bytes[""] != bytes["Display P3"]) << "the same lighting for both spaces";
  }
}

// A ring of level views, as capture-sim names them (yaw000_1.jpg ...): compose ingest names the
// views for their turn, and the capture description lights the object (its views were named
// view1 ..., and --env refused them: "cannot tell where view 'view1' points"; a view named
// yaw000 by a --pattern was refused too).
TEST_F(StageCommands, ARingCaptureDescribedByIngestIsStitched) {
  const fs::path shots = dir_ / "ring";
  const RunResult sim = run("-q capture-sim --env " + quote(smallEnvironment()) +
                                " --views 8 --size 64x48 --no-noise --out " + quote(shots),
                            dir_.path());
  ASSERT_EQ(sim.status, 0) << sim.err;
  std::string photos;
  for (const auto& e : fs::directory_iterator(shots))
    if (e.path().extension() == ".jpg") photos += " " + quote(e.path());
  for (const std::string& grouping :
       {std::string(), std::string(" --group pattern --pattern '{view}_{bracket}.jpg'")}) {
    SCOPED_TRACE(grouping);
    const fs::path described = dir_ / "ring.json";
    const RunResult ingest =
        run("ingest" + grouping + " --json " + quote(described) + photos, dir_.path());
    ASSERT_EQ(ingest.status, 0) << ingest.err;
    std::ifstream in(described);
    const nlohmann::json capture = nlohmann::json::parse(in);
    ASSERT_EQ(capture["views"].size(), 8u) << capture.dump();
    EXPECT_EQ(capture["views"][0]["name"], "yaw000") << capture.dump();
    const RunResult pre =
        run("-q precompute --env " + quote(described) + " --out " + quote(dir_ / "ring.lighting") +
                " --cache " + quote(dir_ / "cache"),
            dir_.path());
    EXPECT_EQ(pre.status, 0) << pre.err;
  }
}

// An option only the one-shot command has, given to a command, is refused before anything is
// read (CLI11 would pass it up to the one-shot command's options, where it was taken and not
// used: compose composite --exposure 1 wrote the same picture as without). The options of every
// command still work after the command's name.
TEST_F(StageCommands, AnOptionOnlyTheOneShotCommandHasIsRefused) {
  const std::string out = " --out " + quote(dir_ / "x");
  const struct {
    std::string args, option;
  } cases[] = {
      {"composite --plate " + quote(plate_) + " --layer missing.exr --exposure 1" + out,
       "--exposure"},
      {"composite --plate " + quote(plate_) + " --layer missing.exr --yaw 45" + out, "--yaw"},
      {"render --plate " + quote(plate_) + " " + objectOptions() +
           " --lighting-file missing.lighting --env " + quote(samples_ / "sunset.exr") + out,
       "--env"},
      {"precompute --env " + quote(samples_ / "forest.exr") + " --albedo 0.3" + out, "--albedo"},
      {"convert missing.exr --to cube --scale 3" + out, "--scale"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(c.args);
    const RunResult r = run(c.args, dir_.path());
    EXPECT_EQ(r.status, 2) << r.err;
    EXPECT_NE(r.err.find(c.option + " is not an option of compose"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "x.exr"));
    EXPECT_FALSE(fs::exists(dir_ / "x"));
  }
  // The object's layer is an OpenEXR: another name is refused before the render (it wrote an EXR
  // named layer.png).
  const RunResult png = run("render --plate " + quote(plate_) + " " + objectOptions() +
                                " --lighting-file missing.lighting --out " + quote(dir_ / "x.png"),
                            dir_.path());
  EXPECT_EQ(png.status, 2) << png.err;
  EXPECT_NE(png.err.find("--out must name an OpenEXR file (.exr): the object's layer is a "
                         "multi-part OpenEXR"),
            std::string::npos)
      << png.err;
  EXPECT_FALSE(fs::exists(dir_ / "x.png"));
  // A command's own option given before its name is refused too, saying where it goes.
  const RunResult before = run("--exposure 1 render --plate " + quote(plate_) + " " +
                                   objectOptions() + " --lighting-file missing.lighting" + out,
                               dir_.path());
  EXPECT_EQ(before.status, 2) << before.err;
  EXPECT_NE(before.err.find("--exposure is an option of compose render: give it after the "
                            "command's name"),
            std::string::npos)
      << before.err;
  // Said first, before what the command then misses: the very option given too early (an option
  // only the command has), or another value it requires.
  for (const std::string early : {"--exposure 1 render", "--lighting-file f.lighting render",
                                  "--lighting-file=f.lighting render --plate p.jpg"}) {
    const RunResult r = run(early, dir_.path());
    EXPECT_EQ(r.status, 2) << early;
    EXPECT_NE(r.err.find(" is an option of compose render: give it after the command's name"),
              std::string::npos)
        << early << "\n"
        << r.err;
  }
  const RunResult pre =
      run("precompute -q --max-pixels 100000000 --env " + quote(samples_ / "forest.exr") +
              " --lighting-params order=4" + " --out " + quote(dir_ / "f.lighting") + " --no-cache",
          dir_.path());
  EXPECT_EQ(pre.status, 0) << pre.err;
  EXPECT_TRUE(fs::exists(dir_ / "f.lighting"));
}

TEST_F(StageCommands, ASavedSceneRunsTheSameJob) {
  const std::string common = "--plate " + quote(plate_) + " " + objectOptions() + " --env " +
                             quote(samples_ / "forest.exr") +
                             " --shadows off --lighting-params order=2";
  const fs::path scene = dir_ / "scenes" / "monkey.json";
  fs::create_directories(scene.parent_path());
  const RunResult save =
      run(common + " --out " + quote(dir_ / "a" / "compose") + " --save-scene " + quote(scene),
          dir_.path());
  ASSERT_EQ(save.status, 0) << save.err;
  EXPECT_FALSE(fs::exists(dir_ / "a" / "compose.exr")) << "--save-scene writes the scene only";
  // Checked as the run checks it: a colour space, display or view the config does not know is
  // refused before the scene is written (it was saved, and compose run failed on it).
  for (const char* bad : {"--exr-space Bogus", "--view Bogus", "--plate-space Bogus"}) {
    const RunResult refused = run(
        common + " " + bad + " --save-scene " + quote(dir_ / "scenes" / "bad.json"), dir_.path());
    EXPECT_EQ(refused.status, 2) << bad << "\n" << refused.err;
    EXPECT_FALSE(fs::exists(dir_ / "scenes" / "bad.json")) << bad;
  }
  const std::string text = slurp(scene);
  EXPECT_NE(text.find("\"plate\": \"../plate.jpg\""), std::string::npos)
      << "paths near the scene are relative to it:\n"
      << text;

  // Run from another folder: the scene's paths do not depend on where compose runs.
  const RunResult fromScene =
      run("-q run " + quote(scene) + " --no-cache", dir_.path().parent_path());
  ASSERT_EQ(fromScene.status, 0) << fromScene.err;
  const RunResult direct =
      run("-q " + common + " --out " + quote(dir_ / "b" / "compose") + " --no-cache", dir_.path());
  ASSERT_EQ(direct.status, 0) << direct.err;
  EXPECT_EQ(slurp(dir_ / "a" / "compose.jpg"), slurp(dir_ / "b" / "compose.jpg"));

  // --set overrides a parameter; the result changes.
  const RunResult moved = run(
      "-q run " + quote(scene) +
          " --no-cache --set render.scale=0.2 --set output.out=" + quote(dir_ / "c" / "compose"),
      dir_.path());
  ASSERT_EQ(moved.status, 0) << moved.err;
  EXPECT_NE(slurp(dir_ / "a" / "compose.jpg"), slurp(dir_ / "c" / "compose.jpg"));

  // The scene is written before the inputs are read: it may replace an older scene (above,
  // again), never a file of another kind, such as the mesh's material library.
  const fs::path mtl = dir_ / "red.mtl", obj = dir_ / "red.obj";
  compose::testing::writeText(mtl, "newmtl red\nKd 1 0 0\n");
  compose::testing::writeText(obj,
                              "mtllib red.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n");
  const RunResult overMtl =
      run("--plate " + quote(plate_) + " --object " + quote(obj) + " --save-scene " + quote(mtl),
          dir_.path());
  EXPECT_EQ(overMtl.status, 1);
  EXPECT_NE(overMtl.err.find("is not a compose scene file and would be replaced"),
            std::string::npos)
      << overMtl.err;
  EXPECT_EQ(slurp(mtl), "newmtl red\nKd 1 0 0\n");
  EXPECT_EQ(run(common + " --save-scene " + quote(scene), dir_.path()).status, 0);

  // --ocio builtin is kept in the scene: run with $OCIO set, the scene's job still takes the
  // built-in config (it took $OCIO's, and its colours with it).
  const fs::path pinned = dir_ / "scenes" / "builtin.json";
  ASSERT_EQ(run("--ocio builtin " + common + " --save-scene " + quote(pinned), dir_.path()).status,
            0);
  EXPECT_NE(slurp(pinned).find("\"ocio\": \"builtin\""), std::string::npos) << slurp(pinned);
  const RunResult underOcio =
      compose::testing::runCompose("run " + quote(pinned) + " --no-cache --explain", dir_.path(),
                                   "OCIO=" + quote(dir_ / "missing.ocio"));
  EXPECT_EQ(underOcio.status, 0) << underOcio.err;
}

TEST_F(StageCommands, SceneErrorsNameTheStageAndListTheValidOnes) {
  const fs::path scene = dir_ / "bad.json";
  compose::testing::writeText(
      scene, R"({"compose": "scene", "version": 1, "stages": {"render": {"sclae": 0.3}}})");
  RunResult r = run("run " + quote(scene), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("no parameter 'sclae'"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("scale"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("bad.json"), std::string::npos) << r.err;

  compose::testing::writeText(scene,
                              R"({"compose": "scene", "version": 1, "stages": {"rendre": {}}})");
  r = run("run " + quote(scene), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("unknown stage 'rendre'"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("ingest, merge, stitch"), std::string::npos) << r.err;

  compose::testing::writeText(scene, "{ not json");
  r = run("run " + quote(scene), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("not JSON"), std::string::npos) << r.err;

  r = run("run " + quote(dir_ / "missing.json"), dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("not found"), std::string::npos) << r.err;

  r = run("run " + quote(scene) + " --set render.scale", dir_.path());
  EXPECT_EQ(r.status, 2) << r.err;
  r = run("run " + quote(scene) + " --set render.scale=0.2 --set render.scale=0.4", dir_.path());
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("--set render.scale is given twice"), std::string::npos) << r.err;

  // A value out of range in the scene file is the file's error (exit 1, naming it); one a --set
  // brings is the command line's (exit 2). Both were "cli:" errors with exit 2.
  const fs::path saved = dir_ / "saved.json";
  r = run("--plate " + quote(plate_) + " " + objectOptions() + " --out " + quote(dir_ / "o") +
              " --save-scene " + quote(saved),
          dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  std::string text = slurp(saved);
  const size_t at = text.find("\"samples\": 2");
  ASSERT_NE(at, std::string::npos) << text;
  compose::testing::writeText(scene, text.replace(at, 12, "\"samples\": 0"));
  r = run("run " + quote(scene), dir_.path());
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("scene: --samples must be in 1..64, got 0 (the value in the scene file)"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("bad.json"), std::string::npos) << r.err;
  r = run("run " + quote(saved) + " --set render.samples=65", dir_.path());
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("--samples must be in 1..64, got 65"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "o.exr"));

  // What the one-shot command refuses as changing nothing, a scene run refuses too (it ran,
  // the values ignored): a JPEG quality for a PNG, self-shadowing parameters with --shadows off.
  for (const auto& [sets, message] : std::vector<std::pair<std::string, std::string>>{
           {" --set output.jpeg-quality=20 --set output.out=" + quote(dir_ / "p.png"),
            "--jpeg-quality applies to a JPEG display image"},
           {" --set shadows.shadows=off --set shadows.shadow-params=refine=0.1",
            "refine is for the object's shadows on itself, which --shadows off leaves out"}}) {
    r = run("run " + quote(saved) + sets, dir_.path());
    EXPECT_EQ(r.status, 2) << sets << ": " << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
  }
  // A path that reads as a number is a path (it was "out must be a path (a string)").
  r = run("run " + quote(saved) + " --explain --set output.out=2024", dir_.path());
  EXPECT_EQ(r.status, 0) << r.err;
  // --explain with --save-scene did not explain; it is one or the other.
  r = run("--plate " + quote(plate_) + " " + objectOptions() + " --explain --save-scene " +
              quote(dir_ / "explained.json"),
          dir_.path());
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "explained.json"));
  // --explain approved a plate the run refuses at once for its size.
  r = run("--max-pixels 1000 --plate " + quote(plate_) + " " + objectOptions() + " --explain",
          dir_.path());
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("more than the limit"), std::string::npos) << r.err;
}

TEST_F(StageCommands, StageFilesThatAreNotOnesAreNamedErrors) {
  const fs::path notLighting = dir_ / "not.lighting";
  compose::testing::writeText(notLighting, "COMPSTG1 but not really");
  RunResult r =
      run("render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
              quote(notLighting) + " --out " + quote(dir_ / "o.exr"),
          dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("not.lighting"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "o.exr"));

  // An EXR that is not an object layer: the plate as EXR.
  const fs::path plainExr = dir_ / "plain.exr";
  OIIO::ImageBuf plate(plate_.string());
  ASSERT_TRUE(plate.write(plainExr.string()));
  r = run("composite --plate " + quote(plate_) + " --layer " + quote(plainExr) + " --out " +
              quote(dir_ / "c"),
          dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("not an object layer"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "c.exr"));
  // Of another size than the plate, and planned: named as not a layer either (--explain blamed
  // its size).
  r = run("composite --explain --plate " + quote(plate_) + " --layer " + quote(smallEnvironment()) +
              " --out " + quote(dir_ / "c"),
          dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("not an object layer"), std::string::npos) << r.err;

  // A folder, a device and a missing file are each called what they are (all were "not found").
  fs::create_directories(dir_ / "folder.exr");
  for (const auto& [layer, message] : std::vector<std::pair<std::string, std::string>>{
           {(dir_ / "folder.exr").string(), "composite: object layer is a folder, not a file"},
           {"/dev/zero", "composite: is a character device, not a regular file"},
           {(dir_ / "missing.exr").string(), "composite: object layer not found"}}) {
    r = run("composite --plate " + quote(plate_) + " --layer " + quote(layer) + " --out " +
                quote(dir_ / "c"),
            dir_.path());
    EXPECT_EQ(r.status, 1) << layer;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(layer), std::string::npos) << r.err;
  }
  r = run("render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
              quote(dir_ / "folder.exr") + " --out " + quote(dir_ / "o.exr"),
          dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("render: lighting file is a folder, not a file"), std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "c.exr"));
}

// A layer saved again by another tool: the object part padded to the frame (oiiotool
// --croptofull) composites as the layer did; its colour converted to another space, with the
// part's chromaticities saying so, is brought back by matrix; a NaN, an alpha above 1 or a
// negative shadow ratio is refused naming the part and the frame's pixel, and nothing is written.
TEST_F(StageCommands, ALayerSavedAgainByAnotherToolIsReadAsItsFileHoldsIt) {
  const fs::path light = dir_ / "forest.lighting", layer = dir_ / "monkey.exr";
  const std::string cache = " --cache " + quote(dir_ / "cache");
  ASSERT_EQ(run("-q precompute --env " + quote(smallEnvironment()) +
                    " --shadow-params order=4,grid=4 --out " + quote(light) + cache,
                dir_.path())
                .status,
            0);
  ASSERT_EQ(run("-q render --plate " + quote(plate_) + " " + objectOptions() + " --lighting-file " +
                    quote(light) + " --out " + quote(layer) + cache,
                dir_.path())
                .status,
            0);
  auto composite = [&](const fs::path& file, const std::string& name) {
    return run("composite --depth float --plate " + quote(plate_) + " --layer " + quote(file) +
                   " --out " + quote(dir_ / "out" / name) + cache,
               dir_.path());
  };
  const RunResult base = composite(layer, "base");
  ASSERT_EQ(base.status, 0) << base.err;

  // Every part again (compose:layer kept), after `edit` changed the parts' pixels, windows or
  // chromaticities.
  struct Saved {
    std::string name;
    Image image;
    int x = 0, y = 0, fullWidth = 0, fullHeight = 0;
    std::array<double, 8> chromaticities = color::kAcesAp1Chromaticities;
  };
  std::vector<Saved> original;
  std::string header;
  {
    ingest::ExrReader in(layer, "test");
    for (int p = 0; p < in.parts(); ++p) {
      const ingest::ExrPartHeader& h = in.header(p);
      original.push_back({h.name, in.read(p), h.x, h.y, h.fullWidth, h.fullHeight});
      if (const ingest::ImageAttribute* a = h.find("compose:layer"))
        header = std::get<std::string>(a->value);
    }
  }
  ASSERT_EQ(original.size(), 2u);
  ASSERT_FALSE(header.empty());
  auto save = [&](const std::string& name, const std::function<void(std::vector<Saved>&)>& edit) {
    std::vector<Saved> parts = original;
    edit(parts);
    std::vector<ingest::ExrPart> out;
    for (const Saved& s : parts) {
      ingest::WriteOptions options;
      options.depth = ingest::WriteOptions::Depth::Float;
      options.chromaticities = s.chromaticities;
      options.attributes = {{"compose:layer", header}};
      out.emplace_back(s.name, &s.image, s.x, s.y, s.fullWidth, s.fullHeight, options);
    }
    const fs::path file = dir_ / (name + ".exr");
    ingest::writeExrFile(file, file, out);
    return file;
  };
  auto channel = [](const Image& image, const std::string& name) {
    const auto it = std::find(image.channelNames.begin(), image.channelNames.end(), name);
    EXPECT_NE(it, image.channelNames.end()) << name;
    return int(it - image.channelNames.begin());
  };
  auto compositePart = [](const fs::path& file) {
    for (Part& p : readParts(file))
      if (p.name == "composite") return p;
    ADD_FAILURE() << "no composite part in " << file;
    return Part{};
  };
  const Part expected = compositePart(dir_ / "out" / "base.exr");

  // Padded to the frame, the padding zero.
  const fs::path padded = save("padded", [](std::vector<Saved>& parts) {
    Saved& o = parts[0];
    Image full(o.fullWidth, o.fullHeight, o.image.channels, o.image.channelNames);
    for (int y = 0; y < o.image.height; ++y)
      for (int x = 0; x < o.image.width; ++x)
        std::copy_n(o.image.at(x, y), o.image.channels, full.at(o.x + x, o.y + y));
    o.image = std::move(full);
    o.x = o.y = 0;
  });
  const RunResult fromPadded = composite(padded, "padded");
  ASSERT_EQ(fromPadded.status, 0) << fromPadded.err;
  EXPECT_NE(fromPadded.err.find("read as the file holds it"), std::string::npos) << fromPadded.err;
  const Part paddedPart = compositePart(dir_ / "out" / "padded.exr");
  EXPECT_EQ(paddedPart.pixels, expected.pixels) << "the padding changed the composite";

  // The colours in linear Rec. 709, the part's chromaticities Rec. 709's.
  const fs::path rec709 = save("rec709", [&](std::vector<Saved>& parts) {
    Saved& o = parts[0];
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    for (const char* name : {"object", "albedo", "irradiance", "irradianceShadowed"}) {
      const std::string prefix = name + std::string(".");
      const int r = channel(o.image, prefix + "R"), g = channel(o.image, prefix + "G"),
                b = channel(o.image, prefix + "B");
      Image rgb(o.image.width, o.image.height, 3);
      for (size_t i = 0; i < o.image.pixelCount(); ++i)
        for (int c = 0; c < 3; ++c)
          rgb.pixels[3 * i + size_t(c)] =
              o.image.pixels[i * size_t(o.image.channels) + size_t(c == 0   ? r
                                                                   : c == 1 ? g
                                                                            : b)];
      rgb.colorSpace = "ACEScg";
      colors.convert(rgb, "Linear Rec.709 (sRGB)");
      for (size_t i = 0; i < o.image.pixelCount(); ++i)
        for (int c = 0; c < 3; ++c)
          o.image.pixels[i * size_t(o.image.channels) + size_t(c == 0   ? r
                                                               : c == 1 ? g
                                                                        : b)] =
              rgb.pixels[3 * i + size_t(c)];
    }
    // OpenEXR's chromaticities are shared by every part of a file.
    for (Saved& s : parts) s.chromaticities = color::kRec709Chromaticities;
  });
  const RunResult from709 = composite(rec709, "rec709");
  ASSERT_EQ(from709.status, 0) << from709.err;
  EXPECT_NE(from709.err.find("brought to the working space by matrix"), std::string::npos)
      << from709.err;
  const Part part709 = compositePart(dir_ / "out" / "rec709.exr");
  ASSERT_EQ(part709.pixels.size(), expected.pixels.size());
  double worst = 0.0;
  for (size_t i = 0; i < expected.pixels.size(); ++i)
    worst = std::max(worst, double(std::abs(part709.pixels[i] - expected.pixels[i])));
  EXPECT_LT(worst, 1e-5) << "taken as ACEScg, the object's colour was up to 8 % off";

  // Values no render holds.
  struct Bad {
    const char* name;
    int part;
    const char* channel;
    float value;
    const char* message;
  };
  for (const Bad& bad : {Bad{"nan", 0, "object.R", std::nanf(""), "NaN in channel object.R"},
                         Bad{"alpha", 0, "object.A", 3.0f, "alpha 3 in channel object.A"},
                         Bad{"ratio", 1, "shadow.G", -2.0f, "ratio -2 in channel shadow.G"}}) {
    SCOPED_TRACE(bad.name);
    int atX = 0, atY = 0;
    const fs::path file = save(bad.name, [&](std::vector<Saved>& parts) {
      Saved& s = parts[size_t(bad.part)];
      const int x = s.image.width / 2, y = s.image.height / 2;
      s.image.at(x, y)[channel(s.image, bad.channel)] = bad.value;
      atX = s.x + x;
      atY = s.y + y;
    });
    const RunResult r = composite(file, bad.name);
    EXPECT_EQ(r.status, 1) << r.err;
    EXPECT_NE(r.err.find(bad.message), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("at pixel (" + std::to_string(atX) + ", " + std::to_string(atY) + ")"),
              std::string::npos)
        << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "out" / (std::string(bad.name) + ".exr")));
  }
  // A header whose camera is not a placement (a singular matrix): refused (the composite's
  // worldToCamera and worldToNDC came out NaN in every part, exit 0).
  nlohmann::json forged = nlohmann::json::parse(header);
  forged["geometry"]["camera"]["worldFromCamera"] = std::vector<double>(16, 0.0);
  header = forged.dump();
  const RunResult singular = composite(save("singular", [](std::vector<Saved>&) {}), "singular");
  EXPECT_EQ(singular.status, 1) << singular.err;
  EXPECT_NE(singular.err.find("the layer's worldFromCamera is not a placement"), std::string::npos)
      << singular.err;
  EXPECT_FALSE(fs::exists(dir_ / "out" / "singular.exr"));
}

// Parallax stage by stage: compose precompute given --room and the object's placement sees the
// environment from the object's centre, as the one-shot command does, and the chained stages give
// the one-shot command's files bit for bit (precompute took no --room, and a render from a lighting
// file lit the object as from the capture point); the lighting differs from the distant one. A
// render that places the object elsewhere than the lighting file did is told, with the distance;
// precompute with parallax and no placement, or a placement without parallax, is refused (exit 2).
TEST_F(StageCommands, ParallaxChainedByHandGivesTheOneShotFilesBitForBit) {
  const std::string env = " --env " + quote(smallEnvironment());
  const std::string lighting = std::string(" --lighting-params order=4") + kQuickShadows;
  const std::string room = " --room 8,4,40 --capture-at 2,1.5,-3";
  const std::string placed = " --plate " + quote(plate_) + " " + objectOptions();
  // Every run shares a cache: the renders after the first reuse its visibility pass (the
  // lighting file's lighting is keyed by the file, and the render made from it again).
  const std::string cache = " --cache " + quote(dir_ / "cache");
  const RunResult one = run(
      "-q" + placed + env + room + lighting + " --out " + quote(dir_ / "one" / "compose") + cache,
      dir_.path());
  ASSERT_EQ(one.status, 0) << one.err;

  const fs::path light = dir_ / "room.lighting", layer = dir_ / "monkey.exr";
  // The placement options render takes, less its shading ones (--samples).
  std::string placement = placed;
  placement.erase(placement.find(" --samples 2"), std::string(" --samples 2").size());
  const RunResult pre =
      run("precompute" + env + room + lighting + placement + " --out " + quote(light) + cache,
          dir_.path());
  ASSERT_EQ(pre.status, 0) << pre.err;
  EXPECT_NE(pre.err.find("parallax: the environment as seen from the object's centre"),
            std::string::npos)
      << pre.err;
  // --explain says so too (it said only "project the environment onto the lighting basis").
  const RunResult plan = run("precompute --explain" + env + room + lighting + placement +
                                 " --out " + quote(dir_ / "plan.lighting") + " --no-cache",
                             dir_.path());
  ASSERT_EQ(plan.status, 0) << plan.err;
  EXPECT_NE(plan.out.find("precompute run     project the environment as seen from the object's "
                          "centre (parallax: room 8 x 4 x 40 m, captured at (2, 1.5, -3))"),
            std::string::npos)
      << plan.out;
  EXPECT_FALSE(fs::exists(dir_ / "plan.lighting"));
  const RunResult ren =
      run("render" + placed + " --lighting-file " + quote(light) + " --out " + quote(layer) + cache,
          dir_.path());
  ASSERT_EQ(ren.status, 0) << ren.err;
  EXPECT_EQ(ren.err.find("warning: the lighting file sees the environment"), std::string::npos)
      << ren.err;
  const RunResult comp = run("-q composite --plate " + quote(plate_) + " --layer " + quote(layer) +
                                 " --out " + quote(dir_ / "two" / "compose") + cache,
                             dir_.path());
  ASSERT_EQ(comp.status, 0) << comp.err;
  const std::vector<Part> a = readParts(dir_ / "one" / "compose.exr");
  ASSERT_EQ(a.size(), 3u);  // composite, object, shadow
  expectSameParts(a, readParts(dir_ / "two" / "compose.exr"));

  // The same stages without parallax light the object otherwise.
  const fs::path distant = dir_ / "distant.lighting", distantLayer = dir_ / "distant.exr";
  ASSERT_EQ(run("-q precompute" + env + lighting + " --out " + quote(distant) + cache, dir_.path())
                .status,
            0);
  ASSERT_EQ(run("-q render" + placed + " --lighting-file " + quote(distant) + " --out " +
                    quote(distantLayer) + cache,
                dir_.path())
                .status,
            0);
  const std::vector<Part> near = readParts(layer), far = readParts(distantLayer);
  ASSERT_FALSE(near.empty());
  ASSERT_EQ(near[0].pixels.size(), far[0].pixels.size());
  const auto red = std::find(near[0].channels.begin(), near[0].channels.end(), "object.R");
  ASSERT_NE(red, near[0].channels.end());
  double differs = 0.0, total = 0.0;
  for (size_t k = size_t(red - near[0].channels.begin()); k < near[0].pixels.size();
       k += near[0].channels.size()) {
    differs += std::abs(near[0].pixels[k] - far[0].pixels[k]);
    total += std::abs(far[0].pixels[k]);
  }
  EXPECT_GT(differs, 0.01 * total) << "parallax changed the object's light by less than 1 %";

  // Moved: the render says the lighting file's point is not where the object stands.
  const RunResult moved = run("render" + placed + " --place 0.3,0.8 --lighting-file " +
                                  quote(light) + " --out " + quote(dir_ / "moved.exr") + cache,
                              dir_.path());
  ASSERT_EQ(moved.status, 0) << moved.err;
  EXPECT_NE(moved.err.find("warning: the lighting file sees the environment (room 8 x 4 x 40 m"),
            std::string::npos)
      << moved.err;
  EXPECT_NE(moved.err.find("precompute again with this placement"), std::string::npos) << moved.err;

  // A lighting file whose record of the point is damaged is refused, naming it, and no layer is
  // written.
  {
    const fs::path damaged = dir_ / "damaged.lighting";
    pipeline::StageCache made = pipeline::StageCache::atFile(light, "precompute");
    ASSERT_TRUE(made.open());
    pipeline::StageCache forged = pipeline::StageCache::atFile(damaged, "precompute");
    for (const char* name : {"lighting", "shadowBasis", "sources"})
      forged.put(name, made.get(name));
    forged.meta() = made.meta();
    ASSERT_TRUE(forged.meta().contains("parallax"));
    forged.meta()["parallax"]["seenFrom"][1] = "high";
    ASSERT_TRUE(forged.write());
    const RunResult r = run("render" + placed + " --lighting-file " + quote(damaged) + " --out " +
                                quote(dir_ / "damaged.exr") + cache,
                            dir_.path());
    EXPECT_EQ(r.status, 1) << r.err;
    EXPECT_NE(r.err.find("the lighting file's parallax (where it sees the environment from) is "
                         "damaged"),
              std::string::npos)
        << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "damaged.exr"));
  }

  // Parallax needs the placement; a placement means nothing without parallax.
  const RunResult bare =
      run("precompute" + env + room + " --out " + quote(dir_ / "x.lighting"), dir_.path());
  EXPECT_EQ(bare.status, 2) << bare.err;
  EXPECT_NE(bare.err.find("--room: with parallax the environment is seen from the object's "
                          "centre; give the plate and the object"),
            std::string::npos)
      << bare.err;
  const RunResult sphere = run("precompute" + env + " --env-radius 12 --plate " + quote(plate_) +
                                   " --out " + quote(dir_ / "x.lighting"),
                               dir_.path());
  EXPECT_EQ(sphere.status, 2) << sphere.err;
  EXPECT_NE(sphere.err.find("--env-radius: with parallax the environment is seen from the "
                            "object's centre"),
            std::string::npos)
      << sphere.err;
  const RunResult unplaced =
      run("precompute" + env + " --object " + quote(samples_ / "monkey.obj") + " --out " +
              quote(dir_ / "x.lighting"),
          dir_.path());
  EXPECT_EQ(unplaced.status, 2) << unplaced.err;
  EXPECT_NE(unplaced.err.find("--object places the object for parallax (--room or --env-radius)"),
            std::string::npos)
      << unplaced.err;
  EXPECT_FALSE(fs::exists(dir_ / "x.lighting"));
}

// precompute never replaces its environment, refuses options that would change nothing in its
// file and bases it cannot keep (exit 2); a lighting file or an object layer made under another
// colour config ($OCIO, another working space) is refused naming the file, not read as this run's
// numbers.
TEST_F(StageCommands, FilesOfOneConfigAreNotReadInAnother) {
  const fs::path env = dir_ / "env.exr";
  fs::copy_file(samples_ / "forest.exr", env);
  const std::string before = slurp(env);
  // The environment under an image's name is refused as a lighting file's name (exit 2); by
  // another name (a link to it), as the input it is.
  RunResult r =
      run("precompute --env " + quote(env) + " --out " + quote(env) + " --no-cache", dir_.path());
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("a lighting file is not an image"), std::string::npos) << r.err;
  fs::create_symlink(env, dir_ / "env.lighting");
  r = run(
      "precompute --env " + quote(env) + " --out " + quote(dir_ / "env.lighting") + " --no-cache",
      dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("the output would replace an input"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(env), before) << "the environment was overwritten";
  for (const std::string option : {"--shadows off", "--no-shadow", "--lighting sh"}) {
    r = run(
        "precompute --env " + quote(env) + " --out " + quote(dir_ / "x.lighting") + " " + option,
        dir_.path());
    EXPECT_EQ(r.status, 2) << option << "\n" << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "x.lighting")) << option;
  }

  const fs::path blender = samples_ / "ocio" / "blender" / "config.ocio";
  ASSERT_TRUE(fs::exists(blender)) << blender;
  const fs::path lighting = dir_ / "forest.lighting";
  // Lower orders than the defaults, and renders without self-shadowing, keep it quick: what is
  // checked is which config the files were made in.
  r = run("precompute --env " + quote(env) + " --out " + quote(lighting) +
              " --no-cache --lighting-params order=4 --shadow-params order=8,grid=8",
          dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string render = "render --plate " + quote(plate_) + " " + objectOptions() +
                             " --shadows off --no-cache --lighting-file " + quote(lighting) +
                             " --out ";
  r = run(render + quote(dir_ / "layer.exr"), dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  ::setenv("OCIO", blender.c_str(), 1);
  r = run(render + quote(dir_ / "other.exr"), dir_.path());
  const RunResult composite = run("composite --no-cache --plate " + quote(plate_) + " --layer " +
                                      quote(dir_ / "layer.exr") + " --out " + quote(dir_ / "final"),
                                  dir_.path());
  ::unsetenv("OCIO");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("the lighting file was made in the working space 'ACEScg'"),
            std::string::npos)
      << r.err;
  EXPECT_NE(r.err.find("forest.lighting"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "other.exr"));
  EXPECT_EQ(composite.status, 1);
  EXPECT_NE(composite.err.find("the object layer was rendered in the working space 'ACEScg'"),
            std::string::npos)
      << composite.err;
  EXPECT_NE(composite.err.find("layer.exr"), std::string::npos) << composite.err;
  EXPECT_FALSE(fs::exists(dir_ / "final.exr"));

  // --ocio names the config as $OCIO does, and wins over it; 'builtin' is the built-in one.
  r = run(render + quote(dir_ / "other.exr") + " --ocio " + quote(blender), dir_.path());
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("the lighting file was made in the working space 'ACEScg'"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "other.exr"));
  ::setenv("OCIO", blender.c_str(), 1);
  r = run(render + quote(dir_ / "other.exr") + " --ocio builtin", dir_.path());
  ::unsetenv("OCIO");
  EXPECT_EQ(r.status, 0) << r.err;
  r = run(render + quote(dir_ / "third.exr") + " --ocio " + quote(dir_ / "missing.ocio"),
          dir_.path());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("OpenColorIO config not found (named by --ocio)"), std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "third.exr"));

  // A scene saved with --ocio names the config (color.ocio), and runs under it: Filmic is a view
  // of Blender's config only.
  const fs::path scene = dir_ / "filmic.json";
  r = run("--ocio " + quote(blender) + " --plate " + quote(plate_) + " " + objectOptions() +
              " --env " + quote(env) +
              " --shadows off --lighting-params order=4 --view Filmic --save-scene " + quote(scene),
          dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(slurp(scene).find("config.ocio"), std::string::npos) << slurp(scene);
  r = run("-q run " + quote(scene) + " --no-cache --set output.out=" + quote(dir_ / "filmic"),
          dir_.path());
  EXPECT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir_ / "filmic.jpg"));
  // The command line's --ocio wins over the scene's.
  r = run("-q --ocio builtin run " + quote(scene) +
              " --no-cache --set output.out=" + quote(dir_ / "filmic2"),
          dir_.path());
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("unknown view 'Filmic'"), std::string::npos) << r.err;
}

// compose cache shows what the caches hold and removes old entries, never the samples or the
// stored camera responses that share the default folder.
TEST_F(StageCommands, TheCacheCommandRemovesOldEntriesOnly) {
  const fs::path cache = dir_ / "cache";
  RunResult r = run("precompute --env " + quote(samples_ / "forest.exr") + " --out " +
                        quote(dir_ / "f.lighting") + " --cache " + quote(cache),
                    dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  fs::create_directories(cache / "samples");
  fs::create_directories(cache / "responses");
  compose::testing::writeText(cache / "samples" / "forest.exr", "not an entry");
  compose::testing::writeText(cache / "responses" / "camera.json", "not an entry");
  r = run("cache --cache " + quote(cache), dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("stages/precompute"), std::string::npos) << r.out;
  // Every entry written 40 days ago, but one.
  std::vector<fs::path> entries;
  for (const auto& e : fs::recursive_directory_iterator(cache / "stages"))
    if (e.is_regular_file()) entries.push_back(e.path());
  ASSERT_FALSE(entries.empty());
  const auto old = fs::file_time_type::clock::now() - std::chrono::hours(24 * 40);
  for (const fs::path& e : entries) fs::last_write_time(e, old);
  fs::last_write_time(cache / "samples" / "forest.exr", old);
  compose::testing::writeText(
      cache / "stages" / "precompute" / "0123456789abcdef0123456789abcdef.stage", "x");
  r = run("cache --cache " + quote(cache) + " --older-than 30 --dry-run", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  for (const fs::path& e : entries) EXPECT_TRUE(fs::exists(e)) << "--dry-run removed " << e;
  r = run("cache --cache " + quote(cache) + " --older-than 30", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  for (const fs::path& e : entries) EXPECT_FALSE(fs::exists(e)) << e;
  EXPECT_TRUE(
      fs::exists(cache / "stages" / "precompute" / "0123456789abcdef0123456789abcdef.stage"));
  EXPECT_TRUE(fs::exists(cache / "samples" / "forest.exr"));
  EXPECT_TRUE(fs::exists(cache / "responses" / "camera.json"));
  // A size beyond any disk keeps every entry (it once overflowed to almost nothing); units in
  // any case, decimal or binary.
  for (const char* size : {"99999999999999999999G", "18446744073709551616", "5g", "2GiB"}) {
    r = run("cache --cache " + quote(cache) + " --max-size " + size, dir_.path());
    ASSERT_EQ(r.status, 0) << size << ": " << r.err;
    EXPECT_TRUE(
        fs::exists(cache / "stages" / "precompute" / "0123456789abcdef0123456789abcdef.stage"))
        << size;
  }
  // A file of the user's in those folders is not an entry: kept. Nor is a temporary a running
  // job is writing (this test's process stands for it): it was listed as an entry and removed,
  // and that job lost its entry.
  compose::testing::writeText(cache / "stages" / "precompute" / "notes.txt", "mine");
  const fs::path writing =
      cache / "stages" / "precompute" /
      ("0123456789abcdef0123456789abcdee.stage.partial-" + std::to_string(::getpid()) + "-0");
  compose::testing::writeText(writing, "being written");
  fs::last_write_time(writing, old);
  // One left by a run that was killed (no such process, written long ago): not an entry (it was
  // listed as one), said as a leftover and removed by pruning.
  const fs::path left = cache / "stages" / "precompute" /
                        "0123456789abcdef0123456789abcded.stage.partial-2147483646-0";
  compose::testing::writeText(left, "");
  fs::last_write_time(left, old);
  r = run("cache --cache " + quote(cache), dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("(1 unfinished entry left by runs that stopped, 0.0 MB: compose cache "
                       "--max-size or --older-than removes them)"),
            std::string::npos)
      << r.out;
  EXPECT_TRUE(fs::exists(left));
  r = run("cache --cache " + quote(cache) + " --max-size 0", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(fs::exists(writing));
  EXPECT_FALSE(fs::exists(left));
  EXPECT_NE(r.out.find("(1 entry being written by running jobs, or left within the last minute "
                       "by one that stopped: not counted, not removed)"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("left by runs that stopped, 0.0 MB: removed)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("removed 1 entries"), std::string::npos) << r.out;
  EXPECT_TRUE(fs::exists(cache / "stages" / "precompute" / "notes.txt"));
  EXPECT_FALSE(
      fs::exists(cache / "stages" / "precompute" / "0123456789abcdef0123456789abcdef.stage"));
  EXPECT_TRUE(fs::exists(cache / "samples" / "forest.exr"));
  r = run("cache --cache " + quote(cache) + " --max-size lots", dir_.path());
  EXPECT_EQ(r.status, 2) << r.err;
  // A folder of the cache moved to another disk and linked back, as runs use it: listed and
  // pruned there (it was skipped: "0 entries", and could never be trimmed).
  compose::testing::writeText(
      cache / "stages" / "precompute" / "0123456789abcdef0123456789abcdef.stage", "x");
  fs::rename(cache / "stages", dir_ / "elsewhere");
  fs::create_directory_symlink(dir_ / "elsewhere", cache / "stages");
  r = run("cache --cache " + quote(cache) + " --max-size 0", dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("(stages is a link to "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("  stages/precompute "), std::string::npos) << r.out;
  EXPECT_FALSE(
      fs::exists(dir_ / "elsewhere" / "precompute" / "0123456789abcdef0123456789abcdef.stage"));
  EXPECT_TRUE(fs::exists(dir_ / "elsewhere" / "precompute" / "notes.txt"));
}

// compose bench times a job cold and warm in a folder of its own under $TMPDIR, removed after;
// the folder an interrupted bench left (its process gone) is removed by the next one (they
// stayed, hundreds of megabytes each), but a folder of the same name that no bench made stays
// (any was removed, a user's own files with it); a $TMPDIR that is not a folder is named.
TEST_F(StageCommands, BenchTimesAJobAndCleansUpAfterItself) {
  const fs::path tmp = dir_ / "tmp";
  // A process id that no process has now: a child that has exited and been waited for.
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  ASSERT_GT(child, 0);
  ::waitpid(child, nullptr, 0);
  const fs::path stale = tmp / ("compose-bench-" + std::to_string(child));
  fs::create_directories(stale / "cache");
  compose::testing::writeText(stale / "cache" / "x", "left");
  compose::testing::writeText(stale / ".compose-bench", "");
  const fs::path users = tmp / ("compose-bench-" + std::to_string(child) + "0");
  fs::create_directories(users);
  compose::testing::writeText(users / "results.csv", "mine");
  const std::string compose = quote(COMPOSE_EXECUTABLE);
  const std::string job = " bench --plate " + quote(plate_) + " " + objectOptions() + " --env " +
                          quote(samples_ / "forest.exr") +
                          " --shadows off --lighting-params order=2 --repeat 1";
  auto shell = [&](const std::string& env, const std::string& command) {
    const int raw = std::system((env + " " + command + " >" + quote(dir_ / "out.txt") + " 2>" +
                                 quote(dir_ / "err.txt") + " </dev/null")
                                    .c_str());
    return std::pair(WIFEXITED(raw) ? WEXITSTATUS(raw) : -1,
                     slurp(dir_ / "out.txt") + slurp(dir_ / "err.txt"));
  };
  auto [status, text] = shell("TMPDIR=" + quote(tmp), compose + job);
  ASSERT_EQ(status, 0) << text;
  EXPECT_NE(text.find("render"), std::string::npos) << text;
  EXPECT_FALSE(fs::exists(stale)) << "the interrupted bench's folder";
  EXPECT_EQ(slurp(users / "results.csv"), "mine") << "a folder no bench made";
  fs::remove_all(users);
  EXPECT_TRUE(fs::is_empty(tmp)) << "the bench's own folder";
  std::tie(status, text) = shell("TMPDIR=" + quote(dir_ / "none"), compose + job);
  EXPECT_EQ(status, 1) << text;
  EXPECT_NE(text.find("no folder for its temporary files (TMPDIR=" + (dir_ / "none").string()),
            std::string::npos)
      << text;
}

// Bare file names, as one types them in the folder one works in: written there.
TEST_F(StageCommands, BareFileNamesAreWrittenInTheWorkingFolder) {
  const fs::path work = dir_ / "work";
  fs::create_directories(work);
  const std::string cd = "cd " + quote(work) + " && ";
  const std::string compose = quote(COMPOSE_EXECUTABLE);
  auto shell = [&](const std::string& command) {
    const int raw = std::system(
        (cd + command + " >/dev/null 2>" + quote(dir_ / "err.txt") + " </dev/null").c_str());
    return std::pair(WIFEXITED(raw) ? WEXITSTATUS(raw) : -1, slurp(dir_ / "err.txt"));
  };
  auto [status, err] = shell(compose + " -q precompute --env " + quote(samples_ / "forest.exr") +
                             " --lighting-params order=4 --out l.stage --no-cache");
  ASSERT_EQ(status, 0) << err;
  EXPECT_TRUE(fs::is_regular_file(work / "l.stage"));
  std::tie(status, err) =
      shell(compose + " -q render --plate " + quote(plate_) + " " + objectOptions() +
            " --shadows off --no-shadow" + " --lighting-file l.stage --out layer.exr --no-cache");
  ASSERT_EQ(status, 0) << err;
  EXPECT_TRUE(fs::is_regular_file(work / "layer.exr"));
  std::tie(status, err) = shell(compose + " -q composite --plate " + quote(plate_) +
                                " --layer layer.exr --out c --no-cache");
  ASSERT_EQ(status, 0) << err;
  EXPECT_TRUE(fs::is_regular_file(work / "c.exr"));
  EXPECT_TRUE(fs::is_regular_file(work / "c.jpg"));
  // A scene file too (its paths are then relative to the working folder).
  std::tie(status, err) = shell(compose + " -q --plate " + quote(plate_) + " " + objectOptions() +
                                " --save-scene s.json");
  ASSERT_EQ(status, 0) << err;
  EXPECT_TRUE(fs::is_regular_file(work / "s.json"));
}

TEST_F(StageCommands, ExplainSaysWhatEachCommandRuns) {
  const RunResult r = run("precompute --explain --env " + quote(samples_ / "forest.exr") +
                              " --out " + quote(dir_ / "l.lighting") + " --no-cache",
                          dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.out.find("precompute run"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("render     skipped not needed"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("merge      skipped the environment is an image"), std::string::npos)
      << r.out;
  // Ingest names what it will read (it said "the plate, the object, and the environment (an
  // image, cube faces, or a capture description of photos)" whatever the job read).
  EXPECT_NE(r.out.find("ingest     run     read the environment forest.exr (one image)\n"),
            std::string::npos)
      << r.out;
  EXPECT_FALSE(fs::exists(dir_ / "l.lighting"));
  // The one-shot command's --explain reads the mesh and writes nothing, not even to the cache.
  const fs::path cache = dir_ / "explain-cache";
  const RunResult one =
      run("--explain --plate " + quote(plate_) + " " + objectOptions() + " --cache " + quote(cache),
          dir_.path());
  ASSERT_EQ(one.status, 0) << one.err;
  EXPECT_TRUE(!fs::exists(cache) || fs::is_empty(cache)) << "--explain wrote into the cache";
  EXPECT_NE(one.out.find("ingest     run     read the plate plate.jpg, the object monkey.obj ("),
            std::string::npos)
      << one.out;
  EXPECT_NE(one.out.find(" triangles) and the environment forest.exr (one image)\n"),
            std::string::npos)
      << one.out;

  // A holdout of another size than the plate: --explain says so, as the run would (it approved
  // the job, which then failed when the plate was read).
  {
    Image mask(320, 210, 1, {"Y"});
    ingest::writeImage(dir_ / "short_mask.png", mask);
    const RunResult holdout =
        run("--explain --plate " + quote(plate_) + " " + objectOptions() + " --holdout " +
                quote(dir_ / "short_mask.png") + " --no-cache",
            dir_.path());
    EXPECT_EQ(holdout.status, 1) << holdout.err;
    EXPECT_NE(holdout.err.find("the holdout mask is 320x210, the plate 320x213"), std::string::npos)
        << holdout.err;
  }

  // Each command's own outputs are checked, not the one-shot's: a file named `out` in the working
  // folder (where the one-shot command writes out/compose.*) is no matter to precompute (its
  // --explain failed: "cannot write into the output folder: it is a file").
  const fs::path work = dir_ / "work";
  fs::create_directories(work);
  compose::testing::writeText(work / "out", "not a folder");
  const RunResult lighting = run("precompute --explain --env " + quote(samples_ / "forest.exr") +
                                     " --out l.lighting --no-cache",
                                 work);
  EXPECT_EQ(lighting.status, 0) << lighting.err;
  // An output that is an input is refused before any stage runs, with --explain too (render ran
  // its shadows and render first; --explain approved it).
  const fs::path exrPlate = dir_ / "plate.exr";
  {
    OIIO::ImageBuf plate(plate_.string());
    ASSERT_TRUE(plate.write(exrPlate.string()));
  }
  const RunResult made = run("precompute --env " + quote(samples_ / "forest.exr") + " --out " +
                                 quote(dir_ / "f.lighting") + " --no-cache",
                             dir_.path());
  ASSERT_EQ(made.status, 0) << made.err;
  for (const char* explain : {" --explain", ""}) {
    const RunResult render =
        run(std::string("render") + explain + " --plate " + quote(exrPlate) + " " +
                objectOptions() + " --lighting-file " + quote(dir_ / "f.lighting") + " --out " +
                quote(exrPlate) + " --no-cache",
            dir_.path());
    EXPECT_EQ(render.status, 1) << explain << render.err;
    EXPECT_NE(render.err.find("the output would replace an input"), std::string::npos)
        << render.err;
    EXPECT_EQ(render.err.find("compose: render "), std::string::npos)
        << "a stage ran: " << render.err;
  }
}

// A render reused from the cache names the mesh of the job in the files' headers, not the file
// it was first made from (a copy of the mesh moved elsewhere kept the old name, which another tool
// rebuilding the scene from the header then could not find).
TEST_F(StageCommands, AReusedRenderNamesTheMeshGiven) {
  fs::create_directories(dir_ / "moved");
  fs::copy_file(samples_ / "monkey.obj", dir_ / "first.obj");
  fs::copy_file(samples_ / "monkey.obj", dir_ / "moved" / "second.obj");
  auto compose = [&](const fs::path& mesh, const std::string& name) {
    return run("--plate " + quote(plate_) + " --object " + quote(mesh) + " --samples 1 --env " +
                   quote(samples_ / "forest.exr") + " --shadow-params order=4,grid=4 --out " +
                   quote(dir_ / name) + " --cache " + quote(dir_ / "cache"),
               dir_.path());
  };
  auto meshOf = [](const fs::path& exr) {
    auto in = OIIO::ImageInput::open(exr.string());
    return in ? std::string(in->spec().get_string_attribute("compose:object")) : std::string();
  };
  const RunResult first = compose(dir_ / "first.obj", "first");
  ASSERT_EQ(first.status, 0) << first.err;
  const RunResult second = compose(dir_ / "moved" / "second.obj", "second");
  ASSERT_EQ(second.status, 0) << second.err;
  const size_t render = second.err.find("compose: render ");
  ASSERT_NE(render, std::string::npos) << second.err;
  EXPECT_NE(second.err.substr(render, second.err.find('\n', render) - render).find("reused"),
            std::string::npos)
      << second.err;
  EXPECT_EQ(meshOf(dir_ / "first.exr"), fs::absolute(dir_ / "first.obj").string());
  EXPECT_EQ(meshOf(dir_ / "second.exr"), fs::absolute(dir_ / "moved" / "second.obj").string());
}

// compose --pose: the object stands on the chessboard's plane, seen from where the pose puts the
// camera. A pose written for a known camera; the object placed where the board's centre is seen.
TEST_F(StageCommands, APlatePoseStandsTheObjectOnTheBoardsPlane) {
  calib::PlatePose pose;
  pose.width = 320;
  pose.height = 213;
  pose.lens = calib::Lens::fromFieldOfView(320, 213, 60.0);
  pose.lens.source = "test lens";
  pose.board.columns = 9;
  pose.board.rows = 6;
  pose.board.square = 0.025;
  const glm::dvec3 eye(0.3, 0.6, 1.4);
  pose.worldFromCamera = glm::inverse(glm::lookAt(eye, glm::dvec3(0.0), glm::dvec3(0, 1, 0)));
  const fs::path poseFile = dir_ / "pose.json";
  calib::writePose(poseFile, pose);

  calib::CameraOptions options;
  options.lens = pose.lens;
  options.worldFromCamera = pose.worldFromCamera;
  const calib::PlateCamera camera = calib::plateCamera(320, 213, {}, options);
  glm::dvec2 pixel;
  ASSERT_TRUE(camera.project(glm::dvec3(0.0), pixel));
  char place[64];
  std::snprintf(place, sizeof place, "%.6f,%.6f", pixel.x / 320.0, pixel.y / 213.0);

  // A box whose base centre is its own origin: world-from-object then carries the ground point.
  compose::testing::writeText(dir_ / "box.obj",
                              "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv -1 2 -1\nv 1 2 -1\n"
                              "v 1 2 1\nv -1 2 1\nf 1 2 3 4\nf 5 8 7 6\nf 1 5 6 2\nf 2 6 7 3\n"
                              "f 3 7 8 4\nf 4 8 5 1\n");
  const RunResult r =
      run("-q --plate " + quote(plate_) + " --object " + quote(dir_ / "box.obj") + " --pose " +
              quote(poseFile) + " --place " + place + " --scale 0.2 --samples 1 --no-cache --out " +
              quote(dir_ / "posed" / "compose"),
          dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  auto in = OIIO::ImageInput::open((dir_ / "posed" / "compose.exr").string());
  ASSERT_TRUE(in);
  double m[16] = {};  // m44d: the translation of a mesh far from its origin needs double
  ASSERT_TRUE(
      in->spec().getattribute("compose:worldFromObject",
                              OIIO::TypeDesc(OIIO::TypeDesc::DOUBLE, OIIO::TypeDesc::MATRIX44), m));
  // Imath layout: the translation is the last row.
  EXPECT_NEAR(m[12], 0.0, 1e-3);
  EXPECT_NEAR(m[13], 0.0, 1e-6) << "the object's base is on the board's plane";
  EXPECT_NEAR(m[14], 0.0, 1e-3);
  float toCamera[16] = {};
  ASSERT_TRUE(in->spec().getattribute("worldToCamera", OIIO::TypeMatrix, toCamera));
  // The camera sits where the pose says: world-to-camera maps the eye to the origin.
  const glm::dvec3 e = eye;
  for (int row = 0; row < 3; ++row) {
    const double v = e.x * toCamera[0 + row] + e.y * toCamera[4 + row] + e.z * toCamera[8 + row] +
                     toCamera[12 + row];
    EXPECT_NEAR(v, 0.0, 1e-4) << row;
  }

  // --pose replaces the height and tilt: giving both is a usage error.
  const RunResult both = run("--plate " + quote(plate_) + " --object " + quote(dir_ / "box.obj") +
                                 " --pose " + quote(poseFile) + " --pitch 10",
                             dir_.path());
  EXPECT_EQ(both.status, 2) << both.err;
  // So does --focal35 with --pose (or --calib): the lens was the file's, and --focal35 silently
  // did nothing.
  const RunResult focal = run("--plate " + quote(plate_) + " --object " + quote(dir_ / "box.obj") +
                                  " --pose " + quote(poseFile) + " --focal35 24",
                              dir_.path());
  EXPECT_EQ(focal.status, 2) << focal.err;
  EXPECT_NE(focal.err.find("--pose gives the plate's lens: leave out --focal35"), std::string::npos)
      << focal.err;

  // A plate of another shape than the pose's: the error names the pose file the lens came from.
  Image square(100, 100, 3, {"R", "G", "B"});
  std::fill(square.pixels.begin(), square.pixels.end(), 0.4f);
  ingest::writeImage(dir_ / "square.png", square);
  const RunResult other = run("--plate " + quote(dir_ / "square.png") + " --object " +
                                  quote(dir_ / "box.obj") + " --pose " + quote(poseFile) +
                                  " --no-cache --out " + quote(dir_ / "other" / "compose"),
                              dir_.path());
  EXPECT_EQ(other.status, 1) << other.err;
  EXPECT_NE(other.err.find("camera: the calibration is for 320x213 images, the plate is 100x100"),
            std::string::npos)
      << other.err;
  EXPECT_NE(other.err.find(poseFile.string()), std::string::npos) << other.err;

  // A pose whose own plate is of another shape than this plate (its lens of this one's): another
  // framing. It was taken without a word.
  calib::PlatePose tall = pose;
  tall.width = 320;
  tall.height = 999;
  calib::writePose(dir_ / "tall.json", tall);
  const RunResult framing =
      run("--plate " + quote(plate_) + " --object " + quote(dir_ / "box.obj") + " --pose " +
              quote(dir_ / "tall.json") + " --place " + place + " --no-cache --out " +
              quote(dir_ / "tall" / "compose"),
          dir_.path());
  EXPECT_EQ(framing.status, 1) << framing.err;
  EXPECT_NE(framing.err.find("the pose was estimated on a 320x999 plate; this one is 320x213"),
            std::string::npos)
      << framing.err;
  EXPECT_FALSE(fs::exists(dir_ / "tall" / "compose.exr"));

  // Parallax with a pose: lengths are the pose's, metres for a board measured with --square,
  // squares for one that was not (a square of 1). The notes said metres for both.
  calib::PlatePose squares = pose;
  squares.board.square = 1.0;
  squares.worldFromCamera =
      glm::inverse(glm::lookAt(eye / 0.025, glm::dvec3(0.0), glm::dvec3(0, 1, 0)));
  calib::writePose(dir_ / "squares.json", squares);
  for (const auto& [file, room, unit] : std::vector<std::tuple<fs::path, std::string, std::string>>{
           {poseFile, " --room 2,1,2 --capture-at 0,0.3,0", "m"},
           {dir_ / "squares.json", " --room 80,40,80 --capture-at 0,12,0", "squares"}}) {
    const RunResult seen =
        run("--plate " + quote(plate_) + " --object " + quote(dir_ / "box.obj") + " --pose " +
                quote(file) + " --place " + place + " --scale 0.2 --samples 1 --shadows off" +
                " --env " + quote(smallEnvironment()) + room + " --no-cache --out " +
                quote(dir_ / ("parallax_" + unit) / "compose"),
            dir_.path());
    ASSERT_EQ(seen.status, 0) << seen.err;
    EXPECT_NE(seen.err.find(") " + unit + "; surroundings: room "), std::string::npos) << seen.err;
    const std::string size = unit == "m" ? "2 x 1 x 2 m" : "80 x 40 x 80 squares";
    EXPECT_NE(seen.err.find("surroundings: room " + size + ", captured at"), std::string::npos)
        << seen.err;
  }
}

// Zero is a value, not the default: calib pose took --square 0 and --focal35 0 as "not given".
TEST_F(StageCommands, CalibPoseRefusesSizesThatAreNot) {
  const std::string out = " --out " + quote(dir_ / "pose.json") + " " + quote(plate_);
  for (const auto& [args, message] : std::vector<std::pair<std::string, std::string>>{
           {"--square 0", "--square must be the side of one square in metres"},
           {"--square -0.02", "got -0.02"},
           {"--square 1e-20", "at least 1e-6 (a micrometre) and less than 1000; got 1e-20"},
           {"--focal35 0",
            "--focal35 must be a 35 mm equivalent focal length of 1 to 10000 mm, "
            "got 0"},
           {"--focal35 1e-300", "got 1e-300"}}) {
    const RunResult r = run("calib pose " + args + out, dir_.path());
    EXPECT_EQ(r.status, 2) << args << ": " << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << args << ": " << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "pose.json")) << args;
  }
}

}  // namespace
}  // namespace compose
