#include "lighting/tchebichef.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>

#include "core/error.h"
#include "core/parallel.h"

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace compose::lighting {

namespace {

void validateSizeOrder(int size, int order) {
  if (size < 1 || size > kMaxTchebichefSize) {
    throw std::invalid_argument("Tchebichef basis: size N = " + std::to_string(size) +
                                " is outside [1, " + std::to_string(kMaxTchebichefSize) + "]");
  }
  if (order < 1 || order > size) {
    throw std::invalid_argument("Tchebichef basis: order K = " + std::to_string(order) +
                                " is outside [1, N = " + std::to_string(size) + "]");
  }
}

// Derivation of the stable evaluation (docs/design.md §4).
//
// The textbook recurrence in n (tchebichefNaive) amplifies rounding error geometrically once n is
// large, so each row is computed by the recurrence in x of Mukundan ("Some computational aspects
// of discrete orthonormal moments", IEEE TIP 13(8), 2004), from the edge x = 0 to the middle,
// and mirrored with t_n(N−1−x) = (−1)^n t_n(x); the route also taken by Abdulhussain et al. ("On
// computational aspects of Tchebichef polynomials for higher polynomial order", IEEE Access 5,
// 2017):
//
//   t_0(0) = 1/√N,   t_n(0) = −√((N−n)/(N+n)) · √((2n+1)/(2n−1)) · t_{n−1}(0)
//   t_n(1) = (1 + n(n+1)/(1−N)) · t_n(0)
//   t_n(x) = γ1 t_n(x−1) + γ2 t_n(x−2),   2 ≤ x ≤ ⌈N/2⌉−1
//     γ1 = (−n(n+1) − (2x−1)(x−N−1) − x) / (x(N−x)),   γ2 = (x−1)(x−N−1) / (x(N−x)).
//
// Difference form. Expanding the numerators, γ1 + γ2 − 1 = −n(n+1) / (x(N−x)) exactly. With
// d(x) = t(x) − t(x−1), s(x) = −γ2 = (x−1)(N+1−x) / (x(N−x)) and q_n(x) = n(n+1) / (x(N−x)):
//
//   d(1) = −n(n+1)/(N−1) · t(0),   d(x) = s(x) d(x−1) − q_n(x) t(x−1),   t(x) = t(x−1) + d(x).
//
// At low order γ1 ≈ 2 and γ2 ≈ −1: both roots of the recurrence sit near 1, and the rounding of
// γ1 + γ2 (≈ 1) is summed twice along x, so in the γ form the error grows faster than linearly
// in x (measured: relative error 2e-11 in t_0 at N = 16384; max|T·Tᵀ − I| = 6e-13 at N = 2048).
// The difference form carries the small quantity q_n directly — t_0 comes out exact — and reaches
// 6e-14 at N = 2048. This is Reinsch's modification, as applied to the Goertzel/Clenshaw
// recurrence (Stoer & Bulirsch, Introduction to Numerical Analysis). At high order the wanted
// solution is the one that grows along x (from |t_{N−1}(0)| ≈ 2^−N to O(1/√N) in the middle), so
// forward errors are damped there.
//
// Range. t_n(0) underflows double long before n = N at large N, and a row spans more than the
// double exponent range, so each value is carried as v·2^e with an integer e. The start value is a
// running product whose mantissa is renormalised with frexp after every factor (relative error
// ≤ ~2n ulp, where a sum of logarithms would lose |log t_n(0)|·ulp); along the row, t and d are
// divided by 2^kRescaleBits, exactly, whenever |t| passes 2^kRescaleBits. Converting v·2^e to
// double rounds once, so values that truly underflow become subnormal or 0 and nothing else is
// lost. Integer coefficients (< 2^31 for N ≤ 16384) are formed exactly in int64.
constexpr int kRescaleBits = 256;
constexpr double kRescaleAbove = 0x1p256;
constexpr double kRescaleBy = 0x1p-256;
// Below the smallest subnormal exponent; |v| < 2^kRescaleBits, so v·2^e rounds to 0 below this.
constexpr int kZeroBelowExponent = -1075 - kRescaleBits;

// Per-x parts of the recurrence, shared by every row: s(x), and q_n(x) = n(n+1)·r(x).
struct XCoefficients {
  std::vector<double> s, r;
};

// Fills rows n0 .. n0+R−1. The R recurrences are interleaved to hide each one's latency. The first
// pass stores the mantissas in the left half of each row and notes where the row was rescaled;
// the second applies 2^e and mirrors. `rescaledAt` is scratch space of R·half ints.
template <int R>
void buildRows(int size, int n0, const XCoefficients& xc, const double* startMant,
               const int* startExp, double* out, float* outF, int* rescaledAt) {
  const int half = (size + 1) / 2;  // x = 0 .. half-1 computed; the middle one if N is odd.
  const double* xs = xc.s.data();
  const double* xr = xc.r.data();
  double* row[R];
  double nn1[R], t[R], d[R];
  int rescales[R];
  for (int k = 0; k < R; ++k) {
    const int64_t n = n0 + k;
    row[k] = out + static_cast<std::size_t>(n) * size;
    nn1[k] = static_cast<double>(n * (n + 1));
    rescales[k] = 0;
    t[k] = startMant[n];
    row[k][0] = t[k];
    d[k] = size > 1 ? -(nn1[k] / static_cast<double>(size - 1)) * t[k] : 0.0;
  }
  if (half > 1) {
    for (int k = 0; k < R; ++k) {
      t[k] += d[k];
      row[k][1] = t[k];
    }
  }
  for (int x = 2; x < half; ++x) {
    const double s = xs[x], r = xr[x];
    bool rescale = false;
#pragma GCC unroll 8
    for (int k = 0; k < R; ++k) {
      d[k] = s * d[k] - (nn1[k] * r) * t[k];
      t[k] += d[k];
      rescale |= std::fabs(t[k]) > kRescaleAbove;
    }
    if (rescale) [[unlikely]] {
      for (int k = 0; k < R; ++k) {
        if (std::fabs(t[k]) <= kRescaleAbove) continue;
        t[k] *= kRescaleBy;
        d[k] *= kRescaleBy;
        rescaledAt[k * half + rescales[k]++] = x;
      }
    }
#pragma GCC unroll 8
    for (int k = 0; k < R; ++k) row[k][x] = t[k];
  }
  for (int k = 0; k < R; ++k) {
    double* rowD = row[k];
    float* rowF = outF + static_cast<std::size_t>(n0 + k) * size;
    const bool oddRow = (n0 + k) % 2 == 1;
    const double sign = oddRow ? -1.0 : 1.0;
    auto emit = [&](int x, double value) {
      rowD[x] = value;
      rowD[size - 1 - x] = sign * value;
      rowF[x] = static_cast<float>(value);
      rowF[size - 1 - x] = static_cast<float>(sign * value);
    };
    for (int c = 0; c <= rescales[k]; ++c) {
      const int from = c == 0 ? 0 : rescaledAt[k * half + c - 1];
      const int to = c < rescales[k] ? rescaledAt[k * half + c] : half;
      const int e = startExp[n0 + k] + c * kRescaleBits;
      if (e >= -1074) {  // 2^e is exactly representable (possibly subnormal): one rounding.
        const double factor = std::ldexp(1.0, e);
        for (int x = from; x < to; ++x) emit(x, rowD[x] * factor);
      } else if (e >= kZeroBelowExponent) {
        for (int x = from; x < to; ++x) emit(x, std::ldexp(rowD[x], e));
      } else {
        for (int x = from; x < to; ++x) emit(x, 0.0);
      }
    }
    // Odd rows vanish at the centre of an odd grid; the recurrence only gets there to rounding.
    if (size % 2 == 1 && oddRow) emit(half - 1, 0.0);
  }
}

void buildStable(int size, int order, double* out, float* outF) {
  const int64_t bigN = size;
  const int half = (size + 1) / 2;
  XCoefficients xc{std::vector<double>(half), std::vector<double>(half)};
  for (int x = 2; x < half; ++x) {
    const int64_t bigX = x;
    const double den = static_cast<double>(bigX * (bigN - bigX));
    xc.s[x] = static_cast<double>((bigX - 1) * (bigN + 1 - bigX)) / den;
    xc.r[x] = 1.0 / den;
  }

  std::vector<double> startMant(order);
  std::vector<int> startExp(order);
  startMant[0] = std::frexp(1.0 / std::sqrt(static_cast<double>(size)), &startExp[0]);
  for (int n = 1; n < order; ++n) {
    const int64_t bign = n;
    const double ratio = static_cast<double>((bigN - bign) * (2 * bign + 1)) /
                         static_cast<double>((bigN + bign) * (2 * bign - 1));
    int de = 0;
    startMant[n] = std::frexp(-startMant[n - 1] * std::sqrt(ratio), &de);
    startExp[n] = startExp[n - 1] + de;
  }

  // Rows are independent: blocks of kInterleave rows, in parallel, with at least ~64k values per
  // task so that small bases are built inline.
  constexpr int kInterleave = 4;
  const int blocks = (order + kInterleave - 1) / kInterleave;
  const int64_t grain = std::max<int64_t>(1, (int64_t{1} << 16) / (int64_t{kInterleave} * size));
  auto buildBlock = [&](int64_t block) {
    const int n0 = static_cast<int>(block) * kInterleave;
    std::vector<int> rescaledAt(static_cast<std::size_t>(kInterleave) * half);
    if (n0 + kInterleave <= order) {
      buildRows<kInterleave>(size, n0, xc, startMant.data(), startExp.data(), out, outF,
                             rescaledAt.data());
    } else {
      for (int n = n0; n < order; ++n) {
        buildRows<1>(size, n, xc, startMant.data(), startExp.data(), out, outF, rescaledAt.data());
      }
    }
  };
  parallelFor(0, blocks, buildBlock, grain);
}

// Sizes `v` to `count` value-initialised elements. A full-order basis is large (192 MiB at
// N = 4096) and on Linux first-touch page faults on 4 KiB pages cost more than computing it, so ask
// for transparent huge pages (a hint; ignored where unsupported) before the memory is touched.
template <class T>
void resizeLarge(std::vector<T>& v, std::size_t count) {
  v.reserve(count);
#if defined(__linux__)
  constexpr std::uintptr_t kHugePage = std::uintptr_t{1} << 21;
  const auto begin = reinterpret_cast<std::uintptr_t>(v.data());
  const std::uintptr_t first = (begin + kHugePage - 1) & ~(kHugePage - 1);
  const std::uintptr_t last = (begin + count * sizeof(T)) & ~(kHugePage - 1);
  if (last > first) madvise(reinterpret_cast<void*>(first), last - first, MADV_HUGEPAGE);
#endif
  v.resize(count);
}

template <class T>
double orthonormalityErrorImpl(std::span<const T> m, int order, int size) {
  if (order < 1 || size < 1 ||
      m.size() != static_cast<std::size_t>(order) * static_cast<std::size_t>(size)) {
    throw std::invalid_argument("orthonormalityError: matrix has " + std::to_string(m.size()) +
                                " elements, expected order × size = " + std::to_string(order) +
                                " × " + std::to_string(size));
  }
  // Blocks of kB × kB row pairs so that each loaded value feeds kB products.
  constexpr int kB = 4;
  const T* base = m.data();
  auto rowPtr = [&](int r) { return base + static_cast<std::size_t>(r) * size; };
  double worst = 0.0;
  for (int i0 = 0; i0 < order; i0 += kB) {
    for (int j0 = i0; j0 < order; j0 += kB) {
      double acc[kB][kB] = {};
      if (i0 + kB <= order && j0 + kB <= order) {
        const T* a[kB] = {rowPtr(i0), rowPtr(i0 + 1), rowPtr(i0 + 2), rowPtr(i0 + 3)};
        const T* b[kB] = {rowPtr(j0), rowPtr(j0 + 1), rowPtr(j0 + 2), rowPtr(j0 + 3)};
        for (int x = 0; x < size; ++x) {
          double av[kB], bv[kB];
          for (int k = 0; k < kB; ++k) {
            av[k] = static_cast<double>(a[k][x]);
            bv[k] = static_cast<double>(b[k][x]);
          }
          for (int p = 0; p < kB; ++p) {
            for (int q = 0; q < kB; ++q) acc[p][q] += av[p] * bv[q];
          }
        }
      } else {
        for (int p = 0; p < kB && i0 + p < order; ++p) {
          for (int q = 0; q < kB && j0 + q < order; ++q) {
            const T* a = rowPtr(i0 + p);
            const T* b = rowPtr(j0 + q);
            double s = 0.0;
            for (int x = 0; x < size; ++x)
              s += static_cast<double>(a[x]) * static_cast<double>(b[x]);
            acc[p][q] = s;
          }
        }
      }
      for (int p = 0; p < kB && i0 + p < order; ++p) {
        for (int q = 0; q < kB && j0 + q < order; ++q) {
          const double expected = (i0 + p == j0 + q) ? 1.0 : 0.0;
          const double deviation = std::fabs(acc[p][q] - expected);
          if (std::isnan(deviation)) return std::numeric_limits<double>::infinity();
          worst = std::max(worst, deviation);
        }
      }
    }
  }
  return worst;
}

void validateMoments(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                     std::size_t inputSize, std::size_t expectedSize, const char* inputName,
                     int order, const char* who) {
  if (order < 1 || order > rowBasis.order() || order > colBasis.order()) {
    throw std::invalid_argument(std::string(who) + ": order K = " + std::to_string(order) +
                                " is outside [1, min(row basis order " +
                                std::to_string(rowBasis.order()) + ", column basis order " +
                                std::to_string(colBasis.order()) + ")]");
  }
  if (inputSize != expectedSize) {
    throw std::invalid_argument(std::string(who) + ": " + inputName + " has " +
                                std::to_string(inputSize) + " elements, expected " +
                                std::to_string(expectedSize));
  }
}

template <class T>
std::vector<double> moments2dImpl(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                                  std::span<const T> image, int order) {
  const std::size_t rows = rowBasis.size();
  const std::size_t cols = colBasis.size();
  const std::size_t k = order;
  validateMoments(rowBasis, colBasis, image.size(), rows * cols, "image (rows × cols)", order,
                  "moments2d");
  // G = F·Qᵀ (rows × K), then T = P·G (K × K).
  std::vector<double> g(rows * k);
  for (std::size_t i = 0; i < rows; ++i) {
    const T* f = image.data() + i * cols;
    for (std::size_t n = 0; n < k; ++n) {
      const double* q = colBasis.row(static_cast<int>(n)).data();
      double s = 0.0;
      for (std::size_t j = 0; j < cols; ++j) s += static_cast<double>(f[j]) * q[j];
      g[i * k + n] = s;
    }
  }
  std::vector<double> t(k * k, 0.0);
  for (std::size_t m = 0; m < k; ++m) {
    const double* p = rowBasis.row(static_cast<int>(m)).data();
    double* tm = t.data() + m * k;
    for (std::size_t i = 0; i < rows; ++i) {
      const double pi = p[i];
      const double* gi = g.data() + i * k;
      for (std::size_t n = 0; n < k; ++n) tm[n] += pi * gi[n];
    }
  }
  return t;
}

}  // namespace

TchebichefBasis::TchebichefBasis(int size, int order) : size_(size), order_(order) {
  validateSizeOrder(size, order);
  const std::size_t count = static_cast<std::size_t>(size) * static_cast<std::size_t>(order);
  resizeLarge(matrix_, count);
  resizeLarge(matrixF_, count);
  buildStable(size, order, matrix_.data(), matrixF_.data());
}

double TchebichefBasis::operator()(int n, int x) const {
  COMPOSE_CHECK(n >= 0 && n < order_ && x >= 0 && x < size_);
  return matrix_[static_cast<std::size_t>(n) * size_ + x];
}

std::span<const double> TchebichefBasis::row(int n) const {
  COMPOSE_CHECK(n >= 0 && n < order_);
  return std::span<const double>(matrix_).subspan(static_cast<std::size_t>(n) * size_, size_);
}

std::span<const float> TchebichefBasis::rowF(int n) const {
  COMPOSE_CHECK(n >= 0 && n < order_);
  return std::span<const float>(matrixF_).subspan(static_cast<std::size_t>(n) * size_, size_);
}

template <class T>
std::vector<T> tchebichefNaive(int size, int order) {
  validateSizeOrder(size, order);
  const std::size_t cols = size;
  const double bigN = size;
  std::vector<T> m(static_cast<std::size_t>(order) * cols);
  const T t0 = static_cast<T>(1.0 / std::sqrt(bigN));
  std::fill(m.begin(), m.begin() + static_cast<std::ptrdiff_t>(cols), t0);
  if (order == 1) return m;
  // The coefficients are rounded once to T; the recurrence itself runs in T.
  const T c1 = static_cast<T>(std::sqrt(3.0 / (bigN * (bigN * bigN - 1.0))));
  for (std::size_t x = 0; x < cols; ++x) {
    m[cols + x] = static_cast<T>(2.0 * static_cast<double>(x) + 1.0 - bigN) * c1;
  }
  for (int n = 2; n < order; ++n) {
    const double dn = n;
    const T alpha =
        static_cast<T>(std::sqrt(4.0 * dn * dn - 1.0) / (dn * std::sqrt(bigN * bigN - dn * dn)));
    const T beta = static_cast<T>(
        -((dn - 1.0) / dn) * std::sqrt((2.0 * dn + 1.0) / (2.0 * dn - 3.0)) *
        std::sqrt((bigN * bigN - (dn - 1.0) * (dn - 1.0)) / (bigN * bigN - dn * dn)));
    T* r = m.data() + static_cast<std::size_t>(n) * cols;
    const T* r1 = r - cols;
    const T* r2 = r1 - cols;
    for (std::size_t x = 0; x < cols; ++x) {
      const T u = static_cast<T>(2.0 * static_cast<double>(x) + 1.0 - bigN);
      r[x] = alpha * u * r1[x] + beta * r2[x];
    }
  }
  return m;
}

template std::vector<double> tchebichefNaive<double>(int, int);
template std::vector<float> tchebichefNaive<float>(int, int);

double orthonormalityError(std::span<const double> m, int order, int size) {
  return orthonormalityErrorImpl(m, order, size);
}

double orthonormalityError(std::span<const float> m, int order, int size) {
  return orthonormalityErrorImpl(m, order, size);
}

std::vector<double> moments2d(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                              std::span<const double> image, int order) {
  return moments2dImpl(rowBasis, colBasis, image, order);
}

std::vector<double> moments2d(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                              std::span<const float> image, int order) {
  return moments2dImpl(rowBasis, colBasis, image, order);
}

std::vector<double> reconstruct2d(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                                  std::span<const double> moments, int order) {
  const std::size_t rows = rowBasis.size();
  const std::size_t cols = colBasis.size();
  const std::size_t k = order;
  validateMoments(rowBasis, colBasis, moments.size(), k * k, "moments (K × K)", order,
                  "reconstruct2d");
  // H = T·Q (K × cols), then F = Pᵀ·H (rows × cols).
  std::vector<double> h(k * cols, 0.0);
  for (std::size_t m = 0; m < k; ++m) {
    double* hm = h.data() + m * cols;
    for (std::size_t n = 0; n < k; ++n) {
      const double tmn = moments[m * k + n];
      const double* q = colBasis.row(static_cast<int>(n)).data();
      for (std::size_t j = 0; j < cols; ++j) hm[j] += tmn * q[j];
    }
  }
  std::vector<double> f(rows * cols, 0.0);
  for (std::size_t m = 0; m < k; ++m) {
    const double* p = rowBasis.row(static_cast<int>(m)).data();
    const double* hm = h.data() + m * cols;
    for (std::size_t i = 0; i < rows; ++i) {
      const double pmi = p[i];
      double* fi = f.data() + i * cols;
      for (std::size_t j = 0; j < cols; ++j) fi[j] += pmi * hm[j];
    }
  }
  return f;
}

}  // namespace compose::lighting
