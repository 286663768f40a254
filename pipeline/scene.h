// Scene files: a whole compose job as JSON, stage by stage (compose run SCENE; compose
// --save-scene SCENE writes the one a command line describes).
//
//   {
//     "compose": "scene", "version": 1,
//     "stages": {
//       "ingest":  {"plate": "plate.jpg", "object": "bunny.obj", "environment": "forest.exr"},
//       "render":  {"place": [0.5, 0.72], "scale": 0.3, "exposure": "auto"},
//       "output":  {"out": "out/compose"}
//     }
//   }
//
// Every stage's parameters (Stage::parameters()) may appear under its name; a parameter left out
// keeps its default. Paths are relative to the scene file's folder. An unknown stage or parameter
// is an error that lists the valid ones.
#pragma once

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "pipeline/compose_job.h"

namespace compose::pipeline {

inline constexpr int kSceneVersion = 1;

// Every parameter of every stage, paths relative to `folder` (where the scene file will be).
nlohmann::ordered_json sceneFromJob(const ComposeJob& job, const std::filesystem::path& folder);
// Writes sceneFromJob() to `file` atomically; throws compose::Error naming the file.
void saveScene(const ComposeJob& job, const std::filesystem::path& file);

// Applies a scene's parameters to `job`; relative paths are taken from `folder`. Throws
// compose::UsageError for an unknown stage or parameter or a value that does not fit.
void applyScene(const nlohmann::json& scene, const std::filesystem::path& folder, ComposeJob& job);
// Reads a scene file onto the default job. Throws compose::Error naming the file when it cannot
// be read, is not JSON, or does not fit (then saying which stage and parameter).
ComposeJob loadScene(const std::filesystem::path& file);

// Sets one parameter, "stage.name=value" (value JSON, or else taken as a string), as compose run
// --set does. Throws compose::UsageError.
void setParameter(ComposeJob& job, const std::string& assignment);

}  // namespace compose::pipeline
