#include "cubemap/photo_header.h"

#include <OpenImageIO/imageio.h>

#include "core/error.h"

namespace compose::cubemap {

PhotoHeader readPhotoHeader(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) throw Error("ingest", "file not found", file);
  auto input = OIIO::ImageInput::open(file.string());
  if (!input) {
    std::string why = OIIO::geterror();
    throw Error("ingest",
                "cannot read image: " + (why.empty() ? std::string("unknown reason") : why), file);
  }
  const OIIO::ImageSpec& spec = input->spec();
  PhotoHeader h;
  h.width = spec.width;
  h.height = spec.height;
  const int orientation = spec.get_int_attribute("Orientation", 1);
  if (orientation >= 5 && orientation <= 8) std::swap(h.width, h.height);  // turned by 90°
  auto positive = [&](const char* name) -> std::optional<double> {
    if (!spec.find_attribute(name)) return std::nullopt;
    const double v = spec.get_float_attribute(name, -1.0f);
    return v > 0.0 ? std::optional<double>(v) : std::nullopt;
  };
  h.focalLength35mm = positive("Exif:FocalLengthIn35mmFilm");
  h.focalLengthMm = positive("Exif:FocalLength");
  h.floatingPoint = spec.format.basetype == OIIO::TypeDesc::FLOAT ||
                    spec.format.basetype == OIIO::TypeDesc::HALF ||
                    spec.format.basetype == OIIO::TypeDesc::DOUBLE;
  h.format = input->format_name();
  input->close();
  if (h.width <= 0 || h.height <= 0) throw Error("ingest", "image has no pixels", file);
  return h;
}

}  // namespace compose::cubemap
