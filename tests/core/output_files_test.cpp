#include "core/output_files.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>

#include "test_util.h"

namespace compose {
namespace {

using compose::testing::TempDir;
using compose::testing::writeText;
namespace fs = std::filesystem;

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

size_t fileCount(const fs::path& dir) {
  size_t n = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++n;
  return n;
}

TEST(OutputFiles, CommitMovesEveryFileIntoPlace) {
  TempDir dir;
  writeText(dir / "a.txt", "old a");
  OutputFiles out;
  const fs::path ta = out.add(dir / "a.txt"), tb = out.add(dir / "b.txt");
  EXPECT_EQ(ta.extension(), ".txt");
  writeText(ta, "new a");
  writeText(tb, "new b");
  EXPECT_EQ(slurp(dir / "a.txt"), "old a") << "nothing moves before commit";
  out.commit();
  EXPECT_EQ(slurp(dir / "a.txt"), "new a");
  EXPECT_EQ(slurp(dir / "b.txt"), "new b");
  EXPECT_EQ(fileCount(dir.path()), 2u) << "no temporaries or backups left";
}

// An output that would replace a file this process read is refused, by any name of that file
// (a plate written over by its own composite was lost).
TEST(OutputFiles, AnInputIsNeverReplaced) {
  TempDir dir;
  writeText(dir / "plate.jpg", "the photo");
  fs::create_hard_link(dir / "plate.jpg", dir / "link.jpg");
  protectInput(dir / "plate.jpg");
  for (const fs::path& name : {dir / "plate.jpg", dir / "." / "link.jpg"}) {
    OutputFiles out;
    COMPOSE_EXPECT_ERROR(out.add(name), "the output would replace an input");
  }
  EXPECT_EQ(slurp(dir / "plate.jpg"), "the photo");
  // Other files, and new ones, are written as before.
  writeText(dir / "other.jpg", "old");
  OutputFiles out;
  writeText(out.add(dir / "other.jpg"), "new");
  writeText(out.add(dir / "new.jpg"), "new");
  out.commit();
  EXPECT_EQ(slurp(dir / "other.jpg"), "new");
}

// A file its owner write-protected is not replaced (the new file was moved over it: that needs
// only the folder's permission), as cp and the shell's > keep it; a writable one beside it is.
// Root may write anything, so the check runs in a child that gives root's rights up.
TEST(OutputFiles, AWriteProtectedFileIsKept) {
  TempDir dir;
  writeText(dir / "kept.jpg", "the graded one");
  fs::permissions(dir / "kept.jpg",
                  fs::perms::owner_read | fs::perms::group_read | fs::perms::others_read);
  fs::permissions(dir.path(), fs::perms::all);  // the folder is writable by anyone
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    if (geteuid() == 0 && (setgid(65534) != 0 || setuid(65534) != 0)) _exit(3);
    try {
      OutputFiles out;
      out.add(dir / "kept.jpg");
      _exit(1);  // accepted
    } catch (const Error& e) {
      if (e.describe().find("cannot replace the file: Permission denied") == std::string::npos)
        _exit(2);
    }
    OutputFiles out;
    writeText(out.add(dir / "other.jpg"), "new");
    out.commit();
    _exit(0);
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "1: the protected file was accepted; 2: another error; "
                                       "3: could not give up root's rights";
  EXPECT_EQ(slurp(dir / "kept.jpg"), "the graded one");
  EXPECT_EQ(slurp(dir / "other.jpg"), "new");
}

// An output in a folder this process cannot write into is refused when it is checked, before any
// work (it failed when the outputs were written, after the whole run). In a child that gives
// root's rights up.
TEST(OutputFiles, AFolderThatCannotBeWrittenIsRefusedUpFront) {
  TempDir dir;
  fs::create_directory(dir / "ro");
  fs::permissions(dir / "ro", fs::perms::owner_read | fs::perms::owner_exec |
                                  fs::perms::group_read | fs::perms::group_exec |
                                  fs::perms::others_read | fs::perms::others_exec);
  fs::permissions(dir.path(), fs::perms::all);
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    if (geteuid() == 0 && (setgid(65534) != 0 || setuid(65534) != 0)) _exit(3);
    for (const fs::path& out : {dir / "ro" / "a.exr", dir / "ro" / "sub" / "a.exr"}) {
      try {
        OutputFiles::check(out, "output");
        _exit(1);  // accepted
      } catch (const Error& e) {
        if (e.describe().find("cannot write into the output folder: Permission denied") ==
            std::string::npos)
          _exit(2);
      }
    }
    OutputFiles::check(dir / "a.exr", "output");  // the writable folder beside it
    _exit(0);
  }
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 0) << "1: accepted; 2: another error; 3: could not give up "
                                       "root's rights";
  fs::permissions(dir / "ro", fs::perms::all);
}

TEST(OutputFiles, AFailedMoveRestoresThePreviousFiles) {
  TempDir dir;
  writeText(dir / "a.exr", "old a");
  OutputFiles out;
  const fs::path ta = out.add(dir / "a.exr"), tb = out.add(dir / "b.jpg");
  writeText(ta, "new a");
  writeText(tb, "new b");
  // Something takes the second name before the commit: a folder cannot be replaced by a file.
  fs::create_directory(dir / "b.jpg");
  writeText(dir / "b.jpg" / "inside", "x");
  COMPOSE_EXPECT_ERROR(out.commit(), "is an existing folder");
  EXPECT_EQ(slurp(dir / "a.exr"), "old a") << "the first output must be restored";
  EXPECT_EQ(fileCount(dir.path()), 2u) << "no temporaries left";
}

TEST(OutputFiles, UncommittedTemporariesAreRemoved) {
  TempDir dir;
  {
    OutputFiles out;
    writeText(out.add(dir / "x.png"), "partial");
  }
  EXPECT_EQ(fileCount(dir.path()), 0u);
}

// The folders made for outputs that were not written go with them; a folder that was there, or
// that holds another file by then, stays.
TEST(OutputFiles, FoldersMadeForUncommittedOutputsAreRemoved) {
  TempDir dir;
  {
    OutputFiles out;
    writeText(out.add(dir / "new" / "deeper" / "x.exr"), "partial");
    writeText(out.add(dir / "new" / "y.exr"), "partial");
  }
  EXPECT_FALSE(std::filesystem::exists(dir / "new"));
  {
    OutputFiles out;
    writeText(out.add(dir / "kept" / "x.exr"), "partial");
    writeText(dir / "kept" / "mine.txt", "the user's");
  }
  EXPECT_TRUE(std::filesystem::exists(dir / "kept" / "mine.txt"));
  {
    OutputFiles out;
    writeText(out.add(dir / "done" / "x.exr"), "whole");
    out.commit();
  }
  EXPECT_TRUE(std::filesystem::exists(dir / "done" / "x.exr"));
}

// What a killed run left (its temporaries, named for its process id) is removed by the next
// writer into the same folder; a running process's, a recent one and other files are kept.
TEST(OutputFiles, AKilledRunsTemporariesAreRemoved) {
  TempDir dir;
  // A process id that no process has now: a child that has exited and been waited for.
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  ASSERT_GT(child, 0);
  ::waitpid(child, nullptr, 0);
  // A process that runs for the length of the test.
  const pid_t sleeper = ::fork();
  if (sleeper == 0) {
    ::sleep(60);
    ::_exit(0);
  }
  ASSERT_GT(sleeper, 0);
  const std::string dead = std::to_string(child), alive = std::to_string(sleeper);
  const auto old = std::filesystem::file_time_type::clock::now() - std::chrono::minutes(5);
  auto make = [&](const std::string& name, bool aged) {
    writeText(dir / name, "x");
    if (aged) std::filesystem::last_write_time(dir / name, old);
  };
  make(".out.partial-" + dead + "-0.exr", true);    // removed
  make(".out.partial-" + dead + "-1.exr", false);   // too recent: kept
  make(".out.partial-" + alive + "-0.exr", true);   // its process runs: kept
  make(".other.partial-" + dead + "-0.exr", true);  // another output's: kept
  make("out.exr", true);                            // kept
  // A killed commit's backup of the output before it.
  make(".out.previous-" + dead + "-2.exr", true);   // removed
  make(".out.previous-" + alive + "-2.exr", true);  // kept
  OutputFiles files("test");
  files.add(dir / "out.exr");
  EXPECT_FALSE(std::filesystem::exists(dir / (".out.partial-" + dead + "-0.exr")));
  EXPECT_TRUE(std::filesystem::exists(dir / (".out.partial-" + dead + "-1.exr")));
  EXPECT_TRUE(std::filesystem::exists(dir / (".out.partial-" + alive + "-0.exr")));
  EXPECT_TRUE(std::filesystem::exists(dir / (".other.partial-" + dead + "-0.exr")));
  EXPECT_TRUE(std::filesystem::exists(dir / "out.exr"));
  EXPECT_FALSE(std::filesystem::exists(dir / (".out.previous-" + dead + "-2.exr")));
  EXPECT_TRUE(std::filesystem::exists(dir / (".out.previous-" + alive + "-2.exr")));
  ::kill(sleeper, SIGKILL);
  ::waitpid(sleeper, nullptr, 0);
}

// A SIGTERM while a commit renames its files waits until they are all in place: the outputs are
// all the new ones or all the previous ones, never some of each (a farm manager's SIGTERM between
// two renames left a new EXR beside the previous run's JPEG). A child commits 300 files over
// their previous versions and is sent SIGTERM at times through its commit; it dies of it either
// way.
TEST(OutputFiles, ASignalDuringACommitLeavesOneRunsFiles) {
  constexpr int kFiles = 300;
  // From just before the commit's renames to after them, on this machine and slower ones.
  for (const int delay : {500, 1000, 1500, 2000, 3000, 4000, 5000, 6500}) {
    TempDir dir;
    for (int i = 0; i < kFiles; ++i) writeText(dir / ("f" + std::to_string(i)), "old");
    int pipe[2];
    ASSERT_EQ(::pipe(pipe), 0);
    const pid_t child = ::fork();
    if (child == 0) {
      OutputFiles files("test");
      for (int i = 0; i < kFiles; ++i)
        std::ofstream(files.add(dir / ("f" + std::to_string(i)))) << "new";
      const char go = 'g';
      if (::write(pipe[1], &go, 1) != 1) ::_exit(3);
      files.commit();
      ::_exit(0);
    }
    ASSERT_GT(child, 0);
    char go = 0;
    ASSERT_EQ(::read(pipe[0], &go, 1), 1);
    ::usleep(useconds_t(delay));
    ::kill(child, SIGTERM);
    int status = 0;
    ::waitpid(child, &status, 0);
    ::close(pipe[0]);
    ::close(pipe[1]);
    int fresh = 0;
    for (int i = 0; i < kFiles; ++i) {
      std::ifstream in(dir / ("f" + std::to_string(i)));
      std::string text;
      in >> text;
      fresh += text == "new" ? 1 : 0;
    }
    EXPECT_TRUE(fresh == 0 || fresh == kFiles)
        << fresh << " of " << kFiles << " files are new, SIGTERM after " << delay << " us";
    EXPECT_TRUE(WIFSIGNALED(status) || (WIFEXITED(status) && WEXITSTATUS(status) == 0));
  }
}

TEST(OutputFiles, RefusesAFolderAsDestination) {
  TempDir dir;
  fs::create_directory(dir / "out.jpg");
  OutputFiles out;
  COMPOSE_EXPECT_ERROR(out.add(dir / "out.jpg"), "is an existing folder");
}

TEST(OutputFiles, APathUnderAFileNamesTheFile) {
  TempDir dir;
  writeText(dir / "file", "x");
  // A path under a regular file cannot be created: the file on the way is named.
  COMPOSE_EXPECT_ERROR(writeTextFile(dir / "file" / "sub" / "t.txt", "y", "output"),
                       "cannot write into the output folder: it is a file, not a folder");
  COMPOSE_EXPECT_ERROR(writeTextFile(dir / "file" / "sub" / "t.txt", "y", "output"),
                       (dir / "file").string() + ")");
}

}  // namespace
}  // namespace compose
