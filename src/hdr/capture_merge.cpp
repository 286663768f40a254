#include "hdr/capture_merge.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <optional>

#include "core/error.h"
#include "core/parallel.h"
#include "hdr/opencv_util.h"
#include "ingest/pixel_util.h"

namespace compose::hdr {

namespace fs = std::filesystem;

namespace {

// A camera's make or model as compared: ASCII letters in lower case, spaces trimmed.
std::string lowerTrimmed(const std::string& s) {
  const size_t first = s.find_first_not_of(" \t\r\n"), last = s.find_last_not_of(" \t\r\n");
  std::string out = first == std::string::npos ? std::string() : s.substr(first, last - first + 1);
  for (char& c : out)
    if (c >= 'A' && c <= 'Z') c = char(c - 'A' + 'a');
  return out;
}

// Two makes (or models) of a camera that may be the same: equal as compared, or one not known.
bool sameCamera(const std::string& a, const std::string& b) {
  return a.empty() || b.empty() || lowerTrimmed(a) == lowerTrimmed(b);
}

bool isEightBit(const ingest::CaptureInfo& info) {
  return info.sampleType == "uint8";
}

// Where every shot of a bracket has pixels once moved by its alignment shift (alignBracket:
// shot i's (x, y) lands on (x + dx_i, y + dy_i)): {x0, y0, x1, y1}, empty when nothing is left.
std::array<int, 4> alignedRect(int width, int height,
                               const std::vector<std::array<int, 2>>& shifts) {
  std::array<int, 4> r{0, 0, width, height};
  for (const std::array<int, 2>& d : shifts) {
    r[0] = std::max(r[0], d[0]), r[2] = std::min(r[2], width + d[0]);
    r[1] = std::max(r[1], d[1]), r[3] = std::min(r[3], height + d[1]);
  }
  return r;
}

// The bracket's codes moved by their shifts, `width` x `height` of them from (x0, y0) of the
// aligned frame (within alignedRect).
std::vector<Codes8> alignedCrops(const std::vector<Codes8>& shots,
                                 const std::vector<std::array<int, 2>>& shifts, int x0, int y0,
                                 int width, int height) {
  std::vector<Codes8> out(shots.size());
  for (size_t i = 0; i < shots.size(); ++i) {
    Codes8& c = out[i];
    c.width = width, c.height = height;
    c.rgb.resize(size_t(width) * size_t(height) * 3);
    const uint8_t* from = shots[i].data();
    const size_t stride = size_t(shots[i].width) * 3;
    parallelFor(0, height, [&](int64_t v) {
      const int y = y0 + int(v) - shifts[i][1], x = x0 - shifts[i][0];
      std::copy_n(from + size_t(y) * stride + size_t(x) * 3, size_t(width) * 3,
                  c.rgb.data() + size_t(v) * size_t(width) * 3);
    });
  }
  return out;
}

// A bracket whose exposures are in another order than its pictures' brightness: the exposures
// were given in another order than the photos (or for other photos). Every merge of it would be
// wrong, and a response recovered from it would be stored for the camera, so it is refused.
// Compares the green samples of each pair of shots adjacent in exposure, at most ~65 k pixels
// each: a longer exposure is brighter wherever neither is clipped, whatever the response.
void checkBrightnessOrder(const ingest::View& view,
                          const std::function<float(size_t shot, size_t pixel)>& green,
                          size_t pixels, float tolerance) {
  const size_t n = view.shots.size();
  std::vector<size_t> order(n);
  for (size_t i = 0; i < n; ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return *view.shots[a].exposure < *view.shots[b].exposure;
  });
  const size_t step = std::max<size_t>(1, pixels / 65536);
  for (size_t k = 0; k + 1 < n; ++k) {
    const ingest::Shot& a = view.shots[order[k]];
    const ingest::Shot& b = view.shots[order[k + 1]];
    const double stops = std::log2(*b.exposure / *a.exposure);
    size_t brighter = 0, darker = 0, sampled = 0;
    for (size_t i = 0; i < pixels; i += step, ++sampled) {
      const float va = green(order[k], i), vb = green(order[k + 1], i);
      if (vb > va + tolerance) ++brighter;
      if (vb < va - tolerance) ++darker;
    }
    if (stops < 1.0 / 6.0) {
      // Given the same exposure (within a sixth of a stop, as merging takes exposures as equal):
      // one cannot be brighter almost everywhere (--exposures 1,1,16 for shots 2 stops apart
      // passed with a warning). Closer than half a stop but apart (a third-stop bracket), the
      // longer shot is rightly brighter, and nothing is said either way.
      const size_t more = std::max(brighter, darker), less = std::min(brighter, darker);
      if (2 * more < sampled || more < 20 * less) continue;
      const ingest::Shot& bright = brighter > darker ? b : a;
      const ingest::Shot& dim = brighter > darker ? a : b;
      char text[400];
      std::snprintf(text, sizeof text,
                    "%s and %s are given exposures %.2f stops apart (%s) but %s is brighter in "
                    "%.0f %% of the pixels (darker in %.0f %%): are these the photos' exposures?",
                    a.file.filename().string().c_str(), b.file.filename().string().c_str(), stops,
                    b.exposureSource.c_str(), bright.file.filename().string().c_str(),
                    100.0 * double(more) / double(sampled), 100.0 * double(less) / double(sampled));
      throw Error(kStage, text, dim.file);
    }
    if (stops < 0.5) continue;  // too close for brightness to tell their order reliably
    if (darker <= brighter || darker * 200 < sampled) continue;
    char text[400];
    std::snprintf(text, sizeof text,
                  "%s is given %.1f stops more exposure than %s (%s) but is darker in %.0f %% of "
                  "the pixels (brighter in %.0f %%): are the exposures in the order of the photos?",
                  b.file.filename().string().c_str(), stops, a.file.filename().string().c_str(),
                  b.exposureSource.c_str(), 100.0 * double(darker) / double(sampled),
                  100.0 * double(brighter) / double(sampled));
    throw Error(kStage, text, b.file);
  }
}

// The recovery options given ("--lambda, --curve-per-channel") and the verb that goes with them,
// for the notes that say they were not applied.
std::string notAppliedOptions(const std::vector<std::string>& options) {
  std::string given;
  for (const std::string& o : options) given += (given.empty() ? "" : ", ") + o;
  return given + (options.size() == 1 ? " was" : " were") + " not applied";
}

}  // namespace

void CaptureMergeOptions::validate() const {
  if (response == ResponseMode::File && responseFile.empty())
    throw Error(kStage, "a response file must be named");
  recovery.validate();
  merge.validate();
}

std::string linearSpaceFor(const color::ColorConfig& colors, const std::string& encodedSpace,
                           const std::string& override, std::string* why) {
  if (!override.empty()) {
    if (why) *why = "as given";
    return colors.resolve(override, "the camera's linear colour space");
  }
  // The linear space of the encoded one's primaries (Display P3 photos: linear P3-D65; they were
  // taken as Rec.709's, their colours less saturated), when the config can tell; else linear
  // Rec.709, a camera's sRGB, by its primaries or by name.
  if (const std::string same = colors.linearSpaceWithPrimariesOf(encodedSpace); !same.empty()) {
    if (why) *why = "linear with the primaries of " + encodedSpace;
    return same;
  }
  if (const std::string byPrimaries = colors.spaceWithChromaticities(color::kRec709Chromaticities);
      !byPrimaries.empty()) {
    if (why) *why = "linear Rec.709, taken for the primaries of " + encodedSpace;
    return byPrimaries;
  }
  for (const char* name : {"lin_rec709", "Linear Rec.709 (sRGB)", "Linear Rec.709", "Linear",
                           "linear", "Utility - Linear - sRGB", "lin_srgb"}) {
    if (colors.has(name)) {
      if (why) *why = "linear with the primaries of " + encodedSpace;
      return colors.resolve(name, "a linear colour space");
    }
  }
  if (why) *why = "the config's reference space (it has no linear Rec.709 under a usual name)";
  return colors.resolve("reference", "the reference role");
}

ResponseCurve curveFromColorSpace(const color::ColorConfig& colors, const std::string& encodedSpace,
                                  const std::string& linearSpace) {
  Image ramp(kCodes, 1, 3);
  for (int z = 0; z < kCodes; ++z)
    for (int c = 0; c < 3; ++c) ramp.pixels[size_t(z) * 3 + size_t(c)] = float(z) / 255.0f;
  ramp.colorSpace = encodedSpace;
  colors.convert(ramp, linearSpace);
  ResponseCurve curve;
  for (int c = 0; c < 3; ++c) {
    auto& ch = curve.inverse[size_t(c)];
    ch.resize(kCodes);
    for (int z = 0; z < kCodes; ++z) ch[size_t(z)] = ramp.pixels[size_t(z) * 3 + size_t(c)];
    // Code 0 decodes to 0 (or below): it still means "some light below code 1".
    for (int z = 1; z < kCodes; ++z) {
      if (!(ch[size_t(z)] > ch[size_t(z) - 1]))
        throw Error("color", "the colour space " + encodedSpace +
                                 " does not decode 8-bit codes "
                                 "to increasing linear values; pass --response, or say the "
                                 "photos' space (--input-space; --env-space with compose --env)");
    }
    if (!(ch[1] > 0.0f))
      throw Error("color", "the colour space " + encodedSpace +
                               " decodes code 1 to a non-positive value; say the photos' space "
                               "(--input-space; --env-space with compose --env)");
    ch[0] = 0.5f * ch[1];
  }
  curve.method = "colorspace";
  curve.source = "the decoding curve of " + encodedSpace + " (OpenColorIO)";
  curve.validate();
  return curve;
}

// Median disagreement between adjacent exposures through a stored response above which it is
// checked against a curve recovered from the photos (responseDisagreement): a curve recovered
// from photos of the same setting gives a few per cent.
constexpr double kStoredResponseTolerance = 0.06;

std::vector<std::vector<ingest::LoadedImage>> readCapturePhotos(const ingest::Capture& capture,
                                                                const Progress& progress) {
  std::vector<std::vector<ingest::LoadedImage>> photos;
  size_t total = 0, done = 0;
  for (const auto& v : capture.views) total += v.shots.size();
  for (const auto& v : capture.views) {
    photos.emplace_back();
    for (const auto& s : v.shots) {
      ingest::LoadedImage photo = ingest::readImage(s.file, "merge", {.codesForEightBit = true});
      // A bracket is one frame of the sensor: a camera pointed up or down may tag its shots
      // with different orientations (its orientation sensor changing its mind). Each is
      // turned as the first one says, with a note.
      const int first =
          photos.back().empty() ? photo.info.orientation : photos.back().front().info.orientation;
      // (An OpenEXR photo is read as stored: its pixels are not turned by any tag.)
      if (photo.info.orientation != first && photo.info.format != "openexr") {
        const int own = photo.info.orientation;
        photo = ingest::readImage(s.file, "merge", {.codesForEightBit = true, .upright = false});
        Image& img = photo.image;
        if (!photo.codes.empty()) {
          ingest::detail::applyOrientation(photo.codes, img.width, img.height, img.channels, first);
        } else {
          ingest::detail::applyOrientation(img.pixels, img.width, img.height, img.channels, first);
        }
        photo.info.orientation = first;
        photo.notes.push_back(
            s.file.filename().string() + " is tagged with EXIF orientation " + std::to_string(own) +
            ", " + v.shots.front().file.filename().string() + " with " + std::to_string(first) +
            ": turned as the bracket's first photo says (a bracket is one "
            "frame of the sensor)");
      }
      photos.back().push_back(std::move(photo));
      report(progress, "read", double(++done) / double(total));
    }
  }
  return photos;
}

CaptureMergeResult mergeCapture(const ingest::Capture& capture,
                                const std::vector<std::vector<ingest::LoadedImage>>& photos,
                                const CaptureMergeOptions& options,
                                const color::ColorConfig& colors, const Progress& progress) {
  const auto start = std::chrono::steady_clock::now();
  options.validate();
  COMPOSE_CHECK(photos.size() == capture.views.size());
  CaptureMergeResult result;
  const std::string working = colors.workingSpace();
  const std::string overrideSpace =
      options.inputSpace.empty() ? std::string()
                                 : colors.resolve(options.inputSpace, options.inputSpaceOption);

  // Colour space of every shot, and which views are 8-bit.
  std::vector<std::vector<std::string>> spaces(capture.views.size());
  std::vector<char> eightBit(capture.views.size(), 0);
  std::string firstEightBitSpace, deepByRule, guessed;
  fs::path deepByRuleFile, guessedFile;  // the photos those notes name
  for (size_t v = 0; v < capture.views.size(); ++v) {
    const ingest::View& view = capture.views[v];
    COMPOSE_CHECK(photos[v].size() == view.shots.size());
    eightBit[v] = isEightBit(view.shots.front().info);
    for (size_t s = 0; s < view.shots.size(); ++s) {
      const ingest::Shot& shot = view.shots[s];
      COMPOSE_CHECK(shot.exposure.has_value());
      const Image& img = photos[v][s].image;
      const Image& ref = photos[v][0].image;
      if (img.width != ref.width || img.height != ref.height) {
        throw Error(kStage,
                    "photos of a bracket must have the same size: this one is " +
                        std::to_string(img.width) + "x" + std::to_string(img.height) + ", " +
                        view.shots[0].file.filename().string() + " is " +
                        std::to_string(ref.width) + "x" + std::to_string(ref.height),
                    shot.file);
      }
      if (isEightBit(shot.info) != bool(eightBit[v])) {
        throw Error(kStage,
                    "a bracket mixes 8-bit and deeper photos (this one is " + shot.info.sampleType +
                        ", " + view.shots.front().file.filename().string() + " is " +
                        view.shots.front().info.sampleType + ")",
                    shot.file);
      }
      std::string space = overrideSpace;
      if (space.empty() && !shot.colorSpace.empty())
        space = colors.resolve(shot.colorSpace, "the colour space of " + shot.file.string());
      if (space.empty()) {
        const color::InputSpace chosen = color::photoInputSpace(
            colors, ingest::nameForRules(shot.file, shot.info.format), shot.info.fileColorSpace,
            shot.info.colorSpaceByConvention, shot.info.integerSamples(), shot.info.iccProfile,
            shot.info.exifUncalibrated);
        space = chosen.space;
        // A guess, or a space the file names that the config does not know (a ProPhoto RGB
        // TIFF, decoded as sRGB in silence: 12.6 % off), is said once, as compose color says it.
        if (chosen.assumed && guessed.empty()) {
          guessedFile = shot.file;
          guessed = shot.file.filename().string() + " read as '" + space + "' (" + chosen.how +
                    "); give " + options.inputSpaceOption + " to say which it is";
        }
        // Deeper integer photos (16-bit TIFF, PNG) whose file names no colour space: decoded
        // by the config's rules, which a linear file (a raw converter's linear output) defeats.
        if (!eightBit[v] && shot.info.integerSamples() && deepByRule.empty() &&
            shot.info.iccProfile.empty() && !colors.isLinearOrData(space)) {
          deepByRuleFile = shot.file;
          deepByRule =
              "16-bit photos such as " + shot.file.filename().string() + " read as '" + space +
              "' by the config's rules (the files name no colour space); linear ones "
              "(a raw converter's linear output) need " +
              options.inputSpaceOption + " '" + linearSpaceFor(colors, space, "", nullptr) +
              "' or a capture description that says so";
        }
      }
      spaces[v].push_back(space);
      if (eightBit[v] && firstEightBitSpace.empty()) firstEightBitSpace = space;
    }
  }
  if (!deepByRule.empty()) result.notes.push_back(deepByRule);
  // A photo the note above names is said there; a guess about another one on its own.
  if (!guessed.empty() && guessedFile != deepByRuleFile) result.notes.push_back(guessed);
  for (size_t v = 0; v < photos.size(); ++v)
    for (const ingest::LoadedImage& photo : photos[v])
      for (const std::string& note : photo.notes)
        result.notes.push_back(capture.views.size() > 1 ? capture.views[v].name + ": " + note
                                                        : note);

  // 8-bit codes of the 8-bit views, made once for recovery and merging.
  std::vector<std::vector<Codes8>> codes(capture.views.size());
  for (size_t v = 0; v < capture.views.size(); ++v) {
    if (!eightBit[v]) continue;
    for (size_t s = 0; s < photos[v].size(); ++s) {
      const ingest::LoadedImage& photo = photos[v][s];
      const int ch = photo.image.channels;
      if (ch < 3) throw Error(kStage, "merging needs RGB photos", capture.views[v].shots[s].file);
      if (photo.codes.empty()) {
        codes[v].push_back(toCodes8(photo.image));
        continue;
      }
      // Read as codes already: borrowed as they are, or without the extra channels (RGBA).
      Codes8 c;
      c.width = photo.image.width;
      c.height = photo.image.height;
      if (ch == 3) {
        c.external = photo.codes.data();
      } else {
        c.rgb.resize(size_t(c.width) * size_t(c.height) * 3);
        for (size_t i = 0; i < size_t(c.width) * size_t(c.height); ++i)
          for (size_t k = 0; k < 3; ++k) c.rgb[i * 3 + k] = photo.codes[i * size_t(ch) + k];
      }
      codes[v].push_back(std::move(c));
    }
  }

  // The exposures agree with the pictures' brightness (before anything is recovered from them).
  for (size_t v = 0; v < capture.views.size(); ++v) {
    const Image& first = photos[v].front().image;
    const size_t pixels = size_t(first.width) * size_t(first.height);
    if (eightBit[v]) {
      checkBrightnessOrder(
          capture.views[v],
          [&](size_t s, size_t i) { return float(codes[v][s].data()[i * 3 + 1]); }, pixels, 2.0f);
    } else if (photos[v].front().hasPixels()) {
      const size_t ch = size_t(first.channels), g = ch > 1 ? 1 : 0;
      checkBrightnessOrder(
          capture.views[v],
          [&](size_t s, size_t i) { return photos[v][s].image.pixels[i * ch + g]; }, pixels,
          2.0f / 65535.0f);
    }
  }

  // One response curve for every 8-bit view.
  std::vector<std::optional<Alignment>> alignments(capture.views.size());
  std::string linearSpace;
  const bool anyEightBit = !firstEightBitSpace.empty();
  if (anyEightBit) {
    std::string why;
    linearSpace = linearSpaceFor(colors, firstEightBitSpace, options.linearSpace, &why);
    ingest::CaptureInfo cameraInfo;
    cameraInfo.cameraMake = capture.cameraMake;
    cameraInfo.cameraModel = capture.cameraModel;
    const std::string camera = cameraInfo.camera();
    // Hand-held brackets are aligned before the response is recovered from them (and checked
    // against them): recovery compares the shots pixel by pixel. The shifts go to the merge too.
    const bool needBrackets =
        options.response == ResponseMode::Auto || options.response == ResponseMode::Recover;
    // Every view is cropped to one size (recovery stacks the views; their widths must agree).
    std::vector<std::vector<Codes8>> aligned(capture.views.size());
    std::vector<std::array<int, 4>> rects(capture.views.size());
    int cropWidth = std::numeric_limits<int>::max(), cropHeight = cropWidth;
    for (size_t v = 0; v < capture.views.size(); ++v) {
      if (!eightBit[v] || photos[v].size() < 2 || !options.merge.align) continue;
      std::vector<const Codes8*> view;
      for (const Codes8& c : codes[v]) view.push_back(&c);
      double seconds = 0.0;
      alignments[v] = alignBracket(view, options.merge.maxShift, &seconds);
      result.openCvSeconds += seconds;
      rects[v] =
          alignedRect(codes[v].front().width, codes[v].front().height, alignments[v]->shifts);
      cropWidth = std::min(cropWidth, rects[v][2] - rects[v][0]);
      cropHeight = std::min(cropHeight, rects[v][3] - rects[v][1]);
    }
    for (size_t v = 0; v < capture.views.size() && needBrackets && cropWidth > 0 && cropHeight > 0;
         ++v) {
      if (alignments[v])
        aligned[v] = alignedCrops(codes[v], alignments[v]->shifts, rects[v][0], rects[v][1],
                                  cropWidth, cropHeight);
    }
    std::vector<BracketCodes> brackets;
    for (size_t v = 0; v < capture.views.size(); ++v) {
      if (!eightBit[v] || photos[v].size() < 2) continue;
      BracketCodes b;
      for (size_t s = 0; s < photos[v].size(); ++s) {
        b.images.push_back(aligned[v].empty() ? &codes[v][s] : &aligned[v][s]);
        b.exposures.push_back(*capture.views[v].shots[s].exposure);
      }
      brackets.push_back(std::move(b));
    }
    auto recover = [&] {
      if (brackets.empty()) {
        throw Error(kStage,
                    "recovering the camera's response needs a bracket of at least two 8-bit "
                    "photos; give a response file (--response FILE) or --response colorspace",
                    capture.views.front().shots.front().file);
      }
      const auto recoveryStart = std::chrono::steady_clock::now();
      double calibrationSeconds = 0.0;
      result.response = recoverResponse(brackets, options.recovery, progress, &calibrationSeconds);
      result.openCvSeconds += calibrationSeconds;
      result.recoverySeconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - recoveryStart).count();
      result.response.make = capture.cameraMake;
      result.response.model = capture.cameraModel;
      result.responseRecovered = true;
      // Codes no smooth, unclipped patch showed are the fit's extrapolation: say so when the
      // photos leave out more than the extremes.
      const auto& seen = result.response.observed;
      if (std::any_of(seen.begin(), seen.end(),
                      [](const std::array<int, 2>& r) { return r[0] > 5 || r[1] < 250; })) {
        // (A channel whose patches are too few to reach either side of code 128 shows none.)
        auto range = [](const std::array<int, 2>& r) {
          return r[0] == r[1] ? std::string("no")
                              : std::to_string(r[0]) + "-" + std::to_string(r[1]);
        };
        const std::string text = "the photos show codes " + range(seen[0]) + " (red), " +
                                 range(seen[1]) + " (green), " + range(seen[2]) +
                                 " (blue) in smooth, unclipped patches; the response outside them "
                                 "is extrapolated";
        const bool dark = seen[0][0] > 5 || seen[1][0] > 5 || seen[2][0] > 5;
        const bool bright = seen[0][1] < 250 || seen[1][1] < 250 || seen[2][1] < 250;
        result.notes.push_back(
            text + " (" + (dark ? "a shorter exposure would measure the low codes" : "") +
            (dark && bright ? "; " : "") +
            (bright ? "a longer exposure would measure the high codes" : "") + ")");
      }
      result.responseCacheFile =
          responseFileFor(options.responseFolder, capture.cameraMake, capture.cameraModel);
      if (result.responseCacheFile.empty()) {
        result.notes.push_back(
            "the photos name no camera (EXIF Make/Model): the recovered response is used for "
            "this merge only");
      }
    };
    switch (options.response) {
      case ResponseMode::File: {
        result.response = readResponse(options.responseFile);
        result.linearisation =
            "8-bit photos linearised by the response curve in " + options.responseFile.string();
        // Given by name, it is used; but a curve of another camera is said (it was applied in
        // silence).
        const ResponseCurve& r = result.response;
        if (!sameCamera(r.make, capture.cameraMake) || !sameCamera(r.model, capture.cameraModel)) {
          result.notes.push_back("the response in " + options.responseFile.string() + " is of '" +
                                 r.make + (r.make.empty() ? "" : " ") + r.model +
                                 "', the photos of '" + camera +
                                 "': used as given; leave the response out to recover this "
                                 "camera's");
        }
        break;
      }
      case ResponseMode::ColorSpace:
        result.response = curveFromColorSpace(colors, firstEightBitSpace, linearSpace);
        result.linearisation = "8-bit photos linearised by the colour space they declare (" +
                               firstEightBitSpace + "), not by a camera response";
        break;
      case ResponseMode::Recover:
        recover();
        result.linearisation =
            "8-bit photos linearised by the camera response " + result.response.source;
        break;
      case ResponseMode::Auto: {
        const fs::path cached =
            responseFileFor(options.responseFolder, capture.cameraMake, capture.cameraModel);
        std::error_code ec;
        // A curve stored for another camera (a file copied in by hand, or named by an older
        // compose for two cameras alike) is not this camera's: recovered instead, nothing stored.
        std::optional<ResponseCurve> kept;
        bool foreign = false;
        if (!cached.empty() && fs::exists(cached, ec)) {
          kept = readResponse(cached);
          if (!sameCamera(kept->make, capture.cameraMake) ||
              !sameCamera(kept->model, capture.cameraModel)) {
            result.notes.push_back("the response in " + cached.string() + " is stored for '" +
                                   kept->make + " " + kept->model + "', not for '" + camera +
                                   "': not used; a curve is recovered from these photos and not "
                                   "stored there");
            kept.reset();
            foreign = true;
          }
        }
        if (kept) {
          result.response = std::move(*kept);
          result.linearisation =
              "8-bit photos linearised by the stored response of " + camera + " (" +
              cached.string() +
              (result.response.created.empty() ? "" : ", recovered " + result.response.created) +
              "); recovery skipped (--response recover to redo it)";
          // The stored curve is the camera's as it was set when recovered: another picture
          // style, contrast or JPEG setting makes it wrong for these photos. Checked on their
          // brackets: when the shots disagree through it, a curve is recovered from them and used
          // if it explains them clearly better (by a quarter; noise and movement make the shots
          // disagree as much through either); the stored one is kept as it is.
          const double stored = responseDisagreement(result.response, brackets);
          bool storedUsed = true;
          if (std::isfinite(stored) && stored > kStoredResponseTolerance) {
            const ResponseCurve storedCurve = result.response;
            const std::vector<std::string> notesBefore = result.notes;
            recover();
            // Either way this run stores no curve.
            result.responseCacheFile.clear();
            result.responseRecovered = false;
            const double fresh = responseDisagreement(result.response, brackets);
            char text[512];
            if (fresh < 0.75 * stored) {
              storedUsed = false;
              std::snprintf(
                  text, sizeof text,
                  "the stored response of %s does not fit these photos (their exposures "
                  "disagree by %.1f %% through it, %.1f %% through a curve recovered from them: "
                  "another picture style or tone setting?): the recovered curve is used and not "
                  "stored (--response recover stores it instead; --response-dir keeps one "
                  "folder of curves per setting)",
                  camera.c_str(), 100.0 * stored, 100.0 * fresh);
              result.notes.push_back(text);
              result.linearisation =
                  "8-bit photos linearised by a camera response recovered "
                  "from them (the stored one of " +
                  camera + " does not fit them)";
            } else {
              // The photos disagree as much through a curve of their own: noise (a high ISO),
              // a hand-held shift, not the curve. The stored one is kept, and the recovery's
              // notes go with the curve that is not used.
              result.response = storedCurve;
              result.notes = notesBefore;
              std::snprintf(
                  text, sizeof text,
                  "the stored response of %s was checked against a curve recovered from these "
                  "photos, their exposures disagreeing by %.1f %% through it and %.1f %% through "
                  "the recovered one (the photos' noise or movement, not the curve): the stored "
                  "one is used",
                  camera.c_str(), 100.0 * stored, 100.0 * fresh);
              result.notes.push_back(text);
              result.linearisation = "8-bit photos linearised by the stored response of " + camera +
                                     " (" + cached.string() +
                                     "), checked against a recovery from them";
            }
          }
          // Options for a recovery that did not make the curve used: said, not dropped silently.
          if (storedUsed && !options.recoveryOptions.empty()) {
            const bool one = options.recoveryOptions.size() == 1;
            result.notes.push_back(notAppliedOptions(options.recoveryOptions) +
                                   ": the curve used is the stored "
                                   "response of " +
                                   camera + " (" + cached.string() + "), not one recovered with " +
                                   (one ? "it" : "them") +
                                   " (--response recover recovers one with " +
                                   (one ? "it" : "them") +
                                   " and stores it for the camera in place of this one; "
                                   "with --response-dir another folder, this one stays)");
          }
        } else {
          recover();
          if (foreign) result.responseCacheFile.clear();
          result.linearisation = "8-bit photos linearised by the camera response " +
                                 result.response.source + (camera.empty() ? "" : " for " + camera);
        }
        break;
      }
    }
    result.linearisation += "; camera RGB taken as " + linearSpace + " (" + why + ")";
  } else if (!options.recoveryOptions.empty()) {
    // 16-bit and float photos are linear already: no curve is recovered.
    result.notes.push_back(notAppliedOptions(options.recoveryOptions) +
                           ": the photos are 16-bit or float, linear already, and no "
                           "response is recovered for them");
  }  // the aligned copies were for recovery only: the merge shifts the shots itself

  // The unit of 8-bit views: middle grey as the sRGB curve decodes it (capture_merge.h, Units).
  if (anyEightBit) {
    constexpr int kMiddleGreyCode = 118;
    const ResponseCurve srgb = ResponseCurve::srgb();
    for (size_t c = 0; c < 3; ++c)
      result.unitScale[c] = double(srgb.inverse[c][kMiddleGreyCode]) /
                            double(result.response.inverse[c][kMiddleGreyCode]);
  }

  // Merge view by view.
  const size_t views = capture.views.size();
  for (size_t v = 0; v < views; ++v) {
    const ingest::View& view = capture.views[v];
    MergedView out;
    out.name = view.name;
    MergeInput input;
    input.eightBit = eightBit[v];
    input.response = input.eightBit ? &result.response : nullptr;
    std::vector<Image> converted;
    if (!input.eightBit) {
      converted.reserve(photos[v].size());
      for (size_t s = 0; s < photos[v].size(); ++s) {
        COMPOSE_CHECK(photos[v][s].hasPixels());
        Image img = photos[v][s].image;
        if (img.channels < 3) throw Error(kStage, "merging needs RGB photos", view.shots[s].file);
        ingest::requireFinite(img, view.shots[s].file, kStage, "the photo", ingest::kMaxPhotoValue);
        img.colorSpace = spaces[v][s];
        colors.convert(img, working);
        converted.push_back(std::move(img));
      }
    }
    for (size_t s = 0; s < photos[v].size(); ++s) {
      input.images.push_back(input.eightBit ? &photos[v][s].image : &converted[s]);
      if (!input.eightBit) input.stored.push_back(&photos[v][s].image);
      if (input.eightBit) input.codes.push_back(&codes[v][s]);
      input.exposures.push_back(*view.shots[s].exposure);
      input.names.push_back(view.shots[s].file.string());
      out.exposures.push_back(*view.shots[s].exposure);
      out.files.push_back(view.shots[s].file);
    }
    input.alignment = alignments[v];
    if (input.eightBit) input.scale = result.unitScale;
    const Progress viewProgress = [&](std::string_view stage, double f) {
      report(progress, stage, (double(v) + f) / double(views));
    };
    out.stats = mergeBracket(input, options.merge, progress ? viewProgress : Progress{});
    out.radiance = std::move(out.stats.radiance);
    out.stats.radiance = Image();
    out.radiance.colorSpace = input.eightBit ? linearSpace : working;
    colors.convert(out.radiance, working);
    result.openCvSeconds += out.stats.openCvSeconds;
    for (const std::string& note : out.stats.notes)
      result.notes.push_back(views > 1 ? view.name + ": " + note : note);
    result.views.push_back(std::move(out));
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace compose::hdr
