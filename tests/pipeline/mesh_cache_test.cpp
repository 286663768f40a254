// The object as read, kept in the cache under its file's content (pipeline/mesh_summary.h).
#include <fstream>

#include "pipeline/mesh_summary.h"
#include "pipeline/stage_cache.h"
#include "render/transfer.h"
#include "test_util.h"

namespace compose::pipeline {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;
using compose::testing::writeText;

// A square pyramid without normals (they are computed: a note says so) and with a degenerate
// triangle (dropped: a warning says so), so that every part of a reading is kept.
const char* kPyramid =
    "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv 0 1.5 0\n"
    "f 1 2 3\nf 1 3 4\nf 1 5 2\nf 2 5 3\nf 3 5 4\nf 4 5 1\nf 1 1 2\n";

class MeshCache : public ::testing::Test {
 protected:
  void SetUp() override {
    file_ = dir_.path() / "pyramid.obj";
    writeText(file_, kPyramid);
    cache_ = dir_.path() / "cache";
  }
  // The first run: a miss, then the mesh read and kept.
  void readAndStore() {
    Hash128 key;
    std::string problem;
    ASSERT_FALSE(cachedMesh(cache_, file_, 60.0, key, problem));
    ASSERT_TRUE(problem.empty()) << problem;
    read_ = render::loadMesh(file_, {.creaseDegrees = 60.0});
    render::addBackSides(read_);  // as the pipeline does
    summary_ = summarize(read_, 60.0);
    ASSERT_TRUE(storeMesh(cache_, key, read_, summary_, problem)) << problem;
  }
  fs::path entryFile() const {
    for (const auto& e : fs::recursive_directory_iterator(cache_ / "meshes"))
      if (e.is_regular_file()) return e.path();
    return {};
  }
  TempDir dir_;
  fs::path file_, cache_;
  render::Mesh read_;
  MeshSummary summary_;
};

TEST_F(MeshCache, ASecondRunTakesTheSameMeshAndSummaryFromTheCache) {
  readAndStore();
  ASSERT_FALSE(read_.warnings.empty());
  ASSERT_FALSE(read_.normalsFromFile);
  Hash128 key;
  std::string problem;
  const std::optional<CachedMesh> cached = cachedMesh(cache_, file_, 60.0, key, problem);
  ASSERT_TRUE(cached) << problem;
  EXPECT_TRUE(cached->summary.fromCache);
  EXPECT_FALSE(summary_.fromCache);
  EXPECT_EQ(cached->summary.key, summary_.key);
  EXPECT_EQ(cached->summary.triangles, read_.triangleCount());
  EXPECT_EQ(cached->summary.convex, summary_.convex);
  EXPECT_EQ(cached->summary.boundsMin, read_.boundsMin());
  EXPECT_EQ(cached->summary.boundsMax, read_.boundsMax());
  EXPECT_EQ(cached->summary.notes, meshNotes(read_));
  EXPECT_EQ(cached->mesh.positions, read_.positions);
  EXPECT_EQ(cached->mesh.normals, read_.normals);
  EXPECT_EQ(cached->mesh.indices, read_.indices);
  EXPECT_EQ(render::meshHash(cached->mesh), render::meshHash(read_));
  // Another crease angle, or another file content, is another reading.
  EXPECT_FALSE(cachedMesh(cache_, file_, 30.0, key, problem));
  EXPECT_TRUE(problem.empty());
  writeText(file_, std::string(kPyramid) + "v 0 3 0\n");
  EXPECT_FALSE(cachedMesh(cache_, file_, 60.0, key, problem));
  EXPECT_TRUE(problem.empty());
}

// An open mesh (the pyramid without its base) is kept with the back sides loading gave it: read
// back, the same triangles, each side where it was, and the file's triangle count.
TEST_F(MeshCache, AnOpenMeshIsKeptWithItsBackSides) {
  writeText(file_,
            "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nv 0 1.5 0\n"
            "f 1 5 2\nf 2 5 3\nf 3 5 4\nf 4 5 1\n");
  readAndStore();
  ASSERT_EQ(read_.triangleCount(), 8u);
  ASSERT_EQ(read_.sides.size(), 8u);
  EXPECT_EQ(summary_.triangles, 4u);
  Hash128 key;
  std::string problem;
  const std::optional<CachedMesh> cached = cachedMesh(cache_, file_, 60.0, key, problem);
  ASSERT_TRUE(cached) << problem;
  EXPECT_EQ(cached->mesh.indices, read_.indices);
  EXPECT_EQ(cached->mesh.sides, read_.sides);
  EXPECT_EQ(cached->summary.triangles, 4u);
  EXPECT_EQ(render::meshHash(cached->mesh), render::meshHash(read_));
}

// A mesh whose vertex colours are its albedo (an OBJ's v x y z r g b, no material library) is
// kept with them and the white material they bring: read back, the same key and albedo.
TEST_F(MeshCache, VertexColoursAreKeptWithTheMesh) {
  writeText(file_,
            "v -1 0 -1 1 0 0\nv 1 0 -1 0 1 0\nv 1 0 1 0 0 1\nv -1 0 1 1 1 0\n"
            "v 0 1.5 0 0.5 0.5 0.5\nf 1 2 3\nf 1 3 4\nf 1 5 2\nf 2 5 3\nf 3 5 4\nf 4 5 1\n");
  readAndStore();
  ASSERT_FALSE(read_.colors.empty());
  Hash128 key;
  std::string problem;
  const std::optional<CachedMesh> cached = cachedMesh(cache_, file_, 60.0, key, problem);
  ASSERT_TRUE(cached) << problem;
  EXPECT_EQ(cached->summary.key, summary_.key);
  EXPECT_EQ(cached->mesh.colors, read_.colors);
  EXPECT_EQ(cached->mesh.colorSpace, read_.colorSpace);
  ASSERT_EQ(cached->mesh.materials.size(), 1u);
  for (uint32_t t = 0; t < read_.triangleCount(); ++t)
    EXPECT_EQ(cached->mesh.albedoAt(t, 0.25f, 0.5f), read_.albedoAt(t, 0.25f, 0.5f)) << t;
}

// Whatever changes the object's look changes its key (and so every stage after it): a texture's
// wrap modes and a material's texture-coordinate transform too (an edited .mtl's -s, a glTF's
// KHR_texture_transform or sampler), with the same geometry and texels.
TEST(MeshKey, EveryPartOfTheLookIsInIt) {
  render::Mesh mesh = render::loadMesh(
      [] {
        static TempDir dir;
        const fs::path f = dir.path() / "tri.obj";
        writeText(f, "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n");
        return f;
      }(),
      {});
  mesh.materials.push_back({});
  mesh.textures.push_back({});
  mesh.textures[0].image = Image(2, 2, 3, {"R", "G", "B"});
  mesh.materials[0].texture = 0;
  const Hash128 base = meshKey(mesh, 60.0);
  EXPECT_EQ(meshKey(mesh, 60.0), base);
  EXPECT_NE(meshKey(mesh, 30.0), base);
  render::Mesh m = mesh;
  m.textures[0].wrapU = render::Texture::Wrap::Clamp;
  EXPECT_NE(meshKey(m, 60.0), base) << "wrap u";
  m = mesh;
  m.textures[0].wrapV = render::Texture::Wrap::Mirror;
  EXPECT_NE(meshKey(m, 60.0), base) << "wrap v";
  m = mesh;
  m.textures[0].nearest = true;
  EXPECT_NE(meshKey(m, 60.0), base) << "magnified as blocks (glTF's magFilter NEAREST)";
  m = mesh;
  m.materials[0].uvTransform[0][0] = 2.0f;
  EXPECT_NE(meshKey(m, 60.0), base) << "texture-coordinate scale";
  m = mesh;
  m.materials[0].uvTransform[2][1] = 0.5f;
  EXPECT_NE(meshKey(m, 60.0), base) << "texture-coordinate offset";
  m = mesh;
  m.materials[0].baseColor.y = 0.5f;
  EXPECT_NE(meshKey(m, 60.0), base) << "base colour";
  m = mesh;
  m.textures[0].image.pixels[4] = 1.0f;
  EXPECT_NE(meshKey(m, 60.0), base) << "a texel";
}

TEST_F(MeshCache, ADamagedOrForgedEntryIsAProblemNotAMesh) {
  readAndStore();
  const fs::path entry = entryFile();
  ASSERT_FALSE(entry.empty());
  Hash128 key;
  std::string problem;
  // Truncated.
  const auto size = fs::file_size(entry);
  fs::resize_file(entry, size / 2);
  EXPECT_FALSE(cachedMesh(cache_, file_, 60.0, key, problem));
  EXPECT_NE(problem.find("is truncated"), std::string::npos) << problem;
  // Forged: a valid entry whose mesh is not the one its key names (one position moved).
  StageCache forged(cache_ / "meshes", "mesh", key.hex());
  forged.meta() = {{"keyA", "0123456789abcdef"},
                   {"keyB", "0123456789abcdef"},
                   {"convex", true},
                   {"normalsFromFile", true},
                   {"normalsSource", "file"},
                   {"warnings", nlohmann::json::array()}};
  forged.put("positions", {0, 0, 0, 1, 0, 0, 0, 1, 0});
  forged.put("normals", {0, 0, 1, 0, 0, 1, 0, 0, 1});
  forged.put("indices", {0, 1, 2});
  ASSERT_TRUE(forged.write()) << forged.error();
  EXPECT_FALSE(cachedMesh(cache_, file_, 60.0, key, problem));
  EXPECT_EQ(problem, "does not fit this job");
  // Indices out of range, or not whole.
  forged.meta()["keyA"] = "0000000000000000";
  for (const std::vector<float>& bad : {std::vector<float>{0, 1, 3}, {0, 1, 1.5f}, {0, 1, -1}}) {
    forged.put("indices", bad);
    ASSERT_TRUE(forged.write());
    EXPECT_FALSE(cachedMesh(cache_, file_, 60.0, key, problem));
    EXPECT_EQ(problem, "does not fit this job");
  }
  // Rewritten, it is taken again.
  ASSERT_TRUE(storeMesh(cache_, key, read_, summary_, problem)) << problem;
  EXPECT_TRUE(cachedMesh(cache_, file_, 60.0, key, problem)) << problem;
}

TEST_F(MeshCache, AMeshThatReadsOtherFilesIsNotKept) {
  // A material library beside the OBJ (missing here, and it may appear later): always read.
  writeText(file_, std::string("mtllib pyramid.mtl\n") + kPyramid);
  readAndStore();
  EXPECT_FALSE(read_.otherFiles.empty());
  EXPECT_FALSE(fs::exists(cache_ / "meshes"));
  Hash128 key;
  std::string problem;
  EXPECT_FALSE(cachedMesh(cache_, file_, 60.0, key, problem));
  // Without a cache folder nothing is kept either.
  writeText(file_, kPyramid);
  EXPECT_FALSE(cachedMesh({}, file_, 60.0, key, problem));
  EXPECT_TRUE(storeMesh({}, key, read_, summary_, problem));
  EXPECT_FALSE(fs::exists(cache_ / "meshes"));
}

}  // namespace
}  // namespace compose::pipeline
