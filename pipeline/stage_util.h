// Small pieces the stage implementations share (not part of the pipeline's interface).
#pragma once

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>

#include "core/hash.h"
#include "core/image.h"

namespace compose::pipeline {

// The contents of a file, into `hash` (its name too, which can carry meaning: cube faces).
// Throws compose::Error (stage `stage`) naming the file when it cannot be read.
void hashFile(Hash128& hash, const std::filesystem::path& file, const std::string& stage);
// The hash of the file's bytes alone (its name left out), as hex: the same for a renamed copy.
std::string contentKey(const std::filesystem::path& file, const std::string& stage);
// Inputs are hashed when a job is planned and read later: a file replaced or rewritten in between
// would be cached under the key of the bytes it had (every later run with the first file would
// take the second's results). hashFile() notes each file's identity (device, inode, size,
// modification and change times) before it reads it; this throws compose::Error (stage `stage`)
// when `file` is not that file any more. Call it after reading a file the keys hashed.
void requireUnchangedSinceHashed(const std::filesystem::path& file, const std::string& stage);
// The same for a file read before it is hashed (a lighting file or an object layer, opened when
// the command is set up or loaded): fileIdentity() before reading it, requireSameFile() after
// hashing it throws compose::Error (stage `stage`) when the file at the path is not the one read.
std::string fileIdentity(const std::filesystem::path& file);
// Why the cache folder `folder` cannot hold entries, or empty when it can: the nearest part of
// its path that is there is a file, a link to nothing (a share not mounted), or cannot be
// written.
std::string cacheFolderProblem(const std::filesystem::path& folder);
void requireSameFile(const std::filesystem::path& file, const std::string& identity,
                     const std::string& stage);

inline void hashVector(Hash128& hash, const glm::dvec3& v) {
  hash.number(v.x);
  hash.number(v.y);
  hash.number(v.z);
}

// Any image made RGB from its picture's channels (core/channels.h): grey is replicated, other
// channels (alpha, other layers) are dropped.
Image toRgb(const Image& in);

// The AOV layers of a rendered object that hold colour (layer.R, .G, .B): converted with the
// object's own colour between colour spaces.
const std::vector<std::string>& colourAovLayers();

// Applies `convert` (a 3-channel image, converted in place) to the three channels of `image`
// from `first` on: a colour among other channels.
void convertChannels(Image& image, size_t first, const std::function<void(Image&)>& convert);

// A holdout mask, as stored (no colour management: it is data): its one channel, else its alpha
// (unless the alpha is opaque everywhere: a painted mask saved with an alpha it does not use),
// else its picture's first colour channel (R, or Y); `how`, when given, says which for an image of
// more than one channel. Throws compose::Error (stage "composite") naming the file when it cannot
// be read, holds a value that is not finite, or is not width x height.
Image loadHoldout(const std::filesystem::path& file, int width, int height,
                  std::string* how = nullptr, int plateOrientation = 1);
// Why a holdout mask of maskWidth x maskHeight (as shown, after its EXIF orientation) does not fit
// a plate of width x height as shown after its EXIF orientation `plateOrientation`, or empty.
std::string holdoutSizeProblem(int maskWidth, int maskHeight, int width, int height,
                               int plateOrientation);

inline double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// printf into a std::string.
template <class... Args>
std::string format(const char* pattern, Args... args) {
  char line[512];
  std::snprintf(line, sizeof line, pattern, args...);
  return line;
}

}  // namespace compose::pipeline
