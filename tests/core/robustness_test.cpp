// Resource limits (core/limits.h), inputs that are not regular files, progress lines, and the
// on-disk caches' checks (core/float_cache.h, pipeline/stage_cache.h): every kind of damaged
// cache file is detected and named, never read as data.
#include <sys/stat.h>

#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "core/float_cache.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "core/progress.h"
#include "ingest/image_io.h"
#include "pipeline/stage_cache.h"
#include "render/mesh.h"
#include "test_util.h"

namespace compose {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;

std::string readBytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeBytes(const fs::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), std::streamsize(bytes.size()));
}

// Sets the process-wide limits for one test and puts the defaults back afterwards.
class ScopedLimits {
 public:
  explicit ScopedLimits(const ResourceLimits& limits) { setResourceLimits(limits); }
  ~ScopedLimits() { setResourceLimits(ResourceLimits{}); }
};

// ---------------------------------------------------------------------------------------------
// Messages quote untrusted text

// A file's bytes reach error messages and notes (an OBJ line, a glTF material name): control
// characters are written out, so that an ESC sequence cannot recolour or retitle the terminal.
TEST(Printable, ControlCharactersAreWrittenOut) {
  EXPECT_EQ(printable("face corner '\x1b[31mRED\x1b]0;pwned\x07'"),
            "face corner '\\x1b[31mRED\\x1b]0;pwned\\x07'");
  EXPECT_EQ(printable("a\rb\x7f"), "a\\x0db\\x7f");
  EXPECT_EQ(printable("two\nlines\tand tabs, caf\xc3\xa9"), "two\nlines\tand tabs, caf\xc3\xa9");
  // C1 controls (CSI is 0x9b): raw, and as UTF-8 (U+009B); other UTF-8 stays whole.
  EXPECT_EQ(printable("a\x9b"
                      "31m"),
            "a\\x9b"
            "31m");
  EXPECT_EQ(printable("a\xc2\x9b"
                      "31m \xe2\x82\xac \xc2\xb0"),
            "a\\xc2\\x9b"
            "31m \xe2\x82\xac \xc2\xb0");
  // The error itself: an OBJ face corner with an escape sequence, named as it is in the file.
  TempDir dir;
  writeBytes(dir / "esc.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \x1b[2J\n");
  try {
    (void)render::loadMesh(dir / "esc.obj");
    ADD_FAILURE() << "loaded";
  } catch (const Error& e) {
    const std::string shown = printable(e.describe());
    EXPECT_EQ(shown.find('\x1b'), std::string::npos) << shown;
    EXPECT_NE(shown.find("'\\x1b[2J'"), std::string::npos) << shown;
  }
}

// ---------------------------------------------------------------------------------------------
// Limits

TEST(ResourceLimits, ImageSizesBeyondTheLimitAreRefusedWithTheOptionNamed) {
  COMPOSE_EXPECT_ERROR(checkImageSize(100000, 100000, 3, "ingest", "huge.png"),
                       "image is 100000 x 100000 pixels (10000 megapixels), more than the limit "
                       "of 268 megapixels (raise it with --max-pixels)");
  checkImageSize(16384, 16384, 4, "ingest", "largest.exr");  // exactly the default limit
  COMPOSE_EXPECT_ERROR(checkImageSize(16384, 16384, 5, "ingest", "wide.exr"), "channels");
  COMPOSE_EXPECT_ERROR(checkImageSize(0, 10, 3, "ingest", "empty.png"), "no pixels");
  {
    ResourceLimits small;
    small.maxPixels = 100;
    const ScopedLimits scoped(small);
    COMPOSE_EXPECT_ERROR(checkImageSize(11, 10, 3, "ingest", "a.png"), "--max-pixels");
    checkImageSize(10, 10, 3, "ingest", "a.png");
  }
}

TEST(ResourceLimits, NonPositiveLimitsAreUsageErrors) {
  ResourceLimits bad;
  bad.maxPixels = 0;
  EXPECT_THROW(setResourceLimits(bad), UsageError);
  bad = {};
  bad.maxTriangles = -1;
  EXPECT_THROW(setResourceLimits(bad), UsageError);
  EXPECT_EQ(resourceLimits().maxPixels, ResourceLimits::kDefaultMaxPixels);
}

// A PNG whose header claims 100,000 x 100,000 pixels (30 GB as 8-bit RGB, 120 GB as float).
std::string hugePngHeader() {
  auto crc32 = [](const std::string& bytes) {
    uint32_t c = 0xFFFFFFFFu;
    for (unsigned char b : bytes) {
      c ^= b;
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return c ^ 0xFFFFFFFFu;
  };
  auto be32 = [](uint32_t v) {
    return std::string{char(v >> 24), char(v >> 16), char(v >> 8), char(v)};
  };
  auto chunk = [&](const std::string& type, const std::string& data) {
    return be32(uint32_t(data.size())) + type + data + be32(crc32(type + data));
  };
  const std::string ihdr = be32(100000) + be32(100000) + std::string{8, 2, 0, 0, 0};
  // An IDAT of one empty zlib stream: the decoder would fail long after allocating.
  const std::string idat("\x78\x9c\x03\x00\x00\x00\x00\x01", 8);
  return std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) + chunk("IDAT", idat) +
         chunk("IEND", "");
}

// A table larger than the memory left is refused before it is allocated, saying how much it
// needed; small ones are not checked.
TEST(ResourceLimits, ATableBeyondTheMemoryLeftIsRefusedUpFront) {
  const size_t available = allocatableBytes();
  ASSERT_GT(available, size_t(0));
  EXPECT_NO_THROW(requireMemory(size_t(1) << 20, "a small table"));
  const size_t huge = std::numeric_limits<size_t>::max() / 2;
  ASSERT_GT(huge, available);
  try {
    requireMemory(huge, "the test's table");
    ADD_FAILURE() << "not refused";
  } catch (const MemoryShortfall& e) {
    EXPECT_EQ(e.needed(), huge);
    EXPECT_NE(std::string(e.what()).find("for the test's table, more than the"), std::string::npos)
        << e.what();
    const std::bad_alloc& asBadAlloc = e;  // what a caller that knows no better catches
    EXPECT_STREQ(asBadAlloc.what(), e.what());
  }
}

TEST(ResourceLimits, AHugeImageHeaderIsRefusedBeforeDecoding) {
  TempDir dir;
  writeBytes(dir / "huge.png", hugePngHeader());
  // Under AddressSanitizer an allocation of this size would itself fail the test.
  COMPOSE_EXPECT_ERROR(ingest::readImage(dir / "huge.png"), "100000 x 100000 pixels");
  COMPOSE_EXPECT_ERROR(ingest::readImage(dir / "huge.png"), "--max-pixels");
}

TEST(ResourceLimits, MeshesBeyondTheTriangleLimitAreRefused) {
  TempDir dir;
  compose::testing::writeText(dir / "quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n");
  render::loadMesh(dir / "quad.obj");
  ResourceLimits one;
  one.maxTriangles = 1;
  const ScopedLimits scoped(one);
  COMPOSE_EXPECT_ERROR(render::loadMesh(dir / "quad.obj"),
                       "mesh has at least 2 triangles, more than the limit of 1 (raise it with "
                       "--max-triangles)");
}

// An output is written to a temporary file and renamed over its destination: over a device or a
// FIFO that would put a file in its place (`--out /dev/null` replaced /dev/null). Refused, and the
// node stays what it was. (OutputFiles::add writes nothing: /dev/null is safe to ask about.)
TEST(RegularFilesOnly, AnOutputOverADeviceOrAFifoIsRefusedAndTheNodeStays) {
  TempDir dir;
  ASSERT_EQ(::mkfifo((dir / "out.exr").c_str(), 0600), 0);
  OutputFiles outputs("output");
  COMPOSE_EXPECT_ERROR(outputs.add(dir / "out.exr"),
                       "output path is a FIFO (named pipe), not a file");
  COMPOSE_EXPECT_ERROR(outputs.add("/dev/null"), "output path is a character device, not a file");
  EXPECT_EQ(fs::status(dir / "out.exr").type(), fs::file_type::fifo);

  ASSERT_EQ(::mkfifo((dir / "out.lighting").c_str(), 0600), 0);
  pipeline::StageCache entry = pipeline::StageCache::atFile(dir / "out.lighting", "precompute");
  entry.meta() = {{"x", 1}};
  EXPECT_FALSE(entry.write());
  EXPECT_NE(entry.error().find("a FIFO (named pipe), not a file"), std::string::npos)
      << entry.error();
  EXPECT_EQ(fs::status(dir / "out.lighting").type(), fs::file_type::fifo);
}

TEST(RegularFilesOnly, DevicesAndFifosAreNamedErrors) {
  COMPOSE_EXPECT_ERROR(requireRegularFile("/dev/zero", "ingest"), "is a character device");
  COMPOSE_EXPECT_ERROR(ingest::readImage("/dev/zero"), "not a regular file");
  COMPOSE_EXPECT_ERROR(render::loadMesh("/dev/null"), "is a character device");
  TempDir dir;
  ASSERT_EQ(::mkfifo((dir / "pipe.jpg").c_str(), 0600), 0);
  // Opening a FIFO for reading would block until a writer comes: refused before that.
  COMPOSE_EXPECT_ERROR(ingest::readImage(dir / "pipe.jpg"), "is a FIFO (named pipe)");
  ASSERT_EQ(::mkfifo((dir / "pipe.obj").c_str(), 0600), 0);
  COMPOSE_EXPECT_ERROR(render::loadMesh(dir / "pipe.obj"), "is a FIFO");
  // A glTF whose buffer is a FIFO: the buffer is not read (it would block).
  ASSERT_EQ(::mkfifo((dir / "buffer.bin").c_str(), 0600), 0);
  compose::testing::writeText(
      dir / "fifo.gltf",
      R"({"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],
          "buffers":[{"uri":"buffer.bin","byteLength":36}],
          "bufferViews":[{"buffer":0,"byteLength":36}],
          "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3"}]})");
  COMPOSE_EXPECT_ERROR(render::loadMesh(dir / "fifo.gltf"), "not a regular file");
  compose::testing::writeText(dir / "plain.txt", "x");
  requireRegularFile(dir / "plain.txt", "ingest");
  requireRegularFile(dir / "missing.txt", "ingest");  // the caller says "not found"
}

TEST(ProgressThrottle, ALineEveryIntervalAndNoneBeforeTheFirst) {
  ProgressThrottle t(5.0, 100.0);
  EXPECT_FALSE(t.due(100.0));
  EXPECT_FALSE(t.due(104.9));
  EXPECT_TRUE(t.due(105.0));
  EXPECT_FALSE(t.due(109.0));
  EXPECT_TRUE(t.due(111.0));
  EXPECT_FALSE(t.due(115.5));
  EXPECT_TRUE(t.due(116.0));
}

// ---------------------------------------------------------------------------------------------
// The float cache (lighting projections, visibility passes)

class FloatCacheFiles : public ::testing::Test {
 protected:
  TempDir dir;
  FloatCache cache{dir / "c", "COMPTST2", ".t"};
  const std::string key = "k";
  const std::string description = "what it holds";
  const std::vector<float> values = {1.0f, -2.5f, 3.25f, 0.0f, 1e-3f};

  void SetUp() override { ASSERT_TRUE(cache.store(key, description, values)); }
  std::string bytes() const { return readBytes(cache.pathFor(key)); }
  void put(const std::string& b) { writeBytes(cache.pathFor(key), b); }
  void expectInvalid(const std::string& needle) {
    const FloatCache::Read r = cache.read(key, description);
    EXPECT_EQ(r.status, FloatCache::Read::Status::Invalid) << needle;
    EXPECT_NE(r.problem.find(needle), std::string::npos) << r.problem;
    EXPECT_TRUE(r.values.empty());
    EXPECT_FALSE(cache.load(key, description));
  }
};

TEST_F(FloatCacheFiles, AStoredEntryReadsBackBitForBit) {
  const FloatCache::Read r = cache.read(key, description);
  ASSERT_EQ(r.status, FloatCache::Read::Status::Hit) << r.problem;
  EXPECT_EQ(std::vector<float>(r.values.begin(), r.values.end()), values);
  EXPECT_EQ(cache.read("other", description).status, FloatCache::Read::Status::Missing);
}

TEST_F(FloatCacheFiles, TruncatedAtEveryLengthIsDetected) {
  const std::string full = bytes();
  for (size_t n = 1; n < full.size(); ++n) {
    put(full.substr(0, n));
    const FloatCache::Read r = cache.read(key, description);
    EXPECT_EQ(r.status, FloatCache::Read::Status::Invalid) << n << " bytes";
    EXPECT_NE(r.problem.find("truncated"), std::string::npos) << n << ": " << r.problem;
  }
  put("");
  expectInvalid("is empty");
}

TEST_F(FloatCacheFiles, ZeroedOldVersionForeignAndDamagedFilesAreDetected) {
  const std::string full = bytes();
  put(std::string(full.size(), '\0'));
  expectInvalid("is zeroed");
  std::string old = full;
  old[7] = '1';
  put(old);
  expectInvalid("is of format version '1', this compose reads version '2'");
  put("#!/bin/sh\necho this is not a cache file at all\n");
  expectInvalid("not a compose cache file");
  // One bit flipped in each byte after the header in turn: the checksum (or a field) catches it.
  for (size_t i = 8; i < full.size(); ++i) {
    std::string damaged = full;
    damaged[i] = char(damaged[i] ^ 0x10);
    put(damaged);
    EXPECT_EQ(cache.read(key, description).status, FloatCache::Read::Status::Invalid) << i;
  }
  put(full + "x");
  expectInvalid("truncated or damaged");
}

TEST_F(FloatCacheFiles, OtherContentsAndNonFiniteValuesAreNotData) {
  EXPECT_EQ(cache.read(key, "something else").status, FloatCache::Read::Status::Invalid);
  ASSERT_TRUE(cache.store(key, description, {1.0f, std::nanf("")}));
  expectInvalid("not finite");
}

// A FIFO where an entry should be: refused at once (opening it must not wait for a writer).
TEST_F(FloatCacheFiles, AFifoInPlaceOfAnEntryIsRefusedWithoutWaiting) {
  fs::remove(cache.pathFor(key));
  ASSERT_EQ(::mkfifo(cache.pathFor(key).c_str(), 0600), 0);
  expectInvalid("is not a regular file");
}

TEST_F(FloatCacheFiles, AFailedStoreSaysWhyAndLeavesNothing) {
  compose::testing::writeText(dir / "file", "a file where a folder should be");
  const FloatCache blocked(dir / "file" / "c", "COMPTST2", ".t");
  std::string problem;
  EXPECT_FALSE(blocked.store(key, description, values, &problem));
  EXPECT_NE(problem.find("cannot create the cache folder"), std::string::npos) << problem;
}

// ---------------------------------------------------------------------------------------------
// The stage cache (pipeline/stage_cache.h)

class StageCacheFiles : public ::testing::Test {
 protected:
  TempDir dir;
  const std::string stage = "render", key = "0123abcd";

  void SetUp() override {
    pipeline::StageCache entry(dir.path(), stage, key);
    entry.meta()["exposure"] = 0.5;
    entry.put("a", {1.0f, 2.0f, 3.0f});
    Image img(2, 3, 3, {"R", "G", "B"});
    for (size_t i = 0; i < img.pixels.size(); ++i) img.pixels[i] = float(i);
    entry.putImage("image", img);
    ASSERT_TRUE(entry.write()) << entry.problem();
  }
  fs::path path() const { return pipeline::StageCache(dir.path(), stage, key).path(); }
  void expectInvalid(const std::string& needle) {
    pipeline::StageCache entry(dir.path(), stage, key);
    EXPECT_FALSE(entry.open()) << needle;
    EXPECT_NE(entry.problem().find(needle), std::string::npos)
        << "problem: " << entry.problem() << "\nexpected: " << needle;
    EXPECT_TRUE(entry.get("a").empty());
  }
};

TEST_F(StageCacheFiles, AWrittenEntryOpensWithItsArraysAndImages) {
  pipeline::StageCache entry(dir.path(), stage, key);
  ASSERT_TRUE(entry.open()) << entry.problem();
  EXPECT_TRUE(entry.problem().empty());
  const std::span<const float> a = entry.get("a");
  EXPECT_EQ(std::vector<float>(a.begin(), a.end()), (std::vector<float>{1.0f, 2.0f, 3.0f}));
  EXPECT_EQ(entry.meta().value("exposure", 0.0), 0.5);
  Image img;
  ASSERT_TRUE(entry.getImage("image", img));
  EXPECT_EQ(img.width, 2);
  EXPECT_EQ(img.height, 3);
  EXPECT_EQ(img.pixels[17], 17.0f);
  pipeline::StageCache missing(dir.path(), stage, "ffff");
  EXPECT_FALSE(missing.open());
  EXPECT_TRUE(missing.problem().empty()) << "a missing entry is a plain miss";
}

TEST_F(StageCacheFiles, AFifoInPlaceOfAnEntryIsRefusedWithoutWaiting) {
  fs::remove(path());
  ASSERT_EQ(::mkfifo(path().c_str(), 0600), 0);
  expectInvalid("is not a regular file");
}

TEST_F(StageCacheFiles, TruncatedAtEveryLengthIsDetected) {
  const std::string full = readBytes(path());
  for (size_t n = 0; n < full.size(); ++n) {
    writeBytes(path(), full.substr(0, n));
    pipeline::StageCache entry(dir.path(), stage, key);
    EXPECT_FALSE(entry.open()) << n;
    EXPECT_FALSE(entry.problem().empty()) << n;
  }
  writeBytes(path(), full.substr(0, full.size() - 1));
  expectInvalid("truncated");
  writeBytes(path(), "");
  expectInvalid("is empty");
}

TEST_F(StageCacheFiles, ZeroedOldVersionForeignAndDamagedEntriesAreDetected) {
  const std::string full = readBytes(path());
  writeBytes(path(), std::string(full.size(), '\0'));
  expectInvalid("is zeroed");
  std::string old = full;
  old[7] = '1';
  writeBytes(path(), old);
  expectInvalid("is of format version '1', this compose reads version '4'");
  writeBytes(path(), "PNG? no. Something else entirely, long enough to have a header.");
  expectInvalid("not a compose stage cache entry");
  for (size_t i = 8; i < full.size(); i += 3) {
    std::string damaged = full;
    damaged[i] = char(damaged[i] ^ 0x04);
    writeBytes(path(), damaged);
    pipeline::StageCache entry(dir.path(), stage, key);
    EXPECT_FALSE(entry.open()) << "byte " << i;
  }
  // An entry moved to another key's name.
  writeBytes(path(), full);
  fs::copy_file(path(), pipeline::StageCache(dir.path(), stage, "beef").path());
  pipeline::StageCache moved(dir.path(), stage, "beef");
  EXPECT_FALSE(moved.open());
  EXPECT_NE(moved.problem().find("another stage's or key's"), std::string::npos) << moved.problem();
}

TEST_F(StageCacheFiles, AFailedWriteSaysWhy) {
  compose::testing::writeText(dir / "file", "a file where a folder should be");
  pipeline::StageCache blocked(dir / "file", stage, key);
  blocked.put("a", {1.0f});
  EXPECT_FALSE(blocked.write());
  EXPECT_FALSE(blocked.error().empty());
}

TEST(StageCacheImages, SizesThatDoNotMatchTheirPixelsAreNotImages) {
  TempDir dir;
  for (const nlohmann::json& bad :
       {nlohmann::json{{"width", 2}, {"height", 2}, {"channels", 3}},
        nlohmann::json{{"width", 1 << 30}, {"height", 1 << 30}, {"channels", 16}},
        nlohmann::json{{"width", 1e30}, {"height", 1}, {"channels", 3}},
        nlohmann::json{{"width", -1}, {"height", -3}, {"channels", 3}}, nlohmann::json("text")}) {
    pipeline::StageCache entry(dir.path(), "s", "k");
    nlohmann::json m = bad;
    if (m.is_object()) {
      m["names"] = {"R", "G", "B"};
      m["colorSpace"] = "ACEScg";
    }
    entry.meta()["images"]["i"] = m;
    entry.put("i", std::vector<float>(3, 1.0f));
    ASSERT_TRUE(entry.write());
    pipeline::StageCache back(dir.path(), "s", "k");
    ASSERT_TRUE(back.open()) << back.problem();
    Image img;
    EXPECT_FALSE(back.getImage("i", img)) << bad.dump();
  }
}

}  // namespace
}  // namespace compose
