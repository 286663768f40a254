#include "core/channels.h"

#include <algorithm>
#include <cctype>
#include <cmath>

namespace compose {

namespace {

std::string upper(std::string s) {
  for (char& c : s) c = char(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

// "beauty.R" -> layer "beauty.", kind "R"; "R" -> "", "R". Nuke's long names are its short ones:
// "rgba.red" -> "rgba.", "R"; "alpha" -> "", "A".
void split(const std::string& name, std::string& layer, std::string& kind) {
  const size_t dot = name.rfind('.');
  layer = dot == std::string::npos ? std::string() : name.substr(0, dot + 1);
  kind = upper(dot == std::string::npos ? name : name.substr(dot + 1));
  if (kind == "RED" || kind == "GREEN" || kind == "BLUE" || kind == "ALPHA")
    kind = kind.substr(0, 1);
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

bool isBeautyName(const std::string& name) {
  return !name.empty() && beautyName(name + ".");
}

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

std::array<float, 3> luminanceWeights(const std::array<double, 8>& c) {
  // The primaries' XYZ up to their scales, as columns (x, y, 1 - x - y); the scales make the
  // three add up to the white at Y = 1 (SMPTE RP 177). Solved by Cramer's rule.
  const double m[3][3] = {{c[0], c[2], c[4]},
                          {c[1], c[3], c[5]},
                          {1.0 - c[0] - c[1], 1.0 - c[2] - c[3], 1.0 - c[4] - c[5]}};
  const std::array<float, 3> rec709 = {0.2126f, 0.7152f, 0.0722f};
  if (!(c[7] > 0.0)) return rec709;
  const double w[3] = {c[6] / c[7], 1.0, (1.0 - c[6] - c[7]) / c[7]};
  auto det = [](const double a[3][3]) {
    return a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) -
           a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0]) +
           a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0]);
  };
  const double d = det(m);
  if (!(std::abs(d) > 1e-9)) return rec709;
  double y[3];
  for (int k = 0; k < 3; ++k) {
    double a[3][3];
    for (int r = 0; r < 3; ++r)
      for (int col = 0; col < 3; ++col) a[r][col] = col == k ? w[r] : m[r][col];
    y[k] = m[1][k] * det(a) / d;  // the primary's scale times its y
  }
  const double sum = y[0] + y[1] + y[2];
  if (!(std::abs(sum) > 1e-9) || !std::isfinite(sum)) return rec709;
  return {float(y[0] / sum), float(y[1] / sum), float(y[2] / sum)};
}

void decodeLuminanceChroma(Image& image, const std::array<float, 3>& weights) {
  const PictureChannels picture = pictureChannels(image);
  if (picture.kind != PictureChannels::Kind::Chroma) return;
  const int y = picture.colour[0], ry = picture.colour[1], by = picture.colour[2];
  const size_t n = size_t(image.channels);
  const auto [wr, wg, wb] = weights;
  for (size_t i = 0; i < image.pixelCount(); ++i) {
    float* p = image.pixels.data() + i * n;
    const float r = p[y] * (1.0f + p[ry]), b = p[y] * (1.0f + p[by]);
    const float g = (p[y] - wr * r - wb * b) / wg;
    p[ry] = r;
    p[y] = g;
    p[by] = b;
  }
  if (image.channelNames.size() == n) {
    image.channelNames[size_t(ry)] = picture.layer + "R";
    image.channelNames[size_t(y)] = picture.layer + "G";
    image.channelNames[size_t(by)] = picture.layer + "B";
  }
}

}  // namespace compose
