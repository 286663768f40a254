// Small glTF files for tests: binary data appended to one buffer, accessors over it, and the rest
// of the JSON (meshes, nodes, materials) written by the test around them.
#pragma once

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace compose::testing {

inline std::string base64(const std::vector<uint8_t>& bytes) {
  static const char* const kAlphabet =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  for (size_t i = 0; i < bytes.size(); i += 3) {
    const uint32_t b0 = bytes[i];
    const uint32_t b1 = i + 1 < bytes.size() ? bytes[i + 1] : 0u;
    const uint32_t b2 = i + 2 < bytes.size() ? bytes[i + 2] : 0u;
    const uint32_t triple = (b0 << 16) | (b1 << 8) | b2;
    out += kAlphabet[(triple >> 18) & 63];
    out += kAlphabet[(triple >> 12) & 63];
    out += i + 1 < bytes.size() ? kAlphabet[(triple >> 6) & 63] : '=';
    out += i + 2 < bytes.size() ? kAlphabet[triple & 63] : '=';
  }
  return out;
}

inline std::vector<uint8_t> readBytes(const std::filesystem::path& file) {
  std::ifstream in(file, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class GltfBuilder {
 public:
  nlohmann::json json;

  GltfBuilder() {
    json["asset"] = {{"version", "2.0"}};
    json["bufferViews"] = nlohmann::json::array();
    json["accessors"] = nlohmann::json::array();
  }

  // Appends `bytes` (4-byte aligned) to the buffer as a new buffer view; returns its index.
  int view(const void* data, size_t bytes, size_t stride = 0) {
    while (buffer_.size() % 4) buffer_.push_back(0);
    nlohmann::json v = {{"buffer", 0}, {"byteOffset", buffer_.size()}, {"byteLength", bytes}};
    if (stride) v["byteStride"] = stride;
    const auto* p = static_cast<const uint8_t*>(data);
    buffer_.insert(buffer_.end(), p, p + bytes);
    json["bufferViews"].push_back(v);
    return int(json["bufferViews"].size()) - 1;
  }

  // An accessor over a new buffer view holding `values`; returns its index. `componentType` is
  // glTF's code (5121 u8, 5123 u16, 5125 u32, 5126 float, ...), `type` "SCALAR", "VEC2"...
  template <class T>
  int accessor(const std::vector<T>& values, int componentType, const std::string& type,
               size_t count, bool normalized = false) {
    const int v = view(values.data(), values.size() * sizeof(T));
    nlohmann::json a = {
        {"bufferView", v}, {"componentType", componentType}, {"count", count}, {"type", type}};
    if (normalized) a["normalized"] = true;
    json["accessors"].push_back(a);
    return int(json["accessors"].size()) - 1;
  }
  int vec3(const std::vector<float>& v) { return accessor(v, 5126, "VEC3", v.size() / 3); }
  int vec2(const std::vector<float>& v) { return accessor(v, 5126, "VEC2", v.size() / 2); }

  // A mesh of one primitive; returns the mesh index.
  int mesh(const nlohmann::json& primitive) {
    json["meshes"].push_back({{"primitives", nlohmann::json::array({primitive})}});
    return int(json["meshes"].size()) - 1;
  }
  // A node; returns its index.
  int node(const nlohmann::json& node) {
    json["nodes"].push_back(node);
    return int(json["nodes"].size()) - 1;
  }
  // One scene of these root nodes.
  void scene(const std::vector<int>& roots) {
    json["scenes"] = nlohmann::json::array({{{"nodes", roots}}});
    json["scene"] = 0;
  }

  // A .gltf with the buffer in a base64 data URI.
  std::string gltf() const {
    nlohmann::json j = json;
    j["buffers"] = nlohmann::json::array(
        {{{"byteLength", buffer_.size()},
          {"uri", "data:application/octet-stream;base64," + base64(buffer_)}}});
    return j.dump(1);
  }

  // The buffer's bytes, for a .gltf whose buffer is a file of its own.
  const std::vector<uint8_t>& bufferBytes() const { return buffer_; }

  // A .glb: the JSON chunk and the buffer as the BIN chunk.
  std::vector<uint8_t> glb() const {
    nlohmann::json j = json;
    j["buffers"] = nlohmann::json::array({{{"byteLength", buffer_.size()}}});
    std::string text = j.dump();
    while (text.size() % 4) text += ' ';
    std::vector<uint8_t> bin = buffer_;
    while (bin.size() % 4) bin.push_back(0);
    std::vector<uint8_t> out;
    auto word = [&](uint32_t w) {
      uint8_t b[4];
      std::memcpy(b, &w, 4);
      out.insert(out.end(), b, b + 4);
    };
    word(0x46546C67);  // "glTF"
    word(2);
    word(uint32_t(12 + 8 + text.size() + 8 + bin.size()));
    word(uint32_t(text.size()));
    word(0x4E4F534A);  // "JSON"
    out.insert(out.end(), text.begin(), text.end());
    word(uint32_t(bin.size()));
    word(0x004E4942);  // "BIN"
    out.insert(out.end(), bin.begin(), bin.end());
    return out;
  }

 private:
  std::vector<uint8_t> buffer_;
};

}  // namespace compose::testing
