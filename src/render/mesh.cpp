#include "render/mesh.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <string_view>
#include <unordered_map>
#include <unordered_set>

#include <tiny_obj_loader.h>
#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/output_files.h"

namespace compose::render {

namespace fs = std::filesystem;

glm::vec3 Mesh::boundsMin() const {
  glm::vec3 lo(std::numeric_limits<float>::max());
  for (const auto& p : positions) lo = glm::min(lo, p);
  return lo;
}

glm::vec3 Mesh::boundsMax() const {
  glm::vec3 hi(-std::numeric_limits<float>::max());
  for (const auto& p : positions) hi = glm::max(hi, p);
  return hi;
}

glm::vec3 Mesh::albedoAt(uint32_t triangle, float u, float v) const {
  const uint32_t m = triangleMaterial.empty() ? 0u : triangleMaterial[triangle];
  const Material& mat = materials[std::min<size_t>(m, materials.size() - 1)];
  if (mat.texture < 0 || texcoords.empty()) return mat.baseColor;
  const uint32_t* c = &indices[3 * size_t(triangle)];
  const glm::vec2 uv = (1.0f - u - v) * texcoords[c[0]] + u * texcoords[c[1]] + v * texcoords[c[2]];
  const Image& img = textures[size_t(mat.texture)].image;
  // Texel centres at (i + 0.5) / width; v = 0 is the bottom row (OBJ and glTF flip differently:
  // loaders store v so that this holds).
  const float x = uv.x * float(img.width) - 0.5f, y = (1.0f - uv.y) * float(img.height) - 0.5f;
  const float fx = std::floor(x), fy = std::floor(y);
  const float ax = x - fx, ay = y - fy;
  auto texel = [&](int ix, int iy) {
    ix = ((ix % img.width) + img.width) % img.width;
    iy = ((iy % img.height) + img.height) % img.height;
    const float* p = img.at(ix, iy);
    return img.channels >= 3 ? glm::vec3(p[0], p[1], p[2]) : glm::vec3(p[0]);
  };
  const int x0 = int(fx), y0 = int(fy);
  const glm::vec3 t = (texel(x0, y0) * (1.0f - ax) + texel(x0 + 1, y0) * ax) * (1.0f - ay) +
                      (texel(x0, y0 + 1) * (1.0f - ax) + texel(x0 + 1, y0 + 1) * ax) * ay;
  return mat.baseColor * t;
}

void computeVertexNormals(Mesh& mesh) {
  // Angle-weighted face normals (Thürmer & Wüthrich 1998): unlike area weighting, the result does
  // not depend on how polygons were split into triangles.
  mesh.normals.assign(mesh.positions.size(), glm::vec3(0.0f));
  for (size_t t = 0; t < mesh.indices.size(); t += 3) {
    const uint32_t v[3] = {mesh.indices[t], mesh.indices[t + 1], mesh.indices[t + 2]};
    const glm::vec3 p[3] = {mesh.positions[v[0]], mesh.positions[v[1]], mesh.positions[v[2]]};
    const glm::vec3 n = glm::cross(p[1] - p[0], p[2] - p[0]);
    const float len = glm::length(n);
    if (!(len > 0.0f)) continue;  // degenerate triangle
    for (int k = 0; k < 3; ++k) {
      const glm::vec3 a = p[(k + 1) % 3] - p[k], b = p[(k + 2) % 3] - p[k];
      const float la = glm::length(a), lb = glm::length(b);
      if (!(la > 0.0f && lb > 0.0f)) continue;
      const float angle = std::acos(std::clamp(glm::dot(a, b) / (la * lb), -1.0f, 1.0f));
      mesh.normals[v[k]] += n * (angle / len);
    }
  }
  for (auto& n : mesh.normals) {
    const float len = glm::length(n);
    n = len > 0.0f ? n / len : glm::vec3(0.0f, 1.0f, 0.0f);
  }
  mesh.normalsFromFile = false;
}

namespace {

// tinyobjloader reads a malformed number ("nan", "inf", "abc") as 0 without saying so. This pass
// over the text finds them first and names the line: every field of v, vn and vt must be a
// finite number, and every corner of f an integer reference.
void checkObjNumbers(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("mesh", withSystemReason("cannot open", errno), path);
  std::string line;
  size_t lineNo = 0;
  auto fail = [&](const std::string& what) {
    throw Error("mesh", "line " + std::to_string(lineNo) + ": " + what, path);
  };
  std::vector<std::string_view> fields;
  while (std::getline(in, line)) {
    ++lineNo;
    fields.clear();
    for (size_t i = 0; i < line.size();) {
      while (i < line.size() && std::isspace(static_cast<unsigned char>(line[i]))) ++i;
      size_t j = i;
      while (j < line.size() && !std::isspace(static_cast<unsigned char>(line[j]))) ++j;
      if (j > i) fields.emplace_back(line.data() + i, j - i);
      i = j;
    }
    if (fields.empty() || fields[0].front() == '#') continue;
    const std::string_view key = fields[0];
    if (key == "v" || key == "vn" || key == "vt") {
      const size_t needed = key == "vt" ? 1 : 3;
      if (fields.size() < needed + 1) {
        fail("'" + std::string(key) + "' needs " + std::to_string(needed) + " numbers, has " +
             std::to_string(fields.size() - 1));
      }
      for (size_t f = 1; f < fields.size(); ++f) {
        const std::string text(fields[f]);
        char* end = nullptr;
        const double v = std::strtod(text.c_str(), &end);
        if (end != text.c_str() + text.size() || !std::isfinite(v)) {
          fail(std::string(key == "v"    ? "vertex coordinate"
                           : key == "vn" ? "normal component"
                                         : "texture coordinate") +
               " '" + text + "' is not a finite number");
        }
      }
    } else if (key == "f") {
      if (fields.size() < 4) fail("a face needs at least 3 corners");
      for (size_t f = 1; f < fields.size(); ++f) {
        // v, v/vt, v//vn or v/vt/vn: integers, the first present and none zero.
        const std::string_view corner = fields[f];
        size_t start = 0;
        for (int part = 0; part < 3 && start <= corner.size(); ++part) {
          const size_t slash = std::min(corner.find('/', start), corner.size());
          const std::string_view number = corner.substr(start, slash - start);
          if (!(number.empty() && part > 0)) {
            long value = 0;
            const auto [ptr, ec] =
                std::from_chars(number.data(), number.data() + number.size(), value);
            if (ec != std::errc() || ptr != number.data() + number.size() || value == 0) {
              fail("face corner '" + std::string(corner) + "' is not a valid vertex reference");
            }
          }
          if (slash == corner.size()) break;
          start = slash + 1;
        }
      }
    }
  }
}

Mesh loadObj(const fs::path& path) {
  checkObjNumbers(path);
  tinyobj::ObjReaderConfig config;
  config.triangulate = true;
  config.vertex_color = false;
  config.mtl_search_path = path.parent_path().string();
  tinyobj::ObjReader reader;
  if (!reader.ParseFromFile(path.string(), config)) {
    std::string why = reader.Error();
    while (!why.empty() && (why.back() == '\n' || why.back() == '\r')) why.pop_back();
    throw Error("mesh", "cannot parse OBJ: " + (why.empty() ? std::string("unknown reason") : why),
                path);
  }
  const tinyobj::attrib_t& attrib = reader.GetAttrib();
  const size_t vertexCount = attrib.vertices.size() / 3;
  const size_t normalCount = attrib.normals.size() / 3;

  bool allNormals = normalCount > 0;
  for (const auto& shape : reader.GetShapes()) {
    for (const auto& idx : shape.mesh.indices) {
      if (idx.normal_index < 0) allNormals = false;
    }
  }

  Mesh mesh;
  // (position, normal) pairs → output vertex.
  std::unordered_map<uint64_t, uint32_t> remap;
  for (const auto& shape : reader.GetShapes()) {
    const auto& m = shape.mesh;
    for (size_t f = 0; f < m.num_face_vertices.size(); ++f) {
      if (m.num_face_vertices[f] != 3)
        throw Error("mesh", "face is not a triangle after triangulation", path);
    }
    for (const auto& idx : m.indices) {
      if (idx.vertex_index < 0 || size_t(idx.vertex_index) >= vertexCount) {
        throw Error("mesh",
                    "face refers to vertex " + std::to_string(idx.vertex_index + 1) +
                        " but the file has " + std::to_string(vertexCount),
                    path);
      }
      const int ni = allNormals ? idx.normal_index : -1;
      if (allNormals && size_t(ni) >= normalCount) {
        throw Error("mesh",
                    "face refers to normal " + std::to_string(ni + 1) + " but the file has " +
                        std::to_string(normalCount),
                    path);
      }
      const uint64_t key = (uint64_t(uint32_t(idx.vertex_index)) << 32) | uint32_t(ni + 1);
      auto [it, inserted] = remap.try_emplace(key, uint32_t(mesh.positions.size()));
      if (inserted) {
        const float* p = &attrib.vertices[3 * size_t(idx.vertex_index)];
        mesh.positions.emplace_back(p[0], p[1], p[2]);
        if (allNormals) {
          const float* n = &attrib.normals[3 * size_t(ni)];
          mesh.normals.emplace_back(n[0], n[1], n[2]);
        }
      }
      mesh.indices.push_back(it->second);
    }
  }
  mesh.normalsFromFile = allNormals;
  return mesh;
}

// Drops triangles that cannot render: degenerate ones (zero area, or a repeated corner) and
// duplicates (the same three positions as an earlier triangle, in any order or winding), with a
// warning that counts them. Unused vertices are left in place (they cost nothing to render).
void dropUnrenderableTriangles(Mesh& mesh, const fs::path& path) {
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  const float size = std::max({extent.x, extent.y, extent.z});
  // Area below (1e-7 of the object's size)² is rounding noise in float coordinates.
  const float minDoubleArea = 1e-14f * size * size;
  // Positions by value, so that vertices split by normals still count as one position.
  std::unordered_map<uint64_t, uint32_t> positionIds;
  std::vector<uint32_t> positionId(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const glm::vec3& p = mesh.positions[i];
    uint32_t bits[3];
    std::memcpy(bits, &p, sizeof bits);
    const uint64_t key = (uint64_t(bits[0]) * 0x9E3779B97F4A7C15ull) ^
                         (uint64_t(bits[1]) * 0xC2B2AE3D27D4EB4Full) ^ uint64_t(bits[2]);
    // Hash collisions only merge keys; equality is checked below through the ids' positions.
    auto [it, inserted] = positionIds.try_emplace(key, uint32_t(i));
    positionId[i] = (inserted || mesh.positions[it->second] == p) ? it->second : uint32_t(i);
  }
  struct TripleHash {
    size_t operator()(const std::array<uint32_t, 3>& t) const {
      return (size_t(t[0]) * 73856093u) ^ (size_t(t[1]) * 19349663u) ^ (size_t(t[2]) * 83492791u);
    }
  };
  std::unordered_set<std::array<uint32_t, 3>, TripleHash> seen;
  std::vector<uint32_t> kept;
  kept.reserve(mesh.indices.size());
  size_t degenerate = 0, duplicate = 0;
  for (size_t t = 0; t < mesh.indices.size(); t += 3) {
    const uint32_t* v = &mesh.indices[t];
    std::array<uint32_t, 3> ids = {positionId[v[0]], positionId[v[1]], positionId[v[2]]};
    const glm::vec3 n = glm::cross(mesh.positions[v[1]] - mesh.positions[v[0]],
                                   mesh.positions[v[2]] - mesh.positions[v[0]]);
    if (ids[0] == ids[1] || ids[1] == ids[2] || ids[0] == ids[2] ||
        !(glm::length(n) > minDoubleArea)) {
      ++degenerate;
      continue;
    }
    std::sort(ids.begin(), ids.end());
    if (!seen.insert(ids).second) {
      ++duplicate;
      continue;
    }
    kept.insert(kept.end(), v, v + 3);
  }
  const size_t total = mesh.indices.size() / 3;
  if (kept.empty()) {
    throw Error("mesh",
                "nothing renderable: all " + std::to_string(total) + " triangles are degenerate" +
                    (duplicate ? " or duplicates" : ""),
                path);
  }
  if (degenerate) {
    mesh.warnings.push_back("dropped " + std::to_string(degenerate) + " of " +
                            std::to_string(total) + " triangles with no area");
  }
  if (duplicate) {
    mesh.warnings.push_back("dropped " + std::to_string(duplicate) + " of " +
                            std::to_string(total) + " triangles that repeat another one");
  }
  mesh.indices = std::move(kept);
}

void validate(Mesh& mesh, const fs::path& path) {
  if (mesh.indices.empty()) throw Error("mesh", "mesh has no triangles", path);
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const glm::vec3& p = mesh.positions[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      throw Error("mesh", "vertex " + std::to_string(i + 1) + " has a non-finite coordinate", path);
    }
  }
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  if (!(std::max({extent.x, extent.y, extent.z}) > 0.0f)) {
    throw Error("mesh", "mesh has zero size (all vertices coincide)", path);
  }
  dropUnrenderableTriangles(mesh, path);
  if (mesh.normalsFromFile) {
    for (size_t i = 0; i < mesh.normals.size(); ++i) {
      glm::vec3& n = mesh.normals[i];
      const float len = glm::length(n);
      if (!std::isfinite(len) || len == 0.0f) {
        throw Error("mesh", "normal of vertex " + std::to_string(i + 1) + " is zero or not finite",
                    path);
      }
      n /= len;
    }
  } else {
    const int flipped = orientConsistently(mesh);
    if (flipped > 0) {
      mesh.warnings.push_back("turned " + std::to_string(flipped) +
                              " triangles wound against their neighbours to face outwards");
    }
    computeVertexNormals(mesh);
  }
}

// Geomview's bicubic Bézier patches ("BBP": 16 control points of 3 numbers per patch, rows of
// four), such as the Newell teapot of its sample data. Each patch is tessellated into
// kSteps x kSteps quads; vertices on shared patch edges coincide exactly (a Bézier patch's edge
// depends on its edge control points only) and are welded. Geomview's models are Z-up: they are
// turned to this project's Y-up frame, (x, y, z) → (x, z, -y). Normals are computed afterwards.
Mesh loadBezierPatches(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw Error("mesh", withSystemReason("cannot open", errno), path);
  std::string header;
  if (!(in >> header) || header != "BBP") {
    throw Error(
        "mesh",
        "not a Geomview bicubic patch file: expected the keyword BBP, found '" + header + "'",
        path);
  }
  std::vector<glm::dvec3> control;
  std::string token;
  std::vector<double> numbers;
  while (in >> token) {
    char* end = nullptr;
    const double v = std::strtod(token.c_str(), &end);
    if (end != token.c_str() + token.size() || !std::isfinite(v)) {
      throw Error("mesh", "'" + token + "' is not a finite number", path);
    }
    numbers.push_back(v);
  }
  if (numbers.empty() || numbers.size() % 48 != 0) {
    throw Error("mesh",
                "a bicubic patch file holds 16 points of 3 numbers per patch; this one has " +
                    std::to_string(numbers.size()) + " numbers",
                path);
  }
  constexpr int kSteps = 16;
  auto bernstein = [](double t, double b[4]) {
    const double s = 1.0 - t;
    b[0] = s * s * s;
    b[1] = 3.0 * t * s * s;
    b[2] = 3.0 * t * t * s;
    b[3] = t * t * t;
  };
  Mesh mesh;
  std::map<std::array<float, 3>, uint32_t> weld;
  const size_t patches = numbers.size() / 48;
  for (size_t patch = 0; patch < patches; ++patch) {
    const double* c = numbers.data() + patch * 48;
    std::vector<uint32_t> ids;
    for (int i = 0; i <= kSteps; ++i) {
      double bu[4];
      bernstein(double(i) / kSteps, bu);
      for (int j = 0; j <= kSteps; ++j) {
        double bv[4];
        bernstein(double(j) / kSteps, bv);
        glm::dvec3 p(0.0);
        for (int a = 0; a < 4; ++a)
          for (int b = 0; b < 4; ++b) {
            const double* q = c + 3 * (4 * a + b);
            p += bu[a] * bv[b] * glm::dvec3(q[0], q[1], q[2]);
          }
        const std::array<float, 3> key = {float(p.x), float(p.z), float(-p.y)};
        auto [it, inserted] = weld.try_emplace(key, uint32_t(mesh.positions.size()));
        if (inserted) mesh.positions.emplace_back(key[0], key[1], key[2]);
        ids.push_back(it->second);
      }
    }
    for (int i = 0; i < kSteps; ++i) {
      for (int j = 0; j < kSteps; ++j) {
        const uint32_t a = ids[size_t(i * (kSteps + 1) + j)];
        const uint32_t b = ids[size_t(i * (kSteps + 1) + j + 1)];
        const uint32_t cc = ids[size_t((i + 1) * (kSteps + 1) + j)];
        const uint32_t d = ids[size_t((i + 1) * (kSteps + 1) + j + 1)];
        mesh.indices.insert(mesh.indices.end(), {a, cc, d, a, d, b});
      }
    }
  }
  mesh.normalsFromFile = false;
  return mesh;
}

}  // namespace

int orientConsistently(Mesh& mesh) {
  const size_t triangles = mesh.triangleCount();
  if (triangles == 0) return 0;
  // Corners by position, so that vertices split by normals or texture seams count as one.
  std::map<std::array<float, 3>, uint32_t> ids;
  std::vector<uint32_t> id(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const glm::vec3& p = mesh.positions[i];
    id[i] = ids.try_emplace({p.x, p.y, p.z}, uint32_t(ids.size())).first->second;
  }
  auto corner = [&](size_t t, int k) { return id[mesh.indices[3 * t + size_t(k)]]; };
  std::unordered_map<uint64_t, std::vector<uint32_t>> edges;  // undirected edge → triangles
  auto edgeKey = [](uint32_t a, uint32_t b) {
    return (uint64_t(std::min(a, b)) << 32) | std::max(a, b);
  };
  for (size_t t = 0; t < triangles; ++t)
    for (int k = 0; k < 3; ++k)
      edges[edgeKey(corner(t, k), corner(t, (k + 1) % 3))].push_back(uint32_t(t));
  // Whether triangle t, as currently wound, runs from a to b.
  auto runs = [&](size_t t, bool flip, uint32_t a, uint32_t b) {
    for (int k = 0; k < 3; ++k) {
      uint32_t u = corner(t, k), v = corner(t, (k + 1) % 3);
      if (flip) std::swap(u, v);
      if (u == a && v == b) return true;
    }
    return false;
  };
  std::vector<int8_t> state(triangles, -1);  // -1 unvisited, 0 keep, 1 flip
  int flippedTotal = 0;
  for (size_t seed = 0; seed < triangles; ++seed) {
    if (state[seed] >= 0) continue;
    // Walk the connected piece, winding each neighbour against the shared edge.
    std::vector<uint32_t> piece = {uint32_t(seed)}, queue = {uint32_t(seed)};
    state[seed] = 0;
    while (!queue.empty()) {
      const uint32_t t = queue.back();
      queue.pop_back();
      for (int k = 0; k < 3; ++k) {
        uint32_t a = corner(t, k), b = corner(t, (k + 1) % 3);
        if (state[t]) std::swap(a, b);  // t runs a → b
        for (uint32_t n : edges[edgeKey(a, b)]) {
          if (n == t || state[n] >= 0) continue;
          // A consistent neighbour runs b → a.
          state[n] = runs(n, false, a, b) ? 1 : 0;
          piece.push_back(n);
          queue.push_back(n);
        }
      }
    }
    // Outwards: the piece's signed volume about its own centre must be positive.
    glm::dvec3 centre(0.0);
    for (uint32_t t : piece)
      for (int k = 0; k < 3; ++k)
        centre += glm::dvec3(mesh.positions[mesh.indices[3 * t + size_t(k)]]);
    centre /= double(3 * piece.size());
    double volume = 0.0;
    for (uint32_t t : piece) {
      glm::dvec3 p[3];
      for (int k = 0; k < 3; ++k)
        p[k] = glm::dvec3(mesh.positions[mesh.indices[3 * t + size_t(k)]]) - centre;
      if (state[t]) std::swap(p[1], p[2]);
      volume += glm::dot(p[0], glm::cross(p[1], p[2]));
    }
    const bool invert = volume < 0.0;
    for (uint32_t t : piece) {
      const bool flip = (state[t] != 0) != invert;
      if (flip) {
        std::swap(mesh.indices[3 * size_t(t) + 1], mesh.indices[3 * size_t(t) + 2]);
        ++flippedTotal;
      }
    }
  }
  return flippedTotal;
}

Mesh loadMesh(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("mesh", "file not found", path);
  if (fs::is_directory(path, ec)) throw Error("mesh", "is a folder, expected a mesh file", path);
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  Mesh mesh;
  if (ext == ".obj") {
    mesh = loadObj(path);
  } else if (ext == ".bez") {
    mesh = loadBezierPatches(path);
  } else {
    throw Error("mesh", "unsupported mesh format '" + ext + "'; supported: .obj, .bez", path);
  }
  validate(mesh, path);
  return mesh;
}

}  // namespace compose::render
