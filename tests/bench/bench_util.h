// What the benchmark programs measure with: wall-clock seconds and the process's peak memory.
#pragma once

#include <sys/resource.h>

#include <chrono>

namespace compose::bench {

using Clock = std::chrono::steady_clock;

// Seconds from `start` to now.
inline double secondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// The peak resident set of this process so far, MB (getrusage's ru_maxrss: kilobytes on Linux).
inline double peakResidentMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_maxrss) / 1024.0;
}

}  // namespace compose::bench
