// The OpenImageIO module (oiio_module.h): built as libcompose_oiio.so, linked to OpenImageIO and
// to nothing of compose.
#include "ingest/oiio_module.h"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

namespace compose::ingest::oiio {

namespace {

// OpenImageIO's error text on one line: its readers stack a message per layer ("Read error: hit
// end of file\nPNG read error: ...\nPNG library error"); they are joined with "; ", and a
// line repeated is kept once.
std::string oneLine(const std::string& text) {
  std::string out;
  size_t start = 0;
  while (start <= text.size()) {
    size_t end = text.find('\n', start);
    if (end == std::string::npos) end = text.size();
    std::string line = text.substr(start, end - start);
    while (!line.empty() && (line.back() == '\r' || line.back() == ' ')) line.pop_back();
    if (!line.empty() && out.find(line) == std::string::npos)
      out += (out.empty() ? "" : "; ") + line;
    start = end + 1;
  }
  return out;
}

// An attribute as plain data: text, a number (int or double), or an array of floats.
void addAttribute(const OIIO::ParamValue& p, std::vector<ImageAttribute>& out) {
  const OIIO::TypeDesc t = p.type();
  const std::string name = p.name().string();
  if (t == OIIO::TypeString) {
    out.push_back({name, std::string(p.get_string())});
    return;
  }
  if (t.basetype == OIIO::TypeDesc::STRING || t.basetype == OIIO::TypeDesc::UNKNOWN ||
      t.basetype == OIIO::TypeDesc::PTR || t.basetype == OIIO::TypeDesc::NONE)
    return;
  const size_t values = size_t(t.numelements()) * size_t(t.aggregate) * size_t(p.nvalues());
  const bool rational = t == OIIO::TypeRational;
  if (values == 1 || rational) {
    const bool integral = !rational && t.basetype != OIIO::TypeDesc::FLOAT &&
                          t.basetype != OIIO::TypeDesc::DOUBLE &&
                          t.basetype != OIIO::TypeDesc::HALF;
    if (integral)
      out.push_back({name, p.get_int()});
    else
      out.push_back({name, double(p.get_float())});
    return;
  }
  // Arrays of numbers (chromaticities, matrices); byte blobs (an ICC profile) are not metadata
  // compose reads.
  if (values == 0 || values > 4096 || t.basetype == OIIO::TypeDesc::UINT8 ||
      t.basetype == OIIO::TypeDesc::INT8)
    return;
  std::vector<float> v(values);
  if (OIIO::convert_pixel_values(OIIO::TypeDesc(OIIO::TypeDesc::BASETYPE(t.basetype)), p.data(),
                                 OIIO::TypeDesc::FLOAT, v.data(), int(values)))
    out.push_back({name, std::move(v)});
}

class OiioReader final : public Reader {
 public:
  // `orientation`: the EXIF orientation of a picture the reader gives unturned although its
  // header says 1 (a camera raw file: raw:flip), 0 to take the header's.
  OiioReader(std::unique_ptr<OIIO::ImageInput> input,
             std::unique_ptr<OIIO::Filesystem::IOMemReader> proxy, int orientation = 0)
      : input_(std::move(input)), proxy_(std::move(proxy)) {
    const OIIO::ImageSpec& spec = input_->spec();
    header_.width = spec.width;
    header_.height = spec.height;
    header_.channels = spec.nchannels;
    header_.format = input_->format_name();
    header_.sampleType = spec.format.c_str();
    header_.bitsPerSample =
        spec.get_int_attribute("oiio:BitsPerSample", int(spec.format.size()) * 8);
    header_.eightBit = spec.format == OIIO::TypeDesc::UINT8;
    for (int c = 0; c < spec.nchannels; ++c) header_.channelNames.push_back(spec.channel_name(c));
    for (const OIIO::ParamValue& p : spec.extra_attribs) addAttribute(p, header_.attributes);
    if (orientation > 1) {
      std::erase_if(header_.attributes,
                    [](const ImageAttribute& a) { return a.name == "Orientation"; });
      header_.attributes.push_back({"Orientation", orientation});
    }
  }
  const Header& header() const override { return header_; }

  bool read(bool eightBit, void* pixels, std::string& error, bool& truncated) override {
    const OIIO::ImageSpec& spec = input_->spec();
    const bool ok = input_->read_image(
        0, 0, 0, spec.nchannels, eightBit ? OIIO::TypeDesc::UINT8 : OIIO::TypeDesc::FLOAT, pixels);
    // The JPEG reader reports a truncated file only as an error message after a "successful"
    // read: the message decides.
    error = oneLine(input_->geterror());
    input_->close();
    // libjpeg says "Premature end", libpng "hit end of file", libtiff "Read error ... end".
    truncated = error.find("Premature end") != std::string::npos ||
                error.find("hit end of file") != std::string::npos;
    if (!ok && error.empty()) error = "unknown reason";
    return ok && error.empty();
  }

 private:
  std::unique_ptr<OIIO::ImageInput> input_;
  std::unique_ptr<OIIO::Filesystem::IOMemReader> proxy_;
  Header header_;
};

OIIO::TypeDesc typeOf(Sample s) {
  switch (s) {
    case Sample::UInt8:
      return OIIO::TypeDesc::UINT8;
    case Sample::UInt16:
      return OIIO::TypeDesc::UINT16;
    case Sample::Half:
      return OIIO::TypeDesc::HALF;
    case Sample::Float:
      return OIIO::TypeDesc::FLOAT;
  }
  return OIIO::TypeDesc::FLOAT;
}

class OiioModule final : public Module {
 public:
  std::unique_ptr<Reader> open(const std::string& path, std::string& error) override {
    // Camera raw files developed to linear light: the camera's white balance and colour matrix,
    // no automatic brightening, Rec.709 primaries with a linear transfer.
    OIIO::ImageSpec config;
    config.attribute("raw:ColorSpace", "linear");
    config.attribute("raw:auto_bright", 0);
    // Colour as the file stores it: a PNG's or TIFF's unassociated alpha is not multiplied into
    // the display-encoded colour (which would then decode wrongly); callers that use alpha
    // premultiply in linear light.
    config.attribute("oiio:UnassociatedAlpha", 1);
    auto input = OIIO::ImageInput::open(path, &config);
    if (!input) {
      error = oneLine(OIIO::geterror());
      if (error.empty()) error = "unknown reason";
      return nullptr;
    }
    // A camera raw file held as a portrait: LibRaw turns the picture itself and OpenImageIO then
    // says Orientation 1 (the turn in raw:flip, LibRaw's code). Read unturned instead and told
    // its EXIF orientation, as a JPEG is, so that what follows the sensor (a lens calibration's
    // size, compose:sensorOrientation) knows it was turned: a portrait raw was taken for a
    // sensor of the other shape and its lens file refused.
    if (std::string(input->format_name()) == "raw") {
      // LibRaw's flip from EXIF's orientation o is "50132467"[o & 7]; the inverse.
      static constexpr int kExifFromFlip[8] = {1, 2, 4, 3, 5, 8, 6, 7};
      const int flip = input->spec().get_int_attribute("raw:flip", 0);
      if (flip > 0 && flip < 8) {
        OIIO::ImageSpec unturned = config;
        unturned.attribute("raw:user_flip", 0);
        if (auto again = OIIO::ImageInput::open(path, &unturned))
          return std::make_unique<OiioReader>(std::move(again), nullptr, kExifFromFlip[flip]);
      }
    }
    return std::make_unique<OiioReader>(std::move(input), nullptr);
  }

  std::unique_ptr<Reader> openMemory(const unsigned char* bytes, size_t size,
                                     const std::string& name, std::string& error) override {
    auto proxy = std::make_unique<OIIO::Filesystem::IOMemReader>(bytes, size);
    OIIO::ImageSpec config;
    config.attribute("oiio:UnassociatedAlpha", 1);  // as open()
    // With a configuration, the proxy goes in it.
    OIIO::Filesystem::IOProxy* io = proxy.get();
    config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &io);
    auto input = OIIO::ImageInput::open(name, &config, proxy.get());
    if (!input) {
      error = oneLine(OIIO::geterror());
      if (error.empty()) error = "unknown reason";
      return nullptr;
    }
    return std::make_unique<OiioReader>(std::move(input), std::move(proxy));
  }

  bool canWrite(const std::string& name) override {
    return OIIO::ImageOutput::create(name) != nullptr;
  }

  bool write(const std::string& file, const std::string& name, const WriteSpec& w,
             const std::function<void(int, int, Sample, void*)>& rows,
             std::string& error) override {
    auto output = OIIO::ImageOutput::create(name);
    if (!output) {
      error = "no image writer for this file extension";
      return false;
    }
    OIIO::ImageSpec spec(w.width, w.height, w.channels, typeOf(w.sample));
    if (!w.channelNames.empty()) spec.channelnames = w.channelNames;
    spec.alpha_channel = w.alphaChannel;
    if (!w.colorSpace.empty()) spec.attribute("oiio:ColorSpace", w.colorSpace);
    spec.attribute("Software", "compose");
    const std::string ext = OIIO::Filesystem::extension(name, false);
    if (ext == "jpg" || ext == "jpeg" || ext == "JPG" || ext == "JPEG")
      spec.attribute("Compression", std::string("jpeg:").append(std::to_string(w.jpegQuality)));
    for (const ImageAttribute& a : w.attributes) {
      if (const int* i = std::get_if<int>(&a.value)) {
        spec.attribute(a.name, *i);
      } else if (const double* d = std::get_if<double>(&a.value)) {
        spec.attribute(a.name, float(*d));
      } else if (const std::string* t = std::get_if<std::string>(&a.value)) {
        if (a.name == "ICCProfile")  // the profile's bytes, as OpenImageIO's writers take them
          spec.attribute(a.name, OIIO::TypeDesc(OIIO::TypeDesc::UINT8, int(t->size())), t->data());
        else
          spec.attribute(a.name, *t);
      } else {
        const auto& v = std::get<std::vector<float>>(a.value);
        spec.attribute(a.name, OIIO::TypeDesc(OIIO::TypeDesc::FLOAT, int(v.size())), v.data());
      }
    }
    auto fail = [&](const std::string& what) {
      const std::string why = oneLine(output->geterror());
      error = what + (why.empty() ? "" : ": " + why);
      if (why.empty() && errno != 0) error += std::string(": ") + std::strerror(errno);
      return false;
    };
    // OpenImageIO's PNG writer does not check its writes: a full disk left a truncated file and
    // "success". A PNG is encoded in memory and written here, every write checked; the other
    // formats are checked by errno afterwards as well.
    const size_t rawBytes =
        typeOf(w.sample).size() * size_t(w.channels) * size_t(w.width) * size_t(w.height);
    std::vector<unsigned char> encoded;
    OIIO::Filesystem::IOVecOutput inMemory(encoded);
    // Only PNG goes through memory: OpenImageIO 2.4's TIFF writer leaves a TIFF without its
    // ImageLength tag when written to an IOProxy; libtiff checks its own writes.
    const bool viaMemory = std::string(output->format_name()) == "png" &&
                           output->supports("ioproxy") && rawBytes <= (size_t(1) << 30) &&
                           output->set_ioproxy(&inMemory);
    errno = 0;
    if (!output->open(file, spec)) return fail("cannot open for writing");
    // The type the writer stores, which is not always the one asked for.
    const OIIO::TypeDesc stored = output->spec().format;
    Sample sample = Sample::Float;
    if (stored == OIIO::TypeDesc::UINT8) sample = Sample::UInt8;
    if (stored == OIIO::TypeDesc::UINT16) sample = Sample::UInt16;
    if (stored == OIIO::TypeDesc::HALF) sample = Sample::Half;
    const OIIO::TypeDesc given = typeOf(sample);
    const size_t rowBytes = given.size() * size_t(w.channels) * size_t(w.width);
    const int bandRows = std::max(1, std::min(w.height, int((size_t(8) << 20) / rowBytes)));
    std::vector<unsigned char> band(rowBytes * size_t(bandRows));
    for (int y0 = 0; y0 < w.height; y0 += bandRows) {
      const int n = std::min(bandRows, w.height - y0);
      rows(y0, n, sample, band.data());
      if (!output->write_scanlines(y0, y0 + n, 0, given, band.data()))
        return fail("cannot write image");
    }
    if (!output->close()) return fail("cannot finish writing");
    if (!viaMemory) {
      // Errors only a write gives: set by a failed write that the writer did not report.
      if (errno == ENOSPC || errno == EFBIG || errno == EDQUOT || errno == EIO) {
        error = std::string("cannot write image: ") + std::strerror(errno);
        return false;
      }
      return true;
    }
    errno = 0;
    std::FILE* f = std::fopen(file.c_str(), "wb");
    if (!f) {
      error = std::string("cannot open for writing: ") + std::strerror(errno);
      return false;
    }
    const bool written =
        std::fwrite(encoded.data(), 1, encoded.size(), f) == encoded.size() && std::fflush(f) == 0;
    const int writeError = errno;
    const bool closed = std::fclose(f) == 0;
    if (!written || !closed) {
      error = std::string("cannot write image: ") +
              std::strerror(written ? errno : (writeError ? writeError : EIO));
      return false;
    }
    return true;
  }
};

}  // namespace

}  // namespace compose::ingest::oiio

extern "C" __attribute__((visibility("default"))) compose::ingest::oiio::Module*
compose_oiio_module() {
  static compose::ingest::oiio::OiioModule module;
  return &module;
}
