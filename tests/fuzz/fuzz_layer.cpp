// Object layers (pipeline/stage_files.h): the float multi-part OpenEXR that compose render writes
// and compose composite reads, whose header attribute compose:layer (JSON) says where the parts
// lie, what their channels are and which camera made them.
//
// The input's first eight bytes choose the size and place of the two parts (object and shadow)
// in a 16x12 frame; the rest is the header's text. The target writes the file, reads it as compose
// composite does, and composites what it read over a plate of the frame's size: the reader either
// refuses the file with a named error or hands the composite parts that lie in the frame.
#include <cmath>

#include "composite/composite.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "fuzz_util.h"
#include "ingest/image_io.h"
#include "pipeline/stage_files.h"
#include "render/renderer.h"

using namespace compose;

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // Frames of a few megapixels at most, so that one input stays cheap.
  ResourceLimits limits;
  limits.maxPixels = int64_t(1) << 22;
  setResourceLimits(limits);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  if (size < 8) return 0;
  fuzz::Bytes shape(data, 8);
  const int width = 1 + shape.byte() % 16, height = 1 + shape.byte() % 12;
  const int x = shape.byte() % 18, y = shape.byte() % 14;
  const int shadowWidth = 1 + shape.byte() % 16, shadowHeight = 1 + shape.byte() % 12;
  const int shadowX = shape.byte() % 18, shadowY = shape.byte() % 14;

  std::vector<std::string> names = {"R", "G", "B", "A"};
  const auto& aovs = render::aovChannelNames();
  names.insert(names.end(), aovs.begin(), aovs.end());
  Image object(width, height, int(names.size()), names);
  for (size_t i = 0; i < object.pixels.size(); ++i) object.pixels[i] = 0.25f * float(i % 5);
  object.colorSpace = "ACEScg";
  Image shadow(shadowWidth, shadowHeight, 3, {"shadow.R", "shadow.G", "shadow.B"});
  for (float& v : shadow.pixels) v = 0.5f;
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::Float;
  ingest::ExrHeader header;
  header.strings.emplace_back("compose:layer",
                              std::string(reinterpret_cast<const char*>(data) + 8, size - 8));
  const auto file = fuzz::scratch() / "layer.exr";
  {
    OutputFiles outputs("render");
    ingest::writeExrParts(outputs, file,
                          {{"object", &object, x, y, 16, 12, options},
                           {"shadow", &shadow, shadowX, shadowY, 16, 12, options}},
                          header);
    outputs.commit();
  }

  const pipeline::ComposeJob job;
  const color::ColorConfig colors = color::ColorConfig::builtin();
  pipeline::Context ctx(job, colors, {});
  try {
    pipeline::objectLayerInput(file).load(ctx);
  } catch (const Error& e) {
    fuzz::checkNamed(e);
    return 0;
  }
  // Read: then the parts lie in the frame, and compositing them cannot fail.
  FUZZ_CHECK(ctx.artefacts.object.has_value());
  {
    const calib::PlateCamera& camera = ctx.geometry().camera;
    Image plate(camera.width, camera.height, 3, {"R", "G", "B"});
    const render::RenderOutput& r = ctx.artefacts.object->output;
    plate.colorSpace = r.beauty.colorSpace;
    if (ctx.artefacts.groundShadow && !ctx.artefacts.groundShadow->ratio.empty()) {
      const pipeline::GroundShadowResult& g = *ctx.artefacts.groundShadow;
      composite::multiply(plate, g.ratio, g.grid.x0, g.grid.y0);
    }
    composite::overInPlace(plate, r.beauty, r.x0, r.y0);
    for (float v : plate.pixels) FUZZ_CHECK(std::isfinite(v));
  }
  return 0;
}
