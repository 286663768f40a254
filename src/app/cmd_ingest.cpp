// compose ingest: what the photos say about themselves (EXIF) and how they group into views and
// brackets. Reads headers only.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

#include "app/cli.h"
#include "cubemap/layouts.h"
#include "ingest/capture.h"

namespace compose::app {

namespace {

struct IngestOptions {
  std::vector<std::filesystem::path> paths;
  std::filesystem::path capture, json;
  std::string group = "auto", pattern, exposures;
  double maxGap = 3.0;
  int brackets = 0;
};

std::string exposureTime(const std::optional<double>& t) {
  if (!t) return "-";
  char text[32];
  if (*t < 0.5) {
    std::snprintf(text, sizeof text, "1/%g s", std::round(1.0 / *t * 10.0) / 10.0);
  } else {
    std::snprintf(text, sizeof text, "%g s", *t);
  }
  return text;
}

std::string number(const std::optional<double>& v, const char* format) {
  if (!v) return "-";
  char text[32];
  std::snprintf(text, sizeof text, format, *v);
  return text;
}

}  // namespace

Runner setupIngest(CLI::App& command, const Globals& globals) {
  auto o = std::make_shared<IngestOptions>();
  command.footer(
      "Read the EXIF of photos (exposure time, f-number, ISO, focal lengths, focal-plane "
      "resolution, camera, capture time), print it, and group the photos into views and "
      "brackets.\n\nExample:\n  compose ingest ~/photos/hdr-session/\n  compose ingest "
      "--pattern '{view}_*.jpg' --json capture.json shots/");
  command.add_option("paths", o->paths, "Photos and folders of photos");
  command
      .add_option("--group", o->group,
                  "Grouping: exif (capture times and exposure sequences), pattern (needs "
                  "--pattern), json (needs --capture), or auto")
      ->capture_default_str();
  command.add_option("--pattern", o->pattern,
                     "File-name pattern with a {view} placeholder, e.g. '{view}_{bracket}.jpg'");
  command.add_option("--capture", o->capture, "Read this JSON capture description instead");
  command
      .add_option("--max-gap", o->maxGap,
                  "EXIF grouping: a pause longer than this (seconds) "
                  "starts a new view")
      ->capture_default_str();
  command
      .add_option("--brackets", o->brackets,
                  "EXIF grouping: photos per view, when known (views are then runs of exactly "
                  "this many photos in capture order)")
      ->check(positiveNumber());
  command.add_option("--exposures", o->exposures,
                     "Relative exposures t1,t2,... overriding EXIF, in the order the photos are "
                     "given (a folder's by name), as compose merge takes them (one view only)");
  command.add_option("--json", o->json, "Write the grouping as a JSON capture description");

  return [o, &command, &globals]() -> int {
    // Everything the command line alone can refute, before a file is read.
    std::string group = o->group;
    if (group == "auto")
      group = !o->capture.empty() ? "json" : (!o->pattern.empty() ? "pattern" : "exif");
    if (group != "exif" && group != "pattern" && group != "json")
      throw UsageError("--group must be exif, pattern, json or auto, got '" + o->group + "'");
    if (group == "json" && o->capture.empty()) throw UsageError("--group json needs --capture");
    if (group == "pattern" && o->pattern.empty())
      throw UsageError("--group pattern needs --pattern");
    if (group == "json" && !o->paths.empty())
      throw UsageError("give either --capture or photos, not both");
    if (group != "json" && o->paths.empty()) throw UsageError("no photos given");
    // Options of a grouping that does not run are refused, not ignored.
    for (const char* option : {"--max-gap", "--brackets"}) {
      if (group != "exif" && command.count(option) > 0) {
        throw UsageError(std::string(option) +
                         " is the EXIF grouping's; it goes with --group exif (the grouping here "
                         "is " +
                         group + ")");
      }
    }
    // A bracket size is the grouping (runs of that many photos): pauses are not looked at.
    if (command.count("--brackets") > 0 && command.count("--max-gap") > 0)
      throw UsageError(
          "--max-gap and --brackets are two ways of finding the views: --brackets takes runs of "
          "that many photos and looks at no pause; give one of them");
    if (group != "pattern" && !o->pattern.empty())
      throw UsageError("--pattern goes with --group pattern (or auto); the grouping here is " +
                       group);
    if (group != "json" && !o->capture.empty())
      throw UsageError("--capture goes with --group json (or auto); the grouping here is " + group);
    if (group == "pattern" && o->pattern.find("{view}") == std::string::npos)
      throw UsageError("--pattern needs a {view} placeholder, e.g. '{view}_{bracket}.jpg'; got '" +
                       o->pattern + "'");
    ingest::ExifGrouping exif;
    exif.maxGapSeconds = o->maxGap;
    exif.bracketSize = o->brackets;
    asUsage([&] { exif.validate(); });
    std::vector<double> exposures;
    if (!o->exposures.empty()) exposures = parseList(o->exposures, "--exposures");
    for (double e : exposures)
      if (!(e >= ingest::kMinExposure && e <= ingest::kMaxExposure))
        throw UsageError("--exposures must be relative exposures between 1e-12 and 1e12");

    ingest::Capture capture;
    // --exposures by the photos' order on the command line: grouping sorts them by capture time
    // (or name), and the list was taken in that order (the shortest exposure given to the photo
    // named second when it was taken first), where compose merge takes the order given.
    std::map<std::filesystem::path, double> givenExposure;
    if (group == "json") {
      capture = ingest::readCaptureDescription(o->capture);
    } else {
      std::vector<std::filesystem::path> leftOut, rawPairs;
      auto shots = ingest::scanShots(o->paths, "ingest", &leftOut, &rawPairs);
      if (!leftOut.empty() && !globals.quiet)
        std::fprintf(stderr, "compose: note: %s\n", printable(leftOutNote(leftOut)).c_str());
      if (!rawPairs.empty() && !globals.quiet)
        std::fprintf(stderr, "compose: note: %s\n", printable(rawPairsNote(rawPairs)).c_str());
      if (!exposures.empty() && exposures.size() == shots.size())
        for (size_t i = 0; i < shots.size(); ++i) givenExposure[shots[i].file] = exposures[i];
      capture = group == "pattern" ? ingest::groupByPattern(std::move(shots), o->pattern)
                                   : ingest::groupByExif(std::move(shots), exif);
    }
    if (!exposures.empty()) {
      if (capture.views.size() != 1) {
        throw UsageError("--exposures applies to one view, but the photos form " +
                         std::to_string(capture.views.size()) + " views");
      }
      ingest::View& view = capture.views[0];
      if (!givenExposure.empty()) {
        for (size_t i = 0; i < view.shots.size(); ++i)
          exposures[i] = givenExposure[view.shots[i].file];
      }
      ingest::setExposures(view, exposures, "--exposures");  // checked below
      // The bracket by increasing exposure, as grouping orders it.
      std::stable_sort(
          view.shots.begin(), view.shots.end(),
          [](const ingest::Shot& a, const ingest::Shot& b) { return *a.exposure < *b.exposure; });
    }

    // The table: one line per photo, as found.
    std::vector<std::string> notes;
    std::printf("%-24s %-11s %-6s %-10s %-5s %-6s %-9s %-7s %-7s %-22s %s\n", "photo", "size",
                "type", "exposure", "f/", "ISO", "rel. EV", "focal", "35mm", "camera", "taken");
    for (const auto& view : capture.views) {
      for (const auto& s : view.shots) {
        const auto& i = s.info;
        const auto rel = s.exposure ? s.exposure : i.relativeExposure();
        const bool derived = i.focalLength35mm && i.focal35mmSource.rfind("derived", 0) == 0;
        std::string f35 = number(i.focalLength35mm, derived ? "%.1f mm" : "%.0f mm");
        if (derived) f35 += "*";
        std::printf("%-24s %-11s %-6s %-10s %-5s %-6s %-9s %-7s %-7s %-22s %s\n",
                    s.file.filename().string().c_str(),
                    // As seen (after the EXIF orientation), as merge and stitch report it.
                    (i.orientation >= 5 && i.orientation <= 8
                         ? std::to_string(i.fileHeight) + "x" + std::to_string(i.fileWidth)
                         : std::to_string(i.fileWidth) + "x" + std::to_string(i.fileHeight))
                        .c_str(),
                    i.sampleType.c_str(), exposureTime(i.exposureTime).c_str(),
                    number(i.fNumber, "%.1f").c_str(), number(i.iso, "%.0f").c_str(),
                    rel ? number(std::log2(*rel), "%+.2f").c_str() : "-",
                    number(i.focalLengthMm, "%.1f mm").c_str(), f35.c_str(),
                    i.camera().empty() ? "-" : printable(i.camera()).c_str(),
                    i.dateTimeOriginal.empty() ? "-" : printable(i.dateTimeOriginal).c_str());
        if (!i.focalLength35mm) {
          notes.push_back(s.file.filename().string() +
                          ": no 35 mm equivalent focal length (FocalLengthIn35mmFilm is 0 or "
                          "missing and no focal-plane resolution): the plate camera assumes 50 mm "
                          "unless --focal35 is given");
        } else if (derived && i.focal35mmSource.find("rounds to") == std::string::npos) {
          notes.push_back(s.file.filename().string() + ": 35 mm equivalent " + i.focal35mmSource +
                          " (marked *)");
        }
        if (!s.exposure && i.exposureTime && !i.exposureAssumptions().empty())
          notes.push_back(s.file.filename().string() + ": exposure assumes " +
                          i.exposureAssumptions());
        if (!rel)
          notes.push_back(s.file.filename().string() +
                          ": no exposure time in EXIF; merging needs --exposures");
      }
    }
    if (group == "exif") {
      // Views whose photos' names all say one cube face (px_1.jpg px_2.jpg px_3.jpg) or one turn
      // of a ring (yaw120_1.jpg, as capture-sim names them) are named for it, so that the
      // description tells compose --env and stitch where they point.
      std::vector<std::string> faces(capture.views.size());
      for (size_t v = 0; v < capture.views.size(); ++v) {
        for (const ingest::Shot& s : capture.views[v].shots) {
          const auto token = cubemap::faceFromPhotoName(s.file);
          const std::string stem = s.file.stem().string();
          const std::optional<double> yaw = cubemap::yawFromName(stem);
          char turn[16];
          std::snprintf(turn, sizeof turn, "yaw%03d", yaw ? int(*yaw) : 0);
          const std::string name = token ? token->token : yaw ? std::string(turn) : std::string();
          if (name.empty() || (!faces[v].empty() && name != faces[v])) {
            faces[v].clear();
            break;
          }
          faces[v] = name;
        }
      }
      int named = 0;
      for (size_t v = 0; v < capture.views.size(); ++v) {
        if (faces[v].empty() || std::count(faces.begin(), faces.end(), faces[v]) > 1) continue;
        capture.views[v].name = faces[v];
        ++named;
      }
      if (named > 0)
        capture.method += "; views named for the cube face or turn in their photos' names";
    }
    std::printf("\ngrouped by %s: %zu view%s\n", capture.method.c_str(), capture.views.size(),
                capture.views.size() == 1 ? "" : "s");
    try {  // a field one photo of a bracket lacks, from the others (merge does the same)
      ingest::fillFromBracket(capture);
    } catch (const Error&) {  // said below, as what merge will refuse
    }
    for (auto& v : capture.views)
      for (auto& s : v.shots)
        if (!s.exposure && s.info.relativeExposure()) {
          s.exposure = s.info.relativeExposure();
          s.exposureSource = "EXIF";
        }
    for (const auto& line : ingest::describeCapture(capture)) std::printf("  %s\n", line.c_str());
    size_t size0 = capture.views.front().shots.size();
    for (const auto& v : capture.views)
      if (v.shots.size() != size0)
        notes.push_back(
            "views have different numbers of photos: check the grouping (--max-gap, "
            "--brackets, --pattern)");
    try {  // what merge will say of this capture, said now
      ingest::Capture check = capture;
      ingest::resolveExposures(check);
      for (const std::string& w : ingest::captureWarnings(check))
        notes.push_back("compose merge will warn: " + w);
    } catch (const Error& e) {
      notes.push_back(std::string("compose merge will refuse this capture: ") + e.what());
    }
    // Duplicate notes (one per photo) are common; print each once.
    std::vector<std::string> unique;
    for (const auto& n : notes)
      if (std::find(unique.begin(), unique.end(), n) == unique.end()) unique.push_back(n);
    printNotes(globals, unique);
    if (!o->json.empty()) {
      ingest::writeCaptureDescription(o->json, capture);
      std::printf("%s\n", o->json.string().c_str());
    }
    return 0;
  };
}

}  // namespace compose::app
