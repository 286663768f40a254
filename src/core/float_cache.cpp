#include "core/float_cache.h"
#include "core/output_files.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <optional>
#include <span>

#include "core/checksum.h"
#include "core/entry_file.h"
#include "core/error.h"
#include "core/hash.h"
#include "core/parallel.h"

namespace compose {

namespace fs = std::filesystem;

namespace {

// The longest description accepted on load: anything longer is not one of ours.
constexpr uint64_t kMaxDescription = 4096;
constexpr size_t kHeaderBytes = 8 + 8;  // magic, description length
constexpr size_t kChecksumBytes = 16;

std::array<uint64_t, 2> checksum(const std::string& description, std::span<const float> values) {
  Hash128 h;
  h.bytes(description);
  h.combine(checksumFloats(values));
  return {h.a, h.b};
}

}  // namespace

FloatCache::FloatCache(fs::path folder, const std::string& magic, std::string extension)
    : folder_(std::move(folder)), extension_(std::move(extension)) {
  COMPOSE_CHECK(magic.size() == magic_.size());
  std::memcpy(magic_.data(), magic.data(), magic_.size());
}

fs::path FloatCache::pathFor(const std::string& key) const {
  return folder_ / (key + extension_);
}

FloatCache::Read FloatCache::read(const std::string& key, const std::string& description) const {
  Read r;
  auto invalid = [&](std::string problem) {
    r.status = Read::Status::Invalid;
    r.problem = std::move(problem);
    r.values.clear();
    return r;
  };
  const EntryFile file(pathFor(key));  // one descriptor, non-blocking (core/entry_file.h)
  if (!file.isOpen()) return r;        // Missing (or unreadable: the next store replaces it)
  const auto readAt = [&](void* to, size_t n, uint64_t at) { return file.readAt(to, n, at); };
  // The size first; every field is then checked against the bytes actually present.
  uint64_t size = 0;
  bool regular = false;
  if (!file.stat(size, regular))
    return invalid(std::string("cannot be read: ") + std::strerror(errno));
  if (!regular) return invalid("is not a regular file");
  if (size == 0) return invalid("is empty (0 bytes)");
  char magic[8] = {};
  if (size < kHeaderBytes || !readAt(magic, sizeof magic, 0))
    return invalid("is truncated (" + std::to_string(size) + " bytes, shorter than its header)");
  if (std::memcmp(magic, magic_.data(), sizeof magic) != 0) {
    if (std::all_of(std::begin(magic), std::end(magic), [](char c) { return c == 0; }))
      return invalid("is zeroed (no header)");
    if (std::memcmp(magic, magic_.data(), 7) == 0) {
      return invalid(std::string("is of format version '") + magic[7] +
                     "', this compose reads version '" + magic_[7] + "'");
    }
    return invalid("is not a compose cache file of this kind (unknown header)");
  }
  uint64_t length = 0, count = 0;
  if (!readAt(&length, sizeof length, sizeof magic)) return invalid("cannot be read to the end");
  if (length > kMaxDescription) return invalid("has a damaged header (description too long)");
  if (size < kHeaderBytes + length + 8)
    return invalid("is truncated (" + std::to_string(size) + " bytes)");
  std::string stored(length, '\0');
  if (!readAt(stored.data(), length, kHeaderBytes) ||
      !readAt(&count, sizeof count, kHeaderBytes + length))
    return invalid("cannot be read to the end");
  const uint64_t payload = size - (kHeaderBytes + length + 8);
  // Never trust the stored count further than the bytes present (and never multiply it first).
  if (count > payload / sizeof(float) || payload != count * sizeof(float) + kChecksumBytes) {
    return invalid("is truncated or damaged (" + std::to_string(size) + " bytes for " +
                   std::to_string(count) + " values)");
  }
  if (stored != description) return invalid("holds other contents than its name says");
  // The floats read and checksummed block by block on every core, into memory not zeroed first.
  const uint64_t valuesAt = kHeaderBytes + length + 8;
  FloatBuffer values(count);
  const std::optional<Hash128> valuesSum = readChecksummedFloats(file.fd(), valuesAt, values);
  uint64_t sum[2] = {0, 0};
  if (!valuesSum || !readAt(sum, sizeof sum, valuesAt + count * sizeof(float)))
    return invalid("cannot be read to the end");
  Hash128 expected;
  expected.bytes(description);
  expected.combine(*valuesSum);
  if (sum[0] != expected.a || sum[1] != expected.b) return invalid("fails its checksum (damaged)");
  constexpr int64_t kCheckBlock = int64_t(1) << 18;
  std::atomic<bool> finite{true};
  parallelFor(0, (int64_t(count) + kCheckBlock - 1) / kCheckBlock, [&](int64_t b) {
    const size_t first = size_t(b * kCheckBlock),
                 last = std::min(size_t(count), first + size_t(kCheckBlock));
    bool ok = true;
    for (size_t i = first; i < last; ++i) ok = ok && std::abs(values[i]) <= kMaxMagnitude;
    if (!ok) finite = false;
  });
  if (!finite) return invalid("holds a value that is not finite");
  r.status = Read::Status::Hit;
  r.values = std::move(values);
  return r;
}

std::optional<FloatBuffer> FloatCache::load(const std::string& key,
                                            const std::string& description) const {
  Read r = read(key, description);
  if (r.status != Read::Status::Hit) return std::nullopt;
  return std::move(r.values);
}

bool FloatCache::store(const std::string& key, const std::string& description,
                       const std::vector<float>& values, std::string* problem) const {
  auto fail = [&](const std::string& why) {
    if (problem) *problem = why;
    return false;
  };
  std::error_code ec;
  fs::create_directories(folder_, ec);
  if (ec) return fail("cannot create the cache folder: " + ec.message());
  const fs::path final = pathFor(key);
  static std::atomic<unsigned> counter{0};
  removeStalePartials(folder_, final.filename().string() + ".partial-");
  fs::path temp = final;
  temp += ".partial-" + std::to_string(::getpid()) + "-" + std::to_string(counter++);
  {
    errno = 0;
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    if (!out)
      return fail(std::string("cannot write into the cache folder: ") +
                  std::strerror(errno ? errno : EIO));
    const uint64_t length = description.size(), count = values.size();
    const auto sum = checksum(description, values);
    out.write(magic_.data(), std::streamsize(magic_.size()));
    out.write(reinterpret_cast<const char*>(&length), sizeof length);
    out.write(description.data(), std::streamsize(length));
    out.write(reinterpret_cast<const char*>(&count), sizeof count);
    out.write(reinterpret_cast<const char*>(values.data()),
              std::streamsize(values.size() * sizeof(float)));
    out.write(reinterpret_cast<const char*>(sum.data()), std::streamsize(sizeof sum));
    out.close();
    if (!out) {
      const int err = errno ? errno : EIO;
      fs::remove(temp, ec);
      return fail(std::string("cannot write the cache file: ") + std::strerror(err));
    }
  }
  fs::rename(temp, final, ec);
  if (ec) {
    const std::string why = ec.message();
    fs::remove(temp, ec);
    return fail("cannot move the cache file into place: " + why);
  }
  return true;
}

fs::path defaultCacheFolder(const std::string& kind) {
  if (const char* dir = std::getenv("COMPOSE_CACHE_DIR"); dir && *dir) return fs::path(dir) / kind;
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg)
    return fs::path(xdg) / "compose" / kind;
  if (const char* home = std::getenv("HOME"); home && *home)
    return fs::path(home) / ".cache" / "compose" / kind;
  return fs::path(".cache") / "compose" / kind;
}

}  // namespace compose
