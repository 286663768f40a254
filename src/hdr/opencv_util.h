// Conversions between compose::Image and OpenCV matrices, and a clock for the time spent inside
// OpenCV. Private to the photo-stage libraries (src/hdr, calib).
#pragma once

#include <chrono>
#include <utility>

#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/image.h"

namespace compose::hdr {

// The first three channels of `image`, values in [0, 1] as read from an 8-bit file (code / 255),
// into `dst` (CV_8UC3, the image's size, already allocated), in R, G, B order.
inline void toCodes8(const Image& image, cv::Mat dst) {
  COMPOSE_CHECK(image.channels >= 3 && dst.type() == CV_8UC3 && dst.rows == image.height &&
                dst.cols == image.width);
  const int ch = image.channels;
  for (int y = 0; y < image.height; ++y) {
    const float* src = image.row(y).data();
    uchar* out = dst.ptr<uchar>(y);
    for (int x = 0; x < image.width; ++x) {
      for (int c = 0; c < 3; ++c) {
        const float v = src[size_t(x) * size_t(ch) + size_t(c)] * 255.0f + 0.5f;
        out[3 * x + c] = uchar(v <= 0.0f ? 0.0f : (v >= 255.0f ? 255.0f : v));
      }
    }
  }
}

// Accumulates wall-clock time spent in the calls it wraps.
class OpenCvClock {
 public:
  template <class F>
  decltype(auto) operator()(F&& f) {
    const auto start = std::chrono::steady_clock::now();
    struct Stop {
      OpenCvClock& clock;
      std::chrono::steady_clock::time_point start;
      ~Stop() {
        clock.seconds +=
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      }
    } stop{*this, start};
    return std::forward<F>(f)();
  }
  double seconds = 0.0;
};

}  // namespace compose::hdr
