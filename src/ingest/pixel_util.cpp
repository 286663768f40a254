#include "ingest/pixel_util.h"

#include <cpuid.h>
#include <immintrin.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include <Imath/half.h>

namespace compose::ingest::detail {

namespace {

__attribute__((target("avx,f16c"))) void toHalfF16c(const float* from, uint16_t* to, size_t n) {
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    const __m128i h = _mm256_cvtps_ph(_mm256_loadu_ps(from + i), _MM_FROUND_TO_NEAREST_INT);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(to + i), h);
  }
  for (; i < n; ++i) to[i] = Imath::half(from[i]).bits();
}

void toHalfPlain(const float* from, uint16_t* to, size_t n) {
  for (size_t i = 0; i < n; ++i) to[i] = Imath::half(from[i]).bits();
}

// Whether the processor converts with F16C (and AVX, whose registers the system must save).
bool hasF16c() {
  unsigned a = 0, b = 0, c = 0, d = 0;
  if (!__get_cpuid(1, &a, &b, &c, &d)) return false;
  if (!(c & bit_AVX) || !(c & bit_F16C) || !(c & bit_OSXSAVE)) return false;
  unsigned low = 0, high = 0;
  __asm__("xgetbv" : "=a"(low), "=d"(high) : "c"(0));
  return (low & 6u) == 6u;  // XMM and YMM state enabled
}

}  // namespace

namespace {

// largestFinite() of values[i], or of values[i] * scales[i] when `Scaled`.
template <bool Scaled>
float largestOf(const float* values, const float* scales, size_t n) {
  // Four lanes at a time, two accumulators: |v| by clearing the sign bit, NaN and infinities
  // zeroed by failing `|v| <= max`; every lane's value is non-negative, so maxps's order does not
  // matter.
  const __m128 magnitude = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  const __m128 top = _mm_set1_ps(std::numeric_limits<float>::max());
  __m128 m0 = _mm_setzero_ps(), m1 = _mm_setzero_ps();
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    __m128 v0 = _mm_loadu_ps(values + i), v1 = _mm_loadu_ps(values + i + 4);
    if constexpr (Scaled) {
      v0 = _mm_mul_ps(v0, _mm_loadu_ps(scales + i));
      v1 = _mm_mul_ps(v1, _mm_loadu_ps(scales + i + 4));
    }
    __m128 a0 = _mm_and_ps(v0, magnitude);
    __m128 a1 = _mm_and_ps(v1, magnitude);
    a0 = _mm_and_ps(a0, _mm_cmple_ps(a0, top));
    a1 = _mm_and_ps(a1, _mm_cmple_ps(a1, top));
    m0 = _mm_max_ps(m0, a0);
    m1 = _mm_max_ps(m1, a1);
  }
  float lanes[4];
  _mm_storeu_ps(lanes, _mm_max_ps(m0, m1));
  float m = std::max(std::max(lanes[0], lanes[1]), std::max(lanes[2], lanes[3]));
  for (; i < n; ++i) {
    const float a = std::abs(Scaled ? values[i] * scales[i] : values[i]);
    if (a <= std::numeric_limits<float>::max() && a > m) m = a;
  }
  return m;
}

}  // namespace

float largestFinite(const float* values, size_t n) {
  return largestOf<false>(values, nullptr, n);
}

float largestFinite(const float* values, const float* scales, size_t n) {
  return largestOf<true>(values, scales, n);
}

void toHalf(const float* from, uint16_t* to, size_t n) {
  static const bool f16c = hasF16c();
  if (f16c) {
    toHalfF16c(from, to, n);
  } else {
    toHalfPlain(from, to, n);
  }
}

}  // namespace compose::ingest::detail
