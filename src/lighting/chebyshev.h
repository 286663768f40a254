// Lighting by 2D discrete Chebyshev (Tchebichef) moments, after Alnasser & Foroosh, "Image-Based
// Rendering of Synthetic Diffuse Objects in Natural Scenes" (ICPR 2006), docs/design.md §5.
//
// On an s x s grid of directions (i = altitude index, j = azimuth index) the outgoing radiance is
//   L_o = Σ_i Σ_j L_in(i, j) f_c(i, j) = Σ_{m<s} Σ_{n<s} T^L_mn T^f_mn       (paper eq. 7)
// with T^X = P X Qᵀ the moments of either factor (orthonormal polynomials t_m, t_n in P, Q).
// Truncating the sum to m, n < k is the approximation; k = s reproduces the grid sum exactly.
// The interface returns irradiance, so the BRDF factor here is the cosine part only (a
// Lambertian f = ρ/π is applied by the renderer).
//
// Three readings of the paper, interchangeable behind DiffuseLighting:
//  * cheb-latlong: world altitude/azimuth grid. L_in(i, j) = mean radiance over the cell (moments
//    once per environment); f_c(i, j) = ∫_cell max(0, n·ω) dω, whose moments are tabulated per
//    normal. The solid angle and the cosine live on the BRDF side, so a constant environment has
//    a single T_00 moment and the white furnace holds at every order.
//  * cheb-face: the same on each of the six cube faces (s = face size, six moment blocks).
//  * cheb-local: a hemisphere grid around the normal (θ from the normal in [0, π/2], φ around it).
//    L_in(i, j) = ∫_cell L cos θ dω — the paper's own L_in, with the cosine on the LIGHTING side
//    — tabulated as k x k moments per normal; f_c(i, j) = 1 (Lambertian). With a constant f_c
//    only T^f_00 is non-zero, so for Lambertian surfaces the product reduces to the (0, 0) term:
//    the accuracy comes from integrating L cos exactly per cell, not from k.
//
// Per-normal tables live on a NormalGrid (lat-long lattice of normals including the poles) and
// are interpolated bilinearly. Storage is reported honestly: floatsStored() counts every table
// that is projected and stored (exportState); cheb-local's per-node irradiance, 3 floats per node
// derived from those tables whenever they are set, is a lookup aid and not counted.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "lighting/lighting.h"
#include "lighting/tchebichef.h"

namespace compose::lighting {

struct ChebParams {
  int order = 3;        // k: k x k moments per channel
  int samples = 16;     // s: the direction grid is s x s (per face for cheb-face)
  int normalRows = 33;  // normal-grid rows (pole to pole, both included)
  int normalCols = 64;  // normal-grid columns (longitude)
  int subsamples = 4;   // q x q sub-cells per grid cell when integrating the cosine (BRDF side)
  // BRDF of the local basis: "lambert", or "oren-nayar" with roughness sigma (radians; the
  // qualitative model of Oren & Nayar 1994), which is view dependent and uses the full k x k
  // product.
  std::string brdf = "lambert";
  double sigma = 0.0;

  // Throws compose::Error (stage "lighting") naming the basis and the bad parameter.
  void validate(const std::string& basis) const;
  // Reads order, samples, rows, cols, subsamples from `params`, then validates.
  static ChebParams from(ParamSet& params, const std::string& basis, ChebParams defaults);
};

// Unit normals on a lat-long lattice: row r at latitude π/2 - rπ/(rows-1), column c at
// longitude 2πc/cols (OpenEXR axes, environment.h). Bilinear interpolation, wrapping in longitude.
class NormalGrid {
 public:
  NormalGrid() = default;
  NormalGrid(int rows, int cols);
  int rows() const { return rows_; }
  int cols() const { return cols_; }
  size_t size() const { return size_t(rows_) * size_t(cols_); }
  glm::vec3 normal(size_t node) const;
  // A tangent frame continuous in longitude: east = ∂n/∂φ normalised, north = n x east.
  void frame(size_t node, glm::vec3& east, glm::vec3& north) const;
  // The four nodes around unit direction n and their bilinear weights.
  void interpolation(const glm::vec3& n, size_t nodes[4], float weights[4]) const;
  // The same for a direction given by latitude and longitude (radians; longitude as atan2(x, z),
  // any value, wrapped).
  void interpolationAt(double latitude, double longitude, size_t nodes[4], float weights[4]) const;

 private:
  int rows_ = 0, cols_ = 0;
};

// Shared machinery: parameters, bases, the normal grid and the per-node tables.
class ChebBase : public DiffuseLighting {
 public:
  ChebBase(std::string name, ChebParams params);
  std::string name() const override { return name_; }
  std::string describe() const override;
  int coefficientsPerChannel() const override { return blocks_ * params_.order * params_.order; }
  size_t floatsStored() const override;
  std::string parameterKey() const override;
  bool exportState(std::vector<float>& out) const override;
  bool importState(std::span<const float> in) override;

  // Truncation estimate from the moments' tail: for each k = 1..order, the SNR of the order-k
  // inner product against the full-order one, over the normal-grid nodes (all channels):
  //   10 log10(Σ E_K² / Σ (E_K - E_k)²),  E_k = Σ_{m,n<k} T^L_mn T^f_mn.
  // It measures what truncation costs, not the grid's own discretisation. Needs project().
  std::vector<double> truncationSnrDb() const;

 protected:
  // E_k at a grid node for one channel: the inner product over the top-left k x k moments.
  virtual double truncatedProduct(size_t node, int channel, int k) const = 0;
  // table_ made grid_.size() x stride_ zeros; compose::MemoryShortfall (core/limits.h) first when
  // that would not fit in the memory left, naming the parameters that size it.
  void reserveTable();

  std::string name_;
  ChebParams params_;
  int blocks_ = 1;         // moment blocks per point (6 for cheb-face)
  size_t globalSize_ = 0;  // floats in global_ once projected (set by each basis' constructor)
  NormalGrid grid_;
  size_t stride_ = 0;          // floats per node
  std::vector<float> table_;   // per node
  std::vector<float> global_;  // per environment (lighting or BRDF moments)
};

class ChebLatLongLighting final : public ChebBase {
 public:
  explicit ChebLatLongLighting(ChebParams params);
  void project(const Environment& environment, const Progress& progress = {}) override;
  glm::vec3 irradiance(const glm::vec3& n) const override;

 protected:
  double truncatedProduct(size_t node, int channel, int k) const override;
};

class ChebFaceLighting final : public ChebBase {
 public:
  explicit ChebFaceLighting(ChebParams params);
  void project(const Environment& environment, const Progress& progress = {}) override;
  glm::vec3 irradiance(const glm::vec3& n) const override;

 protected:
  double truncatedProduct(size_t node, int channel, int k) const override;
};

class ChebLocalLighting final : public ChebBase {
 public:
  explicit ChebLocalLighting(ChebParams params);
  void project(const Environment& environment, const Progress& progress = {}) override;
  glm::vec3 irradiance(const glm::vec3& n) const override;
  glm::vec3 irradiance(const glm::vec3& n, const glm::vec3& view) const override;
  size_t floatsStored() const override;
  bool importState(std::span<const float> in) override;

  int order() const { return params_.order; }
  int samples() const { return params_.samples; }
  bool lambertian() const { return params_.brdf == "lambert"; }
  // E = Σ_mn a_mn b_mn per channel for a Lambertian surface whose normal has this latitude and
  // longitude: a the lighting moments (k x k per channel) there, in the tangent frame of that
  // longitude (east = (cos φ, 0, -sin φ), north = n x east), b the moments of the BRDF side (1,
  // or a visibility mask) of order >= k, its row m starting at b + m * stride. Each grid node's
  // moments are dotted with b, then interpolated as the moments would be. Needs project().
  glm::vec3 shade(double latitude, double longitude, const float* b, int stride) const;

  // Oren–Nayar BRDF times π/ρ for local angles (θi, φi) and (θo, φo); 1 for sigma = 0.
  static double orenNayar(double sigma, double thetaIn, double phiIn, double thetaOut,
                          double phiOut);
  // Table of BRDF moments over the view: kViewThetas x kViewPhis entries of k x k.
  static constexpr int kViewThetas = 17, kViewPhis = 32;

 private:
  // The Lambertian irradiance at every grid node, Σ_mn T^L_mn T^f_mn per channel (node-major RGB),
  // summed once when the moments are set, so that irradiance(n) interpolates four of them.
  void tabulateIrradiance();

  std::vector<float> viewTable_;       // BRDF moments per view direction (Oren–Nayar only)
  std::vector<float> nodeIrradiance_;  // 3 per grid node

 protected:
  double truncatedProduct(size_t node, int channel, int k) const override;
};

}  // namespace compose::lighting
