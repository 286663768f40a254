// compose-bench-stitch: six 12-megapixel photos stitched into 1024² cube faces, end to end through
// the compose executable: wall-clock time and peak memory (the child process's maximum resident
// set), in the default mode (each photo decoded once and held) and with --low-memory.
//
//   compose-bench-stitch [--keep DIR]
//
// The photos are made first (not timed): views of the forest HDRI through a 110° rectilinear lens
// at 4000 x 3000 (the photographer's six directions, each turned by up to ±2°), exposed so that
// the median is mid-grey, sRGB-encoded and saved as JPEG (quality 95), as a camera would.
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "core/parallel.h"
#include "cubemap/render_view.h"
#include "ingest/image_io.h"
#include "lighting/filtered_cube.h"
#include "lighting/sphere_resample.h"
#include "pipeline/compose_job.h"

using namespace compose;
namespace fs = std::filesystem;

namespace {

struct Run {
  int status = -1;
  double seconds = 0.0;
  double peakMegabytes = 0.0;
  std::string err;
};

Run runCompose(const std::vector<std::string>& args, const fs::path& errFile) {
  const auto start = std::chrono::steady_clock::now();
  const pid_t pid = fork();
  if (pid == 0) {
    std::vector<char*> argv;
    std::string exe = COMPOSE_EXECUTABLE;
    argv.push_back(exe.data());
    std::vector<std::string> copy = args;
    for (auto& a : copy) argv.push_back(a.data());
    argv.push_back(nullptr);
    if (!freopen(errFile.c_str(), "w", stderr) || !freopen("/dev/null", "w", stdout)) _exit(127);
    execv(exe.c_str(), argv.data());
    _exit(127);
  }
  Run r;
  int status = 0;
  struct rusage usage {};
  wait4(pid, &status, 0, &usage);
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  r.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.peakMegabytes = double(usage.ru_maxrss) / 1024.0;  // kilobytes on Linux
  std::ifstream in(errFile);
  std::stringstream ss;
  ss << in.rdbuf();
  r.err = ss.str();
  return r;
}

float srgbEncode(float linear) {
  const float v = std::clamp(linear, 0.0f, 1.0f);
  return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

}  // namespace

int main(int argc, char** argv) {
  fs::path dir = fs::temp_directory_path() / ("compose-bench-stitch-" + std::to_string(getpid()));
  bool keep = false;
  if (argc > 2 && std::string(argv[1]) == "--keep") {
    dir = argv[2];
    keep = true;
  }
  fs::create_directories(dir);
  const fs::path source = pipeline::samplesDirectory() / "forest.exr";
  if (!fs::exists(source)) {
    std::fprintf(stderr, "forest.exr missing: run samples/fetch.sh\n");
    return 1;
  }
  const lighting::Environment env =
      lighting::Environment::fromLatLong(ingest::readImage(source).image);
  const lighting::FilteredCube scene = lighting::FilteredCube::fromEnvironment(env, 512);
  const int width = 4000, height = 3000;
  const calib::Lens lens = calib::Lens::fromFieldOfView(width, height, 110.0);
  const char* names[6] = {"px", "nx", "py", "ny", "pz", "nz"};
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> off(-2.0, 2.0);
  std::vector<std::string> photos;
  std::printf("Making six %dx%d photos (%.0f MP) of %s in %s ...\n", width, height,
              width * height / 1e6, source.filename().c_str(), dir.c_str());
  for (int f = 0; f < 6; ++f) {
    const fs::path p = dir / (std::string("forest_") + names[f] + ".jpg");
    photos.push_back(p.string());
    if (fs::exists(p)) continue;
    // Drawn in a fixed order: C++ leaves a call's argument evaluation order unspecified.
    const double roll = off(rng), pitch = off(rng), yaw = off(rng);
    const glm::dmat3 r = cubemap::faceCameraRotation(f) * cubemap::cameraRotation(yaw, pitch, roll);
    Image view = cubemap::renderView(scene, lens, r, 1);
    std::vector<float> lum;
    for (size_t i = 0; i < view.pixels.size(); i += 97) lum.push_back(view.pixels[i]);
    std::nth_element(lum.begin(), lum.begin() + ptrdiff_t(lum.size() / 2), lum.end());
    const float exposure = 0.18f / std::max(lum[lum.size() / 2], 1e-6f);
    parallelFor(
        0, int64_t(view.pixels.size()),
        [&](int64_t i) { view.pixels[size_t(i)] = srgbEncode(exposure * view.pixels[size_t(i)]); },
        1 << 16);
    view.colorSpace = "sRGB";
    ingest::WriteOptions w;
    w.jpegQuality = 95;
    ingest::writeImage(p, view, w);
  }

  std::printf(
      "\nStitching into 1024^2 cube faces (compose stitch --fov 110 --size 1024), %ld "
      "cores:\n\n",
      sysconf(_SC_NPROCESSORS_ONLN));
  std::printf("| mode | wall time | peak memory | steps |\n|---|---|---|---|\n");
  for (const bool lowMemory : {false, true}) {
    std::vector<std::string> args = {
        "stitch", "--fov", "110", "--size", "1024", "--out", (dir / "forest_env.exr").string()};
    if (lowMemory) args.push_back("--low-memory");
    for (const auto& p : photos) args.push_back(p);
    const Run r = runCompose(args, dir / "stderr.txt");
    if (r.status != 0) {
      std::printf("compose stitch failed (%d):\n%s\n", r.status, r.err.c_str());
      return 1;
    }
    std::string steps;
    const size_t at = r.err.find("time: ");
    if (at != std::string::npos) steps = r.err.substr(at + 6, r.err.find('\n', at) - at - 6);
    std::printf("| %s | %.2f s | %.0f MB | %s |\n", lowMemory ? "--low-memory" : "default",
                r.seconds, r.peakMegabytes, steps.c_str());
    if (!lowMemory) {
      std::printf("\n%s\n", r.err.c_str());
      std::printf("| mode | wall time | peak memory | steps |\n|---|---|---|---|\n");
    }
  }
  std::printf("\nTarget: under 5 s on these 2-core machines.\n");
  if (!keep) fs::remove_all(dir);
  return 0;
}
