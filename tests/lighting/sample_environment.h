// The sample HDRIs (samples/fetch.sh) as environments, for the tests that use real maps.
#pragma once

#include <filesystem>
#include <string>

#include "ingest/image_io.h"
#include "lighting/environment.h"
#include "pipeline/compose_job.h"

namespace compose::testing {

// <samples>/<name>.exr as an environment; an empty one when it is not there.
inline lighting::Environment loadSampleEnvironment(const std::string& name) {
  const std::filesystem::path path = pipeline::samplesDirectory() / (name + ".exr");
  if (!std::filesystem::exists(path)) return {};
  return lighting::Environment::fromLatLong(ingest::readImage(path).image, path);
}

}  // namespace compose::testing
