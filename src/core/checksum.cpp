#include "core/checksum.h"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <vector>

#include "core/entry_file.h"
#include "core/parallel.h"

namespace compose {
namespace {

constexpr size_t kBlock = size_t(1) << 18;

// Four lanes of 64-bit words, each lane FNV-1a's step on whole words, h = (h ^ w) * prime: a
// bijection of h for every word, so a change to one word always changes its lane's hash. Two floats
// a word, two instructions a word: the checksum costs far less than reading the values.
Hash128 blockHash(const float* v, size_t n) {
  constexpr uint64_t kPrime = 0x100000001b3ull;
  uint64_t lanes[4] = {0xcbf29ce484222325ull, 0x84222325cbf29ce4ull, 0x9e3779b97f4a7c15ull,
                       0xc2b2ae3d27d4eb4full};
  size_t i = 0;
  for (; i + 8 <= n; i += 8) {
    uint64_t w[4];
    std::memcpy(w, v + i, sizeof w);
    for (int l = 0; l < 4; ++l) lanes[l] = (lanes[l] ^ w[l]) * kPrime;
  }
  for (; i < n; ++i) {
    uint32_t w;
    std::memcpy(&w, v + i, sizeof w);
    lanes[0] = (lanes[0] ^ w) * kPrime;
  }
  Hash128 h;
  for (const uint64_t lane : lanes) {
    h.word(uint32_t(lane));
    h.word(uint32_t(lane >> 32));
  }
  h.word(uint32_t(n));
  return h;
}

Hash128 combineBlocks(const std::vector<Hash128>& sums, size_t count) {
  Hash128 out;
  for (const Hash128& s : sums) out.combine(s);
  out.word(uint32_t(count & 0xFFFFFFFFu));
  out.word(uint32_t(uint64_t(count) >> 32));
  return out;
}

}  // namespace

Hash128 checksumFloats(std::span<const float> values) {
  const size_t blocks = (values.size() + kBlock - 1) / kBlock;
  std::vector<Hash128> sums(blocks);
  parallelFor(0, int64_t(blocks), [&](int64_t b) {
    const size_t first = size_t(b) * kBlock;
    sums[size_t(b)] = blockHash(values.data() + first, std::min(kBlock, values.size() - first));
  });
  return combineBlocks(sums, values.size());
}

std::optional<Hash128> readChecksummedFloats(int fd, uint64_t offset, std::span<float> values) {
  const size_t blocks = (values.size() + kBlock - 1) / kBlock;
  std::vector<Hash128> sums(blocks);
  std::atomic<int> failure{-1};  // -1: none; else the errno (0: the file ended first)
  parallelFor(0, int64_t(blocks), [&](int64_t b) {
    if (failure.load(std::memory_order_relaxed) >= 0) return;
    const size_t first = size_t(b) * kBlock, n = std::min(kBlock, values.size() - first);
    if (!readFullyAt(fd, values.data() + first, n * sizeof(float),
                     offset + first * sizeof(float))) {
      int expected = -1;
      failure.compare_exchange_strong(expected, errno);
      return;
    }
    sums[size_t(b)] = blockHash(values.data() + first, n);
  });
  if (const int f = failure.load(); f >= 0) {
    errno = f;
    return std::nullopt;
  }
  return combineBlocks(sums, values.size());
}

}  // namespace compose
