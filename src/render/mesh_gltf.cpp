// glTF 2.0, .gltf and .glb (see mesh.h for what is read and how), parsed by Debian's shared
// tinygltf. Accessors are decoded here with every bound checked, since tinygltf leaves that to
// its users; images are decoded by our ingest (OpenImageIO), not by tinygltf's stb_image.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <set>

#include <tiny_gltf.h>
#include <glm/gtc/quaternion.hpp>
#include <glm/mat4x4.hpp>

#include "core/error.h"
#include "core/json_keys.h"
#include "core/json_number.h"
#include "core/limits.h"
#include "ingest/image_io.h"
#include "render/mesh_formats.h"

namespace compose::render::detail {

namespace fs = std::filesystem;

namespace {

// A problem with one primitive (a broken accessor, a missing attribute): it is skipped with a
// warning that says why.
struct PrimitiveError {
  std::string what;
};

// Extensions a file may require that do not change what compose reads.
const std::set<std::string>& supportedRequiredExtensions() {
  static const std::set<std::string> names = {"KHR_texture_transform",
                                              "KHR_mesh_quantization",
                                              "KHR_materials_emissive_strength",
                                              "KHR_materials_unlit",
                                              "KHR_materials_ior",
                                              "KHR_materials_specular",
                                              "KHR_materials_pbrSpecularGlossiness",
                                              "EXT_mesh_gpu_instancing"};
  return names;
}

// A file that requires an extension compose cannot honour is an error naming it.
void checkRequiredExtensions(const tinygltf::Model& model, const fs::path& path) {
  for (const std::string& ext : model.extensionsRequired) {
    if (supportedRequiredExtensions().count(ext)) continue;
    std::string why =
        "the file requires the glTF extension " + ext + ", which compose does not support";
    if (ext == "KHR_draco_mesh_compression" || ext == "EXT_meshopt_compression")
      why += " (compressed geometry: export it without compression)";
    throw Error("mesh", why, path);
  }
}

// Percent-decoding of a URI's path (RFC 3986, as glTF's URIs are): '+' is itself. tinygltf 2.7
// decodes buffer URIs as a URL's query string instead ('+' a space, tinygltfDecode), so that
// `a+b.bin` is looked for as `a b.bin`.
std::string decodeUri(const std::string& uri) {
  std::string decoded;
  for (size_t i = 0; i < uri.size(); ++i) {
    if (uri[i] == '%' && i + 2 < uri.size() &&
        std::isxdigit(static_cast<unsigned char>(uri[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(uri[i + 2]))) {
      decoded += char(std::stoi(uri.substr(i + 1, 2), nullptr, 16));
      i += 2;
    } else {
      decoded += uri[i];
    }
  }
  return decoded;
}

// Keeps the encoded bytes of data-URI images for our own decoder. Images in buffer views are
// decoded from the buffer after their bounds are checked, and images in files from the file, so
// their bytes are not kept (nor read) here.
bool keepEncodedImage(tinygltf::Image* image, const int, std::string*, std::string*, int, int,
                      const unsigned char* bytes, int size, void*) {
  if (image->bufferView < 0 && image->uri.empty() && bytes && size > 0)
    image->image.assign(bytes, bytes + size);
  return true;
}

int componentSize(int componentType) {
  switch (componentType) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      return 1;
    case TINYGLTF_COMPONENT_TYPE_SHORT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
      return 2;
    case TINYGLTF_COMPONENT_TYPE_INT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
    case TINYGLTF_COMPONENT_TYPE_FLOAT:
      return 4;
    default:
      return 0;
  }
}

int componentCount(int type) {
  switch (type) {
    case TINYGLTF_TYPE_SCALAR:
      return 1;
    case TINYGLTF_TYPE_VEC2:
      return 2;
    case TINYGLTF_TYPE_VEC3:
      return 3;
    case TINYGLTF_TYPE_VEC4:
    case TINYGLTF_TYPE_MAT2:
      return 4;
    case TINYGLTF_TYPE_MAT3:
      return 9;
    case TINYGLTF_TYPE_MAT4:
      return 16;
    default:
      return 0;
  }
}

const char* typeName(int components) {
  switch (components) {
    case 1:
      return "SCALAR";
    case 2:
      return "VEC2";
    case 3:
      return "VEC3";
    default:
      return "VEC4 or a matrix";
  }
}

// One component, little-endian as glTF stores it; normalised integers map to [0, 1] or [-1, 1]
// (glTF 2.0 §3.11).
double component(const unsigned char* p, int componentType, bool normalized) {
  switch (componentType) {
    case TINYGLTF_COMPONENT_TYPE_BYTE: {
      int8_t v;
      std::memcpy(&v, p, 1);
      return normalized ? std::max(double(v) / 127.0, -1.0) : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      return normalized ? double(p[0]) / 255.0 : double(p[0]);
    case TINYGLTF_COMPONENT_TYPE_SHORT: {
      int16_t v;
      std::memcpy(&v, p, 2);
      return normalized ? std::max(double(v) / 32767.0, -1.0) : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
      uint16_t v;
      std::memcpy(&v, p, 2);
      return normalized ? double(v) / 65535.0 : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_INT: {
      int32_t v;
      std::memcpy(&v, p, 4);
      return normalized ? std::max(double(v) / 2147483647.0, -1.0) : double(v);
    }
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT: {
      uint32_t v;
      std::memcpy(&v, p, 4);
      return normalized ? double(v) / 4294967295.0 : double(v);
    }
    default: {
      float v;
      std::memcpy(&v, p, 4);
      return double(v);
    }
  }
}

class GltfReader {
 public:
  GltfReader(const tinygltf::Model& model, const fs::path& path, LoadedMesh& out)
      : model_(model), path_(path), out_(out), mesh_(out.mesh) {}

  void read();

 private:
  // The bytes of buffer view `view` from `offset`, holding `count` elements of `elementSize`
  // bytes `stride` apart (0: tightly packed, or the view's own stride when `useViewStride`).
  const unsigned char* viewBytes(int view, size_t offset, size_t count, size_t elementSize,
                                 size_t& stride, bool useViewStride, const std::string& what) const;
  // Accessor `index` as `components` doubles per element, sparse substitution applied.
  std::vector<double> accessor(int index, int components, const std::string& what) const;
  std::vector<uint32_t> indices(int index, const std::string& what) const;

  glm::dmat4 localTransform(const tinygltf::Node& node, int index) const;
  // EXT_mesh_gpu_instancing: the node's mesh drawn once per instance, each at its TRANSLATION,
  // ROTATION and SCALE within the node; the identity alone for a node without instances.
  std::vector<glm::dmat4> instances(const tinygltf::Node& node, int index) const;
  void addPrimitive(const tinygltf::Primitive& primitive, const glm::dmat4& objectFromNode);
  // The mesh's material for glTF material `gltfMaterial` (-1: none); a primitive with vertex
  // colours and no material gets glTF's default, white, so that its colours are its albedo.
  uint32_t material(int gltfMaterial, bool coloured = false);
  int texture(int gltfTexture, const std::string& materialName);
  // The pixels of image `imageIndex`. Before decoding, `file` is set to its file, or for an
  // embedded image to a name that says where it is (with the extension of its format, for the
  // colour config's file rules), and `where` to a description for messages.
  Image decodeImage(int imageIndex, fs::path& file, std::string& where, Image* alpha);

  const tinygltf::Model& model_;
  const fs::path& path_;
  LoadedMesh& out_;
  Mesh& mesh_;
  std::map<int, uint32_t> materials_;  // glTF material (-1: none) → Mesh::materials
  std::map<int, int> textures_;        // glTF texture → Mesh::textures (-1: unreadable)
  std::vector<int> texCoordSet_;       // per Mesh material: the TEXCOORD set its texture uses
  size_t primitives_ = 0, skippedLines = 0, droppedIndices = 0, triangles_ = 0;
  size_t colours_ = 0, clampedColours_ = 0, morphs_ = 0, skinned_ = 0, missingTexcoords_ = 0,
         missingMaterials_ = 0;
  // What the materials ask for that a diffuse renderer does not do: feature → materials.
  std::map<std::string, int> unrendered_;
  // Triangle lists whose vertices (or indices) do not come in threes: the primitives, and the
  // vertices left over at their ends.
  size_t ragged_ = 0, leftOver_ = 0;
  bool noMaterial_ = false, someMaterial_ = false;
  std::vector<glm::dvec3> exact_;  // the positions in double, before rounding (recentre())
};

const unsigned char* GltfReader::viewBytes(int view, size_t offset, size_t count,
                                           size_t elementSize, size_t& stride, bool useViewStride,
                                           const std::string& what) const {
  if (view < 0 || size_t(view) >= model_.bufferViews.size()) {
    throw PrimitiveError{what + " refers to buffer view " + std::to_string(view) +
                         ", the file has " + std::to_string(model_.bufferViews.size())};
  }
  const tinygltf::BufferView& bv = model_.bufferViews[size_t(view)];
  if (bv.buffer < 0 || size_t(bv.buffer) >= model_.buffers.size()) {
    throw PrimitiveError{"buffer view " + std::to_string(view) + " refers to buffer " +
                         std::to_string(bv.buffer) + ", the file has " +
                         std::to_string(model_.buffers.size())};
  }
  const std::vector<unsigned char>& data = model_.buffers[size_t(bv.buffer)].data;
  if (bv.byteOffset > data.size() || bv.byteLength > data.size() - bv.byteOffset) {
    throw PrimitiveError{"buffer view " + std::to_string(view) + " (bytes " +
                         std::to_string(bv.byteOffset) + " + " + std::to_string(bv.byteLength) +
                         ") lies outside its buffer of " + std::to_string(data.size()) + " bytes"};
  }
  stride = useViewStride && bv.byteStride ? bv.byteStride : elementSize;
  if (stride < elementSize) {
    throw PrimitiveError{"buffer view " + std::to_string(view) + " has a byte stride of " +
                         std::to_string(stride) + ", less than the " + std::to_string(elementSize) +
                         " bytes of an element of " + what};
  }
  // count ≤ 2^31 and stride ≤ 2^8 (checked by the callers and tinygltf): no overflow in 64 bits.
  if (count > 0 &&
      (offset > bv.byteLength || (count - 1) * stride + elementSize > bv.byteLength - offset)) {
    throw PrimitiveError{what + " reads past the end of buffer view " + std::to_string(view) +
                         " (" + std::to_string(count) + " elements of " +
                         std::to_string(elementSize) + " bytes from byte " +
                         std::to_string(offset) + " of " + std::to_string(bv.byteLength) + ")"};
  }
  return data.data() + bv.byteOffset + offset;
}

std::vector<double> GltfReader::accessor(int index, int components, const std::string& what) const {
  const std::string name = what + " (accessor " + std::to_string(index) + ")";
  if (index < 0 || size_t(index) >= model_.accessors.size()) {
    throw PrimitiveError{what + " refers to accessor " + std::to_string(index) + ", the file has " +
                         std::to_string(model_.accessors.size())};
  }
  const tinygltf::Accessor& a = model_.accessors[size_t(index)];
  if (componentCount(a.type) != components) {
    throw PrimitiveError{name + " holds " + typeName(componentCount(a.type)) + ", expected " +
                         typeName(components)};
  }
  const int size = componentSize(a.componentType);
  if (size == 0) {
    throw PrimitiveError{name + " has the unknown component type " +
                         std::to_string(a.componentType)};
  }
  constexpr size_t kMaxElements = size_t(1) << 28;
  if (a.count > kMaxElements) {
    throw PrimitiveError{name + " has " + std::to_string(a.count) + " elements, more than " +
                         std::to_string(kMaxElements)};
  }
  const size_t elementSize = size_t(size) * size_t(components);
  std::vector<double> values(a.count * size_t(components), 0.0);  // no buffer view: zeros
  if (a.bufferView >= 0) {
    size_t stride = 0;
    const unsigned char* p =
        viewBytes(a.bufferView, a.byteOffset, a.count, elementSize, stride, true, name);
    for (size_t i = 0; i < a.count; ++i)
      for (int c = 0; c < components; ++c)
        values[i * size_t(components) + size_t(c)] =
            component(p + i * stride + size_t(c * size), a.componentType, a.normalized);
  }
  if (a.sparse.isSparse) {
    const int n = a.sparse.count;
    if (n < 0 || size_t(n) > a.count) {
      throw PrimitiveError{name + " has " + std::to_string(n) + " sparse values for " +
                           std::to_string(a.count) + " elements"};
    }
    const int indexType = a.sparse.indices.componentType;
    const int indexSize = componentSize(indexType);
    if (indexType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE &&
        indexType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
        indexType != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT) {
      throw PrimitiveError{name + ": sparse indices must be unsigned integers"};
    }
    size_t stride = 0;
    const unsigned char* idx =
        viewBytes(a.sparse.indices.bufferView, size_t(std::max(0, a.sparse.indices.byteOffset)),
                  size_t(n), size_t(indexSize), stride, false, name + " sparse indices");
    const unsigned char* val =
        viewBytes(a.sparse.values.bufferView, size_t(std::max(0, a.sparse.values.byteOffset)),
                  size_t(n), elementSize, stride, false, name + " sparse values");
    for (size_t k = 0; k < size_t(n); ++k) {
      const double target = component(idx + k * size_t(indexSize), indexType, false);
      if (!(target < double(a.count))) {
        throw PrimitiveError{name + ": sparse index " + std::to_string(uint64_t(target)) +
                             " is beyond its " + std::to_string(a.count) + " elements"};
      }
      for (int c = 0; c < components; ++c)
        values[size_t(target) * size_t(components) + size_t(c)] =
            component(val + k * elementSize + size_t(c * size), a.componentType, a.normalized);
    }
  }
  return values;
}

std::vector<uint32_t> GltfReader::indices(int index, const std::string& what) const {
  if (index >= 0 && size_t(index) < model_.accessors.size()) {
    const int type = model_.accessors[size_t(index)].componentType;
    if (type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE &&
        type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT &&
        type != TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT) {
      throw PrimitiveError{what + " (accessor " + std::to_string(index) +
                           ") must hold unsigned 8-, 16- or 32-bit integers"};
    }
  }
  const std::vector<double> values = accessor(index, 1, what);
  std::vector<uint32_t> out(values.size());
  for (size_t i = 0; i < values.size(); ++i) out[i] = uint32_t(values[i]);
  return out;
}

glm::dmat4 GltfReader::localTransform(const tinygltf::Node& node, int index) const {
  const std::string name =
      "node " + std::to_string(index) + (node.name.empty() ? "" : " '" + node.name + "'");
  auto finite = [&](const std::vector<double>& v, size_t size, const char* what) {
    if (v.empty()) return false;
    if (v.size() != size) {
      throw Error("mesh",
                  name + ": " + what + " has " + std::to_string(v.size()) + " numbers, not " +
                      std::to_string(size),
                  path_);
    }
    for (double x : v)
      if (!std::isfinite(x)) throw Error("mesh", name + ": " + what + " is not finite", path_);
    return true;
  };
  if (finite(node.matrix, 16, "matrix")) {
    glm::dmat4 m;
    for (int c = 0; c < 4; ++c)
      for (int r = 0; r < 4; ++r) m[c][r] = node.matrix[size_t(4 * c + r)];  // column-major
    return m;
  }
  glm::dmat4 m(1.0);
  if (finite(node.translation, 3, "translation")) {
    m[3] = glm::dvec4(node.translation[0], node.translation[1], node.translation[2], 1.0);
  }
  if (finite(node.rotation, 4, "rotation")) {
    glm::dquat q(node.rotation[3], node.rotation[0], node.rotation[1], node.rotation[2]);
    const double len = glm::length(q);
    if (!(len > 0.0)) throw Error("mesh", name + ": rotation is a zero quaternion", path_);
    m = m * glm::mat4_cast(q / len);
  }
  if (finite(node.scale, 3, "scale")) {
    m = m * glm::dmat4(glm::dvec4(node.scale[0], 0, 0, 0), glm::dvec4(0, node.scale[1], 0, 0),
                       glm::dvec4(0, 0, node.scale[2], 0), glm::dvec4(0, 0, 0, 1));
  }
  return m;
}

std::vector<glm::dmat4> GltfReader::instances(const tinygltf::Node& node, int index) const {
  const auto ext = node.extensions.find("EXT_mesh_gpu_instancing");
  if (ext == node.extensions.end() || !ext->second.Has("attributes")) return {glm::dmat4(1.0)};
  const tinygltf::Value& attributes = ext->second.Get("attributes");
  const std::string name =
      "node " + std::to_string(index) + (node.name.empty() ? "" : " '" + node.name + "'");
  // Each attribute's values, `components` per instance; empty where the attribute is absent.
  size_t count = 0;
  bool counted = false;
  auto read = [&](const char* attribute, int components) {
    if (!attributes.Has(attribute)) return std::vector<double>();
    const tinygltf::Value& v = attributes.Get(attribute);
    if (!v.IsInt()) {
      throw Error("mesh", name + ": EXT_mesh_gpu_instancing's " + attribute + " is no accessor",
                  path_);
    }
    // Each instance draws at least a triangle: held to the limit before anything is allocated
    // for them (an accessor without a buffer view may claim 2^28 of them).
    if (const int a = v.Get<int>(); a >= 0 && size_t(a) < model_.accessors.size())
      checkTriangleCount(int64_t(model_.accessors[size_t(a)].count), path_);
    std::vector<double> values;
    try {
      values = accessor(v.Get<int>(), components, std::string("instance ") + attribute);
    } catch (const PrimitiveError& e) {
      throw Error("mesh", name + ": EXT_mesh_gpu_instancing: " + e.what, path_);
    }
    for (double x : values)
      if (!std::isfinite(x))
        throw Error("mesh", name + ": an instance's " + attribute + " is not finite", path_);
    const size_t n = values.size() / size_t(components);
    if (counted && n != count) {
      throw Error("mesh",
                  name + ": EXT_mesh_gpu_instancing's attributes count " + std::to_string(count) +
                      " and " + std::to_string(n) + " instances",
                  path_);
    }
    count = n;
    counted = true;
    return values;
  };
  const std::vector<double> t = read("TRANSLATION", 3), r = read("ROTATION", 4),
                            s = read("SCALE", 3);
  if (!counted) return {glm::dmat4(1.0)};
  std::vector<glm::dmat4> out;
  out.reserve(count);
  for (size_t i = 0; i < count; ++i) {
    glm::dmat4 m(1.0);
    if (!t.empty()) m[3] = glm::dvec4(t[3 * i], t[3 * i + 1], t[3 * i + 2], 1.0);
    if (!r.empty()) {
      glm::dquat q(r[4 * i + 3], r[4 * i], r[4 * i + 1], r[4 * i + 2]);
      const double len = glm::length(q);
      if (!(len > 0.0)) throw Error("mesh", name + ": an instance's rotation is zero", path_);
      m = m * glm::mat4_cast(q / len);
    }
    if (!s.empty()) {
      m = m * glm::dmat4(glm::dvec4(s[3 * i], 0, 0, 0), glm::dvec4(0, s[3 * i + 1], 0, 0),
                         glm::dvec4(0, 0, s[3 * i + 2], 0), glm::dvec4(0, 0, 0, 1));
    }
    out.push_back(m);
  }
  return out;
}

Image GltfReader::decodeImage(int imageIndex, fs::path& file, std::string& where, Image* alpha) {
  if (imageIndex < 0 || size_t(imageIndex) >= model_.images.size()) {
    throw Error("mesh", "refers to image " + std::to_string(imageIndex) + ", the file has " +
                            std::to_string(model_.images.size()));
  }
  const tinygltf::Image& image = model_.images[size_t(imageIndex)];
  if (!image.uri.empty()) {
    // An image file beside the glTF: its URI is relative and percent-encoded.
    file = path_.parent_path() / decodeUri(image.uri);
    mesh_.otherFiles.push_back(file);
    where = file.string();
    return readTextureFile(file, "sRGB", alpha);
  }
  std::span<const unsigned char> bytes(image.image);
  where = "image " + std::to_string(imageIndex) + ", embedded";
  if (image.bufferView >= 0) {
    const int view = image.bufferView;
    size_t stride = 0;
    size_t length = 0;
    if (size_t(view) < model_.bufferViews.size())
      length = model_.bufferViews[size_t(view)].byteLength;
    try {
      bytes = {viewBytes(view, 0, 1, length, stride, false, "image"), length};
    } catch (const PrimitiveError& e) {
      throw Error("mesh", e.what);
    }
    where = "image " + std::to_string(imageIndex) + ", in buffer view " + std::to_string(view);
  }
  // The format from the MIME type, else from the first bytes.
  std::string ext;
  const std::string& mime = image.mimeType;
  if (mime == "image/png" || (bytes.size() >= 4 && std::memcmp(bytes.data(), "\x89PNG", 4) == 0))
    ext = ".png";
  else if (mime == "image/jpeg" ||
           (bytes.size() >= 3 && std::memcmp(bytes.data(), "\xFF\xD8\xFF", 3) == 0))
    ext = ".jpg";
  else if (mime == "image/webp")
    ext = ".webp";
  if (ext.empty()) {
    throw Error("mesh", "an image of type '" + (mime.empty() ? std::string("unknown") : mime) +
                            "', which compose cannot decode");
  }
  if (!mime.empty()) where += ", " + mime;
  file = path_.string() + " (" + where + ")" + ext;
  ingest::ReadOptions stored;
  stored.upright = false;  // UVs are laid on the pixels as stored
  return textureImage(ingest::readImageFromMemory(bytes, file, "mesh", stored).image, "sRGB",
                      alpha);
}

int GltfReader::texture(int gltfTexture, const std::string& materialName) {
  const auto [it, inserted] = textures_.try_emplace(gltfTexture, -1);
  if (!inserted) return it->second;
  std::string where = "texture " + std::to_string(gltfTexture);
  try {
    if (gltfTexture < 0 || size_t(gltfTexture) >= model_.textures.size()) {
      throw Error("mesh", "refers to texture " + std::to_string(gltfTexture) + ", the file has " +
                              std::to_string(model_.textures.size()));
    }
    const tinygltf::Texture& t = model_.textures[size_t(gltfTexture)];
    Texture texture;
    texture.image = decodeImage(t.source, texture.file, where, &texture.alpha);
    texture.srgbByFormat = true;  // glTF: base colour textures are sRGB-encoded
    if (t.sampler >= 0 && size_t(t.sampler) < model_.samplers.size()) {
      auto wrap = [](int mode) {
        return mode == TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE     ? Texture::Wrap::Clamp
               : mode == TINYGLTF_TEXTURE_WRAP_MIRRORED_REPEAT ? Texture::Wrap::Mirror
                                                               : Texture::Wrap::Repeat;
      };
      texture.wrapU = wrap(model_.samplers[size_t(t.sampler)].wrapS);
      texture.wrapV = wrap(model_.samplers[size_t(t.sampler)].wrapT);
      texture.nearest =
          model_.samplers[size_t(t.sampler)].magFilter == TINYGLTF_TEXTURE_FILTER_NEAREST;
    }
    it->second = int(mesh_.textures.size());
    mesh_.textures.push_back(std::move(texture));
  } catch (const Error& e) {
    mesh_.warnings.push_back("the base-colour texture of material '" + materialName + "' (" +
                             where + ") cannot be read (" + e.what() +
                             "): the material renders with its base colour factor");
  }
  return it->second;
}

uint32_t GltfReader::material(int gltfMaterial, bool coloured) {
  if (gltfMaterial >= 0 && size_t(gltfMaterial) >= model_.materials.size()) {
    ++missingMaterials_;
    gltfMaterial = -1;
  }
  if (gltfMaterial < 0 && coloured) gltfMaterial = -2;
  const auto [it, inserted] =
      materials_.try_emplace(gltfMaterial, uint32_t(mesh_.materials.size()));
  if (!inserted) return it->second;
  Material m;
  int set = 0;
  if (gltfMaterial == -2) {
    m.name = "(default: the vertex colours)";
    m.baseColor = glm::vec3(1.0f);
  } else if (gltfMaterial < 0) {
    m.name = "(default)";
    m.baseColor = glm::vec3(kDefaultAlbedo);
  } else {
    const tinygltf::Material& gm = model_.materials[size_t(gltfMaterial)];
    m.name = gm.name.empty() ? "material " + std::to_string(gltfMaterial) : gm.name;
    const std::vector<double>& f = gm.pbrMetallicRoughness.baseColorFactor;
    if (f.size() >= 3 && std::isfinite(f[0] + f[1] + f[2])) {
      m.baseColor = glm::vec3(float(f[0]), float(f[1]), float(f[2]));
    } else {
      mesh_.warnings.push_back("material '" + m.name +
                               "' has no valid baseColorFactor: using white");
    }
    // Every material renders diffuse: what else it asks for is said once, with counts.
    {
      const tinygltf::PbrMetallicRoughness& pbr = gm.pbrMetallicRoughness;
      if (pbr.metallicFactor >= 0.5 && pbr.roughnessFactor < 0.5) ++unrendered_["metal"];
      if (pbr.metallicRoughnessTexture.index >= 0) ++unrendered_["metallic-roughness textures"];
      if (gm.normalTexture.index >= 0) ++unrendered_["normal maps"];
      if (gm.occlusionTexture.index >= 0) ++unrendered_["occlusion maps"];
      const std::vector<double>& e = gm.emissiveFactor;
      if (gm.emissiveTexture.index >= 0 ||
          (e.size() >= 3 && (e[0] > 0.0 || e[1] > 0.0 || e[2] > 0.0)))
        ++unrendered_["emission"];
      for (const auto& [name, value] : gm.extensions)
        if (name != "KHR_materials_pbrSpecularGlossiness" && name != "KHR_texture_transform")
          ++unrendered_[name == "KHR_materials_unlit"
                            ? std::string("KHR_materials_unlit (lit as any other: baked light is "
                                          "lit again)")
                            : name];
    }
    tinygltf::TextureInfo info = gm.pbrMetallicRoughness.baseColorTexture;
    double factorAlpha = f.size() >= 4 && std::isfinite(f[3]) ? f[3] : 1.0;
    // Older exporters' KHR_materials_pbrSpecularGlossiness: its diffuse colour and texture are
    // the albedo (the metallic-roughness fallback, when there is one, is left for it).
    if (const auto sg = gm.extensions.find("KHR_materials_pbrSpecularGlossiness");
        sg != gm.extensions.end() && sg->second.IsObject()) {
      const tinygltf::Value& d = sg->second.Get("diffuseFactor");
      // Its alpha is the diffuse factor's (1 when absent) times the diffuse texture's.
      factorAlpha = d.IsArray() && d.ArrayLen() >= 4 && d.Get(3).IsNumber() &&
                            std::isfinite(d.Get(3).GetNumberAsDouble())
                        ? d.Get(3).GetNumberAsDouble()
                        : 1.0;
      if (d.IsArray() && d.ArrayLen() >= 3 && d.Get(0).IsNumber() && d.Get(1).IsNumber() &&
          d.Get(2).IsNumber()) {
        m.baseColor =
            glm::vec3(float(d.Get(0).GetNumberAsDouble()), float(d.Get(1).GetNumberAsDouble()),
                      float(d.Get(2).GetNumberAsDouble()));
      } else {
        m.baseColor = glm::vec3(1.0f);
      }
      const tinygltf::Value& t = sg->second.Get("diffuseTexture");
      info = tinygltf::TextureInfo();
      if (t.IsObject() && t.Get("index").IsNumber()) {
        info.index = t.Get("index").GetNumberAsInt();
        if (t.Get("texCoord").IsNumber()) info.texCoord = t.Get("texCoord").GetNumberAsInt();
        if (t.Has("extensions") && t.Get("extensions").IsObject() &&
            t.Get("extensions").Has("KHR_texture_transform"))
          info.extensions["KHR_texture_transform"] =
              t.Get("extensions").Get("KHR_texture_transform");
      }
    }
    if (gm.alphaMode == "MASK") {
      // A cut-out: alpha is the base colour factor's fourth component times the texture's.
      m.alphaCutoff = std::isfinite(gm.alphaCutoff) ? float(std::max(0.0, gm.alphaCutoff)) : 0.5f;
      m.baseAlpha = float(factorAlpha);
    } else if (gm.alphaMode == "BLEND") {
      // Semi-transparent, with the same alpha.
      m.blend = true;
      m.baseAlpha = float(factorAlpha);
    } else if (gm.alphaMode != "OPAQUE") {
      mesh_.warnings.push_back("material '" + m.name + "' has alphaMode '" + gm.alphaMode +
                               "', which glTF does not define (OPAQUE, MASK or BLEND): drawn "
                               "opaque, its alpha ignored");
    }
    if (info.index >= 0) {
      m.texture = texture(info.index, m.name);
      set = info.texCoord;
      // KHR_texture_transform, defined on glTF's texture coordinates (v down); ours have v up:
      // uv' = F T R S F uv with F the flip (u, v) → (u, 1 - v).
      const auto ext = info.extensions.find("KHR_texture_transform");
      if (ext != info.extensions.end() && ext->second.IsObject()) {
        const tinygltf::Value& t = ext->second;
        auto number = [](const tinygltf::Value& v, double fallback) {
          return v.IsNumber() ? v.GetNumberAsDouble() : fallback;
        };
        const double ox = number(t.Get("offset").Get(0), 0.0);
        const double oy = number(t.Get("offset").Get(1), 0.0);
        const double rotation = number(t.Get("rotation"), 0.0);
        const double sx = number(t.Get("scale").Get(0), 1.0);
        const double sy = number(t.Get("scale").Get(1), 1.0);
        if (t.Has("texCoord") && t.Get("texCoord").IsNumber())
          set = t.Get("texCoord").GetNumberAsInt();
        const double c = std::cos(rotation), s = std::sin(rotation);
        const glm::dmat3 translate(1, 0, 0, 0, 1, 0, ox, oy, 1);
        // A turn by -rotation in v-down coordinates (u' = c u + s v, v' = -s u + c v), as
        // Blender, Babylon and three.js read it and the extension's sample model shows; the
        // extension's GLSL listing has the opposite sign (KhronosGroup/glTF#1563).
        const glm::dmat3 rotate(c, -s, 0, s, c, 0, 0, 0, 1);
        const glm::dmat3 scale(sx, 0, 0, 0, sy, 0, 0, 0, 1);
        const glm::dmat3 flip(1, 0, 0, 0, -1, 0, 0, 1, 1);
        m.uvTransform = glm::mat3(flip * translate * rotate * scale * flip);
      }
    }
  }
  mesh_.materials.push_back(m);
  texCoordSet_.push_back(set);
  return it->second;
}

void GltfReader::addPrimitive(const tinygltf::Primitive& primitive,
                              const glm::dmat4& objectFromNode) {
  ++primitives_;
  const int mode = primitive.mode < 0 ? TINYGLTF_MODE_TRIANGLES : primitive.mode;
  if (mode == TINYGLTF_MODE_POINTS || mode == TINYGLTF_MODE_LINE ||
      mode == TINYGLTF_MODE_LINE_LOOP || mode == TINYGLTF_MODE_LINE_STRIP) {
    ++skippedLines;
    return;
  }
  if (mode != TINYGLTF_MODE_TRIANGLES && mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
      mode != TINYGLTF_MODE_TRIANGLE_FAN) {
    throw PrimitiveError{"unknown primitive mode " + std::to_string(mode)};
  }
  const auto attribute = [&](const std::string& name) {
    const auto it = primitive.attributes.find(name);
    return it == primitive.attributes.end() ? -1 : it->second;
  };
  const int positionAccessor = attribute("POSITION");
  if (positionAccessor < 0) throw PrimitiveError{"no POSITION attribute"};
  const std::vector<double> positions = accessor(positionAccessor, 3, "POSITION");
  const size_t n = positions.size() / 3;
  std::vector<double> normals;
  if (const int a = attribute("NORMAL"); a >= 0) {
    normals = accessor(a, 3, "NORMAL");
    if (normals.size() != positions.size())
      throw PrimitiveError{"NORMAL and POSITION have different counts"};
  }
  // COLOR_0 (linear RGB or RGBA, float or normalised integers) multiplies the base colour, its
  // alpha the base colour's alpha (glTF 2.0 §3.9.2; it matters to MASK and BLEND materials
  // only). A component outside 0..1 or not finite is clamped and counted; colours that cannot be
  // read are left out with a warning (the geometry stays).
  std::vector<double> colours, alphas;
  if (const int a = attribute("COLOR_0"); a >= 0) {
    try {
      const bool rgba = size_t(a) < model_.accessors.size() &&
                        componentCount(model_.accessors[size_t(a)].type) == 4;
      const int components = rgba ? 4 : 3;
      colours = accessor(a, components, "COLOR_0");
      if (colours.size() != size_t(components) * n)
        throw PrimitiveError{"COLOR_0 and POSITION have different counts"};
      const tinygltf::Accessor& acc = model_.accessors[size_t(a)];
      // Integers must be normalised (glTF 2.0 §3.7.2.1): one that is not says so in range anyway.
      double scale = 1.0;
      if (!acc.normalized && acc.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE)
        scale = 255.0;
      if (!acc.normalized && acc.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT)
        scale = 65535.0;
      std::vector<double> rgb(3 * n);
      if (rgba) alphas.resize(n);
      for (size_t i = 0; i < n; ++i)
        for (int c = 0; c < components; ++c) {
          const double e = colours[i * size_t(components) + size_t(c)] / scale;
          const double inRange = std::isfinite(e) ? std::clamp(e, 0.0, 1.0) : 0.0;
          if (inRange != e) ++clampedColours_;
          (c < 3 ? rgb[3 * i + size_t(c)] : alphas[i]) = inRange;
        }
      colours = std::move(rgb);
    } catch (const PrimitiveError& e) {
      colours.clear();
      alphas.clear();
      mesh_.warnings.push_back("ignored the vertex colours of a primitive: " + e.what);
    }
  }
  const uint32_t materialIndex = material(primitive.material, !colours.empty());
  // A primitive naming a material the file lacks is counted by material() and said once: it is
  // neither a primitive with a material nor one without.
  if (primitive.material < 0 && colours.empty())
    noMaterial_ = true;
  else if (size_t(primitive.material) < model_.materials.size())
    someMaterial_ = true;
  std::vector<double> texcoords;
  const bool textured = mesh_.materials[materialIndex].texture >= 0;
  if (textured) {
    const std::string set = "TEXCOORD_" + std::to_string(texCoordSet_[materialIndex]);
    if (const int a = attribute(set); a >= 0) {
      texcoords = accessor(a, 2, set);
      if (texcoords.size() != 2 * n)
        throw PrimitiveError{set + " and POSITION have different counts"};
    } else {
      ++missingTexcoords_;
    }
  }

  if (!primitive.targets.empty()) ++morphs_;

  std::vector<uint32_t> order;
  if (primitive.indices >= 0) {
    order = indices(primitive.indices, "indices");
  } else {
    order.resize(n);
    for (size_t i = 0; i < n; ++i) order[i] = uint32_t(i);
  }
  // Corners of the triangles (glTF 2.0 §3.7.2.1: strips alternate, fans turn about the first).
  std::vector<uint32_t> corners;
  if (mode == TINYGLTF_MODE_TRIANGLES) {
    corners.assign(order.begin(), order.begin() + std::ptrdiff_t(order.size() / 3 * 3));
    if (order.size() % 3 != 0) {
      ++ragged_;
      leftOver_ += order.size() % 3;
    }
  } else if (mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
    for (size_t i = 0; i + 2 < order.size(); ++i) {
      corners.insert(corners.end(), {order[i], order[i + 1 + i % 2], order[i + 2 - i % 2]});
    }
  } else {
    for (size_t i = 0; i + 2 < order.size(); ++i)
      corners.insert(corners.end(), {order[i + 1], order[i + 2], order[0]});
  }

  // Into object space; a mirroring transform turns the winding round to keep it outwards.
  const glm::dmat3 linear(objectFromNode);
  const bool mirrored = glm::determinant(linear) < 0.0;
  const glm::dmat3 normalFromNode = glm::transpose(glm::inverse(linear));
  // The hierarchy may instance a mesh any number of times: the triangles so far, this instance's
  // included, are checked against the limit before any of them is added.
  checkTriangleCount(int64_t(mesh_.indices.size() / 3 + corners.size() / 3), path_);
  const uint32_t base = uint32_t(mesh_.positions.size());
  for (size_t i = 0; i < n; ++i) {
    const glm::dvec3 p(positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]);
    exact_.emplace_back(objectFromNode * glm::dvec4(p, 1.0));
    mesh_.positions.emplace_back(exact_.back());
    if (!normals.empty()) {
      const glm::dvec3 nn =
          normalFromNode * glm::dvec3(normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]);
      mesh_.normals.emplace_back(nn);  // normalised (or rejected) in validation
    } else {
      mesh_.normals.emplace_back(0.0f);
    }
    out_.hasNormal.push_back(normals.empty() ? 0 : 1);
    // Without the coordinates its texture needs, not finite: the base colour factor alone
    // (render::Mesh::albedoAt), not the texel at (0, 0).
    mesh_.texcoords.emplace_back(
        !texcoords.empty() ? glm::vec2(float(texcoords[2 * i]), float(1.0 - texcoords[2 * i + 1]))
        : textured         ? glm::vec2(std::numeric_limits<float>::quiet_NaN())
                           : glm::vec2(0.0f));
    mesh_.colors.push_back(colours.empty()
                               ? glm::vec3(1.0f)
                               : glm::vec3(float(colours[3 * i]), float(colours[3 * i + 1]),
                                           float(colours[3 * i + 2])));
  }
  if (!colours.empty()) ++colours_;
  for (size_t i = 0; i < n; ++i) mesh_.alphas.push_back(alphas.empty() ? 1.0f : float(alphas[i]));
  for (size_t t = 0; t + 2 < corners.size(); t += 3) {
    uint32_t c[3] = {corners[t], corners[t + 1], corners[t + 2]};
    if (c[0] >= n || c[1] >= n || c[2] >= n) {
      ++droppedIndices;
      continue;
    }
    if (mirrored) std::swap(c[1], c[2]);
    for (uint32_t k : c) mesh_.indices.push_back(base + k);
    mesh_.triangleMaterial.push_back(materialIndex);
  }
  triangles_ += corners.size() / 3;
}

void GltfReader::read() {
  checkRequiredExtensions(model_, path_);
  // The scene: the default one, else the first, else every root node.
  std::vector<int> roots;
  if (!model_.scenes.empty()) {
    int scene = model_.defaultScene >= 0 ? model_.defaultScene : 0;
    if (model_.defaultScene < 0 && model_.scenes.size() > 1) {
      mesh_.warnings.push_back(
          "the file has " + std::to_string(model_.scenes.size()) +
          " scenes and names no default one: rendered scene 0" +
          (model_.scenes[0].name.empty() ? std::string() : " ('" + model_.scenes[0].name + "')"));
    }
    if (size_t(scene) >= model_.scenes.size()) {
      mesh_.warnings.push_back("the default scene " + std::to_string(scene) +
                               " does not exist: rendered scene 0");
      scene = 0;
    }
    roots = model_.scenes[size_t(scene)].nodes;
  } else {
    std::vector<uint8_t> isChild(model_.nodes.size(), 0);
    for (const tinygltf::Node& node : model_.nodes)
      for (int c : node.children)
        if (c >= 0 && size_t(c) < isChild.size()) isChild[size_t(c)] = 1;
    for (size_t i = 0; i < model_.nodes.size(); ++i)
      if (!isChild[i]) roots.push_back(int(i));
  }
  // Depth first, without recursion (a deep hierarchy must not overflow the stack); glTF nodes
  // form a forest, so a node met twice is a broken file.
  std::vector<uint8_t> visited(model_.nodes.size(), 0);
  std::vector<std::pair<int, glm::dmat4>> stack;
  for (auto r = roots.rbegin(); r != roots.rend(); ++r) stack.emplace_back(*r, glm::dmat4(1.0));
  std::vector<std::string> skipped;
  while (!stack.empty()) {
    const auto [index, parent] = stack.back();
    stack.pop_back();
    if (index < 0 || size_t(index) >= model_.nodes.size()) {
      throw Error("mesh",
                  "the scene refers to node " + std::to_string(index) + ", the file has " +
                      std::to_string(model_.nodes.size()),
                  path_);
    }
    if (visited[size_t(index)]) {
      throw Error("mesh",
                  "node " + std::to_string(index) +
                      " appears twice in the node hierarchy (glTF nodes form a tree)",
                  path_);
    }
    visited[size_t(index)] = 1;
    const tinygltf::Node& node = model_.nodes[size_t(index)];
    const glm::dmat4 objectFromNode = parent * localTransform(node, index);
    if (node.mesh >= 0) {
      if (size_t(node.mesh) >= model_.meshes.size()) {
        throw Error("mesh",
                    "node " + std::to_string(index) + " refers to mesh " +
                        std::to_string(node.mesh) + ", the file has " +
                        std::to_string(model_.meshes.size()),
                    path_);
      }
      if (node.skin >= 0) ++skinned_;
      const tinygltf::Mesh& m = model_.meshes[size_t(node.mesh)];
      const std::string meshName =
          "mesh " + std::to_string(node.mesh) + (m.name.empty() ? "" : " '" + m.name + "'");
      const std::vector<glm::dmat4> drawn = instances(node, index);
      size_t skippedByFirst = skippedLines;
      for (size_t i = 0; i < drawn.size(); ++i) {
        if (i == 1) skippedByFirst = skippedLines;  // every instance skips the same primitives
        for (size_t p = 0; p < m.primitives.size(); ++p) {
          try {
            addPrimitive(m.primitives[p], objectFromNode * drawn[i]);
          } catch (const PrimitiveError& e) {
            // Said once: every instance draws the same primitives.
            if (i == 0)
              skipped.push_back(meshName + " primitive " + std::to_string(p) + ": " + e.what);
          }
        }
      }
      if (drawn.size() > 1) skippedLines = skippedByFirst;
    }
    for (auto c = node.children.rbegin(); c != node.children.rend(); ++c)
      stack.emplace_back(*c, objectFromNode);
  }

  for (const std::string& s : skipped) mesh_.warnings.push_back("skipped " + s);
  if (skippedLines) {
    mesh_.warnings.push_back("skipped " + count(skippedLines, "primitive", "primitives") +
                             " of points or lines (only triangles render)");
  }
  if (droppedIndices) {
    mesh_.warnings.push_back("dropped " + std::to_string(droppedIndices) + " of " +
                             std::to_string(triangles_) +
                             " triangles whose indices refer to vertices the primitive does not "
                             "have");
  }
  // A mesh far from its file's origin (a scene exported in place, georeferenced): float positions
  // there are coarse on the object's scale (a 1-unit sphere 5000 units out rounds to 0.0005,
  // enough for its shadows to speckle). Moved to its own middle in double first.
  // The box of the vertices triangles use (a vertex no triangle uses, at the origin, kept a far
  // mesh from being moved).
  if (!exact_.empty()) {
    std::vector<uint8_t> used(exact_.size(), 0);
    for (const uint32_t i : mesh_.indices)
      if (i < used.size()) used[i] = 1;
    glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
    for (size_t i = 0; i < exact_.size(); ++i) {
      const glm::dvec3& p = exact_[i];
      if (!used[i] || !std::isfinite(p.x + p.y + p.z)) continue;
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
    const glm::dvec3 middle = 0.5 * (lo + hi);
    const double size = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
    const double far = std::max({std::abs(middle.x), std::abs(middle.y), std::abs(middle.z)});
    if (lo.x <= hi.x && size > 0.0 && far > 100.0 * size) {
      for (size_t i = 0; i < exact_.size(); ++i) mesh_.positions[i] = glm::vec3(exact_[i] - middle);
      mesh_.fileOrigin = middle;
      char line[240];
      std::snprintf(line, sizeof line,
                    "the mesh lies %.4g units from its file's origin (%.4g times its size): moved "
                    "to its own middle before rounding its positions to float "
                    "(compose:worldFromObject still maps the file's coordinates)",
                    far, far / size);
      mesh_.warnings.push_back(line);
    }
  }
  if (colours_ == 0) mesh_.colors.clear();  // white everywhere: nothing to multiply
  // BLEND with nothing below alpha 1 (exporters often mark every material BLEND) is opaque: no
  // ray needs to ask it.
  std::vector<uint8_t> fades(mesh_.materials.size(), 0);  // some vertex alpha below 1
  for (size_t t = 0; t < mesh_.triangleMaterial.size(); ++t)
    for (int k = 0; k < 3; ++k)
      if (mesh_.alphas[mesh_.indices[3 * t + size_t(k)]] < 1.0f)
        fades[mesh_.triangleMaterial[t]] = 1;
  for (size_t i = 0; i < mesh_.materials.size(); ++i) {
    Material& m = mesh_.materials[i];
    if (m.blend && !(m.baseAlpha < 1.0f) && !fades[i] &&
        (m.texture < 0 || mesh_.textures[size_t(m.texture)].alpha.empty()))
      m.blend = false;
  }
  if (clampedColours_ > 0) {
    mesh_.warnings.push_back(count(clampedColours_, "COLOR_0 component", "COLOR_0 components") +
                             " outside 0..1 (or not finite) clamped");
  }
  if (ragged_) {
    mesh_.warnings.push_back(
        count(ragged_, "triangle list has", "triangle lists have") + " a number of " +
        "vertices (indices, or vertices where it has none) that is not a multiple of 3: the " +
        count(leftOver_, "vertex", "vertices") + " left over at the end ignored");
  }
  if (morphs_) {
    mesh_.warnings.push_back("ignored the morph targets of " +
                             count(morphs_, "primitive", "primitives") +
                             ": the base shape renders");
  }
  if (skinned_) {
    mesh_.warnings.push_back(count(skinned_, "node is", "nodes are") +
                             " skinned: rendered in the bind pose, under the node transforms");
  }
  if (!unrendered_.empty()) {
    std::string what;
    for (const auto& [feature, materials] : unrendered_)
      what += (what.empty() ? "" : ", ") + feature + " (" +
              count(size_t(materials), "material", "materials") + ")";
    mesh_.warnings.push_back(
        "every material renders as a diffuse surface of its base colour; "
        "not rendered: " +
        what);
  }
  if (missingMaterials_) {
    mesh_.warnings.push_back(count(missingMaterials_, "primitive refers", "primitives refer") +
                             " to a material the file does not have: rendered with the default "
                             "albedo");
  }
  if (missingTexcoords_) {
    mesh_.warnings.push_back(count(missingTexcoords_, "primitive has", "primitives have") +
                             " a base-colour texture but not its texture coordinates: rendered "
                             "with the base colour factor");
  }
  if (mesh_.indices.empty()) {
    std::string why = "nothing renderable: ";
    if (primitives_ == 0) {
      why += "the scene has no meshes";
    } else {
      why += "no triangles in " + count(primitives_, "primitive", "primitives");
      if (!skipped.empty()) {
        why += " (" + skipped.front() + ")";
      } else if (!mesh_.warnings.empty()) {
        // Lines or points only, or every triangle's indices out of range: the warnings say which.
        std::string reasons;
        for (const std::string& w : mesh_.warnings) reasons += (reasons.empty() ? "" : "; ") + w;
        why += ": " + reasons;
      }
    }
    throw Error("mesh", why, path_);
  }
  if (!someMaterial_) {
    // No primitive names a material: the renderer's albedo (--albedo) applies everywhere.
    mesh_.materials.clear();
    mesh_.triangleMaterial.clear();
  } else if (noMaterial_) {
    mesh_.warnings.push_back("some primitives have no material: rendered with the default albedo");
  }
}

// What the callbacks saw: the files read besides the glTF itself. `renamed` holds the buffer
// files tinygltf would look for under another name, as it will ask for them and as they are.
struct ReadFiles {
  fs::path main;
  bool binary = false;
  std::vector<fs::path> others;
  std::optional<std::map<std::string, std::string>> renamed;  // read when first needed
};

// tinygltf's file callbacks, for regular files only: a buffer or image URI naming a FIFO would
// block forever (tinygltf's own existence check opens the file), a device be read without end.
// A URI is relative to the glTF's folder: tinygltf 2.7 looks in the working directory after it
// ("./name"), where another export's file of the same name was read without a word.
bool fileExists(const std::string& file, void* user) {
  if (const auto* seen = static_cast<const ReadFiles*>(user)) {
    // The folder as tinygltf takes it from the glTF's path (GetBaseDir): its candidates in that
    // folder start with it ("./asset/model.bin" for ./asset/model.gltf); the working directory's
    // is "./" + the URI.
    const std::string main = seen->main.string();
    const size_t slash = main.find_last_of('/');
    const std::string base = slash == std::string::npos ? std::string() : main.substr(0, slash);
    if (!base.empty() && base != "." && file.rfind("./", 0) == 0 && file.rfind(base + "/", 0) != 0)
      return false;
  }
  std::error_code ec;
  return fs::exists(file, ec);  // without opening it (readRegularFile refuses what is not a file)
}

// A buffer URI as tinygltf 2.7 decodes it (dlib's urldecode): '+' a space, and '%' with the two
// characters after it taken as hexadecimal digits whatever they are (a digit that is not one
// counts 0).
std::string tinygltfDecode(const std::string& uri) {
  auto hex = [](char c) {
    return c >= '0' && c <= '9'   ? c - '0'
           : c >= 'a' && c <= 'f' ? c - 'a' + 10
           : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                  : 0;
  };
  std::string out;
  for (size_t i = 0; i < uri.size(); ++i) {
    if (uri[i] == '+') {
      out += ' ';
    } else if (uri[i] == '%' && uri.size() > i + 2) {
      out += char((hex(uri[i + 1]) << 4) | hex(uri[i + 2]));
      i += 2;
    } else {
      out += uri[i];
    }
  }
  return out;
}

// The JSON of a .gltf, or of a .glb's first chunk; empty when it cannot be read (tinygltf says
// why).
std::string gltfJson(const fs::path& path, bool binary) {
  std::ifstream in(path, std::ios::binary);
  std::string text;
  if (binary) {
    unsigned char header[20];
    if (!in.read(reinterpret_cast<char*>(header), sizeof header)) return {};
    const uint32_t length = uint32_t(header[12]) | uint32_t(header[13]) << 8 |
                            uint32_t(header[14]) << 16 | uint32_t(header[15]) << 24;
    std::error_code ec;
    if (length > fs::file_size(path, ec) || ec) return {};
    text.resize(length);
    if (!in.read(text.data(), std::streamsize(length))) return {};
  } else {
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  return text;
}

// The buffer files whose URI holds a '+', under the path tinygltf will ask for (its base folder
// joined as it joins it) and their true path. A file that does not parse gives none: tinygltf
// says what is wrong with it.
std::map<std::string, std::string> renamedBuffers(const fs::path& path, bool binary) {
  const std::string text = gltfJson(path, binary);
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.is_object() || !j.contains("buffers") || !j["buffers"].is_array())
    return {};
  const std::string file = path.string();
  const size_t slash = file.find_last_of("/\\");
  const std::string base = slash == std::string::npos ? "" : file.substr(0, slash);
  auto join = [&](const std::string& name) {
    return base.empty() ? name : base.back() == '/' ? base + name : base + "/" + name;
  };
  // Every buffer file by the name tinygltf will ask for; a name two files share ("a+b.bin" and
  // "a%20b.bin" both ask for "a b.bin") is left as tinygltf reads it rather than redirected.
  std::map<std::string, std::set<std::string>> asked;
  for (const nlohmann::json& buffer : j["buffers"]) {
    if (!buffer.is_object() || !buffer.contains("uri") || !buffer["uri"].is_string()) continue;
    const std::string uri = buffer["uri"].get<std::string>();
    if (uri.rfind("data:", 0) == 0) continue;
    asked[join(tinygltfDecode(uri))].insert(join(decodeUri(uri)));
  }
  std::map<std::string, std::string> out;
  for (const auto& [name, files] : asked)
    if (files.size() == 1 && *files.begin() != name) out[name] = *files.begin();
  return out;
}

// Only a name with a space can come from a '+': the glTF's JSON is read again for those alone
// (a .gltf of embedded data URIs can be hundreds of megabytes).
std::string expandFilePath(const std::string& file, void* user) {
  auto* seen = static_cast<ReadFiles*>(user);
  if (file.find(' ') == std::string::npos) return file;
  if (!seen->renamed) seen->renamed = renamedBuffers(seen->main, seen->binary);
  if (const auto it = seen->renamed->find(file); it != seen->renamed->end()) return it->second;
  return file;
}

bool readRegularFile(std::vector<unsigned char>* out, std::string* err, const std::string& file,
                     void* user) {
  if (auto* seen = static_cast<ReadFiles*>(user); seen && fs::path(file) != seen->main)
    seen->others.push_back(file);
  std::error_code ec;
  if (fs::exists(file, ec) && !fs::is_regular_file(file, ec)) {
    if (err) *err += "'" + file + "' is not a regular file\n";
    return false;
  }
  return tinygltf::ReadWholeFile(out, err, file, nullptr);
}

// A binary glTF's chunks must lie within the file: tinygltf 2.7 checks the BIN chunk's length
// without its 8-byte header, and read up to 8 bytes past the end of the file's bytes.
void checkGlbChunks(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return;  // tinygltf says why
  auto word = [&](uint64_t at, uint32_t& value) {
    unsigned char b[4];
    in.seekg(std::streamoff(at));
    if (!in.read(reinterpret_cast<char*>(b), 4)) return false;
    value = uint32_t(b[0]) | uint32_t(b[1]) << 8 | uint32_t(b[2]) << 16 | uint32_t(b[3]) << 24;
    return true;
  };
  uint32_t magic = 0, length = 0, jsonLength = 0, binLength = 0;
  if (!word(0, magic) || magic != 0x46546C67u) return;    // not "glTF": tinygltf says so
  if (!word(8, length) || !word(12, jsonLength)) return;  // too short: tinygltf says so
  const uint64_t bin = 20ull + jsonLength;                // where the BIN chunk's header is
  if (bin + 8 > length || !word(bin, binLength)) return;  // no BIN chunk (or tinygltf's error)
  if (bin + 8 + binLength > length) {
    throw Error("mesh",
                "cannot parse glTF: its BIN chunk holds " + std::to_string(binLength) +
                    " bytes, more than the " + std::to_string(length - bin - 8) +
                    " the file's length leaves it (a truncated or damaged .glb)",
                path);
  }
}

}  // namespace

LoadedMesh loadGltf(const fs::path& path) {
  tinygltf::TinyGLTF parser;
  parser.SetImageLoader(&keepEncodedImage, nullptr);
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  if (ext == ".glb") checkGlbChunks(path);
  // tinygltf reads values recursively: a file nested a hundred thousand levels deep overflowed
  // the stack.
  if (jsonNestedDeeperThan(gltfJson(path, ext == ".glb")))
    throw Error("mesh",
                "cannot parse glTF: its JSON nests deeper than " + std::to_string(kMaxJsonDepth) +
                    " levels",
                path);
  ReadFiles seen{path, ext == ".glb", {}, std::nullopt};
  parser.SetFsCallbacks(tinygltf::FsCallbacks{&fileExists, &expandFilePath, &readRegularFile,
                                              &tinygltf::WriteWholeFile, &seen});
  tinygltf::Model model;
  std::string err, warn;
  bool ok = false;
  try {
    ok = ext == ".glb" ? parser.LoadBinaryFromFile(&model, &err, &warn, path.string())
                       : parser.LoadASCIIFromFile(&model, &err, &warn, path.string());
  } catch (const std::exception& e) {
    // tinygltf itself may throw on a malformed file (an index checked with vector::at).
    throw Error("mesh", std::string("cannot parse glTF: ") + e.what(), path);
  }
  auto lines = [](const std::string& text) {
    std::vector<std::string> out;
    size_t start = 0;
    while (start < text.size()) {
      size_t end = text.find('\n', start);
      if (end == std::string::npos) end = text.size();
      std::string line = jsonMessage(text.substr(start, end - start));
      while (!line.empty() && (line.back() == '\r' || line.back() == '.' || line.back() == ' '))
        line.pop_back();
      // tinygltf quotes what it could not read, a whole data: URI of megabytes included.
      constexpr size_t kLongest = 240;
      if (line.size() > kLongest)
        line =
            line.substr(0, kLongest - 40) + "... (" + std::to_string(line.size()) + " characters)";
      if (!line.empty()) out.push_back(line);
      start = end + 1;
    }
    return out;
  };
  if (!ok) {
    // tinygltf reads extensionsRequired before the buffers: a compressed file (meshopt's buffer
    // without a uri) fails on them, and the extension is what to say.
    checkRequiredExtensions(model, path);
    const std::vector<std::string> why = lines(err);
    std::string joined;
    for (const std::string& w : why) joined += (joined.empty() ? "" : "; ") + w;
    throw Error("mesh", "cannot parse glTF: " + (joined.empty() ? "unknown reason" : joined), path);
  }
  // glTF 2.0 §3.2: a file of another major version is not to be read as this one.
  if (const std::string& version = model.asset.version;
      !version.empty() && version.substr(0, version.find('.')) != "2") {
    throw Error("mesh", "glTF version " + version + ": this reader reads glTF 2.x (asset.version)",
                path);
  }
  LoadedMesh loaded;
  loaded.mesh.otherFiles = seen.others;
  GltfReader(model, path, loaded).read();
  return loaded;
}

}  // namespace compose::render::detail
