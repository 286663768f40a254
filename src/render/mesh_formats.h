// Internal to the mesh loaders (mesh.cpp, mesh_obj.cpp, mesh_gltf.cpp): what a format reader
// hands to the shared validation and normal computation of loadMesh().
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "render/mesh.h"

namespace compose::render::detail {

// A mesh as a format reader produced it, before validation.
struct LoadedMesh {
  // positions, indices, and where the file has them normals (one per position, unused where
  // hasNormal is 0), texcoords (one per position or empty), triangleMaterial, materials, textures
  // and warnings.
  Mesh mesh;
  std::vector<uint8_t> hasNormal;  // per position: normals[i] came from the file
  // Per triangle, or empty: OBJ smoothing groups (0 = flat, 's off'). Computed normals are not
  // smoothed across an edge between two groups.
  std::vector<uint32_t> smoothingGroup;
};

LoadedMesh loadObj(const std::filesystem::path& path);
LoadedMesh loadGltf(const std::filesystem::path& path);

// "1 triangle", "3 triangles".
std::string count(size_t n, const std::string& singular, const std::string& plural);

// Reads an image file as an albedo texture (textureImage()); throws compose::Error (stage "mesh")
// when it cannot: missing, not a regular file (a device would never end), undecodable.
Image readTextureFile(const std::filesystem::path& file, const std::string& fallbackSpace,
                      Image* alpha = nullptr);

// An albedo texture from a decoded image: RGB (grey replicated), tagged with the colour space the
// image declared, or `fallbackSpace` when it declared none. The alpha channel goes to `alpha`
// (one channel) when asked and the image has one that is not 1 everywhere, else it is emptied.
Image textureImage(Image decoded, const std::string& fallbackSpace, Image* alpha = nullptr);

}  // namespace compose::render::detail
