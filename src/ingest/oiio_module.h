// OpenImageIO, loaded when a file needs it.
//
// OpenImageIO reads and writes every format compose takes besides OpenEXR and JPEG (PNG, TIFF,
// Radiance HDR, camera raw, ...; image_io.h). Debian's build of it links some 240 libraries
// (OpenVDB, GDAL through OpenCV's video I/O, FFmpeg, DCMTK, ...), and binding their symbols takes
// the dynamic loader 0.2-0.4 s at every start of a program linked to it, more than a warm compose
// run spends on its own work. So the OpenImageIO code lives in a module of its own
// (libcompose_oiio.so), loaded on first use: a run whose files are all OpenEXR and JPEG never
// loads it.
//
// The module knows nothing of compose but this interface: plain data in and out, errors as text,
// no exceptions across it. Its entry point is the C function compose_oiio_module(). The loader
// looks for the file in $COMPOSE_OIIO_MODULE, next to the running program, in ../lib/compose
// from it, and in the build tree it was built in, in that order.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "ingest/image_io.h"

namespace compose::ingest::oiio {

// Pixel types as they cross the interface.
enum class Sample { UInt8, UInt16, Half, Float };

// A file's header as OpenImageIO reports it.
struct Header {
  int width = 0, height = 0, channels = 0;
  std::string format;      // OpenImageIO's format name ("png", "tiff", "raw", ...)
  std::string sampleType;  // the stored type ("uint8", "uint16", "half", "float", ...)
  int bitsPerSample = 0;
  bool eightBit = false;  // stored as 8-bit codes
  std::vector<std::string> channelNames;
  std::vector<ImageAttribute> attributes;  // numbers as int or double, text, float arrays
};

class Reader {
 public:
  virtual ~Reader() = default;
  virtual const Header& header() const = 0;
  // Decodes every pixel as stored (no EXIF turn) into `pixels`: width x height x channels values
  // of uint8 (`eightBit`) or float. False with `error` set when the decoder failed or reported a
  // problem (a truncated file); `truncated` tells which.
  virtual bool read(bool eightBit, void* pixels, std::string& error, bool& truncated) = 0;
};

struct WriteSpec {
  int width = 0, height = 0, channels = 0;
  std::vector<std::string> channelNames;  // empty: OpenImageIO's defaults
  Sample sample = Sample::UInt8;
  int alphaChannel = -1;
  std::string colorSpace;
  int jpegQuality = 95;
  std::vector<ImageAttribute> attributes;
};

class Module {
 public:
  virtual ~Module() = default;
  // Opens a file; camera raw files are developed to linear light (image_io.h). Null with `error`
  // set when OpenImageIO cannot read it.
  virtual std::unique_ptr<Reader> open(const std::string& path, std::string& error) = 0;
  // The same for a file held in memory (which must outlive the reader); `name` tells the format.
  virtual std::unique_ptr<Reader> openMemory(const unsigned char* bytes, size_t size,
                                             const std::string& name, std::string& error) = 0;
  // Whether OpenImageIO has a writer for this file name's extension.
  virtual bool canWrite(const std::string& name) = 0;
  // Writes an image into `file` (its format from `name`'s extension). The writer may store
  // another pixel type than asked (Radiance HDR is always float): `rows(firstRow, rowCount,
  // sample, values)` is asked for the rows in the type it stores, a band at a time. False with
  // `error` set on failure.
  virtual bool write(const std::string& file, const std::string& name, const WriteSpec& spec,
                     const std::function<void(int, int, Sample, void*)>& rows,
                     std::string& error) = 0;
};

// The module, loaded on first call. Throws compose::Error (`stage`, naming `file`, the file that
// needed it) when it cannot be loaded.
Module& module(const std::string& stage, const std::filesystem::path& file);

}  // namespace compose::ingest::oiio

extern "C" compose::ingest::oiio::Module* compose_oiio_module();
