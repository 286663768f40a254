#include "render/transfer.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <mutex>
#include <numbers>
#include <optional>
#include <unordered_map>

#include <glm/common.hpp>
#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/hash.h"
#include "core/parallel.h"

#include <tbb/enumerable_thread_specific.h>
#include "core/numbers.h"
#include "lighting/chebyshev.h"
#include "lighting/sh.h"
#include "lighting/tchebichef.h"
#include "render/embree_scene.h"

namespace compose::render {

namespace {

// A vector whose resize() leaves new elements uninitialised (core/buffer.h).
template <class T>
using Uncleared = std::vector<T, DefaultInitAllocator<T>>;

// The indices of `points` along a Morton (Z-order) curve through their bounding box, so that
// consecutive indices are near each other.
std::vector<uint32_t> spatialOrder(const std::vector<glm::vec3>& points) {
  glm::vec3 lo(std::numeric_limits<float>::max()), hi(-std::numeric_limits<float>::max());
  for (const glm::vec3& p : points) {
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  }
  const glm::vec3 scale = 1023.0f / glm::max(hi - lo, glm::vec3(1e-30f));
  auto spread = [](uint32_t x) {  // bit b of 10 to bit 3b
    x = (x | (x << 16)) & 0x030000FFu;
    x = (x | (x << 8)) & 0x0300F00Fu;
    x = (x | (x << 4)) & 0x030C30C3u;
    return (x | (x << 2)) & 0x09249249u;
  };
  std::vector<std::pair<uint32_t, uint32_t>> code(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const glm::vec3 q = glm::clamp((points[i] - lo) * scale, glm::vec3(0.0f), glm::vec3(1023.0f));
    code[i] = {spread(uint32_t(q.x)) | (spread(uint32_t(q.y)) << 1) | (spread(uint32_t(q.z)) << 2),
               uint32_t(i)};
  }
  std::sort(code.begin(), code.end());
  std::vector<uint32_t> order(points.size());
  for (size_t i = 0; i < code.size(); ++i) order[i] = code[i].second;
  return order;
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

// Calls visit(b0, b1, b2, flat) for each own point of triangle t's grid of L segments per edge
// (all but its corners), in rows of increasing j and, within a row, of increasing i: the order
// in which appendGrid() stores them. flat is the point on the triangle itself.
template <class Visit>
void forEachGridPoint(const Mesh& mesh, size_t t, int L, Visit&& visit) {
  const uint32_t* v = &mesh.indices[3 * t];
  const glm::vec3 p[3] = {mesh.positions[v[0]], mesh.positions[v[1]], mesh.positions[v[2]]};
  for (int j = 0; j <= L; ++j) {
    for (int i = 0; i <= L - j; ++i) {
      if ((i == 0 && j == 0) || (i == L && j == 0) || (i == 0 && j == L)) continue;
      const float b1 = float(i) / float(L), b2 = float(j) / float(L), b0 = 1.0f - b1 - b2;
      visit(b0, b1, b2, b0 * p[0] + b1 * p[1] + b2 * p[2]);
    }
  }
}

// Gives triangle t a grid of L segments per edge (transfer.h): its own points appended in
// forEachGridPoint's order.
void appendGrid(const Mesh& mesh, SurfacePoints& out, size_t t, int L) {
  out.level[t] = uint8_t(L);
  out.first[t] = 0;
  if (L == 1) return;
  out.first[t] = uint32_t(out.positions.size());
  const uint32_t* v = &mesh.indices[3 * t];
  const glm::vec3 p[3] = {mesh.positions[v[0]], mesh.positions[v[1]], mesh.positions[v[2]]};
  const glm::vec3 n[3] = {out.normals[v[0]], out.normals[v[1]], out.normals[v[2]]};
  const float onEdge = 0.5f / float(L);
  forEachGridPoint(mesh, t, L, [&](float b0, float b1, float b2, const glm::vec3& flat) {
    // On the smooth surface of the vertex normals: a flat triangle's own point could be
    // shadowed by its neighbours where the shading says it faces the light.
    out.positions.push_back(mesh.smoothPoint(uint32_t(t), b1, b2, flat));
    const glm::vec3 nn = b0 * n[0] + b1 * n[1] + b2 * n[2];
    const float len = glm::length(nn);
    const glm::vec3 normal =
        len > 1e-12f ? nn / len : glm::normalize(glm::cross(p[1] - p[0], p[2] - p[0]));
    out.normals.push_back(normal);
    // A point on the triangle's edge steps into the triangle, across the edge
    // (SurfacePoints::inward).
    glm::vec3 in(0.0f);
    const int edge = b0 < onEdge ? 0 : b1 < onEdge ? 1 : b2 < onEdge ? 2 : -1;
    if (edge >= 0) {
      // The edge opposite corner `edge`, and the way from it to that corner.
      const glm::vec3 a = p[(edge + 1) % 3], b = p[(edge + 2) % 3], c = p[edge];
      const glm::vec3 along = glm::normalize(b - a);
      in = (c - a) - along * glm::dot(c - a, along);
      in -= normal * glm::dot(normal, in);
      const float l = glm::length(in);
      in = l > 0.0f ? in / l : glm::vec3(0.0f);
    }
    // Only beside a step for every earlier point (SurfacePoints::inward: empty is none).
    if (out.inward.size() + 1 == out.positions.size()) out.inward.push_back(in);
  });
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
         " seed=" + std::to_string(seed) + " lift=1e-4 inward=half frame=longitude" +
         (shBands > 0 ? " sh-projection=cells" : "") + (selfOcclusion ? "" : " no-self-occlusion");
}

std::vector<float> VertexTransfer::exportState() const {
  std::vector<float> out;
  out.reserve(floatsStored());
  out.insert(out.end(), cheb.begin(), cheb.end());
  out.insert(out.end(), sh.begin(), sh.end());
  out.insert(out.end(), ao.begin(), ao.end());
  for (const uint8_t b : buried) out.push_back(float(b));
  return out;
}

bool VertexTransfer::importState(const TransferParams& p, size_t vertices, FloatBuffer in) {
  const size_t kk = size_t(p.order) * size_t(p.order);
  const size_t nsh = size_t(lighting::shCount(p.shBands));
  if (in.size() != vertices * (kk + nsh + 2)) return false;
  const auto flags = in.begin() + ptrdiff_t(vertices * (kk + nsh + 1));
  if (!std::all_of(flags, in.end(), [](float f) { return f == 0.0f || f == 1.0f; })) return false;
  params = p;
  vertexCount = vertices;
  sh.assign(in.begin() + ptrdiff_t(vertices * kk), in.begin() + ptrdiff_t(vertices * (kk + nsh)));
  ao.assign(in.begin() + ptrdiff_t(vertices * (kk + nsh)), flags);
  buried.assign(vertices, 0);
  for (size_t v = 0; v < vertices; ++v) buried[v] = uint8_t(flags[ptrdiff_t(v)] == 1.0f);
  // The moments come first: they stay where they are.
  in.resize(vertices * kk);
  cheb = std::move(in);
  return true;
}

SurfacePoints surfacePoints(const Mesh& mesh, float maxEdgeFraction, size_t budget) {
  COMPOSE_CHECK(maxEdgeFraction > 0.0f);
  SurfacePoints out;
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  out.size = std::max({extent.x, extent.y, extent.z});
  out.centre = 0.5f * (mesh.boundsMin() + mesh.boundsMax());
  out.radius = 0.5f * glm::length(extent);
  // Longest edge per triangle, then the finest spacing whose points fit the budget.
  const size_t triangles = mesh.triangleCount();
  std::vector<float> longestEdge(triangles);
  for (size_t t = 0; t < triangles; ++t) {
    const uint32_t* v = &mesh.indices[3 * t];
    const glm::vec3 p[3] = {mesh.positions[v[0]], mesh.positions[v[1]], mesh.positions[v[2]]};
    longestEdge[t] =
        std::max({glm::length(p[1] - p[0]), glm::length(p[2] - p[1]), glm::length(p[0] - p[2])});
  }
  auto levelFor = [](float longest, float edge) {
    return std::clamp(int(std::ceil(longest / edge)), 1, 32);
  };
  float maxEdge = maxEdgeFraction * out.size;
  // The budget is the front sides': a back side (Mesh::sides) gets the grid of its front, so that
  // giving an open surface its inside does not coarsen its outside.
  for (int attempt = 0; attempt < 64; ++attempt) {
    size_t count = mesh.positions.size();
    for (size_t t = 0; t < triangles; ++t) {
      if (!mesh.sides.empty() && mesh.sides[t] == Mesh::kBackSide) continue;
      const size_t L = size_t(levelFor(longestEdge[t], maxEdge));
      if (L > 1) count += (L + 1) * (L + 2) / 2 - 3;
    }
    if (count <= std::max(budget, mesh.positions.size())) break;
    maxEdge *= 1.25f;
  }
  out.positions = mesh.positions;
  out.normals.resize(mesh.normals.size());
  for (size_t i = 0; i < mesh.normals.size(); ++i) out.normals[i] = glm::normalize(mesh.normals[i]);
  // A vertex steps into its triangles (SurfacePoints::inward): half the integral of the unit
  // direction over the angles its triangles span there (a wedge of angle Δ gives 2 sin(Δ/2)
  // along its bisector), along the surface. Zero inside a flat fan; where the fan is half a
  // turn (a straight boundary or hard crease), length 1 across it; at a square corner, 0.71
  // along the diagonal.
  out.inward.assign(mesh.positions.size(), glm::vec3(0.0f));
  for (size_t t = 0; t < triangles; ++t) {
    const uint32_t* v = &mesh.indices[3 * t];
    for (int k = 0; k < 3; ++k) {
      const glm::vec3 o = mesh.positions[v[k]];
      const glm::vec3 d1 = mesh.positions[v[(k + 1) % 3]] - o;
      const glm::vec3 d2 = mesh.positions[v[(k + 2) % 3]] - o;
      const float l1 = glm::length(d1), l2 = glm::length(d2);
      if (!(l1 > 0.0f && l2 > 0.0f)) continue;
      const glm::vec3 sum = d1 / l1 + d2 / l2;  // along the bisector, length 2 cos(Δ/2)
      const float cosHalf = 0.5f * glm::length(sum);
      if (!(cosHalf > 1e-6f)) continue;
      const float sinHalf = std::sqrt(std::max(0.0f, 1.0f - cosHalf * cosHalf));
      out.inward[v[k]] += sum * (0.5f * sinHalf / cosHalf);  // half of 2 sin(Δ/2), bisector
    }
  }
  for (size_t i = 0; i < out.inward.size(); ++i) {
    glm::vec3 in = out.inward[i];
    in -= out.normals[i] * glm::dot(out.normals[i], in);
    const float l = glm::length(in);
    out.inward[i] = l > 1.0f ? in / l : in;
  }
  out.first.assign(triangles, 0);
  out.level.assign(triangles, 1);
  for (size_t t = 0; t < triangles; ++t) {
    appendGrid(mesh, out, t, levelFor(longestEdge[t], maxEdge));
  }
  return out;
}

void RefineParams::validate() const {
  auto fail = [](const std::string& what) { throw UsageError(what, "shadows"); };
  if (!(spread >= 0.0f && spread <= 1.0f))
    fail("refine (the ambient occlusion spread that refines a triangle) must be in 0..1, got " +
         numberText(spread));
  if (!(budget >= 0.0f && budget <= 16.0f))
    fail("refine budget must be in 0..16 (times the points), got " + numberText(budget));
  if (factor < 2 || factor > 32)
    fail("refine factor must be in 2..32, got " + std::to_string(factor));
}

std::string RefineParams::key() const {
  if (spread <= 0.0f) return "refine=off";
  char text[96];
  std::snprintf(text, sizeof text, "refine=%.9g budget=%.9g factor=%d", double(spread),
                double(budget), factor);
  return text;
}

size_t refineSurfacePoints(const Mesh& mesh, SurfacePoints& points, const std::vector<float>& ao,
                           const RefineParams& params) {
  params.validate();
  COMPOSE_CHECK(ao.size() == points.count());
  const size_t first = points.count();
  if (params.spread <= 0.0f) return first;
  const size_t triangles = mesh.triangleCount();
  std::vector<std::pair<float, uint32_t>> wide;  // (spread, triangle)
  for (size_t t = 0; t < triangles; ++t) {
    const int L = points.level[t];
    if (L >= 32) continue;
    float lo = 1.0f, hi = 0.0f;
    auto take = [&](size_t p) {
      lo = std::min(lo, ao[p]);
      hi = std::max(hi, ao[p]);
    };
    for (int c = 0; c < 3; ++c) take(mesh.indices[3 * t + size_t(c)]);
    if (L > 1) {
      const size_t own = size_t((L + 1) * (L + 2) / 2 - 3);
      for (size_t i = 0; i < own; ++i) take(points.first[t] + i);
    }
    if (hi - lo > params.spread) wide.push_back({hi - lo, uint32_t(t)});
  }
  // Those that span most first (ties by triangle, for a result that does not depend on sorting).
  std::sort(wide.begin(), wide.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  const size_t budget = size_t(double(params.budget) * double(first));
  size_t added = 0;
  std::vector<std::pair<uint32_t, int>> chosen;  // (triangle, level)
  for (const auto& [spread, t] : wide) {
    const int L = std::min(32, points.level[t] * params.factor);
    const size_t more = size_t((L + 1) * (L + 2) / 2 - 3);
    if (added + more > budget) continue;  // a smaller one may still fit
    chosen.push_back({t, L});
    added += more;
  }
  // The grids are appended in the order of the triangles, as restoreLevels appends them from
  // the levels alone: a cache entry's per-point values then belong to the same points.
  std::sort(chosen.begin(), chosen.end());
  for (const auto& [t, L] : chosen) appendGrid(mesh, points, t, L);
  return first;
}

bool restoreLevels(const Mesh& mesh, SurfacePoints& points, const std::vector<uint8_t>& levels) {
  const size_t triangles = mesh.triangleCount();
  if (levels.size() != triangles) return false;
  for (size_t t = 0; t < triangles; ++t)
    if (levels[t] < points.level[t] || levels[t] > 32) return false;
  for (size_t t = 0; t < triangles; ++t)
    if (levels[t] != points.level[t]) appendGrid(mesh, points, t, levels[t]);
  return true;
}

void VertexTransfer::append(const VertexTransfer& more) {
  COMPOSE_CHECK(more.params.key() == params.key());
  cheb.insert(cheb.end(), more.cheb.begin(), more.cheb.end());
  sh.insert(sh.end(), more.sh.begin(), more.sh.end());
  ao.insert(ao.end(), more.ao.begin(), more.ao.end());
  aoSelf.insert(aoSelf.end(), more.aoSelf.begin(), more.aoSelf.end());
  buried.insert(buried.end(), more.buried.begin(), more.buried.end());
  vertexCount += more.vertexCount;
  rays += more.rays;
}

void keepLiftsClear(const Mesh& mesh, const EmbreeScene& scene, SurfacePoints& points,
                    size_t from) {
  const float tnear = 1e-5f * points.size;
  parallelFor(
      0, int64_t(mesh.triangleCount()),
      [&](int64_t ti) {
        const size_t t = size_t(ti);
        const int L = points.level[t];
        if (L == 1 || points.first[t] < from) return;
        uint32_t index = points.first[t];
        forEachGridPoint(mesh, t, L, [&](float, float, float, const glm::vec3& flat) {
          glm::vec3& lifted = points.positions[index++];
          const glm::vec3 d = lifted - flat;
          const float length = glm::length(d);
          if (length > tnear && scene.occluded(flat, d / length, tnear, length)) lifted = flat;
        });
      },
      256);
}

VertexTransfer computeRefinedTransfer(const Mesh& mesh, SurfacePoints& points,
                                      const TransferParams& params, const RefineParams& refine,
                                      const Progress& progress, const GroundContact* ground) {
  const EmbreeScene scene(mesh);
  return computeRefinedTransfer(mesh, scene, points, params, refine, progress, ground);
}

VertexTransfer computeRefinedTransfer(const Mesh& mesh, const EmbreeScene& scene,
                                      SurfacePoints& points, const TransferParams& params,
                                      const RefineParams& refine, const Progress& progress,
                                      const GroundContact* ground) {
  keepLiftsClear(mesh, scene, points);
  // One progress for both passes: the first to 85 %, the refinement's (at most as many points,
  // usually a few per cent) after it.
  constexpr double kFirstShare = 0.85;
  auto part = [&](double from, double to) -> Progress {
    if (!progress) return {};
    return [&progress, from, to](std::string_view stage, double fraction) {
      progress(stage, from + (to - from) * fraction);
    };
  };
  VertexTransfer transfer =
      computeTransfer(mesh, scene, points, params, part(0.0, kFirstShare), ground);
  // Refined where the object's own shadowing changes fast: the ground's darkening is smooth.
  const size_t first = refineSurfacePoints(
      mesh, points, transfer.aoSelf.empty() ? transfer.ao : transfer.aoSelf, refine);
  if (first == points.count()) {
    points.buried = transfer.buried;
    return transfer;
  }
  keepLiftsClear(mesh, scene, points, first);
  SurfacePoints extra;
  extra.size = points.size;
  extra.centre = points.centre;
  extra.radius = points.radius;
  extra.positions.assign(points.positions.begin() + ptrdiff_t(first), points.positions.end());
  extra.normals.assign(points.normals.begin() + ptrdiff_t(first), points.normals.end());
  if (!points.inward.empty())
    extra.inward.assign(points.inward.begin() + ptrdiff_t(first), points.inward.end());
  transfer.append(computeTransfer(mesh, scene, extra, params, part(kFirstShare, 1.0), ground));
  points.buried = transfer.buried;
  return transfer;
}

void GroundContactParams::validate() const {
  auto fail = [](const std::string& what) { throw UsageError(what, "shadows"); };
  if (resolution < 2 || resolution > 1024)
    fail("ground resolution must be in 2..1024, got " + std::to_string(resolution));
  if (!(reach > 0.0f && reach <= 100.0f)) fail("ground reach must be in (0, 100] object sizes");
  if (!(fineReach > 0.0f && fineReach <= 10.0f))
    fail("ground fine reach must be in (0, 10] object heights");
  if (fineSteps < 1 || fineSteps > 1024) fail("ground fine steps must be in 1..1024");
  if (fineBudget < 4 || fineBudget > (size_t(1) << 22)) fail("ground fine budget out of range");
}

std::string GroundContactParams::key() const {
  char text[128];
  std::snprintf(text, sizeof text, "ground v3 %d %.6g fine %.6g %d %zu", resolution, double(reach),
                double(fineReach), fineSteps, fineBudget);
  return text;
}

float GroundGridLevel::at(float x, float z) const {
  const float cx = std::clamp(x, x0, x0 + float(columns - 1) * step);
  const float cz = std::clamp(z, z0, z0 + float(rows - 1) * step);
  const float fa = (cx - x0) / step, fb = (cz - z0) / step;
  const int a = std::min(columns - 2, std::max(0, int(fa)));
  const int b = std::min(rows - 2, std::max(0, int(fb)));
  const float u = std::clamp(fa - float(a), 0.0f, 1.0f), w = std::clamp(fb - float(b), 0.0f, 1.0f);
  const float* row0 = open.data() + size_t(b) * size_t(columns) + size_t(a);
  const float* row1 = row0 + columns;
  const float value[4] = {row0[0], row0[1], row1[0], row1[1]};
  const float weight[4] = {(1.0f - u) * (1.0f - w), u * (1.0f - w), (1.0f - u) * w, u * w};
  float sum = 0.0f, total = 0.0f;
  for (int i = 0; i < 4; ++i) {
    const bool uncovered = value[i] > 0.0f;  // 0: covered by the object
    sum += uncovered ? weight[i] * value[i] : 0.0f;
    total += uncovered ? weight[i] : 0.0f;
  }
  return total > 0.0f ? sum / total : 0.0f;
}

float GroundContact::openAt(float x, float z) const {
  if (!std::isfinite(x) || !std::isfinite(z) || coarse.empty()) return 1.0f;
  if (!fine.empty() && fine.contains(x, z)) return fine.at(x, z);
  const float value = coarse.at(x, z);
  if (coarse.contains(x, z)) return value;
  // Beyond the grid: the shortfall at the nearest edge point falls off as 1/d³ from the centre.
  const float cx = std::clamp(x, coarse.x0, coarse.x0 + float(coarse.columns - 1) * coarse.step);
  const float cz = std::clamp(z, coarse.z0, coarse.z0 + float(coarse.rows - 1) * coarse.step);
  const float edge = std::hypot(cx - centreX, cz - centreZ);
  const float far = std::hypot(x - centreX, z - centreZ);
  if (!(far > edge) || !(edge > 0.0f)) return value;
  const float ratio = edge / far;
  return 1.0f - (1.0f - value) * ratio * ratio * ratio;
}

namespace {

// A grid of `step` over [lo, hi] (x and z), centred on it.
GroundGridLevel groundLevel(float loX, float hiX, float loZ, float hiZ, float step) {
  GroundGridLevel level;
  level.step = step;
  level.columns = std::max(2, int(std::ceil((hiX - loX) / step)) + 1);
  level.rows = std::max(2, int(std::ceil((hiZ - loZ) / step)) + 1);
  level.x0 = 0.5f * (loX + hiX) - 0.5f * step * float(level.columns - 1);
  level.z0 = 0.5f * (loZ + hiZ) - 0.5f * step * float(level.rows - 1);
  return level;
}

}  // namespace

GroundContact groundContact(const Mesh& mesh, const EmbreeScene& scene,
                            const GroundContactParams& params) {
  params.validate();
  GroundContact out;
  if (mesh.positions.empty()) return out;
  // The surface that is there: a cut-out's lower part does not reach the ground.
  glm::vec3 lo, hi;
  mesh.keptBounds(lo, hi);
  const float size = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  if (!(size > 0.0f) || !std::isfinite(size)) return out;
  out.height = lo.y;
  out.centreX = 0.5f * (lo.x + hi.x);
  out.centreZ = 0.5f * (lo.z + hi.z);
  const float margin = params.reach * size;
  const float width = hi.x - lo.x + 2.0f * margin, depth = hi.z - lo.z + 2.0f * margin;
  out.coarse = groundLevel(lo.x - margin, hi.x + margin, lo.z - margin, hi.z + margin,
                           std::max(width, depth) / float(params.resolution - 1));
  // The fine grid, where the ground's darkening changes over a fraction of the height (a flat
  // object has none: its own size sets the scale then).
  const float objectHeight = hi.y - lo.y > 1e-3f * size ? hi.y - lo.y : size;
  const float fineMargin = params.fineReach * objectHeight;
  const float fineWidth = hi.x - lo.x + 2.0f * fineMargin;
  const float fineDepth = hi.z - lo.z + 2.0f * fineMargin;
  const float fineStep =
      std::max(objectHeight / float(params.fineSteps),
               std::sqrt(fineWidth * fineDepth / float(params.fineBudget)) * 1.01f);
  if (fineStep < 0.75f * out.coarse.step) {
    out.fine = groundLevel(lo.x - fineMargin, hi.x + fineMargin, lo.z - fineMargin,
                           hi.z + fineMargin, fineStep);
  }
  // The nodes as surface points facing +Y; their visibility pass' ambient occlusion is open(g).
  SurfacePoints nodes;
  nodes.size = size;
  nodes.centre = 0.5f * (lo + hi);
  nodes.radius = 0.5f * glm::length(hi - lo);
  // A coarse node off the coarse grid's border whose four cells lie inside the fine grid is never
  // read (openAt() takes the fine grid there; a point beyond the coarse grid reads its border):
  // it is filled from the fine grid instead of traced.
  auto hidden = [&](int a, int b, float x, float z) {
    if (out.fine.columns < 2 || out.fine.rows < 2) return false;  // no fine grid
    if (a == 0 || b == 0 || a == out.coarse.columns - 1 || b == out.coarse.rows - 1) return false;
    const float reach = 1.01f * out.coarse.step;
    const float x1 = out.fine.x0 + float(out.fine.columns - 1) * out.fine.step;
    const float z1 = out.fine.z0 + float(out.fine.rows - 1) * out.fine.step;
    return x - reach > out.fine.x0 && x + reach < x1 && z - reach > out.fine.z0 && z + reach < z1;
  };
  std::vector<uint32_t> filled;  // coarse nodes (their index in coarse.open) not traced
  for (const GroundGridLevel* level : {&out.fine, &out.coarse}) {
    for (int b = 0; b < level->rows; ++b)
      for (int a = 0; a < level->columns; ++a) {
        const float x = level->x0 + float(a) * level->step, z = level->z0 + float(b) * level->step;
        if (level == &out.coarse && hidden(a, b, x, z)) {
          filled.push_back(uint32_t(b * level->columns + a));
          continue;
        }
        nodes.positions.emplace_back(x, out.height, z);
      }
  }
  nodes.normals.assign(nodes.positions.size(), glm::vec3(0.0f, 1.0f, 0.0f));
  TransferParams tp;
  tp.order = 1;
  tp.shBands = 0;
  tp.boundaryRays = 2;
  const VertexTransfer t = computeTransfer(mesh, scene, nodes, tp);
  const size_t fineCount = size_t(out.fine.columns) * size_t(out.fine.rows);
  out.fine.open.assign(t.ao.begin(), t.ao.begin() + ptrdiff_t(fineCount));
  out.coarse.open.assign(size_t(out.coarse.columns) * size_t(out.coarse.rows), 0.0f);
  size_t traced = fineCount, skipped = 0;
  for (size_t i = 0; i < out.coarse.open.size(); ++i) {
    if (skipped < filled.size() && filled[skipped] == i) {
      ++skipped;
      continue;
    }
    out.coarse.open[i] = t.ao[traced++];
  }
  COMPOSE_CHECK(traced == t.ao.size() && skipped == filled.size());
  // A node that sees no sky at all is under the object (or shut in by it): no ray that misses
  // the object reaches it. 0 marks it; a node that sees a little keeps that (> 0).
  for (GroundGridLevel* level : {&out.fine, &out.coarse})
    for (float& v : level->open) v = v > 0.0f ? std::max(v, 1e-6f) : 0.0f;
  out.filled = std::move(filled);
  for (const uint32_t i : out.filled) {
    const int a = int(i % uint32_t(out.coarse.columns)), b = int(i / uint32_t(out.coarse.columns));
    out.coarse.open[i] = out.fine.at(out.coarse.x0 + float(a) * out.coarse.step,
                                     out.coarse.z0 + float(b) * out.coarse.step);
  }
  out.rays = t.rays;
  return out;
}

uint32_t SurfacePoints::gridPoint(const Mesh& mesh, uint32_t t, int i, int j) const {
  const uint32_t* corner = &mesh.indices[3 * size_t(t)];
  const int L = level[t];
  if (i == 0 && j == 0) return corner[0];
  if (i == L && j == 0) return corner[1];
  if (i == 0 && j == L) return corner[2];
  int rank = j * (L + 1) - j * (j - 1) / 2 + i;  // row j holds L - j + 1 points
  rank -= 1;                                     // corner (0, 0) is not stored
  if (j > 0) rank -= 1;                          // nor (L, 0), the last of row 0
  return first[t] + uint32_t(rank);
}

void SurfacePoints::locate(const Mesh& mesh, uint32_t t, float u, float v, uint32_t idx[3],
                           float w[3]) const {
  locateGrid(mesh, t, u, v, idx, w);
  if (buried.empty()) return;
  COMPOSE_CHECK(buried.size() == positions.size());
  const int open = int(!buried[idx[0]]) + int(!buried[idx[1]]) + int(!buried[idx[2]]);
  if (open == 0 || open == 3) return;
  // Inside another part: left out, the others' weights scaled up (shared equally where the hit
  // is at the buried point itself). Its place goes to the first open point, so that every hit in
  // the cell names the same three (the renderer shades samples that share them together).
  int keep = -1;
  float sum = 0.0f;
  for (int q = 0; q < 3; ++q) {
    if (buried[idx[q]]) continue;
    sum += w[q];
    if (keep < 0) keep = q;
  }
  for (int q = 0; q < 3; ++q) {
    if (buried[idx[q]]) {
      idx[q] = idx[keep];
      w[q] = 0.0f;
    } else {
      w[q] = sum > 0.0f ? w[q] / sum : 1.0f / float(open);
    }
  }
}

void SurfacePoints::locateGrid(const Mesh& mesh, uint32_t t, float u, float v, uint32_t idx[3],
                               float w[3]) const {
  const uint32_t* corner = &mesh.indices[3 * size_t(t)];
  const int L = level[t];
  if (L == 1) {
    idx[0] = corner[0], idx[1] = corner[1], idx[2] = corner[2];
    w[0] = 1.0f - u - v, w[1] = u, w[2] = v;
    return;
  }
  auto point = [&](int i, int j) { return gridPoint(mesh, t, i, j); };
  const float fu = std::clamp(u, 0.0f, 1.0f) * float(L), fv = std::clamp(v, 0.0f, 1.0f) * float(L);
  int i = std::min(int(fu), L - 1), j = std::min(int(fv), L - 1);
  if (i + j > L - 1) {
    // Rounding put the hit past the diagonal: onto the last cell of its row.
    i = L - 1 - j;
  }
  const float a = fu - float(i), b = fv - float(j);
  if (a + b <= 1.0f || i + j == L - 1) {
    idx[0] = point(i, j), idx[1] = point(i + 1, j), idx[2] = point(i, j + 1);
    w[0] = std::max(0.0f, 1.0f - a - b), w[1] = a, w[2] = b;
  } else {
    idx[0] = point(i + 1, j + 1), idx[1] = point(i, j + 1), idx[2] = point(i + 1, j);
    w[0] = a + b - 1.0f, w[1] = 1.0f - a, w[2] = 1.0f - b;
  }
}

namespace {

// SH transfer projected cell by cell (computeTransfer): each cell's ∫ cos θ Y_lm dω in a point's
// own frame (x east, y north, z the normal) is the same for every point, so it is integrated once,
// finely; a point's transfer is its cells' visible fractions times those integrals, as the
// Chebyshev side pairs the fractions with the lighting's integrals over each cell; it is then
// turned into the object's frame. The turn works band by band: a band-l function is known
// exactly from its values at enough directions, so the turned coefficients are the least-squares
// fit (here exact) of the local function's values at fixed directions seen from the point's frame.
class CellHarmonics {
 public:
  CellHarmonics(int order, int s, const std::vector<double>& cosBound) : order_(order) {
    nsh_ = lighting::shCount(order);
    const size_t cells = size_t(s) * size_t(s);
    local_.assign(cells * size_t(nsh_), 0.0);
    std::vector<double> y(static_cast<size_t>(nsh_));
    constexpr int kSub = 16;  // per cell, in cos θ and in φ: uniform in solid angle
    for (int i = 0; i < s; ++i) {
      const double a = cosBound[size_t(i)], b = cosBound[size_t(i) + 1];
      const double weight = (a - b) / kSub * (2.0 * kPi / s) / kSub;  // dω of a sub-cell
      for (int j = 0; j < s; ++j) {
        double* w = local_.data() + (size_t(i) * size_t(s) + size_t(j)) * size_t(nsh_);
        for (int u = 0; u < kSub; ++u) {
          const double c = a - (u + 0.5) / kSub * (a - b), sn = std::sqrt(std::max(0.0, 1 - c * c));
          for (int v = 0; v < kSub; ++v) {
            const double phi = 2.0 * kPi * (j + (v + 0.5) / kSub) / s;
            lighting::evalSh(order, glm::dvec3(sn * std::cos(phi), sn * std::sin(phi), c),
                             y.data());
            for (int m = 0; m < nsh_; ++m) w[m] += weight * c * y[size_t(m)];
          }
        }
      }
    }
    // Fixed directions (a Fibonacci sphere) and, per band, the least-squares solver of the
    // band's coefficients from values there: (AᵀA)⁻¹Aᵀ with A[i][m] = Y_lm(u_i).
    const int n = kDirections;
    for (int i = 0; i < n; ++i) {
      const double z = 1.0 - (2.0 * i + 1.0) / n, r = std::sqrt(std::max(0.0, 1.0 - z * z));
      const double phi = double(i) * 2.399963229728653;
      directions_.push_back({r * std::cos(phi), r * std::sin(phi), z});
    }
    std::vector<double> all(size_t(n) * size_t(nsh_));
    for (int i = 0; i < n; ++i)
      lighting::evalSh(order, directions_[size_t(i)], &all[size_t(i) * size_t(nsh_)]);
    for (int l = 0; l <= order; ++l) {
      const int w = 2 * l + 1, first = l * l;
      std::vector<double> ata(size_t(w) * size_t(w), 0.0);
      for (int i = 0; i < n; ++i)
        for (int p = 0; p < w; ++p)
          for (int q = 0; q < w; ++q)
            ata[size_t(p * w + q)] += all[size_t(i) * size_t(nsh_) + size_t(first + p)] *
                                      all[size_t(i) * size_t(nsh_) + size_t(first + q)];
      const std::vector<double> inv = inverse(ata, w);
      std::vector<double> solve(size_t(w) * size_t(n), 0.0);  // w x n
      for (int p = 0; p < w; ++p)
        for (int i = 0; i < n; ++i)
          for (int q = 0; q < w; ++q)
            solve[size_t(p) * size_t(n) + size_t(i)] +=
                inv[size_t(p * w + q)] * all[size_t(i) * size_t(nsh_) + size_t(first + q)];
      solvers_.push_back(std::move(solve));
    }
  }

  int count() const { return nsh_; }

  // The transfer in the object's frame from the cells' visible fractions, for a point whose frame
  // is (east, north, n); `local`, `values` and `y` are scratch (nsh, kDirections, nsh).
  void transfer(const float* visible, size_t cells, const glm::dvec3& east, const glm::dvec3& north,
                const glm::dvec3& n, double* local, double* values, double* y, float* out) const {
    std::fill(local, local + nsh_, 0.0);
    for (size_t c = 0; c < cells; ++c) {
      const double f = visible[c];
      if (f == 0.0) continue;
      const double* w = local_.data() + c * size_t(nsh_);
      for (int m = 0; m < nsh_; ++m) local[m] += f * w[m];
    }
    const int nd = kDirections;
    // values[l][i]: band l of the local function at direction i, seen from the point's frame.
    for (int i = 0; i < nd; ++i) {
      const glm::dvec3& u = directions_[size_t(i)];
      lighting::evalSh(order_, glm::dvec3(glm::dot(u, east), glm::dot(u, north), glm::dot(u, n)),
                       y);
      for (int l = 0; l <= order_; ++l) {
        double sum = 0.0;
        for (int m = l * l; m < (l + 1) * (l + 1); ++m) sum += local[m] * y[m];
        values[size_t(l) * size_t(nd) + size_t(i)] = sum;
      }
    }
    for (int l = 0; l <= order_; ++l) {
      const std::vector<double>& solve = solvers_[size_t(l)];
      const double* v = values + size_t(l) * size_t(nd);
      for (int p = 0; p < 2 * l + 1; ++p) {
        double sum = 0.0;
        const double* row = solve.data() + size_t(p) * size_t(nd);
        for (int i = 0; i < nd; ++i) sum += row[i] * v[i];
        out[l * l + p] = float(sum);
      }
    }
  }

  static constexpr int kDirections = 64;  // ≥ 2 (2l + 1) for every band up to 8: well posed

 private:
  // Inverse of a small symmetric positive definite matrix (Gauss-Jordan with partial pivoting).
  static std::vector<double> inverse(std::vector<double> a, int w) {
    std::vector<double> inv(size_t(w) * size_t(w), 0.0);
    for (int i = 0; i < w; ++i) inv[size_t(i * w + i)] = 1.0;
    for (int c = 0; c < w; ++c) {
      int pivot = c;
      for (int r = c + 1; r < w; ++r)
        if (std::abs(a[size_t(r * w + c)]) > std::abs(a[size_t(pivot * w + c)])) pivot = r;
      for (int k = 0; k < w; ++k) {
        std::swap(a[size_t(c * w + k)], a[size_t(pivot * w + k)]);
        std::swap(inv[size_t(c * w + k)], inv[size_t(pivot * w + k)]);
      }
      const double d = a[size_t(c * w + c)];
      for (int k = 0; k < w; ++k) {
        a[size_t(c * w + k)] /= d;
        inv[size_t(c * w + k)] /= d;
      }
      for (int r = 0; r < w; ++r) {
        if (r == c) continue;
        const double f = a[size_t(r * w + c)];
        if (f == 0.0) continue;
        for (int k = 0; k < w; ++k) {
          a[size_t(r * w + k)] -= f * a[size_t(c * w + k)];
          inv[size_t(r * w + k)] -= f * inv[size_t(c * w + k)];
        }
      }
    }
    return inv;
  }

  int order_ = 0, nsh_ = 1;
  std::vector<double> local_;                 // cells x nsh: ∫_cell cos θ Y_lm dω, local frame
  std::vector<glm::dvec3> directions_;        // kDirections fixed directions
  std::vector<std::vector<double>> solvers_;  // per band: (2l+1) x kDirections
};

}  // namespace

VertexTransfer computeTransfer(const Mesh& mesh, const SurfacePoints& points,
                               const TransferParams& params, const Progress& progress) {
  const EmbreeScene scene(mesh);
  return computeTransfer(mesh, scene, points, params, progress);
}

VertexTransfer computeTransfer(const Mesh& mesh, const EmbreeScene& scene,
                               const SurfacePoints& points, const TransferParams& params,
                               const Progress& progress, const GroundContact* ground) {
  if (ground && ground->empty()) ground = nullptr;
  params.validate();
  COMPOSE_CHECK(mesh.normals.size() == mesh.positions.size());
  const int s = params.grid, k = params.order, r = params.boundaryRays;
  const size_t kk = size_t(k) * size_t(k);
  const int nsh = lighting::shCount(params.shBands);
  const size_t count = points.count();
  const size_t cells = size_t(s) * size_t(s);

  VertexTransfer out;
  out.params = params;
  out.vertexCount = count;
  out.cheb.assign(count * kk, 0.0f);
  out.sh.assign(count * size_t(nsh), 0.0f);
  out.ao.assign(count, 0.0f);
  out.buried.assign(count, 0);
  if (ground) out.aoSelf.assign(count, 0.0f);

  // Rays leave a spot lifted off the surface by 1e-4 of the object's size, and ignore hits
  // closer than that: enough for float positions, far below any feature that casts a shadow.
  const float lift = 1e-4f * points.size, tnear = 1e-5f * points.size;

  const lighting::TchebichefBasis basis(s, k);
  const std::vector<float>& basisRows = basis.matrixF();  // k x s, row-major
  std::vector<float> basisColumns(basisRows.size());      // the same transposed, s x k
  for (int m = 0; m < k; ++m)
    for (int j = 0; j < s; ++j) basisColumns[size_t(j * k + m)] = basisRows[size_t(m * s + j)];
  // A row of wholly visible cells projects onto the columns' sums (added in the same order as
  // the projection below adds them: the same floats).
  std::vector<float> columnSums(static_cast<size_t>(k), 0.0f);
  for (int j = 0; j < s; ++j)
    for (int m = 0; m < k; ++m) columnSums[size_t(m)] += 1.0f * basisColumns[size_t(j * k + m)];
  double y00 = 0.0;  // the constant SH basis function
  lighting::evalSh(0, glm::dvec3(0.0, 1.0, 0.0), &y00);
  // Cell boundaries: altitude θ_i = iπ/(2s) (as the cheb-local grid), azimuth φ_j = 2πj/s.
  std::vector<double> cosBound(size_t(s) + 1), omega(static_cast<size_t>(s)),
      cosine(static_cast<size_t>(s));
  for (int i = 0; i <= s; ++i) cosBound[size_t(i)] = std::cos(i * 0.5 * kPi / s);
  for (int i = 0; i < s; ++i) {
    const double a = cosBound[size_t(i)], b = cosBound[size_t(i) + 1];
    omega[size_t(i)] = 2.0 * kPi / s * (a - b);     // the cell's solid angle
    cosine[size_t(i)] = kPi / s * (a * a - b * b);  // ∫_cell cos θ dω
  }
  // SH transfer above band 0: projected cell by cell (CellHarmonics), not from the rays.
  std::optional<CellHarmonics> cellHarmonics;
  if (nsh > 1) cellHarmonics.emplace(params.shBands, s, cosBound);
  // The same in float for the rays' directions, and each column's first azimuth.
  const std::vector<float> cosBoundF(cosBound.begin(), cosBound.end());
  std::vector<float> colStartCos(static_cast<size_t>(s)), colStartSin(static_cast<size_t>(s));
  for (int j = 0; j < s; ++j) {
    colStartCos[size_t(j)] = float(std::cos(2.0 * kPi * j / s));
    colStartSin[size_t(j)] = float(std::sin(2.0 * kPi * j / s));
  }
  const float cellWidth = float(2.0 * kPi / s);
  // Every direction of cell row i lies within cellRadius[i] of its centre direction (along the
  // meridian, then along the parallel), for the bounding-cone test below.
  std::vector<double> cellRadius(static_cast<size_t>(s)), rowSin(static_cast<size_t>(s)),
      rowCos(static_cast<size_t>(s)), colSin(static_cast<size_t>(s)),
      colCos(static_cast<size_t>(s));
  for (int i = 0; i < s; ++i) {
    cellRadius[size_t(i)] = 0.25 * kPi / s + kPi / s * std::sin((i + 1) * 0.5 * kPi / s) + 1e-6;
    const double theta = (i + 0.5) * 0.5 * kPi / s, phi = 2.0 * kPi * (i + 0.5) / s;
    rowSin[size_t(i)] = std::sin(theta);
    rowCos[size_t(i)] = std::cos(theta);
    colSin[size_t(i)] = std::sin(phi);
    colCos[size_t(i)] = std::cos(phi);
  }
  // The first pass visits the cells in blocks of 4 x 4 neighbours: a batch of 16 rays then holds
  // nearby directions.
  std::vector<int> firstPassOrder;
  firstPassOrder.reserve(cells);
  const int blocksPerRow = (s + 3) / 4;
  for (int cell = 0; cell < 16 * blocksPerRow * blocksPerRow; ++cell) {
    const int block = cell / 16, within = cell % 16;
    const int i = 4 * (block / blocksPerRow) + within / 4;
    const int j = 4 * (block % blocksPerRow) + within % 4;
    if (i < s && j < s) firstPassOrder.push_back(i * s + j);
  }
  // Where each cell's ray stands in the first pass' batch (when no cell is skipped), and the
  // 16 cells whose rays tell a point inside another part (4 rows by 4 columns, staggered).
  std::vector<uint32_t> batchIndexOf(cells);
  for (size_t b = 0; b < firstPassOrder.size(); ++b)
    batchIndexOf[size_t(firstPassOrder[b])] = uint32_t(b);
  std::array<uint32_t, 16> probes{};
  for (int b = 0; b < 16 && s >= 4; ++b) {
    const int i = int((double(b / 4) + 0.5) * s / 4.0);
    const int j = ((b % 4) * s + (b / 4) * s / 8) / 4 % s;
    probes[size_t(b)] = batchIndexOf[size_t(i * s + j)];
  }
  const uint64_t fullRow = s == 64 ? ~uint64_t(0) : (uint64_t(1) << s) - 1u;
  // Each cell's row and column (a division per ray otherwise).
  std::vector<uint8_t> rowOf(cells), columnOf(cells);
  for (size_t c = 0; c < cells; ++c) {
    rowOf[c] = uint8_t(c / size_t(s));
    columnOf[c] = uint8_t(c % size_t(s));
  }
  // The object's bounding sphere, in its own coordinates.
  const glm::dvec3 centre = 0.5 * (glm::dvec3(mesh.boundsMin()) + glm::dvec3(mesh.boundsMax()));
  const double radius =
      0.5 * glm::length(glm::dvec3(mesh.boundsMax()) - glm::dvec3(mesh.boundsMin()));
  std::atomic<size_t> done{0};
  std::atomic<int64_t> rays{0};

  // Per-thread scratch, so that no point allocates.
  struct Scratch {
    std::vector<float> visible;             // per cell: the visible fraction
    std::vector<double> y;                  // SH basis values (CellHarmonics)
    std::vector<double> shLocal, shValues;  // CellHarmonics::transfer's scratch
    std::vector<float> cosines;             // the first pass' cos θ per cell
    std::vector<uint8_t> stratum;       // the first pass' ray's stratum a·r + b within its cell
    std::vector<glm::vec3> directions;  // the first pass' ray per cell (with a ground)
    std::vector<float> visibleSelf;     // per cell: the visible fraction without the ground
    std::vector<double> coneCos;     // per row: cos of the cone's half angle plus the cell's radius
    std::vector<uint64_t> occluded;  // per row: bit j set when the first ray of cell j was blocked
    std::vector<float> firstThrough;  // per cell: what its first ray carries through the object
    std::vector<uint64_t> dimmed;     // per row: bit j set when that ray lost more than a tenth
    std::vector<float> projected;     // s x k: the visible fractions projected on the columns
    // Rays of one trace call and their answers (what each carries through the object), sized
    // for the most a point can have (cells x r², 24 MB at s = 64, r = 16) but not cleared: only
    // the pages written are touched.
    Uncleared<glm::vec3> batch;
    Uncleared<float> through;
    Uncleared<int> batchCell;
    Uncleared<float> batchCos;
  };
  tbb::enumerable_thread_specific<Scratch> scratch([&] {
    Scratch sc;
    sc.visible.resize(cells);
    sc.y.resize(size_t(nsh));
    sc.shLocal.resize(size_t(nsh));
    sc.shValues.resize(size_t(params.shBands + 1) * size_t(CellHarmonics::kDirections));
    sc.cosines.resize(cells);
    sc.stratum.resize(cells);
    if (ground) {
      sc.directions.resize(cells);
      sc.visibleSelf.resize(cells);
    }
    sc.coneCos.resize(size_t(s));
    sc.occluded.resize(size_t(s));
    sc.firstThrough.resize(cells);
    sc.dimmed.resize(size_t(s));
    sc.projected.resize(size_t(s) * size_t(k));
    const size_t most = cells * size_t(r) * size_t(r);
    sc.batch.resize(most);
    sc.through.resize(most);
    sc.batchCell.resize(most);
    sc.batchCos.resize(most);
    return sc;
  });

  parallelFor(
      0, int64_t(count),
      [&](int64_t vi) {
        const size_t v = size_t(vi);
        Scratch& sc = scratch.local();
        const glm::dvec3 n = glm::normalize(glm::dvec3(points.normals[v]));
        glm::dvec3 east, north;
        tangentFrame(n, east, north);
        const glm::vec3 nf(n), eastF(east), northF(north);
        const glm::vec3 origin = points.origin(v, lift);
        std::fill(sc.visible.begin(), sc.visible.end(), 0.0f);
        if (ground) std::fill(sc.visibleSelf.begin(), sc.visibleSelf.end(), 0.0f);
        double shBand0 = 0.0;  // the band-0 SH integral, without CellHarmonics
        int64_t traced = 0;
        // The jitter depends on where the point is, not on its index: a point shared by two
        // triangles' grids gets the same answer on both.
        uint32_t bits[3];
        std::memcpy(bits, &points.positions[v], sizeof bits);
        uint32_t sample = (bits[0] * 0x9E3779B1u) ^ (bits[1] * 0x85EBCA77u) ^
                          (bits[2] * 0xC2B2AE3Du) ^ (params.seed * 0x27D4EB2Fu);

        // A direction in cell (i, j) at fractional position (u, w), uniform in solid angle: its
        // cos θ, then the direction itself (float: the rays are traced in float).
        auto cosineAt = [&](int i, float u) {
          return cosBoundF[size_t(i)] - u * (cosBoundF[size_t(i)] - cosBoundF[size_t(i) + 1]);
        };
        auto direction = [&](int j, float cosT, float w) {
          const float sinT = std::sqrt(std::max(0.0f, 1.0f - cosT * cosT));
          const float delta = w * cellWidth;
          const float cd = std::cos(delta), sd = std::sin(delta);
          const float c = colStartCos[size_t(j)] * cd - colStartSin[size_t(j)] * sd;
          const float sn = colStartSin[size_t(j)] * cd + colStartCos[size_t(j)] * sd;
          return (sinT * c) * eastF + (sinT * sn) * northF + cosT * nf;
        };
        // A ray that reaches the environment: its share of the cell and, for band 0 alone (the
        // ground's transfer), of the SH integral; higher bands are projected cell by cell below.
        // With a ground, `weight` is what the ray's ground point leaves open (1 above the horizon).
        auto seen = [&](int cell, float cosT, float share, float weight) {
          sc.visible[size_t(cell)] += share * weight;
          if (ground) sc.visibleSelf[size_t(cell)] += share;
          if (nsh == 1)
            shBand0 += y00 * double(cosT) * double(share * weight) * omega[rowOf[size_t(cell)]];
        };
        // The rays of one trace call: the first `batched` of sc.batch, batchCell and batchCos
        // (sized for the most a point can have).
        size_t batched = 0;
        // Traces them as one stream; calls answer(index, through), `through` what the ray
        // carries through the object: 0 where it is blocked, 1 where nothing is in the way,
        // 1 - alpha through each semi-transparent layer.
        auto traceBatch = [&](auto&& answer) {
          if (params.selfOcclusion) {
            scene.transmittanceStream(origin, sc.batch.data(), batched, tnear, sc.through.data());
            traced += int64_t(batched);
          } else {
            std::fill(sc.through.begin(), sc.through.begin() + ptrdiff_t(batched), 1.0f);
          }
          for (size_t b = 0; b < batched; ++b) answer(b, sc.through[b]);
        };

        // A point outside the object's bounding sphere (a ground point) can only be shadowed
        // from within the cone around the sphere: cells wholly outside it are visible untraced.
        const glm::dvec3 toCentre = centre - glm::dvec3(points.positions[v]);
        const double distance = glm::length(toCentre);
        const bool outside = distance > radius * 1.0001;
        const glm::dvec3 axis = outside ? toCentre / distance : glm::dvec3(0.0);
        const double coneHalf = outside ? std::asin(std::min(1.0, radius / distance)) : kPi;
        // In local coordinates (east, north, normal), for a dot product per cell.
        const glm::dvec3 axisLocal(glm::dot(axis, east), glm::dot(axis, north), glm::dot(axis, n));
        if (outside)
          for (int i = 0; i < s; ++i)
            sc.coneCos[size_t(i)] = coneHalf + cellRadius[size_t(i)] < kPi
                                        ? std::cos(coneHalf + cellRadius[size_t(i)])
                                        : -2.0;  // the cone covers the whole row

        // Pass 1: one jittered ray per cell.
        batched = 0;
        const uint32_t firstSample = sample;
        sample += uint32_t(s * s);
        std::fill(sc.occluded.begin(), sc.occluded.end(), uint64_t(0));
        std::fill(sc.firstThrough.begin(), sc.firstThrough.end(), 1.0f);
        std::fill(sc.dimmed.begin(), sc.dimmed.end(), uint64_t(0));
        for (const int cell : firstPassOrder) {
          const int i = rowOf[size_t(cell)], j = columnOf[size_t(cell)];
          const uint32_t at = firstSample + uint32_t(cell);
          const float u = hash01(2 * at), w = hash01(2 * at + 1);
          const float cosT = cosineAt(i, u);
          sc.cosines[size_t(cell)] = cosT;
          sc.stratum[size_t(cell)] =
              uint8_t(std::min(r - 1, int(u * float(r))) * r + std::min(r - 1, int(w * float(r))));
          if (ground) sc.directions[size_t(cell)] = direction(j, cosT, w);
          // Wholly outside the cone: cannot see the object.
          if (outside) {
            const glm::dvec3 c(rowSin[size_t(i)] * colCos[size_t(j)],
                               rowSin[size_t(i)] * colSin[size_t(j)], rowCos[size_t(i)]);
            if (glm::dot(c, axisLocal) < sc.coneCos[size_t(i)]) continue;
          }
          sc.batch[batched] = ground ? sc.directions[size_t(cell)] : direction(j, cosT, w);
          sc.batchCell[batched++] = cell;
        }
        // For finding shadow edges a cell is blocked when its ray carries less than half, and
        // dimmed when it carries less than 0.9 (behind a faint semi-transparent surface): a
        // change of either between neighbours is an edge. (On an opaque object both are the same.)
        traceBatch([&](size_t index, float through) {
          const int cell = sc.batchCell[index];
          sc.firstThrough[size_t(cell)] = through;
          const uint64_t bit = uint64_t(1) << columnOf[size_t(cell)];
          if (through < 0.5f) sc.occluded[rowOf[size_t(cell)]] |= bit;
          if (through < 0.9f) sc.dimmed[rowOf[size_t(cell)]] |= bit;
        });
        // Inside another part of the object (transfer.h)? Every first ray blocked, and most of
        // 16 of them, spread over the hemisphere, by a surface met from behind.
        if (params.selfOcclusion && batched == cells && cells >= 16 &&
            std::all_of(sc.firstThrough.begin(), sc.firstThrough.end(),
                        [](float f) { return f == 0.0f; })) {
          glm::vec3 origins[16], directions[16];
          EmbreeScene::Hit hits[16];
          for (size_t b = 0; b < 16; ++b) {
            origins[b] = origin;
            directions[b] = sc.batch[probes[b]];
          }
          scene.intersect16(origins, directions, 0xFFFFu, hits, tnear);
          traced += 16;
          int behind = 0;
          for (size_t b = 0; b < 16; ++b) {
            if (!hits[b].found) continue;
            const uint32_t* corner = &mesh.indices[3 * size_t(hits[b].triangle)];
            const glm::vec3 normal = (1.0f - hits[b].u - hits[b].v) * mesh.normals[corner[0]] +
                                     hits[b].u * mesh.normals[corner[1]] +
                                     hits[b].v * mesh.normals[corner[2]];
            behind += int(glm::dot(normal, directions[b]) > 0.0f);
          }
          out.buried[v] = uint8_t(behind >= 12);
        }

        // Cells whose ray disagrees with one of its eight neighbours' (the azimuth wraps around)
        // lie on a shadow's edge: they get r x r stratified rays, the first ray standing for its
        // own stratum; every other cell keeps its one ray. Per row, bit j of `edge` is set for
        // such a cell; around the pole (row 0) every cell is a neighbour of every other.
        auto rotateUp = [&](uint64_t x) {  // bit j to j + 1, bit s - 1 to 0
          return ((x << 1) | (x >> (s - 1))) & fullRow;
        };
        auto rotateDown = [&](uint64_t x) {  // bit j to j - 1, bit 0 to s - 1
          return ((x >> 1) | (x << (s - 1))) & fullRow;
        };
        batched = 0;
        const float share = 1.0f / float(r * r);
        for (int i = 0; i < s; ++i) {
          const uint64_t row = sc.occluded[size_t(i)], dim = sc.dimmed[size_t(i)];
          uint64_t edge = 0;
          for (int ii = std::max(0, i - 1); ii <= std::min(s - 1, i + 1); ++ii) {
            const uint64_t other = sc.occluded[size_t(ii)], otherDim = sc.dimmed[size_t(ii)];
            edge |= (row ^ other) | (row ^ rotateUp(other)) | (row ^ rotateDown(other));
            edge |= (dim ^ otherDim) | (dim ^ rotateUp(otherDim)) | (dim ^ rotateDown(otherDim));
          }
          if (i == 0 && ((row != 0 && row != fullRow) || (dim != 0 && dim != fullRow)))
            edge = fullRow;
          if (r == 1) edge = 0;
          for (int j = 0; j < s; ++j) {
            const int cell = i * s + j;
            const float through = sc.firstThrough[size_t(cell)];
            const float weight = ground && through > 0.0f
                                     ? ground->weight(origin, sc.directions[size_t(cell)])
                                     : 1.0f;
            if (!((edge >> j) & 1u)) {
              if (through > 0.0f) seen(cell, sc.cosines[size_t(cell)], through, weight);
              continue;
            }
            if (through > 0.0f) seen(cell, sc.cosines[size_t(cell)], share * through, weight);
            const int own = sc.stratum[size_t(cell)];
            for (int a = 0; a < r; ++a) {
              for (int b = 0; b < r; ++b, ++sample) {
                if (a * r + b == own) continue;
                const float cosT = cosineAt(i, (float(a) + hash01(2 * sample)) / float(r));
                sc.batch[batched] =
                    direction(j, cosT, (float(b) + hash01(2 * sample + 1)) / float(r));
                sc.batchCell[batched] = cell;
                sc.batchCos[batched++] = cosT;
              }
            }
          }
        }
        traceBatch([&](size_t index, float through) {
          if (!(through > 0.0f)) return;
          const float weight = ground ? ground->weight(origin, sc.batch[index]) : 1.0f;
          seen(sc.batchCell[index], sc.batchCos[index], share * through, weight);
        });

        // AO from the visible fractions and each cell's exact cosine integral, so that a fully
        // visible point has AO 1.
        double ao = 0.0;
        for (int i = 0; i < s; ++i) {
          double rowVisible = 0.0;
          for (int j = 0; j < s; ++j) rowVisible += double(sc.visible[size_t(i * s + j)]);
          ao += rowVisible * cosine[size_t(i)];
        }
        // The k x k moments (tchebichef.h's moments2d, in float without allocating): first
        // along the azimuth, then along the altitude.
        // Rows wholly hidden (nothing to add) and rows wholly visible (the column sums) are
        // not projected cell by cell.
        float* projected = sc.projected.data();
        uint64_t hiddenRows = 0;
        for (int i = 0; i < s; ++i) {
          const float* f = sc.visible.data() + size_t(i * s);
          float* gi = projected + size_t(i * k);
          bool hidden = true, open = true;
          for (int j = 0; j < s; ++j) {
            hidden = hidden && f[j] == 0.0f;
            open = open && f[j] == 1.0f;
          }
          if (hidden) {
            hiddenRows |= uint64_t(1) << i;
            continue;
          }
          if (open) {
            std::copy(columnSums.begin(), columnSums.end(), gi);
            continue;
          }
          std::fill(gi, gi + k, 0.0f);
          for (int j = 0; j < s; ++j) {
            const float fj = f[j];
            if (fj == 0.0f) continue;  // hidden: adds nothing
            const float* q = basisColumns.data() + size_t(j * k);
            for (int m = 0; m < k; ++m) gi[m] += fj * q[m];
          }
        }
        float* moments = out.cheb.data() + v * kk;
        for (int m = 0; m < k; ++m) {
          const float* p = basisRows.data() + size_t(m * s);
          float* tm = moments + size_t(m * k);
          std::fill(tm, tm + k, 0.0f);
          for (int i = 0; i < s; ++i) {
            if ((hiddenRows >> i) & 1u) continue;
            const float pi = p[i];
            const float* gi = projected + size_t(i * k);
            for (int c = 0; c < k; ++c) tm[c] += pi * gi[c];
          }
        }
        if (cellHarmonics) {
          cellHarmonics->transfer(sc.visible.data(), cells, east, north, n, sc.shLocal.data(),
                                  sc.shValues.data(), sc.y.data(), &out.sh[v * size_t(nsh)]);
        } else {
          out.sh[v * size_t(nsh)] = float(shBand0);  // nsh == 1
        }
        out.ao[v] = float(ao / kPi);
        if (ground) {
          double self = 0.0;
          for (int i = 0; i < s; ++i) {
            double rowVisible = 0.0;
            for (int j = 0; j < s; ++j) rowVisible += double(sc.visibleSelf[size_t(i * s + j)]);
            self += rowVisible * cosine[size_t(i)];
          }
          out.aoSelf[v] = float(self / kPi);
        }
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
  if (mesh.hasCutouts()) return false;  // seen through its holes, its inside can be shadowed
  // Corners identified by position, so that vertices split by normals or texture seams count as
  // one: positions snapped to a millionth of the object's size (an exporter's seam vertices differ
  // in the last bits; a pair the snapping splits leaves the mesh "open", which is the safe answer).
  const glm::vec3 size = mesh.boundsMax() - mesh.boundsMin();
  const double snap = std::max(1e-30, 1e-6 * double(std::max({size.x, size.y, size.z})));
  std::map<std::array<int64_t, 3>, uint32_t> ids;
  std::vector<uint32_t> id(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const glm::vec3& p = mesh.positions[i];
    auto cell = [&](float v) { return std::llround(std::clamp(double(v) / snap, -4e18, 4e18)); };
    const std::array<int64_t, 3> key = {cell(p.x), cell(p.y), cell(p.z)};
    id[i] = ids.try_emplace(key, uint32_t(ids.size())).first->second;
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
  if (!mesh.sides.empty()) {  // which triangles rays meet from their front only
    h.bytes("sides");
    h.data(mesh.sides.data(), mesh.sides.size());
  }
  // Where it is cut out, what cuts it (the rest of the materials does not change visibility).
  if (mesh.hasCutouts()) {
    h.bytes("cutouts");
    if (!mesh.alphas.empty()) {
      h.bytes("vertex alphas");
      h.floats(std::span<const float>(mesh.alphas.data(), mesh.alphas.size()));
    }
    if (!mesh.texcoords.empty())
      h.floats(std::span<const float>(&mesh.texcoords[0].x, 2 * mesh.texcoords.size()));
    for (uint32_t m : mesh.triangleMaterial) h.word(m);
    for (const Material& m : mesh.materials) {
      h.floats(std::span<const float>(&m.alphaCutoff, 1));
      h.word(m.blend ? 1u : 0u);
      h.floats(std::span<const float>(&m.baseAlpha, 1));
      h.word(uint32_t(m.texture));
      h.floats(std::span<const float>(&m.uvTransform[0][0], 9));
    }
    for (const Texture& t : mesh.textures) {
      h.word(uint32_t(t.alpha.width));
      h.word(uint32_t(t.alpha.height));
      h.word(uint32_t(t.wrapU));
      h.word(uint32_t(t.wrapV));
      if (t.nearest) h.bytes("nearest");  // the alpha magnified as blocks of texels
      h.floats(t.alpha.pixels);
    }
  }
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

std::vector<SourceFrame> sourceFrames(const std::vector<lighting::LightSource>& sources,
                                      const glm::mat3& envFromObject) {
  const glm::mat3 objectFromEnv = glm::transpose(envFromObject);
  std::vector<SourceFrame> frames(sources.size());
  for (size_t i = 0; i < sources.size(); ++i) {
    const glm::dvec3 d = glm::normalize(glm::dvec3(sources[i].direction));
    const double lat = std::asin(std::clamp(d.y, -1.0, 1.0)), lon = std::atan2(d.x, d.z);
    const glm::dvec3 east(std::cos(lon), 0.0, -std::sin(lon));
    const glm::dvec3 north(-std::sin(lon) * std::sin(lat), std::cos(lat),
                           -std::cos(lon) * std::sin(lat));
    frames[i] = {objectFromEnv * glm::vec3(d), objectFromEnv * glm::vec3(east),
                 objectFromEnv * glm::vec3(north), sources[i].halfLatitude,
                 float(sources[i].halfLongitude * std::cos(lat))};
  }
  return frames;
}

SourceVisibility traceSources(const SurfacePoints& points, const EmbreeScene& scene,
                              const std::vector<lighting::LightSource>& sources,
                              const glm::mat3& envFromObject, int raysPerSource) {
  SourceVisibility out;
  const size_t count = points.count();
  out.count = sources.size();
  out.visible.assign(count * sources.size(), 0.0f);
  if (sources.empty()) return out;
  // Four directions per source: a 2 x 2 stratification of its latitude/longitude extent,
  // jittered per point. The frame (east, north) of each source turns the offsets into directions.
  COMPOSE_CHECK(raysPerSource == 1 || raysPerSource == 2 || raysPerSource == 4);
  const int kPerSource = raysPerSource;
  const int cols = kPerSource >= 2 ? 2 : 1, rows = kPerSource / cols;
  const std::vector<SourceFrame> frames = sourceFrames(sources, envFromObject);
  // Sources near each other in the sky traced one after another: neighbouring rays of a point's
  // stream then hold nearby directions.
  std::vector<glm::vec3> directions(sources.size());
  for (size_t i = 0; i < sources.size(); ++i) directions[i] = sources[i].direction;
  const std::vector<uint32_t> sourceOrder = spatialOrder(directions);
  // Each source's angular radius bounds its directions' angle from its centre (the offsets
  // across its extent are tangent to the sphere at the centre: the angle is at most their
  // length), as its cosine and sine, widened by a margin for rounding. A source wider than a
  // quarter turn gets values for which the test below never holds.
  std::vector<float> cosRadius(sources.size(), -2.0f), sinRadius(sources.size(), 2.0f);
  for (size_t i = 0; i < sources.size(); ++i) {
    const double r = std::hypot(double(frames[i].halfLat), double(frames[i].halfLon)) + 1e-4;
    if (r >= 0.5 * kPi) continue;
    cosRadius[i] = float(std::cos(r));
    sinRadius[i] = float(std::sin(r));
  }
  const float lift = 1e-4f * points.size, tnear = 1e-5f * points.size;
  std::atomic<int64_t> rays{0};
  parallelFor(
      0, int64_t(count),
      [&](int64_t vi) {
        const size_t v = size_t(vi);
        const glm::vec3 n = points.normals[v];
        const glm::vec3 origin = points.origin(v, lift);
        // The point's rays, traced together as one stream at the end.
        thread_local std::vector<glm::vec3> batch;
        thread_local std::vector<uint32_t> index;
        thread_local std::vector<float> through;
        batch.clear();
        index.clear();
        float* seen = out.visible.data() + v * sources.size();
        // Outside the bounding sphere, only directions within its cone can be blocked.
        const glm::vec3 toCentre = points.centre - points.positions[v];
        const float distance = glm::length(toCentre);
        const bool outside = distance > points.radius * 1.0001f;
        const float cosCone =
            outside ? std::sqrt(std::max(
                          0.0f, 1.0f - (points.radius * points.radius) / (distance * distance)))
                    : -2.0f;
        const glm::vec3 axis = outside ? toCentre / distance : glm::vec3(0.0f);
        const float sinCone = std::sqrt(std::max(0.0f, 1.0f - cosCone * cosCone));
        uint32_t bits[3];
        std::memcpy(bits, &points.positions[v], sizeof bits);
        const uint32_t firstSample =
            (bits[0] * 0x9E3779B1u) ^ (bits[1] * 0x85EBCA77u) ^ (bits[2] * 0xC2B2AE3Du);
        for (const uint32_t i : sourceOrder) {
          const SourceFrame& f = frames[i];
          // Wholly below the point's horizon (its centre lower than its radius): no ray of it
          // would be traced, and it gives no light.
          if (glm::dot(n, f.centre) < -sinRadius[i]) continue;
          // A source wholly outside the cone (its centre further from the axis than the cone's
          // half-angle plus its radius) and wholly above the horizon (its centre higher than its
          // radius) is seen whole, as each of its rays would say, without making them.
          if (outside &&
              glm::dot(f.centre, axis) < cosCone * cosRadius[i] - sinCone * sinRadius[i] &&
              glm::dot(n, f.centre) > sinRadius[i]) {
            seen[i] = 1.0f;
            continue;
          }
          for (int k = 0; k < kPerSource; ++k) {
            // The point's own sequence of draws, one per (source, direction).
            const uint32_t sample = firstSample + i * uint32_t(kPerSource) + uint32_t(k);
            const float a = (float(k % cols) + hash01(2 * sample)) / float(cols) - 0.5f;
            const float b = (float(k / cols) + hash01(2 * sample + 1)) / float(rows) - 0.5f;
            const glm::vec3 d = f.direction(a, b);
            if (glm::dot(n, d) <= 0.0f) continue;  // below the horizon: no light anyway
            if (outside && glm::dot(d, axis) < cosCone) {
              seen[i] += 1.0f / float(kPerSource);  // cannot meet the object
              continue;
            }
            batch.push_back(d);
            index.push_back(i);
          }
        }
        // What gets through: a semi-transparent surface lets 1 - alpha of the source by.
        through.resize(batch.size());
        scene.transmittanceStream(origin, batch.data(), batch.size(), tnear, through.data(), 1e30f,
                                  true);
        for (size_t b = 0; b < batch.size(); ++b) seen[index[b]] += through[b] / float(kPerSource);
        rays += int64_t(batch.size());
      },
      256);
  out.rays = rays;
  return out;
}

bool VertexIrradiance::indexPartial() {
  partialFirst.assign(sourcePartial.size() + 1, 0);
  uint64_t total = 0;
  for (size_t p = 0; p < sourcePartial.size(); ++p) {
    partialFirst[p] = uint32_t(total);
    total += uint64_t(std::popcount(sourcePartial[p]));
    if (total > std::numeric_limits<uint32_t>::max()) return false;
  }
  partialFirst.back() = uint32_t(total);
  if (partialFraction.size() != total) return false;
  for (const float f : partialFraction)
    if (!(f > 0.0f && f < 1.0f)) return false;
  return true;
}

int64_t refineSourcePenumbrae(const Mesh& mesh, const SurfacePoints& points,
                              const EmbreeScene& scene,
                              const std::vector<lighting::LightSource>& sources,
                              const glm::mat3& envFromObject, SourceVisibility& visibility) {
  const size_t n = sources.size(), count = points.count();
  if (n == 0) return 0;
  COMPOSE_CHECK(n <= 64 && visibility.count == n && visibility.visible.size() == count * n);
  // Per point, the sources a cell around it sees differently.
  std::vector<uint64_t> seen(count, 0), again(count, 0);
  for (size_t p = 0; p < count; ++p) {
    const float* v = visibility.visible.data() + p * n;
    for (size_t i = 0; i < n; ++i) seen[p] |= uint64_t(v[i] >= 0.5f) << i;
  }
  const size_t triangles = mesh.triangleCount();
  for (size_t t = 0; t < triangles; ++t) {
    const int L = points.level[t];
    auto cell = [&](uint32_t a, uint32_t b, uint32_t c) {
      const uint64_t differ = (seen[a] ^ seen[b]) | (seen[a] ^ seen[c]);
      again[a] |= differ, again[b] |= differ, again[c] |= differ;
    };
    for (int j = 0; j < L; ++j) {
      for (int i = 0; i + j < L; ++i) {
        const uint32_t t32 = uint32_t(t);
        cell(points.gridPoint(mesh, t32, i, j), points.gridPoint(mesh, t32, i + 1, j),
             points.gridPoint(mesh, t32, i, j + 1));
        if (i + j + 1 < L)
          cell(points.gridPoint(mesh, t32, i + 1, j + 1), points.gridPoint(mesh, t32, i, j + 1),
               points.gridPoint(mesh, t32, i + 1, j));
      }
    }
  }
  const std::vector<SourceFrame> frames = sourceFrames(sources, envFromObject);
  const float lift = 1e-4f * points.size, tnear = 1e-5f * points.size;
  constexpr int kStrata = 4;  // 2 x 2 across the source's extent
  std::atomic<int64_t> rays{0};
  parallelFor(
      0, int64_t(count),
      [&](int64_t pi) {
        const size_t p = size_t(pi);
        uint64_t sourcesAgain = again[p];
        if (sourcesAgain == 0) return;
        const glm::vec3 normal = points.normals[p];
        const glm::vec3 origin = points.origin(p, lift);
        thread_local std::vector<glm::vec3> batch;
        thread_local std::vector<uint32_t> index;
        thread_local std::vector<float> through;
        batch.clear();
        index.clear();
        uint32_t bits[3];
        std::memcpy(bits, &points.positions[p], sizeof bits);
        // Draws of their own (another stream than traceSources' first ray).
        const uint32_t firstSample =
            ((bits[0] * 0x9E3779B1u) ^ (bits[1] * 0x85EBCA77u) ^ (bits[2] * 0xC2B2AE3Du)) +
            0x68E31DA4u;
        float* visible = visibility.visible.data() + p * n;
        for (; sourcesAgain != 0; sourcesAgain &= sourcesAgain - 1) {
          const uint32_t i = uint32_t(std::countr_zero(sourcesAgain));
          visible[i] = 0.0f;
          for (int k = 0; k < kStrata; ++k) {
            const uint32_t sample = firstSample + i * uint32_t(kStrata) + uint32_t(k);
            const float a = (float(k % 2) + hash01(2 * sample)) / 2.0f - 0.5f;
            const float b = (float(k / 2) + hash01(2 * sample + 1)) / 2.0f - 0.5f;
            const glm::vec3 d = frames[i].direction(a, b);
            if (glm::dot(normal, d) <= 0.0f) continue;  // below the horizon: no light anyway
            batch.push_back(d);
            index.push_back(i);
          }
        }
        through.resize(batch.size());
        scene.transmittanceStream(origin, batch.data(), batch.size(), tnear, through.data(), 1e30f,
                                  true);
        for (size_t b = 0; b < batch.size(); ++b) visible[index[b]] += through[b] / float(kStrata);
        rays += int64_t(batch.size());
      },
      256);
  visibility.rays += rays;
  return rays;
}

VertexIrradiance shadeVertices(const SurfacePoints& points, const glm::mat3& envFromObject,
                               const ShadowInputs& in) {
  COMPOSE_CHECK(in.shadowLighting != nullptr);
  const ShadowMethod method = in.method;
  const size_t count = points.count();
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
    COMPOSE_CHECK(in.sourceVisibility &&
                  in.sourceVisibility->visible.size() == count * in.sources.size());

  VertexIrradiance out;
  out.shadowed.resize(count);
  out.unshadowed.resize(count);
  if (withSources && method != ShadowMethod::AmbientOcclusion) {
    COMPOSE_CHECK(in.sources.size() <= 64);
    out.sourceCount = in.sources.size();
    out.sourceSeen.resize(count);
    out.sourcePartial.resize(count);
  }
  // (point, fraction) of the sources seen in part, each point's in the order of its sources.
  std::vector<std::pair<uint32_t, float>> fractions;
  std::mutex fractionsMutex;
  std::atomic<int> clamped{0};
  parallelFor(
      0, int64_t(count),
      [&](int64_t vi) {
        const size_t v = size_t(vi);
        const glm::dvec3 nObj = glm::normalize(glm::dvec3(points.normals[v]));
        const glm::vec3 nEnv = glm::normalize(envFromObject * glm::vec3(nObj));
        glm::vec3 unshadowed = glm::max(in.shadowLighting->irradiance(nEnv), glm::vec3(0.0f));
        for (const lighting::LightSource& source : in.sources)
          unshadowed += std::max(0.0f, glm::dot(nEnv, source.direction)) * source.power;
        glm::vec3 shadowed(0.0f);
        switch (method) {
          case ShadowMethod::Chebyshev: {
            const int K = p.order;
            const double lat = std::asin(std::clamp(nObj.y, -1.0, 1.0));
            shadowed = cheb->shade(lat, longitudeOf(nObj) + yaw,
                                   in.transfer->cheb.data() + v * size_t(K) * size_t(K), K);
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
          const float* seen = in.sourceVisibility->visible.data() + v * in.sources.size();
          uint64_t bits = 0, partial = 0;
          for (size_t i = 0; i < in.sources.size(); ++i) {
            bits |= uint64_t(seen[i] >= 0.5f) << i;
            partial |= uint64_t(seen[i] > 0.0f && seen[i] < 1.0f) << i;
            if (seen[i] <= 0.0f) continue;
            const float c = glm::dot(nEnv, in.sources[i].direction);
            if (c > 0.0f) shadowed += seen[i] * c * in.sources[i].power;
          }
          out.sourceSeen[v] = bits;
          out.sourcePartial[v] = partial;
          if (partial != 0) {
            std::lock_guard<std::mutex> lock(fractionsMutex);
            for (uint64_t m = partial; m != 0; m &= m - 1)
              fractions.push_back({uint32_t(v), seen[std::countr_zero(m)]});
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
  if (!out.sourcePartial.empty()) {
    // In the order of the points (stable: each point's own stay in the order of its sources).
    std::stable_sort(fractions.begin(), fractions.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    out.partialFraction.reserve(fractions.size());
    for (const auto& f : fractions) out.partialFraction.push_back(f.second);
    COMPOSE_CHECK(out.indexPartial());
  }
  return out;
}

}  // namespace compose::render
