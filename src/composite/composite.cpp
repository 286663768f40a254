#include "composite/composite.h"

#include <string>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::composite {

Image over(const Image& fg, const Image& bg) {
  if (fg.width != bg.width || fg.height != bg.height) {
    throw Error("composite", "size mismatch: foreground is " + std::to_string(fg.width) + "x" +
                                 std::to_string(fg.height) + ", background is " +
                                 std::to_string(bg.width) + "x" + std::to_string(bg.height));
  }
  return over(fg, 0, 0, bg);
}

Image over(const Image& fg, int x0, int y0, const Image& bg) {
  if (fg.channels != 4)
    throw Error("composite",
                "foreground must be RGBA, it has " + std::to_string(fg.channels) + " channels");
  if (bg.channels < 3) throw Error("composite", "background must have RGB channels");
  if (x0 < 0 || y0 < 0 || x0 + fg.width > bg.width || y0 + fg.height > bg.height) {
    throw Error("composite", "the foreground (" + std::to_string(fg.width) + "x" +
                                 std::to_string(fg.height) + " at " + std::to_string(x0) + "," +
                                 std::to_string(y0) + ") does not lie inside the background (" +
                                 std::to_string(bg.width) + "x" + std::to_string(bg.height) + ")");
  }
  if (!fg.colorSpace.empty() && !bg.colorSpace.empty() && fg.colorSpace != bg.colorSpace) {
    throw Error("composite", "colour-space mismatch: foreground is " + fg.colorSpace +
                                 ", background is " + bg.colorSpace);
  }
  Image out = bg;
  const bool bgAlpha = bg.channels >= 4;
  parallelFor(
      0, fg.height,
      [&](int64_t y) {
        for (int x = 0; x < fg.width; ++x) {
          const float* f = fg.at(x, int(y));
          const float a = f[3];
          if (a == 0.0f && f[0] == 0.0f && f[1] == 0.0f && f[2] == 0.0f) continue;
          float* o = out.at(x + x0, int(y) + y0);
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
