// compose-bench-environment: filtered cube lookups per second (one thread and all), and
// environment conversions against a plain copy of the same bytes.
//
//   compose-bench-environment [--quick]
//
// Lookups: a FilteredCube of the forest HDRI (256² faces, 9 levels), random unit directions with
// footprints log-uniform between a quarter of a finest texel and a whole face, trilinear filtering
// across face edges. Conversions: layout repacking (OpenEXR cube strip ↔ crosses ↔ faces), which
// moves every texel once, against std::memcpy of the same bytes; then the area-exact resampling
// between lat-long and cube maps, which computes closed-form overlaps for every texel, reported
// the same way for honesty.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <tbb/global_control.h>

#include "bench_util.h"
#include "core/parallel.h"
#include "cubemap/layouts.h"
#include "ingest/image_io.h"
#include "lighting/filtered_cube.h"
#include "lighting/sphere_resample.h"
#include "pipeline/compose_job.h"

using namespace compose;

namespace {

// Best of `repeats` timings of f().
template <class F>
double best(int repeats, F&& f) {
  double b = 1e30;
  for (int i = 0; i < repeats; ++i) {
    const auto t = bench::Clock::now();
    f();
    b = std::min(b, bench::secondsSince(t));
  }
  return b;
}

lighting::Environment synthetic(int width) {
  Image img(width, width / 2, 3, {"R", "G", "B"});
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0.0f, 2.0f);
  for (float& v : img.pixels) v = u(rng);
  return lighting::Environment::fromLatLong(img);
}

}  // namespace

int main(int argc, char** argv) {
  const bool quick = argc > 1 && std::string(argv[1]) == "--quick";
  const int threads = tbb::info::default_concurrency();
  std::printf("compose-bench-environment (%d threads available)\n\n", threads);

  // --- Filtered lookups ------------------------------------------------------------------------
  lighting::Environment env;
  const auto forest = pipeline::samplesDirectory() / "forest.exr";
  if (std::filesystem::exists(forest)) {
    env = lighting::Environment::fromLatLong(ingest::readImage(forest).image);
  } else {
    std::printf("(forest.exr missing: a synthetic 1024x512 map instead)\n");
    env = synthetic(1024);
  }
  const lighting::FilteredCube filtered = lighting::FilteredCube::fromEnvironment(env);
  const size_t count = quick ? 1000000 : 4000000;
  std::vector<glm::vec3> dirs(count);
  std::vector<float> footprints(count);
  {
    std::mt19937 rng(7);
    std::normal_distribution<float> g;
    const double texel = 4.0 / (256.0 * 256.0);
    std::uniform_real_distribution<double> lg(std::log(texel / 4.0), std::log(4.0 * 3.14159 / 6.0));
    for (size_t i = 0; i < count; ++i) {
      const float z = g(rng), y = g(rng), x = g(rng);  // a fixed order, whatever the compiler
      glm::vec3 v(x, y, z);
      dirs[i] = v / std::sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
      footprints[i] = float(std::exp(lg(rng)));
    }
  }
  std::vector<glm::vec3> out(count);
  const double one = best(3, [&] {
    for (size_t i = 0; i < count; ++i) out[i] = filtered.lookup(dirs[i], footprints[i]);
  });
  const double all = best(3, [&] {
    parallelFor(
        0, int64_t(count),
        [&](int64_t i) {
          out[size_t(i)] = filtered.lookup(dirs[size_t(i)], footprints[size_t(i)]);
        },
        4096);
  });
  const double nearestOne = best(3, [&] {
    for (size_t i = 0; i < count; ++i) out[i] = filtered.lookupLevel(dirs[i], 0.0f);
  });
  std::printf("Filtered lookups (256^2 faces, %d levels, %.1f MB):\n", filtered.levels(),
              double(filtered.bytes()) / 1e6);
  std::printf("  trilinear by footprint, 1 thread    %8.1f M lookups/s\n",
              double(count) / one / 1e6);
  std::printf("  trilinear by footprint, %d threads   %8.1f M lookups/s\n", threads,
              double(count) / all / 1e6);
  std::printf("  bilinear, finest level, 1 thread    %8.1f M lookups/s\n\n",
              double(count) / nearestOne / 1e6);

  // --- Conversions against a copy ---------------------------------------------------------------
  const int n = quick ? 512 : 1024;
  lighting::CubeMap cube(n);
  {
    std::mt19937 rng(3);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    for (int f = 0; f < lighting::kCubeFaces; ++f)
      for (float& v : cube.face(f)) v = u(rng);
  }
  const Image strip = cubemap::packFaces(cube, cubemap::Layout::Cube);
  const size_t bytes = strip.pixels.size() * sizeof(float);
  // The plain copy: the same bytes as the conversion's output into a new buffer (every conversion
  // allocates its result; a cross is twice the faces' bytes, with its black cells). Each timed
  // run frees its result before the next, for copies and conversions alike.
  volatile float sink = 0.0f;
  auto copyOf = [&](size_t floats) {
    const std::vector<float> source(floats, 1.0f);
    return best(5, [&] {
      std::vector<float> fresh(source);
      sink = sink + fresh[1];
    });
  };
  std::vector<float> target(strip.pixels.size());
  const double warm = best(5, [&] { std::memcpy(target.data(), strip.pixels.data(), bytes); });
  std::printf(
      "Layout conversions of a %dx%d cube (%.0f MB of faces), best of 5, against a copy of "
      "the output's bytes into a new buffer (%.1f ms for the faces' bytes into an existing "
      "one):\n",
      n, n, double(bytes) / 1e6, warm * 1e3);
  struct Case {
    const char* name;
    double seconds, copy;
  };
  std::vector<Case> cases;
  const Image hcross = cubemap::packFaces(cube, cubemap::Layout::HorizontalCross);
  const Image vcross = cubemap::packFaces(cube, cubemap::Layout::VerticalCross);
  const double faceCopy = copyOf(strip.pixels.size()), crossCopy = copyOf(hcross.pixels.size());
  auto pack = [&](cubemap::Layout layout) {
    return best(5, [&] {
      const Image r = cubemap::packFaces(cube, layout);
      sink = sink + r.pixels[1];
    });
  };
  auto unpack = [&](const Image& img, cubemap::Layout layout) {
    return best(5, [&] {
      const auto faces = cubemap::unpackFaces(img, layout);
      sink = sink + faces[0].pixels[1];
    });
  };
  cases.push_back({"six faces -> OpenEXR cube strip", pack(cubemap::Layout::Cube), faceCopy});
  cases.push_back({"cube strip -> six faces", unpack(strip, cubemap::Layout::Cube), faceCopy});
  cases.push_back(
      {"six faces -> horizontal cross", pack(cubemap::Layout::HorizontalCross), crossCopy});
  cases.push_back({"horizontal cross -> six faces",
                   unpack(hcross, cubemap::Layout::HorizontalCross), faceCopy});
  cases.push_back({"six faces -> vertical cross", pack(cubemap::Layout::VerticalCross), crossCopy});
  cases.push_back({"vertical cross -> six faces (one turned)",
                   unpack(vcross, cubemap::Layout::VerticalCross), faceCopy});
  double worst = 0.0;
  for (const Case& c : cases) {
    std::printf("  %-42s %7.1f ms   copy %6.1f ms   %.2f x copy\n", c.name, c.seconds * 1e3,
                c.copy * 1e3, c.seconds / c.copy);
    worst = std::max(worst, c.seconds / c.copy);
  }

  std::printf("  worst ratio to a copy: %.2f (target: within 3)\n", worst);

  // The area-exact resampling does real work per texel: its cost against a copy, for the record.
  std::printf("\nArea-exact resampling (closed-form overlaps per texel), %d threads:\n", threads);
  for (int width : quick ? std::vector<int>{1024} : std::vector<int>{1024, 4096}) {
    const lighting::Environment map = width == env.width() ? env : synthetic(width);
    const int faces = width / 4;
    lighting::CubeMap c;
    const double toCube = best(2, [&] { c = lighting::cubeFromLatLong(map, faces); });
    lighting::Environment back;
    const double toLatLong = best(2, [&] { back = lighting::latLongFromCube(c, width); });
    const size_t llBytes = size_t(width) * size_t(width / 2) * 3 * sizeof(float);
    std::vector<float> a(llBytes / sizeof(float), 1.0f), b(a.size());
    const double llCopy = best(5, [&] { std::memcpy(b.data(), a.data(), llBytes); });
    std::printf("  lat-long %dx%d -> cube %d^2   %8.1f ms   %6.0f x copy (%.2f ms)\n", width,
                width / 2, faces, toCube * 1e3, toCube / llCopy, llCopy * 1e3);
    std::printf("  cube %d^2 -> lat-long %dx%d   %8.1f ms   %6.0f x copy\n", faces, width,
                width / 2, toLatLong * 1e3, toLatLong / llCopy);
  }
  return 0;
}
