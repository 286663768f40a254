#include "lighting/chebyshev.h"

#include <cmath>
#include <fstream>
#include <numbers>
#include <random>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "lighting/exact.h"
#include "lighting/lighting_cache.h"
#include "lighting/monte_carlo.h"
#include "lighting/sh.h"
#include "lighting/tchebichef.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

using compose::testing::randomNormals;

// A smooth sky with a small, very bright sun: the hard case for low-order representations.
Environment sunAndSky(int width, float sun) {
  const Environment probe = Environment::constant(glm::vec3(0.0f), width);
  Image img(width, width / 2, 3);
  const glm::vec3 sunDir = glm::normalize(glm::vec3(0.4f, 0.6f, -0.5f));
  for (int y = 0; y < img.height; ++y) {
    for (int x = 0; x < img.width; ++x) {
      const glm::vec3 d = probe.direction(x, y);
      glm::vec3 L = glm::vec3(0.3f, 0.5f, 0.9f) * (0.6f + 0.4f * d.y) +
                    glm::vec3(0.2f, 0.15f, 0.1f) * (d.y < 0 ? 1.0f : 0.0f);
      if (glm::dot(d, sunDir) > 0.9995f) L += glm::vec3(sun);
      img.at(x, y)[0] = L.x, img.at(x, y)[1] = L.y, img.at(x, y)[2] = L.z;
    }
  }
  return Environment::fromLatLong(img);
}

double snrDb(const DiffuseLighting& basis, const DiffuseLighting& reference,
             const std::vector<glm::vec3>& normals) {
  double signal = 0, noise = 0;
  for (const auto& n : normals) {
    const glm::dvec3 r(reference.irradiance(n)), g(basis.irradiance(n));
    signal += glm::dot(r, r);
    noise += glm::dot(r - g, r - g);
  }
  return 10.0 * std::log10(signal / noise);
}

// The exact reference integrates each texel's cell exactly (closed-form vector moments), so a
// constant map gives π up to the texels the horizon cuts.
TEST(WhiteFurnace, ExactReferenceGivesPi) {
  ExactLighting exact;
  exact.project(Environment::constant(glm::vec3(1.0f), 1024));
  constexpr double kFurnace = 1e-6;  // the bound, at the sample maps' 1024x512
  for (const auto& n : randomNormals(64, 1))
    EXPECT_NEAR(exact.irradiance(n).y, kPi, kFurnace * kPi);
}

TEST(WhiteFurnace, ChebyshevBasesGivePi) {
  const Environment env = Environment::constant(glm::vec3(1.0f), 1024);
  for (const char* name : {"cheb-local", "cheb-latlong", "cheb-face"}) {
    for (const char* params : {"order=1", "order=3"}) {
      auto basis = createLighting(name, ParamSet::parse(params, "t"));
      basis->project(env);
      for (const auto& n : randomNormals(64, 2)) {
        // Every Chebyshev basis integrates exactly except on the horizon (cells and sub-cells the
        // horizon cuts use a clipped linear model), and a constant map has only T_00.
        constexpr double tolerance = 1e-6;
        EXPECT_NEAR(basis->irradiance(n).x, kPi, tolerance * kPi) << name << " " << params;
      }
    }
  }
}

// Projection is deterministic (same parameters, same numbers bit for bit), and truncating the
// moments (k < s) changes the answer.
TEST(Chebyshev, DeterministicAndTruncationIsVisible) {
  const Environment env = sunAndSky(256, 500.0f);
  const auto normals = randomNormals(40, 3);
  for (const char* name : {"cheb-latlong", "cheb-face"}) {
    auto full = createLighting(name, ParamSet::parse("order=8,samples=8,subsamples=2", "t"));
    auto more = createLighting(name, ParamSet::parse("order=8,samples=8,subsamples=2", "t"));
    full->project(env);
    more->project(env);
    auto lower = createLighting(name, ParamSet::parse("order=2,samples=8,subsamples=2", "t"));
    lower->project(env);
    double diffLow = 0, diffFull = 0;
    for (const auto& n : normals) {
      diffLow += glm::length(lower->irradiance(n) - full->irradiance(n));
      diffFull += glm::length(more->irradiance(n) - full->irradiance(n));
    }
    EXPECT_EQ(diffFull, 0.0) << name;
    EXPECT_GT(diffLow, 0.0) << name;
  }
}

// cheb-local on a sun-and-sky map: the sun is a few texels, 2000 times the sky. The local basis
// integrates L cos exactly per normal, so its error is only the normal-grid interpolation.
TEST(Chebyshev, LocalBasisMatchesTheExactReference) {
  const Environment env = sunAndSky(512, 2000.0f);
  ExactLighting exact;
  exact.project(env);
  const auto normals = randomNormals(300, 4);
  auto local = createLighting("cheb-local", ParamSet::parse("order=1", "t"));
  local->project(env);
  auto k3 = createLighting("cheb-local", ParamSet::parse("order=3,samples=8", "t"));
  k3->project(env);
  ShLighting sh(2);
  sh.project(env);
  const double localDb = snrDb(*local, exact, normals), shDb = snrDb(sh, exact, normals);
  // Measured 50-52 dB; SH9 measures about 25 dB on this map.
  constexpr double kLocalFloorDb = 45.0;
  EXPECT_GT(localDb, kLocalFloorDb);
  EXPECT_GT(localDb, shDb + 10.0);
  // For a Lambertian BRDF only T_00 carries weight: k = 3 gives the same answer as k = 1.
  EXPECT_NEAR(snrDb(*k3, exact, normals), localDb, 0.01);
  RecordProperty("local_db", std::to_string(localDb));
  RecordProperty("sh9_db", std::to_string(shDb));
}

// Shading from visibility moments (the self-shadowing's product): a point that sees its whole
// hemisphere gets the unshadowed irradiance, and moments of a higher order than the lighting's
// give what their leading k x k block gives, at any point of the normal grid or between.
TEST(ChebLocalLighting, ShadingFromMomentsOfFullVisibilityIsTheIrradiance) {
  const Environment env = sunAndSky(256, 200.0f);
  ChebParams params;
  params.order = 4;
  params.samples = 12;
  ChebLocalLighting lighting(params);
  lighting.project(env);
  constexpr int kTransferOrder = 6;
  const TchebichefBasis basis(params.samples, kTransferOrder);
  const std::vector<double> ones(size_t(params.samples) * size_t(params.samples), 1.0);
  const std::vector<double> full = moments2d(basis, basis, ones, kTransferOrder);
  const std::vector<float> wide(full.begin(), full.end());  // 6 x 6
  // A random visibility mask's moments, and their leading 4 x 4 block.
  std::mt19937 rng(7);
  std::vector<double> mask(ones.size());
  for (double& v : mask) v = double(rng() % 2);
  const std::vector<double> masked = moments2d(basis, basis, mask, kTransferOrder);
  const std::vector<float> maskWide(masked.begin(), masked.end());
  std::vector<float> leading;
  for (int m = 0; m < params.order; ++m)
    for (int n = 0; n < params.order; ++n)
      leading.push_back(maskWide[size_t(m * kTransferOrder + n)]);
  std::uniform_real_distribution<double> lat(-1.5, 1.5), lon(-3.1, 3.1);
  for (int i = 0; i < 40; ++i) {
    const double a = lat(rng), b = lon(rng);
    const glm::vec3 n(float(std::cos(a) * std::sin(b)), float(std::sin(a)),
                      float(std::cos(a) * std::cos(b)));
    const glm::vec3 expected = lighting.irradiance(n);
    const glm::vec3 fromWide = lighting.shade(a, b, wide.data(), kTransferOrder);
    const glm::vec3 maskedWide = lighting.shade(a, b, maskWide.data(), kTransferOrder);
    const glm::vec3 maskedLeading = lighting.shade(a, b, leading.data(), params.order);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(fromWide[c], expected[c], 1e-4f * expected[c] + 1e-6f) << i << " " << c;
      EXPECT_NEAR(maskedWide[c], maskedLeading[c], 1e-5f * expected[c] + 1e-7f) << i << " " << c;
    }
  }
  // Nothing visible: no light.
  const std::vector<float> none(wide.size(), 0.0f);
  EXPECT_EQ(lighting.shade(0.3, 1.0, none.data(), kTransferOrder), glm::vec3(0.0f));
}

TEST(Chebyshev, CoefficientAndStorageAccounting) {
  auto local =
      createLighting("cheb-local", ParamSet::parse("order=3,samples=8,rows=17,cols=32", "t"));
  auto face =
      createLighting("cheb-face", ParamSet::parse("order=3,samples=8,rows=17,cols=32", "t"));
  auto latlong =
      createLighting("cheb-latlong", ParamSet::parse("order=2,samples=16,rows=17,cols=32", "t"));
  const Environment env = Environment::constant(glm::vec3(1.0f), 64);
  local->project(env);
  face->project(env);
  latlong->project(env);
  EXPECT_EQ(local->coefficientsPerChannel(), 9);
  EXPECT_EQ(face->coefficientsPerChannel(), 54);
  EXPECT_EQ(latlong->coefficientsPerChannel(), 4);
  // Tables on 17 x 32 normals plus the per-environment moments.
  EXPECT_EQ(local->floatsStored(), size_t(17 * 32 * 27 + 9));
  EXPECT_EQ(face->floatsStored(), size_t(17 * 32 * 54 + 6 * 27));
  EXPECT_EQ(latlong->floatsStored(), size_t(17 * 32 * 4 + 12));
}

TEST(Chebyshev, ParametersAreValidated) {
  COMPOSE_EXPECT_ERROR(createLighting("cheb-local", ParamSet::parse("order=9,samples=8", "t")),
                       "cheb-local: order k must be in 1..min(samples, 32)");
  COMPOSE_EXPECT_ERROR(createLighting("cheb-latlong", ParamSet::parse("samples=0", "t")),
                       "cheb-latlong: samples (grid size s) must be in 1..1024");
  COMPOSE_EXPECT_ERROR(createLighting("cheb-face", ParamSet::parse("rows=2", "t")),
                       "rows must be in 3..1025");
  COMPOSE_EXPECT_ERROR(createLighting("cheb-local", ParamSet::parse("ordre=2", "t")),
                       "does not take parameter(s): ordre");
}

TEST(NormalGrid, InterpolatesNodesExactlyAndWrapsInLongitude) {
  const NormalGrid grid(9, 16);
  for (size_t node = 0; node < grid.size(); ++node) {
    size_t nodes[4];
    float w[4];
    const glm::vec3 n = grid.normal(node);
    grid.interpolation(n, nodes, w);
    float total = 0.0f, onNode = 0.0f;
    for (int q = 0; q < 4; ++q) {
      total += w[q];
      if (glm::length(grid.normal(nodes[q]) - n) < 1e-5f) onNode += w[q];
    }
    EXPECT_NEAR(total, 1.0f, 1e-6f);
    EXPECT_NEAR(onNode, 1.0f, 1e-4f) << "node " << node;
  }
}

TEST(MonteCarlo, ConvergesOnTheChebyshevTestMap) {
  // MC sits on the same interface: at 16384 samples it should agree with exact to ~40 dB.
  const Environment env = sunAndSky(256, 500.0f);
  ExactLighting exact;
  exact.project(env);
  MonteCarloLighting mc(16384, 7);
  mc.project(env);
  EXPECT_GT(snrDb(mc, exact, randomNormals(40, 5)), 35.0);  // measured ~40 dB; 5 dB for noise
}

}  // namespace
}  // namespace compose::lighting

namespace compose::lighting {
namespace {

TEST(LightingCache, StoresAndRestoresAProjection) {
  compose::testing::TempDir dir;
  const Environment env = sunAndSky(128, 300.0f);
  const LightingCache cache(dir.path());
  auto first = createLighting("cheb-local", ParamSet::parse("rows=9,cols=16", "t"));
  const std::string key = LightingCache::key(env, *first);
  EXPECT_FALSE(cache.load(key, *first)) << "empty cache";
  first->project(env);
  ASSERT_TRUE(cache.store(key, *first));
  auto second = createLighting("cheb-local", ParamSet::parse("rows=9,cols=16", "t"));
  ASSERT_TRUE(cache.load(key, *second));
  for (const auto& n : randomNormals(50, 9)) EXPECT_EQ(first->irradiance(n), second->irradiance(n));
  // Other parameters or other pixels give another key.
  auto other = createLighting("cheb-local", ParamSet::parse("rows=9,cols=32", "t"));
  EXPECT_NE(LightingCache::key(env, *other), key);
  EXPECT_NE(LightingCache::key(sunAndSky(128, 301.0f), *first), key);
  // A damaged entry is a miss, not a crash or a wrong answer.
  std::filesystem::resize_file(cache.pathFor(key), 100);
  auto third = createLighting("cheb-local", ParamSet::parse("rows=9,cols=16", "t"));
  EXPECT_FALSE(cache.load(key, *third));
  // SH keeps its state (lighting files hold it): stored and read back exactly. A basis that
  // reads the environment while shading keeps none: not cached.
  ShLighting sh(2);
  sh.project(env);
  ASSERT_TRUE(cache.store(LightingCache::key(env, sh), sh));
  ShLighting back(2);
  ASSERT_TRUE(cache.load(LightingCache::key(env, sh), back));
  for (const auto& n : randomNormals(20, 4)) EXPECT_EQ(back.irradiance(n), sh.irradiance(n));
  auto exact = createLighting("exact");
  exact->project(env);
  EXPECT_FALSE(cache.store(LightingCache::key(env, *exact), *exact));
}

}  // namespace
}  // namespace compose::lighting

#include "lighting/order_selector.h"

namespace compose::lighting {
namespace {

// SH: the tail-energy estimate is Parseval over uniformly distributed normals, so it predicts the
// SNR against band 8 measured on uniform random normals; against the exact reference it holds
// while the tail beyond band 8 is small (low orders).
TEST(OrderSelector, ShEstimateMatchesMeasuredSnr) {
  const Environment env = sunAndSky(256, 50.0f);
  const auto estimates = estimateOrders("sh", env, {});
  ASSERT_EQ(estimates.size(), 9u);
  ShLighting full(8);
  full.project(env);
  ExactLighting exact;
  exact.project(env);
  const auto normals = randomNormals(3000, 11);
  for (int order : {0, 1, 2, 4}) {
    ShLighting sh(order);
    sh.project(env);
    // 3000 random normals estimate a sphere integral to ~2% in energy: 0.5 dB.
    EXPECT_NEAR(estimates[size_t(order)].estimatedSnrDb, snrDb(sh, full, normals), 0.5)
        << "order " << order;
    EXPECT_NEAR(estimates[size_t(order)].estimatedSnrDb, snrDb(sh, exact, normals), 1.5)
        << "order " << order;
  }
  for (size_t i = 1; i < estimates.size(); ++i)
    EXPECT_GE(estimates[i].estimatedSnrDb, estimates[i - 1].estimatedSnrDb);
  // Band 3 adds nothing (A_3 = 0), so asking for band 3's accuracy selects band 2.
  EXPECT_EQ(selectOrder(estimates, estimates[3].estimatedSnrDb).order, 2);
  EXPECT_EQ(selectOrder(estimates, estimates[4].estimatedSnrDb).order, 4);
  EXPECT_EQ(selectOrder(estimates, 1e9).order, 8);
}

// Chebyshev: the estimate at the grid nodes predicts the truncated basis against the full-order
// one at arbitrary normals; cheb-local (Lambertian) needs no more than k = 1.
TEST(OrderSelector, ChebyshevEstimateMatchesTruncation) {
  const Environment env = sunAndSky(256, 50.0f);
  const ParamSet params = ParamSet::parse("samples=8,rows=17,cols=32", "t");
  const auto estimates = estimateOrders("cheb-latlong", env, params);
  ASSERT_EQ(estimates.size(), 8u);
  auto full =
      createLighting("cheb-latlong", ParamSet::parse("order=8,samples=8,rows=17,cols=32", "t"));
  full->project(env);
  const auto normals = randomNormals(2000, 12);
  for (int k : {1, 2, 3, 5}) {
    auto truncated = createLighting(
        "cheb-latlong",
        ParamSet::parse("order=" + std::to_string(k) + ",samples=8,rows=17,cols=32", "t"));
    truncated->project(env);
    // Nodes versus random normals: 1 dB.
    EXPECT_NEAR(estimates[size_t(k - 1)].estimatedSnrDb, snrDb(*truncated, *full, normals), 1.0)
        << "k " << k;
  }
  const auto local = estimateOrders("cheb-local", env, ParamSet::parse("rows=9,cols=16", "t"));
  EXPECT_GT(local.front().estimatedSnrDb, 100.0) << "Lambertian: only T_00 matters";
  EXPECT_EQ(selectOrder(local, 60.0).order, 1);
  COMPOSE_EXPECT_ERROR(estimateOrders("mc", env, {}), "no order selection for basis 'mc'");
}

}  // namespace
}  // namespace compose::lighting

namespace compose::lighting {
namespace {

// Oren–Nayar through the local basis against brute force over every texel (the BRDF evaluated
// per texel, in the same local frame). The BRDF varies across the hemisphere, so here — unlike
// Lambertian — higher orders carry weight: the full 2D product at work.
struct OrenNayarCase {
  glm::vec3 n, view;
};

TEST(OrenNayar, ZeroRoughnessIsLambertian) {
  const Environment env = sunAndSky(128, 100.0f);
  auto lambert =
      createLighting("cheb-local", ParamSet::parse("order=4,samples=8,rows=9,cols=16", "t"));
  auto smooth = createLighting(
      "cheb-local",
      ParamSet::parse("order=4,samples=8,rows=9,cols=16,brdf=oren-nayar,sigma=0", "t"));
  lambert->project(env);
  smooth->project(env);
  for (const auto& n : randomNormals(20, 21)) {
    const glm::vec3 view = glm::normalize(n + glm::vec3(0.2f, 0.3f, 0.1f));
    const glm::vec3 a = lambert->irradiance(n), b = smooth->irradiance(n, view);
    EXPECT_NEAR(b.x, a.x, 1e-4f * a.x);
  }
}

TEST(OrenNayar, FullProductConvergesToTheReference) {
  const Environment env = sunAndSky(256, 100.0f);
  constexpr double kSigma = 0.5;
  std::vector<OrenNayarCase> cases;
  for (const auto& n : randomNormals(24, 22)) {
    for (const glm::vec3 tilt :
         {glm::vec3(0.0f), glm::vec3(0.6f, 0.2f, -0.3f), glm::vec3(-0.5f, 0.7f, 0.4f)}) {
      glm::vec3 v = glm::normalize(n + tilt);
      if (glm::dot(v, n) < 0.05f) v = n;
      cases.push_back({n, v});
    }
  }
  std::vector<glm::vec3> reference;
  for (const auto& c : cases)
    reference.push_back(glm::vec3(orenNayarReference(env, kSigma, c.n, c.view)));
  auto snr = [&](const std::string& params) {
    auto basis =
        createLighting("cheb-local", ParamSet::parse(params + ",brdf=oren-nayar,sigma=0.5", "t"));
    basis->project(env);
    double signal = 0, noise = 0;
    for (size_t i = 0; i < cases.size(); ++i) {
      const glm::dvec3 r(reference[i]), g(basis->irradiance(cases[i].n, cases[i].view));
      signal += glm::dot(r, r);
      noise += glm::dot(r - g, r - g);
    }
    return 10.0 * std::log10(signal / noise);
  };
  const double k1 = snr("order=1,samples=8"), k4 = snr("order=4,samples=8"),
               k8 = snr("order=8,samples=8");
  const double k16 = snr("order=16,samples=16");
  std::printf(
      "Oren-Nayar sigma=0.5: k=1 %.1f dB, k=4 %.1f dB, k=8 (s=8) %.1f dB, k=16 (s=16) %.1f dB\n",
      k1, k4, k8, k16);
  RecordProperty("k1_db", std::to_string(k1));
  RecordProperty("k8_db", std::to_string(k8));
  // Measured: k=1 39.4 dB, k=4 46.4 dB, k=8 47.7 dB, k=16 at s=16 50.4 dB.
  EXPECT_GT(k4, k1 + 5.0) << "the view-dependent BRDF needs more than T_00";
  EXPECT_GE(k8, k4 - 0.5);
  EXPECT_GT(k16, 45.0);
}

}  // namespace
}  // namespace compose::lighting

namespace compose::lighting {
namespace {

// A grid finer than the map: cells holding no texel centre take the radiance in their direction,
// so no light is lost (white furnace on a 16x8 map with s = 32).
TEST(Chebyshev, LatLongGridFinerThanTheMapKeepsAllLight) {
  const Environment env = Environment::constant(glm::vec3(1.0f), 16);
  auto basis =
      createLighting("cheb-latlong", ParamSet::parse("order=4,samples=32,rows=9,cols=16", "t"));
  basis->project(env);
  for (const auto& n : randomNormals(20, 31)) EXPECT_NEAR(basis->irradiance(n).x, kPi, 1e-5 * kPi);
}

TEST(OrderSelector, RefusesViewDependentBrdf) {
  COMPOSE_EXPECT_ERROR(estimateOrders("cheb-local", Environment::constant(glm::vec3(1.0f), 32),
                                      ParamSet::parse("brdf=oren-nayar", "t")),
                       "order=auto estimates Lambertian truncation only");
}

// A cache entry whose stored count does not match its size is a miss, without a huge allocation.
TEST(LightingCache, LyingCountIsAMiss) {
  compose::testing::TempDir dir;
  const Environment env = Environment::constant(glm::vec3(1.0f), 32);
  const LightingCache cache(dir.path());
  auto basis = createLighting("cheb-local", ParamSet::parse("rows=5,cols=8", "t"));
  basis->project(env);
  const std::string key = LightingCache::key(env, *basis);
  ASSERT_TRUE(cache.store(key, *basis));
  {
    std::fstream f(cache.pathFor(key), std::ios::in | std::ios::out | std::ios::binary);
    uint64_t keyLength = 0;
    f.seekg(8);
    f.read(reinterpret_cast<char*>(&keyLength), sizeof keyLength);
    const uint64_t lie = 0xFFFFFFFFull;
    f.seekp(std::streamoff(16 + keyLength));
    f.write(reinterpret_cast<const char*>(&lie), sizeof lie);
  }
  auto again = createLighting("cheb-local", ParamSet::parse("rows=5,cols=8", "t"));
  EXPECT_FALSE(cache.load(key, *again));
}

}  // namespace
}  // namespace compose::lighting
