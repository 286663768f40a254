// Compositing: the premultiplied "over" operator (Porter & Duff 1984),
//   out = fg + bg (1 - α_fg),
// in scene-linear light, both images in the same colour space and of the same size.
#pragma once

#include "core/image.h"

namespace compose::composite {

// `foreground` is RGBA, premultiplied. `background` has >= 3 channels; the result has the
// background's channel layout (its alpha, if any, becomes α_fg + α_bg (1 - α_fg)). Throws
// compose::Error (stage "composite") on a size or colour-space mismatch.
Image over(const Image& foreground, const Image& background);
// The same with the foreground covering [x, x + width) x [y, y + height) of the background (it
// must lie inside it); the rest of the background is copied unchanged.
Image over(const Image& foreground, int x, int y, const Image& background);

}  // namespace compose::composite
