#include "hdr/merge.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <tuple>

#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "hdr/opencv_util.h"

namespace compose::hdr {

namespace {

// OpenCV's triangle weights (photo/src/hdr_common.cpp): w(z) = z + 1 below 128, 256 - z above.
inline float triangle(int z) {
  return z < kCodes / 2 ? float(z + 1) : float(kCodes - z);
}

// The hat used for linear input: 1 up to 90 % of full scale, falling to 0 at 98 %.
inline float linearHat(float v) {
  return std::clamp((0.98f - v) / 0.08f, 0.0f, 1.0f);
}

float encodeGamma(float v) {
  return v <= 0.0f ? 0.0f : std::pow(v, 1.0f / 2.2f);
}

cv::Mat responseMat(const ResponseCurve& curve) {
  cv::Mat m(kCodes, 1, CV_32FC3);
  for (int z = 0; z < kCodes; ++z)
    for (int c = 0; c < 3; ++c) m.at<cv::Vec3f>(z)[c] = curve.inverse[size_t(c)][size_t(z)];
  return m;
}

std::string percent(int64_t count, size_t total) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3g %%", 100.0 * double(count) / double(total));
  return text;
}

// How many of the set pixels of `mask` (8-bit, 0 or 1) are joined to the image's border through
// set pixels (8-connected): black beyond a fisheye's image circle rather than a dark scene.
int64_t blackJoinedToTheEdge(const cv::Mat& mask) {
  const int w = mask.cols, h = mask.rows;
  cv::Mat labels;
  const int count = cv::connectedComponents(mask, labels, 8, CV_32S);
  std::vector<uint8_t> outer(size_t(count), 0);
  for (int x = 0; x < w; ++x) {
    outer[size_t(labels.at<int>(0, x))] = 1;
    outer[size_t(labels.at<int>(h - 1, x))] = 1;
  }
  for (int y = 0; y < h; ++y) {
    outer[size_t(labels.at<int>(y, 0))] = 1;
    outer[size_t(labels.at<int>(y, w - 1))] = 1;
  }
  outer[0] = 0;  // the background: pixels not set
  int64_t joined = 0;
  for (int y = 0; y < h; ++y) {
    const int* l = labels.ptr<int>(y);
    for (int x = 0; x < w; ++x) joined += outer[size_t(l[x])];
  }
  return joined;
}

// One shot as the per-pixel passes see it: its values through a shift (x, y) and how they map to
// codes, clipping and linear light.
struct ShotView {
  const Image* image = nullptr;
  const Codes8* codes = nullptr;
  int dx = 0, dy = 0;
  double exposure = 1.0;
  const Image* stored = nullptr;  // deeper input: as stored (MergeInput::stored), or the image
  // Value of channel c at output pixel (x, y); false if the shifted shot does not cover it.
  bool covers(int x, int y) const {
    const int sx = x - dx, sy = y - dy;
    return sx >= 0 && sy >= 0 && sx < image->width && sy < image->height;
  }
  const float* at(int x, int y) const { return image->at(x - dx, y - dy); }
  const float* storedAt(int x, int y) const { return stored->at(x - dx, y - dy); }
  const uint8_t* codeAt(int x, int y) const {
    return codes->data() + (size_t(y - dy) * size_t(codes->width) + size_t(x - dx)) * 3;
  }
};

}  // namespace

const char* mergeMethodName(MergeMethod method) {
  return method == MergeMethod::Debevec ? "debevec" : "robertson";
}

void MergeParams::validate() const {
  if (maxShift < 1 || maxShift > 1024)
    throw Error(kStage,
                "the alignment range (--max-shift) must be between 1 and 1024 pixels, got " +
                    std::to_string(maxShift));
  if (!(ghostStops > 0.0) || !std::isfinite(ghostStops))
    throw Error(kStage,
                "the ghost threshold (--ghost-stops) must be a positive number of stops, got " +
                    numberText(ghostStops));
  if (!(clipLow >= 0.0 && clipLow < clipHigh && clipHigh <= 1.0))
    throw Error(kStage, "clipping thresholds must satisfy 0 <= low < high <= 1");
  if (deghost && method == MergeMethod::Robertson)
    throw Error(kStage,
                "--merge-method robertson is OpenCV's merge, which --deghost replaces by a "
                "weighted average that leaves out what moved: give one or the other");
}

Alignment alignBracket(const std::vector<const Codes8*>& codes, int maxShift,
                       double* openCvSeconds) {
  const size_t n = codes.size();
  Alignment out;
  out.shifts.assign(n, {0, 0});
  out.found.assign(n, {0, 0});
  if (n < 2) return out;
  int bits = 1;
  while ((1 << bits) - 1 < maxShift) ++bits;
  // AlignMTB's pyramid halves the shots `bits` - 1 times; below a few pixels OpenCV throws
  // (--max-shift 32 on a 200 x 60 bracket, 128 on 320 x 240): its coarsest level is kept at 8
  // pixels or more (the search below covers the whole range anyway).
  const int shortest = std::min(codes[0]->width, codes[0]->height);
  while (bits > 1 && (shortest >> (bits - 1)) < 8) --bits;
  const size_t pivot = n / 2;
  OpenCvClock opencv;
  opencv([&] {
    std::vector<cv::Mat> gray(n);
    for (size_t i = 0; i < n; ++i) cv::cvtColor(wrap(*codes[i]), gray[i], cv::COLOR_RGB2GRAY);
    auto mtb = cv::createAlignMTB(bits, 4, true);
    // The share of the pixels both bitmaps trust (outside the band around their medians) whose
    // bits differ, shot `i` shifted by s: AlignMTB's own measure.
    auto differ = [](const cv::Mat& tb0, const cv::Mat& eb0, const cv::Mat& tb1, const cv::Mat& eb1,
                     cv::Point s) {
      const int w = tb0.cols, h = tb0.rows;
      const int x0 = std::max(0, s.x), y0 = std::max(0, s.y);
      const int x1 = std::min(w, w + s.x), y1 = std::min(h, h + s.y);
      if (2 * (x1 - x0) < w || 2 * (y1 - y0) < h) return 2.0;  // less than half overlaps
      const cv::Rect at0(x0, y0, x1 - x0, y1 - y0), at1(x0 - s.x, y0 - s.y, x1 - x0, y1 - y0);
      cv::Mat trusted, diff;
      cv::bitwise_and(eb0(at0), eb1(at1), trusted);
      cv::bitwise_xor(tb0(at0), tb1(at1), diff);
      cv::bitwise_and(diff, trusted, diff);
      // Too few trusted pixels measure nothing (a dark, plain overlap): not a candidate.
      const int valid = cv::countNonZero(trusted);
      return valid < std::max(64, (x1 - x0) * (y1 - y0) / 16)
                 ? 2.0
                 : double(cv::countNonZero(diff)) / valid;
    };
    // The best shift within `radius` of `around` on images scaled down by `factor`, and its
    // share of differing bits.
    auto search = [&](const cv::Mat& g0, const cv::Mat& g1, int factor, cv::Point around,
                      int radius) -> std::pair<cv::Point, double> {
      cv::Mat a = g0, b = g1;
      if (factor > 1) {
        cv::resize(g0, a, cv::Size(), 1.0 / factor, 1.0 / factor, cv::INTER_AREA);
        cv::resize(g1, b, cv::Size(), 1.0 / factor, 1.0 / factor, cv::INTER_AREA);
      }
      cv::Mat tb0, eb0, tb1, eb1;
      mtb->computeBitmaps(a, tb0, eb0);
      mtb->computeBitmaps(b, tb1, eb1);
      cv::Point best = around;
      double least = differ(tb0, eb0, tb1, eb1, around);
      for (int dy = -radius; dy <= radius; ++dy)
        for (int dx = -radius; dx <= radius; ++dx) {
          const cv::Point s(around.x + dx, around.y + dy);
          const double d = differ(tb0, eb0, tb1, eb1, s);
          if (d < least) least = d, best = s;
        }
      return {best, least};
    };
    for (size_t i = 0; i < n; ++i) {
      if (i == pivot) continue;
      const cv::Point byPyramid = mtb->calculateShift(gray[pivot], gray[i]);
      // AlignMTB decides level by level from its pyramid's coarsest image, a few pixels across,
      // searching one pixel each way at each level, and a wrong turn there is not undone (a
      // detailed view of 320 x 240 pixels shaken by 10 px came out 6.5 px off, 15.6 px at 20).
      // The same measure on its bitmaps is searched over the whole range on the shots scaled to
      // about 200 pixels high, then two pixels each way at each finer level; AlignMTB's own
      // answer stays where it explains the shots as well at full size.
      // (And smaller while the range is more than 32 steps there, down to 64 pixels: the search
      // grows with the square of the range; --max-shift 511 took 8 s on a 1024 x 768 bracket.)
      int factor = 1;
      const int side = std::min(gray[i].cols, gray[i].rows);
      while (side / (2 * factor) >= 200 ||
             ((maxShift + factor - 1) / factor > 32 && side / (2 * factor) >= 64))
        factor *= 2;
      cv::Point s(0, 0);
      int radius = (maxShift + factor - 1) / factor;
      double least = 0.0;
      for (;; factor /= 2) {
        std::tie(s, least) = search(gray[pivot], gray[i], factor, s, radius);
        if (factor == 1) break;
        s *= 2;
        radius = 2;
      }
      if (byPyramid != s && search(gray[pivot], gray[i], 1, byPyramid, 0).second < least)
        s = byPyramid;
      out.found[i] = {s.x, s.y};
      if (std::abs(s.x) <= maxShift && std::abs(s.y) <= maxShift) out.shifts[i] = {s.x, s.y};
    }
  });
  if (openCvSeconds) *openCvSeconds += opencv.seconds;
  return out;
}

MergeResult mergeBracket(const MergeInput& input, const MergeParams& params,
                         const Progress& progress) {
  const auto start = std::chrono::steady_clock::now();
  params.validate();
  const size_t n = input.images.size();
  COMPOSE_CHECK(n > 0 && input.exposures.size() == n);
  COMPOSE_CHECK(!input.eightBit || input.response != nullptr);
  auto name = [&](size_t i) {
    return i < input.names.size() ? input.names[i] : "photo " + std::to_string(i + 1);
  };
  const Image& first = *input.images[0];
  const int width = first.width, height = first.height;
  for (size_t i = 0; i < n; ++i) {
    const Image& img = *input.images[i];
    if (img.channels < 3)
      throw Error(
          kStage,
          "merging needs RGB photos; this one has " + std::to_string(img.channels) + " channel(s)",
          name(i));
    if (img.width != width || img.height != height) {
      throw Error(kStage,
                  "photos of a bracket must have the same size: this one is " +
                      std::to_string(img.width) + "x" + std::to_string(img.height) + ", " +
                      name(0) + " is " + std::to_string(width) + "x" + std::to_string(height),
                  name(i));
    }
    if (!(input.exposures[i] > 0.0) || !std::isfinite(input.exposures[i]))
      throw Error(kStage, "exposure must be a positive number", name(i));
    if (i > 0 && !(input.exposures[i] >= input.exposures[i - 1]))
      throw Error(kStage, "exposures must be given in increasing order", name(i));
  }
  if (n > 1 && std::log2(input.exposures.back() / input.exposures.front()) < 1.0 / 6.0)
    throw Error(kStage, "the exposures of the bracket are all equal: nothing to merge", name(0));

  MergeResult result;
  result.shifts.assign(n, {0, 0});
  OpenCvClock opencv;
  report(progress, kStage, 0.0);

  // Thresholds as 8-bit codes; linear input is compared after a 2.2 gamma, so that the same
  // thresholds mean roughly the same thing.
  const int hiCode = int(std::ceil(params.clipHigh * 255.0 - 1e-9));
  const int loCode = int(std::floor(params.clipLow * 255.0 + 1e-9));

  // 8-bit codes of every shot: OpenCV's input, and what the per-pixel pass classifies.
  std::vector<Codes8> ownCodes;
  std::vector<const Codes8*> codePtr = input.codes;
  if (codePtr.empty()) {
    ownCodes.reserve(n);
    for (size_t i = 0; i < n; ++i) {
      COMPOSE_CHECK(!input.images[i]->pixels.empty());
      if (input.eightBit) {
        ownCodes.push_back(toCodes8(*input.images[i]));
      } else {
        // Codes of the linear values, gamma-encoded; where a channel as stored is clipped (it
        // may lie below full scale once converted to the working space), clipped codes.
        const Image& img = *input.images[i];
        const Image* stored = input.stored.empty() ? nullptr : input.stored[i];
        const float full = float(params.clipHigh);
        Image encoded(width, height, 3);
        parallelFor(
            0, height,
            [&](int64_t y) {
              for (int x = 0; x < width; ++x) {
                const float* as = stored ? stored->at(x, int(y)) : nullptr;
                const bool clipped = as && std::max({as[0], as[1], as[2]}) >= full;
                for (int c = 0; c < 3; ++c)
                  encoded.at(x, int(y))[c] = clipped ? 1.0f : encodeGamma(img.at(x, int(y))[c]);
              }
            },
            16);
        ownCodes.push_back(toCodes8(encoded));
      }
    }
    for (const Codes8& c : ownCodes) codePtr.push_back(&c);
  }
  COMPOSE_CHECK(codePtr.size() == n);
  if (!input.eightBit && params.method == MergeMethod::Robertson)
    throw Error(kStage,
                "--merge-method robertson is OpenCV's merge of 8-bit photos; these are deeper "
                "(16-bit or float), merged by a weighted average of their linear values: leave "
                "--merge-method out",
                name(0));
  const bool useOpenCvMerge = input.eightBit && !params.deghost && n > 1;
  std::vector<cv::Mat> codes(n);  // for OpenCV: views of the codes, or shifted copies
  for (size_t i = 0; i < n; ++i) codes[i] = wrap(*codePtr[i]);

  // 1. Alignment against the middle exposure (or the shifts the caller found already).
  if (params.align && n > 1) {
    Alignment alignment;
    if (input.alignment && input.alignment->shifts.size() == n) {
      alignment = *input.alignment;
    } else {
      double seconds = 0.0;
      alignment = alignBracket(codePtr, params.maxShift, &seconds);
      opencv.seconds += seconds;
    }
    result.shifts = alignment.shifts;
    for (size_t i = 0; i < n; ++i) {
      if (!alignment.refused(i)) continue;
      result.notes.push_back(
          name(i) + ": the best shift found is (" + std::to_string(alignment.found[i][0]) + ", " +
          std::to_string(alignment.found[i][1]) + ") pixels, beyond --max-shift " +
          std::to_string(params.maxShift) +
          ": not shifted (too little detail in it to align on?); give a larger --max-shift if "
          "the camera moved that much");
    }
    if (useOpenCvMerge) {
      opencv([&] {
        for (size_t i = 0; i < n; ++i) {
          const cv::Point s(result.shifts[i][0], result.shifts[i][1]);
          if (s.x == 0 && s.y == 0) continue;
          cv::Mat shifted;
          cv::createAlignMTB()->shiftMat(codes[i], shifted, s);
          codes[i] = shifted;
        }
      });
    }
    std::string list;
    for (size_t i = 0; i < n; ++i) {
      list += (list.empty() ? "" : ", ") + name(i) + " (" + std::to_string(result.shifts[i][0]) +
              ", " + std::to_string(result.shifts[i][1]) + ")";
    }
    result.notes.push_back("aligned to " + name(n / 2) +
                           " (median-threshold bitmaps), shifts in pixels: " + list);
  }
  report(progress, kStage, 0.2);

  COMPOSE_CHECK(input.stored.empty() || (!input.eightBit && input.stored.size() == n));
  for (const Image* stored : input.stored)
    COMPOSE_CHECK(stored->width == width && stored->height == height && stored->channels >= 3);
  std::vector<ShotView> shots(n);
  for (size_t i = 0; i < n; ++i)
    shots[i] = {input.images[i],     codePtr[i],
                result.shifts[i][0], result.shifts[i][1],
                input.exposures[i],  input.stored.empty() ? input.images[i] : input.stored[i]};

  // 2. OpenCV's merge of 8-bit brackets.
  cv::Mat merged;
  if (useOpenCvMerge) {
    cv::Mat times(int(n), 1, CV_32F);
    for (size_t i = 0; i < n; ++i) times.at<float>(int(i)) = float(input.exposures[i]);
    const cv::Mat response = responseMat(*input.response);
    opencv([&] {
      if (params.method == MergeMethod::Debevec) {
        cv::createMergeDebevec()->process(codes, merged, times, response);
      } else {
        cv::createMergeRobertson()->process(codes, merged, times, response);
      }
    });
    codes.clear();
  }
  report(progress, kStage, 0.7);

  // 3. Per-pixel pass: clipping, uncovered borders, and (own path) the weighted merge.
  Image& out = result.radiance;
  // Every sample is written below; the frame's pages are first touched here, by every thread in
  // one pass over its rows. (Left to the per-pixel pass, those first touches cost more: on three
  // aligned 12 MP shots, whose pixels all take the general path, 0.52-0.54 s of plumbing against
  // 0.46 s; zeroed by one thread, 0.48 s.)
  out = Image::unfilled(width, height, 4, {"R", "G", "B", "clipped"});
  parallelFor(0, height, [&](int64_t y) {
    const std::span<float> row = out.row(int(y));
    std::fill(row.begin(), row.end(), 0.0f);
  });
  const ResponseCurve* curve = input.response;
  const size_t pivot = n / 2;
  std::vector<float> logExposure(n);
  for (size_t i = 0; i < n; ++i) logExposure[i] = float(std::log(input.exposures[i]));
  std::vector<int64_t> saturatedRows(size_t(height), 0), darkRows(size_t(height), 0),
      ghostRows(size_t(height), 0);
  cv::Mat darkMask = cv::Mat::zeros(height, width, CV_8U);  // black in every shot
  // Linear value of channel c of shot i at a pixel: through the curve for 8-bit codes.
  auto linearOf = [&](const ShotView& shot, int x, int y, int c) -> float {
    return input.eightBit ? curve->inverse[size_t(c)][shot.codeAt(x, y)[c]]
                          : std::max(shot.at(x, y)[c], 0.0f);
  };
  // log(inverse / exposure) for the log-domain averages, looked up rather than computed.
  std::vector<float> logInverse;
  if (input.eightBit) {
    logInverse.resize(3 * kCodes);
    for (int c = 0; c < 3; ++c)
      for (int z = 0; z < kCodes; ++z)
        logInverse[size_t(c * kCodes + z)] = std::log(curve->inverse[size_t(c)][size_t(z)]);
  }
  const std::array<double, 3>& scale = input.scale;
  const bool scaled = scale[0] != 1.0 || scale[1] != 1.0 || scale[2] != 1.0;
  bool unshifted = true;
  for (const auto& s : result.shifts) unshifted = unshifted && s[0] == 0 && s[1] == 0;
  parallelFor(0, height, [&](int64_t yy) {
    const int y = int(yy);
    std::vector<float> weight(n), value(n * 3);
    std::vector<char> over(n), dark(n), covered(n);
    std::vector<const uint8_t*> rowCodes(n);
    for (size_t i = 0; i < n; ++i) rowCodes[i] = codePtr[i]->data() + size_t(y) * size_t(width) * 3;
    const float* mergedRow = useOpenCvMerge ? merged.ptr<float>(y) : nullptr;
    // MergeDebevec gives codes 0 and 255 a small but non-zero weight, and their log values (a
    // bound, not a measurement) pull the average: a pixel with such a code, or one that a shot
    // does not cover (a border an alignment shift left), is redone with the same log-domain
    // average without them, per channel. `codeOf(i)`: shot i's three codes here, or null where it
    // does not cover the pixel. After MergeDebevec a channel that every shot covers and none has
    // at 0 or 255 keeps OpenCV's value, the same average; after MergeRobertson, whose average is
    // another, every channel is redone, so that the three agree.
    auto redo = [&](auto&& codeOf, float* o) {
      bool anyUncovered = false;
      for (size_t i = 0; i < n; ++i) {
        const uint8_t* z = codeOf(i);
        weight[i] = z ? (triangle(z[0]) + triangle(z[1]) + triangle(z[2])) / 3.0f : 0.0f;
        anyUncovered = anyUncovered || !z;
      }
      for (int c = 0; c < 3; ++c) {
        bool redone = anyUncovered || params.method != MergeMethod::Debevec;
        for (size_t i = 0; i < n && !redone; ++i) {
          const uint8_t* z = codeOf(i);
          redone = !z || z[c] == 0 || z[c] == kCodes - 1;
        }
        if (!redone) continue;
        float sum = 0.0f, total = 0.0f;
        for (size_t i = 0; i < n; ++i) {
          const uint8_t* z = codeOf(i);
          if (!z || z[c] == 0 || z[c] == kCodes - 1) continue;
          sum += weight[i] * (logInverse[size_t(c * kCodes + z[c])] - logExposure[i]);
          total += weight[i];
        }
        if (total > 0.0f) o[c] = std::exp(sum / total);
      }
    };
    for (int x = 0; x < width; ++x) {
      if (useOpenCvMerge && unshifted) {
        // The common case first, cheaply: OpenCV's value stands, redone where a shot has a code
        // of 0 or 255; a pixel clipped or black in every shot goes on below.
        bool everyOver = true, everyDark = true, hard = false;
        for (size_t i = 0; i < n; ++i) {
          const uint8_t* z = rowCodes[i] + 3 * x;
          const int hi = std::max({z[0], z[1], z[2]}), lo = std::min({z[0], z[1], z[2]});
          everyOver = everyOver && hi >= hiCode;
          everyDark = everyDark && hi <= loCode;
          hard = hard || lo == 0 || hi == kCodes - 1;
        }
        if (!everyOver && !everyDark) {
          float* o = out.at(x, y);
          o[0] = mergedRow[3 * x];
          o[1] = mergedRow[3 * x + 1];
          o[2] = mergedRow[3 * x + 2];
          o[3] = 0.0f;
          if (hard) redo([&](size_t i) { return rowCodes[i] + 3 * x; }, o);
          continue;
        }
      }
      bool allOver = true, allDark = true, anyUncovered = false, anyHardClip = false;
      for (size_t i = 0; i < n; ++i) {
        covered[i] = shots[i].covers(x, y);
        if (!covered[i]) {
          anyUncovered = true;
          over[i] = dark[i] = 0;
          continue;
        }
        const uint8_t* z = shots[i].codeAt(x, y);
        const int maxCode = std::max({z[0], z[1], z[2]});
        const int minCode = std::min({z[0], z[1], z[2]});
        anyHardClip = anyHardClip || minCode == 0 || maxCode == kCodes - 1;
        over[i] = maxCode >= hiCode;
        dark[i] = maxCode <= loCode;
        allOver = allOver && over[i];
        allDark = allDark && dark[i];
      }
      float* o = out.at(x, y);
      if (allOver || allDark) {
        // Nothing trustworthy: the shortest (over-exposed) or longest (under-exposed) covering
        // shot gives a bound.
        size_t pick = 0;
        if (allOver) {
          for (pick = 0; !covered[pick]; ++pick) {
          }
        } else {
          for (pick = n - 1; !covered[pick]; --pick) {
          }
        }
        for (int c = 0; c < 3; ++c)
          o[c] = float(linearOf(shots[pick], x, y, c) / shots[pick].exposure);
        o[3] = 1.0f;
        (allOver ? saturatedRows : darkRows)[size_t(y)]++;
        if (!allOver) darkMask.at<uint8_t>(y, x) = 1;
        continue;
      }
      o[3] = 0.0f;
      if (useOpenCvMerge) {
        const cv::Vec3f m = merged.at<cv::Vec3f>(y, x);
        o[0] = m[0];
        o[1] = m[1];
        o[2] = m[2];
        if (!anyUncovered && !anyHardClip) continue;
        redo([&](size_t i) { return covered[i] ? shots[i].codeAt(x, y) : nullptr; }, o);
        continue;
      }
      // Own weighted merge (deeper input, ghost suppression, or a single photo).
      for (size_t i = 0; i < n; ++i) {
        weight[i] = 0.0f;
        if (!covered[i]) continue;
        float w = 0.0f;
        if (input.eightBit) {
          const uint8_t* z = shots[i].codeAt(x, y);
          w = (triangle(z[0]) + triangle(z[1]) + triangle(z[2])) / 3.0f;
          if (params.deghost && over[i]) w = 0.0f;
        } else {
          // The hat on the linear values and, when they were converted, on the values as
          // stored (full scale there is full scale of the camera's channels, whatever their
          // encoding): a channel clipped in the camera's space takes the weight away.
          const float* v = shots[i].at(x, y);
          const float* as = shots[i].storedAt(x, y);
          const float peak = std::max({v[0], v[1], v[2]});
          const float storedPeak = std::max({as[0], as[1], as[2]});
          w = float(shots[i].exposure) * std::min(linearHat(peak), linearHat(storedPeak));
          if (dark[i]) w *= 1e-3f;  // keep a trace so that a pixel dark everywhere gets a value
        }
        weight[i] = w;
        for (int c = 0; c < 3; ++c)
          value[i * 3 + size_t(c)] = float(linearOf(shots[i], x, y, c) / shots[i].exposure);
      }
      if (params.deghost) {
        // Reference: the middle shot, or the covered shot with weight nearest to it, among the
        // shots that agree with the over-exposed ones: a shot over-exposed here saw at least its
        // clip level, so a shot saying much less light (a thing that moved in front) is not the
        // reference. (With the middle shot over-exposed, the longer shot, a ghost darker than
        // the scene, was taken, and the shorter shot that saw the scene dropped.) When no shot
        // agrees, the nearest one with weight.
        auto luminance = [&](size_t i) {
          return std::max(1e-20f, value[i * 3] + value[i * 3 + 1] + value[i * 3 + 2]);
        };
        const float ghostRatio = float(std::exp2(-params.ghostStops));
        auto agrees = [&](size_t i) {
          for (size_t j = 0; j < n; ++j)
            if (j != i && covered[j] && over[j] && luminance(i) < ghostRatio * luminance(j))
              return false;
          return true;
        };
        size_t ref = n;
        for (int pass = 0; pass < 2 && ref == n; ++pass) {
          for (size_t d = 0; d < n && ref == n; ++d) {
            if (pivot + d < n && weight[pivot + d] > 0.0f && (pass == 1 || agrees(pivot + d)))
              ref = pivot + d;
            else if (d <= pivot && weight[pivot - d] > 0.0f && (pass == 1 || agrees(pivot - d)))
              ref = pivot - d;
          }
        }
        if (ref < n) {
          const float refLum =
              std::max(1e-20f, value[ref * 3] + value[ref * 3 + 1] + value[ref * 3 + 2]);
          bool dropped = false;
          for (size_t i = 0; i < n; ++i) {
            if (i == ref || weight[i] <= 0.0f) continue;
            const float lum = std::max(1e-20f, value[i * 3] + value[i * 3 + 1] + value[i * 3 + 2]);
            if (std::abs(std::log2(lum / refLum)) > params.ghostStops) {
              weight[i] = 0.0f;
              dropped = true;
            }
          }
          if (dropped) ghostRows[size_t(y)]++;
        }
      }
      double sum[3] = {0, 0, 0}, total = 0.0;
      if (input.eightBit && !params.deghost) {
        // A single 8-bit photo: the same log-domain average as MergeDebevec.
        for (size_t i = 0; i < n; ++i) {
          if (weight[i] <= 0.0f) continue;
          for (int c = 0; c < 3; ++c)
            sum[c] += weight[i] * std::log(std::max(value[i * 3 + size_t(c)], 1e-30f));
          total += weight[i];
        }
        for (int c = 0; c < 3; ++c) o[c] = total > 0.0 ? float(std::exp(sum[c] / total)) : 0.0f;
      } else {
        for (size_t i = 0; i < n; ++i) {
          if (weight[i] <= 0.0f) continue;
          for (int c = 0; c < 3; ++c) sum[c] += weight[i] * value[i * 3 + size_t(c)];
          total += weight[i];
        }
        for (int c = 0; c < 3; ++c) o[c] = total > 0.0 ? float(sum[c] / total) : 0.0f;
      }
      if (!(total > 0.0)) {
        // No shot trusted here although not every one reads as over-exposed (a deep shot just
        // below the clip level in its own encoding, near full scale as stored): the shortest
        // covering shot gives a bound, flagged as clipped. (It was written as black, unflagged.)
        size_t pick = 0;
        while (!covered[pick]) ++pick;
        for (int c = 0; c < 3; ++c) o[c] = value[pick * 3 + size_t(c)];
        o[3] = 1.0f;
        saturatedRows[size_t(y)]++;
      }
    }
    if (scaled) {
      // The caller's unit, while the row is still in cache.
      float* o = out.at(0, y);
      for (int x = 0; x < width; ++x, o += 4)
        for (int c = 0; c < 3; ++c) o[c] = float(o[c] * scale[size_t(c)]);
    }
  });
  for (int y = 0; y < height; ++y) {
    result.saturated += saturatedRows[size_t(y)];
    result.dark += darkRows[size_t(y)];
    result.ghosted += ghostRows[size_t(y)];
  }

  const size_t total = out.pixelCount();
  if (n == 1) {
    result.notes.push_back("only one photo (" + name(0) +
                           "): no merge, its values are linearised and divided by its exposure");
  }
  if (result.saturated > 0) {
    result.notes.push_back(std::to_string(result.saturated) + " pixels (" +
                           percent(result.saturated, total) +
                           ") are over-exposed in every photo: their radiance is a lower bound "
                           "(channel 'clipped' = 1); add a shorter exposure to recover them");
  }
  if (result.dark > 0) {
    result.outside = blackJoinedToTheEdge(darkMask);
    const int64_t inside = result.dark - result.outside;
    if (inside > 0) {
      result.notes.push_back(std::to_string(inside) + " pixels (" + percent(inside, total) +
                             ") are black in every photo: their radiance is an upper bound "
                             "(channel 'clipped' = 1); add a longer exposure to recover them");
    }
    if (result.outside > 0) {
      result.notes.push_back(
          std::to_string(result.outside) + " pixels (" + percent(result.outside, total) +
          ") black in every photo reach the frame's edge: no picture (the black around a "
          "fisheye's image circle, a vignette); channel 'clipped' = 1 there, and the stitch "
          "leaves them to other photos");
    }
  }
  if (params.deghost) {
    result.notes.push_back(
        "ghost suppression left shots out at " + std::to_string(result.ghosted) + " pixels (" +
        percent(result.ghosted, total) + ")" +
        (input.eightBit ? std::string("; with --deghost every pixel is a weighted average of the "
                                      "shots' linear values, not OpenCV's MergeDebevec")
                        : std::string()));
  }
  report(progress, kStage, 1.0);
  result.openCvSeconds = opencv.seconds;
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace compose::hdr
