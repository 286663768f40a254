// Every key=value and command-line value parser: --lighting-params (ParamSet and each basis'
// creator, order=auto included, through the job's validate()), --shadow-params, the CLI's number
// lists, pairs, triples and colours, chessboard sizes, camera curves, layout and face-naming names,
// OpenEXR codecs.
// The input is one line per parser; all of them see every input.
#include "app/cli.h"
#include "calib/chessboard.h"
#include "capture/virtual_camera.h"
#include "core/output_files.h"
#include "core/params.h"
#include "cubemap/layouts.h"
#include "fuzz_util.h"
#include "ingest/exr_io.h"
#include "lighting/lighting.h"
#include "pipeline/compose_job.h"
#include "pipeline/shadows.h"

using namespace compose;

namespace {

template <class F>
void named(F&& f) {
  try {
    f();
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  fuzz::Bytes in(data, size);
  const std::string text = in.line();
  const std::string second = in.line();

  named([&] {
    ParamSet p = ParamSet::parse(text, "lighting");
    for (const std::string& k : p.unusedNames()) FUZZ_CHECK(!k.empty());
  });
  for (const std::string& basis : lighting::lightingNames()) {
    pipeline::ComposeJob job;
    job.plate = "plate.jpg";
    job.object = "object.obj";
    job.lighting = basis;
    job.lightingParams = text;
    job.shadowParams = second;
    named([&] { pipeline::validate(job); });
  }
  named([&] { pipeline::ShadowPlan::parse(text).describe(); });
  named([&] { app::parsePair(text, "--place"); });
  named([&] { app::parseColour(text, "--albedo"); });
  named([&] { app::parseTriple(text, "--room"); });
  named([&] { app::parseNumber(text, "--exposure"); });
  named([&] { app::parseList(text, "--exposures"); });
  named([&] { calib::Board::parse(text); });
  named([&] { capture::CameraCurve::parse(text); });
  cubemap::parseLayout(text);
  cubemap::parseFaceNaming(text);
  {
    // An OpenEXR codec: refused with a reason, or one OpenEXR takes, at a level it takes.
    std::string why;
    const std::optional<ingest::ExrCompression> codec = ingest::parseExrCompression(text, &why);
    FUZZ_CHECK(codec.has_value() == why.empty());
    if (codec) {
      FUZZ_CHECK(codec->zipLevel >= -1 && codec->zipLevel <= 9);
      FUZZ_CHECK(codec->dwaLevel == -1.0f || (codec->dwaLevel >= 1e-3f && codec->dwaLevel <= 1e6f));
    }
    pipeline::ComposeJob job;
    job.exrCompression = text;
    named([&] { pipeline::validate(job); });
  }
  return 0;
}
