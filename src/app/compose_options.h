// The options of the compose job, shared by the one-shot command, the stage commands that run
// part of the pipeline (precompute, render, composite) and compose run. Each command adds the
// groups it takes; apply() turns what was given into the job.
#pragma once

#include <memory>
#include <string>

#include <CLI/CLI.hpp>

#include "app/cli.h"
#include "color/color.h"
#include "pipeline/compose_job.h"

namespace compose::app {

struct ComposeOptions {
  pipeline::ComposeJob job;
  std::string place, albedo, lightingParams, exposure = "auto", shadows = "self", room, captureAt;
  double focal35 = 0.0, envRadius = 0.0;
  bool explain = false, noCache = false, noShadow = false, timings = false;

  // Option groups.
  void addPlate(CLI::App& app);  // --plate, --plate-space
  // --env, --env-space, --env-yaw, and with `parallax` --room, --env-radius, --capture-at.
  void addEnvironment(CLI::App& app, bool parallax = true);
  void addLighting(CLI::App& app);                  // --lighting, --lighting-params
  void addShadows(CLI::App& app, bool parameters);  // --shadows, --no-shadow [, --shadow-params]
  // --object, --crease, placement, camera, and with `shading` --albedo, --exposure, --samples,
  // --sampling.
  void addObject(CLI::App& app, bool shading = true);
  void addOutput(CLI::App& app);  // --out BASE, --display, --view, --holdout
  void addRun(CLI::App& app);     // --cache, --no-cache, --threads, --timings, --explain

  // Applies the options given on `app` to the job; throws UsageError for a malformed value.
  void apply(const CLI::App& app);
};

// Runs the job through the pipeline for `request`: with --explain prints the plan and returns;
// otherwise prints the stages (and --timings) on stderr. Returns the exit status.
// Checks the job's values and the colour names it gives (pipeline::validate, then the config):
// throws UsageError naming the option.
void validateJob(const pipeline::ComposeJob& job, const color::ColorConfig& colors);
// The colour config of a job: --ocio, else the job's own (a scene's color.ocio), else $OCIO, else
// the built-in one.
color::ColorConfig jobConfig(const pipeline::ComposeJob& job, const Globals& globals,
                             const std::string& namedBy = "the scene's color.ocio");

int runJob(const ComposeOptions& o, const Globals& globals,
           const pipeline::RunRequest& request = {}, bool printOutputs = true);

}  // namespace compose::app
