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

// The same, in place: `background` becomes the composite (its pixels outside the foreground's
// rectangle are not touched, and no copy of the frame is made), the foreground's colour
// multiplied by `scale` on the way (a render's exposure; its alpha as it is). Errors as over().
void overInPlace(Image& background, const Image& foreground, int x, int y, float scale = 1.0f);

// Multiplies the first three channels of `image` over [x, x + w) x [y, y + h) by the RGB of
// `factor` (w x h): the ground shadow's ratio applied to the plate in linear light. The rectangle
// must lie inside the image.
void multiply(Image& image, const Image& factor, int x, int y);

// A holdout: where `mask` (one channel, 1 = the plate is in front of the object) is set, the plate
// shows instead of the composite: out = mask × plate + (1 - mask) × composite, per pixel. All three
// images are the same size; the plate's and the composite's colour spaces must agree.
Image holdout(const Image& composite, const Image& plate, const Image& mask);

}  // namespace compose::composite
