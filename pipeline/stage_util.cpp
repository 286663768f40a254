#include "pipeline/stage_util.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <mutex>
#include <optional>
#include <vector>

#include <sys/stat.h>
#include <unistd.h>

#include "core/channels.h"
#include "core/error.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "ingest/image_io.h"
#include "pipeline/stage.h"

namespace compose::pipeline {

namespace {

// What tells one file from another at a path: another file moved over it has another inode, one
// rewritten in place another change time.
struct FileStamp {
  dev_t device = 0;
  ino_t inode = 0;
  off_t size = 0;
  int64_t modified = 0, changed = 0;  // nanoseconds
  bool operator==(const FileStamp&) const = default;
};

std::optional<FileStamp> stampOf(const std::filesystem::path& file) {
  struct stat st {};
  if (::stat(file.c_str(), &st) != 0) return std::nullopt;
  FileStamp s;
  s.device = st.st_dev;
  s.inode = st.st_ino;
  s.size = st.st_size;
  s.modified = int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
  s.changed = int64_t(st.st_ctim.tv_sec) * 1000000000 + st.st_ctim.tv_nsec;
  return s;
}

std::mutex stampsMutex;
std::map<std::string, FileStamp>& hashedStamps() {
  static std::map<std::string, FileStamp> stamps;
  return stamps;
}

std::string stampName(const std::filesystem::path& file) {
  std::error_code ec;
  const std::filesystem::path absolute = std::filesystem::absolute(file, ec);
  return (ec ? file : absolute).lexically_normal().string();
}

void hashBytes(Hash128& hash, const std::filesystem::path& file, const std::string& stage,
               bool withName) {
  protectInput(file);
  const std::optional<FileStamp> before = stampOf(file);
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) throw Error(stage, "file not found", file);
  if (std::filesystem::is_directory(file, ec)) throw Error(stage, "is a folder, not a file", file);
  requireRegularFile(file, stage);
  std::ifstream in(file, std::ios::binary);
  if (!in) {
    const int error = errno;
    throw Error(stage, std::string("cannot read: ") + std::strerror(error), file);
  }
  if (withName) hash.bytes(file.filename().string());
  std::vector<char> buffer(size_t(1) << 20);
  while (in) {
    in.read(buffer.data(), std::streamsize(buffer.size()));
    const std::streamsize n = in.gcount();
    if (n > 0) hash.data(buffer.data(), size_t(n));
  }
  if (in.bad()) throw Error(stage, "read error", file);
  if (before) {
    const std::lock_guard<std::mutex> lock(stampsMutex);
    hashedStamps()[stampName(file)] = *before;
  }
}

}  // namespace

void hashFile(Hash128& hash, const std::filesystem::path& file, const std::string& stage) {
  hashBytes(hash, file, stage, true);
}

void requireUnchangedSinceHashed(const std::filesystem::path& file, const std::string& stage) {
  std::optional<FileStamp> hashed;
  {
    const std::lock_guard<std::mutex> lock(stampsMutex);
    const auto it = hashedStamps().find(stampName(file));
    if (it == hashedStamps().end()) return;
    hashed = it->second;
  }
  if (stampOf(file) == hashed) return;
  throw Error(stage,
              "the file changed while compose ran (it is not the file whose bytes keyed the "
              "cache: replaced or rewritten since): nothing made from it was kept; run again",
              file);
}

// Why the cache folder `folder` cannot hold entries, or empty when it can: the nearest part of
// its path that is there is a file, a link to nothing (a share not mounted), or cannot be
// written. (A file there was said as "Permission denied" by --explain and "Not a directory" by
// the run; a link to nothing as "File exists", and --explain promised caching.)
std::string cacheFolderProblem(const std::filesystem::path& folder) {
  namespace fs = std::filesystem;
  fs::path at = folder;
  std::error_code ec;
  while (!fs::exists(fs::symlink_status(at, ec))) {
    if (!at.has_parent_path() || at.parent_path() == at) {
      at = at.is_relative() ? fs::path(".") : fs::path();
      break;
    }
    at = at.parent_path();
  }
  if (at.empty()) return {};
  if (fs::is_symlink(fs::symlink_status(at, ec)) && !fs::exists(fs::status(at, ec))) {
    const fs::path target = fs::read_symlink(at, ec);
    return "the cache folder " + folder.string() + " cannot be made: " + at.string() +
           " is a link to " + (ec ? std::string("something") : target.string()) +
           ", which is not there";
  }
  if (!fs::is_directory(fs::status(at, ec)))
    return "the cache folder " + folder.string() + " cannot be made: " + at.string() +
           " is a file, not a folder";
  if (::access(at.c_str(), W_OK | X_OK) != 0)
    return "the cache folder " + folder.string() + " cannot be written (" + std::strerror(errno) +
           ")";
  return {};
}

std::string fileIdentity(const std::filesystem::path& file) {
  const std::optional<FileStamp> s = stampOf(file);
  if (!s) return {};
  return std::to_string(s->device) + ":" + std::to_string(s->inode) + ":" +
         std::to_string(s->size) + ":" + std::to_string(s->modified) + ":" +
         std::to_string(s->changed);
}

void requireSameFile(const std::filesystem::path& file, const std::string& identity,
                     const std::string& stage) {
  if (!identity.empty() && fileIdentity(file) == identity) return;
  throw Error(stage,
              "the file changed while compose ran (it is not the file it read: replaced or "
              "rewritten since): nothing made from it was kept; run again",
              file);
}

std::string contentKey(const std::filesystem::path& file, const std::string& stage) {
  Hash128 hash;
  hashBytes(hash, file, stage, false);
  return hash.hex();
}

std::string holdoutSizeProblem(int maskWidth, int maskHeight, int width, int height,
                               int plateOrientation) {
  if (maskWidth == width && maskHeight == height) return {};
  std::string why = "the holdout mask is " + std::to_string(maskWidth) + "x" +
                    std::to_string(maskHeight) + ", the plate " + std::to_string(width) + "x" +
                    std::to_string(height);
  // A plate turned by its EXIF orientation, and a mask painted on its pixels as stored (by a
  // tool that does not turn it).
  const bool turned = plateOrientation >= 5 && plateOrientation <= 8;
  if (plateOrientation != 1) {
    why += " as shown (its EXIF orientation " + std::to_string(plateOrientation) + "; stored " +
           std::to_string(turned ? height : width) + "x" + std::to_string(turned ? width : height) +
           ")";
  }
  why += ": it must be the plate's size";
  if (plateOrientation != 1 && turned && maskWidth == height && maskHeight == width)
    why +=
        " as shown: turn the mask upright as the plate is shown, or tag it with the plate's "
        "orientation";
  return why;
}

Image loadHoldout(const std::filesystem::path& file, int width, int height, std::string* how,
                  int plateOrientation) {
  ingest::LoadedImage m = ingest::readImage(file, "composite");
  if (const std::string why =
          holdoutSizeProblem(m.image.width, m.image.height, width, height, plateOrientation);
      !why.empty())
    throw Error("composite", why, file);
  if (m.image.channels == 1) {
    if (m.hasPixels()) ingest::requireFinite(m.image, file, "composite", "the holdout mask");
    return std::move(m.image);
  }
  // One channel is the matte, as a compositor makes it: the alpha, unless it is opaque everywhere
  // (a painted mask saved with an alpha it does not use); else the picture's first colour
  // channel (R, or Y).
  const Image& in = m.image;
  const PictureChannels picture = pictureChannels(in);
  int channel = picture.kind == PictureChannels::Kind::ByPosition ? 0 : picture.colour[0];
  if (picture.alpha >= 0) {
    bool opaque = true;
    for (size_t i = 0; i < in.pixelCount() && opaque; ++i)
      opaque = in.pixels[i * size_t(in.channels) + size_t(picture.alpha)] >= 1.0f;
    if (!opaque) channel = picture.alpha;
  }
  const std::string name = size_t(channel) < in.channelNames.size()
                               ? in.channelNames[size_t(channel)]
                               : std::to_string(channel);
  if (how) {
    // How much of the frame it holds the plate in front over: a mask read by the wrong channel
    // shows as a matte over almost all of the frame or none of it.
    size_t over = 0;
    for (size_t i = 0; i < in.pixelCount(); ++i)
      if (in.pixels[i * size_t(in.channels) + size_t(channel)] >= 0.5f) ++over;
    char share[96];
    std::snprintf(share, sizeof share, " (the plate in front over %.1f %% of the frame)",
                  100.0 * double(over) / double(std::max<size_t>(1, in.pixelCount())));
    *how = "the holdout mask's channel " + name +
           (channel == picture.alpha ? std::string(" (its alpha)")
            : picture.alpha >= 0     ? std::string(" (its alpha is opaque everywhere)")
                                     : std::string()) +
           " is the matte" + share;
  }
  Image mask = Image::unfilled(width, height, 1, {name});
  parallelFor(0, height, [&](int64_t y) {
    for (int x = 0; x < width; ++x) mask.at(x, int(y))[0] = in.at(x, int(y))[size_t(channel)];
  });
  // Only the matte must be finite: a depth channel beside it may hold infinity where nothing is.
  ingest::requireFinite(mask, file, "composite", "the holdout mask's channel " + name);
  return mask;
}

Image toRgb(const Image& in) {
  return pictureRgb(in);
}

const std::vector<std::string>& colourAovLayers() {
  static const std::vector<std::string> layers = {"albedo", "irradiance", "irradianceShadowed"};
  return layers;
}

void convertChannels(Image& image, size_t first, const std::function<void(Image&)>& convert) {
  Image rgb(image.width, image.height, 3);
  const size_t stride = size_t(image.channels);
  for (size_t i = 0; i < image.pixelCount(); ++i)
    std::copy_n(&image.pixels[i * stride + first], 3, &rgb.pixels[3 * i]);
  convert(rgb);
  for (size_t i = 0; i < image.pixelCount(); ++i)
    std::copy_n(&rgb.pixels[3 * i], 3, &image.pixels[i * stride + first]);
}

StageParameter pathParameter(std::string name, std::string help,
                             std::filesystem::path ComposeJob::*member) {
  StageParameter p{
      name, std::move(help),
      [member](const ComposeJob& job) { return nlohmann::json((job.*member).string()); },
      [member, name](ComposeJob& job, const nlohmann::json& value) {
        if (!value.is_string()) throw UsageError(name + " must be a path (a string)");
        job.*member = value.get<std::string>();
      }};
  p.isPath = true;
  return p;
}

StageParameter textParameter(std::string name, std::string help, std::string ComposeJob::*member) {
  return {name, std::move(help),
          [member](const ComposeJob& job) { return nlohmann::json(job.*member); },
          [member, name](ComposeJob& job, const nlohmann::json& value) {
            if (!value.is_string()) throw UsageError(name + " must be a string");
            job.*member = value.get<std::string>();
          }};
}

}  // namespace compose::pipeline
