#include "hdr/response.h"

#include <algorithm>
#include <array>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <optional>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include "core/error.h"
#include "core/hash.h"
#include "core/json_number.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "hdr/opencv_util.h"

namespace compose::hdr {

namespace fs = std::filesystem;

namespace {

std::string utcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

// Makes a recovered curve usable: positive and non-decreasing, working outwards from the middle
// (the ends rest on few samples and may wiggle).
void makeMonotone(std::vector<float>& curve) {
  for (float& v : curve)
    if (!std::isfinite(v) || v < 0.0f) v = 0.0f;
  const int mid = kCodes / 2;
  for (int z = mid + 1; z < kCodes; ++z) curve[z] = std::max(curve[z], curve[z - 1]);
  for (int z = mid - 1; z >= 0; --z) curve[z] = std::min(curve[z], curve[z + 1]);
  // Codes below any observed value can come out as 0 (Robertson): keep them positive and ordered.
  float floor = 0.0f;
  for (int z = 0; z < kCodes; ++z)
    if (curve[z] > 0.0f) {
      floor = curve[z];
      break;
    }
  if (floor <= 0.0f) return;
  for (int z = 0; z < kCodes && curve[z] <= 0.0f; ++z) curve[z] = floor * 0.5f;
  // An exact repeat of the value below is still non-decreasing; nothing more to do.
}

struct Sample {
  float score = 0.0f;            // roughness: summed 3x3 standard deviation over shots and channels
  std::vector<int> bins;         // per shot and channel: the band of the code
  std::vector<cv::Vec3b> codes;  // per shot, the rounded 3x3 mean
};

// Debevec & Malik (1997) recommend sample pixels from smooth regions, spread over the range of
// values. This picks up to `count` 5 x 5 patches on a grid over every view, scores them by how
// much the codes vary inside (noise, JPEG artefacts, edges: all bad for a least-squares fit),
// and takes the smoothest per band of code, for every shot and channel in turn, so that every
// part of every channel's curve is constrained, the ends included. A patch's codes are its
// rounded 5 x 5 means (a fifth of the noise). Patches with a clipped code (0 or >= 254) anywhere in
// any shot are left out: a clipped code only says "at least" (or "at most"), which the
// least-squares model cannot express, and it biases the patch's mean.
std::vector<Sample> selectSamples(const std::vector<std::vector<cv::Mat>>& views, int count) {
  constexpr int kBins = 32;
  constexpr int kRadius = 2;
  constexpr float kArea = float((2 * kRadius + 1) * (2 * kRadius + 1));
  std::vector<Sample> candidates;
  size_t pixels = 0;
  for (const auto& v : views) pixels += v[0].total();
  const int stride = std::max(3, int(std::sqrt(double(pixels) / (40.0 * count))));
  for (const auto& shots : views) {
    const size_t n = shots.size();
    const cv::Mat& mid = shots[n / 2];
    for (int y = kRadius; y + kRadius < mid.rows; y += stride) {
      for (int x = kRadius; x + kRadius < mid.cols; x += stride) {
        Sample s;
        s.codes.resize(n);
        bool clipped = false;
        for (size_t i = 0; i < n; ++i) {
          for (int c = 0; c < 3; ++c) {
            float sum = 0.0f, sum2 = 0.0f;
            for (int dy = -kRadius; dy <= kRadius; ++dy) {
              const uchar* row = shots[i].ptr<uchar>(y + dy);
              for (int dx = -kRadius; dx <= kRadius; ++dx) {
                const uchar code = row[3 * (x + dx) + c];
                const float v = code;
                sum += v;
                sum2 += v * v;
                clipped = clipped || code == 0 || code >= 254;
              }
            }
            const float mean = sum / kArea;
            s.score += std::sqrt(std::max(0.0f, sum2 / kArea - mean * mean));
            s.codes[i][c] = cv::saturate_cast<uchar>(mean);
          }
        }
        if (clipped) continue;
        for (size_t i = 0; i < n; ++i)
          for (int c = 0; c < 3; ++c) s.bins.push_back(s.codes[i][c] * kBins / kCodes);
        candidates.push_back(std::move(s));
      }
    }
  }
  std::sort(candidates.begin(), candidates.end(),
            [](const Sample& a, const Sample& b) { return a.score < b.score; });
  // Round-robin over the bands of each channel, smoothest first, until `count` are taken.
  const size_t keys = candidates.empty() ? 0 : candidates.front().bins.size();
  std::vector<std::vector<size_t>> bins(keys * kBins);
  for (size_t i = 0; i < candidates.size(); ++i)
    for (size_t k = 0; k < keys; ++k) bins[k * kBins + size_t(candidates[i].bins[k])].push_back(i);
  std::vector<size_t> next(bins.size(), 0);
  std::vector<char> taken(candidates.size(), 0);
  std::vector<Sample> out;
  bool any = true;
  while (int(out.size()) < count && any) {
    any = false;
    for (size_t b = 0; b < bins.size() && int(out.size()) < count; ++b) {
      while (next[b] < bins[b].size() && taken[bins[b][next[b]]]) ++next[b];
      if (next[b] == bins[b].size()) continue;
      const size_t pick = bins[b][next[b]++];
      taken[pick] = 1;
      out.push_back(candidates[pick]);
      any = true;
    }
  }
  return out;
}

// The smooth, unclipped 5 x 5 patches of one channel over every view, for refitFromPatches and
// for the codes a recovery observed. A patch's code in a shot is its mean, kept continuous.
// Patches with a clipped code (0 or >= 254) in any shot are left out, like the samples handed to
// OpenCV, and so is the roughest half of the rest (edges, JPEG ringing: a nonlinear curve maps
// the mean light of an uneven patch to a different code than its mean code).
struct Patches {
  size_t shots = 0;
  std::vector<float> mean;  // patch-major: mean[patch * shots + shot]
  size_t count() const { return shots ? mean.size() / shots : 0; }
};

Patches smoothPatches(const std::vector<const BracketCodes*>& used, size_t shots, int channel) {
  constexpr int kRadius = 2;
  constexpr float kArea = float((2 * kRadius + 1) * (2 * kRadius + 1));
  constexpr double kMaxPatches = 100000.0;  // the grid is thinned beyond this
  size_t pixels = 0;
  for (const BracketCodes* b : used)
    pixels += size_t(b->images[0]->width) * size_t(b->images[0]->height);
  const int stride = std::max(3, int(std::ceil(std::sqrt(double(pixels) / kMaxPatches))));
  std::vector<float> rough, mean;
  std::vector<float> one(shots);
  for (const BracketCodes* b : used) {
    const int width = b->images[0]->width, height = b->images[0]->height;
    for (int y = kRadius; y + kRadius < height; y += stride) {
      for (int x = kRadius; x + kRadius < width; x += stride) {
        float score = 0.0f;
        bool clipped = false;
        for (size_t j = 0; j < shots && !clipped; ++j) {
          const uint8_t* data = b->images[j]->data();
          float sum = 0.0f, sum2 = 0.0f;
          for (int dy = -kRadius; dy <= kRadius; ++dy) {
            const uint8_t* row = data + size_t(y + dy) * size_t(width) * 3;
            for (int dx = -kRadius; dx <= kRadius; ++dx) {
              const uint8_t code = row[3 * (x + dx) + channel];
              clipped = clipped || code == 0 || code >= 254;
              sum += float(code);
              sum2 += float(code) * float(code);
            }
          }
          one[j] = sum / kArea;
          score += std::sqrt(std::max(0.0f, sum2 / kArea - one[j] * one[j]));
        }
        if (clipped) continue;
        rough.push_back(score);
        mean.insert(mean.end(), one.begin(), one.end());
      }
    }
  }
  Patches out;
  out.shots = shots;
  if (rough.empty()) return out;
  std::vector<float> sorted = rough;
  const size_t half = sorted.size() / 2;
  std::nth_element(sorted.begin(), sorted.begin() + ptrdiff_t(half), sorted.end());
  const float limit = sorted[half];
  out.mean.reserve(mean.size() / 2 + shots);
  for (size_t i = 0; i < rough.size(); ++i)
    if (rough[i] <= limit)
      out.mean.insert(out.mean.end(), mean.begin() + ptrdiff_t(i * shots),
                      mean.begin() + ptrdiff_t((i + 1) * shots));
  return out;
}

// The codes the patches measure: from the kMinSeen-th lowest patch mean (over every shot) to
// the kMinSeen-th highest, each side at most up to code 128 ({128, 128}: too few patches).
std::array<int, 2> observedCodes(const Patches& patches) {
  constexpr double kMinSeen = 20.0;
  std::array<double, kCodes> seen{};
  for (float m : patches.mean) seen[size_t(std::clamp(int(std::lround(m)), 0, kCodes - 1))] += 1.0;
  std::array<int, 2> range{kCodes / 2, kCodes / 2};
  double below = 0.0, above = 0.0;
  for (int z = 0; z < kCodes / 2; ++z)
    if ((below += seen[size_t(z)]) >= kMinSeen) {
      range[0] = z;
      break;
    }
  for (int z = kCodes - 1; z > kCodes / 2; --z)
    if ((above += seen[size_t(z)]) >= kMinSeen) {
      range[1] = z;
      break;
    }
  return range;
}

// Debevec & Malik's model, fitted over every smooth patch of every view instead of the few
// hundred samples OpenCV's dense SVD can take. Every patch i asks, for each shot j,
//   g(m_ij) = ln E_i + ln t_j      (g = ln of the inverse response, linear between codes),
// its squared residual weighted by Debevec's hat w(m_ij), and the curve's smoothness
// λ Σ_z w(z) g''(z)² is added. (OpenCV weights each residual itself by the hat, which squares
// it in the sum: the ends of the range weigh less there.)
// The unknown ln E_i of every patch is eliminated in closed form (it is the weighted mean of
// g(m_ij) - ln t_j), which leaves 256 normal equations whatever the number of patches: a patch
// adds A^T (D - w w^T / Σw) A to them, A its shots' interpolation rows and D their weights.
// λ is `smoothness` times the data's mean weight per code. Returns ln of the inverse response,
// 0 at code 128; empty if the patches are too few or the system cannot be solved.
//
// Measured on the virtual camera (six 384 x 288 views, 3 and 5 exposures 2 EV apart, four
// HDRIs): OpenCV's fit from 150 patches wanders by up to ±3 % from code to code in the middle of
// the range (sunset, 5 exposures: 3.4 % largest deviation over codes 16-224, 1.21 % RMS over
// 5-250), this one by less (2.1 %, 0.70 %). The ends still rest on few patches; refineEnds
// refits them.
std::vector<double> refitFromPatches(const Patches& patches, const std::vector<double>& exposures,
                                     double smoothness) {
  constexpr size_t kMinPatches = 64;
  const size_t n = patches.shots, count = patches.count();
  if (count < kMinPatches || n < 2) return {};
  auto hat = [](double z) { return std::min(z, 255.0 - z) + 1.0; };
  std::vector<double> normal(size_t(kCodes) * kCodes, 0.0), rhs(kCodes, 0.0);
  std::vector<double> logTime(n), w(n), frac(n);
  std::vector<int> z0(n);
  for (size_t j = 0; j < n; ++j) logTime[j] = std::log(exposures[j]);
  double total = 0.0;
  for (size_t i = 0; i < count; ++i) {
    const float* m = patches.mean.data() + i * n;
    double sumW = 0.0;
    for (size_t j = 0; j < n; ++j) {
      z0[j] = std::min(int(m[j]), kCodes - 2);
      frac[j] = double(m[j]) - z0[j];
      w[j] = hat(m[j]);
      sumW += w[j];
    }
    total += sumW;
    for (size_t j = 0; j < n; ++j) {
      const double a[2] = {1.0 - frac[j], frac[j]};
      for (size_t k = 0; k < n; ++k) {
        const double q = (j == k ? w[j] : 0.0) - w[j] * w[k] / sumW;
        const double b[2] = {1.0 - frac[k], frac[k]};
        for (int r = 0; r < 2; ++r) {
          double* row = normal.data() + size_t(z0[j] + r) * kCodes + size_t(z0[k]);
          row[0] += a[r] * q * b[0];
          row[1] += a[r] * q * b[1];
          rhs[size_t(z0[j] + r)] += a[r] * q * logTime[k];
        }
      }
    }
  }
  const double lambda = smoothness * total / kCodes;
  for (int z = 1; z + 1 < kCodes; ++z) {
    const double ws = lambda * hat(z);
    const double d[3] = {1.0, -2.0, 1.0};
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        normal[size_t(z - 1 + r) * kCodes + size_t(z - 1 + c)] += ws * d[r] * d[c];
  }
  // The data and the smoothness leave g's level free; this pins it without pulling on the rest.
  normal[size_t(kCodes / 2) * kCodes + kCodes / 2] += 1.0;
  cv::Mat g;
  if (!cv::solve(cv::Mat(kCodes, kCodes, CV_64F, normal.data()),
                 cv::Mat(kCodes, 1, CV_64F, rhs.data()), g, cv::DECOMP_CHOLESKY))
    return {};
  std::vector<double> out(kCodes);
  for (int z = 0; z < kCodes; ++z) out[size_t(z)] = g.at<double>(z) - g.at<double>(kCodes / 2);
  for (double v : out)
    if (!std::isfinite(v)) return {};
  return out;
}

// The ends of a recovered curve, by regression of the code on the light. Debevec's fit rests the
// ends of the range on few samples of low weight and on its smoothness term, which bends them
// (measured on the virtual camera: up to 24 % at code 5, against about 1 % from code 16 to 240).
// But every pixel pairs a code at one end in one shot with a code in the trusted middle in the
// next shot: the middle code, through the curve and the exposure ratio, says how much light the
// pixel got, and the mean of the end codes seen at that light is the response there. Regressing
// the code on the light (not the light on the code) keeps sensor noise from biasing it: the noise
// is in the code, and the mean of a noisy, rounded code follows the noiseless curve wherever the
// noise spans a code or more. Bins of 2 % of light with at least kMinCount pixels are kept, made
// non-decreasing (pooling adjacent violators) and inverted; over kBlend codes towards the trusted
// range the fit is blended into the curve; below the lowest code the bins reach the curve goes on
// as the power of the code they show there, and other codes the bins do not reach keep the fit.
void refineEnds(ResponseCurve& curve, const std::vector<const BracketCodes*>& used,
                const std::vector<double>& exposures) {
  constexpr int kTrustedLow = 16, kTrustedHigh = 240;  // where the fit is within about 1 %
  constexpr int kLowEnd = 24, kHighEnd = 232, kBlend = 8;
  constexpr double kMinCount = 64.0;
  constexpr double kBinWidth = 0.02;  // in log light
  const size_t n = exposures.size();
  size_t pixels = 0;
  for (const BracketCodes* b : used)
    pixels += size_t(b->images[0]->width) * size_t(b->images[0]->height);
  const size_t stride = std::max<size_t>(1, pixels * (n - 1) / (size_t(2) << 20));  // ~2 M pairs
  // The lights come from the curves as fitted; the six (channel, end) tasks write disjoint codes.
  const std::array<std::vector<float>, 3> fits = curve.inverse;
  parallelFor(0, 6, [&](int64_t task) {
    const int c = int(task / 2);
    const bool low = task % 2 == 0;
    std::vector<float>& inv = curve.inverse[size_t(c)];
    const std::vector<float>& fit = fits[size_t(c)];
    // Per pair of adjacent shots, the bin of log light each trusted code gives (kNone: none), and
    // per bin (sum of the end codes, pixels, clipped codes among them).
    constexpr int kNone = INT_MIN;
    std::vector<std::array<int, 256>> binOf(n > 1 ? n - 1 : 0);
    int firstBin = INT_MAX, lastBin = INT_MIN;
    for (size_t j = 0; j + 1 < n; ++j) {
      const double ratio = exposures[j + 1] / exposures[j];
      binOf[j].fill(kNone);
      for (int t = kTrustedLow; t <= kTrustedHigh; ++t) {
        const double light = low ? fit[size_t(t)] / ratio : fit[size_t(t)] * ratio;
        if (!(light > 0.0) || !std::isfinite(light)) continue;
        binOf[j][size_t(t)] = int(std::floor(std::log(light) / kBinWidth));
        firstBin = std::min(firstBin, binOf[j][size_t(t)]);
        lastBin = std::max(lastBin, binOf[j][size_t(t)]);
      }
    }
    if (firstBin > lastBin) return;
    std::vector<std::array<double, 3>> sums(size_t(lastBin - firstBin + 1), {0.0, 0.0, 0.0});
    for (const BracketCodes* b : used) {
      const size_t count = size_t(b->images[0]->width) * size_t(b->images[0]->height);
      for (size_t j = 0; j + 1 < n; ++j) {
        const uint8_t* shorter = b->images[j]->data();
        const uint8_t* longer = b->images[j + 1]->data();
        const std::array<int, 256>& table = binOf[j];
        for (size_t i = (j * 7919) % stride; i < count; i += stride) {
          const int zs = shorter[3 * i + size_t(c)], zl = longer[3 * i + size_t(c)];
          // The trusted code tells the light; the other shot's code is the observation.
          const int trusted = low ? zl : zs, seen = low ? zs : zl;
          if (trusted < kTrustedLow || trusted > kTrustedHigh) continue;
          if (low ? seen > kLowEnd + kBlend : seen < kHighEnd - kBlend) continue;
          const int bin = table[size_t(trusted)];
          if (bin == kNone) continue;
          std::array<double, 3>& sum = sums[size_t(bin - firstBin)];
          sum[0] += seen;
          sum[1] += 1.0;
          sum[2] += (seen == 0 || seen == 255) ? 1.0 : 0.0;
        }
      }
    }
    struct Point {
      double logLight, code, weight;
    };
    std::vector<Point> pooled;
    for (size_t k = 0; k < sums.size(); ++k) {
      const std::array<double, 3>& sum = sums[k];
      if (sum[1] < kMinCount || sum[2] > 0.01 * sum[1]) continue;
      pooled.push_back({(firstBin + int(k) + 0.5) * kBinWidth, sum[0] / sum[1], sum[1]});
      while (pooled.size() >= 2 && pooled[pooled.size() - 2].code > pooled.back().code) {
        const Point b = pooled.back();
        pooled.pop_back();
        Point& a = pooled.back();
        const double w = a.weight + b.weight;
        a = {(a.logLight * a.weight + b.logLight * b.weight) / w,
             (a.code * a.weight + b.code * b.weight) / w, w};
      }
    }
    if (pooled.size() < 2) return;
    // Below the lowest code the bins reach (the light the lowest trusted code says, through the
    // exposure ratio: about code 4 of an sRGB curve 2 EV apart; higher where the darkest bins
    // hold too few pixels), the curve goes on as the power of the code that joins the lowest bin
    // to the one three codes above it, instead of the fit's extrapolation by smoothness (forest,
    // 3 exposures: the bins reached blue code 5.5, and the fit was 15 % off at code 5). Not into
    // the trusted range, and only for a power a camera's toe has (1 for a linear toe, 2.2-2.4
    // for a gamma) joining bins at least two codes apart.
    double power = 0.0;
    if (low) {
      const Point& a = pooled.front();
      size_t k = 1;
      while (k + 1 < pooled.size() && pooled[k].code < a.code + 3.0) ++k;
      const Point& b = pooled[k];
      if (a.code > 0.0 && b.code >= a.code + 2.0)
        power = (b.logLight - a.logLight) / (std::log(b.code) - std::log(a.code));
      if (!(power >= 0.5 && power <= 4.0)) power = 0.0;
    }
    // Invert: the light at which the mean code is z, for the end's codes the bins reach.
    const int from = low ? 1 : kHighEnd - kBlend, to = low ? kLowEnd + kBlend : 254;
    for (int z = from; z <= to; ++z) {
      if (power > 0.0 && z < pooled.front().code && z < kTrustedLow) {
        inv[size_t(z)] =
            float(std::exp(pooled.front().logLight +
                           power * (std::log(double(z)) - std::log(pooled.front().code))));
        continue;
      }
      size_t k = 1;
      while (k < pooled.size() && pooled[k].code < z) ++k;
      if (k == pooled.size() || pooled[k - 1].code > z) continue;  // not reached
      const Point& a = pooled[k - 1];
      const Point& b = pooled[k];
      const double t = b.code > a.code ? (z - a.code) / (b.code - a.code) : 0.5;
      const double fitted = a.logLight + t * (b.logLight - a.logLight);
      // All the fit's at the end, none of it kBlend codes into the trusted range.
      const double w = low ? std::clamp(double(kLowEnd + kBlend - z) / kBlend, 0.0, 1.0)
                           : std::clamp(double(z - (kHighEnd - kBlend)) / kBlend, 0.0, 1.0);
      // (A fit that is not positive there is replaced outright: its logarithm is not a number.)
      const double kept = double(fit[size_t(z)]);
      inv[size_t(z)] =
          float(w >= 1.0 || !(kept > 0.0) ? std::exp(fitted)
                                          : std::exp(w * fitted + (1.0 - w) * std::log(kept)));
    }
  });
}

// One curve for the three channels (RecoveryParams::sharedCurve): at every code, the mean of the
// channels' logarithms, each weighted by the pixels of every shot that show the code in it, so
// that a channel whose photos hardly reach a code takes its shape there from those that do. The
// curves are 1 at code 128: the mean keeps that, and the channels' scales (white balance) are
// what they were. Measured on the virtual camera (six 384 x 288 views of each sample HDRI, 3 and 5
// exposures): response RMS over codes 5-250 0.53-1.53 % -> 0.27-1.00 %, largest deviation at
// codes 16-224 1.34-3.00 % -> 0.9-1.4 % (each channel's ripple with the brackets' period is its
// own, and the mean evens it out); sunset, 3 exposures, whose red photos hold 452 pixels at code
// 5 against blue's 1785: 23.9 % -> 10.5 % off there.
void shareCurve(ResponseCurve& curve, const std::vector<const BracketCodes*>& used) {
  // The pixels counted: every one, or every stride-th of more than about 2 M (three 12 MP shots
  // counted whole took a fifth of the merge's own time).
  size_t pixels = 0;
  for (const BracketCodes* b : used)
    for (const Codes8* image : b->images) pixels += size_t(image->width) * size_t(image->height);
  const size_t stride = std::max<size_t>(1, pixels / (size_t(2) << 20));
  std::array<std::array<double, kCodes>, 3> count{};
  for (const BracketCodes* b : used) {
    for (const Codes8* image : b->images) {
      const uint8_t* codes = image->data();
      const size_t values = size_t(image->width) * size_t(image->height) * 3;
      for (size_t i = 0; i < values; i += 3 * stride)
        for (size_t c = 0; c < 3; ++c) count[c][codes[i + c]] += 1.0;
    }
  }
  std::vector<float> shared(kCodes, 0.0f);
  for (size_t z = 0; z < size_t(kCodes); ++z) {
    double sum = 0.0, weight = 0.0, plain = 0.0, channels = 0.0;
    for (size_t c = 0; c < 3; ++c) {
      const double v = double(curve.inverse[c][z]);
      if (!(v > 0.0) || !std::isfinite(v)) continue;
      sum += count[c][z] * std::log(v);
      weight += count[c][z];
      plain += std::log(v);
      channels += 1.0;
    }
    if (!(weight > 0.0)) {  // no photo shows the code: the channels' plain mean
      sum = plain;
      weight = channels;
    }
    if (!(weight > 0.0)) continue;
    shared[z] = float(std::exp(sum / weight));
  }
  makeMonotone(shared);
  for (auto& ch : curve.inverse) ch = shared;
}

}  // namespace

Codes8 toCodes8(const Image& image) {
  COMPOSE_CHECK(image.channels >= 3);
  Codes8 out;
  out.width = image.width;
  out.height = image.height;
  out.rgb.resize(image.pixelCount() * 3);
  const int ch = image.channels;
  parallelFor(
      0, image.height,
      [&](int64_t y) {
        const float* src = image.row(int(y)).data();
        uint8_t* dst = out.rgb.data() + size_t(y) * size_t(image.width) * 3;
        for (int x = 0; x < image.width; ++x) {
          for (int c = 0; c < 3; ++c) {
            const float v = src[size_t(x) * size_t(ch) + size_t(c)] * 255.0f + 0.5f;
            dst[3 * x + c] = uint8_t(v <= 0.0f ? 0.0f : (v >= 255.0f ? 255.0f : v));
          }
        }
      },
      16);
  return out;
}

const char* methodName(RecoveryMethod method) {
  return method == RecoveryMethod::Debevec ? "debevec" : "robertson";
}

float ResponseCurve::linear(int channel, float code) const {
  const auto& c = inverse[size_t(channel)];
  const float z = std::clamp(code, 0.0f, float(kCodes - 1));
  const int z0 = std::min(int(z), kCodes - 2);
  const float f = z - float(z0);
  return c[size_t(z0)] * (1.0f - f) + c[size_t(z0) + 1] * f;
}

void ResponseCurve::validate(const fs::path& file) const {
  for (int c = 0; c < 3; ++c) {
    const auto& v = inverse[size_t(c)];
    if (v.size() != size_t(kCodes))
      throw Error(kStage, "a response curve needs 256 values per channel", file);
    for (int z = 0; z < kCodes; ++z) {
      if (!std::isfinite(v[size_t(z)]) || !(v[size_t(z)] > 0.0f))
        throw Error(kStage,
                    "response curve value at code " + std::to_string(z) + " is not positive", file);
      if (z > 0 && v[size_t(z)] < v[size_t(z) - 1])
        throw Error(kStage,
                    "response curve decreases at code " + std::to_string(z) +
                        " (a camera's response never does)",
                    file);
    }
    // From black to white a camera's codes span stops of light, not none (a flat curve decodes
    // every code alike) nor more than 40 (a value edited to 3e38 overflowed the merge).
    const double span = double(v.back()) / double(v.front());
    if (!(span >= 2.0) || !(span <= 1e12)) {
      char text[200];
      std::snprintf(text, sizeof text,
                    "response curve of channel %d spans %.3g stops from code 0 to 255 (%g to %g): "
                    "a camera's spans between 1 and 40",
                    c, std::log2(span), double(v.front()), double(v.back()));
      throw Error(kStage, text, file);
    }
  }
}

ResponseCurve ResponseCurve::srgb() {
  ResponseCurve r;
  for (auto& ch : r.inverse) {
    ch.resize(kCodes);
    for (int z = 0; z < kCodes; ++z) ch[size_t(z)] = float(srgbDecode(z / 255.0));
    ch[0] = ch[1] * 0.5f;  // code 0 still means "some light below code 1"
  }
  r.method = "srgb";
  r.source = "the sRGB decoding curve (IEC 61966-2-1)";
  return r;
}

void RecoveryParams::validate() const {
  if (samples < 10 || samples > 100000)
    throw Error(kStage, "response samples (--samples) must be between 10 and 100000, got " +
                            std::to_string(samples));
  if (!(lambda > 0.0) || !std::isfinite(lambda))
    throw Error(kStage, "the response smoothness (--lambda) must be a positive number, got " +
                            numberText(lambda));
  if (!(refitSmoothness > 0.0) || !std::isfinite(refitSmoothness))
    throw Error(kStage,
                "the refit's smoothness (--refit-smoothness) must be a positive number, got " +
                    numberText(refitSmoothness));
  if (maxIterations < 1) throw Error(kStage, "Robertson iterations must be at least 1");
  if (!(threshold > 0.0)) throw Error(kStage, "Robertson threshold must be positive");
  if (maxPixels < 1024) throw Error(kStage, "Robertson needs at least 1024 pixels");
}

double responseDisagreement(const ResponseCurve& curve, const std::vector<BracketCodes>& brackets) {
  COMPOSE_CHECK(!curve.empty());
  std::array<std::array<double, 256>, 3> lnX;
  for (size_t c = 0; c < 3; ++c)
    for (size_t z = 0; z < 256; ++z)
      lnX[c][z] = std::log(std::max(double(curve.inverse[c][z]), 1e-30));
  constexpr int kLow = 16, kHigh = 235;
  constexpr size_t kPixelsPerBracket = 40000;  // a strided sample: enough for a median
  std::vector<float> d;
  for (const BracketCodes& b : brackets) {
    if (b.images.size() < 2) continue;
    const size_t pixels = size_t(b.images[0]->width) * size_t(b.images[0]->height);
    const size_t step = std::max<size_t>(1, pixels / kPixelsPerBracket);
    for (size_t j = 0; j + 1 < b.images.size(); ++j) {
      const uint8_t* a = b.images[j]->data();
      const uint8_t* n = b.images[j + 1]->data();
      const double lnRatio = std::log(b.exposures[j + 1] / b.exposures[j]);
      for (size_t i = 0; i < pixels; i += step) {
        for (size_t c = 0; c < 3; ++c) {
          const int z1 = a[3 * i + c], z2 = n[3 * i + c];
          if (z1 < kLow || z1 > kHigh || z2 < kLow || z2 > kHigh) continue;
          d.push_back(float(std::abs(lnX[c][size_t(z2)] - lnX[c][size_t(z1)] - lnRatio)));
        }
      }
    }
  }
  if (d.empty()) return std::nan("");
  std::nth_element(d.begin(), d.begin() + ptrdiff_t(d.size() / 2), d.end());
  return double(d[d.size() / 2]);
}

ResponseCurve recoverResponse(const std::vector<BracketCodes>& brackets,
                              const RecoveryParams& params, const Progress& progress,
                              double* openCvSeconds) {
  params.validate();
  COMPOSE_CHECK(!brackets.empty());
  const BracketCodes& first = brackets.front();
  COMPOSE_CHECK(first.images.size() == first.exposures.size());
  const size_t n = first.images.size();
  if (n < 2) throw Error(kStage, "recovering a response needs at least two exposures");
  for (const BracketCodes& b : brackets) {
    COMPOSE_CHECK(b.images.size() == b.exposures.size() && !b.images.empty());
    for (const Codes8* img : b.images) {
      if (img->width != b.images[0]->width || img->height != b.images[0]->height)
        throw Error(kStage, "photos of a bracket must have the same size");
    }
  }

  // Brackets with the same exposure sequence (within 1 %) are stacked vertically, so that one
  // calibration sees every view.
  std::vector<const BracketCodes*> used;
  for (const BracketCodes& b : brackets) {
    if (b.exposures.size() != n) continue;
    bool same = true;
    for (size_t i = 0; i < n && same; ++i)
      same = std::abs(b.exposures[i] / first.exposures[i] - 1.0) < 0.01 &&
             b.images[i]->width == first.images[0]->width;
    if (same) used.push_back(&b);
  }
  report(progress, "response", 0.0);
  cv::Mat times(int(n), 1, CV_32F);
  for (size_t i = 0; i < n; ++i) times.at<float>(int(i)) = float(first.exposures[i]);

  cv::Mat response;
  OpenCvClock opencv;
  if (params.method == RecoveryMethod::Debevec) {
    // The chosen samples go to OpenCV as a mosaic of k x k blocks, one block per sample, and
    // OpenCV's grid of `samples` points is made to land on one point in every block: with a
    // mosaic of width kB and height kB + B/2 (blocks shifted down by B/2), k² + k/2 + 1 grid
    // points give exactly k columns and k rows with a step of B, whether OpenCV starts its rows
    // at step/2 or at step (both occur across 4.x releases).
    std::vector<std::vector<cv::Mat>> views;
    for (const BracketCodes* b : used) {
      views.emplace_back();
      for (size_t i = 0; i < n; ++i) views.back().push_back(wrap(*b->images[i]));
    }
    const std::vector<Sample> samples = selectSamples(views, params.samples);
    views.clear();
    if (samples.empty()) {
      // All black or all clipped (a solid photo, or a bracket far too dark or bright).
      throw Error(kStage,
                  "the response recovery failed: no pixel is between black and clipped in every "
                  "exposure, so the photos say nothing about the response (too dark, too bright, "
                  "or of a uniform scene)");
    }
    const int k = std::max(4, int(std::floor(std::sqrt(double(samples.size())))));
    constexpr int B = 4;
    std::vector<cv::Mat> mosaic(n);
    for (size_t i = 0; i < n; ++i) {
      mosaic[i] = cv::Mat(k * B + B / 2, k * B, CV_8UC3);
      for (int row = 0; row < mosaic[i].rows; ++row) {
        const int by = std::clamp((row - B / 2) / B, 0, k - 1);
        for (int col = 0; col < mosaic[i].cols; ++col) {
          const size_t index = size_t(by * k + col / B) % samples.size();
          mosaic[i].at<cv::Vec3b>(row, col) = samples[index].codes[i];
        }
      }
    }
    const int gridPoints = k * k + k / 2 + 1;
    auto calibrate = cv::createCalibrateDebevec(gridPoints, float(params.lambda), false);
    opencv([&] { calibrate->process(mosaic, response, times); });
  } else {
    // Robertson uses every pixel of the views, stacked vertically; large captures are
    // subsampled (nearest, so codes stay codes).
    int rows = 0;
    for (const BracketCodes* b : used) rows += b->images[0]->height;
    const int cols = first.images[0]->width;
    std::vector<cv::Mat> stacks(n);
    for (size_t i = 0; i < n; ++i) {
      stacks[i].create(rows, cols, CV_8UC3);
      int y = 0;
      for (const BracketCodes* b : used) {
        const Codes8& img = *b->images[i];
        wrap(img).copyTo(stacks[i].rowRange(y, y + img.height));
        y += img.height;
      }
    }
    const double scale = std::min(1.0, std::sqrt(double(params.maxPixels) / (double(rows) * cols)));
    if (scale < 1.0) {
      for (cv::Mat& s : stacks) {
        cv::Mat small;
        cv::resize(s, small, cv::Size(), scale, scale, cv::INTER_NEAREST);
        s = small;
      }
    }
    auto calibrate = cv::createCalibrateRobertson(params.maxIterations, float(params.threshold));
    opencv([&] { calibrate->process(stacks, response, times); });
  }
  report(progress, "response", 1.0);
  if (openCvSeconds) *openCvSeconds = opencv.seconds;

  ResponseCurve curve;
  for (int c = 0; c < 3; ++c) {
    auto& ch = curve.inverse[size_t(c)];
    ch.resize(kCodes);
    for (int z = 0; z < kCodes; ++z) ch[size_t(z)] = response.at<cv::Vec3f>(z)[c];
    makeMonotone(ch);
    const float mid = ch[kCodes / 2];
    if (!(mid > 0.0f) || !std::isfinite(mid))
      throw Error(kStage, "the response recovery failed (no usable pixels at mid-grey)");
    for (float& v : ch) v /= mid;
  }
  // Every smooth patch: the codes the photos measure, and Debevec's fit solved over all of them.
  std::array<size_t, 3> refitted{};  // per channel, the patches of its refit (0: none)
  parallelFor(0, 3, [&](int64_t c) {
    const Patches patches = smoothPatches(used, n, int(c));
    curve.observed[size_t(c)] = observedCodes(patches);
    if (params.method != RecoveryMethod::Debevec || !params.refit) return;
    const std::vector<double> g =
        refitFromPatches(patches, first.exposures, params.refitSmoothness);
    if (g.empty()) return;
    auto& ch = curve.inverse[size_t(c)];
    for (int z = 0; z < kCodes; ++z) ch[size_t(z)] = float(std::exp(g[size_t(z)]));
    makeMonotone(ch);
    refitted[size_t(c)] = patches.count();
  });
  if (params.refineEnds) {
    refineEnds(curve, used, first.exposures);
    for (auto& ch : curve.inverse) makeMonotone(ch);
  }
  if (params.sharedCurve) shareCurve(curve, used);
  curve.method = methodName(params.method);
  curve.created = utcNow();
  size_t photos = 0;
  for (const BracketCodes* b : used) photos += b->images.size();
  curve.source =
      "recovered (" + std::string(curve.method) + ") from " + std::to_string(photos) +
      " photos in " + std::to_string(used.size()) + (used.size() == 1 ? " view" : " views") +
      (params.sharedCurve ? ", one curve for the three channels" : ", a curve per channel");
  if (params.method == RecoveryMethod::Debevec && params.refit) {
    std::string kept;
    size_t most = 0;
    for (int c = 0; c < 3; ++c) {
      if (!refitted[size_t(c)]) kept += std::string(kept.empty() ? "" : ", ") + "RGB"[c];
      most = std::max(most, refitted[size_t(c)]);
    }
    if (most > 0) curve.source += ", fitted over up to " + std::to_string(most) + " smooth patches";
    if (!kept.empty())
      curve.source += " (" + kept + ": too few patches, OpenCV's fit from " +
                      std::to_string(params.samples) + " samples kept)";
  }
  curve.validate();
  return curve;
}

std::string responseText(const ResponseCurve& curve) {
  curve.validate();
  nlohmann::ordered_json j;
  j["format"] = "compose-response";
  j["version"] = 1;
  j["camera"] = {{"make", curve.make}, {"model", curve.model}};
  j["method"] = curve.method;
  j["created"] = curve.created;
  j["source"] = curve.source;
  j["channels"] = {"R", "G", "B"};
  j["meaning"] =
      "inverse[c][z]: linear exposure giving 8-bit code z in channel c; radiance = inverse / "
      "(t * ISO / N^2)";
  j["observed"] = {curve.observed[0], curve.observed[1], curve.observed[2]};
  j["inverse"] = {curve.inverse[0], curve.inverse[1], curve.inverse[2]};
  return j.dump(1) + "\n";
}

void writeResponse(const fs::path& file, const ResponseCurve& curve) {
  writeTextFile(file, responseText(curve), kStage);
}

ResponseCurve readResponse(const fs::path& file) try {
  protectInput(file);
  requireInputFile(file, kStage, "response file");
  std::ifstream in(file);
  if (!in) throw Error(kStage, "cannot open the response file", file);
  nlohmann::json j;
  try {
    in >> j;
  } catch (const nlohmann::json::exception& e) {
    throw Error(kStage, std::string("not a valid JSON response file: ") + jsonMessage(e.what()),
                file);
  }
  if (!j.is_object() || j.value("format", std::string()) != "compose-response")
    throw Error(kStage, "not a response file (\"format\" must be \"compose-response\")", file);
  if (wholeMember(j, "version") != 1)
    throw Error(kStage, "unsupported response file version (this compose reads version 1)", file);
  ResponseCurve curve;
  if (j.contains("camera") && j["camera"].is_object()) {
    curve.make = j["camera"].value("make", std::string());
    curve.model = j["camera"].value("model", std::string());
  }
  curve.method = j.value("method", std::string("unknown"));
  curve.created = j.value("created", std::string());
  curve.source = "file " + file.string();
  if (!j.contains("inverse") || !j["inverse"].is_array() || j["inverse"].size() != 3)
    throw Error(kStage, "a response file needs \"inverse\": three arrays of 256 numbers", file);
  for (int c = 0; c < 3; ++c) {
    const auto& a = j["inverse"][size_t(c)];
    if (!a.is_array() || a.size() != size_t(kCodes))
      throw Error(kStage, "a response file needs \"inverse\": three arrays of 256 numbers", file);
    for (const auto& v : a) {
      if (!v.is_number()) throw Error(kStage, "response values must be numbers", file);
      curve.inverse[size_t(c)].push_back(v.get<float>());
    }
  }
  if (j.contains("observed")) {
    const auto& o = j["observed"];
    const bool shaped = o.is_array() && o.size() == 3 &&
                        std::all_of(o.begin(), o.end(), [](const nlohmann::json& r) {
                          return r.is_array() && r.size() == 2;
                        });
    if (!shaped)
      throw Error(kStage, "\"observed\" must be three [first, last] pairs of codes", file);
    for (size_t c = 0; c < 3; ++c) {
      const std::optional<int64_t> first = wholeNumber(o[c][0], 0, kCodes - 1),
                                   last = wholeNumber(o[c][1], 0, kCodes - 1);
      if (!first || !last || *first > *last)
        throw Error(kStage, "\"observed\" codes must be whole numbers 0 <= first <= last <= 255",
                    file);
      curve.observed[c] = {int(*first), int(*last)};
    }
  }
  curve.validate(file);
  return curve;
} catch (const nlohmann::json::exception& e) {
  // A field of the wrong type (a number where text belongs, ...): nlohmann reports it by
  // exception; it is bad input like any other, named with its file.
  throw Error(kStage, std::string("not a valid response file: ") + jsonMessage(e.what()), file);
}

fs::path responseDirectory() {
  if (const char* dir = std::getenv("COMPOSE_RESPONSE_DIR"); dir && *dir) return dir;
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg)
    return fs::path(xdg) / "compose" / "responses";
  if (const char* home = std::getenv("HOME"); home && *home)
    return fs::path(home) / ".cache" / "compose" / "responses";
  return fs::path(".cache") / "compose" / "responses";
}

fs::path responseFileFor(const fs::path& folder, const std::string& make,
                         const std::string& model) {
  if (make.empty() && model.empty()) return {};
  std::string name;
  bool lost = false;  // a character the name cannot hold (not ASCII, a control, a slash, ...)
  for (char c : make + "_" + model) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (std::isalnum(u) || c == '-' || c == '.') {
      name.push_back(char(std::tolower(u)));
      continue;
    }
    lost = lost || u >= 0x80 || u < 0x20;  // not ASCII, or a control character
    if (name.empty() || name.back() != '_') name.push_back('_');
  }
  while (!name.empty() && name.back() == '_') name.pop_back();
  while (!name.empty() && (name.front() == '_' || name.front() == '.')) name.erase(name.begin());
  // Two cameras whose names differ only in letters the file name cannot show (Камера X1 and
  // Зенит X1 were both x1.json), or a name longer than a file name may be (a 300-character make
  // failed the merge), get the exact names' hash. ASCII names keep the names they always had.
  constexpr size_t kLongest = 200;
  if (lost || name.size() > kLongest || name.empty()) {
    if (name.size() > kLongest) name.resize(kLongest);
    Hash128 h;
    h.bytes(make);
    h.bytes(model);
    name = (name.empty() ? "camera" : name) + "-" + h.hex().substr(0, 12);
  }
  return folder / (name + ".json");
}

Image linearize(const Image& encoded, const ResponseCurve& curve) {
  COMPOSE_CHECK(encoded.channels >= 3);
  Image out = encoded;
  const size_t count = encoded.pixelCount();
  const int ch = encoded.channels;
  for (size_t i = 0; i < count; ++i) {
    float* p = out.pixels.data() + i * size_t(ch);
    for (int c = 0; c < 3; ++c) {
      const float code = std::clamp(p[c], 0.0f, 1.0f) * 255.0f;
      const float rounded = std::nearbyint(code);
      p[c] = std::abs(code - rounded) < 1e-3f ? curve.inverse[size_t(c)][size_t(rounded)]
                                              : curve.linear(c, code);
    }
  }
  return out;
}

}  // namespace compose::hdr
