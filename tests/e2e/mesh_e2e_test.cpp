// The mesh formats through the compose command: a Blender glTF's material reaches the renderer
// in the working space (the albedo AOV), --albedo overrides it, and bad meshes and --crease
// values are errors with the documented exit statuses.
#include <sys/wait.h>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include <OpenImageIO/imageio.h>
#include <glm/vec3.hpp>

#include "command_util.h"
#include "pipeline/compose_job.h"
#include "render/gltf_builder.h"
#include "test_util.h"

namespace compose {
namespace {

namespace fs = std::filesystem;
using compose::testing::TempDir;
using compose::testing::writeText;

const fs::path kData = COMPOSE_TEST_DATA_DIR;

using RunResult = compose::testing::CommandResult;
using compose::testing::quote;
using compose::testing::slurp;

RunResult run(const std::string& args, const fs::path& scratch) {
  return compose::testing::runCompose(args, scratch);
}
// The mean albedo AOV over the object's fully covered pixels (part "object" of the EXR).
glm::vec3 meanAlbedo(const fs::path& exr, int& pixels) {
  pixels = 0;
  auto in = OIIO::ImageInput::open(exr.string());
  if (!in || !in->seek_subimage(1, 0)) {
    ADD_FAILURE() << "cannot open the object part of " << exr;
    return {};
  }
  const OIIO::ImageSpec spec = in->spec();
  std::vector<float> px(size_t(spec.width) * size_t(spec.height) * size_t(spec.nchannels));
  EXPECT_TRUE(in->read_image(1, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, px.data()));
  auto channel = [&](const std::string& name) {
    for (int c = 0; c < spec.nchannels; ++c)
      if (spec.channel_name(c) == name) return c;
    ADD_FAILURE() << "no channel " << name;
    return 0;
  };
  const int alpha = channel("object.A"), r = channel("albedo.R");
  glm::dvec3 sum(0.0);
  for (size_t i = 0; i < size_t(spec.width) * size_t(spec.height); ++i) {
    const float* p = px.data() + i * size_t(spec.nchannels);
    if (p[alpha] < 1.0f) continue;
    sum += glm::dvec3(p[r], p[r + 1], p[r + 2]);
    ++pixels;
  }
  return pixels ? glm::vec3(sum / double(pixels)) : glm::vec3(0.0f);
}

class MeshEndToEnd : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(pipeline::defaultEnvironment()))
      GTEST_FAIL() << "sample data missing: " << pipeline::defaultEnvironment();
    // A small grey plate.
    std::vector<float> px(160 * 120 * 3, 0.5f);
    auto out = OIIO::ImageOutput::create((dir_ / "plate.png").string());
    ASSERT_TRUE(out->open((dir_ / "plate.png").string(),
                          OIIO::ImageSpec(160, 120, 3, OIIO::TypeDesc::UINT8)));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
    out->close();
  }
  std::string args(const fs::path& object, const std::string& out) const {
    return "--plate " + quote((dir_ / "plate.png").string()) + " --object " +
           quote(object.string()) + " --samples 1 --no-cache --shadows off --out " +
           quote((dir_ / out).string());
  }
  TempDir dir_;
};

TEST_F(MeshEndToEnd, AGltfMaterialReachesTheRendererInTheWorkingSpace) {
  const RunResult r = run(args(kData / "suzanne_clay.glb", "clay"), dir_.path());
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("compose: note: object: 1 material, base colours read as 'Linear Rec.709"),
            std::string::npos)
      << r.err;
  // Blender's linear base colour (0.8, 0.35, 0.2) in ACEScg (the published Rec.709 → AP1
  // matrix), within half float's precision and the matrix's 7 digits.
  const glm::vec3 expected(0.6130974f * 0.8f + 0.3395231f * 0.35f + 0.0473795f * 0.2f,
                           0.0701937f * 0.8f + 0.9163539f * 0.35f + 0.0134524f * 0.2f,
                           0.0206156f * 0.8f + 0.1095698f * 0.35f + 0.8698146f * 0.2f);
  int pixels = 0;
  const glm::vec3 albedo = meanAlbedo(dir_ / "clay.exr", pixels);
  EXPECT_GT(pixels, 500);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(albedo[c], expected[c], 2e-3f) << "channel " << c;

  // --albedo replaces the material, and says so.
  const RunResult grey =
      run(args(kData / "suzanne_clay.glb", "grey") + " --albedo 0.3", dir_.path());
  ASSERT_EQ(grey.status, 0) << grey.err;
  EXPECT_NE(grey.err.find("object: --albedo replaces the materials of the mesh"), std::string::npos)
      << grey.err;
  const glm::vec3 overridden = meanAlbedo(dir_ / "grey.exr", pixels);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(overridden[c], 0.3f, 1e-3f) << "channel " << c;
}

TEST_F(MeshEndToEnd, BadMeshesAndCreaseAnglesAreErrors) {
  writeText(dir_ / "broken.gltf", "{\"asset\": {\"version\": \"2.0\"}, \"meshes\": [");
  const RunResult broken = run(args(dir_ / "broken.gltf", "b"), dir_.path());
  EXPECT_EQ(broken.status, 1);
  EXPECT_NE(broken.err.find("compose: error: mesh: cannot parse glTF"), std::string::npos)
      << broken.err;
  EXPECT_NE(broken.err.find("broken.gltf"), std::string::npos) << broken.err;
  EXPECT_FALSE(fs::exists(dir_ / "b.exr"));
  EXPECT_FALSE(fs::exists(dir_ / "b.jpg"));
  for (const char* crease : {"-1", "181", "nan"}) {
    const RunResult r =
        run(args("/no/such/mesh.glb", "c") + " --crease " + std::string(crease), dir_.path());
    EXPECT_EQ(r.status, 2) << crease << "\n" << r.err;
    EXPECT_NE(r.err.find("--crease"), std::string::npos) << crease << "\n" << r.err;
    EXPECT_EQ(r.err.find("file not found"), std::string::npos) << r.err;
  }
  // A MASK material whose alpha is below its cutoff everywhere: no placement shows it, and the
  // error says why (it advised a larger --scale).
  compose::testing::GltfBuilder b;
  const int pos = b.vec3({0, 0, 0, 1, 0, 0, 0, 1, 0});
  b.json["materials"] = {{{"name", "leaf"},
                          {"alphaMode", "MASK"},
                          {"pbrMetallicRoughness", {{"baseColorFactor", {1, 1, 1, 0.3}}}}}};
  b.scene({b.node({{"mesh", b.mesh({{"attributes", {{"POSITION", pos}}}, {"material", 0}})}})});
  writeText(dir_ / "cut.gltf", b.gltf());
  const RunResult cut = run(args(dir_ / "cut.gltf", "cut"), dir_.path());
  EXPECT_EQ(cut.status, 1) << cut.err;
  EXPECT_NE(cut.err.find("the object's see-through materials take every surface of it away"),
            std::string::npos)
      << cut.err;
  EXPECT_NE(cut.err.find("'leaf' (MASK, alpha 0.3, cutoff 0.5)"), std::string::npos) << cut.err;
  b.json["materials"][0]["alphaMode"] = "BLEND";
  b.json["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = {1, 1, 1, 0};
  writeText(dir_ / "clear.gltf", b.gltf());
  const RunResult clear = run(args(dir_ / "clear.gltf", "clear"), dir_.path());
  EXPECT_EQ(clear.status, 1) << clear.err;
  EXPECT_NE(clear.err.find("'leaf' (BLEND, alpha 0)"), std::string::npos) << clear.err;
  EXPECT_FALSE(fs::exists(dir_ / "cut.exr"));
}

}  // namespace
}  // namespace compose
