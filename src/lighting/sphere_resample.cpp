#include "lighting/sphere_resample.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <numbers>

#include <tbb/combinable.h>
#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::lighting {

// Derivation. Write a direction by its longitude φ = atan2(x, z) and s = y = sin(latitude). In the
// (φ, s) plane the solid angle is plain area, dω = ds dφ, and a lat-long cell is a rectangle. A
// cube texel is bounded by four great-circle arcs (a straight line on a face lies in a plane
// through the centre). By Green's theorem, for any region R of the plane and any f,
//
//     ∫∫_R f ds dφ = -∮_∂R F(φ, s) dφ,   F(φ, s) = ∫_{-1}^{s} f(φ, s') ds',
//
// the boundary taken counter-clockwise. With f the indicator of cell (i, j), F is
// clamp(s - s_bottom(i), 0, Δs_i) inside column j and 0 elsewhere. Along a piece of the texel's
// boundary that stays inside cell (i, j), the integral therefore gives
//   * to cell (i, j):              -∫ (s(φ) - s_bottom(i)) dφ
//   * to every cell (i', j) below: -Δs_i' Δφ            (accumulated per column, summed at the end)
// and a great circle with unit normal n (n_y ≠ 0) has, with ρ = |(n_x, n_z)|, ψ = φ + atan2(n_z,
// n_x),
//
//     s(φ) = -sign(n_y) ρ sin ψ / sqrt(n_y² + ρ² sin² ψ),     ∫ s dφ = sign(n_y) asin(ρ cos ψ),
//
// both closed form; it crosses the parallel of latitude λ where sin ψ = -n_y tan λ / ρ. Arcs in a
// plane through the y axis (meridians, n_y = 0) have dφ = 0 and contribute nothing. Every piece of
// every arc is thus integrated exactly; the only approximation is double rounding.
//
// The poles need one more segment. A texel that contains a pole (odd face sizes) or touches it with
// a corner (even sizes) has a boundary that does not close in the (φ, s) plane: it winds by 2π, or
// arrives at and leaves the pole along two different meridians. Closing it along the line s = ±1
// adds, at the north pole, F(φ, 1) = Δs_i for every row (a "below" term above row 0); at the south
// pole F = 0, but the column sums then run down to the last row. The orientation of the boundary
// is not tracked: a texel's overlaps all share one sign, made positive at the end.

namespace {

constexpr double kTwoPi = 2.0 * std::numbers::pi;

// Contributions of boundary pieces to one cell: `direct` for the cell the piece runs through,
// `below` (a multiple of -Δφ) for every cell under it in the same column.
struct Entry {
  int column, row;  // row -1: above the map (the north-pole closure)
  double direct, below;
};

class TexelIntegrator {
 public:
  TexelIntegrator(int width, int height, const std::vector<double>& rowTop,
                  const std::vector<double>& tanTop, std::vector<Entry>& entries)
      : width_(width), height_(height), rowTop_(rowTop), tanTop_(tanTop), entries_(entries) {}

  // Adds the arc from p to q (corner directions, any length).
  void arc(const glm::dvec3& p, const glm::dvec3& q) {
    const bool pPole = p.x == 0.0 && p.z == 0.0, qPole = q.x == 0.0 && q.z == 0.0;
    const glm::dvec3 n = glm::cross(p, q);
    if (pPole || qPole || n.y == 0.0) {
      // A meridian: constant longitude, nothing to integrate.
      const glm::dvec3& r = pPole ? q : p;
      setCurrent(std::atan2(r.x, r.z));
      return;
    }
    const double phiP = std::atan2(p.x, p.z), phiQ = std::atan2(q.x, q.z);
    const double delta = std::remainder(phiQ - phiP, kTwoPi);
    const double start = setCurrent(phiP);
    greatCircle(glm::normalize(n), start, start + delta);
    current_ = start + delta;
  }

  // Total longitude swept since the first arc.
  double winding() const { return current_ - first_; }

  // The closing segment along the north pole, from where the boundary ended back to its start.
  void closeNorth() {
    forEachColumnPiece(current_, first_, [&](int column, double dphi) {
      entries_.push_back({column, -1, 0.0, -dphi});
    });
  }

 private:
  // Makes `phi` the current longitude, unwrapped next to the previous one; returns it.
  double setCurrent(double phi) {
    if (!started_) {
      started_ = true;
      first_ = current_ = phi;
    } else {
      current_ = phi + kTwoPi * std::round((current_ - phi) / kTwoPi);
    }
    return current_;
  }

  double columnCoordinate(double phi) const { return (1.0 - phi / kPi) * 0.5 * width_; }
  double longitudeOfColumn(double c) const { return kPi * (1.0 - 2.0 * c / width_); }
  int wrapColumn(int c) const { return ((c % width_) + width_) % width_; }
  int rowOf(double s) const {
    const double lat = std::asin(std::clamp(s, -1.0, 1.0));
    return std::clamp(int(std::floor((0.5 - lat / kPi) * height_)), 0, height_ - 1);
  }

  // Splits [from, to] (either order) at column boundaries; calls f(column, signed Δφ).
  template <class F>
  void forEachColumnPiece(double from, double to, F&& f) const {
    if (from == to) return;
    const double lo = std::min(from, to), hi = std::max(from, to);
    std::vector<double>& bp = scratch_;
    bp.clear();
    bp.push_back(lo);
    const double cFirst = columnCoordinate(hi), cLast = columnCoordinate(lo);
    for (double c = std::floor(cFirst) + 1.0; c < cLast; c += 1.0)
      bp.push_back(longitudeOfColumn(c));
    bp.push_back(hi);
    std::sort(bp.begin(), bp.end());
    const double sign = to > from ? 1.0 : -1.0;
    for (size_t k = 0; k + 1 < bp.size(); ++k) {
      if (!(bp[k + 1] > bp[k])) continue;
      const double mid = 0.5 * (bp[k] + bp[k + 1]);
      f(wrapColumn(int(std::floor(columnCoordinate(mid)))), sign * (bp[k + 1] - bp[k]));
    }
  }

  // The arc of the great circle with unit normal n from longitude `from` to `to` (|to - from| < π).
  void greatCircle(const glm::dvec3& n, double from, double to) {
    const double ny = n.y, rho = std::hypot(n.x, n.z), beta = std::atan2(n.z, n.x);
    const double sgn = ny > 0.0 ? 1.0 : -1.0;
    auto sOf = [&](double sinPsi) {
      return -sgn * rho * sinPsi / std::sqrt(ny * ny + rho * rho * sinPsi * sinPsi);
    };
    const double lo = std::min(from, to), hi = std::max(from, to);
    thread_local std::vector<double> bp;
    bp.clear();
    bp.push_back(lo);
    bp.push_back(hi);
    // Column boundaries.
    const double cFirst = columnCoordinate(hi), cLast = columnCoordinate(lo);
    for (double c = std::floor(cFirst) + 1.0; c < cLast; c += 1.0)
      bp.push_back(longitudeOfColumn(c));
    // Row boundaries: s is monotone in sin ψ, whose range over the arc includes ±1 where ψ passes
    // ±π/2.
    const double psiLo = lo + beta, psiHi = hi + beta;
    double m0 = std::min(std::sin(psiLo), std::sin(psiHi)),
           m1 = std::max(std::sin(psiLo), std::sin(psiHi));
    if (std::floor((psiHi - 0.5 * kPi) / kTwoPi) > std::floor((psiLo - 0.5 * kPi) / kTwoPi))
      m1 = 1.0;
    if (std::floor((psiHi + 0.5 * kPi) / kTwoPi) > std::floor((psiLo + 0.5 * kPi) / kTwoPi))
      m0 = -1.0;
    const double sA = sOf(m0), sB = sOf(m1);
    const double sLo = std::min(sA, sB), sHi = std::max(sA, sB);
    // Inner row edges y = 1 .. height-1 with sLo < rowTop[y] < sHi (rowTop decreases with y).
    const int yFirst = std::max(1, rowOf(sHi)), yLast = std::min(height_ - 1, rowOf(sLo) + 1);
    for (int y = yFirst; y <= yLast; ++y) {
      const double sb = rowTop_[size_t(y)];
      if (!(sb > sLo && sb < sHi)) continue;
      const double c = -ny * tanTop_[size_t(y)] / rho;
      if (!(std::abs(c) <= 1.0)) continue;
      const double a = std::asin(c);
      for (double root : {a, kPi - a}) {
        // root + 2πk within (psiLo, psiHi)
        for (double k = std::ceil((psiLo - root) / kTwoPi); root + kTwoPi * k < psiHi; k += 1.0) {
          const double phi = root + kTwoPi * k - beta;
          if (phi > lo && phi < hi) bp.push_back(phi);
        }
      }
    }
    std::sort(bp.begin(), bp.end());
    if (to < from) std::reverse(bp.begin(), bp.end());
    for (size_t k = 0; k + 1 < bp.size(); ++k) {
      const double q0 = bp[k], q1 = bp[k + 1];
      if (q0 == q1) continue;
      const double mid = 0.5 * (q0 + q1);
      const int column = wrapColumn(int(std::floor(columnCoordinate(mid))));
      const int row = rowOf(sOf(std::sin(mid + beta)));
      // ∫ s dφ = sign(n_y) (asin x1 - asin x0), x = ρ cos ψ, written with atan2 for accuracy
      // (sqrt(1 - x²) = sqrt(n_y² + ρ² sin² ψ) without cancellation).
      const double p0 = q0 + beta, p1 = q1 + beta;
      const double x0 = rho * std::cos(p0), x1 = rho * std::cos(p1);
      const double r0 = rho * std::sin(p0), r1 = rho * std::sin(p1);
      const double c0 = std::sqrt(ny * ny + r0 * r0), c1 = std::sqrt(ny * ny + r1 * r1);
      const double integralS = sgn * std::atan2(x1 * c0 - x0 * c1, c0 * c1 + x0 * x1);
      const double dphi = q1 - q0;
      const double bottom = rowTop_[size_t(row) + 1];
      entries_.push_back({column, row, -(integralS - bottom * dphi), -dphi});
    }
  }

  int width_, height_;
  const std::vector<double>& rowTop_;
  const std::vector<double>& tanTop_;
  std::vector<Entry>& entries_;
  mutable std::vector<double> scratch_;
  bool started_ = false;
  double first_ = 0.0, current_ = 0.0;
};

}  // namespace

CubeLatLongOverlaps::CubeLatLongOverlaps(int cubeSize, int latLongWidth)
    : cubeSize_(cubeSize), width_(latLongWidth), height_(latLongWidth / 2) {
  COMPOSE_CHECK(cubeSize >= 1 && latLongWidth >= 2 && latLongWidth % 2 == 0);
  rowTop_.resize(size_t(height_) + 1);
  tanTop_.assign(size_t(height_) + 1, 0.0);
  for (int y = 0; y <= height_; ++y) {
    const double lat = kPi * (0.5 - double(y) / height_);
    rowTop_[size_t(y)] = std::sin(lat);
    if (y > 0 && y < height_) tanTop_[size_t(y)] = std::tan(lat);
  }
  rowTop_[0] = 1.0;
  rowTop_[size_t(height_)] = -1.0;
  if (height_ % 2 == 0) rowTop_[size_t(height_ / 2)] = 0.0;
}

void CubeLatLongOverlaps::texel(int face, int x, int y, std::vector<CellOverlap>& out) const {
  out.clear();
  thread_local std::vector<Entry> entries;
  entries.clear();
  const double step = 2.0 / cubeSize_;
  const double a0 = -1.0 + step * x, a1 = -1.0 + step * (x + 1);
  const double b0 = -1.0 + step * y, b1 = -1.0 + step * (y + 1);
  const glm::dvec3 corner[4] = {faceImageDirection(face, a0, b0), faceImageDirection(face, a1, b0),
                                faceImageDirection(face, a1, b1), faceImageDirection(face, a0, b1)};
  int start = 0;
  bool poleCorner = false;
  for (int k = 0; k < 4; ++k) {
    if (corner[k].x == 0.0 && corner[k].z == 0.0) {
      start = k;
      poleCorner = true;
    }
  }
  TexelIntegrator integrator(width_, height_, rowTop_, tanTop_, entries);
  for (int e = 0; e < 4; ++e) integrator.arc(corner[(start + e) % 4], corner[(start + e + 1) % 4]);
  const bool aroundPole = poleCorner || std::abs(integrator.winding()) > kPi;
  const bool north = faceFrame(face).forward.y > 0.0;
  if (aroundPole && north) integrator.closeNorth();
  const bool runToBottom = aroundPole && !north;

  // Column sums: cell (column, row) = direct + Δs_row · Σ below over the rows above it.
  std::sort(entries.begin(), entries.end(), [](const Entry& p, const Entry& q) {
    return p.column != q.column ? p.column < q.column : p.row < q.row;
  });
  double total = 0.0;
  for (size_t i = 0; i < entries.size();) {
    const int column = entries[i].column;
    size_t j = i;
    while (j < entries.size() && entries[j].column == column) ++j;
    const int lastRow = runToBottom ? height_ - 1 : entries[j - 1].row;
    double running = 0.0;
    size_t k = i;
    for (int row = entries[i].row; row <= lastRow; ++row) {
      double direct = 0.0, below = 0.0;
      while (k < j && entries[k].row == row) {
        direct += entries[k].direct;
        below += entries[k].below;
        ++k;
      }
      if (row >= 0) {
        const double omega = direct + (rowTop_[size_t(row)] - rowTop_[size_t(row) + 1]) * running;
        if (omega != 0.0) {
          out.push_back({column, row, omega});
          total += omega;
        }
      }
      running += below;
    }
    i = j;
  }
  if (total < 0.0) {
    for (auto& o : out) o.solidAngle = -o.solidAngle;
  }
}

void CubeLatLongOverlaps::forEachTexel(
    const std::function<void(int, int, int, const std::vector<CellOverlap>&)>& visit,
    const Progress& progress) const {
  const int n = cubeSize_;
  // Faces +X -X +Y -Y +Z -Z. -Z (5) stands for the side faces, +Y (2) for -Y; without the
  // quarter-turn symmetry every side face is computed.
  const bool quarterTurns = width_ % 4 == 0;
  const std::vector<int> references =
      quarterTurns ? std::vector<int>{5, 2} : std::vector<int>{0, 1, 4, 5, 2};
  const int half = (n + 1) / 2;  // columns computed per row; the others are their mirrors
  const int64_t tasks = int64_t(references.size()) * n;
  ParallelProgress shared(progress, "resample", tasks);
  parallelFor(0, tasks, [&](int64_t task) {
    const int ref = references[size_t(task / n)], y = int(task % n);
    std::vector<CellOverlap> cells, mirrored, moved;
    for (int x = 0; x < half; ++x) {
      texel(ref, x, y, cells);
      // Texel column N-1-x is the mirror image across the plane of the face's right axis: for a
      // right axis along x, φ -> -φ (cell column c -> W-1-c); along z, φ -> π - φ
      // (c -> W/2-1-c).
      mirrored = cells;
      const bool alongX = faceFrame(ref).right.x != 0.0;
      for (CellOverlap& c : mirrored)
        c.x = alongX ? width_ - 1 - c.x : ((width_ / 2 - 1 - c.x) % width_ + width_) % width_;
      const int mx = n - 1 - x;
      for (int side = 0; side < (mx == x ? 1 : 2); ++side) {
        const std::vector<CellOverlap>& base = side == 0 ? cells : mirrored;
        const int bx = side == 0 ? x : mx;
        visit(ref, bx, y, base);
        if (!quarterTurns) {
          if (ref == 2) {  // -Y: the mirror y -> -y, rows mirrored, texel row N-1-y
            moved = base;
            for (CellOverlap& c : moved) c.y = height_ - 1 - c.y;
            visit(3, bx, n - 1 - y, moved);
          }
          continue;
        }
        if (ref == 5) {
          // Turning -Z about +Y by -90°, 180°, +90° gives +X, +Z, -X with the same texel
          // coordinates; longitude turns with it, φ -> φ + θ, columns shift by -θ W / (2π).
          const int shifts[3][2] = {{0, 1}, {4, 2}, {1, 3}};  // (face, quarter widths)
          for (const auto& [face, quarters] : shifts) {
            moved = base;
            for (CellOverlap& c : moved) c.x = (c.x + quarters * (width_ / 4)) % width_;
            visit(face, bx, y, moved);
          }
        } else {
          moved = base;
          for (CellOverlap& c : moved) c.y = height_ - 1 - c.y;
          visit(3, bx, n - 1 - y, moved);
        }
      }
    }
    shared.step();
  });
  report(progress, "resample", 1.0);
}

CubeMap cubeFromLatLong(const Environment& env, int size, const Progress& progress) {
  COMPOSE_CHECK(size >= 1);
  const CubeLatLongOverlaps overlaps(size, env.width());
  CubeMap cube(size);
  cube.colorSpace = env.colorSpace();
  overlaps.forEachTexel(
      [&](int face, int x, int y, const std::vector<CellOverlap>& cells) {
        glm::dvec3 sum(0.0);
        double area = 0.0;
        for (const CellOverlap& c : cells) {
          sum += c.solidAngle * glm::dvec3(env.radiance(c.x, c.y));
          area += c.solidAngle;
        }
        const glm::dvec3 mean = area > 0.0 ? sum / area : glm::dvec3(0.0);
        float* t = cube.texel(face, x, y);
        t[0] = float(mean.x);
        t[1] = float(mean.y);
        t[2] = float(mean.z);
      },
      progress);
  return cube;
}

Environment latLongFromCube(const CubeMap& cube, int width, const Progress& progress) {
  COMPOSE_CHECK(!cube.empty() && width >= 2 && width % 2 == 0);
  const int size = cube.size(), height = width / 2;
  const CubeLatLongOverlaps overlaps(size, width);
  // Each texel scatters into the cells it overlaps: one accumulator per thread (double), summed
  // at the end.
  const size_t cells = size_t(width) * size_t(height);
  tbb::combinable<std::vector<double>> partial(
      [cells] { return std::vector<double>(cells * 4, 0.0); });
  overlaps.forEachTexel(
      [&](int face, int x, int y, const std::vector<CellOverlap>& hits) {
        std::vector<double>& acc = partial.local();
        const glm::dvec3 L(cube.radiance(face, x, y));
        for (const CellOverlap& c : hits) {
          double* a = acc.data() + (size_t(c.y) * size_t(width) + size_t(c.x)) * 4;
          a[0] += c.solidAngle * L.x;
          a[1] += c.solidAngle * L.y;
          a[2] += c.solidAngle * L.z;
          a[3] += c.solidAngle;
        }
      },
      progress);
  std::vector<double> sum(cells * 4, 0.0);
  partial.combine_each([&](const std::vector<double>& p) {
    for (size_t i = 0; i < sum.size(); ++i) sum[i] += p[i];
  });
  Image img(width, height, 3, {"R", "G", "B"});
  img.colorSpace = cube.colorSpace;
  for (size_t i = 0; i < cells; ++i) {
    const double area = sum[4 * i + 3];
    for (int c = 0; c < 3; ++c)
      img.pixels[3 * i + size_t(c)] = area > 0.0 ? float(sum[4 * i + size_t(c)] / area) : 0.0f;
  }
  // Resampling changes no value's validity: negative values of the input (kept by a conversion of
  // layouts) stay, clamped where light is used.
  SanitizeReport keep;
  keep.keepNegative = true;
  return Environment::fromLatLong(img, {}, &keep);
}

namespace {

// Texel range [first, last] of an n-texel face row overlapping [lo, hi] (face coordinates).
void texelRange(int n, double lo, double hi, int& first, int& last) {
  first = std::clamp(int(std::floor((lo + 1.0) * 0.5 * n)), 0, n - 1);
  last = std::clamp(int(std::ceil((hi + 1.0) * 0.5 * n)) - 1, 0, n - 1);
}

}  // namespace

CubeMap resizeCube(const CubeMap& cube, int size) {
  COMPOSE_CHECK(!cube.empty() && size >= 1);
  const int n = cube.size(), m = size;
  CubeMap out(m);
  out.colorSpace = cube.colorSpace;
  // The overlap weights are the same on every face: computed once, per row of destination texels
  // (child texel index, shared solid angle), then applied to the six faces.
  struct Weight {
    int child;
    double omega;
  };
  std::vector<std::vector<Weight>> rows(static_cast<size_t>(m));
  std::vector<std::vector<int>> starts(static_cast<size_t>(m));
  parallelFor(0, m, [&](int64_t pyy) {
    const int py = int(pyy);
    std::vector<Weight>& w = rows[size_t(py)];
    std::vector<int>& start = starts[size_t(py)];
    const double b0 = -1.0 + 2.0 * py / m, b1 = -1.0 + 2.0 * (py + 1) / m;
    int y0, y1;
    texelRange(n, b0, b1, y0, y1);
    for (int px = 0; px < m; ++px) {
      start.push_back(int(w.size()));
      const double a0 = -1.0 + 2.0 * px / m, a1 = -1.0 + 2.0 * (px + 1) / m;
      int x0, x1;
      texelRange(n, a0, a1, x0, x1);
      for (int y = y0; y <= y1; ++y) {
        const double cb0 = std::max(b0, -1.0 + 2.0 * y / n),
                     cb1 = std::min(b1, -1.0 + 2.0 * (y + 1) / n);
        if (!(cb1 > cb0)) continue;
        for (int x = x0; x <= x1; ++x) {
          const double ca0 = std::max(a0, -1.0 + 2.0 * x / n),
                       ca1 = std::min(a1, -1.0 + 2.0 * (x + 1) / n);
          if (!(ca1 > ca0)) continue;
          w.push_back({y * n + x, cubeSolidAngle(ca0, cb0, ca1, cb1)});
        }
      }
    }
    start.push_back(int(w.size()));
  });
  parallelFor(0, int64_t(kCubeFaces) * m, [&](int64_t task) {
    const int f = int(task / m), py = int(task % m);
    const std::vector<Weight>& w = rows[size_t(py)];
    const std::vector<int>& start = starts[size_t(py)];
    const float* src = cube.face(f).data();
    for (int px = 0; px < m; ++px) {
      glm::dvec3 sum(0.0);
      double area = 0.0;
      for (int k = start[size_t(px)]; k < start[size_t(px) + 1]; ++k) {
        const float* t = src + size_t(w[size_t(k)].child) * 3;
        sum += w[size_t(k)].omega * glm::dvec3(t[0], t[1], t[2]);
        area += w[size_t(k)].omega;
      }
      const glm::dvec3 mean = sum / area;
      float* t = out.texel(f, px, py);
      t[0] = float(mean.x);
      t[1] = float(mean.y);
      t[2] = float(mean.z);
    }
  });
  return out;
}

Environment resizeLatLong(const Environment& env, int width) {
  COMPOSE_CHECK(width >= 2 && width % 2 == 0);
  const int w0 = env.width(), h0 = env.height(), w1 = width, h1 = width / 2;
  // Cells are rectangles in (longitude, sin latitude), where solid angle is plain area: the
  // overlap weights separate into a longitude part and a sin-latitude part.
  // Edges increase with the cell index: longitude fraction for columns, -sin(latitude) for rows.
  auto edges = [](int n, bool latitude) {
    std::vector<double> e(size_t(n) + 1);
    for (int i = 0; i <= n; ++i)
      e[size_t(i)] = latitude ? -std::sin(kPi * (0.5 - double(i) / n)) : double(i) / n;
    e[0] = latitude ? -1.0 : 0.0;
    e[size_t(n)] = 1.0;
    return e;
  };
  // weights[j] lists (source index, overlap) for destination cell j; edges increase with index.
  auto overlaps = [](const std::vector<double>& src, const std::vector<double>& dst) {
    std::vector<std::vector<std::pair<int, double>>> out(dst.size() - 1);
    size_t i = 0;
    for (size_t j = 0; j + 1 < dst.size(); ++j) {
      while (i + 1 < src.size() && src[i + 1] <= dst[j]) ++i;
      for (size_t k = i; k + 1 < src.size() && src[k] < dst[j + 1]; ++k) {
        const double o = std::min(src[k + 1], dst[j + 1]) - std::max(src[k], dst[j]);
        if (o > 0.0) out[j].push_back({int(k), o});
      }
    }
    return out;
  };
  const auto cols = overlaps(edges(w0, false), edges(w1, false));
  const auto rows = overlaps(edges(h0, true), edges(h1, true));
  // Longitude first (per source row), then latitude.
  std::vector<double> tmp(size_t(h0) * size_t(w1) * 3, 0.0);
  parallelFor(0, h0, [&](int64_t y) {
    for (int x = 0; x < w1; ++x) {
      double total = 0.0;
      double* dst = tmp.data() + (size_t(y) * size_t(w1) + size_t(x)) * 3;
      for (const auto& [k, o] : cols[size_t(x)]) {
        const glm::vec3 L = env.radiance(k, int(y));
        dst[0] += o * L.x, dst[1] += o * L.y, dst[2] += o * L.z;
        total += o;
      }
      for (int c = 0; c < 3; ++c) dst[c] /= total;
    }
  });
  Image img(w1, h1, 3, {"R", "G", "B"});
  img.colorSpace = env.colorSpace();
  parallelFor(0, h1, [&](int64_t yy) {
    const int y = int(yy);
    for (int x = 0; x < w1; ++x) {
      double acc[3] = {0, 0, 0}, total = 0.0;
      for (const auto& [k, o] : rows[size_t(y)]) {
        const double* src = tmp.data() + (size_t(k) * size_t(w1) + size_t(x)) * 3;
        for (int c = 0; c < 3; ++c) acc[c] += o * src[c];
        total += o;
      }
      for (int c = 0; c < 3; ++c) img.at(x, y)[c] = float(acc[c] / total);
    }
  });
  // Resampling changes no value's validity: negative values of the input (kept by a conversion of
  // layouts) stay, clamped where light is used.
  SanitizeReport keep;
  keep.keepNegative = true;
  return Environment::fromLatLong(img, {}, &keep);
}

}  // namespace compose::lighting
