#include "core/limits.h"

#include <cstdio>
#include <fstream>
#include <limits>

#include <sys/resource.h>
#include <unistd.h>

#include "core/error.h"

namespace compose {

namespace {

ResourceLimits& current() {
  static ResourceLimits limits;
  return limits;
}

std::string millions(int64_t n) {
  char text[48];
  if (n >= 10'000'000) {
    std::snprintf(text, sizeof text, "%lld", static_cast<long long>(n / 1'000'000));
  } else {
    std::snprintf(text, sizeof text, "%.3g", double(n) / 1e6);
  }
  return text;
}

}  // namespace

void ResourceLimits::validate() const {
  if (maxPixels < 1) throw UsageError("--max-pixels must be a positive number of pixels");
  if (maxTriangles < 1) throw UsageError("--max-triangles must be a positive number of triangles");
}

const ResourceLimits& resourceLimits() {
  return current();
}

void setResourceLimits(const ResourceLimits& limits) {
  limits.validate();
  current() = limits;
}

void checkImageSize(int64_t width, int64_t height, int64_t channels, const std::string& stage,
                    const std::filesystem::path& file) {
  const ResourceLimits& limits = resourceLimits();
  if (width < 1 || height < 1 || channels < 1) throw Error(stage, "image has no pixels", file);
  // width and height come from int fields, so the products below cannot overflow int64.
  const int64_t pixels = width * height;
  if (pixels > limits.maxPixels) {
    throw Error(stage,
                "image is " + std::to_string(width) + " x " + std::to_string(height) + " pixels (" +
                    millions(pixels) + " megapixels), more than the limit of " +
                    millions(limits.maxPixels) + " megapixels (raise it with --max-pixels)",
                file);
  }
  if (channels > ResourceLimits::kValuesPerPixel &&
      pixels * channels > limits.maxPixels * ResourceLimits::kValuesPerPixel) {
    throw Error(stage,
                "image is " + std::to_string(width) + " x " + std::to_string(height) +
                    " pixels of " + std::to_string(channels) +
                    " channels, more values than the limit of " + millions(limits.maxPixels) +
                    " megapixels x 4 channels (raise it with "
                    "--max-pixels)",
                file);
  }
}

void checkTriangleCount(int64_t triangles, const std::filesystem::path& file) {
  const ResourceLimits& limits = resourceLimits();
  if (triangles > limits.maxTriangles) {
    throw Error("mesh",
                "mesh has at least " + std::to_string(triangles) +
                    " triangles, more than the limit of " + std::to_string(limits.maxTriangles) +
                    " (raise it with --max-triangles)",
                file);
  }
}

const char* specialFileKind(const std::filesystem::path& file) {
  namespace fs = std::filesystem;
  std::error_code ec;
  switch (fs::status(file, ec).type()) {
    case fs::file_type::character:
      return "a character device";
    case fs::file_type::block:
      return "a block device";
    case fs::file_type::fifo:
      return "a FIFO (named pipe)";
    case fs::file_type::socket:
      return "a socket";
    case fs::file_type::unknown:
      return "of an unknown kind";
    default:
      return nullptr;  // regular, folder, missing
  }
}

void requireRegularFile(const std::filesystem::path& file, const std::string& stage) {
  const char* kind = specialFileKind(file);
  if (!kind) return;  // regular, folder, missing: the caller's concern
  throw Error(
      stage, std::string("is ") + kind + ", not a regular file (inputs are read from files)", file);
}

void requireInputFile(const std::filesystem::path& file, const std::string& stage,
                      const std::string& what) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(file, ec)) throw Error(stage, what + " not found", file);
  if (fs::is_directory(file, ec)) throw Error(stage, what + " is a folder, not a file", file);
  requireRegularFile(file, stage);
}

size_t allocatableBytes() {
  size_t out = std::numeric_limits<size_t>::max();
  std::ifstream meminfo("/proc/meminfo");
  std::string key;
  size_t kb = 0;
  std::string unit;
  while (meminfo >> key >> kb >> unit) {
    if (key == "MemAvailable:") {
      out = kb * 1024;
      break;
    }
  }
  rlimit limit{};
  if (getrlimit(RLIMIT_AS, &limit) == 0 && limit.rlim_cur != RLIM_INFINITY) {
    size_t pages = 0;
    std::ifstream statm("/proc/self/statm");
    statm >> pages;  // the address space in use, in pages
    const size_t used = pages * size_t(sysconf(_SC_PAGESIZE));
    const size_t cap = size_t(limit.rlim_cur);
    out = std::min(out, cap > used ? cap - used : 0);
  }
  return out;
}

namespace {

std::string gigabytes(size_t bytes) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f GB", double(bytes) / 1e9);
  return text;
}

}  // namespace

MemoryShortfall::MemoryShortfall(std::string what, size_t needed, size_t available)
    : message_("needs " + gigabytes(needed) + " for " + what + ", more than the " +
               gigabytes(available) + " the machine and its limits (ulimit -v) leave"),
      needed_(needed) {}

void requireMemory(size_t bytes, const std::string& what) {
  if (bytes < (size_t(64) << 20)) return;
  const size_t available = allocatableBytes();
  if (bytes > available) throw MemoryShortfall(what, bytes, available);
}

}  // namespace compose
