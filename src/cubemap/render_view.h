// Photos of an environment: what a camera at the centre of a distant environment records, through
// one of the project's lenses (calib/lens.h). Used to make stitching inputs with a known ground
// truth, and available to any stage that needs a virtual photo of an environment.
//
// Each pixel is the mean radiance over s x s sub-pixel rays (stratified, at sub-pixel centres), as
// a sensor integrates the scene over its pixels. The environment is read as what it is, constant
// over each texel: a sub-pixel smaller than a texel takes the texel its ray hits, a larger one the
// prefiltered mean over its footprint (lighting/filtered_cube.h), so a wide-angle view of a
// high-resolution map does not alias. Rays the lens cannot form (beyond a fisheye's 180°) give 0.
// Values are radiance, linear, in the environment's colour space; the image is RGB float.
#pragma once

#include <glm/mat3x3.hpp>

#include "calib/lens.h"
#include "core/image.h"
#include "core/progress.h"
#include "lighting/filtered_cube.h"

namespace compose::cubemap {

// Rotation of a camera that looks along -Z with +Y up (the photographer's convention) after
// turning it by `yaw` about +Y (positive turns left, towards -X), then tilting by `pitch` (positive
// up, towards +Y), then rolling by `roll` about its own axis (positive turns the picture
// counter-clockwise): worldFromCamera = Ry(yaw) Rx(pitch) Rz(roll). Degrees.
glm::dmat3 cameraRotation(double yawDegrees, double pitchDegrees, double rollDegrees = 0.0);

// The rotation of the camera that photographs cube face `face` as the photographer's convention
// has it (lighting/cubemap.h): side views upright, up and down views tilted from the -Z view.
glm::dmat3 faceCameraRotation(int face);

Image renderView(const lighting::FilteredCube& environment, const calib::Lens& lens,
                 const glm::dmat3& worldFromCamera, int supersample = 3,
                 const Progress& progress = {});

}  // namespace compose::cubemap
