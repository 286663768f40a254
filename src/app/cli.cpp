#include "app/cli.h"

#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "core/error.h"
#include "cubemap/layouts.h"
#include "ingest/exr_io.h"
#include "ingest/image_io.h"

namespace compose::app {

namespace {

// Seconds between progress lines when stderr is not a terminal.
constexpr double kProgressLineSeconds = 5.0;

double monotonicSeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace

ProgressPrinter::ProgressPrinter(const Globals& globals)
    : globals_(globals),
      tty_(::isatty(STDERR_FILENO) != 0),
      lines_(kProgressLineSeconds, monotonicSeconds()) {}

void ProgressPrinter::operator()(std::string_view stage, double fraction) {
  if (globals_.quiet) return;
  std::lock_guard lock(mutex_);
  if (!tty_) {
    if (lines_.due(monotonicSeconds())) {
      std::fprintf(stderr, "compose: progress: %.*s %d%%\n", int(stage.size()), stage.data(),
                   int(fraction * 100.0 + 0.5));
      std::fflush(stderr);
    }
    return;
  }
  std::fprintf(stderr, "\r  %-10.*s %3d%%", int(stage.size()), stage.data(),
               int(fraction * 100.0 + 0.5));
  if (fraction >= 1.0) std::fprintf(stderr, "\r\033[K");
  std::fflush(stderr);
}

const std::vector<Command>& commands() {
  static const std::vector<Command> list = {
      {"ingest", "Read photos' EXIF and group them into views and brackets", setupIngest},
      {"merge", "Merge bracketed exposures into scene-linear HDR (OpenEXR)", setupMerge},
      {"capture-sim", "Virtual camera: bracketed photos of an HDR environment, with ground truth",
       setupCaptureSim},
      {"calib", "Lens calibration and plate pose from chessboard photos", setupCalib},
      {"convert", "Convert environment maps between layouts; unwrap mirror balls", setupConvert},
      {"stitch", "Stitch photos from one point into a cube-map environment", setupStitch},
      {"color", "Convert an image to the working space (or another) as OpenEXR", setupColor},
      {"precompute", "Project an environment onto the lighting basis: a lighting file",
       setupPrecompute},
      {"render", "Render the object's layer (with AOVs and ground shadow) from a lighting file",
       setupRender},
      {"composite", "Composite an object's layer into the plate: EXR and JPEG", setupComposite},
      {"run", "Run the job a scene file (JSON) describes", setupRun},
      {"bench", "Time a job stage by stage, cold and warm, with peak memory", setupBench},
      {"cache", "Show what the caches hold; remove old entries (--older-than, --max-size)",
       setupCache},
  };
  return list;
}

glm::dvec2 parsePair(const std::string& text, const std::string& option) {
  std::istringstream in(text);
  double a = 0, b = 0;
  char comma = 0;
  if (!(in >> a >> comma >> b) || comma != ',' || !in.eof()) {
    throw UsageError(option + " expects two numbers as X,Y, got '" + text + "'");
  }
  return {a, b};
}

glm::vec3 parseColour(const std::string& text, const std::string& option) {
  std::istringstream in(text);
  float r = 0, g = 0, b = 0;
  char c1 = 0, c2 = 0;
  if ((in >> r) && in.eof()) return glm::vec3(r);
  in.clear();
  in.str(text);
  if (!(in >> r >> c1 >> g >> c2 >> b) || c1 != ',' || c2 != ',' || !in.eof()) {
    throw UsageError(option + " expects one value or R,G,B, got '" + text + "'");
  }
  return {r, g, b};
}

glm::dvec3 parseTriple(const std::string& text, const std::string& option,
                       const std::string& form) {
  std::istringstream in(text);
  double x = 0, y = 0, z = 0;
  char c1 = 0, c2 = 0;
  if (!(in >> x >> c1 >> y >> c2 >> z) || c1 != ',' || c2 != ',' || !in.eof() ||
      !std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) {
    throw UsageError(option + " expects three numbers as " + form + ", got '" + text + "'");
  }
  return {x, y, z};
}

double parseNumber(const std::string& text, const std::string& option) {
  try {
    size_t used = 0;
    const double v = std::stod(text, &used);
    if (used != text.size()) throw std::invalid_argument(text);
    return v;
  } catch (const std::exception&) {
    throw UsageError(option + " expects a number, got '" + text + "'");
  }
}

std::vector<double> parseList(const std::string& text, const std::string& option) {
  std::vector<double> out;
  size_t start = 0;
  while (start <= text.size()) {
    size_t end = text.find(',', start);
    if (end == std::string::npos) end = text.size();
    out.push_back(parseNumber(text.substr(start, end - start), option));
    start = end + 1;
  }
  return out;
}

void printNotes(const Globals& globals, const std::vector<std::string>& notes) {
  if (globals.quiet) return;
  for (const auto& note : notes)
    std::fprintf(stderr, "compose: note: %s\n", printable(note).c_str());
}

std::string join(const std::vector<std::string>& items, const std::string& separator) {
  std::string s;
  for (const auto& i : items) s += (s.empty() ? "" : separator) + i;
  return s;
}

void requireExrName(const std::string& out, const std::string& why) {
  if (ingest::lowerExtension(out) != ".exr")
    throw UsageError("--out must name an OpenEXR file (.exr): " + why + " ('" + out +
                     "' is not one)");
}

std::string leftOutNote(const std::vector<std::filesystem::path>& files) {
  std::vector<std::string> names;
  for (const auto& f : files) names.push_back(f.filename().string());
  return "left out " + std::to_string(files.size()) + " file" + (files.size() == 1 ? "" : "s") +
         " of the folder with no exposure time in EXIF, where the other photos have one (not a "
         "photo of the brackets: a merged or edited image?): " +
         join(names) + "; name them one by one, or in a capture description, to use them";
}

std::string rawPairsNote(const std::vector<std::filesystem::path>& jpegs) {
  std::vector<std::string> names;
  for (const auto& f : jpegs) names.push_back(f.filename().string());
  return "left out " + std::to_string(jpegs.size()) + " JPEG" + (jpegs.size() == 1 ? "" : "s") +
         " shot with a raw file of the same name and time (RAW+JPEG): " + join(names) +
         "; the raw files are used (name the JPEGs alone to use them instead)";
}

cubemap::WriteOptions environmentWriteOptions(const std::string& depth,
                                              const std::string& faceNames) {
  cubemap::WriteOptions write;
  if (depth == "auto")
    write.depth = cubemap::WriteOptions::Depth::Auto;
  else if (depth == "half")
    write.depth = cubemap::WriteOptions::Depth::Half;
  else if (depth == "float")
    write.depth = cubemap::WriteOptions::Depth::Float;
  else
    throw UsageError("--depth must be auto, half or float; got '" + depth + "'");
  const auto naming = cubemap::parseFaceNaming(faceNames);
  if (!naming) throw UsageError("--face-names must be one of " + join(cubemap::faceNamingNames()));
  write.faceNaming = *naming;
  return write;
}

std::filesystem::path firstEnvironmentFile(const std::string& out, cubemap::Layout to,
                                           const cubemap::WriteOptions& write) {
  return to == cubemap::Layout::Faces ? cubemap::facePaths(out, write.faceNaming)[0]
                                      : std::filesystem::path(out);
}

void refuseUnusedWriteOptions(const CLI::App& command, cubemap::Layout to,
                              const std::filesystem::path& firstFile) {
  if (command.count("--face-names") && to != cubemap::Layout::Faces)
    throw UsageError("--face-names names face files: it goes with --to faces");
  const std::string ext = ingest::lowerExtension(firstFile);
  for (const char* option : {"--depth", "--compression"}) {
    if (command.count(option) && ext != ".exr") {
      throw UsageError(std::string(option) + " says how an OpenEXR file is written; " +
                       firstFile.filename().string() + " is " +
                       (ext.empty() ? std::string("no image file") : "a " + ext + " file") +
                       " (Radiance .hdr: shared-exponent floats, PNG and TIFF: 8 or 16-bit codes, "
                       "as the input's)");
    }
  }
}

CLI::Option* addCompressionOption(CLI::App& command, std::string& compression) {
  return command
      .add_option("--compression", compression,
                  std::string("OpenEXR compression: ") + ingest::kExrCompressionNames +
                      "; lossless but for b44 and b44a on half channels, dwaa and dwab on half "
                      "channels and on float channels named R, G, B, Y, RY or BY (of any layer: "
                      "P.Y, object.R), and pxr24 on float channels")
      ->check(CLI::Validator(
          [](std::string& text) {
            std::string why;
            return ingest::parseExrCompression(text, &why) ? std::string() : why;
          },
          "CODEC[:LEVEL]", "EXR compression"))
      ->capture_default_str();
}

namespace {

CLI::Validator numberAtLeast(double least, bool strictly, const std::string& words) {
  return CLI::Validator(
      [least, strictly, words](std::string& text) {
        double v = 0.0;
        const char* begin = text.c_str();
        char* end = nullptr;
        v = std::strtod(begin, &end);
        const bool number = end != begin && *end == '\0' && std::isfinite(v);
        if (number && (strictly ? v > least : v >= least)) return std::string();
        return "must be " + words + ", got " + text;
      },
      "NUMBER", words);
}

}  // namespace

CLI::Validator positiveNumber() {
  return numberAtLeast(0.0, true, "a number greater than 0");
}

CLI::Validator nonNegativeNumber() {
  return numberAtLeast(0.0, false, "a finite number of 0 or more");
}

void requireLosslessCompression(const std::string& compression, const std::string& why) {
  std::string problem;
  const std::optional<ingest::ExrCompression> codec =
      ingest::parseExrCompression(compression, &problem);
  if (!codec) throw UsageError("--compression: " + problem);
  if (codec->lossy())
    throw UsageError("--compression " + compression + " loses information: " + why +
                     "; give a lossless codec (none, rle, zips, zip, piz)");
}

}  // namespace compose::app
