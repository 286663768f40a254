// A 128-bit content hash for cache keys: two independent 64-bit hashes (FNV-1a and a
// multiply-xorshift mix) over 32-bit words. Not cryptographic; collisions between honest inputs
// are vanishingly unlikely at 128 bits.
#pragma once

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <span>
#include <string>

namespace compose {

struct Hash128 {
  uint64_t a = 1469598103934665603ull, b = 0x9E3779B97F4A7C15ull;

  void word(uint32_t w) {
    a = (a ^ w) * 1099511628211ull;
    b = (b ^ (w + 0x632BE59BD9B4E019ull + (b << 6) + (b >> 2))) * 0xff51afd7ed558ccdull;
  }
  void bytes(const std::string& s) {
    for (unsigned char c : s) word(c);
    word(0xFFFFFFFFu);
  }
  // Floats bit for bit.
  void floats(std::span<const float> values) {
    for (float v : values) {
      uint32_t w;
      std::memcpy(&w, &v, sizeof w);
      word(w);
    }
    word(0xFFFFFFFEu);
  }
  // Raw bytes (file contents), four at a time.
  void data(const void* bytes, size_t size) {
    const auto* p = static_cast<const unsigned char*>(bytes);
    size_t i = 0;
    for (; i + 4 <= size; i += 4) {
      uint32_t w;
      std::memcpy(&w, p + i, 4);
      word(w);
    }
    uint32_t tail = 0;
    std::memcpy(&tail, p + i, size - i);
    word(tail);
    word(uint32_t(size & 0xFFFFFFFFu));
  }
  void number(double v) {
    uint64_t w;
    std::memcpy(&w, &v, sizeof w);
    word(uint32_t(w));
    word(uint32_t(w >> 32));
  }
  void combine(const Hash128& other) {
    word(uint32_t(other.a));
    word(uint32_t(other.a >> 32));
    word(uint32_t(other.b));
    word(uint32_t(other.b >> 32));
  }
  bool operator==(const Hash128&) const = default;
  std::string hex() const {
    char buf[33];
    std::snprintf(buf, sizeof buf, "%016llx%016llx", static_cast<unsigned long long>(a),
                  static_cast<unsigned long long>(b));
    return buf;
  }
};

// Deterministic jitter in [0, 1) from a 32-bit integer (the lowbias32 hash): 24 bits, so exact
// in float.
inline float hash01(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return float(x >> 8) * (1.0f / 16777216.0f);
}

}  // namespace compose
