// The default lighting on the real sample HDRIs: against an independent brute-force quadrature
// written here (sharing no code with the library's integrators), and on the same maps reduced to
// 64 and 128 texels wide, each against its own exact reference.
#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "ingest/image_io.h"
#include "lighting/exact.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

const char* const kMaps[] = {"courtyard", "forest", "interior", "sunset"};

Image loadSample(const std::string& name) {
  const auto file = pipeline::samplesDirectory() / (name + ".exr");
  if (!std::filesystem::exists(file)) {
    ADD_FAILURE() << "sample data missing: " << file << " (run samples/fetch.sh)";
    return {};
  }
  Image img = ingest::readImage(file).image;
  for (float& v : img.pixels) v = std::max(v, 0.0f);  // as Environment::fromLatLong clamps
  return img;
}

// Box reduction of a lat-long map by `factor`, each new texel the solid-angle-weighted mean of
// the texels it covers (so that the map's total power is kept), written out independently.
Image reduce(const Image& in, int factor) {
  Image out(in.width / factor, in.height / factor, 3);
  for (int y = 0; y < out.height; ++y) {
    for (int x = 0; x < out.width; ++x) {
      double sum[3] = {0, 0, 0}, weight = 0;
      for (int j = 0; j < factor; ++j) {
        const int sy = y * factor + j;
        const double top = kPi * (0.5 - double(sy) / in.height);
        const double bottom = kPi * (0.5 - double(sy + 1) / in.height);
        const double w = std::sin(top) - std::sin(bottom);
        for (int i = 0; i < factor; ++i) {
          const float* p = in.at(x * factor + i, sy);
          for (int c = 0; c < 3; ++c) sum[c] += w * p[c];
          weight += w;
        }
      }
      for (int c = 0; c < 3; ++c) out.at(x, y)[c] = float(sum[c] / weight);
    }
  }
  return out;
}

// Brute force: Σ_texels L_t max(0, n·ω_t) Ω_t with ω_t the texel centre, in double.
glm::dvec3 bruteForce(const Image& map, const glm::dvec3& n) {
  glm::dvec3 e(0.0);
  for (int y = 0; y < map.height; ++y) {
    const double top = kPi * (0.5 - double(y) / map.height);
    const double bottom = kPi * (0.5 - double(y + 1) / map.height);
    const double lat = 0.5 * (top + bottom);
    const double omega = 2.0 * kPi / map.width * (std::sin(top) - std::sin(bottom));
    for (int x = 0; x < map.width; ++x) {
      const double lon = kPi * (1.0 - 2.0 * (x + 0.5) / map.width);
      const glm::dvec3 w(std::sin(lon) * std::cos(lat), std::sin(lat),
                         std::cos(lon) * std::cos(lat));
      const double c = glm::dot(n, w);
      if (c <= 0.0) continue;
      const float* p = map.at(x, y);
      e += glm::dvec3(p[0], p[1], p[2]) * (c * omega);
    }
  }
  return e;
}

double snrDb(const DiffuseLighting& basis, const std::vector<glm::dvec3>& reference,
             const std::vector<glm::vec3>& normals) {
  double signal = 0.0, noise = 0.0;
  for (size_t i = 0; i < normals.size(); ++i) {
    const glm::dvec3 got(basis.irradiance(normals[i]));
    signal += glm::dot(reference[i], reference[i]);
    noise += glm::dot(reference[i] - got, reference[i] - got);
  }
  return 10.0 * std::log10(signal / noise);
}

// The sample maps, the right way up, are darker below the horizon than above; upside down, more
// than the 1.5 times at which compose warns (precompute stage).
TEST(SampleMaps, AreDarkerBelowTheHorizonUnlessUpsideDown) {
  for (const char* name : kMaps) {
    Image map = loadSample(name);
    if (map.empty()) return;
    const double ratio = Environment::fromLatLong(map).belowOverAbove();
    Image flipped = map;
    for (int y = 0; y < map.height; ++y)
      for (int x = 0; x < map.width; ++x)
        for (int c = 0; c < 3; ++c) flipped.at(x, map.height - 1 - y)[c] = map.at(x, y)[c];
    const double upsideDown = Environment::fromLatLong(flipped).belowOverAbove();
    std::printf("%s: below / above the horizon %.3f, upside down %.2f\n", name, ratio, upsideDown);
    EXPECT_LT(ratio, 0.5) << name;
    EXPECT_GT(upsideDown, 2.0) << name;
  }
}

TEST(DefaultLightingOnSampleMaps, AgreesWithAnIndependentBruteForceQuadrature) {
  const auto normals = compose::testing::randomNormals(150, 11);
  for (const char* name : kMaps) {
    const Image map = loadSample(name);
    if (map.empty()) return;
    auto basis = createLighting("cheb-local");
    basis->project(Environment::fromLatLong(map));
    std::vector<glm::dvec3> reference;
    for (const glm::vec3& n : normals) reference.push_back(bruteForce(map, glm::dvec3(n)));
    const double db = snrDb(*basis, reference, normals);
    // The benchmark measures 53-61 dB against the library's own exact reference; the
    // brute force differs from it only on horizon texels (centre sampling, ~70 dB here).
    constexpr double kFloorDb = 50.0;
    EXPECT_GT(db, kFloorDb) << name;
    std::printf("%s: cheb-local vs independent brute force %.1f dB\n", name, db);
  }
}

TEST(DefaultLightingOnSampleMaps, SmallMapsAreAsAccurateAsTheFullSize) {
  const auto normals = compose::testing::randomNormals(400, 12);
  for (const char* name : kMaps) {
    const Image full = loadSample(name);
    if (full.empty()) return;
    double fullDb = 0.0;
    for (int width : {1024, 128, 64}) {
      const Image map = width == full.width ? full : reduce(full, full.width / width);
      const Environment env = Environment::fromLatLong(map);
      ExactLighting exact;
      exact.project(env);
      std::vector<glm::dvec3> reference;
      for (const glm::vec3& n : normals) reference.push_back(glm::dvec3(exact.irradiance(n)));
      auto basis = createLighting("cheb-local");
      basis->project(env);
      const double db = snrDb(*basis, reference, normals);
      if (width == full.width) {
        fullDb = db;
      } else {
        // The bound: within 1 dB of the full-size figure (or better).
        constexpr double kAllowedLossDb = 1.0;
        EXPECT_GT(db, fullDb - kAllowedLossDb) << name << " at width " << width;
      }
      std::printf("%s at %d wide: cheb-local vs its own exact reference %.1f dB\n", name, width,
                  db);
    }
  }
}

}  // namespace
}  // namespace compose::lighting
