// compose: put a synthetic diffuse object into a photograph, lit by the place the photo shows.
// This file only parses options, calls the pipeline and reports; the work is in the libraries.
#include <unistd.h>

#include <cstdio>
#include <iostream>
#include <mutex>
#include <sstream>
#include <string>

#include <CLI/CLI.hpp>

#include "color/color.h"
#include "core/error.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"

namespace {

using compose::Error;

// "X,Y" → two numbers.
glm::dvec2 parsePair(const std::string& text, const std::string& option) {
  std::istringstream in(text);
  double a = 0, b = 0;
  char comma = 0;
  if (!(in >> a >> comma >> b) || comma != ',' || !in.eof()) {
    throw Error("cli", option + " expects two numbers as X,Y, got '" + text + "'");
  }
  return {a, b};
}

glm::vec3 parseColour(const std::string& text, const std::string& option) {
  std::istringstream in(text);
  float r = 0, g = 0, b = 0;
  char c1 = 0, c2 = 0;
  if ((in >> r) && in.eof()) return glm::vec3(r);
  in.clear();
  in.str(text);
  if (!(in >> r >> c1 >> g >> c2 >> b) || c1 != ',' || c2 != ',' || !in.eof()) {
    throw Error("cli", option + " expects one value or R,G,B, got '" + text + "'");
  }
  return {r, g, b};
}

std::string join(const std::vector<std::string>& items) {
  std::string s;
  for (const auto& i : items) s += (s.empty() ? "" : ", ") + i;
  return s;
}

// Progress on stderr, one line per stage, redrawn in place on a terminal.
class ProgressPrinter {
 public:
  explicit ProgressPrinter(bool quiet) : quiet_(quiet), tty_(::isatty(STDERR_FILENO) != 0) {}
  void operator()(std::string_view stage, double fraction) {
    if (quiet_ || !tty_) return;
    std::lock_guard lock(mutex_);
    std::fprintf(stderr, "\r  %-10.*s %3d%%", int(stage.size()), stage.data(),
                 int(fraction * 100.0 + 0.5));
    if (fraction >= 1.0) std::fprintf(stderr, "\r\033[K");
    std::fflush(stderr);
  }

 private:
  bool quiet_, tty_;
  std::mutex mutex_;
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "compose: insert a synthetic diffuse object into a photograph, lit by an HDR environment of "
      "the place.\n"
      "Writes <out>.exr (scene-linear, working space, with the object layer and a normal AOV) and "
      "<out>.jpg\n"
      "(through the OpenColorIO display transform).",
      "compose"};
  compose::pipeline::ComposeJob job;
  std::string place, albedo, lightingParams, exposure = "auto";
  double focal35 = 0.0;
  bool explain = false, quiet = false;

  app.add_option("--plate", job.plate, "Background photograph (JPEG, PNG, TIFF, EXR, ...)")
      ->required();
  app.add_option("--object", job.object, "Mesh to insert (Wavefront OBJ)")->required();
  app.add_option(
      "--env", job.environment,
      "HDR environment, lat-long (equirectangular) map [default: the forest sample HDRI]");
  app.add_option("--out", job.output, "Output base path; writes BASE.exr and BASE.jpg (or .png)")
      ->capture_default_str();
  app.add_option("--lighting", job.lighting,
                 "Lighting basis: " + join(compose::lighting::lightingNames()))
      ->capture_default_str();
  app.add_option("--lighting-params", lightingParams,
                 "Basis parameters as key=value,... (cheb-*: order, samples, rows, cols, "
                 "subsamples; sh: order=0..8;"
                 " mc: samples, seed)");
  app.add_option("--place", place,
                 "Image point X,Y in [0,1] where the object stands [default: 0.5,0.72]");
  app.add_option("--scale", job.placement.heightFraction,
                 "Object height as a fraction of the plate height")
      ->capture_default_str();
  app.add_option("--yaw", job.placement.yawDegrees,
                 "Turn the object about the vertical axis, degrees")
      ->capture_default_str();
  app.add_option("--env-yaw", job.environmentYawDegrees,
                 "Turn the environment about the vertical axis, degrees")
      ->capture_default_str();
  app.add_option("--focal35", focal35,
                 "35 mm equivalent focal length of the plate [default: EXIF, else 50]");
  app.add_option("--camera-height", job.camera.height, "Camera height above the ground, metres")
      ->capture_default_str();
  app.add_option("--pitch", job.camera.pitchDegrees, "Camera tilt down, degrees")
      ->capture_default_str();
  app.add_option("--albedo", albedo,
                 "Object albedo, one value or R,G,B in the working space [default: 0.5]");
  app.add_option(
         "--exposure", exposure,
         "Exposure of the object in stops, or 'auto': match the environment to the plate's mean")
      ->capture_default_str();
  app.add_option("--samples", job.samplesPerAxis, "Anti-aliasing: N x N samples per pixel")
      ->capture_default_str();
  app.add_option("--plate-space", job.plateSpace,
                 "Colour space of the plate [default: from the file]");
  app.add_option("--env-space", job.environmentSpace,
                 "Colour space of the environment [default: from the file]");
  app.add_option("--display", job.display,
                 "OpenColorIO display for the JPEG/PNG [default: the config's]");
  app.add_option("--view", job.view, "OpenColorIO view for the JPEG/PNG [default: the config's]");
  bool noCache = false;
  app.add_option("--cache", job.lightingCache, "Folder for cached lighting projections")
      ->capture_default_str();
  app.add_flag("--no-cache", noCache, "Neither read nor write the lighting cache");
  app.add_flag("--explain", explain, "Say which stages run or are skipped and why, then exit");
  app.add_flag("-q,--quiet", quiet, "Print only the output paths and errors");

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << "compose: error: cli: " << e.what() << "\n(run compose --help for usage)\n";
    return 2;
  }

  try {
    if (!place.empty()) job.placement.imagePoint = parsePair(place, "--place");
    if (!albedo.empty()) job.albedo = parseColour(albedo, "--albedo");
    if (app.count("--focal35")) job.camera.focal35mm = focal35;
    job.lightingParams = lightingParams;
    if (noCache) job.lightingCache.clear();
    if (exposure != "auto") {
      try {
        size_t used = 0;
        job.exposureStops = std::stod(exposure, &used);
        if (used != exposure.size()) throw std::invalid_argument(exposure);
      } catch (const std::exception&) {
        throw Error("cli",
                    "--exposure expects a number of stops or 'auto', got '" + exposure + "'");
      }
    }

    if (explain) {
      for (const auto& s : compose::pipeline::plan(job)) {
        std::printf("%-10s %-4s %s\n", s.name.c_str(), s.runs ? "run" : "skip", s.reason.c_str());
      }
      return 0;
    }

    const compose::color::ColorConfig colors = compose::color::ColorConfig::fromEnvironment();
    ProgressPrinter printer(quiet);
    const auto result = compose::pipeline::runCompose(
        job, colors, [&](std::string_view stage, double fraction) { printer(stage, fraction); });
    if (!quiet) {
      for (const auto& note : result.notes)
        std::fprintf(stderr, "compose: note: %s\n", note.c_str());
      for (const auto& s : result.stages) {
        if (s.runs)
          std::fprintf(stderr, "compose: %-10s %7.3f s  %s\n", s.name.c_str(), s.seconds,
                       s.reason.c_str());
      }
    }
    std::printf("%s\n%s\n", result.exrPath.string().c_str(), result.displayPath.string().c_str());
    return 0;
  } catch (const Error& e) {
    std::fprintf(stderr, "compose: error: %s\n", e.describe().c_str());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "compose: error: %s\n", e.what());
    return 1;
  }
}
