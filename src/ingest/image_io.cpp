#include "ingest/image_io.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <system_error>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>
#include <tbb/task_arena.h>

#include "core/error.h"
#include "core/limits.h"
#include "core/parallel.h"

namespace compose::ingest {

namespace fs = std::filesystem;

namespace {

// OpenEXR compresses and decompresses blocks of scanlines on its own thread pool; it gets as many
// threads as oneTBB may use (every core unless the process is limited), so that zlib runs on every
// core. OpenImageIO hands the number to OpenEXR when a reader or writer is created.
void useEveryCoreForExr() {
  OIIO::attribute("exr_threads", tbb::this_task_arena::max_concurrency());
}

// Opens an image file for reading. A camera raw file is developed to linear light (OpenImageIO's
// raw reader, LibRaw: the camera's white balance and colour matrix, no automatic brightening,
// Rec.709 primaries with a linear transfer), so that it comes back as scene-linear values, tagged
// "linear": what merging brackets and compositing need, rather than a display rendering.
std::unique_ptr<OIIO::ImageInput> openInput(const std::string& name) {
  OIIO::ImageSpec config;
  config.attribute("raw:ColorSpace", "linear");
  config.attribute("raw:auto_bright", 0);
  return OIIO::ImageInput::open(name, &config);
}

std::optional<double> floatAttribute(const OIIO::ImageSpec& spec, const char* name) {
  const OIIO::ParamValue* p = spec.find_attribute(name);
  if (!p) return std::nullopt;
  double v = double(spec.get_float_attribute(name, -1.0f));
  if (!(v > 0.0) || !std::isfinite(v)) return std::nullopt;
  return v;
}

std::string lowerExtension(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

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

// Fills everything but the pixels from a file's header.
void fillCaptureInfo(const OIIO::ImageSpec& spec, CaptureInfo& info) {
  info.fileWidth = spec.width;
  info.fileHeight = spec.height;
  info.channels = spec.nchannels;
  info.sampleType = spec.format.c_str();
  info.bitsPerSample = spec.get_int_attribute("oiio:BitsPerSample", int(spec.format.size()) * 8);
  info.orientation = spec.get_int_attribute("Orientation", 1);
  if (info.orientation < 1 || info.orientation > 8) info.orientation = 1;  // not an EXIF value
  info.exposureTime = floatAttribute(spec, "ExposureTime");
  info.fNumber = floatAttribute(spec, "FNumber");
  info.iso = floatAttribute(spec, "Exif:PhotographicSensitivity");
  if (!info.iso) info.iso = floatAttribute(spec, "Exif:ISOSpeedRatings");
  info.focalLengthMm = floatAttribute(spec, "Exif:FocalLength");
  info.focalPlaneXResolution = floatAttribute(spec, "Exif:FocalPlaneXResolution");
  info.focalPlaneYResolution = floatAttribute(spec, "Exif:FocalPlaneYResolution");
  info.focalPlaneResolutionUnit = spec.get_int_attribute("Exif:FocalPlaneResolutionUnit", 2);
  info.cameraMake = trimmed(spec.get_string_attribute("Make"));
  info.cameraModel = trimmed(spec.get_string_attribute("Model"));
  info.fileColorSpace = spec.get_string_attribute("oiio:ColorSpace");
  if (const std::string named = spec.get_string_attribute("colorSpace"); !named.empty())
    info.fileColorSpace = named;
  if (const OIIO::ParamValue* c = spec.find_attribute("chromaticities");
      c && c->type() == OIIO::TypeDesc(OIIO::TypeDesc::FLOAT, 8)) {
    std::array<double, 8> xy;
    const float* v = static_cast<const float*>(c->data());
    bool finite = true;
    for (size_t i = 0; i < 8; ++i) {
      xy[i] = v[i];
      finite = finite && std::isfinite(v[i]);
    }
    if (finite) info.chromaticities = xy;
  }
  info.dateTimeOriginal = trimmed(spec.get_string_attribute("Exif:DateTimeOriginal"));
  if (info.dateTimeOriginal.empty())
    info.dateTimeOriginal = trimmed(spec.get_string_attribute("DateTime"));
  info.captureSeconds =
      exifSeconds(info.dateTimeOriginal, spec.get_string_attribute("Exif:SubsecTimeOriginal"));

  info.focalLength35mm = floatAttribute(spec, "Exif:FocalLengthIn35mmFilm");
  if (info.focalLength35mm) {
    info.focal35mmSource = "EXIF FocalLengthIn35mmFilm";
  } else if (info.focalLengthMm && info.focalPlaneXResolution && info.focalPlaneYResolution &&
             unitMillimetres(info.focalPlaneResolutionUnit) > 0.0) {
    // Sensor size = image size / (pixels per unit); the 35 mm equivalent scales the focal length
    // by the ratio of diagonals (43.27 mm for the 36 x 24 mm frame).
    const double unit = unitMillimetres(info.focalPlaneResolutionUnit);
    const double w = spec.width / *info.focalPlaneXResolution * unit;
    const double h = spec.height / *info.focalPlaneYResolution * unit;
    const double diagonal = std::sqrt(w * w + h * h);
    if (diagonal > 0.5 && diagonal < 500.0) {
      info.focalLength35mm = *info.focalLengthMm * 43.266615305567875 / diagonal;
      char text[160];
      std::snprintf(text, sizeof text,
                    "derived from FocalLength %.3g mm and the focal-plane resolution (sensor "
                    "%.1f x %.1f mm)",
                    *info.focalLengthMm, w, h);
      info.focal35mmSource = text;
    }
  }
}

// The reader's own error messages (not OpenImageIO's global ones, which may be stale).
std::string readerError(OIIO::ImageInput& input) {
  return input.geterror();
}

}  // namespace

CaptureInfo captureInfoFromAttributes(int width, int height, int channels,
                                      const std::vector<ImageAttribute>& attributes) {
  OIIO::ImageSpec spec(width, height, channels, OIIO::TypeDesc::UINT8);
  for (const ImageAttribute& a : attributes) {
    if (const int* i = std::get_if<int>(&a.value)) {
      spec.attribute(a.name, *i);
    } else if (const double* d = std::get_if<double>(&a.value)) {
      spec.attribute(a.name, float(*d));
    } else if (const std::string* t = std::get_if<std::string>(&a.value)) {
      spec.attribute(a.name, *t);
    } else {
      const auto& v = std::get<std::vector<float>>(a.value);
      if (v.empty()) continue;
      spec.attribute(a.name, OIIO::TypeDesc(OIIO::TypeDesc::FLOAT, int(v.size())), v.data());
    }
  }
  CaptureInfo info;
  fillCaptureInfo(spec, info);
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

CaptureInfo readCaptureInfo(const fs::path& path, const std::string& stage) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(stage, "file not found", path);
  if (fs::is_directory(path, ec)) throw Error(stage, "is a folder, expected an image file", path);
  requireRegularFile(path, stage);
  auto input = openInput(path.string());
  if (!input) {
    std::string why = OIIO::geterror();
    if (why.empty()) why = "unknown reason";
    throw Error(stage, "cannot read image: " + why, path);
  }
  CaptureInfo info;
  info.format = input->format_name();
  const OIIO::ImageSpec& spec = input->spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0)
    throw Error(stage, "image has no pixels", path);
  fillCaptureInfo(spec, info);
  return info;
}

namespace {

// Decodes every pixel of `input` as `type` into `pixels`, orientation applied; returns the upright
// spec. Decoded with ImageInput rather than ImageBuf: the JPEG reader reports a truncated file
// only as an error message after a "successful" read, which ImageBuf drops.
template <class Vector>
OIIO::ImageSpec decode(OIIO::ImageInput& input, const OIIO::ImageSpec& spec, int orientation,
                       OIIO::TypeDesc type, Vector& pixels, const fs::path& path,
                       const std::string& stage) {
  pixels.resize(size_t(spec.width) * size_t(spec.height) * size_t(spec.nchannels));
  const bool ok = input.read_image(0, 0, 0, spec.nchannels, type, pixels.data());
  const std::string why = readerError(input);
  input.close();
  if (!ok)
    throw Error(stage, "cannot decode image: " + (why.empty() ? "unknown reason" : why), path);
  if (!why.empty()) {
    const bool truncated = why.find("Premature end") != std::string::npos;
    throw Error(stage, std::string(truncated ? "truncated file: " : "corrupt image data: ") + why,
                path);
  }
  if (orientation == 1) return spec;
  OIIO::ImageSpec stored = spec;  // keeps the Orientation attribute for reorient()
  stored.set_format(type);
  OIIO::ImageBuf buffer(stored, pixels.data());
  OIIO::ImageBuf upright = OIIO::ImageBufAlgo::reorient(buffer);
  if (upright.has_error())
    throw Error(stage, "cannot apply EXIF orientation: " + upright.geterror(), path);
  const OIIO::ImageSpec& s = upright.spec();
  Vector turned(pixels.size());
  OIIO::ROI roi(s.x, s.x + s.width, s.y, s.y + s.height, 0, 1, 0, s.nchannels);
  if (!upright.get_pixels(roi, type, turned.data()))
    throw Error(stage, "cannot apply EXIF orientation: " + upright.geterror(), path);
  pixels = std::move(turned);
  return s;
}

}  // namespace

namespace {

// Everything readImage() does once the file is open; `path` names the file in errors.
LoadedImage readOpened(OIIO::ImageInput& input, const fs::path& path, const std::string& stage,
                       const ReadOptions& options) {
  LoadedImage out;
  CaptureInfo& info = out.info;
  info.format = input.format_name();
  const OIIO::ImageSpec spec = input.spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0) {
    throw Error(stage, "image has no pixels", path);
  }
  // What the header claims, checked before a pixel buffer is allocated (core/limits.h).
  checkImageSize(spec.width, spec.height, spec.nchannels, stage, path);
  fillCaptureInfo(spec, info);

  Image& img = out.image;
  OIIO::ImageSpec upright;
  if (options.codesForEightBit && spec.format == OIIO::TypeDesc::UINT8) {
    upright = decode(input, spec, info.orientation, OIIO::TypeDesc::UINT8, out.codes, path, stage);
  } else {
    upright = decode(input, spec, info.orientation, OIIO::TypeDesc::FLOAT, img.pixels, path, stage);
  }
  img.width = upright.width;
  img.height = upright.height;
  img.channels = upright.nchannels;
  for (int c = 0; c < spec.nchannels; ++c) img.channelNames.push_back(spec.channel_name(c));
  img.colorSpace = info.fileColorSpace;
  return out;
}

}  // namespace

LoadedImage readImage(const fs::path& path, const std::string& stage, const ReadOptions& options) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(stage, "file not found", path);
  if (fs::is_directory(path, ec)) throw Error(stage, "is a folder, expected an image file", path);
  requireRegularFile(path, stage);

  useEveryCoreForExr();
  auto input = openInput(path.string());
  if (!input) {
    std::string why = OIIO::geterror();
    if (why.empty()) why = "unknown reason";
    throw Error(stage, "cannot read image: " + why, path);
  }
  return readOpened(*input, path, stage, options);
}

LoadedImage readImageFromMemory(std::span<const unsigned char> bytes, const fs::path& name,
                                const std::string& stage, const ReadOptions& options) {
  if (bytes.empty()) throw Error(stage, "image data is empty", name);
  OIIO::Filesystem::IOMemReader proxy(bytes.data(), bytes.size());
  auto input = OIIO::ImageInput::open(name.string(), nullptr, &proxy);
  if (!input) {
    std::string why = OIIO::geterror();
    if (why.empty()) why = "unknown reason";
    throw Error(stage, "cannot read image: " + why, name);
  }
  return readOpened(*input, name, stage, options);
}

std::vector<ImageAttribute> exifAttributes(const CaptureInfo& info) {
  std::vector<ImageAttribute> a;
  if (info.exposureTime) a.push_back({"ExposureTime", *info.exposureTime});
  if (info.fNumber) a.push_back({"FNumber", *info.fNumber});
  if (info.iso) a.push_back({"Exif:PhotographicSensitivity", int(std::lround(*info.iso))});
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

// The channels of one output file or part: images of one size whose channels follow one another,
// then channels of one value.
struct ChannelSources {
  std::vector<const Image*> images;
  std::vector<float> constants;

  int width() const { return images.front()->width; }
  int height() const { return images.front()->height; }
  int channels() const {
    int n = int(constants.size());
    for (const Image* image : images) n += image->channels;
    return n;
  }
};

// The largest finite magnitude among the sources' values, rows on every core.
float largestFiniteMagnitude(const ChannelSources& sources) {
  float largest = 0.0f;
  for (float v : sources.constants)
    if (std::isfinite(v)) largest = std::max(largest, std::abs(v));
  for (const Image* image : sources.images) {
    std::vector<float> rowLargest(size_t(image->height), 0.0f);
    parallelFor(0, image->height, [&](int64_t y) {
      // Branch-free, so that it vectorises: NaN and infinities fail `a <= max`.
      float m = 0.0f;
      for (float v : image->row(int(y))) {
        const float a = std::abs(v);
        m = a <= std::numeric_limits<float>::max() && a > m ? a : m;
      }
      rowLargest[size_t(y)] = m;
    });
    for (float m : rowLargest) largest = std::max(largest, m);
  }
  return largest;
}

// The pixel format for `sources` under `options`, and whether a half request became float.
OIIO::TypeDesc pixelFormat(const ChannelSources& sources, const WriteOptions& options, bool isExr,
                           WriteReport& report) {
  OIIO::TypeDesc format = OIIO::TypeDesc::UINT8;
  switch (options.depth) {
    case WriteOptions::Depth::Auto:
      format = isExr ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::UINT8;
      break;
    case WriteOptions::Depth::UInt8:
      format = OIIO::TypeDesc::UINT8;
      break;
    case WriteOptions::Depth::UInt16:
      format = OIIO::TypeDesc::UINT16;
      break;
    case WriteOptions::Depth::Half:
      format = OIIO::TypeDesc::HALF;
      break;
    case WriteOptions::Depth::Float:
      format = OIIO::TypeDesc::FLOAT;
      break;
  }
  if (format == OIIO::TypeDesc::HALF) {
    report.largestMagnitude = largestFiniteMagnitude(sources);
    if (report.largestMagnitude > kHalfMax) {
      format = OIIO::TypeDesc::FLOAT;
      report.promotedToFloat = true;
    }
  }
  return format;
}

// Writes the rows of `sources` into the current image (or part) of `output`, whose data window
// starts at row `y0`, in the pixel type the opened writer stores (which is not always the one
// asked for: Radiance HDR is always float). The conversion from float is OpenImageIO's own (so the
// values are those write_image() would store), done a band of rows at a time on every core; each
// band is then handed over in the file's format, and OpenEXR compresses its blocks of scanlines on
// its thread pool. Only one band is held converted: no full-size copy of the image is made.
bool writeRows(OIIO::ImageOutput& output, int y0, const ChannelSources& sources) {
  const OIIO::TypeDesc format = output.spec().format;
  const int width = sources.width(), height = sources.height();
  const int channels = sources.channels();
  const size_t valueBytes = format.size();
  const size_t pixelBytes = size_t(channels) * valueBytes;
  const size_t rowBytes = pixelBytes * size_t(width);
  // Bands of about 8 MB, in whole blocks of 16 scanlines (OpenEXR's ZIP block), so that every
  // band gives the compressor several blocks to work on at once.
  constexpr size_t kBandBytes = size_t(8) << 20;
  constexpr int kBlockRows = 16;
  const int bandRows = std::max(kBlockRows, int(kBandBytes / rowBytes) / kBlockRows * kBlockRows);
  std::vector<unsigned char> band(size_t(std::min(bandRows, height)) * rowBytes);
  std::vector<unsigned char> constantBytes(sources.constants.size() * valueBytes);
  if (!sources.constants.empty()) {
    OIIO::convert_pixel_values(OIIO::TypeDesc::FLOAT, sources.constants.data(), format,
                               constantBytes.data(), int(sources.constants.size()));
  }
  // One source written straight into the band; several are converted row by row and interleaved.
  const bool direct = sources.images.size() == 1 && sources.constants.empty();
  for (int r0 = 0; r0 < height; r0 += bandRows) {
    const int rows = std::min(bandRows, height - r0);
    parallelFor(0, rows, [&](int64_t r) {
      unsigned char* dst = band.data() + size_t(r) * rowBytes;
      if (direct) {
        const Image& image = *sources.images.front();
        OIIO::convert_pixel_values(OIIO::TypeDesc::FLOAT, image.row(r0 + int(r)).data(), format,
                                   dst, width * channels);
        return;
      }
      std::vector<unsigned char> converted;
      size_t offset = 0;  // of the source's first channel in a pixel, in bytes
      for (const Image* image : sources.images) {
        const size_t sourceBytes = size_t(image->channels) * valueBytes;
        converted.resize(sourceBytes * size_t(width));
        OIIO::convert_pixel_values(OIIO::TypeDesc::FLOAT, image->row(r0 + int(r)).data(), format,
                                   converted.data(), width * image->channels);
        for (int x = 0; x < width; ++x) {
          std::memcpy(dst + size_t(x) * pixelBytes + offset,
                      converted.data() + size_t(x) * sourceBytes, sourceBytes);
        }
        offset += sourceBytes;
      }
      for (int x = 0; x < width && !constantBytes.empty(); ++x)
        std::memcpy(dst + size_t(x) * pixelBytes + offset, constantBytes.data(),
                    constantBytes.size());
    });
    if (!output.write_scanlines(y0 + r0, y0 + r0 + rows, 0, format, band.data())) return false;
  }
  return true;
}

void describeExr(OIIO::ImageSpec& spec, const std::string& colorSpace,
                 const WriteOptions& options) {
  spec.attribute("compression", options.exrCompression);
  if (!colorSpace.empty()) spec.attribute("colorSpace", colorSpace);
  if (options.chromaticities) {
    float c[8];
    for (int i = 0; i < 8; ++i) c[i] = float((*options.chromaticities)[size_t(i)]);
    spec.attribute("chromaticities", OIIO::TypeDesc(OIIO::TypeDesc::FLOAT, 8), c);
  }
}

// Writes into `file` (a temporary); errors name `shown`, the destination the user asked for.
WriteReport writeInto(const fs::path& file, const fs::path& shown, const Image& image,
                      const WriteOptions& options) {
  COMPOSE_CHECK(image.width > 0 && image.height > 0 && image.channels > 0);
  COMPOSE_CHECK(image.pixels.size() == image.pixelCount() * size_t(image.channels));

  const std::string ext = lowerExtension(shown);
  const bool isExr = ext == ".exr";
  if (isExr) useEveryCoreForExr();
  auto output = OIIO::ImageOutput::create(shown.string());
  if (!output) throw Error("output", "no image writer for this file extension", shown);

  WriteReport report;
  const ChannelSources sources{{&image}, {}};
  const OIIO::TypeDesc format = pixelFormat(sources, options, isExr, report);
  OIIO::ImageSpec spec(image.width, image.height, image.channels, format);
  if (!image.channelNames.empty()) {
    COMPOSE_CHECK(int(image.channelNames.size()) == image.channels);
    spec.channelnames = image.channelNames;
  }
  spec.alpha_channel = options.alphaChannel;
  if (!image.colorSpace.empty()) spec.attribute("oiio:ColorSpace", image.colorSpace);
  spec.attribute("Software", "compose");
  if (isExr) describeExr(spec, image.colorSpace, options);
  const bool isJpeg = ext == ".jpg" || ext == ".jpeg";
  if (isJpeg) {
    spec.attribute("Compression", std::string("jpeg:").append(std::to_string(options.jpegQuality)));
  }
  for (const ImageAttribute& a : options.attributes) {
    if (const int* i = std::get_if<int>(&a.value)) {
      spec.attribute(a.name, *i);
    } else if (const double* d = std::get_if<double>(&a.value)) {
      float f = float(*d);
      // OpenImageIO 2.4's JPEG EXIF writer turns exact binary fractions (1/4, 1/64 s) into an
      // infinite rational; one step up in float avoids that and reads back as the same value.
      if (isJpeg) f = std::nextafter(f, std::numeric_limits<float>::infinity());
      spec.attribute(a.name, f);
    } else if (const std::string* t = std::get_if<std::string>(&a.value)) {
      spec.attribute(a.name, *t);
    } else {
      const auto& v = std::get<std::vector<float>>(a.value);
      spec.attribute(a.name, OIIO::TypeDesc(OIIO::TypeDesc::FLOAT, int(v.size())), v.data());
    }
  }
  auto fail = [&](const std::string& what) {
    std::string why = output->geterror();
    if (why.empty() && errno != 0) why = std::strerror(errno);
    output.reset();
    throw Error("output", what + (why.empty() ? "" : ": " + why), shown);
  };
  errno = 0;
  if (!output->open(file.string(), spec)) fail("cannot open for writing");
  if (!writeRows(*output, 0, sources)) fail("cannot write image");
  if (!output->close()) fail("cannot finish writing");
  return report;
}

}  // namespace

WriteReport writeImage(OutputFiles& outputs, const fs::path& path, const Image& image,
                       const WriteOptions& options) {
  if (!OIIO::ImageOutput::create(path.string()))
    throw Error("output", "no image writer for this file extension", path);
  return writeInto(outputs.add(path), path, image, options);
}

std::vector<WriteReport> writeExrParts(OutputFiles& outputs, const fs::path& path,
                                       const std::vector<ExrPart>& parts, const ExrHeader& header) {
  COMPOSE_CHECK(!parts.empty());
  std::vector<WriteReport> reports(parts.size());
  std::vector<ChannelSources> sources(parts.size());
  std::vector<OIIO::TypeDesc> formats(parts.size());
  std::vector<OIIO::ImageSpec> specs;
  for (size_t i = 0; i < parts.size(); ++i) {
    const ExrPart& part = parts[i];
    COMPOSE_CHECK(part.image != nullptr);
    const Image& image = *part.image;
    ChannelSources& s = sources[i];
    s.images.push_back(&image);
    for (const Image* more : part.moreImages) {
      COMPOSE_CHECK(more != nullptr && more->width == image.width && more->height == image.height);
      s.images.push_back(more);
    }
    // The channels' names: the part's own, else the images' (when every image has them).
    std::vector<std::string> names = part.channelNames;
    for (const Image* source : s.images) {
      COMPOSE_CHECK(source->width > 0 && source->height > 0 && source->channels > 0);
      COMPOSE_CHECK(source->pixels.size() == source->pixelCount() * size_t(source->channels));
      if (!part.channelNames.empty()) continue;
      if (source->channelNames.empty()) {
        names.clear();
        break;
      }
      COMPOSE_CHECK(int(source->channelNames.size()) == source->channels);
      names.insert(names.end(), source->channelNames.begin(), source->channelNames.end());
    }
    COMPOSE_CHECK(names.empty() || int(names.size()) == s.channels());
    for (const auto& [name, value] : part.constantChannels) {
      s.constants.push_back(value);
      if (!names.empty()) names.push_back(name);
    }
    formats[i] = pixelFormat(s, part.options, true, reports[i]);
    OIIO::ImageSpec spec(image.width, image.height, s.channels(), formats[i]);
    spec.x = part.x;
    spec.y = part.y;
    spec.full_x = 0;
    spec.full_y = 0;
    spec.full_width = part.fullWidth > 0 ? part.fullWidth : image.width;
    spec.full_height = part.fullHeight > 0 ? part.fullHeight : image.height;
    if (!names.empty()) spec.channelnames = names;
    spec.alpha_channel = part.options.alphaChannel;
    spec.attribute("name", part.name);
    spec.attribute("Software", "compose");
    describeExr(spec, part.colorSpace.empty() ? image.colorSpace : part.colorSpace, part.options);
    for (const auto& [name, m] : header.matrices) spec.attribute(name, OIIO::TypeMatrix, m.data());
    for (const auto& [name, value] : header.strings) spec.attribute(name, value);
    specs.push_back(std::move(spec));
  }
  const fs::path file = outputs.add(path);
  useEveryCoreForExr();
  auto output = OIIO::ImageOutput::create(path.string());
  if (!output) throw Error("output", "no image writer for this file extension", path);
  auto fail = [&](const std::string& what) {
    std::string why = output->geterror();
    if (why.empty() && errno != 0) why = std::strerror(errno);
    output.reset();
    throw Error("output", what + (why.empty() ? "" : ": " + why), path);
  };
  errno = 0;
  if (!output->open(file.string(), int(specs.size()), specs.data()))
    fail("cannot open for writing");
  for (size_t i = 0; i < parts.size(); ++i) {
    if (i > 0 && !output->open(file.string(), specs[i], OIIO::ImageOutput::AppendSubimage))
      fail("cannot start part '" + parts[i].name + "'");
    if (!writeRows(*output, specs[i].y, sources[i]))
      fail("cannot write part '" + parts[i].name + "'");
  }
  if (!output->close()) fail("cannot finish writing");
  return reports;
}

WriteReport writeImage(const fs::path& path, const Image& image, const WriteOptions& options) {
  OutputFiles outputs("output");
  const WriteReport report = writeImage(outputs, path, image, options);
  outputs.commit();
  return report;
}

}  // namespace compose::ingest
