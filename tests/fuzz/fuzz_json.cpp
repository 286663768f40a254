// The JSON files of ours: lens files (calib/lens.h), plate poses (calib/chessboard.h), capture
// descriptions (ingest/capture.h: the photos they name are looked up beside the file; the scratch
// folder holds a small JPEG "a.jpg" with EXIF for them to find) and camera response curves
// (hdr/response.h) and scene files (pipeline/scene.h). COMPOSE_FUZZ_JSON selects the reader:
// lens, pose, capture, response, scene.
#include <cmath>
#include <cstring>

#include "calib/chessboard.h"
#include "calib/lens.h"
#include "core/output_files.h"
#include "fuzz_util.h"
#include "hdr/response.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"
#include "pipeline/scene.h"

using namespace compose;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  Image small(8, 8, 3, {"R", "G", "B"});
  for (float& v : small.pixels) v = 0.5f;
  ingest::WriteOptions w;
  w.attributes = {{"ExposureTime", 0.01}, {"FNumber", 8.0}, {"Exif:PhotographicSensitivity", 100}};
  ingest::writeImage(fuzz::scratch() / "a.jpg", small, w);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  const std::string kind = COMPOSE_FUZZ_JSON;
  const auto file = fuzz::writeInput(kind + ".json", data, size);
  try {
    if (kind == "lens") {
      const calib::Lens lens = calib::readLens(file);
      FUZZ_CHECK(lens.width > 0 && lens.height > 0 && lens.fx > 0 && lens.fy > 0);
      glm::dvec3 d;
      glm::dvec2 px;
      for (double x : {0.0, 0.5 * lens.width, double(lens.width)}) {
        if (lens.direction(x, 0.5 * lens.height, d)) {
          FUZZ_CHECK(std::isfinite(d.x) && std::isfinite(d.y) && std::isfinite(d.z));
          if (lens.project(d, px)) FUZZ_CHECK(std::isfinite(px.x) && std::isfinite(px.y));
        }
      }
      const double fov = lens.horizontalFovDegrees();
      FUZZ_CHECK(fov >= 0.0 && fov <= 360.0);
      lens.resized(2 * lens.width, 2 * lens.height).validate();
    } else if (kind == "pose") {
      calib::readPose(file);
    } else if (kind == "capture") {
      ingest::Capture capture = ingest::readCaptureDescription(file);
      FUZZ_CHECK(!capture.views.empty());
      for (const std::string& line : ingest::describeCapture(capture)) FUZZ_CHECK(!line.empty());
      ingest::resolveExposures(capture);
      for (const ingest::View& v : capture.views)
        for (const ingest::Shot& s : v.shots) FUZZ_CHECK(s.exposure && *s.exposure > 0.0);
    } else if (kind == "scene") {
      // What a scene sets, written back out and read again, sets the same again.
      const pipeline::ComposeJob job = pipeline::loadScene(file);
      const auto folder = file.parent_path();
      pipeline::saveScene(job, fuzz::scratch() / "again.json");
      const pipeline::ComposeJob again = pipeline::loadScene(fuzz::scratch() / "again.json");
      FUZZ_CHECK(pipeline::sceneFromJob(job, folder) == pipeline::sceneFromJob(again, folder));
    } else {
      const hdr::ResponseCurve curve = hdr::readResponse(file);
      for (const auto& channel : curve.inverse)
        for (float v : channel) FUZZ_CHECK(std::isfinite(v));
    }
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
  return 0;
}
