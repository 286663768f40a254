// FloatCache: results kept on disk as arrays of floats, one file per key, so that a later run
// with the same inputs loads them instead of computing them again (the lighting projection, the
// visibility precompute).
//
// A file holds an 8-byte magic naming its kind (7 bytes) and format version (the last byte), a
// description of what it holds (checked on load: a different description is a miss), the count,
// the floats, and a 128-bit checksum of the description and the floats.
//
// Files are written to a temporary next to their final name (unique per process and call) and
// renamed into place, so a reader never sees a half-written entry and any number of processes
// may read and write one folder at once: the last complete write wins, and every write is
// complete. A file that is truncated, zeroed, of another format version, fails its checksum,
// holds values no computation of ours produces (NaN, Inf, beyond ±1e30), or describes other
// contents is *invalid*: read() says what is wrong, so that the caller can tell the user, and
// the next store() rewrites it. Nothing here throws: a cache that cannot be read or written only
// costs time (store() says why it failed).
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "core/buffer.h"

namespace compose {

class FloatCache {
 public:
  // `magic`: 8 bytes, the kind of entry (7) and its format version (1), e.g. "COMPLIT6".
  FloatCache(std::filesystem::path folder, const std::string& magic, std::string extension);

  std::filesystem::path pathFor(const std::string& key) const;
  const std::filesystem::path& folder() const { return folder_; }

  struct Read {
    enum class Status { Hit, Missing, Invalid } status = Status::Missing;
    FloatBuffer values;   // Hit only
    std::string problem;  // Invalid only: what is wrong with the file
  };
  Read read(const std::string& key, const std::string& description) const;

  // The values on a hit; nullopt on a miss or an invalid file.
  std::optional<FloatBuffer> load(const std::string& key, const std::string& description) const;
  // Writes the entry atomically. On failure returns false and, when `problem` is given, sets it
  // to the reason ("No space left on device", "Permission denied").
  bool store(const std::string& key, const std::string& description,
             const std::vector<float>& values, std::string* problem = nullptr) const;

  // The largest magnitude a stored value may have (radiance, moments and visibility are far
  // below it; a larger value is damage, and would overflow what is computed from it).
  static constexpr float kMaxMagnitude = 1e30f;

 private:
  std::filesystem::path folder_;
  std::array<char, 8> magic_{};
  std::string extension_;
};

// The cache folder for a kind of entry: $COMPOSE_CACHE_DIR/<kind> when set, else
// $XDG_CACHE_HOME/compose/<kind>, else ~/.cache/compose/<kind>.
std::filesystem::path defaultCacheFolder(const std::string& kind);

}  // namespace compose
