#include "cubemap/environment_io.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>

#include <Imath/half.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfChromaticitiesAttribute.h>
#include <OpenEXR/ImfEnvmapAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputFile.h>
#include <OpenEXR/ImfMultiPartInputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfStandardAttributes.h>
#include <OpenEXR/ImfStringAttribute.h>

#include "core/channels.h"
#include "core/error.h"
#include "core/numbers.h"
#include "ingest/exr_io.h"
#include "lighting/sphere_resample.h"

namespace compose::cubemap {

namespace fs = std::filesystem;
using ingest::lowerExtension;
using lighting::kCubeFaces;

namespace {

bool isImageFile(const fs::path& p) {
  static const char* kExtensions[] = {".exr", ".hdr",  ".pic", ".rgbe", ".tif", ".tiff", ".png",
                                      ".jpg", ".jpeg", ".pfm", ".dng",  ".cr2", ".nef",  ".arw"};
  const std::string e = lowerExtension(p);
  return std::any_of(std::begin(kExtensions), std::end(kExtensions),
                     [&](const char* k) { return e == k; });
}

bool hasExrMagic(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  unsigned char magic[4] = {0, 0, 0, 0};
  in.read(reinterpret_cast<char*>(magic), 4);
  return in.gcount() == 4 && magic[0] == 0x76 && magic[1] == 0x2f && magic[2] == 0x31 &&
         magic[3] == 0x01;
}

std::string faceList() {
  std::string s;
  for (int f = 0; f < kCubeFaces; ++f) s += std::string(f ? " " : "") + lighting::faceName(f);
  return s;
}

// Six face files, recognised by name or taken in OpenEXR's order.
EnvironmentFile readSixFaces(const std::vector<fs::path>& paths, std::string how) {
  std::array<std::optional<fs::path>, kCubeFaces> byFace;
  int recognised = 0;
  for (const fs::path& p : paths) {
    const auto token = faceFromName(p.stem().string());
    if (!token) continue;
    ++recognised;
    if (byFace[size_t(token->face)]) {
      throw Error("ingest",
                  std::string("two files for cube face ") + lighting::faceName(token->face) + ": " +
                      byFace[size_t(token->face)]->filename().string() + " and " +
                      p.filename().string(),
                  p);
    }
    byFace[size_t(token->face)] = p;
  }
  EnvironmentFile out;
  out.layout = Layout::Faces;
  if (recognised == 0) {
    for (int f = 0; f < kCubeFaces; ++f) byFace[size_t(f)] = paths[size_t(f)];
    how += "; no face names recognised, taken in OpenEXR's order " + faceList();
  } else if (recognised < kCubeFaces) {
    for (int f = 0; f < kCubeFaces; ++f) {
      if (!byFace[size_t(f)]) {
        throw Error("ingest",
                    std::string("missing cube face ") + lighting::faceName(f) +
                        ": no file named for it (names such as *_px, *_posx, *+X, *_right; "
                        "front is -Z, back is +Z)",
                    paths.front().parent_path());
      }
    }
  }
  out.how = how;
  std::array<fs::path, kCubeFaces> files;
  for (int f = 0; f < kCubeFaces; ++f) files[size_t(f)] = *byFace[size_t(f)];
  // The set is read in one colour space, the one its +X face says: a face stored otherwise
  // (another format's encoding, other primaries, another profile) would be read as +X's (five
  // linear Rec. 709 faces were taken as ACEScg by +X's chromaticities; a PNG face's sRGB codes
  // as linear light). How a face says its colour, to compare.
  // (An OpenEXR's chromaticities decide its space whatever name it gives; an ICC profile shows
  // in the space the reader names.)
  auto colourOf = [](const ingest::CaptureInfo& info) {
    std::string s = info.integerSamples() ? "integer codes" : "floats";
    if (info.chromaticities) {
      char text[96];
      const auto& c = *info.chromaticities;
      std::snprintf(text, sizeof text, ", chromaticities %.4g %.4g %.4g %.4g %.4g %.4g", c[0], c[1],
                    c[2], c[3], c[4], c[5]);
      s += text;
    } else if (!info.fileColorSpace.empty()) {
      s += ", '" + info.fileColorSpace + "'";
    }
    return s;
  };
  for (int f = 0; f < kCubeFaces; ++f) {
    ingest::LoadedImage img = ingest::readImage(files[size_t(f)], "ingest", {.picturePart = true});
    ingest::requireColourChannels(img.image, files[size_t(f)], "ingest", "the environment's face");
    img.image = pictureRgb(std::move(img.image));  // by channel name, not as stored
    out.notes.insert(out.notes.end(), img.notes.begin(), img.notes.end());
    if (f == 0) out.info = img.info;
    if (f > 0 && colourOf(img.info) != colourOf(out.info)) {
      throw Error("ingest",
                  std::string("cube faces store their colour differently: ") +
                      lighting::faceName(f) + " is " + colourOf(img.info) + "; +X (" +
                      files[0].filename().string() + ") is " + colourOf(out.info) +
                      ": the set is read in one space; give six faces of one kind (compose "
                      "color converts each to the working space)",
                  files[size_t(f)]);
    }
    checkShape(Layout::Faces, img.image.width, img.image.height, files[size_t(f)]);
    if (f > 0 && img.image.width != out.faces[0].width) {
      throw Error("ingest",
                  std::string("cube faces differ in size: ") + lighting::faceName(f) + " is " +
                      std::to_string(img.image.width) + "x" + std::to_string(img.image.height) +
                      ", +X (" + files[0].filename().string() + ") is " +
                      std::to_string(out.faces[0].width) + "x" +
                      std::to_string(out.faces[0].height),
                  files[size_t(f)]);
    }
    out.faces[size_t(f)] = std::move(img.image);
    out.files.push_back(files[size_t(f)]);
  }
  return out;
}

// The six siblings of a face set from a folder.
std::vector<fs::path> facesInFolder(const fs::path& folder) {
  std::vector<fs::path> candidates;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(folder, ec)) {
    if (entry.is_regular_file() && isImageFile(entry.path()) &&
        faceFromName(entry.path().stem().string()))
      candidates.push_back(entry.path());
  }
  if (ec) throw Error("ingest", "cannot list the folder: " + ec.message(), folder);
  std::sort(candidates.begin(), candidates.end());
  if (candidates.empty()) {
    throw Error("ingest",
                "no cube face files in the folder (expected six images named like env_px.exr ... "
                "env_nz.exr, posx/negx, +X/-X or right/left/top/bottom/back/front)",
                folder);
  }
  return candidates;
}

// The six files of a '%' pattern, trying each naming family.
std::vector<fs::path> facesOfPattern(const fs::path& pattern) {
  const std::string text = pattern.string();
  const size_t at = text.find('%');
  if (text.find('%', at + 1) != std::string::npos)
    throw Error("ingest", "a face pattern holds one '%' (it stands for px, nx, ...)", pattern);
  std::string tried;
  // The naming family with the most of its files there, for saying which face is missing.
  std::vector<fs::path> nearest;
  int nearestCount = 0;
  for (int family = 0; family < 6; ++family) {
    for (const char* like : {"px", "PX"}) {
      std::vector<fs::path> files;
      for (int f = 0; f < kCubeFaces; ++f)
        files.push_back(text.substr(0, at) + faceNameIn(family, f, like) + text.substr(at + 1));
      std::error_code ec;
      const int present = int(std::count_if(files.begin(), files.end(), [&](const fs::path& p) {
        return fs::is_regular_file(p, ec);
      }));
      if (present == kCubeFaces) return files;
      if (present > nearestCount) nearestCount = present, nearest = files;
      tried += (tried.empty() ? "" : ", ") + files.front().filename().string();
    }
  }
  if (nearestCount > 0) {
    std::error_code ec;
    for (int f = 0; f < kCubeFaces; ++f)
      if (!fs::is_regular_file(nearest[size_t(f)], ec))
        throw Error("ingest",
                    std::string("missing cube face ") + lighting::faceName(f) + ": expected " +
                        nearest[size_t(f)].filename().string() + " beside the pattern's " +
                        std::to_string(nearestCount) + " other faces",
                    pattern);
  }
  throw Error("ingest", "no six face files match the pattern (tried " + tried + ", ...)", pattern);
}

// The six siblings of one face file.
std::vector<fs::path> siblingsOf(const fs::path& face, const FaceToken& token) {
  const std::string stem = face.stem().string();
  const std::string prefix = stem.substr(0, stem.size() - token.token.size());
  std::vector<fs::path> files;
  for (int f = 0; f < kCubeFaces; ++f) {
    fs::path p = face;
    p.replace_filename(prefix + faceNameIn(token.family, f, token.token) +
                       face.extension().string());
    std::error_code ec;
    if (!fs::is_regular_file(p, ec)) {
      throw Error("ingest",
                  std::string("missing cube face ") + lighting::faceName(f) + ": expected " +
                      p.filename().string() + " beside " + face.filename().string(),
                  p);
    }
    files.push_back(p);
  }
  return files;
}

std::string aspectText(Layout layout) {
  switch (layout) {
    case Layout::LatLong:
      return "aspect 2:1";
    case Layout::Cube:
      return "aspect 1:6";
    case Layout::HorizontalCross:
      return "aspect 4:3";
    case Layout::VerticalCross:
      return "aspect 3:4";
    default:
      return "";
  }
}

std::string layoutTitle(Layout layout) {
  switch (layout) {
    case Layout::LatLong:
      return "lat-long map";
    case Layout::Cube:
      return "cube map in OpenEXR's layout";
    case Layout::HorizontalCross:
      return "horizontal cross";
    case Layout::VerticalCross:
      return "vertical cross";
    case Layout::Faces:
      return "six face files";
    case Layout::MirrorBall:
      return "mirror ball";
  }
  return "";
}

float maxValue(std::span<const float> v) {
  float m = 0.0f;
  for (float x : v) m = std::max(m, x);
  return m;
}

bool chooseHalf(WriteOptions::Depth depth, float maximum, const fs::path& path,
                std::vector<std::string>& notes) {
  if (lowerExtension(path) != ".exr") return false;
  if (depth == WriteOptions::Depth::Float) return false;
  constexpr float kHalfMax = 65504.0f;
  if (maximum > kHalfMax) {
    // Half would hold infinity there (asked for or not): float, said so.
    notes.push_back(
        "values up to " + numberText(maximum) +
        " exceed half float's range: " + path.filename().string() + " is written as 32-bit float" +
        (depth == WriteOptions::Depth::Half ? " instead of the --depth half asked for" : ""));
    return false;
  }
  return true;
}

// Values below 0 that a file of the format cannot hold: how many were written as 0, the lowest.
struct Clamped {
  size_t count = 0;
  float lowest = 0.0f;
  void note(const fs::path& file, const std::string& space, std::vector<std::string>& notes) const {
    if (count == 0) return;
    char line[160];
    std::snprintf(line, sizeof line, "%zu values below 0 (as low as %.3g", count, double(lowest));
    notes.push_back(std::string(line) +
                    (space.empty() ? std::string() : " in '" + space + "', as written") +
                    ": colours outside the gamut of the file's space, or a resampling's ringing) "
                    "are written as 0: a " +
                    lowerExtension(file) + " file holds no negative values (OpenEXR does)");
  }
};

void writeAny(const fs::path& temporary, const fs::path& destination, const Image& rgb,
              bool useHalf, std::optional<Layout> envmap, const WriteOptions& options,
              std::vector<std::string>& notes, Clamped& clamped) {
  ingest::requireImageWriter(destination);
  // Radiance above 1 needs a format of floats that is read as linear light: OpenEXR or Radiance.
  // An 8- or 16-bit PNG, JPEG or TIFF would clip it (and say nothing); a float TIFF would be read
  // back as sRGB, as the colour config's file rules take TIFFs.
  const std::string ext = lowerExtension(destination);
  const bool floats = ext == ".exr" || ext == ".hdr";
  // Only OpenEXR holds negative values: Radiance's shared exponent has no sign (OpenImageIO's
  // encoder wraps a negative channel round to a large positive one), codes start at 0.
  Image nonNegative;
  const Image* written = &rgb;
  if (ext != ".exr" &&
      std::any_of(rgb.pixels.begin(), rgb.pixels.end(), [](float v) { return v < 0.0f; })) {
    nonNegative = rgb;
    for (float& v : nonNegative.pixels) {
      if (!(v < 0.0f)) continue;
      // Float noise of a conversion (-5e-10) is no colour to speak of.
      if (v < -1e-6f) ++clamped.count;
      clamped.lowest = std::min(clamped.lowest, v);
      v = 0.0f;
    }
    written = &nonNegative;
  }
  if (!floats) {
    // Within float rounding of 1 is white: 8-bit codes that went to linear light and back
    // (a clipped sky, resampled) come back a step or two above it.
    constexpr float kWhite = 1.0f + 1e-5f;
    const float most = maxValue(rgb.pixels);
    if (most > kWhite && options.fromCodes) {
      size_t above = 0;
      for (const float v : rgb.pixels) above += v > kWhite;
      char line[200];
      std::snprintf(line, sizeof line,
                    "%zu values above 1 (up to %.4g: clipped white times an exposure gain) are "
                    "written as white in %s",
                    above, double(most), destination.filename().c_str());
      notes.push_back(line);
    } else if (most > kWhite) {
      // Said in the file's own encoding (the caller has encoded linear light for it).
      const std::string in =
          rgb.colorSpace.empty() ? std::string() : " (in '" + rgb.colorSpace + "', as written)";
      throw Error("output",
                  "the environment holds values up to " + numberText(most) + in + ", which a " +
                      ext +
                      " file of 8- or 16-bit codes would clip to 1: write OpenEXR (.exr) or "
                      "Radiance (.hdr)",
                  destination);
    }
  }
  try {
    if (ext == ".exr") {
      writeExr(temporary, rgb, useHalf, envmap, options.chromaticities, options.exrCompression,
               options.strings);
    } else {
      ingest::WriteOptions write;
      if (floats)
        write.depth = ingest::WriteOptions::Depth::Float;
      else if (options.sixteenBit && ext != ".jpg" && ext != ".jpeg")
        write.depth = ingest::WriteOptions::Depth::UInt16;
      ingest::writeImage(temporary, *written, write);
    }
  } catch (const Error& e) {
    // The temporary is ours: the user knows the file by the name they gave.
    if (e.file() != temporary) throw;
    throw Error(e.stage(), nameTheDestination(e.what(), temporary, destination), destination);
  }
}

}  // namespace

std::string EnvironmentFile::describe() const {
  if (layout == Layout::LatLong || layout == Layout::MirrorBall)
    return layoutTitle(layout) + " " + std::to_string(image.width) + "x" +
           std::to_string(image.height);
  return layoutTitle(layout) + ", faces " + std::to_string(faces[0].width) + "x" +
         std::to_string(faces[0].height);
}

std::optional<Layout> exrEnvmapLayout(const fs::path& file) {
  if (!hasExrMagic(file)) return std::nullopt;
  try {
    // Of a multi-part file, the first part that says (the picture's, which the reader takes).
    Imf::MultiPartInputFile in(file.c_str());
    for (int p = 0; p < in.parts(); ++p) {
      const Imf::Header& header = in.header(p);
      if (!Imf::hasEnvmap(header)) continue;
      return Imf::envmap(header) == Imf::ENVMAP_CUBE ? Layout::Cube : Layout::LatLong;
    }
    return std::nullopt;
  } catch (const std::exception&) {
    return std::nullopt;  // unreadable: the image reader reports it properly
  }
}

namespace {

// How to give a layout that cannot be detected (ReadOptions::adviseConvert).
// A lat-long map slightly off 2:1, within 1 % (4096x2047, 8192x4097: an export rounded its
// height): what to do about it; empty for any other shape.
std::string nearlyLatLong(int w, int h, const fs::path& path) {
  if (h < 1 || w == 2 * h || std::abs(w - 2 * h) > std::max(2, w / 100)) return {};
  const int height = (w + 1) / 2;
  return "a " + std::to_string(w) + "x" + std::to_string(h) +
         " image looks like a lat-long map slightly off 2:1; a lat-long map must be exactly 2:1 "
         "(width = 2 x height): resize it first, e.g. oiiotool " +
         path.string() + " --resize " + std::to_string(2 * height) + "x" + std::to_string(height) +
         " -o ENV.exr";
}

std::string layoutAdvice(const ReadOptions& options, const fs::path& path,
                         const std::string& choices) {
  if (!options.adviseConvert) return "say which with --layout (" + choices + ")";
  return "convert it first, saying which: compose convert " + path.string() + " --layout " +
         choices + " --to latlong --out ENV.exr";
}

}  // namespace

EnvironmentFile readEnvironmentFile(const std::vector<fs::path>& inputs,
                                    const ReadOptions& options) {
  if (inputs.size() == 6) {
    if (options.layout && *options.layout != Layout::Faces) {
      throw Error("ingest", std::string("six inputs are six cube faces, not a ") +
                                layoutName(*options.layout) + " layout");
    }
    return readSixFaces(inputs, "six face files");
  }
  if (inputs.size() != 1) {
    throw Error("ingest",
                "expected one environment (an image, a folder of six faces or a name "
                "pattern with %) or six face files, got " +
                    std::to_string(inputs.size()) + " inputs");
  }
  const fs::path& path = inputs.front();
  std::error_code ec;
  if (path.string().find('%') != std::string::npos && !fs::exists(path, ec))
    return readSixFaces(facesOfPattern(path), "six face files from the pattern");
  if (fs::is_directory(path, ec)) {
    const auto files = facesInFolder(path);
    if (files.size() != 6) {
      // Let readSixFaces name the duplicate; with fewer than six, name the missing face.
      if (files.size() < 6) {
        std::array<bool, kCubeFaces> seen{};
        for (const auto& f : files) seen[size_t(faceFromName(f.stem().string())->face)] = true;
        for (int f = 0; f < kCubeFaces; ++f) {
          if (!seen[size_t(f)]) {
            throw Error("ingest",
                        std::string("missing cube face ") + lighting::faceName(f) +
                            ": the folder has face files for only " + std::to_string(files.size()) +
                            " faces",
                        path);
          }
        }
      }
    }
    return readSixFaces(files, "six face files in the folder");
  }
  if (!fs::exists(path, ec)) throw Error("ingest", "file not found", path);

  const auto token = faceFromName(path.stem().string());
  if (options.layout == Layout::Faces) {
    if (!token) {
      throw Error("ingest",
                  "--layout faces needs six face files, a folder, a % pattern or a file named "
                  "for its face (env_px.exr ...)",
                  path);
    }
    return readSixFaces(siblingsOf(path, *token),
                        "six face files beside " + path.filename().string());
  }

  EnvironmentFile out;
  ingest::LoadedImage img = ingest::readImage(path, "ingest", {.picturePart = true});
  ingest::requireColourChannels(img.image, path, "ingest", "the environment");
  img.image = pictureRgb(std::move(img.image));  // by channel name, not as stored
  out.notes = img.notes;
  const int w = img.image.width, h = img.image.height;
  const std::optional<Layout> declared = exrEnvmapLayout(path);
  if (options.layout) {
    out.layout = *options.layout;
    out.how = std::string("--layout ") + layoutName(out.layout);
    if (declared && *declared != out.layout)
      out.how += std::string(" (the file's envmap attribute says ") + layoutName(*declared) + ")";
  } else if (declared) {
    out.layout = *declared;
    out.how = std::string("OpenEXR envmap attribute: ") + layoutName(out.layout);
  } else if (const auto byAspect = layoutFromAspect(w, h)) {
    out.layout = *byAspect;
    out.how = aspectText(out.layout);
  } else if (w == h && token) {
    return readSixFaces(siblingsOf(path, *token),
                        "six face files beside " + path.filename().string());
  } else if (w == h) {
    throw Error("ingest",
                "a square image could be a mirror ball or a single cube face: a mirror ball? " +
                    layoutAdvice(options, path, "mirrorball") +
                    "; a face? give the six face files (a folder, or names ending _px ... _nz)",
                path);
  } else if (const std::string advice = nearlyLatLong(w, h, path); !advice.empty()) {
    throw Error("ingest", advice, path);
  } else if (const int n = std::max(w, h) / 4;
             n > 0 && std::abs(std::max(w, h) - 4 * n) <= std::max(2, n / 25) &&
             std::abs(std::min(w, h) - 3 * n) <= std::max(2, n / 25)) {
    // A cross a few pixels off 4N x 3N (an editor's canvas, a border): each face must be N x N.
    const bool wide = w > h;
    throw Error("ingest",
                "a " + std::to_string(w) + "x" + std::to_string(h) + " image looks like a " +
                    (wide ? "horizontal" : "vertical") +
                    " cross a few pixels off; a cross must be exactly " +
                    (wide ? "4N x 3N" : "3N x 4N") + " (" + std::to_string(wide ? 4 * n : 3 * n) +
                    "x" + std::to_string(wide ? 3 * n : 4 * n) + " for faces of " +
                    std::to_string(n) + "): crop it to that first",
                path);
  } else {
    throw Error("ingest",
                "cannot tell the environment's layout from a " + std::to_string(w) + "x" +
                    std::to_string(h) +
                    " image: expected 2:1 (lat-long), 1:6 (OpenEXR cube), 4:3 (horizontal "
                    "cross) or 3:4 (vertical cross); " +
                    layoutAdvice(options, path, "LAYOUT"),
                path);
  }
  if (out.layout == Layout::LatLong)
    if (const std::string advice = nearlyLatLong(w, h, path); !advice.empty())
      throw Error("ingest", advice, path);
  checkShape(out.layout, w, h, path);
  if (!options.layout && !declared &&
      (out.layout == Layout::HorizontalCross || out.layout == Layout::VerticalCross)) {
    // A cross leaves six cells empty (black); a photo of that aspect (4:3 is most cameras')
    // fills them. Read as a cross, it would light the object with the wrong light everywhere.
    const double corners = crossCornerRatio(img.image, out.layout);
    if (corners > 0.05) {
      char ratio[32];
      std::snprintf(ratio, sizeof ratio, "%.2f", corners);
      throw Error("ingest",
                  std::string("the image has a cross's aspect (") + aspectText(out.layout) +
                      ") but its cells outside the cross are not empty (" + ratio +
                      " times as bright as the faces): a photo, not a cross? Photos of views "
                      "are stitched into an environment (compose stitch, or --env with the "
                      "capture description); if it is a cross all the same, " +
                      layoutAdvice(options, path, layoutName(out.layout)),
                  path);
    }
  }
  out.files.push_back(path);
  out.info = img.info;
  if (out.layout == Layout::LatLong || out.layout == Layout::MirrorBall) {
    out.image = std::move(img.image);
  } else {
    out.faces = unpackFaces(img.image, out.layout);
  }
  return out;
}

std::vector<fs::path> environmentFiles(const fs::path& path) {
  std::error_code ec;
  if (path.string().find('%') != std::string::npos && !fs::exists(path, ec))
    return facesOfPattern(path);
  if (fs::is_directory(path, ec)) return facesInFolder(path);
  if (!fs::exists(path, ec)) throw Error("ingest", "file not found", path);
  if (const auto token = faceFromName(path.stem().string())) {
    // A face file stands for its set when its siblings are there (readEnvironmentFile decides
    // from the image's shape whether it is one).
    try {
      return siblingsOf(path, *token);
    } catch (const Error&) {
    }
  }
  return {path};
}

lighting::CubeMap cubeMapOf(const EnvironmentFile& file, lighting::SanitizeReport* report) {
  COMPOSE_CHECK(file.isCube());
  std::array<const Image*, kCubeFaces> faces;
  for (int f = 0; f < kCubeFaces; ++f) faces[size_t(f)] = &file.faces[size_t(f)];
  std::array<fs::path, kCubeFaces> names;
  for (int f = 0; f < kCubeFaces; ++f)
    names[size_t(f)] = file.files.size() == 6 ? file.files[size_t(f)] : file.files.front();
  return lighting::CubeMap::fromFaces(faces, file.files.front(), report, &names);
}

LoadedEnvironment loadEnvironment(const fs::path& path, const ReadOptions& options,
                                  const Progress& progress, const FaceToLinear& toLinear) {
  ReadOptions read = options;
  read.adviseConvert = true;  // the one-shot command has no --layout
  EnvironmentFile file = readEnvironmentFile({path}, read);
  LoadedEnvironment out;
  out.info = file.info;
  out.file = file.files.front();
  for (const std::string& n : file.notes) out.notes.push_back("environment " + n);
  if (file.layout == Layout::MirrorBall) {
    throw Error("ingest",
                "a mirror ball needs unwrapping first: compose convert BALL --from mirrorball "
                "--to latlong --out ENV.exr",
                path);
  }
  if (file.layout == Layout::LatLong) {
    out.image = std::move(file.image);
    if (file.how != "aspect 2:1") out.notes.push_back("environment layout: " + file.how);
    return out;
  }
  std::string space = file.info.fileColorSpace;
  if (toLinear) {
    for (Image& face : file.faces) out.linearised = toLinear(face, file.info, out.file);
    space = file.faces.front().colorSpace;
  }
  lighting::SanitizeReport sanitized;
  lighting::CubeMap cube = cubeMapOf(file, &sanitized);
  if (sanitized.negativeTexels > 0) out.notes.push_back(sanitized.negativeNote("cube "));
  const lighting::Environment env = lighting::latLongFromCube(cube, 4 * cube.size(), progress);
  out.image = Image(env.width(), env.height(), 3, {"R", "G", "B"});
  out.image.colorSpace = space;
  out.image.pixels.assign(env.texels().begin(), env.texels().end());
  out.notes.push_back("environment: " + file.describe() + " (" + file.how +
                      "), resampled exactly to a " + std::to_string(env.width()) + "x" +
                      std::to_string(env.height()) + " lat-long map");
  return out;
}

void writeExr(const fs::path& path, const Image& rgb, bool useHalf, std::optional<Layout> envmap,
              const std::optional<std::array<double, 8>>& chromaticities,
              const std::string& compression,
              const std::vector<std::pair<std::string, std::string>>& strings) {
  COMPOSE_CHECK(rgb.channels == 3 && rgb.width > 0 && rgb.height > 0);
  std::string why;
  const std::optional<ingest::ExrCompression> codec =
      ingest::parseExrCompression(compression, &why);
  if (!codec) throw Error("output", why, path);
  try {
    Imf::Header header(rgb.width, rgb.height);
    codec->apply(header);
    const Imf::PixelType type = useHalf ? Imf::HALF : Imf::FLOAT;
    for (const char* name : {"R", "G", "B"}) header.channels().insert(name, Imf::Channel(type));
    if (envmap) {
      COMPOSE_CHECK(*envmap == Layout::LatLong || *envmap == Layout::Cube);
      Imf::addEnvmap(header, *envmap == Layout::Cube ? Imf::ENVMAP_CUBE : Imf::ENVMAP_LATLONG);
    }
    header.insert("software", Imf::StringAttribute("compose"));
    for (const auto& [name, value] : strings) header.insert(name, Imf::StringAttribute(value));
    if (!rgb.colorSpace.empty()) header.insert("colorSpace", Imf::StringAttribute(rgb.colorSpace));
    if (chromaticities) {
      const auto& c = *chromaticities;
      auto xy = [&](int i) {
        return IMATH_NAMESPACE::V2f(float(c[size_t(2 * i)]), float(c[size_t(2 * i + 1)]));
      };
      Imf::addChromaticities(header, Imf::Chromaticities(xy(0), xy(1), xy(2), xy(3)));
    }
    Imf::OutputFile out(path.c_str(), header);
    Imf::FrameBuffer frame;
    std::vector<Imath::half> halves;
    const size_t w = size_t(rgb.width);
    if (useHalf) {
      halves.resize(rgb.pixels.size());
      for (size_t i = 0; i < halves.size(); ++i) halves[i] = Imath::half(rgb.pixels[i]);
      for (int c = 0; c < 3; ++c) {
        frame.insert(c == 0   ? "R"
                     : c == 1 ? "G"
                              : "B",
                     Imf::Slice(Imf::HALF, reinterpret_cast<char*>(halves.data() + c),
                                3 * sizeof(Imath::half), 3 * sizeof(Imath::half) * w));
      }
    } else {
      for (int c = 0; c < 3; ++c) {
        frame.insert(c == 0   ? "R"
                     : c == 1 ? "G"
                              : "B",
                     Imf::Slice(Imf::FLOAT,
                                reinterpret_cast<char*>(const_cast<float*>(rgb.pixels.data() + c)),
                                3 * sizeof(float), 3 * sizeof(float) * w));
      }
    }
    out.setFrameBuffer(frame);
    out.writePixels(rgb.height);
  } catch (const std::exception& e) {
    throw Error("output", std::string("cannot write the EXR: ") + e.what(), path);
  }
}

std::vector<std::string> writeLatLong(OutputFiles& outputs, const fs::path& path,
                                      const lighting::Environment& env,
                                      const WriteOptions& options) {
  std::vector<std::string> notes;
  Image img(env.width(), env.height(), 3, {"R", "G", "B"});
  img.colorSpace = env.colorSpace();
  img.pixels.assign(env.texels().begin(), env.texels().end());
  const bool half = chooseHalf(options.depth, maxValue(img.pixels), path, notes);
  Clamped clamped;
  writeAny(outputs.add(path), path, img, half, Layout::LatLong, options, notes, clamped);
  clamped.note(path, img.colorSpace, notes);
  return notes;
}

std::array<fs::path, kCubeFaces> facePaths(const fs::path& path, int faceNaming) {
  std::array<fs::path, kCubeFaces> out;
  const std::string text = path.string();
  const size_t at = text.find('%');
  if (at != std::string::npos && text.find('%', at + 1) != std::string::npos)
    throw Error("output", "a face pattern holds one '%' (it stands for px, nx, ...)", path);
  for (int f = 0; f < kCubeFaces; ++f) {
    const std::string token = faceNameIn(faceNaming, f, "px");
    if (at != std::string::npos) {
      out[size_t(f)] = text.substr(0, at) + token + text.substr(at + 1);
    } else if (!text.empty() && (text.back() == '/' || fs::is_directory(path))) {
      // A folder: the faces in it by their names alone, as OpenEXR.
      out[size_t(f)] = path / (token + ".exr");
    } else {
      // A base name without an extension gets OpenEXR's, as the HDR default.
      const std::string extension =
          path.extension().empty() ? std::string(".exr") : path.extension().string();
      fs::path p = path;
      p.replace_filename(path.stem().string() + "_" + token + extension);
      out[size_t(f)] = p;
    }
  }
  return out;
}

std::vector<std::string> writeCubeMap(OutputFiles& outputs, const fs::path& path,
                                      const lighting::CubeMap& cube, Layout layout,
                                      const WriteOptions& options) {
  std::vector<std::string> notes;
  float maximum = 0.0f;
  for (int f = 0; f < kCubeFaces; ++f) maximum = std::max(maximum, maxValue(cube.face(f)));
  if (layout == Layout::Faces) {
    const auto paths = facePaths(path, options.faceNaming);
    const bool half = chooseHalf(options.depth, maximum, paths[0], notes);
    Clamped clamped;
    for (int f = 0; f < kCubeFaces; ++f) {
      writeAny(outputs.add(paths[size_t(f)]), paths[size_t(f)], cube.faceImage(f), half,
               std::nullopt, options, notes, clamped);
    }
    clamped.note(paths[0], cube.colorSpace, notes);
    return notes;
  }
  COMPOSE_CHECK(layout == Layout::Cube || layout == Layout::HorizontalCross ||
                layout == Layout::VerticalCross);
  const bool half = chooseHalf(options.depth, maximum, path, notes);
  const Image packed = packFaces(cube, layout);
  Clamped clamped;
  writeAny(outputs.add(path), path, packed, half,
           layout == Layout::Cube ? std::optional<Layout>(Layout::Cube) : std::nullopt, options,
           notes, clamped);
  clamped.note(path, cube.colorSpace, notes);
  return notes;
}

}  // namespace compose::cubemap
