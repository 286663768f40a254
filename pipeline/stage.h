// A stage of the compose pipeline, as a plugin: its name, what it consumes and produces, its
// parameters, and how it decides, keys, caches and runs. The runner (runner.h) knows stages only
// through this interface and the registry (stages()); adding a stage means writing one and adding
// it to the registry's list in registry.cpp.
//
// How the runner uses a stage, for one job:
//  1. prepare(): cheap reading that keys depend on (ingest hashes the input files, reads the mesh).
//  2. skip(): whether the scene needs the stage at all (an HDR environment needs no merge); a
//     skipped stage's outputs are absent, and stages after it do without them.
//  3. key(): the key of its outputs, from its inputs' keys and its parameters, in stage order.
//  4. Backwards from the written files: a stage whose outputs nobody needs is not run; one whose
//     key is in the stage cache is reused (load()); any other runs, and its inputs become needed.
//  5. In stage order: run() (then store() into the cache) for those that run.
#pragma once

#include <algorithm>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/hash.h"
#include "pipeline/compose_job.h"

namespace compose::pipeline {

class Context;
class StageCache;

// A parameter of a stage: how a scene file (compose run) names it and where it lives in the job.
struct StageParameter {
  std::string name;
  std::string help;
  std::function<nlohmann::json(const ComposeJob&)> get;
  // Throws compose::UsageError naming the parameter when the value does not fit.
  std::function<void(ComposeJob&, const nlohmann::json&)> set;
  // A file or folder: a scene file holds it relative to the scene file's folder.
  bool isPath = false;
  // A path's values that name no file and are kept as they are (the ocio parameter's "builtin",
  // and "built-in" as the command line takes it too).
  std::vector<std::string> literals{};
  bool isFile(const nlohmann::json& value) const {
    return isPath && value.is_string() && !value.get<std::string>().empty() &&
           std::find(literals.begin(), literals.end(), value.get<std::string>()) == literals.end();
  }
};

// A parameter that is a path, or a string, held in that member of the job.
StageParameter pathParameter(std::string name, std::string help,
                             std::filesystem::path ComposeJob::*member);
StageParameter textParameter(std::string name, std::string help, std::string ComposeJob::*member);

class Stage {
 public:
  virtual ~Stage() = default;

  virtual std::string name() const = 0;
  virtual std::string summary() const = 0;
  // What the stage will do for this job, for --explain, once prepare() has run: by default the
  // summary (ingest names the files it will read).
  virtual std::string planned(const Context& /*context*/) const { return summary(); }
  virtual std::vector<std::string> inputs() const = 0;   // artefact names (context.h)
  virtual std::vector<std::string> outputs() const = 0;  // artefact names
  // The inputs one output is made from (by default all of them): the colour stage's plate does
  // not need the environment.
  virtual std::vector<std::string> inputsFor(const std::string& /*output*/) const {
    return inputs();
  }
  virtual std::vector<StageParameter> parameters() const { return {}; }

  // Cheap reading that keys depend on (ingest reads the mesh and the capture description).
  virtual void prepare(Context& /*context*/) const {}
  // Empty when the scene may need the stage; else why it does not.
  virtual std::string skip(const Context& /*context*/) const { return {}; }
  // Sets context.keys for each of its outputs this job has: a hash of the inputs' keys, the
  // parameters and the version of the stage's numbers.
  virtual void keys(Context& context) const = 0;
  // Whether the outputs are kept in the stage cache (expensive ones are; cheap ones are not).
  virtual bool cached() const { return false; }
  // Restores the outputs from a cache entry; false if it does not fit (the stage then runs). It
  // may take the entry's arrays (StageCache::takeImage) rather than copy them.
  virtual bool load(Context& /*context*/, StageCache& /*cache*/) const { return false; }
  // Computes the outputs the context needs; returns what it did (one line for the report).
  virtual std::string run(Context& context) const = 0;
  // Writes the outputs into the entry and the entry to disk; false if that failed.
  virtual bool store(const Context& /*context*/, StageCache& /*cache*/) const { return false; }
  // Whether store() may run on a thread of its own while the later stages run: only for a stage
  // whose outputs no later stage changes or moves (they are read, never written, once made).
  virtual bool storesWhileLaterStagesRun() const { return false; }
  // What keeps the stage within memory, for the error when it runs out: the parameters that
  // size what it allocates.
  virtual std::string memoryAdvice() const {
    return "a smaller plate or --max-pixels, which refuses larger images before they are read, "
           "keep it within bounds";
  }
};

// The registry: every stage, in pipeline order.
const std::vector<std::unique_ptr<Stage>>& stages();
// The stage of that name, or throws compose::UsageError listing the valid names.
const Stage& findStage(const std::string& name);
std::vector<std::string> stageNames();

}  // namespace compose::pipeline
