#include "render/renderer.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <numbers>
#include <string>

#include <embree3/rtcore.h>
#include <glm/geometric.hpp>
#include <glm/matrix.hpp>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::render {

namespace {

void embreeError(void*, RTCError code, const char* message) {
  // Reported through rtcGetDeviceError below; nothing to do here but keep Embree quiet.
  (void)code;
  (void)message;
}

// RAII holders for Embree handles.
struct Device {
  RTCDevice handle = rtcNewDevice(nullptr);
  ~Device() {
    if (handle) rtcReleaseDevice(handle);
  }
};
struct Scene {
  RTCScene handle = nullptr;
  ~Scene() {
    if (handle) rtcReleaseScene(handle);
  }
};

// Deterministic per-sample jitter in [0, 1): a 32-bit integer hash (lowbias32).
float hash01(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return float(x >> 8) * (1.0f / 16777216.0f);
}

}  // namespace

RenderOutput renderDiffuse(const Mesh& mesh, const glm::dmat4& worldFromObject,
                           const calib::PinholeCamera& camera,
                           const lighting::DiffuseLighting& lighting,
                           const RenderSettings& settings, const Progress& progress) {
  COMPOSE_CHECK(settings.samplesPerAxis >= 1);
  COMPOSE_CHECK(!mesh.indices.empty() && mesh.normals.size() == mesh.positions.size());

  // Object → world once, in double, then float for Embree.
  const glm::dmat3 normalFromObject = glm::transpose(glm::inverse(glm::dmat3(worldFromObject)));
  std::vector<glm::vec3> normals(mesh.normals.size());
  for (size_t i = 0; i < normals.size(); ++i) {
    normals[i] = glm::vec3(glm::normalize(normalFromObject * glm::dvec3(mesh.normals[i])));
  }

  Device device;
  if (!device.handle) throw Error("render", "cannot create the Embree device");
  rtcSetDeviceErrorFunction(device.handle, embreeError, nullptr);
  Scene scene;
  scene.handle = rtcNewScene(device.handle);
  rtcSetSceneBuildQuality(scene.handle, RTC_BUILD_QUALITY_HIGH);
  RTCGeometry geom = rtcNewGeometry(device.handle, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                               RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                                               mesh.positions.size()));
  auto* triangles = static_cast<uint32_t*>(
      rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                              3 * sizeof(uint32_t), mesh.triangleCount()));
  if (!vertices || !triangles) {
    rtcReleaseGeometry(geom);
    throw Error("render", "Embree could not allocate the mesh buffers");
  }
  glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const glm::dvec3 p =
        glm::dvec3(worldFromObject * glm::dvec4(glm::dvec3(mesh.positions[i]), 1.0));
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
    vertices[3 * i] = float(p.x);
    vertices[3 * i + 1] = float(p.y);
    vertices[3 * i + 2] = float(p.z);
  }
  std::copy(mesh.indices.begin(), mesh.indices.end(), triangles);
  rtcCommitGeometry(geom);
  rtcAttachGeometry(scene.handle, geom);
  rtcReleaseGeometry(geom);
  rtcCommitScene(scene.handle);
  if (rtcGetDeviceError(device.handle) != RTC_ERROR_NONE)
    throw Error("render", "Embree failed to build the scene");

  RenderOutput out;
  out.beauty = Image(camera.width, camera.height, 4, {"R", "G", "B", "A"});
  out.normals = Image(camera.width, camera.height, 3, {"N.X", "N.Y", "N.Z"});
  out.normals.colorSpace = "Raw";

  // Screen rectangle of the world bounding box; the whole frame if any corner is behind the camera.
  int x0 = 0, y0 = 0, x1 = camera.width, y1 = camera.height;
  {
    glm::dvec2 smin(std::numeric_limits<double>::max()), smax(-std::numeric_limits<double>::max());
    bool allInFront = true;
    for (int c = 0; c < 8; ++c) {
      const glm::dvec3 corner((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z);
      glm::dvec2 px;
      if (!camera.project(corner, px)) {
        allInFront = false;
        break;
      }
      smin = glm::min(smin, px);
      smax = glm::max(smax, px);
    }
    if (allInFront) {
      x0 = std::clamp(int(std::floor(smin.x)) - 1, 0, camera.width);
      y0 = std::clamp(int(std::floor(smin.y)) - 1, 0, camera.height);
      x1 = std::clamp(int(std::ceil(smax.x)) + 1, 0, camera.width);
      y1 = std::clamp(int(std::ceil(smax.y)) + 1, 0, camera.height);
    }
  }
  out.x0 = x0;
  out.y0 = y0;
  out.x1 = std::max(x0, x1);
  out.y1 = std::max(y0, y1);

  const int n = settings.samplesPerAxis;
  const float invSamples = 1.0f / float(n * n);
  const float invPi = float(1.0 / std::numbers::pi);
  const glm::vec3 reflect = settings.albedo * settings.exposure * invPi;
  std::atomic<int> rowsDone{0};
  const int rowCount = out.y1 - out.y0;

  parallelFor(out.y0, out.y1, [&](int64_t yy) {
    const int y = int(yy);
    RTCIntersectContext context;
    for (int x = out.x0; x < out.x1; ++x) {
      glm::vec3 colour(0.0f), normalSum(0.0f);
      int hits = 0;
      for (int s = 0; s < n * n; ++s) {
        const uint32_t seed =
            (uint32_t(y) * uint32_t(camera.width) + uint32_t(x)) * uint32_t(n * n) + uint32_t(s);
        const double px = x + (s % n + double(hash01(2 * seed))) / n;
        const double py = y + (s / n + double(hash01(2 * seed + 1))) / n;
        glm::dvec3 org, dir;
        camera.ray(px, py, org, dir);
        RTCRayHit rh{};
        rh.ray.org_x = float(org.x);
        rh.ray.org_y = float(org.y);
        rh.ray.org_z = float(org.z);
        rh.ray.dir_x = float(dir.x);
        rh.ray.dir_y = float(dir.y);
        rh.ray.dir_z = float(dir.z);
        rh.ray.tnear = 0.0f;
        rh.ray.tfar = std::numeric_limits<float>::infinity();
        rh.ray.mask = 0xFFFFFFFFu;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rtcInitIntersectContext(&context);
        rtcIntersect1(scene.handle, &context, &rh);
        if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) continue;
        const uint32_t* tri = &mesh.indices[3 * size_t(rh.hit.primID)];
        const float u = rh.hit.u, v = rh.hit.v;
        glm::vec3 nrm = glm::normalize((1.0f - u - v) * normals[tri[0]] + u * normals[tri[1]] +
                                       v * normals[tri[2]]);
        // Seen from behind (open meshes): shade the side the camera sees.
        const glm::vec3 ng(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z);
        if (glm::dot(ng, glm::vec3(dir)) > 0.0f) nrm = -nrm;
        const glm::vec3 view = -glm::vec3(dir);
        const glm::vec3 e =
            glm::max(lighting.irradiance(settings.envFromWorld * nrm, settings.envFromWorld * view),
                     glm::vec3(0.0f));
        colour += reflect * e;
        normalSum += nrm;
        ++hits;
      }
      if (hits == 0) continue;
      float* b = out.beauty.at(x, y);
      b[0] = colour.x * invSamples;
      b[1] = colour.y * invSamples;
      b[2] = colour.z * invSamples;
      b[3] = float(hits) * invSamples;
      const float len = glm::length(normalSum);
      if (len > 0.0f) {
        float* nn = out.normals.at(x, y);
        nn[0] = normalSum.x / len;
        nn[1] = normalSum.y / len;
        nn[2] = normalSum.z / len;
      }
    }
    const int done = ++rowsDone;
    if (done % 16 == 0) report(progress, "render", double(done) / std::max(rowCount, 1));
  });
  out.rays = int64_t(rowCount) * (out.x1 - out.x0) * n * n;
  report(progress, "render", 1.0);
  return out;
}

}  // namespace compose::render
