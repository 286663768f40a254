#include "lighting/chebyshev.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/error.h"
#include "core/fast_math.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/parallel.h"
#include "lighting/cubemap.h"
#include "lighting/radiance_cells.h"

namespace compose::lighting {

namespace {

// Cells of 8 x 8 texels on the horizon are integrated as uniform patches (RadianceCells): on the
// sample maps this moves E by ~2e-5 relative (~90 dB), far below the normal-grid interpolation
// error, at a tenth of the texel-exact cost.
constexpr int kLeafLevel = 3;

// Moments of one channel of an RGB grid (rows x cols, interleaved) into out[c * k² ...].
void rgbMoments(const TchebichefBasis& rows, const TchebichefBasis& cols,
                const std::vector<double>& rgb, int k, float* out) {
  const size_t count = size_t(rows.size()) * size_t(cols.size());
  std::vector<double> channel(count);
  for (int c = 0; c < 3; ++c) {
    for (size_t i = 0; i < count; ++i) channel[i] = rgb[3 * i + size_t(c)];
    const std::vector<double> m = moments2d(rows, cols, channel, k);
    for (size_t i = 0; i < m.size(); ++i) out[size_t(c) * m.size() + i] = float(m[i]);
  }
}

// Latitude of a (fractional) row boundary of an s-row lat-long grid.
double latitudeOfRow(double row, int rows) {
  return kPi * (0.5 - row / rows);
}

// A piece of a grid cell over which the BRDF side integrates the cosine: its solid angle Ω, its
// mean direction m = ∫ω dω / Ω (exact), and half-extent vectors a, b across it. ∫ max(0, n·ω) dω
// is Ω (n·m) when the piece lies above n's horizon, and otherwise the clipped linear model
// (RadianceCells::clippedMean), so only pieces the horizon cuts carry a (second-order) error.
struct SubCell {
  glm::vec3 mean, halfA, halfB;
  float omega;
  uint32_t cell;
  float cosineIntegral(const glm::vec3& n) const {
    const float c = glm::dot(n, mean), a = glm::dot(n, halfA), b = glm::dot(n, halfB);
    const float spread = std::abs(a) + std::abs(b);
    if (c >= spread) return omega * c;
    if (c <= -spread) return 0.0f;
    return omega * RadianceCells::clippedMean(c, a, b);
  }
};

}  // namespace

// --- parameters -------------------------------------------------------------------------------

void ChebParams::validate(const std::string& basis) const {
  auto fail = [&](const std::string& what) { throw Error("lighting", basis + ": " + what); };
  if (samples < 1 || samples > 1024)
    fail("samples (grid size s) must be in 1..1024, got " + std::to_string(samples));
  if (order < 1 || order > std::min(samples, 32)) {
    fail("order k must be in 1..min(samples, 32) (samples = " + std::to_string(samples) +
         "), got " + std::to_string(order));
  }
  if (normalRows < 3 || normalRows > 1025)
    fail("rows must be in 3..1025, got " + std::to_string(normalRows));
  if (normalCols < 4 || normalCols > 2048)
    fail("cols must be in 4..2048, got " + std::to_string(normalCols));
  if (subsamples < 1 || subsamples > 16)
    fail("subsamples must be in 1..16, got " + std::to_string(subsamples));
  if (brdf != "lambert" && brdf != "oren-nayar")
    fail("brdf must be lambert or oren-nayar, got '" + brdf + "'");
  if (!(sigma >= 0.0 && sigma <= 1.5)) fail("sigma (roughness, radians) must be in 0..1.5");
  if (brdf == "oren-nayar" && basis != "cheb-local")
    fail("only cheb-local supports brdf=oren-nayar");
}

ChebParams ChebParams::from(ParamSet& params, const std::string& basis, ChebParams d) {
  ChebParams p;
  p.order = params.getInt("order", d.order, "lighting");
  p.samples = params.getInt("samples", d.samples, "lighting");
  p.normalRows = params.getInt("rows", d.normalRows, "lighting");
  p.normalCols = params.getInt("cols", d.normalCols, "lighting");
  // A parameter the basis or the BRDF does not use is refused, not ignored.
  if (basis == "cheb-local" && params.has("subsamples"))
    throw Error("lighting",
                "subsamples applies to cheb-latlong and cheb-face (cheb-local samples each "
                "normal's hemisphere: samples=)");
  p.subsamples = params.getInt("subsamples", d.subsamples, "lighting");
  p.brdf = params.getString("brdf", d.brdf);
  if (p.brdf != "oren-nayar" && params.has("sigma"))
    throw Error("lighting", "sigma (roughness) applies to brdf=oren-nayar only");
  p.sigma = params.getDouble("sigma", p.brdf == "oren-nayar" ? 0.3 : 0.0, "lighting");
  p.validate(basis);
  return p;
}

// --- normal grid ------------------------------------------------------------------------------

NormalGrid::NormalGrid(int rows, int cols) : rows_(rows), cols_(cols) {
  COMPOSE_CHECK(rows >= 2 && cols >= 1);
}

glm::vec3 NormalGrid::normal(size_t node) const {
  const int r = int(node / size_t(cols_)), c = int(node % size_t(cols_));
  const double lat = kPi * (0.5 - double(r) / (rows_ - 1));
  const double lon = 2.0 * kPi * c / cols_;
  return glm::vec3(float(std::sin(lon) * std::cos(lat)), float(std::sin(lat)),
                   float(std::cos(lon) * std::cos(lat)));
}

void NormalGrid::frame(size_t node, glm::vec3& east, glm::vec3& north) const {
  const int c = int(node % size_t(cols_));
  const double lon = 2.0 * kPi * c / cols_;
  east = glm::vec3(float(std::cos(lon)), 0.0f, float(-std::sin(lon)));
  north = glm::cross(normal(node), east);
}

void NormalGrid::interpolation(const glm::vec3& n, size_t nodes[4], float weights[4]) const {
  interpolationAt(fastAtan2(n.y, std::sqrt(n.x * n.x + n.z * n.z)), fastAtan2(n.x, n.z), nodes,
                  weights);
}

void NormalGrid::interpolationAt(double lat, double lon, size_t nodes[4], float weights[4]) const {
  // Into [0, 2π): one subtraction for the usual case (atan2's range, or one turn of yaw beyond).
  if (lon < 0.0 || lon >= 2.0 * kPi) lon -= 2.0 * kPi * std::floor(lon / (2.0 * kPi));
  if (lon >= 2.0 * kPi) lon = 0.0;  // rounding just below a whole turn
  const double u = (0.5 - lat / kPi) * (rows_ - 1);
  const double v = lon / (2.0 * kPi) * cols_;
  const int r0 = std::clamp(int(std::floor(u)), 0, rows_ - 2);
  const int c0 = int(std::floor(v)) % cols_;
  const int c1 = (c0 + 1) % cols_;
  const float fu = float(std::clamp(u - r0, 0.0, 1.0)), fv = float(v - std::floor(v));
  nodes[0] = size_t(r0) * size_t(cols_) + size_t(c0);
  nodes[1] = size_t(r0) * size_t(cols_) + size_t(c1);
  nodes[2] = size_t(r0 + 1) * size_t(cols_) + size_t(c0);
  nodes[3] = size_t(r0 + 1) * size_t(cols_) + size_t(c1);
  weights[0] = (1 - fu) * (1 - fv);
  weights[1] = (1 - fu) * fv;
  weights[2] = fu * (1 - fv);
  weights[3] = fu * fv;
}

// --- shared -----------------------------------------------------------------------------------

ChebBase::ChebBase(std::string name, ChebParams params)
    : name_(std::move(name)), params_(params), grid_(params.normalRows, params.normalCols) {
  params_.validate(name_);
}

std::string ChebBase::describe() const {
  return name_ + " order=" + std::to_string(params_.order) +
         " samples=" + std::to_string(params_.samples) +
         " normals=" + std::to_string(params_.normalRows) + "x" +
         std::to_string(params_.normalCols) + " (" + std::to_string(coefficientsPerChannel()) +
         " coefficients/channel, " + std::to_string(floatsStored()) + " floats)";
}

void ChebBase::reserveTable() {
  const size_t floats = grid_.size() * stride_;
  requireMemory(floats * sizeof(float),
                "the " + name_ + " lighting's table (order=" + std::to_string(params_.order) +
                    ", " + std::to_string(params_.normalRows) + " x " +
                    std::to_string(params_.normalCols) + " normals: " + std::to_string(floats) +
                    " floats)");
  table_.assign(floats, 0.0f);
}

size_t ChebBase::floatsStored() const {
  return table_.size() + global_.size();
}

std::string ChebBase::parameterKey() const {
  // Every parameter, and the internal constants of the integrators, that changes the numbers.
  char constants[160];
  std::snprintf(constants, sizeof constants,
                " leaf=%d piece=%.17g patch=%.17g cell-factor=%d view-table=%dx%d", kLeafLevel,
                RadianceCells::kMaxPieceExtent, RadianceCells::kMaxPatchExtent,
                RadianceCells::kFinestFactor, ChebLocalLighting::kViewThetas,
                ChebLocalLighting::kViewPhis);
  return name_ + " order=" + std::to_string(params_.order) +
         " samples=" + std::to_string(params_.samples) +
         " rows=" + std::to_string(params_.normalRows) +
         " cols=" + std::to_string(params_.normalCols) +
         " subsamples=" + std::to_string(params_.subsamples) + " brdf=" + params_.brdf +
         " sigma=" + std::to_string(params_.sigma) + constants;
}

bool ChebBase::exportState(std::vector<float>& out) const {
  if (table_.empty()) return false;
  out.clear();
  out.insert(out.end(), table_.begin(), table_.end());
  out.insert(out.end(), global_.begin(), global_.end());
  return true;
}

bool ChebBase::importState(std::span<const float> in) {
  const size_t stride = size_t(blocks_) * size_t(params_.order) * size_t(params_.order) *
                        (name_ == "cheb-local" ? 3 : 1);
  const size_t tableSize = grid_.size() * stride;
  if (in.size() != tableSize + globalSize_) return false;
  stride_ = stride;
  table_.assign(in.begin(), in.begin() + ptrdiff_t(tableSize));
  global_.assign(in.begin() + ptrdiff_t(tableSize), in.end());
  return true;
}

std::vector<double> ChebBase::truncationSnrDb() const {
  COMPOSE_CHECK(!table_.empty());
  const int order = params_.order;
  std::vector<double> signal(size_t(order), 0.0), noise(size_t(order), 0.0);
  // Nodes weighted by the solid angle they stand for (cos latitude; a pole node gets its share of
  // the polar cap, Δ/8 in the same units), so that the estimate is over uniformly spread normals.
  const double spacing = kPi / (grid_.rows() - 1);
  for (size_t node = 0; node < grid_.size(); ++node) {
    const int row = int(node / size_t(grid_.cols()));
    const double weight = (row == 0 || row == grid_.rows() - 1)
                              ? spacing / 8.0
                              : std::cos(kPi * (0.5 - double(row) / (grid_.rows() - 1)));
    for (int c = 0; c < 3; ++c) {
      const double full = truncatedProduct(node, c, order);
      for (int k = 1; k <= order; ++k) {
        const double d = full - truncatedProduct(node, c, k);
        signal[size_t(k - 1)] += weight * full * full;
        noise[size_t(k - 1)] += weight * d * d;
      }
    }
  }
  std::vector<double> out(static_cast<size_t>(order));
  for (size_t i = 0; i < out.size(); ++i) {
    out[i] = noise[i] > 0.0 ? 10.0 * std::log10(signal[i] / noise[i])
                            : std::numeric_limits<double>::infinity();
  }
  return out;
}

namespace {

// The environment's mean radiance per cell (RGB, 3 values a cell): Σ L_t Ω_t / Σ Ω_t over the
// texels whose centre lies in the cell, `cellOf(x, y)`. A cell finer than the map's texels may
// hold no texel centre: it takes the radiance in the direction of its own centre, `centreOf(cell)`.
template <class CellOf, class CentreOf>
std::vector<double> meanRadianceByCell(const Environment& env, size_t cells, CellOf&& cellOf,
                                       CentreOf&& centreOf) {
  std::vector<double> lin(cells * 3, 0.0), area(cells, 0.0);
  for (int y = 0; y < env.height(); ++y) {
    const double omega = env.rowSolidAngle(y);
    for (int x = 0; x < env.width(); ++x) {
      const size_t idx = cellOf(x, y);
      const glm::vec3 L = env.radiance(x, y);
      double* cell = lin.data() + 3 * idx;
      cell[0] += L.x * omega;
      cell[1] += L.y * omega;
      cell[2] += L.z * omega;
      area[idx] += omega;
    }
  }
  for (size_t idx = 0; idx < cells; ++idx) {
    if (area[idx] > 0.0) {
      for (int c = 0; c < 3; ++c) lin[3 * idx + size_t(c)] /= area[idx];
    } else {
      const glm::vec3 L = env.lookup(centreOf(idx));
      lin[3 * idx] = L.x, lin[3 * idx + 1] = L.y, lin[3 * idx + 2] = L.z;
    }
  }
  return lin;
}

}  // namespace

// --- cheb-latlong -----------------------------------------------------------------------------

ChebLatLongLighting::ChebLatLongLighting(ChebParams params) : ChebBase("cheb-latlong", params) {
  globalSize_ = 3 * size_t(params_.order) * size_t(params_.order);
}

void ChebLatLongLighting::project(const Environment& env, const Progress& progress) {
  const int s = params_.samples, k = params_.order, q = params_.subsamples;
  const TchebichefBasis basis(s, k);
  // Lighting: L_in(i, j) = mean radiance over the cell, Σ L_t Ω_t / Σ Ω_t over the texels whose
  // centre lies in it. The solid angle and the cosine both go to the BRDF side, so a constant
  // environment has only a T_00 moment and the white furnace holds at every order.
  const std::vector<double> lin = meanRadianceByCell(
      env, size_t(s) * size_t(s),
      [&](int x, int y) {
        const int i = std::min(s - 1, int((y + 0.5) * s / env.height()));
        const int j = std::min(s - 1, int((x + 0.5) * s / env.width()));
        return size_t(i) * size_t(s) + size_t(j);
      },
      [&](size_t idx) {
        const int i = int(idx / size_t(s)), j = int(idx % size_t(s));
        const double lat = latitudeOfRow(i + 0.5, s), lon = kPi * (1.0 - 2.0 * (j + 0.5) / s);
        return glm::vec3(float(std::sin(lon) * std::cos(lat)), float(std::sin(lat)),
                         float(std::cos(lon) * std::cos(lat)));
      });
  global_.assign(size_t(3 * k * k), 0.0f);
  rgbMoments(basis, basis, lin, k, global_.data());

  // BRDF side per normal: f_c(i, j) = ∫_cell max(0, n·ω) dω over q x q sub-cells whose vector
  // moments are exact (closed form, as for texels in RadianceCells).
  const int sq = s * q;
  std::vector<SubCell> subs;
  subs.reserve(size_t(sq) * size_t(sq));
  for (int a = 0; a < sq; ++a) {
    const double top = latitudeOfRow(a, sq), bottom = latitudeOfRow(a + 1, sq),
                 mid = latitudeOfRow(a + 0.5, sq);
    const double omega = 2.0 * kPi / sq * (std::sin(top) - std::sin(bottom));
    const double cos2 =
        0.5 * (top - bottom) + 0.25 * (std::sin(2.0 * top) - std::sin(2.0 * bottom));
    const double sincos =
        0.5 * (std::sin(top) * std::sin(top) - std::sin(bottom) * std::sin(bottom));
    for (int b = 0; b < sq; ++b) {
      const double left = kPi * (1.0 - 2.0 * b / sq), right = kPi * (1.0 - 2.0 * (b + 1) / sq);
      const double lon = 0.5 * (left + right);
      const glm::dvec3 m((std::cos(right) - std::cos(left)) * cos2, (left - right) * sincos,
                         (std::sin(left) - std::sin(right)) * cos2);
      const glm::dvec3 north(-std::sin(lon) * std::sin(mid), std::cos(mid),
                             -std::cos(lon) * std::sin(mid));
      const glm::dvec3 east(std::cos(lon), 0.0, -std::sin(lon));
      subs.push_back({glm::vec3(m / omega), glm::vec3(north * (0.5 * (top - bottom))),
                      glm::vec3(east * (0.5 * (left - right) * std::cos(mid))), float(omega),
                      uint32_t((a / q) * s + b / q)});
    }
  }
  stride_ = size_t(k) * size_t(k);
  reserveTable();
  std::atomic<size_t> done{0};
  parallelFor(0, int64_t(grid_.size()), [&](int64_t node) {
    const glm::vec3 n = grid_.normal(size_t(node));
    std::vector<double> fc(size_t(s) * size_t(s), 0.0);
    for (const SubCell& sub : subs) fc[sub.cell] += sub.cosineIntegral(n);
    const std::vector<double> m = moments2d(basis, basis, fc, k);
    std::transform(m.begin(), m.end(), table_.begin() + ptrdiff_t(size_t(node) * stride_),
                   [](double v) { return float(v); });
    const size_t d = ++done;
    if (d % 256 == 0) report(progress, "lighting", double(d) / double(grid_.size()));
  });
  report(progress, "lighting", 1.0);
}

glm::vec3 ChebLatLongLighting::irradiance(const glm::vec3& n) const {
  // Σ_mn T^L_mn T^f_mn(n), with T^f(n) interpolated between grid normals: Σ_q w_q (T^L · T^f_q).
  size_t nodes[4];
  float w[4];
  grid_.interpolation(n, nodes, w);
  glm::vec3 e(0.0f);
  for (int q = 0; q < 4; ++q) {
    const float* tf = table_.data() + nodes[q] * stride_;
    glm::vec3 dot(0.0f);
    for (size_t i = 0; i < stride_; ++i) {
      dot.x += global_[i] * tf[i];
      dot.y += global_[stride_ + i] * tf[i];
      dot.z += global_[2 * stride_ + i] * tf[i];
    }
    e += w[q] * dot;
  }
  return e;
}

double ChebLatLongLighting::truncatedProduct(size_t node, int channel, int k) const {
  const int K = params_.order;
  const float* tf = table_.data() + node * stride_;
  const float* tl = global_.data() + size_t(channel) * stride_;
  double sum = 0.0;
  for (int m = 0; m < k; ++m)
    for (int n = 0; n < k; ++n) sum += double(tl[m * K + n]) * tf[m * K + n];
  return sum;
}

// --- cheb-face --------------------------------------------------------------------------------

ChebFaceLighting::ChebFaceLighting(ChebParams params) : ChebBase("cheb-face", params) {
  blocks_ = kCubeFaces;
  globalSize_ = kCubeFaces * 3 * size_t(params_.order) * size_t(params_.order);
}

void ChebFaceLighting::project(const Environment& env, const Progress& progress) {
  const int s = params_.samples, k = params_.order, q = params_.subsamples;
  const TchebichefBasis basis(s, k);
  const size_t faceTexels = size_t(s) * size_t(s);
  // Lighting: mean radiance over each cube texel, from the environment texels whose centre
  // direction falls in it (solid angle and cosine on the BRDF side, as for cheb-latlong).
  const std::vector<double> lin = meanRadianceByCell(
      env, kCubeFaces * faceTexels,
      [&](int x, int y) {
        int face = 0;
        double u = 0, v = 0;
        cubeFaceCoordinates(env.direction(x, y), face, u, v);
        const int i = std::clamp(int((v + 1.0) * 0.5 * s), 0, s - 1);  // row from v
        const int j = std::clamp(int((u + 1.0) * 0.5 * s), 0, s - 1);  // column from u
        return size_t(face) * faceTexels + size_t(i) * size_t(s) + size_t(j);
      },
      [&](size_t idx) {
        const int f = int(idx / faceTexels), i = int((idx % faceTexels) / size_t(s)),
                  j = int(idx % size_t(s));
        return cubeDirection(f, -1.0 + (2.0 * j + 1.0) / s, -1.0 + (2.0 * i + 1.0) / s);
      });
  const size_t kk = size_t(k) * size_t(k);
  global_.assign(kCubeFaces * 3 * kk, 0.0f);
  for (int f = 0; f < kCubeFaces; ++f) {
    const std::vector<double> faceLin(lin.begin() + ptrdiff_t(size_t(f) * faceTexels * 3),
                                      lin.begin() + ptrdiff_t(size_t(f + 1) * faceTexels * 3));
    rgbMoments(basis, basis, faceLin, k, global_.data() + size_t(f) * 3 * kk);
  }

  // BRDF side: ∫ max(0, n·ω) dω over each cube texel, by q x q sub-texels with exact solid angles
  // and mean directions from 4 x 4 Gauss–Legendre over the sub-texel (ω dω = (u, v, 1)/r³ du dv on
  // a face: smooth, so the rule is accurate to ~1e-10).
  static constexpr double kNodes[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563,
                                       0.8611363115940526};
  static constexpr double kWeights[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461,
                                         0.3478548451374538};
  const int sq = s * q;
  std::vector<SubCell> subs;
  subs.reserve(kCubeFaces * size_t(sq) * size_t(sq));
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int a = 0; a < sq; ++a) {
      const double v0 = -1.0 + 2.0 * a / sq, v1 = -1.0 + 2.0 * (a + 1) / sq, vc = 0.5 * (v0 + v1);
      for (int b = 0; b < sq; ++b) {
        const double u0 = -1.0 + 2.0 * b / sq, u1 = -1.0 + 2.0 * (b + 1) / sq, uc = 0.5 * (u0 + u1);
        glm::dvec3 moment(0.0);
        for (int gi = 0; gi < 4; ++gi) {
          for (int gj = 0; gj < 4; ++gj) {
            const double u = uc + 0.5 * (u1 - u0) * kNodes[gi],
                         v = vc + 0.5 * (v1 - v0) * kNodes[gj];
            const double r2 = 1.0 + u * u + v * v;
            const double jac =
                0.25 * (u1 - u0) * (v1 - v0) * kWeights[gi] * kWeights[gj] / (r2 * std::sqrt(r2));
            moment += glm::dvec3(cubeDirection(f, u, v)) * jac;
          }
        }
        const double omega = cubeSolidAngle(u0, v0, u1, v1);
        const glm::dvec3 du =
            0.5 * (glm::dvec3(cubeDirection(f, u1, vc)) - glm::dvec3(cubeDirection(f, u0, vc)));
        const glm::dvec3 dv =
            0.5 * (glm::dvec3(cubeDirection(f, uc, v1)) - glm::dvec3(cubeDirection(f, uc, v0)));
        subs.push_back(
            {glm::vec3(moment / omega), glm::vec3(dv), glm::vec3(du), float(omega),
             uint32_t(size_t(f) * faceTexels + size_t(a / q) * size_t(s) + size_t(b / q))});
      }
    }
  }
  stride_ = kCubeFaces * kk;
  reserveTable();
  std::atomic<size_t> done{0};
  parallelFor(0, int64_t(grid_.size()), [&](int64_t node) {
    const glm::vec3 n = grid_.normal(size_t(node));
    std::vector<double> fc(kCubeFaces * faceTexels, 0.0);
    for (const SubCell& sub : subs) fc[sub.cell] += sub.cosineIntegral(n);
    for (int f = 0; f < kCubeFaces; ++f) {
      const std::vector<double> m = moments2d(
          basis, basis, std::span<const double>(fc.data() + size_t(f) * faceTexels, faceTexels), k);
      std::transform(m.begin(), m.end(),
                     table_.begin() + ptrdiff_t(size_t(node) * stride_ + size_t(f) * kk),
                     [](double v) { return float(v); });
    }
    const size_t d = ++done;
    if (d % 256 == 0) report(progress, "lighting", double(d) / double(grid_.size()));
  });
  report(progress, "lighting", 1.0);
}

glm::vec3 ChebFaceLighting::irradiance(const glm::vec3& n) const {
  size_t nodes[4];
  float w[4];
  grid_.interpolation(n, nodes, w);
  const size_t kk = stride_ / kCubeFaces;
  glm::vec3 e(0.0f);
  for (int q = 0; q < 4; ++q) {
    const float* tf = table_.data() + nodes[q] * stride_;
    glm::vec3 dot(0.0f);
    for (int f = 0; f < kCubeFaces; ++f) {
      const float* t = tf + size_t(f) * kk;
      const float* g = global_.data() + size_t(f) * 3 * kk;
      for (size_t i = 0; i < kk; ++i) {
        dot.x += g[i] * t[i];
        dot.y += g[kk + i] * t[i];
        dot.z += g[2 * kk + i] * t[i];
      }
    }
    e += w[q] * dot;
  }
  return e;
}

double ChebFaceLighting::truncatedProduct(size_t node, int channel, int k) const {
  const int K = params_.order;
  const size_t kk = size_t(K) * size_t(K);
  double sum = 0.0;
  for (int f = 0; f < kCubeFaces; ++f) {
    const float* tf = table_.data() + node * stride_ + size_t(f) * kk;
    const float* tl = global_.data() + (size_t(f) * 3 + size_t(channel)) * kk;
    for (int m = 0; m < k; ++m)
      for (int n = 0; n < k; ++n) sum += double(tl[m * K + n]) * tf[m * K + n];
  }
  return sum;
}

// --- cheb-local -------------------------------------------------------------------------------

ChebLocalLighting::ChebLocalLighting(ChebParams params) : ChebBase("cheb-local", params) {
  globalSize_ = size_t(params_.order) * size_t(params_.order);
  const int s = params_.samples, k = params_.order;
  const size_t kk = size_t(k) * size_t(k);
  const TchebichefBasis basis(s, k);
  if (params_.brdf == "oren-nayar") {
    // BRDF moments in the local frame for every tabulated view direction: f_c(i, j) is the BRDF
    // (times π/ρ) at the cell centre; the cosine is on the lighting side.
    viewTable_.assign(size_t(kViewThetas) * kViewPhis * kk, 0.0f);
    std::vector<double> fc(size_t(s) * size_t(s));
    for (int a = 0; a < kViewThetas; ++a) {
      const double thetaOut = 0.5 * kPi * a / (kViewThetas - 1);
      for (int b = 0; b < kViewPhis; ++b) {
        const double phiOut = 2.0 * kPi * b / kViewPhis;
        for (int i = 0; i < s; ++i) {
          for (int j = 0; j < s; ++j) {
            fc[size_t(i) * size_t(s) + size_t(j)] =
                orenNayar(params_.sigma, 0.5 * kPi * (i + 0.5) / s, 2.0 * kPi * (j + 0.5) / s,
                          thetaOut, phiOut);
          }
        }
        const std::vector<double> m = moments2d(basis, basis, fc, k);
        std::transform(m.begin(), m.end(),
                       viewTable_.begin() + ptrdiff_t((size_t(a) * kViewPhis + size_t(b)) * kk),
                       [](double v) { return float(v); });
      }
    }
  }
}

void ChebLocalLighting::project(const Environment& env, const Progress& progress) {
  const int s = params_.samples, k = params_.order;
  const TchebichefBasis basis(s, k);
  const size_t kk = size_t(k) * size_t(k);
  // BRDF side, in the local frame: Lambertian f_c = 1 on every cell (the cosine is on the lighting
  // side). Its moments are computed, not assumed; all but T_00 vanish to rounding.
  global_.resize(kk);
  {
    const std::vector<double> ones(size_t(s) * size_t(s), 1.0);
    const std::vector<double> m = moments2d(basis, basis, ones, k);
    std::transform(m.begin(), m.end(), global_.begin(), [](double v) { return float(v); });
  }
  const RadianceCells cells(env);
  stride_ = 3 * kk;
  reserveTable();
  // Altitude cells by their cosine bounds: cell i holds cos θ in (cos((i+1)π/2s), cos(iπ/2s)].
  std::vector<float> cosBound(static_cast<size_t>(s));
  for (int i = 1; i <= s; ++i) cosBound[size_t(i - 1)] = float(std::cos(i * 0.5 * kPi / s));
  const float phiScale = float(s / (2.0 * kPi));
  // Pieces are binned whole by their direction, so none may be wider than an altitude bin.
  const float binExtent = float(0.5 * kPi / s);
  std::atomic<size_t> done{0};
  parallelFor(0, int64_t(grid_.size()), [&](int64_t node) {
    const glm::vec3 n = grid_.normal(size_t(node));
    std::vector<double> lin(size_t(s) * size_t(s) * 3, 0.0);
    if (k == 1 && params_.brdf == "lambert") {
      // Only the mean of L_in is needed: T_00 = t_0 t_0 Σ L_in = E(n) / s. Same sum, no binning.
      const glm::dvec3 e = cells.irradiance(n, kLeafLevel);
      for (int c = 0; c < 3; ++c) lin[size_t(c)] = e[c];  // all in cell (0, 0): same T_00
    } else {
      glm::vec3 east, north;
      grid_.frame(size_t(node), east, north);
      // L_in(i, j) = ∫_cell L cos θ dω, exactly (RadianceCells), binned by altitude θ and azimuth
      // φ.
      cells.forEachAbove(
          n,
          [&](const glm::vec3& w, const glm::vec3& value) {
            const float c = glm::dot(n, w);
            int i = 0;
            while (i < s - 1 && c <= cosBound[size_t(i)]) ++i;
            float phi = fastAtan2(glm::dot(north, w), glm::dot(east, w));
            if (phi < 0.0f) phi += float(2.0 * kPi);
            const int j = std::min(s - 1, int(phi * phiScale));
            double* cell = lin.data() + 3 * (size_t(i) * size_t(s) + size_t(j));
            cell[0] += value.x;
            cell[1] += value.y;
            cell[2] += value.z;
          },
          kLeafLevel, binExtent);
    }
    if (k == 1 && params_.brdf == "lambert") {
      for (int c = 0; c < 3; ++c)
        table_[size_t(node) * stride_ + size_t(c)] = float(lin[size_t(c)] / s);
    } else {
      rgbMoments(basis, basis, lin, k, table_.data() + size_t(node) * stride_);
    }
    const size_t d = ++done;
    if (d % 256 == 0) report(progress, "lighting", double(d) / double(grid_.size()));
  });
  tabulateIrradiance();
  report(progress, "lighting", 1.0);
}

bool ChebLocalLighting::importState(std::span<const float> in) {
  if (!ChebBase::importState(in)) return false;
  tabulateIrradiance();
  return true;
}

void ChebLocalLighting::tabulateIrradiance() {
  const size_t kk = stride_ / 3;
  nodeIrradiance_.assign(grid_.size() * 3, 0.0f);
  parallelFor(
      0, int64_t(grid_.size()),
      [&](int64_t node) {
        const float* tl = table_.data() + size_t(node) * stride_;
        for (size_t c = 0; c < 3; ++c) {
          double sum = 0.0;
          for (size_t i = 0; i < kk; ++i) sum += double(tl[c * kk + i]) * double(global_[i]);
          nodeIrradiance_[3 * size_t(node) + c] = float(sum);
        }
      },
      64);
}

glm::vec3 ChebLocalLighting::irradiance(const glm::vec3& n) const {
  // Σ_mn T^L_mn(n) T^f_mn, with T^L(n) interpolated between grid normals: Σ_q w_q (T^L_q · T^f),
  // each node's product tabulated.
  COMPOSE_CHECK(!nodeIrradiance_.empty());
  size_t nodes[4];
  float w[4];
  grid_.interpolation(n, nodes, w);
  glm::vec3 e(0.0f);
  for (int q = 0; q < 4; ++q) {
    const float* node = nodeIrradiance_.data() + 3 * nodes[q];
    e += w[q] * glm::vec3(node[0], node[1], node[2]);
  }
  return e;
}

namespace {

// Σ x_i y_i over n floats, in eight running sums (vectorised: a single sum would have to keep
// its order).
float innerProduct(const float* x, const float* y, size_t n) {
  float sums[8] = {};
  size_t i = 0;
  for (; i + 8 <= n; i += 8)
    for (size_t j = 0; j < 8; ++j) sums[j] += x[i + j] * y[i + j];
  float sum = 0.0f;
  for (; i < n; ++i) sum += x[i] * y[i];
  for (const float s : sums) sum += s;
  return sum;
}

}  // namespace

glm::vec3 ChebLocalLighting::shade(double latitude, double longitude, const float* b,
                                   int stride) const {
  COMPOSE_CHECK(!table_.empty());
  const size_t k = size_t(params_.order), kk = k * k;
  COMPOSE_CHECK(size_t(stride) >= k);
  size_t nodes[4];
  float w[4];
  grid_.interpolationAt(latitude, longitude, nodes, w);
  glm::vec3 e(0.0f);
  for (int q = 0; q < 4; ++q) {
    if (w[q] == 0.0f) continue;
    const float* node = table_.data() + nodes[q] * stride_;
    for (int c = 0; c < 3; ++c) {
      const float* a = node + size_t(c) * kk;
      float sum = 0.0f;
      if (size_t(stride) == k) {
        sum = innerProduct(a, b, kk);
      } else {
        for (size_t m = 0; m < k; ++m) sum += innerProduct(a + m * k, b + m * size_t(stride), k);
      }
      e[c] += w[q] * sum;
    }
  }
  return e;
}

size_t ChebLocalLighting::floatsStored() const {
  return ChebBase::floatsStored() + viewTable_.size();
}

double ChebLocalLighting::orenNayar(double sigma, double thetaIn, double phiIn, double thetaOut,
                                    double phiOut) {
  const double s2 = sigma * sigma;
  const double a = 1.0 - 0.5 * s2 / (s2 + 0.33), b = 0.45 * s2 / (s2 + 0.09);
  const double alpha = std::max(thetaIn, thetaOut), beta = std::min(thetaIn, thetaOut);
  return a + b * std::max(0.0, std::cos(phiIn - phiOut)) * std::sin(alpha) * std::tan(beta);
}

glm::vec3 ChebLocalLighting::irradiance(const glm::vec3& n, const glm::vec3& view) const {
  if (params_.brdf == "lambert") return irradiance(n);
  // The view in the local frame of n (the same east/north construction as the grid nodes).
  const float h = std::sqrt(n.x * n.x + n.z * n.z);
  const glm::vec3 east =
      h > 1e-6f ? glm::vec3(n.z / h, 0.0f, -n.x / h) : glm::vec3(1.0f, 0.0f, 0.0f);
  const glm::vec3 north = glm::cross(n, east);
  const float cosOut = std::clamp(glm::dot(n, view), 0.0f, 1.0f);
  const double thetaOut = std::acos(double(cosOut));
  double phiOut = fastAtan2(glm::dot(north, view), glm::dot(east, view));
  if (phiOut < 0.0) phiOut += 2.0 * kPi;
  // Bilinear in (θo, φo) over the view table.
  const double u = thetaOut / (0.5 * kPi) * (kViewThetas - 1), v = phiOut / (2.0 * kPi) * kViewPhis;
  const int a0 = std::min(int(u), kViewThetas - 2), b0 = int(v) % kViewPhis,
            b1 = (b0 + 1) % kViewPhis;
  const float fu = float(u - a0), fv = float(v - std::floor(v));
  const size_t kk = stride_ / 3;
  auto entry = [&](int a, int b) {
    return viewTable_.data() + (size_t(a) * kViewPhis + size_t(b)) * kk;
  };
  const float* t00 = entry(a0, b0);
  const float* t01 = entry(a0, b1);
  const float* t10 = entry(a0 + 1, b0);
  const float* t11 = entry(a0 + 1, b1);
  size_t nodes[4];
  float w[4];
  grid_.interpolation(n, nodes, w);
  glm::vec3 e(0.0f);
  for (size_t i = 0; i < kk; ++i) {
    const float tf =
        (1 - fu) * ((1 - fv) * t00[i] + fv * t01[i]) + fu * ((1 - fv) * t10[i] + fv * t11[i]);
    glm::vec3 tl(0.0f);
    for (int q = 0; q < 4; ++q) {
      const float* node = table_.data() + nodes[q] * stride_;
      tl += w[q] * glm::vec3(node[i], node[kk + i], node[2 * kk + i]);
    }
    e += tl * tf;
  }
  return e;
}

double ChebLocalLighting::truncatedProduct(size_t node, int channel, int k) const {
  const int K = params_.order;
  const size_t kk = size_t(K) * size_t(K);
  const float* tl = table_.data() + node * stride_ + size_t(channel) * kk;
  double sum = 0.0;
  for (int m = 0; m < k; ++m)
    for (int n = 0; n < k; ++n) sum += double(tl[m * K + n]) * global_[size_t(m * K + n)];
  return sum;
}

}  // namespace compose::lighting
