#include "render/embree_scene.h"

#include <embree3/rtcore.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "core/error.h"
#include "core/hash.h"
#include "render/mesh.h"

namespace compose::render {

struct EmbreeScene::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  bool filtered = false;  // cutoutFilter decides the hits
  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

namespace {

uint32_t mix(uint32_t h, uint32_t x) {
  h ^= x + 0x9e3779b9u + (h << 6) + (h >> 2);
  return h;
}

uint32_t bitsOf(float f) {
  uint32_t u;
  std::memcpy(&u, &f, sizeof u);
  return u;
}

// The ray id of the camera's rays, which go on through semi-transparent surfaces themselves.
constexpr uint32_t kLayered = 0x4c415952u;
// Rays whose transmittance is wanted: the tag in the id's top byte, the ray's index into
// TransmitContext::transmitted below it.
constexpr uint32_t kTransmitTag = 0x54u;
constexpr float kLeastTransmitted = 1e-4f;
struct TransmitContext {
  RTCIntersectContext base;  // first: Embree hands the filter a pointer to it
  float* transmitted;
  // Per ray, the distances of the first kCounted layers counted: where a ray crosses an edge two
  // triangles share, Embree reports both, and the layer is counted once.
  float* counted;
};
constexpr int kCounted = 4;

// Rejects hits where the mesh is cut away, where a semi-transparent surface lets this ray
// through, or where a triangle with a back side of its own (Mesh::oneSided) turns its back to it
// (the geometry's user data is the Mesh). A ray's random number
// for a semi-transparent triangle is hashed from the ray's origin, direction and the triangle
// (independent between rays and between the layers one ray meets); a kLayered ray meets it
// wherever its alpha is above 0.
void cutoutFilter(const RTCFilterFunctionNArguments* args) {
  const auto* mesh = static_cast<const Mesh*>(args->geometryUserPtr);
  const unsigned n = args->N;
  for (unsigned i = 0; i < n; ++i) {
    if (args->valid[i] != -1) continue;
    const unsigned triangle = RTCHitN_primID(args->hit, n, i);
    if (mesh->oneSided(triangle) &&
        RTCHitN_Ng_x(args->hit, n, i) * RTCRayN_dir_x(args->ray, n, i) +
                RTCHitN_Ng_y(args->hit, n, i) * RTCRayN_dir_y(args->ray, n, i) +
                RTCHitN_Ng_z(args->hit, n, i) * RTCRayN_dir_z(args->ray, n, i) >
            0.0f) {
      args->valid[i] = 0;  // its back: the triangle of the other side is met instead
      continue;
    }
    const uint32_t id = RTCRayN_id(args->ray, n, i);
    if ((id >> 24) == kTransmitTag) {
      // Through semi-transparent surfaces the ray's transmittance falls by each one's 1 - alpha
      // and the ray goes on, until almost nothing is left; anything else opaque stops it.
      const auto* context = reinterpret_cast<const TransmitContext*>(args->context);
      const uint32_t ray = id & 0xffffffu;
      float& left = context->transmitted[ray];
      const float u = RTCHitN_u(args->hit, n, i), v = RTCHitN_v(args->hit, n, i);
      if (mesh->cutAway(triangle, u, v)) {
        args->valid[i] = 0;
      } else if (mesh->semiTransparent(triangle)) {
        args->valid[i] = 0;
        // The hit's distance (Embree puts it in tfar while the filter decides).
        const float t = RTCRayN_tfar(args->ray, n, i);
        float* seen = context->counted + size_t(ray) * kCounted;
        bool again = false;
        for (int k = 0; k < kCounted && !again; ++k) again = std::abs(seen[k] - t) <= 1e-5f * t;
        if (again) continue;
        for (int k = 0; k < kCounted; ++k)
          if (seen[k] < 0.0f) {
            seen[k] = t;
            break;
          }
        left *= 1.0f - std::clamp(mesh->alphaAt(triangle, u, v), 0.0f, 1.0f);
        if (!(left > kLeastTransmitted)) args->valid[i] = -1;
      }
      continue;
    }
    // An opaque mesh is here for its one-sided triangles alone: nothing else to decide, and no
    // ray's random number to hash.
    if (!mesh->hasCutouts()) continue;
    float xi;
    if (id == kLayered) {
      xi = 0.0f;  // met wherever it is there at all
    } else {
      uint32_t h = mix(triangle, bitsOf(RTCRayN_org_x(args->ray, n, i)));
      h = mix(h, bitsOf(RTCRayN_org_y(args->ray, n, i)));
      h = mix(h, bitsOf(RTCRayN_org_z(args->ray, n, i)));
      h = mix(h, bitsOf(RTCRayN_dir_x(args->ray, n, i)));
      h = mix(h, bitsOf(RTCRayN_dir_y(args->ray, n, i)));
      h = mix(h, bitsOf(RTCRayN_dir_z(args->ray, n, i)));
      xi = hash01(h);
    }
    if (mesh->passes(triangle, RTCHitN_u(args->hit, n, i), RTCHitN_v(args->hit, n, i), xi))
      args->valid[i] = 0;
  }
}

// Rays from `o` along each of d[0..count), for a stream query; ids 0, or tagged with the
// transmittance tag and their index.
void streamRays(const glm::vec3& o, const glm::vec3* d, size_t count, float tnear, float tfar,
                bool transmit, std::vector<RTCRay>& rays) {
  rays.resize(count);
  for (size_t i = 0; i < count; ++i) {
    RTCRay& ray = rays[i];
    ray.org_x = o.x;
    ray.org_y = o.y;
    ray.org_z = o.z;
    ray.tnear = tnear;
    ray.dir_x = d[i].x;
    ray.dir_y = d[i].y;
    ray.dir_z = d[i].z;
    ray.time = 0.0f;
    ray.tfar = tfar;
    ray.mask = 0xFFFFFFFFu;
    ray.id = transmit ? (kTransmitTag << 24) | uint32_t(i) : 0u;
    ray.flags = 0;
  }
}

// A packet of up to 16 rays from `o`, those whose bit is set in `active` valid. Only the active
// directions are read: a batch of fewer than 16 ends before the inactive ones (reading them
// overflowed the caller's array, found by AddressSanitizer).
void packetRays(const glm::vec3& o, const glm::vec3* d, uint32_t active, float tnear, float tfar,
                bool transmit, int* valid, RTCRay16& rays) {
  for (int i = 0; i < 16; ++i) {
    valid[i] = (active >> i) & 1u ? -1 : 0;
    const glm::vec3 dir = valid[i] ? d[i] : glm::vec3(0.0f, 1.0f, 0.0f);
    rays.org_x[i] = o.x;
    rays.org_y[i] = o.y;
    rays.org_z[i] = o.z;
    rays.dir_x[i] = dir.x;
    rays.dir_y[i] = dir.y;
    rays.dir_z[i] = dir.z;
    rays.tnear[i] = tnear;
    rays.tfar[i] = tfar;
    rays.mask[i] = 0xFFFFFFFFu;
    rays.id[i] = transmit ? (kTransmitTag << 24) | uint32_t(i) : 0u;
  }
}

}  // namespace

EmbreeScene::EmbreeScene(const Mesh& mesh) : EmbreeScene(mesh.positions, mesh.indices, &mesh) {}

EmbreeScene::EmbreeScene(const std::vector<glm::vec3>& positions,
                         const std::vector<uint32_t>& indices)
    : EmbreeScene(positions, indices, nullptr) {}

EmbreeScene::EmbreeScene(const std::vector<glm::vec3>& positions,
                         const std::vector<uint32_t>& indices, const Mesh* cutouts)
    : impl_(std::make_unique<Impl>()) {
  COMPOSE_CHECK(!indices.empty() && indices.size() % 3 == 0);
  impl_->device = rtcNewDevice(nullptr);
  if (!impl_->device) throw Error("render", "cannot create the Embree device");
  impl_->scene = rtcNewScene(impl_->device);
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_MEDIUM);
  RTCGeometry geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(
      geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), positions.size()));
  auto* triangles = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(
      geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), indices.size() / 3));
  if (!vertices || !triangles) {
    rtcReleaseGeometry(geom);
    throw Error("render", "Embree could not allocate the mesh buffers");
  }
  for (size_t i = 0; i < positions.size(); ++i) {
    vertices[3 * i] = positions[i].x;
    vertices[3 * i + 1] = positions[i].y;
    vertices[3 * i + 2] = positions[i].z;
  }
  std::copy(indices.begin(), indices.end(), triangles);
  COMPOSE_CHECK(!cutouts || cutouts->sides.empty() ||
                cutouts->sides.size() == cutouts->triangleCount());
  if (cutouts && (cutouts->hasCutouts() || !cutouts->sides.empty())) {
    rtcSetGeometryUserData(geom, const_cast<Mesh*>(cutouts));
    rtcSetGeometryIntersectFilterFunction(geom, &cutoutFilter);
    rtcSetGeometryOccludedFilterFunction(geom, &cutoutFilter);
    impl_->filtered = true;
  }
  rtcCommitGeometry(geom);
  rtcAttachGeometry(impl_->scene, geom);
  rtcReleaseGeometry(geom);
  rtcCommitScene(impl_->scene);
  if (rtcGetDeviceError(impl_->device) != RTC_ERROR_NONE)
    throw Error("render", "Embree failed to build the scene");
}

EmbreeScene::~EmbreeScene() = default;

EmbreeScene::Hit EmbreeScene::intersect(const glm::vec3& o, const glm::vec3& d, float tnear,
                                        float tfar, bool layered) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh{};
  rh.ray.org_x = o.x;
  rh.ray.org_y = o.y;
  rh.ray.org_z = o.z;
  rh.ray.dir_x = d.x;
  rh.ray.dir_y = d.y;
  rh.ray.dir_z = d.z;
  rh.ray.tnear = tnear;
  rh.ray.tfar = tfar;
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.id = layered ? kLayered : 0u;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->scene, &context, &rh);
  Hit hit;
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return hit;
  hit.found = true;
  hit.triangle = rh.hit.primID;
  hit.u = rh.hit.u;
  hit.v = rh.hit.v;
  hit.distance = rh.ray.tfar;
  hit.geometricNormal = glm::vec3(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
  return hit;
}

void EmbreeScene::intersect16(const glm::vec3* origins, const glm::vec3* directions,
                              uint32_t active, Hit* hits, float tnear, float tfar,
                              bool layered) const {
  float tnears[16];
  std::fill(tnears, tnears + 16, tnear);
  intersect16(origins, directions, active, hits, tnears, tfar, layered);
}

void EmbreeScene::intersect16(const glm::vec3* origins, const glm::vec3* directions,
                              uint32_t active, Hit* hits, const float* tnears, float tfar,
                              bool layered) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  alignas(64) int valid[16];
  alignas(64) RTCRayHit16 rh{};
  for (int i = 0; i < 16; ++i) {
    valid[i] = (active >> i) & 1u ? -1 : 0;
    // Only the active rays are read (the caller's arrays may be shorter).
    const glm::vec3 o = valid[i] ? origins[i] : glm::vec3(0.0f);
    const glm::vec3 d = valid[i] ? directions[i] : glm::vec3(0.0f, 1.0f, 0.0f);
    rh.ray.org_x[i] = o.x;
    rh.ray.org_y[i] = o.y;
    rh.ray.org_z[i] = o.z;
    rh.ray.dir_x[i] = d.x;
    rh.ray.dir_y[i] = d.y;
    rh.ray.dir_z[i] = d.z;
    rh.ray.tnear[i] = valid[i] ? tnears[i] : 0.0f;
    rh.ray.tfar[i] = tfar;
    rh.ray.mask[i] = 0xFFFFFFFFu;
    rh.ray.id[i] = layered ? kLayered : 0u;
    rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
  }
  rtcIntersect16(valid, impl_->scene, &context, &rh);
  for (int i = 0; i < 16; ++i) {
    Hit& hit = hits[i];
    hit = Hit{};
    if (!valid[i] || rh.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
    hit.found = true;
    hit.triangle = rh.hit.primID[i];
    hit.u = rh.hit.u[i];
    hit.v = rh.hit.v[i];
    hit.distance = rh.ray.tfar[i];
    hit.geometricNormal = glm::vec3(rh.hit.Ng_x[i], rh.hit.Ng_y[i], rh.hit.Ng_z[i]);
  }
}

bool EmbreeScene::occluded(const glm::vec3& o, const glm::vec3& d, float tnear, float tfar) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRay ray{};
  ray.org_x = o.x;
  ray.org_y = o.y;
  ray.org_z = o.z;
  ray.dir_x = d.x;
  ray.dir_y = d.y;
  ray.dir_z = d.z;
  ray.tnear = tnear;
  ray.tfar = tfar;
  ray.mask = 0xFFFFFFFFu;
  rtcOccluded1(impl_->scene, &context, &ray);
  return ray.tfar < 0.0f;  // Embree sets tfar to -inf on a hit
}

uint32_t EmbreeScene::occluded16(const glm::vec3& o, const glm::vec3* d, uint32_t active,
                                 float tnear, float tfar) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  alignas(64) int valid[16];
  alignas(64) RTCRay16 rays{};
  packetRays(o, d, active, tnear, tfar, false, valid, rays);
  rtcOccluded16(valid, impl_->scene, &context, &rays);
  uint32_t hits = 0;
  for (int i = 0; i < 16; ++i)
    if (valid[i] && rays.tfar[i] < 0.0f) hits |= 1u << i;
  return hits;
}

void EmbreeScene::occludedStream(const glm::vec3& o, const glm::vec3* d, size_t count, float tnear,
                                 uint8_t* occluded, float tfar) const {
  if (count == 0) return;
  thread_local std::vector<RTCRay> rays;  // per thread, so that no call allocates once warm
  streamRays(o, d, count, tnear, tfar, false, rays);
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  rtcOccluded1M(impl_->scene, &context, rays.data(), unsigned(count), sizeof(RTCRay));
  for (size_t i = 0; i < count; ++i) occluded[i] = rays[i].tfar < 0.0f ? 1 : 0;
}

void EmbreeScene::transmittanceStream(const glm::vec3& o, const glm::vec3* d, size_t count,
                                      float tnear, float* transmitted, float tfar,
                                      bool coherent) const {
  if (count == 0) return;
  COMPOSE_CHECK(count <= 0xffffffu);
  thread_local std::vector<RTCRay> rays;
  thread_local std::vector<float> counted;
  streamRays(o, d, count, tnear, tfar, true, rays);
  std::fill(transmitted, transmitted + count, 1.0f);
  TransmitContext context;
  rtcInitIntersectContext(&context.base);
  if (coherent) context.base.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  context.transmitted = transmitted;
  context.counted = nullptr;
  if (impl_->filtered) {  // only the filter counts layers
    counted.assign(count * kCounted, -1.0f);
    context.counted = counted.data();
  }
  rtcOccluded1M(impl_->scene, &context.base, rays.data(), unsigned(count), sizeof(RTCRay));
  for (size_t i = 0; i < count; ++i)
    if (rays[i].tfar < 0.0f) transmitted[i] = 0.0f;
}

void EmbreeScene::transmittance16(const glm::vec3& o, const glm::vec3* d, uint32_t active,
                                  float tnear, float* transmitted, float tfar) const {
  alignas(64) int valid[16];
  alignas(64) RTCRay16 rays{};
  packetRays(o, d, active, tnear, tfar, true, valid, rays);
  float left[16], counted[16 * kCounted];
  std::fill(left, left + 16, 1.0f);
  std::fill(counted, counted + 16 * kCounted, -1.0f);
  TransmitContext context;
  rtcInitIntersectContext(&context.base);
  context.transmitted = left;
  context.counted = counted;
  rtcOccluded16(valid, impl_->scene, &context.base, &rays);
  for (int i = 0; i < 16; ++i)
    if (valid[i]) transmitted[i] = rays.tfar[i] < 0.0f ? 0.0f : left[i];
}

}  // namespace compose::render
