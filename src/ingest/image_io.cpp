#include "ingest/image_io.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <system_error>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include "core/error.h"

namespace compose::ingest {

namespace fs = std::filesystem;

namespace {

std::optional<double> floatAttribute(const OIIO::ImageSpec& spec, const char* name) {
  const OIIO::ParamValue* p = spec.find_attribute(name);
  if (!p) return std::nullopt;
  double v = double(spec.get_float_attribute(name, -1.0f));
  if (!(v > 0.0)) return std::nullopt;
  return v;
}

std::string lowerExtension(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

}  // namespace

LoadedImage readImage(const fs::path& path, const std::string& stage) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error(stage, "file not found", path);
  if (fs::is_directory(path, ec)) throw Error(stage, "is a folder, expected an image file", path);

  auto input = OIIO::ImageInput::open(path.string());
  if (!input) {
    std::string why = OIIO::geterror();
    if (why.empty()) why = "unknown reason";
    throw Error(stage, "cannot read image: " + why, path);
  }
  const OIIO::ImageSpec fileSpec = input->spec();
  LoadedImage out;
  CaptureInfo& info = out.info;
  info.format = input->format_name();
  input->close();

  OIIO::ImageBuf buf(path.string());
  if (!buf.read(0, 0, /*force=*/true, OIIO::TypeDesc::FLOAT) || buf.has_error()) {
    throw Error(stage, "cannot decode image: " + buf.geterror(), path);
  }
  const OIIO::ImageSpec& spec = buf.spec();
  if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0) {
    throw Error(stage, "image has no pixels", path);
  }
  info.fileWidth = spec.width;
  info.fileHeight = spec.height;
  info.orientation = spec.get_int_attribute("Orientation", 1);
  info.exposureTime = floatAttribute(spec, "ExposureTime");
  info.fNumber = floatAttribute(spec, "FNumber");
  info.iso = floatAttribute(spec, "Exif:PhotographicSensitivity");
  if (!info.iso) info.iso = floatAttribute(spec, "Exif:ISOSpeedRatings");
  info.focalLengthMm = floatAttribute(spec, "Exif:FocalLength");
  info.focalLength35mm = floatAttribute(spec, "Exif:FocalLengthIn35mmFilm");
  info.cameraMake = spec.get_string_attribute("Make");
  info.cameraModel = spec.get_string_attribute("Model");
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
  (void)fileSpec;

  if (info.orientation != 1) {
    OIIO::ImageBuf upright = OIIO::ImageBufAlgo::reorient(buf);
    if (upright.has_error())
      throw Error(stage, "cannot apply EXIF orientation: " + upright.geterror(), path);
    buf = std::move(upright);
  }

  const OIIO::ImageSpec& s = buf.spec();
  Image& img = out.image;
  img = Image(s.width, s.height, s.nchannels);
  for (int c = 0; c < s.nchannels; ++c) img.channelNames.push_back(s.channel_name(c));
  img.colorSpace = info.fileColorSpace;
  OIIO::ROI roi(s.x, s.x + s.width, s.y, s.y + s.height, 0, 1, 0, s.nchannels);
  if (!buf.get_pixels(roi, OIIO::TypeDesc::FLOAT, img.pixels.data())) {
    throw Error(stage, "cannot decode image: " + buf.geterror(), path);
  }
  return out;
}

namespace {

// The pixel format for `image` under `options`, and whether a half request became float.
OIIO::TypeDesc pixelFormat(const Image& image, const WriteOptions& options, bool isExr,
                           WriteReport& report) {
  OIIO::TypeDesc format = OIIO::TypeDesc::UINT8;
  switch (options.depth) {
    case WriteOptions::Depth::Auto:
      format = isExr ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::UINT8;
      break;
    case WriteOptions::Depth::UInt8:
      format = OIIO::TypeDesc::UINT8;
      break;
    case WriteOptions::Depth::Half:
      format = OIIO::TypeDesc::HALF;
      break;
    case WriteOptions::Depth::Float:
      format = OIIO::TypeDesc::FLOAT;
      break;
  }
  if (format == OIIO::TypeDesc::HALF) {
    for (float v : image.pixels) {
      if (std::isfinite(v))
        report.largestMagnitude = std::max(report.largestMagnitude, std::abs(v));
    }
    if (report.largestMagnitude > kHalfMax) {
      format = OIIO::TypeDesc::FLOAT;
      report.promotedToFloat = true;
    }
  }
  return format;
}

void describeExr(OIIO::ImageSpec& spec, const Image& image, const WriteOptions& options) {
  spec.attribute("compression", "zip");
  if (!image.colorSpace.empty()) spec.attribute("colorSpace", image.colorSpace);
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

  auto output = OIIO::ImageOutput::create(shown.string());
  if (!output) throw Error("output", "no image writer for this file extension", shown);

  const std::string ext = lowerExtension(shown);
  const bool isExr = ext == ".exr";
  WriteReport report;
  OIIO::TypeDesc format = OIIO::TypeDesc::UINT8;
  switch (options.depth) {
    case WriteOptions::Depth::Auto:
      format = isExr ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::UINT8;
      break;
    case WriteOptions::Depth::UInt8:
      format = OIIO::TypeDesc::UINT8;
      break;
    case WriteOptions::Depth::Half:
      format = OIIO::TypeDesc::HALF;
      break;
    case WriteOptions::Depth::Float:
      format = OIIO::TypeDesc::FLOAT;
      break;
  }
  if (format == OIIO::TypeDesc::HALF) {
    for (float v : image.pixels) {
      if (std::isfinite(v))
        report.largestMagnitude = std::max(report.largestMagnitude, std::abs(v));
    }
    if (report.largestMagnitude > kHalfMax) {
      format = OIIO::TypeDesc::FLOAT;
      report.promotedToFloat = true;
    }
  }
  OIIO::ImageSpec spec(image.width, image.height, image.channels, format);
  if (!image.channelNames.empty()) {
    COMPOSE_CHECK(int(image.channelNames.size()) == image.channels);
    spec.channelnames = image.channelNames;
  }
  spec.alpha_channel = options.alphaChannel;
  if (!image.colorSpace.empty()) spec.attribute("oiio:ColorSpace", image.colorSpace);
  spec.attribute("Software", "compose");
  if (isExr) describeExr(spec, image, options);
  if (ext == ".jpg" || ext == ".jpeg") {
    spec.attribute("Compression", std::string("jpeg:").append(std::to_string(options.jpegQuality)));
  }
  auto fail = [&](const std::string& what) {
    std::string why = output->geterror();
    if (why.empty() && errno != 0) why = std::strerror(errno);
    output.reset();
    throw Error("output", what + (why.empty() ? "" : ": " + why), shown);
  };
  errno = 0;
  if (!output->open(file.string(), spec)) fail("cannot open for writing");
  if (!output->write_image(OIIO::TypeDesc::FLOAT, image.pixels.data())) fail("cannot write image");
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
  std::vector<OIIO::ImageSpec> specs;
  for (size_t i = 0; i < parts.size(); ++i) {
    const ExrPart& part = parts[i];
    const Image& image = *part.image;
    COMPOSE_CHECK(image.width > 0 && image.height > 0 && image.channels > 0);
    const OIIO::TypeDesc format = pixelFormat(image, part.options, true, reports[i]);
    OIIO::ImageSpec spec(image.width, image.height, image.channels, format);
    spec.x = part.x;
    spec.y = part.y;
    spec.full_x = 0;
    spec.full_y = 0;
    spec.full_width = part.fullWidth > 0 ? part.fullWidth : image.width;
    spec.full_height = part.fullHeight > 0 ? part.fullHeight : image.height;
    if (!image.channelNames.empty()) spec.channelnames = image.channelNames;
    spec.alpha_channel = part.options.alphaChannel;
    spec.attribute("name", part.name);
    spec.attribute("Software", "compose");
    describeExr(spec, image, part.options);
    for (const auto& [name, m] : header.matrices) spec.attribute(name, OIIO::TypeMatrix, m.data());
    for (const auto& [name, value] : header.strings) spec.attribute(name, value);
    specs.push_back(std::move(spec));
  }
  const fs::path file = outputs.add(path);
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
    if (!output->write_image(OIIO::TypeDesc::FLOAT, parts[i].image->pixels.data()))
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
