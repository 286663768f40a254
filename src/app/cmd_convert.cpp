// compose convert: environment maps between layouts (lat-long, OpenEXR cube, crosses, six faces)
// and mirror-ball photos to environments.
#include <cmath>
#include <cstdio>
#include <optional>
#include <utility>

#include "app/cli.h"
#include "color/color.h"
#include "core/channels.h"
#include "core/error.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/output_files.h"
#include "cubemap/environment_io.h"
#include "cubemap/mirror_ball.h"
#include "ingest/image_io.h"
#include "lighting/sphere_resample.h"

namespace compose::app {

namespace {

struct ConvertOptions {
  std::vector<std::string> inputs;
  std::string to, from, out, depth = "float", faceNames = "pxnx", photoSpace, outSpace,
                             compression = "piz";
  int size = 0, width = 0;  // 0: not given
  double blindSpot = 10.0;
  CLI::Option *sizeOption = nullptr, *widthOption = nullptr, *blindSpotOption = nullptr;
};

std::string fraction(double f) {
  char s[32];
  std::snprintf(s, sizeof s, "%.2f %%", 100.0 * f);
  return s;
}

double energyDifference(const glm::dvec3& a, const glm::dvec3& b) {
  double worst = 0.0;
  for (int c = 0; c < 3; ++c) {
    const double scale = std::max(std::abs(a[c]), std::abs(b[c]));
    if (scale > 0.0) worst = std::max(worst, std::abs(a[c] - b[c]) / scale);
  }
  return worst;
}

// A resampled map's values converted from the linear space they were averaged in to the
// space its file holds (sRGB codes for a PNG).
void encodeCube(const color::ColorConfig& colors, lighting::CubeMap& cube, const std::string& from,
                const std::string& to) {
  for (int f = 0; f < lighting::kCubeFaces; ++f) {
    Image face = cube.faceImage(f);
    face.colorSpace = from;
    colors.convert(face, to);
    std::copy(face.pixels.begin(), face.pixels.end(), cube.face(f).begin());
  }
  cube.colorSpace = to;
}

lighting::Environment encodedLatLong(const color::ColorConfig& colors,
                                     const lighting::Environment& map, const std::string& from,
                                     const std::string& to) {
  Image image(map.width(), map.height(), 3, {"R", "G", "B"});
  image.pixels.assign(map.texels().begin(), map.texels().end());
  image.colorSpace = from;
  colors.convert(image, to);
  lighting::SanitizeReport keep;
  keep.keepNegative = true;
  return lighting::Environment::fromLatLong(image, {}, &keep);
}

}  // namespace

Runner setupConvert(CLI::App& cmd, const Globals& globals) {
  auto o = std::make_shared<ConvertOptions>();
  cmd.description(
      "Convert an environment map between layouts, or unwrap a mirror-ball photo.\n\n"
      "Layouts: latlong (2:1), cube (OpenEXR's 1:6 strip, envmap=cube), hcross (4:3), vcross "
      "(3:4), faces (six files), mirrorball (a square crop of a chrome ball; input only).\n"
      "The input's layout is detected from an EXR's envmap attribute or the aspect ratio; square "
      "images need --from. Resampling is area-exact: the integral of the radiance is kept.\n\n"
      "Examples:\n"
      "  compose convert forest.exr --to cube --out forest_cube.exr\n"
      "  compose convert cross.hdr --to latlong --width 2048 --out env.exr\n"
      "  compose convert env_%.exr --to vcross --out cross.exr       (% stands for px, nx, ...)\n"
      "  compose convert ball.jpg --from mirrorball --to latlong --out env.exr");
  cmd.add_option("inputs", o->inputs,
                 "Environment: an image, a folder of six faces, a face-name pattern with %, or six "
                 "face files")
      ->required();
  cmd.add_option("--to", o->to, "Output layout: latlong, cube, hcross, vcross, faces")->required();
  cmd.add_option("--out", o->out,
                 "Output file; for --to faces a name with % (replaced by the face names) or a "
                 "base name that gets _px, _nx, ...")
      ->required();
  cmd.add_option("--from,--layout", o->from,
                 "Input layout when it cannot be detected: latlong, cube, hcross, vcross, faces, "
                 "mirrorball");
  o->sizeOption = cmd.add_option(
      "--size", o->size, "Cube face size in texels [default: lat-long width / 4, or as read]");
  o->widthOption = cmd.add_option(
      "--width", o->width, "Lat-long width in texels, even [default: 4 x face size, or as read]");
  cmd.add_option("--depth", o->depth,
                 "EXR sample type: float, half, or auto (half unless values exceed its range)")
      ->capture_default_str();
  cmd.add_option("--face-names", o->faceNames,
                 "Names of face files: pxnx, posneg, exr (+X ...), words")
      ->capture_default_str();
  addCompressionOption(cmd, o->compression);
  cmd.add_option("--photo-space", o->photoSpace,
                 "Mirror ball: colour space of the photo [default: from the file]; it is "
                 "linearised before unwrapping");
  cmd.add_option("--out-space", o->outSpace,
                 "Mirror ball: colour space of the result [default: what the config's file rules "
                 "say for --out]");
  o->blindSpotOption =
      cmd.add_option(
             "--blind-spot", o->blindSpot,
             "Mirror ball: degrees around the direction behind the ball that are filled from "
             "their surroundings instead of read")
          ->capture_default_str();

  return [o, &cmd, &globals]() -> int {
    using cubemap::Layout;
    // Every value is checked before any file is read.
    const auto to = cubemap::parseLayout(o->to);
    if (!to || *to == Layout::MirrorBall) {
      throw UsageError("--to must be one of latlong, cube, hcross, vcross, faces; got '" + o->to +
                       "'");
    }
    // One file (faces: one per face, named from a pattern), checked before any photo is read.
    if (*to != Layout::Faces) OutputFiles::check(o->out, "output");
    std::optional<Layout> from;
    if (!o->from.empty()) {
      from = cubemap::parseLayout(o->from);
      if (!from) {
        throw UsageError("--from must be one of " + join(cubemap::layoutNames()) + "; got '" +
                         o->from + "'");
      }
    }
    const bool sizeGiven = o->sizeOption->count() > 0;
    bool widthGiven = o->widthOption->count() > 0;
    if (sizeGiven && (o->size < 1 || o->size > 16384))
      throw UsageError("--size must be 1..16384 texels; got " + std::to_string(o->size));
    if (widthGiven && (o->width < 2 || o->width > 65536 || o->width % 2 != 0)) {
      throw UsageError("--width must be an even number of texels, 2..65536; got " +
                       std::to_string(o->width));
    }
    // --width is a lat-long's; --size a cube's faces, or for a lat-long 4 x size wide.
    if (widthGiven && *to != Layout::LatLong)
      throw UsageError("--width is the width of a lat-long output; the faces of --to " + o->to +
                       " take --size");
    if (*to == Layout::LatLong && sizeGiven) {
      if (widthGiven)
        throw UsageError("--size and --width both set the lat-long's width: give one of them");
      o->width = 4 * o->size;  // at most 65536, as --width
      widthGiven = true;
    }
    // The size asked for is held to the pixel limit like an input's (a 40000-wide lat-long is
    // 800 megapixels, 13 GB of float RGBA with its working copies).
    const int64_t limit = resourceLimits().maxPixels;
    const auto tooLarge = [&](const std::string& option, int value, int64_t pixels) {
      // In megapixels, or in pixels for a limit below one megapixel.
      const bool mega = limit >= 1000000;
      const auto count = [&](int64_t n) {
        return mega ? std::to_string((n + 500000) / 1000000) : std::to_string(n);
      };
      return UsageError(option + " " + std::to_string(value) + " makes a map of " + count(pixels) +
                        (mega ? " megapixels" : " pixels") + ", more than the limit of " +
                        (mega ? std::to_string(limit / 1000000) : count(limit)) +
                        " (raise it with --max-pixels)");
    };
    if (sizeGiven && 6 * int64_t(o->size) * o->size > limit)
      throw tooLarge("--size", o->size, 6 * int64_t(o->size) * o->size);
    if (widthGiven && int64_t(o->width) * (o->width / 2) > limit)
      throw tooLarge("--width", o->width, int64_t(o->width) * (o->width / 2));
    cubemap::WriteOptions write = environmentWriteOptions(o->depth, o->faceNames);
    write.exrCompression = o->compression;
    // The files written: for --to faces, the six face files the name gives (a base name
    // without an extension, or a folder, gets OpenEXR's).
    const std::filesystem::path firstOut = firstEnvironmentFile(o->out, *to, write);
    refuseUnusedWriteOptions(cmd, *to, firstOut);
    ingest::requireImageWriter(firstOut);
    cubemap::MirrorBallOptions ball;
    ball.blindSpotDegrees = o->blindSpot;
    ball.validate();
    if (from == Layout::MirrorBall && o->inputs.size() != 1)
      throw UsageError("--from mirrorball takes one photo");
    if (from != Layout::MirrorBall) {
      // Options of the unwrapping only: given for another layout they would be ignored.
      const char* given = !o->photoSpace.empty()            ? "--photo-space"
                          : !o->outSpace.empty()            ? "--out-space"
                          : o->blindSpotOption->count() > 0 ? "--blind-spot"
                                                            : nullptr;
      if (given) {
        throw UsageError(std::string(given) +
                         " applies to a mirror-ball photo only (with --from mirrorball); an "
                         "environment map keeps the colour space it was written in");
      }
    }

    ProgressPrinter printer(globals);
    std::vector<std::string> notes;
    std::vector<std::filesystem::path> inputs(o->inputs.begin(), o->inputs.end());

    // Read into either a lat-long environment or a cube map.
    lighting::Environment latLong;
    lighting::CubeMap cube;
    glm::dvec3 energyIn(0.0);
    lighting::SanitizeReport sanitized;
    sanitized.keepNegative = true;  // a conversion of layouts changes no value
    // Values resampled in linear light, written in a space that is not linear: from, to.
    std::optional<std::pair<std::string, std::string>> encodeAs;
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    if (from == Layout::MirrorBall) {
      ingest::LoadedImage photo =
          ingest::readImage(inputs.front(), "ingest", {.picturePart = true});
      // Unwrapping averages pixels: it happens on linear radiance.
      const std::string target = o->outSpace.empty() ? colors.inputSpaceFor(firstOut, "")
                                                     : colors.resolve(o->outSpace, "--out-space");
      ingest::requireColourChannels(photo.image, inputs.front(), "ingest", "the mirror ball");
      notes.insert(notes.end(), photo.notes.begin(), photo.notes.end());
      const int ballWidth = photo.image.width, ballHeight = photo.image.height;
      write.sixteenBit = photo.info.sampleType == "uint16";
      Image rgb = pictureRgb(std::move(photo.image));  // by channel name, not as stored
      rgb.colorSpace =
          !o->photoSpace.empty()
              ? colors.resolve(o->photoSpace, "--photo-space")
              : colors
                    .inputSpace(ingest::nameForRules(inputs.front(), photo.info.format),
                                photo.info.fileColorSpace, false, photo.info.integerSamples())
                    .space;
      // Averaged in linear light: the target's space when it is linear, else the working space
      // (any linear space averages alike: a matrix commutes with the mean), and encoded as the
      // file is read afterwards.
      const std::string through = colors.isLinearOrData(target) ? target : colors.workingSpace();
      notes.push_back("mirror ball read as '" + rgb.colorSpace + "', unwrapped in '" + through +
                      "'" + (through != target ? ", written as '" + target + "'" : std::string()));
      colors.convert(rgb, through);
      if (through != target) encodeAs = {through, target};
      write.chromaticities = colors.chromaticities(target);
      ball.faceSize = o->size > 0 && *to != Layout::LatLong ? o->size : 0;
      cubemap::MirrorBallResult unwrapped =
          cubemap::unwrapMirrorBall(rgb, ball, inputs.front(), printer.callback());
      cube = std::move(unwrapped.cube);
      energyIn = cube.integral();
      notes.push_back("mirror ball " + std::to_string(ballWidth) + "x" +
                      std::to_string(ballHeight) + " unwrapped; " +
                      fraction(unwrapped.coverage.uncovered) +
                      " of the sphere (behind the ball) filled from its surroundings, " +
                      fraction(unwrapped.coverage.partial) + " blended towards the fill");
    } else {
      cubemap::ReadOptions read;
      read.layout = from;
      cubemap::EnvironmentFile file = cubemap::readEnvironmentFile(inputs, read);
      notes.insert(notes.end(), file.notes.begin(), file.notes.end());
      notes.push_back("read " + file.describe() + " (" + file.how + ")");
      // Values are resampled as stored when they are linear light; the colour metadata goes
      // along, and the camera and exposure unit of a map stitched from merged photos.
      write.chromaticities = file.info.chromaticities;
      {
        // Only what every file says (six faces: each of them).
        std::string make = file.info.cameraMake, model = file.info.cameraModel,
                    unit = file.info.exposureUnit;
        for (size_t f = 1; f < file.files.size(); ++f) {
          const ingest::CaptureInfo other = ingest::readCaptureInfo(file.files[f], "ingest", true);
          if (other.cameraMake != make || other.cameraModel != model) make = model = unit = "";
          if (other.exposureUnit != unit) unit.clear();
        }
        if (!make.empty()) write.strings.emplace_back("Make", make);
        if (!model.empty()) write.strings.emplace_back("Model", model);
        if (!unit.empty()) write.strings.emplace_back("compose:exposureUnit", unit);
      }
      if (file.layout == Layout::MirrorBall) {
        throw UsageError("a mirror ball is unwrapped with --from mirrorball (one photo)");
      }
      // An OpenEXR's chromaticities say its primaries, as compose --env reads them: the space
      // of the config with those primaries is the name written, not the generic 'Linear'
      // OpenImageIO gives every EXR without a colorSpace; with no such space, the
      // chromaticities alone go along.
      std::string declared = file.info.fileColorSpace;
      if (file.info.chromaticities) {
        declared = colors.spaceWithChromaticities(*file.info.chromaticities);
        if (!declared.empty())
          notes.push_back("read as '" + declared + "' (by the chromaticities in its header)");
      }
      const bool codesRead = file.info.sampleType == "uint8" || file.info.sampleType == "uint16";
      if (!file.info.chromaticities && !codesRead) {
        // Floats with no primaries in the header: the space the config takes them as (OpenEXR's
        // convention, linear Rec.709 with the built-in config), written by its name and with its
        // chromaticities rather than OpenImageIO's generic 'Linear'.
        declared =
            colors
                .inputSpace(ingest::nameForRules(file.files.front(), file.info.format),
                            file.info.fileColorSpace, file.info.colorSpaceByConvention, false)
                .space;
        if (!write.chromaticities) write.chromaticities = colors.chromaticities(declared);
      }
      file.image.colorSpace = declared;
      for (Image& face : file.faces) face.colorSpace = declared;
      // Codes of an 8- or 16-bit picture (an sRGB JPEG, a PNG) written into a format of floats
      // are made linear first, as compose reads such a picture with --env: an OpenEXR holds
      // linear light, and other tools take it so. The other way round, linear light written
      // into 8-bit codes is encoded as compose (and other tools) will read those files.
      // Resampling averages light: values in a space that is not linear are made linear before
      // it and encoded again after it (sRGB codes averaged as stored lose light: a checkerboard
      // of 0 and 1 came out 0.21, not 0.5).
      write.sixteenBit = file.info.sampleType == "uint16";
      const std::string ext = ingest::lowerExtension(firstOut);
      const bool floatsOut = ext == ".exr" || ext == ".hdr";
      const bool codesIn = file.info.sampleType == "uint8" || file.info.sampleType == "uint16";
      const bool byMatrix = file.info.chromaticities && declared.empty();
      const std::string source =
          byMatrix ? std::string("the RGB space of the chromaticities in its header")
          : file.info.chromaticities
              ? declared
              : colors
                    .inputSpace(ingest::nameForRules(file.files.front(), file.info.format),
                                declared, false, file.info.integerSamples())
                    .space;
      // A Radiance file says no primaries: it is read as the config's rules say, so it is
      // written in that space. Codes written as codes keep their space.
      const bool recode = floatsOut == codesIn || ext == ".hdr";
      const std::string target = recode ? colors.inputSpaceFor(firstOut, "") : source;
      const bool sourceLinear = byMatrix || colors.isLinearOrData(source);
      // Linear light is resampled as stored unless its file's space changes.
      const std::string through = !recode && sourceLinear         ? source
                                  : colors.isLinearOrData(target) ? target
                                  : sourceLinear && !byMatrix     ? source
                                                                  : colors.workingSpace();
      if (source != through) {
        auto linearise = [&](Image& image) {
          if (byMatrix) {  // by matrix into the working space, then as any other space
            colors.convertFromChromaticities(image, *file.info.chromaticities,
                                             colors.workingSpace(), file.files.front());
          } else {
            image.colorSpace = source;
          }
          colors.convert(image, through);
        };
        if (file.isCube()) {
          for (Image& face : file.faces) linearise(face);
        } else {
          linearise(file.image);
        }
      }
      if (through != target) encodeAs = {through, target};
      if (source != target) {
        write.chromaticities = colors.chromaticities(target);
        notes.push_back("its " + file.info.sampleType + " values read as '" + source +
                        "' and written as '" + target + "' (as " + firstOut.extension().string() +
                        " files are read)" +
                        (through != target ? ", resampled in '" + through + "'" : std::string()));
      } else if (through != target) {
        notes.push_back("its " + file.info.sampleType + " values ('" + source +
                        "') resampled in '" + through + "'");
      } else if (file.info.chromaticities && declared.empty()) {
        notes.push_back(
            "the header's chromaticities match no space of the colour config: "
            "written with them and no space name");
      }
      if (file.isCube()) {
        cube = cubemap::cubeMapOf(file, &sanitized);
        energyIn = cube.integral();
      } else {
        latLong = lighting::Environment::fromLatLong(file.image, file.files.front(), &sanitized);
        energyIn = lighting::integral(latLong);
      }
    }
    if (sanitized.negativeTexels > 0) notes.push_back(sanitized.negativeNote(""));
    // Negative texels are kept (out-of-gamut colours, ringing of a resampling), but light that
    // sums to less than nothing is no environment.
    for (int c = 0; c < 3; ++c) {
      if (!(energyIn[c] < 0.0)) continue;
      throw Error("ingest",
                  std::string("the environment's ") +
                      (c == 0   ? "red"
                       : c == 1 ? "green"
                                : "blue") +
                      " radiance sums to " + numberText(energyIn[c]) +
                      " over the sphere: its negative texels outweigh its light, which no "
                      "environment does",
                  inputs.front());
    }

    // Convert.
    OutputFiles outputs("output");
    std::vector<std::string> written;
    glm::dvec3 energyOut(0.0);
    if (*to == Layout::LatLong) {
      lighting::Environment result;
      if (!cube.empty()) {
        const int width = o->width > 0 ? o->width : 4 * cube.size();
        // The default, 4N x 2N for faces of N, is a third more texels than the cube's 6N^2.
        if (int64_t(width) * (width / 2) > limit) {
          throw Error("output",
                      "a lat-long map of faces " + std::to_string(cube.size()) + " wide is " +
                          std::to_string(width) + "x" + std::to_string(width / 2) +
                          ", more pixels than the limit (--max-pixels " + std::to_string(limit) +
                          "): give a smaller --width, or raise the limit",
                      o->out);
        }
        result = lighting::latLongFromCube(cube, width, printer.callback());
      } else {
        result = o->width > 0 && o->width != latLong.width()
                     ? lighting::resizeLatLong(latLong, o->width)
                     : latLong;
      }
      energyOut = lighting::integral(result);
      if (encodeAs) result = encodedLatLong(colors, result, encodeAs->first, encodeAs->second);
      for (auto& n : cubemap::writeLatLong(outputs, o->out, result, write)) notes.push_back(n);
      written.push_back(o->out);
    } else {
      lighting::CubeMap result;
      if (!cube.empty()) {
        result = o->size > 0 && o->size != cube.size() ? lighting::resizeCube(cube, o->size) : cube;
      } else {
        const int size = o->size > 0 ? o->size : std::max(1, latLong.width() / 4);
        result = lighting::cubeFromLatLong(latLong, size, printer.callback());
      }
      energyOut = result.integral();
      if (encodeAs) encodeCube(colors, result, encodeAs->first, encodeAs->second);
      for (auto& n : cubemap::writeCubeMap(outputs, o->out, result, *to, write)) notes.push_back(n);
      if (*to == Layout::Faces) {
        for (const auto& p : cubemap::facePaths(o->out, write.faceNaming)) written.push_back(p);
      } else {
        written.push_back(o->out);
      }
    }
    outputs.commit();
    char energy[160];
    std::snprintf(energy, sizeof energy,
                  "radiance integrated over the sphere, resampled, agrees with the input to "
                  "%.1e (relative)",
                  energyDifference(energyIn, energyOut));
    notes.push_back(energy);
    if (!globals.quiet) {
      for (const auto& n : notes) std::fprintf(stderr, "compose: note: %s\n", printable(n).c_str());
    }
    for (const auto& w : written) std::printf("%s\n", w.c_str());
    return 0;
  };
}

}  // namespace compose::app
