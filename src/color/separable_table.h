// A colour transform of the shape "matrix, then a curve per channel", evaluated by table.
//
// Display transforms mostly have that shape: a matrix from the working space to the display's
// primaries, then per-channel curves (a tone curve or highlight shoulder, a clip, the display's
// encoding). OpenColorIO evaluates such curves value by value with pow, log and spline code; the
// built-in Soft Clip view costs about 85 ns a pixel on one core, a quarter of a second on a
// 12-megapixel frame with two. Here the curves are sampled once on the half-float grid (1024 steps
// across [0, 2^-14], then 1024 per binade up to 2^16, both signs) and read by linear
// interpolation, a few nanoseconds a pixel.
//
// The table is checked when it is built: at the middle of every interval it must agree with the
// curves within the tolerance asked for. Intervals where it does not (a kink between grid points,
// a step) are marked, and values falling in them are left to the exact transform, as are values
// beyond the grid (|x| >= 2^16, infinities, NaN). A transform with too many such intervals gets no
// table at all.
#pragma once

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <vector>

#include "core/image.h"

namespace compose::color {

class SeparableTable {
 public:
  // rgb' = M rgb + offset: rows of M, each followed by its offset.
  using Matrix = std::array<double, 12>;
  // Evaluates the curves in place on `count` RGB triples (interleaved).
  using Curves = std::function<void(float* rgb, int64_t count)>;
  // Evaluates the whole transform (matrix and curves) on one RGB triple in place.
  using Exact = std::function<void(float* rgb)>;

  // The grid: entries at 0, 2^-24, ..., 2^-14 (1025), then 1024 per binade up to 2^16.
  static constexpr int kSubnormalSteps = 1024;
  static constexpr int kBinades = 30;
  static constexpr int kEntries = kSubnormalSteps * (1 + kBinades) + 1;
  static constexpr float kLimit = 65536.0f;  // |x| at or above goes to the exact transform
  // At most this share of the intervals may be left to the exact transform.
  static constexpr double kMaxExactShare = 0.01;

  // Samples `curves` on the grid and checks every interval's midpoint: agreement within
  // tolerance * max(1, |value|), or both NaN. Empty when more than kMaxExactShare of the intervals
  // fail the check.
  static std::optional<SeparableTable> build(const Matrix& matrix, const Curves& curves,
                                             double tolerance);

  // Applies the transform to the first three channels of every pixel, in place, rows in parallel.
  // Pixels with a channel (after the matrix) beyond the grid or in a marked interval are given to
  // `exact` as they were. Returns how many were.
  int64_t apply(Image& image, const Exact& exact) const;

  // Intervals left to the exact transform (for tests and reports).
  int exactIntervals() const { return exactIntervals_; }

 private:
  std::array<float, 12> matrix_{};
  // Per sign (0: x >= 0, 1: x < 0) and channel: the curve at the grid's entries.
  std::array<std::array<std::vector<float>, 3>, 2> values_;
  // Per sign and channel: 1 where the interval [i, i+1] is left to the exact transform.
  std::array<std::array<std::vector<uint8_t>, 3>, 2> exact_;
  int exactIntervals_ = 0;
};

}  // namespace compose::color
