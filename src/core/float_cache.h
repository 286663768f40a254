// FloatCache: results kept on disk as arrays of floats, one file per key, so that a later run
// with the same inputs loads them instead of computing them again (the lighting projection, the
// visibility precompute).
//
// A file holds an 8-byte magic naming its kind and format version, a description of what it
// holds (checked on load: a different description is a miss), the count and the floats.
// Files are written to a temporary next to their final name and renamed into place, so a reader
// never sees a half-written entry. A file that is unreadable, truncated, of another kind or
// version, or does not match, is a miss; it is rewritten by the next store. Nothing here throws:
// a cache that cannot be read or written only costs time.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace compose {

class FloatCache {
 public:
  // `magic`: 8 bytes naming the kind of entry and its format version, e.g. "COMPLIT3".
  FloatCache(std::filesystem::path folder, const std::string& magic, std::string extension);

  std::filesystem::path pathFor(const std::string& key) const;
  const std::filesystem::path& folder() const { return folder_; }

  std::optional<std::vector<float>> load(const std::string& key,
                                         const std::string& description) const;
  bool store(const std::string& key, const std::string& description,
             const std::vector<float>& values) const;

 private:
  std::filesystem::path folder_;
  std::array<char, 8> magic_{};
  std::string extension_;
};

// The cache folder for a kind of entry: $COMPOSE_CACHE_DIR/<kind> when set, else
// $XDG_CACHE_HOME/compose/<kind>, else ~/.cache/compose/<kind>.
std::filesystem::path defaultCacheFolder(const std::string& kind);

}  // namespace compose
