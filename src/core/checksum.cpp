#include "core/checksum.h"

#include <algorithm>
#include <cstring>
#include <vector>

#include "core/parallel.h"

namespace compose {

Hash128 checksumFloats(std::span<const float> values) {
  constexpr size_t kBlock = size_t(1) << 18;
  const size_t blocks = (values.size() + kBlock - 1) / kBlock;
  std::vector<Hash128> sums(blocks);
  parallelFor(0, int64_t(blocks), [&](int64_t b) {
    const size_t first = size_t(b) * kBlock, n = std::min(kBlock, values.size() - first);
    const float* v = values.data() + first;
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
    sums[size_t(b)] = h;
  });
  Hash128 out;
  for (const Hash128& s : sums) out.combine(s);
  out.word(uint32_t(values.size() & 0xFFFFFFFFu));
  out.word(uint32_t(uint64_t(values.size()) >> 32));
  return out;
}

}  // namespace compose
