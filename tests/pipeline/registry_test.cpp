// The stage registry: a consistent graph, named errors, the skips a scene implies, the stage cache
// and scene files.
#include <chrono>
#include <fstream>
#include <map>
#include <set>
#include <thread>

#include <glm/gtc/matrix_transform.hpp>

#include "core/channels.h"
#include "core/error.h"
#include "ingest/image_io.h"
#include "pipeline/compose_job.h"
#include "pipeline/scene.h"
#include "pipeline/stage.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_util.h"
#include "pipeline/stages.h"
#include "test_util.h"

namespace compose::pipeline {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;
using compose::testing::writeText;

// An image made RGB by its channels' names: R, G, B wherever they are, a layer's too; grey from Y;
// OpenEXR's luminance-chroma (Y, RY, BY) turned back into RGB (it was read as R, G, B).
TEST(ToRgb, TakesTheChannelsByName) {
  auto values = [](const Image& image) {
    return std::vector<float>(image.pixels.begin(), image.pixels.end());
  };
  Image bgr(1, 1, 4, {"B", "A", "G", "R"});
  bgr.pixels = {0.3f, 1.0f, 0.2f, 0.1f};
  EXPECT_EQ(values(toRgb(bgr)), (std::vector<float>{0.1f, 0.2f, 0.3f}));
  Image layer(1, 1, 3, {"beauty.R", "beauty.G", "beauty.B"});
  layer.pixels = {0.1f, 0.2f, 0.3f};
  EXPECT_EQ(values(toRgb(layer)), values(layer));
  Image grey(1, 1, 2, {"A", "Y"});
  grey.pixels = {1.0f, 0.4f};
  EXPECT_EQ(values(toRgb(grey)), (std::vector<float>{0.4f, 0.4f, 0.4f}));
  // R, G, B = 0.5, 0.25, 2: Y by Rec. 709's weights, RY = (R - Y) / Y, BY = (B - Y) / Y.
  const float r = 0.5f, g = 0.25f, b = 2.0f;
  const float y = 0.2126f * r + 0.7152f * g + 0.0722f * b;
  Image yc(1, 1, 3, {"BY", "RY", "Y"});
  yc.pixels = {(b - y) / y, (r - y) / y, y};
  const Image back = toRgb(yc);
  EXPECT_NEAR(back.pixels[0], r, 1e-5f);
  EXPECT_NEAR(back.pixels[1], g, 1e-5f);
  EXPECT_NEAR(back.pixels[2], b, 1e-5f);
  Image unnamed(1, 1, 3);
  unnamed.pixels = {0.1f, 0.2f, 0.3f};
  EXPECT_EQ(values(toRgb(unnamed)), values(unnamed));
}

// A holdout mask is the matte a compositor makes: its alpha when it has one (an element's alpha
// over black colour was read by its R: no holdout at all), unless the alpha is opaque everywhere
// (a painted mask saved with an alpha it does not use), else its first colour channel.
TEST(Holdout, TheAlphaIsTheMatteUnlessItIsOpaque) {
  TempDir dir;
  Image rgba(2, 1, 4, {"R", "G", "B", "A"});
  rgba.pixels = {0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, 0.0f};
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;
  options.alphaChannel = 3;
  ingest::writeImage(dir / "element.exr", rgba, options);
  std::string how;
  const Image fromAlpha = loadHoldout(dir / "element.exr", 2, 1, &how);
  ASSERT_EQ(fromAlpha.channels, 1);
  EXPECT_EQ(fromAlpha.pixels[0], 1.0f);
  EXPECT_EQ(fromAlpha.pixels[1], 0.0f);
  EXPECT_NE(how.find("channel A (its alpha)"), std::string::npos) << how;
  // A PNG's channels come R, G, B, A (an EXR's sorted A, B, G, R): its black R was the matte.
  ingest::WriteOptions png;
  png.alphaChannel = 3;
  png.attributes.push_back({"oiio:UnassociatedAlpha", 1});
  ingest::writeImage(dir / "element.png", rgba, png);
  const Image fromPng = loadHoldout(dir / "element.png", 2, 1);
  EXPECT_EQ(fromPng.pixels[0], 1.0f);
  EXPECT_EQ(fromPng.pixels[1], 0.0f);
  rgba.pixels = {0.25f, 0.0f, 0.0f, 1.0f, 0.75f, 0.0f, 0.0f, 1.0f};
  ingest::writeImage(dir / "painted.exr", rgba, options);
  const Image fromRed = loadHoldout(dir / "painted.exr", 2, 1, &how);
  EXPECT_EQ(fromRed.pixels[0], 0.25f);
  EXPECT_EQ(fromRed.pixels[1], 0.75f);
  EXPECT_NE(how.find("channel R (its alpha is opaque everywhere)"), std::string::npos) << how;
  // Only the matte must be finite: a depth channel beside it may be infinite where nothing is
  // (the mask was refused for it), colour that is NaN where alpha is 0 too.
  Image withDepth(2, 1, 5, {"R", "G", "B", "A", "Z"});
  const float inf = std::numeric_limits<float>::infinity();
  withDepth.pixels = {0.0f, 0.0f, 0.0f, 1.0f, 2.0f, std::nanf(""), 0.0f, 0.0f, 0.0f, inf};
  ingest::writeImage(dir / "depth.exr", withDepth, options);
  const Image fromDepth = loadHoldout(dir / "depth.exr", 2, 1);
  EXPECT_EQ(fromDepth.pixels[0], 1.0f);
  EXPECT_EQ(fromDepth.pixels[1], 0.0f);
  withDepth.pixels[3] = std::nanf("");
  ingest::writeImage(dir / "bad.exr", withDepth, options);
  COMPOSE_EXPECT_ERROR(loadHoldout(dir / "bad.exr", 2, 1),
                       "NaN in the holdout mask's channel A at pixel (0, 0)");
  // A plate turned by its EXIF orientation: the sizes as shown and as stored are said.
  COMPOSE_EXPECT_ERROR(loadHoldout(dir / "depth.exr", 1, 2, nullptr, 6),
                       "the holdout mask is 2x1, the plate 1x2 as shown (its EXIF orientation 6; "
                       "stored 2x1): it must be the plate's size as shown: turn the mask upright");
}

// A layered image is read from the layer that is its picture, not from whichever sorts first: a
// render's beauty beside albedo and irradiance passes (OpenEXR sorts albedo first), bare R, G, B
// before any layer, a layer named as a beauty pass (Blender's Combined beside its AO), or the
// one layer with an alpha. With nothing to tell them apart the choice is marked ambiguous.
TEST(ToRgb, TakesTheLayerThatIsThePicture) {
  auto values = [](const Image& image) {
    return std::vector<float>(image.pixels.begin(), image.pixels.end());
  };
  Image render(
      1, 1, 8,
      {"AO.Y", "albedo.R", "albedo.G", "albedo.B", "object.A", "object.B", "object.G", "object.R"});
  render.pixels = {0.9f, 0.5f, 0.5f, 0.5f, 1.0f, 0.3f, 0.2f, 0.1f};
  EXPECT_EQ(values(toRgb(render)), (std::vector<float>{0.1f, 0.2f, 0.3f}));
  PictureChannels picture = pictureChannels(render);
  EXPECT_EQ(picture.layer, "object.");
  EXPECT_EQ(picture.alpha, 4);
  EXPECT_FALSE(picture.ambiguous);
  EXPECT_EQ(picture.otherLayers, (std::vector<std::string>{"albedo."}));

  Image blender(1, 1, 6,
                {"ViewLayer.AO.B", "ViewLayer.AO.G", "ViewLayer.AO.R", "ViewLayer.Combined.B",
                 "ViewLayer.Combined.G", "ViewLayer.Combined.R"});
  blender.pixels = {0.7f, 0.7f, 0.7f, 0.3f, 0.2f, 0.1f};
  EXPECT_EQ(values(toRgb(blender)), (std::vector<float>{0.1f, 0.2f, 0.3f}));

  Image bare(1, 1, 6, {"B", "G", "R", "diffuse.B", "diffuse.G", "diffuse.R"});
  bare.pixels = {0.3f, 0.2f, 0.1f, 0.7f, 0.7f, 0.7f};
  EXPECT_EQ(values(toRgb(bare)), (std::vector<float>{0.1f, 0.2f, 0.3f}));

  Image passes(1, 1, 6, {"albedo.B", "albedo.G", "albedo.R", "normal.B", "normal.G", "normal.R"});
  passes.pixels = {0.3f, 0.2f, 0.1f, 0.7f, 0.7f, 0.7f};
  picture = pictureChannels(passes);
  EXPECT_TRUE(picture.ambiguous);
  EXPECT_EQ(picture.layer, "albedo.");

  // Without names: by position, the fourth channel the alpha.
  Image unnamed(1, 1, 4);
  picture = pictureChannels(unnamed);
  EXPECT_EQ(picture.colour, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(picture.alpha, 3);
}

TEST(Registry, EveryInputIsMadeByAnEarlierStageAndEveryOutputByOne) {
  std::map<std::string, std::string> producer;
  std::set<std::string> names;
  for (const auto& stage : stages()) {
    EXPECT_TRUE(names.insert(stage->name()).second) << "two stages named " << stage->name();
    for (const std::string& in : stage->inputs())
      EXPECT_TRUE(producer.count(in))
          << stage->name() << " reads " << in << " that no earlier stage makes";
    for (const std::string& out : stage->outputs()) {
      for (const std::string& in : stage->inputsFor(out)) {
        const auto& all = stage->inputs();
        EXPECT_NE(std::find(all.begin(), all.end(), in), all.end())
            << stage->name() << ": " << out << " is made from " << in << ", not an input";
      }
      EXPECT_TRUE(producer.emplace(out, stage->name()).second)
          << out << " is made by both " << producer[out] << " and " << stage->name();
    }
  }
  EXPECT_EQ(producer["files"], stages().back()->name());
  for (const char* expected :
       {"ingest", "merge", "stitch", "color", "precompute", "render", "composite", "output"})
    EXPECT_TRUE(names.count(expected)) << expected;
}

TEST(Registry, AnUnknownStageIsAnErrorListingTheValidOnes) {
  try {
    findStage("rendr");
    FAIL() << "no error";
  } catch (const UsageError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("'rendr'"), std::string::npos) << what;
    for (const std::string& n : stageNames()) EXPECT_NE(what.find(n), std::string::npos) << n;
  }
  EXPECT_EQ(findStage("render").name(), "render");
}

TEST(Registry, AnOutputCodecOrQualityFromASceneIsCheckedBeforeAnythingRuns) {
  ComposeJob job;
  setParameter(job, "output.compression=dwab:60");
  EXPECT_NO_THROW(validate(job));
  for (const char* bad : {"output.compression=lzw", "output.compression=zip:12",
                          "output.compression=dwaa:0x2D", "output.compression=dwaa:1e-50"}) {
    ComposeJob j;
    setParameter(j, bad);
    try {
      validate(j);
      ADD_FAILURE() << bad << " was taken";
    } catch (const UsageError& e) {
      EXPECT_NE(std::string(e.what()).find("compression"), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW(setParameter(job, "output.jpeg-quality=0"), UsageError);
  EXPECT_THROW(setParameter(job, "output.jpeg-quality=101"), UsageError);
  setParameter(job, "output.jpeg-quality=70");
  EXPECT_EQ(job.jpegQuality, 70);
}

// A pair after --set is written as on the one-shot command line (--place 0.5,0.7) or as JSON.
TEST(Registry, APairIsTakenAsTheOneShotCommandWritesIt) {
  ComposeJob job;
  setParameter(job, "render.place=0.25,0.75");
  EXPECT_EQ(job.placement.imagePoint.x, 0.25);
  EXPECT_EQ(job.placement.imagePoint.y, 0.75);
  setParameter(job, "render.place=[0.5, 0.6]");
  EXPECT_EQ(job.placement.imagePoint.x, 0.5);
  EXPECT_EQ(job.placement.imagePoint.y, 0.6);
  for (const char* bad : {"render.place=0.5", "render.place=0.5,0.6,0.7", "render.place=a,b"}) {
    try {
      setParameter(job, bad);
      ADD_FAILURE() << bad << " was taken";
    } catch (const UsageError& e) {
      EXPECT_NE(std::string(e.what()).find("[X, Y] in a scene file, X,Y after --set"),
                std::string::npos)
          << e.what();
    }
  }
}

TEST(Registry, ParametersReadBackWhatTheySetAndRefuseTheWrongKind) {
  ComposeJob job;
  job.placement.heightFraction = 0.42;
  job.lighting = "sh";
  job.albedo = glm::vec3(0.2f, 0.3f, 0.4f);
  job.room = glm::dvec3(4, 3, 5);
  job.exposureStops = -1.5;
  job.groundShadow = false;
  job.exrCompression = "dwaa:30";
  job.jpegQuality = 80;
  const auto scene = sceneFromJob(job, "/nowhere");
  ComposeJob copy;
  applyScene(scene, "/nowhere", copy);
  EXPECT_EQ(sceneFromJob(copy, "/nowhere").dump(), scene.dump());
  // The default output (out/compose) is relative to where compose runs: not written, so that
  // `compose run` reads it so (it was written relative to the scene: ../out/compose); one given
  // is written.
  EXPECT_FALSE(scene["stages"].contains("output") && scene["stages"]["output"].contains("out"))
      << scene.dump();
  job.output = "/nowhere/renders/bunny";
  EXPECT_EQ(sceneFromJob(job, "/nowhere")["stages"]["output"]["out"], "renders/bunny");
  EXPECT_EQ(copy.placement.heightFraction, 0.42);
  EXPECT_EQ(copy.lighting, "sh");
  EXPECT_FALSE(copy.groundShadow);
  EXPECT_EQ(copy.exrCompression, "dwaa:30");
  EXPECT_EQ(copy.jpegQuality, 80);
  ASSERT_TRUE(copy.exposureStops);
  EXPECT_EQ(*copy.exposureStops, -1.5);

  for (const auto& stage : stages()) {
    for (const StageParameter& p : stage->parameters()) {
      ComposeJob j;
      // An object is the wrong kind for every parameter.
      EXPECT_THROW(p.set(j, nlohmann::json::object({{"x", 1}})), UsageError)
          << stage->name() << "." << p.name;
    }
  }
}

TEST(Registry, SceneParametersAreCheckedByName) {
  ComposeJob job;
  EXPECT_THROW(setParameter(job, "render.sclae=0.3"), UsageError);
  EXPECT_THROW(setParameter(job, "rendre.scale=0.3"), UsageError);
  EXPECT_THROW(setParameter(job, "render.scale"), UsageError);
  EXPECT_THROW(setParameter(job, "render.scale=\"big\""), UsageError);
  setParameter(job, "render.scale=0.25");
  EXPECT_EQ(job.placement.heightFraction, 0.25);
  setParameter(job, "precompute.lighting=cheb-global");  // not JSON: taken as a string
  EXPECT_EQ(job.lighting, "cheb-global");
  EXPECT_THROW(applyScene(nlohmann::json::parse(R"({"compose": "scene", "version": 99})"), {}, job),
               UsageError);
  EXPECT_THROW(applyScene(nlohmann::json::parse(R"({"stages": {}})"), {}, job), UsageError);
}

TEST(Registry, ScenePathsAreRelativeToTheSceneFile) {
  TempDir dir;
  fs::create_directories(dir / "scenes");
  writeText(dir / "scenes" / "s.json",
            R"({"compose": "scene", "version": 1,
                "stages": {"ingest": {"plate": "../plate.jpg", "object": "/abs/mesh.obj"},
                           "output": {"out": "out/x"}}})");
  const ComposeJob job = loadScene(dir / "scenes" / "s.json");
  EXPECT_EQ(job.plate, fs::absolute(dir / "plate.jpg").lexically_normal());
  EXPECT_EQ(job.object, fs::path("/abs/mesh.obj"));
  EXPECT_EQ(job.output, fs::absolute(dir / "scenes" / "out" / "x").lexically_normal());
  // The built-in colour config by either name the command line takes: not a file beside it.
  for (const std::string name : {"builtin", "built-in"}) {
    writeText(
        dir / "scenes" / "ocio.json",
        R"({"compose": "scene", "version": 1, "stages": {"color": {"ocio": ")" + name + R"("}}})");
    EXPECT_EQ(loadScene(dir / "scenes" / "ocio.json").ocio, fs::path(name));
  }
  // A key given twice is refused, naming it (the last one counted, without a word).
  writeText(dir / "scenes" / "twice.json",
            R"({"compose": "scene", "version": 1,
                "stages": {"ingest": {"plate": "../plate.jpg", "object": "/abs/mesh.obj"},
                           "render": {"scale": 0.2}, "render": {"samples": 1}}})");
  COMPOSE_EXPECT_ERROR(loadScene(dir / "scenes" / "twice.json"), "'stages.render' is given twice");
}

// A scene in a folder reached through a symbolic link (proj -> store/a/proj) names its inputs by
// the path that leads to them from its true folder, and is read back so: ".." follows the link,
// as the operating system takes it. It was worked out on the text of the paths: the scene saved
// through the link named ../in/plate.jpg, which from store/a/proj is store/a/in.
TEST(Registry, ScenePathsFollowSymbolicLinks) {
  TempDir dir;
  fs::create_directories(dir / "store" / "a" / "proj");
  fs::create_directories(dir / "in");
  writeText(dir / "in" / "plate.jpg", "a plate");
  fs::create_directory_symlink(dir / "store" / "a" / "proj", dir / "proj");
  ComposeJob job;
  job.plate = dir / "in" / "plate.jpg";
  for (const fs::path& savedIn : {dir / "proj", dir / "store" / "a" / "proj"}) {
    writeText(savedIn / "s.json", sceneFromJob(job, savedIn).dump(2));
    for (const fs::path& readFrom : {dir / "proj", dir / "store" / "a" / "proj"}) {
      const ComposeJob read = loadScene(readFrom / "s.json");
      EXPECT_TRUE(fs::exists(read.plate)) << read.plate << " saved in " << savedIn;
      if (fs::exists(read.plate)) {
        EXPECT_TRUE(fs::equivalent(read.plate, job.plate)) << read.plate;
      }
    }
  }
  // A file that is itself a link keeps its name (an OBJ's material library and textures are
  // found beside the name it was given, not beside its target).
  fs::create_symlink(dir / "in" / "plate.jpg", dir / "in" / "linked.jpg");
  job.plate = dir / "in" / "linked.jpg";
  writeText(dir / "proj" / "l.json", sceneFromJob(job, dir / "proj").dump(2));
  EXPECT_EQ(loadScene(dir / "proj" / "l.json").plate.filename(), "linked.jpg");
  // A file name that is not UTF-8 (Latin-1's café) cannot be written into JSON: the parameter
  // is named (the JSON library's exception was the message, naming nothing).
  job.plate = dir / "caf\xe9.jpg";
  COMPOSE_EXPECT_ERROR(sceneFromJob(job, dir / "proj"), "ingest.plate: ");
  COMPOSE_EXPECT_ERROR(sceneFromJob(job, dir / "proj"), "is not UTF-8 text");
}

// plan() over a job: each stage's state and reason, by name.
std::map<std::string, StageRecord> planned(const ComposeJob& job) {
  std::map<std::string, StageRecord> out;
  for (const StageRecord& r : plan(job, color::ColorConfig::builtin())) out[r.name] = r;
  return out;
}

class RegistrySkips : public ::testing::Test {
 protected:
  void SetUp() override {
    env_ = samplesDirectory() / "forest.exr";
    if (!fs::exists(env_)) GTEST_FAIL() << "sample data missing: run samples/fetch.sh";
    // plan() hashes the plate and reads its header (the camera), without decoding it.
    Image plate(64, 48, 3, {"R", "G", "B"});
    std::fill(plate.pixels.begin(), plate.pixels.end(), 0.5f);
    plate.colorSpace = "sRGB";
    ingest::writeImage(dir_ / "plate.jpg", plate);
    // A tetrahedron: closed and convex. A second one beside it: not convex as a whole.
    writeText(dir_ / "convex.obj",
              "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n");
    writeText(dir_ / "pair.obj",
              "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
              "v 3 0 0\nv 4 0 0\nv 3 1 0\nv 3 0 1\nf 5 7 6\nf 5 6 8\nf 5 8 7\nf 6 7 8\n");
    job_.plate = dir_ / "plate.jpg";
    job_.object = dir_ / "pair.obj";
    job_.environment = env_;
    job_.cache = dir_ / "cache";
  }
  TempDir dir_;
  fs::path env_;
  ComposeJob job_;
};

TEST_F(RegistrySkips, ALatLongMapNeedsNoMergeNorStitch) {
  auto p = planned(job_);
  EXPECT_EQ(p["merge"].state, StageState::Skipped);
  EXPECT_NE(p["merge"].reason.find("not photos"), std::string::npos) << p["merge"].reason;
  EXPECT_EQ(p["stitch"].state, StageState::Skipped);
  for (const char* s :
       {"ingest", "color", "precompute", "shadows", "ground", "render", "composite", "output"})
    EXPECT_EQ(p[s].state, StageState::Run) << s << ": " << p[s].reason;
}

TEST_F(RegistrySkips, ShadowsOffOrAConvexObjectNeedNoVisibilityPass) {
  ComposeJob off = job_;
  off.shadows = false;
  auto p = planned(off);
  EXPECT_EQ(p["shadows"].state, StageState::Skipped);
  EXPECT_EQ(p["shadows"].reason, "--shadows off");

  // A convex object cannot shadow itself, but the ground beneath it darkens its underside: the
  // pass runs (without rays to the object) unless that is off too.
  ComposeJob convex = job_;
  convex.object = dir_ / "convex.obj";
  p = planned(convex);
  EXPECT_EQ(p["shadows"].state, StageState::Run) << p["shadows"].reason;
  convex.shadowParams = "ground=off";
  p = planned(convex);
  EXPECT_EQ(p["shadows"].state, StageState::Skipped);
  EXPECT_NE(p["shadows"].reason.find("convex"), std::string::npos) << p["shadows"].reason;
  EXPECT_EQ(p["ground"].state, StageState::Run) << "a convex object still shadows the ground";
}

TEST_F(RegistrySkips, NoShadowNeedsNoGroundPass) {
  ComposeJob job = job_;
  job.groundShadow = false;
  auto p = planned(job);
  EXPECT_EQ(p["ground"].state, StageState::Skipped);
  EXPECT_EQ(p["ground"].reason, "--no-shadow");
  EXPECT_EQ(p["shadows"].state, StageState::Run);
}

// Every shadow parameter that changes the numbers keys the stages it changes: sh's and ao's
// grid, the boundary rays and the refinement's budget and spread did not (a job with another
// value took the shadows, ground shadow and render of the one before from the cache).
TEST_F(RegistrySkips, EveryShadowParameterKeysTheStagesItChanges) {
  const auto entries = [&](const std::string& params) {
    ComposeJob job = job_;
    job.shadowParams = params;
    // plan() names the entry each stage would be cached in.
    std::map<std::string, std::string> out;
    for (auto& [name, record] : planned(job)) {
      const size_t at = record.reason.find("cached in ");
      if (at != std::string::npos) out[name] = record.reason.substr(at);
    }
    return out;
  };
  const std::vector<std::pair<std::string, std::string>> pairs = {
      {"method=sh", "method=sh,grid=8"},
      {"method=ao", "method=ao,grid=4"},
      {"boundary=2", "boundary=6"},
      {"refine-budget=1", "refine-budget=0.2"},
      {"refine=0.35", "refine=0.351"}};
  for (const auto& [a, b] : pairs) {
    const auto first = entries(a), second = entries(b);
    for (const char* stage : {"shadows", "ground", "render"}) {
      ASSERT_FALSE(first.at(stage).empty()) << stage;
      EXPECT_NE(first.at(stage), second.at(stage)) << stage << ": " << a << " vs " << b;
    }
  }
  // The ground beneath the object darkens the object only: the plate's ground shadow is the same.
  const auto on = entries("ground=on"), off = entries("ground=off");
  EXPECT_NE(on.at("shadows"), off.at("shadows"));
  EXPECT_EQ(on.at("ground"), off.at("ground"));
  // The same parameters written otherwise are the same job.
  EXPECT_EQ(entries("method=cheb,order=16").at("shadows"), entries("").at("shadows"));
}

TEST_F(RegistrySkips, AJobWithoutAPlateSaysSo) {
  ComposeJob job = job_;
  job.plate.clear();
  try {
    planned(job);
    FAIL() << "no error";
  } catch (const UsageError& e) {
    EXPECT_NE(std::string(e.what()).find("--plate"), std::string::npos) << e.what();
  }
}

// An input replaced between hashing it for the keys and reading it is said, and stops the job
// (the results of the new file were cached under the old file's key: every later run with the
// old file took them, an object lit by another map, a lens's distortion from another lens).
TEST(InputFiles, AFileReplacedAfterItWasHashedIsSaid) {
  TempDir dir;
  writeText(dir / "lens.json", "{\"fx\": 1}");
  writeText(dir / "other.json", "{\"fx\": 2}");
  Hash128 h;
  hashFile(h, dir / "lens.json", "camera");
  requireUnchangedSinceHashed(dir / "lens.json", "camera");  // the same file: nothing said
  // Another file moved over it.
  fs::rename(dir / "other.json", dir / "lens.json");
  COMPOSE_EXPECT_ERROR(requireUnchangedSinceHashed(dir / "lens.json", "camera"),
                       "camera: the file changed while compose ran");
  // Hashed again: that file is the one now; rewritten in place, it is another again.
  hashFile(h, dir / "lens.json", "camera");
  requireUnchangedSinceHashed(dir / "lens.json", "camera");
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  writeText(dir / "lens.json", "{\"fx\": 3}");
  COMPOSE_EXPECT_ERROR(requireUnchangedSinceHashed(dir / "lens.json", "camera"),
                       "nothing made from it was kept; run again");
  // A file never hashed is not checked.
  requireUnchangedSinceHashed(dir / "never.json", "camera");
}

// A file read before it is hashed (a lighting file, an object layer): replaced in between (a
// precompute writing it again), the bytes hashed are not those read, and the run is stopped
// (it cached the old lighting's render under the new file's key, which every later run reused).
TEST(InputFiles, AFileReplacedBetweenReadingAndHashingIsSaid) {
  TempDir dir;
  writeText(dir / "scene.lighting", "first");
  writeText(dir / "new.lighting", "second");
  const std::string read = fileIdentity(dir / "scene.lighting");
  EXPECT_FALSE(read.empty());
  Hash128 h;
  hashFile(h, dir / "scene.lighting", "render");
  requireSameFile(dir / "scene.lighting", read, "render");  // the same file: nothing said
  fs::rename(dir / "new.lighting", dir / "scene.lighting");
  hashFile(h, dir / "scene.lighting", "render");
  COMPOSE_EXPECT_ERROR(requireSameFile(dir / "scene.lighting", read, "render"),
                       "render: the file changed while compose ran (it is not the file it read");
  // Rewritten in place (same inode, other times and size).
  const std::string again = fileIdentity(dir / "scene.lighting");
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  writeText(dir / "scene.lighting", "third, longer");
  COMPOSE_EXPECT_ERROR(requireSameFile(dir / "scene.lighting", again, "composite"),
                       "nothing made from it was kept; run again");
  // Gone, or never there.
  EXPECT_TRUE(fileIdentity(dir / "missing.lighting").empty());
  fs::remove(dir / "scene.lighting");
  COMPOSE_EXPECT_ERROR(requireSameFile(dir / "scene.lighting", again, "render"),
                       "the file changed while compose ran");
}

TEST(StageCacheFile, RoundTripsAndRefusesDamagedEntries) {
  TempDir dir;
  StageCache entry(dir.path(), "render", "0123abcd");
  entry.meta()["x0"] = 7;
  entry.put("values", {1.0f, -2.5f, 3.25f});
  Image image(2, 1, 3, {"R", "G", "B"});
  image.pixels = {1, 2, 3, 4, 5, 6};
  image.colorSpace = "ACEScg";
  entry.putImage("beauty", image);
  ASSERT_TRUE(entry.write());

  StageCache read(dir.path(), "render", "0123abcd");
  ASSERT_TRUE(read.open());
  EXPECT_EQ(read.meta()["x0"], 7);
  const std::span<const float> values = read.get("values");
  EXPECT_EQ(std::vector<float>(values.begin(), values.end()),
            (std::vector<float>{1.0f, -2.5f, 3.25f}));
  Image back;
  ASSERT_TRUE(read.getImage("beauty", back));
  EXPECT_EQ(back.pixels, image.pixels);
  EXPECT_EQ(back.colorSpace, "ACEScg");

  // Another key or stage at the same path is a miss.
  StageCache other(dir.path(), "render", "ffff");
  EXPECT_FALSE(other.open());

  // Truncated: a miss, never a crash or a short array.
  const fs::path path = entry.path();
  const auto size = fs::file_size(path);
  fs::resize_file(path, size - 4);
  StageCache truncated(dir.path(), "render", "0123abcd");
  EXPECT_FALSE(truncated.open());
  // Zeroed.
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out << std::string(size, '\0');
  }
  StageCache zeroed(dir.path(), "render", "0123abcd");
  EXPECT_FALSE(zeroed.open());

  // A user-named file opens whatever key it was written under.
  StageCache named = StageCache::atFile(dir / "mine.lighting", "precompute");
  named.put("a", {1.0f});
  ASSERT_TRUE(named.write());
  StageCache reopened = StageCache::atFile(dir / "mine.lighting", "precompute");
  EXPECT_TRUE(reopened.open());
  StageCache wrongStage = StageCache::atFile(dir / "mine.lighting", "render");
  EXPECT_FALSE(wrongStage.open());
  // Written through a hidden temporary beside it: one left by a run killed while writing it (no
  // such process, over a minute old) is removed by the next write, and nothing else is left in view
  // (a killed precompute left "mine.lighting.partial-PID-N" beside the user's files).
  const fs::path folder = dir / "named";
  fs::create_directories(folder);
  const fs::path left = folder / ".mine.lighting.partial-2147483646-0";
  {
    std::ofstream out(left);
    out << "killed while writing";
  }
  fs::last_write_time(left, fs::file_time_type::clock::now() - std::chrono::minutes(2));
  StageCache again = StageCache::atFile(folder / "mine.lighting", "precompute");
  again.put("a", {2.0f});
  ASSERT_TRUE(again.write());
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(folder))
    names.push_back(e.path().filename().string());
  EXPECT_EQ(names, std::vector<std::string>{"mine.lighting"});
}

// The output's header says when worldToNDC is not the whole lens: a distorted one keeps its
// pinhole part, and a fisheye has none (it said nothing of a fisheye without distortion terms,
// whose worldToNDC put the object's points 215 pixels from where they show, on average).
TEST(SceneHeader, SaysWhenWorldToNdcIsNotTheLens) {
  auto lensNote = [](const calib::Lens& lens) {
    Geometry geometry;
    geometry.camera.width = lens.width;
    geometry.camera.height = lens.height;
    geometry.camera.lens = lens;
    for (const auto& [name, value] : sceneHeader(geometry, "", glm::dvec3(0.0)).strings)
      if (name == "compose:lens") return value;
    return std::string();
  };
  calib::Lens pinhole = calib::Lens::fromFieldOfView(640, 480, 60.0);
  EXPECT_EQ(lensNote(pinhole), "");
  pinhole.distortion = {-0.1, 0.02, 0.0, 0.0, 0.0};
  EXPECT_EQ(lensNote(pinhole), "distorted lens: worldToNDC holds its pinhole part only");
  const calib::Lens fisheye =
      calib::Lens::fromFieldOfView(640, 480, 150.0, calib::Projection::Equidistant);
  EXPECT_EQ(lensNote(fisheye),
            "equidistant fisheye lens: worldToNDC is the pinhole of its focal lengths and "
            "principal point, not its projection");
}

// compose:worldFromObject maps the mesh file's coordinates: for a mesh far from its file's
// origin (here a million units out) its translation needs double, which float rounded by
// centimetres (the rebuilt bunny stood 7 cm off where it was rendered).
TEST(SceneHeader, TheObjectsPlacementIsKeptInDouble) {
  Geometry geometry;
  geometry.camera.width = 640;
  geometry.camera.height = 480;
  geometry.camera.lens = calib::Lens::fromFieldOfView(640, 480, 60.0);
  geometry.worldFromObject = glm::scale(glm::dmat4(1.0), glm::dvec3(1.1005657));
  const glm::dvec3 origin(1000000.123, 0.5, 2000000.456);
  const ingest::ExrHeader header = sceneHeader(geometry, "far.obj", origin);
  const std::array<double, 16>* m = nullptr;
  for (const auto& [name, value] : header.doubleMatrices)
    if (name == "compose:worldFromObject") m = &value;
  ASSERT_NE(m, nullptr);
  // Row vectors, translation in the last row: the file's origin lands at the object's.
  for (int c = 0; c < 3; ++c) {
    const double atOrigin = origin[c] * (*m)[size_t(4 * c + c)] + (*m)[size_t(12 + c)];
    EXPECT_NEAR(atOrigin, 0.0, 1e-9) << c;
  }
}

// A Geomview .bez is Z up and read Y up: the matrix maps the file's own coordinates, so the turn
// is in it (without it the rebuilt teapot lay on its side, 2 m into the ground).
TEST(SceneHeader, TheObjectsPlacementTakesAFilesAxes) {
  Geometry geometry;
  geometry.camera.width = 640;
  geometry.camera.height = 480;
  geometry.camera.lens = calib::Lens::fromFieldOfView(640, 480, 60.0);
  geometry.worldFromObject = glm::translate(glm::dmat4(1.0), glm::dvec3(0.5, 0.0, -4.0));
  for (const auto& [file, expected] :
       std::vector<std::pair<std::string, glm::dvec3>>{{"teapot.bez", {1.5, 3.0, -6.0}},
                                                       {"TEAPOT.BEZ", {1.5, 3.0, -6.0}},
                                                       {"bunny.obj", {1.5, 2.0, -1.0}}}) {
    const ingest::ExrHeader header = sceneHeader(geometry, file, glm::dvec3(0.0));
    const std::array<double, 16>* m = nullptr;
    for (const auto& [name, value] : header.doubleMatrices)
      if (name == "compose:worldFromObject") m = &value;
    ASSERT_NE(m, nullptr);
    const double p[3] = {1.0, 2.0, 3.0};  // in the file
    for (int c = 0; c < 3; ++c) {
      const double w = p[0] * (*m)[size_t(c)] + p[1] * (*m)[size_t(4 + c)] +
                       p[2] * (*m)[size_t(8 + c)] + (*m)[size_t(12 + c)];
      EXPECT_NEAR(w, expected[c], 1e-12) << file << " " << c;
    }
  }
}

}  // namespace
}  // namespace compose::pipeline
