#include "ingest/pixel_util.h"

#include <cpuid.h>
#include <immintrin.h>

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

void toHalf(const float* from, uint16_t* to, size_t n) {
  static const bool f16c = hasF16c();
  if (f16c) {
    toHalfF16c(from, to, n);
  } else {
    toHalfPlain(from, to, n);
  }
}

}  // namespace compose::ingest::detail
