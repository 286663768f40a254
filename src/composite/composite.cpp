#include "composite/composite.h"

#include <algorithm>
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
  Image out = bg;
  overInPlace(out, fg, x0, y0);
  return out;
}

void overInPlace(Image& bg, const Image& fg, int x0, int y0, float scale) {
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
  const bool bgAlpha = bg.channels >= 4;
  parallelFor(
      0, fg.height,
      [&](int64_t y) {
        for (int x = 0; x < fg.width; ++x) {
          const float* f = fg.at(x, int(y));
          const float a = f[3];
          if (a == 0.0f && f[0] == 0.0f && f[1] == 0.0f && f[2] == 0.0f) continue;
          float* o = bg.at(x + x0, int(y) + y0);
          const float k = 1.0f - a;
          o[0] = f[0] * scale + o[0] * k;
          o[1] = f[1] * scale + o[1] * k;
          o[2] = f[2] * scale + o[2] * k;
          if (bgAlpha) o[3] = a + o[3] * k;
        }
      },
      8);
}

void multiply(Image& image, const Image& factor, int x0, int y0) {
  if (image.channels < 3 || factor.channels < 3)
    throw Error("composite", "multiply needs RGB channels in the image and the factor");
  if (x0 < 0 || y0 < 0 || x0 + factor.width > image.width || y0 + factor.height > image.height) {
    throw Error("composite", "the factor (" + std::to_string(factor.width) + "x" +
                                 std::to_string(factor.height) + " at " + std::to_string(x0) + "," +
                                 std::to_string(y0) + ") does not lie inside the image (" +
                                 std::to_string(image.width) + "x" + std::to_string(image.height) +
                                 ")");
  }
  parallelFor(0, factor.height, [&](int64_t y) {
    for (int x = 0; x < factor.width; ++x) {
      const float* f = factor.at(x, int(y));
      float* o = image.at(x + x0, int(y) + y0);
      o[0] *= f[0];
      o[1] *= f[1];
      o[2] *= f[2];
    }
  });
}

Image holdout(const Image& comp, const Image& plate, const Image& mask) {
  if (comp.width != plate.width || comp.height != plate.height || mask.width != comp.width ||
      mask.height != comp.height) {
    throw Error("composite", "holdout: the composite, the plate and the mask differ in size");
  }
  if (!comp.colorSpace.empty() && !plate.colorSpace.empty() && comp.colorSpace != plate.colorSpace)
    throw Error("composite", "holdout: the composite and the plate are in different colour spaces");
  COMPOSE_CHECK(comp.channels >= 3 && plate.channels >= 3 && mask.channels >= 1);
  Image out = comp;
  parallelFor(0, comp.height, [&](int64_t y) {
    for (int x = 0; x < comp.width; ++x) {
      const float m = std::clamp(mask.at(x, int(y))[0], 0.0f, 1.0f);
      if (m == 0.0f) continue;
      float* o = out.at(x, int(y));
      const float* p = plate.at(x, int(y));
      for (int c = 0; c < 3; ++c) o[c] = m * p[c] + (1.0f - m) * o[c];
      if (comp.channels >= 4) o[3] = m * (plate.channels >= 4 ? p[3] : 1.0f) + (1.0f - m) * o[3];
    }
  });
  return out;
}

}  // namespace compose::composite
