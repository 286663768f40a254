// The stage implementations, for the registry (registry.cpp).
#pragma once

#include <memory>

#include "pipeline/context.h"
#include "pipeline/stage.h"

namespace compose::pipeline {

std::unique_ptr<Stage> makeIngestStage();
std::unique_ptr<Stage> makeMergeStage();
std::unique_ptr<Stage> makeStitchStage();
std::unique_ptr<Stage> makeColorStage();
std::unique_ptr<Stage> makePrecomputeStage();
std::unique_ptr<Stage> makeShadowsStage();
std::unique_ptr<Stage> makeGroundStage();
std::unique_ptr<Stage> makeRenderStage();
std::unique_ptr<Stage> makeCompositeStage();
std::unique_ptr<Stage> makeOutputStage();

// Brings an input image (RGB first, other channels left alone) to the working space, the way the
// colour stage does, and says how it was read: an explicit colour space (`option`, e.g.
// --plate-space) wins; an OpenEXR file's chromaticities come next; then the space the file
// declares, else the config's file rules.
std::string toWorkingSpace(Image& image, const std::filesystem::path& file,
                           const ingest::CaptureInfo& info, const std::string& explicitSpace,
                           const std::string& option, const color::ColorConfig& colors);
// The colour space to assume for a file with this header (ColorConfig::inputSpace): what it
// declares, or its format's convention, else the config's rules, 8- and 16-bit images taken as
// sRGB-encoded where those make them linear.
color::InputSpace inputSpaceOf(const color::ColorConfig& colors, const std::filesystem::path& file,
                               const ingest::CaptureInfo& info);

// The camera and the placement in OpenEXR header attributes, so that another tool can rebuild
// the scene: worldToCamera and worldToNDC (OpenEXR's standard attributes; the pinhole part of a
// distorted lens, said in compose:lens), compose:worldFromObject (the mesh file's coordinates to
// world space) and compose:object (the mesh file).
// `fileOrigin` is the mesh's render::Mesh::fileOrigin.
ingest::ExrHeader sceneHeader(const Geometry& geometry, const std::string& meshFile,
                              const glm::dvec3& fileOrigin);

// Chooses the exposure of a render (RenderedObject::exposureChosen false) for the plate it is
// composited on: the one given in stops, else from EXIF where the plate and the environment's
// photos come from one camera, else by matching a mid-grey card on the ground to the plate's
// ground (the note printed says which); `pending` becomes it.
void chooseExposure(Context& ctx, RenderedObject& object);
// The environment's side of the exposure from EXIF, worked out from the environment (a capture
// description, or the files of a map), for a lighting file to carry.
EnvironmentExif environmentExif(const Context& ctx);

// Writes the outputs of a job: the multi-part OpenEXR (the composite, the object with its AOVs in
// its own data window, the ground shadow's ratio in its own) and the display image, together or
// not at all, the object's pending exposure applied on the way. Returns notes for the user.
// `floatSamples`: the EXR's parts in 32-bit float, else half (float where a value exceeds half).
// `holdout` (the mask, the plate's size): the object and shadow parts held out as the composite
// was, so that they give it again, and the mask's file named in the header.
std::vector<std::string> writeComposeFiles(
    const color::ColorConfig& colors, const ComposeJob& job, const Geometry& geometry,
    const Image& composite, const RenderedObject& object, const GroundShadowResult* ground,
    const std::filesystem::path& exrPath, const std::filesystem::path& displayPath,
    bool floatSamples = false, const Image* holdout = nullptr);

}  // namespace compose::pipeline
