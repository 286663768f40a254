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

Hash128 blockHash(const float* v, size_t n) {
  Hash128 lanes[4];
  for (uint32_t l = 0; l < 4; ++l) lanes[l].word(l);
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    uint32_t w[4];
    std::memcpy(w, v + i, sizeof w);
    lanes[0].word(w[0]);
    lanes[1].word(w[1]);
    lanes[2].word(w[2]);
    lanes[3].word(w[3]);
  }
  for (; i < n; ++i) {
    uint32_t w;
    std::memcpy(&w, v + i, sizeof w);
    lanes[0].word(w);
  }
  Hash128 h;
  for (const Hash128& lane : lanes) h.combine(lane);
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
