// compose-bench-ground: the object's shadow on the ground, as compose computes it (points on a
// grid of plate pixels, interpolated between them), against the ratio computed at every pixel's
// own ground point, with its cost.
//
//   compose-bench-ground [--mesh bunny.obj] [--env forest] [--step N] [--size WxH]
//                        [--place X,Y] [--scale H] [--repeat N]
//
// For each mesh (the Stanford bunny, Suzanne) in each sample environment, the object stands where
// `compose` puts it by default (0.5, 0.72 of a 1920x1080 plate, 0.3 of its height, the default
// camera). The ground pass is timed (median of --repeat runs, 3 by default, after one to warm up)
// and its points counted. The reference is the ratio E_with / E_without at the ground point of
// every --step-th pixel (2 by default) of the pass's rectangle that shows the ground (the
// object does not hide it), computed the same way (the same
// visibility pass and the same rays per bright source) at that point alone: the difference is
// what sampling the ground on a grid costs. Printed per case: mean, 99th percentile and largest
// |ratio - reference| over every channel of those pixels, and the mean over the pixels the
// reference shades by more than 2 %.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/matrix.hpp>

#include "bench_util.h"
#include "calib/plate_camera.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"
#include "pipeline/compose_job.h"
#include "pipeline/shadows.h"
#include "render/embree_scene.h"
#include "render/ground.h"
#include "render/mesh.h"
#include "render/transfer.h"

namespace {

using namespace compose;
namespace fs = std::filesystem;

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  std::string onlyMesh, onlyEnv;
  int step = 2, repeat = 3, width = 1920, height = 1080;
  glm::dvec2 at(0.5, 0.72);
  double scale = 0.3;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--mesh" && i + 1 < argc) {
      onlyMesh = argv[++i];
    } else if (a == "--env" && i + 1 < argc) {
      onlyEnv = argv[++i];
    } else if (a == "--step" && i + 1 < argc) {
      step = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--size" && i + 1 < argc) {
      if (std::sscanf(argv[++i], "%dx%d", &width, &height) != 2 || width < 16 || height < 16) {
        std::fprintf(stderr, "--size takes WxH\n");
        return 2;
      }
    } else if (a == "--place" && i + 1 < argc) {
      if (std::sscanf(argv[++i], "%lf,%lf", &at.x, &at.y) != 2) {
        std::fprintf(stderr, "--place takes X,Y\n");
        return 2;
      }
    } else if (a == "--scale" && i + 1 < argc) {
      scale = std::atof(argv[++i]);
    } else {
      std::fprintf(stderr,
                   "usage: %s [--mesh FILE] [--env NAME] [--step N] [--size WxH] [--place X,Y] "
                   "[--scale H] [--repeat N]\n",
                   argv[0]);
      return 2;
    }
  }
  const fs::path samples = pipeline::samplesDirectory();
  const pipeline::ShadowPlan plan = pipeline::ShadowPlan::parse("");
  render::TransferParams params = plan.transfer;
  params.shBands = 0;

  std::printf(
      "%dx%d plate, object at %.2f,%.2f, %.2f of the plate high; reference every %d "
      "pixels\n\n",
      width, height, at.x, at.y, scale, step);
  std::printf(
      "| mesh | HDRI | points | rays | time (s) | mean err | 99th pct | max err | mean err "
      "where shaded > 2 %% |\n|---|---|---|---|---|---|---|---|---|\n");
  const char* meshes[] = {"bunny.obj", "monkey.obj"};
  const char* envs[] = {"courtyard", "forest", "interior", "sunset"};
  for (const char* meshName : meshes) {
    if (!onlyMesh.empty() && onlyMesh != meshName) continue;
    const render::Mesh mesh = [&] {  // as the pipeline reads it: open pieces with back sides
      render::Mesh read = render::loadMesh(samples / meshName);
      render::addBackSides(read);
      return read;
    }();
    const render::EmbreeScene scene(mesh);
    const calib::PlateCamera camera = calib::plateCamera(width, height, {}, {});
    calib::Placement place;
    place.imagePoint = at;
    place.heightFraction = scale;
    const glm::dmat4 worldFromObject = calib::placeOnGround(
        camera, place, glm::dvec3(mesh.boundsMin()), glm::dvec3(mesh.boundsMax()));
    glm::mat3 envFromObject = glm::mat3(worldFromObject);
    for (int c = 0; c < 3; ++c) envFromObject[c] = glm::normalize(envFromObject[c]);
    const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
    const glm::mat3 envFromWorld(1.0f);

    for (const char* envName : envs) {
      if (!onlyEnv.empty() && onlyEnv != envName) continue;
      Image img = ingest::readImage(samples / (std::string(envName) + ".exr")).image;
      const lighting::Environment env = lighting::Environment::fromLatLong(img);
      const pipeline::ShadowLighting lighting = pipeline::prepareShadowLighting(env, plan, {});

      pipeline::GroundShadowResult ground;
      std::vector<double> times;
      for (int r = 0; r <= repeat; ++r) {
        const auto t0 = bench::Clock::now();
        ground = pipeline::computeGroundShadow(mesh, scene, worldFromObject, camera, lighting,
                                               envFromWorld, envFromObject, plan);
        if (r > 0) times.push_back(bench::secondsSince(t0));
      }
      if (ground.ratio.empty()) {
        std::printf("| %s | %s | no ground in view | | | | | | |\n", meshName, envName);
        continue;
      }
      // The reference: every step-th pixel's own ground point.
      const render::GroundGrid& grid = ground.grid;
      render::SurfacePoints exact;
      const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
      exact.size = std::max({extent.x, extent.y, extent.z});
      exact.centre = 0.5f * (mesh.boundsMin() + mesh.boundsMax());
      exact.radius = 0.5f * glm::length(extent);
      std::vector<glm::ivec2> pixels;
      for (int y = 0; y < ground.ratio.height; y += step) {
        for (int x = 0; x < ground.ratio.width; x += step) {
          glm::dvec3 origin, dir;
          if (!camera.ray(grid.x0 + x + 0.5, grid.y0 + y + 0.5, origin, dir) || !(dir.y < -1e-9))
            continue;
          const glm::dvec3 g = origin + dir * (-origin.y / dir.y);
          if (g.x < grid.regionX0 || g.x > grid.regionX1 || g.z < grid.regionZ0 ||
              g.z > grid.regionZ1)
            continue;
          // Pixels that show the object, not the ground, are left out.
          const glm::dvec3 o = glm::dvec3(objectFromWorld * glm::dvec4(origin, 1.0));
          const glm::dvec3 d = glm::dvec3(objectFromWorld * glm::dvec4(dir, 0.0));
          if (scene.occluded(glm::vec3(o), glm::vec3(glm::normalize(d)))) continue;
          exact.positions.push_back(glm::vec3(glm::dvec3(objectFromWorld * glm::dvec4(g, 1.0))));
          exact.normals.emplace_back(0.0f, 1.0f, 0.0f);
          pixels.emplace_back(x, y);
        }
      }
      const render::VertexTransfer transfer = render::computeTransfer(mesh, scene, exact, params);
      const render::SourceVisibility seen =
          render::traceSources(exact, scene, lighting.split.sources, envFromObject, 4);
      render::ShadowInputs in;
      in.transfer = &transfer;
      in.shadowLighting = lighting.lighting.get();
      in.sources = lighting.split.sources;
      in.sourceVisibility = &seen;
      const render::VertexIrradiance truth = render::shadeVertices(exact, envFromObject, in);
      std::vector<double> errors;
      double shadedSum = 0.0;
      size_t shadedCount = 0;
      for (size_t k = 0; k < pixels.size(); ++k) {
        const float* got = ground.ratio.at(pixels[k].x, pixels[k].y);
        double worstChannel = 0.0;
        bool shaded = false;
        for (int c = 0; c < 3; ++c) {
          const float un = truth.unshadowed[k][c], sh = truth.shadowed[k][c];
          const double ref = un > 1e-20f ? std::clamp(sh / un, 0.0f, 1.0f) : 1.0;
          const double e = std::abs(double(got[c]) - ref);
          errors.push_back(e);
          worstChannel = std::max(worstChannel, e);
          shaded = shaded || ref < 0.98;
        }
        if (shaded) shadedSum += worstChannel, ++shadedCount;
      }
      double mean = 0.0;
      for (const double e : errors) mean += e;
      mean /= double(std::max<size_t>(1, errors.size()));
      std::sort(errors.begin(), errors.end());
      const double p99 = errors.empty() ? 0.0 : errors[errors.size() * 99 / 100];
      const double worst = errors.empty() ? 0.0 : errors.back();
      std::printf("| %s | %s | %lld | %.2f M | %.3f | %.4f | %.4f | %.3f | %.4f (%zu px) |\n",
                  meshName, envName, static_cast<long long>(ground.points),
                  double(ground.rays) * 1e-6, median(times), mean, p99, worst,
                  shadedCount ? shadedSum / double(shadedCount) : 0.0, shadedCount);
      std::fflush(stdout);
    }
  }
  std::printf("\n(ground pass: %s)\n", "median time of the runs; 2 cores");
  return 0;
}
