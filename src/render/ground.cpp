#include "render/ground.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <glm/geometric.hpp>
#include <glm/matrix.hpp>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::render {

GroundGrid groundGrid(const Mesh& mesh, const glm::dmat4& worldFromObject,
                      const calib::PlateCamera& camera,
                      const std::vector<lighting::LightSource>& sources,
                      const GroundSettings& settings) {
  GroundGrid grid;
  // The object's footprint on the ground and its height, in world units.
  glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
  for (const glm::vec3& p : mesh.positions) {
    const glm::dvec3 w = glm::dvec3(worldFromObject * glm::dvec4(glm::dvec3(p), 1.0));
    lo = glm::min(lo, w);
    hi = glm::max(hi, w);
  }
  const double height = std::max(hi.y, 1e-9);
  double x0 = lo.x - settings.reach * height, x1 = hi.x + settings.reach * height;
  double z0 = lo.z - settings.reach * height, z1 = hi.z + settings.reach * height;
  // Stretch away from the brightest sources above the horizon, as far as their shadows reach.
  std::vector<lighting::LightSource> bright = sources;
  std::sort(bright.begin(), bright.end(), [](const auto& a, const auto& b) {
    return a.power.x + a.power.y + a.power.z > b.power.x + b.power.y + b.power.z;
  });
  if (bright.size() > 8) bright.resize(8);
  for (const lighting::LightSource& s : bright) {
    const glm::dvec3 d = glm::normalize(glm::dvec3(s.direction));
    if (d.y <= 1e-3) continue;
    const double horizontal = std::sqrt(d.x * d.x + d.z * d.z);
    const double length = std::min(height * horizontal / d.y, settings.maxReach * height);
    if (horizontal < 1e-9) continue;
    const double dx = -d.x / horizontal * length, dz = -d.z / horizontal * length;
    x0 = std::min(x0, lo.x + dx), x1 = std::max(x1, hi.x + dx);
    z0 = std::min(z0, lo.z + dz), z1 = std::max(z1, hi.z + dz);
  }
  // The plate rectangle that shows the region: its corners and edges projected; where part of
  // the region is behind the camera, everything below the horizon.
  double px0 = std::numeric_limits<double>::max(), py0 = px0, px1 = -px0, py1 = -px0;
  bool behind = false;
  constexpr int kSteps = 8;
  const glm::dvec3 corner[4] = {{x0, 0.0, z0}, {x1, 0.0, z0}, {x1, 0.0, z1}, {x0, 0.0, z1}};
  for (int e = 0; e < 4; ++e) {
    const glm::dvec3 a = corner[e], b = corner[(e + 1) % 4];
    for (int i = 0; i <= kSteps; ++i) {
      glm::dvec2 px;
      if (!camera.project(a + (b - a) * (double(i) / kSteps), px)) {
        behind = true;
        continue;
      }
      px0 = std::min(px0, px.x), px1 = std::max(px1, px.x);
      py0 = std::min(py0, px.y), py1 = std::max(py1, px.y);
    }
  }
  if (behind) {  // the whole frame; pixels above the horizon get no ground point
    px0 = 0.0, px1 = camera.width, py0 = 0.0, py1 = camera.height;
  }
  constexpr double kLimit = 1e7;
  auto clampInt = [&](double v, int lo_, int hi_) {
    return std::clamp(int(std::clamp(v, -kLimit, kLimit)), lo_, hi_);
  };
  grid.x0 = clampInt(std::floor(px0) - 1, 0, camera.width);
  grid.x1 = clampInt(std::ceil(px1) + 1, 0, camera.width);
  grid.y0 = clampInt(std::floor(py0) - 1, 0, camera.height);
  grid.y1 = clampInt(std::ceil(py1) + 1, 0, camera.height);
  const int w = std::max(0, grid.x1 - grid.x0), h = std::max(0, grid.y1 - grid.y0);
  if (w == 0 || h == 0) return grid;
  grid.stride = std::max(1, int(std::ceil(std::sqrt(double(w) * h / double(settings.maxPoints)))));
  grid.columns = (w + grid.stride - 1) / grid.stride + 1;
  grid.rows = (h + grid.stride - 1) / grid.stride + 1;
  grid.node.assign(size_t(grid.columns) * size_t(grid.rows), -1);

  // Ground points of the grid's pixels, in the object's own coordinates; the ground's normal
  // there is +Y (the placement only turns the object about +Y and scales it).
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  grid.points.size = std::max({extent.x, extent.y, extent.z});
  grid.points.centre = 0.5f * (mesh.boundsMin() + mesh.boundsMax());
  grid.points.radius = 0.5f * glm::length(extent);
  for (int j = 0; j < grid.rows; ++j) {
    for (int i = 0; i < grid.columns; ++i) {
      const double x = grid.x0 + i * grid.stride + 0.5, y = grid.y0 + j * grid.stride + 0.5;
      glm::dvec3 origin, dir;
      if (!camera.ray(x, y, origin, dir) || !(dir.y < -1e-9)) continue;
      const glm::dvec3 g = origin + dir * (-origin.y / dir.y);
      if (g.x < x0 || g.x > x1 || g.z < z0 || g.z > z1) continue;
      grid.node[size_t(j) * size_t(grid.columns) + size_t(i)] = int(grid.points.positions.size());
      grid.points.positions.push_back(glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(g, 1.0))));
      grid.points.normals.emplace_back(0.0f, 1.0f, 0.0f);
    }
  }
  return grid;
}

Image groundRatio(const GroundGrid& grid, const VertexIrradiance& irradiance) {
  COMPOSE_CHECK(irradiance.shadowed.size() == grid.points.count());
  const int w = grid.x1 - grid.x0, h = grid.y1 - grid.y0;
  Image out(std::max(w, 0), std::max(h, 0), 3, {"shadow.R", "shadow.G", "shadow.B"});
  out.colorSpace = "Raw";
  std::fill(out.pixels.begin(), out.pixels.end(), 1.0f);
  if (grid.empty()) return out;
  // The ratio at each grid node (1 where there is no ground point).
  std::vector<glm::vec3> nodeRatio(grid.node.size(), glm::vec3(1.0f));
  for (size_t n = 0; n < grid.node.size(); ++n) {
    const int p = grid.node[n];
    if (p < 0) continue;
    const glm::vec3 un = irradiance.unshadowed[size_t(p)], sh = irradiance.shadowed[size_t(p)];
    for (int c = 0; c < 3; ++c)
      nodeRatio[n][c] = un[c] > 1e-20f ? std::clamp(sh[c] / un[c], 0.0f, 1.0f) : 1.0f;
  }
  const float inv = 1.0f / float(grid.stride);
  parallelFor(0, h, [&](int64_t yy) {
    const int y = int(yy);
    const float gy = float(y) * inv;
    const int j = std::min(int(gy), grid.rows - 2);
    const float fy = std::clamp(gy - float(j), 0.0f, 1.0f);
    for (int x = 0; x < w; ++x) {
      const float gx = float(x) * inv;
      const int i = std::min(int(gx), grid.columns - 2);
      const float fx = std::clamp(gx - float(i), 0.0f, 1.0f);
      auto at = [&](int ii, int jj) {
        return nodeRatio[size_t(jj) * size_t(grid.columns) + size_t(ii)];
      };
      const glm::vec3 r = (at(i, j) * (1 - fx) + at(i + 1, j) * fx) * (1 - fy) +
                          (at(i, j + 1) * (1 - fx) + at(i + 1, j + 1) * fx) * fy;
      float* o = out.at(x, y);
      o[0] = r.x, o[1] = r.y, o[2] = r.z;
    }
  });
  return out;
}

}  // namespace compose::render
