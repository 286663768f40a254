#include "render/mesh.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#include <tiny_obj_loader.h>
#include <glm/geometric.hpp>

#include "core/error.h"

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

Mesh loadObj(const fs::path& path) {
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
    computeVertexNormals(mesh);
  }
}

}  // namespace

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
  } else {
    throw Error("mesh", "unsupported mesh format '" + ext + "'; supported: .obj", path);
  }
  validate(mesh, path);
  return mesh;
}

}  // namespace compose::render
