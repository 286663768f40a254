// Image: the in-memory raster passed between stages.
//
// Pixels are 32-bit float, interleaved, row-major, top row first. Every image carries the name of
// its colour space (an OpenColorIO colour-space name, or empty when unknown) so that no stage has
// to guess what its numbers mean. Inside the pipeline, images are scene-linear in the working
// space (see color/color.h); only ingest and the display output see encoded values.
#pragma once

#include <cstddef>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "core/buffer.h"

namespace compose {

// An image's samples (sized without zeros: core/buffer.h).
using Pixels = FloatBuffer;

struct Image {
  int width = 0;
  int height = 0;
  int channels = 0;
  Pixels pixels;                          // width * height * channels, interleaved
  std::vector<std::string> channelNames;  // one per channel ("R", "G", "B", "A", "N.X", ...)
  std::string colorSpace;                 // OpenColorIO colour-space name; empty if unknown

  Image() = default;
  Image(int w, int h, int c, std::vector<std::string> names = {})
      : width(w),
        height(h),
        channels(c),
        pixels(size_t(w) * size_t(h) * size_t(c), 0.0f),
        channelNames(std::move(names)) {}

  // The same size and names with the samples left unset: for a frame whose every sample is about
  // to be written (decoded, converted, read), which the writing threads then touch first.
  static Image unfilled(int w, int h, int c, std::vector<std::string> names = {}) {
    Image image;
    image.width = w;
    image.height = h;
    image.channels = c;
    image.pixels.resize(size_t(w) * size_t(h) * size_t(c));
    image.channelNames = std::move(names);
    return image;
  }

  bool empty() const { return pixels.empty(); }
  size_t pixelCount() const { return size_t(width) * size_t(height); }

  float* at(int x, int y) {
    return pixels.data() + (size_t(y) * size_t(width) + size_t(x)) * channels;
  }
  const float* at(int x, int y) const {
    return pixels.data() + (size_t(y) * size_t(width) + size_t(x)) * channels;
  }
  std::span<float> row(int y) {
    return {pixels.data() + size_t(y) * size_t(width) * channels, size_t(width) * channels};
  }
  std::span<const float> row(int y) const {
    return {pixels.data() + size_t(y) * size_t(width) * channels, size_t(width) * channels};
  }
};

}  // namespace compose
