#include "core/channels.h"

#include <algorithm>
#include <cctype>

namespace compose {

namespace {

std::string upper(std::string s) {
  for (char& c : s) c = char(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

// "beauty.R" -> layer "beauty.", kind "R"; "R" -> "", "R".
void split(const std::string& name, std::string& layer, std::string& kind) {
  const size_t dot = name.rfind('.');
  layer = dot == std::string::npos ? std::string() : name.substr(0, dot + 1);
  kind = upper(dot == std::string::npos ? name : name.substr(dot + 1));
}

struct Layer {
  std::string name;
  int r = -1, g = -1, b = -1, y = -1, ry = -1, by = -1, a = -1;
  bool rgb() const { return r >= 0 && g >= 0 && b >= 0; }
  bool chroma() const { return y >= 0 && ry >= 0 && by >= 0; }
};

bool beautyName(const std::string& layer) {
  // The last part of the layer's name: "ViewLayer.Combined." is Combined.
  std::string n = layer.empty() ? layer : layer.substr(0, layer.size() - 1);
  n = upper(n.substr(n.rfind('.') == std::string::npos ? 0 : n.rfind('.') + 1));
  return n == "BEAUTY" || n == "COMBINED" || n == "RGBA" || n == "RGB" || n == "COLOR" ||
         n == "COLOUR";
}

}  // namespace

PictureChannels pictureChannels(const Image& image) {
  std::vector<Layer> layers;
  int alphas = 0, onlyAlpha = -1;
  for (int c = 0; c < int(image.channelNames.size()) && c < image.channels; ++c) {
    std::string layerName, kind;
    split(image.channelNames[size_t(c)], layerName, kind);
    auto it = std::find_if(layers.begin(), layers.end(),
                           [&](const Layer& l) { return l.name == layerName; });
    if (it == layers.end()) it = layers.insert(layers.end(), Layer{layerName});
    int* slot = kind == "R"    ? &it->r
                : kind == "G"  ? &it->g
                : kind == "B"  ? &it->b
                : kind == "Y"  ? &it->y
                : kind == "RY" ? &it->ry
                : kind == "BY" ? &it->by
                : kind == "A"  ? &it->a
                               : nullptr;
    if (slot && *slot < 0) *slot = c;
    if (kind == "A" && alphas++ == 0) onlyAlpha = c;
  }

  PictureChannels out;
  // The layers that hold a colour of the best kind there is: R, G, B; else Y, RY, BY; else Y.
  std::vector<const Layer*> candidates;
  for (PictureChannels::Kind kind :
       {PictureChannels::Kind::Rgb, PictureChannels::Kind::Chroma, PictureChannels::Kind::Grey}) {
    for (const Layer& l : layers) {
      const bool holds = kind == PictureChannels::Kind::Rgb      ? l.rgb()
                         : kind == PictureChannels::Kind::Chroma ? l.chroma()
                                                                 : l.y >= 0;
      if (holds) candidates.push_back(&l);
    }
    if (!candidates.empty()) {
      out.kind = kind;
      break;
    }
  }
  if (candidates.empty()) {
    out.colour = image.channels < 3 ? std::vector<int>{0} : std::vector<int>{0, 1, 2};
    // Unnamed channels: grey and alpha, or R, G, B and alpha, as a file without names has them.
    if (image.channelNames.empty() && (image.channels == 2 || image.channels == 4))
      out.alpha = image.channels - 1;
    else if (alphas == 1)
      out.alpha = onlyAlpha;
    return out;
  }

  const Layer* chosen = nullptr;
  for (const Layer* l : candidates)
    if (l->name.empty()) chosen = l;
  if (!chosen) {
    std::vector<const Layer*> named;
    for (const Layer* l : candidates)
      if (beautyName(l->name)) named.push_back(l);
    if (named.size() == 1) chosen = named.front();
  }
  if (!chosen) {
    std::vector<const Layer*> withAlpha;
    for (const Layer* l : candidates)
      if (l->a >= 0) withAlpha.push_back(l);
    if (withAlpha.size() == 1) chosen = withAlpha.front();
  }
  if (!chosen) {
    chosen = candidates.front();
    out.ambiguous = candidates.size() > 1;
  }
  for (const Layer* l : candidates)
    if (l != chosen) out.otherLayers.push_back(l->name);
  out.layer = chosen->name;
  switch (out.kind) {
    case PictureChannels::Kind::Rgb:
      out.colour = {chosen->r, chosen->g, chosen->b};
      break;
    case PictureChannels::Kind::Chroma:
      out.colour = {chosen->y, chosen->ry, chosen->by};
      break;
    default:
      out.colour = {chosen->y};
      break;
  }
  out.alpha = chosen->a >= 0 ? chosen->a : alphas == 1 ? onlyAlpha : -1;
  return out;
}

Image pictureRgb(const Image& in) {
  // The picture's colour by channel name (core/channels.h): R, G, B in that order wherever they
  // are (of the layer that is the picture); else Y alone as grey, or Y with OpenEXR's chroma RY,
  // BY; else by position, as an image without names has them.
  const PictureChannels picture = pictureChannels(in);
  const bool rgb = picture.kind == PictureChannels::Kind::Rgb;
  const bool chroma = picture.kind == PictureChannels::Kind::Chroma;
  const bool grey = picture.kind == PictureChannels::Kind::Grey;
  const int r = rgb ? picture.colour[0] : -1, g = rgb ? picture.colour[1] : -1,
            b = rgb ? picture.colour[2] : -1;
  const int y = chroma || grey ? picture.colour[0] : -1, ry = chroma ? picture.colour[1] : -1,
            by = chroma ? picture.colour[2] : -1;
  if (in.channels == 3 &&
      ((rgb && r == 0 && g == 1 && b == 2) || picture.kind == PictureChannels::Kind::ByPosition))
    return in;
  Image out(in.width, in.height, 3, {"R", "G", "B"});
  out.colorSpace = in.colorSpace;
  const int n = in.channels;
  // OpenEXR's luminance weights without a chromaticities attribute (Rec. ITU-R BT.709).
  constexpr float kWr = 0.2126f, kWg = 0.7152f, kWb = 0.0722f;
  for (size_t i = 0; i < in.pixelCount(); ++i) {
    const float* s = in.pixels.data() + i * size_t(n);
    float* d = out.pixels.data() + i * 3;
    if (rgb) {
      d[0] = s[r], d[1] = s[g], d[2] = s[b];
    } else if (chroma) {
      d[0] = s[y] * (1.0f + s[ry]);
      d[2] = s[y] * (1.0f + s[by]);
      d[1] = (s[y] - kWr * d[0] - kWb * d[2]) / kWg;
    } else if (y >= 0) {
      d[0] = d[1] = d[2] = s[y];
    } else if (n < 3) {
      d[0] = d[1] = d[2] = s[0];
    } else {
      d[0] = s[0], d[1] = s[1], d[2] = s[2];
    }
  }
  return out;
}

Image pictureRgb(Image&& in) {
  const PictureChannels picture = pictureChannels(in);
  const auto& k = picture.colour;
  if (in.channels == 3 &&
      ((picture.kind == PictureChannels::Kind::Rgb && k[0] == 0 && k[1] == 1 && k[2] == 2) ||
       picture.kind == PictureChannels::Kind::ByPosition))
    return std::move(in);
  return pictureRgb(static_cast<const Image&>(in));
}

}  // namespace compose
