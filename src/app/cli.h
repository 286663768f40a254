// Shared pieces of the compose command line: the command list, option parsers and the progress
// printer. Commands only parse options, load, call the libraries and save; the work is elsewhere.
#pragma once

#include <filesystem>
#include <functional>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include <CLI/CLI.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "core/error.h"
#include "core/limits.h"
#include "core/progress.h"
#include "cubemap/environment_io.h"

namespace compose::app {

// Options every command honours.
struct Globals {
  bool quiet = false;
  ResourceLimits limits;  // --max-pixels, --max-triangles (core/limits.h)
  std::string ocio;       // --ocio: the OpenColorIO config instead of $OCIO
};

// Progress on stderr: on a terminal one line per stage, redrawn in place; otherwise (a log, a
// pipe, CI) a line "compose: progress: <stage> NN%" every few seconds of long work; nothing when
// quiet.
class ProgressPrinter {
 public:
  explicit ProgressPrinter(const Globals& globals);
  void operator()(std::string_view stage, double fraction);
  Progress callback() {
    return [this](std::string_view stage, double fraction) { (*this)(stage, fraction); };
  }

 private:
  const Globals& globals_;
  bool tty_;
  ProgressThrottle lines_;
  std::mutex mutex_;
};

// What a command runs once the command line is parsed; returns the exit status. Bad input throws
// compose::Error (exit 1) or compose::UsageError (exit 2).
using Runner = std::function<int()>;

// A command adds its options (and its --help text with a worked example) to `command`, an
// already created subcommand of `compose`, and returns its runner.
struct Command {
  std::string name;
  std::string summary;
  Runner (*setup)(CLI::App& command, const Globals& globals);
};

// The explicit list of `compose <command>` subcommands.
const std::vector<Command>& commands();

// The one-shot `compose --plate ... --object ...`: its options live on the top-level app.
Runner setupCompose(CLI::App& app, const Globals& globals);

// The stage commands (cmd_<name>.cpp).
Runner setupIngest(CLI::App& command, const Globals& globals);
Runner setupMerge(CLI::App& command, const Globals& globals);
Runner setupCaptureSim(CLI::App& command, const Globals& globals);
Runner setupCalib(CLI::App& command, const Globals& globals);
Runner setupConvert(CLI::App& command, const Globals& globals);
Runner setupStitch(CLI::App& command, const Globals& globals);
Runner setupColor(CLI::App& command, const Globals& globals);
Runner setupPrecompute(CLI::App& command, const Globals& globals);
Runner setupRender(CLI::App& command, const Globals& globals);
Runner setupComposite(CLI::App& command, const Globals& globals);
Runner setupRun(CLI::App& command, const Globals& globals);
Runner setupBench(CLI::App& command, const Globals& globals);
Runner setupCache(CLI::App& command, const Globals& globals);

// "X,Y" → two numbers; throws UsageError naming `option`.
glm::dvec2 parsePair(const std::string& text, const std::string& option);
// "V" or "R,G,B" → three numbers; throws UsageError naming `option`.
glm::vec3 parseColour(const std::string& text, const std::string& option);
// "X,Y,Z" → three finite numbers; throws UsageError naming `option`.
glm::dvec3 parseTriple(const std::string& text, const std::string& option,
                       const std::string& form = "X,Y,Z");
// A number, or throws UsageError naming `option`.
double parseNumber(const std::string& text, const std::string& option);
std::string join(const std::vector<std::string>& items, const std::string& separator = ", ");
// "a,b,c" → numbers; throws UsageError naming `option`.
std::vector<double> parseList(const std::string& text, const std::string& option);
// Throws UsageError unless `out` names an OpenEXR file (.exr, any case); `why` says why it must.
void requireExrName(const std::string& out, const std::string& why);
// The note for the files of a folder of photos that ingest::scanShots left out (no exposure time
// in their EXIF where the others have one).
std::string leftOutNote(const std::vector<std::filesystem::path>& files);
// The note for the JPEGs of RAW+JPEG pairs that scanShots left out.
std::string rawPairsNote(const std::vector<std::filesystem::path>& jpegs);

// How convert and stitch write an environment: --depth (auto, half or float) and --face-names
// (layouts.h); throws UsageError for a value that is neither.
cubemap::WriteOptions environmentWriteOptions(const std::string& depth,
                                              const std::string& faceNames);
// The file convert and stitch write first: --out, or for --to faces the first face's name.
std::filesystem::path firstEnvironmentFile(const std::string& out, cubemap::Layout to,
                                           const cubemap::WriteOptions& write);
// Refuses (UsageError) the writing options of `command` that the output would ignore:
// --face-names but for --to faces, --depth and --compression but for OpenEXR files.
void refuseUnusedWriteOptions(const CLI::App& command, cubemap::Layout to,
                              const std::filesystem::path& firstFile);

// --compression: the OpenEXR compression of the EXRs a command writes, as OpenImageIO and oiiotool
// name it ("piz", "zip:4", "dwaa:45", "none"); a name it does not know is a bad command line.
CLI::Option* addCompressionOption(CLI::App& command, std::string& compression);

// Checks of a number option that say what is wanted in words ("must be a number greater than 0,
// got 0"; CLI11's own print the largest double in full), and refuse NaN and infinities.
CLI::Validator positiveNumber();
CLI::Validator nonNegativeNumber();
// Throws UsageError when `compression` (already checked by that option) loses information; `why`
// says why the output must keep every value.
void requireLosslessCompression(const std::string& compression, const std::string& why);

// Runs `check` (a parameter validation that throws compose::Error) and reports a failure as a
// bad command line (UsageError, exit 2), so that bad values are refused before any file is read.
template <class Check>
void asUsage(Check&& check) {
  try {
    check();
  } catch (const UsageError&) {
    throw;
  } catch (const Error& e) {
    throw UsageError(e.what());
  }
}

// Prints a library's notes on stderr ("compose: note: ..."), unless quiet.
void printNotes(const Globals& globals, const std::vector<std::string>& notes);

}  // namespace compose::app
