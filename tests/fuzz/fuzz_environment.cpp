// Environments after decoding: the checks every environment goes through (lighting/environment.h
// and lighting/cubemap.h: NaN, Inf and negative texels), layout detection by aspect and header
// (1x1, 1xN, huge aspects, squares), cube resampling, and a projection of what was accepted.
//
// Input: width and height (1..255 each), channels (1..4), a layout hint (none, envmap=latlong,
// envmap=cube), then texel values drawn from a palette of awkward numbers or taken as raw floats.
// The image goes through the real loader (written as a float OpenEXR, read by
// cubemap::loadEnvironment) and through Environment::fromLatLong / CubeMap::fromFaces directly.
#include <cmath>
#include <limits>

#include <glm/geometric.hpp>

#include "core/output_files.h"
#include "core/params.h"
#include "cubemap/environment_io.h"
#include "cubemap/layouts.h"
#include "fuzz_util.h"
#include "lighting/cubemap.h"
#include "lighting/environment.h"
#include "lighting/lighting.h"

using namespace compose;

namespace {

float texel(fuzz::Bytes& in) {
  constexpr float kInf = std::numeric_limits<float>::infinity();
  static const float kPalette[] = {0.0f, 1.0f,    0.5f,  -0.0f, -1e-6f, -1.0f, 1e-30f,
                                   1e5f, 65504.f, 1e30f, 3e38f, kInf,   -kInf, std::nanf("")};
  const uint8_t code = in.byte();
  if (code < 200) return float(code) / 50.0f;
  if (code < 240) return kPalette[code % std::size(kPalette)];
  return in.f32();
}

void checkLighting(const lighting::Environment& env) {
  for (const char* name : {"sh", "cheb-local"}) {
    ParamSet p = ParamSet::parse(std::string(name) == "sh" ? "order=2" : "rows=5,cols=8,samples=4",
                                 "lighting");
    auto basis = lighting::createLighting(name, p);
    basis->project(env);
    for (const glm::vec3 n : {glm::vec3(0, 1, 0), glm::vec3(0, -1, 0), glm::vec3(0, 0, 1),
                              glm::normalize(glm::vec3(0.3f, 0.2f, -0.9f))}) {
      const glm::vec3 e = basis->irradiance(n);
      FUZZ_CHECK(std::isfinite(e.x) && std::isfinite(e.y) && std::isfinite(e.z));
    }
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  forgetProtectedInputs();  // each input is a job of its own
  fuzz::Bytes in(data, size);
  const int width = 1 + in.byte() % 255, height = 1 + in.byte() % 255;
  const int channels = 1 + in.byte() % 4;
  const uint8_t hint = in.byte() % 3;
  if (int64_t(width) * height > 8192) return 0;
  Image image(width, height, channels);
  for (float& v : image.pixels) v = texel(in);

  // Directly: the lat-long checks and the cube checks.
  try {
    lighting::SanitizeReport report;
    const lighting::Environment env = lighting::Environment::fromLatLong(image, "direct", &report);
    FUZZ_CHECK(env.width() == 2 * env.height());
    for (float v : env.texels()) FUZZ_CHECK(std::isfinite(v) && v >= 0.0f);
    checkLighting(env);
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
  if (width == height) {
    try {
      std::array<const Image*, lighting::kCubeFaces> faces;
      faces.fill(&image);
      const lighting::CubeMap cube = lighting::CubeMap::fromFaces(faces, "direct");
      FUZZ_CHECK(cube.size() == width);
    } catch (const Error& e) {
      fuzz::checkNamed(e);
    }
  }

  // Through the loader: an RGB float OpenEXR, with the envmap attribute the hint asks for.
  if (channels != 3) return 0;
  const auto file = fuzz::scratch() / "environment.exr";
  const std::optional<cubemap::Layout> envmap =
      hint == 0 ? std::nullopt
                : std::optional(hint == 1 ? cubemap::Layout::LatLong : cubemap::Layout::Cube);
  try {
    cubemap::writeExr(file, image, false, envmap);
  } catch (const Error&) {
    return 0;  // OpenEXR refuses the header (not the reader under test)
  }
  try {
    const cubemap::LoadedEnvironment loaded = cubemap::loadEnvironment(file);
    FUZZ_CHECK(loaded.image.width == 2 * loaded.image.height);
    lighting::SanitizeReport report;
    const lighting::Environment env =
        lighting::Environment::fromLatLong(loaded.image, file, &report);
    checkLighting(env);
  } catch (const Error& e) {
    fuzz::checkNamed(e);
  }
  return 0;
}
