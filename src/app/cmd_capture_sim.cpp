// compose capture-sim: the virtual camera. Bracketed photos of an HDR environment through a
// documented camera model, with the ground truth written next to them.
#include <charconv>
#include <cmath>
#include <cstdio>

#include "app/cli.h"
#include "capture/virtual_camera.h"
#include "color/color.h"
#include "cubemap/environment_io.h"
#include "hdr/capture_merge.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"

namespace compose::app {

namespace {

struct SimOptions {
  capture::VirtualCameraParams params;
  std::filesystem::path env, out;
  std::string size = "1024x768", lens = "rectilinear", curve = "filmic", whiteBalance, envSpace;
  std::string exposure, seed = "1", chroma = "4:2:0";
  bool noNoise = false, noJpeg = false, omit35 = false, truthImages = false;
  std::string compression = "zip";
};

}  // namespace

Runner setupCaptureSim(CLI::App& command, const Globals& globals) {
  auto o = std::make_shared<SimOptions>();
  capture::VirtualCameraParams& params = o->params;
  command.footer(
      "Take bracketed photos of an HDR environment with a virtual camera: a lens, a response "
      "curve, white balance, sensor noise (fixed seed), 8-bit quantisation and JPEG, EXIF written "
      "as a camera would. Writes the photos, capture.json (for compose merge --capture), "
      "camera.json (the lens), truth.json and response_truth.json (the ground truth).\n\n"
      "Example:\n  compose capture-sim --env forest.exr --out shots/ --views 6 --brackets 3 "
      "--ev-step 2\n  compose merge --capture shots/capture.json --out merged/");
  command
      .add_option("--env", o->env,
                  "HDR environment: lat-long (equirectangular), a cube, a cross or six faces, "
                  "as compose --env takes it")
      ->required();
  command.add_option("--out", o->out, "Output folder")->required();
  command.add_option("--fov", params.fovDegrees, "Horizontal field of view, degrees")
      ->capture_default_str();
  command
      .add_option("--views", params.views,
                  "6: the cube directions px nx py ny pz nz; otherwise a ring around the "
                  "horizon")
      ->capture_default_str();
  command.add_option("--brackets", params.brackets, "Exposures per view")->capture_default_str();
  command.add_option("--ev-step", params.evStep, "Stops between exposures")->capture_default_str();
  command
      .add_option("--seed", o->seed,
                  "Seed of everything random (noise, shake, jitter): a whole number, "
                  "0..18446744073709551615")
      ->capture_default_str();
  command.add_option("--size", o->size, "Image size WxH")->capture_default_str();
  command.add_option("--lens", o->lens, "rectilinear or fisheye (equidistant)")
      ->capture_default_str();
  command.add_option("--exposure", o->exposure,
                     "Middle exposure time, seconds [default: automatic, whole stops]");
  command.add_option("--f-number", params.fNumber, "Aperture")->capture_default_str();
  command.add_option("--iso", params.iso, "ISO")->capture_default_str();
  command
      .add_option("--response", o->curve,
                  "Response curve: filmic[:C] (sRGB of a soft shoulder C), srgb, gamma[:G]")
      ->capture_default_str();
  command.add_option("--white-balance", o->whiteBalance, "White-balance gains R,G,B [1,1,1]");
  command.add_flag("--no-noise", o->noNoise, "No sensor noise");
  command.add_option("--full-well", params.fullWellElectrons, "Electrons at clipping, ISO 100")
      ->capture_default_str();
  command.add_option("--read-noise", params.readNoiseElectrons, "Read noise, electrons")
      ->capture_default_str();
  command.add_option("--supersample", params.supersample,
                     "S x S rays per pixel, 1-16 (anti-aliasing) [default: automatic, the "
                     "fewest, up to 8, whose spacing is at most one texel of the environment]");
  command
      .add_option("--blur", params.blurPixels,
                  "Optics: Gaussian point-spread sigma, pixels (the part of a pixel's area its "
                  "rays do not integrate is added to it)")
      ->capture_default_str();
  command.add_option("--jpeg-quality", params.jpegQuality, "JPEG quality")->capture_default_str();
  command
      .add_option("--jpeg-chroma", o->chroma,
                  "JPEG chroma: 4:2:0 (half resolution both ways, as most cameras write it) or "
                  "4:4:4 (full resolution, as some cameras do at their finest setting)")
      ->capture_default_str();
  command.add_flag("--tiff", params.writeTiff16,
                   "Also write 16-bit linear TIFFs, described by capture-tiff.json (by "
                   "capture.json with --no-jpeg)");
  command.add_flag("--no-jpeg", o->noJpeg, "Write no JPEGs (with --tiff)");
  command
      .add_option("--shake", params.shakePixels, "Hand-held shift per shot, up to this many pixels")
      ->capture_default_str();
  command.add_option("--roll", params.shakeRollDegrees, "Hand-held roll per shot, up to degrees")
      ->capture_default_str();
  command
      .add_option("--jitter", params.orientationJitterDegrees,
                  "Views off their nominal direction by up to degrees per axis")
      ->capture_default_str();
  command.add_flag("--omit-35mm", o->omit35,
                   "Write FocalLengthIn35mmFilm = 0, as many phones do (the focal-plane "
                   "resolution is still written)");
  command.add_option("--make", params.make, "EXIF Make")->capture_default_str();
  command.add_option("--model", params.model, "EXIF Model")->capture_default_str();
  command.add_flag("--truth-images", o->truthImages,
                   "Also write <view>_truth.exr, the radiance each view saw");
  addCompressionOption(command, o->compression)
      ->description(
          "OpenEXR compression of the truth images (lossless: none, rle, zips, zip, piz)");
  command.add_option("--env-space", o->envSpace,
                     "Colour space of the environment [default: from the file]");

  return [o, &command, &globals]() -> int {
    capture::VirtualCameraParams& p = o->params;
    {
      // Parsed here: as an unsigned option, -1 wrapped to 2^64 - 1 and 2^64 was clamped.
      uint64_t seed = 0;
      const char* end = o->seed.data() + o->seed.size();
      const auto [ptr, ec] = std::from_chars(o->seed.data(), end, seed);
      if (ec != std::errc() || ptr != end || o->seed.empty())
        throw UsageError("--seed must be a whole number from 0 to 18446744073709551615, got '" +
                         o->seed + "'");
      p.seed = seed;
    }
    {
      if (command.count("--compression") && !o->truthImages)
        throw UsageError("--compression is for the truth images: it goes with --truth-images");
      requireLosslessCompression(o->compression, "the truth images are the ground truth");
    }
    int w = 0, h = 0;
    char x = 0, extra = 0;
    if (std::sscanf(o->size.c_str(), "%d%c%d%c", &w, &x, &h, &extra) != 3 || x != 'x')
      throw UsageError("--size expects WxH, got '" + o->size + "'");
    p.width = w;
    p.height = h;
    if (o->lens == "rectilinear") {
      p.projection = calib::Projection::Rectilinear;
    } else if (o->lens == "fisheye" || o->lens == "equidistant") {
      p.projection = calib::Projection::Equidistant;
    } else {
      throw UsageError("--lens must be rectilinear or fisheye, got '" + o->lens + "'");
    }
    if (!o->exposure.empty()) p.exposureTime = parseNumber(o->exposure, "--exposure");
    asUsage([&] { p.curve = capture::CameraCurve::parse(o->curve); });
    if (!o->whiteBalance.empty())
      p.whiteBalance = glm::dvec3(parseColour(o->whiteBalance, "--white-balance"));
    p.noise = !o->noNoise;
    p.writeJpeg = !o->noJpeg;
    if (o->chroma != "4:2:0" && o->chroma != "4:4:4")
      throw UsageError("--jpeg-chroma must be 4:2:0 or 4:4:4, got '" + o->chroma + "'");
    for (const char* option : {"--jpeg-quality", "--jpeg-chroma"})
      if (command.count(option) && o->noJpeg)
        throw UsageError(std::string(option) + " is for the JPEGs: it does not go with --no-jpeg");
    p.jpegFullChroma = o->chroma == "4:4:4";
    p.write35mm = !o->omit35;
    asUsage([&] { p.validate(); });
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    std::string envSpace;
    asUsage([&] {
      if (!o->envSpace.empty()) envSpace = colors.resolve(o->envSpace, "--env-space");
    });
    // The camera's RGB is linear Rec.709 (what its sRGB JPEGs decode to).
    std::string why;
    const std::string cameraSpace = hdr::linearSpaceFor(colors, "sRGB", "", &why);

    // Any layout --env takes (a cube, a cross, six faces), as a lat-long map; its colour space
    // as compose --env reads it (an OpenEXR's chromaticities first), made linear before a cube's
    // faces are resampled.
    const auto toCamera = [&](Image& image, const ingest::CaptureInfo& info,
                              const std::filesystem::path&) {
      const std::string byPrimaries = envSpace.empty() && info.chromaticities
                                          ? colors.spaceWithChromaticities(*info.chromaticities)
                                          : std::string();
      if (envSpace.empty() && info.chromaticities && byPrimaries.empty()) {
        colors.convertFromChromaticities(image, *info.chromaticities, cameraSpace, o->env);
      } else {
        image.colorSpace = !envSpace.empty() ? envSpace
                           : !byPrimaries.empty()
                               ? byPrimaries
                               : colors
                                     .inputSpace(ingest::nameForRules(o->env, info.format),
                                                 info.fileColorSpace, false, info.integerSamples())
                                     .space;
        colors.convert(image, cameraSpace);
      }
      return cameraSpace;
    };
    cubemap::LoadedEnvironment env = cubemap::loadEnvironment(o->env, {}, {}, toCamera);
    if (!globals.quiet)
      for (const std::string& n : env.notes)
        std::fprintf(stderr, "compose: note: %s\n", printable(n).c_str());
    if (env.linearised.empty()) toCamera(env.image, env.info, o->env);
    lighting::SanitizeReport sanitize;
    const lighting::Environment environment =
        lighting::Environment::fromLatLong(env.image, o->env, &sanitize);

    ProgressPrinter printer(globals);
    capture::SimulatedCapture sim = [&] {
      try {
        return capture::simulateCapture(environment, p, printer.callback());
      } catch (const Error& e) {
        if (!e.file().empty()) throw;
        throw Error(e.stage(), e.what(), o->env);  // what it says is of the environment
      }
    }();
    sim.environmentName = o->env.string();
    capture::WriteCaptureOptions write;
    write.truthImages = o->truthImages;
    write.truthCompression = o->compression;
    write.linearSpace = cameraSpace;
    write.jpegSpace = colors.has("sRGB") ? "sRGB" : colors.inputSpaceFor("x.jpg", "");
    const capture::CaptureFiles files =
        capture::writeCapture(o->out, sim, write, printer.callback());

    if (!globals.quiet) {
      std::fprintf(stderr,
                   "compose: %zu view%s x %d exposure%s, %dx%d, %s lens %g degrees (f = %.1f px); "
                   "middle exposure %g s at f/%g ISO %g, %g EV apart\n",
                   sim.views.size(), sim.views.size() == 1 ? "" : "s", p.brackets,
                   p.brackets == 1 ? "" : "s", p.width, p.height,
                   p.projection == calib::Projection::Rectilinear ? "rectilinear" : "fisheye",
                   p.fovDegrees, sim.lens.fx, sim.middleExposureTime, p.fNumber, p.iso, p.evStep);
      const std::string jpegs = p.writeJpeg
                                    ? "; JPEG quality " + std::to_string(p.jpegQuality) + ", " +
                                          (p.jpegFullChroma ? "4:4:4" : "4:2:0") + " chroma"
                                    : "";
      std::fprintf(stderr,
                   "compose: response %s; noise %s; seed %llu; %d x %d rays per pixel%s, blur "
                   "sigma %.3g px%s\n",
                   p.curve.describe().c_str(), p.noise ? "on" : "off",
                   static_cast<unsigned long long>(p.seed), sim.supersample, sim.supersample,
                   p.supersample ? "" : " (automatic)",
                   capture::appliedBlur(p.blurPixels, sim.supersample), jpegs.c_str());
      if (sanitize.negativeTexels > 0)
        std::fprintf(stderr, "compose: note: %lld negative texels of the environment set to 0\n",
                     static_cast<long long>(sanitize.negativeTexels));
    }
    std::printf("%s\n", files.description.string().c_str());
    return 0;
  };
}

}  // namespace compose::app
