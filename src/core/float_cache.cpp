#include "core/float_cache.h"

#include <unistd.h>

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <fstream>

#include "core/error.h"

namespace compose {

namespace fs = std::filesystem;

namespace {
// The longest description accepted on load: anything longer is not one of ours.
constexpr uint64_t kMaxDescription = 4096;
}  // namespace

FloatCache::FloatCache(fs::path folder, const std::string& magic, std::string extension)
    : folder_(std::move(folder)), extension_(std::move(extension)) {
  COMPOSE_CHECK(magic.size() == magic_.size());
  std::memcpy(magic_.data(), magic.data(), magic_.size());
}

fs::path FloatCache::pathFor(const std::string& key) const {
  return folder_ / (key + extension_);
}

std::optional<std::vector<float>> FloatCache::load(const std::string& key,
                                                   const std::string& description) const {
  std::ifstream in(pathFor(key), std::ios::binary);
  if (!in) return std::nullopt;
  char magic[8];
  uint64_t length = 0, count = 0;
  if (!in.read(magic, sizeof magic) || std::memcmp(magic, magic_.data(), sizeof magic) != 0)
    return std::nullopt;
  if (!in.read(reinterpret_cast<char*>(&length), sizeof length) || length > kMaxDescription)
    return std::nullopt;
  std::string stored(length, '\0');
  if (!in.read(stored.data(), std::streamsize(length)) || stored != description)
    return std::nullopt;
  if (!in.read(reinterpret_cast<char*>(&count), sizeof count)) return std::nullopt;
  // Never trust the stored count further than the bytes actually present.
  const std::streamoff here = in.tellg();
  in.seekg(0, std::ios::end);
  const std::streamoff end = in.tellg();
  in.seekg(here);
  if (here < 0 || end < here || uint64_t(end - here) != count * sizeof(float)) return std::nullopt;
  std::vector<float> values(count);
  if (!in.read(reinterpret_cast<char*>(values.data()), std::streamsize(count * sizeof(float))))
    return std::nullopt;
  return values;
}

bool FloatCache::store(const std::string& key, const std::string& description,
                       const std::vector<float>& values) const {
  std::error_code ec;
  fs::create_directories(folder_, ec);
  const fs::path final = pathFor(key);
  fs::path temp = final;
  temp += ".partial-" + std::to_string(::getpid()) + "-" +
          std::to_string(reinterpret_cast<uintptr_t>(&values) & 0xFFFF);
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    const uint64_t length = description.size(), count = values.size();
    out.write(magic_.data(), std::streamsize(magic_.size()));
    out.write(reinterpret_cast<const char*>(&length), sizeof length);
    out.write(description.data(), std::streamsize(length));
    out.write(reinterpret_cast<const char*>(&count), sizeof count);
    out.write(reinterpret_cast<const char*>(values.data()),
              std::streamsize(values.size() * sizeof(float)));
    out.close();
    if (!out) {
      fs::remove(temp, ec);
      return false;
    }
  }
  fs::rename(temp, final, ec);
  if (ec) {
    fs::remove(temp, ec);
    return false;
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
