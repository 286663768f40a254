// compose-bench-shadows: self-shadowing accuracy against a ray-traced reference, with its cost,
// for every transfer method, on real meshes in the sample environments (docs/design.md §10).
//
//   compose-bench-shadows [--out DIR] [--quick] [--pixels N] [--mesh bunny.obj] [--env forest]
//                         [--boundary R] [--points FRACTION] [--grid S] [--normal-grid RxC]
//                         [--source-rays 1|2|4]
//
// --grid sets s (the transfer's grid, and the largest k measured), --normal-grid the shadow
// lighting's grid of normals, --source-rays the rays per surface point and bright source (the
// renderer traces the sources again where the points around a hit disagree, as compose does).
//
// For each mesh (the Stanford bunny, Suzanne, the Newell teapot) the object is rendered alone at
// 480x360, one sample per pixel at the pixel's centre, so that every pixel is shaded at one point
// whose position and normal the P and N AOVs give. The reference at a pixel is the exact
// unshadowed irradiance at its normal minus a Monte Carlo estimate (environment and cosine
// sampling, MIS) of the light the object blocks there, with 32768 samples, its rays leaving from
// the hit lifted onto the smooth surface of the vertex normals as the renderer's do (Mesh::
// smoothPoint: without it a coarse mesh's facets shadow its terminator); a second reference
// with another seed says how converged it is. The object's pixels are compared with it: SNR and
// relative error over an even spread of fully covered pixels.
//
// Methods: no shadows; ambient occlusion x irradiance; SH transfer (Sloan et al. 2002) with 9,
// 16, 25, 49 and 81 coefficients; Chebyshev transfer with k = 1..16 on the 16x16 grid; both
// transfers with and without the 64 brightest sources split off and shadowed by rays; and Monte
// Carlo with visibility rays per pixel at several sample counts. Beside them, the default
// Chebyshev transfer computed at the reference pixels themselves instead of interpolated between
// surface points: what the points' spacing costs.
//
// Writes shadows.csv, shadows.md and one SVG plot per mesh (SNR against the floats stored per
// vertex) into DIR (default out/bench), and prints the tables.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <numbers>
#include <string>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/gtc/matrix_transform.hpp>

#include "bench_util.h"
#include "calib/plate_camera.h"
#include "ingest/image_io.h"
#include "lighting/chebyshev.h"
#include "lighting/exact.h"
#include "lighting/monte_carlo.h"
#include "lighting/sh.h"
#include "lighting/sources.h"
#include "pipeline/compose_job.h"
#include "render/embree_scene.h"
#include "render/mesh.h"
#include "render/renderer.h"
#include "render/transfer.h"
#include "svg_plot.h"

namespace {

using namespace compose;
namespace fs = std::filesystem;

struct Pixel {
  int x, y;
  glm::vec3 p, n;
  // Object space: the hit lifted onto the smooth surface of the vertex normals
  // (Mesh::smoothPoint), where the renderer's shadow rays leave from, and the reference's too.
  glm::vec3 origin{0.0f};
};

struct Row {
  std::string mesh, env, method;
  int order = 0;  // k, SH bands, or MC samples
  bool sources = false;
  double floatsPerVertex = 0;
  double lightingFloats = 0;
  double precomputeS = 0;  // projection of the lighting (the visibility pass is per mesh)
  double shadeS = 0;       // per-vertex shading + rendering the frame
  double snrDb = 0, relError = 0;
};

struct Measure {
  double snrDb, relError;
};

Measure compare(const std::vector<glm::dvec3>& got, const std::vector<glm::dvec3>& ref) {
  double s = 0, e = 0, rel = 0;
  for (size_t i = 0; i < ref.size(); ++i) {
    s += glm::dot(ref[i], ref[i]);
    const glm::dvec3 d = ref[i] - got[i];
    e += glm::dot(d, d);
    const double r1 = std::abs(ref[i].x) + std::abs(ref[i].y) + std::abs(ref[i].z);
    rel += (std::abs(d.x) + std::abs(d.y) + std::abs(d.z)) / std::max(r1, 1e-12);
  }
  return {10.0 * std::log10(s / e), rel / double(ref.size())};
}

std::string fmt(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  fs::path outDir = "out/bench";
  bool quick = false;
  int pixels = 1200;
  std::string onlyMesh, onlyEnv;
  int boundary = 2;
  float pointFraction = 1.0f / 96.0f;
  size_t pointBudget = 80000;
  render::RefineParams refine;
  int grid = 16;
  int sourceRays = 1;  // per point and source, as the pipeline traces them
  int normalRows = lighting::ChebParams{}.normalRows,
      normalCols = lighting::ChebParams{}.normalCols;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--out" && i + 1 < argc) {
      outDir = argv[++i];
    } else if (a == "--quick") {
      quick = true;
      pixels = 300;
    } else if (a == "--pixels" && i + 1 < argc) {
      pixels = std::atoi(argv[++i]);
    } else if (a == "--mesh" && i + 1 < argc) {
      onlyMesh = argv[++i];
    } else if (a == "--boundary" && i + 1 < argc) {
      boundary = std::atoi(argv[++i]);
    } else if (a == "--points" && i + 1 < argc) {
      pointFraction = float(std::atof(argv[++i]));
    } else if (a == "--refine" && i + 1 < argc) {
      refine.spread = float(std::atof(argv[++i]));
    } else if (a == "--refine-budget" && i + 1 < argc) {
      refine.budget = float(std::atof(argv[++i]));
    } else if (a == "--point-budget" && i + 1 < argc) {
      pointBudget = size_t(std::atoll(argv[++i]));
    } else if (a == "--source-rays" && i + 1 < argc) {
      sourceRays = std::atoi(argv[++i]);
    } else if (a == "--env" && i + 1 < argc) {
      onlyEnv = argv[++i];
    } else if (a == "--grid" && i + 1 < argc) {
      grid = std::atoi(argv[++i]);
    } else if (a == "--normal-grid" && i + 1 < argc) {
      if (std::sscanf(argv[++i], "%dx%d", &normalRows, &normalCols) != 2) return 2;
    } else {
      std::fprintf(stderr,
                   "usage: %s [--out DIR] [--quick] [--pixels N] [--mesh FILE] [--env NAME] "
                   "[--boundary R] [--points FRACTION] [--grid S] [--normal-grid RxC] "
                   "[--source-rays 1|2|4]\n",
                   argv[0]);
      return 2;
    }
  }
  fs::create_directories(outDir);
  const fs::path samples = pipeline::samplesDirectory();
  const int kReferenceSamples = quick ? 8192 : 32768;
  std::vector<Row> rows;
  std::vector<std::string> notes;

  const char* meshes[] = {"bunny.obj", "monkey.obj", "teapot.bez"};
  const char* envs[] = {"courtyard", "forest", "interior", "sunset"};
  for (const char* meshName : meshes) {
    if (!onlyMesh.empty() && onlyMesh != meshName) continue;
    const render::Mesh mesh = [&] {  // as the pipeline reads it: open pieces with back sides
      render::Mesh read = render::loadMesh(samples / meshName);
      render::addBackSides(read);
      return read;
    }();
    const render::EmbreeScene scene(mesh);
    const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
    const float size = std::max({extent.x, extent.y, extent.z});
    // The visibility pass once, at the largest order measured (lower orders are its top-left
    // moments) and with SH up to band 8.
    render::TransferParams tp;
    tp.grid = grid;
    tp.order = grid;
    tp.shBands = 8;
    tp.boundaryRays = boundary;
    const auto t0 = bench::Clock::now();
    render::SurfacePoints points = render::surfacePoints(mesh, pointFraction, pointBudget);
    const size_t basePoints = points.count();
    const render::VertexTransfer transfer =
        render::computeRefinedTransfer(mesh, points, tp, refine);
    const double transferS = bench::secondsSince(t0);
    notes.push_back(
        std::string(meshName) + ": " + std::to_string(mesh.positions.size()) + " vertices, " +
        std::to_string(mesh.triangleCount()) + " triangles, " + std::to_string(basePoints) +
        " surface points (" + std::to_string(points.count() - basePoints) + " more where " +
        refine.key() + "); visibility pass " + fmt("%.2f", transferS) + " s, " +
        std::to_string(transfer.rays) + " rays (" +
        fmt("%.0f", double(transfer.rays) / double(points.count())) + " per point, 2 cores)");
    std::printf("%s\n", notes.back().c_str());

    // The object alone, large in a 480x360 frame, turned 30 degrees.
    const calib::PlateCamera camera = calib::plateCamera(480, 360, {}, {});
    calib::Placement place;
    place.imagePoint = {0.5, 0.85};
    place.heightFraction = 0.7;
    place.yawDegrees = 30.0;
    const glm::dmat4 worldFromObject = calib::placeOnGround(
        camera, place, glm::dvec3(mesh.boundsMin()), glm::dvec3(mesh.boundsMax()));
    glm::mat3 envFromObject = glm::mat3(worldFromObject);
    for (int c = 0; c < 3; ++c) envFromObject[c] = glm::normalize(envFromObject[c]);

    for (const char* envName : envs) {
      if (!onlyEnv.empty() && onlyEnv != envName) continue;
      Image img = ingest::readImage(samples / (std::string(envName) + ".exr")).image;
      const lighting::Environment env = lighting::Environment::fromLatLong(img);
      lighting::ExactLighting exact;
      exact.project(env);
      auto unshadowedLighting = lighting::createLighting("cheb-local");
      unshadowedLighting->project(env);
      render::RenderSettings settings;
      settings.samplesPerAxis = 1;
      settings.jitter = false;
      settings.albedo = glm::vec3(1.0f);
      settings.exposure = float(std::numbers::pi);  // the object layer is then E itself
      const lighting::SourceSplit split = lighting::splitBrightSources(env, 64);
      auto renderWith = [&](const lighting::DiffuseLighting& lighting,
                            const render::VertexIrradiance* shadows) {
        render::RenderSettings s = settings;
        s.points = &points;
        s.shadows = shadows;
        s.sources = &split.sources;
        return render::renderDiffuse(mesh, scene, worldFromObject, camera, lighting, s);
      };
      // The pixels: an even spread of fully covered ones, with their points and normals.
      const render::RenderOutput plain = renderWith(*unshadowedLighting, nullptr);
      std::vector<Pixel> all;
      for (int y = 0; y < plain.beauty.height; ++y)
        for (int x = 0; x < plain.beauty.width; ++x) {
          if (plain.beauty.at(x, y)[3] < 1.0f) continue;
          const float* a = plain.aovs.at(x, y);
          all.push_back({x, y, glm::vec3(a[3], a[4], a[5]), glm::vec3(a[0], a[1], a[2])});
        }
      std::vector<Pixel> px;
      const size_t step = std::max<size_t>(1, all.size() / size_t(pixels));
      for (size_t i = 0; i < all.size(); i += step) px.push_back(all[i]);
      // Each pixel's triangle, found again along its camera ray, for its smooth point.
      const glm::dmat4 objectFromWorld = glm::inverse(worldFromObject);
      const glm::vec3 eye(objectFromWorld * glm::dvec4(camera.position(), 1.0));
      for (Pixel& p : px) {
        const glm::vec3 pObj = glm::vec3(objectFromWorld * glm::dvec4(glm::dvec3(p.p), 1.0));
        const glm::vec3 dir = glm::normalize(pObj - eye);
        const render::EmbreeScene::Hit hit = scene.intersect(eye, dir);
        p.origin = hit.found ? mesh.smoothPoint(hit.triangle, hit.u, hit.v, pObj,
                                                glm::dot(hit.geometricNormal, dir) > 0.0f)
                             : pObj;
      }

      // References: exact unshadowed minus the MC estimate of the blocked light, twice.
      const glm::mat3 objectFromEnv = glm::transpose(envFromObject);
      auto reference = [&](uint64_t seed, std::vector<glm::dvec3>& out,
                           std::vector<glm::dvec3>* unshadowed) {
        lighting::MonteCarloLighting mc(1, seed);
        mc.project(env);
        out.resize(px.size());
        if (unshadowed) unshadowed->resize(px.size());
        for (size_t i = 0; i < px.size(); ++i) {
          const glm::vec3 n = glm::normalize(px[i].n);  // world = environment frame here
          const glm::vec3 nObj = glm::normalize(objectFromEnv * n);
          const glm::vec3 origin = px[i].origin + 1e-4f * size * nObj;
          const lighting::MonteCarloLighting::VisibilityFn blocked = [&](const glm::vec3& d) {
            return scene.occluded(origin, objectFromEnv * d, 1e-5f * size);
          };
          const glm::dvec3 e(exact.irradiance(n));
          out[i] = e - glm::dvec3(mc.estimate(n, kReferenceSamples, &blocked));
          if (unshadowed) (*unshadowed)[i] = e;
        }
      };
      const auto r0 = bench::Clock::now();
      std::vector<glm::dvec3> ref, ref2, refUnshadowed;
      reference(11, ref, &refUnshadowed);
      const double referenceS = bench::secondsSince(r0);
      reference(12, ref2, nullptr);
      const Measure converged = compare(ref2, ref);
      const Measure lightingOnly = [&] {
        std::vector<glm::dvec3> got;
        for (const Pixel& p : px) {
          const float* b = plain.beauty.at(p.x, p.y);
          got.emplace_back(b[0], b[1], b[2]);
        }
        return compare(got, refUnshadowed);
      }();
      // The same comparison without the renderer: at the pixels' own normals, and over normals
      // spread uniformly on the sphere (what the lighting benchmark measures). The first must
      // match the image-space figure; the second differs by how the mesh's visible normals are
      // distributed.
      auto direct = [&](const std::vector<glm::vec3>& normals) {
        std::vector<glm::dvec3> got, want;
        for (const glm::vec3& n : normals) {
          got.emplace_back(unshadowedLighting->irradiance(n));
          want.emplace_back(exact.irradiance(n));
        }
        return compare(got, want);
      };
      std::vector<glm::vec3> pixelNormals, sphereNormals;
      for (const Pixel& p : px) pixelNormals.push_back(glm::normalize(p.n));
      constexpr int kSphere = 16384;  // a Fibonacci lattice: equal areas
      for (int i = 0; i < kSphere; ++i) {
        const double y = 1.0 - (2.0 * i + 1.0) / kSphere, r = std::sqrt(1.0 - y * y);
        const double phi = i * std::numbers::pi * (3.0 - std::sqrt(5.0));
        sphereNormals.emplace_back(r * std::cos(phi), y, r * std::sin(phi));
      }
      // And over the normals of a sphere standing where the object stands, as this camera sees
      // it: the hemisphere facing the camera, each normal weighted by the area it covers in the
      // image (a Fibonacci lattice on the sphere's disc, seen from afar).
      std::vector<glm::vec3> seenSphereNormals;
      {
        const glm::dvec3 centre = glm::dvec3(
            worldFromObject *
            glm::dvec4(0.5 * (glm::dvec3(mesh.boundsMin()) + glm::dvec3(mesh.boundsMax())), 1.0));
        const glm::dvec3 toCamera = glm::normalize(camera.position() - centre);
        const glm::dvec3 right = glm::normalize(glm::cross(glm::dvec3(0.0, 1.0, 0.0), toCamera));
        const glm::dvec3 up = glm::cross(toCamera, right);
        for (int i = 0; i < kSphere; ++i) {
          const double r = std::sqrt((i + 0.5) / kSphere);
          const double phi = i * std::numbers::pi * (3.0 - std::sqrt(5.0));
          const double x = r * std::cos(phi), y = r * std::sin(phi);
          seenSphereNormals.emplace_back(glm::normalize(
              x * right + y * up + std::sqrt(std::max(0.0, 1.0 - r * r)) * toCamera));
        }
      }
      const Measure atPixelNormals = direct(pixelNormals), overSphere = direct(sphereNormals);
      const Measure overSeenSphere = direct(seenSphereNormals);
      char line[600];
      std::snprintf(line, sizeof line,
                    "%s / %s: %zu pixels; reference %d samples in %.1f s, two seeds agree to "
                    "%.1f dB; unshadowed cheb-local vs exact unshadowed %.1f dB (image space), "
                    "%.1f dB evaluated at the same normals without rendering, %.1f dB over the "
                    "sphere's normals, %.1f dB over a sphere's normals as this camera sees them",
                    meshName, envName, px.size(), kReferenceSamples, referenceS, converged.snrDb,
                    lightingOnly.snrDb, atPixelNormals.snrDb, overSphere.snrDb,
                    overSeenSphere.snrDb);
      notes.push_back(line);
      std::printf("%s\n", line);

      auto measure = [&](const render::RenderOutput& out) {
        std::vector<glm::dvec3> got;
        for (const Pixel& p : px) {
          const float* b = out.beauty.at(p.x, p.y);
          got.emplace_back(b[0], b[1], b[2]);
        }
        return compare(got, ref);
      };
      auto add = [&](const std::string& method, int order, bool sources, double floatsPerVertex,
                     double lightingFloats, double precomputeS, double shadeS, Measure m) {
        rows.push_back({meshName, envName, method, order, sources, floatsPerVertex, lightingFloats,
                        precomputeS, shadeS, m.snrDb, m.relError});
        std::printf("  %-8s %-10s order %5d %s  %7.1f floats/vertex  %6.1f dB  %6.2f %%\n", envName,
                    method.c_str(), order, sources ? "+sources" : "        ", floatsPerVertex,
                    m.snrDb, 100.0 * m.relError);
      };
      add("none", 0, false, 0, double(unshadowedLighting->floatsStored()), 0, 0, measure(plain));

      render::SourceVisibility seen =
          render::traceSources(points, scene, split.sources, envFromObject, sourceRays);
      // As the pipeline does: a source traced again across its penumbra.
      if (sourceRays == 1)
        render::refineSourcePenumbrae(mesh, points, scene, split.sources, envFromObject, seen);
      for (const bool withSources : {false, true}) {
        const lighting::Environment& shadowEnv = withSources ? split.residual : env;
        render::ShadowInputs in;
        in.transfer = &transfer;
        if (withSources) {
          in.sources = split.sources;
          in.sourceVisibility = &seen;
        }
        auto run = [&](const std::string& method, int order,
                       std::unique_ptr<lighting::DiffuseLighting> lighting, render::ShadowMethod m,
                       double floatsPerVertex) {
          const auto p0 = bench::Clock::now();
          lighting->project(shadowEnv);
          const double projectS = bench::secondsSince(p0);
          in.method = m;
          in.shadowLighting = lighting.get();
          const auto s0 = bench::Clock::now();
          const render::VertexIrradiance vi = render::shadeVertices(points, envFromObject, in);
          const render::RenderOutput out = renderWith(*unshadowedLighting, &vi);
          if (std::getenv("COMPOSE_BENCH_WORST") && method == "cheb" && order == 16 &&
              withSources) {
            std::vector<std::pair<double, size_t>> err;
            for (size_t i = 0; i < px.size(); ++i) {
              const float* b = out.beauty.at(px[i].x, px[i].y);
              const glm::dvec3 g(b[0], b[1], b[2]);
              err.push_back({glm::length(g - ref[i]), i});
            }
            std::sort(err.rbegin(), err.rend());
            for (int q = 0; q < 8; ++q) {
              const size_t i = err[size_t(q)].second;
              const float* b = out.beauty.at(px[i].x, px[i].y);
              const float* un = plain.beauty.at(px[i].x, px[i].y);
              std::printf(
                  "    worst %d: pixel (%d, %d) ref %.4f got %.4f unshadowed %.4f n (%.2f %.2f "
                  "%.2f)\n",
                  q, px[i].x + plain.x0, px[i].y + plain.y0, ref[i].y, double(b[1]), double(un[1]),
                  double(px[i].n.x), double(px[i].n.y), double(px[i].n.z));
            }
          }
          add(method, order, withSources, floatsPerVertex + (withSources ? 1.0 : 0.0),
              double(lighting->floatsStored()), projectS, bench::secondsSince(s0), measure(out));
        };
        if (!withSources) {
          run("ao", 1, lighting::createLighting("cheb-local"),
              render::ShadowMethod::AmbientOcclusion, 1);
        }
        for (int bands : {2, 3, 4, 6, 8})
          run("sh", bands, std::make_unique<lighting::ShLighting>(bands),
              render::ShadowMethod::Harmonics, lighting::shCount(bands));
        for (int k : {1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 16, 24, 32}) {
          if (k > grid || (quick && (k == 2 || k == 10))) continue;
          lighting::ChebParams cp;
          cp.order = k;
          cp.samples = grid;
          cp.normalRows = normalRows;
          cp.normalCols = normalCols;
          run("cheb", k, std::make_unique<lighting::ChebLocalLighting>(cp),
              render::ShadowMethod::Chebyshev, k * k);
        }
      }
      {
        // The same Chebyshev transfer (k = s, with sources) computed at the reference pixels
        // themselves rather than interpolated between surface points: what the surface points'
        // spacing costs.
        render::SurfacePoints at;
        at.size = points.size;
        at.centre = points.centre;
        at.radius = points.radius;
        for (const Pixel& p : px) {
          at.positions.push_back(p.origin);
          at.normals.push_back(glm::normalize(objectFromEnv * glm::normalize(p.n)));
        }
        render::TransferParams tq = tp;
        tq.shBands = 0;
        const render::VertexTransfer tr = render::computeTransfer(mesh, at, tq);
        const render::SourceVisibility sv =
            render::traceSources(at, scene, split.sources, envFromObject);
        lighting::ChebParams cp;
        cp.order = grid;
        cp.samples = grid;
        cp.normalRows = normalRows;
        cp.normalCols = normalCols;
        lighting::ChebLocalLighting cl(cp);
        cl.project(split.residual);
        render::ShadowInputs in;
        in.transfer = &tr;
        in.sources = split.sources;
        in.sourceVisibility = &sv;
        in.shadowLighting = &cl;
        const render::VertexIrradiance vi = render::shadeVertices(at, envFromObject, in);
        std::vector<glm::dvec3> got(vi.shadowed.begin(), vi.shadowed.end());
        const Measure m = compare(got, ref);
        char note[200];
        std::snprintf(note, sizeof note,
                      "%s / %s: Chebyshev k=%d + 64 sources computed at the pixels themselves "
                      "(no interpolation between surface points): %.1f dB",
                      meshName, envName, grid, m.snrDb);
        notes.push_back(note);
        std::printf("%s\n", note);
      }
      // Monte Carlo with visibility rays at each pixel (measured on the reference pixels).
      for (int n : {16, 64, 256, 1024}) {
        lighting::MonteCarloLighting mc(n, 99);
        mc.project(env);
        std::vector<glm::dvec3> got(px.size());
        const auto m0 = bench::Clock::now();
        for (size_t i = 0; i < px.size(); ++i) {
          const glm::vec3 nw = glm::normalize(px[i].n);
          const glm::vec3 origin = px[i].origin + 1e-4f * size * glm::normalize(objectFromEnv * nw);
          const lighting::MonteCarloLighting::VisibilityFn visible = [&](const glm::vec3& d) {
            return !scene.occluded(origin, objectFromEnv * d, 1e-5f * size);
          };
          got[i] = glm::dvec3(mc.irradiance(nw, visible));
        }
        // Time scaled to the whole frame's covered pixels.
        const double frameS = bench::secondsSince(m0) * double(all.size()) / double(px.size());
        add("mc", n, false, 0, double(mc.floatsStored()), 0, frameS, compare(got, ref));
      }
    }
  }

  // --- outputs ---------------------------------------------------------------------------------
  {
    std::ofstream csv(outDir / "shadows.csv");
    csv << "mesh,env,method,order,sources,floats_per_vertex,lighting_floats,projection_s,"
           "shade_render_s,snr_db,rel_error\n";
    for (const Row& r : rows) {
      csv << r.mesh << ',' << r.env << ',' << r.method << ',' << r.order << ','
          << (r.sources ? 64 : 0) << ',' << r.floatsPerVertex << ',' << r.lightingFloats << ','
          << r.precomputeS << ',' << r.shadeS << ',' << r.snrDb << ',' << r.relError << '\n';
    }
  }
  std::ofstream md(outDir / "shadows.md");
  md << "# Self-shadowing: accuracy against a ray-traced reference\n\n"
        "Produced by `compose-bench-shadows`"
     << (quick ? " --quick" : "")
     << ". Object pixels (480x360, one sample per pixel at its centre) against the exact "
        "unshadowed irradiance minus a Monte Carlo estimate of the light the object blocks. "
        "SNR in dB (relative error in %).\n\n";
  for (const std::string& n : notes) md << "- " << n << "\n";
  md << "\n";
  for (const char* meshName : meshes) {
    md << "## " << meshName
       << "\n\n| method | floats/vertex | courtyard | forest | interior | "
          "sunset |\n|---|---|---|---|---|---|\n";
    std::map<std::string, std::map<std::string, const Row*>> table;
    std::vector<std::string> order;
    for (const Row& r : rows) {
      if (r.mesh != meshName) continue;
      std::string label = r.method == "none" ? "no shadows"
                          : r.method == "ao" ? "AO x irradiance"
                          : r.method == "mc" ? "MC " + std::to_string(r.order) + " samples/pixel"
                          : r.method == "sh"
                              ? "SH " + std::to_string(lighting::shCount(r.order)) + " coefficients"
                              : "Chebyshev k=" + std::to_string(r.order);
      if (r.sources) label += " + 64 sources";
      if (!table.count(label)) order.push_back(label);
      table[label][r.env] = &r;
    }
    for (const std::string& label : order) {
      const Row* any = table[label].begin()->second;
      md << "| " << label << " | " << fmt("%.0f", any->floatsPerVertex);
      for (const char* env : envs) {
        const auto it = table[label].find(env);
        md << " | "
           << (it == table[label].end() ? std::string("–")
                                        : fmt("%.1f", it->second->snrDb) + " (" +
                                              fmt("%.2f", 100.0 * it->second->relError) + " %)");
      }
      md << " |\n";
    }
    md << "\n";

    bench::Chart chart;
    chart.title = std::string("Self-shadowing on ") + meshName + " (mean over the four HDRIs)";
    chart.xLabel = "floats stored per vertex";
    chart.yLabel = "SNR against the ray-traced reference (dB)";
    chart.logX = true;
    for (const auto& [method, sources, label] :
         std::vector<std::tuple<std::string, bool, std::string>>{
             {"cheb", false, "Chebyshev transfer"},
             {"cheb", true, "Chebyshev transfer + 64 sources"},
             {"sh", false, "SH transfer"},
             {"sh", true, "SH transfer + 64 sources"},
             {"ao", false, "AO x irradiance"}}) {
      bench::Series s;
      s.label = label;
      std::map<int, std::pair<double, int>> byOrder;
      std::map<int, double> floats;
      for (const Row& r : rows) {
        if (r.mesh != meshName || r.method != method || r.sources != sources) continue;
        byOrder[r.order].first += r.snrDb;
        byOrder[r.order].second += 1;
        floats[r.order] = r.floatsPerVertex;
      }
      for (const auto& [o, v] : byOrder) {
        s.x.push_back(floats[o]);
        s.y.push_back(v.first / v.second);
      }
      chart.series.push_back(s);
    }
    chart.hLines.push_back({40.0, "40 dB"});
    std::string stem = meshName;
    stem = stem.substr(0, stem.find('.'));
    bench::writeSvg(chart, outDir / ("shadows_" + stem + ".svg"));
  }
  md << "Peak resident memory of the benchmark: " << fmt("%.0f", bench::peakResidentMb())
     << " MB.\n";
  std::printf("peak resident memory %.0f MB; wrote %s\n", bench::peakResidentMb(),
              (outDir / "shadows.md").c_str());
  return 0;
}
