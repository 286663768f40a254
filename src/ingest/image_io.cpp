#include "ingest/image_io.h"

#include <unistd.h>

#include <algorithm>
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

void writeImage(const fs::path& path, const Image& image, const WriteOptions& options) {
  COMPOSE_CHECK(image.width > 0 && image.height > 0 && image.channels > 0);
  COMPOSE_CHECK(image.pixels.size() == image.pixelCount() * size_t(image.channels));

  std::error_code ec;
  fs::path dir = path.parent_path();
  if (!dir.empty() && !fs::exists(dir, ec)) {
    fs::create_directories(dir, ec);
    if (ec) throw Error("output", "cannot create folder: " + ec.message(), dir);
  }

  auto output = OIIO::ImageOutput::create(path.string());
  if (!output) throw Error("output", "no image writer for this file extension", path);

  const std::string ext = lowerExtension(path);
  const bool isExr = ext == ".exr";
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
  OIIO::ImageSpec spec(image.width, image.height, image.channels, format);
  if (!image.channelNames.empty()) {
    COMPOSE_CHECK(int(image.channelNames.size()) == image.channels);
    spec.channelnames = image.channelNames;
  }
  spec.alpha_channel = options.alphaChannel;
  if (!image.colorSpace.empty()) spec.attribute("oiio:ColorSpace", image.colorSpace);
  spec.attribute("Software", "compose");
  if (isExr) spec.attribute("compression", "zip");
  if (ext == ".jpg" || ext == ".jpeg") {
    spec.attribute("Compression", std::string("jpeg:").append(std::to_string(options.jpegQuality)));
  }

  // Same folder, so that the final rename cannot cross file systems.
  fs::path temp = path;
  std::string tempName = path.filename().string();
  tempName.insert(tempName.begin(), '.');
  tempName.append(".partial-").append(std::to_string(::getpid()));
  temp.replace_filename(tempName);
  auto fail = [&](const std::string& what) {
    std::string why = output->geterror();
    output.reset();
    fs::remove(temp, ec);
    throw Error("output", what + (why.empty() ? "" : ": " + why), path);
  };
  if (!output->open(temp.string(), spec)) fail("cannot open for writing");
  if (!output->write_image(OIIO::TypeDesc::FLOAT, image.pixels.data())) fail("cannot write image");
  if (!output->close()) fail("cannot finish writing");
  output.reset();
  fs::rename(temp, path, ec);
  if (ec) {
    fs::remove(temp, ec);
    throw Error("output", "cannot move the finished file into place", path);
  }
}

}  // namespace compose::ingest
