// Progress reporting. Libraries never print: long-running functions take a Progress callback and
// the front end decides how to show it.
#pragma once

#include <functional>
#include <string_view>

namespace compose {

// Called with the stage name and the fraction done in [0, 1]. It may be called from any thread,
// but never concurrently for the same stage. An empty function means "no progress wanted".
using Progress = std::function<void(std::string_view stage, double fraction)>;

inline void report(const Progress& progress, std::string_view stage, double fraction) {
  if (progress) progress(stage, fraction);
}

}  // namespace compose
