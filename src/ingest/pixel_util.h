// Pixel plumbing shared by the image readers and writers of ingest (not a public interface):
// the channels of one output assembled from several images, the largest value they hold, the
// float-to-integer conversion OpenImageIO uses, and EXIF orientation.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "core/image.h"

namespace compose::ingest::detail {

// The channels of one output file or part: images of one size whose channels follow one another,
// then channels of one value. An image's channels may be multiplied by factors on the way: `scales`
// holds one factor per channel of each image, or nothing for an image taken as it is (and is
// empty when no image is scaled).
struct ChannelSources {
  std::vector<const Image*> images;
  std::vector<float> constants;
  std::vector<std::vector<float>> scales;

  const std::vector<float>* scalesOf(size_t image) const {
    return image < scales.size() && !scales[image].empty() ? &scales[image] : nullptr;
  }

  int width() const { return images.front()->width; }
  int height() const { return images.front()->height; }
  int channels() const {
    int n = int(constants.size());
    for (const Image* image : images) n += image->channels;
    return n;
  }
};

// The largest finite magnitude among the sources' values (scaled), rows on every core.
float largestFiniteMagnitude(const ChannelSources& sources);

// The largest finite magnitude among `n` values (0 when there is none), four at a time; the same
// among values[i] * scales[i].
float largestFinite(const float* values, size_t n);
float largestFinite(const float* values, const float* scales, size_t n);

// An image's per-channel factors repeated over a row of `width` pixels, so that a row is scaled
// value by value.
inline std::vector<float> rowOfScales(const std::vector<float>& perChannel, int width) {
  std::vector<float> row;
  row.reserve(perChannel.size() * size_t(width));
  for (int x = 0; x < width; ++x) row.insert(row.end(), perChannel.begin(), perChannel.end());
  return row;
}

// Floats to halves as Imath rounds them (to nearest, ties to even), `n` of them: eight at a time
// with the processor's F16C instructions where it has them.
void toHalf(const float* from, uint16_t* to, size_t n);

// Float to an integer code of `maxCode` (255, 65535) as OpenImageIO converts it: v · maxCode
// rounded half away from zero, clamped to [0, maxCode]; NaN gives 0.
inline uint32_t toCode(float v, float maxCode) {
  float s = v * maxCode;
  s += s < 0.0f ? -0.5f : 0.5f;
  if (!(s > 0.0f)) return 0;  // negative, or NaN
  return s >= maxCode ? uint32_t(maxCode) : uint32_t(s);
}

// Turns `values` (width x height pixels of `channels` values, as stored in a file) upright for
// EXIF orientation 2-8 (1 and anything else leave it as it is); width and height are swapped for
// orientations 5-8.
template <class Vector>
void applyOrientation(Vector& values, int& width, int& height, int channels, int orientation) {
  if (orientation < 2 || orientation > 8) return;
  const int w = width, h = height;
  const bool turned = orientation >= 5;  // the stored rows become columns
  const int outW = turned ? h : w, outH = turned ? w : h;
  Vector out(values.size());
  const size_t c = size_t(channels);
  // For each stored pixel (x, y): where it goes in the upright picture (EXIF 2.3, Orientation:
  // the stored row 0 is the picture's top (1-4) or left (5-8) side; 2, 3, 4 mirror, turn and
  // flip; 5 transposes, 6 turns clockwise, 7 transverses, 8 turns anticlockwise).
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      int u = x, v = y;
      switch (orientation) {
        case 2:
          u = w - 1 - x;
          break;
        case 3:
          u = w - 1 - x;
          v = h - 1 - y;
          break;
        case 4:
          v = h - 1 - y;
          break;
        case 5:
          u = y;
          v = x;
          break;
        case 6:
          u = h - 1 - y;
          v = x;
          break;
        case 7:
          u = h - 1 - y;
          v = w - 1 - x;
          break;
        case 8:
          u = y;
          v = w - 1 - x;
          break;
        default:
          break;
      }
      const auto* from = values.data() + (size_t(y) * size_t(w) + size_t(x)) * c;
      auto* to = out.data() + (size_t(v) * size_t(outW) + size_t(u)) * c;
      for (size_t k = 0; k < c; ++k) to[k] = from[k];
    }
  }
  values = std::move(out);
  width = outW;
  height = outH;
}

}  // namespace compose::ingest::detail
