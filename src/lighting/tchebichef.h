// Orthonormal discrete Tchebichef (Chebyshev) polynomials and the separable 2D moment transforms
// built on them (docs/design.md §4, §5).
//
// For a size N ≥ 1, the polynomials t_0 .. t_{N-1} are defined on the integer grid x = 0 .. N-1 and
// are orthonormal there:
//
//     Σ_x t_m(x) t_n(x) = δ_mn,        t_n has degree n and a positive leading coefficient,
//
// so t_0(x) = 1/√N, t_1(x) = (2x + 1 − N)·√(3 / (N(N² − 1))), and t_n(N−1−x) = (−1)^n t_n(x).
//
// Numerical contract
//   * TchebichefBasis is accurate at any order: max|T·Tᵀ − I| ≤ 1e-10 for every N ≤ 16384 at full
//     order; measured 6e-14 at N = 2048, 1.6e-13 at 4096, 3.5e-13 at 8192 (full checks) and
//     3e-13 on a sample of row pairs at 16384 (tests/bench/tchebichef_bench.cpp). It does NOT use
//     the textbook recurrence in n, which loses orthonormality from order ≈ 55 at N = 64
//     (docs/design.md §4); tchebichefNaive() keeps that recurrence only for comparison.
//   * Values too small for double (at the edges of very high orders at large N: t_{N−1}(0) is
//     about 2^−N) come out as subnormals or 0.
//   * Cost: O(N·K) time, K·N doubles plus K·N floats of memory. A full-order N = 16384 basis is
//     3 GiB; build only the order you need.
//
// Errors
//   * Bad sizes, orders and image shapes throw std::invalid_argument with a message that says which
//     argument was wrong. Indexing a row or element out of range is a bug and aborts
//     (COMPOSE_CHECK).
//
// Threading: the TchebichefBasis constructor builds rows in parallel with compose::parallelFor
// (oneTBB); everything else is single-threaded. All functions are reentrant, and a constructed
// basis is immutable and may be shared between threads.
#pragma once

#include <span>
#include <vector>

namespace compose::lighting {

// Largest supported N. Limits memory (a full-order basis is 12·N² bytes) and keeps the integer
// arithmetic of the recurrences exact in double.
inline constexpr int kMaxTchebichefSize = 16384;

// The first `order` (K) orthonormal Tchebichef polynomials sampled on x = 0 .. size-1 (N).
// Stored row-major K×N: row n holds t_n(0 .. N-1). A float copy of the same values (rounded from
// double) is kept for hot paths that work in float.
class TchebichefBasis {
 public:
  // Throws std::invalid_argument unless 1 ≤ size ≤ kMaxTchebichefSize and 1 ≤ order ≤ size.
  TchebichefBasis(int size, int order);

  int size() const { return size_; }
  int order() const { return order_; }

  // t_n(x) for 0 ≤ n < order(), 0 ≤ x < size().
  double operator()(int n, int x) const;

  // t_n(0 .. size()-1), in double or in float; 0 ≤ n < order().
  std::span<const double> row(int n) const;
  std::span<const float> rowF(int n) const;

  // All rows, K×N row-major.
  const std::vector<double>& matrix() const { return matrix_; }
  const std::vector<float>& matrixF() const { return matrixF_; }

 private:
  int size_;
  int order_;
  std::vector<double> matrix_;
  std::vector<float> matrixF_;
};

// The textbook three-term recurrence in n (Mukundan 2004, docs/design.md §4), evaluated entirely in
// T (double or float). Kept for comparison and benchmarks only: it is numerically unstable at high
// order. Returns K×N row-major. Throws std::invalid_argument on the same conditions as
// TchebichefBasis.
template <class T>
std::vector<T> tchebichefNaive(int size, int order);
extern template std::vector<double> tchebichefNaive<double>(int, int);
extern template std::vector<float> tchebichefNaive<float>(int, int);

// max over all 0 ≤ m, n < order of |Σ_x M(m, x) M(n, x) − δ_mn| for a row-major order×size matrix
// M, accumulated in double; +inf if any entry of M·Mᵀ is not finite (the naive recurrence
// overflows at large N). Costs O(order²·size): about a second at N = K = 2048. Throws
// std::invalid_argument if m.size() != order·size.
double orthonormalityError(std::span<const double> m, int order, int size);
double orthonormalityError(std::span<const float> m, int order, int size);

// ---------------------------------------------------------------------------------------------
// Separable 2D moments (docs/design.md §5, paper eq. 3)
//
// An image f has rows×cols samples, row-major, with rows = rowBasis.size() and
// cols = colBasis.size(). Its order-K moments are the K×K matrix (row-major)
//
//     T_mn = Σ_i Σ_j t_m(i) t_n(j) f(i, j),      0 ≤ m, n < K,
//
// where t_m comes from rowBasis and t_n from colBasis; computed separably as P·F·Qᵀ with P, Q the
// first K rows of the two bases, in O(K·rows·cols + K²·rows) with double accumulation.
// reconstruct2d is the (truncated) inverse Pᵀ·T·Q:
//
//     f̂(i, j) = Σ_{m<K} Σ_{n<K} t_m(i) t_n(j) T_mn,
//
// which returns f exactly (to rounding) when K = rows = cols, and otherwise its least-squares
// projection onto the first K×K moments. No weights are applied: put quadrature weights into f.
//
// Both allocate and return their output. They throw std::invalid_argument if K < 1, K exceeds the
// order of either basis, or the input has the wrong number of elements.
// ---------------------------------------------------------------------------------------------
std::vector<double> moments2d(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                              std::span<const double> image, int order);
std::vector<double> moments2d(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                              std::span<const float> image, int order);

// Returns rows×cols samples, row-major, from K×K moments (row-major).
std::vector<double> reconstruct2d(const TchebichefBasis& rowBasis, const TchebichefBasis& colBasis,
                                  std::span<const double> moments, int order);

}  // namespace compose::lighting
