#include "render/mesh.h"

#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/image.h"
#include "ingest/image_io.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::render {
namespace {

using compose::testing::TempDir;
using compose::testing::writeText;

// A unit cube, 8 positions, 6 quads, no normals.
constexpr const char* kCube =
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
    "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\n";

// Fully smooth normals (crease 180°).
const MeshOptions kSmooth{.creaseDegrees = 180.0};
constexpr float kPi = 3.14159265f;

// Mip levels: area averages down to 1 x 1 whatever the size (an odd one too), the mean kept; for a
// cut-out, the colour weighted by what it keeps, so that the colour of texels that are not there
// does not tint the levels; for an opaque material the alpha plays no part.
TEST(Mesh, MipLevelsKeepTheMeanAndACutOutsColourIsWeightedByWhatItKeeps) {
  Texture t;
  t.image = Image(5, 3, 3, {"R", "G", "B"});
  double sum = 0.0;
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 5; ++x) {
      t.image.at(x, y)[0] = float(x * 3 + y * 7 % 5);
      sum += t.image.at(x, y)[0];
    }
  buildMipLevels(t);
  ASSERT_EQ(t.levels.size(), 2u);  // 2 x 1, 1 x 1
  EXPECT_EQ(t.levels[0].width, 2);
  EXPECT_EQ(t.levels[0].height, 1);
  const Image& last = t.levels.back();
  ASSERT_EQ(last.width * last.height, 1);
  EXPECT_NEAR(last.pixels[0], sum / 15.0, 1e-4);
  EXPECT_NEAR(0.5 * (t.levels[0].pixels[0] + t.levels[0].pixels[3]), sum / 15.0, 1e-4);
  EXPECT_TRUE(t.keptLevels.empty());

  // Red with alpha 0.6, blue with alpha 0 and green with alpha 1 on alternate texels of rows.
  Texture leaf;
  leaf.image = Image(8, 8, 3, {"R", "G", "B"});
  leaf.alpha = Image(8, 8, 1, {"A"});
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) {
      const int kind = (x + y) % 2 == 0 ? 0 : (y % 2 == 0 ? 1 : 2);  // red, blue, green
      leaf.image.at(x, y)[kind == 0 ? 0 : kind == 1 ? 2 : 1] = 1.0f;
      leaf.alpha.at(x, y)[0] = kind == 0 ? 0.6f : kind == 1 ? 0.0f : 1.0f;
    }
  // Opaque: the alpha plays no part (half red, a quarter each blue and green).
  buildMipLevels(leaf);
  ASSERT_EQ(leaf.levels.size(), 3u);
  EXPECT_TRUE(leaf.keptLevels.empty());
  EXPECT_NEAR(leaf.levels.back().pixels[0], 0.5f, 1e-6f);
  EXPECT_NEAR(leaf.levels.back().pixels[2], 0.25f, 1e-6f);
  // A cut-out at 0.5 keeps red and green whole and no blue: two thirds red, a third green.
  buildMipLevels(leaf, 0.5f);
  ASSERT_EQ(leaf.keptLevels.size(), 3u);
  ASSERT_EQ(leaf.keptWeights.size(), 4u);  // with the full size's
  for (const Image& level : leaf.keptLevels)
    for (size_t i = 0; i < size_t(level.width * level.height); ++i) {
      EXPECT_NEAR(level.pixels[3 * i], 2.0f / 3.0f, 1e-5f);
      EXPECT_NEAR(level.pixels[3 * i + 1], 1.0f / 3.0f, 1e-5f);
      EXPECT_NEAR(level.pixels[3 * i + 2], 0.0f, 1e-6f);
    }
  EXPECT_NEAR(leaf.keptWeights.back().pixels[0], 0.75f, 1e-6f);
  // Semi-transparent: weighted by alpha (red 0.6 against green 1).
  buildMipLevels(leaf, -1.0f);
  EXPECT_NEAR(leaf.keptLevels.back().pixels[0], 0.6f / 1.1f, 1e-5f);
  EXPECT_NEAR(leaf.keptLevels.back().pixels[1], 0.5f / 1.1f, 1e-5f);
}

// A clamped texture beyond 0..1 is its edge texels, whatever the footprint: filtering over the
// footprint must not reach into the texture (its mip levels average the whole of it).
TEST(Mesh, AClampedTextureBeyondItsEdgeIsTheEdgeTexelsWhateverTheFootprint) {
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.normals = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}};
  m.indices = {0, 1, 2};
  m.texcoords = {{0, 0}, {3, 0}, {0, 3}};
  Texture t;
  t.image = Image(64, 64, 3, {"R", "G", "B"});
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x) t.image.at(x, y)[x == 63 ? 0 : 2] = 1.0f;  // red right edge
  t.wrapU = t.wrapV = Texture::Wrap::Clamp;
  buildMipLevels(t);
  m.textures.push_back(t);
  Material mat;
  mat.texture = 0;
  m.materials.push_back(mat);
  // u = 2.5 (beyond the right edge), v = 0.5; a footprint of 19 texels across u.
  const float u = 2.5f / 3.0f, v = 0.5f / 3.0f;
  const glm::vec3 wide = m.albedoAt(0, u, v, {0.1f, 0, 0}, {0, 0, 0});
  EXPECT_NEAR(wide.x, 1.0f, 1e-4f);
  EXPECT_NEAR(wide.z, 0.0f, 1e-4f);
  // Inside the texture the same footprint averages: mostly blue.
  const glm::vec3 inside = m.albedoAt(0, 0.5f / 3.0f, v, {0.1f, 0, 0}, {0, 0, 0});
  EXPECT_GT(inside.z, 0.9f);
}

// The albedo is the product factor x texture x vertex colour, taken in the space they are given
// in and then converted (Mesh::albedoToWorking), plain and filtered alike.
TEST(Mesh, TheAlbedosProductIsConvertedAfterItIsTaken) {
  Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  m.normals = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}};
  m.indices = {0, 1, 2};
  m.texcoords = {{0, 0}, {1, 0}, {0, 1}};
  Texture t;
  t.image = Image(4, 4, 3, {"R", "G", "B"});
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) t.image.at(x, y)[0] = 1.0f;  // pure red
  buildMipLevels(t);
  m.textures.push_back(t);
  Material mat;
  mat.texture = 0;
  mat.baseColor = glm::vec3(0.2f, 0.4f, 0.8f);
  m.materials.push_back(mat);
  m.colors = {glm::vec3(0.5f), glm::vec3(0.5f), glm::vec3(0.5f)};
  // A matrix that mixes channels: a product of converted factors would differ.
  m.albedoToWorking = glm::mat3(glm::vec3(0.6f, 0.1f, 0.0f), glm::vec3(0.3f, 0.8f, 0.1f),
                                glm::vec3(0.1f, 0.1f, 0.9f));
  m.convertsAlbedo = true;
  const glm::vec3 expected = m.albedoToWorking * glm::vec3(0.2f * 0.5f, 0.0f, 0.0f);
  const glm::vec3 plain = m.albedoAt(0, 0.3f, 0.3f);
  const glm::vec3 filtered = m.albedoAt(0, 0.3f, 0.3f, {0.5f, 0, 0}, {0, 0.5f, 0});
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(plain[c], expected[c], 1e-6f) << c;
    EXPECT_NEAR(filtered[c], expected[c], 1e-6f) << c;
  }
}

TEST(Mesh, TriangulatesAndComputesNormalsWhenAbsent) {
  TempDir dir;
  writeText(dir / "cube.obj", kCube);
  const Mesh m = loadMesh(dir / "cube.obj", kSmooth);
  EXPECT_FALSE(m.normalsFromFile);
  EXPECT_EQ(m.triangleCount(), 12u);
  EXPECT_EQ(m.positions.size(), 8u);
  // Corner normals of a cube point out along the diagonal from the centre.
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const glm::vec3 out = glm::normalize(m.positions[i] - glm::vec3(0.5f));
    EXPECT_GT(glm::dot(m.normals[i], out), 0.99f) << "vertex " << i;
  }
  EXPECT_EQ(m.boundsMin(), glm::vec3(0.0f));
  EXPECT_EQ(m.boundsMax(), glm::vec3(1.0f));
}

// The face normal of triangle t.
glm::vec3 faceNormal(const Mesh& m, size_t t) {
  const glm::vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
                  c = m.positions[m.indices[3 * t + 2]];
  return glm::normalize(glm::cross(b - a, c - a));
}

// An OBJ far from its file's origin (a 1 mm quad 5000 units out, exported in place): parsed in
// double and moved to its own middle before its positions become float, as a glTF is, so that
// its shape keeps float's precision on its own scale (parsed as float, 5000.001 was 5000.00098
// and 2000.0005 was 2000.0: a step of a quarter of the quad's size); the file origin says where
// it was.
TEST(Mesh, AnObjFarFromTheOriginKeepsItsShape) {
  TempDir dir;
  writeText(dir / "far.obj",
            "v 5000 -3000 2000\nv 5000.001 -3000 2000\nv 5000 -2999.999 2000\n"
            "v 5000.001 -2999.999 2000.0005\nf 1 2 3\nf 2 4 3\n");
  const Mesh m = loadMesh(dir / "far.obj");
  ASSERT_EQ(m.positions.size(), 4u);
  EXPECT_NEAR(m.fileOrigin.x, 5000.0005, 1e-9);
  EXPECT_NEAR(m.fileOrigin.y, -2999.9995, 1e-9);
  EXPECT_NEAR(m.fileOrigin.z, 2000.00025, 1e-9);
  bool said = false;
  for (const std::string& w : m.warnings)
    said = said || w.find("from its file's origin") != std::string::npos;
  EXPECT_TRUE(said);
  const glm::dvec3 expected[] = {{5000, -3000, 2000},
                                 {5000.001, -3000, 2000},
                                 {5000, -2999.999, 2000},
                                 {5000.001, -2999.999, 2000.0005}};
  for (const glm::dvec3& e : expected) {
    double nearest = 1e30;
    for (const glm::vec3& p : m.positions)
      nearest = std::min(nearest, glm::length(glm::dvec3(p) + m.fileOrigin - e));
    EXPECT_LT(nearest, 1e-9) << e.x << " " << e.y << " " << e.z;
  }
  // A loose vertex at the origin, which no face uses (CAD exports leave them), does not keep it
  // there: it kept the mesh from being moved, and float rounding at 5000 flattened it.
  writeText(dir / "stray.obj",
            "v 0 0 0\nv 5000 -3000 2000\nv 5000.001 -3000 2000\nv 5000 -2999.999 2000\n"
            "v 5000.001 -2999.999 2000.0005\nf 2 3 4\nf 3 5 4\n");
  const Mesh stray = loadMesh(dir / "stray.obj");
  EXPECT_NEAR(stray.fileOrigin.x, 5000.0005, 1e-9);
  EXPECT_NEAR(stray.fileOrigin.z, 2000.00025, 1e-9);
  ASSERT_EQ(stray.positions.size(), 4u);
  for (size_t i = 0; i < 4; ++i)
    EXPECT_LT(glm::length(glm::dvec3(stray.positions[i]) - glm::dvec3(m.positions[i])), 1e-9);
  // Near its origin, a mesh stays where the file puts it.
  writeText(dir / "near.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_EQ(loadMesh(dir / "near.obj").fileOrigin, glm::dvec3(0.0));
}

TEST(Mesh, CreaseAngleSplitsVerticesWhereFacesMeetSharply) {
  TempDir dir;
  writeText(dir / "cube.obj", kCube);
  // The cube's edges are 90°: below that every corner normal is its own face's normal (each of
  // the 8 corners split into 3), above it they are smooth again.
  for (const double crease : {0.0, 60.0, 89.0}) {
    const Mesh m = loadMesh(dir / "cube.obj", {.creaseDegrees = crease});
    EXPECT_EQ(m.positions.size(), 24u) << crease;
    for (size_t t = 0; t < m.triangleCount(); ++t)
      for (int k = 0; k < 3; ++k)
        EXPECT_GT(glm::dot(m.normals[m.indices[3 * t + size_t(k)]], faceNormal(m, t)), 0.9999f);
    EXPECT_NE(m.normalsSource.find("crease angle of " + std::to_string(int(crease)) + "°"),
              std::string::npos)
        << m.normalsSource;
  }
  EXPECT_EQ(loadMesh(dir / "cube.obj", {.creaseDegrees = 91.0}).positions.size(), 8u);

  // A strip folded by 20° along its middle edge stays smooth at 60° (the shared vertices get the
  // mean of both faces' normals) and splits at 10°.
  const float s = std::sin(20.0f * kPi / 180.0f), c = std::cos(20.0f * kPi / 180.0f);
  writeText(dir / "fold.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 " + std::to_string(1 + c) +
                                  " " + std::to_string(s) + "\nv 1 " + std::to_string(1 + c) + " " +
                                  std::to_string(s) + "\nf 1 2 4 3\nf 3 4 6 5\n");
  const Mesh smooth = loadMesh(dir / "fold.obj");
  EXPECT_EQ(smooth.positions.size(), 6u);
  const Mesh sharp = loadMesh(dir / "fold.obj", {.creaseDegrees = 10.0});
  EXPECT_EQ(sharp.positions.size(), 8u);
  EXPECT_NE(sharp.normalsSource.find("2 vertices added"), std::string::npos) << sharp.normalsSource;
}

// A 7 × 5 grid of unit squares in the plane y = 0 with a ridge along z = 2: the ridge's
// vertices x = lo..hi raised to y = `height` (0.8: the faces meet at 70-77° along it, a little
// sharper than the default crease of 60°; 3: at about 140°). With `groupFrom` >= 0 the faces at
// x >= groupFrom are in smoothing group 2, the others in group 1.
std::string ridgeGrid(int lo, int hi, double height = 0.8, int groupFrom = -1) {
  std::string obj;
  for (int z = 0; z < 5; ++z)
    for (int x = 0; x < 7; ++x)
      obj += "v " + std::to_string(x) + " " +
             std::to_string(z == 2 && x >= lo && x <= hi ? height : 0.0) + " " + std::to_string(z) +
             "\n";
  for (int z = 0; z < 4; ++z)
    for (int x = 0; x < 6; ++x) {
      const int a = 7 * z + x + 1;
      if (groupFrom >= 0) obj += x >= groupFrom ? "s 2\n" : "s 1\n";
      obj += "f " + std::to_string(a) + " " + std::to_string(a + 7) + " " + std::to_string(a + 8) +
             " " + std::to_string(a + 1) + "\n";
    }
  return obj;
}

TEST(Mesh, SharpRidgesThatEndInASmoothSurfaceAreShadedSmooth) {
  TempDir dir;
  auto load = [&](const std::string& name, const std::string& obj, MeshOptions options = {}) {
    writeText(dir / name, obj);
    return loadMesh(dir / name, options);
  };
  const std::string smoothed = " sharper edges on lines that end in a smooth surface shaded smooth";
  // Across the whole grid the ridge is a crease line: its 7 vertices split in two.
  const Mesh through = load("through.obj", ridgeGrid(0, 6));
  EXPECT_EQ(through.positions.size(), 35u + 7u);
  EXPECT_EQ(through.normalsSource.find(smoothed), std::string::npos) << through.normalsSource;
  // A ridge that starts and stops inside the surface (x = 2..4) is not a crease: every vertex
  // keeps one normal, and the note counts the sharp edges shaded smooth.
  const Mesh inside = load("inside.obj", ridgeGrid(2, 4));
  EXPECT_EQ(inside.positions.size(), 35u);
  EXPECT_NE(inside.normalsSource.find(smoothed), std::string::npos) << inside.normalsSource;
  // The ridge's top vertex (x = 3) gets the mean of both slopes: its normal points up.
  int tops = 0;
  for (size_t v = 0; v < inside.positions.size(); ++v) {
    if (inside.positions[v] != glm::vec3(3.0f, 0.8f, 2.0f)) continue;
    EXPECT_GT(inside.normals[v].y, 0.99f);
    ++tops;
  }
  EXPECT_EQ(tops, 1);
  // From the boundary to a free end inside (x = 0..4): removed back to the boundary, five edges
  // one after the other.
  EXPECT_EQ(load("half.obj", ridgeGrid(0, 4)).positions.size(), 35u);
  // Much sharper than the crease (about 140°), a line is a crease even where it stops.
  EXPECT_GT(load("blade.obj", ridgeGrid(2, 4, 3.0)).positions.size(), 35u);
  // Flat shading asked for stays flat; within one smoothing group the ridge is smooth as without
  // groups; a line that runs from the boundary to the edge between two smoothing groups (x = 4)
  // ends on both sides, and stays.
  EXPECT_GT(load("flat.obj", ridgeGrid(2, 4), {.creaseDegrees = 0.0}).positions.size(), 35u + 20u);
  EXPECT_EQ(load("one-group.obj", ridgeGrid(2, 4).insert(0, "s 1\n")).positions.size(), 35u);
  const Mesh grouped = load("groups.obj", ridgeGrid(0, 4, 0.8, 4));
  EXPECT_EQ(load("no-groups.obj", ridgeGrid(0, 4)).positions.size(), 35u);
  EXPECT_GE(grouped.positions.size(), 35u + 5u + 4u) << "5 on the groups' edge, 4 on the ridge";
  EXPECT_EQ(grouped.normalsSource.find(smoothed), std::string::npos) << grouped.normalsSource;
}

TEST(Mesh, SmoothingGroupsOfTheFileSplitComputedNormals) {
  TempDir dir;
  // The folded strip again, each face in its own smoothing group: sharp even at 180°. With
  // "s off" the faces are flat; with one group they are smooth.
  const std::string v = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 2 0.2\nv 1 2 0.2\n";
  writeText(dir / "groups.obj", v + "s 1\nf 1 2 4 3\ns 2\nf 3 4 6 5\n");
  EXPECT_EQ(loadMesh(dir / "groups.obj", kSmooth).positions.size(), 8u);
  writeText(dir / "off.obj", v + "s off\nf 1 2 4 3\nf 3 4 6 5\n");
  EXPECT_EQ(loadMesh(dir / "off.obj", kSmooth).positions.size(), 8u);
  writeText(dir / "one.obj", v + "s 1\nf 1 2 4 3\nf 3 4 6 5\n");
  EXPECT_EQ(loadMesh(dir / "one.obj", kSmooth).positions.size(), 6u);
}

TEST(Mesh, NormalsAreSmoothedAcrossTextureSeams) {
  TempDir dir;
  // Two faces meeting at a fold, their shared corners with different texture coordinates: the
  // seam vertices are separate but get one normal.
  writeText(dir / "seam.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 2 0.3\nv 1 2 0.3\n"
            "vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvt 0 0.5\nvt 1 0.5\nvt 0 1\nvt 1 1\n"
            "f 1/1 2/2 4/4 3/3\nf 3/5 4/6 6/8 5/7\n");
  const Mesh m = loadMesh(dir / "seam.obj");
  EXPECT_EQ(m.positions.size(), 8u);
  std::vector<glm::vec3> atY1;
  for (size_t i = 0; i < m.positions.size(); ++i)
    if (m.positions[i].y == 1.0f) atY1.push_back(m.normals[i]);
  ASSERT_EQ(atY1.size(), 4u);
  for (const glm::vec3& n : atY1) EXPECT_GT(glm::dot(n, atY1[0]), 0.99999f);
  EXPECT_LT(atY1[0].z, 0.999f) << "the seam normal leans between the two faces";
}

TEST(Mesh, KeepsFileNormalsAndSplitsVerticesPerNormal) {
  TempDir dir;
  // Two triangles sharing an edge with different normals per corner, CRLF line endings, and a
  // material library that does not exist (as in real exports): both must be fine.
  writeText(dir / "flat.obj",
            "mtllib missing.mtl\r\nv 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nv 1 1 0\r\n"
            "vn 0 0 2\r\nvn 0 0 -1\r\nf 1//1 2//1 3//1\r\nf 2//2 4//2 3//2\r\n");
  const Mesh m = loadMesh(dir / "flat.obj");
  EXPECT_TRUE(m.normalsFromFile);
  EXPECT_EQ(m.triangleCount(), 2u);
  EXPECT_EQ(m.positions.size(), 6u);  // vertices 2 and 3 are used with two normals each
  EXPECT_EQ(m.normals[0], glm::vec3(0, 0, 1)) << "normals are normalised";
}

TEST(Mesh, ErrorsNameTheFileAndTheProblem) {
  TempDir dir;
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "nope.obj"), "mesh: file not found");
  writeText(dir / "empty.obj", "# nothing\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "empty.obj"), "mesh has no triangles (");
  writeText(dir / "nan.obj", "v 0 0 0\nv 1e999 0 0\nv 0 1 0\nf 1 2 3\n");  // overflows to inf
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "nan.obj"),
                       "line 2: vertex coordinate '1e999' is not a finite");
  writeText(dir / "colour.obj", "v 0 0 0 nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "colour.obj"),
                       "line 1: vertex colour component 'nan' is not a finite");
  // A material library's Kd that is not a number (tinyobjloader reads "nan" as 0): the default
  // grey, said.
  writeText(dir / "k.mtl", "newmtl a\nKd nan 1 1\n");
  writeText(dir / "k.obj", "mtllib k.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  // Line ends of every kind, as tinyobjloader splits lines (a classic Mac file ends its lines in
  // a lone CR); a Kd followed by a comment, and a Kd of one number (a grey).
  writeText(dir / "mac.mtl", "newmtl red\rKd 1 0 0 # pure red\rnewmtl grey\r\nKd 0.25\n");
  writeText(dir / "mac.obj",
            "# made on a Mac\rmtllib mac.mtl\rv 0 0 0\rv 1 0 0\rv 0 1 0\r\nv 1 1 0\r"
            "usemtl red\rf 1 2 3\nusemtl grey\rf 2 4 3\r");
  const Mesh mac = loadMesh(dir / "mac.obj");
  EXPECT_EQ(mac.triangleCount(), 2u);
  EXPECT_TRUE(mac.warnings.empty()) << mac.warnings[0];
  ASSERT_EQ(mac.materials.size(), 2u);
  for (const Material& material : mac.materials) {
    const glm::vec3 expected = material.name == "red" ? glm::vec3(1, 0, 0) : glm::vec3(0.25f);
    EXPECT_EQ(material.baseColor, expected) << material.name;
  }
  const Mesh k = loadMesh(dir / "k.obj");
  ASSERT_EQ(k.materials.size(), 1u);
  EXPECT_EQ(k.materials[0].baseColor, glm::vec3(0.5f));
  ASSERT_EQ(k.warnings.size(), 1u);
  EXPECT_EQ(k.warnings[0],
            "material 'a' has a Kd that is not a colour ('nan 1 1'): using the default grey");
  writeText(dir / "point.obj", "v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "point.obj"), "zero size");
  writeText(dir / "model.stl", "solid x\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "model.stl"), "unsupported mesh format '.stl'");
  COMPOSE_EXPECT_ERROR(loadMesh(dir.path()), "is a folder");
}

TEST(Mesh, ZeroNormalsInTheFileAreComputedWithAWarning) {
  TempDir dir;
  writeText(dir / "zeron.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nvn 0 0 1\nf 1//1 2//2 3//2\n");
  const Mesh m = loadMesh(dir / "zeron.obj");
  ASSERT_EQ(m.warnings.size(), 1u);
  EXPECT_EQ(m.warnings[0], "1 normal in the file was zero or not finite: computed instead");
  EXPECT_FALSE(m.normalsFromFile);
  for (const glm::vec3& n : m.normals) EXPECT_NEAR(n.z, 1.0f, 1e-6f);
  EXPECT_NE(m.normalsSource.find("from the file for 2 of 3 vertices"), std::string::npos);
  // Every normal zero: the source does not say "not in the file" beside the warning that they
  // were.
  writeText(dir / "allzero.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nf 1//1 2//1 3//1\n");
  const Mesh z = loadMesh(dir / "allzero.obj");
  ASSERT_EQ(z.warnings.size(), 1u);
  EXPECT_EQ(z.normalsSource.find("not in the file"), std::string::npos) << z.normalsSource;
  EXPECT_NE(z.normalsSource.find("in the file but none usable: computed"), std::string::npos)
      << z.normalsSource;
}

TEST(Mesh, MalformedNumbersAreErrorsNamingTheLine) {
  TempDir dir;
  // tinyobjloader alone reads each of these as 0 and renders wrong geometry.
  const std::pair<const char*, const char*> cases[] = {
      {"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "line 2: vertex coordinate 'nan'"},
      {"v 0 0 0\nv 1 0 0\n\nv 0 inf 0\nf 1 2 3\n", "line 4: vertex coordinate 'inf'"},
      {"v 0 0 0\nv 1 0 abc\nv 0 1 0\nf 1 2 3\n", "line 2: vertex coordinate 'abc'"},
      {"v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1x\nf 1//1 2//1 3//1\n", "line 4: normal component '1x'"},
      {"v 0 0 0\nv 1 0 0\nv 0 1\nf 1 2 3\n", "line 3: 'v' needs 3 numbers, has 2"},
      {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 two 3\n", "line 4: face corner 'two'"},
      {"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "line 4: face corner '0'"},
      // Hexadecimal, which strtod reads and tinyobjloader does not (it read 0x2 as 0).
      {"v 0 0 0\nv 1 0 0\nv 0 0x2 0\nf 1 2 3\n", "line 3: vertex coordinate '0x2'"},
      {"v 0 0 0\nv 1 0 0\nv 0 +-1 0\nf 1 2 3\n", "line 3: vertex coordinate '+-1'"},
      {"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0x1p-1 0\nf 1/1 2/1 3/1\n",
       "line 4: texture coordinate '0x1p-1'"},
  };
  for (const auto& [text, message] : cases) {
    writeText(dir / "bad.obj", text);
    COMPOSE_EXPECT_ERROR(loadMesh(dir / "bad.obj"), message);
  }
  // Valid forms still load: exponents, signs, relative indices, v/vt/vn corners.
  writeText(dir / "ok.obj",
            "v 0 0 0\nv 1e0 -0 +0\nv 0 1.0E+0 1e-320\nvt 0 0\nvn 0 0 +1\nf -3/1/1 -2/1/1 -1/1/1\n");
  EXPECT_EQ(loadMesh(dir / "ok.obj").triangleCount(), 1u);
}

TEST(Mesh, DegenerateAndDuplicateTrianglesAreDroppedWithAWarning) {
  TempDir dir;
  // One good triangle, one with a repeated corner, one with three collinear corners, one
  // repeating the first in another winding.
  writeText(dir / "m.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\n"
            "f 1 2 3\nf 1 1 2\nf 1 2 4\nf 3 2 1\n");
  const Mesh m = loadMesh(dir / "m.obj");
  EXPECT_EQ(m.triangleCount(), 1u);
  ASSERT_EQ(m.warnings.size(), 2u);
  EXPECT_EQ(m.warnings[0], "dropped 2 of 4 triangles with no area");
  EXPECT_EQ(m.warnings[1], "dropped 1 of 4 triangles that repeat another one");
  writeText(dir / "flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "flat.obj"),
                       "nothing renderable: all 2 triangles are degenerate");
  writeText(dir / "one.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "one.obj"),
                       "nothing renderable: the one triangle is degenerate");
  // A coordinate beyond single precision reads as infinity: said so, not only "not finite".
  writeText(dir / "wide.obj", "v -1e38 0 0\nv 1e38 0 0\nv 0 1e38 0\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "wide.obj"),
                       "mesh spans 2e+38 units: coordinates this large overflow single precision");
  // Spans from about 5e12 rendered as a streak or nothing: refused from 1e12.
  writeText(dir / "large.obj", "v 0 0 0\nv 2e13 0 0\nv 0 2e13 0\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "large.obj"),
                       "mesh spans 2e+13 units: coordinates this large overflow single precision");
  writeText(dir / "fine.obj", "v 0 0 0\nv 5e11 0 0\nv 0 5e11 0\nf 1 2 3\n");
  EXPECT_EQ(loadMesh(dir / "fine.obj").triangleCount(), 1u);
  // And too small: refused by its size, not "degenerate" (the area test underflowed).
  writeText(dir / "tiny.obj", "v 0 0 0\nv 2e-12 0 0\nv 0 2e-12 0\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "tiny.obj"),
                       "mesh spans 2e-12 units: coordinates this small underflow single precision");
  writeText(dir / "small.obj", "v 0 0 0\nv 2e-7 0 0\nv 0 2e-7 0\nf 1 2 3\n");
  EXPECT_EQ(loadMesh(dir / "small.obj").triangleCount(), 1u);
  writeText(dir / "huge.obj", "v 0 0 0\nv 1e308 0 0\nv 0 1 0\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "huge.obj"),
                       "nothing renderable: the one triangle has a corner whose coordinates are "
                       "not finite numbers (NaN, infinite, or beyond single precision's 3.4e38)");
}

TEST(Mesh, TrianglesWoundAgainstTheirNeighboursAreTurnedOutwards) {
  TempDir dir;
  // The cube with one face wound inwards (and no normals): the computed normals must still
  // point out of every corner.
  writeText(dir / "cube.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
            "f 1 4 3 2\nf 8 7 6 5\nf 1 2 6 5\nf 4 8 7 3\nf 1 5 8 4\nf 2 3 7 6\n");
  const Mesh m = loadMesh(dir / "cube.obj", kSmooth);
  ASSERT_EQ(m.warnings.size(), 1u);
  EXPECT_EQ(m.warnings[0], "turned 2 triangles wound against their neighbours to face outwards");
  for (size_t i = 0; i < m.positions.size(); ++i) {
    const glm::vec3 out = glm::normalize(m.positions[i] - glm::vec3(0.5f));
    EXPECT_GT(glm::dot(m.normals[i], out), 0.99f) << "vertex " << i;
  }
  // A cube wound entirely inside out is turned as a whole.
  writeText(dir / "inside.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
            "f 2 3 4 1\nf 8 7 6 5\nf 5 6 2 1\nf 3 7 8 4\nf 4 8 5 1\nf 6 7 3 2\n");
  const Mesh inside = loadMesh(dir / "inside.obj", kSmooth);
  for (size_t i = 0; i < inside.positions.size(); ++i)
    EXPECT_GT(glm::dot(inside.normals[i], glm::normalize(inside.positions[i] - glm::vec3(0.5f))),
              0.99f);
}

// The area of a triangle list and whether every triangle faces +Z.
std::pair<float, bool> areaFacingZ(const Mesh& m) {
  float area = 0.0f;
  bool up = true;
  for (size_t t = 0; t < m.triangleCount(); ++t) {
    const glm::vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
                    c = m.positions[m.indices[3 * t + 2]];
    const glm::vec3 n = glm::cross(b - a, c - a);
    area += 0.5f * glm::length(n);
    up = up && n.z > 0.0f;
  }
  return {area, up};
}

// Polygons of 256 corners and more (a CAD disc's cap): tinyobjloader counts a face's corners in
// 8 bits; every corner is kept, in a file with other faces and groups before and after it.
TEST(Mesh, PolygonsOfManyCornersAreWhole) {
  TempDir dir;
  for (const int n : {255, 256, 257, 300, 1000}) {
    std::string obj = "v 0 0 -1\nv 1 0 -1\nv 0 1 -1\ng before\nf 1 2 3\ng disc\n";
    for (int i = 0; i < n; ++i) {
      const double a = 2.0 * std::numbers::pi * i / n;
      obj += "v " + std::to_string(std::cos(a)) + " " + std::to_string(std::sin(a)) + " 0\n";
    }
    obj += "f";
    for (int i = 0; i < n; ++i) obj += " " + std::to_string(4 + i);
    obj += "\ng after\nf 3 2 1\n";
    writeText(dir / "disc.obj", obj);
    const Mesh m = loadMesh(dir / "disc.obj");
    // The disc's n - 2 triangles and the two small ones (one a duplicate of the other: dropped).
    EXPECT_EQ(m.triangleCount(), size_t(n - 2 + 1)) << n;
    const double disc = 0.5 * n * std::sin(2.0 * std::numbers::pi / n);
    double area = 0.0;
    for (size_t t = 0; t < m.triangleCount(); ++t) {
      const glm::vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
                      c = m.positions[m.indices[3 * t + 2]];
      area += 0.5 * double(glm::length(glm::cross(b - a, c - a)));
    }
    EXPECT_NEAR(area, disc + 0.5, 1e-3) << n;
  }
}

TEST(Mesh, ConcavePolygonsAreTriangulatedInsideTheirOutline) {
  TempDir dir;
  // A dart (concave quad: its 0-2 diagonal lies outside), an arrow of 7 corners and a U of 8,
  // all in the plane z = 0 facing +Z. Triangles inside the outline add up to its area and all
  // face the same way; a triangle outside it would overlap others or turn over.
  const std::pair<std::string, float> cases[] = {
      {"v 0 0 0\nv 2 1 0\nv 4 0 0\nv 2 3 0\nf 1 2 3 4\n", 4.0f},
      {"v 0 1 0\nv 3 1 0\nv 3 0 0\nv 5 2 0\nv 3 4 0\nv 3 3 0\nv 0 3 0\nf 1 2 3 4 5 6 7\n",
       6.0f + 4.0f},
      {"v 0 0 0\nv 3 0 0\nv 3 3 0\nv 2 3 0\nv 2 1 0\nv 1 1 0\nv 1 3 0\nv 0 3 0\n"
       "f 1 2 3 4 5 6 7 8\n",
       7.0f},
  };
  for (const auto& [text, area] : cases) {
    writeText(dir / "polygon.obj", text);
    const Mesh m = loadMesh(dir / "polygon.obj");
    const auto [sum, up] = areaFacingZ(m);
    EXPECT_NEAR(sum, area, 1e-5f) << text;
    EXPECT_TRUE(up) << text;
  }
  // The same U, tilted out of every axis plane and with its corners starting elsewhere.
  std::vector<glm::vec3> u = {{1, 1, 0}, {1, 3, 0}, {0, 3, 0}, {0, 0, 0},
                              {3, 0, 0}, {3, 3, 0}, {2, 3, 0}, {2, 1, 0}};
  const glm::vec3 ex = glm::normalize(glm::vec3(1, 1, 0)), ey = glm::normalize(glm::vec3(-1, 1, 1));
  const glm::vec3 ez = glm::cross(ex, ey);
  for (glm::vec3& p : u) p = p.x * ex + p.y * ey + p.z * ez;
  const std::vector<uint32_t> tri = triangulatePolygon(u);
  ASSERT_EQ(tri.size(), 3u * 6u);
  float sum = 0.0f;
  for (size_t t = 0; t < tri.size(); t += 3) {
    const glm::vec3 n = glm::cross(u[tri[t + 1]] - u[tri[t]], u[tri[t + 2]] - u[tri[t]]);
    EXPECT_GT(glm::dot(n, ez), 0.0f);
    sum += 0.5f * glm::length(n);
  }
  EXPECT_NEAR(sum, 7.0f, 1e-5f);
}

// A 2x2 8-bit PNG: red, green on the top row; blue, white below.
void writeQuadrants(const std::filesystem::path& file) {
  Image img(2, 2, 3, {"R", "G", "B"});
  const float px[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1};
  std::copy(px, px + 12, img.pixels.begin());
  img.colorSpace = "sRGB";
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::UInt8;
  ingest::writeImage(file, img, options);
}

bool near(const glm::vec3& a, const glm::vec3& b) {
  return glm::length(a - b) < 1e-6f;
}

TEST(Mesh, ObjMaterialsGiveBaseColoursAndTextures) {
  TempDir dir;
  std::filesystem::create_directories(dir / "maps");
  writeQuadrants(dir / "maps" / "quadrants.png");
  // Kd times map_Kd (a Windows path); map_Kd alone (Blender writes no Kd then); Kd alone; and a
  // name no library defines.
  writeText(dir / "m.mtl",
            "newmtl painted\nKd 0.5 1 1\nmap_Kd maps\\quadrants.png\n"
            "newmtl texture\nmap_Kd -s 1 1 1 -o 0.5 0 0 maps/quadrants.png\n"
            "newmtl plain\r\nKd 0.2 0.4 0.6\r\n");
  // Texture coordinates (0.25, 0.75), (0.75, 0.75), (0.25, 0.25) in OBJ's convention (v up):
  // the centres of the red, green and blue texels.
  writeText(dir / "m.obj",
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nv 2 1 0\n"
            "v 4 0 0\nv 5 0 0\nv 4 1 0\nv 6 0 0\nv 7 0 0\nv 6 1 0\n"
            "vt 0.25 0.75\nvt 0.75 0.75\nvt 0.25 0.25\n"
            "g first\nusemtl painted\nf 1/1 2/2 3/3\ng second\nusemtl texture\nf 4/1 5/2 6/3\n"
            "usemtl plain\nf 7 8 9\nusemtl nowhere\nf 10 11 12\n");
  const Mesh m = loadMesh(dir / "m.obj");
  ASSERT_EQ(m.triangleCount(), 4u);
  ASSERT_EQ(m.materials.size(), 4u);
  ASSERT_EQ(m.textures.size(), 1u) << "one file, read once";
  EXPECT_EQ(m.colorSpace, "lin_rec709");
  // Kd times the texture is said (Blender shows the texture alone); the texture alone is not.
  const std::vector<std::string> warnings = {
      "1 face uses material 'nowhere', which no material library defines: rendered with the "
      "default albedo",
      "material 'painted': its Kd (0.5 1 1) multiplies its map_Kd, as the MTL format says "
      "(Blender, Maya and 3ds Max show the texture alone; Kd 1 1 1 does that here)"};
  EXPECT_EQ(m.warnings, warnings);
  // Triangles in file order (materials in the order faces first use them).
  EXPECT_TRUE(near(m.albedoAt(0, 0, 0), {0.5f, 0, 0})) << "red times Kd";
  EXPECT_TRUE(near(m.albedoAt(0, 1, 0), {0, 1, 0})) << "green";
  EXPECT_TRUE(near(m.albedoAt(0, 0, 1), {0, 0, 1})) << "blue times Kd";
  EXPECT_TRUE(near(m.albedoAt(1, 0, 0), {0, 1, 0})) << "-o 0.5: red's place shows green";
  EXPECT_TRUE(near(m.albedoAt(2, 0.3f, 0.3f), {0.2f, 0.4f, 0.6f}));
  EXPECT_TRUE(near(m.albedoAt(3, 0.3f, 0.3f), glm::vec3(kDefaultAlbedo)));
  EXPECT_FALSE(m.normalsFromFile);
}

// Two materials on one texture file, repeated and clamped (-clamp on): each keeps its own wrap
// (the first to use the file set it for both).
TEST(Mesh, ObjMaterialsSharingATextureKeepTheirOwnWrap) {
  TempDir dir;
  writeQuadrants(dir / "quadrants.png");
  writeText(dir / "w.mtl",
            "newmtl repeated\nmap_Kd -o 1 0 0 quadrants.png\n"
            "newmtl clamped\nmap_Kd -clamp on -o 1 0 0 quadrants.png\n");
  writeText(dir / "w.obj",
            "mtllib w.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nv 2 1 0\n"
            "vt 0.25 0.75\nvt 0.75 0.75\nvt 0.25 0.25\n"
            "usemtl repeated\nf 1/1 2/2 3/3\nusemtl clamped\nf 4/1 5/2 6/3\n");
  const Mesh m = loadMesh(dir / "w.obj");
  ASSERT_EQ(m.triangleCount(), 2u);
  // u = 1.25: repeated, red's column again; clamped, the right edge (green).
  EXPECT_TRUE(near(m.albedoAt(0, 0, 0), {1, 0, 0}));
  EXPECT_TRUE(near(m.albedoAt(1, 0, 0), {0, 1, 0}));
  EXPECT_EQ(m.otherFiles.size(), 2u) << "the library and the texture, once each";
}

// Material names as written: `usemtl Red Paint` is the material of that whole name (tinyobjloader
// took its first word, here another material), before its `mtllib` too; a name no library
// defines is said, even when no face has a material (it rendered grey without a word).
TEST(Mesh, ObjMaterialNamesAreWholeAndAnUndefinedOneIsSaid) {
  TempDir dir;
  writeText(dir / "m.mtl", "newmtl Red Paint\nKd 1 0 0\nnewmtl Red\nKd 0 0 1\n");
  writeText(dir / "m.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl Red Paint \nf 1 2 3\nmtllib m.mtl\n"
            "usemtl Red\nf 2 4 3\n");
  const Mesh m = loadMesh(dir / "m.obj");
  EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
  ASSERT_EQ(m.triangleCount(), 2u);
  EXPECT_TRUE(near(m.albedoAt(0, 0.2f, 0.2f), {1, 0, 0}));
  EXPECT_TRUE(near(m.albedoAt(1, 0.2f, 0.2f), {0, 0, 1}));

  writeText(dir / "u.obj",
            "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl red\nf 1 2 3\n"
            "usemtl Blue Paint\nf 2 4 3\n");
  const Mesh u = loadMesh(dir / "u.obj");
  const std::vector<std::string> said = {
      "2 faces use materials 'red', 'Blue Paint', which no material library defines: rendered "
      "with the default albedo"};
  EXPECT_EQ(u.warnings, said);
  EXPECT_FALSE(u.hasMaterials()) << "the renderer's albedo applies";
}

// What Windows tools write: a UTF-8 byte-order mark (Notepad) before the first line of the OBJ
// and the MTL, `mtllib mats\red.mtl` (tinyobjloader took the backslash for an escape and looked
// for matsred.mtl), and a face that goes on on the next line after a backslash (as Blender reads
// it). Each lost the materials or the first vertex without a word.
TEST(Mesh, AnObjFromWindowsToolsReadsAsBlenderReadsIt) {
  TempDir dir;
  std::filesystem::create_directories(dir / "mats");
  writeText(dir / "mats" / "red.mtl", "\xEF\xBB\xBFnewmtl red\nKd 1 0 0\n");
  writeText(dir / "w.obj",
            "\xEF\xBB\xBFv 0 0 0\r\nmtllib mats\\red.mtl\r\nv 1 0 0\r\nv 0 1 0\r\nv 1 1 0\r\n"
            "usemtl red\r\nf 1 2 \\\r\n  3 4\r\n# a comment that ends in a backslash \\\r\n"
            "f 2 4 3\r\nf 1 2 x\r\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "w.obj"),
                       "line 11: face corner 'x' is not a valid vertex reference");
  writeText(dir / "w.obj",
            "\xEF\xBB\xBFv 0 0 0\r\nmtllib mats\\red.mtl\r\nv 1 0 0\r\nv 0 1 0\r\nv 1 1 0\r\n"
            "usemtl red\r\nf 1 2 \\\r\n  4 3\r\n# a comment that ends in a backslash \\\r\n"
            "v 5 5 5\r\n");
  const Mesh m = loadMesh(dir / "w.obj");
  EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
  EXPECT_EQ(m.triangleCount(), 2u) << "the quad joined from two lines";
  ASSERT_TRUE(m.hasMaterials());
  EXPECT_TRUE(near(m.albedoAt(0, 0.2f, 0.2f), {1, 0, 0}));
  EXPECT_TRUE(near(m.boundsMin(), {0, 0, 0})) << "the first vertex is read";
}

// map_Kd as the MTL format writes it: its file relative to the library's own folder; -s and -o
// with one or two numbers (the file name was taken for the third); options compose does not use
// (-cc on) skipped; a path from another machine found by its name beside the library, said.
TEST(Mesh, ObjTextureMapsAsTheMtlFormatWritesThem) {
  TempDir dir;
  std::filesystem::create_directories(dir / "mats");
  writeQuadrants(dir / "mats" / "quadrants.png");
  writeText(dir / "mats" / "t.mtl",
            "newmtl near\nmap_Kd quadrants.png\n"
            "newmtl scaled\nmap_Kd -s 2 2 quadrants.png\n"
            "newmtl shifted\nmap_Kd -cc on -o 0.5 quadrants.png\n"
            "newmtl elsewhere\nmap_Kd C:\\Users\\me\\textures\\quadrants.png\n");
  // (0.25, 0.75) is red's centre; (0.125, 0.375) scaled by 2 is too; shifted by 0.5, (0.25,
  // 0.75) is green's.
  writeText(dir / "t.obj",
            "mtllib mats/t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nv 2 1 0\n"
            "v 4 0 0\nv 5 0 0\nv 4 1 0\nv 6 0 0\nv 7 0 0\nv 6 1 0\nvt 0.25 0.75\n"
            "vt 0.125 0.375\nusemtl near\nf 1/1 2/1 3/1\nusemtl scaled\nf 4/2 5/2 6/2\n"
            "usemtl shifted\nf 7/1 8/1 9/1\nusemtl elsewhere\nf 10/1 11/1 12/1\n");
  const Mesh m = loadMesh(dir / "t.obj");
  ASSERT_EQ(m.triangleCount(), 4u);
  ASSERT_EQ(m.textures.size(), 1u) << "one file, read once";
  EXPECT_EQ(m.textures[0].file, dir / "mats" / "quadrants.png");
  const std::vector<std::string> said = {
      "texture 'C:\\Users\\me\\textures\\quadrants.png' of material 'elsewhere' is not where its "
      "library says: read " +
      (dir / "mats" / "quadrants.png").string() +
      ", the file of that name beside the library or the OBJ"};
  EXPECT_EQ(m.warnings, said);
  EXPECT_TRUE(near(m.albedoAt(0, 0.2f, 0.2f), {1, 0, 0}));
  EXPECT_TRUE(near(m.albedoAt(1, 0.2f, 0.2f), {1, 0, 0})) << "-s 2 2";
  EXPECT_TRUE(near(m.albedoAt(2, 0.2f, 0.2f), {0, 1, 0})) << "-o 0.5";
  EXPECT_TRUE(near(m.albedoAt(3, 0.2f, 0.2f), {1, 0, 0}));
}

// A material without Kd whose texture cannot be read renders the default grey (it rendered
// white: the texture's colour 1 with no texture), and says so; a second definition of a name
// in another library does not change the first (its one-number Kd did).
TEST(Mesh, ObjMaterialsWithoutTheirTextureOrDefinedTwice) {
  TempDir dir;
  writeText(dir / "a.mtl", "newmtl gone\nmap_Kd gone.png\nnewmtl twice\nKd 1 0 0\n");
  writeText(dir / "b.mtl", "newmtl twice\nKd 0.2\n");
  writeText(dir / "g.obj",
            "mtllib a.mtl b.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nv 2 1 0\n"
            "vt 0 0\nusemtl gone\nf 1/1 2/1 3/1\nusemtl twice\nf 4 5 6\n");
  const Mesh m = loadMesh(dir / "g.obj");
  ASSERT_EQ(m.warnings.size(), 2u);
  EXPECT_EQ(m.warnings[0],
            "material 'twice' is defined again in b.mtl: the first definition (a.mtl) is used");
  EXPECT_NE(m.warnings[1].find("texture 'gone.png' of material 'gone' cannot be read (file not "
                               "found): the material renders with the default albedo"),
            std::string::npos)
      << m.warnings[1];
  ASSERT_TRUE(m.hasMaterials());
  EXPECT_TRUE(near(m.albedoAt(0, 0.2f, 0.2f), glm::vec3(kDefaultAlbedo)));
  EXPECT_TRUE(near(m.albedoAt(1, 0.2f, 0.2f), {1, 0, 0}));
}

// See-through MTL materials: `d` is the opacity, and a map_d naming map_Kd's own file makes its
// alpha channel the texture's opacity (a leaf's cut-out). They are semi-transparent like glTF's
// BLEND: a back side of their own, rays through them carry 1 - alpha. They rendered opaque
// without a word. Tr is not read (OpenMVS writes Tr 1 on opaque materials, others 1 - d): one
// between 0 and 1 is said, Tr 1 is not. d 0 is taken for an exporter's mistake, said.
TEST(Mesh, SeeThroughObjMaterials) {
  TempDir dir;
  Image leaf(2, 1, 4, {"R", "G", "B", "A"});
  const float px[8] = {0, 1, 0, 1, 0, 1, 0, 0};  // green, its right half cut away
  std::copy(px, px + 8, leaf.pixels.begin());
  leaf.colorSpace = "sRGB";
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::UInt8;
  ingest::writeImage(dir / "leaf.png", leaf, options);
  writeQuadrants(dir / "opaque.png");
  writeText(dir / "s.mtl",
            "newmtl glass\nKd 0.2 0.2 0.2\nd 0.25\nTr 0.5\n"
            "newmtl tinted\nKd 1 1 1\nTr 0.4\nnewmtl scanned\nKd 1 1 1\nTr 1.000000\n"
            "newmtl leaf\nmap_Kd leaf.png\nmap_d -imfchan m leaf.png\n"
            "newmtl solid\nKd 0.5 0.5 0.5\nd 1\n"
            "newmtl ghost\nKd 1 0 0\nd 0\n"
            "newmtl other\nmap_Kd opaque.png\nmap_d leaf.png\n"
            "newmtl veil\nmap_Kd leaf.png\nd 0.5\n");
  writeText(
      dir / "s.obj",
      "mtllib s.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\nv 2 1 0\n"
      "v 4 0 0\nv 5 0 0\nv 4 1 0\nv 6 0 0\nv 7 0 0\nv 6 1 0\nv 8 0 0\nv 9 0 0\nv 8 1 0\n"
      "v 10 0 0\nv 11 0 0\nv 10 1 0\nvt 0.25 0.5\nvt 0.75 0.5\n"
      "usemtl glass\nf 1 2 3\nusemtl tinted\nf 4 5 6\nusemtl leaf\nf 7/1 8/2 9/1\n"
      "usemtl solid\nf 10 11 12\nusemtl ghost\nf 13 14 15\nusemtl other\nf 16/1 17/1 18/1\n"
      "usemtl scanned\nf 1 3 4\nv 12 0 0\nv 13 0 0\nv 12 1 0\nusemtl veil\nf 19/1 20/2 21/1\n");
  const Mesh m = loadMesh(dir / "s.obj");
  const std::vector<std::string> said = {
      "material 'tinted': 'Tr 0.4' is not read (exporters disagree on whether Tr is the "
      "transparency or the opacity): it renders opaque; give d, the opacity",
      "material 'ghost' says it is fully transparent ('d 0'), most often an exporter's mistake: "
      "rendered opaque",
      "material 'other': its map_d 'leaf.png' is not read (it is not map_Kd's file, whose alpha "
      "channel is read): the texture is opaque"};
  EXPECT_EQ(m.warnings, said);
  ASSERT_EQ(m.materials.size(), 8u);
  auto material = [&](const std::string& name) -> const Material& {
    for (const Material& mat : m.materials)
      if (mat.name == name) return mat;
    ADD_FAILURE() << "no material " << name;
    return m.materials[0];
  };
  EXPECT_TRUE(material("glass").blend);
  EXPECT_FLOAT_EQ(material("glass").baseAlpha, 0.25f);
  EXPECT_FALSE(material("tinted").blend);
  EXPECT_FALSE(material("scanned").blend);
  EXPECT_TRUE(material("leaf").blend);
  EXPECT_FALSE(material("solid").blend);
  EXPECT_FALSE(material("other").blend);
  EXPECT_FALSE(material("ghost").blend);
  EXPECT_TRUE(material("veil").blend);
  // The file's triangles, in its order; for rendering each gets a back side of its own (every
  // one is a sheet; three are see-through), after them.
  EXPECT_EQ(m.triangleCount(), 8u);
  Mesh sided = m;
  EXPECT_EQ(addBackSides(sided), 5u) << "the opaque sheets";
  EXPECT_EQ(sided.triangleCount(), 16u);
  // d alone: its texture's alpha does not cut it (no map_d names it).
  EXPECT_FLOAT_EQ(m.alphaAt(7, 1.0f, 0.0f), 0.5f);
  EXPECT_FLOAT_EQ(m.alphaAt(0, 0.3f, 0.3f), 0.25f);
  EXPECT_FALSE(m.passes(0, 0.3f, 0.3f, 0.2f)) << "met by a ray whose number is below alpha";
  EXPECT_TRUE(m.passes(0, 0.3f, 0.3f, 0.3f));
  EXPECT_FLOAT_EQ(m.alphaAt(2, 0.0f, 0.0f), 1.0f) << "the leaf's opaque texel";
  EXPECT_FLOAT_EQ(m.alphaAt(2, 1.0f, 0.0f), 0.0f) << "its cut-away texel";
  EXPECT_FLOAT_EQ(m.alphaAt(3, 0.3f, 0.3f), 1.0f);
  EXPECT_FLOAT_EQ(m.alphaAt(5, 0.3f, 0.3f), 1.0f);
}

// A base colour is an albedo: outside 0..1 (Kd 5 -1 0) it rendered as given without a word (and
// --albedo 1.5 is refused). A Kd that is not a number (tinyobjloader reads nan as 0) is the
// default grey, with a warning of its own.
TEST(Mesh, BaseColoursOutsideZeroToOneAreClampedWithAWarning) {
  TempDir dir;
  writeText(dir / "k.mtl",
            "newmtl hot\nKd 5 -1 0.5\nnewmtl bad\nKd nan 0.2 0.3\nnewmtl ok\nKd 0.1 "
            "0.2 0.3\n");
  writeText(dir / "k.obj",
            "mtllib k.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 1 0\nusemtl hot\nf 1 2 3\n"
            "usemtl bad\nf 2 4 3\nusemtl ok\nf 2 5 4\n");
  const Mesh m = loadMesh(dir / "k.obj");
  ASSERT_EQ(m.warnings.size(), 2u) << m.warnings[0];
  EXPECT_EQ(m.warnings[0],
            "material 'bad' has a Kd that is not a colour ('nan 0.2 0.3'): using the default grey");
  EXPECT_EQ(m.warnings[1],
            "1 material has a base colour outside 0..1 ('hot': 5 -1 0.5): clamped to 0..1 (a "
            "value that is not a number: the default albedo)");
  for (const Material& material : m.materials) {
    for (int c = 0; c < 3; ++c) {
      EXPECT_GE(material.baseColor[c], 0.0f) << material.name;
      EXPECT_LE(material.baseColor[c], 1.0f) << material.name;
    }
    if (material.name == "ok") {
      EXPECT_TRUE(near(material.baseColor, {0.1f, 0.2f, 0.3f}));
    }
    if (material.name == "bad") {
      EXPECT_TRUE(near(material.baseColor, glm::vec3(kDefaultAlbedo)));
    }
  }
}

// `mtllib My Chair.mtl`: one library whose name has a space (as Blender reads it), not two
// files, even when a file named like the last word exists.
TEST(Mesh, AMaterialLibraryWhoseNameHasSpaces) {
  TempDir dir;
  writeText(dir / "my mats.mtl", "newmtl a\nKd 0.8 0.1 0.2\n");
  writeText(dir / "mats.mtl", "newmtl a\nKd 0 0 1\n");
  writeText(dir / "m.obj", "mtllib my mats.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n");
  const Mesh m = loadMesh(dir / "m.obj");
  EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
  ASSERT_EQ(m.materials.size(), 1u);
  EXPECT_TRUE(near(m.materials[0].baseColor, {0.8f, 0.1f, 0.2f}));
  // Two libraries on one line still are two.
  writeText(dir / "b.mtl", "newmtl b\nKd 0.3 0.3 0.3\n");
  writeText(dir / "two.obj",
            "mtllib mats.mtl b.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\nf 1 2 3\n"
            "usemtl b\nf 2 4 3\n");
  const Mesh two = loadMesh(dir / "two.obj");
  EXPECT_TRUE(two.warnings.empty()) << two.warnings[0];
  EXPECT_EQ(two.materials.size(), 2u);
  // A space escaped as tinyobjloader reads it (`my\ mats.mtl`), and a library named again on a
  // later line, read once (it said its materials were "defined again" in the same file).
  writeText(dir / "escaped.obj",
            "mtllib my\\ mats.mtl\nmtllib my\\ mats.mtl b.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
            "v 1 1 0\nusemtl a\nf 1 2 3\nusemtl b\nf 2 4 3\n");
  const Mesh escaped = loadMesh(dir / "escaped.obj");
  EXPECT_TRUE(escaped.warnings.empty()) << escaped.warnings[0];
  ASSERT_EQ(escaped.materials.size(), 2u);
  EXPECT_TRUE(near(escaped.materials[0].baseColor, {0.8f, 0.1f, 0.2f}));
}

// A two-sided card (the same triangle twice, back to back, another material on each side): one is
// dropped as a repeat, and the warning says a material was lost with it.
TEST(Mesh, ATwoSidedCardSaysItsBackMaterialIsLost) {
  TempDir dir;
  writeText(dir / "card.mtl", "newmtl front\nKd 1 0 0\nnewmtl back\nKd 0 0 1\n");
  writeText(dir / "card.obj",
            "mtllib card.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 0 0\nv 6 0 0\nv 5 1 0\n"
            "usemtl front\nf 1 2 3\nf 4 5 6\nusemtl back\nf 1 3 2\n");
  const Mesh m = loadMesh(dir / "card.obj");
  bool said = false;
  for (const std::string& w : m.warnings)
    said = said || w.find("1 of them with another material: the back of a two-sided card") !=
                       std::string::npos;
  EXPECT_TRUE(said) << (m.warnings.empty() ? "no warning" : m.warnings[0]);
}

// Vertex colours (v x y z r g b) are not the albedo: a note says they were ignored.
// OBJ vertex colours (v x y z r g b, sRGB-encoded as MeshLab and Blender write them) are decoded
// to linear and multiply the albedo; without materials they are the albedo (a white material).
TEST(Mesh, ObjVertexColoursAreTheAlbedo) {
  TempDir dir;
  writeText(dir / "c.obj", "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 0.5\nf 1 2 3\n");
  const Mesh m = loadMesh(dir / "c.obj");
  ASSERT_EQ(m.triangleCount(), 1u);
  EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
  ASSERT_TRUE(m.hasMaterials());
  ASSERT_EQ(m.colors.size(), 3u);
  EXPECT_EQ(m.materials[0].baseColor, glm::vec3(1.0f));
  const float half = std::pow((0.5f + 0.055f) / 1.055f, 2.4f);  // sRGB 0.5 in linear light
  // At each corner its own colour (corner 0 at barycentrics (0, 0), 1 at u = 1, 2 at v = 1).
  const glm::vec3 corner[3] = {m.albedoAt(0, 0, 0), m.albedoAt(0, 1, 0), m.albedoAt(0, 0, 1)};
  const glm::vec3 expected[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, half}};
  for (int c = 0; c < 3; ++c) {
    const uint32_t v = m.indices[size_t(c)];
    const glm::vec3 p = m.positions[v];
    const int file = p.x > 0.5f ? 1 : p.y > 0.5f ? 2 : 0;  // the file's vertex at this corner
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(corner[c][k], expected[file][k], 1e-6f) << c;
  }
  // Halfway along an edge: the mean of its corners' linear colours.
  const glm::vec3 mid = m.albedoAt(0, 0.5f, 0.0f);
  const glm::vec3 a = m.colors[m.indices[0]], b = m.colors[m.indices[1]];
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(mid[k], 0.5f * (a[k] + b[k]), 1e-6f);
  // Out of range: clamped and counted; a plain file has neither colours nor materials.
  writeText(dir / "over.obj", "v 0 0 0 1.5 0 0\nv 1 0 0 0 -1 0\nv 0 1 0 0 0 1\nf 1 2 3\n");
  const Mesh over = loadMesh(dir / "over.obj");
  ASSERT_EQ(over.warnings.size(), 1u);
  EXPECT_EQ(over.warnings[0], "2 vertex colour components outside 0..1 (or not finite) clamped");
  // Colours on some vertices only: the others white, said (all were dropped without a word).
  writeText(dir / "some.obj", "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0 0 0 1\nf 1 2 3\n");
  const Mesh some = loadMesh(dir / "some.obj");
  ASSERT_EQ(some.colors.size(), 3u);
  ASSERT_EQ(some.warnings.size(), 1u);
  EXPECT_EQ(some.warnings[0],
            "2 of 3 vertices have a colour (v x y z r g b): the others are white");
  for (size_t v = 0; v < 3; ++v) {
    const glm::vec3 p = some.positions[v];
    const glm::vec3 want = p.x > 0.5f   ? glm::vec3(1)
                           : p.y > 0.5f ? glm::vec3(0, 0, 1)
                                        : glm::vec3(1, 0, 0);
    EXPECT_EQ(some.colors[v], want) << v;
  }
  writeText(dir / "plain.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  const Mesh plain = loadMesh(dir / "plain.obj");
  EXPECT_TRUE(plain.colors.empty());
  EXPECT_FALSE(plain.hasMaterials());
  // With a material: its Kd times the colours; the colours follow vertices split at creases.
  writeText(dir / "m.mtl", "newmtl grey\nKd 0.5 0.5 0.5\n");
  writeText(dir / "box.obj",
            "mtllib m.mtl\nusemtl grey\n"
            "v 0 0 0 1 0 0\nv 1 0 0 1 0 0\nv 1 1 0 1 0 0\nv 0 1 0 1 0 0\n"
            "v 0 0 1 0 1 0\nv 1 0 1 0 1 0\nv 1 1 1 0 1 0\nv 0 1 1 0 1 0\n"
            "f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n");
  const Mesh box = loadMesh(dir / "box.obj");
  ASSERT_EQ(box.colors.size(), box.positions.size());
  EXPECT_GT(box.positions.size(), 8u);  // split at the 90° edges
  for (size_t v = 0; v < box.positions.size(); ++v) {
    const glm::vec3 want = box.positions[v].z < 0.5f ? glm::vec3(1, 0, 0) : glm::vec3(0, 1, 0);
    EXPECT_EQ(box.colors[v], want) << v;
  }
  EXPECT_NEAR(box.albedoAt(0, 0.0f, 0.0f).x, 0.5f * box.colors[box.indices[0]].x, 1e-6f);
}

TEST(Mesh, MissingMaterialLibrariesAndTexturesAreWarningsNamingThem) {
  TempDir dir;
  writeText(dir / "m.obj", "mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl a\nf 1 2 3\n");
  const Mesh none = loadMesh(dir / "m.obj");
  ASSERT_EQ(none.warnings.size(), 1u);
  EXPECT_EQ(none.warnings[0],
            "material library 'missing.mtl' cannot be read (No such file or directory): its "
            "materials render with the default albedo");
  EXPECT_FALSE(none.hasMaterials()) << "the renderer's albedo applies";

  writeText(dir / "t.mtl", "newmtl a\nKd 0.1 0.2 0.3\nmap_Kd gone.png\n");
  writeText(dir / "t.obj",
            "mtllib t.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nusemtl a\nf 1/1 2/1 3/1\n");
  const Mesh untextured = loadMesh(dir / "t.obj");
  ASSERT_EQ(untextured.warnings.size(), 1u);
  EXPECT_NE(untextured.warnings[0].find("texture 'gone.png' of material 'a' cannot be read (file "
                                        "not found): the material renders with its Kd"),
            std::string::npos)
      << untextured.warnings[0];
  ASSERT_TRUE(untextured.hasMaterials());
  EXPECT_TRUE(near(untextured.albedoAt(0, 0.2f, 0.2f), {0.1f, 0.2f, 0.3f}));

  // A device instead of a file would be read forever: refused, named.
  writeText(dir / "dev.mtl", "newmtl a\nKd 0.1 0.2 0.3\nmap_Kd /dev/zero\n");
  writeText(dir / "dev.obj",
            "mtllib /dev/zero dev.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n"
            "usemtl a\nf 1/1 2/1 3/1\n");
  const Mesh device = loadMesh(dir / "dev.obj");
  const std::vector<std::string> expected = {
      "material library '/dev/zero' cannot be read (not a regular file): its materials render "
      "with the default albedo",
      "texture '/dev/zero' of material 'a' cannot be read (not a regular file): the material "
      "renders with its Kd"};
  EXPECT_EQ(device.warnings, expected);
}

TEST(Mesh, FacesReferringToMissingVerticesAreDroppedWithCounts) {
  TempDir dir;
  writeText(dir / "m.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n"
            "f 1 2 3\nf 1 2 9\nf 1/2 2/1 3/1\nf 1//3 2//1 3//1\nf -1 -2 -7\n");
  const Mesh m = loadMesh(dir / "m.obj");
  EXPECT_EQ(m.triangleCount(), 1u);
  ASSERT_GE(m.warnings.size(), 1u);
  EXPECT_EQ(m.warnings[0],
            "dropped 4 of 5 faces referring to vertices, texture coordinates or normals the file "
            "does not have (it has 3 vertices, 1 texture coordinate, 1 normal)");
  writeText(dir / "none.obj", "v 0 0 0\nv 1 0 0\nf 1 2 3\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "none.obj"),
                       "nothing renderable: dropped the one face referring to vertices");
  writeText(dir / "huge.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4294967299\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "huge.obj"),
                       "line 4: face corner '4294967299' is not a valid vertex reference");
}

TEST(Mesh, FacesWithAndWithoutNormalsAndTextureCoordinates) {
  TempDir dir;
  // One quad with normals and texture coordinates, one with neither, one with texture
  // coordinates only, sharing an edge each: file normals are kept, the rest computed.
  writeText(dir / "m.obj",
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nv 3 0 0\nv 3 1 0\n"
            "vt 0 0\nvt 1 1\nvn 0 0 1\n"
            "f 1/1/1 2/2/1 3/1/1 4/2/1\nf 2 5 6 3\nf 5/1 7/2 8/1 6/2\n");
  const Mesh m = loadMesh(dir / "m.obj");
  EXPECT_EQ(m.triangleCount(), 6u);
  EXPECT_FALSE(m.normalsFromFile);
  EXPECT_NE(m.normalsSource.find("from the file for 4 of"), std::string::npos) << m.normalsSource;
  for (const glm::vec3& n : m.normals) EXPECT_NEAR(n.z, 1.0f, 1e-6f);
  EXPECT_TRUE(m.texcoords.empty()) << "no textured material: texture coordinates unused";
}

TEST(Mesh, BicubicPatchesAreTessellatedWeldedAndTurnedUpright) {
  TempDir dir;
  // One flat patch in Geomview's Z-up frame: the unit square at z = 2, control points on a grid.
  std::string text = "BBP\n";
  for (int a = 0; a < 4; ++a)
    for (int b = 0; b < 4; ++b)
      text += std::to_string(a / 3.0) + " " + std::to_string(b / 3.0) + " 2\n";
  writeText(dir / "patch.bez", text);
  const Mesh m = loadMesh(dir / "patch.bez");
  EXPECT_EQ(m.positions.size(), 17u * 17u);
  EXPECT_EQ(m.triangleCount(), 2u * 16u * 16u);
  // Z-up → Y-up: the patch lies at y = 2.
  EXPECT_NEAR(m.boundsMin().y, 2.0f, 1e-6f);
  EXPECT_NEAR(m.boundsMax().y, 2.0f, 1e-6f);
  writeText(dir / "bad.bez", "BBP\n0 0 0\n1 1\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "bad.bez"), "16 points of 3 numbers per patch");
  writeText(dir / "other.bez", "CBBP\n");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "other.bez"), "expected the keyword BBP");
}

TEST(Mesh, TheSampleTeapotIsOneSmoothSurface) {
  const auto file = pipeline::samplesDirectory() / "teapot.bez";
  if (!std::filesystem::exists(file)) GTEST_FAIL() << "sample data missing: " << file;
  const Mesh m = loadMesh(file);
  EXPECT_GT(m.triangleCount(), 14000u);
  // Upright: taller than deep in y, and every normal of the top lid rim faces up.
  EXPECT_GT(m.boundsMax().y - m.boundsMin().y, 0.5f);
}

}  // namespace
}  // namespace compose::render
