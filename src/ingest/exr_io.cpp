#include "ingest/exr_io.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <mutex>
#include <optional>

#include <OpenEXR/ImfBoxAttribute.h>
#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfChromaticitiesAttribute.h>
#include <OpenEXR/ImfDoubleAttribute.h>
#include <OpenEXR/ImfFloatAttribute.h>
#include <OpenEXR/ImfFloatVectorAttribute.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfInputPart.h>
#include <OpenEXR/ImfIntAttribute.h>
#include <OpenEXR/ImfMatrixAttribute.h>
#include <OpenEXR/ImfMultiPartInputFile.h>
#include <OpenEXR/ImfMultiPartOutputFile.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfOutputPart.h>
#include <OpenEXR/ImfPartType.h>
#include <OpenEXR/ImfStringAttribute.h>
#include <OpenEXR/ImfStringVectorAttribute.h>
#include <OpenEXR/ImfThreading.h>
#include <OpenEXR/ImfVecAttribute.h>
#include <tbb/task_arena.h>

#include "core/error.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "ingest/pixel_util.h"

namespace compose::ingest {

namespace fs = std::filesystem;

namespace {

// OpenEXR's thread pool gets every core oneTBB may use, once.
void useEveryCoreForExr() {
  static std::once_flag once;
  std::call_once(once, [] { Imf::setGlobalThreadCount(tbb::this_task_arena::max_concurrency()); });
}

bool equalsIgnoringCase(const std::string& a, const std::string& b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char p, char q) {
           return std::tolower(static_cast<unsigned char>(p)) ==
                  std::tolower(static_cast<unsigned char>(q));
         });
}

// OpenEXR's standard attribute names and OpenImageIO's for the same thing (both ways), as
// OpenImageIO 2.4 translates them.
struct NamePair {
  const char* exr;
  const char* oiio;
};
constexpr NamePair kRenamed[] = {{"capDate", "DateTime"},
                                 {"comments", "ImageDescription"},
                                 {"owner", "Copyright"},
                                 {"pixelAspectRatio", "PixelAspectRatio"},
                                 {"xDensity", "XResolution"},
                                 {"expTime", "ExposureTime"},
                                 {"aperture", "FNumber"},
                                 {"chunkCount", "openexr:chunkCount"},
                                 {"dwaCompressionLevel", "openexr:dwaCompressionLevel"},
                                 {"maxSamplesPerPixel", "openexr:maxSamplesPerPixel"}};
// Header fields that are part of the image's layout, not metadata.
constexpr const char* kLayout[] = {"channels",      "compression", "dataWindow",
                                   "displayWindow", "envmap",      "tiles",
                                   "type",          "lineOrder",   "version"};

std::string oiioName(const std::string& exrName) {
  if (exrName == "cameraTransform") return "worldtocamera";
  for (const NamePair& p : kRenamed)
    if (exrName == p.exr) return p.oiio;
  return exrName;
}

// The OpenEXR name an attribute is written under; empty: not written.
std::string exrName(const std::string& name) {
  // OpenImageIO's report of a file's layout ("openexr:chunkCount") is not metadata to write back.
  if (name.size() > 8 && equalsIgnoringCase(name.substr(0, 8), "openexr:")) return {};
  for (const NamePair& p : kRenamed)
    if (equalsIgnoringCase(name, p.oiio) || equalsIgnoringCase(name, p.exr)) return p.exr;
  if (equalsIgnoringCase(name, "worldtocamera")) return "worldToCamera";
  if (equalsIgnoringCase(name, "worldtoNDC")) return "worldToNDC";
  if (equalsIgnoringCase(name, "worldtoscreen")) return "worldToScreen";
  if (equalsIgnoringCase(name, "YResolution") || name.rfind("oiio:", 0) == 0) return {};
  for (const char* layout : kLayout)
    if (equalsIgnoringCase(name, layout)) return {};
  // Metadata meant for another format ("jpeg:subsampling", "tiff:Compression") is not written.
  for (const char* other : {"jpeg:", "tiff:", "png:", "raw:", "openexr:"})
    if (name.size() > std::strlen(other) &&
        equalsIgnoringCase(name.substr(0, std::strlen(other)), other))
      return {};
  return name;
}

template <class V>
std::vector<float> floats(const V* values, size_t n) {
  std::vector<float> out(n);
  for (size_t i = 0; i < n; ++i) out[i] = float(values[i]);
  return out;
}

// The header's metadata as OpenImageIO names and types it (see exr_io.h).
std::vector<ImageAttribute> attributesOf(const Imf::Header& header) {
  std::vector<ImageAttribute> out;
  for (auto it = header.begin(); it != header.end(); ++it) {
    const std::string name = it.name();
    if (std::find_if(std::begin(kLayout), std::end(kLayout),
                     [&](const char* l) { return name == l; }) != std::end(kLayout))
      continue;
    const std::string as = oiioName(name);
    const Imf::Attribute& a = it.attribute();
    if (const auto* s = dynamic_cast<const Imf::StringAttribute*>(&a)) {
      if (!s->value().empty()) out.push_back({as, s->value()});
    } else if (const auto* i = dynamic_cast<const Imf::IntAttribute*>(&a)) {
      out.push_back({as, i->value()});
    } else if (const auto* f = dynamic_cast<const Imf::FloatAttribute*>(&a)) {
      out.push_back({as, double(f->value())});
    } else if (const auto* d = dynamic_cast<const Imf::DoubleAttribute*>(&a)) {
      out.push_back({as, d->value()});
    } else if (const auto* c = dynamic_cast<const Imf::ChromaticitiesAttribute*>(&a)) {
      const Imf::Chromaticities& v = c->value();
      out.push_back({as, std::vector<float>{v.red.x, v.red.y, v.green.x, v.green.y, v.blue.x,
                                            v.blue.y, v.white.x, v.white.y}});
    } else if (const auto* m = dynamic_cast<const Imf::M44fAttribute*>(&a)) {
      out.push_back({as, floats(&m->value()[0][0], 16)});
    } else if (const auto* m3 = dynamic_cast<const Imf::M33fAttribute*>(&a)) {
      out.push_back({as, floats(&m3->value()[0][0], 9)});
    } else if (const auto* md = dynamic_cast<const Imf::M44dAttribute*>(&a)) {
      out.push_back({as, floats(&md->value()[0][0], 16)});
    } else if (const auto* v2 = dynamic_cast<const Imf::V2fAttribute*>(&a)) {
      out.push_back({as, std::vector<float>{v2->value().x, v2->value().y}});
    } else if (const auto* v3 = dynamic_cast<const Imf::V3fAttribute*>(&a)) {
      out.push_back({as, std::vector<float>{v3->value().x, v3->value().y, v3->value().z}});
    } else if (const auto* v2i = dynamic_cast<const Imf::V2iAttribute*>(&a)) {
      out.push_back({as, std::vector<float>{float(v2i->value().x), float(v2i->value().y)}});
    } else if (const auto* fv = dynamic_cast<const Imf::FloatVectorAttribute*>(&a)) {
      out.push_back({as, fv->value()});
    } else if (const auto* b = dynamic_cast<const Imf::Box2iAttribute*>(&a)) {
      const auto& box = b->value();
      out.push_back({as, std::vector<float>{float(box.min.x), float(box.min.y), float(box.max.x),
                                            float(box.max.y)}});
    }
    // Other types (preview images, key and time codes, opaque attributes) are not metadata the
    // pipeline reads.
  }
  out.push_back({"oiio:ColorSpace", std::string("Linear")});
  return out;
}

// OpenImageIO's channel order (exr_io.h): by layer, then the special names first.
std::vector<std::string> channelOrder(const Imf::ChannelList& channels) {
  struct Named {
    std::string full, layer, suffix;
    int special = 10000;
  };
  std::vector<Named> all;
  for (auto it = channels.begin(); it != channels.end(); ++it) {
    Named n;
    n.full = it.name();
    const size_t dot = n.full.rfind('.');
    n.layer = dot == std::string::npos ? std::string() : n.full.substr(0, dot);
    n.suffix = dot == std::string::npos ? n.full : n.full.substr(dot + 1);
    all.push_back(std::move(n));
  }
  std::stable_sort(all.begin(), all.end(),
                   [](const Named& a, const Named& b) { return a.layer < b.layer; });
  static const char* const kSpecial[] = {"R",    "Red",  "G",  "Green", "B",     "Blue", "Y",
                                         "real", "imag", "A",  "Alpha", "AR",    "RA",   "AG",
                                         "GA",   "AB",   "BA", "Z",     "Depth", "Zback"};
  static const char* const kSpecialXyz[] = {"R",  "Red", "G",    "Green", "B",  "Blue",  "X",
                                            "Y",  "Z",   "real", "imag",  "A",  "Alpha", "AR",
                                            "RA", "AG",  "GA",   "AB",    "BA", "Depth", "Zback"};
  for (size_t begin = 0; begin < all.size();) {
    size_t end = begin + 1;
    while (end < all.size() && all[end].layer == all[begin].layer) ++end;
    auto has = [&](const char* suffix) {
      for (size_t i = begin; i < end; ++i)
        if (equalsIgnoringCase(all[i].suffix, suffix)) return true;
      return false;
    };
    const bool xyz = has("X") && (has("Y") || has("Z"));
    for (size_t i = begin; i < end; ++i) {
      const auto& list =
          xyz ? std::vector<const char*>(std::begin(kSpecialXyz), std::end(kSpecialXyz))
              : std::vector<const char*>(std::begin(kSpecial), std::end(kSpecial));
      for (size_t k = 0; k < list.size(); ++k) {
        if (equalsIgnoringCase(all[i].suffix, list[k])) {
          all[i].special = int(k);
          break;
        }
      }
    }
    std::sort(all.begin() + std::ptrdiff_t(begin), all.begin() + std::ptrdiff_t(end),
              [](const Named& a, const Named& b) {
                if (a.special != b.special) return a.special < b.special;
                return a.suffix < b.suffix;
              });
    begin = end;
  }
  std::vector<std::string> names;
  for (Named& n : all) names.push_back(std::move(n.full));
  return names;
}

const char* typeName(Imf::PixelType type) {
  switch (type) {
    case Imf::HALF:
      return "half";
    case Imf::FLOAT:
      return "float";
    case Imf::UINT:
      return "uint";
    default:
      return "unknown";
  }
}

}  // namespace

std::vector<std::string> defaultChannelNames(int channels) {
  if (channels == 1) return {"Y"};
  std::vector<std::string> names;
  for (int c = 0; c < channels; ++c)
    names.push_back(c < 4 ? std::string(1, "RGBA"[c]) : "channel" + std::to_string(c));
  return names;
}

bool hasExrMagic(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  unsigned char magic[4] = {0, 0, 0, 0};
  if (!in.read(reinterpret_cast<char*>(magic), 4)) return false;
  return magic[0] == 0x76 && magic[1] == 0x2f && magic[2] == 0x31 && magic[3] == 0x01;
}

const ImageAttribute* ExrPartHeader::find(const std::string& attributeName) const {
  for (const ImageAttribute& a : attributes)
    if (equalsIgnoringCase(a.name, attributeName)) return &a;
  return nullptr;
}

struct ExrReader::Impl {
  fs::path file;
  std::string stage;
  std::unique_ptr<Imf::MultiPartInputFile> input;
  std::vector<ExrPartHeader> headers;
};

ExrReader::ExrReader(const fs::path& file, const std::string& stage)
    : impl_(std::make_unique<Impl>()) {
  protectInput(file);
  impl_->file = file;
  impl_->stage = stage;
  useEveryCoreForExr();
  try {
    // The chunk table is taken as the file has it: a damaged table is an error when the pixels
    // are read, not a picture with missing rows filled in.
    impl_->input =
        std::make_unique<Imf::MultiPartInputFile>(file.c_str(), Imf::globalThreadCount(), false);
    for (int p = 0; p < impl_->input->parts(); ++p) {
      const Imf::Header& h = impl_->input->header(p);
      ExrPartHeader out;
      if (h.hasName()) out.name = h.name();
      const Imath::Box2i& dw = h.dataWindow();
      const Imath::Box2i& display = h.displayWindow();
      const int64_t w = int64_t(dw.max.x) - dw.min.x + 1, hgt = int64_t(dw.max.y) - dw.min.y + 1;
      const int64_t fw = int64_t(display.max.x) - display.min.x + 1;
      const int64_t fh = int64_t(display.max.y) - display.min.y + 1;
      if (w <= 0 || hgt <= 0 || w > INT32_MAX || hgt > INT32_MAX || fw <= 0 || fh <= 0 ||
          fw > INT32_MAX || fh > INT32_MAX)
        throw Error(stage, "image has no pixels (its data or display window is empty)", file);
      const int64_t dx = int64_t(dw.min.x) - display.min.x, dy = int64_t(dw.min.y) - display.min.y;
      if (dx < INT32_MIN || dx > INT32_MAX || dy < INT32_MIN || dy > INT32_MAX)
        throw Error(stage, "its data window lies too far from its display window", file);
      out.x = int(dx);
      out.y = int(dy);
      out.width = int(w);
      out.height = int(hgt);
      out.fullWidth = int(fw);
      out.fullHeight = int(fh);
      out.channelNames = channelOrder(h.channels());
      if (out.channelNames.empty()) throw Error(stage, "image has no channels", file);
      // As OpenImageIO merges the channels' types: one type if they share it, else float.
      bool allHalf = true, allUint = true;
      for (auto it = h.channels().begin(); it != h.channels().end(); ++it) {
        allHalf = allHalf && it.channel().type == Imf::HALF;
        allUint = allUint && it.channel().type == Imf::UINT;
      }
      out.sampleType = typeName(allHalf ? Imf::HALF : allUint ? Imf::UINT : Imf::FLOAT);
      out.tiled = h.hasTileDescription();
      out.attributes = attributesOf(h);
      impl_->headers.push_back(std::move(out));
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(stage, std::string("cannot read image: ") + e.what(), file);
  }
  if (impl_->headers.empty()) throw Error(stage, "image has no parts", file);
}

ExrReader::~ExrReader() = default;

int ExrReader::parts() const {
  return int(impl_->headers.size());
}

const ExrPartHeader& ExrReader::header(int part) const {
  COMPOSE_CHECK(part >= 0 && part < parts());
  return impl_->headers[size_t(part)];
}

Image ExrReader::read(int part) const {
  const ExrPartHeader& h = header(part);
  const fs::path& file = impl_->file;
  const std::string& stage = impl_->stage;
  const int channels = int(h.channelNames.size());
  checkImageSize(h.width, h.height, channels, stage, file);
  Image image = Image::unfilled(h.width, h.height, channels, h.channelNames);
  try {
    const Imf::Header& header = impl_->input->header(part);
    if (Imf::isDeepData(header.type()))
      throw Error(stage, "deep OpenEXR images are not supported", file);
    for (auto it = header.channels().begin(); it != header.channels().end(); ++it) {
      if (it.channel().xSampling != 1 || it.channel().ySampling != 1)
        throw Error(
            stage,
            std::string("subsampled channels are not supported (channel \"") + it.name() + "\")",
            file);
    }
    Imf::InputPart input(*impl_->input, part);
    Imf::FrameBuffer frame;
    const size_t xStride = sizeof(float) * size_t(channels);
    for (int c = 0; c < channels; ++c) {
      frame.insert(h.channelNames[size_t(c)],
                   Imf::Slice::Make(Imf::FLOAT, image.pixels.data() + c, header.dataWindow(),
                                    xStride, xStride * size_t(h.width)));
    }
    input.setFrameBuffer(frame);
    input.readPixels(header.dataWindow().min.y, header.dataWindow().max.y);
    // OpenImageIO converts integer channels to float normalised to their range (a uint of
    // 2^32 - 1 is 1.0); OpenEXR gives the integer's value.
    for (int c = 0; c < channels; ++c) {
      const Imf::Channel* channel = header.channels().findChannel(h.channelNames[size_t(c)]);
      if (!channel || channel->type != Imf::UINT) continue;
      const float scale = float(1.0 / 4294967295.0);
      for (size_t i = size_t(c); i < image.pixels.size(); i += size_t(channels))
        image.pixels[i] *= scale;
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(stage, std::string("cannot decode image: ") + e.what(), file);
  }
  return image;
}

const char* const kExrCompressionNames =
    "none, rle, zips, zip, piz, pxr24, b44, b44a, dwaa, dwab (zip:0..9, zips:0..9, dwaa:LEVEL, "
    "dwab:LEVEL)";

namespace {

const std::map<std::string, Imf::Compression>& compressionsByName() {
  static const std::map<std::string, Imf::Compression> names = {
      {"none", Imf::NO_COMPRESSION},   {"rle", Imf::RLE_COMPRESSION},
      {"zips", Imf::ZIPS_COMPRESSION}, {"zip", Imf::ZIP_COMPRESSION},
      {"piz", Imf::PIZ_COMPRESSION},   {"pxr24", Imf::PXR24_COMPRESSION},
      {"b44", Imf::B44_COMPRESSION},   {"b44a", Imf::B44A_COMPRESSION},
      {"dwaa", Imf::DWAA_COMPRESSION}, {"dwab", Imf::DWAB_COMPRESSION}};
  return names;
}

// A finite decimal number written plainly ("45", "4.5", "1e2"), or nothing: "4x", "", " 4",
// "+4", "0x2D", "nan" are nothing. Independent of the locale.
std::optional<double> strictNumber(const std::string& text) {
  double v = 0.0;
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, v);
  if (text.empty() || ec != std::errc() || ptr != end || !std::isfinite(v)) return std::nullopt;
  return v;
}

}  // namespace

bool ExrCompression::lossy() const {
  return name == "pxr24" || name == "b44" || name == "b44a" || name == "dwaa" || name == "dwab";
}

void ExrCompression::apply(Imf::Header& header) const {
  header.compression() = compressionsByName().at(name);
  if (zipLevel >= 0) header.zipCompressionLevel() = zipLevel;
  if (dwaLevel > 0.0f) header.dwaCompressionLevel() = dwaLevel;
}

std::optional<ExrCompression> parseExrCompression(const std::string& text, std::string* why) {
  const size_t colon = text.find(':');
  ExrCompression out;
  out.name = text.substr(0, colon);
  for (char& c : out.name) c = char(std::tolower(static_cast<unsigned char>(c)));
  if (compressionsByName().count(out.name) == 0) {
    *why = "unknown OpenEXR compression '" + text + "' (known: " + kExrCompressionNames + ")";
    return std::nullopt;
  }
  if (colon == std::string::npos) return out;
  const std::string level = text.substr(colon + 1);
  const bool zip = out.name == "zip" || out.name == "zips";
  const bool dwa = out.name == "dwaa" || out.name == "dwab";
  if (!zip && !dwa) {
    *why = "the OpenEXR compression '" + out.name + "' takes no level, got '" + text + "'";
    return std::nullopt;
  }
  const std::optional<double> value = strictNumber(level);
  if (zip && !(value && *value >= 0.0 && *value <= 9.0 && *value == std::floor(*value))) {
    *why = "the level of '" + out.name + "' must be a whole number 0-9, got '" + level + "'";
    return std::nullopt;
  }
  // As OpenEXR holds it (a float); 45 is its default, larger loses more.
  if (dwa && !(value && float(*value) >= 1e-3f && *value <= 1e6)) {
    *why = "the level of '" + out.name + "' must be a number from 0.001 to 1000000, got '" + level +
           "'";
    return std::nullopt;
  }
  if (zip) out.zipLevel = int(*value);
  if (dwa) out.dwaLevel = float(*value);
  return out;
}

namespace {

// The header of one part: size, windows, channels of their `types` in the file's order, and
// metadata.
Imf::Header headerOf(const ExrPart& part, const detail::ChannelSources& sources,
                     const std::vector<std::string>& names,
                     const std::vector<Imf::PixelType>& types, const ExrHeader& shared,
                     bool multiPart, const fs::path& shown) {
  const Image& image = *part.image;
  const int fullWidth = part.fullWidth > 0 ? part.fullWidth : image.width;
  const int fullHeight = part.fullHeight > 0 ? part.fullHeight : image.height;
  Imf::Header header(
      Imath::Box2i({0, 0}, {fullWidth - 1, fullHeight - 1}),
      Imath::Box2i({part.x, part.y}, {part.x + image.width - 1, part.y + image.height - 1}));
  std::string why;
  const std::optional<ExrCompression> compression =
      parseExrCompression(part.options.exrCompression, &why);
  if (!compression) throw Error("output", why, shown);
  compression->apply(header);
  COMPOSE_CHECK(int(names.size()) == sources.channels());
  for (size_t c = 0; c < names.size(); ++c)
    header.channels().insert(names[c], Imf::Channel(types[c]));
  if (multiPart || !part.name.empty()) {
    header.setName(part.name);
    header.setType(Imf::SCANLINEIMAGE);
  }
  header.insert("Software", Imf::StringAttribute("compose"));
  const std::string colorSpace = part.colorSpace.empty() ? image.colorSpace : part.colorSpace;
  if (!colorSpace.empty()) header.insert("colorSpace", Imf::StringAttribute(colorSpace));
  if (part.options.chromaticities) {
    const auto& c = *part.options.chromaticities;
    auto xy = [&](int i) {
      return Imath::V2f(float(c[size_t(2 * i)]), float(c[size_t(2 * i + 1)]));
    };
    header.insert("chromaticities",
                  Imf::ChromaticitiesAttribute(Imf::Chromaticities(xy(0), xy(1), xy(2), xy(3))));
  }
  // m44f and m44d alike: Imath's rows, as stored.
  auto insertMatrices = [&]<class Matrix, class Attribute>(const auto& matrices) {
    for (const auto& [name, m] : matrices) {
      const std::string as = exrName(name);
      if (as.empty()) continue;
      Matrix matrix;
      std::memcpy(&matrix[0][0], m.data(), sizeof m);
      header.insert(as, Attribute(matrix));
    }
  };
  if (shared.pixelAspectRatio != 1.0f) header.pixelAspectRatio() = shared.pixelAspectRatio;
  insertMatrices.operator()<Imath::M44f, Imf::M44fAttribute>(shared.matrices);
  insertMatrices.operator()<Imath::M44d, Imf::M44dAttribute>(shared.doubleMatrices);
  for (const auto& [name, value] : shared.strings) {
    const std::string as = exrName(name);
    if (!as.empty()) header.insert(as, Imf::StringAttribute(value));
  }
  for (const ImageAttribute& a : part.options.attributes) {
    const std::string as = exrName(a.name);
    if (as.empty()) continue;
    // OpenEXR's standard attributes have fixed types: expTime and aperture are floats.
    const bool floatOnly = as == "expTime" || as == "aperture" || as == "pixelAspectRatio" ||
                           as == "xDensity" || as == "dwaCompressionLevel";
    if (const int* i = std::get_if<int>(&a.value)) {
      if (floatOnly)
        header.insert(as, Imf::FloatAttribute(float(*i)));
      else
        header.insert(as, Imf::IntAttribute(*i));
    } else if (const double* d = std::get_if<double>(&a.value)) {
      header.insert(as, Imf::FloatAttribute(float(*d)));
    } else if (const std::string* t = std::get_if<std::string>(&a.value)) {
      if (!floatOnly) header.insert(as, Imf::StringAttribute(*t));
    } else {
      const auto& v = std::get<std::vector<float>>(a.value);
      if (v.size() == 16) {
        Imath::M44f matrix;
        std::memcpy(&matrix[0][0], v.data(), sizeof(float) * 16);
        header.insert(as, Imf::M44fAttribute(matrix));
      } else if (!v.empty()) {
        header.insert(as, Imf::FloatVectorAttribute(v));
      }
    }
  }
  return header;
}

// Writes the rows of `sources` through `write(firstRow, rows)` after pointing `frame` at a band
// of converted rows: bands of about 8 MB in whole blocks of 16 scanlines (OpenEXR's ZIP block;
// PIZ's is 32), converted on every core, so that no full-size converted copy is held and the
// compressor gets several blocks at once.
template <class SetFrame, class Write>
void writeBands(const detail::ChannelSources& sources, const std::vector<std::string>& names,
                const std::vector<Imf::PixelType>& types, int x0, int y0, SetFrame&& setFrame,
                Write&& write) {
  const int width = sources.width(), height = sources.height();
  const int channels = sources.channels();
  COMPOSE_CHECK(int(types.size()) == channels);
  auto bytesOf = [](Imf::PixelType t) {
    return t == Imf::HALF ? sizeof(Imath::half) : sizeof(float);
  };
  const bool uniform =
      std::all_of(types.begin(), types.end(), [&](Imf::PixelType t) { return t == types.front(); });
  const Imf::PixelType type = types.front();             // when uniform
  std::vector<size_t> offsets(size_t(channels) + 1, 0);  // of each channel in a pixel, in bytes
  for (int c = 0; c < channels; ++c)
    offsets[size_t(c) + 1] = offsets[size_t(c)] + bytesOf(types[size_t(c)]);
  const size_t pixelBytes = offsets.back();
  const size_t rowBytes = pixelBytes * size_t(width);
  // Per image, its channels in runs of one type (the object's colour, normal, position, depth,
  // albedo, ... are five runs of two images): a pixel is put in place run by run.
  struct Run {
    int first = 0, count = 0;  // the image's channels [first, first + count)
    bool half = true;
    size_t offset = 0;  // in the file's pixel, in bytes
  };
  std::vector<std::vector<Run>> runs;
  for (int c = 0; const Image* image : sources.images) {
    std::vector<Run>& r = runs.emplace_back();
    for (int k = 0; k < image->channels; ++k, ++c) {
      const bool half = types[size_t(c)] == Imf::HALF;
      if (!r.empty() && r.back().half == half)
        ++r.back().count;
      else
        r.push_back({k, 1, half, offsets[size_t(c)]});
    }
  }
  // The factors of the scaled images, over a row.
  std::vector<std::vector<float>> rowScales(sources.images.size());
  for (size_t i = 0; i < sources.images.size(); ++i)
    if (const std::vector<float>* scales = sources.scalesOf(i))
      rowScales[i] = detail::rowOfScales(*scales, width);
  constexpr size_t kBandBytes = size_t(8) << 20;
  constexpr int kBlockRows = 32;
  const int bandRows = std::max(kBlockRows, int(kBandBytes / rowBytes) / kBlockRows * kBlockRows);
  std::vector<unsigned char> band(size_t(std::min(bandRows, height)) * rowBytes);
  for (int r0 = 0; r0 < height; r0 += bandRows) {
    const int rows = std::min(bandRows, height - r0);
    parallelFor(0, rows, [&](int64_t r) {
      unsigned char* dst = band.data() + size_t(r) * rowBytes;
      const int y = r0 + int(r);
      if (uniform && sources.images.size() == 1 && sources.constants.empty() &&
          !sources.scalesOf(0)) {
        // One image: its rows are already laid out as the file's pixels.
        const float* row = sources.images.front()->row(y).data();
        const size_t values = size_t(width) * size_t(channels);
        if (type == Imf::HALF) {
          detail::toHalf(row, reinterpret_cast<uint16_t*>(dst), values);
        } else {
          std::memcpy(dst, row, values * sizeof(float));
        }
        return;
      }
      // Otherwise each image's row is converted to halves (scaled first where it is to be), and
      // each run of channels is put in place from the halves or the floats, as its type says.
      thread_local std::vector<uint16_t> halves;
      thread_local std::vector<float> scaled;
      int first = 0;  // the image's first channel
      for (size_t i = 0; i < sources.images.size(); ++i) {
        const Image* image = sources.images[i];
        const float* row = image->row(y).data();
        const int n = image->channels;
        const size_t values = size_t(width) * size_t(n);
        if (!rowScales[i].empty()) {
          scaled.resize(values);
          const float* factor = rowScales[i].data();
          for (size_t k = 0; k < values; ++k) scaled[k] = row[k] * factor[k];
          row = scaled.data();
        }
        halves.resize(values);
        detail::toHalf(row, halves.data(), values);
        for (int x = 0; x < width; ++x) {
          unsigned char* pixel = dst + size_t(x) * pixelBytes;
          const size_t at = size_t(x) * size_t(n);
          for (const Run& run : runs[i]) {
            if (run.half)
              std::memcpy(pixel + run.offset, &halves[at + size_t(run.first)],
                          size_t(run.count) * sizeof(uint16_t));
            else
              std::memcpy(pixel + run.offset, &row[at + size_t(run.first)],
                          size_t(run.count) * sizeof(float));
          }
        }
        first += n;
      }
      for (const float v : sources.constants) {
        const size_t c = size_t(first++);
        unsigned char value[sizeof(float)];
        if (types[c] == Imf::HALF) {
          const uint16_t h = Imath::half(v).bits();
          std::memcpy(value, &h, sizeof h);
        } else {
          std::memcpy(value, &v, sizeof v);
        }
        for (int x = 0; x < width; ++x)
          std::memcpy(dst + size_t(x) * pixelBytes + offsets[c], value, bytesOf(types[c]));
      }
    });
    Imf::FrameBuffer frame;
    // The band holds rows y0 + r0 ... of the data window, whose left edge is x0: its base
    // pointer is placed so that OpenEXR's absolute coordinates land in it.
    const Imath::Box2i bandWindow({x0, y0 + r0}, {x0 + width - 1, y0 + r0 + rows - 1});
    for (size_t c = 0; c < names.size(); ++c) {
      frame.insert(names[c], Imf::Slice::Make(types[c], band.data() + offsets[c], bandWindow,
                                              pixelBytes, rowBytes));
    }
    setFrame(frame, r0);
    write(y0 + r0, rows);
  }
}

}  // namespace

std::vector<WriteReport> writeExrFile(const fs::path& file, const fs::path& shown,
                                      const std::vector<ExrPart>& parts, const ExrHeader& shared) {
  COMPOSE_CHECK(!parts.empty());
  useEveryCoreForExr();
  std::vector<WriteReport> reports(parts.size());
  std::vector<detail::ChannelSources> sources(parts.size());
  std::vector<std::vector<std::string>> names(parts.size());
  std::vector<Imf::PixelType> types(parts.size());
  std::vector<std::vector<Imf::PixelType>> channelTypes(parts.size());
  std::vector<Imf::Header> headers;
  for (size_t i = 0; i < parts.size(); ++i) {
    const ExrPart& part = parts[i];
    COMPOSE_CHECK(part.image != nullptr);
    const Image& image = *part.image;
    detail::ChannelSources& s = sources[i];
    s.images.push_back(&image);
    for (const Image* more : part.moreImages) {
      COMPOSE_CHECK(more != nullptr && more->width == image.width && more->height == image.height);
      s.images.push_back(more);
    }
    // The channels' names: the part's own, else the images' (when every image has them), else
    // OpenImageIO's defaults.
    std::vector<std::string>& n = names[i];
    n = part.channelNames;
    for (const Image* source : s.images) {
      COMPOSE_CHECK(source->width > 0 && source->height > 0 && source->channels > 0);
      COMPOSE_CHECK(source->pixels.size() == source->pixelCount() * size_t(source->channels));
      if (!part.channelNames.empty()) continue;
      if (source->channelNames.empty()) {
        n.clear();
        break;
      }
      COMPOSE_CHECK(int(source->channelNames.size()) == source->channels);
      n.insert(n.end(), source->channelNames.begin(), source->channelNames.end());
    }
    for (const auto& [name, value] : part.constantChannels) {
      s.constants.push_back(value);
      if (!n.empty()) n.push_back(name);
    }
    if (n.empty()) n = defaultChannelNames(s.channels());
    COMPOSE_CHECK(int(n.size()) == s.channels());
    if (!part.channelScales.empty()) {
      size_t c = 0;
      for (const Image* source : s.images) {
        std::vector<float> factors(size_t(source->channels), 1.0f);
        bool any = false;
        for (float& f : factors) {
          for (const auto& [name, scale] : part.channelScales) {
            if (name != n[c]) continue;
            f = scale;
            any = any || scale != 1.0f;
          }
          ++c;
        }
        s.scales.push_back(any ? std::move(factors) : std::vector<float>());
      }
      for (const auto& scaled : part.channelScales) {
        COMPOSE_CHECK(std::find(n.begin(), n.begin() + std::ptrdiff_t(c), scaled.first) !=
                      n.begin() + std::ptrdiff_t(c));
      }
    }
    types[i] = part.options.depth == WriteOptions::Depth::Float ? Imf::FLOAT : Imf::HALF;
    if (types[i] == Imf::HALF) {
      // The channels written as float whatever the depth (floatChannels: positions, depth) do
      // not count: a depth beyond half's range made every other channel float too.
      detail::ChannelSources probe = s;
      if (!part.floatChannels.empty()) {
        probe.scales.resize(s.images.size());
        size_t c = 0;
        for (size_t k = 0; k < s.images.size(); ++k) {
          std::vector<float> factors =
              s.scalesOf(k) ? *s.scalesOf(k)
                            : std::vector<float>(size_t(s.images[k]->channels), 1.0f);
          for (float& f : factors) {
            if (std::find(part.floatChannels.begin(), part.floatChannels.end(), n[c]) !=
                part.floatChannels.end())
              f = 0.0f;
            ++c;
          }
          probe.scales[k] = std::move(factors);
        }
        for (size_t k = 0; k < s.constants.size(); ++k, ++c)
          if (std::find(part.floatChannels.begin(), part.floatChannels.end(), n[c]) !=
              part.floatChannels.end())
            probe.constants[k] = 0.0f;
      }
      reports[i].largestMagnitude = detail::largestFiniteMagnitude(probe);
      if (reports[i].largestMagnitude > kHalfMax) {
        types[i] = Imf::FLOAT;
        reports[i].promotedToFloat = true;
      }
    }
    channelTypes[i].assign(n.size(), types[i]);
    for (size_t c = 0; c < n.size(); ++c)
      if (std::find(part.floatChannels.begin(), part.floatChannels.end(), n[c]) !=
          part.floatChannels.end())
        channelTypes[i][c] = Imf::FLOAT;
  }
  errno = 0;
  try {
    for (size_t i = 0; i < parts.size(); ++i)
      headers.push_back(headerOf(parts[i], sources[i], names[i], channelTypes[i], shared,
                                 parts.size() > 1, shown));
    if (parts.size() == 1) {
      Imf::OutputFile out(file.c_str(), headers[0], Imf::globalThreadCount());
      writeBands(
          sources[0], names[0], channelTypes[0], parts[0].x, parts[0].y,
          [&](const Imf::FrameBuffer& frame, int) { out.setFrameBuffer(frame); },
          [&](int, int rows) { out.writePixels(rows); });
    } else {
      Imf::MultiPartOutputFile out(file.c_str(), headers.data(), int(headers.size()), false,
                                   Imf::globalThreadCount());
      for (size_t i = 0; i < parts.size(); ++i) {
        Imf::OutputPart part(out, int(i));
        writeBands(
            sources[i], names[i], channelTypes[i], parts[i].x, parts[i].y,
            [&](const Imf::FrameBuffer& frame, int) { part.setFrameBuffer(frame); },
            [&](int, int rows) { part.writePixels(rows); });
      }
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    std::string why = nameTheDestination(e.what(), file, shown);
    if (errno != 0) why += std::string(" (") + std::strerror(errno) + ")";
    throw Error("output", "cannot write image: " + why, shown);
  }
  return reports;
}

}  // namespace compose::ingest
