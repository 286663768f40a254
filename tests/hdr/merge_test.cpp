// Exposure merging: analytic brackets of known radiance, clipping, bad brackets, response files
// and the per-camera store, alignment of hand-held shots, ghost suppression, 16-bit input.
#include "hdr/merge.h"

#include <cmath>
#include <cstdio>
#include <random>

#include "capture_fixture.h"
#include "hdr/capture_merge.h"
#include "hdr/response.h"

namespace compose::hdr {
namespace {

using compose::testing::captureOnDisk;
using compose::testing::loadSampleEnvironment;
using compose::testing::smallCaptureParams;
using compose::testing::TempDir;

double srgbEncode(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1.0 / 2.4) - 0.055;
}

// A bracket of 8-bit sRGB-coded images of a radiance ramp (no noise, no JPEG): pixel x of row y
// has radiance L = 2^(stops x / W + lowest) · (1, 0.8, 0.6) · (1 + y / H).
struct SyntheticBracket {
  std::vector<Image> images;
  std::vector<double> exposures;
  Image radiance;
};

SyntheticBracket syntheticBracket(int w, int h, std::vector<double> exposures, double stops = 12.0,
                                  double lowest = -8.0) {
  SyntheticBracket b;
  b.exposures = exposures;
  b.radiance = Image(w, h, 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const double l = std::exp2(stops * x / w + lowest) * (1.0 + double(y) / h);
      float* p = b.radiance.at(x, y);
      p[0] = float(l);
      p[1] = float(0.8 * l);
      p[2] = float(0.6 * l);
    }
  for (double e : exposures) {
    Image img(w, h, 3);
    for (size_t i = 0; i < img.pixels.size(); ++i)
      img.pixels[i] = float(std::round(255.0 * srgbEncode(b.radiance.pixels[i] * e)) / 255.0);
    b.images.push_back(std::move(img));
  }
  return b;
}

MergeInput inputOf(const SyntheticBracket& b, const ResponseCurve* curve) {
  MergeInput in;
  for (const Image& img : b.images) in.images.push_back(&img);
  in.exposures = b.exposures;
  in.response = curve;
  return in;
}

TEST(Merge, SyntheticBracketMergesBackToItsRadiance) {
  // With the exact (sRGB) curve and no noise, the only error is 8-bit quantisation: at least
  // one shot sees every unclipped pixel at code >= 30, where half a step is under 2 % in
  // linear light; the median is far below.
  constexpr double kQuantisation = 0.02;
  const SyntheticBracket b = syntheticBracket(256, 16, {0.25, 1.0, 4.0});
  const ResponseCurve srgb = ResponseCurve::srgb();
  for (MergeMethod method : {MergeMethod::Debevec, MergeMethod::Robertson}) {
    MergeParams params;
    params.method = method;
    const MergeResult r = mergeBracket(inputOf(b, &srgb), params);
    ASSERT_EQ(r.radiance.channels, 4);
    EXPECT_EQ(r.radiance.channelNames[3], "clipped");
    std::vector<double> errors;
    for (size_t i = 0; i < r.radiance.pixelCount(); ++i) {
      const float* m = r.radiance.pixels.data() + i * 4;
      const float* t = b.radiance.pixels.data() + i * 3;
      if (m[3] > 0.0f) continue;
      for (int c = 0; c < 3; ++c) errors.push_back(std::abs(m[c] / t[c] - 1.0));
    }
    std::sort(errors.begin(), errors.end());
    EXPECT_LT(errors[errors.size() / 2], kQuantisation / 4) << mergeMethodName(method);
    EXPECT_LT(errors[errors.size() * 95 / 100], kQuantisation) << mergeMethodName(method);
    EXPECT_GT(r.openCvSeconds, 0.0);
  }
}

// A pixel with a code of 0 or 255 in some shot is Debevec's log-domain average without those
// shots, channel by channel (MergeDebevec gives them a small weight, and their value is a bound),
// and the capture's unit multiplies R, G and B, not the mask.
TEST(Merge, ClippedCodesLeaveTheAverageAndTheUnitScalesColourOnly) {
  // From 2^-8 to 2^4: the long shot clips, the short one is black, over most of the ramp.
  const SyntheticBracket b = syntheticBracket(256, 4, {0.25, 1.0, 4.0}, 12.0, -8.0);
  const ResponseCurve srgb = ResponseCurve::srgb();
  const MergeResult plain = mergeBracket(inputOf(b, &srgb), {});
  MergeInput scaledInput = inputOf(b, &srgb);
  scaledInput.scale = {2.0, 3.0, 4.0};
  const MergeResult scaled = mergeBracket(scaledInput, {});
  int redone = 0;
  for (size_t i = 0; i < b.radiance.pixelCount(); ++i) {
    const float* m = plain.radiance.pixels.data() + i * 4;
    const float* s = scaled.radiance.pixels.data() + i * 4;
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(s[c], m[c] * scaledInput.scale[size_t(c)], 1e-6 * std::abs(s[c]));
    EXPECT_EQ(s[3], m[3]);
    if (m[3] > 0.0f) continue;
    // The reference: the triangle weights (their mean over the channels) and logs of every shot
    // whose code in this channel is neither 0 nor 255.
    bool clipped = false;
    for (int c = 0; c < 3; ++c) {
      double sum = 0.0, total = 0.0;
      for (size_t j = 0; j < b.images.size(); ++j) {
        const float* v = b.images[j].pixels.data() + i * 3;
        int z[3];
        double w = 0.0;
        for (int k = 0; k < 3; ++k) {
          z[k] = int(std::lround(v[k] * 255.0));
          w += z[k] < 128 ? z[k] + 1 : 256 - z[k];
        }
        if (z[c] == 0 || z[c] == 255) {
          clipped = true;
          continue;
        }
        sum += w / 3.0 * std::log(srgb.inverse[size_t(c)][size_t(z[c])] / b.exposures[j]);
        total += w / 3.0;
      }
      ASSERT_GT(total, 0.0);
      EXPECT_NEAR(m[c], std::exp(sum / total), 1e-4 * m[c]) << "pixel " << i << " channel " << c;
    }
    redone += clipped;
  }
  EXPECT_GT(redone, 100);  // the ramp's pixels with a clipped code that the merge kept
}

TEST(Merge, PixelsClippedInEveryShotAreFlaggedCountedAndBounded) {
  // From 2^-12 (black in the longest shot) to 2^4 (white in the shortest).
  const SyntheticBracket b = syntheticBracket(256, 4, {0.25, 1.0, 4.0}, 16.0, -12.0);
  const ResponseCurve srgb = ResponseCurve::srgb();
  const MergeResult r = mergeBracket(inputOf(b, &srgb), {});
  // Over-exposed in every shot: some channel at code >= 250 in the shortest; black in every
  // shot: every channel at code <= 4 in the longest. Both can be counted exactly.
  int64_t over = 0, dark = 0;
  for (size_t i = 0; i < b.radiance.pixelCount(); ++i) {
    const float* t = b.radiance.pixels.data() + i * 3;
    const float* m = r.radiance.pixels.data() + i * 4;
    int code = 0;
    for (int c = 0; c < 3; ++c)
      code = std::max(code, int(std::round(255.0 * srgbEncode(t[c] * 0.25))));
    int longCode = 0;
    for (int c = 0; c < 3; ++c)
      longCode = std::max(longCode, int(std::round(255.0 * srgbEncode(t[c] * 4.0))));
    if (code >= 250) {
      ++over;
      EXPECT_EQ(m[3], 1.0f);
      // The shortest shot's value: a lower bound where the code is 255 (up to half a code
      // step, 1 % up there), else close.
      if (code == 255) {
        EXPECT_LE(m[0], t[0] * 1.01f) << "a lower bound";
      } else {
        EXPECT_NEAR(m[0] / t[0], 1.0, 0.01);
      }
    } else if (longCode <= 4) {
      ++dark;
      EXPECT_EQ(m[3], 1.0f);
    } else {
      EXPECT_EQ(m[3], 0.0f);
    }
  }
  EXPECT_GT(over, 0);
  EXPECT_GT(dark, 0);
  EXPECT_EQ(r.saturated, over);
  EXPECT_EQ(r.dark, dark);
  bool noted = false;
  for (const auto& n : r.notes) noted = noted || n.find("over-exposed in every photo") != n.npos;
  EXPECT_TRUE(noted);
}

// A circular fisheye's frame: black beyond its image circle in every shot, which is no picture,
// and a black spot inside it, which is a dark scene a longer exposure would recover. The note
// tells the two apart (it called the corners under-exposed).
TEST(Merge, BlackReachingTheFramesEdgeIsToldApartFromADarkScene) {
  constexpr int kSize = 96;
  SyntheticBracket b = syntheticBracket(kSize, kSize, {0.25, 1.0, 4.0}, 2.0, -3.0);
  int64_t corners = 0, spot = 0;
  for (int y = 0; y < kSize; ++y)
    for (int x = 0; x < kSize; ++x) {
      const double r = std::hypot(x + 0.5 - 0.5 * kSize, y + 0.5 - 0.5 * kSize);
      const bool outside = r > 0.45 * kSize, inside = r < 5.0;
      if (!outside && !inside) continue;
      (outside ? corners : spot)++;
      for (Image& img : b.images)
        for (int c = 0; c < 3; ++c) img.at(x, y)[c] = 0.0f;
    }
  const ResponseCurve srgb = ResponseCurve::srgb();
  const MergeResult r = mergeBracket(inputOf(b, &srgb), {});
  EXPECT_EQ(r.dark, corners + spot);
  EXPECT_EQ(r.outside, corners);
  auto noted = [&](const std::string& count, const std::string& text) {
    for (const auto& n : r.notes)
      if (n.rfind(count + " pixels", 0) == 0 && n.find(text) != n.npos) return true;
    return false;
  };
  EXPECT_TRUE(noted(std::to_string(corners), "reach the frame's edge: no picture"));
  EXPECT_TRUE(noted(std::to_string(spot), "add a longer exposure"));
}

TEST(Merge, BadBracketsAreNamedErrors) {
  const SyntheticBracket b = syntheticBracket(64, 8, {0.25, 1.0, 4.0});
  const ResponseCurve srgb = ResponseCurve::srgb();
  MergeInput in = inputOf(b, &srgb);
  in.names = {"a.jpg", "b.jpg", "c.jpg"};
  const Image small(32, 8, 3);
  in.images[2] = &small;
  COMPOSE_EXPECT_ERROR(mergeBracket(in, {}), "must have the same size");
  COMPOSE_EXPECT_ERROR(mergeBracket(in, {}), "(c.jpg)");
  in = inputOf(b, &srgb);
  in.exposures = {1.0, 1.0, 1.0};
  COMPOSE_EXPECT_ERROR(mergeBracket(in, {}), "all equal");
  MergeParams bad;
  bad.clipLow = 0.9;
  bad.clipHigh = 0.5;
  COMPOSE_EXPECT_ERROR(mergeBracket(inputOf(b, &srgb), bad), "clipping thresholds");
}

// Photos with no pixel between black and clipped (a solid frame, or a bracket far too dark): the
// recovery sampled nothing and divided by the count of samples (SIGFPE), with either photo solid.
TEST(Response, PhotosWithoutMidTonesAreANamedErrorNotACrash) {
  Codes8 black, grey;
  black.width = grey.width = 64;
  black.height = grey.height = 48;
  black.rgb.assign(64 * 48 * 3, 0);
  grey.rgb.assign(64 * 48 * 3, 128);
  for (const Codes8* second : {&black, &grey}) {
    BracketCodes bracket;
    bracket.images = {&black, second};
    bracket.exposures = {1.0, 4.0};
    COMPOSE_EXPECT_ERROR(recoverResponse({bracket}, {}),
                         "the response recovery failed: no pixel is between black and clipped");
  }
}

// One tone curve for the three channels by default (the mean of the channels' curves weighted by
// the pixels that show each code), a curve per channel on request; the curve's source says which.
TEST(Response, OneCurveForTheThreeChannelsOrOnePerChannel) {
  const SyntheticBracket b = syntheticBracket(384, 96, {1.0 / 16.0, 1.0 / 4.0, 1.0, 4.0});
  std::vector<Codes8> codes;
  for (const Image& img : b.images) codes.push_back(toCodes8(img));
  BracketCodes bracket;
  for (const Codes8& c : codes) bracket.images.push_back(&c);
  bracket.exposures = b.exposures;
  const ResponseCurve shared = recoverResponse({bracket}, {});
  EXPECT_EQ(shared.inverse[0], shared.inverse[1]);
  EXPECT_EQ(shared.inverse[0], shared.inverse[2]);
  EXPECT_NE(shared.source.find("one curve for the three channels"), std::string::npos)
      << shared.source;
  RecoveryParams separate;
  separate.sharedCurve = false;
  const ResponseCurve own = recoverResponse({bracket}, separate);
  EXPECT_NE(own.inverse[0], own.inverse[2]);
  EXPECT_NE(own.source.find("a curve per channel"), std::string::npos) << own.source;
  // The shared curve lies between the channels' own at every code (a weighted mean of them).
  for (int z = 1; z < 255; ++z) {
    const float lo = std::min({own.inverse[0][z], own.inverse[1][z], own.inverse[2][z]});
    const float hi = std::max({own.inverse[0][z], own.inverse[1][z], own.inverse[2][z]});
    EXPECT_GE(shared.inverse[0][z], lo * (1.0f - 1e-5f)) << z;
    EXPECT_LE(shared.inverse[0][z], hi * (1.0f + 1e-5f)) << z;
  }
}

TEST(Response, FilesRoundTripAndBadOnesAreRefused) {
  TempDir dir;
  ResponseCurve c = ResponseCurve::srgb();
  c.make = "Acme";
  c.model = "X 1";
  c.observed[2] = {7, 241};
  writeResponse(dir / "r.json", c);
  const ResponseCurve back = readResponse(dir / "r.json");
  EXPECT_EQ(back.inverse[1], c.inverse[1]);
  EXPECT_EQ(back.model, "X 1");
  EXPECT_EQ(back.observed, c.observed);
  EXPECT_EQ(responseFileFor(dir.path(), "Acme Corp.", "X 1 (mk II)").filename(),
            "acme_corp._x_1_mk_ii.json");
  EXPECT_TRUE(responseFileFor(dir.path(), "", "").empty());
  // Names in another script get the exact names' hash: two cameras do not share a file (both
  // were x1.json, the second's curve replacing the first's), nor is a long name refused (a
  // 300-character make failed the merge). ASCII names keep the files they always had.
  const std::filesystem::path first = responseFileFor(dir.path(), "Камера", "X1"),
                              second = responseFileFor(dir.path(), "Зенит", "X1"),
                              starred = responseFileFor(dir.path(), "PENTAX", "*ist DS");
  EXPECT_NE(first, second);
  EXPECT_EQ(first.filename().string().rfind("x1-", 0), 0u) << first;
  EXPECT_EQ(starred.filename(), "pentax_ist_ds.json");
  const std::filesystem::path longName = responseFileFor(dir.path(), std::string(300, 'A'), "B");
  EXPECT_LE(longName.filename().string().size(), 220u);
  EXPECT_NE(longName, responseFileFor(dir.path(), std::string(299, 'A'), "B"));
  c.inverse[0][200] = c.inverse[0][199] * 0.5f;
  COMPOSE_EXPECT_ERROR(writeResponse(dir / "bad.json", c), "decreases at code 200");
  compose::testing::writeText(dir / "bad.json", R"({"format": "compose-response", "version": 1,
      "inverse": [[1, 2], [1, 2], [1, 2]]})");
  COMPOSE_EXPECT_ERROR(readResponse(dir / "bad.json"), "three arrays of 256 numbers");
  // The observed codes are optional (older files), but must make sense when present.
  std::string text = responseText(ResponseCurve::srgb());
  const size_t at = text.find("\"observed\"");
  ASSERT_NE(at, std::string::npos);
  compose::testing::writeText(dir / "bad.json", text.substr(0, at) +
                                                    "\"observed\": [[9, 3], [0, 255], [0, 255]], " +
                                                    text.substr(text.find("\"inverse\"")));
  COMPOSE_EXPECT_ERROR(readResponse(dir / "bad.json"), "first <= last");
  compose::testing::writeText(dir / "bad.json",
                              text.substr(0, at) +
                                  "\"observed\": [[4294967296, 4294967551], [0, 255], [0, 255]], " +
                                  text.substr(text.find("\"inverse\"")));
  COMPOSE_EXPECT_ERROR(readResponse(dir / "bad.json"), "whole numbers");
  compose::testing::writeText(dir / "bad.json",
                              text.substr(0, at) + text.substr(text.find("\"inverse\"")));
  EXPECT_EQ(readResponse(dir / "bad.json").observed[0], (std::array<int, 2>{0, 255}));
  // A flat curve decodes every code alike; one value edited to 3e38 overflowed the merge.
  ResponseCurve flat = ResponseCurve::srgb();
  std::fill(flat.inverse[1].begin(), flat.inverse[1].end(), 0.5f);
  COMPOSE_EXPECT_ERROR(writeResponse(dir / "flat.json", flat),
                       "response curve of channel 1 spans 0 stops from code 0 to 255");
  ResponseCurve huge = ResponseCurve::srgb();
  huge.inverse[2][255] = 3e38f;
  COMPOSE_EXPECT_ERROR(writeResponse(dir / "huge.json", huge), "a camera's spans between 1 and 40");
}

TEST(Response, RecoveredOnceThenReusedFromThePerCameraStore) {
  TempDir dir;
  auto params = smallCaptureParams(3);
  params.width = 192;
  params.height = 144;
  params.views = 2;
  const auto env = loadSampleEnvironment("interior");
  auto on = captureOnDisk(env, params, dir / "capture");
  const auto colors = color::ColorConfig::builtin();
  CaptureMergeOptions options;
  options.responseFolder = dir / "responses";
  const CaptureMergeResult first = mergeCapture(on.capture, on.photos, options, colors);
  EXPECT_TRUE(first.responseRecovered);
  ASSERT_FALSE(first.responseCacheFile.empty());
  EXPECT_EQ(first.responseCacheFile.parent_path(), dir / "responses");
  writeResponse(first.responseCacheFile, first.response);
  const CaptureMergeResult second = mergeCapture(on.capture, on.photos, options, colors);
  EXPECT_FALSE(second.responseRecovered);
  EXPECT_NE(second.linearisation.find("recovery skipped"), std::string::npos)
      << second.linearisation;
  EXPECT_EQ(second.views[0].radiance.pixels, first.views[0].radiance.pixels);
  // Linearising by the colour space instead says so.
  options.response = ResponseMode::ColorSpace;
  const CaptureMergeResult third = mergeCapture(on.capture, on.photos, options, colors);
  EXPECT_NE(third.linearisation.find("not by a camera response"), std::string::npos);
}

TEST(Response, ColorSpaceCurveIsTheSrgbDecoding) {
  const auto colors = color::ColorConfig::builtin();
  const ResponseCurve c = curveFromColorSpace(colors, "sRGB", "lin_rec709");
  const ResponseCurve s = ResponseCurve::srgb();
  for (int z = 1; z < kCodes; ++z)
    EXPECT_NEAR(c.inverse[0][z], s.inverse[0][z], 1e-5f * float(1 + z));
  std::string why;
  EXPECT_EQ(linearSpaceFor(colors, "sRGB - Texture", "", &why), "Linear Rec.709 (sRGB)");
  COMPOSE_EXPECT_ERROR(linearSpaceFor(colors, "sRGB", "no such space"), "no such space");
}

// A camera pointed up or down may tag the shots of one bracket with different orientations
// (its orientation sensor changing its mind): each was turned by its own tag, and the bracket
// merged a photo turned 180° with the others (every pixel wrong, and the curve recovered from
// them stored for the camera). The bracket is one frame of the sensor: every shot is turned as
// the first says, with a note.
TEST(Merge, TheShotsOfABracketAreTurnedAsItsFirstSays) {
  TempDir dir;
  Image picture(24, 16, 3, {"R", "G", "B"});
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 24; ++x)
      for (int c = 0; c < 3; ++c) picture.at(x, y)[c] = 0.1f + 0.03f * float(x) + 0.01f * float(y);
  const double times[3] = {0.25, 1.0, 4.0};
  for (int k = 0; k < 3; ++k) {
    ingest::CaptureInfo info;
    info.exposureTime = times[k];
    info.fNumber = 8.0;
    info.iso = 100.0;
    info.dateTimeOriginal = "2024:05:01 12:00:0" + std::to_string(k);
    ingest::WriteOptions options;
    options.jpegQuality = 100;
    options.attributes = ingest::exifAttributes(info);
    if (k == 1) options.attributes.push_back({"Orientation", 3});
    ingest::writeImage(dir / ("IMG_000" + std::to_string(k + 1) + ".jpg"), picture, options);
  }
  ingest::Capture capture = ingest::groupByExif(ingest::scanShots({dir.path()}), {});
  ASSERT_EQ(capture.views.size(), 1u);
  ASSERT_EQ(capture.views[0].shots.size(), 3u);
  ASSERT_EQ(capture.views[0].shots[1].info.orientation, 3) << "the tag is written";
  const auto photos = readCapturePhotos(capture);
  ASSERT_EQ(photos[0].size(), 3u);
  const ingest::LoadedImage &first = photos[0][0], &turned = photos[0][1];
  ASSERT_FALSE(first.codes.empty());
  EXPECT_EQ(turned.codes, first.codes) << "the same stored pixels, the same way up";
  EXPECT_EQ(turned.info.orientation, 1);
  ASSERT_EQ(turned.notes.size(), 1u);
  EXPECT_EQ(turned.notes[0],
            "IMG_0002.jpg is tagged with EXIF orientation 3, IMG_0001.jpg with 1: turned as the "
            "bracket's first photo says (a bracket is one frame of the sensor)");
}

// A 16 x 8 bracket of one radiance (linear Rec.709) as 16-bit TIFFs at exposures 1/4, 1 and 4,
// clipped at full scale, linear or sRGB-encoded, merged; with the truth in the working space.
struct DeepBracket {
  CaptureMergeResult merged;
  Image truth;
};
DeepBracket mergeDeepBracket(const TempDir& dir, const glm::vec3& radiance, bool encoded) {
  const double exposures[3] = {0.25, 1.0, 4.0};
  auto srgb = [](float v) {
    return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
  };
  std::vector<ingest::Shot> shots;
  for (int k = 0; k < 3; ++k) {
    Image shot(16, 8, 3, {"R", "G", "B"});
    for (size_t i = 0; i < shot.pixelCount(); ++i)
      for (int c = 0; c < 3; ++c) {
        const float v = std::min(1.0f, radiance[c] * float(exposures[k]));
        shot.pixels[3 * i + size_t(c)] = encoded ? srgb(v) : v;
      }
    ingest::WriteOptions options;
    options.depth = ingest::WriteOptions::Depth::UInt16;
    const auto file = dir / ("s" + std::to_string(k) + ".tif");
    ingest::writeImage(file, shot, options);
    shots.push_back(ingest::scanShots({file}).front());
  }
  ingest::Capture capture;
  capture.views.push_back({"view", shots, {}});
  ingest::setExposures(capture.views[0], {0.25, 1.0, 4.0}, "test");
  std::vector<std::vector<ingest::LoadedImage>> photos(1);
  for (const ingest::Shot& s : capture.views[0].shots)
    photos[0].push_back(ingest::readImage(s.file));
  const auto colors = color::ColorConfig::builtin();
  CaptureMergeOptions options;
  options.responseFolder = dir / "responses";
  options.inputSpace = encoded ? "sRGB - Texture" : "lin_rec709";
  DeepBracket out{mergeCapture(capture, photos, options, colors), Image(1, 1, 3, {"R", "G", "B"})};
  for (int c = 0; c < 3; ++c) out.truth.pixels[size_t(c)] = radiance[c];
  out.truth.colorSpace = "lin_rec709";
  colors.convert(out.truth, colors.workingSpace());
  return out;
}

// A 16-bit bracket whose longer shots clip red alone (a tungsten lamp, a sunset): clipping is
// judged on the values as stored, channel by channel. Judged after the conversion to the
// working space (Rec. 709 (1, 0.3, 0.1) is about (0.72, 0.35, 0.14) in ACEScg, below any
// threshold) the clipped shots took their full weight and red came out 37 % low.
TEST(Merge, ADeepShotClippedInOneChannelIsNotTrusted) {
  for (const bool encoded : {false, true}) {
    SCOPED_TRACE(encoded ? "sRGB-encoded 16-bit" : "linear 16-bit");
    TempDir dir;
    const DeepBracket b = mergeDeepBracket(dir, glm::vec3(2.0f, 0.3f, 0.1f), encoded);
    const float* m = b.merged.views[0].radiance.at(8, 4);
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(m[c] / b.truth.pixels[size_t(c)], 1.0f, 0.01f) << "channel " << c;
  }
}

// A pixel that no shot of a 16-bit bracket can be trusted at although not every shot reads as
// over-exposed: the shortest shot just below its clip level as stored (64240 of 65535, where the
// weight has fallen to 0), the longer ones clipped. It is bounded by the shortest shot and flagged
// as clipped (it was written as black, unflagged).
TEST(Merge, ADeepPixelNoShotIsTrustedAtIsBoundedAndFlagged) {
  TempDir dir;
  const DeepBracket b =
      mergeDeepBracket(dir, glm::vec3(float(64240.0 / 65535.0 / 0.25), 0.3f, 0.1f), false);
  const float* m = b.merged.views[0].radiance.at(8, 4);
  EXPECT_EQ(m[3], 1.0f) << "flagged as clipped";
  for (int c = 0; c < 3; ++c)
    EXPECT_NEAR(m[c] / b.truth.pixels[size_t(c)], 1.0f, 0.01f) << "channel " << c;
  EXPECT_EQ(b.merged.views[0].stats.saturated, 16 * 8);
}

// One small view of the courtyard, three exposures `evStep` stops apart, written and read back.
compose::testing::CaptureOnDisk smallCourtyardCapture(const TempDir& dir, double evStep = 2.0) {
  auto params = smallCaptureParams(3);
  params.evStep = evStep;
  params.width = 96;
  params.height = 72;
  params.views = 1;
  return captureOnDisk(loadSampleEnvironment("courtyard"), params, dir / "capture");
}

// The space a photo declares, as ingest reads it: Adobe RGB's primaries are the camera's RGB (they
// were taken for Rec.709's: red 9.5 % off), and a space the config does not know (a ProPhoto RGB
// profile) or a camera's EXIF "uncalibrated" (65535) is said in a note (they passed in silence).
TEST(Merge, APhotosDeclaredSpaceIsUsedOrItsGuessSaid) {
  TempDir dir;
  const auto on = smallCourtyardCapture(dir);
  const auto colors = color::ColorConfig::builtin();
  auto merged = [&](const std::function<void(ingest::CaptureInfo&)>& tag) {
    ingest::Capture capture = on.capture;
    auto photos = on.photos;
    for (auto& shot : capture.views[0].shots) {
      shot.colorSpace.clear();  // as photos named on the command line: their files say
      tag(shot.info);
    }
    for (auto& photo : photos[0]) tag(photo.info);
    CaptureMergeOptions options;
    options.responseFolder = dir / "responses";
    return mergeCapture(capture, photos, options, colors);
  };
  auto said = [](const CaptureMergeResult& r, const std::string& text) {
    for (const std::string& n : r.notes)
      if (n.find(text) != std::string::npos) return true;
    return false;
  };
  const CaptureMergeResult plain = merged([](ingest::CaptureInfo&) {});
  EXPECT_FALSE(said(plain, "give --input-space")) << "a camera's sRGB JPEG is no guess";
  const CaptureMergeResult adobe = merged([](ingest::CaptureInfo& info) {
    info.fileColorSpace = info.iccProfile = "Adobe RGB (1998)";
    info.colorSpaceByConvention = false;
  });
  EXPECT_NE(adobe.linearisation.find("camera RGB taken as Linear Adobe RGB (1998)"),
            std::string::npos)
      << adobe.linearisation << " / " << plain.linearisation;
  const CaptureMergeResult prophoto = merged([](ingest::CaptureInfo& info) {
    info.fileColorSpace = info.iccProfile = "ProPhoto RGB";
    info.colorSpaceByConvention = false;
  });
  EXPECT_TRUE(said(prophoto, "the file says 'ProPhoto RGB', which the config does not know"));
  EXPECT_TRUE(said(prophoto, "give --input-space to say which it is"));
  const CaptureMergeResult uncalibrated =
      merged([](ingest::CaptureInfo& info) { info.exifUncalibrated = true; });
  EXPECT_TRUE(said(uncalibrated, "uncalibrated (65535), as cameras set to Adobe RGB write"));
}

// What a user gives by hand is used, but what contradicts the photos is said or refused: a
// response file of another camera is noted (it was applied in silence), and exposures given as
// equal for shots 2 stops apart are refused (--exposures 1,1,16 passed with warnings).
TEST(Merge, AResponseOfAnotherCameraAndEqualExposuresForUnequalShots) {
  TempDir dir;
  const auto on = smallCourtyardCapture(dir);
  const auto colors = color::ColorConfig::builtin();
  ResponseCurve other = ResponseCurve::srgb();
  other.make = "Canon";
  other.model = "EOS 5D";
  writeResponse(dir / "canon.json", other);
  CaptureMergeOptions options;
  options.responseFolder = dir / "responses";
  options.response = ResponseMode::File;
  options.responseFile = dir / "canon.json";
  const CaptureMergeResult given = mergeCapture(on.capture, on.photos, options, colors);
  bool said = false;
  for (const std::string& n : given.notes)
    said = said || n.find(
                       "is of 'Canon EOS 5D', the photos of 'compose virtual camera': used "
                       "as given") != std::string::npos;
  EXPECT_TRUE(said);
  ResponseCurve same = other;
  same.make = "compose";
  same.model = "virtual camera";
  writeResponse(dir / "same.json", same);
  options.responseFile = dir / "same.json";
  for (const std::string& n : mergeCapture(on.capture, on.photos, options, colors).notes)
    EXPECT_EQ(n.find("used as given"), std::string::npos) << n;
  ResponseCurve makeOnly = other;  // a file that names the make alone: no contradiction
  makeOnly.make = "COMPOSE";
  makeOnly.model.clear();
  writeResponse(dir / "make.json", makeOnly);
  options.responseFile = dir / "make.json";
  for (const std::string& n : mergeCapture(on.capture, on.photos, options, colors).notes)
    EXPECT_EQ(n.find("used as given"), std::string::npos) << n;

  ingest::Capture equal = on.capture;
  ingest::setExposures(equal.views[0], {1.0, 1.0, 16.0}, "--exposures");
  options.response = ResponseMode::ColorSpace;
  COMPOSE_EXPECT_ERROR(mergeCapture(equal, on.photos, options, colors),
                       "are given exposures 0.00 stops apart (--exposures) but");
  // A third-stop bracket: the longer shots are brighter, as they should be (it was refused).
  TempDir thirds;
  const auto near = smallCourtyardCapture(thirds, 1.0 / 3.0);
  CaptureMergeOptions plain;
  plain.responseFolder = thirds / "responses";
  plain.response = ResponseMode::ColorSpace;
  EXPECT_NO_THROW(mergeCapture(near.capture, near.photos, plain, colors));
}

TEST(Merge, SixteenBitLinearTiffsMergeByOurOwnWeights) {
  // Linear 16-bit data, no JPEG: only noise and quantisation remain.
  constexpr double kMedianError = 0.01;
  TempDir dir;
  auto params = smallCaptureParams(3);
  params.width = 192;
  params.height = 144;
  params.views = 2;
  params.writeJpeg = false;
  params.writeTiff16 = true;
  const auto env = loadSampleEnvironment("sunset");
  auto on = captureOnDisk(env, params, dir / "capture");
  EXPECT_EQ(on.photos[0][0].info.sampleType, "uint16");
  const auto colors = color::ColorConfig::builtin();
  CaptureMergeOptions options;
  options.responseFolder = dir / "responses";
  const CaptureMergeResult merged = mergeCapture(on.capture, on.photos, options, colors);
  EXPECT_TRUE(merged.response.empty()) << "no response for linear data";
  EXPECT_EQ(merged.openCvSeconds, 0.0);
  std::vector<double> errors;
  for (size_t v = 0; v < merged.views.size(); ++v) {
    Image truth = on.simulated.views[v].truth;
    truth.colorSpace = "lin_rec709";
    colors.convert(truth, colors.workingSpace());
    const Image& m = merged.views[v].radiance;
    for (size_t i = 0; i < m.pixelCount(); ++i) {
      const float* a = m.pixels.data() + i * 4;
      const float* t = truth.pixels.data() + i * 3;
      if (a[3] > 0.0f) continue;
      double d = 0.0, r = 0.0;
      for (int c = 0; c < 3; ++c) d += std::abs(a[c] - t[c]), r += std::abs(t[c]);
      if (r > 0.0) errors.push_back(d / r);
    }
  }
  std::sort(errors.begin(), errors.end());
  // The linear data needs no scale: radiance = s / e = K · L with K = 1.
  EXPECT_LT(errors[errors.size() / 2], kMedianError);
}

TEST(Merge, HandHeldShiftsUpToTwentyPixelsAreAlignedWithinOnePixel) {
  constexpr double kAlignment = 1.0;  // pixels, the issue's bound
  TempDir dir;
  auto params = smallCaptureParams(3, 11);
  params.views = 2;
  params.shakePixels = 20.0;
  const auto env = loadSampleEnvironment("courtyard");
  auto on = captureOnDisk(env, params, dir / "capture");
  const auto colors = color::ColorConfig::builtin();
  CaptureMergeOptions options;
  options.responseFolder = dir / "responses";
  options.merge.align = true;
  const CaptureMergeResult merged = mergeCapture(on.capture, on.photos, options, colors);
  double worst = 0.0, largest = 0.0;
  for (size_t v = 0; v < merged.views.size(); ++v) {
    const auto& shots = on.simulated.views[v].shots;
    const glm::dvec2 pivot = shots[1].shift;
    for (size_t i = 0; i < shots.size(); ++i) {
      const glm::dvec2 want = pivot - shots[i].shift;  // the shift that undoes the shake
      const auto got = merged.views[v].stats.shifts[i];
      worst = std::max({worst, std::abs(got[0] - want.x), std::abs(got[1] - want.y)});
      largest = std::max({largest, std::abs(want.x), std::abs(want.y)});
    }
  }
  std::printf("[ figures ] alignment: largest shake %.1f px, worst error %.2f px\n", largest,
              worst);
  EXPECT_GT(largest, 10.0) << "the test needs real shake";
  EXPECT_LE(worst, kAlignment);

  // Small detailed views (a ring of four, 320 x 240) shaken by up to 10 and 20 px: every shift
  // up to 20 px within a pixel. AlignMTB's pyramid alone, deciding on images a few pixels
  // across, put the brightest shot of one view 6.5 px off at 10 px of shake, and at 20 px one
  // shot 15.6 px off.
  for (const auto& [shake, seed] : {std::pair{10.0, uint64_t(1)}, std::pair{20.0, uint64_t(3)}}) {
    TempDir ring;
    auto small = smallCaptureParams(3, seed);
    small.views = 4;
    small.width = 320;
    small.height = 240;
    small.shakePixels = shake;
    auto shaken = captureOnDisk(env, small, ring / "capture");
    CaptureMergeOptions aligned;
    aligned.responseFolder = ring / "responses";
    aligned.merge.align = true;
    const CaptureMergeResult m = mergeCapture(shaken.capture, shaken.photos, aligned, colors);
    double ringWorst = 0.0;
    int counted = 0;
    for (size_t v = 0; v < m.views.size(); ++v) {
      const auto& shots = shaken.simulated.views[v].shots;
      for (size_t i = 0; i < shots.size(); ++i) {
        const glm::dvec2 want = shots[1].shift - shots[i].shift;
        if (i == 1 || std::max(std::abs(want.x), std::abs(want.y)) > 20.0) continue;
        const auto got = m.views[v].stats.shifts[i];
        ringWorst = std::max({ringWorst, std::abs(got[0] - want.x), std::abs(got[1] - want.y)});
        ++counted;
      }
    }
    std::printf(
        "[ figures ] ring of 320 x 240 views shaken by up to %.0f px: %d shifts up to 20 px, "
        "worst error %.2f px\n",
        shake, counted, ringWorst);
    EXPECT_GE(counted, 4);
    EXPECT_LE(ringWorst, kAlignment) << "shake " << shake;
  }
  // A strip of 200 x 60 pixels at the default --max-shift 32, and 160 x 120 at 64: AlignMTB's
  // pyramid went below a few pixels and OpenCV threw (-215 !fixedSize()).
  for (const auto& [w, h, range] : {std::tuple{200, 60, 32}, std::tuple{160, 120, 64}}) {
    TempDir strip;
    auto narrow = smallCaptureParams(3, 2);
    narrow.views = 1;
    narrow.width = w;
    narrow.height = h;
    narrow.shakePixels = 5.0;
    auto shot = captureOnDisk(env, narrow, strip / "capture");
    CaptureMergeOptions aligned;
    aligned.responseFolder = strip / "responses";
    aligned.response = ResponseMode::ColorSpace;
    aligned.merge.align = true;
    aligned.merge.maxShift = range;
    EXPECT_NO_THROW(mergeCapture(shot.capture, shot.photos, aligned, colors)) << w << "x" << h;
  }
}

TEST(Merge, GhostSuppressionKeepsTheReferenceShotWhereSomethingMoved) {
  // A dark square present only in the longest shot (someone walked through): with ghost
  // suppression the merged pixels there follow the other shots.
  SyntheticBracket b = syntheticBracket(128, 32, {0.25, 1.0, 4.0});
  for (int y = 8; y < 24; ++y)
    for (int x = 40; x < 60; ++x)
      for (int c = 0; c < 3; ++c) b.images[2].at(x, y)[c] = 0.1f;
  const ResponseCurve srgb = ResponseCurve::srgb();
  MergeParams plain, deghost;
  deghost.deghost = true;
  const MergeResult with = mergeBracket(inputOf(b, &srgb), deghost);
  const MergeResult without = mergeBracket(inputOf(b, &srgb), plain);
  const float* t = b.radiance.at(50, 16);
  EXPECT_NEAR(with.radiance.at(50, 16)[1] / t[1], 1.0, 0.03);
  EXPECT_GT(std::abs(without.radiance.at(50, 16)[1] / t[1] - 1.0), 0.2);
  EXPECT_GE(with.ghosted, 16 * 20);

  // The same where the middle shot is over-exposed (and the longest, but for the dark square):
  // the reference is the shortest shot, which agrees with the clipped middle one, not the
  // longest, which says less light than the middle shot's clip level (merged 0.002 of the truth).
  SyntheticBracket bright = syntheticBracket(128, 32, {0.25, 1.0, 4.0});
  for (int y = 4; y < 12; ++y)
    for (int x = 88; x < 98; ++x)
      for (int c = 0; c < 3; ++c) bright.images[2].at(x, y)[c] = 0.1f;
  ASSERT_GE(bright.images[1].at(88, 4)[0], 250.0f / 255.0f) << "the middle shot is clipped there";
  ASSERT_LT(bright.images[0].at(97, 11)[0], 250.0f / 255.0f) << "the shortest one is not";
  const MergeResult brightWith = mergeBracket(inputOf(bright, &srgb), deghost);
  for (const auto& [x, y] : {std::pair{88, 4}, std::pair{93, 8}, std::pair{97, 11}})
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(brightWith.radiance.at(x, y)[c] / bright.radiance.at(x, y)[c], 1.0, 0.03)
          << x << "," << y << " channel " << c;
}

}  // namespace
}  // namespace compose::hdr
