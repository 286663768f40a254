#include "cubemap/layouts.h"

#include <algorithm>
#include <cctype>

#include "core/error.h"

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

std::array<Image, kCubeFaces> unpackFaces(const Image& image, Layout layout) {
  COMPOSE_CHECK(layout == Layout::Cube || layout == Layout::HorizontalCross ||
                layout == Layout::VerticalCross);
  const int n = checkShape(layout, image.width, image.height, {});
  std::array<Image, kCubeFaces> faces;
  for (int f = 0; f < kCubeFaces; ++f) {
    Image& face = faces[size_t(f)];
    face = Image(n, n, image.channels, image.channelNames);
    face.colorSpace = image.colorSpace;
    int x0 = 0, y0 = f * n;
    bool rotated = false;
    if (layout != Layout::Cube) {
      const CrossCell cell = crossCell(layout, f);
      x0 = cell.column * n;
      y0 = cell.row * n;
      rotated = cell.rotated180;
    }
    const size_t rowFloats = size_t(n) * size_t(image.channels);
    for (int y = 0; y < n; ++y) {
      if (!rotated) {
        std::copy_n(image.at(x0, y0 + y), rowFloats, face.at(0, y));
      } else {
        for (int x = 0; x < n; ++x)
          std::copy_n(image.at(x0 + n - 1 - x, y0 + n - 1 - y), size_t(image.channels),
                      face.at(x, y));
      }
    }
  }
  return faces;
}

Image packFaces(const lighting::CubeMap& cube, Layout layout) {
  COMPOSE_CHECK(layout == Layout::Cube || layout == Layout::HorizontalCross ||
                layout == Layout::VerticalCross);
  const int n = cube.size();
  const int w = layout == Layout::Cube ? n : layout == Layout::HorizontalCross ? 4 * n : 3 * n;
  const int h = layout == Layout::Cube ? 6 * n : layout == Layout::HorizontalCross ? 3 * n : 4 * n;
  Image out(w, h, 3, {"R", "G", "B"});
  out.colorSpace = cube.colorSpace;
  for (int f = 0; f < kCubeFaces; ++f) {
    int x0 = 0, y0 = f * n;
    bool rotated = false;
    if (layout != Layout::Cube) {
      const CrossCell cell = crossCell(layout, f);
      x0 = cell.column * n;
      y0 = cell.row * n;
      rotated = cell.rotated180;
    }
    for (int y = 0; y < n; ++y) {
      if (!rotated) {
        std::copy_n(cube.texel(f, 0, y), size_t(n) * 3, out.at(x0, y0 + y));
      } else {
        for (int x = 0; x < n; ++x)
          std::copy_n(cube.texel(f, x, y), 3, out.at(x0 + n - 1 - x, y0 + n - 1 - y));
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
