// The renderer: ray-casts a mesh with Embree from the plate camera and shades every hit as a
// diffuse surface lit by the environment, optionally with self-shadowing (transfer.h).
//
// Output is scene-linear RGBA in the working space, PREMULTIPLIED by coverage (alpha = fraction
// of the pixel's samples that hit the object), and arbitrary output variables (AOVs). Only the
// screen rectangle the object can cover is traced and stored: every image of RenderOutput is the
// size of that rectangle, whose top-left pixel on the plate is (x0, y0); everything outside it is
// transparent black. Anti-aliasing: n x n stratified samples per pixel (jittered, or at the
// strata's centres), box filter.
//
// Shading: a Lambertian surface of albedo ρ, outgoing radiance ρ E / π times the exposure, E the
// irradiance of the lighting (lighting.h) at the interpolated vertex normal. With self-shadowing,
// E is the unshadowed irradiance at the pixel's normal times the ratio of the shadowed to the
// unshadowed irradiance interpolated from the surface points around the hit, so that the
// per-pixel normal keeps its detail and the visibility comes from the transfer; a bright source
// whose shadow edge crosses the hit's triangle is traced from the hit (RenderSettings::sources).
// Negative irradiance (SH ringing) is clamped to 0. The shading normal faces the viewer: a back
// face is shaded from the side the camera sees, and an interpolated normal that points away from
// the viewer is bent back to the tangent plane. `envFromWorld` rotates world directions into the
// environment's frame.
//
// The mesh is traced in its own coordinates (one Embree scene serves the renderer and the
// visibility precompute); camera rays are carried into it by the inverse of `worldFromObject`.
//
// Threading: rows in parallel on oneTBB; the lighting and the scene are only read.
#pragma once

#include <string>
#include <vector>

#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>

#include "calib/plate_camera.h"
#include "core/image.h"
#include "core/progress.h"
#include "lighting/lighting.h"
#include "render/embree_scene.h"
#include "render/mesh.h"
#include "render/transfer.h"

namespace compose::render {

struct RenderSettings {
  int samplesPerAxis = 4;  // n x n samples per pixel
  bool jitter = true;      // jittered within each stratum; false: the strata's centres
  glm::vec3 albedo{0.5f};  // in the working space
  // Use `albedo` even where the mesh has materials (the pipeline sets it for --albedo).
  bool overrideMaterials = false;
  float exposure = 1.0f;  // linear multiplier on the object's radiance
  glm::mat3 envFromWorld{1.0f};
  // Self-shadowing (transfer.h): the surface points, their irradiance with and without it, and
  // their ambient occlusion (for the AO AOV); null: no shadowing, AO 1.
  const SurfacePoints* points = nullptr;
  const VertexIrradiance* shadows = nullptr;
  const std::vector<float>* occlusion = nullptr;
  // The bright sources the shadows split off (environment frame), whose visibility per point
  // `shadows` holds (null or empty: none). Where the three points around a hit see a source
  // differently, its shadow's edge crosses the triangle: that source is then traced from the hit
  // itself and shaded at the pixel's normal, and the rest of the light keeps the interpolated
  // ratio. So a lamp's or the sun's shadow keeps its edge at the pixel, not at the triangles'
  // scale; the extra rays go only where an edge passes.
  const std::vector<lighting::LightSource>* sources = nullptr;
  // Trace only the pixels a triangle's projection reaches (the others cannot be hit; the image
  // is the same). With a distorted or non-rectilinear lens, or the object partly behind the
  // camera, every pixel of the rectangle is traced.
  bool skipUncoveredPixels = true;
  // Adaptive sampling: the four corner samples of the n x n grid are traced first, and where they
  // find one smooth surface (no silhouette, occluding edge, gap, thinner part in front, change of
  // material, crease or fold anywhere in the pixel; no texture, cut-out or shadow edge of a bright
  // source, and nearly the same normal, self-shadowing and albedo at the four) they stand for all
  // n x n; every other pixel keeps them and gets the rest. Needs the pixels' nearest surfaces and
  // edges, hence a rectilinear lens without distortion and skipUncoveredPixels; off for
  // semi-transparent meshes, meshes of more triangles than the traced rectangle has pixels, and
  // n = 1 (docs/design.md, "Adaptive anti-aliasing").
  bool adaptive = true;
};

// The AOV channels, in order (Nuke's layer.channel names). All are the mean over the pixel's
// samples that hit the object (not premultiplied), 0 where none did:
//   N      world-space unit normal (+Y up)
//   P      world-space position (metres)
//   depth  distance in front of the camera along its axis (depth.Z, metres)
//   albedo diffuse albedo
//   irradiance        unshadowed irradiance E x exposure (so that the object layer is
//                     albedo x shadowed / π)
//   irradianceShadowed  the same with self-shadowing
//   AO     ambient occlusion, (1/π) ∫ V cos θ dω, V weighted by the ground beneath where the pass
//          had one (transfer.h's GroundContact); 1 without the visibility pass
const std::vector<std::string>& aovChannelNames();

struct RenderOutput {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // the traced rectangle [x0, x1) x [y0, y1) on the plate
  Image beauty;                        // RGBA, premultiplied, working space; (x1 - x0) x (y1 - y0)
  Image aovs;                          // aovChannelNames(); (x1 - x0) x (y1 - y0)
  int64_t rays = 0;                    // camera rays traced and rays to the bright sources
  double coverage = 0.0;               // sum of alpha
  int64_t pixelsTraced = 0;            // pixels whose rays were traced
  int64_t pixelsPlain = 0;             // of those, shaded from their four corner samples
};

RenderOutput renderDiffuse(const Mesh& mesh, const EmbreeScene& objectScene,
                           const glm::dmat4& worldFromObject, const calib::PlateCamera& camera,
                           const lighting::DiffuseLighting& lighting,
                           const RenderSettings& settings, const Progress& progress = {});

}  // namespace compose::render
