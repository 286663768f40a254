#include "ingest/capture.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <initializer_list>
#include <iterator>
#include <limits>
#include <map>
#include <regex>
#include <set>

#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/json_keys.h"
#include "core/json_number.h"
#include "core/limits.h"
#include "core/output_files.h"

namespace compose::ingest {

namespace fs = std::filesystem;

namespace {

constexpr const char* kStage = "ingest";

// Natural order: "img2" before "img10".
bool naturalLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (std::isdigit(static_cast<unsigned char>(a[i])) &&
        std::isdigit(static_cast<unsigned char>(b[j]))) {
      size_t ie = i, je = j;
      while (ie < a.size() && std::isdigit(static_cast<unsigned char>(a[ie]))) ++ie;
      while (je < b.size() && std::isdigit(static_cast<unsigned char>(b[je]))) ++je;
      const std::string na = a.substr(i, ie - i), nb = b.substr(j, je - j);
      const std::string ta = na.substr(std::min(na.find_first_not_of('0'), na.size()));
      const std::string tb = nb.substr(std::min(nb.find_first_not_of('0'), nb.size()));
      if (ta.size() != tb.size()) return ta.size() < tb.size();
      if (ta != tb) return ta < tb;
      i = ie;
      j = je;
    } else {
      if (a[i] != b[j]) return a[i] < b[j];
      ++i;
      ++j;
    }
  }
  return a.size() - i < b.size() - j;
}

bool shotNameLess(const Shot& a, const Shot& b) {
  return naturalLess(a.file.filename().string(), b.file.filename().string());
}

std::string stops(double exposure, double reference) {
  char text[32];
  std::snprintf(text, sizeof text, "%+.1f EV", std::log2(exposure / reference));
  return text;
}

void fillCamera(Capture& capture) {
  for (const View& v : capture.views) {
    for (const Shot& s : v.shots) {
      if (capture.cameraMake.empty() && capture.cameraModel.empty()) {
        capture.cameraMake = s.info.cameraMake;
        capture.cameraModel = s.info.cameraModel;
      }
    }
  }
}

// Whether two headers name one camera: Make and Model compared without letter case (firmware
// and editors write "Canon" or "CANON"; the stored responses' file names are lower case), a Make
// missing on either side not counting against it.
bool sameCamera(const CaptureInfo& a, const CaptureInfo& b) {
  auto lower = [](std::string t) {
    std::string out;
    for (unsigned char c : t)
      if (!std::isspace(c)) out.push_back(char(std::tolower(c)));
    return out;
  };
  const std::string makeA = lower(a.cameraMake), makeB = lower(b.cameraMake);
  if (!makeA.empty() && !makeB.empty() && makeA != makeB) return false;
  std::string modelA = lower(a.cameraModel), modelB = lower(b.cameraModel);
  // Some cameras repeat the make in the model ("Canon EOS R5" under Make "Canon").
  for (std::string* m : {&modelA, &modelB})
    for (const std::string& make : {makeA, makeB})
      if (!make.empty() && m->rfind(make, 0) == 0) m->erase(0, make.size());
  return modelA == modelB;
}

std::string relativeTo(const fs::path& file, const fs::path& folder) {
  std::error_code ec;
  const fs::path absFile = fs::absolute(file, ec);
  const fs::path absFolder = fs::absolute(folder.empty() ? fs::path(".") : folder, ec);
  const fs::path rel = absFile.lexically_normal().lexically_relative(absFolder.lexically_normal());
  if (!rel.empty() && *rel.begin() != "..") return rel.generic_string();
  return absFile.lexically_normal().generic_string();
}

}  // namespace

std::vector<Shot> scanShots(const std::vector<fs::path>& paths, const std::string& stage,
                            std::vector<fs::path>* leftOut, std::vector<fs::path>* rawPairs) {
  std::vector<Shot> shots;
  std::vector<int> folderOf;  // per shot: the index of the folder it was found in, or -1
  int folders = 0;
  for (const fs::path& p : paths) {
    std::error_code ec;
    if (fs::is_directory(p, ec)) {
      std::vector<Shot> inFolder;
      for (const auto& entry : fs::directory_iterator(p, ec)) {
        // Hidden files are not photos: macOS's "._IMG_0001.jpg" resource forks, editors' copies.
        if (!entry.is_regular_file(ec) || !looksLikeImageFile(entry.path()) ||
            entry.path().filename().string().front() == '.')
          continue;
        inFolder.push_back(Shot{entry.path(), {}, {}, {}, {}, {}});
      }
      if (ec) throw Error(stage, "cannot list the folder: " + ec.message(), p);
      if (inFolder.empty()) throw Error(stage, "no image files in the folder", p);
      std::sort(inFolder.begin(), inFolder.end(), shotNameLess);
      for (Shot& s : inFolder) {
        shots.push_back(std::move(s));
        folderOf.push_back(folders);
      }
      ++folders;
    } else {
      shots.push_back(Shot{p, {}, {}, {}, {}, {}});
      folderOf.push_back(-1);
    }
  }
  if (shots.empty()) throw Error(stage, "no photos given");
  for (Shot& s : shots) s.info = readCaptureInfo(s.file, stage);
  if (rawPairs) {
    // RAW+JPEG: a camera writes IMG_0001.CR2 and IMG_0001.JPG of one shot; merged together they
    // made views of two shots of the same exposure each. The JPEG is left out.
    auto isJpeg = [](const fs::path& f) {
      const std::string e = lowerExtension(f);
      return e == ".jpg" || e == ".jpeg";
    };
    auto isRaw = [](const fs::path& f) {
      static const char* const kRaw[] = {".dng", ".cr2", ".cr3", ".nef", ".arw",
                                         ".orf", ".rw2", ".raf", ".pef", ".srw"};
      const std::string e = lowerExtension(f);
      return std::any_of(std::begin(kRaw), std::end(kRaw), [&](const char* r) { return e == r; });
    };
    auto key = [](const fs::path& f) {
      std::string k = (f.parent_path() / f.stem()).string();
      std::transform(k.begin(), k.end(), k.begin(),
                     [](unsigned char c) { return char(std::tolower(c)); });
      return k;
    };
    std::map<std::string, const Shot*> raws;
    for (const Shot& s : shots)
      if (isRaw(s.file)) raws.emplace(key(s.file), &s);
    std::vector<Shot> kept;
    std::vector<int> keptFolder;
    for (size_t i = 0; i < shots.size(); ++i) {
      const Shot& s = shots[i];
      const auto raw = isJpeg(s.file) ? raws.find(key(s.file)) : raws.end();
      // The same second (a raw reader may give whole seconds where the JPEG has sub-seconds).
      if (raw != raws.end() &&
          (!s.info.captureSeconds || !raw->second->info.captureSeconds ||
           std::abs(*s.info.captureSeconds - *raw->second->info.captureSeconds) < 1.0)) {
        rawPairs->push_back(s.file);
        continue;
      }
      keptFolder.push_back(folderOf[i]);
      kept.push_back(s);
    }
    shots = std::move(kept);
    folderOf = std::move(keptFolder);
  }
  if (!leftOut) return shots;
  // In a folder where some photos say their exposure time and others do not, the others are not
  // photos of the brackets (a merged EXR, a panorama saved beside them): left out, and named.
  std::vector<bool> timed(size_t(folders), false), untimed(size_t(folders), false);
  for (size_t i = 0; i < shots.size(); ++i) {
    if (folderOf[i] < 0) continue;
    (shots[i].info.exposureTime ? timed : untimed)[size_t(folderOf[i])] = true;
  }
  std::vector<Shot> kept;
  for (size_t i = 0; i < shots.size(); ++i) {
    const int f = folderOf[i];
    if (f >= 0 && timed[size_t(f)] && untimed[size_t(f)] && !shots[i].info.exposureTime) {
      leftOut->push_back(shots[i].file);
      continue;
    }
    kept.push_back(std::move(shots[i]));
  }
  return kept;
}

void ExifGrouping::validate() const {
  if (!(maxGapSeconds > 0.0) || !std::isfinite(maxGapSeconds))
    throw Error(kStage, "the time gap between views must be a positive number of seconds");
  if (bracketSize < 0) throw Error(kStage, "the bracket size must be a positive number of photos");
  if (!(sameExposureStops > 0.0 && sameExposureStops < 1.0))
    throw Error(kStage, "the same-exposure tolerance must be between 0 and 1 stop");
}

Capture groupByExif(std::vector<Shot> shots, const ExifGrouping& options) {
  options.validate();
  Capture capture;
  const bool timed = std::all_of(shots.begin(), shots.end(),
                                 [](const Shot& s) { return s.info.captureSeconds.has_value(); });
  if (timed) {
    std::stable_sort(shots.begin(), shots.end(), [](const Shot& a, const Shot& b) {
      if (*a.info.captureSeconds != *b.info.captureSeconds)
        return *a.info.captureSeconds < *b.info.captureSeconds;
      return shotNameLess(a, b);
    });
    capture.method = "EXIF capture times (a new view after a pause of more than " +
                     std::to_string(int(std::lround(options.maxGapSeconds))) +
                     " s) and exposure sequences";
  } else {
    capture.method = "file names and exposure sequences (not every photo has an EXIF capture time)";
  }
  if (options.bracketSize > 0) {
    // A known bracket size is the grouping: consecutive runs of exactly that many photos.
    const size_t n = size_t(options.bracketSize);
    if (shots.size() % n != 0) {
      throw Error(kStage, std::to_string(shots.size()) + " photos do not make brackets of " +
                              std::to_string(n) + " (the bracket size given): " +
                              std::to_string(shots.size() % n) + " left over");
    }
    capture.method = std::string(timed ? "EXIF capture times" : "file names") + ", " +
                     std::to_string(n) + " photos per view (the bracket size given)";
  }
  View* current = nullptr;
  double previousTime = 0.0;
  for (Shot& s : shots) {
    bool startNew = current == nullptr;
    if (options.bracketSize > 0) {
      if (!startNew && int(current->shots.size()) >= options.bracketSize) startNew = true;
      if (startNew) {
        capture.views.push_back(View{});
        current = &capture.views.back();
      }
      current->shots.push_back(std::move(s));
      continue;
    }
    if (!startNew && timed && *s.info.captureSeconds - previousTime > options.maxGapSeconds)
      startNew = true;
    // A photo without the ISO or f-number the view's photos state is taken at theirs, as
    // fillFromBracket() takes it (at ISO 100 or f/1 it would seem stops off the bracket).
    auto exposureOf = [&](const Shot& shot) {
      CaptureInfo info = shot.info;
      for (auto it = current->shots.rbegin(); it != current->shots.rend(); ++it) {
        if (!info.iso) info.iso = it->info.iso;
        if (!info.fNumber) info.fNumber = it->info.fNumber;
      }
      return info.relativeExposure();
    };
    const auto e = startNew ? s.info.relativeExposure() : exposureOf(s);
    if (!startNew && e) {
      // An exposure the view has already: the next direction's bracket.
      std::vector<double> stops;  // the view's exposures so far, in stops
      for (const Shot& o : current->shots)
        if (const auto oe = exposureOf(o)) stops.push_back(std::log2(*oe));
      const double here = std::log2(*e);
      double nearest = std::numeric_limits<double>::infinity();
      for (const double x : stops) nearest = std::min(nearest, std::abs(here - x));
      if (nearest < options.sameExposureStops) startNew = true;
      // Off the steps of the bracket so far (a stop off a bracket 2 EV apart): the next
      // direction's bracket, metered anew (auto-exposure bracketing on a panoramic head). The
      // step is the closest two exposures' distance, to the nearest third of a stop (shutter
      // speeds are rounded: 1/125 to 1/60 is 1.06 stops), and the new one is measured from its
      // nearest neighbour, so that the rounding of a long bracket does not add up.
      double step = std::numeric_limits<double>::infinity();
      for (size_t a = 0; a < stops.size(); ++a)
        for (size_t b = a + 1; b < stops.size(); ++b)
          if (const double apart = std::abs(stops[a] - stops[b]);
              apart >= options.sameExposureStops)
            step = std::min(step, apart);
      step = std::round(step * 3.0) / 3.0;
      if (!startNew && std::isfinite(step) && step >= 0.9) {
        const double at = nearest / step;
        if (std::abs(at - std::round(at)) * step > 1.0 / 3.0) startNew = true;
      }
    }
    if (startNew) {
      capture.views.push_back(View{});
      current = &capture.views.back();
    }
    // A pause is from the end of one exposure to the start of the next (EXIF's capture time is
    // the start): a 16 s shot of a night bracket is no pause.
    if (timed) previousTime = *s.info.captureSeconds + s.info.exposureTime.value_or(0.0);
    current->shots.push_back(std::move(s));
  }
  const int digits = capture.views.size() >= 10 ? 2 : 1;
  for (size_t i = 0; i < capture.views.size(); ++i) {
    char name[40];
    std::snprintf(name, sizeof name, "view%0*zu", digits, i + 1);
    capture.views[i].name = name;
  }
  fillCamera(capture);
  return capture;
}

Capture groupByPattern(std::vector<Shot> shots, const std::string& pattern) {
  if (pattern.find("{view}") == std::string::npos)
    throw Error(kStage, "the file-name pattern '" + pattern + "' has no {view} placeholder");
  std::string re;
  for (size_t i = 0; i < pattern.size();) {
    if (pattern.compare(i, 6, "{view}") == 0) {
      re += "(.+)";  // greedy: a view's name may hold the separator (garden_px of garden_px_1)
      i += 6;
    } else if (pattern.compare(i, 9, "{bracket}") == 0) {
      re += ".+?";
      i += 9;
    } else if (pattern[i] == '*') {
      re += ".*?";
      ++i;
    } else if (pattern[i] == '?') {
      re += ".";
      ++i;
    } else {
      const char c = pattern[i++];
      if (std::string("\\^$.|+()[]{}").find(c) != std::string::npos) re += '\\';
      re += c;
    }
  }
  std::regex matcher;
  try {
    matcher = std::regex(re);
  } catch (const std::regex_error&) {
    throw Error(kStage, "cannot use the file-name pattern '" + pattern + "'");
  }
  std::stable_sort(shots.begin(), shots.end(), shotNameLess);
  Capture capture;
  capture.method = "file-name pattern " + pattern;
  std::map<std::string, size_t> index;
  for (Shot& s : shots) {
    std::smatch m;
    const std::string name = s.file.filename().string();
    if (!std::regex_match(name, m, matcher))
      throw Error(kStage, "file name does not match the pattern '" + pattern + "'", s.file);
    const std::string key = m[1].str();
    auto it = index.find(key);
    if (it == index.end()) {
      it = index.emplace(key, capture.views.size()).first;
      capture.views.push_back(View{key, {}, {}});
    }
    capture.views[it->second].shots.push_back(std::move(s));
  }
  fillCamera(capture);
  return capture;
}

Capture readCaptureDescription(const fs::path& file) try {
  protectInput(file);
  requireInputFile(file, kStage, "capture description");
  std::ifstream in(file);
  if (!in) throw Error(kStage, "cannot open the capture description", file);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (jsonNestedDeeperThan(text))
    throw Error(kStage,
                "its JSON nests deeper than " + std::to_string(kMaxJsonDepth) +
                    " levels: not a capture description",
                file);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    throw Error(kStage,
                std::string("not a valid JSON capture description: ") + jsonMessage(e.what()),
                file);
  }
  if (const std::string key = repeatedJsonKey(text); !key.empty())
    throw Error(kStage, "'" + key + "' is given twice: which one counts? Give it once", file);
  auto fail = [&](const std::string& what) -> void { throw Error(kStage, what, file); };
  if (!j.is_object()) fail("a capture description must hold a JSON object");
  if (j.value("format", std::string()) != "compose-capture")
    fail("not a capture description (\"format\" must be \"compose-capture\")");
  if (wholeMember(j, "version") != 1)
    fail("unsupported capture description version (this compose reads version 1)");
  if (!j.contains("views") || !j["views"].is_array() || j["views"].empty())
    fail("a capture description needs a non-empty \"views\" array");
  // A key this reader does not know is a misspelling (exposuretime) or a field of another tool:
  // left out without a word, its value silently did not count.
  auto onlyKnown = [&](const nlohmann::json& o, std::initializer_list<const char*> known,
                       const std::string& where) {
    for (const auto& item : o.items()) {
      if (std::none_of(known.begin(), known.end(),
                       [&](const char* k) { return item.key() == k; })) {
        std::string list;
        for (const char* k : known) list += std::string(list.empty() ? "" : ", ") + k;
        fail(where + "\"" + item.key() + "\" is not a field of a capture description (" + list +
             ")");
      }
    }
  };
  onlyKnown(j, {"format", "version", "camera", "lens", "groundTruth", "views"}, "");
  const fs::path folder = file.parent_path();
  auto resolvePath = [&](const std::string& p) {
    return fs::path(p).is_absolute() ? fs::path(p) : folder / p;
  };

  Capture capture;
  capture.method = "capture description " + file.string();
  if (j.contains("camera")) {
    if (!j["camera"].is_object()) fail("\"camera\" must be an object");
    onlyKnown(j["camera"], {"make", "model"}, "camera: ");
    capture.cameraMake = j["camera"].value("make", std::string());
    capture.cameraModel = j["camera"].value("model", std::string());
  }
  if (j.contains("lens")) {
    if (!j["lens"].is_string()) fail("\"lens\" must name a lens file");
    capture.lensFile = resolvePath(j["lens"].get<std::string>());
  }
  if (j.contains("groundTruth")) {
    if (!j["groundTruth"].is_string()) fail("\"groundTruth\" must name a file");
    capture.groundTruth = resolvePath(j["groundTruth"].get<std::string>());
  }
  auto positive = [&](const nlohmann::json& o, const char* key,
                      const std::string& where) -> std::optional<double> {
    if (!o.contains(key)) return std::nullopt;
    if (!o[key].is_number() || !(o[key].get<double>() > 0.0) ||
        !std::isfinite(o[key].get<double>()))
      fail(where + ": \"" + key + "\" must be a positive number");
    return o[key].get<double>();
  };
  std::map<std::string, int> names;
  for (const auto& jv : j["views"]) {
    const std::string where = "view " + std::to_string(capture.views.size() + 1);
    if (!jv.is_object()) fail(where + " must be an object");
    onlyKnown(jv, {"name", "worldFromCamera", "colorSpace", "exposures"}, where + ": ");
    View v;
    v.name = jv.value("name", "view" + std::to_string(capture.views.size() + 1));
    if (v.name.empty() || v.name.find_first_of("/\\") != std::string::npos)
      fail(where + ": a view name must be a non-empty plain name");
    if (names[v.name]++) fail("two views are named '" + v.name + "'");
    if (jv.contains("worldFromCamera")) {
      const auto& m = jv["worldFromCamera"];
      bool ok = m.is_array() && m.size() == 3;
      glm::dmat3 r(1.0);
      for (int row = 0; ok && row < 3; ++row) {
        ok = m[row].is_array() && m[row].size() == 3;
        for (int col = 0; ok && col < 3; ++col) {
          ok = m[row][col].is_number();
          if (ok) r[col][row] = m[row][col].get<double>();
        }
      }
      if (!ok) fail("view '" + v.name + "': \"worldFromCamera\" must be 3 rows of 3 numbers");
      // A rotation: orthonormal with determinant +1 (to a tolerance for hand-written files).
      const glm::dmat3 should = glm::transpose(r) * r;
      double err = std::abs(glm::determinant(r) - 1.0);
      for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) err = std::max(err, std::abs(should[a][b] - (a == b)));
      if (err > 1e-3) fail("view '" + v.name + "': \"worldFromCamera\" is not a rotation");
      v.worldFromCamera = r;
    }
    const std::string viewSpace = jv.value("colorSpace", std::string());
    if (!jv.contains("exposures") || !jv["exposures"].is_array() || jv["exposures"].empty())
      fail("view '" + v.name + "' needs a non-empty \"exposures\" array");
    for (const auto& je : jv["exposures"]) {
      if (!je.is_object() || !je.contains("file") || !je["file"].is_string())
        fail("view '" + v.name + "': every exposure needs a \"file\"");
      onlyKnown(je, {"file", "exposure", "exposureTime", "fNumber", "iso", "colorSpace"},
                "view '" + v.name + "', " + je["file"].get<std::string>() + ": ");
      Shot s;
      s.file = resolvePath(je["file"].get<std::string>());
      s.colorSpace = je.value("colorSpace", viewSpace);
      s.info = readCaptureInfo(s.file);
      const std::string at = "view '" + v.name + "', " + s.file.filename().string();
      const auto rel = positive(je, "exposure", at);
      const auto t = positive(je, "exposureTime", at);
      const auto n = positive(je, "fNumber", at);
      const auto iso = positive(je, "iso", at);
      if (rel) {
        s.exposure = rel;
        s.exposureSource = "capture description";
      } else if (t || n || iso) {
        // Fields given here override EXIF; missing ones come from EXIF (without an exposure
        // time in either, resolveExposures() says so).
        CaptureInfo merged = s.info;
        if (t) merged.exposureTime = t;
        if (n) merged.fNumber = n;
        if (iso) merged.iso = iso;
        s.exposure = merged.relativeExposure();
        s.exposureSource = t ? "capture description" : "capture description and EXIF";
        // What EXIF lacks, the description gives: the exposure rests on it, not on a default.
        if (!s.info.fNumber) s.info.fNumber = n;
        if (!s.info.iso) s.info.iso = iso;
      }
      v.shots.push_back(std::move(s));
    }
    capture.views.push_back(std::move(v));
  }
  fillCamera(capture);
  return capture;
} catch (const nlohmann::json::exception& e) {
  // A field of the wrong type (a number where text belongs, ...): nlohmann reports it by
  // exception; it is bad input like any other, named with its file.
  throw Error(kStage, std::string("not a valid capture description: ") + jsonMessage(e.what()),
              file);
}

std::string captureDescriptionText(const fs::path& file, const Capture& capture) {
  const fs::path folder = file.parent_path();
  nlohmann::ordered_json j;
  j["format"] = "compose-capture";
  j["version"] = 1;
  if (!capture.cameraMake.empty() || !capture.cameraModel.empty())
    j["camera"] = {{"make", capture.cameraMake}, {"model", capture.cameraModel}};
  if (!capture.lensFile.empty()) j["lens"] = relativeTo(capture.lensFile, folder);
  if (!capture.groundTruth.empty()) j["groundTruth"] = relativeTo(capture.groundTruth, folder);
  nlohmann::ordered_json views = nlohmann::ordered_json::array();
  for (const View& v : capture.views) {
    nlohmann::ordered_json jv;
    jv["name"] = v.name;
    if (v.worldFromCamera) {
      const glm::dmat3& r = *v.worldFromCamera;
      jv["worldFromCamera"] = {
          {r[0][0], r[1][0], r[2][0]}, {r[0][1], r[1][1], r[2][1]}, {r[0][2], r[1][2], r[2][2]}};
    }
    nlohmann::ordered_json exposures = nlohmann::ordered_json::array();
    for (const Shot& s : v.shots) {
      nlohmann::ordered_json je;
      je["file"] = relativeTo(s.file, folder);
      if (s.exposure) {
        if (s.exposureSource == "EXIF" && s.info.exposureTime) {
          je["exposureTime"] = *s.info.exposureTime;
          if (s.info.fNumber) je["fNumber"] = *s.info.fNumber;
          if (s.info.iso) je["iso"] = *s.info.iso;
        } else {
          je["exposure"] = *s.exposure;
        }
      }
      if (!s.colorSpace.empty()) je["colorSpace"] = s.colorSpace;
      exposures.push_back(je);
    }
    jv["exposures"] = exposures;
    views.push_back(jv);
  }
  j["views"] = views;
  return j.dump(2) + "\n";
}

void writeCaptureDescription(const fs::path& file, const Capture& capture) {
  // An older description may be replaced, nothing else (a photo named by mistake).
  requireReplaceable(
      file, "capture description",
      [](std::istream& in) {
        const nlohmann::json j = nlohmann::json::parse(in, nullptr, false);
        return j.is_object() && j.value("format", std::string()) == "compose-capture";
      },
      kStage);
  writeTextFile(file, captureDescriptionText(file, capture), kStage);
}

void setExposures(View& view, const std::vector<double>& exposures, const std::string& source) {
  if (exposures.size() != view.shots.size()) {
    throw Error(kStage, std::to_string(exposures.size()) +
                            (exposures.size() == 1 ? " exposure" : " exposures") + " given for " +
                            std::to_string(view.shots.size()) +
                            (view.shots.size() == 1 ? " photo" : " photos"));
  }
  for (size_t i = 0; i < exposures.size(); ++i) {
    if (!(exposures[i] >= kMinExposure && exposures[i] <= kMaxExposure)) {
      char text[160];
      std::snprintf(text, sizeof text,
                    "exposure %g (of %s) is not a relative exposure: they are between 1e-12 and "
                    "1e12",
                    exposures[i], view.shots[i].file.filename().string().c_str());
      throw Error(kStage, text);
    }
    view.shots[i].exposure = exposures[i];
    view.shots[i].exposureSource = source;
  }
}

bool atOwnExifExposure(const Shot& shot) {
  const std::optional<double> own = shot.info.relativeExposure();
  return shot.info.bitsPerSample == 8 && shot.exposure && own &&
         shot.info.exposureAssumptions().empty() && std::abs(*shot.exposure / *own - 1.0) <= 1e-6;
}

std::string exposureContradiction(const View& view) {
  const size_t n = view.shots.size();
  for (const Shot& s : view.shots)
    if (!s.exposure || !s.info.relativeExposure()) return {};
  double worst = 0.0;
  size_t worstI = 0, worstJ = 0;
  bool reordered = false;
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = i + 1; j < n; ++j) {
      const Shot& a = view.shots[i];
      const Shot& b = view.shots[j];
      const double given = std::log2(*b.exposure / *a.exposure);
      const double exif = std::log2(*b.info.relativeExposure() / *a.info.relativeExposure());
      const bool flipped =
          (given > 1.0 / 6.0 && exif < -1.0 / 6.0) || (given < -1.0 / 6.0 && exif > 1.0 / 6.0);
      if (flipped && !reordered) {
        reordered = true;
        worst = 0.0;
      }
      if ((flipped || !reordered) && std::abs(given - exif) > worst) {
        worst = std::abs(given - exif);
        worstI = i;
        worstJ = j;
      }
    }
  }
  if (!reordered && worst <= 1.0 / 3.0) return {};
  const Shot& a = view.shots[worstI];
  const Shot& b = view.shots[worstJ];
  char text[400];
  std::snprintf(text, sizeof text,
                "the exposures given (%s) %s their EXIF: %s to %s is %+.1f stops given, %+.1f "
                "stops by EXIF; the given ones are used (is their order that of the photos?)",
                a.exposureSource.c_str(),
                reordered ? "order the photos otherwise than" : "differ from",
                a.file.filename().string().c_str(), b.file.filename().string().c_str(),
                std::log2(*b.exposure / *a.exposure),
                std::log2(*b.info.relativeExposure() / *a.info.relativeExposure()));
  return text;
}

std::vector<std::string> captureWarnings(const Capture& capture) {
  std::vector<std::string> out;
  for (const View& v : capture.views)
    if (std::string w = exposureContradiction(v); !w.empty())
      out.push_back("view '" + v.name + "': " + w);
  // One exposure several times in a view: two exposures within a sixth of a stop are one.
  for (const View& v : capture.views) {
    size_t repeated = 0;
    for (size_t i = 1; i < v.shots.size(); ++i)
      if (v.shots[i].exposure && v.shots[i - 1].exposure &&
          std::abs(std::log2(*v.shots[i].exposure / *v.shots[i - 1].exposure)) < 1.0 / 6.0)
        ++repeated;
    if (repeated > 0) {
      out.push_back("view '" + v.name + "' holds " + std::to_string(v.shots.size()) + " photos, " +
                    std::to_string(repeated) +
                    " of them at an exposure another of its photos has: the photos of several "
                    "directions grouped as one view? A merge averages them (check the grouping: "
                    "--pattern, --max-gap, --brackets, or the capture description)");
    }
  }
  for (const View& v : capture.views)
    for (const Shot& s : v.shots)
      if (!s.filledFromBracket.empty())
        out.push_back(s.file.filename().string() + "'s EXIF lacks what the other photos of view '" +
                      v.name + "' state: taken as " + s.filledFromBracket + ", as theirs");
  if (capture.views.size() < 2) return out;
  // The views' scale: their exposures must rest on the same facts. An exposure from EXIF that
  // assumed a missing f-number or ISO is off by N² or the ISO ratio against views whose EXIF
  // says them; given exposures off their EXIF by a factor are off the views taken from EXIF.
  std::map<std::string, std::vector<std::string>> byAssumption;  // assumption → views
  std::vector<std::pair<std::string, double>> offsets;           // view → stops given - EXIF
  for (const View& v : capture.views) {
    std::set<std::string> assumed;
    std::vector<double> stops;
    for (const Shot& s : v.shots) {
      if (s.exposureSource == "EXIF") assumed.insert(s.info.exposureAssumptions());
      const std::optional<double> own = s.info.relativeExposure();
      if (s.exposure && own && s.info.exposureAssumptions().empty())
        stops.push_back(std::log2(*s.exposure / *own));
    }
    for (const std::string& a : assumed) byAssumption[a].push_back(v.name);
    if (!stops.empty()) {
      std::nth_element(stops.begin(), stops.begin() + ptrdiff_t(stops.size() / 2), stops.end());
      offsets.emplace_back(v.name, stops[stops.size() / 2]);
    }
  }
  auto listed = [](const std::vector<std::string>& names) {
    std::string s;
    for (size_t i = 0; i < names.size() && i < 6; ++i) s += (i ? ", " : "") + names[i];
    return names.size() > 6 ? s + ", ..." : s;
  };
  if (byAssumption.size() > 1) {
    for (const auto& [assumption, views] : byAssumption) {
      if (assumption.empty()) continue;
      out.push_back("the exposures of view" + std::string(views.size() > 1 ? "s " : " ") +
                    listed(views) + " assume " + assumption +
                    ", other views' photos say theirs: the views' radiance is on different "
                    "scales (give the missing field in the capture description)");
    }
  }
  if (offsets.size() > 1) {
    double lo = offsets.front().second, hi = lo;
    for (const auto& [name, stops] : offsets) lo = std::min(lo, stops), hi = std::max(hi, stops);
    if (hi - lo > 1.0 / 3.0) {
      std::string which;
      for (const auto& [name, stops] : offsets) {
        if (std::abs(stops) <= 1.0 / 6.0) continue;
        char text[96];
        std::snprintf(text, sizeof text, "%s%s %+.2f stops", which.empty() ? "" : ", ",
                      name.c_str(), stops);
        which += text;
      }
      out.push_back(
          "the exposures given stand at different scales to the photos' EXIF from "
          "view to view (" +
          which +
          " from EXIF): the views' radiance disagrees by as much (give every view's "
          "exposures on one scale, or leave them to EXIF)");
    }
  }
  return out;
}

void fillFromBracket(Capture& capture) {
  // Every view is filled; the first conflict is thrown after them (ingest lists the others).
  std::optional<Error> conflict;
  for (View& v : capture.views) {
    if (v.shots.size() < 2) continue;
    auto fill = [&](std::optional<double> CaptureInfo::*field, const char* tag, auto&& show) {
      // Only shots whose exposure is still to come from EXIF (not given by --exposures or a
      // capture description) need the field.
      std::vector<double> stated;
      const Shot* missing = nullptr;
      for (const Shot& s : v.shots) {
        if (s.info.*field)
          stated.push_back(*(s.info.*field));
        else if (!s.exposure && !missing)
          missing = &s;
      }
      if (stated.empty() || !missing) return;
      const auto [lo, hi] = std::minmax_element(stated.begin(), stated.end());
      if (*hi > *lo * 1.01) {
        if (!conflict)
          conflict =
              Error(kStage,
                    "no " + std::string(tag) + " in EXIF, and the other photos of view '" + v.name +
                        "' state different ones (" + show(*lo) + " to " + show(*hi) +
                        "): its exposure cannot be known (pass --exposures t1,t2,... in "
                        "the order of the photos, or a capture description)",
                    missing->file);
        return;
      }
      for (Shot& s : v.shots) {
        if (s.info.*field || s.exposure) continue;
        s.info.*field = *lo;
        s.filledFromBracket += (s.filledFromBracket.empty() ? "" : ", ") + show(*lo);
      }
    };
    fill(&CaptureInfo::iso, "ISO", [](double iso) {
      char text[32];
      std::snprintf(text, sizeof text, "ISO %g", iso);
      return std::string(text);
    });
    fill(&CaptureInfo::fNumber, "FNumber", [](double n) {
      char text[32];
      std::snprintf(text, sizeof text, "f/%g", n);
      return std::string(text);
    });
  }
  if (conflict) throw *conflict;
}

void resolveExposures(Capture& capture) {
  fillFromBracket(capture);
  // One photo, one shot: a file given twice would count as two exposures (or two views).
  std::vector<std::pair<fs::path, fs::path>> seen;  // canonical, as given
  // One camera: a response belongs to one (it is stored under its Make and Model).
  CaptureInfo described;
  described.cameraMake = capture.cameraMake;
  described.cameraModel = capture.cameraModel;
  const std::string declared = described.camera();
  const Shot* firstNamed = nullptr;
  for (const View& v : capture.views) {
    for (const Shot& s : v.shots) {
      std::error_code ec;
      fs::path canonical = fs::weakly_canonical(s.file, ec);
      if (ec) canonical = fs::absolute(s.file, ec).lexically_normal();
      for (const auto& [other, given] : seen) {
        if (other == canonical) {
          throw Error(kStage,
                      "the same photo is given twice (also as " + given.string() +
                          "): each shot is one exposure of one view",
                      s.file);
        }
      }
      seen.emplace_back(canonical, s.file);
      const std::string camera = s.info.camera();
      if (camera.empty()) continue;
      if (!firstNamed) firstNamed = &s;
      if (!sameCamera(s.info, firstNamed->info)) {
        throw Error(kStage,
                    "the photos come from more than one camera: '" + camera + "' here, '" +
                        firstNamed->info.camera() + "' in " + firstNamed->file.string() +
                        ": a capture is one camera's (its response is recovered and stored "
                        "under its name); merge each camera's photos on their own",
                    s.file);
      }
    }
  }
  // One kind of photo for every view: 8-bit photos' radiance comes out in the unit of the
  // camera's response (middle grey as sRGB decodes it), 16-bit photos' in their own linear unit;
  // views of both kinds would disagree in brightness by the camera's processing (1.8 times in
  // the virtual camera's JPEGs against its TIFFs), face against face. (Float views, such as
  // merged ones, carry their unit.)
  const View* eightBit = nullptr;
  const View* deeper = nullptr;
  for (const View& v : capture.views) {
    if (v.shots.empty()) continue;
    const std::string& type = v.shots.front().info.sampleType;
    if (type == "uint8") eightBit = &v;
    if (type == "uint16" || type == "uint32") deeper = &v;
  }
  if (eightBit && deeper && capture.views.size() > 1) {
    throw Error(kStage,
                "the views mix 8-bit photos (view '" + eightBit->name + "', " +
                    eightBit->shots.front().file.filename().string() + ") and deeper ones (view '" +
                    deeper->name + "', " + deeper->shots.front().file.filename().string() + ", " +
                    deeper->shots.front().info.sampleType +
                    "): their radiance comes out in different units, and the faces would not "
                    "agree; give every view as one kind of photo",
                deeper->shots.front().file);
  }
  // A description's camera (grouping takes the photos' own) is the one whose response is used.
  if (firstNamed && !declared.empty() && !sameCamera(firstNamed->info, described)) {
    throw Error(kStage,
                "the photos' EXIF name the camera '" + firstNamed->info.camera() +
                    "', the capture description '" + declared +
                    "': a capture is one camera's (its response is recovered and stored under "
                    "its name)",
                firstNamed->file);
  }
  for (View& v : capture.views) {
    for (Shot& s : v.shots) {
      if (s.exposure) continue;
      s.exposure = s.info.relativeExposure();
      if (!s.exposure) {
        const bool fromDescription = capture.method.rfind("capture description", 0) == 0;
        throw Error(kStage,
                    fromDescription
                        ? "no exposure time in EXIF and none in the capture description "
                          "(give it an \"exposure\" or \"exposureTime\")"
                        : "no exposure time in EXIF and no exposure given (pass --exposures "
                          "t1,t2,... in the order of the photos, or a capture description)",
                    s.file);
      }
      s.exposureSource = "EXIF";
    }
    for (const Shot& s : v.shots) {
      if (!(*s.exposure >= kMinExposure && *s.exposure <= kMaxExposure)) {
        char text[160];
        std::snprintf(text, sizeof text,
                      "relative exposure %g (from the %s) is outside 1e-12..1e12: no camera's",
                      *s.exposure, s.exposureSource.c_str());
        throw Error(kStage, text, s.file);
      }
    }
    std::stable_sort(v.shots.begin(), v.shots.end(),
                     [](const Shot& a, const Shot& b) { return *a.exposure < *b.exposure; });
    if (v.shots.size() > 1) {
      const double lo = *v.shots.front().exposure, hi = *v.shots.back().exposure;
      if (std::log2(hi / lo) < 1.0 / 6.0) {
        std::string files;
        for (const Shot& s : v.shots)
          files += (files.empty() ? "" : ", ") + s.file.filename().string();
        throw Error(kStage,
                    "the exposures of view '" + v.name + "' are all equal (" + files +
                        "): a bracket needs different exposures to merge",
                    v.shots.front().file);
      }
    }
  }
}

std::vector<std::string> describeCapture(const Capture& capture) {
  std::vector<std::string> lines;
  for (const View& v : capture.views) {
    std::string line = v.name + ": " + std::to_string(v.shots.size()) +
                       (v.shots.size() == 1 ? " photo" : " photos");
    double reference = 0.0;
    for (const Shot& s : v.shots)
      if (s.exposure && reference == 0.0) reference = *s.exposure;
    if (reference > 0.0 && v.shots.size() > 1) {
      double lo = reference, hi = reference;
      for (const Shot& s : v.shots)
        if (s.exposure) lo = std::min(lo, *s.exposure), hi = std::max(hi, *s.exposure);
      char span[48];
      std::snprintf(span, sizeof span, ", %.1f EV range", std::log2(hi / lo));
      line += span;
    }
    line += ":";
    for (const Shot& s : v.shots) {
      line += " " + s.file.filename().string();
      if (s.exposure && reference > 0.0) line += " (" + stops(*s.exposure, reference) + ")";
    }
    lines.push_back(line);
  }
  return lines;
}

}  // namespace compose::ingest
