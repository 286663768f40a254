// The white furnace at every map size: a constant environment of radiance 1 gives E = π for every
// normal, whatever the resolution of the map, for every lighting basis.
#include <cmath>
#include <numbers>

#include <glm/geometric.hpp>

#include "core/numbers.h"
#include "lighting/lighting.h"
#include "test_util.h"

namespace compose::lighting {
namespace {

struct FurnaceCase {
  std::string basis;
  std::string params;
  int width;
};

void PrintTo(const FurnaceCase& c, std::ostream* os) {
  *os << c.basis << (c.params.empty() ? "" : " " + c.params) << " at width " << c.width;
}

std::string caseName(const ::testing::TestParamInfo<FurnaceCase>& info) {
  std::string n =
      info.param.basis + "_" + info.param.params + "_" + std::to_string(info.param.width);
  for (char& c : n)
    if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
  return n;
}

class WhiteFurnaceAtEverySize : public ::testing::TestWithParam<FurnaceCase> {};

TEST_P(WhiteFurnaceAtEverySize, GivesPiForEveryNormal) {
  const FurnaceCase& c = GetParam();
  const Environment env = Environment::constant(glm::vec3(1.0f), c.width);
  auto basis = createLighting(c.basis, ParamSet::parse(c.params, "lighting"));
  basis->project(env);
  double worst = 0.0;
  // Random normals, plus the poles and the equator where grids and cells have their seams.
  std::vector<glm::vec3> normals = compose::testing::randomNormals(400, 7);
  for (const glm::vec3 n : {glm::vec3(0, 1, 0), glm::vec3(0, -1, 0), glm::vec3(1, 0, 0),
                            glm::vec3(0, 0, -1), glm::vec3(1, 0, 1), glm::vec3(-1, 1, 0)})
    normals.push_back(glm::normalize(n));
  for (const glm::vec3& n : normals) {
    const glm::vec3 e = basis->irradiance(n);
    for (int k = 0; k < 3; ++k) worst = std::max(worst, std::abs(double(e[k]) - kPi) / kPi);
  }
  // The bound: float accumulation keeps every basis well inside it.
  constexpr double kFurnaceRelative = 1e-4;
  EXPECT_LT(worst, kFurnaceRelative) << c.basis << " at " << c.width << "x" << c.width / 2;
  RecordProperty("worst_relative_error", std::to_string(worst));
  std::printf("%s %s width %d: worst relative error %.2e\n", c.basis.c_str(), c.params.c_str(),
              c.width, worst);
}

std::vector<FurnaceCase> allCases() {
  std::vector<FurnaceCase> out;
  for (int w = 4; w <= 8192; w *= 2) {
    out.push_back({"exact", "", w});
    out.push_back({"cheb-local", "", w});
    out.push_back({"cheb-local", "order=3", w});
    out.push_back({"cheb-latlong", "", w});
    out.push_back({"cheb-face", "", w});
    out.push_back({"sh", "", w});
    out.push_back({"sh", "order=6", w});
  }
  out.push_back({"exact", "", 2});
  out.push_back({"cheb-local", "", 2});
  return out;
}

INSTANTIATE_TEST_SUITE_P(AllBases, WhiteFurnaceAtEverySize, ::testing::ValuesIn(allCases()),
                         caseName);

}  // namespace
}  // namespace compose::lighting
