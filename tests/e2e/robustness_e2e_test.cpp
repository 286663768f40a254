// The compose command against hostile inputs and a hostile machine: devices and FIFOs as inputs,
// headers claiming huge sizes, the limits' options, eight runs sharing one cache folder at once,
// two runs writing the same outputs, damaged cache entries, a cache folder that cannot be
// written, a full disk (a file-size limit) and an output folder that does not exist.
//
// The inputs are small and made here (a 96x64 plate, two octahedra that shadow each other, a
// 64x32 environment), so that many runs stay cheap.
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "command_util.h"
#include "core/image.h"
#include "ingest/image_io.h"
#include "pipeline/stage_cache.h"
#include "test_util.h"

namespace compose {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;

using RunResult = compose::testing::CommandResult;
using compose::testing::quote;
using compose::testing::slurp;

// Runs a shell command line (sh), its output and errors captured as <tag>.out and <tag>.err.
RunResult runShell(const std::string& command, const fs::path& scratch, const std::string& tag) {
  return compose::testing::runShell(command, scratch / (tag + ".out"), scratch / (tag + ".err"));
}
const std::string kCompose = quote(COMPOSE_EXECUTABLE);

// The report line of one stage ("compose: render ... reused ...").
std::string stageLine(const std::string& err, const std::string& stage) {
  const std::string prefix = "compose: " + stage + " ";
  const size_t at = err.find(prefix);
  if (at == std::string::npos) return {};
  return err.substr(at, err.find('\n', at) - at);
}

class Robustness : public ::testing::Test {
 protected:
  TempDir dir;

  void SetUp() override {
    Image plate(96, 64, 3, {"R", "G", "B"});
    for (int y = 0; y < plate.height; ++y)
      for (int x = 0; x < plate.width; ++x)
        for (int c = 0; c < 3; ++c)
          plate.pixels[(size_t(y) * 96 + size_t(x)) * 3 + size_t(c)] =
              0.2f + 0.5f * float(y) / 64.0f + 0.1f * float(c) + 0.002f * float(x);
    ingest::writeImage(dir / "plate.jpg", plate);
    Image env(64, 32, 3, {"R", "G", "B"});
    for (int y = 0; y < env.height; ++y)
      for (int x = 0; x < env.width; ++x)
        for (int c = 0; c < 3; ++c)
          env.pixels[(size_t(y) * 64 + size_t(x)) * 3 + size_t(c)] =
              (y < 8 ? 3.0f : 0.3f) + 0.01f * float(x % 7) + 0.05f * float(c);
    env.colorSpace = "lin_rec709";
    ingest::writeImage(dir / "env.exr", env);
    // Two octahedra side by side: not convex, so the self-shadowing stage runs and is cached.
    std::string obj;
    const float corners[6][3] = {{1, 0, 0},  {-1, 0, 0}, {0, 1, 0},
                                 {0, -1, 0}, {0, 0, 1},  {0, 0, -1}};
    const int faces[8][3] = {{1, 3, 5}, {3, 2, 5}, {2, 4, 5}, {4, 1, 5},
                             {3, 1, 6}, {2, 3, 6}, {4, 2, 6}, {1, 4, 6}};
    const float offsets[2][2] = {{-1.2f, 0.0f}, {1.2f, 0.5f}};
    for (const auto& o : offsets)
      for (const auto& p : corners)
        obj += "v " + std::to_string(p[0] + o[0]) + " " + std::to_string(p[1] + o[1]) + " " +
               std::to_string(p[2]) + "\n";
    for (int k = 0; k < 2; ++k)
      for (const auto& f : faces)
        obj += "f " + std::to_string(f[0] + 6 * k) + " " + std::to_string(f[1] + 6 * k) + " " +
               std::to_string(f[2] + 6 * k) + "\n";
    compose::testing::writeText(dir / "two.obj", obj);
  }

  std::string inputs(const std::string& plate = "", const std::string& object = "") const {
    return "--plate " + quote(plate.empty() ? (dir / "plate.jpg").string() : plate) + " --object " +
           quote(object.empty() ? (dir / "two.obj").string() : object) + " --env " +
           quote((dir / "env.exr").string()) +
           " --samples 1 --shadow-params order=4,grid=4,sources=4";
  }
  std::string job(const std::string& out, const std::string& extra = "") const {
    return kCompose + " " + inputs() + " --cache " + quote((dir / "cache").string()) + " --out " +
           quote((dir / out).string()) + " " + extra;
  }
  RunResult run(const std::string& out, const std::string& extra = "") const {
    std::string tag = out;
    for (char& c : tag)
      if (c == '/') c = '_';
    return runShell(job(out, extra), dir.path(), tag);
  }
  Pixels pixels(const std::string& file) const {
    return ingest::readImage(dir / file).image.pixels;
  }
};

// ---------------------------------------------------------------------------------------------

TEST_F(Robustness, DevicesAndFifosAsInputsAreNamedErrorsNotHangs) {
  const RunResult zero =
      runShell(kCompose + " " + inputs("/dev/zero") + " --out " + quote((dir / "z").string()),
               dir.path(), "zero");
  EXPECT_EQ(zero.status, 1) << zero.err;
  EXPECT_NE(zero.err.find("is a character device, not a regular file"), std::string::npos)
      << zero.err;
  EXPECT_NE(zero.err.find("/dev/zero"), std::string::npos) << zero.err;
  // A FIFO nobody writes to: opening it would block forever.
  ASSERT_EQ(::mkfifo((dir / "pipe.obj").c_str(), 0600), 0);
  const RunResult fifo = runShell(kCompose + " " + inputs("", (dir / "pipe.obj").string()) +
                                      " --out " + quote((dir / "f").string()),
                                  dir.path(), "fifo");
  EXPECT_EQ(fifo.status, 1) << fifo.err;
  EXPECT_NE(fifo.err.find("is a FIFO (named pipe)"), std::string::npos) << fifo.err;
  EXPECT_FALSE(fs::exists(dir / "z.exr"));
}

// A stage command's --out that cannot be a file (a FIFO, an existing folder) is refused before
// the stage works, not after: nothing is computed, so nothing reaches the cache.
TEST_F(Robustness, AStageCommandRefusesAnOutputThatCannotBeAFileBeforeWorking) {
  ASSERT_EQ(::mkfifo((dir / "pipe.lighting").c_str(), 0600), 0);
  fs::create_directories(dir / "folder.exr");
  const std::string cache = " --cache " + quote((dir / "cache").string());
  const std::string env = " --env " + quote((dir / "env.exr").string());
  const RunResult precompute = runShell(
      kCompose + " precompute" + env + cache + " --out " + quote((dir / "pipe.lighting").string()),
      dir.path(), "precompute");
  EXPECT_EQ(precompute.status, 1) << precompute.err;
  EXPECT_NE(precompute.err.find("precompute: output path is a FIFO (named pipe)"),
            std::string::npos)
      << precompute.err;
  const RunResult render =
      runShell(kCompose + " render --plate " + quote((dir / "plate.jpg").string()) + " --object " +
                   quote((dir / "two.obj").string()) + " --lighting-file " +
                   quote((dir / "pipe.lighting").string()) + cache + " --out " +
                   quote((dir / "folder.exr").string()),
               dir.path(), "render");
  EXPECT_EQ(render.status, 1) << render.err;
  EXPECT_NE(render.err.find("render: output path is an existing folder"), std::string::npos)
      << render.err;
  // A folder on the way that is a file: nothing can be made there, said before the work.
  compose::testing::writeText(dir / "afile", "not a folder");
  const RunResult nested = runShell(kCompose + " precompute" + env + cache + " --out " +
                                        quote((dir / "afile" / "sub" / "out.lighting").string()),
                                    dir.path(), "nested");
  EXPECT_EQ(nested.status, 1) << nested.err;
  EXPECT_NE(nested.err.find("it is a file, not a folder"), std::string::npos) << nested.err;
  // Nothing was computed: no cache entry, and the nodes are what they were.
  std::error_code ec;
  EXPECT_TRUE(!fs::exists(dir / "cache") || fs::is_empty(dir / "cache", ec));
  EXPECT_EQ(fs::status(dir / "pipe.lighting").type(), fs::file_type::fifo);
  EXPECT_TRUE(fs::is_directory(dir / "folder.exr") && fs::is_empty(dir / "folder.exr", ec));
}

// --explain makes the run's own checks on its outputs before saying what would run: a plan that
// the run would refuse at once (its EXR over the environment, its output a folder) is that error,
// not a plan. A scene without a plate is the scene's error (exit 1, naming it), and precompute
// does not replace a file that is not a lighting file.
TEST_F(Robustness, ExplainScenesAndLightingFilesRefuseWhatTheRunWould) {
  const fs::path envCopy = dir / "env_copy.exr";
  fs::copy_file(dir / "env.exr", envCopy);
  const std::string over = kCompose + " --plate " + quote((dir / "plate.jpg").string()) +
                           " --object " + quote((dir / "two.obj").string()) + " --env " +
                           quote(envCopy.string()) + " --out " +
                           quote((dir / "env_copy").string()) + " --explain";
  const RunResult a = runShell(over, dir.path(), "explain_over");
  EXPECT_EQ(a.status, 1) << a.out << a.err;
  EXPECT_NE(a.err.find("the output would replace an input"), std::string::npos) << a.err;
  EXPECT_EQ(a.out.find("render"), std::string::npos) << "no plan printed: " << a.out;
  fs::create_directories(dir / "folder.exr");
  const RunResult b = run("folder", "--explain");
  EXPECT_EQ(b.status, 1) << b.out << b.err;
  EXPECT_NE(b.err.find("output path is an existing folder"), std::string::npos) << b.err;
  const RunResult fine = run("fine", "--explain");
  EXPECT_EQ(fine.status, 0) << fine.err;
  EXPECT_NE(fine.out.find("render"), std::string::npos) << fine.out;

  compose::testing::writeText(dir / "noplate.json",
                              "{\"compose\": \"scene\", \"version\": 1, \"stages\": {\"ingest\": "
                              "{\"object\": \"two.obj\"}}}\n");
  const RunResult c =
      runShell(kCompose + " run " + quote((dir / "noplate.json").string()) + " --explain",
               dir.path(), "noplate");
  EXPECT_EQ(c.status, 1) << c.err;
  EXPECT_NE(c.err.find("scene: the scene gives no plate: set ingest.plate"), std::string::npos)
      << c.err;
  EXPECT_NE(c.err.find("noplate.json"), std::string::npos) << c.err;
  // A path the scene names that is not there: its key, and where scene paths are read from.
  compose::testing::writeText(dir / "missing.json",
                              "{\"compose\": \"scene\", \"version\": 1, \"stages\": {\"ingest\": "
                              "{\"plate\": \"plate.jpg\", \"object\": \"two.obj\", "
                              "\"environment\": \"elsewhere/env.exr\"}}}\n");
  const RunResult m =
      runShell(kCompose + " run " + quote((dir / "missing.json").string()) + " --explain",
               dir.path(), "missing");
  EXPECT_EQ(m.status, 1) << m.err;
  EXPECT_NE(m.err.find("scene: ingest.environment names a file that is not there: "),
            std::string::npos)
      << m.err;
  EXPECT_NE(m.err.find("read from the scene file's folder"), std::string::npos) << m.err;

  const std::string sceneText = slurp(dir / "noplate.json");
  const RunResult d = runShell(kCompose + " precompute --env " + quote((dir / "env.exr").string()) +
                                   " --cache " + quote((dir / "cache").string()) + " --out " +
                                   quote((dir / "noplate.json").string()),
                               dir.path(), "precompute_over_scene");
  EXPECT_EQ(d.status, 1) << d.err;
  EXPECT_NE(d.err.find("is not a compose lighting file and would be replaced"), std::string::npos)
      << d.err;
  EXPECT_EQ(slurp(dir / "noplate.json"), sceneText) << "the scene file is untouched";
  // An older lighting file is replaced.
  const std::string lighting = " --out " + quote((dir / "a.lighting").string());
  const std::string precompute = kCompose + " precompute --env " +
                                 quote((dir / "env.exr").string()) + " --cache " +
                                 quote((dir / "cache").string());
  EXPECT_EQ(runShell(precompute + lighting, dir.path(), "lighting1").status, 0);
  EXPECT_EQ(runShell(precompute + " --env-yaw 30" + lighting, dir.path(), "lighting2").status, 0);
}

TEST_F(Robustness, LimitsRefuseWithTheirOptionNamed) {
  const RunResult pixels = run("p", "--max-pixels 1000");
  EXPECT_EQ(pixels.status, 1) << pixels.err;
  EXPECT_NE(pixels.err.find("image is 96 x 64 pixels"), std::string::npos) << pixels.err;
  EXPECT_NE(pixels.err.find("raise it with --max-pixels"), std::string::npos) << pixels.err;
  const RunResult triangles = run("t", "--max-triangles 10");
  EXPECT_EQ(triangles.status, 1) << triangles.err;
  EXPECT_NE(triangles.err.find("more than the limit of 10 (raise it with --max-triangles)"),
            std::string::npos)
      << triangles.err;
  for (const char* bad : {"--max-pixels 0", "--max-triangles -5", "--samples 65"}) {
    const RunResult r = run("u", bad);
    EXPECT_EQ(r.status, 2) << bad << ": " << r.err;
  }
  EXPECT_FALSE(fs::exists(dir / "p.exr"));
}

TEST_F(Robustness, EightRunsAtOnceShareOneCacheFolder) {
  // Eight processes started together on the same inputs and the same (empty) cache folder.
  std::string script;
  for (int i = 0; i < 8; ++i) {
    const std::string n = std::to_string(i);
    script += "( " + job("run" + n) + " >" + quote((dir / ("run" + n + ".log")).string()) +
              " 2>&1; echo $? >" + quote((dir / ("run" + n + ".status")).string()) + " ) & ";
  }
  script += "wait";
  runShell(script, dir.path(), "eight");
  const Pixels first = pixels("run0.exr");
  ASSERT_FALSE(first.empty());
  for (int i = 0; i < 8; ++i) {
    const std::string n = std::to_string(i);
    EXPECT_EQ(slurp(dir / ("run" + n + ".status")), "0\n") << slurp(dir / ("run" + n + ".log"));
    EXPECT_EQ(pixels("run" + n + ".exr"), first) << "run " << i << " differs";
    EXPECT_EQ(slurp(dir / ("run" + n + ".log")).find("ignored"), std::string::npos)
        << "run " << i << " found a damaged cache entry:\n"
        << slurp(dir / ("run" + n + ".log"));
  }
  // The cache is valid afterwards: no temporaries left, and a ninth run reuses every stage it
  // needs without a note about a damaged entry, with the same pixels.
  for (const auto& e : fs::recursive_directory_iterator(dir / "cache"))
    EXPECT_EQ(e.path().filename().string().find(".partial-"), std::string::npos) << e.path();
  const RunResult ninth = run("ninth");
  ASSERT_EQ(ninth.status, 0) << ninth.err;
  EXPECT_EQ(ninth.err.find("ignored"), std::string::npos) << ninth.err;
  EXPECT_NE(stageLine(ninth.err, "render").find("reused"), std::string::npos) << ninth.err;
  EXPECT_EQ(pixels("ninth.exr"), first);
}

TEST_F(Robustness, TwoRunsWritingTheSameOutputsLeaveOneRunsCompleteSet) {
  // References, one run at a time: two jobs that differ in their pixels.
  ASSERT_EQ(run("a", "--albedo 0.2").status, 0);
  ASSERT_EQ(run("b", "--albedo 0.8").status, 0);
  const Pixels a = pixels("a.exr"), b = pixels("b.exr");
  ASSERT_NE(a, b);
  const Pixels aJpg = pixels("a.jpg"), bJpg = pixels("b.jpg");
  for (int round = 0; round < 3; ++round) {
    runShell(
        "( " + job("same", "--albedo 0.2") + " ) & ( " + job("same", "--albedo 0.8") + " ) & wait",
        dir.path(), "both");
    const Pixels exr = pixels("same.exr"), jpg = pixels("same.jpg");
    const bool isA = exr == a, isB = exr == b;
    EXPECT_TRUE(isA || isB) << "round " << round << ": the EXR is neither run's";
    // The display JPEG belongs to the same run as the EXR: never one run's EXR with the other's.
    EXPECT_EQ(jpg, isA ? aJpg : bJpg) << "round " << round;
  }
  for (const auto& e : fs::directory_iterator(dir.path()))
    EXPECT_EQ(e.path().filename().string().find(".partial-"), std::string::npos) << e.path();
}

TEST_F(Robustness, DamagedCacheEntriesAreNotedRecomputedAndRewritten) {
  ASSERT_EQ(run("first").status, 0);
  const Pixels reference = pixels("first.exr");
  struct Damage {
    const char* name;
    const char* note;
    void (*apply)(const fs::path&);
  };
  const Damage damages[] = {
      {"truncated", "is truncated",
       [](const fs::path& p) { fs::resize_file(p, fs::file_size(p) / 2); }},
      {"zeroed", "is zeroed",
       [](const fs::path& p) {
         const auto n = fs::file_size(p);
         std::ofstream(p, std::ios::binary | std::ios::trunc) << std::string(n, '\0');
       }},
      {"old version", "is of format version '1'",
       [](const fs::path& p) {
         std::fstream f(p, std::ios::binary | std::ios::in | std::ios::out);
         f.seekp(7);
         f.put('1');
       }},
      {"empty", "is empty", [](const fs::path& p) { fs::resize_file(p, 0); }},
  };
  for (const Damage& d : damages) {
    // Every entry of every stage damaged the same way.
    int damaged = 0;
    for (const auto& e : fs::recursive_directory_iterator(dir / "cache" / "stages")) {
      if (e.is_regular_file()) {
        d.apply(e.path());
        ++damaged;
      }
    }
    ASSERT_GT(damaged, 2);
    // --explain sees the damage without running anything: no damaged entry counts as reused.
    const RunResult explain = run("explain", "--explain");
    ASSERT_EQ(explain.status, 0) << d.name << ": " << explain.err;
    EXPECT_EQ(explain.out.find("reused"), std::string::npos) << d.name << ": " << explain.out;
    EXPECT_NE(explain.out.find(d.note), std::string::npos) << d.name << ": " << explain.out;
    const RunResult r = run("again");
    ASSERT_EQ(r.status, 0) << d.name << ": " << r.err;
    EXPECT_NE(r.err.find(d.note), std::string::npos) << d.name << ": " << r.err;
    EXPECT_NE(r.err.find("ignored and computed again"), std::string::npos) << r.err;
    EXPECT_EQ(pixels("again.exr"), reference) << d.name;
    // Rewritten: the next run reuses them without a note.
    const RunResult next = run("next");
    ASSERT_EQ(next.status, 0) << next.err;
    EXPECT_EQ(next.err.find("ignored"), std::string::npos) << d.name << ": " << next.err;
    EXPECT_NE(stageLine(next.err, "render").find("reused"), std::string::npos) << next.err;
  }
  // Forged: entries that check out (a valid checksum over what is there) but whose contents are
  // not what their stage wrote: every metadata value replaced by a string, every array cut to
  // one value. Each stage's loader refuses it with a note; nothing throws out of the run.
  for (const auto& e : fs::recursive_directory_iterator(dir / "cache" / "stages")) {
    if (!e.is_regular_file()) continue;
    const std::string stage = e.path().parent_path().filename().string();
    pipeline::StageCache entry(dir / "cache" / "stages", stage, e.path().stem().string());
    ASSERT_TRUE(entry.open()) << e.path() << ": " << entry.problem();
    pipeline::StageCache forged(dir / "cache" / "stages", stage, e.path().stem().string());
    for (auto& [name, value] : entry.meta().items()) forged.meta()[name] = "forged";
    for (const char* name : {"image", "values", "beauty", "radiance", "object"})
      forged.put(name, {1.0f});
    ASSERT_TRUE(forged.write()) << forged.error();
  }
  const RunResult forged = run("forged");
  ASSERT_EQ(forged.status, 0) << forged.err;
  EXPECT_NE(forged.err.find("does not fit this job"), std::string::npos) << forged.err;
  EXPECT_EQ(pixels("forged.exr"), reference);
  const RunResult after = run("after");
  ASSERT_EQ(after.status, 0) << after.err;
  EXPECT_EQ(after.err.find("ignored"), std::string::npos) << after.err;
  EXPECT_NE(stageLine(after.err, "render").find("reused"), std::string::npos) << after.err;

  // The visibility pass's own cache (core/float_cache.h) the same way: a damaged file is named.
  for (const auto& e : fs::recursive_directory_iterator(dir / "cache" / "visibility"))
    if (e.is_regular_file()) fs::resize_file(e.path(), 10);
  fs::remove_all(dir / "cache" / "stages");
  const RunResult vis = run("vis");
  ASSERT_EQ(vis.status, 0) << vis.err;
  EXPECT_NE(vis.err.find("the cached visibility pass"), std::string::npos) << vis.err;
  EXPECT_NE(vis.err.find("is truncated"), std::string::npos) << vis.err;
  EXPECT_EQ(pixels("vis.exr"), reference);
}

// A cache path that is a file, or a link to a folder that is not there (a share not mounted):
// --explain and the run say what it is, and the run goes on uncached. (A file was "Permission
// denied" to --explain and "Not a directory" to the run; a link to nothing "File exists", and
// --explain promised caching.) An entry's place taken by a folder is that entry's problem, not
// the folder's.
TEST_F(Robustness, ACachePathThatIsAFileOrALinkToNothingIsSaidAsSuch) {
  compose::testing::writeText(dir / "cache", "not a folder");
  RunResult explain = run("file", "--explain");
  ASSERT_EQ(explain.status, 0) << explain.err;
  const std::string file = "is a file, not a folder";
  EXPECT_NE(explain.out.find("not cached: the cache folder " + (dir / "cache" / "stages").string() +
                             " cannot be made: " + (dir / "cache").string() + " " + file),
            std::string::npos)
      << explain.out;
  RunResult r = run("file");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find(file + ": the outputs of"), std::string::npos) << r.err;
  EXPECT_TRUE(fs::exists(dir / "file.exr"));

  fs::remove(dir / "cache");
  fs::create_directory_symlink(dir / "unmounted", dir / "cache");
  const std::string link = (dir / "cache").string() + " is a link to " +
                           (dir / "unmounted").string() + ", which is not there";
  explain = run("link", "--explain");
  ASSERT_EQ(explain.status, 0) << explain.err;
  EXPECT_NE(explain.out.find(link), std::string::npos) << explain.out;
  EXPECT_EQ(explain.out.find("; cached in"), std::string::npos) << explain.out;
  r = run("link");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find(link + ": the outputs of"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find("File exists"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "unmounted")) << "nothing made at the link's target";

  // A folder where one entry goes: that entry could not be written, the folder is fine.
  fs::remove(dir / "cache");
  ASSERT_EQ(run("first").status, 0);
  fs::path entry;
  for (const auto& e : fs::directory_iterator(dir / "cache" / "stages" / "render"))
    entry = e.path();
  ASSERT_FALSE(entry.empty());
  fs::remove(entry);
  fs::create_directory(entry);
  explain = run("blocked", "--explain");
  EXPECT_NE(explain.out.find("computed again, not cached (only a file there can be replaced)"),
            std::string::npos)
      << explain.out;
  r = run("blocked");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("the cache entries of render could not be written ("), std::string::npos)
      << r.err;
  EXPECT_EQ(r.err.find("the cache folder"), std::string::npos) << r.err;
  // One stage's folder a link to nothing (moved to a disk not mounted): said for that stage.
  fs::remove_all(dir / "cache" / "stages" / "render");
  fs::create_directory_symlink(dir / "gone", dir / "cache" / "stages" / "render");
  const std::string stageLink = (dir / "cache" / "stages" / "render").string() + " is a link to " +
                                (dir / "gone").string() + ", which is not there";
  explain = run("stage", "--explain");
  EXPECT_NE(explain.out.find("not cached: the cache folder"), std::string::npos) << explain.out;
  EXPECT_NE(explain.out.find(stageLink), std::string::npos) << explain.out;
  r = run("stage");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find(stageLink + ": the outputs of render were not cached"), std::string::npos)
      << r.err;
}

TEST_F(Robustness, AReadOnlyCacheFolderIsANoteAndTheRunGoesOn) {
  fs::create_directories(dir / "cache");
  std::string prefix;
  if (::geteuid() == 0) {
    // Root writes through permission bits: a read-only file system instead (a private mount).
    const RunResult probe = runShell("unshare -m true", dir.path(), "probe");
    if (probe.status != 0) GTEST_SKIP() << "running as root without unshare -m: " << probe.err;
    prefix = "unshare -m sh -c " + quote("mount -t tmpfs -o ro,size=1m tmpfs " +
                                         (dir / "cache").string() + " && exec " + job("ro"));
  } else {
    fs::permissions(dir / "cache", fs::perms::owner_read | fs::perms::owner_exec);
    prefix = job("ro");
  }
  const RunResult r = runShell(prefix, dir.path(), "ro");
  fs::permissions(dir / "cache", fs::perms::owner_all);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("cannot be written ("), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("were not cached"), std::string::npos) << r.err;
  // Those written while the later stages run (the render's, the ground shadow's) are named too.
  const size_t note = r.err.find("stages cannot be written (");
  const std::string line =
      note == std::string::npos ? "" : r.err.substr(note, r.err.find('\n', note) - note);
  EXPECT_NE(line.find("render"), std::string::npos) << line;
  EXPECT_NE(line.find("ground"), std::string::npos) << line;
  EXPECT_TRUE(fs::exists(dir / "ro.exr"));
  EXPECT_TRUE(fs::exists(dir / "ro.jpg"));
}

// Lighting parameters whose tables do not fit in memory (cheb-local at order 32 on a 1025 x 2048
// grid of normals: 26 GB) under a 4 GB address-space limit: refused before the table is allocated
// (with the kernel's overcommit, filling it could get the process killed without a word), the
// stage and the parameters that size it named; exit 1 and nothing written.
TEST_F(Robustness, LightingParametersBeyondMemoryNameWhatSizesThem) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "AddressSanitizer reserves more address space than the limit";
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
  GTEST_SKIP() << "AddressSanitizer reserves more address space than the limit";
#endif
#endif
  const RunResult r = runShell(
      "ulimit -v 4000000; " +
          job("big", "--no-cache --lighting-params order=32,samples=32,rows=1025,cols=2048"),
      dir.path(), "big");
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("compose: error: precompute: out of memory"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--lighting-params order, rows, cols"), std::string::npos) << r.err;
  // Found before the table is allocated: what needs how much.
  EXPECT_NE(r.err.find("needs 25.8 GB for the cheb-local lighting's table (order=32, 1025 x 2048"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir / "big.exr"));
}

TEST_F(Robustness, AFullDiskIsANamedErrorAndThePreviousOutputsStay) {
  ASSERT_EQ(run("out", "--albedo 0.3").status, 0);
  const std::string exr = slurp(dir / "out.exr"), jpg = slurp(dir / "out.jpg");
  // A file-size limit of 8 KB (ulimit -f counts 512-byte blocks in sh): the EXR cannot be written.
  const RunResult r =
      runShell("ulimit -f 16; " + job("out", "--albedo 0.7 --no-cache"), dir.path(), "full");
  EXPECT_EQ(r.status, 1) << r.err;
  EXPECT_NE(r.err.find("File too large"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("out."), std::string::npos) << r.err;
  EXPECT_EQ(slurp(dir / "out.exr"), exr) << "the previous EXR was changed";
  EXPECT_EQ(slurp(dir / "out.jpg"), jpg) << "the previous JPEG was changed";
  for (const auto& e : fs::directory_iterator(dir.path()))
    EXPECT_EQ(e.path().filename().string().find(".partial-"), std::string::npos) << e.path();
  EXPECT_EQ(r.err.find(".partial-"), std::string::npos) << "names a temporary: " << r.err;

  // The same for an environment written by convert, in each kind of file: the error names the
  // file asked for, not the temporary the writer fills. (OpenImageIO's PNG writer does not check
  // its writes: the faces were left cut short with exit 0.) A PNG takes values up to 1 only.
  Image ldr(64, 32, 3, {"R", "G", "B"});
  for (size_t i = 0; i < ldr.pixels.size(); ++i)
    ldr.pixels[i] = 0.2f + 0.6f * float(i % 97) / 97.0f;
  ldr.colorSpace = "lin_rec709";
  ingest::writeImage(dir / "ldr.exr", ldr);
  for (const std::string out : {"cube.exr", "faces_%.png"}) {
    const std::string input = out == "cube.exr" ? "env.exr" : "ldr.exr";
    const RunResult c =
        runShell("ulimit -f 4; " + kCompose + " convert " + quote((dir / input).string()) +
                     " --to " + (out == "cube.exr" ? "cube" : "faces") + " --size 256 --out " +
                     quote((dir / out).string()),
                 dir.path(), "convert");
    EXPECT_EQ(c.status, 1) << c.err;
    EXPECT_NE(c.err.find("File too large"), std::string::npos) << c.err;
    EXPECT_NE(c.err.find((dir / (out == "cube.exr" ? "cube.exr" : "faces_")).string()),
              std::string::npos)
        << c.err;
    EXPECT_EQ(c.err.find(".partial-"), std::string::npos) << "names a temporary: " << c.err;
    for (const auto& e : fs::directory_iterator(dir.path()))
      EXPECT_EQ(e.path().filename().string().find(".partial-"), std::string::npos) << e.path();
  }
}

TEST_F(Robustness, AnOutputFolderThatDoesNotExistIsCreated) {
  const RunResult r = run("new/folder/deep/x");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "new/folder/deep/x.exr"));
  EXPECT_TRUE(fs::exists(dir / "new/folder/deep/x.jpg"));
  // A file where a folder of the path should be: a named error.
  compose::testing::writeText(dir / "blocker", "x");
  const RunResult blocked = run("blocker/x");
  EXPECT_EQ(blocked.status, 1) << blocked.err;
  EXPECT_NE(blocked.err.find("compose: error: output:"), std::string::npos) << blocked.err;
}

}  // namespace
}  // namespace compose
