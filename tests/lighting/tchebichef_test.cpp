#include "lighting/tchebichef.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

namespace compose::lighting {
namespace {

// The project's accuracy requirement for the basis: max|T·Tᵀ − I| at full order, N ≤ 16384.
constexpr double kOrthonormalTol = 1e-10;
// Round trip reconstruct2d(moments2d(f)) at K = N, from the same requirement. Exact arithmetic
// gives f; what is left is rounding in two K×K×N products, ~1e-14.
constexpr double kRoundTripTol = 1e-10;
// Element-wise agreement with independent references computed in long double (Gram–Schmidt,
// closed forms), relative to the largest |t_n(x)| of the row. The recurrence's error grows slowly
// with N; measured worst cases: ~1e-15 for N ≤ 9, 1.6e-14 for t_1 at N = 16384, 4e-14 for
// t_{N−1} at N = 4096. 25× headroom over the worst.
constexpr double kReferenceRelTol = 1e-12;
// The float copy is the double basis rounded to float: each value moves by ≤ 2^-24 relatively, so
// by Cauchy–Schwarz each entry of T·Tᵀ moves by ≤ 2·2^-24 ≈ 1.2e-7. Twice that bound.
constexpr double kFloatCopyOrthonormalTol = 0x1p-22;
// "Has lost orthonormality": the threshold docs/design.md §4 uses for the naive recurrence.
constexpr double kBrokenTol = 1e-6;

// Runs `f` and returns the message of the std::invalid_argument it throws ("" if none).
template <class F>
std::string invalidArgumentMessage(F&& f) {
  try {
    f();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

std::vector<double> randomImage(std::size_t count, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> dist(-1.0, 1.0);
  std::vector<double> f(count);
  for (double& v : f) v = dist(rng);
  return f;
}

double maxAbsDiff(const std::vector<double>& a, const std::vector<double>& b) {
  EXPECT_EQ(a.size(), b.size());
  double worst = 0.0;
  for (std::size_t i = 0; i < a.size() && i < b.size(); ++i) {
    worst = std::max(worst, std::fabs(a[i] - b[i]));
  }
  return worst;
}

// Orthonormal polynomials on x = 0..N-1 by Gram–Schmidt of 1, u, u², ... (u = x mapped to [-1, 1]
// for conditioning; same span, same sign of the leading coefficient), in long double, twice for
// numerical orthogonality. Independent of the library: no recurrence, no closed form.
std::vector<std::vector<long double>> gramSchmidtBasis(int size) {
  std::vector<std::vector<long double>> q;
  for (int k = 0; k < size; ++k) {
    std::vector<long double> p(size);
    for (int x = 0; x < size; ++x) {
      const long double u = size == 1 ? 0.0L : (2.0L * x - (size - 1)) / (size - 1);
      p[x] = std::pow(u, k);
    }
    for (int pass = 0; pass < 2; ++pass) {
      for (const auto& qj : q) {
        long double dot = 0.0L;
        for (int x = 0; x < size; ++x) dot += p[x] * qj[x];
        for (int x = 0; x < size; ++x) p[x] -= dot * qj[x];
      }
    }
    long double norm = 0.0L;
    for (int x = 0; x < size; ++x) norm += p[x] * p[x];
    norm = std::sqrt(norm);
    for (int x = 0; x < size; ++x) p[x] /= norm;
    q.push_back(std::move(p));
  }
  return q;
}

TEST(TchebichefBasis, InvalidSizeOrOrderThrows) {
  EXPECT_NE(invalidArgumentMessage([] { TchebichefBasis(0, 1); }).find("size N = 0"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([] { TchebichefBasis(-3, 1); }).find("size N = -3"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([] {
              TchebichefBasis(kMaxTchebichefSize + 1, 1);
            }).find("size N = 16385"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([] { TchebichefBasis(8, 0); }).find("order K = 0"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([] { TchebichefBasis(8, 9); }).find("order K = 9"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([] { tchebichefNaive<double>(8, 9); }).find("order K = 9"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([] { tchebichefNaive<float>(0, 1); }).find("size N = 0"),
            std::string::npos);
  // The limits themselves are valid.
  EXPECT_EQ(invalidArgumentMessage([] { TchebichefBasis(1, 1); }), "");
  EXPECT_EQ(invalidArgumentMessage([] { TchebichefBasis(kMaxTchebichefSize, 2); }), "");
}

TEST(TchebichefBasis, OrthonormalityErrorRejectsWrongShape) {
  const std::vector<double> m(12, 0.0);
  EXPECT_NE(invalidArgumentMessage([&] { orthonormalityError(m, 3, 5); }).find("3 × 5"),
            std::string::npos);
}

TEST(TchebichefBasis, OrthonormalAtFullOrder) {
  for (int n : {1, 2, 3, 4, 5, 7, 8, 16, 31, 64, 100, 128, 255, 256, 512, 1000, 1024, 2048}) {
    SCOPED_TRACE("N = " + std::to_string(n));
    const TchebichefBasis basis(n, n);
    ASSERT_EQ(basis.size(), n);
    ASSERT_EQ(basis.order(), n);
    ASSERT_EQ(basis.matrix().size(), static_cast<std::size_t>(n) * n);
    EXPECT_LE(orthonormalityError(basis.matrix(), n, n), kOrthonormalTol);
    if (n <= 512) {  // The float bound is analytic; small sizes suffice and keep the test fast.
      EXPECT_LE(orthonormalityError(basis.matrixF(), n, n), kFloatCopyOrthonormalTol);
    }
  }
}

TEST(TchebichefBasis, OrthonormalAtLowOrderForLargestSize) {
  const TchebichefBasis basis(kMaxTchebichefSize, 16);
  EXPECT_LE(orthonormalityError(basis.matrix(), 16, kMaxTchebichefSize), kOrthonormalTol);
}

// Highest orders at N = 4096, where t_n(0) underflows double and the row is rescaled many times:
// every pair among the top 24 rows and each of those against 24 low and middle rows.
TEST(TchebichefBasis, OrthonormalNearFullOrderAtLargeSize) {
  constexpr int kN = 4096;
  const TchebichefBasis basis(kN, kN);
  std::vector<int> rows;
  for (int n = kN - 24; n < kN; ++n) rows.push_back(n);
  std::vector<int> others = rows;
  for (int n = 0; n < 12; ++n) others.push_back(n);
  for (int n = kN / 2 - 6; n < kN / 2 + 6; ++n) others.push_back(n);
  double worst = 0.0;
  for (int m : rows) {
    for (int n : others) {
      const auto a = basis.row(m);
      const auto b = basis.row(n);
      double dot = 0.0;
      for (int x = 0; x < kN; ++x) dot += a[x] * b[x];
      worst = std::max(worst, std::fabs(dot - (m == n ? 1.0 : 0.0)));
    }
  }
  EXPECT_LE(worst, kOrthonormalTol);
}

TEST(TchebichefBasis, MatchesGramSchmidtForSmallSizes) {
  for (int n = 1; n <= 9; ++n) {
    SCOPED_TRACE("N = " + std::to_string(n));
    const TchebichefBasis basis(n, n);
    const auto reference = gramSchmidtBasis(n);
    for (int k = 0; k < n; ++k) {
      long double rowMax = 0.0L;
      for (int x = 0; x < n; ++x) rowMax = std::max(rowMax, std::fabs(reference[k][x]));
      for (int x = 0; x < n; ++x) {
        EXPECT_NEAR(basis(k, x), static_cast<double>(reference[k][x]),
                    kReferenceRelTol * static_cast<double>(rowMax))
            << "n = " << k << ", x = " << x;
      }
    }
  }
}

// t_0 = 1/√N, t_1 = (2x+1−N)·√(3/(N(N²−1))), t_2 = (6x² − 6(N−1)x +
// (N−1)(N−2))·√(5/(N(N²−1)(N²−4))) (Mukundan 2001, with ρ(n, N) = (2n)!·C(N+n, 2n+1)).
TEST(TchebichefBasis, MatchesClosedFormsOfLowOrders) {
  for (int n : {3, 4, 5, 10, 333, 1000, kMaxTchebichefSize}) {
    SCOPED_TRACE("N = " + std::to_string(n));
    const TchebichefBasis basis(n, 3);
    const long double bigN = n;
    const long double c1 = std::sqrt(3.0L / (bigN * (bigN * bigN - 1)));
    const long double c2 = std::sqrt(5.0L / (bigN * (bigN * bigN - 1) * (bigN * bigN - 4)));
    std::vector<long double> expected[3];
    for (int x = 0; x < n; ++x) {
      const long double lx = x;
      expected[0].push_back(1.0L / std::sqrt(bigN));
      expected[1].push_back((2 * lx + 1 - bigN) * c1);
      expected[2].push_back((6 * lx * lx - 6 * (bigN - 1) * lx + (bigN - 1) * (bigN - 2)) * c2);
    }
    for (int k = 0; k < 3; ++k) {
      long double rowMax = 0.0L;
      for (long double v : expected[k]) rowMax = std::max(rowMax, std::fabs(v));
      double worst = 0.0;
      for (int x = 0; x < n; ++x) {
        worst = std::max(worst, std::fabs(basis(k, x) - static_cast<double>(expected[k][x])));
      }
      EXPECT_LE(worst, kReferenceRelTol * static_cast<double>(rowMax)) << "n = " << k;
    }
  }
}

// The highest order is the (N−1)-th finite difference, t_{N−1}(x) ∝ (−1)^x C(N−1, x), the only
// direction orthogonal to every polynomial of degree < N−1 on N points; normalised,
//   t_{N−1}(x) = (−1)^(N−1+x) C(N−1, x) / √C(2N−2, N−1).
// This tests the region n ≈ N, where the start value t_n(0) ≈ 2^−N underflows.
TEST(TchebichefBasis, MatchesClosedFormOfHighestOrder) {
  for (int n : {2, 3, 6, 64, 1000, 4096}) {
    SCOPED_TRACE("N = " + std::to_string(n));
    const TchebichefBasis basis(n, n);
    std::vector<long double> expected(n);
    long double rowMax = 0.0L;
    for (int x = 0; x < n; ++x) {
      const long double logBinomial = std::lgamma(static_cast<long double>(n)) -
                                      std::lgamma(static_cast<long double>(x + 1)) -
                                      std::lgamma(static_cast<long double>(n - x));
      const long double logNorm = 0.5L * (std::lgamma(static_cast<long double>(2 * n - 1)) -
                                          2 * std::lgamma(static_cast<long double>(n)));
      const long double sign = (n - 1 + x) % 2 == 0 ? 1.0L : -1.0L;
      expected[x] = sign * std::exp(logBinomial - logNorm);
      rowMax = std::max(rowMax, std::fabs(expected[x]));
    }
    double worst = 0.0;
    for (int x = 0; x < n; ++x) {
      worst = std::max(worst, std::fabs(basis(n - 1, x) - static_cast<double>(expected[x])));
    }
    EXPECT_LE(worst, kReferenceRelTol * static_cast<double>(rowMax));
  }
}

TEST(TchebichefBasis, RowsHaveParitySymmetry) {
  for (int n : {1, 2, 3, 8, 9, 255, 256}) {
    SCOPED_TRACE("N = " + std::to_string(n));
    const TchebichefBasis basis(n, n);
    for (int k = 0; k < n; ++k) {
      const double sign = k % 2 == 0 ? 1.0 : -1.0;
      for (int x = 0; x < n; ++x) ASSERT_EQ(basis(k, n - 1 - x), sign * basis(k, x));
      // Odd rows vanish exactly at the centre of an odd grid.
      if (n % 2 == 1 && k % 2 == 1) {
        ASSERT_EQ(basis(k, n / 2), 0.0);
      }
    }
  }
}

TEST(TchebichefBasis, RowsAgreeWithMatrixAndFloatCopy) {
  const TchebichefBasis basis(37, 20);
  ASSERT_EQ(basis.matrixF().size(), basis.matrix().size());
  for (int k = 0; k < basis.order(); ++k) {
    const auto row = basis.row(k);
    const auto rowF = basis.rowF(k);
    ASSERT_EQ(row.size(), 37u);
    ASSERT_EQ(rowF.size(), 37u);
    for (int x = 0; x < 37; ++x) {
      ASSERT_EQ(row[x], basis.matrix()[k * 37 + x]);
      ASSERT_EQ(row[x], basis(k, x));
      ASSERT_EQ(rowF[x], static_cast<float>(row[x]));
    }
  }
}

// A truncated basis is the leading rows of the full one.
TEST(TchebichefBasis, LowerOrderIsPrefixOfFullOrder) {
  const TchebichefBasis full(300, 300);
  const TchebichefBasis part(300, 17);
  for (int k = 0; k < 17; ++k) {
    for (int x = 0; x < 300; ++x) ASSERT_EQ(part(k, x), full(k, x));
  }
}

// docs/design.md §4: the recurrence in n loses orthonormality near order 55 at N = 64.
TEST(TchebichefNaive, BreaksDownWhereStableBasisHolds) {
  constexpr int kN = 64;
  const std::vector<double> naive = tchebichefNaive<double>(kN, kN);
  const TchebichefBasis stable(kN, kN);
  EXPECT_GT(orthonormalityError(naive, kN, kN), kBrokenTol);
  EXPECT_LE(orthonormalityError(stable.matrix(), kN, kN), kOrthonormalTol);
  // Float breaks down sooner (from order ~31 at N = 64).
  EXPECT_GT(orthonormalityError(tchebichefNaive<float>(kN, 40), 40, kN), kBrokenTol);
}

// At low order the naive recurrence is accurate, so it validates the stable one independently.
TEST(TchebichefNaive, AgreesWithStableBasisAtLowOrder) {
  constexpr int kN = 512;
  constexpr int kK = 24;
  const std::vector<double> naive = tchebichefNaive<double>(kN, kK);
  const TchebichefBasis stable(kN, kK);
  EXPECT_LE(orthonormalityError(naive, kK, kN), kOrthonormalTol);
  // Values are O(1/√N) ≈ 0.04; a few hundred ulp of the recurrences.
  EXPECT_LE(maxAbsDiff(naive, stable.matrix()), 1e-13);
}

TEST(Moments2d, RoundTripIsExactAtFullOrder) {
  for (int n : {1, 2, 37, 64}) {
    SCOPED_TRACE("N = " + std::to_string(n));
    const TchebichefBasis basis(n, n);
    const std::vector<double> image = randomImage(static_cast<std::size_t>(n) * n, 7u + n);
    const std::vector<double> moments = moments2d(basis, basis, image, n);
    ASSERT_EQ(moments.size(), static_cast<std::size_t>(n) * n);
    EXPECT_LE(maxAbsDiff(reconstruct2d(basis, basis, moments, n), image), kRoundTripTol);

    // The float overload reads the same values (the image is rounded to float first).
    std::vector<float> imageF(image.begin(), image.end());
    const std::vector<double> exactF(imageF.begin(), imageF.end());
    EXPECT_LE(
        maxAbsDiff(reconstruct2d(basis, basis, moments2d(basis, basis, imageF, n), n), exactF),
        kRoundTripTol);
  }
}

// Against the definition T_mn = Σ_i Σ_j t_m(i) t_n(j) f(i, j), summed directly, on a non-square
// image with different row and column bases.
TEST(Moments2d, MatchesDirectDoubleSum) {
  constexpr int kRows = 13, kCols = 17, kK = 9;
  const TchebichefBasis rowBasis(kRows, 11);
  const TchebichefBasis colBasis(kCols, kCols);
  const std::vector<double> image = randomImage(kRows * kCols, 3u);
  const std::vector<double> moments = moments2d(rowBasis, colBasis, image, kK);
  ASSERT_EQ(moments.size(), static_cast<std::size_t>(kK * kK));
  for (int m = 0; m < kK; ++m) {
    for (int n = 0; n < kK; ++n) {
      double direct = 0.0;
      for (int i = 0; i < kRows; ++i) {
        for (int j = 0; j < kCols; ++j)
          direct += rowBasis(m, i) * colBasis(n, j) * image[i * kCols + j];
      }
      // |f| ≤ 1 and Σ|t_m(i) t_n(j)| ≤ √(rows·cols) ≈ 15: rounding of 221 terms, ~1e-15.
      EXPECT_NEAR(moments[m * kK + n], direct, 1e-13) << "m = " << m << ", n = " << n;
    }
  }
}

// f = t_a ⊗ t_b has the single moment T_ab = 1, and reconstructs from it.
TEST(Moments2d, SeparableBasisImageHasOneMoment) {
  constexpr int kRows = 20, kCols = 33, kK = 12;
  const TchebichefBasis rowBasis(kRows, kK);
  const TchebichefBasis colBasis(kCols, kK);
  for (auto [a, b] : {std::pair{0, 0}, std::pair{3, 7}, std::pair{11, 2}}) {
    SCOPED_TRACE("a = " + std::to_string(a) + ", b = " + std::to_string(b));
    std::vector<double> image(kRows * kCols);
    for (int i = 0; i < kRows; ++i) {
      for (int j = 0; j < kCols; ++j) image[i * kCols + j] = rowBasis(a, i) * colBasis(b, j);
    }
    std::vector<double> expected(kK * kK, 0.0);
    expected[a * kK + b] = 1.0;
    const std::vector<double> moments = moments2d(rowBasis, colBasis, image, kK);
    // Entries of an orthonormal change of basis of a unit-norm image: rounding only.
    EXPECT_LE(maxAbsDiff(moments, expected), 1e-14);
    EXPECT_LE(maxAbsDiff(reconstruct2d(rowBasis, colBasis, expected, kK), image), 1e-14);
  }
}

// Truncated reconstruction is an orthogonal projection: the moments of the reconstruction are the
// truncated moments, and the residual has none.
TEST(Moments2d, TruncatedReconstructionIsProjection) {
  constexpr int kRows = 24, kCols = 30, kK = 6;
  const TchebichefBasis rowBasis(kRows, kRows);
  const TchebichefBasis colBasis(kCols, kCols);
  const std::vector<double> image = randomImage(kRows * kCols, 11u);
  const std::vector<double> moments = moments2d(rowBasis, colBasis, image, kK);
  const std::vector<double> projected = reconstruct2d(rowBasis, colBasis, moments, kK);
  EXPECT_LE(maxAbsDiff(moments2d(rowBasis, colBasis, projected, kK), moments), 1e-13);
  std::vector<double> residual(image.size());
  for (std::size_t i = 0; i < image.size(); ++i) residual[i] = image[i] - projected[i];
  EXPECT_LE(
      maxAbsDiff(moments2d(rowBasis, colBasis, residual, kK), std::vector<double>(kK * kK, 0.0)),
      1e-13);
  // And it changes the image: the test image is not already low order.
  EXPECT_GT(maxAbsDiff(projected, image), 0.1);
}

TEST(Moments2d, InvalidArgumentsThrow) {
  const TchebichefBasis rows(4, 4);
  const TchebichefBasis cols(5, 3);
  const std::vector<double> image(20, 1.0);
  EXPECT_NE(invalidArgumentMessage([&] { moments2d(rows, cols, image, 4); }).find("order K = 4"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([&] { moments2d(rows, cols, image, 0); }).find("order K = 0"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([&] {
              moments2d(rows, cols, std::vector<double>(19, 1.0), 3);
            }).find("image (rows × cols) has 19 elements, expected 20"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([&] {
              moments2d(rows, cols, std::vector<float>(21, 1.0f), 3);
            }).find("has 21 elements"),
            std::string::npos);
  EXPECT_NE(invalidArgumentMessage([&] {
              reconstruct2d(rows, cols, std::vector<double>(8, 0.0), 3);
            }).find("moments (K × K) has 8 elements, expected 9"),
            std::string::npos);
  EXPECT_EQ(invalidArgumentMessage([&] { moments2d(rows, cols, image, 3); }), "");
}

}  // namespace
}  // namespace compose::lighting
