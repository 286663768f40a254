#include "color/separable_table.h"

#include <algorithm>
#include <bit>
#include <cmath>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::color {
namespace {

constexpr float kNormalStart = 0x1p-14f;  // where the binades begin
constexpr float kSubnormalStep = 0x1p-24f;
constexpr int kMantissaShift = 13;  // 23 float mantissa bits, 10 kept: 1024 entries a binade

// The grid value at entry i (0 <= i < kEntries).
float gridValue(int i) {
  if (i <= SeparableTable::kSubnormalSteps) return float(i) * kSubnormalStep;
  const uint32_t bits = std::bit_cast<uint32_t>(kNormalStart) +
                        (uint32_t(i - SeparableTable::kSubnormalSteps) << kMantissaShift);
  return std::bit_cast<float>(bits);
}

// The interval of the grid holding a (0 <= a < kLimit), and the position in it (0 <= f < 1).
// Within a binade the grid is uniform in value, so the fraction is linear in a.
inline int gridInterval(float a, float& f) {
  if (a < kNormalStart) {
    const float p = a * (1.0f / kSubnormalStep);  // exact: a power of two
    const int i = int(p);
    f = p - float(i);
    return i;
  }
  const uint32_t d = std::bit_cast<uint32_t>(a) - std::bit_cast<uint32_t>(kNormalStart);
  f = float(d & ((1u << kMantissaShift) - 1)) * (1.0f / float(1u << kMantissaShift));
  return SeparableTable::kSubnormalSteps + int(d >> kMantissaShift);
}

bool agrees(float table, float exact, double tolerance) {
  if (std::isnan(table) || std::isnan(exact)) return std::isnan(table) && std::isnan(exact);
  return std::abs(double(table) - double(exact)) <=
         tolerance * std::max(1.0, std::abs(double(exact)));
}

}  // namespace

std::optional<SeparableTable> SeparableTable::build(const Matrix& matrix, const Curves& curves,
                                                    double tolerance) {
  SeparableTable t;
  for (size_t k = 0; k < 12; ++k) t.matrix_[k] = float(matrix[k]);
  constexpr int kIntervals = kEntries - 1;
  // Every grid value and every interval's midpoint, both signs, in one call of the curves.
  std::vector<float> rgb(size_t(2) * (kEntries + kIntervals) * 3);
  auto slot = [&](int sign, int i, bool mid) {
    return (size_t(sign) * (kEntries + kIntervals) + (mid ? kEntries + i : i)) * 3;
  };
  for (int sign = 0; sign < 2; ++sign) {
    const float s = sign ? -1.0f : 1.0f;
    for (int i = 0; i < kEntries; ++i) {
      std::fill_n(rgb.begin() + ptrdiff_t(slot(sign, i, false)), 3, s * gridValue(i));
    }
    for (int i = 0; i < kIntervals; ++i) {
      const float mid = 0.5f * (gridValue(i) + gridValue(i + 1));
      std::fill_n(rgb.begin() + ptrdiff_t(slot(sign, i, true)), 3, s * mid);
    }
  }
  curves(rgb.data(), int64_t(rgb.size() / 3));

  for (int sign = 0; sign < 2; ++sign) {
    for (int c = 0; c < 3; ++c) {
      std::vector<float>& values = t.values_[size_t(sign)][size_t(c)];
      std::vector<uint8_t>& exact = t.exact_[size_t(sign)][size_t(c)];
      values.resize(kEntries);
      exact.assign(kIntervals, 0);
      for (int i = 0; i < kEntries; ++i) values[size_t(i)] = rgb[slot(sign, i, false) + size_t(c)];
      for (int i = 0; i < kIntervals; ++i) {
        const float interpolated = 0.5f * (values[size_t(i)] + values[size_t(i) + 1]);
        if (!agrees(interpolated, rgb[slot(sign, i, true) + size_t(c)], tolerance)) {
          exact[size_t(i)] = 1;
          ++t.exactIntervals_;
        }
      }
    }
  }
  if (t.exactIntervals_ > kMaxExactShare * 6.0 * kIntervals) return std::nullopt;
  return t;
}

int64_t SeparableTable::apply(Image& image, const Exact& exact) const {
  COMPOSE_CHECK(image.channels >= 3);
  const int channels = image.channels;
  const float* values[2][3];
  const uint8_t* marked[2][3];
  for (size_t sign = 0; sign < 2; ++sign)
    for (size_t c = 0; c < 3; ++c) {
      values[sign][c] = values_[sign][c].data();
      marked[sign][c] = exact_[sign][c].data();
    }
  const bool anyMarked = exactIntervals_ > 0;
  const float* m = matrix_.data();
  std::vector<int64_t> exactRows(size_t(image.height), 0);
  parallelFor(0, image.height, [&](int64_t y) {
    float* p = image.row(int(y)).data();
    int64_t exactHere = 0;
    for (int x = 0; x < image.width; ++x, p += channels) {
      const float r = p[0], g = p[1], b = p[2];
      float out[3];
      bool tabled = true;
      for (int c = 0; c < 3; ++c) {
        const float* row = m + 4 * c;
        const float v = row[0] * r + row[1] * g + row[2] * b + row[3];
        const float a = std::abs(v);
        if (!(a < kLimit)) {  // also NaN
          tabled = false;
          break;
        }
        const size_t sign = std::signbit(v) ? 1 : 0;
        float f;
        const int i = gridInterval(a, f);
        if (anyMarked && marked[sign][c][i]) {
          tabled = false;
          break;
        }
        const float* t = values[sign][c] + i;
        out[c] = t[0] + f * (t[1] - t[0]);
      }
      if (tabled) {
        p[0] = out[0];
        p[1] = out[1];
        p[2] = out[2];
      } else {
        exact(p);
        ++exactHere;
      }
    }
    exactRows[size_t(y)] = exactHere;
  });
  int64_t total = 0;
  for (int64_t n : exactRows) total += n;
  return total;
}

}  // namespace compose::color
