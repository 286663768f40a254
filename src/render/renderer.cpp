#include "render/renderer.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <tuple>

#include <tbb/parallel_invoke.h>

#include <glm/geometric.hpp>
#include <glm/matrix.hpp>

#include "core/error.h"
#include "core/hash.h"
#include "core/parallel.h"

namespace compose::render {

namespace {

// Channel offsets in the AOV image.
enum Aov { kN = 0, kP = 3, kDepth = 6, kAlbedo = 7, kIrradiance = 10, kShadowed = 13, kAo = 16 };
constexpr int kAovChannels = 17;

// The screen rectangle that can hold the object: the projection of points along the world
// bounding box's edges (a distorted lens bends them), padded by two pixels; the whole frame when
// some of the box is behind the camera. Coordinates are clamped before they become integers.
void screenRectangle(const calib::PlateCamera& camera, const glm::dvec3& lo, const glm::dvec3& hi,
                     int& x0, int& y0, int& x1, int& y1) {
  x0 = 0, y0 = 0, x1 = camera.width, y1 = camera.height;
  glm::dvec2 smin(std::numeric_limits<double>::max()), smax(-std::numeric_limits<double>::max());
  constexpr int kSteps = 16;
  for (int c = 0; c < 8; ++c) {
    const glm::dvec3 a((c & 1) ? hi.x : lo.x, (c & 2) ? hi.y : lo.y, (c & 4) ? hi.z : lo.z);
    for (int axis = 0; axis < 3; ++axis) {
      if (c & (1 << axis)) continue;  // each edge once, from its low corner
      glm::dvec3 b = a;
      b[axis] = axis == 0 ? hi.x : axis == 1 ? hi.y : hi.z;
      for (int s = 0; s <= kSteps; ++s) {
        glm::dvec2 px;
        if (!camera.project(a + (b - a) * (double(s) / kSteps), px)) return;  // behind: all
        smin = glm::min(smin, px);
        smax = glm::max(smax, px);
      }
    }
  }
  constexpr double kLimit = 1e7;  // far outside any image, well inside int
  auto toInt = [&](double v) { return int(std::clamp(v, -kLimit, kLimit)); };
  x0 = std::clamp(toInt(std::floor(smin.x)) - 2, 0, camera.width);
  y0 = std::clamp(toInt(std::floor(smin.y)) - 2, 0, camera.height);
  x1 = std::clamp(toInt(std::ceil(smax.x)) + 2, 0, camera.width);
  y1 = std::clamp(toInt(std::ceil(smax.y)) + 2, 0, camera.height);
  x1 = std::max(x0, x1);
  y1 = std::max(y0, y1);
}

// Camera rays for the render loop, in the object's coordinates. A rectilinear lens without
// distortion maps a pixel to a direction linearly before normalising, so a ray is a few
// multiply-adds: the rays of PlateCamera::ray up to rounding. Any other lens goes through
// PlateCamera::ray. Every ray starts at the camera's centre.
class CameraRays {
 public:
  CameraRays(const calib::PlateCamera& camera, const glm::dmat4& objectFromWorld)
      : camera_(camera),
        objectFromWorld_(objectFromWorld),
        linear_(camera.lens.projection == calib::Projection::Rectilinear &&
                !camera.lens.hasDistortion()) {
    const glm::dmat3 r(camera.worldFromCamera);
    const calib::Lens& lens = camera.lens;
    // World direction ∝ r · ((px - cx) / fx, -(py - cy) / fy, -1).
    perX_ = r[0] / lens.fx;
    perY_ = -r[1] / lens.fy;
    base_ = -r[0] * (lens.cx / lens.fx) + r[1] * (lens.cy / lens.fy) - r[2];
    originObject_ = glm::vec3(objectFromWorld * glm::dvec4(camera.position(), 1.0));
  }
  // The ray through pixel position (px, py): world direction, and origin and direction in the
  // object's coordinates (the same ray parameter on both sides).
  bool ray(double px, double py, glm::dvec3& direction, glm::vec3& originObject,
           glm::vec3& directionObject) const {
    if (linear_) {
      direction = glm::normalize(base_ + px * perX_ + py * perY_);
    } else {
      glm::dvec3 origin;
      if (!camera_.ray(px, py, origin, direction)) return false;
    }
    originObject = originObject_;
    directionObject = glm::vec3(objectFromWorld_ * direction);
    return true;
  }

 private:
  const calib::PlateCamera& camera_;
  glm::dmat3 objectFromWorld_;  // directions only: the origin is transformed once
  bool linear_;
  glm::dvec3 perX_{0.0}, perY_{0.0}, base_{0.0};
  glm::vec3 originObject_{0.0f};
};

// The pixels of the traced rectangle [x0, x0 + w) x [y0, y0 + h) that a triangle's projection
// may overlap (row-major, 1 where a camera ray may hit the object): a small triangle marks its
// bounding box, a larger one is clipped to each pixel row it crosses and marks the row's pixels
// under its extent there, both widened by a twentieth of a pixel for rounding in the rays and in
// Embree's test. A pixel no triangle reaches cannot be hit, so its rays need not be traced.
// Empty (trace every pixel) when the lens bends straight edges or a corner is not in front of the
// camera: a projected triangle is then not the triangle of its projected corners.
//
// What adaptive sampling needs to know of each pixel of the rectangle beyond its samples.
struct PixelSurfaces {
  // The nearest surface: the largest 1 / depth (depth along the camera's axis) any triangle
  // reaches within the pixel, 0 where none does. The inverse depth of a plane is affine in the
  // image, so a triangle's largest over a pixel is at one of the pixel's corners, clamped to its
  // corners' range (a sliver or a clipped span may reach past them).
  std::vector<float> nearest;
  // 1 where an edge passes across which coverage or shading can jump (markEdges): a contour, a
  // boundary, a change of material, a crease or seam, a fold of more than 25°. A gap between
  // parts, or a groove, narrower than the corner samples' spacing is bounded by such edges.
  std::vector<uint8_t> edges;
};

// Marks the pixels of the edges across which a pixel's coverage or shading can jump
// (PixelSurfaces::edges), points every tenth of a pixel along each (clipped to the rectangle),
// and the pixels within a twentieth of a pixel of each point. Corners are identified by position
// (vertices split for normals or texture coordinates are one corner) and side (a back side's own
// vertices, Mesh::sides, are corners of their own). An edge is marked when:
// - it is a contour: its two triangles' third corners project on the same side of it (one folds
//   behind the other as seen from the camera; this holds whatever their winding), or it has one
//   triangle (a boundary) or more than two;
// - its triangles have different materials, or split vertices there (a crease of the normals, a
//   seam of texture coordinates or colours);
// - its triangles meet at more than 25° (a groove or a ridge narrower than the samples' spacing).
void markEdges(const Mesh& mesh, const std::vector<glm::dvec2>& projected, int x0, int y0, int w,
               int h, std::vector<uint8_t>& marked) {
  marked.assign(size_t(w) * size_t(h), 0);
  const size_t n = mesh.positions.size();
  std::vector<uint32_t> order(n), corner(n);
  for (size_t v = 0; v < n; ++v) order[v] = uint32_t(v);
  // The back sides (Mesh::sides) have their own vertices: their corners are their own, so that
  // an edge inside a surface seen from both sides is one side's edge between two triangles.
  std::vector<uint8_t> back(mesh.sides.empty() ? 0 : n, 0);
  for (size_t t = 0; t < mesh.sides.size(); ++t)
    if (mesh.sides[t] == Mesh::kBackSide)
      for (size_t k = 0; k < 3; ++k) back[mesh.indices[3 * t + k]] = 1;
  auto key = [&](uint32_t v) {
    const glm::vec3& p = mesh.positions[v];
    return std::make_tuple(back.empty() ? uint8_t(0) : back[v], p.x, p.y, p.z);
  };
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key(a) < key(b); });
  for (size_t i = 0; i < n; ++i)
    corner[order[i]] =
        i > 0 && key(order[i]) == key(order[i - 1]) ? corner[order[i - 1]] : order[i];
  // The edges that reach the rectangle (widened by a pixel), keyed by their corners: triangle t's
  // edge k runs from its vertex k to vertex k + 1.
  struct Edge {
    uint64_t corners;
    uint32_t triangle, k;
  };
  const double left = x0 - 1.0, right = x0 + w + 1.0, top = y0 - 1.0, bottom = y0 + h + 1.0;
  auto reaches = [&](uint32_t a, uint32_t b) {
    const glm::dvec2 pa = projected[a], pb = projected[b];
    return !(std::max(pa.x, pb.x) < left || std::min(pa.x, pb.x) > right ||
             std::max(pa.y, pb.y) < top || std::min(pa.y, pb.y) > bottom);
  };
  // Sorted by corners, then triangle: counted into buckets by the lower corner (in triangle
  // order), then each bucket, a vertex's few edges, sorted by the other corner. A general sort of
  // the bunny's 209,000 edges took half the time of this function.
  std::vector<uint32_t> bucket(n + 1, 0);
  auto forEachEdge = [&](auto&& f) {
    for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
      const uint32_t* v = &mesh.indices[t];
      for (uint32_t k = 0; k < 3; ++k) {
        const uint32_t a = v[k], b = v[(k + 1) % 3];
        const uint32_t ca = corner[a], cb = corner[b];
        if (ca != cb && reaches(a, b)) f(std::min(ca, cb), std::max(ca, cb), uint32_t(t / 3), k);
      }
    }
  };
  forEachEdge([&](uint32_t low, uint32_t, uint32_t, uint32_t) { ++bucket[low + 1]; });
  for (size_t v = 0; v < n; ++v) bucket[v + 1] += bucket[v];
  std::vector<Edge> edges(bucket[n]);
  std::vector<uint32_t> fill(bucket.begin(), bucket.end() - 1);
  forEachEdge([&](uint32_t low, uint32_t high, uint32_t triangle, uint32_t k) {
    edges[fill[low]++] = {uint64_t(low) << 32 | high, triangle, k};
  });
  for (size_t v = 0; v < n; ++v) {
    // Triangle order within a bucket is kept: a stable sort by the upper corner, by insertion for
    // the few edges of a usual vertex.
    Edge* const first = edges.data() + bucket[v];
    Edge* const last = edges.data() + bucket[v + 1];
    if (last - first > 32) {
      std::stable_sort(first, last,
                       [](const Edge& p, const Edge& q) { return p.corners < q.corners; });
      continue;
    }
    for (Edge* i = first + 1; i < last; ++i) {
      const Edge e = *i;
      Edge* j = i;
      for (; j > first && (j - 1)->corners > e.corners; --j) *j = *(j - 1);
      *j = e;
    }
  }
  auto vertex = [&](const Edge& e, uint32_t i) {
    return mesh.indices[3 * size_t(e.triangle) + (e.k + i) % 3];
  };
  auto faceNormal = [&](uint32_t t) {
    const glm::dvec3 a(mesh.positions[mesh.indices[3 * size_t(t)]]);
    const glm::dvec3 b(mesh.positions[mesh.indices[3 * size_t(t) + 1]]);
    const glm::dvec3 c(mesh.positions[mesh.indices[3 * size_t(t) + 2]]);
    return glm::cross(b - a, c - a);
  };
  auto material = [&](uint32_t t) {
    return mesh.triangleMaterial.empty() ? 0u : mesh.triangleMaterial[t];
  };
  const double creaseCos = std::cos(25.0 * std::numbers::pi / 180.0);
  constexpr double kStep = 0.1, kPad = 0.05;
  auto mark = [&](glm::dvec2 a, glm::dvec2 b) {
    // Clipped to the widened rectangle first (Liang-Barsky): a long edge's steps stay fine.
    double from = 0.0, to = 1.0;
    const glm::dvec2 d = b - a;
    const double p[4] = {-d.x, d.x, -d.y, d.y};
    const double q[4] = {a.x - left, right - a.x, a.y - top, bottom - a.y};
    for (int i = 0; i < 4; ++i) {
      if (p[i] == 0.0) {
        if (q[i] < 0.0) return;
        continue;
      }
      const double r = q[i] / p[i];
      if (p[i] < 0.0)
        from = std::max(from, r);
      else
        to = std::min(to, r);
    }
    if (from > to) return;
    const glm::dvec2 start = a + d * from, end = a + d * to;
    const int steps = int(std::ceil(glm::length(end - start) / kStep)) + 1;
    for (int i = 0; i <= steps; ++i) {
      const glm::dvec2 at = start + (end - start) * (double(i) / double(steps));
      const int l = int(std::floor(at.x - kPad)) - x0, r = int(std::floor(at.x + kPad)) - x0;
      const int t = int(std::floor(at.y - kPad)) - y0, u = int(std::floor(at.y + kPad)) - y0;
      for (int y = std::max(t, 0); y <= std::min(u, h - 1); ++y)
        for (int x = std::max(l, 0); x <= std::min(r, w - 1); ++x)
          marked[size_t(y) * size_t(w) + size_t(x)] = 1;
    }
  };
  for (size_t i = 0; i < edges.size();) {
    size_t j = i + 1;
    while (j < edges.size() && edges[j].corners == edges[i].corners) ++j;
    const Edge& e = edges[i];
    bool jump = j - i != 2;
    if (!jump) {
      const Edge& f = edges[i + 1];
      const glm::dvec2 pa = projected[vertex(e, 0)], pb = projected[vertex(e, 1)];
      auto side = [&](uint32_t v) {
        const glm::dvec2 pc = projected[v] - pa, ab = pb - pa;
        return ab.x * pc.y - ab.y * pc.x;
      };
      const glm::dvec3 ne = faceNormal(e.triangle), nf = faceNormal(f.triangle);
      const double lengths = glm::length(ne) * glm::length(nf);
      jump = side(vertex(e, 2)) * side(vertex(f, 2)) >= 0.0 ||
             material(e.triangle) != material(f.triangle) ||
             !((vertex(e, 0) == vertex(f, 0) && vertex(e, 1) == vertex(f, 1)) ||
               (vertex(e, 0) == vertex(f, 1) && vertex(e, 1) == vertex(f, 0))) ||
             !(std::abs(glm::dot(ne, nf)) > creaseCos * lengths);
    }
    if (jump) mark(projected[vertex(e, 0)], projected[vertex(e, 1)]);
    i = j;
  }
}

// With `surfaces`, also each pixel's nearest surface and the pixels of markEdges' edges.
std::vector<uint8_t> coverablePixels(const Mesh& mesh, const glm::dmat4& worldFromObject,
                                     const calib::PlateCamera& camera, const glm::vec3& rayOrigin,
                                     int x0, int y0, int w, int h,
                                     PixelSurfaces* surfaces = nullptr) {
  std::vector<float>* nearest = surfaces ? &surfaces->nearest : nullptr;
  if (surfaces) *surfaces = PixelSurfaces{};
  if (camera.lens.projection != calib::Projection::Rectilinear || camera.lens.hasDistortion() ||
      w <= 0 || h <= 0)
    return {};
  // Seen from where the rays start: the camera's centre in the object's coordinates as the rays
  // have it, rounded to float (far from the object's origin that rounding is more than a pixel's
  // padding). cameraFromObject · v = M · (v - centre) for the exact centre.
  const glm::dmat3 cameraFromObject = glm::dmat3(camera.cameraFromWorld() * worldFromObject);
  const glm::dvec3 origin(rayOrigin);
  const calib::Lens& lens = camera.lens;
  // The corners projected as CameraRays inverts it: direction ∝ ((px - cx) / fx,
  // -(py - cy) / fy, -1).
  std::vector<glm::dvec2> projected(mesh.positions.size());
  std::vector<double> inverseDepth(nearest ? mesh.positions.size() : 0);
  for (size_t v = 0; v < mesh.positions.size(); ++v) {
    const glm::dvec3 c = cameraFromObject * (glm::dvec3(mesh.positions[v]) - origin);
    if (!(c.z < -1e-9)) return {};
    projected[v] = {lens.cx + lens.fx * c.x / -c.z, lens.cy - lens.fy * c.y / -c.z};
    if (nearest) inverseDepth[v] = 1.0 / -c.z;
  }
  if (nearest) nearest->assign(size_t(w) * size_t(h), 0.0f);
  constexpr double kPad = 0.05;
  constexpr int kSmall = 8;  // a triangle whose box is narrower and lower is marked by its box
  std::vector<uint8_t> mask(size_t(w) * size_t(h), 0);
  // The triangle being marked: its inverse depth alongX·x + alongY·y + offset over the image
  // (x, y the pixel coordinates), within [lowest, highest].
  double alongX = 0.0, alongY = 0.0, offset = 0.0, lowest = 0.0, highest = 0.0;
  auto mark = [&](int y, int first, int last) {
    uint8_t* row = mask.data() + size_t(y - y0) * size_t(w) - x0;
    for (int x = first; x <= last; ++x) row[x] = 1;
    if (!nearest) return;
    float* near = nearest->data() + size_t(y - y0) * size_t(w) - x0;
    const double rowPart = alongY * (double(y) + (alongY > 0.0 ? 1.0 : 0.0)) + offset;
    const double corner = alongX > 0.0 ? 1.0 : 0.0;
    for (int x = first; x <= last; ++x) {
      const float value =
          float(std::clamp(alongX * (double(x) + corner) + rowPart, lowest, highest));
      near[x] = std::max(near[x], value);
    }
  };
  // The first and last pixel (row or column) of [from, from + size) that [lo - pad, hi + pad]
  // reaches.
  auto first = [](double lo, int from, int size) {
    return int(std::clamp(std::floor(lo - kPad), double(from), double(from + size)));
  };
  auto last = [](double hi, int from, int size) {
    return int(std::clamp(std::floor(hi + kPad), double(from - 1), double(from + size - 1)));
  };
  auto rasterise = [&] {
    for (size_t t = 0; t + 2 < mesh.indices.size(); t += 3) {
      const glm::dvec2 p[3] = {projected[mesh.indices[t]], projected[mesh.indices[t + 1]],
                               projected[mesh.indices[t + 2]]};
      const glm::dvec2 lo = glm::min(glm::min(p[0], p[1]), p[2]);
      const glm::dvec2 hi = glm::max(glm::max(p[0], p[1]), p[2]);
      const int left = first(lo.x, x0, w), right = last(hi.x, x0, w);
      const int top = first(lo.y, y0, h), bottom = last(hi.y, y0, h);
      if (left > right || top > bottom) continue;  // outside the rectangle
      if (nearest) {
        const double q[3] = {inverseDepth[mesh.indices[t]], inverseDepth[mesh.indices[t + 1]],
                             inverseDepth[mesh.indices[t + 2]]};
        lowest = std::min({q[0], q[1], q[2]});
        highest = std::max({q[0], q[1], q[2]});
        // The plane through the three (x, y, 1 / depth); a triangle seen edge on has none: its
        // nearest corner stands for all of it.
        const glm::dvec2 e1 = p[1] - p[0], e2 = p[2] - p[0];
        const double det = e1.x * e2.y - e1.y * e2.x;
        if (std::abs(det) > 1e-9) {
          alongX = ((q[1] - q[0]) * e2.y - (q[2] - q[0]) * e1.y) / det;
          alongY = ((q[2] - q[0]) * e1.x - (q[1] - q[0]) * e2.x) / det;
          offset = q[0] - alongX * p[0].x - alongY * p[0].y;
        } else {
          alongX = alongY = 0.0;
          offset = highest;
        }
      }
      if (right - left < kSmall && bottom - top < kSmall) {
        // A small triangle: its bounding box (a few pixels more than it covers, at most).
        for (int y = top; y <= bottom; ++y) mark(y, left, right);
        continue;
      }
      for (int y = top; y <= bottom; ++y) {
        // The triangle's extent in x within the row's slab [y - pad, y + 1 + pad]: its corners in
        // the slab and its edges' crossings of the slab's two lines.
        const double ya = double(y) - kPad, yb = double(y) + 1.0 + kPad;
        double from = std::numeric_limits<double>::max(), to = -from;
        for (int e = 0; e < 3; ++e) {
          const glm::dvec2 a = p[e], b = p[(e + 1) % 3];
          if (a.y >= ya && a.y <= yb) from = std::min(from, a.x), to = std::max(to, a.x);
          if (a.y == b.y) continue;
          for (const double line : {ya, yb}) {
            const double f = (line - a.y) / (b.y - a.y);
            if (f < 0.0 || f > 1.0) continue;
            const double x = a.x + f * (b.x - a.x);
            from = std::min(from, x), to = std::max(to, x);
          }
        }
        if (from > to) continue;
        const int x1 = std::max(left, first(from, x0, w)), x2 = std::min(right, last(to, x0, w));
        if (x1 <= x2) mark(y, x1, x2);
      }
    }
  };
  // The edges are found beside the rasterisation (the two write different arrays).
  if (nearest) {
    tbb::parallel_invoke([&] { markEdges(mesh, projected, x0, y0, w, h, surfaces->edges); },
                         rasterise);
  } else {
    rasterise();
  }
  return mask;
}

float luminance(const glm::vec3& c) {
  return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z;
}

// The bright sources at a hit whose three surface points see them differently (a shadow edge
// crosses the triangle): traced from the hit and shaded at its normal; the rest of the light keeps
// the ratio interpolated between the points (renderer.h).
class SourceEdges {
 public:
  SourceEdges(const RenderSettings& settings, const glm::dmat4& worldFromObject)
      : vi_(*settings.shadows), points_(*settings.points), sources_(*settings.sources) {
    glm::dmat3 rotation(worldFromObject);
    for (int c = 0; c < 3; ++c) rotation[c] = glm::normalize(rotation[c]);
    envFromObject_ = settings.envFromWorld * glm::mat3(rotation);
    frames_ = sourceFrames(sources_, envFromObject_);
    lift_ = 1e-4f * points_.size;
    tnear_ = 1e-5f * points_.size;
    const int n = settings.samplesPerAxis;
    raysPerSample_ = std::max(1, 16 / (n * n));
    // Each point's normal in the environment's frame, and the sources above its horizon.
    const size_t count = points_.count();
    normals_.resize(count);
    facing_.assign(count, 0);
    parallelFor(
        0, int64_t(count),
        [&](int64_t p) {
          const glm::vec3 normal = envFromObject_ * points_.normals[size_t(p)];
          const float length = glm::length(normal);
          normals_[size_t(p)] = length > 0.0f ? normal / length : normal;
          uint64_t bits = 0;
          for (size_t i = 0; i < sources_.size(); ++i)
            bits |= uint64_t(glm::dot(normals_[size_t(p)], sources_[i].direction) > 0.0f) << i;
          facing_[size_t(p)] = bits;
        },
        1024);
  }

  // The sources whose shadow's edge or penumbra (or terminator) crosses the cell of these three
  // points: they see them differently, or in part.
  uint64_t crossing(const uint32_t near[3]) const {
    const uint64_t* seen = vi_.sourceSeen.data();
    const uint64_t* partial = vi_.sourcePartial.data();
    return (seen[near[0]] ^ seen[near[1]]) | (seen[near[0]] ^ seen[near[2]]) | partial[near[0]] |
           partial[near[1]] | partial[near[2]];
  }

  static bool wanted(const RenderSettings& settings) {
    return settings.shadows && settings.points && settings.sources && !settings.sources->empty() &&
           settings.shadows->sourceCount == settings.sources->size() &&
           settings.shadows->sourceSeen.size() == settings.points->count() &&
           settings.shadows->sourcePartial.size() == settings.points->count();
  }

  // The sources above the horizon of a surface point that the point does not see (it is in their
  // shadow) are in its unshadowed irradiance and not in its shadowed one. Left in, the ratio of
  // the two would dim the rest of the light with them, and where the hit's normal has turned past
  // their terminator (none of their light there to lose) it would draw a dark line along it.
  // Those that none of the triangle's three points sees are taken out of the interpolated
  // unshadowed irradiance `un` and of the hit's irradiance `e` (normal `nEnv`): the ratio is then
  // that of the light the points do get, and applies to the light the hit gets but for them.
  // Sources in `taken` (traced from the hit, already out of both) are left alone.
  void removeUnseen(const uint32_t near[3], const float weight[3], const glm::vec3& nEnv,
                    glm::vec3& un, glm::vec3& e, uint64_t taken = 0) const {
    const uint64_t* seen = vi_.sourceSeen.data();
    const uint64_t* partial = vi_.sourcePartial.data();
    uint64_t unseen = ~(seen[near[0]] | seen[near[1]] | seen[near[2]] | partial[near[0]] |
                        partial[near[1]] | partial[near[2]] | taken) &
                      (facing_[near[0]] | facing_[near[1]] | facing_[near[2]]);
    if (unseen == 0) return;
    for (; unseen != 0; unseen &= unseen - 1) {
      const lighting::LightSource& source = sources_[size_t(std::countr_zero(unseen))];
      for (int q = 0; q < 3; ++q)
        un -= (weight[q] * std::max(0.0f, glm::dot(normals_[near[q]], source.direction))) *
              source.power;
      e -= std::max(0.0f, glm::dot(nEnv, source.direction)) * source.power;
    }
    un = glm::max(un, glm::vec3(0.0f));
    e = glm::max(e, glm::vec3(0.0f));
  }

  // The shadowed irradiance at a hit (object-space position `at`, `lifted()` giving it lifted
  // onto the smooth surface by Mesh::smoothPoint, asked only when a source is traced; shading
  // normal `nObj` and its environment-frame twin `nEnv`, unshadowed irradiance `e` there), or
  // false when no source needs tracing (then the plain interpolated ratio applies). A source whose
  // edge crosses the triangle is traced only where it could change the pixel by more than 1/256 of
  // its irradiance (less is below what an 8-bit display shows, and the interpolated ratio already
  // holds it approximately).
  template <class Lifted>
  bool shade(const EmbreeScene& scene, const uint32_t near[3], const float weight[3],
             const glm::vec3& at, Lifted&& lifted, const glm::vec3& nObj, const glm::vec3& nEnv,
             const glm::vec3& e, uint32_t seed, glm::vec3& shadowed, int64_t& rays) const {
    // The sources the three points see differently, or in part: their shadow's edge, penumbra
    // (or their terminator) crosses the triangle.
    uint64_t mask = crossing(near);
    if (mask == 0) return false;
    const float floor = (1.0f / 256.0f) * luminance(e);
    struct Taken {
      uint32_t source;
      float cosine, visible;
    };
    Taken taken[64];
    int n = 0;
    for (; mask != 0; mask &= mask - 1) {
      const uint32_t i = uint32_t(std::countr_zero(mask));
      const float c = std::max(0.0f, glm::dot(nEnv, sources_[i].direction));
      if (c * luminance(sources_[i].power) > floor) taken[n++] = {i, c, 0.0f};
    }
    if (n == 0) return false;

    // Those sources taken out of the interpolated ratio ...
    glm::vec3 sh(0.0f), un(0.0f);
    for (int q = 0; q < 3; ++q) {
      sh += weight[q] * vi_.shadowed[near[q]];
      un += weight[q] * vi_.unshadowed[near[q]];
    }
    for (int q = 0; q < 3; ++q) {
      const glm::vec3 corner = envFromObject_ * points_.normals[near[q]];
      for (int k = 0; k < n; ++k) {
        const lighting::LightSource& source = sources_[taken[k].source];
        const glm::vec3 light =
            (weight[q] * std::max(0.0f, glm::dot(corner, source.direction))) * source.power;
        sh -= vi_.seenFraction(near[q], int(taken[k].source)) * light;
        un -= light;
      }
    }
    // ... and traced from the hit, across their extent: from its point on the smooth surface
    // (Mesh::smoothPoint) unless something of the object lies between the two.
    glm::vec3 from = lifted();
    const glm::vec3 up = from - at;
    const float length = glm::length(up);
    if (length > tnear_) {
      ++rays;
      if (scene.occluded(at, up / length, tnear_, length)) from = at;
    }
    const glm::vec3 origin = from + lift_ * nObj;
    glm::vec3 batch[16];
    int owner[16];
    int m = 0;
    auto flush = [&] {
      float through[16];  // a semi-transparent surface lets 1 - alpha by
      scene.transmittance16(origin, batch, (1u << m) - 1u, tnear_, through);
      for (int b = 0; b < m; ++b) taken[owner[b]].visible += through[b] / float(raysPerSample_);
      rays += m;
      m = 0;
    };
    const int side = raysPerSample_ >= 16 ? 4 : raysPerSample_ >= 4 ? 2 : 1;
    for (int k = 0; k < n; ++k) {
      const uint32_t i = taken[k].source;
      for (int r = 0; r < raysPerSample_; ++r) {
        const uint32_t h = (seed * 0x9E3779B1u) ^ (i * 0x85EBCA77u) ^ (uint32_t(r) * 0xC2B2AE3Du);
        const float a = (float(r % side) + hash01(2 * h)) / float(side) - 0.5f;
        const float b = (float((r / side) % side) + hash01(2 * h + 1)) / float(side) - 0.5f;
        const glm::vec3 d = frames_[i].direction(a, b);
        if (glm::dot(nObj, d) <= 0.0f) continue;  // below the horizon: no light anyway
        batch[m] = d;
        owner[m] = k;
        if (++m == 16) flush();
      }
    }
    if (m > 0) flush();
    glm::vec3 rest = e, direct(0.0f);
    for (int k = 0; k < n; ++k) {
      const lighting::LightSource& source = sources_[taken[k].source];
      rest -= taken[k].cosine * source.power;
      direct += taken[k].visible * taken[k].cosine * source.power;
    }
    rest = glm::max(rest, glm::vec3(0.0f));
    uint64_t tracedMask = 0;
    for (int k = 0; k < n; ++k) tracedMask |= uint64_t(1) << taken[k].source;
    removeUnseen(near, weight, nEnv, un, rest, tracedMask);
    for (int c = 0; c < 3; ++c) {
      const float ratio = un[c] > 1e-20f ? std::clamp(sh[c] / un[c], 0.0f, 1.0f) : 1.0f;
      // Visibility never adds light: a source's light at the hit as from its centre can exceed
      // what the lighting says the hit gets.
      shadowed[c] = std::min(rest[c] * ratio + direct[c], e[c]);
    }
    return true;
  }

 private:
  const VertexIrradiance& vi_;
  const SurfacePoints& points_;
  const std::vector<lighting::LightSource>& sources_;
  glm::mat3 envFromObject_{1.0f};
  std::vector<SourceFrame> frames_;
  float lift_ = 0.0f, tnear_ = 0.0f;
  int raysPerSample_ = 1;
  std::vector<glm::vec3> normals_;  // per surface point, in the environment's frame
  std::vector<uint64_t> facing_;    // per surface point: the sources above its horizon
};

}  // namespace

const std::vector<std::string>& aovChannelNames() {
  static const std::vector<std::string> names = {"N.X",
                                                 "N.Y",
                                                 "N.Z",
                                                 "P.X",
                                                 "P.Y",
                                                 "P.Z",
                                                 "depth.Z",
                                                 "albedo.R",
                                                 "albedo.G",
                                                 "albedo.B",
                                                 "irradiance.R",
                                                 "irradiance.G",
                                                 "irradiance.B",
                                                 "irradianceShadowed.R",
                                                 "irradianceShadowed.G",
                                                 "irradianceShadowed.B",
                                                 "AO.Y"};
  return names;
}

RenderOutput renderDiffuse(const Mesh& mesh, const EmbreeScene& scene,
                           const glm::dmat4& worldFromObject, const calib::PlateCamera& camera,
                           const lighting::DiffuseLighting& lighting,
                           const RenderSettings& settings, const Progress& progress) {
  COMPOSE_CHECK(settings.samplesPerAxis >= 1);
  COMPOSE_CHECK(!mesh.indices.empty() && mesh.normals.size() == mesh.positions.size());
  if (settings.shadows || settings.occlusion) COMPOSE_CHECK(settings.points != nullptr);
  if (settings.shadows)
    COMPOSE_CHECK(settings.shadows->shadowed.size() == settings.points->count());
  if (settings.occlusion) COMPOSE_CHECK(settings.occlusion->size() == settings.points->count());

  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  const glm::dmat3 normalFromObject = glm::transpose(glm::inverse(glm::dmat3(worldFromObject)));
  const glm::dmat4 cameraFromWorld = camera.cameraFromWorld();

  glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
  for (const glm::vec3& p : mesh.positions) {
    const glm::dvec3 w = glm::dvec3(worldFromObject * glm::dvec4(glm::dvec3(p), 1.0));
    lo = glm::min(lo, w);
    hi = glm::max(hi, w);
  }
  RenderOutput out;
  screenRectangle(camera, lo, hi, out.x0, out.y0, out.x1, out.y1);
  const int w = out.x1 - out.x0, h = out.y1 - out.y0;
  out.beauty = Image(w, h, 4, {"R", "G", "B", "A"});
  out.aovs = Image(w, h, kAovChannels, aovChannelNames());
  out.aovs.colorSpace = "Raw";
  if (w == 0 || h == 0) return out;

  const int n = settings.samplesPerAxis;
  const float invSamples = 1.0f / float(n * n);
  const float invPi = float(1.0 / std::numbers::pi);
  const bool materials = mesh.hasMaterials() && !settings.overrideMaterials;
  // Semi-transparent surfaces: a camera ray goes on through them, each layer taking its alpha of
  // what the layers in front left of the sample, up to kMaxLayers of them or until less than
  // kLeastLeft is left (the last layer met takes it all).
  const bool translucent = std::any_of(mesh.materials.begin(), mesh.materials.end(),
                                       [](const Material& m) { return m.blend; });
  constexpr int kMaxLayers = 16;
  constexpr float kLeastLeft = 1.0f / 256.0f;
  const float reflect = settings.exposure * invPi;
  std::atomic<int> rowsDone{0};
  std::atomic<double> hitsTotal{0.0};
  std::atomic<int64_t> sourceRays{0};
  std::optional<SourceEdges> edges;
  if (SourceEdges::wanted(settings)) {
    COMPOSE_CHECK(settings.sources->size() <= 64);  // one bit each
    edges.emplace(settings, worldFromObject);
  }
  const CameraRays cameraRays(camera, objectFromWorld);
  const glm::dvec3 origin = camera.position();

  // Shading one hit: the irradiance with and without self-shadowing, the shading normal and the
  // ambient occlusion, at barycentrics (u, v) of `triangle`, seen along world direction `dir`.
  // `at` is the hit in object space and `seed` the sample's, for the rays a source's shadow edge
  // needs (none when `traceEdges` is false).
  struct Shaded {
    glm::vec3 e{0.0f}, shadowed{0.0f}, normal{0.0f};
    float ao = 1.0f;
  };
  auto shade = [&](uint32_t triangle, float u, float v, const uint32_t near[3],
                   const float weight[3], const glm::dvec3& dir, const glm::vec3& at,
                   const glm::vec3& geometricNormal, uint32_t seed, bool traceEdges,
                   int64_t& rays) {
    Shaded r;
    const uint32_t* tri = &mesh.indices[3 * size_t(triangle)];
    const float t = 1.0f - u - v;
    const glm::vec3 interpolated =
        t * mesh.normals[tri[0]] + u * mesh.normals[tri[1]] + v * mesh.normals[tri[2]];
    glm::vec3 ng = glm::vec3(glm::normalize(normalFromObject * glm::dvec3(geometricNormal)));
    glm::vec3 nrm = glm::dot(interpolated, interpolated) > 1e-12f
                        ? glm::vec3(glm::normalize(normalFromObject * glm::dvec3(interpolated)))
                        : ng;  // a zero interpolated normal: the face's own
    const glm::vec3 view = -glm::vec3(dir);
    // Shade the side the camera sees: a back face turns both normals round, and a shading
    // normal that still points away from the viewer is bent back to the tangent plane.
    const bool backFace = glm::dot(ng, view) < 0.0f;
    if (backFace) {
      ng = -ng;
      nrm = -nrm;
    }
    const float away = glm::dot(nrm, view);
    if (away < 0.0f) nrm = glm::normalize(nrm - (away - 1e-3f) * view);
    r.normal = nrm;
    r.e = glm::max(lighting.irradiance(settings.envFromWorld * nrm, settings.envFromWorld * view),
                   glm::vec3(0.0f));
    r.shadowed = r.e;
    if (traceEdges && edges && glm::dot(interpolated, interpolated) > 1e-12f &&
        edges->shade(
            scene, near, weight, at, [&] { return mesh.smoothPoint(triangle, u, v, at, backFace); },
            glm::normalize(backFace ? -interpolated : interpolated), settings.envFromWorld * nrm,
            r.e, seed, r.shadowed, rays)) {
      // A source's shadow edge crosses the triangle: traced from the hit.
    } else if (settings.shadows) {
      const VertexIrradiance& vi = *settings.shadows;
      const glm::vec3 sh = weight[0] * vi.shadowed[near[0]] + weight[1] * vi.shadowed[near[1]] +
                           weight[2] * vi.shadowed[near[2]];
      glm::vec3 un = weight[0] * vi.unshadowed[near[0]] + weight[1] * vi.unshadowed[near[1]] +
                     weight[2] * vi.unshadowed[near[2]];
      glm::vec3 e = r.e;
      if (edges) edges->removeUnseen(near, weight, settings.envFromWorld * nrm, un, e);
      for (int c = 0; c < 3; ++c) {
        // Where the vertices get (almost) no light there is nothing to shadow.
        const float ratio = un[c] > 1e-20f ? std::clamp(sh[c] / un[c], 0.0f, 1.0f) : 1.0f;
        r.shadowed[c] = e[c] * ratio;
      }
    }
    if (settings.occlusion) {
      const std::vector<float>& ao = *settings.occlusion;
      r.ao = weight[0] * ao[near[0]] + weight[1] * ao[near[1]] + weight[2] * ao[near[2]];
    }
    return r;
  };

  // Pixels no triangle reaches are not traced (they would be left empty all the same).
  PixelSurfaces surfaces;  // per pixel: the nearest surface, and whether an edge passes
  // Not for a mesh of more triangles than the rectangle has pixels: most pixels hold an edge of
  // one, and finding the edges would cost more than the rays it saves.
  const bool adaptiveWanted = settings.adaptive && n >= 2 && !translucent &&
                              mesh.indices.size() / 3 <= size_t(w) * size_t(h);
  const std::vector<uint8_t> coverable =
      settings.skipUncoveredPixels
          ? coverablePixels(mesh, worldFromObject, camera,
                            glm::vec3(objectFromWorld * glm::dvec4(camera.position(), 1.0)), out.x0,
                            out.y0, w, h, adaptiveWanted ? &surfaces : nullptr)
          : std::vector<uint8_t>{};
  // Adaptive sampling (RenderSettings::adaptive) needs the nearest surface of each pixel.
  const bool adaptive = adaptiveWanted && !surfaces.nearest.empty();
  // The camera's axis, for a hit's depth; the angle a pixel spans at the centre of the image.
  const glm::dvec3 forward = -glm::dmat3(camera.worldFromCamera)[2];
  const double pixelAngle = 1.0 / std::min(camera.lens.fx, camera.lens.fy);
  // The four corner samples of the n x n grid: they stand for the pixel where it is plain.
  const int probeSample[4] = {0, n - 1, n * (n - 1), n * n - 1};
  const float probeCover = float(n * n) / 4.0f;
  const float kPlainNormalCos = float(std::cos(10.0 * std::numbers::pi / 180.0));
  // What a plain pixel's shading must not depend on: a texture or a cut-out's edge between its
  // samples.
  auto plainMaterial = [&](uint32_t triangle) {
    if (!materials || mesh.materials.empty()) return true;
    const uint32_t m = mesh.triangleMaterial.empty() ? 0u : mesh.triangleMaterial[triangle];
    const Material& material = mesh.materials[std::min<size_t>(m, mesh.materials.size() - 1)];
    return material.texture < 0 && !material.cutOut();
  };
  bool textured = false;  // some material has a texture with mip levels to filter it
  if (materials)
    for (const Material& m : mesh.materials)
      textured = textured || (m.texture >= 0 && !mesh.textures[size_t(m.texture)].levels.empty());
  // The footprint a sample's texture lookup averages, in pixels: wider than the samples' spacing
  // (1/n), three quarters of a pixel. With the samples' own box it makes a tent of about 1.75
  // pixels: no grain where the texture is finer than the samples. Measured against 16 x 16
  // samples filtered over 1/16 pixel (Suzanne with a 2048^2 checker of 2-texel squares on the
  // meadow plate, 960 wide): RMS 0.0088 unfiltered, 0.0072 over 1/4 pixel, 0.0043 over 3/4, 0.0048
  // over one pixel; at a third of the size 0.0046, 0.0019, 0.00075, 0.00073.
  const double textureFootprint = std::max(1.0 / n, 0.75);
  std::atomic<int64_t> cameraRaysTotal{0}, plainPixels{0}, tracedPixels{0};
  parallelFor(out.y0, out.y1, [&](int64_t yy) {
    const int y = int(yy);
    double rowHits = 0.0;
    int64_t rowSourceRays = 0, rowCameraRays = 0, rowPlain = 0, rowTraced = 0;
    const uint8_t* coverableRow =
        coverable.empty() ? nullptr : coverable.data() + size_t(y - out.y0) * size_t(w);
    // A pixel's hits, then grouped by the surface cell they landed in (triangle and the three
    // surface points around them).
    struct SampleHit {
      uint32_t triangle;
      float u, v, distance;
      uint32_t near[3];
      float weight[3];
      glm::dvec3 dir;
      glm::vec3 d, at, geometricNormal;  // d: the ray's direction in the object's frame
      uint32_t seed;
      int group;
      float cover;  // of the sample: 1, or what a semi-transparent layer takes of it
    };
    std::vector<SampleHit> samples;
    samples.reserve(size_t(n) * size_t(n));
    // Sample s of pixel x's n x n: its world direction, and its ray in the object's frame.
    auto sampleRay = [&](int x, int s, glm::dvec3& dir, glm::vec3& o, glm::vec3& d) {
      const uint32_t seed =
          (uint32_t(y) * uint32_t(camera.width) + uint32_t(x)) * uint32_t(n * n) + uint32_t(s);
      const double jx = settings.jitter ? double(hash01(2 * seed)) : 0.5;
      const double jy = settings.jitter ? double(hash01(2 * seed + 1)) : 0.5;
      return cameraRays.ray(x + (s % n + jx) / n, y + (s / n + jy) / n, dir, o, d);
    };
    // Adaptive sampling: the corner samples of the row's pixels that a surface reaches, traced
    // first, four pixels to a packet (Embree's cost is the packet's, however few rays it holds).
    struct Probe {
      EmbreeScene::Hit hit;
      glm::dvec3 dir;
      glm::vec3 o, d;
      bool traced = false;
    };
    thread_local std::vector<Probe> probes;
    const float* nearestRow =
        adaptive ? surfaces.nearest.data() + size_t(y - out.y0) * size_t(w) : nullptr;
    const uint8_t* edgeRow =
        adaptive ? surfaces.edges.data() + size_t(y - out.y0) * size_t(w) : nullptr;
    if (adaptive) {
      probes.assign(size_t(w) * 4, Probe{});
      int pending[4], count = 0;
      auto flush = [&] {
        glm::vec3 oObj[16], dObj[16];
        EmbreeScene::Hit found[16];
        uint32_t active = 0;
        for (int q = 0; q < count; ++q) {
          Probe* p = &probes[size_t(pending[q] - out.x0) * 4];
          for (int b = 0; b < 4; ++b)
            if (sampleRay(pending[q], probeSample[b], p[b].dir, oObj[4 * q + b], dObj[4 * q + b]))
              active |= 1u << (4 * q + b);
        }
        if (active != 0) scene.intersect16(oObj, dObj, active, found, 0.0f, 1e30f, false);
        rowCameraRays += std::popcount(active);
        for (int q = 0; q < count; ++q) {
          Probe* p = &probes[size_t(pending[q] - out.x0) * 4];
          for (int b = 0; b < 4; ++b) {
            p[b].traced = (active >> (4 * q + b)) & 1u;
            p[b].hit = found[4 * q + b];
            p[b].o = oObj[4 * q + b];
            p[b].d = dObj[4 * q + b];
          }
        }
        count = 0;
      };
      for (int x = out.x0; x < out.x1; ++x) {
        if ((coverableRow && !coverableRow[x - out.x0]) || !(nearestRow[x - out.x0] > 0.0f) ||
            edgeRow[x - out.x0])
          continue;  // traced in full
        pending[count++] = x;
        if (count == 4) flush();
      }
      if (count > 0) flush();
    }
    for (int x = out.x0; x < out.x1; ++x) {
      if (coverableRow && !coverableRow[x - out.x0]) continue;
      ++rowTraced;
      glm::vec3 colour(0.0f), normalSum(0.0f), irradianceSum(0.0f), shadowedSum(0.0f),
          albedoSum(0.0f);
      glm::dvec3 positionSum(0.0);
      float aoSum = 0.0f;
      samples.clear();
      // How a sample's ray changes across its footprint, across and down (object frame): textures
      // are filtered over what that spans on the surface.
      glm::vec3 stepX(0.0f), stepY(0.0f);
      bool footprints = false;
      if (textured) {
        glm::dvec3 world;
        glm::vec3 o(0.0f), d0(0.0f), d1(0.0f), d2(0.0f);
        footprints = cameraRays.ray(x + 0.5, y + 0.5, world, o, d0) &&
                     cameraRays.ray(x + 0.5 + textureFootprint, y + 0.5, world, o, d1) &&
                     cameraRays.ray(x + 0.5, y + 0.5 + textureFootprint, world, o, d2);
        stepX = d1 - d0;
        stepY = d2 - d0;
      }
      // A sample's albedo, its texture filtered over its footprint: the steps across it carried
      // to its hit and onto the triangle's plane (ray differentials).
      auto albedoOf = [&](const SampleHit& s) {
        if (!materials) return settings.albedo;
        if (!footprints) return mesh.albedoAt(s.triangle, s.u, s.v);
        const glm::vec3& normal = s.geometricNormal;
        const float facing = glm::dot(s.d, normal);
        auto onPlane = [&](const glm::vec3& step) {
          const glm::vec3 a = s.distance * step;
          return a - s.d * (glm::dot(a, normal) / facing);
        };
        return mesh.albedoAt(s.triangle, s.u, s.v, onPlane(stepX), onPlane(stepY));
      };
      const uint32_t pixelSeed =
          (uint32_t(y) * uint32_t(camera.width) + uint32_t(x)) * uint32_t(n * n);
      auto addSample = [&](const EmbreeScene::Hit& hit, const glm::dvec3& dir, const glm::vec3& o,
                           const glm::vec3& d, int s, float cover) {
        SampleHit sample;
        sample.triangle = hit.triangle;
        sample.u = hit.u;
        sample.v = hit.v;
        sample.distance = hit.distance;
        sample.near[0] = sample.near[1] = sample.near[2] = 0;
        sample.weight[0] = sample.weight[1] = sample.weight[2] = 0.0f;
        if (settings.points)
          settings.points->locate(mesh, hit.triangle, hit.u, hit.v, sample.near, sample.weight);
        sample.dir = dir;
        sample.d = d;
        sample.at = o + d * hit.distance;
        sample.geometricNormal = hit.geometricNormal;
        sample.seed = pixelSeed + uint32_t(s);
        sample.group = -1;
        sample.cover = cover;
        samples.push_back(sample);
      };
      // A plain pixel: its four corner samples hit one smooth surface, with nothing nearer
      // anywhere in the pixel, no texture or cut-out, no crease and no shadow edge of a bright
      // source between them. They stand for all n x n samples: the shading is smooth across it.
      bool plain = false;
      const Probe* probe = adaptive ? &probes[size_t(x - out.x0) * 4] : nullptr;
      if (probe && probe[0].traced && probe[1].traced && probe[2].traced && probe[3].traced) {
        plain = true;
        double nearDepth = std::numeric_limits<double>::max(), farDepth = 0.0;
        glm::vec3 normals[4];
        for (int b = 0; b < 4 && plain; ++b) {
          const EmbreeScene::Hit& hit = probe[b].hit;
          if (!hit.found || !plainMaterial(hit.triangle)) {
            plain = false;
            break;
          }
          const double depth = double(hit.distance) * glm::dot(probe[b].dir, forward);
          nearDepth = std::min(nearDepth, depth);
          farDepth = std::max(farDepth, depth);
          const uint32_t* tri = &mesh.indices[3 * size_t(hit.triangle)];
          // Compared in world space: a non-uniform scale turns object-space normals.
          normals[b] =
              glm::vec3(normalFromObject *
                        glm::dvec3((1.0f - hit.u - hit.v) * mesh.normals[tri[0]] +
                                   hit.u * mesh.normals[tri[1]] + hit.v * mesh.normals[tri[2]]));
          const float length = glm::length(normals[b]);
          if (!(length > 1e-6f)) {
            plain = false;
            break;
          }
          normals[b] /= length;
        }
        // One surface: its depth changes across the samples at most as a surface turned 72°
        // from the camera does (more is an occluding edge, or grazing), and no triangle in the
        // pixel comes nearer than it by more than that slope over the pixel's border and two
        // pixels' width of depth (a thin part in front that the samples missed).
        if (plain) {
          const double footprint = farDepth * pixelAngle;
          const double spacing = std::sqrt(2.0) * double(n - 1) / double(n);
          if (!(nearDepth > 0.0) || farDepth - nearDepth > 3.0 * spacing * footprint) {
            plain = false;
          } else {
            const double inverseNear = 1.0 / nearDepth, inverseFar = 1.0 / farDepth;
            const double allowed =
                inverseNear + 0.5 * (inverseNear - inverseFar) + 2.0 * pixelAngle * inverseNear;
            if (double(nearestRow[x - out.x0]) > allowed) plain = false;
          }
        }
        // The shading nearly the same at the four: normals within 10°, ...
        for (int b = 0; b < 4 && plain; ++b)
          for (int c = b + 1; c < 4 && plain; ++c)
            if (glm::dot(normals[b], normals[c]) < kPlainNormalCos) plain = false;
        if (plain) {
          for (int b = 0; b < 4; ++b)
            addSample(probe[b].hit, probe[b].dir, probe[b].o, probe[b].d, probeSample[b],
                      probeCover);
          // ... every surface point around them seeing the same bright sources (no shadow edge
          // between or across their cells), the self-shadowing's ratio within 2 % ...
          if (edges) {
            const uint64_t* seen = settings.shadows->sourceSeen.data();
            const uint64_t first = seen[samples[0].near[0]];
            for (const SampleHit& sample : samples) {
              if (edges->crossing(sample.near) != 0) plain = false;
              for (int q = 0; q < 3; ++q)
                if (seen[sample.near[q]] != first) plain = false;
            }
          }
          if (plain && settings.shadows) {
            const VertexIrradiance& vi = *settings.shadows;
            float least = std::numeric_limits<float>::max(), most = 0.0f;
            for (const SampleHit& sample : samples) {
              float sh = 0.0f, un = 0.0f;
              for (int q = 0; q < 3; ++q) {
                sh += sample.weight[q] * luminance(vi.shadowed[sample.near[q]]);
                un += sample.weight[q] * luminance(vi.unshadowed[sample.near[q]]);
              }
              const float ratio = un > 1e-20f ? std::clamp(sh / un, 0.0f, 1.0f) : 1.0f;
              least = std::min(least, ratio);
              most = std::max(most, ratio);
            }
            if (most - least > 0.02f * most) plain = false;
          }
          // ... and the albedo (vertex colours, base colours) within 1 %.
          if (plain && materials) {
            glm::vec3 least(std::numeric_limits<float>::max()), most(0.0f);
            for (const SampleHit& sample : samples) {
              const glm::vec3 a = mesh.albedoAt(sample.triangle, sample.u, sample.v);
              least = glm::min(least, a);
              most = glm::max(most, a);
            }
            for (int c = 0; c < 3; ++c)
              if (most[c] - least[c] > 0.01f * most[c] + 1e-6f) plain = false;
          }
          if (!plain) samples.clear();
        }
      }
      if (plain) ++rowPlain;
      // A pixel that is not plain keeps its corner samples' hits (an opaque mesh: their first
      // hits are all there is) and traces the others.
      const bool reuse = !plain && probe && probe[0].traced && probe[1].traced && probe[2].traced &&
                         probe[3].traced;
      if (reuse) {
        for (int b = 0; b < 4; ++b)
          if (probe[b].hit.found)
            addSample(probe[b].hit, probe[b].dir, probe[b].o, probe[b].d, probeSample[b], 1.0f);
      }
      // The pixel's samples, sixteen at a time: one coherent packet for Embree.
      for (int first = 0; first < n * n && !plain; first += 16) {
        const int count = std::min(16, n * n - first);
        glm::dvec3 dirs[16];
        glm::vec3 oObj[16], dObj[16];
        uint32_t active = 0;
        for (int b = 0; b < count; ++b) {
          const int s = first + b;
          if (reuse && (s == probeSample[0] || s == probeSample[1] || s == probeSample[2] ||
                        s == probeSample[3]))
            continue;
          if (sampleRay(x, s, dirs[b], oObj[b], dObj[b])) active |= 1u << b;
        }
        rowCameraRays += std::popcount(active);
        if (active == 0) continue;
        // Through semi-transparent layers, front to back: each takes its alpha of what the
        // layers in front of it left of the sample; the rays that go on are traced again, from
        // just past their last hit.
        EmbreeScene::Hit found[16];
        float tnear[16], left[16];
        int layer[16];
        std::fill(tnear, tnear + 16, 0.0f);
        std::fill(left, left + 16, 1.0f);
        std::fill(layer, layer + 16, 0);
        for (uint32_t tracing = active; tracing != 0;) {
          scene.intersect16(oObj, dObj, tracing, found, tnear, 1e30f, translucent);
          uint32_t further = 0;
          for (int b = 0; b < count; ++b) {
            const EmbreeScene::Hit& hit = found[b];
            if (!((tracing >> b) & 1u) || !hit.found) continue;
            float cover = left[b];
            if (translucent && mesh.semiTransparent(hit.triangle) && layer[b] < kMaxLayers &&
                left[b] > kLeastLeft) {
              cover *= std::clamp(mesh.alphaAt(hit.triangle, hit.u, hit.v), 0.0f, 1.0f);
              left[b] -= cover;
            } else {
              left[b] = 0.0f;
            }
            addSample(hit, dirs[b], oObj[b], dObj[b], first + b, cover);
            if (left[b] > 0.0f) {
              tnear[b] = hit.distance * 1.00001f;
              ++layer[b];
              further |= 1u << b;
            }
          }
          rowCameraRays += std::popcount(further);
          tracing = further;
        }
      }
      const int hits = int(samples.size());
      // Samples in one cell are shaded once, at their mean barycentrics and direction: the
      // shading varies smoothly inside a cell (normals, irradiance and the shadow ratio are
      // interpolated linearly there), so the mean of the samples' shading and the shading at
      // their mean differ in the second order only. A cell whose points see a bright source
      // differently has a shadow edge crossing it: its samples are shaded one by one, each
      // tracing the source from its own hit, so that the edge keeps its antialiasing. Albedo is
      // looked up per sample (a texture keeps its detail within the pixel).
      const uint64_t* seen =
          edges ? settings.shadows->sourceSeen.data() : nullptr;  // one bit per bright source
      for (int i = 0; i < hits; ++i) {
        SampleHit& a = samples[size_t(i)];
        if (a.group >= 0) continue;
        a.group = i;
        int members = 1;
        float cover = a.cover;
        glm::dvec3 dirSum = a.dir;
        double uSum = a.u, vSum = a.v;
        for (int j = i + 1; j < hits; ++j) {
          SampleHit& b = samples[size_t(j)];
          if (b.group >= 0 || b.triangle != a.triangle || b.near[0] != a.near[0] ||
              b.near[1] != a.near[1] || b.near[2] != a.near[2])
            continue;
          b.group = i;
          ++members;
          cover += b.cover;
          dirSum += b.dir;
          uSum += b.u;
          vSum += b.v;
        }
        const bool edge = seen && edges->crossing(a.near) != 0;
        // Adds shading `r` for `count` samples whose albedos sum to `albedo`.
        auto accumulate = [&](const Shaded& r, const glm::vec3& albedo, float count) {
          colour += reflect * albedo * r.shadowed;
          irradianceSum += count * r.e;
          shadowedSum += count * r.shadowed;
          normalSum += count * r.normal;
          aoSum += count * r.ao;
        };
        if (members == 1 || edge) {
          for (int j = i; j < hits; ++j) {
            const SampleHit& b = samples[size_t(j)];
            if (b.group != i) continue;
            const Shaded r = shade(b.triangle, b.u, b.v, b.near, b.weight, b.dir, b.at,
                                   b.geometricNormal, b.seed, true, rowSourceRays);
            const glm::vec3 albedo = b.cover * albedoOf(b);
            albedoSum += albedo;
            accumulate(r, albedo, b.cover);
          }
          continue;
        }
        const float mu = float(uSum / members), mv = float(vSum / members);
        uint32_t near[3];
        float weight[3] = {a.weight[0], a.weight[1], a.weight[2]};
        std::copy_n(a.near, 3, near);
        if (settings.points) settings.points->locate(mesh, a.triangle, mu, mv, near, weight);
        const Shaded r = shade(a.triangle, mu, mv, near, weight, glm::normalize(dirSum), a.at,
                               a.geometricNormal, a.seed, false, rowSourceRays);
        glm::vec3 albedo(0.0f);
        for (int j = i; j < hits; ++j) {
          const SampleHit& b = samples[size_t(j)];
          if (b.group != i) continue;
          albedo += b.cover * albedoOf(b);
        }
        albedoSum += albedo;
        accumulate(r, albedo, cover);
      }
      double covered = 0.0;
      for (const SampleHit& sample : samples) {
        positionSum += double(sample.cover) * (origin + sample.dir * double(sample.distance));
        covered += double(sample.cover);
      }
      if (!(covered > 0.0)) continue;
      rowHits += covered;
      float* b = out.beauty.at(x - out.x0, y - out.y0);
      b[0] = colour.x * invSamples;
      b[1] = colour.y * invSamples;
      b[2] = colour.z * invSamples;
      b[3] = float(covered) * invSamples;
      float* a = out.aovs.at(x - out.x0, y - out.y0);
      const float inv = float(1.0 / covered);
      const float len = glm::length(normalSum);
      if (len > 0.0f) {
        a[kN] = normalSum.x / len;
        a[kN + 1] = normalSum.y / len;
        a[kN + 2] = normalSum.z / len;
      }
      for (int c = 0; c < 3; ++c) {
        a[kP + c] = float(positionSum[c] / covered);
        a[kAlbedo + c] = albedoSum[c] * inv;
        a[kIrradiance + c] = irradianceSum[c] * inv * settings.exposure;
        a[kShadowed + c] = shadowedSum[c] * inv * settings.exposure;
      }
      // Depth is linear in the position: the mean position's depth is the samples' mean depth.
      // Through a fisheye, the mean position's distance along the ray: its points 90° or more
      // off the axis are not in front of it (their depth along the axis came out negative).
      const glm::dvec3 atCamera =
          glm::dvec3(cameraFromWorld * glm::dvec4(positionSum / covered, 1.0));
      a[kDepth] =
          float(camera.lens.projection == calib::Projection::Rectilinear ? -atCamera.z
                                                                         : glm::length(atCamera));
      a[kAo] = aoSum * inv;
    }
    hitsTotal += rowHits;
    sourceRays += rowSourceRays;
    cameraRaysTotal += rowCameraRays;
    plainPixels += rowPlain;
    tracedPixels += rowTraced;
    const int done = ++rowsDone;
    // Every row: a row can take seconds (Monte Carlo lighting at many samples per pixel).
    report(progress, "render", double(done) / std::max(h, 1));
  });
  out.rays = cameraRaysTotal + sourceRays;
  out.pixelsTraced = tracedPixels;
  out.pixelsPlain = plainPixels;
  out.coverage = hitsTotal * double(invSamples);
  report(progress, "render", 1.0);
  return out;
}

}  // namespace compose::render
