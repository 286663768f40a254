// LightingCache: projected lighting kept on disk, so that a second run with the same environment
// and the same basis parameters loads it instead of projecting again.
//
// The key is a 128-bit hash of the environment's radiance (every texel, bit for bit), its size,
// the basis' parameterKey() (every parameter and internal constant that changes the numbers), and
// kProjectionVersion. Entries are single files named by the key, written atomically (temporary
// file + rename; core/float_cache.h), so that concurrent runs share one folder safely. A file
// that is truncated, zeroed, of an older format, damaged or does not fit the basis is ignored
// with a note for the user, and rewritten. Only bases whose exportState() returns true are cached.
//
// kProjectionVersion names the numbers a projection produces. Any change to how a cacheable basis
// projects must bump it: tests/lighting/cache_version_test.cpp holds a fingerprint of a golden
// projection for the current version and fails when the numbers move without a new version.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "core/float_cache.h"
#include "lighting/lighting.h"

namespace compose::lighting {

class LightingCache {
 public:
  static constexpr int kProjectionVersion = 3;

  explicit LightingCache(std::filesystem::path folder)
      : files_(std::move(folder), "COMPLIT6", ".lighting") {}

  static std::string key(const Environment& environment, const DiffuseLighting& basis);
  // Whether a restored basis gives finite irradiance (probed at the 26 axis and diagonal
  // directions): a state of finite numbers can still overflow when evaluated (products of
  // coefficients), which no projection of ours produces. A restored state that fails is refused.
  static bool finiteIrradiance(const DiffuseLighting& basis);
  std::filesystem::path pathFor(const std::string& key) const { return files_.pathFor(key); }

  // Restores `basis` from the entry for `key`; false on a miss or an entry that is invalid or
  // does not fit, which adds a note to `notes` (when given) saying what was wrong with which file.
  bool load(const std::string& key, DiffuseLighting& basis,
            std::vector<std::string>* notes = nullptr) const;
  // Writes the entry; false (nothing left behind) if the basis is not cacheable or the write fails,
  // which adds a note with the reason to `notes` (when given).
  bool store(const std::string& key, const DiffuseLighting& basis,
             std::vector<std::string>* notes = nullptr) const;

 private:
  FloatCache files_;
};

}  // namespace compose::lighting
