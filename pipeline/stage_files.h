// The files the stage-by-stage commands hand each other, so that chaining them by hand gives the
// one-shot command's result:
//
//   compose precompute --env E --out lighting.stage     the projected lighting (and the sources
//                                                       and residual the shadows use), in the
//                                                       stage cache's format (stage_cache.h)
//   compose render --lighting lighting.stage ... --out object.exr
//                                                       the object's layer: a float multi-part
//                                                       OpenEXR (the object with its AOVs, the
//                                                       ground shadow's ratio) whose header
//                                                       carries the camera and placement
//   compose composite --plate P --layer object.exr --out BASE
//
// Each save function writes from a run's context (RunRequest::finish); each input function
// returns the StageInput that reads the file back into a later run.
#pragma once

#include <filesystem>

#include "pipeline/compose_job.h"
#include "pipeline/context.h"

namespace compose::pipeline {

// Writes the precompute stage's outputs (lighting, and shadow lighting if the run made it) with
// the parameters they were made with. Throws compose::Error naming the file if it cannot.
void savePrecompute(Context& ctx, const std::filesystem::path& file);

// Reads a file savePrecompute() wrote: sets the job's lighting basis and parameters (and shadow
// parameters) to those the file was made with, and returns the input that restores the outputs.
// Throws compose::Error naming the file when it is not one.
StageInput precomputeInput(const std::filesystem::path& file, ComposeJob& job);

// Writes the object's layer of a run (render and ground): a float OpenEXR with the display window
// of the plate, part "object" (R, G, B, A premultiplied, then the AOVs) in the traced rectangle,
// part "shadow" (the ground shadow's ratio) where the shadow falls, and the camera, placement and
// exposure in the header attribute compose:layer (JSON). `compression` is a lossless OpenEXR codec
// (ingest::parseExrCompression): compose composite reads these numbers back.
void saveObjectLayer(Context& ctx, const std::filesystem::path& file,
                     const std::string& compression = "zip");

// Reads a layer saveObjectLayer() wrote, for the render and ground stages' outputs and the
// geometry. Throws compose::Error naming the file when it is not one.
StageInput objectLayerInput(const std::filesystem::path& file);

}  // namespace compose::pipeline
