#include "lighting/order_selector.h"

#include <cmath>
#include <limits>

#include "core/error.h"
#include "lighting/chebyshev.h"
#include "lighting/sh.h"

namespace compose::lighting {

std::vector<OrderEstimate> estimateOrders(const std::string& basis, const Environment& env,
                                          const ParamSet& params) {
  std::vector<OrderEstimate> out;
  if (basis == "sh") {
    ShLighting full(kMaxShOrder);
    full.project(env);
    const auto& L = full.radianceCoefficients();
    std::vector<double> band(kMaxShOrder + 1, 0.0);  // A_l² Σ_m |L_lm|² (all channels)
    for (int l = 0; l <= kMaxShOrder; ++l) {
      const double a = shCosineLobe(l);
      for (int m = -l; m <= l; ++m) {
        const glm::dvec3& c = L[size_t(l * (l + 1) + m)];
        band[size_t(l)] += a * a * (c.x * c.x + c.y * c.y + c.z * c.z);
      }
    }
    double total = 0.0;
    for (double b : band) total += b;
    for (int order = 0; order <= kMaxShOrder; ++order) {
      double tail = 0.0;
      for (int l = order + 1; l <= kMaxShOrder; ++l) tail += band[size_t(l)];
      out.push_back(
          {order, shCount(order),
           tail > 0.0 ? 10.0 * std::log10(total / tail) : std::numeric_limits<double>::infinity()});
    }
    return out;
  }
  if (basis == "cheb-latlong" || basis == "cheb-face" || basis == "cheb-local") {
    ParamSet p = params;
    if (p.getString("brdf", "lambert") != "lambert") {
      throw Error("lighting", "order=auto estimates Lambertian truncation only; give brdf=" +
                                  p.getString("brdf", "") + " an explicit order");
    }
    ChebParams defaults;
    if (basis == "cheb-face") defaults.samples = 8, defaults.subsamples = 4;
    if (basis == "cheb-local") defaults.samples = 8;
    const int samples = p.getInt("samples", defaults.samples, "lighting");
    p.set("samples", std::to_string(samples));
    p.set("order", std::to_string(std::min(samples, 32)));
    ChebParams cp = ChebParams::from(p, basis, defaults);
    std::unique_ptr<ChebBase> full;
    if (basis == "cheb-latlong") full = std::make_unique<ChebLatLongLighting>(cp);
    if (basis == "cheb-face") full = std::make_unique<ChebFaceLighting>(cp);
    if (basis == "cheb-local") full = std::make_unique<ChebLocalLighting>(cp);
    full->project(env);
    const std::vector<double> snr = full->truncationSnrDb();
    const int blocks = basis == "cheb-face" ? 6 : 1;
    for (int k = 1; k <= cp.order; ++k) out.push_back({k, blocks * k * k, snr[size_t(k - 1)]});
    return out;
  }
  throw Error("lighting", "no order selection for basis '" + basis + "' (sh and cheb-* have one)");
}

OrderEstimate selectOrder(const std::vector<OrderEstimate>& estimates, double targetSnrDb) {
  COMPOSE_CHECK(!estimates.empty());
  for (const auto& e : estimates) {
    if (e.estimatedSnrDb >= targetSnrDb) return e;
  }
  return estimates.back();
}

}  // namespace compose::lighting
