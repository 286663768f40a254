#include "ingest/pixel_util.h"

#include <immintrin.h>

#include <cstring>

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

}  // namespace

void toHalf(const float* from, uint16_t* to, size_t n) {
  static const bool f16c = __builtin_cpu_supports("f16c") && __builtin_cpu_supports("avx");
  if (f16c) {
    toHalfF16c(from, to, n);
  } else {
    toHalfPlain(from, to, n);
  }
}

}  // namespace compose::ingest::detail
