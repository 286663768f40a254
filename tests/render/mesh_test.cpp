#include "render/mesh.h"

#include <cmath>

#include <glm/geometric.hpp>

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
  };
  for (const auto& [text, message] : cases) {
    writeText(dir / "bad.obj", text);
    COMPOSE_EXPECT_ERROR(loadMesh(dir / "bad.obj"), message);
  }
  // Valid forms still load: exponents, signs, relative indices, v/vt/vn corners.
  writeText(dir / "ok.obj",
            "v 0 0 0\nv 1e0 -0 +0\nv 0 1.0E+0 0\nvt 0 0\nvn 0 0 1\nf -3/1/1 -2/1/1 -1/1/1\n");
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
