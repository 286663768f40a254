// Shared by the merge tests: virtual-camera captures of the sample HDRIs written to a temporary
// folder and read back as a photographer's files would be.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "capture/virtual_camera.h"
#include "color/color.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::testing {

inline lighting::Environment loadSampleEnvironment(const std::string& name) {
  const auto file = pipeline::samplesDirectory() / (name + ".exr");
  ingest::LoadedImage img = ingest::readImage(file);
  // The samples are linear Rec.709 (the virtual camera's RGB): no conversion needed.
  return lighting::Environment::fromLatLong(img.image, file);
}

// Small views, still honest: 384 x 288 pixels over 100 degrees (0.26 degrees a pixel, finer than
// the sample HDRIs' 0.35-degree texels, as a real camera would be), six views, 2 x 2 rays per
// pixel; everything else is the virtual camera's default model (noise, JPEG quality 95).
inline capture::VirtualCameraParams smallCaptureParams(int brackets, uint64_t seed = 7) {
  capture::VirtualCameraParams p;
  p.width = 384;
  p.height = 288;
  p.fovDegrees = 100.0;
  p.views = 6;
  p.brackets = brackets;
  p.evStep = 2.0;
  p.seed = seed;
  p.supersample = 2;
  return p;
}

struct CaptureOnDisk {
  capture::SimulatedCapture simulated;
  capture::CaptureFiles files;
  ingest::Capture capture;
  std::vector<std::vector<ingest::LoadedImage>> photos;
};

// Simulates, writes the files, and reads them back through ingest (capture description, EXIF,
// JPEG decoding).
inline CaptureOnDisk captureOnDisk(const lighting::Environment& env,
                                   const capture::VirtualCameraParams& params,
                                   const std::filesystem::path& folder) {
  CaptureOnDisk c;
  c.simulated = capture::simulateCapture(env, params);
  c.files = capture::writeCapture(folder, c.simulated);
  c.capture = ingest::readCaptureDescription(c.files.description);
  ingest::resolveExposures(c.capture);
  for (const auto& v : c.capture.views) {
    c.photos.emplace_back();
    for (const auto& s : v.shots) c.photos.back().push_back(ingest::readImage(s.file));
  }
  return c;
}

}  // namespace compose::testing
