// The renderer: ray-casts a mesh with Embree from the plate camera and shades every hit with a
// diffuse lighting representation.
//
// Output is scene-linear RGBA in the working space, PREMULTIPLIED by coverage (alpha = fraction
// of the pixel's samples that hit the object), the size of the plate. Anti-aliasing: n x n
// stratified, jittered samples per pixel, box filter. Only the screen rectangle the object's
// bounding box projects to is traced; the rest is transparent black.
//
// Shading: a Lambertian surface of albedo ρ, outgoing radiance ρ E(n) / π with E the irradiance
// from the lighting (lighting.h). Negative irradiance (SH ringing) is clamped to 0. The normal is
// the interpolated vertex normal; `envFromWorld` rotates world normals into the environment's
// frame (turning the environment about +Y).
//
// Threading: rows in parallel on oneTBB; the lighting is only read.
#pragma once

#include <glm/mat3x3.hpp>
#include <glm/mat4x4.hpp>
#include <glm/vec3.hpp>

#include "calib/plate_camera.h"
#include "core/image.h"
#include "core/progress.h"
#include "lighting/lighting.h"
#include "render/mesh.h"

namespace compose::render {

struct RenderSettings {
  int samplesPerAxis = 4;  // n x n samples per pixel
  glm::vec3 albedo{0.8f};  // in the working space
  float exposure = 1.0f;   // linear multiplier on the object's radiance
  glm::mat3 envFromWorld{1.0f};
};

struct RenderOutput {
  Image beauty;   // RGBA, premultiplied, working space
  Image normals;  // N.X N.Y N.Z: world-space unit normal (mean over the pixel's hits), 0 off the
                  // object
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // traced rectangle [x0, x1) x [y0, y1)
  int64_t rays = 0;
};

RenderOutput renderDiffuse(const Mesh& mesh, const glm::dmat4& worldFromObject,
                           const calib::PinholeCamera& camera,
                           const lighting::DiffuseLighting& lighting,
                           const RenderSettings& settings, const Progress& progress = {});

}  // namespace compose::render
