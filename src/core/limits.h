// Resource limits: how large an input may claim to be before anything is allocated for it.
//
// A file from anywhere can claim anything in its header: an image of 100,000 x 100,000 pixels is
// a 40-byte PNG header away, and decoding it would ask for 120 GB. Every reader of ours checks
// what a header claims against these limits *before* allocating pixel buffers or triangle arrays,
// and refuses with a compose::Error that names the file, the size and the option that raises the
// limit. The limits are process-wide, like OpenImageIO's own "limits:" attributes: the front end
// sets them once (--max-pixels, --max-triangles) before any work starts, and the readers read
// them; libraries never change them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <new>
#include <string>

namespace compose {

struct ResourceLimits {
  // 2^28 = 268 million pixels: a 16384 x 16384 image, or a 32K x 8K panorama; 4.3 GB as RGBA
  // float. Larger than any photo or HDRI a camera writes today.
  static constexpr int64_t kDefaultMaxPixels = int64_t(1) << 28;
  // 50 million triangles: 10 times a dense photogrammetry scan, about 3 GB once loaded.
  static constexpr int64_t kDefaultMaxTriangles = 50'000'000;
  // A decoded image holds at most this many values per pixel of the pixel limit (RGBA), so that
  // a header claiming thousands of channels is refused as well.
  static constexpr int64_t kValuesPerPixel = 4;

  int64_t maxPixels = kDefaultMaxPixels;
  int64_t maxTriangles = kDefaultMaxTriangles;

  // Throws compose::UsageError naming the option if a limit is not positive.
  void validate() const;
};

// The limits in force for this process (the defaults until setResourceLimits is called).
const ResourceLimits& resourceLimits();
// Sets them; call before any work starts (it is not synchronised with readers on other threads).
void setResourceLimits(const ResourceLimits& limits);

// Throws compose::Error (stage `stage`, naming `file`) when an image of width x height x channels
// exceeds the limits: "image is 100000 x 100000 pixels (10000 megapixels), more than the limit of
// 268 megapixels (raise it with --max-pixels)".
void checkImageSize(int64_t width, int64_t height, int64_t channels, const std::string& stage,
                    const std::filesystem::path& file);
// The same for a mesh of `triangles` triangles (stage "mesh").
void checkTriangleCount(int64_t triangles, const std::filesystem::path& file);

// Inputs are regular files: a device (/dev/zero, /dev/urandom), a FIFO or a socket can be read
// forever or block forever. Throws compose::Error (stage `stage`, naming `file`) when `file`
// exists and is one of those ("is a character device, not a regular file"); a missing file or a
// folder is left to the caller, which has its own message for them. Symbolic links are followed.
void requireRegularFile(const std::filesystem::path& file, const std::string& stage);
// The same, with a missing file and a folder refused as well: "<what> not found", "<what> is a
// folder, not a file".
void requireInputFile(const std::filesystem::path& file, const std::string& stage,
                      const std::string& what);
// What `file` is when it exists and is neither a regular file nor a folder ("a character
// device", "a FIFO (named pipe)", ...), else nullptr. An output is written to a temporary file and
// renamed over its destination: over /dev/null that would put a file in the device's place.
const char* specialFileKind(const std::filesystem::path& file);

// Memory this process may still take: the machine's available memory (MemAvailable in
// /proc/meminfo) and, under an address-space limit (ulimit -v), what that limit leaves beside the
// address space already in use; the smaller of the two, SIZE_MAX where neither is known.
size_t allocatableBytes();

// A table whose size the user's parameters choose would not fit: thrown before it is allocated,
// as the std::bad_alloc it would otherwise become (or, with the kernel's overcommit, a process
// killed while filling it, with no message). what() says what needed how much, and how much
// there was.
class MemoryShortfall : public std::bad_alloc {
 public:
  MemoryShortfall(std::string what, size_t needed, size_t available);
  const char* what() const noexcept override { return message_.c_str(); }
  size_t needed() const { return needed_; }

 private:
  std::string message_;
  size_t needed_ = 0;
};
// Throws MemoryShortfall when `bytes` (for `what`, e.g. "the lighting's table of 1025 x 2048
// normals") exceed allocatableBytes(). Sizes below 64 MB are not checked.
void requireMemory(size_t bytes, const std::string& what);

}  // namespace compose
