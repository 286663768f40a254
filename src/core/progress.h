// Progress reporting. Libraries never print: long-running functions take a Progress callback and
// the front end decides how to show it.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <string_view>

namespace compose {

// Called with the stage name and the fraction done in [0, 1]. It may be called from any thread,
// but never concurrently for the same stage. An empty function means "no progress wanted".
using Progress = std::function<void(std::string_view stage, double fraction)>;

inline void report(const Progress& progress, std::string_view stage, double fraction) {
  if (progress) progress(stage, fraction);
}

// Progress written as lines (to a log or a pipe, where a bar redrawn in place would not show):
// at most one line every `intervalSeconds`, the first after that long, so that short runs stay
// quiet and long ones show they are alive. Times are seconds on any monotonic clock.
class ProgressThrottle {
 public:
  ProgressThrottle(double intervalSeconds, double startSeconds)
      : interval_(intervalSeconds), last_(startSeconds) {}
  // Whether a line is due at `nowSeconds`; if so, the next one is due `intervalSeconds` later.
  bool due(double nowSeconds) {
    if (nowSeconds - last_ < interval_) return false;
    last_ = nowSeconds;
    return true;
  }

 private:
  double interval_, last_;
};

// Progress from inside a parallel loop of `total` steps: step() may be called from any thread;
// the callback is called at most every `every` steps and never concurrently (a busy reporter is
// skipped, not waited for).
class ParallelProgress {
 public:
  ParallelProgress(const Progress& progress, std::string stage, int64_t total, int64_t every = 64)
      : progress_(progress), stage_(std::move(stage)), total_(total), every_(every) {}
  void step() {
    const int64_t d = ++done_;
    if (!progress_ || (d % every_ != 0 && d != total_)) return;
    std::unique_lock lock(mutex_, std::try_to_lock);
    if (lock.owns_lock()) progress_(stage_, double(d) / double(total_));
  }

 private:
  const Progress& progress_;
  std::string stage_;
  int64_t total_, every_;
  std::atomic<int64_t> done_{0};
  std::mutex mutex_;
};

}  // namespace compose
