// compose-bench-lighting: run time against error for every lighting basis (docs/design.md §5-7,
// issue 3).
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
#include <tuple>
#include <vector>

#include "core/parallel.h"
#include "ingest/image_io.h"
#include "lighting/chebyshev.h"
#include "lighting/environment.h"
#include "lighting/exact.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"
#include "svg_plot.h"

namespace fs = std::filesystem;
using namespace compose;
using Clock = std::chrono::steady_clock;

namespace {

double seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

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
  // Windowed (deringed) SH, reported separately from raw SH.
  for (int order : {2, 4, 6})
    c.push_back({"sh", "order=" + std::to_string(order) + ",window=hanning"});
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
  for (int n : {16, 64, 256, 1024, 4096, 16384, 65536, 262144}) {
    if (quick && n > 4096) break;
    c.push_back({"mc", "samples=" + std::to_string(n)});
  }
  if (!quick) {
    for (int k : {4, 6, 8})
      c.push_back({"cheb-local", "order=" + std::to_string(k) + ",samples=8"});
    c.push_back({"cheb-local", "order=3,samples=8,rows=17,cols=32"});
    c.push_back({"cheb-local", "order=3,samples=8,rows=65,cols=128"});
  }
  return c;
}

// A 1920x1080 image of normals: a sphere filling the frame height; pixels outside it take the
// normals of the far side (mirrored), so every pixel carries a normal to shade.
std::vector<glm::vec3> frameNormals() {
  constexpr int kW = 1920, kH = 1080;
  std::vector<glm::vec3> out(size_t(kW) * kH);
  for (int y = 0; y < kH; ++y) {
    for (int x = 0; x < kW; ++x) {
      double u = (x + 0.5 - kW / 2.0) / (kH / 2.0), v = 1.0 - (y + 0.5) / (kH / 2.0);
      double r2 = u * u + v * v;
      double z = 1.0;
      if (r2 >= 1.0) {
        const double r = std::sqrt(r2);
        u /= r * 1.0001, v /= r * 1.0001;
        r2 = u * u + v * v;
        z = -1.0;
      }
      out[size_t(y) * kW + size_t(x)] =
          glm::vec3(float(u), float(v), float(z * std::sqrt(std::max(0.0, 1.0 - r2))));
    }
  }
  return out;
}

// Runs Filament's cmgen the way its users would (--sh=3 --sh-window=no -i) on `file`, best of 3
// wall-clock runs; a negative number if cmgen is missing or fails.
double timeCmgen(const fs::path& file, const fs::path& scratch) {
  const std::string cmd = "cmgen --sh=3 --sh-window=no -i -q --sh-output='" +
                          (scratch / "cmgen_sh.txt").string() + "' '" + file.string() +
                          "' >/dev/null 2>&1";
  double best = -1.0;
  for (int i = 0; i < 3; ++i) {
    const auto t0 = Clock::now();
    const int raw = std::system(cmd.c_str());
    const double t = seconds(t0, Clock::now());
    if (!WIFEXITED(raw) || WEXITSTATUS(raw) != 0) return -1.0;
    best = best < 0 ? t : std::min(best, t);
  }
  return best;
}

struct OrenNayarRow {
  std::string env, params;
  double snrDb = 0, precomputeMs = 0;
};

struct SideBySide {
  std::string env;
  double readMs = 0, chebPrecomputeMs = 0, chebEvalMs = 0, shPrecomputeMs = 0, shEvalMs = 0,
         cmgenMs = -1;
};

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
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
      std::fprintf(stderr, "usage: %s [--out DIR] [--quick] [--sphere N] [--only BASIS]\n",
                   argv[0]);
      return 2;
    }
  }
  fs::create_directories(outDir);
  const fs::path samples = pipeline::samplesDirectory();
  const std::vector<glm::vec3> normals = sphereNormals(sphere);
  std::printf("lighting benchmark: %zu sphere normals (%dx%d, front and back), samples in %s\n",
              normals.size(), sphere, sphere, samples.c_str());

  std::vector<Row> rows;
  std::vector<OrenNayarRow> orenNayarRows;
  std::vector<SideBySide> sideBySide;
  const std::vector<glm::vec3> frame = frameNormals();
  const std::string defaultBasis = pipeline::ComposeJob{}.lighting;
  for (const char* name : {"courtyard", "forest", "interior", "sunset"}) {
    const fs::path file = samples / (std::string(name) + ".exr");
    ingest::LoadedImage img;
    const auto r0 = Clock::now();
    try {
      img = ingest::readImage(file);
    } catch (const Error& e) {
      std::fprintf(stderr, "error: %s (run samples/fetch.sh)\n", e.describe().c_str());
      return 1;
    }
    const lighting::Environment env = lighting::Environment::fromLatLong(img.image, file);
    SideBySide side{name};
    side.readMs = 1e3 * seconds(r0, Clock::now());

    // Side by side with cmgen --sh=3: the default basis and SH9, each projected and evaluated on a
    // 1920x1080 image of normals. cmgen cannot read DWAB-compressed EXR, so it gets the same
    // pixels rewritten as a ZIP-compressed float EXR.
    {
      for (const std::string& which : {defaultBasis, std::string("sh")}) {
        auto basis = lighting::createLighting(which);
        double bestPre = 1e30, bestEval = 1e30;
        for (int rep = 0; rep < 3; ++rep) {
          const auto a = Clock::now();
          basis->project(env);
          const auto b = Clock::now();
          std::vector<glm::vec3> out(frame.size());
          parallelFor(
              0, int64_t(frame.size()),
              [&](int64_t i) { out[size_t(i)] = basis->irradiance(frame[size_t(i)]); }, 4096);
          const auto c = Clock::now();
          bestPre = std::min(bestPre, 1e3 * seconds(a, b));
          bestEval = std::min(bestEval, 1e3 * seconds(b, c));
        }
        (which == "sh" ? side.shPrecomputeMs : side.chebPrecomputeMs) = bestPre;
        (which == "sh" ? side.shEvalMs : side.chebEvalMs) = bestEval;
      }
      const fs::path plain = outDir / (std::string(name) + "_zip.exr");
      ingest::WriteOptions opt;
      opt.depth = ingest::WriteOptions::Depth::Float;
      ingest::writeImage(plain, img.image, opt);
      side.cmgenMs = 1e3 * timeCmgen(plain, outDir);
      fs::remove(plain);
      std::printf(
          "%s: 1920x1080 normals: %s %.1f + %.1f ms, sh9 %.1f + %.1f ms, cmgen --sh=3 %.1f ms "
          "(ratio %.2f)\n",
          name, defaultBasis.c_str(), side.chebPrecomputeMs, side.chebEvalMs, side.shPrecomputeMs,
          side.shEvalMs, side.cmgenMs, (side.chebPrecomputeMs + side.chebEvalMs) / side.cmgenMs);
      sideBySide.push_back(side);
    }

    lighting::ExactLighting exact;
    const auto t0 = Clock::now();
    exact.project(env);
    std::vector<glm::dvec3> ref(normals.size());
    parallelFor(
        0, int64_t(normals.size()),
        [&](int64_t i) { ref[size_t(i)] = glm::dvec3(exact.irradiance(normals[size_t(i)])); }, 64);
    std::printf("\n%s: exact reference %.2f s\n", name, seconds(t0, Clock::now()));

    for (const Config& cfg : sweep(quick)) {
      if (!only.empty() && cfg.basis != only) continue;
      auto basis = lighting::createLighting(cfg.basis, ParamSet::parse(cfg.params, "bench"));
      const auto p0 = Clock::now();
      basis->project(env);
      const auto p1 = Clock::now();
      // Monte Carlo is evaluated on an even subset of the normals (its cost per point is
      // thousands of times higher); its SNR and time per million points come from that subset.
      size_t subset = normals.size();
      if (cfg.basis == "mc") subset = cfg.params == "samples=262144" ? 500 : 2000;
      const size_t stride = std::max<size_t>(1, normals.size() / subset);
      std::vector<glm::vec3> got(normals.size());
      const int64_t evaluated = int64_t((normals.size() + stride - 1) / stride);
      parallelFor(
          0, evaluated,
          [&](int64_t i) {
            got[size_t(i) * stride] = basis->irradiance(normals[size_t(i) * stride]);
          },
          16);
      const auto p2 = Clock::now();
      double signal = 0, noise = 0, rel = 0;
      for (size_t i = 0; i < normals.size(); i += stride) {
        const glm::dvec3 r = ref[i], g = glm::dvec3(got[i]);
        signal += glm::dot(r, r);
        noise += glm::dot(r - g, r - g);
        const double l1 = std::abs(r.x) + std::abs(r.y) + std::abs(r.z);
        rel +=
            (std::abs(r.x - g.x) + std::abs(r.y - g.y) + std::abs(r.z - g.z)) / std::max(l1, 1e-30);
      }
      Row row{name,
              cfg.basis,
              cfg.params,
              basis->coefficientsPerChannel(),
              basis->floatsStored(),
              1e3 * seconds(p0, p1),
              1e3 * seconds(p1, p2) * 1e6 / double(evaluated),
              10.0 * std::log10(signal / std::max(noise, 1e-300)),
              rel / double(evaluated)};
      rows.push_back(row);
      std::printf(
          "  %-12s %-36s coeff %4d  floats %8zu  pre %8.2f ms  eval %8.1f ms/M  SNR %6.2f dB  rel "
          "%.2e\n",
          row.basis.c_str(), row.params.c_str(), row.coefficients, row.floats, row.precomputeMs,
          row.evalMsPerMillion, row.snrDb, row.relError);
      std::fflush(stdout);
    }

    // Oren–Nayar (sigma 0.3), the view-dependent case: a subset of the sphere's normals, each
    // seen orthographically along ±Z, against the per-texel reference. "lambert" ignores the
    // roughness altogether (the error of not modelling the BRDF).
    if (only.empty() || only == "oren-nayar") {
      constexpr double kSigma = 0.3;
      const size_t step = std::max<size_t>(1, normals.size() / (quick ? 300 : 1500));
      std::vector<size_t> picks;
      for (size_t i = 0; i < normals.size(); i += step) picks.push_back(i);
      std::vector<glm::dvec3> onRef(picks.size());
      parallelFor(0, int64_t(picks.size()), [&](int64_t i) {
        const glm::vec3 n = normals[picks[size_t(i)]];
        onRef[size_t(i)] = lighting::orenNayarReference(
            env, kSigma, n, glm::vec3(0.0f, 0.0f, n.z >= 0.0f ? 1.0f : -1.0f));
      });
      for (const char* params : {"lambert", "order=1,samples=8", "order=2,samples=8",
                                 "order=4,samples=8", "order=8,samples=8", "order=16,samples=16"}) {
        const bool lambert = std::string(params) == "lambert";
        auto basis = lighting::createLighting(
            "cheb-local",
            ParamSet::parse(lambert ? std::string("order=1")
                                    : std::string(params) + ",brdf=oren-nayar,sigma=0.3",
                            "bench"));
        const auto a = Clock::now();
        basis->project(env);
        const double pre = 1e3 * seconds(a, Clock::now());
        double signal = 0, noise = 0;
        for (size_t i = 0; i < picks.size(); ++i) {
          const glm::vec3 n = normals[picks[i]];
          const glm::dvec3 g(
              basis->irradiance(n, glm::vec3(0.0f, 0.0f, n.z >= 0.0f ? 1.0f : -1.0f)));
          signal += glm::dot(onRef[i], onRef[i]);
          noise += glm::dot(onRef[i] - g, onRef[i] - g);
        }
        orenNayarRows.push_back({name, params, 10.0 * std::log10(signal / noise), pre});
        std::printf("  oren-nayar   %-36s SNR %6.2f dB  pre %8.2f ms\n", params,
                    orenNayarRows.back().snrDb, pre);
      }
    }
  }

  std::ofstream csv(outDir / "lighting.csv");
  csv << "environment,basis,params,coefficients_per_channel,floats_stored,precompute_ms,eval_ms_"
         "per_million,snr_db,"
         "relative_error\n";
  for (const Row& r : rows) {
    csv << r.env << "," << r.basis << ",\"" << r.params << "\"," << r.coefficients << ","
        << r.floats << "," << r.precomputeMs << "," << r.evalMsPerMillion << "," << r.snrDb << ","
        << r.relError << "\n";
  }
  std::printf("\nwrote %s\n", (outDir / "lighting.csv").c_str());

  // --- plots: the paper's Figure 2 (SNR and relative error against coefficients, averaged over
  // the environments) and the Pareto view (error against total time per million points).
  struct Key {
    std::string basis, params;
    bool operator<(const Key& o) const {
      return std::tie(basis, params) < std::tie(o.basis, o.params);
    }
  };
  std::map<Key, std::vector<const Row*>> byConfig;
  for (const Row& r : rows) byConfig[{r.basis, r.params}].push_back(&r);
  auto mean = [](const std::vector<const Row*>& v, double Row::*field) {
    double sum = 0;
    for (const Row* r : v) sum += r->*field;
    return sum / double(v.size());
  };
  // One curve per basis (and grid size): the configurations in the order of the sweep.
  std::map<std::string, bench::Series> snrCurves, relCurves, pareto;
  for (const Config& cfg : sweep(quick)) {
    auto it = byConfig.find({cfg.basis, cfg.params});
    if (it == byConfig.end() || cfg.basis == "mc") continue;
    std::string family = cfg.basis;
    const auto grid = cfg.params.find("samples=");
    if (grid != std::string::npos && cfg.basis != "cheb-local")
      family += " s=" + cfg.params.substr(grid + 8);
    if (cfg.params.find("rows=") != std::string::npos) continue;
    if (cfg.params.find("window=") != std::string::npos) family += " (hanning)";
    const double coeff = it->second.front()->coefficients;
    snrCurves[family].label = family;
    snrCurves[family].x.push_back(coeff);
    snrCurves[family].y.push_back(mean(it->second, &Row::snrDb));
    relCurves[family].label = family;
    relCurves[family].x.push_back(coeff);
    relCurves[family].y.push_back(mean(it->second, &Row::relError));
  }
  for (const auto& [key, v] : byConfig) {
    auto& series = pareto[key.basis];
    series.label = key.basis;
    series.lines = false;
    series.x.push_back(mean(v, &Row::precomputeMs) + mean(v, &Row::evalMsPerMillion));
    series.y.push_back(mean(v, &Row::snrDb));
  }
  bench::Chart snr;
  snr.title = "SNR against coefficients (mean of 4 environments, sphere, exact reference)";
  snr.xLabel = "coefficients per point and channel";
  snr.yLabel = "SNR (dB)";
  snr.logX = true;
  snr.hLines.push_back({45.0, "45 dB target"});
  for (auto& [k, v] : snrCurves) snr.series.push_back(v);
  bench::Chart rel;
  rel.title = "Mean relative error against coefficients (mean of 4 environments)";
  rel.xLabel = "coefficients per point and channel";
  rel.yLabel = "relative error";
  rel.logX = rel.logY = true;
  for (auto& [k, v] : relCurves) rel.series.push_back(v);
  bench::Chart front;
  front.title =
      "Accuracy against time: precompute + evaluation of 1M points (mean of 4 environments)";
  front.xLabel = "time (ms)";
  front.yLabel = "SNR (dB)";
  front.logX = true;
  front.hLines.push_back({45.0, "45 dB target"});
  for (auto& [k, v] : pareto) front.series.push_back(v);
  bench::writeSvg(snr, outDir / "snr_vs_coefficients.svg");
  bench::writeSvg(rel, outDir / "relerr_vs_coefficients.svg");
  bench::writeSvg(front, outDir / "snr_vs_time.svg");

  // --- Markdown summary.
  std::ofstream md(outDir / "lighting.md");
  md << "# Lighting bases: accuracy against cost\n\n"
     << "Sphere seen from the front and the back (" << normals.size()
     << " normals, every direction), "
     << "irradiance against the exact reference (quadrature over every texel of the 1024x512 map). "
     << "SNR = 10 log10(Σ ref² / Σ (ref - x)²); relative error = mean |ref - x|₁ / |ref|₁. Times: "
     << "precompute (projection) once per environment, evaluation per million points, 2 cores.\n\n";
  md << "## Side by side with Filament cmgen, 1920x1080 normals\n\n"
     << "| environment | " << defaultBasis
     << " precompute + evaluation (ms) | SH9 precompute + evaluation (ms) "
     << "| cmgen --sh=3 wall (ms) | ratio " << defaultBasis
     << " / cmgen |\n|---|---|---|---|---|\n";
  for (const auto& sbs : sideBySide) {
    md << "| " << sbs.env << " | " << fmt("%.1f", sbs.chebPrecomputeMs) << " + "
       << fmt("%.1f", sbs.chebEvalMs) << " | " << fmt("%.1f", sbs.shPrecomputeMs) << " + "
       << fmt("%.1f", sbs.shEvalMs) << " | "
       << (sbs.cmgenMs > 0 ? fmt("%.1f", sbs.cmgenMs) : std::string("not installed")) << " | "
       << (sbs.cmgenMs > 0 ? fmt("%.2f", (sbs.chebPrecomputeMs + sbs.chebEvalMs) / sbs.cmgenMs)
                           : std::string("-"))
       << " |\n";
  }
  md << "\ncmgen's time is its whole run (reading the EXR included); reading the EXR here takes "
     << fmt("%.0f", sideBySide.empty() ? 0.0 : sideBySide.front().readMs)
     << " ms and is not counted above.\n\n";
  md << "## At most 9 coefficients per point and channel (best SNR of each basis)\n\n| basis | "
        "params | coefficients |";
  for (const auto& sbs : sideBySide) md << " " << sbs.env << " SNR dB |";
  md << " floats stored |\n|---|---|---|";
  for (size_t i = 0; i < sideBySide.size(); ++i) md << "---|";
  md << "---|\n";
  std::map<std::string, const std::vector<const Row*>*> best;
  for (const auto& [key, v] : byConfig) {
    if (v.front()->coefficients > 9 || key.basis == "mc") continue;
    auto& b = best[key.basis];
    if (!b || mean(v, &Row::snrDb) > mean(*b, &Row::snrDb)) b = &v;
  }
  {
    // The configuration compose uses by default, whatever the sweep found best.
    auto it = byConfig.find({defaultBasis, "order=1,samples=8"});
    if (it != byConfig.end()) best[defaultBasis + " (compose default)"] = &it->second;
  }
  for (const auto& [basis, v] : best) {
    md << "| " << basis << " | " << v->front()->params << " | " << v->front()->coefficients << " |";
    for (const Row* r : *v) md << " " << fmt("%.1f", r->snrDb) << " |";
    md << " " << v->front()->floats << " |\n";
  }
  if (!orenNayarRows.empty()) {
    md << "\n## Oren–Nayar (sigma 0.3, view dependent), cheb-local\n\nSNR against a per-texel "
          "reference on "
          "a subset of the sphere's normals, each seen along ±Z. `lambert` ignores the "
          "roughness.\n\n| params |";
    for (const auto& sbs : sideBySide) md << " " << sbs.env << " SNR dB |";
    md << "\n|---|";
    for (size_t i = 0; i < sideBySide.size(); ++i) md << "---|";
    md << "\n";
    std::vector<std::string> order;
    for (const auto& r : orenNayarRows)
      if (std::find(order.begin(), order.end(), r.params) == order.end()) order.push_back(r.params);
    for (const auto& p : order) {
      md << "| " << p << " |";
      for (const auto& r : orenNayarRows)
        if (r.params == p) md << " " << fmt("%.1f", r.snrDb) << " |";
      md << "\n";
    }
  }
  md << "\n## Every configuration\n\n| environment | basis | params | coefficients | floats | "
        "precompute ms | "
        "eval ms/M | SNR dB | rel. error |\n|---|---|---|---|---|---|---|---|---|\n";
  for (const Row& r : rows) {
    md << "| " << r.env << " | " << r.basis << " | " << r.params << " | " << r.coefficients << " | "
       << r.floats << " | " << fmt("%.1f", r.precomputeMs) << " | "
       << fmt("%.1f", r.evalMsPerMillion) << " | " << fmt("%.2f", r.snrDb) << " | "
       << fmt("%.2e", r.relError) << " |\n";
  }
  md << "\nPlots: snr_vs_coefficients.svg, relerr_vs_coefficients.svg, snr_vs_time.svg. Monte "
        "Carlo rows are "
        "evaluated on an even subset of about 2000 normals (500 at 262144 samples).\n";
  std::printf("wrote %s and the plots\n", (outDir / "lighting.md").c_str());
  return 0;
}
