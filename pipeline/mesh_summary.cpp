#include "pipeline/mesh_summary.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>

#include "core/error.h"
#include "core/limits.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_util.h"
#include "render/transfer.h"

namespace compose::pipeline {

namespace fs = std::filesystem;

namespace {

// Raise when reading a mesh file gives anything different (the loaders, the normals, the
// repairs) or when the convexity test (render::isConvex) changes: an entry kept by an older
// compose would otherwise stand for a different mesh, or skip the self-shadowing wrongly.
// 2: a mesh far from its file's origin is moved to it; 3: OBJs too; 4: OBJ vertex colours are
// read (such a file has a material now, and is no longer kept); 5: sharp edges on lines that end
// in a smooth surface are shaded smooth; 6: only those less than 25° sharper than the crease;
// 7: OBJ faces of 256 corners and more kept whole, a Kd that is not a number the default grey;
// 8: lines split at a lone CR, a Kd of one number a grey; 9: KHR_texture_transform's rotation
// turned as Blender turns it, textures not turned by their EXIF orientation; 10: OBJ material
// names whole, map_Kd relative to its library and with its options read as the MTL format has
// them, a byte-order mark skipped, backslash-continued lines joined; 11: a glTF primitive
// without the texture coordinates its texture needs renders its base colour factor; 12: MTL
// d and map_d read; 13: glTF's KHR_materials_unlit said; 14: a far mesh moved by the vertices
// its triangles use; 15: meshes of 1e12 units or more refused, OBJ colours on some vertices kept;
// 16: meshes under 1e-7 units refused; 17: glTF's EXT_mesh_gpu_instancing drawn; 18: open
// pieces get back sides of their own (render::addBackSides).
constexpr uint32_t kMeshVersion = 18;
constexpr uint32_t kConvexityVersion = 2;  // 2: corners welded to a millionth of the size

StageCache meshEntry(const fs::path& cacheRoot, const Hash128& contentKey) {
  return StageCache(cacheRoot / "meshes", "mesh", contentKey.hex());
}

std::optional<uint64_t> hexWord(const nlohmann::json& value) {
  if (!value.is_string()) return std::nullopt;
  const std::string s = value.get<std::string>();
  if (s.size() != 16 || s.find_first_not_of("0123456789abcdef") != std::string::npos)
    return std::nullopt;
  return std::strtoull(s.c_str(), nullptr, 16);
}

// The mesh's one material is the white one its vertex colours brought, with no texture.
bool colouredOnly(const render::Mesh& mesh) {
  if (mesh.colors.empty() || mesh.materials.size() != 1 || !mesh.textures.empty()) return false;
  const render::Material& m = mesh.materials[0];
  return m.baseColor == glm::vec3(1.0f) && m.texture < 0 && !m.cutOut() &&
         m.uvTransform == glm::mat3(1.0f);
}

}  // namespace

Hash128 meshKey(const render::Mesh& mesh, double creaseDegrees) {
  Hash128 h;
  h.bytes("mesh");
  h.bytes(render::meshHash(mesh));
  h.number(creaseDegrees);
  if (!mesh.texcoords.empty())
    h.floats(std::span<const float>(&mesh.texcoords[0].x, 2 * mesh.texcoords.size()));
  if (!mesh.colors.empty()) {
    h.bytes("colours");
    h.floats(std::span<const float>(&mesh.colors[0].x, 3 * mesh.colors.size()));
  }
  if (!mesh.alphas.empty()) {
    h.bytes("alphas");
    h.floats(std::span<const float>(mesh.alphas.data(), mesh.alphas.size()));
  }
  for (uint32_t m : mesh.triangleMaterial) h.word(m);
  for (const render::Material& m : mesh.materials) {
    h.floats(std::span<const float>(&m.baseColor.x, 3));
    h.word(uint32_t(m.texture));
    h.floats(std::span<const float>(&m.uvTransform[0][0], 9));
    h.floats(std::span<const float>(&m.alphaCutoff, 1));
    h.floats(std::span<const float>(&m.baseAlpha, 1));
    if (m.blend) h.bytes("blend");
  }
  for (const render::Texture& t : mesh.textures) {
    h.word(uint32_t(t.image.width));
    h.word(uint32_t(t.image.height));
    h.word(uint32_t(t.image.channels));
    h.bytes(t.image.colorSpace);
    h.bytes(t.file.filename().string());
    h.word(uint32_t(t.wrapU));
    h.word(uint32_t(t.wrapV));
    h.word(t.srgbByFormat ? 1u : 0u);
    if (t.nearest) h.bytes("nearest");  // magnified as blocks of texels
    h.floats(t.image.pixels);
    h.floats(t.alpha.pixels);
  }
  h.bytes(mesh.colorSpace);
  // Where the file puts the object (a far mesh moved to its middle): the header maps from there.
  h.number(mesh.fileOrigin.x);
  h.number(mesh.fileOrigin.y);
  h.number(mesh.fileOrigin.z);
  return h;
}

std::vector<std::string> meshNotes(const render::Mesh& mesh) {
  std::vector<std::string> notes;
  if (!mesh.normalsFromFile) notes.push_back("object normals: " + mesh.normalsSource);
  for (const std::string& w : mesh.warnings) notes.push_back("object: " + w);
  return notes;
}

MeshSummary summarize(const render::Mesh& mesh, double creaseDegrees) {
  MeshSummary s;
  s.key = meshKey(mesh, creaseDegrees);
  s.nothingKept = !mesh.keptBounds(s.boundsMin, s.boundsMax);  // without what cut-outs take away
  s.triangles = mesh.frontTriangleCount();
  s.convex = render::isConvex(mesh);
  s.notes = meshNotes(mesh);
  return s;
}

std::optional<CachedMesh> cachedMesh(const fs::path& cacheRoot, const fs::path& file,
                                     double creaseDegrees, Hash128& contentKey,
                                     std::string& problem) {
  problem.clear();
  contentKey = Hash128{};
  if (cacheRoot.empty()) return std::nullopt;
  // Whatever is wrong with the file is for the mesh reader to say, in its own words.
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) return std::nullopt;
  Hash128 h;
  h.bytes("mesh as read");
  h.word(kMeshVersion);
  h.word(kConvexityVersion);
  h.number(creaseDegrees);
  h.bytes(file.extension().string());
  try {
    hashFile(h, file, "ingest");
  } catch (const Error&) {
    return std::nullopt;
  }
  contentKey = h;
  StageCache entry = meshEntry(cacheRoot, contentKey);
  if (!entry.open()) {
    problem = entry.problem();
    return std::nullopt;
  }
  problem = "does not fit this job";
  const nlohmann::json& m = entry.meta();
  const auto a = m.contains("keyA") ? hexWord(m["keyA"]) : std::nullopt;
  const auto b = m.contains("keyB") ? hexWord(m["keyB"]) : std::nullopt;
  if (!a || !b || !m.contains("convex") || !m["convex"].is_boolean() ||
      !m.contains("normalsFromFile") || !m["normalsFromFile"].is_boolean() ||
      !m.contains("normalsSource") || !m["normalsSource"].is_string() || !m.contains("warnings") ||
      !m["warnings"].is_array())
    return std::nullopt;
  CachedMesh out;
  render::Mesh& mesh = out.mesh;
  mesh.normalsFromFile = m["normalsFromFile"].get<bool>();
  mesh.normalsSource = m["normalsSource"].get<std::string>();
  if (const auto o = m.find("fileOrigin"); o != m.end()) {
    if (!o->is_array() || o->size() != 3 || !(*o)[0].is_number() || !(*o)[1].is_number() ||
        !(*o)[2].is_number())
      return std::nullopt;
    mesh.fileOrigin = {(*o)[0].get<double>(), (*o)[1].get<double>(), (*o)[2].get<double>()};
  }
  for (const nlohmann::json& w : m["warnings"]) {
    if (!w.is_string()) return std::nullopt;
    mesh.warnings.push_back(w.get<std::string>());
  }
  const std::span<const float> positions = entry.get("positions");
  const std::span<const float> normals = entry.get("normals");
  const std::span<const float> indices = entry.get("indices");
  const std::span<const float> texcoords = entry.get("texcoords");
  const std::span<const float> colours = entry.get("colours");
  const std::span<const float> sides = entry.get("sides");
  const size_t n = positions.size() / 3;
  if (n == 0 || positions.size() != 3 * n || normals.size() != 3 * n || indices.empty() ||
      indices.size() % 3 != 0 || (!texcoords.empty() && texcoords.size() != 2 * n) ||
      (!colours.empty() &&
       (colours.size() != 3 * n || !m.contains("colourSpace") || !m["colourSpace"].is_string())))
    return std::nullopt;
  for (const float i : indices)
    if (!(i >= 0.0f && i < float(n) && i == std::floor(i))) return std::nullopt;
  if (!sides.empty() && sides.size() != indices.size() / 3) return std::nullopt;
  size_t backSides = 0;
  for (const float s : sides) {
    if (s != 0.0f && s != float(render::Mesh::kFrontSide) && s != float(render::Mesh::kBackSide))
      return std::nullopt;
    backSides += s == float(render::Mesh::kBackSide);
  }
  // The limit holds for the mesh as kept, as for one read (--max-triangles: the file's
  // triangles, without the back sides loading gave them).
  checkTriangleCount(int64_t(indices.size() / 3 - backSides), file);
  mesh.positions.resize(n);
  mesh.normals.resize(n);
  std::memcpy(&mesh.positions[0].x, positions.data(), positions.size() * sizeof(float));
  std::memcpy(&mesh.normals[0].x, normals.data(), normals.size() * sizeof(float));
  mesh.indices.assign(indices.begin(), indices.end());
  mesh.sides.assign(sides.begin(), sides.end());
  if (!texcoords.empty()) {
    mesh.texcoords.resize(n);
    std::memcpy(&mesh.texcoords[0].x, texcoords.data(), texcoords.size() * sizeof(float));
  }
  if (!colours.empty()) {  // with the white material they bring (render::loadMesh)
    mesh.colors.resize(n);
    std::memcpy(&mesh.colors[0].x, colours.data(), colours.size() * sizeof(float));
    mesh.colorSpace = m["colourSpace"].get<std::string>();
    render::Material white;
    white.name = "vertex colours";
    mesh.materials.push_back(white);
    mesh.triangleMaterial.assign(mesh.triangleCount(), 0u);
  }
  // What the entry says of the mesh must be the mesh it holds.
  MeshSummary& s = out.summary;
  s.key = meshKey(mesh, creaseDegrees);
  if (s.key.a != *a || s.key.b != *b) return std::nullopt;
  s.nothingKept = !mesh.keptBounds(s.boundsMin, s.boundsMax);
  s.triangles = mesh.frontTriangleCount();
  s.convex = m["convex"].get<bool>();
  s.notes = meshNotes(mesh);
  s.fromCache = true;
  problem.clear();
  return out;
}

bool storeMesh(const fs::path& cacheRoot, const Hash128& contentKey, const render::Mesh& mesh,
               const MeshSummary& summary, std::string& problem) {
  problem.clear();
  // Indices are kept as floats: exact below 2^24. A mesh whose only material is the white one
  // its vertex colours brought (render::loadMesh) is kept with its colours.
  if (cacheRoot.empty() || contentKey == Hash128{} || !mesh.otherFiles.empty() ||
      (mesh.hasMaterials() && !colouredOnly(mesh)) || mesh.positions.empty() ||
      mesh.positions.size() >= (size_t(1) << 24))
    return true;
  StageCache entry = meshEntry(cacheRoot, contentKey);
  char word[17];
  std::snprintf(word, sizeof word, "%016llx", static_cast<unsigned long long>(summary.key.a));
  entry.meta()["keyA"] = word;
  std::snprintf(word, sizeof word, "%016llx", static_cast<unsigned long long>(summary.key.b));
  entry.meta()["keyB"] = word;
  entry.meta()["convex"] = summary.convex;
  entry.meta()["normalsFromFile"] = mesh.normalsFromFile;
  entry.meta()["normalsSource"] = mesh.normalsSource;
  entry.meta()["warnings"] = mesh.warnings;
  entry.meta()["fileOrigin"] = {mesh.fileOrigin.x, mesh.fileOrigin.y, mesh.fileOrigin.z};
  const auto floats = [](const auto& v, size_t per) {
    std::vector<float> out(v.size() * per);
    if (!v.empty()) std::memcpy(out.data(), &v[0].x, out.size() * sizeof(float));
    return out;
  };
  entry.put("positions", floats(mesh.positions, 3));
  entry.put("normals", floats(mesh.normals, 3));
  entry.put("indices", std::vector<float>(mesh.indices.begin(), mesh.indices.end()));
  if (!mesh.sides.empty())
    entry.put("sides", std::vector<float>(mesh.sides.begin(), mesh.sides.end()));
  if (!mesh.texcoords.empty()) entry.put("texcoords", floats(mesh.texcoords, 2));
  if (!mesh.colors.empty()) {
    entry.put("colours", floats(mesh.colors, 3));
    entry.meta()["colourSpace"] = mesh.colorSpace;
  }
  if (entry.write()) return true;
  problem = entry.error();
  return false;
}

}  // namespace compose::pipeline
