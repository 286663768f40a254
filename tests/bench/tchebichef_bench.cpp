// Stress benchmark for the orthonormal Tchebichef basis (src/lighting/tchebichef.h).
//
//   tchebichef_bench                 prints, for N = 64 .. 16384 at full order K = N, the
//                                    orthonormality error max|T·Tᵀ − I| and the build time of the
//                                    naive n-recurrence and the stable basis, in double and float.
//   tchebichef_bench --benchmark_... runs the Google Benchmark cases instead (any --benchmark_*
//                                    flag, e.g. --benchmark_filter=Moments). Only when built with
//                                    COMPOSE_HAVE_GOOGLE_BENCHMARK defined and linked with
//                                    benchmark::benchmark; otherwise the table is all there is.
//
// The full check is O(K²·N) and is done up to N = 2048; above that a deterministic sample of row
// pairs is checked instead (see samplePairs) and the table says so. Peak memory is ~3 GiB (the
// N = 16384 stable basis: 2 GiB of doubles plus its 1 GiB float copy).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "lighting/tchebichef.h"

#if defined(COMPOSE_HAVE_GOOGLE_BENCHMARK)
#include <benchmark/benchmark.h>
#endif

namespace compose::lighting {
namespace {

using Clock = std::chrono::steady_clock;

// A basis "has broken down" once a Gram entry is off by more than this (docs/design.md §4).
constexpr double kBrokenTol = 1e-6;
// Largest N whose full K×K Gram matrix is checked.
constexpr int kFullCheckMaxSize = 2048;
// Sampled check: every (n, n), (n, n+1), (n, n+2); all pairs among the top kTopOrders rows; and
// kRandomPairs pairs drawn with a fixed seed.
constexpr int kTopOrders = 32;
constexpr int kRandomPairs = 2000;
constexpr std::uint64_t kPairSeed = 20240611;
// firstBrokenOrder compares row n with rows n−kBand .. n.
constexpr int kBand = 16;

double msSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

template <class T>
double dot(const std::vector<T>& m, int size, int a, int b) {
  const T* ra = m.data() + static_cast<std::size_t>(a) * size;
  const T* rb = m.data() + static_cast<std::size_t>(b) * size;
  double s = 0.0;
  for (int x = 0; x < size; ++x) s += static_cast<double>(ra[x]) * static_cast<double>(rb[x]);
  return s;
}

double deviation(double gram, int a, int b) {
  const double d = std::fabs(gram - (a == b ? 1.0 : 0.0));
  return std::isnan(d) ? std::numeric_limits<double>::infinity() : d;
}

std::vector<std::pair<int, int>> samplePairs(int order) {
  std::vector<std::pair<int, int>> pairs;
  for (int n = 0; n < order; ++n) {
    for (int d = 0; d <= 2 && n + d < order; ++d) pairs.emplace_back(n, n + d);
  }
  for (int a = std::max(0, order - kTopOrders); a < order; ++a) {
    for (int b = a + 3; b < order; ++b) pairs.emplace_back(a, b);
  }
  std::mt19937_64 rng(kPairSeed);
  std::uniform_int_distribution<int> pick(0, order - 1);
  for (int i = 0; i < kRandomPairs; ++i) {
    const int a = pick(rng), b = pick(rng);
    pairs.emplace_back(std::min(a, b), std::max(a, b));
  }
  return pairs;
}

// max|T·Tᵀ − I|: over all pairs up to kFullCheckMaxSize, over samplePairs above.
template <class T>
double orthonormality(const std::vector<T>& m, int order, int size) {
  if (size <= kFullCheckMaxSize) return orthonormalityError(std::span<const T>(m), order, size);
  double worst = 0.0;
  for (auto [a, b] : samplePairs(order))
    worst = std::max(worst, deviation(dot(m, size, a, b), a, b));
  return worst;
}

// First n whose row deviates by more than kBrokenTol from unit norm or from orthogonality to one of
// the kBand rows before it; −1 if none.
template <class T>
int firstBrokenOrder(const std::vector<T>& m, int order, int size) {
  for (int n = 0; n < order; ++n) {
    for (int j = std::max(0, n - kBand); j <= n; ++j) {
      if (deviation(dot(m, size, j, n), j, n) > kBrokenTol) return n;
    }
  }
  return -1;
}

// Builds `repeats` times and keeps the fastest; returns the last result.
template <class Build>
auto timeBest(int repeats, double& bestMs, Build build) {
  bestMs = std::numeric_limits<double>::infinity();
  for (int r = 0;; ++r) {
    const Clock::time_point start = Clock::now();
    auto result = build();
    bestMs = std::min(bestMs, msSince(start));
    if (r + 1 >= repeats) return result;
  }
}

// Repeats per build: 10 up to N = 2048, 4 at 4096, 1 above.
int repeatsFor(int size) {
  return std::clamp((1 << 26) / (size * size), 1, 10);
}

std::string formatError(double e) {
  if (std::isinf(e)) return "inf";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1e", e);
  return buf;
}

std::string formatOrder(int n) {
  return n < 0 ? "none" : std::to_string(n);
}

void printTable() {
  std::printf("Orthonormal discrete Tchebichef basis at full order K = N (no size is capped).\n");
  std::printf("err    max|T·Tᵀ − I|, accumulated in double; inf once the naive values overflow.\n");
  std::printf("check  'full': every row pair (N <= %d). 'sampled': all (n,n), (n,n+1), (n,n+2),\n",
              kFullCheckMaxSize);
  std::printf("       every pair among the top %d orders and %d seeded random pairs.\n", kTopOrders,
              kRandomPairs);
  std::printf("broken first order n whose norm, or product with one of the %d rows before it, is\n",
              kBand);
  std::printf("       off by more than %.0e (naive n-recurrence).\n", kBrokenTol);
  std::printf("ms     build time (steady_clock), allocation included; best of %d runs up to\n",
              repeatsFor(2048));
  std::printf("       N = 2048, of %d at 4096, a single run above. The stable basis builds its\n",
              repeatsFor(4096));
  std::printf("       double matrix and its float copy together; 'err f' is the float copy's.\n\n");

  std::printf("%6s %8s | %9s %7s %8s | %9s %7s %8s | %9s %9s %8s\n", "", "", "naive", "double", "",
              "naive", "float", "", "stable", "stable", "stable");
  std::printf("%6s %8s | %9s %7s %8s | %9s %7s %8s | %9s %9s %8s\n", "N", "check", "err", "broken",
              "ms", "err", "broken", "ms", "err d", "err f", "ms");
  std::printf("%s\n", std::string(106, '-').c_str());
  const Clock::time_point total = Clock::now();
  for (int n : {64, 128, 256, 512, 1024, 2048, 4096, 8192, 16384}) {
    const int repeats = repeatsFor(n);
    double naiveMs = 0.0, naiveFMs = 0.0, stableMs = 0.0;
    double naiveErr = 0.0, naiveFErr = 0.0, stableErr = 0.0, stableFErr = 0.0;
    int naiveBroken = -1, naiveFBroken = -1;
    {
      const auto m = timeBest(repeats, naiveMs, [&] { return tchebichefNaive<double>(n, n); });
      naiveErr = orthonormality(m, n, n);
      naiveBroken = firstBrokenOrder(m, n, n);
    }
    {
      const auto m = timeBest(repeats, naiveFMs, [&] { return tchebichefNaive<float>(n, n); });
      naiveFErr = orthonormality(m, n, n);
      naiveFBroken = firstBrokenOrder(m, n, n);
    }
    {
      const auto basis = timeBest(repeats, stableMs, [&] { return TchebichefBasis(n, n); });
      stableErr = orthonormality(basis.matrix(), n, n);
      stableFErr = orthonormality(basis.matrixF(), n, n);
    }
    std::printf("%6d %8s | %9s %7s %8.2f | %9s %7s %8.2f | %9s %9s %8.2f\n", n,
                n <= kFullCheckMaxSize ? "full" : "sampled", formatError(naiveErr).c_str(),
                formatOrder(naiveBroken).c_str(), naiveMs, formatError(naiveFErr).c_str(),
                formatOrder(naiveFBroken).c_str(), naiveFMs, formatError(stableErr).c_str(),
                formatError(stableFErr).c_str(), stableMs);
    std::fflush(stdout);
  }
  std::printf("\ntotal %.1f s\n", msSince(total) / 1000.0);
}

#if defined(COMPOSE_HAVE_GOOGLE_BENCHMARK)
// Google Benchmark cases: basis construction and the 2D transforms at sizes the lighting code uses.
void BM_StableBasis(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(TchebichefBasis(n, n).matrix().data());
  state.SetItemsProcessed(state.iterations() * n * n);
}
BENCHMARK(BM_StableBasis)->RangeMultiplier(4)->Range(64, 4096)->Unit(benchmark::kMillisecond);

void BM_NaiveBasis(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(tchebichefNaive<double>(n, n).data());
  state.SetItemsProcessed(state.iterations() * n * n);
}
BENCHMARK(BM_NaiveBasis)->RangeMultiplier(4)->Range(64, 4096)->Unit(benchmark::kMillisecond);

// range(0) = image side, range(1) = order K.
void BM_Moments2d(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int k = static_cast<int>(state.range(1));
  const TchebichefBasis basis(n, k);
  std::vector<float> image(static_cast<std::size_t>(n) * n);
  for (std::size_t i = 0; i < image.size(); ++i) image[i] = static_cast<float>(i % 7) * 0.25f;
  for (auto _ : state) benchmark::DoNotOptimize(moments2d(basis, basis, image, k).data());
  state.SetItemsProcessed(state.iterations() * n * n);
}
BENCHMARK(BM_Moments2d)->Args({32, 3})->Args({64, 8})->Args({256, 16})->Args({1024, 32});

void BM_Reconstruct2d(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const int k = static_cast<int>(state.range(1));
  const TchebichefBasis basis(n, k);
  const std::vector<double> moments(static_cast<std::size_t>(k) * k, 0.5);
  for (auto _ : state) benchmark::DoNotOptimize(reconstruct2d(basis, basis, moments, k).data());
  state.SetItemsProcessed(state.iterations() * n * n);
}
BENCHMARK(BM_Reconstruct2d)->Args({32, 3})->Args({64, 8})->Args({256, 16})->Args({1024, 32});
#endif  // COMPOSE_HAVE_GOOGLE_BENCHMARK

}  // namespace
}  // namespace compose::lighting

int main(int argc, char** argv) {
#if defined(COMPOSE_HAVE_GOOGLE_BENCHMARK)
  bool googleBenchmark = false;
  for (int i = 1; i < argc; ++i) {
    googleBenchmark = googleBenchmark || std::strncmp(argv[i], "--benchmark", 11) == 0;
  }
  if (googleBenchmark) {
    benchmark::Initialize(&argc, argv);
    if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
    return 0;
  }
#endif
  if (argc > 1) {
    std::fprintf(stderr, "usage: %s%s\n", argv[0],
#if defined(COMPOSE_HAVE_GOOGLE_BENCHMARK)
                 " [--benchmark_...]"
#else
                 ""
#endif
    );
    return 2;
  }
  compose::lighting::printTable();
  return 0;
}
