// Meshes through the loader, normal generation included: OBJ (COMPOSE_FUZZ_MESH_EXT=".obj"),
// glTF 2.0 (".gltf" text, ".glb" binary) and Geomview bicubic patches (".bez"), one binary per
// format.
#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>

#include "core/limits.h"
#include "core/output_files.h"
#include "fuzz_util.h"
#include "render/mesh.h"

using namespace compose;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // Keep each input cheap: a fuzzed file of a few kilobytes may not ask for millions of triangles
  // (the limit itself is what is tested there).
  ResourceLimits limits;
  limits.maxTriangles = 200'000;
  setResourceLimits(limits);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  const auto file = fuzz::writeInput("input" COMPOSE_FUZZ_MESH_EXT, data, size);
  try {
    const render::Mesh mesh = render::loadMesh(file);
    FUZZ_CHECK(!mesh.indices.empty() && mesh.indices.size() % 3 == 0);
    FUZZ_CHECK(mesh.normals.size() == mesh.positions.size());
    FUZZ_CHECK(int64_t(mesh.triangleCount()) <= resourceLimits().maxTriangles);
    for (uint32_t i : mesh.indices) FUZZ_CHECK(i < mesh.positions.size());
    for (const glm::vec3& p : mesh.positions)
      FUZZ_CHECK(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
    for (const glm::vec3& n : mesh.normals) FUZZ_CHECK(std::abs(glm::length(n) - 1.0f) < 1e-3f);
    const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
    FUZZ_CHECK(std::max({extent.x, extent.y, extent.z}) > 0.0f);
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
  return 0;
}
