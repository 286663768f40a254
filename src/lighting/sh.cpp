#include "lighting/sh.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <numbers>
#include <string>

#include "core/error.h"
#include "core/numbers.h"
#include "core/parallel.h"

namespace compose::lighting {

namespace {

// Normalisation K_lm = sqrt((2l+1)/(4π) (l-m)!/(l+m)!), with the √2 of the real basis folded in
// for m > 0. Computed once.
struct ShNorm {
  std::array<double, shCount(kMaxShOrder)> k{};
  ShNorm() {
    for (int l = 0; l <= kMaxShOrder; ++l) {
      for (int m = 0; m <= l; ++m) {
        double ratio = 1.0;  // (l-m)!/(l+m)!
        for (int i = l - m + 1; i <= l + m; ++i) ratio /= i;
        double v = std::sqrt((2 * l + 1) / (4 * kPi) * ratio);
        if (m > 0) v *= std::numbers::sqrt2;
        k[size_t(l * (l + 1) + m)] = v;
      }
    }
  }
};
const ShNorm& shNorm() {
  static const ShNorm norm;
  return norm;
}

// Y_lm through the "reduced" associated Legendre functions Q_l^m(z) = P_l^m(z) / sin^m θ and
// (x + iy)^m = sin^m θ e^{imφ}, which avoids trigonometry and the pole singularity.
template <class T>
void evalShImpl(int order, T xs, T ys, T zs, T* out) {
  COMPOSE_CHECK(order >= 0 && order <= kMaxShOrder);
  const auto& k = shNorm().k;
  T cm = 1, sm = 0;  // Re, Im of (x + iy)^m
  T qmm = 1;         // Q_m^m = (2m-1)!!
  for (int m = 0; m <= order; ++m) {
    if (m > 0) {
      const T c = cm * xs - sm * ys;
      sm = cm * ys + sm * xs;
      cm = c;
      qmm *= T(2 * m - 1);
    }
    T q2 = 0, q1 = qmm;  // Q_{l-2}^m, Q_{l-1}^m
    for (int l = m; l <= order; ++l) {
      T q;
      if (l == m) {
        q = qmm;
      } else if (l == m + 1) {
        q = T(2 * m + 1) * zs * qmm;
      } else {
        q = (T(2 * l - 1) * zs * q1 - T(l + m - 1) * q2) / T(l - m);
      }
      if (l > m) {
        q2 = q1;
        q1 = q;
      }
      const int base = l * (l + 1);
      const T kq = T(k[size_t(base + m)]) * q;
      if (m == 0) {
        out[base] = kq;
      } else {
        out[base + m] = kq * cm;
        out[base - m] = kq * sm;
      }
    }
  }
}

}  // namespace

// World (x, y, z) → SH frame (z_w, x_w, y_w): the pole is world +Y.
void evalSh(int order, const glm::vec3& d, float* out) {
  evalShImpl<float>(order, d.z, d.x, d.y, out);
}
void evalSh(int order, const glm::dvec3& d, double* out) {
  evalShImpl<double>(order, d.z, d.x, d.y, out);
}

double shCosineLobe(int l) {
  if (l == 0) return kPi;
  if (l == 1) return 2.0 * kPi / 3.0;
  if (l % 2 == 1) return 0.0;
  // 2π (-1)^(l/2-1) / ((l+2)(l-1)) · l! / (2^l ((l/2)!)^2)
  double binom = 1.0;  // l! / ((l/2)!)^2 / 2^l
  for (int i = 1; i <= l / 2; ++i) binom *= double(l / 2 + i) / double(i) / 4.0;
  const double sign = ((l / 2 - 1) % 2 == 0) ? 1.0 : -1.0;
  return 2.0 * kPi * sign / (double(l + 2) * double(l - 1)) * binom;
}

ShLighting::ShLighting(int order, ShWindow window) : order_(order), window_(window) {
  if (order < 0 || order > kMaxShOrder) {
    throw Error("lighting", "sh order must be in 0.." + std::to_string(kMaxShOrder) + ", got " +
                                std::to_string(order));
  }
}

std::string ShLighting::describe() const {
  const char* window = window_ == ShWindow::Hanning   ? " window=hanning"
                       : window_ == ShWindow::Lanczos ? " window=lanczos"
                                                      : "";
  return "sh order=" + std::to_string(order_) + window + " (" + std::to_string(shCount(order_)) +
         " coefficients/channel)";
}

double ShLighting::windowWeight(int l) const {
  const double x = double(l) / double(order_ + 1);
  switch (window_) {
    case ShWindow::Hanning:
      return 0.5 * (1.0 + std::cos(kPi * x));
    case ShWindow::Lanczos:
      return l == 0 ? 1.0 : std::sin(kPi * x) / (kPi * x);
    case ShWindow::None:
      break;
  }
  return 1.0;
}

// Projection integrates each basis function over each texel instead of point-sampling it at the
// centre. With the pole on +Y, the SH azimuth is the map's longitude and cos θ = sin(latitude), so
// Y_lm = N_lm P_l^m(z) {cos, sin}(mφ) separates over a texel's z-interval and φ-interval:
//   ∫_texel Y_lm dω = N_lm ∫_{z0}^{z1} P_l^m(z) dz · ∫_{φ0}^{φ1} {cos, sin}(mφ) dφ.
// The φ integral is closed-form; the z integral uses 5-point Gauss–Legendre per row (exact for
// the polynomial m-even terms up to band 9). A texel's value is the mean radiance over the texel
// (box filter), so L_lm = Σ_t L_t ∫_t Y_lm dω is the exact projection of that piecewise-constant
// map: a constant map projects to band 0 alone and the white furnace gives π to float precision.
void ShLighting::project(const Environment& env, const Progress& progress) {
  const int count = shCount(order_);
  const int w = env.width(), h = env.height();

  // Per column: ∫ cos(mφ) dφ and ∫ sin(mφ) dφ over the texel, m = 0..order.
  const int mCount = order_ + 1;
  std::vector<double> colCos(size_t(w) * size_t(mCount)), colSin(size_t(w) * size_t(mCount));
  for (int x = 0; x < w; ++x) {
    const double left = kPi * (1.0 - 2.0 * x / w), right = kPi * (1.0 - 2.0 * (x + 1) / w);
    colCos[size_t(x * mCount)] = left - right;
    colSin[size_t(x * mCount)] = 0.0;
    for (int m = 1; m <= order_; ++m) {
      colCos[size_t(x * mCount + m)] = (std::sin(m * left) - std::sin(m * right)) / m;
      colSin[size_t(x * mCount + m)] = (std::cos(m * right) - std::cos(m * left)) / m;
    }
  }

  // Per row: Σ_x L(x, y) ∫cos / ∫sin, then times N_lm ∫P_l^m dz; summed in row order afterwards
  // so that the result does not depend on scheduling.
  std::vector<glm::dvec3> rows(size_t(h) * size_t(count), glm::dvec3(0.0));
  std::atomic<int> done{0};
  parallelFor(0, h, [&](int64_t yy) {
    const int y = int(yy);
    std::array<glm::dvec3, kMaxShOrder + 1> sc{}, ss{};
    for (int x = 0; x < w; ++x) {
      const glm::dvec3 L(env.radiance(x, y));
      if (L.x == 0.0 && L.y == 0.0 && L.z == 0.0) continue;
      for (int m = 0; m <= order_; ++m) {
        sc[size_t(m)] += L * colCos[size_t(x * mCount + m)];
        ss[size_t(m)] += L * colSin[size_t(x * mCount + m)];
      }
    }
    // 5-point Gauss–Legendre on [z0, z1].
    static constexpr double kNodes[5] = {0.0, -0.5384693101056831, 0.5384693101056831,
                                         -0.9061798459386640, 0.9061798459386640};
    static constexpr double kWeights[5] = {0.5688888888888889, 0.4786286704993665,
                                           0.4786286704993665, 0.2369268850561891,
                                           0.2369268850561891};
    const double z1 = std::sin(kPi * (0.5 - double(y) / h)),
                 z0 = std::sin(kPi * (0.5 - double(y + 1) / h));
    std::array<double, shCount(kMaxShOrder)> zInt{};
    std::array<double, shCount(kMaxShOrder)> basis{};
    for (int g = 0; g < 5; ++g) {
      const double z = 0.5 * (z0 + z1) + 0.5 * (z1 - z0) * kNodes[g];
      const double wg = 0.5 * (z1 - z0) * kWeights[g];
      // (x_sh, y_sh, z_sh) = (sin θ, 0, z): φ = 0, so Y_lm for m >= 0 is N_lm P_l^m(z) and the
      // m < 0 entries vanish; divide N back out below.
      const double st = std::sqrt(std::max(0.0, 1.0 - z * z));
      evalSh(order_, glm::dvec3(0.0, z, st), basis.data());  // world (x, y, z) = (y_sh, z_sh, x_sh)
      for (int i = 0; i < count; ++i) zInt[size_t(i)] += wg * basis[size_t(i)];
    }
    glm::dvec3* acc = rows.data() + size_t(y) * size_t(count);
    for (int l = 0; l <= order_; ++l) {
      for (int m = 0; m <= l; ++m) {
        const double pz = zInt[size_t(l * (l + 1) + m)];  // N_lm ∫ P_l^m dz (N includes the √2)
        if (m == 0) {
          acc[l * (l + 1)] += sc[0] * pz;
        } else {
          acc[l * (l + 1) + m] += sc[size_t(m)] * pz;
          acc[l * (l + 1) - m] += ss[size_t(m)] * pz;
        }
      }
    }
    const int d = ++done;
    if (d % 64 == 0) report(progress, "lighting", double(d) / h);
  });
  radiance_.assign(size_t(count), glm::dvec3(0.0));
  for (int y = 0; y < h; ++y) {
    for (int i = 0; i < count; ++i)
      radiance_[size_t(i)] += rows[size_t(y) * size_t(count) + size_t(i)];
  }
  irradiance_.resize(size_t(count));
  for (int l = 0; l <= order_; ++l) {
    const double a = shCosineLobe(l) * windowWeight(l);
    for (int m = -l; m <= l; ++m) {
      const size_t i = size_t(l * (l + 1) + m);
      irradiance_[i] = glm::vec3(radiance_[i] * a);
    }
  }
  report(progress, "lighting", 1.0);
}

bool ShLighting::exportState(std::vector<float>& out) const {
  if (irradiance_.empty()) return false;
  out.clear();
  for (const glm::vec3& e : irradiance_) out.insert(out.end(), {e.x, e.y, e.z});
  for (const glm::dvec3& L : radiance_) {
    for (int c = 0; c < 3; ++c) {
      const float hi = float(L[c]);
      const float mid = float(L[c] - double(hi));
      const float lo = float(L[c] - double(hi) - double(mid));
      out.insert(out.end(), {hi, mid, lo});
    }
  }
  return true;
}

bool ShLighting::importState(std::span<const float> in) {
  const size_t count = size_t(shCount(order_));
  if (in.size() != 3 * count + 9 * count) return false;
  irradiance_.resize(count);
  radiance_.resize(count);
  for (size_t i = 0; i < count; ++i) irradiance_[i] = {in[3 * i], in[3 * i + 1], in[3 * i + 2]};
  const float* r = in.data() + 3 * count;
  for (size_t i = 0; i < count; ++i)
    for (int c = 0; c < 3; ++c, r += 3)
      radiance_[i][c] = double(r[0]) + double(r[1]) + double(r[2]);
  return true;
}

glm::vec3 ShLighting::irradiance(const glm::vec3& n) const {
  COMPOSE_CHECK(!irradiance_.empty());
  std::array<float, shCount(kMaxShOrder)> basis;
  evalSh(order_, n, basis.data());
  glm::vec3 e(0.0f);
  for (size_t i = 0; i < irradiance_.size(); ++i) e += irradiance_[i] * basis[i];
  return e;
}

}  // namespace compose::lighting
