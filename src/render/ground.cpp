#include "render/ground.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
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

// Samples lattice node (a, b) if it has not been: its ground point as a new (pending) point, or
// -1 where the pixel shows no ground of the region.
void makeNode(GroundGrid& grid, const glm::dmat4& objectFromWorld, const calib::PlateCamera& camera,
              int a, int b) {
  const size_t n = size_t(b) * size_t(grid.columns) + size_t(a);
  if (grid.node[n] != -2) return;
  glm::vec3 g;
  if (!groundPoint(grid, objectFromWorld, camera, grid.x0 + a * grid.unit + 0.5,
                   grid.y0 + b * grid.unit + 0.5, g)) {
    grid.node[n] = -1;
    return;
  }
  grid.node[n] = int(grid.points.count());
  grid.points.positions.push_back(g);
  grid.points.normals.emplace_back(0.0f, 1.0f, 0.0f);
  grid.pointNode.push_back(uint32_t(n));
}

// The largest of the three channels.
float largest(const glm::vec3& v) {
  return std::max({v.x, v.y, v.z});
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
  // A region a few pixels across (a small or far object seen at a grazing angle: a band of a few
  // rows) is sampled at every few of them: its first nodes, 2^coarse strides apart, fell outside
  // it (no shadow at all, "no ground in view"), or a handful fell where the lattice happened to.
  const int shorter = std::min(w, h);
  grid.stride = std::min(grid.stride, std::max(1, shorter / 4));
  // Below the base stride, halvings down to about fineStride pixels (at most 3: the lattice stays
  // within 64 times the base grid's nodes).
  grid.fine = 0;
  while (grid.fine < 3 && (grid.stride >> grid.fine) > std::max(1, settings.fineStride) &&
         double(grid.stride) / double(1 << (grid.fine + 1)) >= 1.0)
    ++grid.fine;
  grid.coarse = std::clamp(settings.coarseLevels, 0, 6);
  while (grid.coarse > 0 && (grid.stride << grid.coarse) * 8 > shorter) --grid.coarse;
  grid.unit = double(grid.stride) / double(1 << grid.fine);
  const int first = grid.firstStride(), cells = 1 << grid.levels();
  const int firstColumns = (w + first - 1) / first + 1, firstRows = (h + first - 1) / first + 1;
  grid.columns = (firstColumns - 1) * cells + 1;
  grid.rows = (firstRows - 1) * cells + 1;
  const size_t lattice = size_t(grid.columns) * size_t(grid.rows);
  grid.node.assign(lattice, -2);
  grid.ratio.assign(lattice, glm::vec3(1.0f));
  grid.split.resize(size_t(grid.levels()));
  grid.splitCount.assign(size_t(grid.levels()), 0);
  for (int l = 0; l < grid.levels(); ++l) {
    const size_t side = size_t(1) << l;
    grid.split[size_t(l)].assign(size_t(firstColumns - 1) * side * size_t(firstRows - 1) * side, 0);
  }

  // What the refinement asks about: the region, the object's bounding sphere, the sources.
  grid.regionX0 = x0, grid.regionX1 = x1, grid.regionZ0 = z0, grid.regionZ1 = z1;
  const glm::dvec3 centre = 0.5 * (glm::dvec3(mesh.boundsMin()) + glm::dvec3(mesh.boundsMax()));
  grid.sphereCentre = glm::dvec3(worldFromObject * glm::dvec4(centre, 1.0));
  const double objectRadius =
      0.5 * glm::length(glm::dvec3(mesh.boundsMax()) - glm::dvec3(mesh.boundsMin()));
  grid.sphereRadius = objectRadius * glm::length(glm::dvec3(worldFromObject[0]));
  grid.sources = sources;

  // The first points: every `first` pixels. Ground points are in the object's own coordinates;
  // the ground's normal there is +Y (the placement only turns the object about +Y and scales it).
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  grid.points.size = std::max({extent.x, extent.y, extent.z});
  grid.points.centre = 0.5f * (mesh.boundsMin() + mesh.boundsMax());
  grid.points.radius = 0.5f * glm::length(extent);
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  for (int b = 0; b < grid.rows; b += cells)
    for (int a = 0; a < grid.columns; a += cells) makeNode(grid, objectFromWorld, camera, a, b);
  return grid;
}

float GroundGrid::seenFraction(size_t p, int i) const {
  if (p < partial.size() && ((partial[p] >> i) & 1u))
    return partialFraction[partialFirst[p] +
                           uint32_t(std::popcount(partial[p] & ((uint64_t(1) << i) - 1)))];
  return p < seen.size() ? float((seen[p] >> i) & 1u) : 1.0f;
}

SurfacePoints GroundGrid::pending() const {
  SurfacePoints out;
  out.size = points.size, out.centre = points.centre, out.radius = points.radius;
  out.positions.assign(points.positions.begin() + std::ptrdiff_t(shaded), points.positions.end());
  out.normals.assign(points.normals.begin() + std::ptrdiff_t(shaded), points.normals.end());
  return out;
}

void shadeGroundPoints(GroundGrid& grid, const VertexIrradiance& irradiance) {
  const size_t count = grid.points.count() - grid.shaded;
  COMPOSE_CHECK(irradiance.shadowed.size() == count && irradiance.unshadowed.size() == count);
  const bool bits = irradiance.sourceSeen.size() == count;
  const bool fractions = bits && irradiance.sourcePartial.size() == count &&
                         irradiance.partialFirst.size() == count + 1;
  grid.seen.resize(grid.points.count(), ~uint64_t(0));
  grid.partial.resize(grid.points.count(), 0);
  grid.partialFirst.resize(grid.points.count(), uint32_t(grid.partialFraction.size()));
  for (size_t k = 0; k < count; ++k) {
    const size_t p = grid.shaded + k;
    grid.ratio[grid.pointNode[p]] = ratioAt(irradiance, k);
    grid.partialFirst[p] = uint32_t(grid.partialFraction.size());
    if (fractions) {
      grid.partial[p] = irradiance.sourcePartial[k];
      for (int i = 0; i < 64; ++i)
        if ((grid.partial[p] >> i) & 1u)
          grid.partialFraction.push_back(irradiance.seenFraction(k, i));
    }
    if (bits) grid.seen[p] = irradiance.sourceSeen[k];
    if (p == 0) grid.open = irradiance.unshadowed[k];
  }
  grid.shaded = grid.points.count();
}

bool refineGroundGrid(GroundGrid& grid, const EmbreeScene& scene, const glm::dmat4& worldFromObject,
                      const calib::PlateCamera& camera, const GroundSettings& settings) {
  COMPOSE_CHECK(grid.shaded == grid.points.count());
  if (grid.level >= grid.levels() || grid.empty()) return false;
  const int l = grid.level++;
  const bool coarse = l < grid.coarse;
  const float threshold = coarse ? settings.spread : settings.sharp;
  const int size = 1 << (grid.levels() - l), half = size / 2;
  const int across = (grid.columns - 1) / size, down = (grid.rows - 1) / size;
  // The sources that alone can change the ratio by more than the threshold: their irradiance on
  // the ground over the ground's, and their mask in the points' `seen` bits.
  uint64_t strong = 0;
  std::vector<glm::dvec3> strongDirections;
  for (size_t i = 0; i < grid.sources.size() && i < 64; ++i) {
    const lighting::LightSource& s = grid.sources[i];
    const glm::dvec3 d = glm::normalize(glm::dvec3(s.direction));
    if (d.y <= 0.0) continue;
    float weight = 0.0f;
    for (int c = 0; c < 3; ++c)
      if (grid.open[c] > 1e-20f) weight = std::max(weight, float(s.power[c] * d.y) / grid.open[c]);
    if (weight <= threshold) continue;
    strong |= uint64_t(1) << i;
    strongDirections.push_back(d);
  }
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  auto nodeAt = [&](int a, int b) { return size_t(b) * size_t(grid.columns) + size_t(a); };
  auto seenAt = [&](int a, int b) {
    const int p = grid.node[nodeAt(a, b)];
    return p >= 0 ? grid.seen[size_t(p)] : ~uint64_t(0);
  };
  // The ground point (world) a lattice position shows, if any.
  auto worldPoint = [&](double a, double b, glm::dvec3& g) {
    glm::dvec3 origin, dir;
    if (!camera.ray(grid.x0 + a * grid.unit + 0.5, grid.y0 + b * grid.unit + 0.5, origin, dir) ||
        !(dir.y < -1e-9))
      return false;
    g = origin + dir * (-origin.y / dir.y);
    return true;
  };
  // Whether a strong source may cast the object's shadow into the cell: the bounding sphere's
  // shadow comes within the cell's reach of its centre.
  auto mayHoldShadow = [&](int a, int b) {
    glm::dvec3 c;
    if (strongDirections.empty() || !worldPoint(a + 0.5 * size, b + 0.5 * size, c)) return false;
    double reach = 0.0;
    for (const auto& [da, db] : {std::pair{0, 0}, {size, 0}, {0, size}, {size, size}}) {
      glm::dvec3 g;
      if (!worldPoint(a + da, b + db, g)) return true;  // reaching the horizon: take no risk
      reach = std::max(reach, glm::length(g - c));
    }
    for (const glm::dvec3& d : strongDirections) {
      const double t = std::max(0.0, glm::dot(grid.sphereCentre - c, d));
      if (glm::length(grid.sphereCentre - (c + t * d)) <= grid.sphereRadius + reach) return true;
    }
    return false;
  };
  // Whether the object hides the plate pixel of lattice position (a, b) from the camera: less
  // than 1/512 of it shows through (a semi-transparent object lets the plate show).
  grid.hidden.resize(grid.node.size(), -1);
  auto hiddenAt = [&](int a, int b) {
    int8_t& h = grid.hidden[nodeAt(a, b)];
    if (h < 0) {
      glm::dvec3 origin, dir;
      h = 0;
      if (camera.ray(grid.x0 + a * grid.unit + 0.5, grid.y0 + b * grid.unit + 0.5, origin, dir)) {
        const glm::dvec3 o = glm::dvec3(objectFromWorld * glm::dvec4(origin, 1.0));
        const glm::dvec3 d = glm::dvec3(objectFromWorld * glm::dvec4(dir, 0.0));
        const glm::vec3 direction(glm::normalize(d));
        float through = 1.0f;
        scene.transmittanceStream(glm::vec3(o), &direction, 1, 0.0f, &through);
        h = through < 1.0f / 512.0f ? 1 : 0;
      }
    }
    return h == 1;
  };
  // A cell hidden at its corners, edges' midpoints and centre shows no ground.
  auto cellHidden = [&](int a, int b) {
    for (int db = 0; db <= size; db += half)
      for (int da = 0; da <= size; da += half)
        if (!hiddenAt(a + da, b + db)) return false;
    return true;
  };
  std::vector<uint8_t>& split = grid.split[size_t(l)];
  // The cells of this level that exist (their parent was split) and need splitting, with how
  // much the ratio may change inside them.
  std::vector<std::pair<float, int>> wanted;
  for (int j = 0; j < down; ++j) {
    for (int i = 0; i < across; ++i) {
      if (l > 0 && !grid.split[size_t(l - 1)][size_t(j / 2) * size_t(across / 2) + size_t(i / 2)])
        continue;
      const int a = i * size, b = j * size;
      const glm::vec3 r[4] = {grid.ratio[nodeAt(a, b)], grid.ratio[nodeAt(a + size, b)],
                              grid.ratio[nodeAt(a, b + size)],
                              grid.ratio[nodeAt(a + size, b + size)]};
      float change = largest(glm::max(glm::max(r[0], r[1]), glm::max(r[2], r[3])) -
                             glm::min(glm::min(r[0], r[1]), glm::min(r[2], r[3])));
      const uint64_t s0 = seenAt(a, b), s1 = seenAt(a + size, b), s2 = seenAt(a, b + size),
                     s3 = seenAt(a + size, b + size);
      if (((s0 ^ s1) | (s0 ^ s2) | (s0 ^ s3)) & strong) change = std::max(change, 1.0f);
      if (change <= threshold && coarse && mayHoldShadow(a, b)) change = threshold * 1.0001f;
      if (change > threshold && !cellHidden(a, b)) wanted.emplace_back(change, j * across + i);
    }
  }
  if (!coarse) {
    // Within the budget of points below the base stride, the sharpest first.
    std::sort(wanted.begin(), wanted.end(), [](const auto& x, const auto& y) {
      return x.first != y.first ? x.first > y.first : x.second < y.second;
    });
    size_t made = 0;
    for (int f = grid.coarse; f < l; ++f) made += grid.splitCount[size_t(f)] * 5;
    const size_t room = settings.maxRefinedPoints > made ? settings.maxRefinedPoints - made : 0;
    wanted.resize(std::min(wanted.size(), room / 5));
    std::sort(wanted.begin(), wanted.end(),
              [](const auto& x, const auto& y) { return x.second < y.second; });
  }
  for (const auto& [change, cell] : wanted) {
    split[size_t(cell)] = 1;
    const int a = (cell % across) * size, b = (cell / across) * size;
    makeNode(grid, objectFromWorld, camera, a + half, b);
    makeNode(grid, objectFromWorld, camera, a, b + half);
    makeNode(grid, objectFromWorld, camera, a + half, b + half);
    makeNode(grid, objectFromWorld, camera, a + size, b + half);
    makeNode(grid, objectFromWorld, camera, a + half, b + size);
  }
  grid.splitCount[size_t(l)] = wanted.size();
  return true;
}

Image groundRatio(const GroundGrid& grid) {
  const int w = grid.x1 - grid.x0, h = grid.y1 - grid.y0;
  Image out(std::max(w, 0), std::max(h, 0), 3, {"shadow.R", "shadow.G", "shadow.B"});
  out.colorSpace = "Raw";
  std::fill(out.pixels.begin(), out.pixels.end(), 1.0f);
  if (grid.empty()) return out;
  const int levels = grid.levels(), top = 1 << levels;
  const int across0 = (grid.columns - 1) / top, down0 = (grid.rows - 1) / top;
  auto nodeAt = [&](int a, int b) { return size_t(b) * size_t(grid.columns) + size_t(a); };
  // Continuity where a cell meets finer ones: the nodes inside its edges take the edge's
  // interpolation, coarse cells first (their corners may lie on a coarser cell's edge).
  std::vector<glm::vec3> ratio = grid.ratio;
  // Where the first cells are not split (the ratio changes little there), each first node's ratio
  // is the mean of its own and its neighbours' on the first lattice (3 x 3): a point's ratio is a
  // noisy estimate (the object's outline is sampled by a few rays per cell), and spread over
  // whole first cells that noise would show as blotches; averaged, it is three times smaller.
  if (levels > 0) {
    const std::vector<uint8_t>& split0 = grid.split[0];
    auto leaf = [&](int i, int j) {  // first cell (i, j), or none outside the lattice: not split
      return i < 0 || j < 0 || i >= across0 || j >= down0 ||
             !split0[size_t(j) * size_t(across0) + size_t(i)];
    };
    const std::vector<glm::vec3> first = ratio;
    for (int j = 0; j <= down0; ++j) {
      for (int i = 0; i <= across0; ++i) {
        const size_t n = nodeAt(i * top, j * top);
        if (grid.node[n] < 0) continue;
        if (!leaf(i - 1, j - 1) || !leaf(i, j - 1) || !leaf(i - 1, j) || !leaf(i, j)) continue;
        glm::vec3 sum(0.0f);
        int count = 0;
        for (int jj = std::max(0, j - 1); jj <= std::min(down0, j + 1); ++jj) {
          for (int ii = std::max(0, i - 1); ii <= std::min(across0, i + 1); ++ii) {
            const size_t m = nodeAt(ii * top, jj * top);
            if (grid.node[m] < 0) continue;
            sum += first[m];
            ++count;
          }
        }
        ratio[n] = sum / float(count);
      }
    }
  }
  for (int l = 0; l < levels; ++l) {
    const int size = 1 << (levels - l);
    const int across = across0 << l, down = down0 << l;
    for (int j = 0; j < down; ++j) {
      for (int i = 0; i < across; ++i) {
        if (l > 0 && !grid.split[size_t(l - 1)][size_t(j / 2) * size_t(across / 2) + size_t(i / 2)])
          continue;  // not a cell of this level
        if (grid.split[size_t(l)][size_t(j) * size_t(across) + size_t(i)]) continue;  // not a leaf
        const int a = i * size, b = j * size;
        auto edge = [&](int a0, int b0, int da, int db) {
          const glm::vec3 r0 = ratio[nodeAt(a0, b0)],
                          r1 = ratio[nodeAt(a0 + da * size, b0 + db * size)];
          for (int t = 1; t < size; ++t) {
            const size_t n = nodeAt(a0 + da * t, b0 + db * t);
            if (grid.node[n] >= 0) ratio[n] = r0 + (r1 - r0) * (float(t) / float(size));
          }
        };
        edge(a, b, 1, 0);
        edge(a, b + size, 1, 0);
        edge(a, b, 0, 1);
        edge(a + size, b, 0, 1);
      }
    }
  }
  const double inv = 1.0 / grid.unit;
  parallelFor(0, h, [&](int64_t yy) {
    const double v = double(yy) * inv;
    for (int x = 0; x < w; ++x) {
      const double u = double(x) * inv;
      // The leaf cell that holds (u, v): down the levels while the cell is split.
      int l = 0, size = top;
      int i = std::min(int(u / size), across0 - 1), j = std::min(int(v / size), down0 - 1);
      while (l < levels && grid.split[size_t(l)][size_t(j) * size_t(across0 << l) + size_t(i)]) {
        ++l;
        size >>= 1;
        i = std::clamp(int(u / size), 2 * i, 2 * i + 1);
        j = std::clamp(int(v / size), 2 * j, 2 * j + 1);
      }
      const int a = i * size, b = j * size;
      const float fx = float(std::clamp((u - a) / size, 0.0, 1.0));
      const float fy = float(std::clamp((v - b) / size, 0.0, 1.0));
      const glm::vec3 r =
          (ratio[nodeAt(a, b)] * (1 - fx) + ratio[nodeAt(a + size, b)] * fx) * (1 - fy) +
          (ratio[nodeAt(a, b + size)] * (1 - fx) + ratio[nodeAt(a + size, b + size)] * fx) * fy;
      float* o = out.at(x, int(yy));
      o[0] = r.x, o[1] = r.y, o[2] = r.z;
    }
  });
  return out;
}

int64_t sharpenGroundEdges(const GroundGrid& grid, Image& ratio, const EmbreeScene& scene,
                           const glm::dmat4& worldFromObject, const calib::PlateCamera& camera,
                           const GroundSettings& settings) {
  const int levels = grid.levels();
  if (grid.empty() || levels == 0 || grid.split.empty()) return 0;
  // The sources that change the ratio by more than a fiftieth of the sharp threshold, and what
  // each adds to it where it is seen.
  uint64_t strong = 0;
  std::vector<glm::vec3> share(64, glm::vec3(0.0f));
  for (size_t i = 0; i < grid.sources.size() && i < 64; ++i) {
    const lighting::LightSource& src = grid.sources[i];
    const glm::vec3 d = glm::normalize(src.direction);
    if (d.y <= 0.0f) continue;
    float weight = 0.0f;
    for (int c = 0; c < 3; ++c) {
      share[i][c] = grid.open[c] > 1e-20f ? src.power[c] * d.y / grid.open[c] : 0.0f;
      weight = std::max(weight, share[i][c]);
    }
    // (A sun split into several sources: each may be below the sharp threshold, their edges
    // together are not.)
    if (weight > 0.02f * settings.sharp) strong |= uint64_t(1) << i;
  }
  if (strong == 0) return 0;
  const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
  auto nodeAt = [&](int a, int b) { return size_t(b) * size_t(grid.columns) + size_t(a); };
  // The finest cells: one lattice unit, inside the cells of the last level that were split.
  const int last = levels - 1, parent = 2;
  const int across = (grid.columns - 1) / parent, down = (grid.rows - 1) / parent;
  const std::vector<uint8_t>& split = grid.split[size_t(last)];
  std::vector<std::array<int, 2>> cells;
  for (int j = 0; j < down; ++j)
    for (int i = 0; i < across; ++i)
      if (split[size_t(j) * size_t(across) + size_t(i)])
        for (int q = 0; q < 4; ++q) cells.push_back({2 * i + q % 2, 2 * j + q / 2});
  const double lift = 1e-4 * grid.sphereRadius;
  // Each strong source's four directions (object frame), one to each quarter of its extent, in
  // the order of a pixel's 2 x 2 samples.
  std::vector<std::array<glm::vec3, 4>> quarters(64);
  for (int i = 0; i < 64; ++i) {
    if (!((strong >> i) & 1u)) continue;
    const lighting::LightSource& src = grid.sources[size_t(i)];
    const glm::dvec3 d = glm::normalize(glm::dvec3(src.direction));
    const glm::dvec3 east =
        glm::normalize(glm::cross(glm::dvec3(0, 1, 0), d) + glm::dvec3(1e-12, 0, 0));
    const glm::dvec3 north = glm::cross(d, east);
    for (int q = 0; q < 4; ++q) {
      const double du =
          (q % 2 - 0.5) * double(src.halfLongitude) * std::sqrt(std::max(0.0, 1.0 - d.y * d.y));
      const double dv = (q / 2 - 0.5) * double(src.halfLatitude);
      const glm::dvec3 jittered = glm::normalize(d + east * du + north * dv);
      quarters[size_t(i)][size_t(q)] =
          glm::vec3(glm::normalize(glm::dvec3(objectFromWorld * glm::dvec4(jittered, 0.0))));
    }
  }
  std::atomic<int64_t> rays{0};
  parallelFor(0, int64_t(cells.size()), [&](int64_t k) {
    const int a = cells[size_t(k)][0], b = cells[size_t(k)][1];
    // The strong sources whose visibility differs at the cell's corners (or a corner shows no
    // ground): the bilinear ratio draws their shadow's edge as the cell's square.
    uint64_t all = ~uint64_t(0), any = 0;
    uint64_t corner[4];
    int cornerPoint[4];
    for (int q = 0; q < 4; ++q) {
      const int p = grid.node[nodeAt(a + q % 2, b + q / 2)];
      if (p < 0 || size_t(p) >= grid.seen.size()) return;
      cornerPoint[q] = p;
      corner[q] = grid.seen[size_t(p)];
      all &= corner[q];
      any |= corner[q];
    }
    const uint64_t differ = (any & ~all) & strong;
    if (differ == 0) return;
    glm::vec3 directions[64];
    int sources[64], count = 0;
    for (int i = 0; i < 64; ++i)
      if ((differ >> i) & 1u) sources[count++] = i;
    int64_t traced = 0;
    const int px0 = int(std::ceil(a * grid.unit)), px1 = int(std::ceil((a + 1) * grid.unit));
    const int py0 = int(std::ceil(b * grid.unit)), py1 = int(std::ceil((b + 1) * grid.unit));
    for (int y = std::max(py0, 0); y < std::min(py1, ratio.height); ++y) {
      for (int x = std::max(px0, 0); x < std::min(px1, ratio.width); ++x) {
        // The pixel's bilinear share of each source (as groundRatio weighs the corners), and its
        // own: 2 x 2 samples across the pixel, each to its own quarter of the source's extent.
        const double u = double(x) / grid.unit - a, v = double(y) / grid.unit - b;
        const double wq[4] = {(1 - u) * (1 - v), u * (1 - v), (1 - u) * v, u * v};
        float seenHere[64] = {};
        int samples = 0;
        for (int sy = 0; sy < 2; ++sy) {
          for (int sx = 0; sx < 2; ++sx) {
            glm::vec3 g;
            glm::dvec3 origin, dir;
            if (!camera.ray(grid.x0 + x + 0.25 + 0.5 * sx, grid.y0 + y + 0.25 + 0.5 * sy, origin,
                            dir) ||
                !(dir.y < -1e-9))
              continue;
            const glm::dvec3 world = origin + dir * (-origin.y / dir.y) + glm::dvec3(0, lift, 0);
            g = glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(world, 1.0)));
            for (int n = 0; n < count; ++n)
              directions[n] = quarters[size_t(sources[n])][size_t(2 * sy + sx)];
            float through[64];
            scene.transmittanceStream(g, directions, size_t(count), 0.0f, through);
            traced += count;
            for (int n = 0; n < count; ++n) seenHere[n] += through[n];
            ++samples;
          }
        }
        if (samples == 0) continue;
        float* o = ratio.at(x, y);
        for (int n = 0; n < count; ++n) {
          double bilinear = 0.0;
          for (int q = 0; q < 4; ++q)
            bilinear += wq[q] * double(grid.seenFraction(size_t(cornerPoint[q]), sources[n]));
          const float change = seenHere[n] / float(samples) - float(bilinear);
          for (int c = 0; c < 3; ++c) o[c] += change * share[size_t(sources[n])][c];
        }
        for (int c = 0; c < 3; ++c) o[c] = std::clamp(o[c], 0.0f, 1.0f);
      }
    }
    rays += traced;
  });
  return rays.load();
}

}  // namespace compose::render
