#include "cubemap/layouts.h"

#include <algorithm>
#include <cctype>
#include <cmath>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::cubemap {

using lighting::kCubeFaces;

namespace {

std::string lower(std::string s) {
  for (auto& c : s) c = char(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

std::string shape(int w, int h) {
  return std::to_string(w) + "x" + std::to_string(h);
}

// Face tokens per naming family, in face order +X -X +Y -Y +Z -Z.
const std::vector<std::array<const char*, kCubeFaces>>& families() {
  static const std::vector<std::array<const char*, kCubeFaces>> list = {
      {"px", "nx", "py", "ny", "pz", "nz"},
      {"posx", "negx", "posy", "negy", "posz", "negz"},
      {"pos_x", "neg_x", "pos_y", "neg_y", "pos_z", "neg_z"},
      {"+x", "-x", "+y", "-y", "+z", "-z"},
      {"right", "left", "top", "bottom", "back", "front"},
      {"right", "left", "up", "down", "back", "front"},
  };
  return list;
}

constexpr int kSignedFamily = 3;  // +X -X ...: may follow any character

}  // namespace

const char* layoutName(Layout layout) {
  switch (layout) {
    case Layout::LatLong:
      return "latlong";
    case Layout::Cube:
      return "cube";
    case Layout::HorizontalCross:
      return "hcross";
    case Layout::VerticalCross:
      return "vcross";
    case Layout::Faces:
      return "faces";
    case Layout::MirrorBall:
      return "mirrorball";
  }
  return "?";
}

std::vector<std::string> layoutNames() {
  return {"latlong", "cube", "hcross", "vcross", "faces", "mirrorball"};
}

std::optional<Layout> parseLayout(const std::string& name) {
  const std::string n = lower(name);
  if (n == "latlong" || n == "lat-long" || n == "equirect" || n == "equirectangular")
    return Layout::LatLong;
  if (n == "cube" || n == "strip" || n == "exr-cube" || n == "cubemap") return Layout::Cube;
  if (n == "hcross" || n == "cross-h" || n == "horizontal-cross") return Layout::HorizontalCross;
  if (n == "vcross" || n == "cross-v" || n == "vertical-cross") return Layout::VerticalCross;
  if (n == "faces" || n == "six-faces") return Layout::Faces;
  if (n == "mirrorball" || n == "mirror-ball" || n == "ball" || n == "probe")
    return Layout::MirrorBall;
  return std::nullopt;
}

std::optional<Layout> layoutFromAspect(int w, int h) {
  if (w <= 0 || h <= 0) return std::nullopt;
  if (w == 2 * h) return Layout::LatLong;
  if (h == 6 * w) return Layout::Cube;
  if (3 * w == 4 * h && w % 4 == 0) return Layout::HorizontalCross;
  if (4 * w == 3 * h && w % 3 == 0) return Layout::VerticalCross;
  return std::nullopt;
}

int checkShape(Layout layout, int w, int h, const std::filesystem::path& file) {
  auto fail = [&](const std::string& expected) {
    throw Error("ingest",
                std::string(layoutName(layout)) + " layout needs " + expected + ", the image is " +
                    shape(w, h),
                file);
  };
  switch (layout) {
    case Layout::LatLong:
      if (h < 1 || w != 2 * h) fail("width = 2 x height (2:1)");
      return h;
    case Layout::Cube:
      if (w < 1 || h != 6 * w) fail("six square faces stacked vertically (N x 6N, 1:6)");
      return w;
    case Layout::HorizontalCross:
      if (w < 4 || w % 4 != 0 || 3 * w != 4 * h) fail("a 4:3 image of 4N x 3N pixels");
      return w / 4;
    case Layout::VerticalCross:
      if (w < 3 || w % 3 != 0 || 4 * w != 3 * h) fail("a 3:4 image of 3N x 4N pixels");
      return w / 3;
    case Layout::Faces:
      if (w < 1 || w != h) fail("a square face");
      return w;
    case Layout::MirrorBall:
      if (w < 2 || w != h) fail("a square crop of the ball");
      return w;
  }
  return 0;
}

CrossCell crossCell(Layout layout, int face) {
  COMPOSE_CHECK(layout == Layout::HorizontalCross || layout == Layout::VerticalCross);
  // Faces +X -X +Y -Y +Z -Z.
  static const CrossCell kHorizontal[kCubeFaces] = {{2, 1, false}, {0, 1, false}, {1, 0, false},
                                                    {1, 2, false}, {3, 1, false}, {1, 1, false}};
  static const CrossCell kVertical[kCubeFaces] = {{2, 1, false}, {0, 1, false}, {1, 0, false},
                                                  {1, 2, false}, {1, 3, true},  {1, 1, false}};
  return (layout == Layout::HorizontalCross ? kHorizontal : kVertical)[face];
}

double crossCornerRatio(const Image& image, Layout layout) {
  const int n = checkShape(layout, image.width, image.height, {});
  const int columns = image.width / n, rows = image.height / n;
  std::vector<bool> used(size_t(columns * rows), false);
  for (int f = 0; f < kCubeFaces; ++f) {
    const CrossCell c = crossCell(layout, f);
    used[size_t(c.row * columns + c.column)] = true;
  }
  double sum[2] = {0.0, 0.0};  // outside the cross, the faces
  const int channels = std::min(image.channels, 3);
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const float* p = image.at(x, y);
      double v = 0.0;
      for (int k = 0; k < channels; ++k) v += std::isfinite(p[k]) ? std::abs(double(p[k])) : 0.0;
      sum[used[size_t((y / n) * columns + x / n)] ? 1 : 0] += v;
    }
  }
  return sum[1] > 0.0 ? sum[0] / sum[1] : (sum[0] > 0.0 ? 1.0 : 0.0);  // six cells each
}

// Both directions build their outputs row by row with insert(), so every output float is written
// once (no zero-filling first): layout conversions are memory copies, and cost about as much.

std::array<Image, kCubeFaces> unpackFaces(const Image& image, Layout layout) {
  COMPOSE_CHECK(layout == Layout::Cube || layout == Layout::HorizontalCross ||
                layout == Layout::VerticalCross);
  const int n = checkShape(layout, image.width, image.height, {});
  const size_t c = size_t(image.channels), rowFloats = size_t(n) * c;
  std::array<Image, kCubeFaces> faces;
  parallelFor(0, kCubeFaces, [&](int64_t ff) {
    const int f = int(ff);
    int x0 = 0, y0 = f * n;
    bool rotated = false;
    if (layout != Layout::Cube) {
      const CrossCell cell = crossCell(layout, f);
      x0 = cell.column * n;
      y0 = cell.row * n;
      rotated = cell.rotated180;
    }
    Image& face = faces[size_t(f)];
    face.width = face.height = n;
    face.channels = image.channels;
    face.channelNames = image.channelNames;
    face.colorSpace = image.colorSpace;
    face.pixels.reserve(rowFloats * size_t(n));
    std::vector<float> reversed(rotated ? rowFloats : 0);
    for (int y = 0; y < n; ++y) {
      if (!rotated) {
        const float* src = image.at(x0, y0 + y);
        face.pixels.insert(face.pixels.end(), src, src + rowFloats);
      } else {
        const float* src = image.at(x0, y0 + n - 1 - y);
        for (int x = 0; x < n; ++x)
          std::copy_n(src + size_t(n - 1 - x) * c, c, reversed.data() + size_t(x) * c);
        face.pixels.insert(face.pixels.end(), reversed.begin(), reversed.end());
      }
    }
  });
  return faces;
}

Image packFaces(const lighting::CubeMap& cube, Layout layout) {
  COMPOSE_CHECK(layout == Layout::Cube || layout == Layout::HorizontalCross ||
                layout == Layout::VerticalCross);
  const int n = cube.size();
  const int cols = layout == Layout::Cube ? 1 : layout == Layout::HorizontalCross ? 4 : 3;
  const int rows = layout == Layout::Cube ? 6 : layout == Layout::HorizontalCross ? 3 : 4;
  Image out;
  out.width = cols * n;
  out.height = rows * n;
  out.channels = 3;
  out.channelNames = {"R", "G", "B"};
  out.colorSpace = cube.colorSpace;
  const size_t faceRow = size_t(n) * 3;
  // Which face sits in each cell of the layout's grid (-1: black).
  std::vector<int> cell(size_t(cols) * size_t(rows), -1);
  std::vector<bool> turned(kCubeFaces, false);
  for (int f = 0; f < kCubeFaces; ++f) {
    if (layout == Layout::Cube) {
      cell[size_t(f)] = f;
    } else {
      const CrossCell c = crossCell(layout, f);
      cell[size_t(c.row) * size_t(cols) + size_t(c.column)] = f;
      turned[size_t(f)] = c.rotated180;
    }
  }
  out.pixels.reserve(size_t(out.width) * size_t(out.height) * 3);
  std::vector<float> reversed(faceRow);
  for (int r = 0; r < rows; ++r) {
    for (int y = 0; y < n; ++y) {
      for (int k = 0; k < cols; ++k) {
        const int f = cell[size_t(r) * size_t(cols) + size_t(k)];
        if (f < 0) {
          out.pixels.insert(out.pixels.end(), faceRow, 0.0f);
        } else if (!turned[size_t(f)]) {
          const float* src = cube.texel(f, 0, y);
          out.pixels.insert(out.pixels.end(), src, src + faceRow);
        } else {
          const float* src = cube.texel(f, 0, n - 1 - y);
          for (int x = 0; x < n; ++x)
            std::copy_n(src + size_t(n - 1 - x) * 3, 3, reversed.data() + size_t(x) * 3);
          out.pixels.insert(out.pixels.end(), reversed.begin(), reversed.end());
        }
      }
    }
  }
  return out;
}

std::optional<FaceToken> faceFromName(const std::string& stem) {
  const std::string s = lower(stem);
  std::optional<FaceToken> best;
  for (size_t fam = 0; fam < families().size(); ++fam) {
    for (int f = 0; f < kCubeFaces; ++f) {
      const std::string token = families()[fam][size_t(f)];
      if (s.size() < token.size() || s.compare(s.size() - token.size(), token.size(), token) != 0)
        continue;
      const size_t at = s.size() - token.size();
      const bool separated = at == 0 || std::string("_-. ").find(s[at - 1]) != std::string::npos;
      if (!separated && int(fam) != kSignedFamily) continue;
      // Prefer the longest token ("neg_x" over "x"-like shorter matches).
      if (!best || token.size() > best->token.size())
        best = FaceToken{f, stem.substr(at), int(fam)};
    }
  }
  return best;
}

std::optional<double> yawFromName(const std::string& stem) {
  if (stem.size() < 4 || stem.compare(0, 3, "yaw") != 0) return std::nullopt;
  size_t end = 3;
  while (end < stem.size() && end < 6 && std::isdigit(static_cast<unsigned char>(stem[end]))) ++end;
  if (end == 3 || (end < stem.size() && std::isalnum(static_cast<unsigned char>(stem[end]))))
    return std::nullopt;
  const int degrees = std::stoi(stem.substr(3, end - 3));
  if (degrees >= 360) return std::nullopt;
  return double(degrees);
}

std::optional<FaceToken> faceFromPhotoName(const std::filesystem::path& file) {
  const std::string stem = file.stem().string();
  if (auto token = faceFromName(stem)) return token;
  size_t end = stem.size();
  while (end > 0 && std::isdigit(static_cast<unsigned char>(stem[end - 1]))) --end;
  if (end == stem.size() || end < 2 || std::string("_-. ").find(stem[end - 1]) == std::string::npos)
    return std::nullopt;
  return faceFromName(stem.substr(0, end - 1));
}

std::string faceNameIn(int family, int face, const std::string& like) {
  std::string token = families()[size_t(family)][size_t(face)];
  const bool upper =
      std::any_of(like.begin(), like.end(), [](unsigned char c) { return std::isupper(c); }) &&
      std::none_of(like.begin(), like.end(), [](unsigned char c) { return std::islower(c); });
  const bool capital = !upper && !like.empty() && std::isupper(static_cast<unsigned char>(like[0]));
  if (family == kSignedFamily || upper) {
    for (auto& c : token) c = char(std::toupper(static_cast<unsigned char>(c)));
  } else if (capital) {
    token[0] = char(std::toupper(static_cast<unsigned char>(token[0])));
  }
  return token;
}

std::optional<int> parseFaceNaming(const std::string& name) {
  const std::string n = lower(name);
  if (n == "pxnx") return 0;
  if (n == "posneg") return 1;
  if (n == "exr") return kSignedFamily;
  if (n == "words") return 4;
  return std::nullopt;
}

std::vector<std::string> faceNamingNames() {
  return {"pxnx", "posneg", "exr", "words"};
}

}  // namespace compose::cubemap
