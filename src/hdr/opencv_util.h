// OpenCV views of our data, and a clock for the time spent inside OpenCV. Private to src/hdr.
#pragma once

#include <chrono>
#include <utility>

#include <opencv2/core.hpp>

#include "core/error.h"
#include "core/image.h"
#include "hdr/response.h"

namespace compose::hdr {

// The stage these files' errors name.
inline constexpr const char* kStage = "merge";

// A matrix over the codes, without copying (OpenCV only reads it).
inline cv::Mat wrap(const Codes8& codes) {
  return cv::Mat(codes.height, codes.width, CV_8UC3, const_cast<uint8_t*>(codes.data()));
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
