// The stage registry: the one place that lists the stages, in pipeline order.
#include "core/error.h"
#include "pipeline/stage.h"
#include "pipeline/stages.h"

namespace compose::pipeline {

const std::vector<std::unique_ptr<Stage>>& stages() {
  static const std::vector<std::unique_ptr<Stage>> list = [] {
    std::vector<std::unique_ptr<Stage>> s;
    s.push_back(makeIngestStage());
    s.push_back(makeMergeStage());
    s.push_back(makeStitchStage());
    s.push_back(makeColorStage());
    s.push_back(makePrecomputeStage());
    s.push_back(makeShadowsStage());
    s.push_back(makeGroundStage());
    s.push_back(makeRenderStage());
    s.push_back(makeCompositeStage());
    s.push_back(makeOutputStage());
    return s;
  }();
  return list;
}

std::vector<std::string> stageNames() {
  std::vector<std::string> names;
  for (const auto& s : stages()) names.push_back(s->name());
  return names;
}

const Stage& findStage(const std::string& name) {
  for (const auto& s : stages())
    if (s->name() == name) return *s;
  std::string valid;
  for (const auto& n : stageNames()) valid += (valid.empty() ? "" : ", ") + n;
  throw UsageError("unknown stage '" + name + "'; the stages are " + valid);
}

}  // namespace compose::pipeline
