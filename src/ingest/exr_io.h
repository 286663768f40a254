// OpenEXR files read and written with OpenEXR itself.
//
// The pipeline's own files (the composite, the object layer, merged and stitched environments)
// and the HDR maps it is given are OpenEXR, so they go straight through the OpenEXR library;
// OpenImageIO (image_io.h) is kept for the other formats. The files are those OpenImageIO would
// write and read the same way as OpenImageIO reads them, so that either side opens the other's:
//
//  * Channels come back in OpenImageIO's order: layer by layer (the part before the last '.'),
//    and in each layer R G B (Y) A first, then the rest by name; X Y Z first in a layer that has
//    X and Y or Z (a normal or a position). An RGBA file is therefore R, G, B, A whatever the
//    file's own (alphabetical) order.
//  * Header attributes are named as OpenImageIO names them: expTime is "ExposureTime", aperture
//    "FNumber", capDate "DateTime", owner "Copyright", comments "ImageDescription",
//    pixelAspectRatio "PixelAspectRatio", xDensity "XResolution", chunkCount and
//    dwaCompressionLevel get the "openexr:" prefix; the rest keep their names. Every file also
//    gets "oiio:ColorSpace" = "Linear", as OpenImageIO assumes for OpenEXR. Writing maps the same
//    names back, drops OpenImageIO's own "oiio:" attributes, and writes 16-float attributes as
//    4x4 matrices.
//  * Pixels are read as 32-bit float from any channel type (half, float, uint); scanline and tiled
//    parts (the highest-resolution level of a mipmapped file) alike. Deep parts and subsampled
//    channels are refused with an error, as OpenImageIO refuses them.
//
// Threads: OpenEXR compresses and decompresses blocks of scanlines on its own thread pool, given as
// many threads as oneTBB may use. Errors throw compose::Error naming the file.
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <OpenEXR/ImfForward.h>

#include "core/image.h"
#include "ingest/image_io.h"

namespace compose::ingest {

// Whether the file starts with OpenEXR's magic number (false when it cannot be read).
bool hasExrMagic(const std::filesystem::path& file);

// The header of one part of an OpenEXR file.
struct ExrPartHeader {
  std::string name;                       // the part's name; empty when it has none
  int x = 0, y = 0;                       // the data window's top left, in the display window
  int width = 0, height = 0;              // the data window's size (the pixels stored)
  int fullWidth = 0, fullHeight = 0;      // the display window's size
  std::vector<std::string> channelNames;  // in OpenImageIO's order (above)
  std::string sampleType;                 // the widest channel type: "half", "float" or "uint"
  bool tiled = false;
  std::vector<ImageAttribute> attributes;  // named as OpenImageIO names them (above)

  // The attribute of this name (case-insensitive, as OpenImageIO looks them up), or null.
  const ImageAttribute* find(const std::string& attributeName) const;
};

// An OpenEXR file opened for reading: its parts' headers at once, their pixels on demand.
class ExrReader {
 public:
  // Throws compose::Error (`stage`, naming `file`) when the file cannot be opened or its header
  // is not valid OpenEXR.
  ExrReader(const std::filesystem::path& file, const std::string& stage);
  ~ExrReader();
  ExrReader(const ExrReader&) = delete;
  ExrReader& operator=(const ExrReader&) = delete;

  int parts() const;
  const ExrPartHeader& header(int part) const;
  // The part's data window as float, channels in header(part).channelNames' order, colour space
  // unset. What the header claims is checked against resourceLimits() first (core/limits.h); a
  // deep part, subsampled channels or damaged pixel data are errors.
  Image read(int part) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// OpenImageIO's names for the channels of an image that has none: Y for one channel, else R G B A,
// then channel4, channel5 ...
std::vector<std::string> defaultChannelNames(int channels);

// An OpenEXR compression, from OpenImageIO's (and oiiotool's) name for it: none, rle, zips, zip,
// piz, pxr24, b44, b44a, dwaa, dwab, with a level after a colon for zip and zips (0-9, "zip:1")
// and for dwaa and dwab (a positive number, "dwaa:45"); the name in either case.
struct ExrCompression {
  std::string name;        // in lower case, without the level
  int zipLevel = -1;       // -1: OpenEXR's default
  float dwaLevel = -1.0f;  // -1: OpenEXR's default (45)
  // Whether decoding may give other values than were written: b44, b44a, dwaa and dwab on half
  // channels (they keep float channels whole), pxr24 on float channels (it keeps 24 of their 32
  // bits; half channels whole).
  bool lossy() const;
  // Sets it on an OpenEXR header.
  void apply(Imf::Header& header) const;
};

// The compression `text` names, or nothing, with what is wrong in `why`.
std::optional<ExrCompression> parseExrCompression(const std::string& text, std::string* why);
// The names parseExrCompression() takes, for help texts.
extern const char* const kExrCompressionNames;

// Writes `parts` (see ExrPart in image_io.h) into `file` as OpenEXR: a single-part file for one
// part, a multi-part file otherwise. Returns a report per part. Errors name `shown`.
std::vector<WriteReport> writeExrFile(const std::filesystem::path& file,
                                      const std::filesystem::path& shown,
                                      const std::vector<ExrPart>& parts,
                                      const ExrHeader& header = {});

}  // namespace compose::ingest
