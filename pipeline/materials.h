// The object's material colours into the working space (part of the color stage).
//
// Base colours are linear, in the colour space Mesh::colorSpace names (linear Rec.709 from every
// loader: glTF's baseColorFactor and OBJ's Kd). When the config does not know that name, linear
// Rec.709 is converted by its primaries; when the config cannot say what its working space's
// primaries are either, the base colours are taken as they are, and the returned line says so.
// Each texture is taken to be in the colour space its image declares when the config knows it,
// else what the config's file rules say for its file (sRGB for 8-bit images with the built-in
// config), and converted; a texture keeps that name in its image, so a second call converts
// nothing twice.
#pragma once

#include <string>

#include "color/color.h"
#include "render/mesh.h"

namespace compose::pipeline {

// Converts the base colours and textures of `mesh` to colors.workingSpace() in place: when the
// config converts the base colours' space to the working space by a matrix (linear Rec.709 to
// ACEScg), the base and vertex colours stay, the textures are brought to their space, and the
// matrix goes to Mesh::albedoToWorking, so that factor x texture x vertex colour is multiplied
// where glTF defines it and then converted; otherwise each is converted on its own. Returns a
// line for the user that says what they were read as, or an empty string when the mesh has no
// materials. Throws compose::Error (stage "color") when a conversion fails.
std::string materialsToWorkingSpace(render::Mesh& mesh, const color::ColorConfig& colors);

}  // namespace compose::pipeline
