// End-to-end: compose convert and compose stitch through the executable, the one-shot command
// with cube-map environments, and bad environment input (a named error, a non-zero exit, nothing
// written).
#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <numbers>
#include <random>
#include <sstream>

#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <glm/geometric.hpp>
#include <glm/matrix.hpp>
#include <nlohmann/json.hpp>

#include "color/color.h"
#include "command_util.h"
#include "cubemap/environment_io.h"
#include "cubemap/render_view.h"
#include "cubemap/seams.h"
#include "ingest/image_io.h"
#include "lighting/filtered_cube.h"
#include "lighting/sphere_resample.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose {
namespace {

namespace fs = std::filesystem;
using lighting::CubeMap;
using lighting::Environment;
using lighting::kCubeFaces;
using testing::TempDir;

using RunResult = compose::testing::CommandResult;

std::string q(const fs::path& p) {
  return compose::testing::quote(p);
}

RunResult run(const std::string& args, const TempDir& scratch) {
  return compose::testing::runCompose(args, scratch.path());
}

fs::path sample(const std::string& name) {
  return pipeline::samplesDirectory() / name;
}

// Files in a folder besides the runner's own stdout/stderr captures.
std::vector<std::string> filesIn(const fs::path& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string n = e.path().filename().string();
    if (n != "stdout.txt" && n != "stderr.txt") names.push_back(n);
  }
  std::sort(names.begin(), names.end());
  return names;
}

double relativeEnergy(const glm::dvec3& a, const glm::dvec3& b) {
  double worst = 0.0;
  for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(a[c] - b[c]) / std::abs(b[c]));
  return worst;
}

TEST(ConvertCommand, LatLongToEveryLayoutAndBackKeepsTheEnergy) {
  if (!fs::exists(sample("forest.exr"))) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  TempDir dir;
  const Environment source =
      Environment::fromLatLong(ingest::readImage(sample("forest.exr")).image);
  const glm::dvec3 energy = lighting::integral(source);

  RunResult r = run(
      "convert " + q(sample("forest.exr")) + " --to cube --size 128 --out " + q(dir / "cube.exr"),
      dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("aspect 2:1"), std::string::npos) << "the detection is reported";
  EXPECT_EQ(cubemap::exrEnvmapLayout(dir / "cube.exr"), cubemap::Layout::Cube);
  // The HDRI says no primaries (OpenEXR's convention: Rec.709): the cube says them, with the
  // config's name for that space, not OpenImageIO's generic 'Linear'.
  {
    const ingest::CaptureInfo info = ingest::readCaptureInfo(dir / "cube.exr");
    ASSERT_TRUE(info.chromaticities.has_value());
    EXPECT_NEAR((*info.chromaticities)[0], 0.64, 1e-6);
    EXPECT_NEAR((*info.chromaticities)[3], 0.60, 1e-6);
    EXPECT_EQ(info.fileColorSpace, "Linear Rec.709 (sRGB)");
  }
  for (const char* layout : {"hcross", "vcross"}) {
    r = run(std::string("convert ") + q(dir / "cube.exr") + " --to " + layout + " --out " +
                q(dir / (std::string(layout) + ".exr")),
            dir);
    ASSERT_EQ(r.status, 0) << r.err;
  }
  r = run("convert " + q(dir / "vcross.exr") + " --to faces --out " + q(dir / "face_%.exr"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  r = run("convert " + q(dir / "face_%.exr") + " --to latlong --out " + q(dir / "back.exr"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(cubemap::exrEnvmapLayout(dir / "back.exr"), cubemap::Layout::LatLong);
  const Environment back = Environment::fromLatLong(ingest::readImage(dir / "back.exr").image);
  EXPECT_EQ(back.width(), 512);  // 4 x the face size
  // The issue's 1e-4, through four files written as float.
  constexpr double kIssueEnergy = 1e-4;
  EXPECT_LT(relativeEnergy(lighting::integral(back), energy), kIssueEnergy);
  const cubemap::EnvironmentFile hcross = cubemap::readEnvironmentFile({dir / "hcross.exr"});
  EXPECT_LT(relativeEnergy(cubemap::cubeMapOf(hcross).integral(), energy), kIssueEnergy);
}

// A chrome ball photographed in a synthetic room with one lamp: the unwrapped map has the lamp
// where it was.
TEST(ConvertCommand, MirrorBallToLatLong) {
  TempDir dir;
  const glm::dvec3 lamp = glm::normalize(glm::dvec3(0.4, 0.6, 0.7));
  const int size = 256;
  Image ball(size, size, 3, {"R", "G", "B"});
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const double u = 2.0 * (x + 0.5) / size - 1.0, v = 1.0 - 2.0 * (y + 0.5) / size;
      if (u * u + v * v > 1.0) continue;
      const glm::dvec3 n(u, v, std::sqrt(1.0 - u * u - v * v));
      const glm::dvec3 d = 2.0 * n.z * n - glm::dvec3(0, 0, 1);
      const float L = glm::dot(d, lamp) > 0.995 ? 50.0f : 0.5f + 0.25f * float(d.y);
      ball.at(x, y)[0] = ball.at(x, y)[1] = ball.at(x, y)[2] = L;
    }
  ingest::WriteOptions w;
  w.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "ball.exr", ball, w);
  const RunResult r =
      run("convert " + q(dir / "ball.exr") + " --from mirrorball --to latlong --width 256 --out " +
              q(dir / "env.exr"),
          dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("of the sphere (behind the ball) filled"), std::string::npos) << r.err;
  const Environment env = Environment::fromLatLong(ingest::readImage(dir / "env.exr").image);
  float best = 0.0f;
  glm::vec3 dir3(0.0f);
  for (int y = 0; y < env.height(); ++y)
    for (int x = 0; x < env.width(); ++x)
      if (env.radiance(x, y).x > best) {
        best = env.radiance(x, y).x;
        dir3 = env.direction(x, y);
      }
  // The lamp is a 5.7° disc; the map has 1.4° texels.
  EXPECT_GT(glm::dot(glm::dvec3(dir3), lamp), std::cos(4.0 * 3.14159265 / 180.0));
}

// Six photos named for their faces, rendered from the courtyard HDRI with orientations up to 2°
// off, stitched through the command line.
// Photos of 8-bit codes stitched into a JPEG: a clipped sky times an exposure gain goes a little
// above 1, which the JPEG writes as white, with a note; float photos (radiance) into a JPEG are
// refused, as convert refuses them.
TEST(StitchCommand, PhotosOfCodesMayBeStitchedIntoAJpeg) {
  if (!fs::exists(sample("courtyard.exr"))) GTEST_SKIP() << "samples missing";
  TempDir dir;
  const Environment env =
      Environment::fromLatLong(ingest::readImage(sample("courtyard.exr")).image);
  const lighting::FilteredCube scene(lighting::cubeFromLatLong(env, 128));
  const calib::Lens lens = calib::Lens::fromFieldOfView(192, 192, 100.0);
  const char* names[kCubeFaces] = {"px", "nx", "py", "ny", "pz", "nz"};
  std::string jpegs, exrs;
  for (int f = 0; f < kCubeFaces; ++f) {
    Image view = cubemap::renderView(scene, lens, cubemap::faceCameraRotation(f), 2);
    ingest::WriteOptions w;
    w.depth = ingest::WriteOptions::Depth::Float;
    ingest::writeImage(dir / (std::string("hdr_") + names[f] + ".exr"), view, w);
    exrs += " " + q(dir / (std::string("hdr_") + names[f] + ".exr"));
    // A camera's photo: bright, clipped at white, one of them taken darker (its gain above 1).
    for (float& v : view.pixels) v = std::min(1.0f, v * (f == 2 ? 2.0f : 4.0f));
    ingest::writeImage(dir / (std::string("ldr_") + names[f] + ".png"), view);
    jpegs += " " + q(dir / (std::string("ldr_") + names[f] + ".png"));
  }
  const RunResult ldr =
      run("stitch --fov 100 --size 64 --gains on --to latlong --out " + q(dir / "pano.jpg") + jpegs,
          dir);
  ASSERT_EQ(ldr.status, 0) << ldr.err;
  EXPECT_NE(ldr.err.find("are written as white in pano.jpg"), std::string::npos) << ldr.err;
  EXPECT_TRUE(fs::exists(dir / "pano.jpg"));
  const RunResult hdr =
      run("stitch --fov 100 --size 64 --no-refine --to latlong --out " + q(dir / "hdr.jpg") + exrs,
          dir);
  EXPECT_EQ(hdr.status, 1) << hdr.err;
  EXPECT_NE(hdr.err.find("would clip to 1: write OpenEXR (.exr) or Radiance (.hdr)"),
            std::string::npos)
      << hdr.err;
  EXPECT_FALSE(fs::exists(dir / "hdr.jpg"));
  // Faces named by a base name get OpenEXR's extension and hold linear light, as a pattern's do
  // (the base name's file rules made them sRGB-encoded: 0.176 written as 0.456).
  for (const char* out : {"base", "pattern_%.exr"}) {
    const RunResult faces =
        run("stitch --fov 100 --size 32 --no-refine --to faces --out " + q(dir / out) + exrs, dir);
    ASSERT_EQ(faces.status, 0) << faces.err;
  }
  const ingest::LoadedImage byBase = ingest::readImage(dir / "base_pz.exr");
  const ingest::LoadedImage byPattern = ingest::readImage(dir / "pattern_pz.exr");
  EXPECT_EQ(byBase.image.pixels, byPattern.image.pixels);
  EXPECT_EQ(byBase.info.fileColorSpace, byPattern.info.fileColorSpace);
  EXPECT_EQ(byBase.info.fileColorSpace.find("sRGB - Texture"), std::string::npos);
}

TEST(StitchCommand, SixNamedPhotosToACube) {
  if (!fs::exists(sample("courtyard.exr"))) GTEST_SKIP() << "samples missing";
  TempDir dir;
  const Environment env =
      Environment::fromLatLong(ingest::readImage(sample("courtyard.exr")).image);
  const CubeMap truth = lighting::cubeFromLatLong(env, 128);
  const lighting::FilteredCube scene(lighting::cubeFromLatLong(env, 256));
  const calib::Lens lens = calib::Lens::fromFieldOfView(384, 384, 100.0);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> off(-2.0, 2.0);
  const char* names[kCubeFaces] = {"px", "nx", "py", "ny", "pz", "nz"};
  std::string photos;
  for (int f = 0; f < kCubeFaces; ++f) {
    // Drawn in a fixed order: C++ leaves a call's argument evaluation order unspecified.
    const double roll = off(rng), pitch = off(rng), yaw = off(rng);
    const glm::dmat3 r = cubemap::faceCameraRotation(f) * cubemap::cameraRotation(yaw, pitch, roll);
    ingest::WriteOptions w;
    w.depth = ingest::WriteOptions::Depth::Float;
    // Named as a user names them (yard_px) or as capture-sim does (nx_2: a face, then the
    // bracket), and given in reverse order: the names say where each points.
    const fs::path p =
        dir / (f % 2 == 0 ? std::string("yard_") + names[f] : std::string(names[f]) + "_2");
    ingest::writeImage(p.string() + ".exr", cubemap::renderView(scene, lens, r, 2), w);
    photos = " " + q(p.string() + ".exr") + photos;
  }
  const RunResult r = run("stitch --fov 100 --size 128 --out " + q(dir / "env.exr") + photos, dir);
  ASSERT_EQ(r.status, 0) << r.err;
  if (std::getenv("SHOWERR")) std::printf("%s", r.err.c_str());
  EXPECT_NE(r.err.find("of the sphere was seen by no photo"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("orientation corrected by"), std::string::npos) << r.err;
  const cubemap::EnvironmentFile file = cubemap::readEnvironmentFile({dir / "env.exr"});
  ASSERT_EQ(file.layout, cubemap::Layout::Cube) << file.how;
  const CubeMap stitched = cubemap::cubeMapOf(file);
  std::vector<double> rel;
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < 128; ++y)
      for (int x = 0; x < 128; ++x) {
        const glm::vec3 a = truth.radiance(f, x, y), b = stitched.radiance(f, x, y);
        rel.push_back(double(glm::length(a - b) / std::max(glm::length(a), 1e-6f)));
      }
  std::nth_element(rel.begin(), rel.begin() + ptrdiff_t(rel.size() / 2), rel.end());
  // The photos' common orientation error is not removed here (as in the library test), so the
  // whole map may turn by up to ~1°: looser than 5 %.
  EXPECT_LT(rel[rel.size() / 2], 0.10);
  EXPECT_EQ(r.err.find("compose: warning"), std::string::npos) << r.err;

  // The same photos unnamed, in the order a photographer turning round takes them (front, right,
  // back, left, up, down), are taken in the order +X -X +Y -Y +Z -Z: nothing matches where they
  // are put, which is said.
  const char* turning[kCubeFaces] = {"nz_2", "yard_px", "yard_pz", "nx_2", "yard_py", "ny_2"};
  std::string unnamed;
  for (int i = 0; i < kCubeFaces; ++i) {
    const fs::path to = dir / ("IMG_000" + std::to_string(i + 1) + ".exr");
    fs::copy_file(dir / (std::string(turning[i]) + ".exr"), to);
    unnamed += " " + q(to);
  }
  const RunResult scrambled =
      run("stitch --fov 100 --size 128 --out " + q(dir / "scrambled.exr") + unnamed, dir);
  ASSERT_EQ(scrambled.status, 0) << scrambled.err;
  EXPECT_NE(scrambled.err.find("compose: warning: 0 of"), std::string::npos) << scrambled.err;
  EXPECT_NE(scrambled.err.find("are the photos' directions right?"), std::string::npos)
      << scrambled.err;

  const RunResult twice = run("stitch --fov 100 --size 128 --out " + q(dir / "twice.exr") +
                                  unnamed + " " + q(dir / "." / "IMG_0001.exr"),
                              dir);
  EXPECT_EQ(twice.status, 1) << twice.err;
  EXPECT_NE(twice.err.find("the same photo is given twice"), std::string::npos) << twice.err;
  EXPECT_FALSE(fs::exists(dir / "twice.exr"));
}

// A ring of level views named as compose capture-sim names them (yaw000, yaw120_2, ...): the name
// says where each points, as @120,0 would; the stitched map matches the scene.
TEST(StitchCommand, ARingOfViewsNamedByTheirTurn) {
  if (!fs::exists(sample("courtyard.exr"))) GTEST_SKIP() << "samples missing";
  TempDir dir;
  const Environment env =
      Environment::fromLatLong(ingest::readImage(sample("courtyard.exr")).image);
  const lighting::FilteredCube scene(lighting::cubeFromLatLong(env, 128));
  const CubeMap truth = lighting::cubeFromLatLong(env, 64);
  const calib::Lens lens =
      calib::Lens::fromFieldOfView(256, 256, 200.0, calib::Projection::Equidistant);
  std::string photos;
  for (int k = 0; k < 3; ++k) {
    const int yaw = 120 * k;
    char name[32];
    std::snprintf(name, sizeof name, k == 1 ? "yaw%03d_2.exr" : "yaw%03d.exr", yaw);
    ingest::WriteOptions w;
    w.depth = ingest::WriteOptions::Depth::Float;
    ingest::writeImage(dir / name,
                       cubemap::renderView(scene, lens, cubemap::cameraRotation(yaw, 0, 0), 2), w);
    photos += " " + q(dir / name);
  }
  const RunResult r =
      run("stitch --fov 200 --fisheye --no-refine --size 64 --out " + q(dir / "ring.exr") + photos,
          dir);
  ASSERT_EQ(r.status, 0) << r.err;
  const CubeMap stitched = cubemap::cubeMapOf(cubemap::readEnvironmentFile({dir / "ring.exr"}));
  std::vector<double> rel;
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < 64; ++y)
      for (int x = 0; x < 64; ++x) {
        const glm::vec3 a = truth.radiance(f, x, y), b = stitched.radiance(f, x, y);
        rel.push_back(double(glm::length(a - b) / std::max(glm::length(a), 1e-6f)));
      }
  std::nth_element(rel.begin(), rel.begin() + ptrdiff_t(rel.size() / 2), rel.end());
  EXPECT_LT(rel[rel.size() / 2], 0.05);
  // A name that says nothing of its direction is still refused.
  fs::copy_file(dir / "yaw000.exr", dir / "yawning.exr");
  const RunResult bad = run("stitch --fov 200 --fisheye --out " + q(dir / "bad.exr") + " " +
                                q(dir / "yawning.exr") + " " + q(dir / "yaw120_2.exr"),
                            dir);
  EXPECT_EQ(bad.status, 2) << bad.err;
  EXPECT_NE(bad.err.find("cannot tell where"), std::string::npos) << bad.err;
}

// A float photo holding NaN is an error naming it and the pixel, and nothing is written (the NaN
// used to spread into thousands of texels of the stitched map).
TEST(StitchCommand, ANonFinitePhotoIsANamedError) {
  TempDir dir;
  Image photo(48, 32, 3);
  std::fill(photo.pixels.begin(), photo.pixels.end(), 0.25f);
  photo.at(9, 4)[2] = std::nanf("");
  ingest::WriteOptions w;
  w.depth = ingest::WriteOptions::Depth::Float;
  const fs::path bad = dir / "bad.exr";
  ingest::writeImage(bad, photo, w);
  const RunResult r =
      run("stitch --fov 100 --out " + q(dir / "env.exr") + " " + q(bad) + "@0,0", dir);
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("NaN in the photo at pixel (9, 4): its values must be finite (" +
                       bad.string() + ")"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "env.exr"));
}

// JPEG photos, each exposed for itself as a camera in automatic mode would: the exposure gains
// bring them to one scale, so the faces keep the brightness ratios of the scene.
TEST(StitchCommand, AutoExposedJpegsAreBroughtToOneScale) {
  if (!fs::exists(sample("sunset.exr"))) GTEST_SKIP() << "samples missing";
  TempDir dir;
  const Environment env = Environment::fromLatLong(ingest::readImage(sample("sunset.exr")).image);
  const CubeMap truth = lighting::cubeFromLatLong(env, 32);
  const lighting::FilteredCube scene(lighting::cubeFromLatLong(env, 128));
  const calib::Lens lens = calib::Lens::fromFieldOfView(384, 384, 100.0);
  const char* names[kCubeFaces] = {"px", "nx", "py", "ny", "pz", "nz"};
  std::string photos;
  for (int f = 0; f < kCubeFaces; ++f) {
    Image view = cubemap::renderView(scene, lens, cubemap::faceCameraRotation(f), 2);
    std::vector<float> values(view.pixels.begin(), view.pixels.end());
    std::nth_element(values.begin(), values.begin() + ptrdiff_t(values.size() / 2), values.end());
    const float exposure = 0.18f / std::max(values[values.size() / 2], 1e-6f);
    for (float& v : view.pixels) {
      const float x = std::clamp(exposure * v, 0.0f, 1.0f);  // sRGB encoding, clipped at white
      v = x <= 0.0031308f ? 12.92f * x : 1.055f * std::pow(x, 1.0f / 2.4f) - 0.055f;
    }
    const fs::path p = dir / (std::string("sky_") + names[f] + ".jpg");
    ingest::writeImage(p, view);
    photos += " " + q(p);
  }
  const RunResult r = run("stitch --fov 100 --size 32 --out " + q(dir / "env.exr") + photos, dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("clipping at white"), std::string::npos) << r.err;
  const CubeMap stitched = cubemap::cubeMapOf(cubemap::readEnvironmentFile({dir / "env.exr"}));
  auto faceMean = [](const CubeMap& c, int f) {
    double sum = 0.0;
    for (float v : c.face(f)) sum += v;
    return sum;
  };
  // Brightness of each side face relative to the -Z face, stitched against the scene: the sky
  // (+Y) is many times the ground (-Y) in the scene, and the photos were exposed to hide it.
  for (int f : {0, 1, 2, 3, 4}) {
    const double expected = faceMean(truth, f) / faceMean(truth, 5);
    const double ours = faceMean(stitched, f) / faceMean(stitched, 5);
    // Gains from feature radiance ratios, JPEG quantisation and clipped highlights: 15 %.
    constexpr double kGains = 0.15;
    EXPECT_NEAR(ours / expected, 1.0, kGains)
        << lighting::faceName(f) << " scene ratio " << expected;
  }
}

// The rotation nearest to m (polar decomposition by Newton's iteration; m is close to one).
glm::dmat3 nearestRotation(glm::dmat3 m) {
  for (int i = 0; i < 30; ++i) m = 0.5 * (m + glm::transpose(glm::inverse(m)));
  return m;
}

glm::dmat3 matrixOf(const nlohmann::json& rows) {
  glm::dmat3 m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m[c][r] = rows.at(size_t(r)).at(size_t(c)).get<double>();
  return m;
}

// The issue's stitch test on photographs: the virtual camera's bracketed JPEGs of each sample HDRI
// (six views, 100° field of view, each view off its nominal direction by up to ±3° about every
// axis, a filmic response, sensor noise, JPEG at quality 95), merged (the response recovered from
// the photos) and stitched by the commands a user runs, against the HDRI.
//
// Two things no stitch can know are taken out. The merge fixes radiance only up to one scale per
// capture (the median ratio over the texels is used). And photos fix their orientations only
// relative to each other: the stitch puts the group where the rough orientations say it is on
// average, so the whole map is turned by the mean of the views' errors (here 2.54°: at 256² faces
// that moves forest's texels, which differ from their neighbours by 38 %, by about seven texels).
// The truth is turned by the same rotation, read from the capture's truth.json, and averaged over
// 8 x 8 directions per texel.
//
// Measured (seed 5: the capture turned by 2.54° as a whole; 1536² photos, 2.4 MP, fewer than any
// camera's): median relative error courtyard 1.56 %, forest 3.98 %, interior 0.89 %, sunset
// 1.01 % (2.35 % while the group was put where five of the six rough orientations say: sunset's
// sky photo shares no features with the others and is aligned on its radiance); the comparison's
// own floor (the sampled truth against the exact cube) 0.03-0.53 %. Without turning the truth:
// 6-41 %. With 768² photos forest is at 5.9 %: its detail is finer than what a photo of 7.7
// pixels a degree keeps after the lens' blur and JPEG. The worst seam is 0.99, 0.95, 0.98 and
// 1.10 (sunset's sky face, below).
class StitchFromPhotos : public ::testing::TestWithParam<const char*> {};

TEST_P(StitchFromPhotos, SixJitteredViewsWithinFivePercent) {
  const std::string name = GetParam();
  if (!fs::exists(sample(name + ".exr"))) GTEST_FAIL() << "samples missing: run samples/fetch.sh";
  TempDir dir;
  RunResult r = run("capture-sim --env " + q(sample(name + ".exr")) + " --out " + q(dir / "shots") +
                        " --views 6 --brackets 3 --ev-step 2 --fov 100 --jitter 3 --size 1536x1536 "
                        "--seed 5 -q",
                    dir);
  ASSERT_EQ(r.status, 0) << r.err;
  // The response is recovered from these photos: a folder of its own, not the user's, where a
  // response stored by an earlier capture of the same virtual camera would be reused. The merged
  // views are written uncompressed (the same numbers; ZIP took 3.4 s of the merge's 5.7 s).
  r = run("merge --capture " + q(dir / "shots" / "capture.json") + " --out " + q(dir / "merged") +
              "/ --compression none --response-dir " + q(dir / "responses"),
          dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("response saved to"), std::string::npos) << r.err;
  std::string views;
  for (const char* v : {"px", "nx", "py", "ny", "pz", "nz"})
    views += " " + q(dir / "merged" / (std::string(v) + ".exr"));
  constexpr int kFace = 256;  // the HDRIs' resolution on the equator (1024 / 4)
  r = run("stitch --calib " + q(dir / "shots" / "camera.json") + " --to cube --size " +
              std::to_string(kFace) + " --out " + q(dir / "cube.exr") + views,
          dir);
  ASSERT_EQ(r.status, 0) << r.err;

  // The capture's rotation as a whole: the one that best maps the true orientations onto the
  // nominal ones, G = nearest rotation to Σ nominal truthᵀ. The stitched map at d shows the
  // truth at Gᵀ d.
  std::ifstream truthFile(dir / "shots" / "truth.json");
  const nlohmann::json truthJson = nlohmann::json::parse(truthFile);
  glm::dmat3 alignment(0.0);
  for (const nlohmann::json& v : truthJson.at("views"))
    alignment += matrixOf(v.at("nominalWorldFromCamera")) *
                 glm::transpose(matrixOf(v.at("worldFromCamera")));
  const glm::dmat3 g = nearestRotation(alignment);
  const double turned =
      std::acos(std::clamp(0.5 * (g[0][0] + g[1][1] + g[2][2] - 1.0), -1.0, 1.0)) * 180.0 /
      std::numbers::pi;

  // The truth in the stitched map's colour space (the one its header declares).
  const cubemap::EnvironmentFile file = cubemap::readEnvironmentFile({dir / "cube.exr"});
  const CubeMap stitched = cubemap::cubeMapOf(file);
  const color::ColorConfig colors = color::ColorConfig::builtin();
  Image truthImage = ingest::readImage(sample(name + ".exr")).image;
  truthImage.colorSpace = "lin_rec709";
  ASSERT_TRUE(file.info.chromaticities) << "the stitched map declares its primaries";
  const std::string space = colors.spaceWithChromaticities(*file.info.chromaticities);
  ASSERT_FALSE(space.empty());
  colors.convert(truthImage, space);
  const Environment truthMap = Environment::fromLatLong(truthImage);
  // A texel of the turned truth: the mean of the HDRI's texels (nearest, no interpolation) at
  // 8 x 8 directions over it, which approaches the box filter of an exact resampling.
  constexpr int kSub = 8;
  auto truthTexel = [&](int f, int x, int y, const glm::dmat3& rotation) {
    glm::dvec3 sum(0.0);
    for (int j = 0; j < kSub; ++j)
      for (int i = 0; i < kSub; ++i) {
        const double a = -1.0 + (2.0 * x + 2.0 * (i + 0.5) / kSub) / kFace;
        const double b = -1.0 + (2.0 * y + 2.0 * (j + 0.5) / kSub) / kFace;
        const glm::dvec3 d =
            glm::normalize(glm::transpose(rotation) * lighting::faceImageDirection(f, a, b));
        // Texel (x, y) covers φ ∈ π(1 - 2[x, x+1]/W), λ ∈ π(1/2 - [y, y+1]/H) (environment.h).
        const double lat = std::asin(std::clamp(d.y, -1.0, 1.0)), lon = std::atan2(d.x, d.z);
        const int w = truthMap.width(), h = truthMap.height();
        const int tx =
            std::clamp(int(std::floor((1.0 - lon / std::numbers::pi) * 0.5 * w)), 0, w - 1);
        const int ty = std::clamp(int(std::floor((0.5 - lat / std::numbers::pi) * h)), 0, h - 1);
        sum += glm::dvec3(truthMap.radiance(tx, ty));
      }
    return glm::vec3(sum / double(kSub * kSub));
  };

  auto turnedTruth = [&](const glm::dmat3& rotation) {
    CubeMap cube(kFace);
    for (int f = 0; f < kCubeFaces; ++f)
      for (int y = 0; y < kFace; ++y)
        for (int x = 0; x < kFace; ++x) {
          const glm::vec3 t = truthTexel(f, x, y, rotation);
          float* texel = cube.face(f).data() + 3 * (size_t(y) * kFace + size_t(x));
          texel[0] = t.x, texel[1] = t.y, texel[2] = t.z;
        }
    return cube;
  };
  // The best scale of `map` to `truth` (median ratio), and the median relative error after it.
  struct Fit {
    float scale = 1.0f;
    double median = 0.0;
  };
  auto compare = [&](const CubeMap& truth, const CubeMap& map) {
    std::vector<double> ratios, errors;
    for (int f = 0; f < kCubeFaces; ++f)
      for (int y = 0; y < kFace; ++y)
        for (int x = 0; x < kFace; ++x) {
          const glm::vec3 t = truth.radiance(f, x, y), m = map.radiance(f, x, y);
          const double st = t.x + t.y + t.z, sm = m.x + m.y + m.z;
          if (st > 0.0 && sm > 0.0) ratios.push_back(st / sm);
        }
    std::nth_element(ratios.begin(), ratios.begin() + ptrdiff_t(ratios.size() / 2), ratios.end());
    Fit fit;
    fit.scale = float(ratios[ratios.size() / 2]);
    for (int f = 0; f < kCubeFaces; ++f)
      for (int y = 0; y < kFace; ++y)
        for (int x = 0; x < kFace; ++x) {
          const glm::vec3 t = truth.radiance(f, x, y), m = fit.scale * map.radiance(f, x, y);
          errors.push_back(double(glm::length(t - m) / std::max(glm::length(t), 1e-6f)));
        }
    std::nth_element(errors.begin(), errors.begin() + ptrdiff_t(errors.size() / 2), errors.end());
    fit.median = errors[errors.size() / 2];
    return fit;
  };
  const CubeMap truth = turnedTruth(g), unturnedTruth = turnedTruth(glm::dmat3(1.0));
  const Fit fit = compare(truth, stitched);
  const double unturned = compare(unturnedTruth, stitched).median;
  // What the comparison itself costs: the sampled truth against the HDRI's exact cube map.
  const double floor = compare(unturnedTruth, lighting::cubeFromLatLong(truthMap, kFace)).median;
  // Seams, as in tests/cubemap/stitch_test.cpp: on 128² faces, the step across every face edge
  // against the neighbouring texel-to-texel steps and the step the scene itself has there.
  CubeMap scaled = stitched;
  for (int f = 0; f < kCubeFaces; ++f)
    for (float& v : scaled.face(f)) v *= fit.scale;
  const CubeMap stitched128 = lighting::resizeCube(scaled, 128);
  const CubeMap truth128 = lighting::resizeCube(truth, 128);
  const double seam = compose::testing::worstSeam(stitched128, truth128);
  const double levelStep = compose::testing::worstLevelStep(stitched128, truth128);
  std::printf(
      "[ figures ] %-9s stitched from capture-sim photos: median relative error %.2f %% "
      "(%.2f %% without turning the truth by the capture's %.2f°; the comparison's own "
      "floor %.2f %%); worst seam %.2f, worst level step %.3f\n",
      name.c_str(), 100.0 * fit.median, 100.0 * unturned, turned, 100.0 * floor, seam, levelStep);
  constexpr double kIssueMedian = 0.05;
  EXPECT_LT(fit.median, kIssueMedian) << name;
  // No seam (at most 1) but on sunset's sky face, 1.10: there the photos' 8-bit quantisation
  // contours and JPEG blocks (1.08 without sensor noise) double the stitched sky's texel-to-texel
  // variation against the scene's, and two texels across an edge differ by more than two beside
  // it; the level step across those edges is 0.24 of that variation at most. The level steps
  // (tests/cubemap/seams.h), measured 0.29 / 0.83 / 0.76 / 0.26 (sunset 0.81 while its group was
  // put where five of the six rough orientations say).
  constexpr double kSeam = 1.2;
  EXPECT_LT(seam, kSeam) << name;
  constexpr double kLevelStep = 1.0;
  EXPECT_LT(levelStep, kLevelStep) << name;
}

INSTANTIATE_TEST_SUITE_P(SampleHdris, StitchFromPhotos,
                         ::testing::Values("courtyard", "forest", "interior", "sunset"));

// A lat-long map stored upside down lit the object from below without a word: it is warned
// about (its lower half brighter than its upper one), and the map the right way up is not.
TEST(ComposeWithLatLongEnvironments, AnUpsideDownMapIsWarnedAbout) {
  if (!fs::exists(sample("forest.exr")) || !fs::exists(sample("bunny.obj")))
    GTEST_SKIP() << "samples missing";
  TempDir dir;
  Image plate(160, 120, 3, {"R", "G", "B"});
  for (float& v : plate.pixels) v = 0.4f;
  ingest::writeImage(dir / "plate.png", plate);
  const Image forest = ingest::readImage(sample("forest.exr")).image;
  Image flipped = forest;
  for (int y = 0; y < forest.height; ++y)
    for (int x = 0; x < forest.width; ++x)
      for (int c = 0; c < forest.channels; ++c)
        flipped.at(x, forest.height - 1 - y)[c] = forest.at(x, y)[c];
  ingest::writeImage(dir / "flipped.exr", flipped);
  for (const auto& [env, warned] :
       {std::pair{dir / "flipped.exr", true}, std::pair{sample("forest.exr"), false}}) {
    const RunResult r = run(
        "--plate " + q(dir / "plate.png") + " --object " + q(sample("bunny.obj")) + " --env " +
            q(env) + " --shadows off --no-shadow --samples 1 --no-cache --out " + q(dir / "out"),
        dir);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_EQ(r.err.find("times as bright below its horizon as above it") != std::string::npos,
              warned)
        << r.err;
  }
}

TEST(ComposeWithCubeEnvironments, CrossesAndFaceFoldersLightTheObject) {
  if (!fs::exists(sample("forest.exr")) || !fs::exists(sample("bunny.obj")))
    GTEST_SKIP() << "samples missing";
  TempDir dir;
  // A small grey plate keeps the render short: the environment's path is what is tested.
  Image plate(320, 240, 3, {"R", "G", "B"});
  for (float& v : plate.pixels) v = 0.4f;
  ingest::writeImage(dir / "plate.png", plate);
  ASSERT_EQ(run("convert " + q(sample("forest.exr")) + " --to vcross --size 64 --out " +
                    q(dir / "cross.exr"),
                dir)
                .status,
            0);
  const RunResult r = run("--plate " + q(dir / "plate.png") + " --object " +
                              q(sample("bunny.obj")) + " --env " + q(dir / "cross.exr") +
                              " --samples 1 --no-cache --room 8,4,40 --out " + q(dir / "out"),
                          dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("vertical cross"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("parallax: the environment as seen from the object's centre"),
            std::string::npos)
      << r.err;
  EXPECT_TRUE(fs::exists(dir / "out.exr"));
}

// A cross of 8-bit codes lights the object as its lat-long map in linear light does: its faces
// are made linear before they are resampled (a checker of codes 0 and 255 averaged as stored
// is code 128, 0.22 of the light where the faces hold 0.5: the object came out 30 % dark).
TEST(ComposeWithCubeEnvironments, ACrossOfCodesLightsAsItsLatLongMap) {
  if (!fs::exists(sample("bunny.obj"))) GTEST_SKIP() << "samples missing";
  TempDir dir;
  Image plate(160, 120, 3, {"R", "G", "B"});
  for (float& v : plate.pixels) v = 0.4f;
  ingest::writeImage(dir / "plate.png", plate);
  // A horizontal cross of 16-texel faces: a checker of 2-texel squares in its cells, black
  // outside them.
  Image cross(64, 48, 3, {"R", "G", "B"});
  const int cells[kCubeFaces][2] = {{2, 1}, {0, 1}, {1, 0}, {1, 2}, {1, 1}, {3, 1}};
  for (const auto& cell : cells)
    for (int y = 0; y < 16; ++y)
      for (int x = 0; x < 16; ++x)
        for (int c = 0; c < 3; ++c)
          cross.at(cell[0] * 16 + x, cell[1] * 16 + y)[c] = float((x / 2 + y / 2) % 2);
  ingest::writeImage(dir / "cross.png", cross);
  ASSERT_EQ(run("convert " + q(dir / "cross.png") + " --to latlong --out " + q(dir / "ll.exr"), dir)
                .status,
            0);
  std::map<std::string, Image> composites;
  for (const char* env : {"cross.png", "ll.exr"}) {
    const RunResult r = run("--plate " + q(dir / "plate.png") + " --object " +
                                q(sample("bunny.obj")) + " --env " + q(dir / env) +
                                " --exposure 0 --shadows off --no-shadow --samples 1 --no-cache "
                                "--out " +
                                q(dir / ("lit_by_" + fs::path(env).stem().string())),
                            dir);
    ASSERT_EQ(r.status, 0) << env << ": " << r.err;
    composites[env] = ingest::readImage(dir / ("lit_by_" + fs::path(env).stem().string() + ".exr"),
                                        "ingest", {.picturePart = true})
                          .image;
  }
  const Image &a = composites["cross.png"], &b = composites["ll.exr"];
  ASSERT_EQ(a.pixels.size(), b.pixels.size());
  ASSERT_GE(a.channels, 3);
  double sumA = 0.0, sumB = 0.0, worst = 0.0;  // of the colour, less the plate's
  for (size_t i = 0; i < a.pixels.size(); ++i) {
    if (int(i % size_t(a.channels)) >= 3) continue;
    sumA += a.pixels[i] - 0.4;
    sumB += b.pixels[i] - 0.4;
    worst = std::max(worst, double(std::abs(a.pixels[i] - b.pixels[i])));
  }
  EXPECT_GT(std::abs(sumB), 10.0) << "the object should stand out of the plate";
  EXPECT_NEAR(sumA / sumB, 1.0, 0.01);
  EXPECT_LT(worst, 0.01);
}

// The issue's bad input: each a named error, a non-zero exit and nothing written.
class BadEnvironmentInput : public ::testing::Test {
 protected:
  void SetUp() override {
    img8_ = Image(8, 8, 3, {"R", "G", "B"});
    for (float& v : img8_.pixels) v = 0.5f;
  }
  fs::path write(const std::string& name, int w, int h) {
    Image img(w, h, 3, {"R", "G", "B"});
    for (float& v : img.pixels) v = 0.5f;
    ingest::writeImage(dir_ / name, img);
    return dir_ / name;
  }
  // Runs, expects `status` and `message` on stderr naming `file`, and no new file but the inputs.
  void expectRefused(const std::string& args, int status, const std::string& message,
                     const std::string& file) {
    const auto before = filesIn(dir_.path());
    const RunResult r = run(args, dir_);
    EXPECT_EQ(r.status, status) << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    EXPECT_NE(r.err.find(file), std::string::npos) << "names the file: " << r.err;
    EXPECT_EQ(filesIn(dir_.path()), before) << "nothing written for: " << args;
  }
  TempDir dir_;
  Image img8_;
};

TEST_F(BadEnvironmentInput, FacesOfDifferentSizes) {
  for (const char* f : {"px", "nx", "py", "ny", "pz"})
    write(std::string("a_") + f + ".exr", 16, 16);
  write("a_nz.exr", 32, 32);
  expectRefused("convert " + q(dir_ / "a_%.exr") + " --to latlong --out " + q(dir_ / "x.exr"), 1,
                "cube faces differ in size: -Z is 32x32, +X (a_px.exr) is 16x16", "a_nz.exr");
}

TEST_F(BadEnvironmentInput, NonSquareFace) {
  for (const char* f : {"px", "nx", "ny", "pz", "nz"})
    write(std::string("b_") + f + ".exr", 16, 16);
  write("b_py.exr", 16, 12);
  expectRefused("convert " + q(dir_ / "b_%.exr") + " --to cube --out " + q(dir_ / "x.exr"), 1,
                "faces layout needs a square face, the image is 16x12", "b_py.exr");
}

TEST_F(BadEnvironmentInput, CrossOfTheWrongAspect) {
  write("cross.exr", 40, 20);
  expectRefused(
      "convert " + q(dir_ / "cross.exr") + " --from hcross --to latlong --out " + q(dir_ / "x.exr"),
      1, "hcross layout needs a 4:3 image of 4N x 3N pixels, the image is 40x20", "cross.exr");
  write("odd.exr", 50, 20);
  expectRefused("--plate " + q(dir_ / "odd.exr") + " --object " + q(sample("bunny.obj")) +
                    " --env " + q(dir_ / "odd.exr") + " --out " + q(dir_ / "out"),
                1, "cannot tell the environment's layout from a 50x20 image", "odd.exr");
  // The one-shot command has no --layout: its message says how to convert the file instead.
  expectRefused("--plate " + q(dir_ / "odd.exr") + " --object " + q(sample("bunny.obj")) +
                    " --env " + q(dir_ / "odd.exr") + " --out " + q(dir_ / "out"),
                1,
                "convert it first, saying which: compose convert " + (dir_ / "odd.exr").string() +
                    " --layout LAYOUT",
                "odd.exr");
  expectRefused("convert " + q(dir_ / "odd.exr") + " --to cube --out " + q(dir_ / "x.exr"), 1,
                "or 3:4 (vertical cross); say which with --layout (LAYOUT)", "odd.exr");
  // A photo of a 4:3 frame (a merged view) has a horizontal cross's aspect, but fills the cells
  // a cross leaves empty: refused, not read as a cross; --layout hcross reads it as one.
  write("view.exr", 64, 48);
  expectRefused("convert " + q(dir_ / "view.exr") + " --to latlong --out " + q(dir_ / "x.exr"), 1,
                "its cells outside the cross are not empty (1.00 times as bright as the faces)",
                "view.exr");
  const RunResult forced = run("convert " + q(dir_ / "view.exr") +
                                   " --layout hcross --to latlong --out " + q(dir_ / "forced.exr"),
                               dir_);
  EXPECT_EQ(forced.status, 0) << forced.err;
  fs::remove(dir_ / "forced.exr");
  // An output without an extension: said so, naming the file asked for.
  write("ok.exr", 64, 32);
  expectRefused("convert " + q(dir_ / "ok.exr") + " --to cube --out " + q(dir_ / "cube"), 1,
                "the file name has no extension to say its format", (dir_ / "cube").string() + ")");
}

TEST_F(BadEnvironmentInput, MissingFace) {
  fs::create_directories(dir_ / "faces");
  for (const char* f : {"px", "nx", "py", "ny", "nz"})
    write(std::string("faces/c_") + f + ".exr", 8, 8);
  expectRefused("convert " + q(dir_ / "faces") + " --to latlong --out " + q(dir_ / "x.exr"), 1,
                "missing cube face +Z", "faces");
  expectRefused(
      "convert " + q(dir_ / "faces" / "c_px.exr") + " --to latlong --out " + q(dir_ / "x.exr"), 1,
      "missing cube face +Z: expected c_pz.exr", "c_pz.exr");
}

TEST_F(BadEnvironmentInput, PhotosWithoutIntrinsics) {
  std::string photos;
  for (const char* f : {"px", "nx", "py", "ny", "pz", "nz"}) {
    ingest::writeImage(dir_ / (std::string("p_") + f + ".jpg"), img8_);
    photos += " " + q(dir_ / (std::string("p_") + f + ".jpg"));
  }
  expectRefused("stitch --out " + q(dir_ / "env.exr") + photos, 1,
                "no intrinsics for this photo: its EXIF has no 35 mm equivalent focal length; "
                "give --fov DEG or --calib LENS.json",
                "p_px.jpg");
}

TEST_F(BadEnvironmentInput, MirrorBallCropNotSquare) {
  write("ball.exr", 30, 20);
  expectRefused("convert " + q(dir_ / "ball.exr") + " --from mirrorball --to latlong --out " +
                    q(dir_ / "x.exr"),
                1, "a mirror-ball photo must be cropped square to the ball, this one is 30x20",
                "ball.exr");
}

TEST_F(BadEnvironmentInput, BadCommandLinesExitTwoBeforeReadingFiles) {
  expectRefused("convert missing.exr --to sphere --out " + q(dir_ / "x.exr"), 2,
                "--to must be one of", "sphere");
  expectRefused("stitch --fov 200 --out " + q(dir_ / "x.exr") + " missing_px.jpg", 2,
                "--fov must be a field of view", "--fov");
  expectRefused("stitch --fov 90 --out " + q(dir_ / "x.exr") + " a.jpg b.jpg", 2,
                "cannot tell where a.jpg points", "a.jpg");
  expectRefused(
      "--plate p.jpg --object o.obj --room 4,3,4 --capture-at 9,1,0 --out " + q(dir_ / "out"), 2,
      "is not inside the room", "(9, 1, 0)");
  // Sizes: zero is not a default, and what is asked for is held to the pixel limit (a
  // 40000-wide lat-long asked for 18.9 GB and ended in bad_alloc).
  expectRefused("convert missing.exr --to cube --size 0 --out " + q(dir_ / "x.exr"), 2,
                "--size must be 1..16384 texels; got 0", "--size");
  expectRefused("convert missing.exr --to latlong --width 0 --out " + q(dir_ / "x.exr"), 2,
                "--width must be an even number of texels, 2..65536; got 0", "--width");
  expectRefused("convert missing.exr --to latlong --width 40000 --out " + q(dir_ / "x.exr"), 2,
                "--width 40000 makes a map of 800 megapixels, more than the limit of 268",
                "--max-pixels");
  expectRefused(
      "--max-pixels 1000000 convert missing.exr --to cube --size 1000 --out " + q(dir_ / "x.exr"),
      2, "--size 1000 makes a map of 6 megapixels, more than the limit of 1", "--size");
  expectRefused(
      "--max-pixels 1000 convert missing.exr --to cube --size 32 --out " + q(dir_ / "x.exr"), 2,
      "--size 32 makes a map of 6144 pixels, more than the limit of 1000", "--size");
  // Options of the mirror-ball unwrapping were ignored for other layouts.
  expectRefused("convert missing.exr --to cube --photo-space sRGB --out " + q(dir_ / "x.exr"), 2,
                "--photo-space applies to a mirror-ball photo only (with --from mirrorball)",
                "--photo-space");
  expectRefused("convert missing.exr --to cube --blind-spot 5 --out " + q(dir_ / "x.exr"), 2,
                "--blind-spot applies to a mirror-ball photo only", "--blind-spot");
  // Options of how an OpenEXR or face files are written, given for other files, were ignored;
  // a format nothing writes is said before any file is read.
  expectRefused("convert missing.exr --to cube --face-names words --out " + q(dir_ / "x.exr"), 2,
                "--face-names names face files: it goes with --to faces", "--face-names");
  expectRefused("convert missing.exr --to latlong --compression zip:9 --out " + q(dir_ / "x.hdr"),
                2, "--compression says how an OpenEXR file is written; x.hdr is a .hdr file",
                "x.hdr");
  expectRefused("convert missing.exr --to hcross --depth half --out " + q(dir_ / "x.png"), 2,
                "--depth says how an OpenEXR file is written; x.png is a .png file", "x.png");
  expectRefused(
      "stitch --fov 90 --to faces --depth float --out " + q(dir_ / "f_%.tif") + " a_px.jpg", 2,
      "--depth says how an OpenEXR file is written; f_px.tif is a .tif file", "f_px.tif");
  expectRefused("convert missing.exr --to latlong --out " + q(dir_ / "x.xyz"), 1,
                "no image writer for the extension '.xyz'", "x.xyz");
  // The same in stitch.
  expectRefused("stitch --fov 90 --size 0 --out " + q(dir_ / "x.exr") + " a_px.jpg", 2,
                "--size must be 8..8192; got 0", "--size");
  expectRefused("stitch --fov 90 --width 256 --out " + q(dir_ / "x.exr") + " a_px.jpg", 2,
                "--width is the width of a lat-long map: it goes with --to latlong", "--width");
  expectRefused(
      "stitch --fov 90 --no-refine --max-correction 5 --out " + q(dir_ / "x.exr") + " a_px.jpg", 2,
      "--max-correction bounds the refinement", "--no-refine");
  // Exposure gains are measured on the refinement's matches: with --no-refine the photos kept
  // their exposures, each gain 1, exit 0.
  expectRefused("stitch --fov 90 --no-refine --gains on --out " + q(dir_ / "x.exr") + " a_px.jpg",
                2, "--gains on needs the refinement's feature matching", "--no-refine");
  expectRefused(
      "stitch --fov 90 --no-refine --feature-size 300 --out " + q(dir_ / "x.exr") + " a_px.jpg", 2,
      "--feature-size needs the refinement's feature matching", "--no-refine");
  // An EXR codec it does not know, in every command that writes EXRs.
  expectRefused("convert missing.exr --to cube --compression lzw --out " + q(dir_ / "x.exr"), 2,
                "unknown OpenEXR compression 'lzw'", "--compression");
  expectRefused("stitch --fov 90 --compression zip:11 --out " + q(dir_ / "x.exr") + " a_px.jpg", 2,
                "the level of 'zip' must be a whole number 0-9, got '11'", "--compression");
  expectRefused("merge --compression piz:1 --out " + q(dir_ / "x.exr") + " a.jpg b.jpg", 2,
                "the OpenEXR compression 'piz' takes no level", "--compression");
  // The virtual camera's truth images are the ground truth: lossless only.
  expectRefused("capture-sim --env missing.exr --out " + q(dir_ / "shots") +
                    " --truth-images --compression b44",
                2, "--compression b44 loses information: the truth images are the ground truth",
                "--compression");
}

// Radiance above 1 is not written into 8- or 16-bit codes: a PNG, JPEG or TIFF of an HDR map is
// refused, naming the file and the formats that keep it, and nothing is written; Radiance's .hdr
// keeps the sun (within its shared-exponent precision). compose color writes OpenEXR only.
TEST(ConvertCommand, RadianceGoesToFormatsOfFloatsOnly) {
  if (!fs::exists(sample("forest.exr"))) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  TempDir dir;
  const fs::path outs = dir / "outputs";
  fs::create_directory(outs);
  for (const std::string& args : {std::string(" --to cube --out ") + q(outs / "forest.png"),
                                  std::string(" --to latlong --out ") + q(outs / "forest.jpg"),
                                  std::string(" --to faces --out ") + q(outs / "forest_%.png"),
                                  std::string(" --to latlong --out ") + q(outs / "forest.tif")}) {
    SCOPED_TRACE(args);
    const RunResult r = run("convert " + q(sample("forest.exr")) + args, dir);
    EXPECT_EQ(r.status, 1) << r.err;
    EXPECT_NE(r.err.find("file of 8- or 16-bit codes would clip to 1: write OpenEXR (.exr) or "
                         "Radiance (.hdr)"),
              std::string::npos)
        << r.err;
    EXPECT_NE(r.err.find("forest"), std::string::npos) << r.err;
    EXPECT_TRUE(fs::is_empty(outs)) << "nothing written";
  }
  const RunResult tif = run(
      "convert " + q(sample("forest.exr")) + " --to latlong --width 256 --out " + q(dir / "f.hdr"),
      dir);
  ASSERT_EQ(tif.status, 0) << tif.err;
  const RunResult exr = run(
      "convert " + q(sample("forest.exr")) + " --to latlong --width 256 --out " + q(dir / "f.exr"),
      dir);
  ASSERT_EQ(exr.status, 0) << exr.err;
  const ingest::LoadedImage a = ingest::readImage(dir / "f.hdr"),
                            b = ingest::readImage(dir / "f.exr");
  ASSERT_EQ(a.image.pixels.size(), b.image.pixels.size());
  float largest = 0.0f;
  double worst = 0.0;
  for (size_t i = 0; i < a.image.pixels.size(); i += 3) {
    // RGBE: 8 bits of mantissa for the largest channel of each texel.
    const float ea = std::max({a.image.pixels[i], a.image.pixels[i + 1], a.image.pixels[i + 2]});
    const float eb = std::max({b.image.pixels[i], b.image.pixels[i + 1], b.image.pixels[i + 2]});
    if (eb > 1e-3f) worst = std::max(worst, std::abs(double(ea) / double(eb) - 1.0));
    largest = std::max(largest, ea);
  }
  EXPECT_LT(worst, 0.01);
  EXPECT_GT(largest, 100.0f) << "the sun's radiance is kept";

  const RunResult color =
      run("color " + q(sample("forest.exr")) + " --out " + q(outs / "forest_acescg.png"), dir);
  EXPECT_EQ(color.status, 2) << color.err;
  EXPECT_NE(color.err.find("--out must name an OpenEXR file (.exr)"), std::string::npos)
      << color.err;
  EXPECT_TRUE(fs::is_empty(outs)) << "nothing written";
}

// Face files: a missing face is named with the file it expected; a pattern holds one '%'. Sizes:
// --width is a lat-long's, --size a cube's faces (or a lat-long 4 x size wide).
TEST(ConvertCommand, FacePatternsAndSizesSayWhatIsWrong) {
  if (!fs::exists(sample("forest.exr"))) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  TempDir dir;
  ASSERT_EQ(run("convert " + q(sample("forest.exr")) + " --to faces --size 16 --out " +
                    q(dir / "f_%.exr"),
                dir)
                .status,
            0);
  fs::remove(dir / "f_ny.exr");
  RunResult r =
      run("convert " + q(dir / "f_%.exr") + " --to latlong --out " + q(dir / "l.exr"), dir);
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("missing cube face -Y: expected f_ny.exr beside the pattern's 5 other "
                       "faces"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "l.exr"));
  r = run("convert " + q(sample("forest.exr")) + " --to faces --size 8 --out " + q(dir / "%_%.exr"),
          dir);
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("a face pattern holds one '%'"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "px_%.exr"));
  // A base name without an extension, as the help has it: OpenEXR faces base_px.exr ...; a
  // failed write into a new folder leaves no empty folder behind.
  r = run("convert " + q(sample("forest.exr")) + " --to faces --size 8 --out " +
              q(dir / "new" / "base"),
          dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "new" / "base_px.exr"));
  EXPECT_TRUE(fs::exists(dir / "new" / "base_nz.exr"));
  r = run("convert " + q(sample("forest.exr")) + " --to faces --size 8 --out " +
              q(dir / "none" / "deeper" / "base.bmp"),
          dir);
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_FALSE(fs::exists(dir / "none")) << r.err;
  r = run("convert " + q(sample("forest.exr")) + " --to cube --width 64 --out " + q(dir / "c.exr"),
          dir);
  EXPECT_EQ(r.status, 2) << r.err;
  EXPECT_NE(r.err.find("--width is the width of a lat-long output"), std::string::npos) << r.err;
  r = run("convert " + q(sample("forest.exr")) + " --to latlong --size 16 --width 64 --out " +
              q(dir / "l.exr"),
          dir);
  EXPECT_EQ(r.status, 2) << r.err;
  r = run(
      "convert " + q(sample("forest.exr")) + " --to latlong --size 16 --out " + q(dir / "l16.exr"),
      dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(ingest::readImage(dir / "l16.exr").image.width, 64);
}

// A picture of 8-bit codes (an sRGB PNG) written as OpenEXR holds linear light: the sRGB curve
// undone, as compose reads that picture with --env and as other tools read an EXR; written back
// as a PNG it is encoded again, and every code comes back.
TEST(ConvertCommand, CodesBecomeLinearLightInAnExrAndComeBack) {
  TempDir dir;
  Image codes(64, 32, 3, {"R", "G", "B"});
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 64; ++x)
      for (int c = 0; c < 3; ++c)
        codes.pixels[(size_t(y) * 64 + size_t(x)) * 3 + size_t(c)] =
            float((x * 4 + y * 8 + c * 85) % 256) / 255.0f;
  ingest::writeImage(dir / "codes.png", codes);
  const RunResult toExr =
      run("convert " + q(dir / "codes.png") + " --to latlong --out " + q(dir / "linear.exr"), dir);
  ASSERT_EQ(toExr.status, 0) << toExr.err;
  EXPECT_NE(toExr.err.find("its uint8 values read as 'sRGB - Texture'"), std::string::npos)
      << toExr.err;
  const ingest::LoadedImage linear = ingest::readImage(dir / "linear.exr");
  ASSERT_EQ(linear.image.pixels.size(), codes.pixels.size());
  double worst = 0.0;
  for (size_t i = 0; i < codes.pixels.size(); ++i) {
    const double v = codes.pixels[i];
    const double expected = v <= 0.04045 ? v / 12.92 : std::pow((v + 0.055) / 1.055, 2.4);
    worst = std::max(worst, std::abs(double(linear.image.pixels[i]) - expected));
  }
  EXPECT_LT(worst, 1e-4) << "the sRGB curve undone";

  const RunResult toPng =
      run("convert " + q(dir / "linear.exr") + " --to latlong --out " + q(dir / "back.png"), dir);
  ASSERT_EQ(toPng.status, 0) << toPng.err;
  const ingest::LoadedImage back = ingest::readImage(dir / "back.png");
  ASSERT_EQ(back.image.pixels.size(), codes.pixels.size());
  int moved = 0;
  for (size_t i = 0; i < codes.pixels.size(); ++i)
    moved = std::max(moved,
                     int(std::lround(std::abs(back.image.pixels[i] - codes.pixels[i]) * 255.0f)));
  EXPECT_EQ(moved, 0) << "codes that moved";
}

// Resampling averages light: a map written as codes (PNG) is resampled in linear light and
// encoded afterwards, from a map of floats or of codes alike, and a mirror-ball photo is
// unwrapped so. A checkerboard of 0 and 1 in blocks of 2x2 texels averages to 0.5 over a texel
// of an 8x8 cube (its codes averaged as stored gave 0.21: 57 % of the light lost, with a note that
// the energy agreed). A repacking without resampling keeps the codes.
TEST(ConvertCommand, CodesAreResampledAsLight) {
  TempDir dir;
  Image checker(256, 128, 3, {"R", "G", "B"});
  for (int y = 0; y < 128; ++y)
    for (int x = 0; x < 256; ++x)
      for (int c = 0; c < 3; ++c) checker.at(x, y)[c] = float(((x / 2) + (y / 2)) % 2);
  ingest::WriteOptions floats;
  floats.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "checker.exr", checker, floats);
  ingest::writeImage(dir / "checker.png", checker);
  // The linear mean of a written file of codes (sRGB) or floats.
  auto linearMean = [](const fs::path& file) {
    const ingest::LoadedImage read = ingest::readImage(file);
    const bool codes = read.info.integerSamples();
    double sum = 0.0;
    for (float v : read.image.pixels)
      sum += !codes || v <= 0.04045f ? (codes ? v / 12.92 : v) : std::pow((v + 0.055) / 1.055, 2.4);
    return sum / double(read.image.pixels.size());
  };
  for (const char* in : {"checker.exr", "checker.png"}) {
    for (const auto& [args, out] :
         std::vector<std::pair<std::string, std::string>>{{"--to cube --size 8", "cube.png"},
                                                          {"--to latlong --width 32", "small.png"},
                                                          {"--to cube --size 8", "cube.exr"}}) {
      const RunResult r =
          run("convert " + q(dir / in) + " " + args + " --out " + q(dir / out), dir);
      ASSERT_EQ(r.status, 0) << in << " " << args << ": " << r.err;
      EXPECT_NEAR(linearMean(dir / out), 0.5, 0.01) << in << " -> " << out;
    }
    // The same size: a change of layout moves codes, resamples nothing.
    const RunResult cube =
        run("convert " + q(dir / in) + " --to cube --size 16 --out " + q(dir / "c16.png"), dir);
    ASSERT_EQ(cube.status, 0) << cube.err;
    const RunResult cross =
        run("convert " + q(dir / "c16.png") + " --to vcross --out " + q(dir / "c16cross.png"), dir);
    ASSERT_EQ(cross.status, 0) << cross.err;
    const Pixels a = ingest::readImage(dir / "c16.png").image.pixels;
    std::vector<float> sortedA(a.begin(), a.end()), sortedB;
    for (float v : ingest::readImage(dir / "c16cross.png").image.pixels)
      if (v > 0.0f) sortedB.push_back(v);  // the cross's empty corners are black
    sortedA.erase(std::remove(sortedA.begin(), sortedA.end(), 0.0f), sortedA.end());
    std::sort(sortedA.begin(), sortedA.end());
    std::sort(sortedB.begin(), sortedB.end());
    EXPECT_EQ(sortedA, sortedB) << in << ": codes changed by a repacking";
  }
  // A mirror ball of the same checker (in the ball's image) unwrapped into codes.
  Image ball(128, 128, 3, {"R", "G", "B"});
  for (int y = 0; y < 128; ++y)
    for (int x = 0; x < 128; ++x)
      for (int c = 0; c < 3; ++c) ball.at(x, y)[c] = float(((x / 2) + (y / 2)) % 2);
  ingest::writeImage(dir / "ball.png", ball);
  const RunResult r =
      run("convert " + q(dir / "ball.png") + " --from mirrorball --to latlong --width 32 --out " +
              q(dir / "ball_ll.png"),
          dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NEAR(linearMean(dir / "ball_ll.png"), 0.5, 0.03);
}

// 8- and 16-bit TIFFs are codes as PNGs are: convert linearises them the same way (a rule for
// float images must not take them for linear light); a float TIFF is linear light already.
TEST(ConvertCommand, IntegerTiffsAreCodesAndFloatTiffsAreLight) {
  TempDir dir;
  Image codes(64, 32, 3, {"R", "G", "B"});
  for (size_t i = 0; i < codes.pixels.size(); ++i) codes.pixels[i] = float(i % 256) / 255.0f;
  ingest::writeImage(dir / "codes.png", codes);
  ingest::WriteOptions sixteen;
  sixteen.depth = ingest::WriteOptions::Depth::UInt16;
  ingest::writeImage(dir / "codes8.tif", codes);
  ingest::writeImage(dir / "codes16.tif", codes, sixteen);
  ingest::WriteOptions floats;
  floats.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "light.tif", codes, floats);
  std::map<std::string, Pixels> out;
  for (const char* name : {"codes.png", "codes8.tif", "codes16.tif", "light.tif"}) {
    const RunResult r = run(
        "convert " + q(dir / name) + " --to latlong --out " + q(dir / (std::string(name) + ".exr")),
        dir);
    ASSERT_EQ(r.status, 0) << name << ": " << r.err;
    out[name] = ingest::readImage(dir / (std::string(name) + ".exr")).image.pixels;
  }
  for (const char* name : {"codes8.tif", "codes16.tif"}) {
    ASSERT_EQ(out[name].size(), out["codes.png"].size());
    double worst = 0.0;
    for (size_t i = 0; i < out[name].size(); ++i)
      worst = std::max(worst, double(std::abs(out[name][i] - out["codes.png"][i])));
    EXPECT_LT(worst, 1e-4) << name;
  }
  // Code 128 is 0.2158 once decoded; as light it stays 0.502.
  EXPECT_NEAR(out["codes.png"][128], 0.2158605f, 1e-4);
  EXPECT_NEAR(out["light.tif"][128], 128.0f / 255.0f, 1e-4);
}

// A map of 16-bit codes is written with 16 bits (it came out 8-bit, 256 codes made one, even
// through a repacking), and the clipped white of a photo stays white through linear light and
// back (a value a float step above 1 refused the map as HDR).
TEST(ConvertCommand, SixteenBitCodesStaySixteenBitAndClippedWhiteStaysWhite) {
  TempDir dir;
  Image ramp(128, 64, 3, {"R", "G", "B"});
  for (size_t i = 0; i < ramp.pixels.size(); ++i)
    ramp.pixels[i] = float((i * 97) % 65536) / 65535.0f;
  ingest::WriteOptions sixteen;
  sixteen.depth = ingest::WriteOptions::Depth::UInt16;
  ingest::writeImage(dir / "ramp.png", ramp, sixteen);
  for (const auto& [in, args, out] :
       std::vector<std::array<std::string, 3>>{{"ramp.png", "--to hcross", "cross.png"},
                                               {"cross.png", "--to vcross", "vcross.png"},
                                               {"cross.png", "--to faces", "face_%.tif"}}) {
    const RunResult r = run("convert " + q(dir / in) + " " + args + " --out " + q(dir / out), dir);
    ASSERT_EQ(r.status, 0) << args << ": " << r.err;
  }
  for (const char* out : {"cross.png", "vcross.png", "face_px.tif"})
    EXPECT_EQ(ingest::readCaptureInfo(dir / out, "ingest").sampleType, "uint16") << out;
  // A repacking moves codes: the same values, 16-bit ones among them.
  auto sortedNonZero = [](const fs::path& file) {
    std::vector<float> v;
    for (float x : ingest::readImage(file).image.pixels)
      if (x > 0.0f) v.push_back(x);
    std::sort(v.begin(), v.end());
    return v;
  };
  const std::vector<float> cross = sortedNonZero(dir / "cross.png");
  EXPECT_EQ(sortedNonZero(dir / "vcross.png"), cross);
  size_t fine = 0;
  for (float x : cross) fine += std::abs(x * 255.0f - std::round(x * 255.0f)) > 1e-3f;
  EXPECT_GT(fine, cross.size() / 2) << "codes between 8-bit steps";

  // A bright photo clipped at white, as a lat-long JPEG; its cube in PNG codes.
  Image bright(512, 256, 3, {"R", "G", "B"});
  for (int y = 0; y < 256; ++y)
    for (int x = 0; x < 512; ++x)
      for (int c = 0; c < 3; ++c)
        bright.at(x, y)[c] = std::min(1.0f, 0.3f + 0.9f * float((x * 7 + y * 3 + c) % 64) / 63.0f);
  ingest::writeImage(dir / "bright.jpg", bright);
  for (const char* out : {"bright_cross.png", "bright_cube.tif"}) {
    const RunResult r =
        run("convert " + q(dir / "bright.jpg") + " --to hcross --out " + q(dir / out), dir);
    ASSERT_EQ(r.status, 0) << out << ": " << r.err;
  }
}

// A conversion of layouts changes no value: negative texels (the ringing of a resize around the
// sun, out-of-gamut colours) are kept, with a note, through the cube and back, and the energy
// with them (they were clamped: the map came back brighter).
TEST(ConvertCommand, NegativeTexelsAreKept) {
  TempDir dir;
  Image map(64, 32, 3, {"R", "G", "B"});
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 64; ++x)
      for (int c = 0; c < 3; ++c)
        map.at(x, y)[c] = (x / 8 + y / 8) % 2 ? 1.0f : (c == 0 ? -0.25f : 0.5f);
  ingest::WriteOptions floats;
  floats.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "neg.exr", map, floats);
  RunResult r =
      run("convert " + q(dir / "neg.exr") + " --to cube --size 16 --out " + q(dir / "c.exr"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("had negative values (as low as -0.25): kept"), std::string::npos) << r.err;
  r = run("convert " + q(dir / "c.exr") + " --to latlong --out " + q(dir / "back.exr"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  const Image back = ingest::readImage(dir / "back.exr").image;
  float lowest = 0.0f;
  for (float v : back.pixels) lowest = std::min(lowest, v);
  EXPECT_LT(lowest, -0.1f) << "the negative red is kept";
  lighting::SanitizeReport keep;
  keep.keepNegative = true;
  EXPECT_LT(relativeEnergy(lighting::integral(Environment::fromLatLong(back, {}, &keep)),
                           lighting::integral(Environment::fromLatLong(map, {}, &keep))),
            1e-4);
  // Radiance's shared exponent holds no sign: negative texels are written as 0, said so (they
  // came back as large positive values, -0.25 red as 1.46, the map brighter by a third).
  r = run("convert " + q(dir / "neg.exr") + " --to latlong --out " + q(dir / "neg.hdr"), dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("values below 0 (as low as -0.25 in"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("are written as 0: a .hdr file holds no negative values"), std::string::npos)
      << r.err;
  const Image hdr = ingest::readImage(dir / "neg.hdr").image;
  ASSERT_EQ(hdr.pixels.size(), map.pixels.size());
  for (size_t i = 0; i < hdr.pixels.size(); ++i)
    ASSERT_NEAR(hdr.pixels[i], std::max(map.pixels[i], 0.0f), 0.01f) << "value " << i;
  // Red mostly negative: more negative light than light is no environment.
  for (float& v : map.pixels) v = v < 0.0f ? -2.0f : v;
  ingest::writeImage(dir / "worse.exr", map, floats);
  r = run("convert " + q(dir / "worse.exr") + " --to cube --size 16 --out " + q(dir / "w.exr"),
          dir);
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("the environment's red radiance sums to -"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("its negative texels outweigh its light"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "w.exr"));
}

// Faces named by a base name or a folder (the forms --help gives) are OpenEXRs of linear light,
// as the face pattern's are (they were sRGB-encoded: a texel of 0.5 came out 0.7354, a sun of
// 1e6 at 200); and a value beyond half's range is written as float whatever --depth says (half
// held infinity, which compose then refused to read).
TEST(ConvertCommand, FacesByBaseNameOrFolderAreLinearAndBrightTexelsStayFinite) {
  TempDir dir;
  Image map(64, 32, 3, {"R", "G", "B"});
  for (float& v : map.pixels) v = 0.5f;
  for (int c = 0; c < 3; ++c) map.at(10, 8)[c] = 1e6f;
  ingest::WriteOptions floats;
  floats.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "sun.exr", map, floats);
  fs::create_directories(dir / "folder");
  for (const fs::path& out : {dir / "base", dir / "folder" / ""}) {
    const RunResult r =
        run("convert " + q(dir / "sun.exr") + " --to faces --size 16 --out " + q(out), dir);
    ASSERT_EQ(r.status, 0) << r.err;
  }
  for (const fs::path& face : {dir / "base_py.exr", dir / "folder" / "py.exr"}) {
    ASSERT_TRUE(fs::exists(face)) << face;
    const Image up = ingest::readImage(face).image;
    float least = 1e30f;
    for (float v : up.pixels) least = std::min(least, v);
    EXPECT_NEAR(least, 0.5f, 1e-3f) << face;
  }
  float brightest = 0.0f;
  for (const char* f : {"px", "nx", "py", "ny", "pz", "nz"})
    for (float v : ingest::readImage(dir / ("base_" + std::string(f) + ".exr")).image.pixels)
      brightest = std::max(brightest, v);
  EXPECT_GT(brightest, 1e4f) << "the sun's texel is linear light";
  const RunResult r = run("convert " + q(dir / "sun.exr") + " --to cube --size 16 --depth half " +
                              "--out " + q(dir / "half.exr"),
                          dir);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("instead of the --depth half asked for"), std::string::npos) << r.err;
  for (float v : ingest::readImage(dir / "half.exr").image.pixels) ASSERT_TRUE(std::isfinite(v));
}

// An OpenEXR that says its primaries by chromaticities only (no colorSpace attribute; OpenImageIO
// calls every such file 'Linear') is read as compose --env reads it: as the config's space with
// those primaries, whose name the converted map carries; encoded into a PNG it gives the codes
// of the same map named. Primaries no space has go along as chromaticities, with no name.
TEST(ConvertCommand, ChromaticitiesAloneSayTheSourceSpace) {
  TempDir dir;
  const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
  const auto acescg = colors.chromaticities("ACEScg");
  ASSERT_TRUE(acescg);
  Image map(64, 32, 3, {"R", "G", "B"});
  for (int y = 0; y < 32; ++y)
    for (int x = 0; x < 64; ++x)
      for (int c = 0; c < 3; ++c)
        map.pixels[(size_t(y) * 64 + size_t(x)) * 3 + size_t(c)] =
            0.02f + 0.3f * float((x * 3 + y * 5 + c * 11) % 17) / 17.0f;
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;
  options.chromaticities = acescg;
  map.colorSpace = "ACEScg";
  ingest::writeImage(dir / "named.exr", map, options);
  map.colorSpace.clear();
  ingest::writeImage(dir / "primaries.exr", map, options);
  std::array<double, 8> odd = *acescg;
  odd[0] -= 0.02;  // a red no space of the config has
  options.chromaticities = odd;
  ingest::writeImage(dir / "odd.exr", map, options);
  ASSERT_NE(ingest::readImage(dir / "primaries.exr").info.fileColorSpace, "ACEScg");

  const RunResult cube =
      run("convert " + q(dir / "primaries.exr") + " --to cube --out " + q(dir / "cube.exr"), dir);
  ASSERT_EQ(cube.status, 0) << cube.err;
  EXPECT_NE(cube.err.find("read as 'ACEScg' (by the chromaticities in its header)"),
            std::string::npos)
      << cube.err;
  const ingest::LoadedImage cubeFile = ingest::readImage(dir / "cube.exr");
  EXPECT_EQ(cubeFile.info.fileColorSpace, "ACEScg");
  ASSERT_TRUE(cubeFile.info.chromaticities);
  for (int i = 0; i < 8; ++i)  // stored as float
    EXPECT_NEAR((*cubeFile.info.chromaticities)[size_t(i)], (*acescg)[size_t(i)], 1e-6);

  for (const char* name : {"named", "primaries"}) {
    const RunResult png = run("convert " + q(dir / (std::string(name) + ".exr")) +
                                  " --to latlong --out " + q(dir / (std::string(name) + ".png")),
                              dir);
    ASSERT_EQ(png.status, 0) << png.err;
  }
  EXPECT_EQ(ingest::readImage(dir / "named.png").image.pixels,
            ingest::readImage(dir / "primaries.png").image.pixels);
  // A Radiance file says no primaries and is read as the config's rules say: written in that
  // space, not in ACEScg's.
  const RunResult hdr =
      run("convert " + q(dir / "primaries.exr") + " --to latlong --out " + q(dir / "map.hdr"), dir);
  ASSERT_EQ(hdr.status, 0) << hdr.err;
  EXPECT_NE(hdr.err.find("read as 'ACEScg' and written as"), std::string::npos) << hdr.err;
  EXPECT_NE(hdr.err.find("(as .hdr files are read)"), std::string::npos) << hdr.err;

  const RunResult oddCube =
      run("convert " + q(dir / "odd.exr") + " --to cube --out " + q(dir / "odd_cube.exr"), dir);
  ASSERT_EQ(oddCube.status, 0) << oddCube.err;
  EXPECT_NE(oddCube.err.find("match no space of the colour config"), std::string::npos)
      << oddCube.err;
  const ingest::LoadedImage oddFile = ingest::readImage(dir / "odd_cube.exr");
  ASSERT_TRUE(oddFile.info.chromaticities);
  for (int i = 0; i < 8; ++i)
    EXPECT_NEAR((*oddFile.info.chromaticities)[size_t(i)], odd[size_t(i)], 1e-6);
  EXPECT_NE(oddFile.info.fileColorSpace, "ACEScg");
}

TEST(ConvertCommand, WritesTheCompressionAskedFor) {
  if (!fs::exists(sample("sunset.exr"))) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
  TempDir dir;
  Pixels first;
  for (const char* codec : {"none", "zip:1", "piz"}) {
    SCOPED_TRACE(codec);
    const fs::path out =
        dir / (std::string("latlong_") + (codec[0] == 'z' ? "zip" : codec) + ".exr");
    const RunResult r = run(std::string("convert ") + q(sample("sunset.exr")) +
                                " --to latlong --compression " + codec + " --out " + q(out),
                            dir);
    ASSERT_EQ(r.status, 0) << r.err;
    const ingest::LoadedImage back = ingest::readImage(out);
    const Imf::Compression stored = codec[0] == 'z'   ? Imf::ZIP_COMPRESSION
                                    : codec[0] == 'n' ? Imf::NO_COMPRESSION
                                                      : Imf::PIZ_COMPRESSION;
    EXPECT_EQ(Imf::InputFile(out.c_str()).header().compression(), stored);
    // Lossless: the same numbers whatever the codec.
    if (first.empty()) first = back.image.pixels;
    EXPECT_EQ(back.image.pixels, first);
  }
}

}  // namespace
}  // namespace compose
