// Captures: photos grouped into views (directions the camera looked in) and, per view, a bracket
// of exposures. This is what the merge stage takes and what the stitch stage needs to know about
// each view.
//
// Three ways to get one:
//  * groupByExif(): shots ordered by EXIF DateTimeOriginal (else by file name) are cut into views
//    where the time gap to the previous shot exceeds a limit, or where the exposure sequence
//    starts again (an exposure already present in the current view), or where a view is full
//    (when the bracket size is known).
//  * groupByPattern(): a file-name pattern with a {view} placeholder; files whose {view} part is
//    the same form one view.
//  * readCaptureDescription(): an explicit JSON capture description (written by `compose ingest
//    --json`, `compose capture-sim`, or by hand). Format, version 1 (paths relative to the file):
//
//      {
//        "format": "compose-capture", "version": 1,
//        "camera": {"make": "Canon", "model": "EOS 5D"},        // optional
//        "lens": "camera.json",                                 // optional lens file
//        (calib/lens.h) "groundTruth": "truth.json",                           // optional, virtual
//        camera only "views": [
//          {"name": "nz",
//           "worldFromCamera": [[1,0,0],[0,1,0],[0,0,1]],       // optional rotation, rows
//           "colorSpace": "sRGB",                               // optional, for every exposure
//           "exposures": [
//             {"file": "nz_1.jpg", "exposureTime": 0.008, "fNumber": 8, "iso": 100},
//             {"file": "nz_2.jpg", "exposure": 0.5}             // or a relative exposure
//           ]}]
//      }
//
//    Exposure fields are optional: a shot without them takes its exposure from EXIF. The camera
//    frame is the project's (+X right, +Y up, looking along -Z); worldFromCamera is the rotation
//    the photographer intended (nominal, to be refined by stitching).
//
// resolveExposures() sorts the shots of each view by increasing exposure. Exposures are *relative*:
// t · ISO / N² (CaptureInfo::relativeExposure), or the values given in the description or on the
// command line. Errors throw compose::Error (stage "ingest") naming the file.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <glm/mat3x3.hpp>

#include "ingest/image_io.h"

namespace compose::ingest {

struct Shot {
  std::filesystem::path file;
  CaptureInfo info;                // from the file's header (readCaptureInfo)
  std::optional<double> exposure;  // relative exposure used for merging; empty = unknown
  std::string exposureSource;      // "EXIF", "capture description", "--exposures", ...
  std::string colorSpace;          // colour space declared by a capture description, else empty
  std::string filledFromBracket;   // "ISO 200": what EXIF lacked, taken from the bracket's others
};

struct View {
  std::string name;
  std::vector<Shot> shots;  // the bracket, by increasing exposure
  std::optional<glm::dmat3> worldFromCamera;
};

struct Capture {
  std::vector<View> views;
  std::string cameraMake, cameraModel;
  std::filesystem::path lensFile;     // empty if none
  std::filesystem::path groundTruth;  // empty if none
  std::string method;                 // how it was grouped, for messages
};

// Shots from files and folders (folders: every image file inside, not recursive, by name). Reads
// headers only. Throws if a file cannot be read or nothing is found. With `leftOut`, the files of
// a folder that say no exposure time in their EXIF, where others of that folder do, are left out
// and listed there (files named one by one are always kept). With `rawPairs`, the JPEG of a
// camera's RAW+JPEG pair (the same name and capture time beside a raw file) is left out and
// listed there: the raw file is the deeper record of the same shot.
std::vector<Shot> scanShots(const std::vector<std::filesystem::path>& paths,
                            const std::string& stage = "ingest",
                            std::vector<std::filesystem::path>* leftOut = nullptr,
                            std::vector<std::filesystem::path>* rawPairs = nullptr);

struct ExifGrouping {
  double maxGapSeconds = 3.0;  // a longer pause between shots starts a new view
  int bracketSize = 0;  // > 0: views are runs of exactly this many shots (pauses not looked at)
  // Two exposures within this ratio (in stops) count as the same exposure.
  double sameExposureStops = 1.0 / 6.0;
  void validate() const;  // compose::Error (stage "ingest")
};

Capture groupByExif(std::vector<Shot> shots, const ExifGrouping& options);

// `pattern` is matched against the whole file name: {view} matches the view's key (at least one
// character, as many as the rest of the pattern leaves: garden_px_1.jpg is view garden_px of
// {view}_{bracket}.jpg), {bracket} (at least one character, as few as it can) and * any text, ?
// one character; everything else literally. A bracket part that holds the separator needs the
// pattern to say so: px_1_m2ev.png is view px of {view}_{bracket}_*.png (of {view}_{bracket}.png
// it is view px_1). Files that do not match are an error naming the first of them.
Capture groupByPattern(std::vector<Shot> shots, const std::string& pattern);

// Reads a JSON capture description and the headers of the files it names.
Capture readCaptureDescription(const std::filesystem::path& file);
// Writes one (atomically); file paths are written relative to the description's folder when they
// lie below it.
void writeCaptureDescription(const std::filesystem::path& file, const Capture& capture);
// The text writeCaptureDescription() would write (for OutputFiles users).
std::string captureDescriptionText(const std::filesystem::path& file, const Capture& capture);

// Sets every shot's exposure from EXIF where it has none, checks the result and sorts each view
// by increasing exposure: every shot needs an exposure (error naming the first file without one,
// suggesting --exposures), and a view of more than one shot needs at least two different
// exposures (error naming the view's files). A file given twice, photos whose EXIF names two
// cameras, or a camera other than the description's are errors naming the file.
// A shot whose EXIF lacks the ISO or the f-number that the other photos of its view state
// (a tool that dropped a tag, a lens without contacts) takes theirs when they agree: its exposure
// assumed ISO 100 or f/1, stops off the others'. Shot::filledFromBracket says what was taken,
// and captureWarnings() says it. Photos of the view that state different values are an error
// naming the file. Called by resolveExposures(); again is harmless.
void fillFromBracket(Capture& capture);
void resolveExposures(Capture& capture);

// The range of relative exposures (t·ISO/N², or the values of --exposures) the merge accepts:
// beyond it radiance overflows single precision (1e-300 gave infinities in the EXR) or
// vanishes below it.
inline constexpr double kMinExposure = 1e-12, kMaxExposure = 1e12;

// Overrides the exposures of a single view from a list (e.g. --exposures): the list must have
// one value per shot, in the order the shots were given.
void setExposures(View& view, const std::vector<double>& exposures, const std::string& source);

// Whether a shot is an 8-bit photo merged at its own EXIF exposure (t · ISO / N², every field in
// EXIF), so that merged radiance is in the camera's EXIF exposure unit (kExifExposureUnit).
bool atOwnExifExposure(const Shot& shot);

// When every shot of `view` has both an exposure given (setExposures) and one in EXIF, and the
// two disagree beyond EXIF's rounding (the given ones order the photos otherwise, or a ratio
// between two photos differs by more than a third of a stop): a sentence saying so, naming the
// photos. Empty otherwise. (The given list wins; a wrong one silently scales the radiance.)
std::string exposureContradiction(const View& view);

// What may make a resolved capture's views disagree, or its views not be views, each said in a
// sentence: exposures given that contradict EXIF (exposureContradiction()); views whose EXIF
// exposures rest on different assumptions (one view's photos without an f-number, taken as f/1,
// beside views whose photos say theirs: off by N²); views whose given exposures stand at another
// scale to their EXIF than other views' do; and a view holding one exposure several times (the
// photos of several directions grouped as one view, which a merge would average).
std::vector<std::string> captureWarnings(const Capture& capture);

// A human-readable summary: one line per view with its shots and exposures in stops.
std::vector<std::string> describeCapture(const Capture& capture);

}  // namespace compose::ingest
