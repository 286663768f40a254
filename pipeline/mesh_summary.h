// What the pipeline needs to know of the object before deciding what to run: its key (its whole
// content, for every later stage's key), its bounds (the placement), its size and whether it is
// convex (the self-shadowing stage's skip). Reading a large OBJ and computing its normals and
// convexity takes longer than anything else a run with a warm cache does, so the mesh as read is
// kept in the stage cache under its file's content, with its summary: a later run with the same
// file takes both from there.
//
// Only a mesh that its file alone gives is kept this way: one that reads material libraries,
// textures or glTF buffers beside it (or has materials to convert, but for the white one that
// vertex colours alone bring) is always read.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "core/hash.h"
#include "render/mesh.h"

namespace compose::pipeline {

struct MeshSummary {
  Hash128 key;  // meshKey(): everything of the mesh later stages read
  glm::vec3 boundsMin{0.0f}, boundsMax{0.0f};  // Mesh::keptBounds: what cut-outs keep
  size_t triangles = 0;
  bool convex = false;
  bool nothingKept = false;        // its cut-outs take every surface away
  std::vector<std::string> notes;  // what reading the mesh said (normals, repairs), for the user
  bool fromCache = false;          // taken from the cache rather than read from the file
};

// Everything in a mesh the later stages read: geometry, normals, materials and textures.
Hash128 meshKey(const render::Mesh& mesh, double creaseDegrees);

// The summary of a mesh as read (computes the key and the convexity).
MeshSummary summarize(const render::Mesh& mesh, double creaseDegrees);

// The notes reading a mesh gives: how its normals were obtained, and its warnings.
std::vector<std::string> meshNotes(const render::Mesh& mesh);

// The mesh in `file` (read with `creaseDegrees`) and its summary, when a previous run kept them
// for this file content under `cacheRoot`; `contentKey` receives the file content's key (for
// storeMesh). An entry that is damaged or does not fit sets `problem` (it is then ignored and
// rewritten); a plain miss leaves it empty.
struct CachedMesh {
  render::Mesh mesh;
  MeshSummary summary;
};
std::optional<CachedMesh> cachedMesh(const std::filesystem::path& cacheRoot,
                                     const std::filesystem::path& file, double creaseDegrees,
                                     Hash128& contentKey, std::string& problem);

// Keeps the mesh (as read, with the back sides render::addBackSides gave it) and its summary for
// `contentKey` when the mesh came from its file alone; false
// (with the reason in `problem`) if the entry could not be written. Does nothing for any other
// mesh.
bool storeMesh(const std::filesystem::path& cacheRoot, const Hash128& contentKey,
               const render::Mesh& mesh, const MeshSummary& summary, std::string& problem);

}  // namespace compose::pipeline
