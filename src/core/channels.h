// Which of an image's channels hold its picture: the colour by channel name, as OpenEXR and Nuke
// name them (R, G, B; a layer's beauty.R, G, B; Y alone for grey; Y, RY, BY for luminance-chroma),
// and the alpha that goes with it. A layered image (a render's AOVs beside its beauty) is read
// from the layer that is its picture, not from whichever layer sorts first.
#pragma once

#include <array>
#include <string>
#include <vector>

#include "core/image.h"

namespace compose {

struct PictureChannels {
  enum class Kind { Rgb, Chroma, Grey, ByPosition };
  Kind kind = Kind::ByPosition;
  // Indices: R, G, B (Rgb); Y, RY, BY (Chroma); Y (Grey); the first three, or the first of fewer
  // (ByPosition: channels without colour names).
  std::vector<int> colour;
  int alpha = -1;     // the layer's A, else the only A of the image; -1: none
  std::string layer;  // the colour's layer ("" for bare R, G, B), with its dot: "beauty."
  // Layers that hold a colour too, beside the one chosen (for notes and errors).
  std::vector<std::string> otherLayers;
  // More than one layer holds a colour and nothing says which is the picture: no bare R, G, B,
  // no layer named as a beauty pass (beauty, combined, rgba, rgb, color, colour), and not just
  // one of them with an alpha. `layer` is then the first of them.
  bool ambiguous = false;
};

// The picture's channels by the rules above: bare channels first, then a layer named as a beauty
// pass, then the one layer with an alpha, then the only layer with a colour.
PictureChannels pictureChannels(const Image& image);

// Whether a layer's or an OpenEXR part's name says it holds the picture: its last dot-separated
// part is beauty, combined, rgba, rgb, color or colour (any case): "ViewLayer.Combined".
bool isBeautyName(const std::string& name);

// Any image made RGB from its picture's channels: R, G, B in that order wherever they are; Y
// alone replicated as grey; Y with OpenEXR's chroma RY, BY converted (Rec. 709 luminance
// weights); channels without colour names by position (one replicated). Other channels (alpha,
// other layers) are dropped. The second form moves an image that is RGB already.
Image pictureRgb(const Image& in);
Image pictureRgb(Image&& in);

// OpenEXR's luminance weights of a linear RGB space: the Y row of its RGB → XYZ matrix, summing
// to 1 (Imf::computeYw), from its chromaticities (red x, y, green x, y, blue x, y, white x, y).
// Rec. 709's when the chromaticities describe no space.
std::array<float, 3> luminanceWeights(const std::array<double, 8>& chromaticities);

// An image whose picture is luminance-chroma (Y, RY, BY) made RGB in place, as OpenEXR's RgbaYca
// decodes it with the weights of the file's primaries: the three channels hold R, G, B and are
// named so (within their layer); alpha and other channels stay. Anything else is left alone.
void decodeLuminanceChroma(Image& image, const std::array<float, 3>& weights);

}  // namespace compose
