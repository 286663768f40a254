#include "pipeline/stage_cache.h"

#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdint>
#include <cstring>
#include <fstream>

namespace compose::pipeline {

namespace fs = std::filesystem;

namespace {
constexpr char kMagic[8] = {'C', 'O', 'M', 'P', 'S', 'T', 'G', '1'};
constexpr uint64_t kMaxHeader = 1 << 20;
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

bool StageCache::open() {
  if (!enabled()) return false;
  std::ifstream in(path_, std::ios::binary);
  if (!in) return false;
  char magic[8];
  uint64_t length = 0;
  if (!in.read(magic, sizeof magic) || std::memcmp(magic, kMagic, sizeof magic) != 0) return false;
  if (!in.read(reinterpret_cast<char*>(&length), sizeof length) || length > kMaxHeader)
    return false;
  std::string text(length, '\0');
  if (!in.read(text.data(), std::streamsize(length))) return false;
  const nlohmann::json header = nlohmann::json::parse(text, nullptr, false);
  if (header.is_discarded() || !header.is_object() || header.value("stage", "") != stage_ ||
      (!anyKey_ && header.value("key", "") != key_) || !header.contains("arrays") ||
      !header["arrays"].is_array() || !header.contains("meta"))
    return false;
  // Never trust stored counts further than the bytes actually present.
  const std::streamoff here = in.tellg();
  in.seekg(0, std::ios::end);
  const std::streamoff end = in.tellg();
  in.seekg(here);
  uint64_t total = 0;
  for (const auto& a : header["arrays"]) {
    if (!a.is_array() || a.size() != 2 || !a[0].is_string() || !a[1].is_number_unsigned())
      return false;
    total += a[1].get<uint64_t>();
  }
  if (here < 0 || end < here || uint64_t(end - here) != total * sizeof(float)) return false;
  std::map<std::string, std::vector<float>> arrays;
  for (const auto& a : header["arrays"]) {
    std::vector<float> values(a[1].get<uint64_t>());
    if (!in.read(reinterpret_cast<char*>(values.data()),
                 std::streamsize(values.size() * sizeof(float))))
      return false;
    arrays[a[0].get<std::string>()] = std::move(values);
  }
  meta_ = header["meta"];
  arrays_ = std::move(arrays);
  if (anyKey_) key_ = header.value("key", "");
  return true;
}

bool StageCache::write() const {
  if (!enabled()) return false;
  std::error_code ec;
  fs::create_directories(path_.parent_path(), ec);
  nlohmann::json header;
  header["stage"] = stage_;
  header["key"] = key_;
  header["meta"] = meta_;
  header["arrays"] = nlohmann::json::array();
  for (const auto& [name, values] : arrays_) header["arrays"].push_back({name, values.size()});
  const std::string text = header.dump();
  static std::atomic<int> serial{0};
  fs::path temp = path_;
  temp += ".partial-" + std::to_string(::getpid()) + "-" + std::to_string(serial++);
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    const uint64_t length = text.size();
    out.write(kMagic, sizeof kMagic);
    out.write(reinterpret_cast<const char*>(&length), sizeof length);
    out.write(text.data(), std::streamsize(length));
    for (const auto& [name, values] : arrays_)
      out.write(reinterpret_cast<const char*>(values.data()),
                std::streamsize(values.size() * sizeof(float)));
    out.close();
    if (!out) {
      error_ = std::strerror(errno);
      fs::remove(temp, ec);
      return false;
    }
  }
  fs::rename(temp, path_, ec);
  if (ec) {
    error_ = ec.message();
    fs::remove(temp, ec);
    return false;
  }
  return true;
}

void StageCache::put(const std::string& name, std::vector<float> values) {
  arrays_[name] = std::move(values);
}

const std::vector<float>& StageCache::get(const std::string& name) const {
  static const std::vector<float> none;
  const auto it = arrays_.find(name);
  return it == arrays_.end() ? none : it->second;
}

void StageCache::putImage(const std::string& name, const Image& image) {
  meta_["images"][name] = {{"width", image.width},
                           {"height", image.height},
                           {"channels", image.channels},
                           {"names", image.channelNames},
                           {"colorSpace", image.colorSpace}};
  put(name, image.pixels);
}

const std::vector<float>* StageCache::imageWithoutPixels(const std::string& name,
                                                         Image& image) const {
  if (!meta_.contains("images") || !meta_["images"].contains(name)) return nullptr;
  const nlohmann::json& m = meta_["images"][name];
  try {
    const int width = m.at("width").get<int>(), height = m.at("height").get<int>(),
              channels = m.at("channels").get<int>();
    const auto it = arrays_.find(name);
    if (it == arrays_.end() || width < 0 || height < 0 || channels < 0 ||
        it->second.size() != size_t(width) * size_t(height) * size_t(channels))
      return nullptr;
    Image out;
    out.width = width;
    out.height = height;
    out.channels = channels;
    out.channelNames = m.at("names").get<std::vector<std::string>>();
    out.colorSpace = m.at("colorSpace").get<std::string>();
    image = std::move(out);
    return &it->second;
  } catch (const nlohmann::json::exception&) {
    return nullptr;
  }
}

bool StageCache::getImage(const std::string& name, Image& image) const {
  Image out;
  const std::vector<float>* pixels = imageWithoutPixels(name, out);
  if (!pixels) return false;
  out.pixels = *pixels;
  image = std::move(out);
  return true;
}

bool StageCache::takeImage(const std::string& name, Image& image) {
  Image out;
  if (!imageWithoutPixels(name, out)) return false;
  std::vector<float>& pixels = arrays_[name];
  out.pixels = std::move(pixels);
  pixels = {};
  image = std::move(out);
  return true;
}

}  // namespace compose::pipeline
