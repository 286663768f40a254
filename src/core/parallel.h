// The one place where work is split across threads. Kernels are written as per-row (or per-item)
// functors; this helper does the tiling and threading on oneTBB.
#pragma once

#include <cstdint>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace compose {

// Calls body(i) for every i in [begin, end), in parallel. `grain` is the smallest chunk handed to
// one task. body must be safe to call concurrently for different i.
template <class Body>
void parallelFor(int64_t begin, int64_t end, Body&& body, int64_t grain = 1) {
  tbb::parallel_for(tbb::blocked_range<int64_t>(begin, end, grain),
                    [&](const tbb::blocked_range<int64_t>& r) {
                      for (int64_t i = r.begin(); i != r.end(); ++i) body(i);
                    });
}

}  // namespace compose
