#include "pipeline/stage_cache.h"
#include "core/output_files.h"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <climits>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <optional>

#include "core/checksum.h"
#include "core/entry_file.h"
#include "core/hash.h"
#include "core/limits.h"

namespace compose::pipeline {

namespace fs = std::filesystem;

namespace {
// The last character is the format's version (4: checksums of 64-bit words).
constexpr char kMagic[8] = {'C', 'O', 'M', 'P', 'S', 'T', 'G', '4'};
constexpr uint64_t kMaxHeader = 1 << 20;
constexpr uint64_t kChecksumBytes = 16;

std::array<uint64_t, 2> checksum(const std::string& header,
                                 const std::map<std::string, Pixels>& arrays) {
  Hash128 h;
  h.bytes(header);
  for (const auto& [name, values] : arrays) h.combine(checksumFloats(values));
  return {h.a, h.b};
}

// An entry's fixed part read and checked: its size, the magic, the header's length and JSON, the
// stage and the key it names (`key` empty: any). `problem` says what is wrong, else is empty.
struct EntryHeader {
  uint64_t size = 0;
  uint64_t end = 0;  // where the arrays begin
  std::string text;
  nlohmann::json json;
  std::string problem;
};

EntryHeader readHeader(const EntryFile& file, const std::string& stage, const std::string& key) {
  EntryHeader h;
  const auto invalid = [&](std::string why) {
    h.problem = std::move(why);
    return h;
  };
  const auto cannotRead = [&]() {
    return invalid(errno != 0 ? std::string("cannot be read: ") + std::strerror(errno)
                              : std::string("cannot be read to the end"));
  };
  // The size first; every field is then checked against the bytes actually present.
  bool regular = false;
  if (!file.stat(h.size, regular)) return cannotRead();
  if (!regular) return invalid("is not a regular file");
  if (h.size == 0) return invalid("is empty (0 bytes)");
  char magic[8] = {};
  if (h.size < sizeof magic + 8 || !file.readAt(magic, sizeof magic, 0))
    return invalid("is truncated (" + std::to_string(h.size) + " bytes, shorter than its header)");
  if (std::memcmp(magic, kMagic, sizeof magic) != 0) {
    if (std::all_of(std::begin(magic), std::end(magic), [](char c) { return c == 0; }))
      return invalid("is zeroed (no header)");
    if (std::memcmp(magic, kMagic, 7) == 0) {
      return invalid(std::string("is of format version '") + magic[7] +
                     "', this compose reads version '" + kMagic[7] + "'");
    }
    return invalid("is not a compose stage cache entry (unknown header)");
  }
  uint64_t length = 0;
  if (!file.readAt(&length, sizeof length, sizeof magic)) return cannotRead();
  if (length > kMaxHeader) return invalid("has a damaged header (header length)");
  h.end = sizeof magic + 8 + length;
  if (h.size < h.end + kChecksumBytes)
    return invalid("is truncated (" + std::to_string(h.size) + " bytes)");
  h.text.assign(length, '\0');
  if (!file.readAt(h.text.data(), length, sizeof magic + 8)) return cannotRead();
  h.json = nlohmann::json::parse(h.text, nullptr, false);
  if (h.json.is_discarded() || !h.json.is_object())
    return invalid("has a damaged header (not JSON)");
  const auto it = h.json.find("stage"), keyIt = h.json.find("key");
  if (it == h.json.end() || !it->is_string() || it->get<std::string>() != stage ||
      (!key.empty() &&
       (keyIt == h.json.end() || !keyIt->is_string() || keyIt->get<std::string>() != key)))
    return invalid("holds another stage's or key's outputs than its name says");
  return h;
}
}  // namespace

StageCache::StageCache(fs::path folder, std::string stage, std::string key)
    : stage_(std::move(stage)), key_(std::move(key)) {
  if (!folder.empty()) path_ = folder / stage_ / (key_ + ".stage");
}

StageCache StageCache::atFile(fs::path file, std::string stage) {
  StageCache entry({}, std::move(stage), "file");
  entry.path_ = std::move(file);
  entry.anyKey_ = true;
  return entry;
}

bool StageCache::exists() const {
  std::error_code ec;
  return enabled() && fs::is_regular_file(path_, ec);
}

bool StageCache::verify() {
  const bool ok = open();
  clear();
  return ok;
}

nlohmann::json StageCache::peekMeta() const {
  std::error_code ec;
  if (!enabled() || !fs::exists(path_, ec)) return nullptr;
  const EntryFile file(path_);
  if (!file.isOpen()) return nullptr;
  EntryHeader h = readHeader(file, stage_, anyKey_ ? std::string() : key_);
  if (!h.problem.empty() || !h.json.contains("meta")) return nullptr;
  return std::move(h.json["meta"]);
}

void StageCache::clear() {
  arrays_.clear();
  meta_ = nlohmann::json::object();
}

bool StageCache::open() {
  problem_.clear();
  if (!enabled()) return false;
  auto invalid = [&](std::string why) {
    problem_ = std::move(why);
    return false;
  };
  std::error_code ec;
  const fs::file_status status = fs::status(path_, ec);
  if (!fs::exists(status)) return false;  // a plain miss
  const EntryFile file(path_);            // one descriptor, non-blocking (core/entry_file.h)
  if (!file.isOpen()) return invalid(std::string("cannot be read: ") + std::strerror(errno));
  const auto cannotRead = [&]() {
    return invalid(errno != 0 ? std::string("cannot be read: ") + std::strerror(errno)
                              : std::string("cannot be read to the end"));
  };
  const auto readAt = [&](void* to, size_t n, uint64_t at) { return file.readAt(to, n, at); };
  EntryHeader h = readHeader(file, stage_, anyKey_ ? std::string() : key_);
  if (!h.problem.empty()) return invalid(std::move(h.problem));
  const uint64_t size = h.size, headerEnd = h.end;
  const std::string& text = h.text;
  const nlohmann::json& header = h.json;
  const auto text_of = [&](const char* name) {
    const auto it = header.find(name);
    return it != header.end() && it->is_string() ? it->get<std::string>() : std::string();
  };
  const auto arraysIt = header.find("arrays");
  if (arraysIt == header.end() || !arraysIt->is_array() || !header.contains("meta"))
    return invalid("has a damaged header (no arrays or meta)");
  // The stored counts never trusted further than the bytes present (and never summed blindly).
  const uint64_t payload = size - headerEnd - kChecksumBytes;
  uint64_t total = 0;
  for (const auto& a : *arraysIt) {
    if (!a.is_array() || a.size() != 2 || !a[0].is_string() || !a[1].is_number_unsigned())
      return invalid("has a damaged header (array list)");
    const uint64_t n = a[1].get<uint64_t>();
    if (n > payload / sizeof(float) - total)
      return invalid("is truncated or damaged (" + std::to_string(size) + " bytes)");
    total += n;
  }
  if (payload != total * sizeof(float))
    return invalid("is truncated or damaged (" + std::to_string(size) + " bytes for " +
                   std::to_string(total) + " values)");
  // Each array is read and checksummed in one parallel pass; the sums are combined in the order
  // write() wrote them: by name (std::map order), whatever the order in the file.
  std::map<std::string, Pixels> arrays;
  std::map<std::string, Hash128> sums;
  uint64_t at = headerEnd;
  for (const auto& a : *arraysIt) {
    const std::string name = a[0].get<std::string>();
    if (arrays.count(name)) return invalid("has a damaged header (an array named twice)");
    Pixels values(a[1].get<uint64_t>());  // not zeroed: the reading threads touch it first
    const std::optional<Hash128> sum = readChecksummedFloats(file.fd(), at, values);
    if (!sum) return cannotRead();
    at += values.size() * sizeof(float);
    sums[name] = *sum;
    arrays[name] = std::move(values);
  }
  uint64_t sum[2] = {0, 0};
  if (!readAt(sum, sizeof sum, at)) return cannotRead();
  Hash128 expected;
  expected.bytes(text);
  for (const auto& [name, s] : sums) expected.combine(s);
  if (sum[0] != expected.a || sum[1] != expected.b) return invalid("fails its checksum (damaged)");
  meta_ = header["meta"];
  arrays_ = std::move(arrays);
  if (anyKey_) key_ = text_of("key");
  return true;
}

bool StageCache::write() const {
  error_.clear();
  if (!enabled()) return false;
  auto fail = [&](std::string why) {
    error_ = std::move(why);
    return false;
  };
  std::error_code ec;
  // A bare file name (compose precompute --out x.stage) has no folder to make.
  if (!path_.parent_path().empty()) {
    fs::create_directories(path_.parent_path(), ec);
    if (ec) return fail(ec.message());
  }
  if (const char* kind = specialFileKind(path_))
    return fail(std::string("it is ") + kind + ", not a file (it would be replaced by one)");
  nlohmann::json header;
  header["stage"] = stage_;
  header["key"] = key_;
  header["meta"] = meta_;
  header["arrays"] = nlohmann::json::array();
  for (const auto& [name, values] : arrays_) header["arrays"].push_back({name, values.size()});
  const std::string text = header.dump();
  const auto sum = checksum(text, arrays_);
  static std::atomic<int> serial{0};
  // A file the user named is written through a hidden temporary beside it (".NAME.partial-PID-N",
  // hidden as OutputFiles' temporaries are): a run killed while writing it leaves nothing in view.
  // A cache entry's temporary keeps the entry's name (KEY.stage.partial-PID-N: compose cache lists
  // it as one).
  const std::string prefix = (anyKey_ ? "." : "") + path_.filename().string() + ".partial-";
  removeStalePartials(path_.parent_path(), prefix);
  const fs::path temp =
      path_.parent_path() / (prefix + std::to_string(::getpid()) + "-" + std::to_string(serial++));
  {
    errno = 0;
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    if (!out) return fail(std::strerror(errno ? errno : EIO));
    const uint64_t length = text.size();
    out.write(kMagic, sizeof kMagic);
    out.write(reinterpret_cast<const char*>(&length), sizeof length);
    out.write(text.data(), std::streamsize(length));
    for (const auto& [name, values] : arrays_)
      out.write(reinterpret_cast<const char*>(values.data()),
                std::streamsize(values.size() * sizeof(float)));
    out.write(reinterpret_cast<const char*>(sum.data()), std::streamsize(sizeof sum));
    out.close();
    if (!out) {
      const int err = errno ? errno : EIO;
      fs::remove(temp, ec);
      return fail(std::strerror(err));
    }
  }
  fs::rename(temp, path_, ec);
  if (ec) {
    const std::string why = ec.message();
    fs::remove(temp, ec);
    return fail(why);
  }
  return true;
}

void StageCache::put(const std::string& name, std::span<const float> values) {
  arrays_[name].assign(values.begin(), values.end());
}

void StageCache::put(const std::string& name, Pixels&& values) {
  arrays_[name] = std::move(values);
}

std::span<const float> StageCache::get(const std::string& name) const {
  const auto it = arrays_.find(name);
  if (it == arrays_.end()) return {};
  return it->second;
}

void StageCache::putImage(const std::string& name, const Image& image) {
  meta_["images"][name] = {{"width", image.width},
                           {"height", image.height},
                           {"channels", image.channels},
                           {"names", image.channelNames},
                           {"colorSpace", image.colorSpace}};
  put(name, image.pixels);
}

const Pixels* StageCache::imageWithoutPixels(const std::string& name, Image& image) const {
  if (!meta_.contains("images") || !meta_["images"].contains(name)) return nullptr;
  const nlohmann::json& m = meta_["images"][name];
  // Whole numbers in int's range only (a conversion from anything else would be undefined).
  auto whole = [&](const char* key) -> int {
    const auto it = m.find(key);
    if (it == m.end() || !it->is_number_integer()) return -1;
    const int64_t v = it->get<int64_t>();
    return v >= 0 && v <= INT32_MAX ? int(v) : -1;
  };
  if (!m.is_object()) return nullptr;
  try {
    const int width = whole("width"), height = whole("height"), channels = whole("channels");
    const auto it = arrays_.find(name);
    // Sizes within the pixel limit (so that the product below cannot overflow) and matching the
    // stored values exactly.
    const int64_t maxPixels = resourceLimits().maxPixels;
    if (it == arrays_.end() || width < 0 || height < 0 || channels < 0 || channels > 64 ||
        (height > 0 && int64_t(width) > maxPixels / height) ||
        it->second.size() != size_t(width) * size_t(height) * size_t(channels))
      return nullptr;
    Image out;
    out.width = width;
    out.height = height;
    out.channels = channels;
    out.channelNames = m.at("names").get<std::vector<std::string>>();
    if (!out.channelNames.empty() && out.channelNames.size() != size_t(channels)) return nullptr;
    out.colorSpace = m.at("colorSpace").get<std::string>();
    image = std::move(out);
    return &it->second;
  } catch (const nlohmann::json::exception&) {
    return nullptr;
  }
}

bool StageCache::getImage(const std::string& name, Image& image) const {
  Image out;
  const Pixels* pixels = imageWithoutPixels(name, out);
  if (!pixels) return false;
  out.pixels = *pixels;
  image = std::move(out);
  return true;
}

bool StageCache::takeImage(const std::string& name, Image& image) {
  Image out;
  if (!imageWithoutPixels(name, out)) return false;
  Pixels& pixels = arrays_[name];
  out.pixels = std::move(pixels);
  pixels = {};
  image = std::move(out);
  return true;
}

}  // namespace compose::pipeline
