// EXIF-driven ingestion: the capture metadata (ingest::CaptureInfo) made from a header's
// attributes, as OpenImageIO hands them over, and what is derived from it: relative exposures,
// the 35 mm focal length and the plate camera, capture times and the grouping of photos into
// views and brackets.
//
// Input: width and height (two bytes each), then records of [name index, type, value]; names
// are the attributes we read (and a few more), values int, float, text or float arrays.
#include <cmath>

#include "calib/plate_camera.h"
#include "core/output_files.h"
#include "fuzz_util.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"

using namespace compose;

namespace {

const char* const kNames[] = {"ExposureTime",
                              "FNumber",
                              "Exif:PhotographicSensitivity",
                              "Exif:ISOSpeedRatings",
                              "Exif:FocalLength",
                              "Exif:FocalLengthIn35mmFilm",
                              "Exif:FocalPlaneXResolution",
                              "Exif:FocalPlaneYResolution",
                              "Exif:FocalPlaneResolutionUnit",
                              "Orientation",
                              "Make",
                              "Model",
                              "Exif:DateTimeOriginal",
                              "Exif:SubsecTimeOriginal",
                              "DateTime",
                              "oiio:ColorSpace",
                              "colorSpace",
                              "chromaticities",
                              "oiio:BitsPerSample",
                              "Software"};

std::vector<ingest::ImageAttribute> attributes(fuzz::Bytes& in) {
  std::vector<ingest::ImageAttribute> out;
  while (!in.empty() && out.size() < 32) {
    const size_t name = in.byte() % std::size(kNames);
    const uint8_t type = in.byte() % 4;
    ingest::ImageAttribute a;
    a.name = kNames[name];
    if (type == 0) {
      a.value = int(in.u32());
    } else if (type == 1) {
      a.value = double(in.f32());
    } else if (type == 2) {
      a.value = in.line();
    } else {
      std::vector<float> v(in.byte() % 10);
      for (float& f : v) f = in.f32();
      a.value = v;
    }
    out.push_back(std::move(a));
  }
  return out;
}

void checkPositive(const std::optional<double>& v) {
  if (v) FUZZ_CHECK(*v > 0.0 && std::isfinite(*v));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  fuzz::Bytes in(data, size);
  const int width = 1 + int(in.byte()) * 256 % 65536 + in.byte();
  const int height = 1 + int(in.byte()) * 256 % 65536 + in.byte();
  std::vector<ingest::Shot> shots;
  for (int shot = 0; shot < 3 && !in.empty(); ++shot) {
    const std::string chunk = in.line();
    fuzz::Bytes part(reinterpret_cast<const uint8_t*>(chunk.data()), chunk.size());
    const ingest::CaptureInfo info =
        ingest::captureInfoFromAttributes(width, height, 3, attributes(part));
    FUZZ_CHECK(info.orientation >= 1 && info.orientation <= 8);
    checkPositive(info.exposureTime);
    checkPositive(info.fNumber);
    checkPositive(info.iso);
    checkPositive(info.focalLengthMm);
    checkPositive(info.focalLength35mm);
    if (const auto e = info.relativeExposure()) FUZZ_CHECK(*e >= 0.0);
    info.exposureAssumptions();
    info.camera();
    if (info.captureSeconds) FUZZ_CHECK(std::isfinite(*info.captureSeconds));
    try {
      const calib::PlateCamera camera = calib::plateCamera(width, height, info, {});
      FUZZ_CHECK(std::isfinite(camera.focal35mm) && camera.focal35mm > 0.0);
      FUZZ_CHECK(camera.lens.fx > 0.0 && std::isfinite(camera.lens.fx));
    } catch (const Error& e) {
      fuzz::checkNamed(e);
    }
    shots.push_back(ingest::Shot{"shot" + std::to_string(shot) + ".jpg", info, {}, {}, {}, {}});
  }
  if (shots.empty()) return 0;
  try {
    ingest::Capture capture = ingest::groupByExif(shots, {});
    size_t grouped = 0;
    for (const ingest::View& v : capture.views) grouped += v.shots.size();
    FUZZ_CHECK(grouped == shots.size());
    ingest::describeCapture(capture);
    ingest::resolveExposures(capture);
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
  return 0;
}
