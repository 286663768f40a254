#include "ingest/jpeg_io.h"

#include <algorithm>
#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>

#include <jpeglib.h>

#include "core/error.h"
#include "core/limits.h"
#include "ingest/exif.h"

namespace compose::ingest::jpeg {

namespace fs = std::filesystem;

namespace {

// libjpeg reports a fatal error through error_exit, which must not return: it jumps back to the
// setjmp of the phase that called libjpeg (below). Warnings come through emit_message: the first
// one is kept, and turns the read into an error once the phase is over.
struct ErrorManager {
  jpeg_error_mgr pub;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
  char warning[JMSG_LENGTH_MAX];
  bool warned;
};

extern "C" void onError(j_common_ptr cinfo) {
  auto* e = reinterpret_cast<ErrorManager*>(cinfo->err);
  cinfo->err->format_message(cinfo, e->message);
  std::longjmp(e->jump, 1);
}

extern "C" void onMessage(j_common_ptr cinfo, int level) {
  if (level >= 0) return;  // trace messages
  auto* e = reinterpret_cast<ErrorManager*>(cinfo->err);
  if (!e->warned) {
    cinfo->err->format_message(cinfo, e->warning);
    e->warned = true;
  }
  ++cinfo->err->num_warnings;
}

void install(ErrorManager& e, jpeg_error_mgr*& slot) {
  std::memset(&e, 0, sizeof e);
  slot = jpeg_std_error(&e.pub);
  e.pub.error_exit = onError;
  e.pub.emit_message = onMessage;
}

// The decompressor and what it reads from; destroyed whatever happened.
struct Decompressor {
  jpeg_decompress_struct cinfo;
  ErrorManager err;
  bool created = false;
  std::FILE* file = nullptr;
  Decompressor() { std::memset(&cinfo, 0, sizeof cinfo); }
  ~Decompressor() {
    if (created) jpeg_destroy_decompress(&cinfo);
    if (file) std::fclose(file);
  }
};

// The phases that call libjpeg hold no C++ objects of their own, so that a longjmp out of libjpeg
// skips no destructor. Each returns false after a fatal error (message in err.message).
bool readHeaderPhase(Decompressor& d, const unsigned char* bytes, size_t size) {
  install(d.err, d.cinfo.err);
  if (setjmp(d.err.jump)) return false;
  jpeg_create_decompress(&d.cinfo);
  d.created = true;
  if (d.file) {
    jpeg_stdio_src(&d.cinfo, d.file);
  } else {
    jpeg_mem_src(&d.cinfo, bytes, static_cast<unsigned long>(size));
  }
  jpeg_save_markers(&d.cinfo, JPEG_APP0 + 1, 0xffff);
  jpeg_save_markers(&d.cinfo, JPEG_APP0 + 2, 0xffff);  // an ICC profile
  jpeg_read_header(&d.cinfo, TRUE);
  return true;
}

bool decodePhase(Decompressor& d, uint8_t* codes, size_t rowBytes, int channels) {
  if (setjmp(d.err.jump)) return false;
  d.cinfo.out_color_space = channels == 1 ? JCS_GRAYSCALE : JCS_RGB;
  jpeg_start_decompress(&d.cinfo);
  while (d.cinfo.output_scanline < d.cinfo.output_height) {
    JSAMPROW row = codes + size_t(d.cinfo.output_scanline) * rowBytes;
    jpeg_read_scanlines(&d.cinfo, &row, 1);
  }
  jpeg_finish_decompress(&d.cinfo);
  return true;
}

Decoded read(Decompressor& d, const unsigned char* bytes, size_t size, const fs::path& file,
             bool headerOnly, const std::string& stage) {
  if (!readHeaderPhase(d, bytes, size))
    throw Error(stage, std::string("cannot read image: ") + d.err.message, file);
  // A warning in the header (stray bytes before a marker) matters only if the pixels are read.
  if (d.err.warned && !headerOnly)
    throw Error(stage, std::string("corrupt image data: ") + d.err.warning, file);
  Decoded out;
  Header& h = out.header;
  h.width = int(d.cinfo.image_width);
  h.height = int(d.cinfo.image_height);
  const J_COLOR_SPACE space = d.cinfo.jpeg_color_space;
  h.native = (d.cinfo.num_components == 1 && space == JCS_GRAYSCALE) ||
             (d.cinfo.num_components == 3 && (space == JCS_YCbCr || space == JCS_RGB));
  h.channels = d.cinfo.num_components == 1 ? 1 : 3;
  for (jpeg_saved_marker_ptr m = d.cinfo.marker_list; m; m = m->next) {
    if (m->marker == JPEG_APP0 + 1 && m->data_length >= 6 &&
        std::memcmp(m->data, "Exif\0\0", 6) == 0) {
      std::vector<ImageAttribute> exif = exif::decode({m->data + 6, m->data_length - 6});
      h.attributes.insert(h.attributes.end(), exif.begin(), exif.end());
      break;
    }
  }
  // An embedded ICC profile, in APP2 chunks "ICC_PROFILE\0", sequence number, count: its
  // description, as OpenImageIO names it.
  std::vector<std::pair<int, std::span<const unsigned char>>> chunks;
  for (jpeg_saved_marker_ptr m = d.cinfo.marker_list; m; m = m->next) {
    if (m->marker == JPEG_APP0 + 2 && m->data_length > 14 &&
        std::memcmp(m->data, "ICC_PROFILE\0", 12) == 0)
      chunks.emplace_back(m->data[12],
                          std::span<const unsigned char>(m->data + 14, m->data_length - 14));
  }
  if (!chunks.empty()) {
    std::sort(chunks.begin(), chunks.end(),
              [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<unsigned char> profile;
    for (const auto& [sequence, chunk] : chunks)
      profile.insert(profile.end(), chunk.begin(), chunk.end());
    if (const std::string description = exif::iccDescription(profile); !description.empty())
      h.attributes.push_back({"ICCProfile:profile_description", description});
  }
  h.attributes.push_back({"oiio:ColorSpace", std::string("sRGB")});
  if (h.width <= 0 || h.height <= 0) throw Error(stage, "image has no pixels", file);
  if (headerOnly || !h.native) return out;

  checkImageSize(h.width, h.height, h.channels, stage, file);
  const size_t rowBytes = size_t(h.width) * size_t(h.channels);
  out.codes.resize(rowBytes * size_t(h.height));
  if (!decodePhase(d, out.codes.data(), rowBytes, h.channels))
    throw Error(stage, std::string("cannot decode image: ") + d.err.message, file);
  if (d.err.warned) {
    const bool truncated = std::strstr(d.err.warning, "Premature end") != nullptr;
    throw Error(
        stage, std::string(truncated ? "truncated file: " : "corrupt image data: ") + d.err.warning,
        file);
  }
  return out;
}

struct Compressor {
  jpeg_compress_struct cinfo;
  ErrorManager err;
  bool created = false;
  std::FILE* file = nullptr;
  Compressor() { std::memset(&cinfo, 0, sizeof cinfo); }
  ~Compressor() {
    if (created) jpeg_destroy_compress(&cinfo);
    if (file) std::fclose(file);
  }
};

bool encodePhase(Compressor& c, int width, int height, int channels, int quality,
                 const std::vector<unsigned char>& exifBlock,
                 const std::function<void(int, int, uint8_t*)>& rows, uint8_t* band, int bandRows,
                 bool fullChroma) {
  install(c.err, c.cinfo.err);
  if (setjmp(c.err.jump)) return false;
  jpeg_create_compress(&c.cinfo);
  c.created = true;
  jpeg_stdio_dest(&c.cinfo, c.file);
  c.cinfo.image_width = JDIMENSION(width);
  c.cinfo.image_height = JDIMENSION(height);
  c.cinfo.input_components = channels;
  c.cinfo.in_color_space = channels == 1 ? JCS_GRAYSCALE : JCS_RGB;
  jpeg_set_defaults(&c.cinfo);
  jpeg_set_quality(&c.cinfo, quality, TRUE);
  if (fullChroma)
    for (int k = 0; k < c.cinfo.num_components; ++k)
      c.cinfo.comp_info[k].h_samp_factor = c.cinfo.comp_info[k].v_samp_factor = 1;
  c.cinfo.write_JFIF_header = TRUE;
  jpeg_start_compress(&c.cinfo, TRUE);
  if (!exifBlock.empty())
    jpeg_write_marker(&c.cinfo, JPEG_APP0 + 1, exifBlock.data(), unsigned(exifBlock.size()));
  const size_t rowBytes = size_t(width) * size_t(channels);
  for (int y0 = 0; y0 < height; y0 += bandRows) {
    const int n = height - y0 < bandRows ? height - y0 : bandRows;
    rows(y0, n, band);
    for (int r = 0; r < n; ++r) {
      JSAMPROW row = band + size_t(r) * rowBytes;
      jpeg_write_scanlines(&c.cinfo, &row, 1);
    }
  }
  jpeg_finish_compress(&c.cinfo);
  return true;
}

}  // namespace

bool hasMagic(std::span<const unsigned char> first3) {
  return first3.size() >= 3 && first3[0] == 0xFF && first3[1] == 0xD8 && first3[2] == 0xFF;
}

Decoded readFile(const fs::path& file, bool headerOnly, const std::string& stage) {
  Decompressor d;
  d.file = std::fopen(file.c_str(), "rb");
  if (!d.file) throw Error(stage, std::string("cannot read image: ") + std::strerror(errno), file);
  return read(d, nullptr, 0, file, headerOnly, stage);
}

Decoded readMemory(std::span<const unsigned char> bytes, const fs::path& name, bool headerOnly,
                   const std::string& stage) {
  Decompressor d;
  return read(d, bytes.data(), bytes.size(), name, headerOnly, stage);
}

void write(const fs::path& file, const fs::path& shown, int width, int height, int channels,
           int quality, const std::vector<ImageAttribute>& attributes,
           const std::function<void(int, int, uint8_t*)>& rows, bool fullChroma) {
  COMPOSE_CHECK(width > 0 && height > 0 && (channels == 1 || channels == 3));
  std::vector<unsigned char> exifBlock;
  if (std::vector<unsigned char> tiff = exif::encode(attributes); !tiff.empty()) {
    // An APP1 segment holds at most 65533 bytes; the tags written here take a few hundred.
    exifBlock = {'E', 'x', 'i', 'f', 0, 0};
    exifBlock.insert(exifBlock.end(), tiff.begin(), tiff.end());
    if (exifBlock.size() > 65533) exifBlock.clear();
  }
  // Bands of about 4 MB of codes.
  const int bandRows =
      std::max(1, std::min(height, int((size_t(4) << 20) / (size_t(width) * size_t(channels)))));
  std::vector<uint8_t> band(size_t(bandRows) * size_t(width) * size_t(channels));
  Compressor c;
  errno = 0;
  c.file = std::fopen(file.c_str(), "wb");
  if (!c.file)
    throw Error("output", std::string("cannot open for writing: ") + std::strerror(errno), shown);
  const bool ok = encodePhase(c, width, height, channels, std::clamp(quality, 1, 100), exifBlock,
                              rows, band.data(), bandRows, fullChroma);
  const int writeErrno = errno;
  if (!ok) {
    std::string why = c.err.message;
    if (writeErrno != 0) why += std::string(": ") + std::strerror(writeErrno);
    throw Error("output", "cannot write image: " + why, shown);
  }
  std::FILE* f = c.file;
  c.file = nullptr;
  const bool failed = std::ferror(f) != 0;
  if (std::fclose(f) != 0 || failed)
    throw Error("output", std::string("cannot finish writing: ") + std::strerror(errno), shown);
}

}  // namespace compose::ingest::jpeg
