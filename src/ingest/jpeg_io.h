// JPEG files read and written with libjpeg-turbo, the library OpenImageIO itself uses for them,
// with the same settings, so that the pixels are those OpenImageIO gives and writes:
//
//  * Reading: grayscale and YCbCr/RGB JPEGs (baseline or progressive) decode to 8-bit codes, one
//    or three channels, with libjpeg's defaults (islow DCT, fancy upsampling); the EXIF block
//    (exif.h) gives the attributes; the colour space is "sRGB", as OpenImageIO assumes for JPEG.
//    CMYK and YCCK files are not decoded here (`native` is false): OpenImageIO converts them.
//  * A file libjpeg had to give up on part-way (a truncated JPEG: "Premature end of JPEG file")
//    or that it found damaged, even where it could go on (corrupt entropy data), is an error,
//    not a picture with a grey bottom: OpenImageIO's reader reports the same warnings as errors.
//  * Writing: quality as asked (baseline tables), libjpeg's default 4:2:0 chroma subsampling or
//    full-resolution chroma (4:4:4, `fullChroma`),
//    a JFIF header and, when there are any, the EXIF attributes in an APP1 segment.
//
// Errors throw compose::Error with the stage and the file.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "ingest/image_io.h"

namespace compose::ingest::jpeg {

// Whether the bytes start like a JPEG file (SOI marker followed by another marker).
bool hasMagic(std::span<const unsigned char> first3);

struct Header {
  int width = 0, height = 0;
  int channels = 0;    // as decoded: 1 (grayscale) or 3 (RGB)
  bool native = true;  // false: CMYK or YCCK, or a component count libjpeg does not convert
  std::vector<ImageAttribute> attributes;  // EXIF, and "oiio:ColorSpace" = "sRGB"
};

struct Decoded {
  Header header;
  std::vector<uint8_t> codes;  // width x height x channels, interleaved, as stored (no EXIF turn)
};

// Reads the JPEG file's header (markers up to the first scan) and, unless `headerOnly`, its
// pixels (when header.native). What the header claims is checked against resourceLimits()
// before the pixels are allocated. Errors name `file` and `stage`.
Decoded readFile(const std::filesystem::path& file, bool headerOnly, const std::string& stage);
// The same for a JPEG held in memory; `name` stands for the file in errors.
Decoded readMemory(std::span<const unsigned char> bytes, const std::filesystem::path& name,
                   bool headerOnly, const std::string& stage);

// Writes a JPEG of width x height pixels of `channels` (1 or 3) 8-bit codes into `file`:
// `rows(firstRow, rowCount, codes)` fills the codes of the rows asked for (interleaved), a band
// at a time. `attributes` go into the EXIF block. Chroma is subsampled 2 x 2 (4:2:0, as cameras
// and OpenImageIO write), or kept at full resolution (`fullChroma`, 4:4:4). Errors name `shown`.
void write(const std::filesystem::path& file, const std::filesystem::path& shown, int width,
           int height, int channels, int quality, const std::vector<ImageAttribute>& attributes,
           const std::function<void(int, int, uint8_t*)>& rows, bool fullChroma = false);

}  // namespace compose::ingest::jpeg
