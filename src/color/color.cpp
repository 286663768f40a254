#include "color/color.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <utility>

#include <OpenColorIO/OpenColorIO.h>
#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>
#include <glm/matrix.hpp>

#include "color/builtin_config.h"
#include "color/separable_table.h"
#include "core/error.h"
#include "core/hash.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace OCIO = OCIO_NAMESPACE;

namespace compose::color {

struct ColorConfig::Impl {
  OCIO::ConstConfigRcPtr config;
  std::string source;
  // The config's sRGB-encoded colour space, found on first use (srgbEncodedSpace()).
  struct Found {
    std::once_flag once;
    std::string name;
  };
  std::shared_ptr<Found> srgb = std::make_shared<Found>();
  // identity(), made on first use.
  struct Identity {
    std::once_flag once;
    std::string value;
  };
  std::shared_ptr<Identity> identity = std::make_shared<Identity>();
};

namespace {

ColorConfig::Impl load(const std::string& source,
                       const std::function<OCIO::ConstConfigRcPtr()>& make,
                       const std::filesystem::path& file) {
  try {
    ColorConfig::Impl impl{make(), source};
    impl.config->validate();
    return impl;
  } catch (const OCIO::Exception& e) {
    throw Error("color", std::string("cannot load OpenColorIO config: ") + e.what(), file);
  }
}

std::string listSpaces(const OCIO::ConstConfigRcPtr& config) {
  std::string s;
  for (int i = 0; i < config->getNumColorSpaces(); ++i) {
    if (i) s += ", ";
    s += config->getColorSpaceNameByIndex(i);
  }
  return s;
}

// Applies `processor` to the first three channels of every pixel, rows in parallel.
void applyRgb(const OCIO::ConstProcessorRcPtr& processor, Image& image) {
  COMPOSE_CHECK(image.channels >= 3);
  OCIO::ConstCPUProcessorRcPtr cpu =
      processor->getOptimizedCPUProcessor(OCIO::OPTIMIZATION_LOSSLESS);
  const auto pixelStride = ptrdiff_t(sizeof(float)) * image.channels;
  constexpr int kRowsPerTask = 16;
  const int tasks = (image.height + kRowsPerTask - 1) / kRowsPerTask;
  parallelFor(0, tasks, [&](int64_t t) {
    const int y0 = int(t) * kRowsPerTask;
    const int rows = std::min(kRowsPerTask, image.height - y0);
    OCIO::PackedImageDesc desc(image.row(y0).data(), image.width, rows, OCIO::CHANNEL_ORDERING_RGB,
                               OCIO::BIT_DEPTH_F32, ptrdiff_t(sizeof(float)), pixelStride,
                               pixelStride * image.width);
    cpu->apply(desc);
  });
}

// --- display transforms by table -----------------------------------------------------------------

// A display image is quantised to 8 bits (or 16): the table may differ from OpenColorIO by at most
// a two-hundredth of an 8-bit step.
constexpr double kDisplayTableTolerance = 2e-5;
// Building the table evaluates the transform at about 127,000 values: not worth it for less.
constexpr int64_t kDisplayTableMinPixels = 1 << 18;

// The processor as a matrix and per-channel curves (separable_table.h), when OpenColorIO's
// optimised form of it is leading matrices followed by transforms with no channel crosstalk;
// empty otherwise (then the caller applies the processor itself).
std::optional<SeparableTable> separableTable(const OCIO::ConstConfigRcPtr& config,
                                             const OCIO::ConstProcessorRcPtr& processor) {
  const OCIO::GroupTransformRcPtr group = processor->createGroupTransform();
  glm::dmat4 matrix(1.0);  // homogeneous: the offset in the last column
  int first = 0;
  for (; first < group->getNumTransforms(); ++first) {
    const auto step = OCIO::DynamicPtrCast<const OCIO::MatrixTransform>(group->getTransform(first));
    if (!step) break;
    double m[16], offset[4];
    step->getMatrix(m);
    step->getOffset(offset);
    if (m[3] != 0.0 || m[7] != 0.0 || m[11] != 0.0) return std::nullopt;  // RGB reads alpha
    glm::dmat4 h(1.0);  // glm is column-major: h[column][row]
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) h[c][r] = m[4 * r + c];
      h[3][r] = offset[r];
    }
    if (step->getDirection() == OCIO::TRANSFORM_DIR_INVERSE) h = glm::inverse(h);
    matrix = h * matrix;
  }
  const OCIO::GroupTransformRcPtr rest = OCIO::GroupTransform::Create();
  for (int i = first; i < group->getNumTransforms(); ++i)
    rest->appendTransform(group->getTransform(i)->createEditableCopy());
  const OCIO::ConstProcessorRcPtr curves = config->getProcessor(rest);
  if (curves->hasChannelCrosstalk()) return std::nullopt;
  const OCIO::ConstCPUProcessorRcPtr cpu =
      curves->getOptimizedCPUProcessor(OCIO::OPTIMIZATION_LOSSLESS);
  SeparableTable::Matrix rows;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) rows[size_t(4 * r + c)] = matrix[c][r];
    rows[size_t(4 * r + 3)] = matrix[3][r];
  }
  return SeparableTable::build(
      rows,
      [&](float* rgb, int64_t count) {
        OCIO::PackedImageDesc desc(rgb, long(count), 1, 3);
        cpu->apply(desc);
      },
      kDisplayTableTolerance);
}

// --- linear RGB spaces from chromaticities ------------------------------------------------------

// XYZ of a colour of chromaticity x, y and luminance 1 (y > 0).
glm::dvec3 xyzOfChromaticity(double x, double y) {
  return {x / y, 1.0, (1.0 - x - y) / y};
}

// The primaries' chromaticity coordinates x, y, z = 1 - x - y, as columns: each primary's XYZ up
// to its scale, defined for a primary with y = 0 (CIE XYZ's X and Z) as for any other.
glm::dmat3 primaryColumns(const Chromaticities& c) {
  return glm::dmat3(glm::dvec3(c[0], c[1], 1.0 - c[0] - c[1]),
                    glm::dvec3(c[2], c[3], 1.0 - c[2] - c[3]),
                    glm::dvec3(c[4], c[5], 1.0 - c[4] - c[5]));
}

// RGB → XYZ of a linear RGB space (the normalised primary matrix, SMPTE RP 177): each primary
// scaled so that the three add up to the white at luminance 1.
glm::dmat3 xyzFromRgb(const Chromaticities& c) {
  const glm::dmat3 primaries = primaryColumns(c);
  const glm::dvec3 scale = glm::inverse(primaries) * xyzOfChromaticity(c[6], c[7]);
  return glm::dmat3(primaries[0] * scale[0], primaries[1] * scale[1], primaries[2] * scale[2]);
}

// Bradford chromatic adaptation of XYZ from white `from` to white `to` (xy).
glm::dmat3 bradford(double fromX, double fromY, double toX, double toY) {
  // glm is column-major: these are the rows of the Bradford cone matrix, transposed.
  const glm::dmat3 cone = glm::transpose(
      glm::dmat3(0.8951, 0.2664, -0.1614, -0.7502, 1.7135, 0.0367, 0.0389, -0.0685, 1.0296));
  const glm::dvec3 s = cone * xyzOfChromaticity(fromX, fromY);
  const glm::dvec3 d = cone * xyzOfChromaticity(toX, toY);
  glm::dmat3 gain(1.0);
  for (int i = 0; i < 3; ++i) gain[i][i] = d[i] / s[i];
  return glm::inverse(cone) * gain * cone;
}

// XYZ → xy chromaticities of the columns and of the white (sum of columns) of an RGB → XYZ
// matrix.
Chromaticities chromaticitiesOf(const glm::dmat3& m) {
  Chromaticities c{};
  auto xy = [](const glm::dvec3& v, double* out) {
    const double sum = v.x + v.y + v.z;
    out[0] = v.x / sum;
    out[1] = v.y / sum;
  };
  for (int i = 0; i < 3; ++i) xy(m[i], &c[size_t(2 * i)]);
  xy(m[0] + m[1] + m[2], &c[6]);
  return c;
}

double maxDifference(const glm::dmat3& a, const glm::dmat3& b) {
  double d = 0.0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) d = std::max(d, std::abs(a[i][j] - b[i][j]));
  return d;
}

constexpr Chromaticities kP3D65 = {0.680, 0.320, 0.265, 0.690, 0.150, 0.060, 0.3127, 0.3290};
constexpr Chromaticities kRec2020 = {0.708, 0.292, 0.170, 0.797, 0.131, 0.046, 0.3127, 0.3290};
constexpr Chromaticities kAdobeRgb = {0.64, 0.33, 0.21, 0.71, 0.15, 0.06, 0.3127, 0.3290};
// CIE XYZ as RGB: its primaries are the XYZ axes, and (1, 1, 1) is the equal-energy white E, so
// that the matrix OpenEXR makes of them is the identity.
constexpr Chromaticities kXyzChromaticities = {1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0 / 3.0, 1.0 / 3.0};

// Linear spaces by the names configs give them (the built-in config, OCIO v1's nuke-default and
// ACES 1.x, Blender's, OCIO v2's studio configs), for configs with no interchange role.
const std::vector<std::pair<const Chromaticities*, std::vector<const char*>>> kNamedLinearSpaces = {
    {&kRec709Chromaticities,
     {"Linear Rec.709 (sRGB)", "lin_rec709", "Linear Rec.709", "Utility - Linear - sRGB",
      "lin_srgb", "linear", "Linear"}},
    {&kAcesAp1Chromaticities, {"ACEScg", "ACES - ACEScg", "lin_ap1"}},
    {&kAcesAp0Chromaticities, {"ACES2065-1", "ACES - ACES2065-1", "lin_ap0"}},
    {&kP3D65, {"Linear P3-D65", "lin_p3d65", "Utility - Linear - P3-D65"}},
    {&kRec2020, {"Linear Rec.2020", "lin_rec2020", "Utility - Linear - Rec.2020"}}};

}  // namespace

std::string chromaticitiesProblem(const Chromaticities& c) {
  if (!std::all_of(c.begin(), c.end(), [](double v) { return std::isfinite(v); }))
    return "a value is not a finite number";
  if (!(c[7] > 0.0)) return "the white's y is not positive";
  // Primaries on one line span no space; a white on the line through two primaries needs none
  // of the third, and the matrix is singular just the same.
  if (!(std::abs(glm::determinant(primaryColumns(c))) > 1e-6))
    return "the three primaries lie on one line";
  if (!(std::abs(glm::determinant(xyzFromRgb(c))) > 1e-9))
    return "the white lies on the line through two primaries";
  return {};
}

void requireRgbSpace(const Chromaticities& c, const std::filesystem::path& file) {
  const std::string why = chromaticitiesProblem(c);
  if (why.empty()) return;
  char given[160];
  std::snprintf(given, sizeof given, "red %.4g,%.4g green %.4g,%.4g blue %.4g,%.4g white %.4g,%.4g",
                c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]);
  throw Error("color",
              "the chromaticities (" + std::string(given) + ") describe no RGB space: " + why,
              file);
}

ColorConfig ColorConfig::builtin() {
  ColorConfig c;
  c.impl_ = std::make_shared<Impl>(load("built-in",
                                        [] {
                                          std::istringstream in(detail::kBuiltinConfig);
                                          return OCIO::Config::CreateFromStream(in);
                                        },
                                        {}));
  return c;
}

ColorConfig ColorConfig::fromFile(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::exists(file, ec))
    throw Error("color", "OpenColorIO config not found", file);
  ColorConfig c;
  c.impl_ = std::make_shared<Impl>(load(
      file.string(), [&] { return OCIO::Config::CreateFromFile(file.string().c_str()); }, file));
  return c;
}

namespace {
std::string& chosenConfig() {
  static std::string file;
  return file;
}
std::string& chosenBy() {
  static std::string by;
  return by;
}
}  // namespace

void ColorConfig::useConfig(const std::string& file, const std::string& namedBy) {
  chosenConfig() = file;
  chosenBy() = namedBy;
}

ColorConfig ColorConfig::fromEnvironment() {
  if (const std::string& chosen = chosenConfig(); !chosen.empty()) {
    if (chosen == "builtin" || chosen == "built-in") return builtin();
    try {
      return fromFile(chosen);
    } catch (const Error& e) {
      throw Error("color", std::string(e.what()) + " (named by " + chosenBy() + ")", e.file());
    }
  }
  const char* env = std::getenv("OCIO");
  if (!(env && *env)) return builtin();
  try {
    return fromFile(env);
  } catch (const Error& e) {
    // Say where the name came from: the user may not know $OCIO is set.
    throw Error("color",
                std::string(e.what()) + " (named by $OCIO; unset it for the built-in config)",
                e.file());
  }
}

const std::string& ColorConfig::source() const {
  return impl_->source;
}

namespace {

// The files the FileTransforms in `t` name (through groups), added to `files`.
void namedFiles(const OCIO::ConstTransformRcPtr& t, std::set<std::string>& files) {
  if (!t) return;
  if (auto file = OCIO::DynamicPtrCast<const OCIO::FileTransform>(t)) {
    if (file->getSrc()) files.insert(file->getSrc());
  } else if (auto group = OCIO::DynamicPtrCast<const OCIO::GroupTransform>(t)) {
    for (int i = 0; i < group->getNumTransforms(); ++i) namedFiles(group->getTransform(i), files);
  }
}

}  // namespace

std::string ColorConfig::identity() const {
  std::call_once(impl_->identity->once, [&] {
    const OCIO::Config& c = *impl_->config;
    std::string id;
    try {
      id = c.getCacheID();
    } catch (const OCIO::Exception&) {
      id = impl_->source;
    }
    // OpenColorIO's cache ID does not change when a LUT the config names is edited: the content
    // of every file its transforms name (as the config's search path finds it) goes in too.
    std::set<std::string> files;
    for (int i = 0; i < c.getNumColorSpaces(OCIO::SEARCH_REFERENCE_SPACE_ALL, OCIO::COLORSPACE_ALL);
         ++i) {
      const OCIO::ConstColorSpaceRcPtr cs = c.getColorSpace(
          c.getColorSpaceNameByIndex(OCIO::SEARCH_REFERENCE_SPACE_ALL, OCIO::COLORSPACE_ALL, i));
      if (!cs) continue;
      namedFiles(cs->getTransform(OCIO::COLORSPACE_DIR_TO_REFERENCE), files);
      namedFiles(cs->getTransform(OCIO::COLORSPACE_DIR_FROM_REFERENCE), files);
    }
    for (int i = 0; i < c.getNumLooks(); ++i) {
      if (const OCIO::ConstLookRcPtr look = c.getLook(c.getLookNameByIndex(i))) {
        namedFiles(look->getTransform(), files);
        namedFiles(look->getInverseTransform(), files);
      }
    }
    for (int i = 0; i < c.getNumViewTransforms(); ++i) {
      if (const OCIO::ConstViewTransformRcPtr v =
              c.getViewTransform(c.getViewTransformNameByIndex(i))) {
        namedFiles(v->getTransform(OCIO::VIEWTRANSFORM_DIR_TO_REFERENCE), files);
        namedFiles(v->getTransform(OCIO::VIEWTRANSFORM_DIR_FROM_REFERENCE), files);
      }
    }
    for (int i = 0; i < c.getNumNamedTransforms(OCIO::NAMEDTRANSFORM_ALL); ++i) {
      if (const OCIO::ConstNamedTransformRcPtr t =
              c.getNamedTransform(c.getNamedTransformNameByIndex(OCIO::NAMEDTRANSFORM_ALL, i))) {
        namedFiles(t->getTransform(OCIO::TRANSFORM_DIR_FORWARD), files);
        namedFiles(t->getTransform(OCIO::TRANSFORM_DIR_INVERSE), files);
      }
    }
    Hash128 h;
    for (const std::string& name : files) {
      h.bytes(name);
      std::string where;
      try {
        where = c.getCurrentContext()->resolveFileLocation(name.c_str());
      } catch (const OCIO::Exception&) {
        continue;  // not found: the name alone (using it fails with OpenColorIO's error)
      }
      h.bytes(where);
      // A regular file's content, read in pieces; past 64 MB (a LUT that large is rare, and
      // reading it on every command would cost seconds) its size and time stamp stand for it.
      std::error_code ec;
      const std::filesystem::file_status status = std::filesystem::status(where, ec);
      if (!std::filesystem::is_regular_file(status)) continue;  // a device: never read
      const uintmax_t size = std::filesystem::file_size(where, ec);
      if (ec || size > (uintmax_t(64) << 20)) {
        h.number(double(size));
        h.number(double(std::filesystem::last_write_time(where, ec).time_since_epoch().count()));
        continue;
      }
      std::ifstream in(where, std::ios::binary);
      std::vector<char> piece(1 << 20);
      while (in) {
        in.read(piece.data(), std::streamsize(piece.size()));
        h.data(piece.data(), size_t(in.gcount()));
      }
    }
    impl_->identity->value = id + " " + h.hex();
  });
  return impl_->identity->value;
}

std::string ColorConfig::workingSpace() const {
  if (!impl_->config->hasRole(OCIO::ROLE_SCENE_LINEAR)) {
    throw Error("color", "the OpenColorIO config (" + impl_->source +
                             ") has no scene_linear role: it names the working space, which "
                             "compose needs");
  }
  return resolve(OCIO::ROLE_SCENE_LINEAR, "the scene_linear role");
}

bool ColorConfig::has(const std::string& name) const {
  return !name.empty() && impl_->config->getColorSpace(name.c_str()) != nullptr;
}

std::string ColorConfig::resolve(const std::string& name, const std::string& what) const {
  OCIO::ConstColorSpaceRcPtr cs =
      name.empty() ? nullptr : impl_->config->getColorSpace(name.c_str());
  if (!cs) {
    throw Error("color", "unknown colour space '" + name + "' for " + what + "; the config (" +
                             impl_->source + ") has: " + listSpaces(impl_->config));
  }
  return cs->getName();
}

bool ColorConfig::isData(const std::string& space) const {
  OCIO::ConstColorSpaceRcPtr cs =
      space.empty() ? nullptr : impl_->config->getColorSpace(space.c_str());
  return cs && cs->isData();
}

bool ColorConfig::isLinearOrData(const std::string& space) const {
  const OCIO::ConstConfigRcPtr& config = impl_->config;
  OCIO::ConstColorSpaceRcPtr cs = space.empty() ? nullptr : config->getColorSpace(space.c_str());
  if (!cs) return false;
  if (cs->isData()) return true;
  try {
    OCIO::ConstCPUProcessorRcPtr cpu =
        config->getProcessor(cs->getName(), OCIO::ROLE_SCENE_LINEAR)->getDefaultCPUProcessor();
    float v[3][3] = {{0.25f, 0.25f, 0.25f}, {0.5f, 0.5f, 0.5f}, {1.0f, 1.0f, 1.0f}};
    for (auto& rgb : v) cpu->applyRGB(rgb);
    for (int c = 0; c < 3; ++c) {
      if (!(std::abs(v[1][c] - 2.0f * v[0][c]) <= 1e-3f * std::abs(v[1][c])) ||
          !(std::abs(v[2][c] - 2.0f * v[1][c]) <= 1e-3f * std::abs(v[2][c])))
        return false;
    }
    return true;
  } catch (const OCIO::Exception&) {
    return false;
  }
}

std::string ColorConfig::srgbEncodedSpace() const {
  std::call_once(impl_->srgb->once, [&] {
    const OCIO::ConstConfigRcPtr& config = impl_->config;
    // Candidates: the roles for display-encoded images, then every space named like sRGB.
    std::vector<std::string> candidates;
    for (const char* role : {"default_byte", OCIO::ROLE_MATTE_PAINT, OCIO::ROLE_TEXTURE_PAINT,
                             OCIO::ROLE_COLOR_PICKING})
      if (config->hasRole(role)) candidates.push_back(role);
    auto lower = [](std::string t) {
      std::transform(t.begin(), t.end(), t.begin(),
                     [](unsigned char c) { return std::tolower(c); });
      return t;
    };
    for (int i = 0; i < config->getNumColorSpaces(); ++i) {
      OCIO::ConstColorSpaceRcPtr cs = config->getColorSpace(config->getColorSpaceNameByIndex(i));
      if (!cs) continue;
      bool named = lower(cs->getName()).find("srgb") != std::string::npos;
      for (size_t a = 0; a < cs->getNumAliases(); ++a)
        named = named || lower(cs->getAlias(a)).find("srgb") != std::string::npos;
      if (named) candidates.push_back(cs->getName());
    }
    // Linear Rec.709, to check the primaries too when the config says which space that is.
    const std::string rec709 = spaceWithChromaticities(kRec709Chromaticities);
    for (const std::string& candidate : candidates) {
      try {
        OCIO::ConstColorSpaceRcPtr cs = config->getColorSpace(candidate.c_str());
        if (!cs || cs->isData()) continue;
        OCIO::ConstCPUProcessorRcPtr cpu =
            config->getProcessor(cs->getName(), OCIO::ROLE_SCENE_LINEAR)->getDefaultCPUProcessor();
        // Greys: the sRGB curve against white (a gamma of 2.2 is 12 % off at code 0.2).
        float white[3] = {1.0f, 1.0f, 1.0f};
        cpu->applyRGB(white);
        bool fits = white[0] > 0.0f && white[1] > 0.0f && white[2] > 0.0f;
        for (const double code : {0.1, 0.2, 0.5, 0.8}) {
          float rgb[3] = {float(code), float(code), float(code)};
          cpu->applyRGB(rgb);
          for (int c = 0; c < 3 && fits; ++c)
            fits = std::abs(rgb[c] / white[c] - srgbDecode(code)) <= 0.01 * srgbDecode(code);
        }
        if (fits && !rec709.empty()) {
          // Colours: decoded, then taken from linear Rec.709.
          OCIO::ConstCPUProcessorRcPtr linear =
              config->getProcessor(rec709.c_str(), OCIO::ROLE_SCENE_LINEAR)
                  ->getDefaultCPUProcessor();
          for (const glm::dvec3 code : {glm::dvec3(1, 0, 0), glm::dvec3(0, 1, 0),
                                        glm::dvec3(0, 0, 1), glm::dvec3(0.5, 0.2, 0.8)}) {
            float a[3] = {float(code.x), float(code.y), float(code.z)};
            float b[3] = {float(srgbDecode(code.x)), float(srgbDecode(code.y)),
                          float(srgbDecode(code.z))};
            cpu->applyRGB(a);
            linear->applyRGB(b);
            for (int c = 0; c < 3 && fits; ++c)
              fits = std::abs(a[c] - b[c]) <= 0.01 * std::max(std::abs(b[c]), 0.01f * white[c]);
          }
        }
        if (fits) {
          impl_->srgb->name = cs->getName();
          return;
        }
      } catch (const OCIO::Exception&) {
      }
    }
  });
  return impl_->srgb->name;
}

InputSpace ColorConfig::inputSpace(const std::filesystem::path& file, const std::string& declared,
                                   bool declaredByConvention, bool integerData,
                                   bool samplesKnown) const {
  InputSpace r;
  // The names an embedded ICC profile's space goes by in other configs (ingest::CaptureInfo).
  std::string known = declared;
  if (!has(known)) {
    static const std::vector<std::pair<std::string, std::vector<std::string>>> kSynonyms = {
        {"Display P3", {"sRGB Encoded P3-D65", "srgb_encoded_p3d65", "Display P3 - Texture"}},
        {"Adobe RGB (1998)", {"Adobe RGB", "AdobeRGB", "adobe_rgb"}},
        {"Linear P3-D65", {"lin_p3d65", "Utility - Linear - P3-D65"}},
        {"Linear Adobe RGB (1998)", {"lin_adobergb", "Utility - Linear - Adobe RGB"}},
        {"Linear Rec.709 (sRGB)",
         {"lin_rec709", "Linear Rec.709", "Linear", "linear", "Utility - Linear - sRGB",
          "lin_srgb"}}};
    for (const auto& [name, others] : kSynonyms)
      if (declared == name)
        for (const std::string& o : others)
          if (known == declared && has(o)) known = o;
    // Linear light on known primaries, by the primaries where the config can tell them.
    if (!has(known) && (declared == "Linear Rec.709 (sRGB)" || declared == "Linear P3-D65")) {
      const std::string byPrimaries =
          spaceWithChromaticities(declared == "Linear P3-D65" ? kP3D65 : kRec709Chromaticities);
      if (!byPrimaries.empty()) known = byPrimaries;
    }
  }
  // The space a format implies (OpenImageIO's 'Linear' for every OpenEXR, 'sRGB' for a JPEG)
  // gives way to a file rule of the config's own for the file: a studio config that reads
  // OpenEXRs as ACEScg means it.
  const OCIO::ConstConfigRcPtr& rules = impl_->config;
  if (declaredByConvention && !rules->filepathOnlyMatchesDefaultRule(file.string().c_str())) {
    const char* byRule = rules->getColorSpaceFromFilepath(file.string().c_str());
    if (byRule && has(byRule)) known.clear();
  }
  if (has(known)) {
    r.space = resolve(known, file.string());
    r.how = declaredByConvention ? "its format's usual space" : "as the file says";
  } else {
    const OCIO::ConstConfigRcPtr& config = impl_->config;
    const std::string path = file.string();
    const char* byRule = config->getColorSpaceFromFilepath(path.c_str());
    const bool onlyDefault = config->filepathOnlyMatchesDefaultRule(path.c_str());
    r.space = byRule && has(byRule) ? resolve(byRule, path)
                                    : resolve(OCIO::ROLE_DEFAULT, "the default role");
    r.how = onlyDefault ? "the config's default rule" : "the config's file rule for it";
    if (!declared.empty() && !declaredByConvention)
      r.how = "the file says '" + declared + "', which the config does not know; " + r.how;
    r.assumed = onlyDefault || (!declared.empty() && !declaredByConvention);
  }
  if (integerData && r.assumed && isLinearOrData(r.space)) {
    // 8- and 16-bit images hold display-encoded values (a linear 16-bit TIFF says so in its
    // header or capture description), as Nuke and Blender read them.
    const std::string srgb = srgbEncodedSpace();
    if (!srgb.empty()) {
      r.how = "an 8- or 16-bit image, taken as sRGB-encoded (" + r.how + " gave '" + r.space +
              "', linear)";
      r.space = srgb;
    } else {
      r.how += "; the config has no sRGB-encoded space for this 8- or 16-bit image";
    }
    r.assumed = true;
  } else if (samplesKnown && !integerData && r.assumed && r.space == srgbEncodedSpace()) {
    // Float samples (a float TIFF, a PFM) are scene-linear, not sRGB codes, as Nuke and Blender
    // read them: a rule meant for 8-bit images would decode them with the sRGB curve. (Only the
    // sRGB-encoded space, whose primaries are Rec.709's, is replaced: a log space such as
    // ACEScct is a float encoding of its own.)
    std::string linear = spaceWithChromaticities(kRec709Chromaticities);
    if (linear.empty()) linear = resolve(OCIO::ROLE_SCENE_LINEAR, "the scene_linear role");
    r.how =
        "float samples, taken as linear (" + r.how + " gave '" + r.space + "', display-encoded)";
    r.space = linear;
  }
  return r;
}

std::string ColorConfig::inputSpaceFor(const std::filesystem::path& file,
                                       const std::string& declared) const {
  std::string ext = file.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  // Integer samples for a JPEG or a PNG, float for OpenEXR, Radiance and PFM; a TIFF may be
  // either, and is left to the rules.
  const bool integer = ext == ".jpg" || ext == ".jpeg" || ext == ".png";
  const bool known = integer || ext == ".exr" || ext == ".hdr" || ext == ".pfm";
  return inputSpace(file, declared, false, integer, known).space;
}

Image ColorConfig::convertCodes(std::span<const uint8_t> codes, int width, int height, int channels,
                                const std::string& from, const std::string& to) const {
  COMPOSE_CHECK(channels >= 3 && width >= 0 && height >= 0);
  COMPOSE_CHECK(codes.size() == size_t(width) * size_t(height) * size_t(channels));
  const std::string src = resolve(from, "an image");
  const std::string dst = resolve(to, "a conversion target");
  Image out = Image::unfilled(width, height, 3, {"R", "G", "B"});
  out.colorSpace = dst;
  try {
    // Lossless, plus the per-channel prefix of the transform as a table of the input's codes.
    const auto flags = OCIO::OptimizationFlags(OCIO::OPTIMIZATION_LOSSLESS |
                                               OCIO::OPTIMIZATION_COMP_SEPARABLE_PREFIX);
    OCIO::ConstCPUProcessorRcPtr cpu =
        impl_->config->getProcessor(src.c_str(), dst.c_str())
            ->getOptimizedCPUProcessor(OCIO::BIT_DEPTH_UINT8, OCIO::BIT_DEPTH_F32, flags);
    constexpr int kRowsPerTask = 16;
    const int tasks = (height + kRowsPerTask - 1) / kRowsPerTask;
    parallelFor(0, tasks, [&](int64_t t) {
      const int y0 = int(t) * kRowsPerTask;
      const int rows = std::min(kRowsPerTask, height - y0);
      // OpenColorIO takes a non-const pointer for the source too; it only reads it.
      uint8_t* in = const_cast<uint8_t*>(codes.data()) + size_t(y0) * size_t(width) * channels;
      OCIO::PackedImageDesc source(in, width, rows, OCIO::CHANNEL_ORDERING_RGB,
                                   OCIO::BIT_DEPTH_UINT8, 1, channels, ptrdiff_t(width) * channels);
      OCIO::PackedImageDesc target(out.row(y0).data(), width, rows, OCIO::CHANNEL_ORDERING_RGB,
                                   OCIO::BIT_DEPTH_F32, ptrdiff_t(sizeof(float)),
                                   ptrdiff_t(3 * sizeof(float)),
                                   ptrdiff_t(3 * sizeof(float)) * width);
      cpu->apply(source, target);
    });
  } catch (const OCIO::Exception& e) {
    throw Error("color", "cannot convert " + src + " to " + dst + ": " + e.what());
  }
  return out;
}

void ColorConfig::convert(Image& image, const std::string& to) const {
  const std::string src = resolve(image.colorSpace, "an image");
  const std::string dst = resolve(to, "a conversion target");
  if (src != dst) {
    try {
      applyRgb(impl_->config->getProcessor(src.c_str(), dst.c_str()), image);
    } catch (const OCIO::Exception& e) {
      throw Error("color", "cannot convert " + src + " to " + dst + ": " + e.what());
    }
  }
  image.colorSpace = dst;
}

glm::dvec3 ColorConfig::lumaWeights(const std::string& space) const {
  if (const std::optional<Chromaticities> c = chromaticities(space)) {
    const glm::dmat3 m = xyzFromRgb(*c);  // columns: the primaries' XYZ
    return {m[0].y, m[1].y, m[2].y};
  }
  double coefs[3];
  impl_->config->getDefaultLumaCoefs(coefs);
  return {coefs[0], coefs[1], coefs[2]};
}

std::optional<Chromaticities> ColorConfig::chromaticities(const std::string& space) const {
  const OCIO::ConstConfigRcPtr& config = impl_->config;
  OCIO::ConstColorSpaceRcPtr cs = space.empty() ? nullptr : config->getColorSpace(space.c_str());
  if (!cs || cs->isData()) return std::nullopt;
  // The interchange space and the white its conversions adapt to.
  std::string interchange;
  glm::dmat3 xyzFromInterchange(1.0);
  double whiteX = 0.0, whiteY = 0.0;
  if (config->hasRole(OCIO::ROLE_INTERCHANGE_SCENE)) {
    interchange = OCIO::ROLE_INTERCHANGE_SCENE;
    xyzFromInterchange = xyzFromRgb(kAcesAp0Chromaticities);
    whiteX = kAcesAp0Chromaticities[6];
    whiteY = kAcesAp0Chromaticities[7];
  } else if (config->hasRole(OCIO::ROLE_INTERCHANGE_DISPLAY)) {
    interchange = OCIO::ROLE_INTERCHANGE_DISPLAY;
    whiteX = 0.3127;
    whiteY = 0.3290;
  } else {
    // A config that says no primaries (OCIO v1: nuke-default, ACES 1.x): the linear spaces by
    // their usual names.
    for (const auto& [primaries, names] : kNamedLinearSpaces)
      for (const char* name : names)
        if (OCIO::ConstColorSpaceRcPtr known = config->getColorSpace(name);
            known && std::string(known->getName()) == cs->getName())
          return *primaries;
    return std::nullopt;
  }
  glm::dmat3 toInterchange(1.0);
  try {
    OCIO::ConstCPUProcessorRcPtr cpu =
        config->getProcessor(cs->getName(), interchange.c_str())->getDefaultCPUProcessor();
    for (int i = 0; i < 3; ++i) {
      float rgb[3] = {0.0f, 0.0f, 0.0f};
      rgb[i] = 1.0f;
      cpu->applyRGB(rgb);
      toInterchange[i] = glm::dvec3(rgb[0], rgb[1], rgb[2]);
    }
    // Linear spaces only: the conversion must scale and add like a matrix.
    float probe[3] = {0.25f, 2.0f, 0.5f};
    cpu->applyRGB(probe);
    const glm::dvec3 expected = toInterchange * glm::dvec3(0.25, 2.0, 0.5);
    for (int i = 0; i < 3; ++i) {
      if (!(std::abs(probe[i] - expected[i]) <= 1e-4 * (1.0 + std::abs(expected[i]))))
        return std::nullopt;
    }
  } catch (const OCIO::Exception&) {
    return std::nullopt;
  }
  const glm::dmat3 xyz = xyzFromInterchange * toInterchange;
  // A well-known set, adapted the way the config adapts (Bradford to the interchange white).
  // Configs publish these matrices to 4-7 digits and differ in how they derive the ACES white
  // (up to 2e-4 here); a different set of primaries differs by more than 1e-2.
  for (const Chromaticities& known : {kRec709Chromaticities, kAcesAp1Chromaticities,
                                      kAcesAp0Chromaticities, kP3D65, kRec2020, kAdobeRgb}) {
    const glm::dmat3 adapted = bradford(known[6], known[7], whiteX, whiteY) * xyzFromRgb(known);
    if (maxDifference(adapted, xyz) < 1e-3) return known;
  }
  // CIE XYZ itself, taken as having the white of D65 (Blender's 'XYZ', cie_xyz_d65), E, D60 (ACES)
  // or D50 (ICC) when the config adapts it to the interchange's white: written as XYZ, not as its
  // adapted primaries.
  for (const auto& [x, y] : {std::pair{0.3127, 0.3290},
                             {1.0 / 3.0, 1.0 / 3.0},
                             {kAcesAp0Chromaticities[6], kAcesAp0Chromaticities[7]},
                             {0.3457, 0.3585}}) {
    if (maxDifference(bradford(x, y, whiteX, whiteY), xyz) < 1e-3) return kXyzChromaticities;
  }
  return chromaticitiesOf(xyz);
}

bool ColorConfig::samePrimaries(const std::string& from, const std::string& to) const {
  Image probe(6, 1, 3, {"R", "G", "B"});
  for (int i = 0; i < 6; ++i) probe.at(i, 0)[i % 3] = i < 3 ? 1.0f : 0.5f;
  probe.colorSpace = from;
  convert(probe, to);
  for (int i = 0; i < 6; ++i) {
    for (int c = 0; c < 3; ++c) {
      const float v = probe.at(i, 0)[c];
      if (!std::isfinite(v) || (c == i % 3 ? !(v > 0.0f) : !(std::abs(v) <= 1e-4f))) return false;
    }
  }
  return true;
}

std::string ColorConfig::linearSpaceWithPrimariesOf(const std::string& space) const {
  const std::string resolved = resolve(space, "a colour space");
  if (isLinearOrData(resolved)) return isData(resolved) ? std::string() : resolved;
  for (const Chromaticities* known : {&kRec709Chromaticities, &kP3D65, &kAdobeRgb, &kRec2020,
                                      &kAcesAp1Chromaticities, &kAcesAp0Chromaticities}) {
    const std::string linear = spaceWithChromaticities(*known);
    if (!linear.empty() && samePrimaries(resolved, linear)) return linear;
  }
  return {};
}

std::string ColorConfig::spaceWithChromaticities(const Chromaticities& c) const {
  const OCIO::ConstConfigRcPtr& config = impl_->config;
  for (int i = 0; i < config->getNumColorSpaces(); ++i) {
    const std::string name = config->getColorSpaceNameByIndex(i);
    const std::optional<Chromaticities> own = chromaticities(name);
    if (!own) continue;
    double d = 0.0;
    for (size_t k = 0; k < c.size(); ++k) d = std::max(d, std::abs(c[k] - (*own)[k]));
    if (d < 1e-3) return name;
  }
  return {};
}

void ColorConfig::convertFromChromaticities(Image& image, const Chromaticities& from,
                                            const std::string& to,
                                            const std::filesystem::path& file) const {
  COMPOSE_CHECK(image.channels >= 3);
  requireRgbSpace(from, file);
  const std::string dst = resolve(to, "a conversion target");
  const std::optional<Chromaticities> target = chromaticities(dst);
  if (!target) {
    throw Error("color", "cannot convert by chromaticities: the config (" + impl_->source +
                             ") does not say what the primaries of '" + dst + "' are");
  }
  const glm::dmat3 m = glm::inverse(xyzFromRgb(*target)) *
                       bradford(from[6], from[7], (*target)[6], (*target)[7]) * xyzFromRgb(from);
  const glm::mat3 mf(m);
  parallelFor(0, image.height, [&](int64_t y) {
    for (float *p = image.row(int(y)).data(), *end = p + size_t(image.width) * image.channels;
         p != end; p += image.channels) {
      const glm::vec3 v = mf * glm::vec3(p[0], p[1], p[2]);
      p[0] = v.x;
      p[1] = v.y;
      p[2] = v.z;
    }
  });
  image.colorSpace = dst;
}

std::string ColorConfig::defaultDisplay() const {
  return impl_->config->getDefaultDisplay();
}

std::string ColorConfig::defaultView(const std::string& display) const {
  return impl_->config->getDefaultView(display.c_str());
}

std::vector<std::string> ColorConfig::displays() const {
  std::vector<std::string> out;
  for (int i = 0; i < impl_->config->getNumDisplays(); ++i)
    out.emplace_back(impl_->config->getDisplay(i));
  return out;
}

std::vector<std::string> ColorConfig::views(const std::string& display) const {
  std::vector<std::string> out;
  for (int i = 0; i < impl_->config->getNumViews(display.c_str()); ++i) {
    out.emplace_back(impl_->config->getView(display.c_str(), i));
  }
  return out;
}

void ColorConfig::checkDisplayView(const std::string& display, const std::string& view) const {
  auto join = [](const std::vector<std::string>& v) {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
    return s;
  };
  const std::vector<std::string> known = displays();
  if (std::find(known.begin(), known.end(), display) == known.end()) {
    throw Error("color", "unknown display '" + display + "'; the config has: " + join(known));
  }
  const std::vector<std::string> knownViews = views(display);
  if (std::find(knownViews.begin(), knownViews.end(), view) == knownViews.end()) {
    throw Error("color", "unknown view '" + view + "' for display '" + display +
                             "'; it has: " + join(knownViews));
  }
}

Image ColorConfig::toDisplay(const Image& image, const std::string& display,
                             const std::string& view) const {
  // The copy is made on every core, which then first touch its pages.
  Image copy = Image::unfilled(image.width, image.height, image.channels, image.channelNames);
  copy.colorSpace = image.colorSpace;
  parallelFor(0, image.height, [&](int64_t y) {
    const std::span<const float> from = image.row(int(y));
    std::copy(from.begin(), from.end(), copy.row(int(y)).begin());
  });
  return toDisplay(std::move(copy), display, view);
}

Image ColorConfig::toDisplay(Image&& image, const std::string& display,
                             const std::string& view) const {
  checkDisplayView(display, view);
  Image out = std::move(image);
  try {
    OCIO::DisplayViewTransformRcPtr t = OCIO::DisplayViewTransform::Create();
    t->setSrc(resolve(out.colorSpace, "an image").c_str());
    t->setDisplay(display.c_str());
    t->setView(view.c_str());
    const OCIO::ConstProcessorRcPtr processor = impl_->config->getProcessor(t);
    std::optional<SeparableTable> table;
    if (int64_t(out.width) * out.height >= kDisplayTableMinPixels) {
      try {
        table = separableTable(impl_->config, processor);
      } catch (const OCIO::Exception&) {
        table.reset();  // a transform OpenColorIO cannot take apart: it is applied whole
      }
    }
    if (table) {
      const OCIO::ConstCPUProcessorRcPtr cpu =
          processor->getOptimizedCPUProcessor(OCIO::OPTIMIZATION_LOSSLESS);
      table->apply(out, [&](float* rgb) { cpu->applyRGB(rgb); });
    } else {
      applyRgb(processor, out);
    }
  } catch (const OCIO::Exception& e) {
    throw Error("color",
                "cannot apply display transform " + display + "/" + view + ": " + e.what());
  }
  out.colorSpace = display + "/" + view;
  return out;
}

InputSpace photoInputSpace(const ColorConfig& colors, const std::filesystem::path& file,
                           const std::string& declared, bool declaredByConvention, bool integerData,
                           const std::string& iccProfile, bool exifUncalibrated) {
  InputSpace s = colors.inputSpace(file, declared, declaredByConvention, integerData);
  if (!iccProfile.empty() && s.how == "as the file says")
    s.how = "by its ICC profile '" + iccProfile + "'";
  if (exifUncalibrated) {
    s.how +=
        "; its EXIF says the colour space is uncalibrated (65535), as cameras set to Adobe "
        "RGB write: give the space (such as 'Adobe RGB (1998)') if it is not this one";
    s.assumed = true;
  }
  return s;
}

}  // namespace compose::color
