// glTF 2.0 loading on small files written here: the hierarchy, every primitive mode and index
// width, sparse and quantised accessors, materials and textures (data URIs and .glb buffer
// views), and every kind of broken input.
#include <cmath>
#include <limits>

#include <glm/geometric.hpp>

#include "core/image.h"
#include "gltf_builder.h"
#include "ingest/image_io.h"
#include "render/mesh.h"
#include "test_util.h"

namespace compose::render {
namespace {

using compose::testing::base64;
using compose::testing::GltfBuilder;
using compose::testing::readBytes;
using compose::testing::TempDir;
using compose::testing::writeText;
using nlohmann::json;

constexpr int kU8 = 5121, kU16 = 5123, kU32 = 5125, kFloat = 5126;

std::vector<uint8_t> asBytes(const std::vector<float>& v) {
  std::vector<uint8_t> out(v.size() * 4);
  std::memcpy(out.data(), v.data(), out.size());
  return out;
}

void writeBytes(const std::filesystem::path& file, const std::vector<uint8_t>& bytes) {
  std::ofstream out(file, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
}

// Whether the mesh has a vertex at p (to 1e-5).
bool hasPosition(const Mesh& m, const glm::vec3& p) {
  for (const glm::vec3& q : m.positions)
    if (glm::length(q - p) < 1e-5f) return true;
  return false;
}

// Triangle t's face normal times twice its area.
glm::vec3 faceCross(const Mesh& m, size_t t) {
  const glm::vec3 a = m.positions[m.indices[3 * t]], b = m.positions[m.indices[3 * t + 1]],
                  c = m.positions[m.indices[3 * t + 2]];
  return glm::cross(b - a, c - a);
}

// A 2x2 8-bit PNG: red, green on the top row; blue, white below. Returns its bytes.
std::vector<uint8_t> quadrantPng(const TempDir& dir) {
  Image img(2, 2, 3, {"R", "G", "B"});
  const float px[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1};
  std::copy(px, px + 12, img.pixels.begin());
  img.colorSpace = "sRGB";
  ingest::WriteOptions options;
  options.depth = ingest::WriteOptions::Depth::UInt8;
  ingest::writeImage(dir / "quadrants.png", img, options);
  return readBytes(dir / "quadrants.png");
}

// The quadrant texture as an RGBA PNG with unassociated alpha, written byte by byte (stored
// deflate blocks): green fully transparent, blue half.
std::vector<uint8_t> quadrantPngWithAlpha() {
  auto crc32 = [](const uint8_t* p, size_t n) {
    uint32_t c = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; ++i) {
      c ^= p[i];
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return ~c;
  };
  auto be32 = [](std::vector<uint8_t>& out, uint32_t v) {
    for (int s = 24; s >= 0; s -= 8) out.push_back(uint8_t(v >> s));
  };
  std::vector<uint8_t> png = {0x89, 'P', 'N', 'G', 0x0D, 0x0A, 0x1A, 0x0A};
  auto chunk = [&](const char* type, const std::vector<uint8_t>& data) {
    be32(png, uint32_t(data.size()));
    std::vector<uint8_t> body(type, type + 4);
    body.insert(body.end(), data.begin(), data.end());
    png.insert(png.end(), body.begin(), body.end());
    be32(png, crc32(body.data(), body.size()));
  };
  std::vector<uint8_t> header;
  be32(header, 2);
  be32(header, 2);
  header.insert(header.end(), {8, 6, 0, 0, 0});  // 8 bits, RGBA
  chunk("IHDR", header);
  const std::vector<uint8_t> raw = {0, 255, 0, 0,   255, 0,   255, 0,   0,
                                    0, 0,   0, 255, 128, 128, 128, 128, 255};
  uint32_t a = 1, b = 0;  // Adler-32
  for (const uint8_t v : raw) a = (a + v) % 65521u, b = (b + a) % 65521u;
  std::vector<uint8_t> z = {0x78, 0x01, 1, uint8_t(raw.size()), 0, uint8_t(~raw.size()), 0xFF};
  z.insert(z.end(), raw.begin(), raw.end());
  be32(z, (b << 16) | a);
  chunk("IDAT", z);
  chunk("IEND", {});
  return png;
}

TEST(Gltf, AHandWrittenTriangleWithoutNormals) {
  TempDir dir;
  const std::string data = base64(asBytes({0, 0, 0, 1, 0, 0, 0, 1, 0}));
  writeText(dir / "triangle.gltf", R"({
  "asset": {"version": "2.0"},
  "scene": 0,
  "scenes": [{"nodes": [0]}],
  "nodes": [{"mesh": 0}],
  "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
  "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,)" +
                                       data + R"("}],
  "bufferViews": [{"buffer": 0, "byteLength": 36}],
  "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                 "min": [0, 0, 0], "max": [1, 1, 0]}]
})");
  const Mesh m = loadMesh(dir / "triangle.gltf");
  ASSERT_EQ(m.triangleCount(), 1u);
  EXPECT_TRUE(m.warnings.empty());
  EXPECT_FALSE(m.hasMaterials());
  EXPECT_FALSE(m.normalsFromFile);
  EXPECT_NE(m.normalsSource.find("not in the file"), std::string::npos);
  for (const glm::vec3& n : m.normals) EXPECT_NEAR(n.z, 1.0f, 1e-6f);
  EXPECT_EQ(m.boundsMax(), glm::vec3(1, 1, 0));
}

TEST(Gltf, IndicesOfEveryWidthGiveTheSameMesh) {
  TempDir dir;
  const std::vector<float> quad = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
  std::vector<std::vector<uint32_t>> results;
  for (const int type : {kU8, kU16, kU32}) {
    GltfBuilder b;
    const int pos = b.vec3(quad);
    int idx = 0;
    if (type == kU8) idx = b.accessor(std::vector<uint8_t>{0, 1, 2, 0, 2, 3}, type, "SCALAR", 6);
    if (type == kU16) idx = b.accessor(std::vector<uint16_t>{0, 1, 2, 0, 2, 3}, type, "SCALAR", 6);
    if (type == kU32) idx = b.accessor(std::vector<uint32_t>{0, 1, 2, 0, 2, 3}, type, "SCALAR", 6);
    b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"indices", idx}})}})});
    writeText(dir / "quad.gltf", b.gltf());
    const Mesh m = loadMesh(dir / "quad.gltf");
    EXPECT_EQ(m.triangleCount(), 2u) << type;
    results.push_back(m.indices);
  }
  EXPECT_EQ(results[0], results[1]);
  EXPECT_EQ(results[0], results[2]);
  // Signed indices are not indices.
  GltfBuilder b;
  const int pos = b.vec3(quad);
  const int idx = b.accessor(std::vector<int16_t>{0, 1, 2}, 5122, "SCALAR", 3);
  b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"indices", idx}})}})});
  writeText(dir / "signed.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "signed.gltf"),
                       "indices (accessor 1) must hold unsigned 8-, 16- or 32-bit integers");
}

TEST(Gltf, StripsAndFansBecomeOutwardTriangles) {
  TempDir dir;
  // The unit square facing +Z, as a strip and as a fan (glTF 2.0 §3.7.2.1).
  const std::pair<int, std::vector<float>> cases[] = {
      {5, {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0}},
      {6, {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0}},
  };
  for (const auto& [mode, vertices] : cases) {
    GltfBuilder b;
    const int pos = b.vec3(vertices);
    b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"mode", mode}})}})});
    writeText(dir / "square.gltf", b.gltf());
    const Mesh m = loadMesh(dir / "square.gltf", {.creaseDegrees = 0.0});
    ASSERT_EQ(m.triangleCount(), 2u) << "mode " << mode;
    float area = 0.0f;
    for (size_t t = 0; t < 2; ++t) {
      EXPECT_GT(faceCross(m, t).z, 0.0f) << "mode " << mode << " triangle " << t;
      area += 0.5f * glm::length(faceCross(m, t));
    }
    EXPECT_NEAR(area, 1.0f, 1e-6f) << "mode " << mode;
  }
}

TEST(Gltf, PointsAndLinesAreSkippedWithAWarning) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int m = b.mesh({{"attributes", {{"POSITION", pos}}}});
  b.json["meshes"][size_t(m)]["primitives"].push_back(
      {{"attributes", {{"POSITION", pos}}}, {"mode", 1}});
  b.json["meshes"][size_t(m)]["primitives"].push_back(
      {{"attributes", {{"POSITION", pos}}}, {"mode", 0}});
  b.scene({b.node({{"mesh", m}})});
  writeText(dir / "mixed.gltf", b.gltf());
  const Mesh mesh = loadMesh(dir / "mixed.gltf");
  EXPECT_EQ(mesh.triangleCount(), 1u);
  ASSERT_EQ(mesh.warnings.size(), 1u);
  EXPECT_EQ(mesh.warnings[0], "skipped 2 primitives of points or lines (only triangles render)");

  GltfBuilder lines;
  const int p = lines.vec3({0, 0, 0, 1, 0, 0});
  lines.scene(
      {lines.node({{"mesh", lines.mesh({{"attributes", {{"POSITION", p}}}, {"mode", 1}})}})});
  writeText(dir / "lines.gltf", lines.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "lines.gltf"),
                       "mesh: nothing renderable: no triangles in 1 primitive: skipped 1 primitive "
                       "of points or lines (only triangles render) (");
}

TEST(Gltf, TheNodeHierarchyIsFlattenedIntoObjectSpace) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int mesh = b.mesh({{"attributes", {{"POSITION", pos}}}});
  const float h = std::sqrt(0.5f);
  // parent: translate (10, 0, 0); child: rotate 90° about +Z, scale 2. Another root places the
  // same mesh by a matrix (column-major) translating by (0, 5, 0).
  const int child = b.node({{"mesh", mesh}, {"rotation", {0, 0, h, h}}, {"scale", {2, 2, 2}}});
  const int parent = b.node({{"translation", {10, 0, 0}}, {"children", {child}}});
  const int matrix =
      b.node({{"mesh", mesh}, {"matrix", {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 5, 0, 1}}});
  b.scene({parent, matrix});
  writeText(dir / "tree.gltf", b.gltf());
  const Mesh m = loadMesh(dir / "tree.gltf");
  ASSERT_EQ(m.triangleCount(), 2u);
  // (1, 0, 0): scaled to (2, 0, 0), turned to (0, 2, 0), moved to (10, 2, 0).
  EXPECT_TRUE(hasPosition(m, {10, 2, 0}));
  EXPECT_TRUE(hasPosition(m, {8, 0, 0}));
  EXPECT_TRUE(hasPosition(m, {10, 0, 0}));
  EXPECT_TRUE(hasPosition(m, {1, 5, 0}));
  EXPECT_TRUE(hasPosition(m, {0, 6, 0}));
  // Two scenes and no default: the first renders, and a note says so.
  b.json["scenes"].push_back({{"name", "other"}, {"nodes", json::array()}});
  b.json.erase("scene");
  writeText(dir / "twoscenes.gltf", b.gltf());
  const Mesh two = loadMesh(dir / "twoscenes.gltf");
  EXPECT_EQ(two.triangleCount(), 2u);
  ASSERT_EQ(two.warnings.size(), 1u);
  EXPECT_NE(two.warnings[0].find("2 scenes and names no default one: rendered scene 0"),
            std::string::npos)
      << two.warnings[0];
  // Without scenes, every root node renders.
  b.json.erase("scenes");
  b.json.erase("scene");
  writeText(dir / "noscene.gltf", b.gltf());
  EXPECT_EQ(loadMesh(dir / "noscene.gltf").triangleCount(), 2u);
}

// EXT_mesh_gpu_instancing (glTF-Transform and Blender write it for scattered copies): the node's
// mesh drawn at each instance's translation, rotation and scale, within the node's transform
// (one copy of three was drawn, without a word).
TEST(Gltf, GpuInstancesAreEachDrawn) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int mesh = b.mesh({{"attributes", {{"POSITION", pos}}}});
  const float h = std::sqrt(0.5f);
  const int translation = b.vec3({0, 0, 0, 5, 0, 0, 10, 0, 0});
  const int rotation =
      b.accessor(std::vector<float>{0, 0, 0, 1, 0, 0, h, h, 0, 0, 0, 1}, 5126, "VEC4", 3);
  const int scale = b.vec3({1, 1, 1, 1, 1, 1, 3, 3, 3});
  const int node =
      b.node({{"mesh", mesh},
              {"translation", {0, 0, 2}},
              {"extensions",
               {{"EXT_mesh_gpu_instancing",
                 {{"attributes",
                   {{"TRANSLATION", translation}, {"ROTATION", rotation}, {"SCALE", scale}}}}}}}});
  b.scene({node});
  b.json["extensionsUsed"] = {"EXT_mesh_gpu_instancing"};
  b.json["extensionsRequired"] = {"EXT_mesh_gpu_instancing"};
  writeText(dir / "instanced.gltf", b.gltf());
  const Mesh m = loadMesh(dir / "instanced.gltf");
  ASSERT_EQ(m.triangleCount(), 3u);
  EXPECT_TRUE(m.warnings.empty()) << m.warnings.front();
  EXPECT_TRUE(hasPosition(m, {1, 0, 2}));  // the first as it is, within the node
  EXPECT_TRUE(
      hasPosition(m, {4, 0, 2}));  // the second turned 90° about +Z: (0, 1, 0) to (-1, 0, 0)
  EXPECT_TRUE(hasPosition(m, {13, 0, 2}));  // the third scaled 3 times
  // Attributes of different counts are a broken file.
  b.json["accessors"][size_t(scale)]["count"] = 2;
  writeText(dir / "uneven.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "uneven.gltf"),
                       "EXT_mesh_gpu_instancing's attributes count 3 and 2 instances");
  // More instances than the triangle limit: refused before anything is allocated for them (an
  // accessor without a buffer view holds zeros for as many as it claims).
  b.json["accessors"][size_t(scale)]["count"] = 3;
  b.json["accessors"].push_back({{"componentType", 5126}, {"count", 1 << 27}, {"type", "VEC3"}});
  b.json["nodes"][size_t(node)]["extensions"]["EXT_mesh_gpu_instancing"]["attributes"] = {
      {"TRANSLATION", int(b.json["accessors"].size()) - 1}};
  writeText(dir / "many.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "many.gltf"), "mesh has at least 134217728 triangles");
}

// A small mesh far from the file's origin (a node translation of 5000 for a 1 mm triangle pair):
// moved to its own middle in double before its positions become float, so that its shape keeps
// float's precision on its own scale (at 5000, float's step is half a millimetre), and the file
// origin says where it was.
TEST(Gltf, AMeshFarFromTheOriginKeepsItsShape) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 0.001f, 0, 0, 0, 0.001f, 0, 0.001f, 0.001f, 0.0005f});
  const int idx = b.accessor(std::vector<uint32_t>{0, 1, 2, 1, 3, 2}, 5125, "SCALAR", 6);
  b.scene({b.node({{"translation", {5000.0, -3000.0, 2000.0}},
                   {"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"indices", idx}})}})});
  writeText(dir / "far.gltf", b.gltf());
  const Mesh m = loadMesh(dir / "far.gltf");
  ASSERT_EQ(m.positions.size(), 4u);
  EXPECT_NEAR(m.fileOrigin.x, 5000.0005, 1e-9);
  EXPECT_NEAR(m.fileOrigin.y, -2999.9995, 1e-9);
  EXPECT_NEAR(m.fileOrigin.z, 2000.00025, 1e-9);
  bool said = false;
  for (const std::string& w : m.warnings)
    said = said || w.find("from its file's origin") != std::string::npos;
  EXPECT_TRUE(said);
  // Every corner where the file puts it, to float's precision at the mesh's own scale.
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
  // A vertex no triangle uses, at the file's origin, does not keep the mesh there (it kept it
  // from being moved, and float rounding at 5000 flattened it).
  GltfBuilder stray;
  const int strayPos = stray.vec3(
      {0, 0, 0, 0.001f, 0, 0, 0, 0.001f, 0, 0.001f, 0.001f, 0.0005f, -5000.0f, 3000.0f, -2000.0f});
  const int strayIdx = stray.accessor(std::vector<uint32_t>{0, 1, 2, 1, 3, 2}, 5125, "SCALAR", 6);
  stray.scene({stray.node(
      {{"translation", {5000.0, -3000.0, 2000.0}},
       {"mesh", stray.mesh({{"attributes", {{"POSITION", strayPos}}}, {"indices", strayIdx}})}})});
  writeText(dir / "stray.gltf", stray.gltf());
  const Mesh s = loadMesh(dir / "stray.gltf");
  EXPECT_NEAR(s.fileOrigin.x, 5000.0005, 1e-9);
  EXPECT_NEAR(s.fileOrigin.z, 2000.00025, 1e-9);
  ASSERT_EQ(s.triangleCount(), 2u);
  for (const glm::dvec3& e : expected) {
    double nearest = 1e30;
    for (const glm::vec3& p : s.positions)
      nearest = std::min(nearest, glm::length(glm::dvec3(p) + s.fileOrigin - e));
    EXPECT_LT(nearest, 1e-9) << e.x << " " << e.y << " " << e.z;
  }
}

TEST(Gltf, AMirroringNodeKeepsTrianglesWoundOutwards) {
  TempDir dir;
  // A tetrahedron with flat outward normals, unindexed, under a scale of -1 in x.
  const glm::vec3 c[4] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const int faces[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  std::vector<float> positions, normals;
  for (const auto& f : faces) {
    const glm::vec3 n = glm::normalize(glm::cross(c[f[1]] - c[f[0]], c[f[2]] - c[f[0]]));
    for (int k = 0; k < 3; ++k) {
      positions.insert(positions.end(), {c[f[k]].x, c[f[k]].y, c[f[k]].z});
      normals.insert(normals.end(), {n.x, n.y, n.z});
    }
  }
  for (const double sx : {1.0, -1.0}) {
    GltfBuilder b;
    const int pos = b.vec3(positions), nrm = b.vec3(normals);
    b.scene({b.node({{"scale", {sx, 1, 1}},
                     {"mesh", b.mesh({{"attributes", {{"POSITION", pos}, {"NORMAL", nrm}}}})}})});
    writeText(dir / "tet.gltf", b.gltf());
    const Mesh m = loadMesh(dir / "tet.gltf");
    ASSERT_EQ(m.triangleCount(), 4u);
    EXPECT_TRUE(m.normalsFromFile);
    double volume = 0.0;
    for (size_t t = 0; t < 4; ++t) {
      const glm::vec3 fn = faceCross(m, t);
      for (int k = 0; k < 3; ++k)
        EXPECT_GT(glm::dot(fn, m.normals[m.indices[3 * t + size_t(k)]]), 0.0f) << "scale " << sx;
      volume += glm::dot(m.positions[m.indices[3 * t]], fn) / 6.0;
    }
    EXPECT_NEAR(volume, 1.0 / 6.0, 1e-6) << "scale " << sx;
    EXPECT_TRUE(hasPosition(m, {float(sx), 0, 0}));
  }
}

// Two triangles: one with material 0 (a factor times the quadrant texture), one with material 1
// (a factor alone). Texture coordinates of the first: (0.25, 0.25), (0.75, 0.25), (0.25, 0.75) in
// glTF's convention (v down), the centres of the red, green and blue texels.
GltfBuilder texturedPair(const json& image) {
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int pos2 = b.vec3({2, 0, 0, 3, 0, 0, 2, 1, 0});
  const int uv = b.vec2({0.25f, 0.25f, 0.75f, 0.25f, 0.25f, 0.75f});
  b.json["images"] = json::array({image});
  b.json["textures"] = json::array({{{"source", 0}}});
  b.json["materials"] = json::array(
      {{{"name", "painted"},
        {"pbrMetallicRoughness",
         {{"baseColorFactor", {0.5, 1, 1, 1}}, {"baseColorTexture", {{"index", 0}}}}}},
       {{"name", "plain"}, {"pbrMetallicRoughness", {{"baseColorFactor", {0.2, 0.4, 0.6, 1}}}}}});
  const int m = b.mesh({{"attributes", {{"POSITION", pos}, {"TEXCOORD_0", uv}}}, {"material", 0}});
  b.json["meshes"][size_t(m)]["primitives"].push_back(
      {{"attributes", {{"POSITION", pos2}}}, {"material", 1}});
  b.scene({b.node({{"mesh", m}})});
  return b;
}

void expectPaintedPair(const Mesh& m) {
  ASSERT_EQ(m.triangleCount(), 2u);
  ASSERT_EQ(m.materials.size(), 2u);
  ASSERT_EQ(m.textures.size(), 1u);
  EXPECT_EQ(m.colorSpace, "lin_rec709");
  EXPECT_EQ(m.textures[0].image.colorSpace, "sRGB");
  EXPECT_EQ(m.materials[0].name, "painted");
  // The first triangle's corners: barycentrics (0, 0), (1, 0), (0, 1). Texels are the 8-bit
  // codes / 255, still encoded (the pipeline linearises them); exact at texel centres.
  const uint32_t first = m.positions[m.indices[0]].x < 1.5f ? 0u : 1u;
  auto near = [](const glm::vec3& a, const glm::vec3& b) { return glm::length(a - b) < 1e-6f; };
  EXPECT_TRUE(near(m.albedoAt(first, 0, 0), {0.5f, 0, 0})) << "red, top left";
  EXPECT_TRUE(near(m.albedoAt(first, 1, 0), {0, 1, 0})) << "green, top right";
  EXPECT_TRUE(near(m.albedoAt(first, 0, 1), {0, 0, 1})) << "blue, bottom left";
  const glm::vec3 plain = m.albedoAt(1 - first, 0.3f, 0.3f);
  EXPECT_TRUE(near(plain, {0.2f, 0.4f, 0.6f}));
}

TEST(Gltf, BaseColourFactorsAndTexturesFromDataUris) {
  TempDir dir;
  const std::string png = "data:image/png;base64," + base64(quadrantPng(dir));
  writeText(dir / "pair.gltf", texturedPair({{"uri", png}}).gltf());
  const Mesh m = loadMesh(dir / "pair.gltf");
  EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
  expectPaintedPair(m);
}

// A base colour texture's alpha is not its colour: transparent and half-transparent texels keep
// the colour they store (alpha is not multiplied into it), and the texture is sRGB by glTF's
// rule. Without alphaMode MASK it cuts nothing; a BLEND material is semi-transparent by it; an
// alphaMode glTF does not define is opaque, with a warning.
TEST(Gltf, TextureAlphaLeavesTheColourAlone) {
  TempDir dir;
  const std::vector<uint8_t> png = quadrantPngWithAlpha();
  GltfBuilder b = texturedPair(json::object());
  const int view = b.view(png.data(), png.size());
  b.json["images"][0] = {{"bufferView", view}, {"mimeType", "image/png"}};
  writeBytes(dir / "alpha.glb", b.glb());
  const Mesh m = loadMesh(dir / "alpha.glb");
  EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
  expectPaintedPair(m);
  ASSERT_EQ(m.textures.size(), 1u);
  EXPECT_TRUE(m.textures[0].srgbByFormat);
  EXPECT_FALSE(m.hasCutouts());  // alpha alone (OPAQUE) cuts nothing
  const uint32_t first = m.positions[m.indices[0]].x < 1.5f ? 0u : 1u;
  EXPECT_FALSE(m.cutAway(first, 1, 0));
  // Opaque, the colour blends across texels whatever their alpha: between red's and green's
  // centres, both.
  EXPECT_GT(m.albedoAt(first, 0.45f, 0).y, 0.4f);
  // A cut-out's colour is filtered by alpha: green, not there, does not bleed into red's edge
  // (a purple fringe along the cut where the transparent texels were blue).
  b.json["materials"][0]["alphaMode"] = "MASK";
  writeBytes(dir / "mask.glb", b.glb());
  const Mesh masked = loadMesh(dir / "mask.glb");
  EXPECT_LT(glm::length(masked.albedoAt(first, 0.45f, 0) - glm::vec3(0.5f, 0, 0)), 1e-5f);
  // BLEND: semi-transparent by the texture's alpha (green 0: not there; blue 128/255: found by
  // rays whose random number is below it).
  b.json["materials"][0]["alphaMode"] = "BLEND";
  writeBytes(dir / "blend.glb", b.glb());
  const Mesh blended = loadMesh(dir / "blend.glb");
  EXPECT_TRUE(blended.warnings.empty()) << blended.warnings[0];
  ASSERT_TRUE(blended.hasCutouts());
  EXPECT_TRUE(blended.materials[0].blend);
  ASSERT_EQ(blended.triangleCount(), 2u) << "the file's triangles";
  // For rendering, each gets a back side of its own: the semi-transparent one, and the opaque
  // one, a sheet (after the others, in their order).
  Mesh sided = blended;
  EXPECT_EQ(addBackSides(sided), 1u) << "the opaque sheet";
  ASSERT_EQ(sided.triangleCount(), 4u);
  for (uint32_t t = 0; t < 4; ++t) {
    EXPECT_TRUE(sided.oneSided(t)) << t;
    EXPECT_EQ(sided.semiTransparent(t), t % 2 == first) << t;
  }
  EXPECT_FALSE(blended.materials[1].cutOut()) << "the plain material is opaque";
  EXPECT_FALSE(blended.cutAway(first, 0, 0)) << "red, opaque";
  EXPECT_TRUE(blended.cutAway(first, 1, 0)) << "green, transparent";
  EXPECT_FALSE(blended.passes(first, 0, 1, 0.45f)) << "blue, alpha 0.502";
  EXPECT_TRUE(blended.passes(first, 0, 1, 0.55f)) << "blue, alpha 0.502";
  EXPECT_FALSE(blended.passes(first, 0, 0, 0.999f)) << "red, opaque";
  // The factor's alpha multiplies the texture's; BLEND with alpha 1 everywhere is opaque.
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = {1, 1, 1, 0.5};
  writeBytes(dir / "blend-faded.glb", b.glb());
  const Mesh faded = loadMesh(dir / "blend-faded.glb");
  EXPECT_FALSE(faded.passes(first, 0, 0, 0.45f)) << "red, 0.5 x 1";
  EXPECT_TRUE(faded.passes(first, 0, 0, 0.55f)) << "red, 0.5 x 1";
  b.json["materials"][0]["pbrMetallicRoughness"].erase("baseColorTexture");
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = {1, 1, 1, 1};
  writeBytes(dir / "blend-opaque.glb", b.glb());
  EXPECT_FALSE(loadMesh(dir / "blend-opaque.glb").hasCutouts());
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = {1, 1, 1, 0.5};
  b.json["materials"][0]["alphaMode"] = "blend";  // glTF's names are upper case
  writeBytes(dir / "lower-case.glb", b.glb());
  const Mesh unknown = loadMesh(dir / "lower-case.glb");
  EXPECT_FALSE(unknown.hasCutouts());
  ASSERT_EQ(unknown.warnings.size(), 1u);
  EXPECT_NE(unknown.warnings[0].find("alphaMode 'blend', which glTF does not define"),
            std::string::npos)
      << unknown.warnings[0];
}

// alphaMode MASK cuts the surface away where alpha (the base colour factor's times the
// texture's) is below alphaCutoff (0.5 by default): red alpha 1, green 0, blue 128/255.
TEST(Gltf, MaskMaterialsCutTheSurfaceWhereAlphaIsBelowTheCutoff) {
  TempDir dir;
  const std::vector<uint8_t> png = quadrantPngWithAlpha();
  GltfBuilder b = texturedPair(json::object());
  const int view = b.view(png.data(), png.size());
  b.json["images"][0] = {{"bufferView", view}, {"mimeType", "image/png"}};
  b.json["materials"][0]["alphaMode"] = "MASK";
  auto load = [&](const std::string& name) {
    writeBytes(dir / name, b.glb());
    return loadMesh(dir / name);
  };
  const Mesh masked = load("mask.glb");
  EXPECT_TRUE(masked.warnings.empty()) << masked.warnings[0];
  expectPaintedPair(masked);  // the colour is unchanged
  ASSERT_TRUE(masked.hasCutouts());
  EXPECT_FLOAT_EQ(masked.materials[0].alphaCutoff, 0.5f);
  EXPECT_FALSE(masked.materials[1].cutOut());
  const uint32_t first = masked.positions[masked.indices[0]].x < 1.5f ? 0u : 1u;
  EXPECT_FALSE(masked.cutAway(first, 0, 0)) << "red, opaque";
  EXPECT_TRUE(masked.cutAway(first, 1, 0)) << "green, transparent";
  EXPECT_FALSE(masked.cutAway(first, 0, 1)) << "blue, alpha 0.502";
  EXPECT_FALSE(masked.cutAway(1 - first, 0.3f, 0.3f)) << "the plain material is opaque";
  b.json["materials"][0]["alphaCutoff"] = 0.6;
  const Mesh higher = load("cutoff.glb");
  EXPECT_TRUE(higher.cutAway(first, 0, 1)) << "blue, below 0.6";
  EXPECT_FALSE(higher.cutAway(first, 0, 0));
  b.json["materials"][0].erase("alphaCutoff");
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = {0.5, 1, 1, 0.5};
  const Mesh faded = load("faded.glb");
  EXPECT_FALSE(faded.cutAway(first, 0, 0)) << "red, 0.5 x 1: at the cutoff";
  EXPECT_TRUE(faded.cutAway(first, 0, 1)) << "blue, 0.5 x 0.502";
}

// KHR_materials_pbrSpecularGlossiness: the diffuse factor is the base colour.
TEST(Gltf, SpecularGlossinessDiffuseIsTheBaseColour) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  b.json["materials"] = json::array(
      {{{"name", "old"},
        {"extensions",
         {{"KHR_materials_pbrSpecularGlossiness", {{"diffuseFactor", {0.8, 0.1, 0.2, 1}}}}}}}});
  b.json["extensionsUsed"] = json::array({"KHR_materials_pbrSpecularGlossiness"});
  b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"material", 0}})}})});
  writeText(dir / "sg.gltf", b.gltf());
  const Mesh m = loadMesh(dir / "sg.gltf");
  ASSERT_EQ(m.materials.size(), 1u);
  EXPECT_EQ(m.materials[0].baseColor, glm::vec3(0.8f, 0.1f, 0.2f));
  // As a cut-out, its alpha is the diffuse factor's, not the metallic-roughness fallback's.
  b.json["materials"][0]["alphaMode"] = "MASK";
  b.json["materials"][0]["extensions"]["KHR_materials_pbrSpecularGlossiness"]["diffuseFactor"] = {
      0.8, 0.1, 0.2, 0.2};
  b.json["materials"][0]["pbrMetallicRoughness"] = {{"baseColorFactor", {1, 1, 1, 1}}};
  writeText(dir / "sg-mask.gltf", b.gltf());
  const Mesh cut = loadMesh(dir / "sg-mask.gltf");
  EXPECT_FLOAT_EQ(cut.materials[0].baseAlpha, 0.2f);
  EXPECT_TRUE(cut.cutAway(0, 0.3f, 0.3f));
  b.json["materials"][0]["extensions"]["KHR_materials_pbrSpecularGlossiness"]["diffuseFactor"] = {
      0.8, 0.1, 0.2, 1};
  b.json["materials"][0]["pbrMetallicRoughness"] = {{"baseColorFactor", {1, 1, 1, 0.2}}};
  writeText(dir / "sg-opaque.gltf", b.gltf());
  EXPECT_FALSE(loadMesh(dir / "sg-opaque.gltf").cutAway(0, 0.3f, 0.3f));
}

TEST(Gltf, JpegTexturesAreDecodedToo) {
  TempDir dir;
  Image img(16, 16, 3, {"R", "G", "B"});
  std::fill(img.pixels.begin(), img.pixels.end(), 0.5f);
  img.colorSpace = "sRGB";
  ingest::writeImage(dir / "grey.jpg", img);
  const std::vector<uint8_t> jpeg = readBytes(dir / "grey.jpg");
  GltfBuilder b = texturedPair(json::object());
  const int view = b.view(jpeg.data(), jpeg.size());
  b.json["images"][0] = {{"bufferView", view}, {"mimeType", "image/jpeg"}};
  writeBytes(dir / "jpeg.glb", b.glb());
  const Mesh m = loadMesh(dir / "jpeg.glb");
  EXPECT_TRUE(m.warnings.empty()) << m.warnings[0];
  ASSERT_EQ(m.textures.size(), 1u);
  const uint32_t first = m.positions[m.indices[0]].x < 1.5f ? 0u : 1u;
  // Mid grey through JPEG: within two 8-bit steps.
  const glm::vec3 albedo = m.albedoAt(first, 0.3f, 0.3f);
  EXPECT_NEAR(albedo.y, 128.0f / 255.0f, 2.0f / 255.0f);
}

// A texture's EXIF orientation is not applied: UVs are laid on the pixels as stored, and Blender
// and glTF viewers ignore the tag (a phone photo used as a label was turned a quarter).
TEST(Gltf, ATexturesExifOrientationIsNotApplied) {
  TempDir dir;
  Image img(16, 16, 3, {"R", "G", "B"});
  for (int y = 0; y < 16; ++y)
    for (int x = 0; x < 16; ++x) {
      float* p = img.at(x, y);
      p[0] = (y < 8) == (x < 8) ? 1.0f : 0.0f;  // red top left and bottom right
      p[1] = 0.0f;
      p[2] = (y < 8) == (x < 8) ? 0.0f : 1.0f;
    }
  img.colorSpace = "sRGB";
  ingest::WriteOptions options;
  options.jpegQuality = 100;
  options.attributes.push_back({"Orientation", 6});
  ingest::writeImage(dir / "label.jpg", img, options);
  // As a photo, the file is turned upright: its top left is then blue.
  const Image upright = ingest::readImage(dir / "label.jpg").image;
  ASSERT_GT(upright.at(2, 2)[2], 0.8f) << "the file carries orientation 6";
  writeText(dir / "label.gltf", texturedPair({{"uri", "label.jpg"}}).gltf());
  const Mesh m = loadMesh(dir / "label.gltf");
  const uint32_t first = m.positions[m.indices[0]].x < 1.5f ? 0u : 1u;
  const glm::vec3 topLeft = m.albedoAt(first, 0, 0);  // uv (0.25, 0.25): the stored top left
  EXPECT_GT(topLeft.x, 0.4f);                         // red (times the base colour factor's 0.5)
  EXPECT_LT(topLeft.z, 0.1f);
}

// Every material renders diffuse; what a material asks for beyond its base colour is said once,
// with counts (a glass, an emitter and a metal silently became clay).
TEST(Gltf, WhatMaterialsAskForBeyondTheirBaseColourIsSaid) {
  TempDir dir;
  GltfBuilder b = texturedPair(json::object());
  b.json["images"] = json::array();
  b.json["textures"] = json::array();
  b.json["materials"] = json::array(
      {{{"name", "chrome"},
        {"pbrMetallicRoughness", {{"metallicFactor", 1.0}, {"roughnessFactor", 0.1}}},
        {"normalTexture", {{"index", 0}}},
        {"emissiveFactor", {1.0, 0.5, 0.0}}},
       {{"name", "glass"},
        {"extensions", {{"KHR_materials_transmission", {{"transmissionFactor", 1.0}}}}}}});
  b.json["textures"] = json::array({{{"source", 0}}});
  b.json["images"] = json::array({{{"uri", "none.png"}}});
  b.json["meshes"][0]["primitives"][0].erase("attributes");
  b.json["meshes"][0]["primitives"][0]["attributes"] =
      b.json["meshes"][0]["primitives"][1]["attributes"];
  b.json["meshes"][0]["primitives"][1]["material"] = 1;
  writeText(dir / "materials.gltf", b.gltf());
  const Mesh m = loadMesh(dir / "materials.gltf");
  const std::string expected =
      "every material renders as a diffuse surface of its base colour; not rendered: "
      "KHR_materials_transmission (1 material), emission (1 material), metal (1 material), normal "
      "maps (1 material)";
  EXPECT_NE(std::find(m.warnings.begin(), m.warnings.end(), expected), m.warnings.end())
      << ::testing::PrintToString(m.warnings);
  // A plain material (glTF's defaults: metallic 1, rough 1) says nothing.
  writeText(dir / "plain.gltf", texturedPair({{"uri", "none.png"}}).gltf());
  for (const std::string& w : loadMesh(dir / "plain.gltf").warnings)
    EXPECT_EQ(w.find("not rendered"), std::string::npos) << w;
}

TEST(Gltf, ABinaryGlbWithItsTextureInABufferView) {
  TempDir dir;
  const std::vector<uint8_t> png = quadrantPng(dir);
  GltfBuilder b = texturedPair(json::object());
  const int view = b.view(png.data(), png.size());
  b.json["images"][0] = {{"bufferView", view}, {"mimeType", "image/png"}};
  writeBytes(dir / "pair.glb", b.glb());
  expectPaintedPair(loadMesh(dir / "pair.glb"));
  // The same as a .gltf with the image beside it, its name percent-encoded.
  std::filesystem::copy_file(dir / "quadrants.png", dir / "my texture.png");
  writeText(dir / "pair.gltf", texturedPair({{"uri", "my%20texture.png"}}).gltf());
  const Mesh external = loadMesh(dir / "pair.gltf");
  expectPaintedPair(external);
  EXPECT_EQ(external.textures[0].file.filename(), "my texture.png");
}

// glTF's URIs are RFC 3986 references: '+' in a file name is itself (tinygltf 2.7 read it as a
// space, as in a URL's query, and found no buffer), "%2B" too, and "%20" a space.
TEST(Gltf, BufferFilesNamedWithPlusSigns) {
  TempDir dir;
  const std::vector<uint8_t> png = quadrantPng(dir);
  for (const auto& [uri, name] :
       std::vector<std::pair<std::string, std::string>>{{"pair+v2.bin", "pair+v2.bin"},
                                                        {"pair%2Bv3 .bin", "pair+v3 .bin"},
                                                        {"a+b%20c.bin", "a+b c.bin"}}) {
    GltfBuilder b = texturedPair(json::object());
    const int view = b.view(png.data(), png.size());
    b.json["images"][0] = {{"bufferView", view}, {"mimeType", "image/png"}};
    const std::vector<uint8_t>& bytes = b.bufferBytes();
    writeBytes(dir / name, bytes);
    nlohmann::json j = nlohmann::json::parse(b.gltf());
    j["buffers"][0]["uri"] = uri;
    writeText(dir / "plus.gltf", j.dump(1));
    const Mesh m = loadMesh(dir / "plus.gltf");
    expectPaintedPair(m);
    ASSERT_EQ(m.otherFiles.size(), 1u) << uri;
    EXPECT_EQ(m.otherFiles[0].filename(), name);
    // The same buffer in a .glb's JSON, as a file beside it (a .glb's first buffer may be one).
    std::vector<uint8_t> glb = b.glb();
    uint32_t jsonLength = 0;
    std::memcpy(&jsonLength, glb.data() + 12, 4);
    nlohmann::json inGlb =
        nlohmann::json::parse(std::string(glb.begin() + 20, glb.begin() + 20 + jsonLength));
    inGlb["buffers"][0]["uri"] = uri;
    std::string text = inGlb.dump();
    while (text.size() % 4) text += ' ';
    // The header, then the JSON chunk alone.
    const uint32_t words[5] = {0x46546C67u, 2u, uint32_t(20 + text.size()), uint32_t(text.size()),
                               0x4E4F534Au};
    std::vector<uint8_t> out(20 + text.size());
    std::memcpy(out.data(), words, 20);
    std::memcpy(out.data() + 20, text.data(), text.size());
    writeBytes(dir / "plus.glb", out);
    expectPaintedPair(loadMesh(dir / "plus.glb"));
  }
}

TEST(Gltf, TextureTransformAndWrapModes) {
  TempDir dir;
  const std::string png = "data:image/png;base64," + base64(quadrantPng(dir));
  GltfBuilder b = texturedPair({{"uri", png}});
  // An offset of half the texture to the right: red's place shows green.
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
      {"KHR_texture_transform", {{"offset", {0.5, 0}}}}};
  writeText(dir / "offset.gltf", b.gltf());
  Mesh m = loadMesh(dir / "offset.gltf");
  const uint32_t first = m.positions[m.indices[0]].x < 1.5f ? 0u : 1u;
  EXPECT_LT(glm::length(m.albedoAt(first, 0, 0) - glm::vec3(0, 1, 0)), 1e-6f);
  // A quarter turn alone: uv -> (v, -u) in glTF's v-down texture space, as Blender, Babylon and
  // three.js turn it and the extension's sample model checks (its GLSL listing turns the other
  // way, KhronosGroup/glTF#1563): red's corner shows blue, green's red, blue's white.
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
      {"KHR_texture_transform", {{"rotation", 1.5707963267948966}}}};
  writeText(dir / "turned.gltf", b.gltf());
  m = loadMesh(dir / "turned.gltf");
  EXPECT_LT(glm::length(m.albedoAt(first, 0, 0) - glm::vec3(0, 0, 1)), 1e-5f);
  EXPECT_LT(glm::length(m.albedoAt(first, 1, 0) - glm::vec3(0.5f, 0, 0)), 1e-5f);
  EXPECT_LT(glm::length(m.albedoAt(first, 0, 1) - glm::vec3(0.5f, 1, 1)), 1e-5f);
  // Halfway between red's and green's texel centres: blended, or red's own with magFilter
  // NEAREST (9728) below the centre line of the texture (Blender's "Closest").
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"].erase("extensions");
  writeText(dir / "linear.gltf", b.gltf());
  m = loadMesh(dir / "linear.gltf");
  EXPECT_LT(glm::length(m.albedoAt(first, 0.45f, 0) - glm::vec3(0.5f * 0.55f, 0.45f, 0)), 1e-5f);
  b.json["samplers"] = json::array({{{"magFilter", 9728}}});
  b.json["textures"][0]["sampler"] = 0;
  writeText(dir / "nearest.gltf", b.gltf());
  m = loadMesh(dir / "nearest.gltf");
  EXPECT_LT(glm::length(m.albedoAt(first, 0.45f, 0) - glm::vec3(0.5f, 0, 0)), 1e-6f);
  EXPECT_LT(glm::length(m.albedoAt(first, 0.55f, 0) - glm::vec3(0, 1, 0)), 1e-6f);
  b.json.erase("samplers");
  b.json["textures"][0].erase("sampler");
  // u = 1.25: repeat wraps to red's column, clamp stays at green's.
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
      {"KHR_texture_transform", {{"offset", {1.0, 0}}}}};
  for (const auto& [wrap, expected] :
       {std::pair{10497, glm::vec3(0.5f, 0, 0)}, std::pair{33071, glm::vec3(0, 1, 0)},
        std::pair{33648, glm::vec3(0, 1, 0)}}) {
    b.json["samplers"] = json::array({{{"wrapS", wrap}, {"wrapT", wrap}}});
    b.json["textures"][0]["sampler"] = 0;
    writeText(dir / "wrap.gltf", b.gltf());
    m = loadMesh(dir / "wrap.gltf");
    EXPECT_LT(glm::length(m.albedoAt(first, 0, 0) - expected), 1e-6f) << "wrap " << wrap;
  }
}

TEST(Gltf, SparseAndQuantisedAccessors) {
  TempDir dir;
  GltfBuilder b;
  // A quad whose corner 3 is moved to (-1, 2, 0) by a sparse substitution.
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0});
  const std::vector<uint16_t> which = {3};
  const std::vector<float> value = {-1, 2, 0};
  b.json["accessors"][size_t(pos)]["sparse"] = {
      {"count", 1},
      {"indices", {{"bufferView", b.view(which.data(), 2)}, {"componentType", kU16}}},
      {"values", {{"bufferView", b.view(value.data(), 12)}}}};
  const int idx = b.accessor(std::vector<uint8_t>{0, 1, 2, 0, 2, 3}, kU8, "SCALAR", 6);
  // A second primitive whose positions have no buffer view at all: zeros, then sparse values.
  const std::vector<uint8_t> at = {1, 2};
  const std::vector<float> moved = {0, 0, 3, 0, 3, 3};
  b.json["accessors"].push_back(
      {{"componentType", kFloat},
       {"count", 3},
       {"type", "VEC3"},
       {"sparse",
        {{"count", 2},
         {"indices", {{"bufferView", b.view(at.data(), 2)}, {"componentType", kU8}}},
         {"values", {{"bufferView", b.view(moved.data(), 24)}}}}}});
  const int zeros = int(b.json["accessors"].size()) - 1;
  // A third, quantised as KHR_mesh_quantization allows: normalised unsigned shorts.
  const int quantised = b.accessor(
      std::vector<uint16_t>{0, 0, 65535, 65535, 0, 65535, 0, 65535, 65535}, kU16, "VEC3", 3, true);
  const int m = b.mesh({{"attributes", {{"POSITION", pos}}}, {"indices", idx}});
  b.json["meshes"][size_t(m)]["primitives"].push_back({{"attributes", {{"POSITION", zeros}}}});
  b.json["meshes"][size_t(m)]["primitives"].push_back({{"attributes", {{"POSITION", quantised}}}});
  b.json["extensionsUsed"] = {"KHR_mesh_quantization"};
  b.json["extensionsRequired"] = {"KHR_mesh_quantization"};
  b.scene({b.node({{"mesh", m}})});
  writeText(dir / "sparse.gltf", b.gltf());
  const Mesh mesh = loadMesh(dir / "sparse.gltf");
  EXPECT_EQ(mesh.triangleCount(), 4u) << ::testing::PrintToString(mesh.warnings);
  EXPECT_TRUE(hasPosition(mesh, {-1, 2, 0}));
  EXPECT_FALSE(hasPosition(mesh, {0, 1, 0})) << "replaced by the sparse value";
  EXPECT_TRUE(hasPosition(mesh, {0, 0, 3}));
  EXPECT_TRUE(hasPosition(mesh, {0, 3, 3}));
  EXPECT_TRUE(hasPosition(mesh, {1, 0, 1}));
  EXPECT_TRUE(hasPosition(mesh, {0, 1, 1}));

  // A sparse index beyond the accessor skips its primitive, naming it.
  b.json["accessors"][size_t(zeros)]["count"] = 2;
  writeText(dir / "sparse.gltf", b.gltf());
  const Mesh skipped = loadMesh(dir / "sparse.gltf");
  ASSERT_EQ(skipped.warnings.size(), 1u);
  EXPECT_EQ(skipped.warnings[0],
            "skipped mesh 0 primitive 1: POSITION (accessor 2): sparse index 2 is beyond its 2 "
            "elements");
}

TEST(Gltf, BadIndicesNonFiniteCoordinatesAndDuplicatesAreDroppedWithCounts) {
  TempDir dir;
  GltfBuilder b;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, nan, 0, 0});
  // Good, good, a corner beyond the 5 vertices, a corner at NaN, a repeat, one with no area.
  const int idx =
      b.accessor(std::vector<uint16_t>{0, 1, 2, 0, 2, 3, 0, 2, 9, 0, 1, 4, 2, 1, 0, 0, 0, 1}, kU16,
                 "SCALAR", 18);
  b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"indices", idx}})}})});
  writeText(dir / "bad.gltf", b.gltf());
  const Mesh m = loadMesh(dir / "bad.gltf");
  EXPECT_EQ(m.triangleCount(), 2u);
  EXPECT_EQ(m.positions.size(), 4u) << "the NaN vertex is gone, so bounds stay finite";
  const std::vector<std::string> expected = {
      "dropped 1 of 6 triangles whose indices refer to vertices the primitive does not have",
      "dropped 1 of 5 triangles with a corner whose coordinates are not finite numbers (NaN, "
      "infinite, or beyond single precision's 3.4e38)",
      "dropped 1 of 5 triangles with no area", "dropped 1 of 5 triangles that repeat another one"};
  EXPECT_EQ(m.warnings, expected);
}

// A triangle list of 8 vertices and no indices (as "indices": -1 reads): two triangles, and the
// two vertices left over are said, not dropped in silence.
TEST(Gltf, VerticesLeftOverFromATriangleListAreSaid) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0, 2, 0, 0, 3, 0, 0, 2, 1, 0, 5, 5, 5, 6, 6, 6});
  b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"indices", -1}})}})});
  writeText(dir / "ragged.gltf", b.gltf());
  const Mesh m = loadMesh(dir / "ragged.gltf");
  EXPECT_EQ(m.triangleCount(), 2u);
  const std::vector<std::string> expected = {
      "1 triangle list has a number of vertices (indices, or vertices where it has none) that is "
      "not a multiple of 3: the 2 vertices left over at the end ignored"};
  EXPECT_EQ(m.warnings, expected);
}

TEST(Gltf, BrokenFilesAreErrorsNamingWhatIsWrong) {
  TempDir dir;
  writeText(dir / "text.gltf", "this is not JSON");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "text.gltf"), "mesh: cannot parse glTF: ");
  writeText(dir / "empty.glb", "");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "empty.glb"), "mesh: cannot parse glTF: ");
  writeText(dir / "nomesh.gltf", R"({"asset": {"version": "2.0"}, "scenes": [{"nodes": []}]})");
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "nomesh.gltf"),
                       "nothing renderable: the scene has no meshes (");

  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}})}})});
  // Missing buffer file.
  json external = json::parse(b.gltf());
  external["buffers"][0]["uri"] = "geometry.bin";
  writeText(dir / "external.gltf", external.dump());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "external.gltf"), "cannot parse glTF: ");
  // Not taken from the working directory either, where another export's file of that name was
  // read without a word (tinygltf looks there after the glTF's folder).
  std::filesystem::create_directories(dir / "elsewhere");
  writeBytes(dir / "elsewhere" / "geometry.bin", b.bufferBytes());
  const std::filesystem::path before = std::filesystem::current_path();
  std::filesystem::current_path(dir / "elsewhere");
  std::string fromHere;
  try {
    loadMesh("../external.gltf");
  } catch (const Error& e) {
    fromHere = e.describe();
  }
  std::filesystem::current_path(before);
  EXPECT_NE(fromHere.find("File not found : geometry.bin"), std::string::npos) << fromHere;
  // Beside it, named from the working directory with a leading "./": found.
  writeBytes(dir / "geometry.bin", b.bufferBytes());
  std::filesystem::current_path(dir.path().parent_path());
  size_t found = 0;
  try {
    found = loadMesh("./" + dir.path().filename().string() + "/external.gltf").triangleCount();
  } catch (const Error& e) {
    ADD_FAILURE() << e.describe();
  }
  std::filesystem::current_path(before);
  EXPECT_EQ(found, 1u);
  std::filesystem::remove(dir / "geometry.bin");
  // A data URI that does not decode to the buffer's length: the message quotes the start of the
  // URI, not its 40,000 characters.
  json longUri = json::parse(b.gltf());
  longUri["buffers"][0]["uri"] =
      "data:application/octet-stream;base64," + base64(std::vector<uint8_t>(30000, 7));
  writeText(dir / "long.gltf", longUri.dump());
  try {
    loadMesh(dir / "long.gltf");
    ADD_FAILURE() << "a data URI of the wrong length was read";
  } catch (const Error& e) {
    const std::string said = e.describe();
    EXPECT_NE(said.find("Failed to decode 'uri' : data:application/octet-stream;base64,"),
              std::string::npos)
        << said.substr(0, 400);
    EXPECT_NE(said.find("... (40"), std::string::npos) << said.substr(0, 400);
    EXPECT_LT(said.size(), 600u) << said.substr(0, 400);
  }
  // An accessor that reads past its buffer view.
  b.json["accessors"][size_t(pos)]["count"] = 4;
  writeText(dir / "short.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "short.gltf"),
                       "nothing renderable: no triangles in 1 primitive (mesh 0 primitive 0: "
                       "POSITION (accessor 0) reads past the end of buffer view 0 (4 elements of "
                       "12 bytes from byte 0 of 36)) (");
  b.json["accessors"][size_t(pos)]["count"] = 3;
  // A cycle in the hierarchy.
  b.json["nodes"][0]["children"] = {0};
  writeText(dir / "cycle.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "cycle.gltf"), "node 0 appears twice in the node hierarchy");
  b.json["nodes"][0].erase("children");
  // A malformed transform.
  b.json["nodes"][0]["translation"] = {0, 1};
  writeText(dir / "short.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "short.gltf"), "node 0: translation has 2 numbers, not 3");
  b.json["nodes"][0].erase("translation");
  // A glTF of another major version (glTF 2.0 §3.2: not to be read as 2.x).
  b.json["asset"]["version"] = "3.0";
  writeText(dir / "future.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "future.gltf"),
                       "glTF version 3.0: this reader reads glTF 2.x (asset.version)");
  b.json["asset"]["version"] = "2.1";
  writeText(dir / "minor.gltf", b.gltf());
  EXPECT_EQ(loadMesh(dir / "minor.gltf").triangleCount(), 1u);
  b.json["asset"]["version"] = "2.0";
  // A required extension compose cannot honour.
  b.json["extensionsUsed"] = {"KHR_draco_mesh_compression"};
  b.json["extensionsRequired"] = {"KHR_draco_mesh_compression"};
  writeText(dir / "draco.gltf", b.gltf());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "draco.gltf"),
                       "requires the glTF extension KHR_draco_mesh_compression, which compose "
                       "does not support (compressed geometry: export it without compression)");
  // The same when the file cannot be read without it: gltfpack's meshopt buffer has no uri
  // (tinygltf failed on it first, and its message was given).
  b.json["extensionsUsed"] = {"EXT_meshopt_compression"};
  b.json["extensionsRequired"] = {"EXT_meshopt_compression"};
  json meshopt = json::parse(b.gltf());
  meshopt["buffers"].push_back({{"byteLength", 64}});
  writeText(dir / "meshopt.gltf", meshopt.dump());
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "meshopt.gltf"),
                       "requires the glTF extension EXT_meshopt_compression, which compose does "
                       "not support (compressed geometry: export it without compression)");
  b.json.erase("extensionsUsed");
  b.json.erase("extensionsRequired");

  // A .glb whose BIN chunk says it is longer than what the file holds after its header: tinygltf
  // read up to 8 bytes past the end (AddressSanitizer: heap-buffer-overflow).
  std::vector<uint8_t> glb = b.glb();
  writeBytes(dir / "good.glb", glb);
  EXPECT_EQ(loadMesh(dir / "good.glb").triangleCount(), 1u);
  uint32_t jsonLength = 0, binLength = 0;
  std::memcpy(&jsonLength, glb.data() + 12, 4);
  std::memcpy(&binLength, glb.data() + 20 + jsonLength, 4);
  binLength += 8;
  std::memcpy(glb.data() + 20 + jsonLength, &binLength, 4);
  writeBytes(dir / "long.glb", glb);
  COMPOSE_EXPECT_ERROR(loadMesh(dir / "long.glb"),
                       "cannot parse glTF: its BIN chunk holds 44 bytes, more than the 36 the "
                       "file's length leaves it (a truncated or damaged .glb)");
}

// A primitive whose material has a base-colour texture but which has no texture coordinates
// renders the base colour factor alone, as the warning says (it took the texel at (0, 0)).
TEST(Gltf, APrimitiveWithoutTheTextureCoordinatesItsTextureNeedsRendersTheFactor) {
  TempDir dir;
  const std::string png = "data:image/png;base64," + base64(quadrantPng(dir));
  json j = json::parse(texturedPair({{"uri", png}}).gltf());
  j["meshes"][0]["primitives"][0]["attributes"].erase("TEXCOORD_0");
  writeText(dir / "bare.gltf", j.dump());
  const Mesh m = loadMesh(dir / "bare.gltf");
  const std::vector<std::string> said = {
      "1 primitive has a base-colour texture but not its texture coordinates: rendered with the "
      "base colour factor"};
  EXPECT_EQ(m.warnings, said);
  ASSERT_EQ(m.triangleCount(), 2u);
  const uint32_t first = m.positions[m.indices[0]].x < 1.5f ? 0u : 1u;
  for (const auto& [u, v] : {std::pair{0.0f, 0.0f}, {0.3f, 0.3f}, {1.0f, 0.0f}}) {
    EXPECT_EQ(m.albedoAt(first, u, v), glm::vec3(0.5f, 1, 1)) << u << ", " << v;
    EXPECT_EQ(m.albedoAt(first, u, v, glm::vec3(0.01f, 0, 0), glm::vec3(0, 0.01f, 0)),
              glm::vec3(0.5f, 1, 1))
        << "with a footprint, " << u << ", " << v;
  }
  EXPECT_EQ(m.albedoAt(1 - first, 0.3f, 0.3f), glm::vec3(0.2f, 0.4f, 0.6f));
}

TEST(Gltf, AnUnreadableTextureLeavesTheBaseColourWithAWarning) {
  TempDir dir;
  writeText(dir / "pair.gltf", texturedPair({{"uri", "missing.png"}}).gltf());
  const Mesh m = loadMesh(dir / "pair.gltf");
  ASSERT_EQ(m.warnings.size(), 1u);
  EXPECT_EQ(m.warnings[0], "the base-colour texture of material 'painted' (" +
                               (dir / "missing.png").string() +
                               ") cannot be read (file not found): the material renders with its "
                               "base colour factor");
  EXPECT_EQ(m.materials[0].texture, -1);
  const uint32_t first = m.positions[m.indices[0]].x < 1.5f ? 0u : 1u;
  EXPECT_EQ(m.albedoAt(first, 0.2f, 0.2f), glm::vec3(0.5f, 1, 1));
  // An embedded image that is not an image.
  writeText(dir / "junk.gltf",
            texturedPair({{"uri", "data:image/png;base64," + base64({1, 2, 3, 4, 5})}}).gltf());
  const Mesh junk = loadMesh(dir / "junk.gltf");
  ASSERT_EQ(junk.warnings.size(), 1u);
  EXPECT_NE(
      junk.warnings[0].find("(image 0, embedded, image/png) cannot be read (cannot read image"),
      std::string::npos)
      << junk.warnings[0];
}

TEST(Gltf, NormalsVertexColoursAndPrimitivesWithoutMaterial) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int nrm = b.vec3({0, 0, 2, 0, 0, 2, 0, 0, 2});  // not unit: normalised
  const int col = b.vec3({1, 0, 0, 0, 1, 0, 0, 0, 1});
  const int pos2 = b.vec3({0, 0, 1, 1, 0, 1, 0, 1, 1});
  b.json["materials"] =
      json::array({{{"pbrMetallicRoughness", {{"baseColorFactor", {1, 0, 0, 1}}}}}});
  const int m = b.mesh(
      {{"attributes", {{"POSITION", pos}, {"NORMAL", nrm}, {"COLOR_0", col}}}, {"material", 0}});
  b.json["meshes"][size_t(m)]["primitives"].push_back({{"attributes", {{"POSITION", pos2}}}});
  b.scene({b.node({{"mesh", m}})});
  writeText(dir / "colours.gltf", b.gltf());
  const Mesh mesh = loadMesh(dir / "colours.gltf");
  const std::vector<std::string> expected = {
      "some primitives have no material: rendered with the default albedo"};
  EXPECT_EQ(mesh.warnings, expected);
  ASSERT_EQ(mesh.materials.size(), 2u);
  EXPECT_EQ(mesh.materials[1].baseColor, glm::vec3(kDefaultAlbedo));
  // COLOR_0 multiplies the base colour (red x red, red x green); the primitive without it is
  // white there (the default grey material alone).
  ASSERT_EQ(mesh.colors.size(), mesh.positions.size());
  for (uint32_t t = 0; t < mesh.triangleCount(); ++t) {
    const glm::vec3 at0 = mesh.albedoAt(t, 0.0f, 0.0f);
    if (mesh.triangleMaterial[t] == 1) {
      EXPECT_EQ(at0, glm::vec3(kDefaultAlbedo));
      continue;
    }
    const glm::vec3 colour = mesh.colors[mesh.indices[3 * t]];
    EXPECT_EQ(at0, glm::vec3(1, 0, 0) * colour);
  }
  EXPECT_FALSE(mesh.normalsFromFile);
  EXPECT_NE(mesh.normalsSource.find("from the file for 3 of 6 vertices"), std::string::npos);
  for (const glm::vec3& n : mesh.normals) EXPECT_NEAR(n.z, 1.0f, 1e-6f);
}

// COLOR_0 as normalised unsigned bytes in RGBA (its alpha unused: no material reads it), with no
// material: the colours are the albedo (glTF's default material is white). Components that are
// not finite are clamped and counted.
TEST(Gltf, VertexColoursAsNormalisedBytesWithoutAMaterial) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int col = b.accessor(std::vector<uint8_t>{255, 0, 0, 10, 0, 51, 0, 255, 0, 0, 255, 128},
                             5121, "VEC4", 3, true);
  const int m = b.mesh({{"attributes", {{"POSITION", pos}, {"COLOR_0", col}}}});
  b.scene({b.node({{"mesh", m}})});
  writeText(dir / "bytes.gltf", b.gltf());
  const Mesh mesh = loadMesh(dir / "bytes.gltf");
  EXPECT_TRUE(mesh.warnings.empty()) << mesh.warnings[0];
  ASSERT_TRUE(mesh.hasMaterials());
  ASSERT_EQ(mesh.colors.size(), 3u);
  const glm::vec3 want[3] = {{1, 0, 0}, {0, 0.2f, 0}, {0, 0, 1}};
  for (int k = 0; k < 3; ++k) {
    const uint32_t v = mesh.indices[size_t(k)];
    const glm::vec3 p = mesh.positions[v];
    const int file = p.x > 0.5f ? 1 : p.y > 0.5f ? 2 : 0;
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(mesh.colors[v][c], want[file][c], 1e-6f);
  }
  const int nan = b.vec3({std::numeric_limits<float>::quiet_NaN(), 0, 0, 2, 0, 0, 0, 0, 1});
  GltfBuilder c = b;
  c.json["meshes"][size_t(m)]["primitives"][0]["attributes"]["COLOR_0"] = nan;
  writeText(dir / "nan.gltf", c.gltf());
  const Mesh clamped = loadMesh(dir / "nan.gltf");
  EXPECT_EQ(clamped.warnings,
            std::vector<std::string>{"2 COLOR_0 components outside 0..1 (or not finite) clamped"});
}

// COLOR_0's alpha multiplies the base colour's alpha, which MASK and BLEND materials read: alphas
// 0.2, 0.2, 1 at the corners of a triangle over (0, 0), (1, 0), (0, 1): 0.2 + 0.8 y.
TEST(Gltf, VertexAlphaMultipliesTheAlphaOfMaskAndBlendMaterials) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int col =
      b.accessor(std::vector<float>{1, 1, 1, 0.2f, 1, 1, 1, 0.2f, 1, 1, 1, 1}, 5126, "VEC4", 3);
  b.json["materials"] = json::array({{{"alphaMode", "MASK"}}});
  const int m = b.mesh({{"attributes", {{"POSITION", pos}, {"COLOR_0", col}}}, {"material", 0}});
  b.scene({b.node({{"mesh", m}})});
  writeText(dir / "mask.gltf", b.gltf());
  const Mesh mask = loadMesh(dir / "mask.gltf");
  EXPECT_TRUE(mask.warnings.empty()) << mask.warnings[0];
  ASSERT_EQ(mask.alphas.size(), mask.positions.size());
  // Which corner is which: by position.
  float u = 0.0f, v = 0.0f;  // barycentrics of (0, 0.5)
  const uint32_t* c = &mask.indices[0];
  for (int k = 1; k < 3; ++k)
    if (mask.positions[c[k]].y > 0.5f) (k == 1 ? u : v) = 0.5f;
  EXPECT_NEAR(mask.alphaAt(0, u, v), 0.6f, 1e-6f);
  EXPECT_FALSE(mask.cutAway(0, u, v)) << "0.6, above the cutoff";
  // Stood on what is kept: y >= 0.375 (alpha 0.5), found to a sixteenth of the triangle.
  glm::vec3 lo, hi;
  mask.keptBounds(lo, hi);
  EXPECT_GE(lo.y, 0.375f - 1e-5f);
  EXPECT_LE(lo.y, 0.375f + 1.0f / 16.0f + 1e-5f);
  // BLEND reads it too; an opaque material does not keep it.
  b.json["materials"][0]["alphaMode"] = "BLEND";
  writeText(dir / "blend.gltf", b.gltf());
  const Mesh blend = loadMesh(dir / "blend.gltf");
  ASSERT_TRUE(blend.materials[0].blend) << "vertex alpha below 1: semi-transparent";
  EXPECT_NEAR(blend.alphaAt(0, u, v), 0.6f, 1e-6f);
  b.json["materials"][0].erase("alphaMode");
  writeText(dir / "opaque.gltf", b.gltf());
  EXPECT_TRUE(loadMesh(dir / "opaque.gltf").alphas.empty());
}

// A coloured primitive without a material beside one with a material is coloured by its colours
// alone (glTF's default material is white; it had half of them, the grey default). Colours that
// cannot be read are left out with a warning; the primitive's triangles stay.
TEST(Gltf, ColouredPrimitivesWithoutAMaterialAndUnreadableColours) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int pos2 = b.vec3({0, 0, 1, 1, 0, 1, 0, 1, 1});
  const int pos3 = b.vec3({0, 0, 2, 1, 0, 2, 0, 1, 2});
  const int green = b.vec3({0, 1, 0, 0, 1, 0, 0, 1, 0});
  const int flat = b.vec2({1, 0, 1, 0, 1, 0});
  b.json["materials"] =
      json::array({{{"pbrMetallicRoughness", {{"baseColorFactor", {1, 0, 0, 1}}}}}});
  const int m = b.mesh({{"attributes", {{"POSITION", pos}}}, {"material", 0}});
  b.json["meshes"][size_t(m)]["primitives"].push_back(
      {{"attributes", {{"POSITION", pos2}, {"COLOR_0", green}}}});
  b.json["meshes"][size_t(m)]["primitives"].push_back(
      {{"attributes", {{"POSITION", pos3}, {"COLOR_0", flat}}}, {"material", 0}});
  b.scene({b.node({{"mesh", m}})});
  writeText(dir / "mixed.gltf", b.gltf());
  const Mesh mesh = loadMesh(dir / "mixed.gltf");
  ASSERT_EQ(mesh.triangleCount(), 3u) << "the primitive with unreadable colours keeps its triangle";
  ASSERT_EQ(mesh.warnings.size(), 1u);
  EXPECT_EQ(mesh.warnings[0].find("ignored the vertex colours of a primitive: COLOR_0"), 0u)
      << mesh.warnings[0];
  for (uint32_t t = 0; t < 3; ++t) {
    const float z = mesh.positions[mesh.indices[3 * t]].z;
    const glm::vec3 albedo = mesh.albedoAt(t, 0.2f, 0.3f);
    if (z > 0.5f && z < 1.5f) {
      EXPECT_EQ(albedo, glm::vec3(0, 1, 0)) << "coloured, no material";
    } else {
      EXPECT_EQ(albedo, glm::vec3(1, 0, 0)) << "the material, no colours (white there)";
    }
  }
}

// A primitive naming a material the file lacks is said once, as such: not also as a primitive
// without a material. When it is the only one, nothing has a material and --albedo applies.
TEST(Gltf, AMissingMaterialIsSaidOnce) {
  TempDir dir;
  GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  const int m = b.mesh({{"attributes", {{"POSITION", pos}}}, {"material", 3}});
  b.scene({b.node({{"mesh", m}})});
  writeText(dir / "missing.gltf", b.gltf());
  const Mesh alone = loadMesh(dir / "missing.gltf");
  EXPECT_EQ(alone.warnings, std::vector<std::string>{"1 primitive refers to a material the file "
                                                     "does not have: rendered with the default "
                                                     "albedo"});
  EXPECT_TRUE(alone.materials.empty());
  // Beside a primitive with a material: the default material for it, one warning still.
  b.json["materials"] =
      json::array({{{"pbrMetallicRoughness", {{"baseColorFactor", {1, 0, 0, 1}}}}}});
  const int pos2 = b.vec3({0, 0, 1, 1, 0, 1, 0, 1, 1});
  b.json["meshes"][size_t(m)]["primitives"].push_back(
      {{"attributes", {{"POSITION", pos2}}}, {"material", 0}});
  writeText(dir / "both.gltf", b.gltf());
  const Mesh both = loadMesh(dir / "both.gltf");
  EXPECT_EQ(both.warnings, alone.warnings);
  ASSERT_EQ(both.materials.size(), 2u);
  EXPECT_EQ(both.materials[0].baseColor, glm::vec3(kDefaultAlbedo));
  EXPECT_EQ(both.materials[1].baseColor, glm::vec3(1, 0, 0));
}

}  // namespace
}  // namespace compose::render
