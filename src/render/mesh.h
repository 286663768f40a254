// Triangle meshes for rendering: loading, validation, normals.
//
// loadMesh() reads Wavefront OBJ (through tinyobjloader; polygons are triangulated). Vertices are
// split where a position is used with different normals. A mesh without normals, or with
// normals missing on some faces, gets smooth angle-weighted vertex normals; normals of zero length
// or NaN in the file are an error. Every number in the file must be a finite number (a malformed
// one is an error naming its line). Degenerate and duplicate triangles are dropped with a warning
// (Mesh::warnings); a mesh with nothing renderable left is an error. Errors throw compose::Error
// (stage "mesh") naming the file.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

namespace compose::render {

struct Mesh {
  std::vector<glm::vec3> positions;   // object space
  std::vector<glm::vec3> normals;     // unit, one per position
  std::vector<uint32_t> indices;      // three per triangle, counter-clockwise seen from outside
  bool normalsFromFile = false;       // false: computed by computeVertexNormals()
  std::vector<std::string> warnings;  // what loading dropped or repaired, for the user

  size_t triangleCount() const { return indices.size() / 3; }
  glm::vec3 boundsMin() const;
  glm::vec3 boundsMax() const;
};

Mesh loadMesh(const std::filesystem::path& path);

// Smooth vertex normals: the angle-weighted mean of the adjacent face normals.
void computeVertexNormals(Mesh& mesh);

// Winds every connected piece of the mesh one way (each triangle against its neighbours across
// shared edges), then outwards (a positive signed volume about the piece's centre). Used for
// meshes whose normals are computed, where a triangle wound the wrong way would turn its corner
// normals inside out. Returns how many triangles were turned.
int orientConsistently(Mesh& mesh);

}  // namespace compose::render
