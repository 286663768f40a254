// Image bytes from anywhere through our own readers: the EXIF block decoder (any bytes are a TIFF
// structure to it) and the JPEG reader over libjpeg-turbo (a file starting with a JPEG marker:
// header, EXIF, pixels, the warnings that make a damaged file an error).
//
// Input: the bytes of a file. The JPEG seeds are small real JPEGs with EXIF (corpus/image).
#include <span>

#include "core/limits.h"
#include "core/output_files.h"
#include "fuzz_util.h"
#include "ingest/exif.h"
#include "ingest/jpeg_io.h"

using namespace compose;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // Pictures of a few megapixels at most, so that one input stays within the fuzzer's memory: a
  // 689-byte progressive JPEG claiming 10256 x 25360 pixels (under the default limit) made
  // libjpeg allocate 780 MB of coefficients, and the decoded codes would take as much again.
  ResourceLimits limits;
  limits.maxPixels = int64_t(1) << 22;
  setResourceLimits(limits);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  const std::span<const unsigned char> bytes(data, size);
  for (const ingest::ImageAttribute& a : ingest::exif::decode(bytes)) {
    FUZZ_CHECK(!a.name.empty());
    if (const std::string* t = std::get_if<std::string>(&a.value)) FUZZ_CHECK(t->size() <= size);
  }
  if (!ingest::jpeg::hasMagic(bytes.first(std::min<size_t>(3, size)))) return 0;
  try {
    const ingest::jpeg::Decoded d = ingest::jpeg::readMemory(bytes, "fuzz.jpg", false, "ingest");
    FUZZ_CHECK(d.header.width > 0 && d.header.height > 0);
    FUZZ_CHECK(d.header.channels == 1 || d.header.channels == 3);
    if (d.header.native)
      FUZZ_CHECK(d.codes.size() ==
                 size_t(d.header.width) * size_t(d.header.height) * size_t(d.header.channels));
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
  return 0;
}
