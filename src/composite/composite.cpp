#include "composite/composite.h"

#include <string>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::composite {

Image over(const Image& fg, const Image& bg) {
  if (fg.channels != 4)
    throw Error("composite",
                "foreground must be RGBA, it has " + std::to_string(fg.channels) + " channels");
  if (bg.channels < 3) throw Error("composite", "background must have RGB channels");
  if (fg.width != bg.width || fg.height != bg.height) {
    throw Error("composite", "size mismatch: foreground is " + std::to_string(fg.width) + "x" +
                                 std::to_string(fg.height) + ", background is " +
                                 std::to_string(bg.width) + "x" + std::to_string(bg.height));
  }
  if (!fg.colorSpace.empty() && !bg.colorSpace.empty() && fg.colorSpace != bg.colorSpace) {
    throw Error("composite", "colour-space mismatch: foreground is " + fg.colorSpace +
                                 ", background is " + bg.colorSpace);
  }
  Image out = bg;
  const bool bgAlpha = bg.channels >= 4;
  parallelFor(
      0, bg.height,
      [&](int64_t y) {
        for (int x = 0; x < bg.width; ++x) {
          const float* f = fg.at(x, int(y));
          const float a = f[3];
          if (a == 0.0f && f[0] == 0.0f && f[1] == 0.0f && f[2] == 0.0f) continue;
          float* o = out.at(x, int(y));
          const float k = 1.0f - a;
          o[0] = f[0] + o[0] * k;
          o[1] = f[1] + o[1] * k;
          o[2] = f[2] + o[2] * k;
          if (bgAlpha) o[3] = a + o[3] * k;
        }
      },
      8);
  return out;
}

}  // namespace compose::composite
