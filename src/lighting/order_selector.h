// Order selection: the smallest truncation order that reaches a target accuracy, decided from the
// projection's own tail energy instead of from a reference (which a user does not have).
//
//  * sh: Parseval over the sphere of normals, ∫|E_8 - E_L|² dn = Σ_{L<l≤8} A_l² Σ_m L_lm², so the
//    SNR of order L against order 8 is 10 log10(Σ_{l≤8} A_l² |L_l|² / Σ_{L<l≤8} A_l² |L_l|²).
//  * cheb-*: the inner product truncated to k x k against the full-order one (k = samples), over
//    the normal-grid nodes (ChebBase::truncationSnrDb).
// Both estimate the truncation error only; the bases' grids add their own, measured in the
// benchmark. The tests check the estimates against the exact reference.
#pragma once

#include <string>
#include <vector>

#include "lighting/lighting.h"

namespace compose::lighting {

struct OrderEstimate {
  int order = 0;  // sh: band limit L; cheb-*: k
  int coefficientsPerChannel = 0;
  double estimatedSnrDb = 0.0;  // +inf when truncation costs nothing
};

// Estimates for every order the basis can take with `params` (its `order`, if given, is ignored).
// Supports sh, cheb-latlong, cheb-face and cheb-local; throws compose::Error otherwise.
std::vector<OrderEstimate> estimateOrders(const std::string& basis, const Environment& environment,
                                          const ParamSet& params);

// The first estimate reaching `targetSnrDb`, or the last (most accurate) one if none does.
OrderEstimate selectOrder(const std::vector<OrderEstimate>& estimates, double targetSnrDb);

}  // namespace compose::lighting
