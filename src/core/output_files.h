// Output files that appear together or not at all.
//
// A command that writes several files (an EXR and a JPEG, a cube map and its preview) must never
// leave a mix of new and old results, nor a half-written file. OutputFiles hands out a temporary
// path in the destination's folder for every output; when all of them have been written, commit()
// moves them into place. If a move fails, the outputs already moved are put back as they were
// (previous files restored, new ones removed), so a failure leaves every previous output
// untouched. Temporaries that were never committed are removed when the object goes away.
// Commits into one folder are serialised by an advisory lock on the folder (flock), so that two
// runs writing the same outputs at once leave one run's complete set, never a mix of the two.
//
// Errors throw compose::Error with the given stage, the file, and the operating system's reason.
#pragma once

#include <filesystem>
#include <functional>
#include <istream>
#include <mutex>
#include <string>
#include <vector>

namespace compose {

class OutputFiles {
 public:
  explicit OutputFiles(std::string stage = "output") : stage_(std::move(stage)) {}
  OutputFiles(const OutputFiles&) = delete;
  OutputFiles& operator=(const OutputFiles&) = delete;
  ~OutputFiles();

  // Checks that `destination` can be written (its folder exists or can be made, it is not a
  // folder itself) and returns a fresh temporary path next to it, with the same extension so that
  // writers that choose a format by extension pick the right one. Outputs may be added (and
  // written) from several threads at once; commit() is called once, after they are all written.
  std::filesystem::path add(const std::filesystem::path& destination);

  // The checks of add() that need nothing written or made: `destination` names a file, is not
  // an existing folder, a device, a FIFO or a socket, and its folder is not a file. A command
  // calls it on its --out before long work, so that a bad path is refused before, not after.
  static void check(const std::filesystem::path& destination, const std::string& stage);

  // Moves every temporary into place. On failure, restores what was there and throws.
  void commit();

 private:
  struct Entry {
    std::filesystem::path temporary, destination;
  };
  std::string stage_;
  std::vector<Entry> entries_;
  std::vector<std::filesystem::path> createdFolders_;  // by add(), to remove on failure
  std::mutex mutex_;                                   // guards entries_ in add()
  bool committed_ = false;
};

// A file this process reads, which no output may replace: OutputFiles::add() refuses a
// destination that is the same file (by any name or link) as a protected input. The image, mesh
// and JSON readers protect what they read; a command protects its inputs before it writes
// anything that precedes reading them (a scene file saved from the command line).
void protectInput(const std::filesystem::path& file);

// Removes what a killed run left in `folder`: files named `prefix` + "<pid>-..." (the temporary
// names writers here give files before renaming them into place) whose process no longer runs and
// which have not changed for a minute. Errors are ignored: it only tidies.
void removeStalePartials(const std::filesystem::path& folder, const std::string& prefix);
// Whether `file` is such a temporary (a name with ".partial-<pid>-"): its process gone, unchanged
// for a minute.
bool isAbandonedTemporary(const std::filesystem::path& file);

// Forgets every protected input: for a process that runs one job after another (a fuzz target
// writes a file, reads it, and writes it again for the next input).
void forgetProtectedInputs();

// For outputs that are documents of one kind (a scene file, a capture description): an existing
// regular file at `file` may be replaced only when `ours` says it is such a document (an older
// one); anything else there (a photo, a material library, a texture given by mistake) is an
// error naming the file and `kind`, and nothing is written.
void requireReplaceable(const std::filesystem::path& file, const std::string& kind,
                        const std::function<bool(std::istream&)>& ours, const std::string& stage);

// Writes `text` to `file` atomically (temporary + rename). Throws compose::Error (stage `stage`).
void writeTextFile(const std::filesystem::path& file, const std::string& text,
                   const std::string& stage);

// `text` (a library's error message about writing `temporary`) with the temporary's path and
// name replaced by those of `destination`, the file the user asked for: the temporary is ours.
std::string nameTheDestination(std::string text, const std::filesystem::path& temporary,
                               const std::filesystem::path& destination);

// "<what>: <strerror(errno)>" for error messages that keep the operating system's reason.
std::string withSystemReason(const std::string& what, int error);

}  // namespace compose
