#include "ingest/image_io.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <optional>
#include <set>
#include <sstream>

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <Imath/half.h>

#include "core/channels.h"
#include "core/error.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "ingest/exif.h"
#include "ingest/exr_io.h"
#include "ingest/jpeg_io.h"
#include "ingest/oiio_module.h"
#include "ingest/pixel_util.h"

namespace compose::ingest {

namespace fs = std::filesystem;

namespace detail {

float largestFiniteMagnitude(const ChannelSources& sources) {
  float largest = 0.0f;
  for (float v : sources.constants)
    if (std::isfinite(v)) largest = std::max(largest, std::abs(v));
  for (size_t i = 0; i < sources.images.size(); ++i) {
    const Image* image = sources.images[i];
    const std::vector<float>* scales = sources.scalesOf(i);
    const std::vector<float> rowScales =
        scales ? rowOfScales(*scales, image->width) : std::vector<float>();
    std::vector<float> rowLargest(size_t(image->height), 0.0f);
    parallelFor(0, image->height, [&](int64_t y) {
      const std::span<const float> row = image->row(int(y));
      rowLargest[size_t(y)] = scales ? largestFinite(row.data(), rowScales.data(), row.size())
                                     : largestFinite(row.data(), row.size());
    });
    for (float m : rowLargest) largest = std::max(largest, m);
  }
  return largest;
}

}  // namespace detail

std::string lowerExtension(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

fs::path nameForRules(const fs::path& file, const std::string& format) {
  static const std::pair<const char*, std::vector<const char*>> kExtensions[] = {
      {"openexr", {".exr", ".sxr", ".mxr"}},
      {"jpeg", {".jpg", ".jpeg", ".jpe", ".jfif", ".jif"}},
      {"png", {".png"}},
      {"tiff", {".tif", ".tiff", ".tx", ".env", ".sm", ".vsm"}},
      {"hdr", {".hdr", ".rgbe"}},
      {"webp", {".webp"}},
  };
  const std::string ext = lowerExtension(file);
  for (const auto& [name, extensions] : kExtensions) {
    if (format != name) continue;
    for (const char* e : extensions)
      if (ext == e) return file;
    fs::path renamed = file;
    renamed.replace_extension(extensions.front());
    return renamed;
  }
  return file;  // a format without a known extension: its name as it is
}

namespace {

std::string trimmed(std::string s) {
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  size_t i = 0;
  while (i < s.size() && s[i] == ' ') ++i;
  return s.substr(i);
}

// Days from 1970-01-01 of a proleptic Gregorian date (H. Hinnant's days_from_civil).
int64_t daysFromCivil(int64_t y, int64_t m, int64_t d) {
  y -= m <= 2;
  const int64_t era = (y >= 0 ? y : y - 399) / 400;
  const int64_t yoe = y - era * 400;
  const int64_t doy = (153 * (m + (m > 2 ? -3 : 9)) + 2) / 5 + d - 1;
  const int64_t doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
  return era * 146097 + doe - 719468;
}

// "YYYY:MM:DD HH:MM:SS" (EXIF) → seconds; empty if malformed or blank.
std::optional<double> exifSeconds(const std::string& text, const std::string& subsec) {
  int y = 0, mo = 0, d = 0, h = 0, mi = 0, sec = 0;
  if (std::sscanf(text.c_str(), "%d:%d:%d %d:%d:%d", &y, &mo, &d, &h, &mi, &sec) != 6)
    return std::nullopt;
  if (y < 1800 || mo < 1 || mo > 12 || d < 1 || d > 31 || h < 0 || h > 23 || mi < 0 || mi > 59 ||
      sec < 0 || sec > 60)
    return std::nullopt;
  double t = double(daysFromCivil(y, mo, d)) * 86400.0 + h * 3600.0 + mi * 60.0 + sec;
  // SubSecTimeOriginal holds the digits of a decimal fraction ("25" = 0.25 s).
  std::string digits;
  for (char c : subsec) {
    if (c < '0' || c > '9') break;
    digits.push_back(c);
  }
  if (!digits.empty()) t += std::stod("0." + digits);
  return t;
}

double unitMillimetres(int unit) {
  switch (unit) {
    case 2:
      return 25.4;
    case 3:
      return 10.0;
    case 4:
      return 1.0;
    case 5:
      return 0.001;
    default:
      return 0.0;
  }
}

// What the readers tell of a file before its pixels: everything CaptureInfo is made from.
struct FileHeader {
  int width = 0, height = 0, channels = 0;
  std::string format;      // "openexr", "jpeg", or OpenImageIO's name for the format
  std::string sampleType;  // "uint8", "half", ...
  int bitsPerSample = 0;
  const std::vector<ImageAttribute>* attributes = nullptr;

  // Attribute lookups as OpenImageIO's ImageSpec does them: names are not case-sensitive, and
  // numbers convert between int and float.
  const ImageAttribute* find(const char* name) const {
    for (const ImageAttribute& a : *attributes) {
      if (a.name.size() == std::strlen(name) &&
          std::equal(a.name.begin(), a.name.end(), name, [](char p, char q) {
            return std::tolower(static_cast<unsigned char>(p)) ==
                   std::tolower(static_cast<unsigned char>(q));
          }))
        return &a;
    }
    return nullptr;
  }
  std::optional<double> number(const char* name) const {
    const ImageAttribute* a = find(name);
    if (!a) return std::nullopt;
    if (const int* i = std::get_if<int>(&a->value)) return double(*i);
    if (const double* d = std::get_if<double>(&a->value)) return *d;
    return std::nullopt;
  }
  // A positive, finite number, or empty.
  std::optional<double> positive(const char* name) const {
    const std::optional<double> v = number(name);
    if (!v || !(*v > 0.0) || !std::isfinite(*v)) return std::nullopt;
    return v;
  }
  int integer(const char* name, int fallback) const {
    const std::optional<double> v = number(name);
    if (!v || !std::isfinite(*v) || std::abs(*v) > 2e9) return fallback;
    return int(*v);
  }
  std::string text(const char* name) const {
    const ImageAttribute* a = find(name);
    const std::string* t = a ? std::get_if<std::string>(&a->value) : nullptr;
    return t ? *t : std::string();
  }
};

// Fills everything but the pixels from a file's header.
void fillCaptureInfo(const FileHeader& h, CaptureInfo& info) {
  info.format = h.format;
  info.fileWidth = h.width;
  info.fileHeight = h.height;
  info.channels = h.channels;
  info.sampleType = h.sampleType;
  info.bitsPerSample = h.integer("oiio:BitsPerSample", h.bitsPerSample);
  info.orientation = h.integer("Orientation", 1);
  if (info.orientation < 1 || info.orientation > 8) info.orientation = 1;  // not an EXIF value
  info.exposureTime = h.positive("ExposureTime");
  info.fNumber = h.positive("FNumber");
  if (h.format == "openexr") info.pixelAspectRatio = h.positive("PixelAspectRatio").value_or(1.0);
  info.iso = h.positive("Exif:PhotographicSensitivity");
  if (!info.iso) info.iso = h.positive("Exif:ISOSpeedRatings");
  // Above 65535 the 16-bit tag holds 65535 and the sensitivity is in ISOSpeed (Exif 2.3, with
  // SensitivityType 3 or another that includes it), as cameras write ISO 102400.
  if (!info.iso || *info.iso >= 65535.0) {
    if (const std::optional<double> speed = h.positive("Exif:ISOSpeed")) info.iso = speed;
  }
  info.focalLengthMm = h.positive("Exif:FocalLength");
  info.focalPlaneXResolution = h.positive("Exif:FocalPlaneXResolution");
  info.focalPlaneYResolution = h.positive("Exif:FocalPlaneYResolution");
  info.focalPlaneResolutionUnit = h.integer("Exif:FocalPlaneResolutionUnit", 2);
  info.cameraMake = trimmed(h.text("Make"));
  info.cameraModel = trimmed(h.text("Model"));
  info.exposureUnit = trimmed(h.text("compose:exposureUnit"));
  info.sensorOrientation = h.integer("compose:sensorOrientation", 1);
  if (info.sensorOrientation < 1 || info.sensorOrientation > 8) info.sensorOrientation = 1;
  info.fileColorSpace = h.text("oiio:ColorSpace");
  // OpenImageIO's TIFF reader calls any file whose EXIF ColorSpace is 1 sRGB, float samples
  // too (a linear float TIFF from a camera's raw converter): EXIF's tag speaks of 8-bit
  // encodings, so floats are left to the rules for float samples (scene-linear).
  if (h.format == "tiff" && (h.sampleType == "float" || h.sampleType == "half") &&
      info.fileColorSpace == "sRGB" && h.integer("Exif:ColorSpace", 0) == 1)
    info.fileColorSpace.clear();
  info.colorSpaceByConvention =
      (info.fileColorSpace == "Linear" && (h.format == "openexr" || h.format == "hdr")) ||
      (info.fileColorSpace == "sRGB" &&
       (h.format == "jpeg" || h.format == "png" || h.format == "webp"));
  info.iccProfile = trimmed(h.text("ICCProfile:profile_description"));
  if (!info.iccProfile.empty() &&
      (h.format == "jpeg" || h.format == "png" || h.format == "tiff" || h.format == "webp")) {
    std::string lower = info.iccProfile;
    std::transform(lower.begin(), lower.end(), lower.begin(),
                   [](unsigned char c) { return std::tolower(c); });
    const bool linear = lower.find("linear") != std::string::npos ||
                        lower.find("g10") != std::string::npos;  // as "sRGB-elle-V4-g10"
    // P3 with D65 white (Display P3, phones' photos); DCI-P3 (theatre white, gamma 2.6) and
    // ACES' P3-D60 are other spaces, named in a note.
    const bool p3 =
        lower.find("p3") != std::string::npos && lower.find("dci") == std::string::npos &&
        lower.find("d60") == std::string::npos && lower.find("431") == std::string::npos;
    const bool adobe =
        lower.find("adobe rgb") != std::string::npos || lower.find("adobergb") != std::string::npos;
    if (linear && p3) {
      info.fileColorSpace = "Linear P3-D65";
    } else if (linear && adobe) {
      info.fileColorSpace = "Linear Adobe RGB (1998)";
    } else if (linear && (lower.find("srgb") != std::string::npos ||
                          lower.find("709") != std::string::npos)) {
      info.fileColorSpace = "Linear Rec.709 (sRGB)";  // compose capture-sim --tiff, linear exports
    } else if (linear) {
      info.fileColorSpace = info.iccProfile;  // linear on primaries no config names
    } else if (p3) {
      info.fileColorSpace = "Display P3";
    } else if (adobe) {
      info.fileColorSpace = "Adobe RGB (1998)";
    } else if (lower.find("srgb") == std::string::npos) {
      info.fileColorSpace = info.iccProfile;  // ProPhoto, a camera's own: not a config's name
    }
    if (info.fileColorSpace != "sRGB") info.colorSpaceByConvention = false;
  }
  info.unassociatedAlpha = h.integer("oiio:UnassociatedAlpha", 0) != 0;
  info.exifUncalibrated = info.iccProfile.empty() && h.integer("Exif:ColorSpace", 1) == 65535;
  if (const std::string named = h.text("colorSpace"); !named.empty()) {
    info.exifUncalibrated = false;
    info.fileColorSpace = named;
    info.colorSpaceByConvention = false;
  }
  if (const ImageAttribute* c = h.find("chromaticities")) {
    const auto* v = std::get_if<std::vector<float>>(&c->value);
    if (v && v->size() == 8 &&
        std::all_of(v->begin(), v->end(), [](float x) { return std::isfinite(x); })) {
      std::array<double, 8> xy;
      for (size_t i = 0; i < 8; ++i) xy[i] = (*v)[i];
      info.chromaticities = xy;
    }
  }
  info.dateTimeOriginal = trimmed(h.text("Exif:DateTimeOriginal"));
  if (info.dateTimeOriginal.empty()) info.dateTimeOriginal = trimmed(h.text("DateTime"));
  info.captureSeconds = exifSeconds(info.dateTimeOriginal, h.text("Exif:SubsecTimeOriginal"));

  // The 35 mm equivalent: derived from the true focal length and the focal-plane resolution
  // (sensor size = image size / pixels per unit; scaled by the ratio of diagonals, 43.27 mm for
  // the 36 x 24 mm frame), or EXIF's FocalLengthIn35mmFilm, a whole number of millimetres. Both
  // given, the derived one is taken when it agrees with the tag to the tag's rounding (15 mm for
  // 14.5 mm is 2° of a 100° field of view); otherwise the tag (a resized photo keeps the sensor's
  // focal-plane resolution, which then gives a wrong sensor size). The resolution counts the
  // pixels of EXIF's PixelXDimension x PixelYDimension when the file gives them, as ExifTool
  // reads it: a photo resized by a tool that keeps its EXIF keeps both, and its own size would
  // give a sensor of half the size for half the pixels (twice the focal length).
  std::optional<double> derived;
  std::string derivedText;
  if (info.focalLengthMm && info.focalPlaneXResolution && info.focalPlaneYResolution &&
      unitMillimetres(info.focalPlaneResolutionUnit) > 0.0) {
    const double unit = unitMillimetres(info.focalPlaneResolutionUnit);
    const std::optional<double> pixelsX = h.positive("Exif:PixelXDimension");
    const std::optional<double> pixelsY = h.positive("Exif:PixelYDimension");
    const bool counted = pixelsX && pixelsY;
    const double w = (counted ? *pixelsX : h.width) / *info.focalPlaneXResolution * unit;
    const double hgt = (counted ? *pixelsY : h.height) / *info.focalPlaneYResolution * unit;
    const double diagonal = std::sqrt(w * w + hgt * hgt);
    if (diagonal > 0.5 && diagonal < 500.0) {
      derived = *info.focalLengthMm * 43.266615305567875 / diagonal;
      char text[200];
      std::snprintf(text, sizeof text,
                    "derived from FocalLength %.3g mm and the focal-plane resolution (sensor "
                    "%.1f x %.1f mm): %.2f mm",
                    *info.focalLengthMm, w, hgt, *derived);
      derivedText = text;
    }
  }
  const std::optional<double> tag = h.positive("Exif:FocalLengthIn35mmFilm");
  if (tag && derived && std::abs(*derived - *tag) <= 0.5 + 1e-6) {
    info.focalLength35mm = derived;
    char text[64];
    std::snprintf(text, sizeof text, ", which FocalLengthIn35mmFilm rounds to %.0f mm", *tag);
    info.focal35mmSource = derivedText + text;
  } else if (tag) {
    info.focalLength35mm = tag;
    info.focal35mmSource = "EXIF FocalLengthIn35mmFilm";
  } else if (derived) {
    info.focalLength35mm = derived;
    info.focal35mmSource = derivedText;
  }
}

// The size is the display window's: readExr() returns that frame (a data window is put in it).
FileHeader headerOf(const ExrPartHeader& part) {
  return {part.fullWidth,  part.fullHeight, int(part.channelNames.size()),
          "openexr",       part.sampleType, part.sampleType == "half" ? 16 : 32,
          &part.attributes};
}

FileHeader headerOf(const jpeg::Header& jpeg) {
  return {jpeg.width, jpeg.height, jpeg.channels, "jpeg", "uint8", 8, &jpeg.attributes};
}

FileHeader headerOf(const oiio::Header& oiio, const std::vector<ImageAttribute>& attributes) {
  return {oiio.width,      oiio.height,        oiio.channels, oiio.format,
          oiio.sampleType, oiio.bitsPerSample, &attributes};
}

// A file's bytes mapped into memory, read only as they are looked at. Empty when the file cannot
// be mapped.
class MappedFile {
 public:
  explicit MappedFile(const fs::path& file) {
    const int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return;
    struct stat st {};
    if (::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && st.st_size > 0) {
      void* at = ::mmap(nullptr, size_t(st.st_size), PROT_READ, MAP_PRIVATE, fd, 0);
      if (at != MAP_FAILED) bytes_ = {static_cast<const unsigned char*>(at), size_t(st.st_size)};
    }
    ::close(fd);
  }
  ~MappedFile() {
    if (!bytes_.empty()) ::munmap(const_cast<unsigned char*>(bytes_.data()), bytes_.size());
  }
  MappedFile(const MappedFile&) = delete;
  MappedFile& operator=(const MappedFile&) = delete;
  std::span<const unsigned char> bytes() const { return bytes_; }

 private:
  std::span<const unsigned char> bytes_;
};

// A WebP's EXIF and ICC profile, which OpenImageIO 2.4's WebP reader does not give: its
// RIFF chunks read here (EXIF: a TIFF structure, as exif.h reads; ICCP: the profile, named by
// its description). Nothing if the file is not a RIFF WebP.
std::vector<ImageAttribute> webpAttributes(std::span<const unsigned char> riff) {
  std::vector<ImageAttribute> out;
  if (riff.size() < 12 || !std::equal(riff.begin(), riff.begin() + 4, "RIFF") ||
      !std::equal(riff.begin() + 8, riff.begin() + 12, "WEBP"))
    return out;
  for (size_t at = 12; at + 8 <= riff.size();) {
    const uint64_t size = uint64_t(riff[at + 4]) | uint64_t(riff[at + 5]) << 8 |
                          uint64_t(riff[at + 6]) << 16 | uint64_t(riff[at + 7]) << 24;
    if (size > riff.size() - at - 8) break;  // a truncated chunk: the decoder says so
    std::span<const unsigned char> payload = riff.subspan(at + 8, size_t(size));
    const std::string kind(riff.begin() + ptrdiff_t(at), riff.begin() + ptrdiff_t(at) + 4);
    if (kind == "EXIF") {
      if (payload.size() >= 6 && std::equal(payload.begin(), payload.begin() + 6, "Exif\0\0"))
        payload = payload.subspan(6);  // as some writers prefix it
      for (ImageAttribute& a : exif::decode(payload)) out.push_back(std::move(a));
    } else if (kind == "ICCP") {
      if (const std::string name = exif::iccDescription(payload); !name.empty())
        out.push_back({"ICCProfile:profile_description", name});
    }
    at += 8 + size_t(size) + (size & 1);
  }
  return out;
}

// A file's attributes as OpenImageIO read them, with the EXIF tags its TIFF reader leaves out
// read from the TIFF structure itself (exif.h: a TIFF file is one). OpenImageIO 2.4 drops the
// Exif IFD's ISO (tag 0x8827), which raw converters write into their 16-bit TIFFs and which an
// exposure needs; its WebP reader gives neither EXIF nor the ICC profile (webpAttributes).
// `bytes` is the file's bytes (empty: the file is mapped).
std::vector<ImageAttribute> attributesOf(const oiio::Header& h, const fs::path& file,
                                         std::span<const unsigned char> bytes = {}) {
  std::vector<ImageAttribute> attributes = h.attributes;
  if (h.format != "tiff" && h.format != "webp") return attributes;
  std::optional<MappedFile> mapped;
  if (bytes.empty()) bytes = mapped.emplace(file).bytes();
  for (ImageAttribute& a : h.format == "tiff" ? exif::decode(bytes) : webpAttributes(bytes)) {
    if (!FileHeader{0, 0, 0, {}, {}, 0, &attributes}.find(a.name.c_str()))
      attributes.push_back(std::move(a));
  }
  return attributes;
}

// Which reader a file goes to: by its first bytes, not its name.
enum class Kind { Exr, Jpeg, Other };

Kind kindOf(std::span<const unsigned char> first4) {
  if (first4.size() >= 4 && first4[0] == 0x76 && first4[1] == 0x2f && first4[2] == 0x31 &&
      first4[3] == 0x01)
    return Kind::Exr;
  if (jpeg::hasMagic(first4)) return Kind::Jpeg;
  return Kind::Other;
}

Kind kindOf(const fs::path& file, const std::string& stage) {
  errno = 0;
  std::ifstream in(file, std::ios::binary);
  if (!in)
    throw Error(stage,
                std::string("cannot read image: ") + (errno ? std::strerror(errno) : "cannot open"),
                file);
  unsigned char first[4] = {0, 0, 0, 0};
  in.read(reinterpret_cast<char*>(first), 4);
  if (in.gcount() < 4)
    throw Error(stage, "not an image file (" + std::to_string(in.gcount()) + " bytes)", file);
  return kindOf({first, 4});
}

// A PNG's chunks walked before OpenImageIO decodes it (`size` bytes; `read` fills 8 bytes at an
// offset): one that ends early, or a file without its IEND chunk, is a truncated file. (libpng
// would say so too, but writes its own message to the terminal first.) Empty when the chunks are
// whole or the file is not a PNG.
template <class Read>
std::string pngTruncation(uint64_t size, Read&& read) {
  static constexpr unsigned char kSignature[8] = {0x89, 'P', 'N', 'G', 0x0D, 0x0A, 0x1A, 0x0A};
  unsigned char bytes[8];
  if (size < 8 || !read(0, bytes) || !std::equal(bytes, bytes + 8, kSignature)) return {};
  uint64_t at = 8;
  while (at + 8 <= size) {
    if (!read(at, bytes)) return {};
    const uint64_t length = (uint64_t(bytes[0]) << 24) | (uint64_t(bytes[1]) << 16) |
                            (uint64_t(bytes[2]) << 8) | uint64_t(bytes[3]);
    std::string type;
    for (int i = 4; i < 8; ++i) type += std::isalpha(bytes[i]) ? char(bytes[i]) : '?';
    if (at + 12 + length > size) {
      return "the PNG ends inside its " + type + " chunk (" + std::to_string(size) +
             " bytes, the chunk needs " + std::to_string(at + 12 + length) + ")";
    }
    if (type == "IEND") return {};
    at += 12 + length;
  }
  return "the PNG ends before its IEND chunk (" + std::to_string(size) + " bytes)";
}

void checkPng(const fs::path& path, const std::string& stage) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const uintmax_t size = fs::file_size(path, ec);
  if (!in || ec) return;  // the reader says what is wrong
  const std::string why = pngTruncation(size, [&](uint64_t at, unsigned char* out) {
    in.seekg(std::streamoff(at));
    in.read(reinterpret_cast<char*>(out), 8);
    return in.gcount() == 8;
  });
  if (!why.empty()) throw Error(stage, "truncated file: " + why, path);
}

void checkPng(std::span<const unsigned char> bytes, const fs::path& name,
              const std::string& stage) {
  const std::string why = pngTruncation(bytes.size(), [&](uint64_t at, unsigned char* out) {
    if (at + 8 > bytes.size()) return false;
    std::copy_n(bytes.data() + at, 8, out);
    return true;
  });
  if (!why.empty()) throw Error(stage, "truncated file: " + why, name);
}

// A portable float map (PF colour, Pf grey) shorter than its header says: OpenImageIO fails it
// with "unknown reason". The header is three whitespace-separated tokens (type, width height,
// scale) and one whitespace character; then width x height x channels floats.
void checkPfm(const fs::path& path, const std::string& stage) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const uintmax_t size = fs::file_size(path, ec);
  if (!in || ec) return;
  char magic[3] = {};
  if (!in.read(magic, 3) || magic[0] != 'P' || (magic[1] != 'F' && magic[1] != 'f') ||
      !std::isspace(static_cast<unsigned char>(magic[2])))
    return;
  long long width = 0, height = 0;
  double scale = 0.0;
  if (!(in >> width >> height >> scale) || width <= 0 || height <= 0) return;  // the reader says
  in.get();  // the one whitespace character before the data
  const std::streamoff header = in.tellg();
  if (header < 0) return;
  const uintmax_t need =
      uintmax_t(header) + uintmax_t(width) * uintmax_t(height) * (magic[1] == 'F' ? 3u : 1u) * 4u;
  if (size < need)
    throw Error(stage,
                "truncated file: a " + std::to_string(width) + "x" + std::to_string(height) +
                    " portable float map needs " + std::to_string(need) +
                    " bytes, the file holds " + std::to_string(size),
                path);
}

void checkInputFile(const fs::path& path, const std::string& stage) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(stage, "file not found", path);
  if (fs::is_directory(path, ec)) throw Error(stage, "is a folder, expected an image file", path);
  requireRegularFile(path, stage);
}

// 8-bit codes to floats as OpenImageIO converts them: code · (1/255) in float (which differs from
// code / 255 in the last bit for half the codes).
const std::array<float, 256>& codeValues() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t;
    for (int c = 0; c < 256; ++c) t[size_t(c)] = float(c) * (1.0f / 255.0f);
    return t;
  }();
  return table;
}

// The loaded image of `codes` (width x height x channels, as stored), turned upright: the codes
// themselves, or their float values.
void fromCodes(std::vector<uint8_t>&& codes, int width, int height, int channels,
               const ReadOptions& options, LoadedImage& out) {
  detail::applyOrientation(codes, width, height, channels, out.info.orientation);
  Image& img = out.image;
  img.width = width;
  img.height = height;
  img.channels = channels;
  if (options.codesForEightBit) {
    out.codes = std::move(codes);
    return;
  }
  img.pixels.resize(codes.size());
  const std::array<float, 256>& value = codeValues();
  const size_t rowValues = size_t(width) * size_t(channels);
  parallelFor(0, height, [&](int64_t y) {
    const uint8_t* from = codes.data() + size_t(y) * rowValues;
    float* to = img.pixels.data() + size_t(y) * rowValues;
    for (size_t i = 0; i < rowValues; ++i) to[i] = value[from[i]];
  });
}

// Whether `name` is a colour channel: R, G, B (or red, green, blue), a layer's (beauty.R), or Y
// for grey (a layer's Y is not: N.Y is a normal's).
bool isColourChannel(const std::string& name) {
  std::string upper = name;
  for (char& c : upper) c = char(std::toupper(static_cast<unsigned char>(c)));
  const size_t dot = upper.rfind('.');
  const std::string base = dot == std::string::npos ? upper : upper.substr(dot + 1);
  return base == "R" || base == "G" || base == "B" || base == "RED" || base == "GREEN" ||
         base == "BLUE" || upper == "Y";
}

// The part of a multi-part OpenEXR that holds the picture: of the parts with R, G and B the one
// named as a picture (beauty, rgba, combined: core/channels.h), else the first; else of those
// with a colour channel of a layer (beauty.R) or Y the one so named, else the first; else the
// first; and a note saying which when there is a choice.
int pictureExrPart(const ExrReader& reader, const fs::path& path, std::vector<std::string>& notes) {
  auto has = [](const ExrPartHeader& h, const char* name) {
    return std::find(h.channelNames.begin(), h.channelNames.end(), name) != h.channelNames.end();
  };
  auto rgb = [&](const ExrPartHeader& h) { return has(h, "R") && has(h, "G") && has(h, "B"); };
  auto colour = [](const ExrPartHeader& h) {
    return std::any_of(h.channelNames.begin(), h.channelNames.end(), isColourChannel);
  };
  int chosen = -1;
  std::string why;
  for (int p = 0; p < reader.parts() && chosen < 0; ++p)
    if (rgb(reader.header(p)) && isBeautyName(reader.header(p).name))
      chosen = p, why = "named as the picture, with R, G and B";
  for (int p = 0; p < reader.parts() && chosen < 0; ++p)
    if (rgb(reader.header(p))) chosen = p, why = "the first with R, G and B";
  for (int p = 0; p < reader.parts() && chosen < 0; ++p)
    if (colour(reader.header(p)) && isBeautyName(reader.header(p).name))
      chosen = p, why = "named as the picture, with a colour channel (none has R, G and B)";
  for (int p = 0; p < reader.parts() && chosen < 0; ++p)
    if (colour(reader.header(p)))
      chosen = p, why = "the first with a colour channel (none has R, G and B)";
  if (chosen < 0) chosen = 0, why = "the first (none has a colour channel)";
  if (reader.parts() > 1) {
    std::string names;
    for (int p = 0; p < reader.parts(); ++p) {
      const std::string& n = reader.header(p).name;
      names += (p ? ", " : "") + (n.empty() ? "(unnamed)" : "'" + n + "'");
    }
    const std::string& n = reader.header(chosen).name;
    notes.push_back(path.filename().string() + ": an OpenEXR of " + std::to_string(reader.parts()) +
                    " parts (" + names + "): read part " + std::to_string(chosen) +
                    (n.empty() ? "" : " '" + n + "'") + ", " + why);
  }
  return chosen;
}

LoadedImage readExr(const fs::path& path, const std::string& stage, bool picturePart) {
  ExrReader reader(path, stage);
  LoadedImage out;
  const int chosen = picturePart ? pictureExrPart(reader, path, out.notes) : 0;
  const ExrPartHeader& part = reader.header(chosen);
  fillCaptureInfo(headerOf(part), out.info);
  checkImageSize(part.width, part.height, int(part.channelNames.size()), stage, path);
  out.image = reader.read(chosen);
  if (part.x != 0 || part.y != 0 || part.width != part.fullWidth ||
      part.height != part.fullHeight) {
    // In 64 bits: a crafted header's offsets and sizes may each fit an int and not their sum.
    const int64_t right = int64_t(part.x) + part.width, bottom = int64_t(part.y) + part.height;
    // The image is the display window (OpenEXR's frame, as Nuke keeps it): the stored pixels go
    // where the data window says, pixels outside it are 0 and overscan beyond the frame is not
    // kept.
    checkImageSize(part.fullWidth, part.fullHeight, int(part.channelNames.size()), stage, path);
    Image framed(part.fullWidth, part.fullHeight, out.image.channels, out.image.channelNames);
    const int x0 = int(std::clamp<int64_t>(part.x, 0, part.fullWidth));
    const int x1 = int(std::clamp<int64_t>(right, 0, part.fullWidth));
    const int y0 = int(std::clamp<int64_t>(part.y, 0, part.fullHeight));
    const int y1 = int(std::clamp<int64_t>(bottom, 0, part.fullHeight));
    const size_t c = size_t(out.image.channels);
    for (int y = y0; y < y1 && x0 < x1; ++y) {
      std::copy_n(out.image.at(x0 - part.x, y - part.y), size_t(x1 - x0) * c, framed.at(x0, y));
    }
    char line[320];
    std::snprintf(line, sizeof line,
                  "%s: its data window (%dx%d at %d,%d) is not its display window (%dx%d): the "
                  "image is the display window%s%s",
                  path.filename().string().c_str(), part.width, part.height, part.x, part.y,
                  part.fullWidth, part.fullHeight,
                  (x0 > 0 || y0 > 0 || x1 < part.fullWidth || y1 < part.fullHeight)
                      ? ", 0 where no pixel is stored"
                      : "",
                  (part.x < 0 || part.y < 0 || right > part.fullWidth || bottom > part.fullHeight)
                      ? ", the overscan outside it left out"
                      : "");
    out.notes.push_back(line);
    if (x0 > 0 || y0 > 0 || x1 < part.fullWidth || y1 < part.fullHeight) {
      out.info.partlyStored = true;
      out.info.storedX0 = x0, out.info.storedY0 = y0;
      out.info.storedX1 = std::max(x0, x1), out.info.storedY1 = std::max(y0, y1);
    }
    out.image = std::move(framed);
    out.info.fileWidth = part.fullWidth;
    out.info.fileHeight = part.fullHeight;
  }
  if (out.info.orientation != 1) {
    detail::applyOrientation(out.image.pixels, out.image.width, out.image.height,
                             out.image.channels, out.info.orientation);
  }
  // Luminance-chroma made RGB with the weights of the file's own primaries (OpenEXR's): Rec.
  // 709's for ACES primaries made green 38 % too bright.
  decodeLuminanceChroma(
      out.image, out.info.chromaticities
                     ? luminanceWeights(*out.info.chromaticities)
                     : luminanceWeights({0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290}));
  out.image.colorSpace = out.info.fileColorSpace;
  return out;
}

LoadedImage fromJpeg(jpeg::Decoded&& decoded, const ReadOptions& options) {
  LoadedImage out;
  fillCaptureInfo(headerOf(decoded.header), out.info);
  if (!options.upright) out.info.orientation = 1;
  const int channels = decoded.header.channels;
  fromCodes(std::move(decoded.codes), decoded.header.width, decoded.header.height, channels,
            options, out);
  out.image.channelNames = defaultChannelNames(channels);
  out.image.colorSpace = out.info.fileColorSpace;
  return out;
}

// Everything readImage() does with a file OpenImageIO opened; `path` names it in errors. `bytes`
// are the file's when it was read from memory.
LoadedImage readWithOiio(oiio::Reader& reader, const fs::path& path, const std::string& stage,
                         const ReadOptions& options, std::span<const unsigned char> bytes = {}) {
  const oiio::Header& h = reader.header();
  if (h.width <= 0 || h.height <= 0 || h.channels <= 0)
    throw Error(stage, "image has no pixels", path);
  // What the header claims, checked before a pixel buffer is allocated (core/limits.h).
  checkImageSize(h.width, h.height, h.channels, stage, path);
  LoadedImage out;
  fillCaptureInfo(headerOf(h, attributesOf(h, path, bytes)), out.info);
  if (!options.upright) out.info.orientation = 1;
  std::string why;
  bool truncated = false;
  const size_t values = size_t(h.width) * size_t(h.height) * size_t(h.channels);
  if (options.codesForEightBit && h.eightBit) {
    std::vector<uint8_t> codes(values);
    if (!reader.read(true, codes.data(), why, truncated))
      throw Error(
          stage, std::string(truncated ? "truncated file: " : "cannot decode image: ") + why, path);
    fromCodes(std::move(codes), h.width, h.height, h.channels, options, out);
  } else {
    Image& img = out.image;
    img.pixels.resize(values);
    if (!reader.read(false, img.pixels.data(), why, truncated))
      throw Error(
          stage, std::string(truncated ? "truncated file: " : "cannot decode image: ") + why, path);
    img.width = h.width;
    img.height = h.height;
    img.channels = h.channels;
    detail::applyOrientation(img.pixels, img.width, img.height, img.channels, out.info.orientation);
  }
  out.image.channelNames = h.channelNames;
  out.image.colorSpace = out.info.fileColorSpace;
  return out;
}

// What a Radiance picture's header says of its values (Ward, "The RADIANCE Picture File
// Format"): each EXPOSURE= multiplies the exposure the stored values carry, so that radiance is
// the value divided by their product; COLORCORR= does so per channel; PRIMARIES= gives the RGB
// primaries and white point (without it a file is in Radiance's own primaries, taken as Rec.
// 709 as every tool takes .hdr files). OpenImageIO reports the last EXPOSURE alone and applies
// none of them.
struct RadianceHeader {
  double exposure = 1.0;
  std::array<double, 3> correction{1.0, 1.0, 1.0};
  std::optional<std::array<double, 8>> primaries;  // when other than Radiance's own
};

// The header of a Radiance picture (one that starts with "#?"), read before OpenImageIO reads
// the file; nullopt for any other file. An unreadable value is an error naming it, and so is a
// picture in CIE XYZ (FORMAT=32-bit_rle_xyze), which OpenImageIO does not read ("no FORMAT
// specifier found").
std::optional<RadianceHeader> readRadianceHeader(const fs::path& path, const std::string& stage) {
  std::ifstream in(path, std::ios::binary);
  char magic[2] = {};
  if (!in.read(magic, 2) || magic[0] != '#' || magic[1] != '?') return std::nullopt;
  RadianceHeader header;
  auto numbers = [&](const std::string& text, size_t count, const char* what) {
    std::istringstream fields(text);
    std::vector<double> values;
    for (double v; values.size() < count && fields >> v;) values.push_back(v);
    if (values.size() != count ||
        !std::all_of(values.begin(), values.end(), [](double v) { return std::isfinite(v); }))
      throw Error(stage,
                  std::string("the Radiance header's ") + what + " is not " +
                      std::to_string(count) + " number" + (count > 1 ? "s" : "") + ": '" + text +
                      "'",
                  path);
    return values;
  };
  std::string line;
  std::getline(in, line);  // the rest of the "#?RADIANCE" line
  for (size_t read = 0; read < (1u << 16) && std::getline(in, line); read += line.size() + 1) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) break;  // the header ends with an empty line
    if (line.rfind("FORMAT=32-bit_rle_xyze", 0) == 0) {
      throw Error(stage,
                  "a Radiance picture in CIE XYZ (FORMAT=32-bit_rle_xyze): compose reads RGB "
                  "ones (FORMAT=32-bit_rle_rgbe); convert it first (Radiance's ra_xyze -r)",
                  path);
    } else if (line.rfind("EXPOSURE=", 0) == 0) {
      const double v = numbers(line.substr(9), 1, "EXPOSURE")[0];
      if (!(v > 0.0)) throw Error(stage, "the Radiance header's EXPOSURE is not positive", path);
      header.exposure *= v;
    } else if (line.rfind("COLORCORR=", 0) == 0) {
      const std::vector<double> v = numbers(line.substr(10), 3, "COLORCORR");
      for (int c = 0; c < 3; ++c) {
        if (!(v[size_t(c)] > 0.0))
          throw Error(stage, "the Radiance header's COLORCORR is not positive", path);
        header.correction[size_t(c)] *= v[size_t(c)];
      }
    } else if (line.rfind("PRIMARIES=", 0) == 0) {
      const std::vector<double> v = numbers(line.substr(10), 8, "PRIMARIES");
      std::array<double, 8> xy;
      std::copy(v.begin(), v.end(), xy.begin());
      // Radiance's own primaries (white E) are what a file without the line has: taken alike.
      const std::array<double, 8> radiance = {0.640, 0.330, 0.290,     0.600,
                                              0.150, 0.060, 1.0 / 3.0, 1.0 / 3.0};
      bool standard = true;
      for (size_t k = 0; k < 8; ++k) standard = standard && std::abs(xy[k] - radiance[k]) < 2e-3;
      header.primaries = standard ? std::nullopt : std::optional(xy);
    }
  }
  return header;
}

// Decodes the mantissas as Radiance defines them, divides the values by the header's exposures
// (and colour corrections), with a note, and takes its primaries.
void applyRadianceHeader(const RadianceHeader& header, const fs::path& path, LoadedImage& out) {
  if (header.primaries) out.info.chromaticities = header.primaries;
  Image& img = out.image;
  const int n = img.channels;
  if (img.pixels.empty() || n < 3) return;
  // A mantissa m of shared exponent e is (m + 1/2) 2^(e - 136) (Ward's colr_color): writers
  // truncate. OpenImageIO decodes m 2^(e - 136), half a step low: every .hdr read 0.4 % dark
  // (0.996 of its energy through a round trip). The step q = 2^(e - 136) follows from the
  // largest channel, whose mantissa is 128..255: q = 2^(floor(log2 max) - 7), exactly.
  for (size_t i = 0; i < img.pixelCount(); ++i) {
    float* p = img.pixels.data() + i * size_t(n);
    const float largest = std::max({p[0], p[1], p[2]});
    if (!(largest > 0.0f)) continue;  // exponent 0: black
    int exponent = 0;
    std::frexp(largest, &exponent);  // largest = f 2^exponent, f in [0.5, 1)
    const float half = std::ldexp(0.5f, exponent - 8);
    for (int c = 0; c < 3; ++c) p[c] += half;
  }
  const double exposure = header.exposure;
  const std::array<double, 3>& correction = header.correction;
  if (exposure == 1.0 && correction == std::array<double, 3>{1.0, 1.0, 1.0}) return;
  const float scale[3] = {float(1.0 / (exposure * correction[0])),
                          float(1.0 / (exposure * correction[1])),
                          float(1.0 / (exposure * correction[2]))};
  for (size_t i = 0; i < img.pixelCount(); ++i)
    for (int c = 0; c < 3; ++c) img.pixels[i * size_t(n) + size_t(c)] *= scale[c];
  char text[200];
  if (correction == std::array<double, 3>{1.0, 1.0, 1.0})
    std::snprintf(text, sizeof text,
                  ": the EXPOSURE of its Radiance header (%g) applied: values divided by it, the "
                  "radiance the format defines",
                  exposure);
  else
    std::snprintf(text, sizeof text,
                  ": the EXPOSURE (%g) and COLORCORR (%g %g %g) of its Radiance header applied: "
                  "values divided by them, the radiance the format defines",
                  exposure, correction[0], correction[1], correction[2]);
  out.notes.push_back(path.filename().string() + text);
}

}  // namespace

CaptureInfo captureInfoFromAttributes(int width, int height, int channels,
                                      const std::vector<ImageAttribute>& attributes) {
  CaptureInfo info;
  fillCaptureInfo({width, height, channels, "", "uint8", 8, &attributes}, info);
  return info;
}

std::optional<double> CaptureInfo::relativeExposure() const {
  if (!exposureTime) return std::nullopt;
  const double n = fNumber.value_or(1.0);
  return *exposureTime * iso.value_or(100.0) / (n * n);
}

std::string CaptureInfo::exposureAssumptions() const {
  std::string s;
  if (!iso) s += "ISO 100 (no ISO in EXIF)";
  if (!fNumber) s += std::string(s.empty() ? "" : ", ") + "f/1 (no FNumber in EXIF)";
  return s;
}

std::string CaptureInfo::camera() const {
  return trimmed(trimmed(cameraMake) + " " + trimmed(cameraModel));
}

bool looksLikeImageFile(const fs::path& path) {
  static const char* const kExtensions[] = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".exr",
                                            ".hdr", ".dng",  ".cr2", ".cr3", ".nef",  ".arw",
                                            ".orf", ".rw2",  ".raf", ".pef", ".srw",  ".heic"};
  const std::string ext = lowerExtension(path);
  for (const char* e : kExtensions)
    if (ext == e) return true;
  return false;
}

void requireColourChannels(const Image& image, const fs::path& file, const std::string& stage,
                           const std::string& what) {
  if (image.channelNames.empty()) return;
  std::string names;
  std::set<std::string> bases;  // R, G, B, Y, RY, BY present (the last part of a layered name)
  for (const std::string& n : image.channelNames) {
    names += (names.empty() ? "" : ", ") + n;
    std::string upper = n.substr(n.rfind('.') == std::string::npos ? 0 : n.rfind('.') + 1);
    for (char& c : upper) c = char(std::toupper(static_cast<unsigned char>(c)));
    bases.insert(upper);
  }
  // Two of a colour's three channels: the third cannot be made up, nor the two taken for grey (R
  // and G alone read as a grey R before). One alone is a grey image's channel, as some writers
  // name it.
  const size_t rgbCount = bases.count("R") + bases.count("G") + bases.count("B");
  const bool someRgb = rgbCount > 0;
  if (rgbCount == 2) {
    throw Error(stage,
                what +
                    " has two of the colour channels R, G, B but not the third (its channels "
                    "are " +
                    names + ")",
                file);
  }
  const bool someChroma = bases.count("RY") || bases.count("BY");
  if (!someRgb && someChroma && !(bases.count("Y") && bases.count("RY") && bases.count("BY"))) {
    throw Error(stage,
                what +
                    " has luminance-chroma channels without all of Y, RY and BY (its channels "
                    "are " +
                    names + ")",
                file);
  }
  for (const std::string& n : image.channelNames) {
    if (!isColourChannel(n)) continue;
    // Several layers with a colour and nothing to say which is the picture: refused rather than
    // read from whichever sorts first (a render's albedo.R before its beauty).
    const PictureChannels picture = pictureChannels(image);
    if (picture.ambiguous) {
      std::string layers = "'" + picture.layer.substr(0, picture.layer.size() - 1) + "'";
      for (const std::string& l : picture.otherLayers)
        layers += ", '" + (l.empty() ? l : l.substr(0, l.size() - 1)) + "'";
      const std::string first = picture.layer;
      throw Error(stage,
                  what + " has colour in several layers (" + layers +
                      ") and none is marked as the picture (bare R, G, B, a layer named beauty, "
                      "combined or rgba, or the only one with an alpha): take the one you mean "
                      "out first, e.g. oiiotool IN --ch " +
                      first + "R," + first + "G," + first + "B --chnames R,G,B -o OUT",
                  file);
    }
    return;
  }
  throw Error(stage,
              what + " has no colour channel (R, G, B or Y): its channels are " + names +
                  " (a depth or data image?)",
              file);
}

CaptureInfo readCaptureInfo(const fs::path& path, const std::string& stage, bool picturePart) {
  checkInputFile(path, stage);
  protectInput(path);
  CaptureInfo info;
  switch (kindOf(path, stage)) {
    case Kind::Exr: {
      ExrReader reader(path, stage);
      std::vector<std::string> notes;  // said when the pixels are read
      fillCaptureInfo(
          headerOf(reader.header(picturePart ? pictureExrPart(reader, path, notes) : 0)), info);
      return info;
    }
    case Kind::Jpeg: {
      // As readImage(): a JPEG libjpeg does not convert (CMYK) is OpenImageIO's, header too (its
      // EXIF rationals arrive as floats: the same file must give the same facts both ways).
      const jpeg::Decoded header = jpeg::readFile(path, true, stage);
      if (!header.header.native) break;
      fillCaptureInfo(headerOf(header.header), info);
      return info;
    }
    case Kind::Other:
      break;
  }
  std::string why;
  auto reader = oiio::module(stage, path).open(path.string(), why);
  if (!reader) throw Error(stage, "cannot read image: " + why, path);
  const oiio::Header& h = reader->header();
  if (h.width <= 0 || h.height <= 0 || h.channels <= 0)
    throw Error(stage, "image has no pixels", path);
  fillCaptureInfo(headerOf(h, attributesOf(h, path)), info);
  return info;
}

void floatsFromCodes(LoadedImage& loaded) {
  Image& image = loaded.image;
  image.pixels.resize(loaded.codes.size());
  parallelFor(0, image.height, [&](int64_t y) {
    const size_t n = size_t(image.width) * size_t(image.channels), first = size_t(y) * n;
    for (size_t i = first; i < first + n; ++i) image.pixels[i] = float(loaded.codes[i]) / 255.0f;
  });
  loaded.codes = {};
}

bool isSrgbEncoded(const std::string& space) {
  std::string s = space;
  std::transform(s.begin(), s.end(), s.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  const size_t slash = s.find('/');
  if (slash == std::string::npos) return s == "srgb";
  const std::string display = s.substr(0, slash), view = s.substr(slash + 1);
  if (view == "raw" || view == "none") return false;
  // OpenColorIO 2 configs name the encoding by the display ("sRGB - Display"), version 1 configs
  // by the view (ACES 1.2's display "ACES", view "sRGB"; nuke-default's "default/sRGB").
  return display.rfind("srgb", 0) == 0 || view.rfind("srgb", 0) == 0;
}

LoadedImage readImage(const fs::path& path, const std::string& stage, const ReadOptions& options) {
  checkInputFile(path, stage);
  protectInput(path);
  bool cmyk = false;
  switch (kindOf(path, stage)) {
    case Kind::Exr:
      return readExr(path, stage, options.picturePart);
    case Kind::Jpeg: {
      jpeg::Decoded decoded = jpeg::readFile(path, false, stage);
      if (decoded.header.native) return fromJpeg(std::move(decoded), options);
      cmyk = true;
      break;  // CMYK: OpenImageIO converts it
    }
    case Kind::Other:
      checkPng(path, stage);
      checkPfm(path, stage);
      break;
  }
  const std::optional<RadianceHeader> radiance = readRadianceHeader(path, stage);
  std::string why;
  auto reader = oiio::module(stage, path).open(path.string(), why);
  if (!reader) throw Error(stage, "cannot read image: " + why, path);
  LoadedImage out = readWithOiio(*reader, path, stage, options);
  if (radiance) applyRadianceHeader(*radiance, path, out);
  if (cmyk) {
    // OpenImageIO converts the inks the naive way whatever profile the file carries.
    out.notes.push_back(
        path.filename().string() +
        ": a CMYK JPEG: its inks are made RGB as OpenImageIO does, (1 - C)(1 - K), "
        "not as a press prints them" +
        (out.info.iccProfile.empty() ? std::string() : ", its CMYK profile not applied") +
        "; an RGB file is read as it looks");
  }
  return out;
}

void requireFinite(const Image& image, const std::filesystem::path& file, const std::string& stage,
                   const std::string& what, float limit) {
  const auto bad = std::find_if(image.pixels.begin(), image.pixels.end(), [limit](float v) {
    return !std::isfinite(v) || std::abs(v) > limit;
  });
  if (bad == image.pixels.end()) return;
  const size_t at = size_t(bad - image.pixels.begin()) / size_t(std::max(1, image.channels));
  const size_t width = size_t(std::max(1, image.width));
  const std::string where = " in " + what + " at pixel (" + std::to_string(at % width) + ", " +
                            std::to_string(at / width) + ")";
  if (std::isfinite(*bad)) {
    char text[96];
    std::snprintf(text, sizeof text, "value %g", double(*bad));
    std::string message = text + where;
    std::snprintf(text, sizeof text, " is beyond any light (more than %g): a damaged file?",
                  double(limit));
    throw Error(stage, message + text, file);
  }
  throw Error(
      stage,
      std::string(std::isnan(*bad) ? "NaN" : "infinity") + where + ": its values must be finite",
      file);
}

LoadedImage readImageFromMemory(std::span<const unsigned char> bytes, const fs::path& name,
                                const std::string& stage, const ReadOptions& options) {
  if (bytes.empty()) throw Error(stage, "image data is empty", name);
  if (kindOf(bytes.first(std::min<size_t>(4, bytes.size()))) == Kind::Jpeg) {
    jpeg::Decoded decoded = jpeg::readMemory(bytes, name, false, stage);
    if (decoded.header.native) return fromJpeg(std::move(decoded), options);
  }
  checkPng(bytes, name, stage);
  std::string why;
  auto reader =
      oiio::module(stage, name).openMemory(bytes.data(), bytes.size(), name.string(), why);
  if (!reader) throw Error(stage, "cannot read image: " + why, name);
  return readWithOiio(*reader, name, stage, options, bytes);
}

std::vector<ImageAttribute> exifAttributes(const CaptureInfo& info) {
  std::vector<ImageAttribute> a;
  if (info.exposureTime) a.push_back({"ExposureTime", *info.exposureTime});
  if (info.fNumber) a.push_back({"FNumber", *info.fNumber});
  if (info.iso) {
    // The 16-bit tag tops out at 65535: above, ISOSpeed holds the value (Exif 2.3). ISOSpeed is
    // written whatever the value: OpenImageIO 2.4's TIFF writer drops PhotographicSensitivity
    // and keeps ISOSpeed (a TIFF of ISO 400 photos was read as ISO 100: two stops off).
    const long iso = std::lround(*info.iso);
    a.push_back({"Exif:PhotographicSensitivity", int(std::min(iso, 65535L))});
    a.push_back({"Exif:SensitivityType", 3});
    a.push_back({"Exif:ISOSpeed", int(std::min(iso, long(INT32_MAX)))});
  }
  if (info.focalLengthMm) a.push_back({"Exif:FocalLength", *info.focalLengthMm});
  a.push_back({"Exif:FocalLengthIn35mmFilm",
               info.focalLength35mm ? int(std::lround(*info.focalLength35mm)) : 0});
  if (info.focalPlaneXResolution && info.focalPlaneYResolution) {
    a.push_back({"Exif:FocalPlaneXResolution", *info.focalPlaneXResolution});
    a.push_back({"Exif:FocalPlaneYResolution", *info.focalPlaneYResolution});
    a.push_back({"Exif:FocalPlaneResolutionUnit", info.focalPlaneResolutionUnit});
  }
  if (!info.cameraMake.empty()) a.push_back({"Make", info.cameraMake});
  if (!info.cameraModel.empty()) a.push_back({"Model", info.cameraModel});
  if (!info.dateTimeOriginal.empty()) {
    // "YYYY:MM:DD HH:MM:SS[.fraction]": the fraction goes to SubSecTimeOriginal.
    const std::string& t = info.dateTimeOriginal;
    const size_t dot = t.find('.');
    a.push_back({"Exif:DateTimeOriginal", t.substr(0, dot)});
    if (dot != std::string::npos) a.push_back({"Exif:SubsecTimeOriginal", t.substr(dot + 1)});
  }
  return a;
}

namespace {

bool isJpegName(const std::string& ext) {
  return ext == ".jpg" || ext == ".jpeg";
}

// Fills `values` with rows [y0, y0 + rows) of `image` as `sample`s: integers as OpenImageIO
// converts floats to them, halves as Imath rounds them. Rows on every core.
void convertRows(const Image& image, int y0, int rows, oiio::Sample sample, void* values) {
  const size_t rowValues = size_t(image.width) * size_t(image.channels);
  parallelFor(0, rows, [&](int64_t r) {
    const float* from = image.row(y0 + int(r)).data();
    const size_t first = size_t(r) * rowValues;
    switch (sample) {
      case oiio::Sample::UInt8: {
        uint8_t* to = static_cast<uint8_t*>(values) + first;
        for (size_t i = 0; i < rowValues; ++i) to[i] = uint8_t(detail::toCode(from[i], 255.0f));
        break;
      }
      case oiio::Sample::UInt16: {
        uint16_t* to = static_cast<uint16_t*>(values) + first;
        for (size_t i = 0; i < rowValues; ++i) to[i] = uint16_t(detail::toCode(from[i], 65535.0f));
        break;
      }
      case oiio::Sample::Half: {
        Imath::half* to = static_cast<Imath::half*>(values) + first;
        for (size_t i = 0; i < rowValues; ++i) to[i] = Imath::half(from[i]);
        break;
      }
      case oiio::Sample::Float:
        std::copy_n(from, rowValues, static_cast<float*>(values) + first);
        break;
    }
  });
}

// A JPEG holds one or three channels, as OpenImageIO writes them: the first three of three or
// more, a two-channel image as luminance when its first channel is Y (else RGB with a black
// third), one as grayscale.
void writeJpeg(const fs::path& file, const fs::path& shown, const Image& image,
               const WriteOptions& options) {
  const bool gray = image.channels == 1 || (image.channels == 2 && !image.channelNames.empty() &&
                                            image.channelNames[0] == "Y");
  const int channels = gray ? 1 : 3;
  std::vector<ImageAttribute> attributes = options.attributes;
  attributes.push_back({"Software", std::string("compose")});
  if (isSrgbEncoded(image.colorSpace)) attributes.push_back({"Exif:ColorSpace", 1});
  jpeg::write(
      file, shown, image.width, image.height, channels, options.jpegQuality, attributes,
      [&](int y0, int rows, uint8_t* codes) {
        parallelFor(0, rows, [&](int64_t r) {
          const float* from = image.row(y0 + int(r)).data();
          uint8_t* to = codes + size_t(r) * size_t(image.width) * size_t(channels);
          if (image.channels == channels) {  // the file's layout already
            const size_t values = size_t(image.width) * size_t(channels);
            for (size_t i = 0; i < values; ++i) to[i] = uint8_t(detail::toCode(from[i], 255.0f));
            return;
          }
          for (int x = 0; x < image.width; ++x) {
            const float* p = from + size_t(x) * size_t(image.channels);
            for (int c = 0; c < channels; ++c) {
              const float v = c < image.channels ? p[c] : 0.0f;
              to[size_t(x) * size_t(channels) + size_t(c)] = uint8_t(detail::toCode(v, 255.0f));
            }
          }
        });
      },
      options.jpegFullChroma);
}

// Writes into `file` (a temporary); errors name `shown`, the destination the user asked for.
WriteReport writeInto(const fs::path& file, const fs::path& shown, const Image& image,
                      const WriteOptions& options) {
  COMPOSE_CHECK(image.width > 0 && image.height > 0 && image.channels > 0);
  COMPOSE_CHECK(image.pixels.size() == image.pixelCount() * size_t(image.channels));
  const std::string ext = lowerExtension(shown);
  if (ext == ".exr")
    return writeExrFile(file, shown, {ExrPart("", &image, 0, 0, 0, 0, options)}).front();
  WriteReport report;
  if (isJpegName(ext)) {
    writeJpeg(file, shown, image, options);
    return report;
  }
  oiio::WriteSpec spec;
  spec.width = image.width;
  spec.height = image.height;
  spec.channels = image.channels;
  spec.channelNames = image.channelNames;
  spec.alphaChannel = options.alphaChannel;
  // A display image says sRGB where its display is one (the PNG's sRGB chunk), not the
  // config's "display/view" name, which no reader knows.
  spec.colorSpace = isSrgbEncoded(image.colorSpace) ? "sRGB" : image.colorSpace;
  spec.jpegQuality = options.jpegQuality;
  spec.attributes = options.attributes;
  switch (options.depth) {
    case WriteOptions::Depth::Auto:
    case WriteOptions::Depth::UInt8:
      spec.sample = oiio::Sample::UInt8;
      break;
    case WriteOptions::Depth::UInt16:
      spec.sample = oiio::Sample::UInt16;
      break;
    case WriteOptions::Depth::Half:
    case WriteOptions::Depth::Float:
      spec.sample = oiio::Sample::Float;
      break;
  }
  if (options.depth == WriteOptions::Depth::Half) {
    report.largestMagnitude = detail::largestFiniteMagnitude({{&image}, {}, {}});
    if (report.largestMagnitude > kHalfMax)
      report.promotedToFloat = true;
    else
      spec.sample = oiio::Sample::Half;
  }
  std::string why;
  if (!oiio::module("output", shown)
           .write(
               file.string(), shown.string(), spec,
               [&](int y0, int rows, oiio::Sample sample, void* values) {
                 convertRows(image, y0, rows, sample, values);
               },
               why))
    throw Error("output", nameTheDestination(why, file, shown), shown);
  return report;
}

}  // namespace

void requireImageWriter(const fs::path& path, const std::string& stage) {
  const std::string ext = lowerExtension(path);
  if (ext.empty()) {
    throw Error(stage,
                "the file name has no extension to say its format (.exr, .png, .tif, .hdr, .jpg)",
                path);
  }
  if (ext != ".exr" && !isJpegName(ext) && !oiio::module(stage, path).canWrite(path.string()))
    throw Error(stage, "no image writer for the extension '" + ext + "'", path);
}

WriteReport writeImage(OutputFiles& outputs, const fs::path& path, const Image& image,
                       const WriteOptions& options) {
  requireImageWriter(path);
  return writeInto(outputs.add(path), path, image, options);
}

std::vector<WriteReport> writeExrParts(OutputFiles& outputs, const fs::path& path,
                                       const std::vector<ExrPart>& parts, const ExrHeader& header) {
  return writeExrFile(outputs.add(path), path, parts, header);
}

WriteReport writeImage(const fs::path& path, const Image& image, const WriteOptions& options) {
  OutputFiles outputs("output");
  const WriteReport report = writeImage(outputs, path, image, options);
  outputs.commit();
  return report;
}

}  // namespace compose::ingest
