#include "lighting/lighting_cache.h"

#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <fstream>

namespace compose::lighting {

namespace fs = std::filesystem;

namespace {

constexpr char kMagic[8] = {'C', 'O', 'M', 'P', 'L', 'I', 'T', '2'};

// Two independent 64-bit hashes (FNV-1a and a multiply-xorshift mix) over 32-bit words.
struct Hash128 {
  uint64_t a = 1469598103934665603ull, b = 0x9E3779B97F4A7C15ull;
  void word(uint32_t w) {
    a = (a ^ w) * 1099511628211ull;
    b = (b ^ (w + 0x632BE59BD9B4E019ull + (b << 6) + (b >> 2))) * 0xff51afd7ed558ccdull;
  }
  void bytes(const std::string& s) {
    for (unsigned char c : s) word(c);
    word(0xFFFFFFFFu);
  }
  std::string hex() const {
    char buf[33];
    std::snprintf(buf, sizeof buf, "%016llx%016llx", static_cast<unsigned long long>(a),
                  static_cast<unsigned long long>(b));
    return buf;
  }
};

}  // namespace

std::string LightingCache::key(const Environment& env, const DiffuseLighting& basis) {
  Hash128 h;
  h.word(uint32_t(env.width()));
  h.word(uint32_t(env.height()));
  for (float v : env.texels()) {
    uint32_t w;
    std::memcpy(&w, &v, sizeof w);
    h.word(w);
  }
  h.bytes(basis.parameterKey());
  h.word(uint32_t(kProjectionVersion));
  return h.hex();
}

bool LightingCache::load(const std::string& key, DiffuseLighting& basis) const {
  std::ifstream in(pathFor(key), std::ios::binary);
  if (!in) return false;
  char magic[8];
  uint64_t keyLength = 0, count = 0;
  if (!in.read(magic, sizeof magic) || std::memcmp(magic, kMagic, sizeof magic) != 0) return false;
  if (!in.read(reinterpret_cast<char*>(&keyLength), sizeof keyLength) || keyLength > 4096)
    return false;
  std::string storedKey(keyLength, '\0');
  if (!in.read(storedKey.data(), std::streamsize(keyLength)) || storedKey != basis.parameterKey())
    return false;
  if (!in.read(reinterpret_cast<char*>(&count), sizeof count)) return false;
  {
    // Never trust the stored count further than the bytes actually present.
    const std::streamoff here = in.tellg();
    in.seekg(0, std::ios::end);
    const std::streamoff end = in.tellg();
    in.seekg(here);
    if (here < 0 || end < here || count != uint64_t(end - here) / sizeof(float)) return false;
  }
  std::vector<float> state(count);
  if (!in.read(reinterpret_cast<char*>(state.data()), std::streamsize(count * sizeof(float))))
    return false;
  return basis.importState(state);
}

bool LightingCache::store(const std::string& key, const DiffuseLighting& basis) const {
  std::vector<float> state;
  if (!basis.exportState(state)) return false;
  std::error_code ec;
  fs::create_directories(folder_, ec);
  const fs::path final = pathFor(key);
  fs::path temp = final;
  temp += ".partial-" + std::to_string(::getpid());
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    const std::string paramKey = basis.parameterKey();
    const uint64_t keyLength = paramKey.size(), count = state.size();
    out.write(kMagic, sizeof kMagic);
    out.write(reinterpret_cast<const char*>(&keyLength), sizeof keyLength);
    out.write(paramKey.data(), std::streamsize(keyLength));
    out.write(reinterpret_cast<const char*>(&count), sizeof count);
    out.write(reinterpret_cast<const char*>(state.data()),
              std::streamsize(state.size() * sizeof(float)));
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

}  // namespace compose::lighting
