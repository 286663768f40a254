// compose merge: bracketed exposures → scene-linear OpenEXR. One bracket from the command line,
// or every view of a capture description.
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "app/cli.h"
#include "color/color.h"
#include "core/output_files.h"
#include "hdr/capture_merge.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"

namespace compose::app {

namespace {

struct MergeOptions {
  std::vector<std::filesystem::path> images;
  std::filesystem::path out, capture, responseDir;
  std::string exposures, response = "auto", recovery = "debevec", method = "debevec";
  std::string inputSpace, linearSpace;
  // Float radiance: ZIP is smaller than PIZ on it and as fast to write.
  std::string compression = "zip";
  std::string depth = "float";
  bool align = false, deghost = false, noRefit = false, curvePerChannel = false;
  hdr::CaptureMergeOptions merge;
};

std::vector<ingest::ImageAttribute> exrAttributes(const hdr::CaptureMergeResult& result,
                                                  const hdr::MergedView& view,
                                                  const ingest::Capture& capture) {
  std::vector<ingest::ImageAttribute> a;
  std::vector<float> exposures(view.exposures.begin(), view.exposures.end());
  std::string files;
  for (const auto& f : view.files) files += (files.empty() ? "" : ";") + f.filename().string();
  a.push_back({"compose:relativeExposures", exposures});
  a.push_back({"compose:sourceFiles", files});
  // The exposures the radiance is divided by: EXIF's t·ISO/N², or the numbers given for them
  // (--exposures, a capture description's), whatever their unit.
  const ingest::View* source = nullptr;
  for (const ingest::View& v : capture.views)
    if (v.name == view.name) source = &v;
  bool fromExif = source != nullptr;
  if (source) {
    for (const ingest::Shot& s : source->shots) {
      const std::optional<double> own = s.info.relativeExposure();
      if (!s.exposure || !own || std::abs(*s.exposure / *own - 1.0) > 1e-6) fromExif = false;
    }
  }
  const std::string per = fromExif ? "linear value / (t * ISO / N^2)"
                                   : "linear value / (the relative exposure given for each photo)";
  a.push_back(
      {"compose:radianceUnit",
       !result.response.empty()  // 8-bit photos were linearised by a curve
           ? per + ", 8-bit photos' linear values scaled so that code 118 (middle grey) decodes as "
                   "the sRGB curve decodes it"
           : per + ", in the photos' own linear unit"});
  a.push_back({"compose:linearisation", result.linearisation});
  if (!result.response.empty())
    a.push_back({"compose:response", result.response.method + ": " + result.response.source});
  a.push_back({"compose:clippedPixels", int(view.stats.saturated + view.stats.dark)});
  // The radiance is in the camera's EXIF exposure unit when every photo of the view is 8-bit
  // and merged at its own EXIF exposure (not --exposures, not a description's numbers).
  bool exifUnit = source && !result.response.empty();
  if (source) {
    for (const ingest::Shot& s : source->shots)  // every photo names the camera of the unit
      if (!ingest::atOwnExifExposure(s) || s.info.camera().empty()) exifUnit = false;
  }
  if (exifUnit) a.push_back({"compose:exposureUnit", std::string(ingest::kExifExposureUnit)});
  // The photos were turned upright by their EXIF orientation; the merged view is stored upright
  // and says how, so that a lens calibrated in the sensor's frame is turned for it (stitch).
  if (source && !source->shots.empty()) {
    const int turn = source->shots.front().info.orientation;
    const bool same =
        std::all_of(source->shots.begin(), source->shots.end(),
                    [&](const ingest::Shot& s) { return s.info.orientation == turn; });
    if (same && turn != 1) a.push_back({"compose:sensorOrientation", turn});
  }
  // The lens of the view's photos (focal length, its 35 mm equivalent, the focal plane's
  // resolution): stitch finds its intrinsics in the merged view as in the photos.
  if (source && !source->shots.empty()) {
    for (ingest::ImageAttribute& e : ingest::exifAttributes(source->shots.front().info))
      if (e.name.rfind("Exif:Focal", 0) == 0) a.push_back(std::move(e));
  }
  if (!capture.cameraMake.empty()) a.push_back({"Make", capture.cameraMake});
  if (!capture.cameraModel.empty()) a.push_back({"Model", capture.cameraModel});
  return a;
}

}  // namespace

Runner setupMerge(CLI::App& command, const Globals& globals) {
  auto o = std::make_shared<MergeOptions>();
  command.footer(
      "Merge a bracket of exposures (8-bit JPEGs, 16-bit TIFFs, ...) into scene-linear radiance "
      "in the working colour space, written as float OpenEXR with a 'clipped' mask channel.\n"
      "The camera's response is recovered with OpenCV and kept per camera (Make/Model) in "
      "$COMPOSE_RESPONSE_DIR, else $XDG_CACHE_HOME/compose/responses, else "
      "~/.cache/compose/responses (--response-dir); later merges reuse it.\n\n"
      "Examples:\n  compose merge --out hdr.exr IMG_0101.jpg IMG_0102.jpg IMG_0103.jpg\n"
      "  compose merge --out hdr.exr --exposures 0.25,1,4 --align a.jpg b.jpg c.jpg\n"
      "  compose merge --capture capture.json --out merged/     # every view, one exposure scale");
  command.add_option("images", o->images, "The photos of one bracket, in any order");
  command
      .add_option("--out", o->out,
                  "Output EXR (one bracket) or folder (with --capture: <folder>/<view>.exr)")
      ->required();
  addCompressionOption(command, o->compression);
  command
      .add_option("--depth", o->depth,
                  "EXR sample type: float, or half (half the size; a view with values beyond "
                  "half's range, 65504, is written as float and a note says so)")
      ->capture_default_str();
  command.add_option("--capture", o->capture,
                     "JSON capture description (compose ingest --json, compose capture-sim)");
  command.add_option("--exposures", o->exposures,
                     "Relative exposures t1,t2,... in the order of the images (overrides EXIF; "
                     "exposure times in seconds at a fixed aperture and ISO will do)");
  command.add_flag("--align", o->align, "Align hand-held shots (OpenCV AlignMTB, translation)");
  command.add_option("--max-shift", o->merge.merge.maxShift, "Alignment search range, pixels")
      ->capture_default_str();
  command.add_flag("--deghost", o->deghost,
                   "Leave out, per pixel, shots that disagree with the reference (moving things)");
  command
      .add_option("--ghost-stops", o->merge.merge.ghostStops, "Ghost suppression threshold, stops")
      ->capture_default_str();
  command
      .add_option("--response", o->response,
                  "auto (the camera's stored curve, else recover), recover, colorspace (decode "
                  "by the files' colour space), or a response file")
      ->capture_default_str();
  command.add_option("--recovery", o->recovery, "Response recovery: debevec or robertson")
      ->capture_default_str();
  command.add_option("--samples", o->merge.recovery.samples, "Debevec: patches sampled")
      ->capture_default_str();
  command.add_option("--lambda", o->merge.recovery.lambda, "Debevec: smoothness")
      ->capture_default_str();
  command.add_flag("--no-refit", o->noRefit,
                   "Debevec: keep OpenCV's fit from --samples patches instead of solving it again "
                   "over every smooth patch");
  command.add_flag("--curve-per-channel", o->curvePerChannel,
                   "Recover a response curve per channel, each from its own pixels, instead of one "
                   "tone curve for the three (as a camera's JPEG engine applies one after white "
                   "balance): for a film scan, or a camera with a curve per channel (a recovery "
                   "option: with --response auto it applies when no curve is stored for the "
                   "camera)");
  command
      .add_option("--refit-smoothness", o->merge.recovery.refitSmoothness,
                  "Debevec: smoothness of the fit over every patch, relative to the data")
      ->capture_default_str();
  command.add_option("--merge-method", o->method, "8-bit merge: debevec or robertson (OpenCV)")
      ->capture_default_str();
  command.add_option("--response-dir", o->responseDir,
                     "Folder of per-camera response curves [default: $COMPOSE_RESPONSE_DIR, "
                     "else $XDG_CACHE_HOME/compose/responses, else ~/.cache/compose/responses]");
  command.add_option("--input-space", o->inputSpace,
                     "Colour space of the photos [default: declared by the files]");
  command.add_option("--linear-space", o->linearSpace,
                     "The camera's linear RGB for 8-bit photos [default: linear Rec.709]");

  return [o, &command, &globals]() -> int {
    hdr::CaptureMergeOptions& m = o->merge;
    // Options of a step that does not run are refused, not ignored.
    if (command.count("--max-shift") && !o->align)
      throw UsageError("--max-shift is the alignment's range: it goes with --align");
    if (command.count("--ghost-stops") && !o->deghost)
      throw UsageError(
          "--ghost-stops is the ghost suppression's threshold: it goes with --deghost");
    if (o->response != "auto" && o->response != "recover") {
      for (const char* option : {"--recovery", "--samples", "--lambda", "--no-refit",
                                 "--refit-smoothness", "--curve-per-channel"}) {
        if (command.count(option)) {
          throw UsageError(std::string(option) +
                           " is for recovering a response, which --response " + o->response +
                           " does not do");
        }
      }
    }
    // The command line first: nothing is read until it is known to be sound.
    if (o->depth != "float" && o->depth != "half")
      throw UsageError("--depth must be float or half, got '" + o->depth + "'");
    if (o->capture.empty() && o->images.empty())
      throw UsageError("give the photos of a bracket, or --capture FILE");
    if (!o->capture.empty() && !o->images.empty())
      throw UsageError("give either --capture or photos, not both");
    std::vector<double> exposures;
    if (!o->exposures.empty()) {
      if (!o->capture.empty()) throw UsageError("--exposures applies to photos given directly");
      exposures = parseList(o->exposures, "--exposures");
      for (double e : exposures)
        if (!(e >= ingest::kMinExposure && e <= ingest::kMaxExposure))
          throw UsageError("--exposures must be relative exposures between 1e-12 and 1e12");
      const auto [lo, hi] = std::minmax_element(exposures.begin(), exposures.end());
      if (exposures.size() > 1 && std::log2(*hi / *lo) < 1.0 / 6.0)
        throw UsageError("--exposures are all equal: a bracket needs different exposures");
      if (exposures.size() != o->images.size()) {
        throw UsageError("--exposures has " + std::to_string(exposures.size()) +
                         (exposures.size() == 1 ? " value" : " values") + " for " +
                         std::to_string(o->images.size()) +
                         (o->images.size() == 1 ? " photo" : " photos"));
      }
    }
    if (o->response == "auto") {
      m.response = hdr::ResponseMode::Auto;
    } else if (o->response == "recover") {
      m.response = hdr::ResponseMode::Recover;
    } else if (o->response == "colorspace" || o->response == "srgb") {
      m.response = hdr::ResponseMode::ColorSpace;
    } else {
      m.response = hdr::ResponseMode::File;
      m.responseFile = o->response;
    }
    if (o->recovery == "debevec") {
      m.recovery.method = hdr::RecoveryMethod::Debevec;
    } else if (o->recovery == "robertson") {
      m.recovery.method = hdr::RecoveryMethod::Robertson;
    } else {
      throw UsageError("--recovery must be debevec or robertson, got '" + o->recovery + "'");
    }
    if (o->method == "debevec") {
      m.merge.method = hdr::MergeMethod::Debevec;
    } else if (o->method == "robertson") {
      m.merge.method = hdr::MergeMethod::Robertson;
    } else {
      throw UsageError("--merge-method must be debevec or robertson, got '" + o->method + "'");
    }
    m.merge.align = o->align;
    m.recovery.refit = !o->noRefit;
    m.recovery.sharedCurve = !o->curvePerChannel;
    for (const char* option : {"--recovery", "--samples", "--lambda", "--no-refit",
                               "--refit-smoothness", "--curve-per-channel"})
      if (command.count(option)) m.recoveryOptions.push_back(option);
    m.merge.deghost = o->deghost;
    if (!o->responseDir.empty()) m.responseFolder = o->responseDir;
    asUsage([&] { m.validate(); });
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    // Colour-space names are checked against the config before any photo is read.
    asUsage([&] {
      if (!o->inputSpace.empty()) m.inputSpace = colors.resolve(o->inputSpace, "--input-space");
      if (!o->linearSpace.empty()) m.linearSpace = colors.resolve(o->linearSpace, "--linear-space");
    });
    if (o->capture.empty() && o->out.extension() != ".exr")
      throw UsageError("--out must name an .exr file (or a folder, with --capture)");
    if (o->capture.empty()) OutputFiles::check(o->out, "merge");
    if (!o->capture.empty() && ingest::looksLikeImageFile(o->out)) {
      throw UsageError(
          "with --capture, --out is a folder (one EXR per view, named by the views); '" +
          o->out.string() + "' names an image file");
    }

    // Group, resolve exposures, read.
    ingest::Capture capture;
    if (!o->capture.empty()) {
      capture = ingest::readCaptureDescription(o->capture);
    } else {
      capture.views.push_back(ingest::View{o->out.stem().string(), {}, {}});
      std::vector<std::filesystem::path> leftOut, rawPairs;
      for (const auto& s : ingest::scanShots(o->images, "merge", &leftOut, &rawPairs))
        capture.views[0].shots.push_back(s);
      if (!leftOut.empty() && !globals.quiet)
        std::fprintf(stderr, "compose: note: %s\n", printable(leftOutNote(leftOut)).c_str());
      if (!rawPairs.empty() && !globals.quiet)
        std::fprintf(stderr, "compose: note: %s\n", printable(rawPairsNote(rawPairs)).c_str());
      if (capture.views[0].shots.size() != o->images.size() && !exposures.empty())
        throw UsageError("--exposures needs one value per photo merged: " +
                         std::to_string(capture.views[0].shots.size()) + " photos from " +
                         std::to_string(o->images.size()) +
                         " paths (folders given, or JPEGs of RAW+JPEG pairs left out)");
      if (!exposures.empty()) ingest::setExposures(capture.views[0], exposures, "--exposures");
      capture.method = "the photos given";
    }
    ingest::resolveExposures(capture);  // checks too that the photos are one camera's
    for (const std::string& w : ingest::captureWarnings(capture))
      std::fprintf(stderr, "compose: warning: %s\n", printable(w).c_str());
    if (o->capture.empty()) {
      for (const ingest::Shot& s : capture.views[0].shots) {  // the first photo that names one
        if (s.info.camera().empty()) continue;
        capture.cameraMake = s.info.cameraMake;
        capture.cameraModel = s.info.cameraModel;
        break;
      }
    }
    ProgressPrinter printer(globals);
    std::vector<std::vector<ingest::LoadedImage>> photos =
        hdr::readCapturePhotos(capture, printer.callback());

    const hdr::CaptureMergeResult result =
        hdr::mergeCapture(capture, photos, m, colors, printer.callback());
    photos.clear();

    // Write every output together: the EXRs and, when recovered here, the camera's response.
    OutputFiles outputs("merge");
    std::vector<std::filesystem::path> written;
    std::vector<std::string> promoted;
    for (const auto& view : result.views) {
      const std::filesystem::path dst = o->capture.empty() ? o->out : o->out / (view.name + ".exr");
      ingest::WriteOptions w;
      w.depth = o->depth == "half" ? ingest::WriteOptions::Depth::Half
                                   : ingest::WriteOptions::Depth::Float;
      w.attributes = exrAttributes(result, view, capture);
      w.chromaticities = colors.chromaticities(view.radiance.colorSpace);
      w.exrCompression = o->compression;
      const ingest::WriteReport report = ingest::writeImage(outputs, dst, view.radiance, w);
      if (report.promotedToFloat) {
        char text[64];
        std::snprintf(text, sizeof text, "%g", double(report.largestMagnitude));
        promoted.push_back(dst.string() + ": values up to " + text +
                           " exceed half float's range (65504): written as 32-bit float");
      }
      written.push_back(dst);
    }
    if (result.responseRecovered && !result.responseCacheFile.empty()) {
      writeTextFile(outputs.add(result.responseCacheFile), hdr::responseText(result.response),
                    "merge");
    }
    outputs.commit();
    printNotes(globals, promoted);

    if (!globals.quiet) {
      if (!result.linearisation.empty())
        std::fprintf(stderr, "compose: %s\n", result.linearisation.c_str());
      if (result.responseRecovered && !result.responseCacheFile.empty())
        std::fprintf(stderr, "compose: response saved to %s (reused by later merges with %s %s)\n",
                     result.responseCacheFile.string().c_str(), capture.cameraMake.c_str(),
                     capture.cameraModel.c_str());
      for (const auto& view : result.views) {
        std::string stops;
        for (double e : view.exposures) {
          char text[24];
          std::snprintf(text, sizeof text, "%s%+.1f", stops.empty() ? "" : " ",
                        std::log2(e / view.exposures.front()));
          stops += text;
        }
        std::string outside;
        if (view.stats.outside > 0)
          outside = " (" + std::to_string(view.stats.outside) + " beyond the picture)";
        std::fprintf(stderr, "compose: %-8s %zu photo%s (EV %s), %lld clipped pixels%s\n",
                     view.name.c_str(), view.files.size(), view.files.size() == 1 ? "" : "s",
                     stops.c_str(), static_cast<long long>(view.stats.saturated + view.stats.dark),
                     outside.c_str());
      }
      std::fprintf(stderr, "compose: merged in %.2f s (%.2f s inside OpenCV)\n", result.seconds,
                   result.openCvSeconds);
    }
    printNotes(globals, result.notes);
    for (const auto& f : written) std::printf("%s\n", f.string().c_str());
    return 0;
  };
}

}  // namespace compose::app
