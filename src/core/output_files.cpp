#include "core/output_files.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>

#include <array>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <mutex>
#include <optional>

#include "core/error.h"
#include "core/limits.h"

namespace compose {

namespace fs = std::filesystem;

namespace {

// A name unique to this process and call, in the destination's folder, keeping the extension.
fs::path temporaryNear(const fs::path& destination, const char* tag) {
  static std::atomic<unsigned> counter{0};
  fs::path temp = destination;
  // Appended piece by piece: GCC 12 warns (-Wrestrict, falsely) on a chain of operator+.
  std::string name(1, '.');
  name.append(destination.stem().string()).append(1, '.').append(tag).append(1, '-');
  name.append(std::to_string(::getpid())).append(1, '-').append(std::to_string(counter++));
  name.append(destination.extension().string());
  temp.replace_filename(name);
  return temp;
}

// Advisory locks on the destination folders for the length of a commit, so that the outputs of
// two runs committing into the same folder at once never interleave (one run's EXR with the
// other's JPEG): each set appears whole, the later one replacing the earlier. Folders are locked
// in sorted order, so two commits cannot wait for each other. A folder that cannot be opened or
// locked (a file system without flock) is committed without the lock.
class FolderLocks {
 public:
  explicit FolderLocks(std::vector<fs::path> folders) {
    std::sort(folders.begin(), folders.end());
    folders.erase(std::unique(folders.begin(), folders.end()), folders.end());
    for (const fs::path& f : folders) {
      const int fd = ::open(f.empty() ? "." : f.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
      if (fd < 0) continue;
      while (::flock(fd, LOCK_EX) != 0 && errno == EINTR) {
      }
      fds_.push_back(fd);
    }
  }
  ~FolderLocks() {
    for (int fd : fds_) ::close(fd);  // closing releases the lock
  }
  FolderLocks(const FolderLocks&) = delete;
  FolderLocks& operator=(const FolderLocks&) = delete;

 private:
  std::vector<int> fds_;
};

std::mutex protectedMutex;
std::vector<fs::path> protectedInputs;

// The protected input that `destination` is, if any.
std::optional<fs::path> protectedInputAt(const fs::path& destination) {
  std::error_code ec;
  if (!fs::exists(destination, ec)) return std::nullopt;  // a new file replaces nothing
  const std::lock_guard<std::mutex> lock(protectedMutex);
  for (const fs::path& input : protectedInputs) {
    std::error_code same;
    if (fs::equivalent(destination, input, same) && !same) return input;
  }
  return std::nullopt;
}

}  // namespace

bool isAbandonedTemporary(const fs::path& file) {
  const std::string name = file.filename().string();
  // A temporary being written (.partial-), or a commit's backup of the file it replaces
  // (.previous-); the writer's process id follows, then '-'.
  size_t at = name.rfind(".partial-"), from = at + 9;
  if (at == std::string::npos) {
    at = name.rfind(".previous-");
    from = at + 10;
  }
  if (at == std::string::npos) return false;
  size_t digits = from;
  while (digits < name.size() && std::isdigit(static_cast<unsigned char>(name[digits]))) ++digits;
  if (digits == from || digits >= name.size() || name[digits] != '-') return false;
  const long pid = std::strtol(name.c_str() + from, nullptr, 10);
  if (pid <= 0 || pid == long(::getpid())) return false;
  if (!(::kill(pid_t(pid), 0) != 0 && errno == ESRCH)) return false;  // running (or not ours)
  std::error_code e;
  if (!fs::is_regular_file(file, e)) return false;
  const auto changed = fs::last_write_time(file, e);
  return !e && fs::file_time_type::clock::now() - changed >= std::chrono::minutes(1);
}

void removeStalePartials(const fs::path& folder, const std::string& prefix) {
  std::error_code ec;
  for (fs::directory_iterator it(folder.empty() ? fs::path(".") : folder, ec), end;
       !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) continue;
    std::error_code e;
    if (isAbandonedTemporary(it->path())) fs::remove(it->path(), e);
  }
}

void protectInput(const fs::path& file) {
  if (file.empty()) return;
  const std::lock_guard<std::mutex> lock(protectedMutex);
  if (std::find(protectedInputs.begin(), protectedInputs.end(), file) == protectedInputs.end())
    protectedInputs.push_back(file);
}

void forgetProtectedInputs() {
  const std::lock_guard<std::mutex> lock(protectedMutex);
  protectedInputs.clear();
}

std::string nameTheDestination(std::string text, const fs::path& temporary,
                               const fs::path& destination) {
  // The whole path first, then the bare name (a message may quote either).
  const std::pair<std::string, std::string> names[] = {
      {temporary.string(), destination.string()},
      {temporary.filename().string(), destination.filename().string()}};
  for (const auto& [from, to] : names) {
    if (from.empty()) continue;
    for (size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
      text.replace(at, from.size(), to);
  }
  return text;
}

std::string withSystemReason(const std::string& what, int error) {
  return what + ": " + std::strerror(error);
}

OutputFiles::~OutputFiles() {
  if (committed_) return;
  std::error_code ec;
  for (const Entry& e : entries_) fs::remove(e.temporary, ec);
  // The folders made for the outputs, deepest first: removed when nothing else was put there.
  std::vector<fs::path> folders = createdFolders_;
  std::sort(folders.begin(), folders.end(), [](const fs::path& a, const fs::path& b) {
    return a.native().size() > b.native().size();
  });
  for (const fs::path& dir : folders) fs::remove(dir, ec);
}

void OutputFiles::check(const fs::path& destination, const std::string& stage) {
  std::error_code ec;
  if (destination.filename().empty())
    throw Error(stage, "output path names a folder, not a file", destination);
  if (fs::is_directory(destination, ec))
    throw Error(stage, "output path is an existing folder", destination);
  if (const char* kind = specialFileKind(destination)) {
    throw Error(stage,
                std::string("output path is ") + kind +
                    ", not a file: outputs are written to files (it would be replaced by one)",
                destination);
  }
  // The nearest folder on the path that exists must be a folder (a/b/out.exr with a a file
  // cannot be made) that this process may write into: found now, not after the work (a read-only
  // folder failed the run when its outputs were written, its caches filled).
  fs::path nearest = ".";
  for (fs::path dir = destination.parent_path(); !dir.empty(); dir = dir.parent_path()) {
    if (!fs::exists(dir, ec)) {
      if (dir == dir.parent_path()) break;
      continue;
    }
    if (!fs::is_directory(dir, ec))
      throw Error(stage, "cannot write into the output folder: it is a file, not a folder", dir);
    nearest = dir;
    break;
  }
  if (fs::is_directory(nearest, ec) && ::access(nearest.c_str(), W_OK | X_OK) != 0 &&
      (errno == EACCES || errno == EROFS))
    throw Error(stage, withSystemReason("cannot write into the output folder", errno), nearest);
  // A file its owner write-protected is kept, as cp and the shell's > keep it: moving the new
  // file over it needs only the folder's permission, which would go past the protection.
  if (fs::is_regular_file(destination, ec) && ::access(destination.c_str(), W_OK) != 0 &&
      errno == EACCES)
    throw Error(stage, withSystemReason("cannot replace the file", EACCES), destination);
}

fs::path OutputFiles::add(const fs::path& destination) {
  std::error_code ec;
  check(destination, stage_);
  const fs::path dir = destination.parent_path();
  if (!dir.empty() && !fs::exists(dir, ec)) {
    std::vector<fs::path> missing;  // deepest first
    for (fs::path d = dir; !d.empty() && !fs::exists(d, ec); d = d.parent_path()) {
      missing.push_back(d);
      if (d == d.parent_path()) break;
    }
    fs::create_directories(dir, ec);
    if (ec) throw Error(stage_, "cannot create the output folder: " + ec.message(), dir);
    const std::lock_guard<std::mutex> lock(mutex_);
    createdFolders_.insert(createdFolders_.end(), missing.begin(), missing.end());
  }
  if (!dir.empty() && !fs::is_directory(dir, ec))
    throw Error(stage_, "cannot write into the output folder: it is a file, not a folder", dir);
  if (const std::optional<fs::path> input = protectedInputAt(destination)) {
    throw Error(
        stage_,
        "the output would replace an input (" + input->string() + "): choose another output path",
        destination);
  }
  removeStalePartials(dir, "." + destination.stem().string() + ".partial-");
  // A killed commit's backups of the outputs before it, as stale.
  removeStalePartials(dir, "." + destination.stem().string() + ".previous-");
  Entry e{temporaryNear(destination, "partial"), destination};
  const std::lock_guard<std::mutex> lock(mutex_);
  entries_.push_back(e);
  return e.temporary;
}

namespace {

// SIGINT, SIGTERM, SIGHUP and SIGQUIT wait while a commit renames its files into place, and are
// raised again once they all are: a farm manager's SIGTERM between two renames left a new EXR
// beside the previous run's JPEG. (SIGKILL cannot wait; the renames follow one another with
// nothing else between them.) Handlers are the process's, whichever thread a signal reaches.
class DeferredSignals {
 public:
  DeferredSignals() {
    const std::lock_guard<std::mutex> lock(mutex());
    if (depth_++ > 0) return;  // another commit holds them already
    struct sigaction record {};
    record.sa_handler = &DeferredSignals::record;
    record.sa_flags = SA_RESTART;
    sigemptyset(&record.sa_mask);
    for (size_t i = 0; i < kSignals.size(); ++i) ::sigaction(kSignals[i], &record, &previous_[i]);
  }
  ~DeferredSignals() {
    int signal = 0;
    {
      const std::lock_guard<std::mutex> lock(mutex());
      if (--depth_ > 0) return;
      for (size_t i = 0; i < kSignals.size(); ++i) ::sigaction(kSignals[i], &previous_[i], nullptr);
      signal = pending_;
      pending_ = 0;
    }
    if (signal != 0) ::raise(signal);
  }
  DeferredSignals(const DeferredSignals&) = delete;
  DeferredSignals& operator=(const DeferredSignals&) = delete;

 private:
  static constexpr std::array<int, 4> kSignals = {SIGINT, SIGTERM, SIGHUP, SIGQUIT};
  static void record(int signal) { pending_ = signal; }
  static std::mutex& mutex() {
    static std::mutex m;
    return m;
  }
  static inline volatile std::sig_atomic_t pending_ = 0;
  // Commits in several threads at once: the first installs the handlers, the last restores them.
  static inline int depth_ = 0;
  static inline std::array<struct sigaction, 4> previous_{};
};

}  // namespace

void OutputFiles::commit() {
  COMPOSE_CHECK(!committed_);
  std::vector<fs::path> folders;
  for (const Entry& e : entries_) {
    std::error_code ec;
    folders.push_back(fs::absolute(e.destination, ec).parent_path());
  }
  const FolderLocks locks(std::move(folders));
  // First every check, and the previous outputs kept under backup names (hard links: the
  // originals stay in place until they are replaced), so that a failed move can put them back;
  // then the renames, one after the other.
  struct Prepared {
    fs::path temporary, destination, backup;
    bool hadPrevious;
  };
  std::vector<Prepared> prepared;
  auto removeAll = [&] {
    std::error_code ec;
    for (const Prepared& p : prepared)
      if (p.hadPrevious) fs::remove(p.backup, ec);
    for (const Entry& e : entries_) fs::remove(e.temporary, ec);
  };
  for (const Entry& e : entries_) {
    std::error_code ec;
    if (fs::is_directory(e.destination, ec)) {
      removeAll();
      throw Error(stage_, "output path is an existing folder", e.destination);
    }
    const bool hadPrevious = fs::exists(fs::symlink_status(e.destination, ec));
    if (hadPrevious && fs::is_regular_file(e.destination, ec) &&
        ::access(e.destination.c_str(), W_OK) != 0 && errno == EACCES) {
      removeAll();  // write-protected since the job began (see check())
      throw Error(stage_, withSystemReason("cannot replace the file", EACCES), e.destination);
    }
    fs::path backup;
    if (hadPrevious) {
      backup = temporaryNear(e.destination, "previous");
      if (::link(e.destination.c_str(), backup.c_str()) != 0) {
        // No hard links on this file system: fall back to a copy.
        fs::copy_file(e.destination, backup, fs::copy_options::overwrite_existing, ec);
        if (ec) {
          const int err = ec.value();
          removeAll();
          throw Error(stage_, withSystemReason("cannot keep the previous file", err),
                      e.destination);
        }
      }
    }
    prepared.push_back({e.temporary, e.destination, backup, hadPrevious});
  }
  {
    const DeferredSignals deferred;
    for (size_t i = 0; i < prepared.size(); ++i) {
      const Prepared& p = prepared[i];
      if (::rename(p.temporary.c_str(), p.destination.c_str()) == 0) continue;
      const int err = errno;
      // Put back what was moved: the previous files, or nothing where there was none.
      std::error_code ec;
      for (size_t j = i; j-- > 0;) {
        if (prepared[j].hadPrevious) {
          fs::rename(prepared[j].backup, prepared[j].destination, ec);
        } else {
          fs::remove(prepared[j].destination, ec);
        }
      }
      removeAll();
      throw Error(stage_, withSystemReason("cannot move the finished file into place", err),
                  p.destination);
    }
    committed_ = true;
    // The backups go before a held signal is raised: they are the previous outputs' copies.
    std::error_code ec;
    for (const Prepared& p : prepared) {
      if (p.hadPrevious) fs::remove(p.backup, ec);
    }
  }
}

void requireReplaceable(const fs::path& file, const std::string& kind,
                        const std::function<bool(std::istream&)>& ours, const std::string& stage) {
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) return;  // nothing there, or what OutputFiles refuses
  std::ifstream in(file, std::ios::binary);
  bool replaceable = false;
  try {
    replaceable = in && ours(in);
  } catch (const std::exception&) {
    replaceable = false;
  }
  if (!replaceable) {
    throw Error(stage,
                "is not a " + kind + " and would be replaced: choose another path, or remove it",
                file);
  }
}

void writeTextFile(const fs::path& file, const std::string& text, const std::string& stage) {
  OutputFiles outputs(stage);
  const fs::path temp = outputs.add(file);
  {
    errno = 0;
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(stage, withSystemReason("cannot open for writing", errno), file);
    out << text;
    out.close();
    if (!out) throw Error(stage, withSystemReason("cannot write", errno ? errno : EIO), file);
  }
  outputs.commit();
}

}  // namespace compose
