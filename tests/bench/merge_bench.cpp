// Merge benchmark: three 12-megapixel brackets (4000 x 3000 JPEGs from the virtual camera, of
// the forest HDRI), merged as `compose merge` does: decode, response recovery and merge
// (OpenCV), our own plumbing around them, the float EXR written. Prints the time of each part,
// the share spent inside OpenCV, how much our plumbing adds on top of the OpenCV calls, and the
// peak memory (getrusage ru_maxrss) of the merging process alone.
//
//   compose-bench-merge [--width 4000] [--height 3000] [--align] [--keep DIR]
//
// The photos are made first; the merge runs in a child process (this program again, with
// --merge-only), so that its peak memory does not include the virtual camera's.

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>

#include "bench_util.h"
#include "capture/virtual_camera.h"
#include "color/color.h"
#include "hdr/capture_merge.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"
#include "pipeline/compose_job.h"

namespace fs = std::filesystem;
using namespace compose;

namespace {

int mergeOnly(const fs::path& dir, bool align) {
  const auto t0 = std::chrono::steady_clock::now();
  ingest::Capture capture = ingest::readCaptureDescription(dir / "capture.json");
  ingest::resolveExposures(capture);
  std::vector<std::vector<ingest::LoadedImage>> photos(1);
  ingest::ReadOptions read;
  read.codesForEightBit = true;  // as compose merge reads them
  for (const auto& s : capture.views[0].shots)
    photos[0].push_back(ingest::readImage(s.file, "merge", read));
  const double decode = bench::secondsSince(t0);

  const color::ColorConfig colors = color::ColorConfig::builtin();
  hdr::CaptureMergeOptions options;
  options.response = hdr::ResponseMode::Recover;
  options.responseFolder = dir / "responses";
  options.merge.align = align;
  const hdr::CaptureMergeResult r = hdr::mergeCapture(capture, photos, options, colors);
  photos.clear();

  const auto t2 = std::chrono::steady_clock::now();
  ingest::WriteOptions w;
  w.depth = ingest::WriteOptions::Depth::Float;
  ingest::writeImage(dir / "merged.exr", r.views[0].radiance, w);
  const double write = bench::secondsSince(t2);

  const double plumbing = r.seconds - r.openCvSeconds;
  const auto& img = r.views[0].radiance;
  std::printf("merge of %zu exposures, %d x %d (%.1f megapixels)%s\n",
              capture.views[0].shots.size(), img.width, img.height,
              img.width * double(img.height) / 1e6, align ? ", aligned" : "");
  std::printf("  %-46s %8.3f s\n", "decode JPEGs (OpenImageIO)", decode);
  std::printf("  %-46s %8.3f s\n", "response recovery (of which OpenCV below)", r.recoverySeconds);
  std::printf("  %-46s %8.3f s\n", "merge library total (mergeCapture)", r.seconds);
  std::printf("  %-46s %8.3f s\n", "  inside OpenCV (CalibrateDebevec, Merge, Align)",
              r.openCvSeconds);
  std::printf("  %-46s %8.3f s\n", "  our plumbing (conversions, mask, colour)", plumbing);
  std::printf("  %-46s %8.1f %%\n", "  share inside OpenCV", 100.0 * r.openCvSeconds / r.seconds);
  std::printf("  %-46s %8.1f %%  (target <= 20 %%)\n", "  plumbing on top of the OpenCV calls",
              100.0 * plumbing / r.openCvSeconds);
  std::printf("  %-46s %8.3f s\n", "write float EXR (OpenImageIO)", write);
  std::printf("  %-46s %8.3f s\n", "end to end", bench::secondsSince(t0));
  std::printf("  %-46s %8.0f MB\n", "peak memory of the merging process (ru_maxrss)",
              bench::peakResidentMb());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  int width = 4000, height = 3000;
  bool align = false;
  fs::path keep, mergeDir;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--width") {
      width = std::atoi(next().c_str());
    } else if (a == "--height") {
      height = std::atoi(next().c_str());
    } else if (a == "--align") {
      align = true;
    } else if (a == "--keep") {
      keep = next();
    } else if (a == "--merge-only") {
      mergeDir = next();
    } else {
      std::fprintf(stderr,
                   "usage: compose-bench-merge [--width W] [--height H] [--align] [--keep DIR]\n");
      return 2;
    }
  }
  try {
    if (!mergeDir.empty()) return mergeOnly(mergeDir, align);

    const fs::path dir = keep.empty() ? fs::temp_directory_path() /
                                            ("compose-bench-merge-" + std::to_string(getpid()))
                                      : keep;
    const auto t0 = std::chrono::steady_clock::now();
    const fs::path envFile = pipeline::samplesDirectory() / "forest.exr";
    const ingest::LoadedImage envImage = ingest::readImage(envFile);
    const auto env = lighting::Environment::fromLatLong(envImage.image, envFile);
    capture::VirtualCameraParams p;
    p.width = width;
    p.height = height;
    p.views = 1;
    p.brackets = 3;
    p.evStep = 2.0;
    p.supersample = 1;
    if (align) p.shakePixels = 15.0;
    {
      const capture::SimulatedCapture sim = capture::simulateCapture(env, p);
      capture::writeCapture(dir, sim);
    }
    std::printf("setup: the virtual camera took and wrote 3 JPEGs in %.1f s (%s)\n",
                bench::secondsSince(t0), dir.string().c_str());
    std::fflush(stdout);
    const std::string cmd = "'/proc/" + std::to_string(getpid()) + "/exe' --merge-only '" +
                            dir.string() + "'" + (align ? " --align" : "");
    const int status = std::system(cmd.c_str());
    if (keep.empty()) fs::remove_all(dir);
    return status == 0 ? 0 : 1;
  } catch (const Error& e) {
    std::fprintf(stderr, "compose-bench-merge: error: %s\n", e.describe().c_str());
    return 1;
  }
}
