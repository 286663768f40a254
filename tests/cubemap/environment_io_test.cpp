// Layouts and their files: orientation through every layout, detection, the exrenvmap cross-check
// and bad input.
#include "cubemap/environment_io.h"

#include <cmath>
#include <cstdlib>
#include <numbers>

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfEnvmapAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfMultiPartOutputFile.h>
#include <OpenEXR/ImfOutputPart.h>
#include <OpenEXR/ImfPartType.h>
#include <OpenEXR/ImfStandardAttributes.h>
#include <glm/geometric.hpp>

#include "color/color.h"
#include "core/numbers.h"
#include "cubemap/layouts.h"
#include "lighting/sphere_resample.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::cubemap {
namespace {

namespace fs = std::filesystem;
using lighting::CubeMap;
using lighting::Environment;
using lighting::kCubeFaces;
using testing::TempDir;

constexpr float kSun = 1000.0f;

// A black lat-long map with one bright texel; returns the texel's centre direction.
Environment sunMap(int width, int sx, int sy, glm::vec3& direction) {
  Image img(width, width / 2, 3, {"R", "G", "B"});
  float* p = img.at(sx, sy);
  p[0] = kSun;
  p[1] = 0.5f * kSun;
  p[2] = 0.25f * kSun;
  const Environment env = Environment::fromLatLong(img);
  direction = env.direction(sx, sy);
  return env;
}

glm::vec3 brightestDirection(const CubeMap& cube) {
  float best = -1.0f;
  glm::vec3 dir(0.0f);
  for (int f = 0; f < kCubeFaces; ++f)
    for (int y = 0; y < cube.size(); ++y)
      for (int x = 0; x < cube.size(); ++x)
        if (cube.radiance(f, x, y).x > best) {
          best = cube.radiance(f, x, y).x;
          dir = cube.direction(f, x, y);
        }
  return dir;
}

glm::vec3 brightestDirection(const Environment& env) {
  float best = -1.0f;
  glm::vec3 dir(0.0f);
  for (int y = 0; y < env.height(); ++y)
    for (int x = 0; x < env.width(); ++x)
      if (env.radiance(x, y).x > best) {
        best = env.radiance(x, y).x;
        dir = env.direction(x, y);
      }
  return dir;
}

double angleDegrees(const glm::vec3& a, const glm::vec3& b) {
  return std::acos(std::clamp(double(glm::dot(glm::normalize(a), glm::normalize(b))), -1.0, 1.0)) *
         180.0 / kPi;
}

TEST(Layouts, DetectedByAspect) {
  EXPECT_EQ(layoutFromAspect(1024, 512), Layout::LatLong);
  EXPECT_EQ(layoutFromAspect(256, 1536), Layout::Cube);
  EXPECT_EQ(layoutFromAspect(1024, 768), Layout::HorizontalCross);
  EXPECT_EQ(layoutFromAspect(768, 1024), Layout::VerticalCross);
  EXPECT_EQ(layoutFromAspect(512, 512), std::nullopt);   // mirror ball or a single face
  EXPECT_EQ(layoutFromAspect(1000, 751), std::nullopt);  // nearly 4:3
  EXPECT_EQ(layoutFromAspect(3088, 2056), std::nullopt);
}

TEST(Layouts, FaceNames) {
  struct Case {
    const char* stem;
    int face;
  };
  for (const Case c :
       {Case{"env_px", 0}, Case{"env_NX", 1}, Case{"sky.posy", 2}, Case{"sky_neg_y", 3},
        Case{"room+Z", 4}, Case{"room-Z", 5}, Case{"right", 0}, Case{"cave_left", 1},
        Case{"cave_top", 2}, Case{"cave-down", 3}, Case{"yard_back", 4}, Case{"yard_front", 5}}) {
    const auto t = faceFromName(c.stem);
    ASSERT_TRUE(t.has_value()) << c.stem;
    EXPECT_EQ(t->face, c.face) << c.stem;
  }
  EXPECT_FALSE(faceFromName("campx").has_value());  // no separator before the token
  EXPECT_FALSE(faceFromName("forest").has_value());
  const auto t = faceFromName("Env_PX");
  EXPECT_EQ(faceNameIn(t->family, 3, t->token), "NY");
}

// The issue's orientation check: one bright texel in a known direction (not on an axis, so that a
// swapped or mirrored axis anywhere would move it), through every layout and back.
TEST(Layouts, OneBrightTexelKeepsItsDirectionThroughEveryLayout) {
  glm::vec3 sun;
  const Environment env = sunMap(128, 37, 21, sun);  // up and to the left of +X, towards -Z
  ASSERT_GT(sun.y, 0.2f);
  const int n = 32;
  const CubeMap cube = lighting::cubeFromLatLong(env, n);
  const double texel = 90.0 / n;  // a cube texel at a face centre, in degrees
  EXPECT_LT(angleDegrees(brightestDirection(cube), sun), texel);

  TempDir dir;
  for (Layout layout :
       {Layout::Cube, Layout::HorizontalCross, Layout::VerticalCross, Layout::Faces}) {
    for (const char* ext : {".exr", ".hdr"}) {
      const fs::path path = dir / (std::string("sun_") + layoutName(layout) +
                                   (layout == Layout::Faces ? "_%" : "") + ext);
      OutputFiles out;
      WriteOptions options;
      options.depth = WriteOptions::Depth::Float;
      writeCubeMap(out, path, cube, layout, options);
      out.commit();
      // Read back with detection only (faces: through the pattern).
      const EnvironmentFile file = readEnvironmentFile({path});
      EXPECT_EQ(file.layout, layout) << file.how;
      const CubeMap back = cubeMapOf(file);
      ASSERT_EQ(back.size(), n);
      // Same texel, same value: every layout is a lossless re-arrangement.
      EXPECT_EQ(brightestDirection(back), brightestDirection(cube)) << layoutName(layout) << ext;
      const double e = (back.integral() - cube.integral()).x / cube.integral().x;
      // .hdr stores RGBE (8-bit mantissas): 1 % per value; EXR float is exact.
      EXPECT_LT(std::abs(e), std::string(ext) == ".hdr" ? 1e-2 : 1e-12) << layoutName(layout);
    }
  }
  // Lat-long files (EXR with envmap=latlong) and the conversion back.
  const Environment round = lighting::latLongFromCube(cube, 128);
  EXPECT_LT(angleDegrees(brightestDirection(round), sun), texel);
  OutputFiles out;
  writeLatLong(out, dir / "sun_ll.exr", round);
  out.commit();
  EXPECT_EQ(exrEnvmapLayout(dir / "sun_ll.exr"), Layout::LatLong);
  const EnvironmentFile ll = readEnvironmentFile({dir / "sun_ll.exr"});
  EXPECT_EQ(ll.layout, Layout::LatLong);
  EXPECT_EQ(brightestDirection(Environment::fromLatLong(ll.image)), brightestDirection(round));
}

// Against the documented layouts (layouts.h, OpenEXR's Imf::CubeMap): a texel on an axis lands
// in the centre of the face named for it, in the right cell of each cross.
TEST(Layouts, AxisTexelsLandInTheirDocumentedCells) {
  const int n = 8;
  for (int face = 0; face < kCubeFaces; ++face) {
    CubeMap cube(n);
    // The texel just right of and below the face centre.
    cube.texel(face, n / 2, n / 2)[0] = 1.0f;
    const Image strip = packFaces(cube, Layout::Cube);
    EXPECT_EQ(strip.at(n / 2, face * n + n / 2)[0], 1.0f) << lighting::faceName(face);
    const Image h = packFaces(cube, Layout::HorizontalCross);
    const int hc[kCubeFaces][2] = {{2, 1}, {0, 1}, {1, 0}, {1, 2}, {3, 1}, {1, 1}};
    EXPECT_EQ(h.at(hc[face][0] * n + n / 2, hc[face][1] * n + n / 2)[0], 1.0f);
    const Image v = packFaces(cube, Layout::VerticalCross);
    if (face == 4) {  // +Z hangs at the bottom, turned 180°: (n/2, n/2) → (n/2 - 1, n/2 - 1)
      EXPECT_EQ(v.at(n + n / 2 - 1, 3 * n + n / 2 - 1)[0], 1.0f);
    } else {
      const int vc[kCubeFaces][2] = {{2, 1}, {0, 1}, {1, 0}, {1, 2}, {1, 3}, {1, 1}};
      EXPECT_EQ(v.at(vc[face][0] * n + n / 2, vc[face][1] * n + n / 2)[0], 1.0f);
    }
    // And the direction of that texel is the face's axis, half a texel off.
    EXPECT_GT(
        glm::dot(cube.direction(face, n / 2, n / 2), glm::vec3(lighting::faceFrame(face).forward)),
        0.98f);  // half a texel off the axis at n = 8: cos = 0.985
  }
}

bool haveExrenvmap() {
  return std::system("command -v exrenvmap >/dev/null 2>&1") == 0;
}

// Bilinear sample of an exrenvmap cube face at our face coordinates (a, b): its texel i sits at
// a = -1 + 2i/(N-1), first and last centres on the face edges.
glm::vec3 sampleExrenvmapFace(const Image& face, double a, double b) {
  const int n = face.width;
  const double x = (a + 1.0) * 0.5 * (n - 1), y = (b + 1.0) * 0.5 * (n - 1);
  const int x0 = std::clamp(int(x), 0, n - 2), y0 = std::clamp(int(y), 0, n - 2);
  const float fx = float(x - x0), fy = float(y - y0);
  auto at = [&](int i, int j) {
    return glm::vec3(face.at(i, j)[0], face.at(i, j)[1], face.at(i, j)[2]);
  };
  return (at(x0, y0) * (1 - fx) + at(x0 + 1, y0) * fx) * (1 - fy) +
         (at(x0, y0 + 1) * (1 - fx) + at(x0 + 1, y0 + 1) * fx) * fy;
}

// The issue's peer check: a cube written here and one written by OpenEXR's exrenvmap from the same
// lat-long map agree. exrenvmap filters with its own kernel (a 5 x 5 supersampled filter of radius
// one texel) and samples face edges, so texel values differ by the two filters on a noisy map;
// both are box-filtered to 16² faces before comparing, where the filters' difference is small and
// any orientation or layout error (a mirrored face is off by the whole picture) is not.
TEST(ExrenvmapCrossCheck, CubesAgreeOnTheSampleHdris) {
  if (!haveExrenvmap()) GTEST_SKIP() << "exrenvmap (Debian package openexr) is not installed";
  TempDir dir;
  for (const char* name : {"courtyard", "forest", "interior", "sunset"}) {
    const fs::path source = pipeline::samplesDirectory() / (std::string(name) + ".exr");
    if (!fs::exists(source)) GTEST_SKIP() << "samples missing: run samples/fetch.sh";
    const int n = 128;
    const fs::path theirs = dir / (std::string(name) + "_exrenvmap.exr");
    const std::string cmd = "exrenvmap -c -w " + std::to_string(n) + " '" + source.string() +
                            "' '" + theirs.string() + "' >/dev/null 2>&1";
    ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
    const EnvironmentFile file = readEnvironmentFile({theirs});
    ASSERT_EQ(file.layout, Layout::Cube) << "exrenvmap's output carries envmap=cube: " << file.how;
    // Our cube on our texel grid, theirs resampled at our texel centres.
    const Environment env = Environment::fromLatLong(ingest::readImage(source).image);
    const CubeMap ours = lighting::cubeFromLatLong(env, n);
    CubeMap resampled(n);
    for (int f = 0; f < kCubeFaces; ++f)
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x) {
          const glm::vec3 L = sampleExrenvmapFace(file.faces[size_t(f)], -1.0 + (2.0 * x + 1) / n,
                                                  -1.0 + (2.0 * y + 1) / n);
          float* t = resampled.texel(f, x, y);
          t[0] = L.x, t[1] = L.y, t[2] = L.z;
        }
    const CubeMap a = lighting::resizeCube(ours, 16), b = lighting::resizeCube(resampled, 16);
    double sum = 0.0;
    int count = 0;
    for (int f = 0; f < kCubeFaces; ++f)
      for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) {
          const glm::vec3 p = a.radiance(f, x, y), q = b.radiance(f, x, y);
          sum += double(glm::length(p - q) / std::max(glm::length(p), 1e-3f));
          ++count;
        }
    const double meanRelative = sum / count;
    const double energy = std::abs(b.integral().x / a.integral().x - 1.0);
    std::printf(
        "%-10s exrenvmap vs here (16^2 faces): mean relative difference %.4f, energy %.4f\n", name,
        meanRelative, energy);
    // Measured 0.5-1.8 % on the four maps; a mirrored or swapped face gives tens of percent.
    constexpr double kFilters = 0.05;
    EXPECT_LT(meanRelative, kFilters) << name;
    // exrenvmap does not conserve energy exactly (point samples of its filter, half floats).
    constexpr double kTheirEnergy = 0.02;
    EXPECT_LT(energy, kTheirEnergy) << name;
  }
}

// And the other way: exrenvmap turns our cube file back into a lat-long map with the sun where it
// belongs, which proves the file's layout and attribute are what OpenEXR expects.
TEST(ExrenvmapCrossCheck, ReadsOurCubeFiles) {
  if (!haveExrenvmap()) GTEST_SKIP() << "exrenvmap (Debian package openexr) is not installed";
  glm::vec3 sun;
  const Environment env = sunMap(256, 150, 40, sun);
  const CubeMap cube = lighting::cubeFromLatLong(env, 64);
  TempDir dir;
  OutputFiles out;
  writeCubeMap(out, dir / "ours.exr", cube, Layout::Cube);
  out.commit();
  const std::string cmd = "exrenvmap -l -w 256 '" + (dir / "ours.exr").string() + "' '" +
                          (dir / "back.exr").string() + "' >/dev/null 2>&1";
  ASSERT_EQ(std::system(cmd.c_str()), 0);
  const Environment back = Environment::fromLatLong(ingest::readImage(dir / "back.exr").image);
  // exrenvmap's lat-long pixel centres sit half a texel from ours and it filters over about a
  // texel: within two lat-long texels (1.4°).
  EXPECT_LT(angleDegrees(brightestDirection(back), sun), 1.5);
}

// A multi-part OpenEXR whose envmap attribute is on its picture's part, not its first (a data
// part written first): the layout is still read from the file.
TEST(Layouts, TheEnvmapAttributeOfAMultiPartFileIsFoundOnAnyPart) {
  compose::testing::TempDir dir;
  const fs::path file = dir / "mp.exr";
  {
    Imf::Header depth(8, 4);
    depth.setName("depth");
    depth.setType(Imf::SCANLINEIMAGE);
    depth.channels().insert("Z", Imf::Channel(Imf::FLOAT));
    Imf::Header picture(8, 4);
    picture.setName("rgba");
    picture.setType(Imf::SCANLINEIMAGE);
    for (const char* c : {"R", "G", "B"}) picture.channels().insert(c, Imf::Channel(Imf::FLOAT));
    Imf::addEnvmap(picture, Imf::ENVMAP_LATLONG);
    const Imf::Header headers[2] = {depth, picture};
    std::vector<float> z(32, 1.0f), rgb(32 * 3, 0.5f);
    Imf::MultiPartOutputFile out(file.c_str(), headers, 2);
    {
      Imf::OutputPart part(out, 0);
      Imf::FrameBuffer fb;
      fb.insert("Z", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(z.data()), sizeof(float),
                                8 * sizeof(float)));
      part.setFrameBuffer(fb);
      part.writePixels(4);
    }
    {
      Imf::OutputPart part(out, 1);
      Imf::FrameBuffer fb;
      for (int c = 0; c < 3; ++c)
        fb.insert(std::string(1, "RGB"[c]),
                  Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(rgb.data() + c), 3 * sizeof(float),
                             24 * sizeof(float)));
      part.setFrameBuffer(fb);
      part.writePixels(4);
    }
  }
  EXPECT_EQ(exrEnvmapLayout(file), Layout::LatLong);
}

TEST(EnvironmentFiles, BadInputIsNamed) {
  TempDir dir;
  auto write = [&](const std::string& name, int w, int h) {
    Image img(w, h, 3, {"R", "G", "B"});
    ingest::writeImage(dir / name, img);
    return dir / name;
  };
  // Faces of different sizes.
  for (const char* f : {"a_px", "a_nx", "a_py", "a_ny", "a_pz"})
    write(std::string(f) + ".exr", 16, 16);
  write("a_nz.exr", 32, 32);
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "a_%.exr"}), "cube faces differ in size");
  // A non-square face.
  for (const char* f : {"b_px", "b_nx", "b_py", "b_ny", "b_pz"})
    write(std::string(f) + ".exr", 16, 16);
  write("b_nz.exr", 16, 12);
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "b_%.exr"}), "square face");
  // A face whose colour is stored otherwise than +X's: the set is read in +X's space, and five
  // faces were read as another space's (a PNG face's codes as linear light).
  fs::create_directories(dir / "c");
  fs::create_directories(dir / "d");
  for (const char* f :
       {"c/px", "c/nx", "c/ny", "c/pz", "c/nz", "d/nx", "d/py", "d/ny", "d/pz", "d/nz"})
    write(std::string(f) + ".exr", 16, 16);
  write("c/py.png", 16, 16);
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "c"}),
                       "cube faces store their colour differently: +Y is integer codes");
  {
    Image img(16, 16, 3, {"R", "G", "B"});
    ingest::WriteOptions o;
    o.chromaticities = color::kAcesAp1Chromaticities;
    ingest::writeImage(dir / "d" / "px.exr", img, o);
  }
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "d"}),
                       "cube faces store their colour differently: -X is floats");
  // A cross a pixel off 4N x 3N: the size it must be (the advice was a convert that refused it).
  write("near.exr", 161, 121);
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "near.exr"}),
                       "a 161x121 image looks like a horizontal cross a few pixels off; a cross "
                       "must be exactly 4N x 3N (160x120 for faces of 40)");
  // A missing face, beside a named face file and in a folder.
  fs::create_directories(dir / "five");
  for (const char* f : {"px", "nx", "py", "ny", "pz"}) {
    Image img(8, 8, 3);
    ingest::writeImage(dir / "five" / (std::string("c_") + f + ".exr"), img);
  }
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "five"}), "missing cube face -Z");
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "five" / "c_px.exr"}), "missing cube face -Z");
  // A cross of the wrong aspect, when the layout is forced.
  const fs::path wide = write("wide.exr", 40, 20);
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({wide}, {Layout::HorizontalCross}),
                       "hcross layout needs a 4:3 image");
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({wide}, {Layout::VerticalCross}), "3:4 image");
  // An aspect that fits nothing, and an ambiguous square.
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({write("odd.exr", 50, 20)}),
                       "cannot tell the environment's layout");
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({write("square.exr", 20, 20)}), "--layout");
  // Two files for one face among six.
  std::vector<fs::path> six;
  for (const char* f : {"d_px", "d_nx", "d_py", "d_ny", "d_pz", "e_pz"})
    six.push_back(write(std::string(f) + ".exr", 8, 8));
  COMPOSE_EXPECT_ERROR(readEnvironmentFile(six), "two files for cube face +Z");
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "nothing.exr"}), "file not found");
}

TEST(EnvironmentFiles, NaNTexelsAreRefused) {
  TempDir dir;
  CubeMap cube(8);
  cube.texel(3, 2, 5)[1] = std::nanf("");
  OutputFiles out;
  WriteOptions options;
  options.depth = WriteOptions::Depth::Float;
  writeCubeMap(out, dir / "nan.exr", cube, Layout::Cube, options);
  out.commit();
  const EnvironmentFile file = readEnvironmentFile({dir / "nan.exr"});
  COMPOSE_EXPECT_ERROR(cubeMapOf(file), "NaN radiance in cube face -Y at texel (2, 5)");
}

TEST(EnvironmentFiles, LoadEnvironmentTurnsCubesIntoLatLongMaps) {
  glm::vec3 sun;
  const Environment env = sunMap(64, 10, 12, sun);
  const CubeMap cube = lighting::cubeFromLatLong(env, 16);
  TempDir dir;
  OutputFiles out;
  WriteOptions options;
  options.depth = WriteOptions::Depth::Float;
  writeCubeMap(out, dir / "cross.exr", cube, Layout::VerticalCross, options);
  out.commit();
  const LoadedEnvironment loaded = loadEnvironment(dir / "cross.exr");
  ASSERT_EQ(loaded.image.width, 64);
  const Environment back = Environment::fromLatLong(loaded.image);
  EXPECT_LT(std::abs(lighting::integral(back).x / lighting::integral(env).x - 1.0), 1e-6);
  EXPECT_LT(angleDegrees(brightestDirection(back), sun), 90.0 / 16);
  ASSERT_FALSE(loaded.notes.empty());
  EXPECT_NE(loaded.notes.back().find("vertical cross"), std::string::npos);
}

// Every layout takes the picture's colour by channel name, as a lat-long map with --env does: a
// cube strip stored as Z, beauty.R, beauty.G, beauty.B lit the object by (Z, R, G) (a red sun
// turned green), and a one-channel Y map was refused by compose convert.
TEST(EnvironmentFiles, EveryLayoutReadsThePicturesChannelsByName) {
  TempDir dir;
  Image strip(8, 48, 4, {"Z", "beauty.R", "beauty.G", "beauty.B"});
  for (size_t i = 0; i < strip.pixelCount(); ++i) {
    float* p = strip.pixels.data() + 4 * i;
    p[0] = 100.0f, p[1] = 1.0f, p[2] = 2.0f, p[3] = 3.0f;
  }
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "layered_cube.exr", strip, options);
  const EnvironmentFile cube = readEnvironmentFile({dir / "layered_cube.exr"});
  ASSERT_TRUE(cube.isCube());
  for (const Image& face : cube.faces) {
    ASSERT_EQ(face.channels, 3);
    EXPECT_EQ(face.pixels[0], 1.0f);
    EXPECT_EQ(face.pixels[1], 2.0f);
    EXPECT_EQ(face.pixels[2], 3.0f);
  }
  Image grey(16, 8, 1, {"Y"});
  for (float& v : grey.pixels) v = 0.5f;
  ingest::writeImage(dir / "grey.exr", grey, options);
  const EnvironmentFile latLong = readEnvironmentFile({dir / "grey.exr"});
  ASSERT_EQ(latLong.image.channels, 3);
  EXPECT_EQ(latLong.image.pixels[0], 0.5f);
  EXPECT_EQ(latLong.image.pixels[2], 0.5f);
  EXPECT_NEAR(lighting::integral(Environment::fromLatLong(latLong.image)).y, 0.5 * 4.0 * kPi, 1e-4);
}

// A lat-long map a texel off 2:1 (an export that rounded its height) is told how to make it 2:1
// (the advice was to convert it with --layout latlong, which refuses it the same way); a folder
// of Radiance faces named .pic is a folder of faces (it held "no cube face files").
TEST(EnvironmentFiles, NearlyLatLongMapsAndRadianceFaces) {
  TempDir dir;
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;
  Image odd(64, 31, 3, {"R", "G", "B"});
  ingest::writeImage(dir / "odd.exr", odd, options);
  const std::string advice =
      "a 64x31 image looks like a lat-long map slightly off 2:1; a lat-long map must be exactly "
      "2:1 "
      "(width = 2 x height): resize it first, e.g. oiiotool " +
      (dir / "odd.exr").string() + " --resize 64x32 -o ENV.exr";
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "odd.exr"}), advice);
  ReadOptions latLong;
  latLong.layout = Layout::LatLong;
  COMPOSE_EXPECT_ERROR(readEnvironmentFile({dir / "odd.exr"}, latLong), advice);

  fs::create_directory(dir / "faces");
  Image face(8, 8, 3, {"R", "G", "B"});
  for (float& v : face.pixels) v = 2.0f;
  for (const char* name : {"px", "nx", "py", "ny", "pz", "nz"}) {
    ingest::writeImage(dir / "faces" / (std::string(name) + ".hdr"), face);
    fs::rename(dir / "faces" / (std::string(name) + ".hdr"),
               dir / "faces" / (std::string(name) + ".pic"));
  }
  const EnvironmentFile faces = readEnvironmentFile({dir / "faces"});
  ASSERT_TRUE(faces.isCube());
  EXPECT_EQ(faces.files.size(), 6u);
  EXPECT_NEAR(faces.faces[0].pixels[0], 2.0f, 0.01f);
}

}  // namespace
}  // namespace compose::cubemap
