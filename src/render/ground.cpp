#include "render/ground.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#include <glm/geometric.hpp>
#include <glm/matrix.hpp>

#include "core/error.h"
#include "core/parallel.h"

namespace compose::render {

namespace {

// The ground point (object space) that the plate pixel (x, y) shows, if it lies in the grid's
// region of the ground.
bool groundPoint(const GroundGrid& grid, const glm::dmat4& objectFromWorld,
                 const calib::PlateCamera& camera, double x, double y, glm::vec3& out) {
  glm::dvec3 origin, dir;
  if (!camera.ray(x, y, origin, dir) || !(dir.y < -1e-9)) return false;
  const glm::dvec3 g = origin + dir * (-origin.y / dir.y);
  if (g.x < grid.regionX0 || g.x > grid.regionX1 || g.z < grid.regionZ0 || g.z > grid.regionZ1)
    return false;
  out = glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(g, 1.0)));
  return true;
}

// E_with / E_without at point p, per channel in [0, 1] (1 where the point gets no light).
glm::vec3 ratioAt(const VertexIrradiance& irradiance, size_t p) {
  const glm::vec3 un = irradiance.unshadowed[p], sh = irradiance.shadowed[p];
  glm::vec3 r(1.0f);
  for (int c = 0; c < 3; ++c) r[c] = un[c] > 1e-20f ? std::clamp(sh[c] / un[c], 0.0f, 1.0f) : 1.0f;
  return r;
}

std::vector<glm::vec3> nodeRatios(const std::vector<int>& node,
                                  const VertexIrradiance& irradiance) {
  std::vector<glm::vec3> out(node.size(), glm::vec3(1.0f));
  for (size_t n = 0; n < node.size(); ++n)
    if (node[n] >= 0) out[n] = ratioAt(irradiance, size_t(node[n]));
  return out;
}

}  // namespace

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
  if (behind) {
    // Part of the region is behind the camera: the part in front is bounded by the projections
    // of a fine lattice over the region (those in front of the camera), padded by a lattice cell
    // in the image; where none is in front, nothing of the ground is in view.
    constexpr int kLattice = 128;
    px0 = py0 = std::numeric_limits<double>::max(), px1 = py1 = -px0;
    for (int j = 0; j <= kLattice; ++j) {
      for (int i = 0; i <= kLattice; ++i) {
        const glm::dvec3 g(x0 + (x1 - x0) * i / kLattice, 0.0, z0 + (z1 - z0) * j / kLattice);
        glm::dvec2 px;
        if (!camera.project(g, px)) continue;
        px0 = std::min(px0, px.x), px1 = std::max(px1, px.x);
        py0 = std::min(py0, px.y), py1 = std::max(py1, px.y);
      }
    }
    if (px0 > px1) return grid;
    // Only the far side is trusted to the lattice: the ground nearer than its first row in front
    // of the camera can reach any of the other edges (a rolled camera, a low one), so the
    // rectangle keeps the frame's full width and reaches its bottom edge.
    const double pad = 2.0 * std::max(camera.width, camera.height) / kLattice;
    py0 -= pad;
    px0 = 0.0, px1 = camera.width, py1 = camera.height;
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
  grid.regionX0 = x0, grid.regionX1 = x1, grid.regionZ0 = z0, grid.regionZ1 = z1;
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  grid.points.size = std::max({extent.x, extent.y, extent.z});
  grid.points.centre = 0.5f * (mesh.boundsMin() + mesh.boundsMax());
  grid.points.radius = 0.5f * glm::length(extent);
  for (int j = 0; j < grid.rows; ++j) {
    for (int i = 0; i < grid.columns; ++i) {
      glm::vec3 g;
      if (!groundPoint(grid, objectFromWorld, camera, grid.x0 + i * grid.stride + 0.5,
                       grid.y0 + j * grid.stride + 0.5, g))
        continue;
      grid.node[size_t(j) * size_t(grid.columns) + size_t(i)] = int(grid.points.positions.size());
      grid.points.positions.push_back(g);
      grid.points.normals.emplace_back(0.0f, 1.0f, 0.0f);
    }
  }
  return grid;
}

size_t refineGroundGrid(GroundGrid& grid, const VertexIrradiance& irradiance,
                        const glm::dmat4& worldFromObject, const calib::PlateCamera& camera,
                        const GroundSettings& settings) {
  COMPOSE_CHECK(irradiance.shadowed.size() == grid.points.count());
  grid.steps = 0;
  grid.refinedCell.clear();
  grid.fineNode.clear();
  grid.finePoints = SurfacePoints{};
  grid.finePoints.size = grid.points.size;
  grid.finePoints.centre = grid.points.centre;
  grid.finePoints.radius = grid.points.radius;
  const int steps =
      std::clamp((grid.stride + settings.fineStride - 1) / std::max(1, settings.fineStride), 1, 16);
  const int cols = grid.columns, rows = grid.rows;
  if (steps < 2 || cols < 2 || rows < 2 || grid.empty()) return 0;
  const std::vector<glm::vec3> ratio = nodeRatios(grid.node, irradiance);
  auto at = [&](int i, int j) { return ratio[size_t(j) * size_t(cols) + size_t(i)]; };
  // How sharply the ratio bends at each node: its distance from the mean of its neighbours.
  std::vector<float> bend(ratio.size(), 0.0f);
  for (int j = 0; j < rows; ++j) {
    for (int i = 0; i < cols; ++i) {
      glm::vec3 b(0.0f);
      if (i > 0 && i + 1 < cols)
        b = glm::max(b, glm::abs(at(i, j) - 0.5f * (at(i - 1, j) + at(i + 1, j))));
      if (j > 0 && j + 1 < rows)
        b = glm::max(b, glm::abs(at(i, j) - 0.5f * (at(i, j - 1) + at(i, j + 1))));
      bend[size_t(j) * size_t(cols) + size_t(i)] = std::max({b.x, b.y, b.z});
    }
  }
  // The cells to refine, sharpest first, within the budget of new points.
  std::vector<std::pair<float, int>> sharp;
  for (int j = 0; j + 1 < rows; ++j) {
    for (int i = 0; i + 1 < cols; ++i) {
      const size_t n = size_t(j) * size_t(cols) + size_t(i);
      const float b =
          std::max({bend[n], bend[n + 1], bend[n + size_t(cols)], bend[n + size_t(cols) + 1]});
      if (b > settings.bend) sharp.emplace_back(b, j * (cols - 1) + i);
    }
  }
  std::sort(sharp.begin(), sharp.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  const size_t perCell = size_t(steps + 1) * size_t(steps + 1) - 4;
  const size_t cells = std::min(sharp.size(), settings.maxRefinedPoints / perCell);
  sharp.resize(cells);
  std::sort(sharp.begin(), sharp.end(),
            [](const auto& a, const auto& b) { return a.second < b.second; });
  grid.steps = steps;
  grid.refinedCell.assign(size_t(cols - 1) * size_t(rows - 1), -1);
  // Fine nodes shared by two refined cells are made once: keyed by their place on the fine
  // lattice.
  std::unordered_map<uint64_t, int> made;
  const int first = int(grid.points.count());
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  for (const auto& [b, cell] : sharp) {
    const int i = cell % (cols - 1), j = cell / (cols - 1);
    grid.refinedCell[size_t(cell)] = int(grid.fineNode.size() / size_t((steps + 1) * (steps + 1)));
    for (int fb = 0; fb <= steps; ++fb) {
      for (int fa = 0; fa <= steps; ++fa) {
        if ((fa == 0 || fa == steps) && (fb == 0 || fb == steps)) {
          // A corner: the grid's own node.
          grid.fineNode.push_back(
              grid.node[size_t(j + fb / steps) * size_t(cols) + size_t(i + fa / steps)]);
          continue;
        }
        const uint64_t key = (uint64_t(uint32_t(j * steps + fb)) << 32) | uint32_t(i * steps + fa);
        auto [it, inserted] = made.try_emplace(key, -1);
        if (inserted) {
          glm::vec3 g;
          const double x = grid.x0 + (i + double(fa) / steps) * grid.stride + 0.5;
          const double y = grid.y0 + (j + double(fb) / steps) * grid.stride + 0.5;
          if (groundPoint(grid, objectFromWorld, camera, x, y, g)) {
            it->second = first + int(grid.finePoints.positions.size());
            grid.finePoints.positions.push_back(g);
            grid.finePoints.normals.emplace_back(0.0f, 1.0f, 0.0f);
          }
        }
        grid.fineNode.push_back(it->second);
      }
    }
  }
  return cells;
}

Image groundRatio(const GroundGrid& grid, const VertexIrradiance& irradiance,
                  const VertexIrradiance& fine) {
  COMPOSE_CHECK(irradiance.shadowed.size() == grid.points.count());
  COMPOSE_CHECK(fine.shadowed.size() == grid.finePoints.count());
  const int w = grid.x1 - grid.x0, h = grid.y1 - grid.y0;
  Image out(std::max(w, 0), std::max(h, 0), 3, {"shadow.R", "shadow.G", "shadow.B"});
  out.colorSpace = "Raw";
  std::fill(out.pixels.begin(), out.pixels.end(), 1.0f);
  if (grid.empty()) return out;
  // The ratio at each grid node and at each refined cell's fine node (1 where there is no
  // ground point).
  const std::vector<glm::vec3> nodeRatio = nodeRatios(grid.node, irradiance);
  std::vector<glm::vec3> fineRatio(grid.fineNode.size(), glm::vec3(1.0f));
  const int first = int(grid.points.count());
  for (size_t n = 0; n < grid.fineNode.size(); ++n) {
    const int p = grid.fineNode[n];
    if (p >= first)
      fineRatio[n] = ratioAt(fine, size_t(p - first));
    else if (p >= 0)
      fineRatio[n] = ratioAt(irradiance, size_t(p));
  }
  const int steps = grid.steps, side = steps + 1;
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
      const int block = grid.refinedCell.empty()
                            ? -1
                            : grid.refinedCell[size_t(j) * size_t(grid.columns - 1) + size_t(i)];
      glm::vec3 r;
      if (block < 0) {
        auto at = [&](int ii, int jj) {
          return nodeRatio[size_t(jj) * size_t(grid.columns) + size_t(ii)];
        };
        r = (at(i, j) * (1 - fx) + at(i + 1, j) * fx) * (1 - fy) +
            (at(i, j + 1) * (1 - fx) + at(i + 1, j + 1) * fx) * fy;
      } else {
        // Within a refined cell: the same on its fine grid.
        const float sx = fx * float(steps), sy = fy * float(steps);
        const int a = std::min(int(sx), steps - 1), b = std::min(int(sy), steps - 1);
        const float gx2 = sx - float(a), gy2 = sy - float(b);
        const glm::vec3* f = fineRatio.data() + size_t(block) * size_t(side * side);
        auto at = [&](int aa, int bb) { return f[size_t(bb) * size_t(side) + size_t(aa)]; };
        r = (at(a, b) * (1 - gx2) + at(a + 1, b) * gx2) * (1 - gy2) +
            (at(a, b + 1) * (1 - gx2) + at(a + 1, b + 1) * gx2) * gy2;
      }
      float* o = out.at(x, y);
      o[0] = r.x, o[1] = r.y, o[2] = r.z;
    }
  });
  return out;
}

}  // namespace compose::render
