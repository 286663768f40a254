#include "render/transfer.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <map>
#include <numbers>
#include <unordered_map>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/hash.h"
#include "core/parallel.h"
#include "lighting/chebyshev.h"
#include "lighting/sh.h"
#include "lighting/tchebichef.h"
#include "render/embree_scene.h"

namespace compose::render {

namespace {

constexpr double kPi = std::numbers::pi;

// Deterministic jitter in [0, 1) from a 32-bit integer hash (lowbias32).
double hash01(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return double(x >> 8) * (1.0 / 16777216.0);
}

// The tangent frame of a normal (transfer.h): east along increasing longitude.
void tangentFrame(const glm::dvec3& n, glm::dvec3& east, glm::dvec3& north) {
  const double h = std::sqrt(n.x * n.x + n.z * n.z);
  east = h > 1e-6 ? glm::dvec3(n.z / h, 0.0, -n.x / h) : glm::dvec3(1.0, 0.0, 0.0);
  north = glm::cross(n, east);
}

double longitudeOf(const glm::dvec3& n) {
  return std::sqrt(n.x * n.x + n.z * n.z) > 1e-6 ? std::atan2(n.x, n.z) : 0.0;
}

}  // namespace

void TransferParams::validate() const {
  auto fail = [](const std::string& what) { throw UsageError(what, "shadows"); };
  if (grid < 2 || grid > 64) fail("grid (s) must be in 2..64, got " + std::to_string(grid));
  if (order < 1 || order > grid)
    fail("order (k) must be in 1..grid (" + std::to_string(grid) + "), got " +
         std::to_string(order));
  if (boundaryRays < 1 || boundaryRays > 16)
    fail("boundary rays must be in 1..16, got " + std::to_string(boundaryRays));
  if (shBands < 0 || shBands > lighting::kMaxShOrder)
    fail("SH bands must be in 0..8, got " + std::to_string(shBands));
}

std::string TransferParams::key() const {
  return "grid=" + std::to_string(grid) + " order=" + std::to_string(order) +
         " boundary=" + std::to_string(boundaryRays) + " sh=" + std::to_string(shBands) +
         " seed=" + std::to_string(seed) + " lift=1e-4 frame=longitude";
}

std::vector<float> VertexTransfer::exportState() const {
  std::vector<float> out;
  out.reserve(floatsStored());
  out.insert(out.end(), cheb.begin(), cheb.end());
  out.insert(out.end(), sh.begin(), sh.end());
  out.insert(out.end(), ao.begin(), ao.end());
  return out;
}

bool VertexTransfer::importState(const TransferParams& p, size_t vertices,
                                 const std::vector<float>& in) {
  const size_t kk = size_t(p.order) * size_t(p.order);
  const size_t nsh = size_t(lighting::shCount(p.shBands));
  if (in.size() != vertices * (kk + nsh + 1)) return false;
  params = p;
  vertexCount = vertices;
  cheb.assign(in.begin(), in.begin() + ptrdiff_t(vertices * kk));
  sh.assign(in.begin() + ptrdiff_t(vertices * kk), in.begin() + ptrdiff_t(vertices * (kk + nsh)));
  ao.assign(in.begin() + ptrdiff_t(vertices * (kk + nsh)), in.end());
  return true;
}

VertexTransfer computeTransfer(const Mesh& mesh, const TransferParams& params,
                               const Progress& progress) {
  params.validate();
  COMPOSE_CHECK(mesh.normals.size() == mesh.positions.size());
  const int s = params.grid, k = params.order, r = params.boundaryRays;
  const size_t kk = size_t(k) * size_t(k);
  const int nsh = lighting::shCount(params.shBands);
  const size_t count = mesh.positions.size();

  VertexTransfer out;
  out.params = params;
  out.vertexCount = count;
  out.cheb.assign(count * kk, 0.0f);
  out.sh.assign(count * size_t(nsh), 0.0f);
  out.ao.assign(count, 0.0f);

  const EmbreeScene scene(mesh.positions, mesh.indices);
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  const float size = std::max({extent.x, extent.y, extent.z});
  // Rays leave a point lifted off the surface by 1e-4 of the object's size, and ignore hits
  // closer than that: enough for float positions, far below any feature that casts a shadow.
  const float lift = 1e-4f * size, tnear = 1e-5f * size;

  const lighting::TchebichefBasis basis(s, k);
  // Cell boundaries: altitude θ_i = iπ/(2s) (as the cheb-local grid), azimuth φ_j = 2πj/s.
  std::vector<double> cosBound(size_t(s) + 1);
  for (int i = 0; i <= s; ++i) cosBound[size_t(i)] = std::cos(i * 0.5 * kPi / s);
  std::atomic<size_t> done{0};
  std::atomic<int64_t> rays{0};
  const size_t cells = size_t(s) * size_t(s);

  parallelFor(
      0, int64_t(count),
      [&](int64_t vi) {
        const size_t v = size_t(vi);
        const glm::dvec3 n = glm::normalize(glm::dvec3(mesh.normals[v]));
        glm::dvec3 east, north;
        tangentFrame(n, east, north);
        const glm::vec3 origin = mesh.positions[v] + lift * glm::vec3(n);
        std::vector<double> visible(cells, 0.0);
        std::vector<double> y(static_cast<size_t>(nsh));
        std::vector<double> shSum(static_cast<size_t>(nsh), 0.0);
        double aoSum = 0.0;
        int64_t traced = 0;
        uint32_t sample = (uint32_t(v) * 0x9E3779B1u) ^ (params.seed * 0x85EBCA77u);

        // A direction in cell (i, j) at fractional position (u, w), uniform in solid angle.
        auto direction = [&](int i, int j, double u, double w) {
          const double cosT =
              cosBound[size_t(i)] - u * (cosBound[size_t(i)] - cosBound[size_t(i) + 1]);
          const double sinT = std::sqrt(std::max(0.0, 1.0 - cosT * cosT));
          const double phi = 2.0 * kPi * (j + w) / s;
          return sinT * std::cos(phi) * east + sinT * std::sin(phi) * north + cosT * n;
        };
        // Traces `dirs` (grouped by 8) and adds each visible ray's share to the integrals.
        struct Ray {
          glm::dvec3 d;
          int cell;
          double weight;  // the solid angle it stands for
        };
        std::vector<Ray> batch;
        auto trace = [&](std::vector<Ray>& list, std::vector<char>* hitOut) {
          glm::vec3 dirs[8];
          for (size_t first = 0; first < list.size(); first += 8) {
            const int m = int(std::min<size_t>(8, list.size() - first));
            for (int b = 0; b < m; ++b) dirs[b] = glm::vec3(list[first + size_t(b)].d);
            const uint32_t hit = scene.occluded8(origin, dirs, (1u << m) - 1u, tnear);
            for (int b = 0; b < m; ++b) {
              const Ray& ray = list[first + size_t(b)];
              const bool occluded = (hit >> b) & 1u;
              if (hitOut) (*hitOut)[first + size_t(b)] = occluded ? 1 : 0;
              if (occluded) continue;
              visible[size_t(ray.cell)] += ray.weight;
              const double cosT = glm::dot(ray.d, n);
              if (nsh > 0) {
                lighting::evalSh(params.shBands, ray.d, y.data());
                for (int c = 0; c < nsh; ++c) shSum[size_t(c)] += y[size_t(c)] * cosT * ray.weight;
              }
            }
          }
          traced += int64_t(list.size());
        };
        auto cellOmega = [&](int i) {
          return 2.0 * kPi / s * (cosBound[size_t(i)] - cosBound[size_t(i) + 1]);
        };

        // Pass 1: one jittered ray per cell.
        batch.clear();
        for (int i = 0; i < s; ++i)
          for (int j = 0; j < s; ++j, ++sample)
            batch.push_back({direction(i, j, hash01(2 * sample), hash01(2 * sample + 1)), i * s + j,
                             cellOmega(i)});
        std::vector<char> occluded(cells, 0);
        {
          // Trace without accumulating yet: cells on a shadow boundary are sampled again.
          std::vector<double> keepVisible = visible;
          const std::vector<double> keepSh = shSum;
          trace(batch, &occluded);
          if (r > 1) {
            visible = keepVisible;
            shSum = keepSh;
          }
        }
        if (r > 1) {
          // Cells whose ray disagrees with a neighbour's lie on a shadow boundary: they get r x r
          // stratified rays; the others keep their one ray.
          auto at = [&](int i, int j) { return occluded[size_t(i * s + ((j % s + s) % s))]; };
          bool poleMixed = false;
          for (int j = 1; j < s; ++j) poleMixed = poleMixed || at(0, j) != at(0, 0);
          std::vector<Ray> settled, refine;
          for (int i = 0; i < s; ++i) {
            for (int j = 0; j < s; ++j) {
              const char c = at(i, j);
              bool boundary = i == 0 && poleMixed;
              for (int di = -1; di <= 1 && !boundary; ++di) {
                const int ii = i + di;
                if (ii < 0 || ii >= s) continue;
                for (int dj = -1; dj <= 1; ++dj) boundary = boundary || at(ii, j + dj) != c;
              }
              const Ray& first = batch[size_t(i * s + j)];
              if (!boundary) {
                settled.push_back(first);
                continue;
              }
              for (int a = 0; a < r; ++a) {
                for (int b = 0; b < r; ++b, ++sample) {
                  refine.push_back({direction(i, j, (a + hash01(2 * sample)) / r,
                                              (b + hash01(2 * sample + 1)) / r),
                                    i * s + j, cellOmega(i) / (r * r)});
                }
              }
            }
          }
          // The first pass' answers for settled cells count as they are (no second trace).
          for (const Ray& ray : settled) {
            if (occluded[size_t(ray.cell)]) continue;
            visible[size_t(ray.cell)] += ray.weight;
            const double cosT = glm::dot(ray.d, n);
            if (nsh > 0) {
              lighting::evalSh(params.shBands, ray.d, y.data());
              for (int c = 0; c < nsh; ++c) shSum[size_t(c)] += y[size_t(c)] * cosT * ray.weight;
            }
          }
          trace(refine, nullptr);
        }
        // Visible fraction per cell; AO from it and each cell's exact cosine integral
        // ∫_cell cos θ dω = (π/s)(cos²θ_i - cos²θ_{i+1}), so that a fully visible point has AO 1.
        for (int i = 0; i < s; ++i) {
          const double cosine = kPi / s *
                                (cosBound[size_t(i)] * cosBound[size_t(i)] -
                                 cosBound[size_t(i) + 1] * cosBound[size_t(i) + 1]);
          for (int j = 0; j < s; ++j) {
            visible[size_t(i * s + j)] /= cellOmega(i);
            aoSum += visible[size_t(i * s + j)] * cosine;
          }
        }
        const std::vector<double> m = lighting::moments2d(basis, basis, visible, k);
        std::transform(m.begin(), m.end(), out.cheb.begin() + ptrdiff_t(v * kk),
                       [](double x) { return float(x); });
        for (int c = 0; c < nsh; ++c) out.sh[v * size_t(nsh) + size_t(c)] = float(shSum[size_t(c)]);
        out.ao[v] = float(aoSum / kPi);
        rays += traced;
        const size_t d = ++done;
        if (d % 1024 == 0) report(progress, "shadows", double(d) / double(count));
      },
      64);
  out.rays = rays;
  report(progress, "shadows", 1.0);
  return out;
}

bool isConvex(const Mesh& mesh) {
  // Corners identified by position, so that vertices split by normals count as one.
  std::map<std::array<float, 3>, uint32_t> ids;
  std::vector<uint32_t> id(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const glm::vec3& p = mesh.positions[i];
    id[i] = ids.try_emplace({p.x, p.y, p.z}, uint32_t(ids.size())).first->second;
  }
  // Each undirected edge → the triangles on it and their third corners.
  struct Side {
    uint32_t triangle, opposite;
  };
  std::unordered_map<uint64_t, std::vector<Side>> edges;
  const size_t triangles = mesh.triangleCount();
  for (size_t t = 0; t < triangles; ++t) {
    for (int e = 0; e < 3; ++e) {
      const uint32_t a = id[mesh.indices[3 * t + size_t(e)]];
      const uint32_t b = id[mesh.indices[3 * t + size_t((e + 1) % 3)]];
      const uint64_t key = (uint64_t(std::min(a, b)) << 32) | std::max(a, b);
      edges[key].push_back({uint32_t(t), mesh.indices[3 * t + size_t((e + 2) % 3)]});
    }
  }
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  const float tolerance = 1e-5f * std::max({extent.x, extent.y, extent.z});
  for (const auto& [key, sides] : edges) {
    if (sides.size() != 2) return false;  // open or non-manifold: assume it can shadow itself
    for (int s = 0; s < 2; ++s) {
      const uint32_t* tri = &mesh.indices[3 * size_t(sides[size_t(s)].triangle)];
      const glm::vec3 p0 = mesh.positions[tri[0]];
      const glm::vec3 n =
          glm::normalize(glm::cross(mesh.positions[tri[1]] - p0, mesh.positions[tri[2]] - p0));
      // The other triangle's far corner must not lie above this triangle's plane.
      const glm::vec3 q = mesh.positions[sides[size_t(1 - s)].opposite];
      if (glm::dot(n, q - p0) > tolerance) return false;
    }
  }
  // Locally convex everywhere and closed: convex if connected (Tietze); check that the mesh is
  // one piece, since two convex pieces can shadow each other.
  std::vector<uint32_t> parent(ids.size());
  for (size_t i = 0; i < parent.size(); ++i) parent[i] = uint32_t(i);
  auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  for (size_t t = 0; t < triangles; ++t) {
    const uint32_t a = find(id[mesh.indices[3 * t]]);
    for (int e = 1; e < 3; ++e) parent[find(id[mesh.indices[3 * t + size_t(e)]])] = a;
  }
  const uint32_t root = find(id[mesh.indices[0]]);
  for (size_t t = 0; t < triangles; ++t)
    if (find(id[mesh.indices[3 * t]]) != root) return false;
  return true;
}

std::string meshHash(const Mesh& mesh) {
  Hash128 h;
  h.word(uint32_t(mesh.positions.size()));
  h.floats(std::span<const float>(&mesh.positions[0].x, 3 * mesh.positions.size()));
  h.floats(std::span<const float>(&mesh.normals[0].x, 3 * mesh.normals.size()));
  for (uint32_t i : mesh.indices) h.word(i);
  return h.hex();
}

const char* shadowMethodName(ShadowMethod method) {
  switch (method) {
    case ShadowMethod::Chebyshev:
      return "Chebyshev transfer";
    case ShadowMethod::Harmonics:
      return "SH transfer";
    case ShadowMethod::AmbientOcclusion:
      return "ambient occlusion x irradiance";
  }
  return "";
}

SourceVisibility traceSources(const Mesh& mesh, const EmbreeScene& scene,
                              const std::vector<lighting::LightSource>& sources,
                              const glm::mat3& envFromObject) {
  COMPOSE_CHECK(sources.size() <= 64);
  SourceVisibility out;
  const size_t count = mesh.positions.size();
  out.visible.assign(count, 0);
  if (sources.empty()) return out;
  const glm::mat3 objectFromEnv = glm::transpose(envFromObject);
  std::vector<glm::vec3> dirs(sources.size());
  for (size_t i = 0; i < sources.size(); ++i) dirs[i] = objectFromEnv * sources[i].direction;
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  const float size = std::max({extent.x, extent.y, extent.z});
  const float lift = 1e-4f * size, tnear = 1e-5f * size;
  std::atomic<int64_t> rays{0};
  parallelFor(
      0, int64_t(count),
      [&](int64_t vi) {
        const size_t v = size_t(vi);
        const glm::vec3 n = glm::normalize(mesh.normals[v]);
        const glm::vec3 origin = mesh.positions[v] + lift * n;
        glm::vec3 batch[8];
        int index[8];
        int m = 0;
        uint64_t visible = 0;
        int64_t traced = 0;
        auto flush = [&] {
          const uint32_t hit = scene.occluded8(origin, batch, (1u << m) - 1u, tnear);
          for (int b = 0; b < m; ++b)
            if (!((hit >> b) & 1u)) visible |= uint64_t(1) << index[b];
          traced += m;
          m = 0;
        };
        for (size_t i = 0; i < dirs.size(); ++i) {
          if (glm::dot(n, dirs[i]) <= 0.0f) continue;  // below the horizon: no light anyway
          batch[m] = dirs[i];
          index[m] = int(i);
          if (++m == 8) flush();
        }
        if (m > 0) flush();
        out.visible[v] = visible;
        rays += traced;
      },
      256);
  out.rays = rays;
  return out;
}

VertexIrradiance shadeVertices(const Mesh& mesh, const glm::mat3& envFromObject,
                               const ShadowInputs& in) {
  COMPOSE_CHECK(in.shadowLighting != nullptr);
  const ShadowMethod method = in.method;
  const size_t count = mesh.positions.size();
  // The rotation must be a turn about +Y: its angle is the longitude offset.
  const glm::vec3 x = envFromObject[0];
  COMPOSE_CHECK(std::abs(x.y) < 1e-4f && std::abs(envFromObject[1].y - 1.0f) < 1e-4f);
  const double yaw = std::atan2(-double(x.z), double(x.x));

  const auto* cheb = dynamic_cast<const lighting::ChebLocalLighting*>(in.shadowLighting);
  const auto* sh = dynamic_cast<const lighting::ShLighting*>(in.shadowLighting);
  if (!in.transfer) {
    throw Error("shadows", std::string(shadowMethodName(method)) + " needs the visibility pass");
  }
  COMPOSE_CHECK(in.transfer->vertexCount == count);
  const TransferParams& p = in.transfer->params;
  if (method == ShadowMethod::Chebyshev) {
    if (!cheb || !cheb->lambertian())
      throw Error("shadows", "Chebyshev transfer needs the cheb-local lighting with brdf=lambert");
    if (cheb->samples() != p.grid || cheb->order() > p.order) {
      throw Error("shadows",
                  "Chebyshev transfer needs cheb-local on the visibility's grid "
                  "(samples=" +
                      std::to_string(p.grid) + ") with order <= " + std::to_string(p.order) +
                      "; the lighting has samples=" + std::to_string(cheb->samples()) +
                      ", order=" + std::to_string(cheb->order()));
    }
  }
  if (method == ShadowMethod::Harmonics) {
    if (!sh) throw Error("shadows", "SH transfer needs the sh lighting");
    if (sh->coefficientsPerChannel() > lighting::shCount(p.shBands)) {
      throw Error("shadows", "SH transfer was computed up to band " + std::to_string(p.shBands) +
                                 "; the sh lighting has more bands");
    }
  }
  const bool withSources = !in.sources.empty();
  if (withSources && method != ShadowMethod::AmbientOcclusion)
    COMPOSE_CHECK(in.sourceVisibility && in.sourceVisibility->visible.size() == count);

  VertexIrradiance out;
  out.shadowed.resize(count);
  out.unshadowed.resize(count);
  std::atomic<int> clamped{0};
  parallelFor(
      0, int64_t(count),
      [&](int64_t vi) {
        const size_t v = size_t(vi);
        const glm::dvec3 nObj = glm::normalize(glm::dvec3(mesh.normals[v]));
        const glm::vec3 nEnv = glm::normalize(envFromObject * glm::vec3(nObj));
        glm::vec3 unshadowed = glm::max(in.shadowLighting->irradiance(nEnv), glm::vec3(0.0f));
        for (const lighting::LightSource& source : in.sources)
          unshadowed += std::max(0.0f, glm::dot(nEnv, source.direction)) * source.power;
        glm::vec3 shadowed(0.0f);
        switch (method) {
          case ShadowMethod::Chebyshev: {
            const int k = cheb->order(), K = p.order;
            const size_t kk = size_t(k) * size_t(k);
            float a[3 * 32 * 32];  // k <= 32 (ChebParams)
            const double lat = std::asin(std::clamp(nObj.y, -1.0, 1.0));
            cheb->lightMoments(lat, longitudeOf(nObj) + yaw, a);
            const float* b = in.transfer->cheb.data() + v * size_t(K) * size_t(K);
            for (int m = 0; m < k; ++m) {
              for (int n = 0; n < k; ++n) {
                const float bv = b[m * K + n];
                const size_t i = size_t(m * k + n);
                shadowed += bv * glm::vec3(a[i], a[kk + i], a[2 * kk + i]);
              }
            }
            break;
          }
          case ShadowMethod::Harmonics: {
            const int bands = int(std::lround(std::sqrt(sh->coefficientsPerChannel()))) - 1;
            const int stride = lighting::shCount(p.shBands);
            const float* t = in.transfer->sh.data() + v * size_t(stride);
            const std::vector<glm::dvec3>& L = sh->radianceCoefficients();
            glm::dvec3 e(0.0);
            for (int l = 0; l <= bands; ++l) {
              const int base = l * (l + 1);
              e += double(t[base]) * L[size_t(base)];
              for (int m = 1; m <= l; ++m) {
                // Turn the object's transfer by the yaw: (c, s) of band m rotate by mα.
                const double c = t[base + m], s = t[base - m];
                const double cr = std::cos(m * yaw), sr = std::sin(m * yaw);
                e += (c * cr - s * sr) * L[size_t(base + m)] +
                     (c * sr + s * cr) * L[size_t(base - m)];
              }
            }
            shadowed = glm::vec3(e);
            break;
          }
          case ShadowMethod::AmbientOcclusion:
            shadowed = in.transfer->ao[v] * unshadowed;
            break;
        }
        if (withSources && method != ShadowMethod::AmbientOcclusion) {
          const uint64_t seen = in.sourceVisibility->visible[v];
          for (size_t i = 0; i < in.sources.size(); ++i) {
            if (!((seen >> i) & 1u)) continue;
            const float c = glm::dot(nEnv, in.sources[i].direction);
            if (c > 0.0f) shadowed += c * in.sources[i].power;
          }
        }
        // Truncation can ring below 0 or above the unshadowed value: light is never negative and
        // visibility never adds light.
        const glm::vec3 limited = glm::clamp(shadowed, glm::vec3(0.0f), unshadowed);
        if (glm::any(glm::greaterThan(glm::abs(limited - shadowed), 1e-3f * unshadowed + 1e-12f)))
          ++clamped;
        out.shadowed[v] = limited;
        out.unshadowed[v] = unshadowed;
      },
      256);
  out.clamped = clamped;
  return out;
}

}  // namespace compose::render
