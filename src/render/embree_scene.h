// A triangle mesh in an Embree scene: the one place the renderer and the visibility precompute
// talk to Embree. RAII over the device and the scene; queries are const and thread-safe.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include <glm/vec3.hpp>

namespace compose::render {

struct Mesh;

class EmbreeScene {
 public:
  // Builds a scene of the triangles `indices` (three per triangle) over `positions`. Throws
  // compose::Error (stage "render") if Embree cannot build it.
  EmbreeScene(const std::vector<glm::vec3>& positions, const std::vector<uint32_t>& indices);
  // The mesh's triangles; where its materials cut it out (Mesh::cutAway) every ray passes
  // through, where they are semi-transparent a ray passes with a probability of 1 - alpha
  // (Mesh::passes; Embree's filter functions) unless it is `layered` (below); a triangle with a
  // back side of its own is met from its front only (Mesh::oneSided). `mesh` must outlive the
  // scene.
  explicit EmbreeScene(const Mesh& mesh);
  EmbreeScene(const Mesh&& mesh) = delete;  // the scene keeps a pointer to it
  ~EmbreeScene();
  EmbreeScene(const EmbreeScene&) = delete;
  EmbreeScene& operator=(const EmbreeScene&) = delete;

  struct Hit {
    bool found = false;
    uint32_t triangle = 0;
    float u = 0.0f, v = 0.0f;  // barycentrics of corners 1 and 2
    float distance = 0.0f;
    glm::vec3 geometricNormal{0.0f};  // unnormalised, (p1 - p0) x (p2 - p0)
  };

  // Closest hit along origin + t·direction, t in [tnear, tfar].
  Hit intersect(const glm::vec3& origin, const glm::vec3& direction, float tnear = 0.0f,
                float tfar = 1e30f, bool layered = false) const;
  // Closest hits of up to 16 rays at once, those whose bit is set in `active` (only their
  // origins and directions are read; the others' hits are not found). For rays that stay close
  // together, such as the samples of one pixel: Embree traces them as one coherent packet.
  // `layered`: the rays are the camera's, which go on through semi-transparent surfaces
  // themselves (Mesh::alphaAt): such a surface is met wherever its alpha is above 0, by these
  // and by intersect()'s. Other rays find it with a probability of its alpha.
  void intersect16(const glm::vec3* origins, const glm::vec3* directions, uint32_t active,
                   Hit* hits, float tnear = 0.0f, float tfar = 1e30f, bool layered = false) const;
  // The same with each ray's own tnear.
  void intersect16(const glm::vec3* origins, const glm::vec3* directions, uint32_t active,
                   Hit* hits, const float* tnears, float tfar, bool layered) const;
  // Whether anything lies along origin + t·direction, t in [tnear, tfar].
  bool occluded(const glm::vec3& origin, const glm::vec3& direction, float tnear = 0.0f,
                float tfar = 1e30f) const;
  // Whether anything lies along each of up to 16 rays from one origin; `active` masks the rays
  // to trace (only their directions are read: `directions` may hold fewer than 16); returns a bit
  // mask of the occluded ones.
  uint32_t occluded16(const glm::vec3& origin, const glm::vec3* directions, uint32_t active,
                      float tnear, float tfar = 1e30f) const;
  // Whether anything lies along each of `count` rays from one origin, traced as one stream:
  // sets occluded[i] to 1 or 0. For many rays in scattered directions (a point's hemisphere),
  // which Embree sorts into coherent groups itself, faster than fixed packets of 16.
  void occludedStream(const glm::vec3& origin, const glm::vec3* directions, size_t count,
                      float tnear, uint8_t* occluded, float tfar = 1e30f) const;
  // What each of `count` rays from one origin carries through the mesh (1: nothing in the way;
  // 0: something opaque; the product of 1 - alpha over the semi-transparent surfaces met
  // otherwise), into transmitted[i]. For a mesh without semi-transparent surfaces, 1 or 0 as
  // occludedStream says. `coherent`: the directions lie close together, in the order given (a
  // point's rays to the bright sources, sorted across the sky): Embree's traversal for coherent
  // rays, a quarter faster there and slower for a whole hemisphere of directions.
  void transmittanceStream(const glm::vec3& origin, const glm::vec3* directions, size_t count,
                           float tnear, float* transmitted, float tfar = 1e30f,
                           bool coherent = false) const;
  // The same for up to 16 rays, those whose bit is set in `active` (only their directions are
  // read and their transmitted[] written).
  void transmittance16(const glm::vec3& origin, const glm::vec3* directions, uint32_t active,
                       float tnear, float* transmitted, float tfar = 1e30f) const;

 private:
  EmbreeScene(const std::vector<glm::vec3>& positions, const std::vector<uint32_t>& indices,
              const Mesh* cutouts);
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace compose::render
