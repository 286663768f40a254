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

#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "core/image.h"

namespace compose::render {

// An albedo texture: RGB (or RGBA, alpha unused) float in `image.colorSpace`, sampled bilinearly
// with wrap-around at texture coordinates (u to the right, v up: v = 0 is the image's bottom row,
// as in OBJ; a glTF loader flips its v into this convention).
struct Texture {
  std::filesystem::path file;
  Image image;
};

// A diffuse material: the albedo is baseColor times the texture's colour (when there is one).
// baseColor is linear, in the colour space named by Mesh::colorSpace.
struct Material {
  std::string name;
  glm::vec3 baseColor{1.0f};
  int texture = -1;  // index into Mesh::textures, or -1
};

struct Mesh {
  std::vector<glm::vec3> positions;   // object space
  std::vector<glm::vec3> normals;     // unit, one per position
  std::vector<uint32_t> indices;      // three per triangle, counter-clockwise seen from outside
  bool normalsFromFile = false;       // false: computed by computeVertexNormals()
  std::vector<std::string> warnings;  // what loading dropped or repaired, for the user

  // Materials: empty when the file has none (the renderer then uses --albedo everywhere).
  std::vector<glm::vec2> texcoords;        // one per position, or empty
  std::vector<uint32_t> triangleMaterial;  // one per triangle, or empty (all material 0)
  std::vector<Material> materials;
  std::vector<Texture> textures;
  // The colour space of the base colours (linear); textures carry their own. The pipeline
  // converts both to the working space before rendering.
  std::string colorSpace = "lin_rec709";

  size_t triangleCount() const { return indices.size() / 3; }
  glm::vec3 boundsMin() const;
  glm::vec3 boundsMax() const;
  bool hasMaterials() const { return !materials.empty(); }
  // The albedo at barycentrics (u, v) of `triangle` (Embree's: u for corner 1, v for corner 2):
  // its material's base colour times its texture at the interpolated texture coordinates. Only
  // meaningful when hasMaterials().
  glm::vec3 albedoAt(uint32_t triangle, float u, float v) const;
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
