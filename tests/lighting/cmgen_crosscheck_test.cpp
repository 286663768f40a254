// Cross-check of the SH irradiance (lighting/sh.h) against Filament's `cmgen` (Debian package
// libfilament-tools, 1.9.25+dfsg2 in bookworm) on the four sample HDRIs, as docs/design.md §7 asks:
// `cmgen --sh=3 --sh-window=no -i` must agree with ShLighting(2) within 1e-3 relative.
//
// cmgen's conventions, found by experiment (cones of radiance in known directions, an index map
// read back with --extract) and confirmed in Filament's libs/ibl/src/CubemapSH.cpp:
//  * `--sh=3` means 3 bands (9 coefficients). `--sh-output=f.txt` writes lines
//    "( r, g, b); // L1-1, irradiance", in the order l = 0..2, m = -l..l (index l(l+1)+m).
//  * Basis: real SH, orthonormal, pole on +Z, WITH the Condon-Shortley phase:
//    Y1-1 = -k1 y, Y10 = k1 z, Y11 = -k1 x, Y2-2 = k2 xy, Y2-1 = -k2 yz, Y20 = k20 (3z²-1),
//    Y21 = -k2 xz, Y22 = k22 (x²-y²)  (k1 = √3/(2√π), k2 = √15/(2√π), k20 = √5/(4√π),
//    k22 = √15/(4√π)). Ours has its pole on +Y and no Condon-Shortley phase (sh.h), so the two
//    coefficient vectors differ by a rotation/sign pattern; E(n) does not depend on it.
//  * `-i` prints A_l·L_lm with A = (π, 2π/3, π/4): irradiance, no 1/π (a constant map of radiance 1
//    gives L00 = π·√(4π)). Newer Filament (not in Debian) multiplies by 1/π: a π-sized failure
//    here after a cmgen upgrade means that.
//  * Axes: cmgen's (x, y, z) are our world axes (+Y up). Its equirect reader maps longitude
//    atan2(x, z) increasing left to right and then mirrors the cube in x (the "Mirroring..." step,
//    off with --no-mirror), which together give OpenEXR's lat-long orientation (+Z at the centre
//    column, +X a quarter in from the left, top row +Y). Cube faces are OpenGL's
//    (Filament Cubemap::getAddressFor); a horizontal cross is laid out -X +Z +X -Z / +Y above +Z /
//    -Y below +Z.
//  * cmgen reads EXR through tinyexr, which cannot decode the samples' DWAB compression ("Unknown
//    compression type"), so the test hands it a lossless float/ZIP copy.
//
// Why the strict check goes through a cube cross. cmgen turns an equirect into a cube (--size,
// 256 by default) by point sampling: each cube texel takes max(1, ⌊footprint in source pixels⌋)
// Hammersley samples (the first at the texel corner) and reads the nearest source pixel
// ⌊u·(W-1)⌋, ⌊v·(H-1)⌋ — a stretch of up to one texel across the map. Its SH step is then exact to
// ~5e-5, but the resampling alone moves E(n) by 0.9-8 % on these maps (interior: 7 lamp texels
// carry 30 % of the power and one sample more or less per texel matters). Measured with the
// issue's command line (default --size=256), max over channels of max|ΔE|/max|E|:
//     courtyard 8.6e-3, forest 1.16e-2, interior 8.2e-2, sunset 1.6e-2
// and --size does not fix it (sunset / courtyard: 64 → 4.5e-3 / 6.6e-3, 1024 → 5.6e-3 / 5.3e-3,
// 2048 → 1.15e-2 / 1.08e-2 and 14-18 s; cmgen's float solid angles degrade large cubes). Even
// resampling the map onto cmgen's pixel grid at 4x first (and --size=64) leaves 2.8e-3 on interior.
// So the 1e-3 check (CubeCross) gives cmgen a cube cross built here by splatting every lat-long
// texel's power into the cube texels (power-conserving; misplacement below 1/4 texel), read by
// cmgen without resampling (face size = --size, --no-mirror). Measured: max relative E error
// courtyard 2.0e-5, forest 2.0e-5, interior 1.9e-4, sunset 1.5e-5 (interior's residual is
// cmgen's midpoint rule over 256² faces with a lamp inside a texel). The equirect path is
// still checked (Equirect), at the measured resampling limit, to pin cmgen's own lat-long axes;
// a mirrored or rotated axis gives errors of 0.3-0.7 there.
//
// Error measure: per channel, max over 100 Fibonacci-sphere normals of |E_cmgen − E_ours| divided
// by max over the normals of |E_ours|. Per-normal relative error is ill-defined: for sun-lit maps
// SH9 irradiance comes near zero (or rings below it) on the far side.
#include <sys/wait.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"
#include "lighting/sh.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;

constexpr int kCoefficients = 9;
using Coefficients = std::array<glm::dvec3, kCoefficients>;

// ---------------------------------------------------------------------------------------------
// Running cmgen.

constexpr const char* kInstallCmgen =
    "cmgen not found on PATH: install the Debian package libfilament-tools "
    "(apt-get install libfilament-tools), which the project's setup installs";

fs::path findCmgen() {
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    if (dir.empty()) continue;
    const fs::path candidate = fs::path(dir) / "cmgen";
    std::error_code ec;
    if (fs::is_regular_file(candidate, ec) &&
        (fs::status(candidate, ec).permissions() & fs::perms::others_exec) != fs::perms::none) {
      return candidate;
    }
  }
  return {};
}

std::string quote(const fs::path& p) {
  std::string q(1, '\'');  // built up by appending: GCC 12 warns falsely (-Wrestrict) on "'" + s
  q.append(p.string()).push_back('\'');
  return q;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

struct CmgenRun {
  Coefficients irradiance{};  // A_l L_lm per channel, in cmgen's basis
  double seconds = 0.0;
};

// Runs `cmgen --sh=3 --sh-window=no -i <extra> --sh-output=... input` and parses its output.
// Adds a failure (with cmgen's console output) and returns nothing if anything is off.
std::optional<CmgenRun> runCmgen(const fs::path& cmgen, const fs::path& input,
                                 const std::string& extra, const fs::path& scratch) {
  const fs::path out = scratch / (input.stem().string() + "_sh.txt");
  const fs::path log = scratch / (input.stem().string() + "_cmgen.log");
  fs::remove(out);
  const std::string cmd = quote(cmgen) + " --sh=3 --sh-window=no -i " + extra +
                          " --sh-output=" + quote(out) + " " + quote(input) + " >" + quote(log) +
                          " 2>&1 </dev/null";
  const auto start = std::chrono::steady_clock::now();
  const int raw = std::system(cmd.c_str());
  CmgenRun run;
  run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const int status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  // cmgen exits 0 on some input errors, so the output file is what counts.
  if (status != 0 || !fs::exists(out)) {
    ADD_FAILURE() << "cmgen failed (status " << status << "): " << cmd << "\n" << slurp(log);
    return std::nullopt;
  }
  static const char* const kLabels[kCoefficients] = {"L00",  "L1-1", "L10", "L11", "L2-2",
                                                     "L2-1", "L20",  "L21", "L22"};
  std::ifstream in(out);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    if (line.find('(') == std::string::npos) continue;
    if (n == kCoefficients) {
      ADD_FAILURE() << "cmgen printed more than 9 coefficients:\n" << slurp(out);
      return std::nullopt;
    }
    const size_t open = line.find('('), close = line.find(')');
    const size_t label = line.find("//");
    std::string values =
        line.substr(open + 1, close == std::string::npos ? std::string::npos : close - open - 1);
    std::replace(values.begin(), values.end(), ',', ' ');
    std::istringstream vs(values);
    glm::dvec3 c;
    // The label says which coefficient this is and that -i made it irradiance.
    const std::string expected = std::string(kLabels[n]) + ", irradiance";
    if (!(vs >> c.x >> c.y >> c.z) || close == std::string::npos || label == std::string::npos ||
        line.find(expected, label) == std::string::npos) {
      ADD_FAILURE() << "unexpected cmgen output line " << n << " (wanted \"" << expected
                    << "\"): " << line;
      return std::nullopt;
    }
    run.irradiance[size_t(n++)] = c;
  }
  if (n != kCoefficients) {
    ADD_FAILURE() << "cmgen printed " << n << " coefficients, expected 9:\n" << slurp(out);
    return std::nullopt;
  }
  return run;
}

// ---------------------------------------------------------------------------------------------
// cmgen's basis, written out from its conventions (see the top of the file).

std::array<double, kCoefficients> cmgenBasis(const glm::dvec3& d) {
  const double k0 = 0.5 / std::sqrt(kPi);
  const double k1 = std::sqrt(3.0) * k0, k2 = std::sqrt(15.0) * k0;
  const double x = d.x, y = d.y, z = d.z;
  return {k0,
          -k1 * y,
          k1 * z,
          -k1 * x,
          k2 * x * y,
          -k2 * y * z,
          0.5 * std::sqrt(5.0) * k0 * (3.0 * z * z - 1.0),
          -k2 * x * z,
          0.5 * k2 * (x * x - y * y)};
}

glm::dvec3 cmgenIrradiance(const Coefficients& c, const glm::dvec3& n) {
  const auto b = cmgenBasis(n);
  glm::dvec3 e(0.0);
  for (size_t i = 0; i < size_t(kCoefficients); ++i) e += c[i] * b[i];
  return e;
}

// ---------------------------------------------------------------------------------------------
// Geometry, written here from the documented conventions rather than taken from src/lighting.

// Lat-long texel (x, y) of a W x H map (environment.h): φ ∈ π(1 - 2[x, x+1]/W) with
// φ = atan2(x_w, z_w), z_w = sin(latitude) ∈ [zBottom(y), zTop(y)].
double zTop(int y, int h) {
  return std::sin(kPi * (0.5 - double(y) / h));
}
double zBottom(int y, int h) {
  return std::sin(kPi * (0.5 - double(y + 1) / h));
}
glm::dvec3 latLongDirection(double phi, double z) {
  const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
  return {r * std::sin(phi), z, r * std::cos(phi)};
}

// Filament's cube faces (OpenGL orientation) and where they go in a horizontal cross.
enum Face { kPX, kNX, kPY, kNY, kPZ, kNZ };
struct CubeTexel {
  int face, x, y;
};
CubeTexel cubeAddress(const glm::dvec3& d, int size) {
  const double ax = std::abs(d.x), ay = std::abs(d.y), az = std::abs(d.z);
  int face;
  double sc, tc, ma;
  if (ax >= ay && ax >= az) {
    ma = ax;
    face = d.x >= 0 ? kPX : kNX;
    sc = d.x >= 0 ? -d.z : d.z;
    tc = -d.y;
  } else if (ay >= az) {
    ma = ay;
    face = d.y >= 0 ? kPY : kNY;
    sc = d.x;
    tc = d.y >= 0 ? d.z : -d.z;
  } else {
    ma = az;
    face = d.z >= 0 ? kPZ : kNZ;
    sc = d.z >= 0 ? d.x : -d.x;
    tc = -d.y;
  }
  const auto texel = [&](double s) {
    return std::clamp(int((s / ma + 1.0) * 0.5 * size), 0, size - 1);
  };
  return {face, texel(sc), texel(tc)};
}
constexpr int kCrossX[6] = {2, 0, 1, 1, 1, 3};  // in face sizes, indexed by Face
constexpr int kCrossY[6] = {1, 1, 0, 2, 1, 1};

// Exact solid angle of cube texel (x, y) of a size x size face.
double cubeTexelSolidAngle(int x, int y, int size) {
  const auto corner = [](double a, double b) {
    return std::atan2(a * b, std::sqrt(a * a + b * b + 1.0));
  };
  const double s0 = 2.0 * x / size - 1.0, s1 = 2.0 * (x + 1) / size - 1.0;
  const double t0 = 2.0 * y / size - 1.0, t1 = 2.0 * (y + 1) / size - 1.0;
  return corner(s0, t0) - corner(s0, t1) - corner(s1, t0) + corner(s1, t1);
}

// The environment as a cube cross whose texels hold the mean radiance over their solid angle. Each
// lat-long texel is split into k x k cells of equal solid angle (uniform in φ and z) whose power
// goes to the cube texel containing the cell centre, so power is conserved exactly and only moves
// by less than a cell; the brightest texels get finer cells.
Image cubeCross(const Environment& env, int size) {
  const int w = env.width(), h = env.height();
  std::vector<glm::dvec3> power(size_t(6) * size_t(size) * size_t(size), glm::dvec3(0.0));
  double total = 0.0;
  for (int y = 0; y < h; ++y) {
    const double texelSolidAngle = 2.0 * kPi / w * (zTop(y, h) - zBottom(y, h));
    for (int x = 0; x < w; ++x) {
      const glm::dvec3 L(env.radiance(x, y));
      total += (L.x + L.y + L.z) * texelSolidAngle;
    }
  }
  for (int y = 0; y < h; ++y) {
    const double z0 = zBottom(y, h), z1 = zTop(y, h);
    const double texelSolidAngle = 2.0 * kPi / w * (z1 - z0);
    for (int x = 0; x < w; ++x) {
      const glm::dvec3 L(env.radiance(x, y));
      const double p = (L.x + L.y + L.z) * texelSolidAngle;
      if (p <= 0.0) continue;
      const int k = p > 1e-5 * total ? 32 : 4;
      const glm::dvec3 cellPower = L * (texelSolidAngle / (k * k));
      for (int j = 0; j < k; ++j) {
        const double z = z0 + (z1 - z0) * (j + 0.5) / k;
        for (int i = 0; i < k; ++i) {
          const double phi = kPi * (1.0 - 2.0 * (x + (i + 0.5) / k) / w);
          const CubeTexel t = cubeAddress(latLongDirection(phi, z), size);
          power[(size_t(t.face) * size_t(size) + size_t(t.y)) * size_t(size) + size_t(t.x)] +=
              cellPower;
        }
      }
    }
  }
  Image cross(4 * size, 3 * size, 3, {"R", "G", "B"});
  for (int face = 0; face < 6; ++face) {
    for (int y = 0; y < size; ++y) {
      for (int x = 0; x < size; ++x) {
        const glm::dvec3 L =
            power[(size_t(face) * size_t(size) + size_t(y)) * size_t(size) + size_t(x)] /
            cubeTexelSolidAngle(x, y, size);
        float* px = cross.at(kCrossX[face] * size + x, kCrossY[face] * size + y);
        px[0] = float(L.x);
        px[1] = float(L.y);
        px[2] = float(L.z);
      }
    }
  }
  return cross;
}

void writeFloatExr(const fs::path& path, const Image& image) {
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;  // ZIP compressed: tinyexr reads it
  ingest::writeImage(path, image, options);
}

// ---------------------------------------------------------------------------------------------
// Comparison.

std::vector<glm::dvec3> fibonacciNormals(int count) {
  std::vector<glm::dvec3> out;
  const double golden = kPi * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < count; ++i) {
    const double z = 1.0 - (2.0 * i + 1.0) / count;
    const double r = std::sqrt(1.0 - z * z);
    out.emplace_back(r * std::cos(golden * i), z, r * std::sin(golden * i));
  }
  return out;
}

struct Agreement {
  glm::dvec3 maxRel{0.0}, rmsRel{0.0};  // per channel, relative to max |E_ours| over the normals
  double worst() const { return std::max({maxRel.x, maxRel.y, maxRel.z}); }
};

Agreement compareIrradiance(const ShLighting& ours, const Coefficients& cmgen) {
  const auto normals = fibonacciNormals(100);
  std::vector<glm::dvec3> diff;
  glm::dvec3 scale(0.0);
  for (const auto& n : normals) {
    const glm::dvec3 e(ours.irradiance(glm::vec3(n)));
    scale = glm::max(scale, glm::abs(e));
    diff.push_back(glm::abs(cmgenIrradiance(cmgen, n) - e));
  }
  Agreement a;
  for (const auto& d : diff) {
    a.maxRel = glm::max(a.maxRel, d / scale);
    a.rmsRel += (d / scale) * (d / scale);
  }
  a.rmsRel = glm::sqrt(a.rmsRel / double(diff.size()));
  return a;
}

// cmgen's coefficients in our basis: M_ij = ∫ Y_i(ours) Y_j(cmgen) dω, exact by Gauss-Legendre
// (4 nodes in z) x 8 azimuths, since the products are polynomials of degree ≤ 4. Both bases are
// orthonormal, so M must be orthogonal: that is checked too.
std::array<std::array<double, kCoefficients>, kCoefficients> basisChange() {
  static constexpr double kNodes[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563,
                                       0.8611363115940526};
  static constexpr double kWeights[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461,
                                         0.3478548451374538};
  std::array<std::array<double, kCoefficients>, kCoefficients> m{};
  for (int a = 0; a < 4; ++a) {
    for (int p = 0; p < 8; ++p) {
      const double z = kNodes[a], r = std::sqrt(1.0 - z * z), phi = 2.0 * kPi * p / 8.0;
      const glm::dvec3 d(r * std::cos(phi), r * std::sin(phi), z);
      const double weight = kWeights[a] * 2.0 * kPi / 8.0;
      std::array<double, kCoefficients> ours{};
      evalSh(2, d, ours.data());
      const auto theirs = cmgenBasis(d);
      for (size_t i = 0; i < size_t(kCoefficients); ++i)
        for (size_t j = 0; j < size_t(kCoefficients); ++j) m[i][j] += weight * ours[i] * theirs[j];
    }
  }
  return m;
}

// ---------------------------------------------------------------------------------------------

class CmgenCrosscheck : public ::testing::TestWithParam<const char*> {
 protected:
  void SetUp() override {
    cmgen_ = findCmgen();
    if (cmgen_.empty()) {
      GTEST_FAIL() << kInstallCmgen;
    }
    file_ = pipeline::samplesDirectory() / (std::string(GetParam()) + ".exr");
    if (!fs::exists(file_))
      GTEST_FAIL() << "sample HDRI missing: " << file_ << ": run samples/fetch.sh";
    loaded_ = ingest::readImage(file_).image;
    env_ = Environment::fromLatLong(loaded_, file_);
    sh_.project(env_);
  }

  void report(const char* path, const Agreement& a, double seconds) {
    std::printf(
        "[ cmgen    ] %-9s %-8s E max rel %.2e %.2e %.2e  rms %.2e %.2e %.2e  (cmgen %.2f s)\n",
        GetParam(), path, a.maxRel.x, a.maxRel.y, a.maxRel.z, a.rmsRel.x, a.rmsRel.y, a.rmsRel.z,
        seconds);
  }

  fs::path cmgen_, file_;
  Image loaded_;
  Environment env_;
  ShLighting sh_{2};
  TempDir scratch_;
};

// The 1e-3 check: cmgen reads a cube cross of this environment without resampling it.
TEST_P(CmgenCrosscheck, CubeCrossIrradianceWithin1e3) {
  constexpr int kSize = 256;  // larger cubes lose accuracy in cmgen's float solid angles
  const fs::path cross = scratch_ / (std::string(GetParam()) + "_cross.exr");
  writeFloatExr(cross, cubeCross(env_, kSize));
  const auto run = runCmgen(cmgen_, cross, "--no-mirror --size=" + std::to_string(kSize) + " -q",
                            scratch_.path());
  ASSERT_TRUE(run);

  const Agreement a = compareIrradiance(sh_, run->irradiance);
  report("cube", a, run->seconds);
  EXPECT_LT(a.worst(), 1e-3) << "E(n) from cmgen vs ShLighting(2), max relative error per channel: "
                             << a.maxRel.x << " " << a.maxRel.y << " " << a.maxRel.z;

  // The coefficient vectors, once cmgen's are expressed in our basis.
  const auto m = basisChange();
  for (size_t i = 0; i < size_t(kCoefficients); ++i) {
    for (size_t j = 0; j < size_t(kCoefficients); ++j) {
      double dot = 0.0;
      for (size_t k = 0; k < size_t(kCoefficients); ++k) dot += m[k][i] * m[k][j];
      ASSERT_NEAR(dot, i == j ? 1.0 : 0.0, 1e-9)
          << "basis change not orthogonal at " << i << "," << j;
    }
  }
  const auto& radiance = sh_.radianceCoefficients();
  std::array<glm::dvec3, kCoefficients> ours{}, mapped{};
  glm::dvec3 scale(0.0);
  for (size_t i = 0; i < size_t(kCoefficients); ++i) {
    const int l = i == 0 ? 0 : (i < 4 ? 1 : 2);
    ours[i] = radiance[i] * shCosineLobe(l);
    for (size_t j = 0; j < size_t(kCoefficients); ++j) mapped[i] += m[i][j] * run->irradiance[j];
    scale = glm::max(scale, glm::abs(ours[i]));
  }
  for (size_t i = 0; i < size_t(kCoefficients); ++i) {
    const glm::dvec3 rel = glm::abs(mapped[i] - ours[i]) / scale;
    EXPECT_LT(std::max({rel.x, rel.y, rel.z}), 1e-3)
        << "irradiance coefficient " << i << ": ours (" << ours[i].x << ", " << ours[i].y << ", "
        << ours[i].z << "), cmgen in our basis (" << mapped[i].x << ", " << mapped[i].y << ", "
        << mapped[i].z << ")";
  }
}

// The issue's command line on the HDRI itself (a lossless float/ZIP copy: cmgen cannot read
// DWAB). Agreement is limited by cmgen's equirect-to-cube point sampling (see the top of the file);
// the bounds are about 1.5x the values measured with cmgen 1.9.25 and catch any axis or sign
// mistake, which costs 0.3-0.7.
TEST_P(CmgenCrosscheck, EquirectIrradianceWithinResamplingLimit) {
  const std::string name = GetParam();
  const double bound = name == "courtyard"  ? 0.015
                       : name == "forest"   ? 0.02
                       : name == "interior" ? 0.12
                                            : 0.025;
  const fs::path copy = scratch_ / (name + "_float.exr");
  writeFloatExr(copy, loaded_);
  const auto run = runCmgen(cmgen_, copy, "-q", scratch_.path());
  ASSERT_TRUE(run);
  const Agreement a = compareIrradiance(sh_, run->irradiance);
  report("equirect", a, run->seconds);
  EXPECT_LT(a.worst(), bound)
      << "E(n) from cmgen's equirect path vs ShLighting(2), max relative error per channel: "
      << a.maxRel.x << " " << a.maxRel.y << " " << a.maxRel.z;
}

INSTANTIATE_TEST_SUITE_P(SampleHdris, CmgenCrosscheck,
                         ::testing::Values("courtyard", "forest", "interior", "sunset"),
                         [](const ::testing::TestParamInfo<const char*>& p) {
                           return std::string(p.param);
                         });

// cmgen's own lat-long reader puts a bright cap where our convention says it is: the band-1
// coefficients (-L11, -L1-1, L10), Condon-Shortley signs included, point at the cap.
TEST(CmgenConventions, EquirectAxesMatchOpenExrLatLong) {
  const fs::path cmgen = findCmgen();
  ASSERT_FALSE(cmgen.empty()) << kInstallCmgen;
  TempDir scratch;
  const int w = 256, h = 128;
  for (const glm::dvec3 target : {glm::dvec3(1, 0, 0), glm::dvec3(0, 1, 0), glm::dvec3(0, 0, 1),
                                  glm::normalize(glm::dvec3(1, -2, 3))}) {
    Image img(w, h, 3, {"R", "G", "B"});
    for (int y = 0; y < h; ++y) {
      const double z = 0.5 * (zTop(y, h) + zBottom(y, h));
      for (int x = 0; x < w; ++x) {
        const double phi = kPi * (1.0 - 2.0 * (x + 0.5) / w);
        const float v = glm::dot(latLongDirection(phi, z), target) > std::cos(0.25) ? 1.0f : 0.0f;
        std::fill_n(img.at(x, y), 3, v);
      }
    }
    const fs::path file = scratch / "cap.exr";
    writeFloatExr(file, img);
    const auto run = runCmgen(cmgen, file, "-q", scratch.path());
    ASSERT_TRUE(run);
    const Coefficients& c = run->irradiance;
    const glm::dvec3 seen = glm::normalize(glm::dvec3(-c[3].x, -c[1].x, c[2].x));
    EXPECT_GT(glm::dot(seen, target), 0.999)
        << "cap at (" << target.x << ", " << target.y << ", " << target.z << ") seen by cmgen at ("
        << seen.x << ", " << seen.y << ", " << seen.z << ")";
  }
}

}  // namespace
}  // namespace compose::lighting
