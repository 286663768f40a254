// compose stitch: photos from one point in roughly known directions to a cube-map environment.
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <optional>
#include <sstream>

#include "app/cli.h"
#include "calib/lens.h"
#include "color/color.h"
#include "core/error.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "cubemap/environment_io.h"
#include "cubemap/layouts.h"
#include "cubemap/photo_header.h"
#include "cubemap/render_view.h"
#include "cubemap/stitch.h"
#include "lighting/sphere_resample.h"

namespace compose::app {

namespace {

namespace fs = std::filesystem;

// A level view named by its turn (cubemap::yawFromName): yaw120_2.jpg.
std::optional<double> yawFromPhotoName(const fs::path& file) {
  return cubemap::yawFromName(file.stem().string());
}

struct StitchCommandOptions {
  std::vector<std::string> photos;
  std::string out, calib, to = "cube", photoSpace, outSpace, depth = "auto", faceNames = "pxnx",
                          compression = "piz";
  double fov = 0.0, maxCorrection = 10.0;
  int size = 0, width = 0, featureSize = 800;
  std::string gains = "auto";
  bool fisheye = false, noRefine = false, lowMemory = false;
};

// "file@yaw,pitch[,roll]" → file and the angles; no '@' → file only.
struct PhotoArgument {
  fs::path file;
  std::optional<glm::dvec3> angles;  // yaw, pitch, roll in degrees
};

PhotoArgument parsePhoto(const std::string& text) {
  PhotoArgument p;
  const size_t at = text.rfind('@');
  std::error_code ec;
  // A file whose name holds an '@' (photo@2x.jpg) is that file, not a direction; so is a name
  // whose part before the '@' is no file (then "not found" names it whole).
  if (at == std::string::npos || text.find('/', at) != std::string::npos || fs::exists(text, ec) ||
      !fs::exists(text.substr(0, at), ec)) {
    p.file = text;
    return p;
  }
  p.file = text.substr(0, at);
  std::istringstream in(text.substr(at + 1));
  std::vector<double> v;
  std::string item;
  while (std::getline(in, item, ','))
    v.push_back(parseNumber(item, "the orientation of " + p.file.string()));
  if (v.size() < 2 || v.size() > 3) {
    throw UsageError("a photo's orientation is @YAW,PITCH or @YAW,PITCH,ROLL in degrees, got '" +
                     text.substr(at) + "'");
  }
  for (double a : v)
    if (!std::isfinite(a) || std::abs(a) > 360.0)
      throw UsageError("orientation angles must be finite degrees within ±360: '" + text + "'");
  p.angles = glm::dvec3(v[0], v[1], v.size() == 3 ? v[2] : 0.0);
  return p;
}

std::string percent(double f) {
  char s[32];
  std::snprintf(s, sizeof s, "%.2f %%", 100.0 * f);
  return s;
}

}  // namespace

Runner setupStitch(CLI::App& cmd, const Globals& globals) {
  auto o = std::make_shared<StitchCommandOptions>();
  cmd.description(
      "Stitch photos taken from one point into a cube-map environment.\n\n"
      "Each photo's rough direction comes from its name (px nx py ny pz nz, posx.., +X.., right "
      "left top bottom back front: the photographer's convention, side views upright, up and down "
      "views tilted from the -Z view) or from an @YAW,PITCH[,ROLL] suffix in degrees (yaw turns "
      "left from -Z, pitch tilts up). Six unnamed photos are taken in the order +X -X +Y -Y +Z -Z. "
      "Orientations are refined by feature matching and bundle adjustment; directions no photo "
      "saw are filled and reported.\n"
      "Intrinsics: --calib (a lens file from compose calib lens), --fov, or the photos' EXIF 35 mm "
      "focal length.\n\n"
      "Examples:\n"
      "  compose stitch --fov 100 --out env.exr room_px.jpg room_nx.jpg room_py.jpg room_ny.jpg "
      "room_pz.jpg room_nz.jpg\n"
      "  compose stitch --calib lens.json --to latlong --out env.exr a.exr@0,0 b.exr@60,0 "
      "c.exr@120,0 ... up.exr@0,90 down.exr@0,-90");
  cmd.add_option("photos", o->photos,
                 "Photos (linear EXR/HDR merges, or JPEG/PNG/TIFF), "
                 "optionally with @YAW,PITCH[,ROLL]")
      ->required();
  cmd.add_option("--out", o->out, "Output file (for --to faces: a name with %, see convert)")
      ->required();
  cmd.add_option("--fov", o->fov,
                 "Field of view across the camera sensor's width, degrees: a photo's horizontal "
                 "one, a portrait's (turned by its EXIF orientation) across its height");
  cmd.add_option("--calib", o->calib, "Lens file (JSON) from compose calib lens");
  cmd.add_flag("--fisheye", o->fisheye,
               "With --fov: an equidistant fisheye instead of rectilinear");
  cmd.add_option("--to", o->to, "Output layout: cube, latlong, hcross, vcross, faces")
      ->capture_default_str();
  cmd.add_option("--size", o->size,
                 "Cube face size [default: the photos' resolution, at most 2048]");
  cmd.add_option("--width", o->width, "Lat-long width for --to latlong [default: 4 x face size]");
  cmd.add_option("--max-correction", o->maxCorrection,
                 "How far the rough orientations may be off, degrees")
      ->capture_default_str();
  cmd.add_flag("--no-refine", o->noRefine, "Use the rough orientations as they are");
  cmd.add_option("--gains", o->gains,
                 "Exposure compensation between photos: on, off, or auto (on when a photo is not "
                 "HDR: merged HDR photos have known exposures)")
      ->capture_default_str();
  cmd.add_option("--feature-size", o->featureSize,
                 "Long side of the images features are found on, pixels")
      ->capture_default_str();
  cmd.add_flag("--low-memory", o->lowMemory, "Hold one photo at a time (each is decoded twice)");
  cmd.add_option("--photo-space", o->photoSpace,
                 "Colour space of the photos [default: from the file]");
  cmd.add_option("--out-space", o->outSpace,
                 "Colour space of the result [default: what the config's file rules say for "
                 "--out, so that compose --env reads it back correctly]");
  cmd.add_option("--depth", o->depth,
                 "EXR sample type: auto (half float unless a value exceeds its range), half, float")
      ->capture_default_str();
  addCompressionOption(cmd, o->compression);
  cmd.add_option("--face-names", o->faceNames, "For --to faces: pxnx, posneg, exr, words")
      ->capture_default_str();

  return [o, &cmd, &globals]() -> int {
    using cubemap::Layout;
    // Command-line checks, before any file is read.
    const auto to = cubemap::parseLayout(o->to);
    if (!to || *to == Layout::MirrorBall)
      throw UsageError("--to must be one of cube, latlong, hcross, vcross, faces; got '" + o->to +
                       "'");
    // One file (faces: one per face, named from a pattern), checked before any photo is read.
    if (*to != Layout::Faces) OutputFiles::check(o->out, "output");
    if (cmd.count("--fov") && cmd.count("--calib"))
      throw UsageError("give either --fov or --calib, not both");
    if (cmd.count("--fov") && !(o->fov > 1.0 && o->fov < (o->fisheye ? 360.0 : 179.0)))
      throw UsageError(
          "--fov must be a field of view in degrees within (1, 179) (360 for --fisheye)");
    if (o->fisheye && !cmd.count("--fov")) throw UsageError("--fisheye goes with --fov");
    // Zero is a value given, not the default; options of another layout are refused, not ignored.
    if (cmd.count("--size") && (o->size < 8 || o->size > 8192))
      throw UsageError("--size must be 8..8192; got " + std::to_string(o->size));
    if (cmd.count("--width") && (o->width < 2 || o->width % 2 != 0 || o->width > 65536)) {
      throw UsageError("--width must be an even number of texels, 2..65536; got " +
                       std::to_string(o->width));
    }
    if (cmd.count("--width") && *to != Layout::LatLong)
      throw UsageError("--width is the width of a lat-long map: it goes with --to latlong");
    if (cmd.count("--max-correction") && o->noRefine)
      throw UsageError("--max-correction bounds the refinement, which --no-refine turns off");
    // Exposure gains are measured on the features the refinement matches.
    if (o->noRefine && (o->gains == "on" || cmd.count("--feature-size"))) {
      throw UsageError(std::string(o->gains == "on" ? "--gains on" : "--feature-size") +
                       " needs the refinement's feature matching, which --no-refine turns off");
    }
    const int64_t limit = resourceLimits().maxPixels;
    if ((cmd.count("--size") && 6 * int64_t(o->size) * o->size > limit) ||
        (cmd.count("--width") && int64_t(o->width) * (o->width / 2) > limit)) {
      throw UsageError("the map asked for (--size, --width) is more pixels than the limit of " +
                       std::to_string(limit / 1000000) +
                       " megapixels (raise it with --max-pixels)");
    }
    cubemap::WriteOptions write = environmentWriteOptions(o->depth, o->faceNames);
    write.exrCompression = o->compression;
    const std::filesystem::path firstOut = firstEnvironmentFile(o->out, *to, write);
    refuseUnusedWriteOptions(cmd, *to, firstOut);
    ingest::requireImageWriter(firstOut);
    cubemap::StitchOptions options;
    options.faceSize = o->size > 0 ? o->size : 1024;
    options.refine = !o->noRefine;
    if (o->gains != "auto" && o->gains != "on" && o->gains != "off")
      throw UsageError("--gains must be on, off or auto; got '" + o->gains + "'");
    options.maxCorrectionDegrees = o->maxCorrection;
    options.featureSize = o->featureSize;
    options.keepPhotos = !o->lowMemory;
    options.validate();

    // Where each photo points.
    std::vector<PhotoArgument> args;
    for (const auto& p : o->photos) args.push_back(parsePhoto(p));
    for (size_t i = 0; i < args.size(); ++i) {
      for (size_t j = 0; j < i; ++j) {
        std::error_code ec;
        if (fs::equivalent(args[i].file, args[j].file, ec)) {
          throw Error("stitch",
                      "the same photo is given twice (also as " + args[j].file.string() +
                          "): each photo is one view",
                      args[i].file);
        }
      }
    }
    std::vector<std::string> notes;
    std::vector<glm::dmat3> rough(args.size());
    bool allNamed = true, noneNamed = true;
    for (size_t i = 0; i < args.size(); ++i) {
      if (args[i].angles) {
        rough[i] = cubemap::cameraRotation(args[i].angles->x, args[i].angles->y, args[i].angles->z);
        noneNamed = false;
      } else if (const auto token = cubemap::faceFromPhotoName(args[i].file)) {
        rough[i] = cubemap::faceCameraRotation(token->face);
        noneNamed = false;
      } else if (const std::optional<double> yaw = yawFromPhotoName(args[i].file)) {
        rough[i] = cubemap::cameraRotation(*yaw, 0.0, 0.0);
        noneNamed = false;
      } else {
        allNamed = false;
      }
    }
    if (!allNamed) {
      if (noneNamed && args.size() == 6) {
        for (int f = 0; f < 6; ++f) rough[size_t(f)] = cubemap::faceCameraRotation(f);
        notes.push_back("no directions in the photo names: taken in the order +X -X +Y -Y +Z -Z");
      } else {
        for (const auto& a : args) {
          if (!a.angles && !cubemap::faceFromPhotoName(a.file) && !yawFromPhotoName(a.file))
            throw UsageError("cannot tell where " + a.file.string() +
                             " points: name it for a cube face (_px, _nx, ...) or a level turn "
                             "(yaw120), or add @YAW,PITCH[,ROLL]");
        }
      }
    }

    // Intrinsics, from the headers.
    std::optional<calib::Lens> lensFile;
    if (!o->calib.empty()) lensFile = calib::readLens(o->calib);
    std::vector<cubemap::StitchPhoto> photos;
    std::vector<cubemap::PhotoHeader> headers;
    for (size_t i = 0; i < args.size(); ++i) {
      const cubemap::PhotoHeader h = cubemap::readPhotoHeader(args[i].file);
      headers.push_back(h);
      cubemap::StitchPhoto p;
      p.name = args[i].file.filename().string();
      p.worldFromCamera = rough[i];
      p.lens = cubemap::photoLens(args[i].file, h, lensFile, o->fov, o->fisheye);
      photos.push_back(p);
    }
    options.gains = o->gains == "on" ||
                    (o->gains == "auto" && !o->noRefine &&
                     std::any_of(headers.begin(), headers.end(),
                                 [](const cubemap::PhotoHeader& h) { return !h.floatingPoint; }));
    std::string faceSizeFrom;  // the photo whose pixels set the face size
    if (o->size == 0) {
      // Texels as fine as the photos' pixels at their centres: a face of 2 fx texels, at most 2048.
      double fx = 1e9;
      for (const auto& p : photos) {
        if (p.lens.fx < fx) faceSizeFrom = p.name;
        fx = std::min(fx, p.lens.fx);
      }
      options.faceSize = std::clamp(int(std::lround(2.0 * fx / 8.0)) * 8, 64, 2048);
    }

    // Colour: photos are linearised into the space the result will be read as.
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    // (For --to faces, as the face files are read: a base name gets OpenEXR's extension.)
    const std::string target = o->outSpace.empty() ? colors.inputSpaceFor(firstOut, "")
                                                   : colors.resolve(o->outSpace, "--out-space");
    const std::string forced =
        o->photoSpace.empty() ? std::string() : colors.resolve(o->photoSpace, "--photo-space");
    std::vector<std::string> spaces(photos.size());
    auto load = [&](int i) {
      ingest::LoadedImage img =
          ingest::readImage(args[size_t(i)].file, "ingest", {.codesForEightBit = true});
      // A photo's space: --photo-space, else an OpenEXR's chromaticities (as compose --env reads
      // them: the config's space with those primaries, or a matrix into the working space),
      // else what the file says, else the config's file rules.
      const std::optional<std::array<double, 8>> primaries =
          forced.empty() && img.hasPixels() ? img.info.chromaticities : std::nullopt;
      const std::string byPrimaries = primaries ? colors.spaceWithChromaticities(*primaries) : "";
      const std::string space =
          !forced.empty() ? forced
          : primaries     ? byPrimaries
                          : colors
                            .inputSpace(ingest::nameForRules(args[size_t(i)].file, img.info.format),
                                        img.info.fileColorSpace, false, img.info.integerSamples())
                            .space;
      spaces[size_t(i)] = space.empty() ? "the primaries in its header" : space;
      const int channels = img.image.channels;
      if (!img.hasPixels() && channels >= 3) {
        // An 8-bit photo: linearised from its codes (a table of the 256 codes per channel).
        return colors.convertCodes(img.codes, img.image.width, img.image.height, channels, space,
                                   target);
      }
      if (!img.hasPixels())
        ingest::floatsFromCodes(img);
      else
        ingest::requireFinite(img.image, args[size_t(i)].file, "ingest", "the photo",
                              ingest::kMaxPhotoValue);
      // A merged view's pixels black in every photo (its 'clipped' channel, below the view's
      // median) hold only a bound: outside a circular fisheye's image circle they are no picture
      // at all. They are made 0, which the stitch reads as no picture where it reaches the frame.
      {
        const auto& names = img.image.channelNames;
        const auto it = std::find(names.begin(), names.end(), "clipped");
        const int nc = img.image.channels;
        if (it != names.end() && nc >= 4) {
          const size_t k = size_t(it - names.begin()), count = img.image.pixelCount();
          auto luminance = [&](size_t at) {
            const float* q = img.image.pixels.data() + at * size_t(nc);
            return q[0] + q[1] + q[2];
          };
          std::vector<float> sample;
          for (size_t at = 0; at < count; at += std::max<size_t>(1, count / 4096))
            sample.push_back(luminance(at));
          std::nth_element(sample.begin(), sample.begin() + ptrdiff_t(sample.size() / 2),
                           sample.end());
          const float median = sample.empty() ? 0.0f : sample[sample.size() / 2];
          for (size_t at = 0; at < count; ++at) {
            float* q = img.image.pixels.data() + at * size_t(nc);
            if (q[k] >= 0.5f && luminance(at) < median) q[0] = q[1] = q[2] = 0.0f;
          }
        }
      }
      Image rgb;
      if (img.image.channels == 3) {
        rgb = std::move(img.image);
      } else {
        rgb = Image(img.image.width, img.image.height, 3, {"R", "G", "B"});
        for (size_t k = 0; k < rgb.pixelCount(); ++k) {
          const float* s = img.image.pixels.data() + k * size_t(img.image.channels);
          for (int c = 0; c < 3; ++c)
            rgb.pixels[3 * k + size_t(c)] = s[img.image.channels >= 3 ? c : 0];
        }
      }
      if (space.empty()) {
        colors.convertFromChromaticities(rgb, *primaries, colors.workingSpace(),
                                         args[size_t(i)].file);
      } else {
        rgb.colorSpace = space;
      }
      colors.convert(rgb, target);
      return rgb;
    };
    // LDR photos clip at their white: what encoded 1.0 becomes in the target space.
    for (size_t i = 0; i < photos.size(); ++i) {
      if (headers[i].floatingPoint) continue;
      Image white(1, 1, 3, {"R", "G", "B"});
      white.pixels = {1.0f, 1.0f, 1.0f};
      white.colorSpace =
          forced.empty()
              ? colors.inputSpaceFor(ingest::nameForRules(args[i].file, headers[i].format), "")
              : forced;
      colors.convert(white, target);
      photos[i].saturation = 0.98f * std::min({white.pixels[0], white.pixels[1], white.pixels[2]});
    }

    write.chromaticities = colors.chromaticities(target);
    // Photos of one camera, merged at its EXIF exposures and not evened out by gains: the map
    // keeps their unit, and says so (the one-shot command then takes the exposure from the
    // plate's EXIF, as it does with the capture description).
    const auto agree = [&](auto field) {
      return std::all_of(headers.begin(), headers.end(), [&](const cubemap::PhotoHeader& h) {
        return h.*field == headers.front().*field;
      });
    };
    if (!headers.front().cameraModel.empty() && agree(&cubemap::PhotoHeader::cameraMake) &&
        agree(&cubemap::PhotoHeader::cameraModel)) {
      if (!headers.front().cameraMake.empty())
        write.strings.emplace_back("Make", headers.front().cameraMake);
      write.strings.emplace_back("Model", headers.front().cameraModel);
      if (!options.gains && headers.front().exposureUnit == ingest::kExifExposureUnit &&
          agree(&cubemap::PhotoHeader::exposureUnit))
        write.strings.emplace_back("compose:exposureUnit", ingest::kExifExposureUnit);
    }
    write.fromCodes =
        std::none_of(headers.begin(), headers.end(), [](const auto& h) { return h.floatingPoint; });
    write.sixteenBit =
        std::any_of(headers.begin(), headers.end(), [](const auto& h) { return h.sixteenBit; });
    ProgressPrinter printer(globals);
    const cubemap::StitchResult result = cubemap::stitch(photos, load, options, printer.callback());

    const auto writeStart = std::chrono::steady_clock::now();
    OutputFiles outputs("output");
    std::vector<std::string> written;
    lighting::CubeMap cube = result.cube;
    cube.colorSpace = target;
    if (*to == Layout::LatLong) {
      const int width = o->width > 0 ? o->width : 4 * cube.size();
      lighting::Environment env = lighting::latLongFromCube(cube, width, printer.callback());
      for (auto& n : cubemap::writeLatLong(outputs, o->out, env, write)) notes.push_back(n);
      written.push_back(o->out);
    } else {
      for (auto& n : cubemap::writeCubeMap(outputs, o->out, cube, *to, write)) notes.push_back(n);
      if (*to == Layout::Faces) {
        for (const auto& p : cubemap::facePaths(o->out, write.faceNaming)) written.push_back(p);
      } else {
        written.push_back(o->out);
      }
    }
    outputs.commit();
    const double writeSeconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - writeStart).count();

    if (!globals.quiet) {
      for (size_t i = 0; i < photos.size(); ++i) {
        char line[256];
        std::snprintf(
            line, sizeof line,
            "%s: %s, %.1f° field of view (%s), %s; orientation corrected by %.2f°, gain %.3f",
            photos[i].name.c_str(), spaces[i].c_str(), photos[i].lens.horizontalFovDegrees(),
            photos[i].lens.source.c_str(),
            photos[i].saturation > 0.0f ? "clipping at white" : "HDR", result.correctionDegrees[i],
            double(result.gains[i]));
        notes.push_back(line);
      }
      for (const auto& n : result.notes) notes.push_back(n);
      notes.push_back(
          "cube faces " + std::to_string(cube.size()) + "x" + std::to_string(cube.size()) +
          (faceSizeFrom.empty() ? std::string(" (--size)")
                                : " (as fine as the coarsest photo's pixels: " + faceSizeFrom +
                                      "; --size sets it)") +
          ", colour space '" + target + "'");
      notes.push_back(percent(result.coverage.uncovered) +
                      " of the sphere was seen by no photo and filled from its surroundings" +
                      (result.coverage.partial > 0.0
                           ? ", " + percent(result.coverage.partial) + " blended into the fill"
                           : std::string()));
      std::string timing;
      for (const auto& [step, s] : result.seconds) {
        char t[64];
        std::snprintf(t, sizeof t, "%s%s %.2f s", timing.empty() ? "" : ", ", step.c_str(), s);
        timing += t;
      }
      char w[64];
      std::snprintf(w, sizeof w, ", write %.2f s", writeSeconds);
      notes.push_back("time: " + timing + w);
      for (const auto& n : notes) std::fprintf(stderr, "compose: note: %s\n", printable(n).c_str());
    }
    for (const auto& w : result.warnings)
      std::fprintf(stderr, "compose: warning: %s\n", printable(w).c_str());
    for (const auto& w : written) std::printf("%s\n", w.c_str());
    return 0;
  };
}

}  // namespace compose::app
