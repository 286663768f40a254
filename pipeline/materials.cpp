#include "pipeline/materials.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <optional>

#include "color/color.h"
#include "core/error.h"

namespace compose::pipeline {

namespace {

// The matrix that takes `from` to `to` when the config converts between them by one (linear
// spaces), found by converting the unit colours and checked on a probe.
std::optional<glm::mat3> conversionMatrix(const color::ColorConfig& colors, const std::string& from,
                                          const std::string& to) {
  Image probe(4, 1, 3, {"R", "G", "B"});
  probe.pixels = {1.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.25f, 0.8f, 0.5f};
  probe.colorSpace = from;
  colors.convert(probe, to);
  glm::mat3 m;
  for (int c = 0; c < 3; ++c)
    m[c] = glm::vec3(probe.at(c, 0)[0], probe.at(c, 0)[1], probe.at(c, 0)[2]);
  const glm::vec3 expected = m * glm::vec3(0.25f, 0.8f, 0.5f);
  for (int k = 0; k < 3; ++k) {
    const float got = probe.at(3, 0)[k];
    if (!std::isfinite(got) || !(std::abs(got - expected[k]) <= 1e-4f * (1.0f + std::abs(got))))
      return std::nullopt;
  }
  return m;
}

// The colour space a texture's values are in as stored: glTF's base colour textures are sRGB;
// others as their files say, else as the config's rules read them.
std::string textureSpace(const color::ColorConfig& colors, const render::Texture& texture) {
  if (texture.srgbByFormat) {
    const std::string s =
        colors.has("sRGB") ? colors.resolve("sRGB", "a glTF texture") : colors.srgbEncodedSpace();
    return s.empty() ? colors.inputSpaceFor(texture.file, "") : s;
  }
  return colors.inputSpaceFor(texture.file, texture.image.colorSpace);
}

}  // namespace

std::string materialsToWorkingSpace(render::Mesh& mesh, const color::ColorConfig& colors) {
  if (!mesh.hasMaterials()) return {};
  const std::string working = colors.workingSpace();

  // The space the albedo's product is taken in (render::Mesh::albedoToWorking): the base
  // colours' own, when the config has it and converts it to the working space by a matrix. The
  // textures are brought to it, and the product to the working space as it is shaded.
  std::string productSpace;
  if (colors.has(mesh.colorSpace))
    productSpace = colors.resolve(mesh.colorSpace, "the object's base colours");
  else if (mesh.colorSpace == "lin_rec709")
    productSpace = colors.spaceWithChromaticities(color::kRec709Chromaticities);
  // Only where every texture has the product space's primaries (glTF's base colour textures,
  // whose product glTF defines in linear Rec.709; an OBJ's sRGB PNG): another texture may hold
  // colours beyond its gamut (a phone's Display P3 JPEG as an OBJ's map_Kd), which the clamp to
  // an albedo's 0..1 in that space would clip; converted on its own to the wider working space,
  // it keeps them.
  std::vector<std::string> spaces(mesh.textures.size());
  for (size_t t = 0; t < mesh.textures.size(); ++t) {
    const render::Texture& texture = mesh.textures[t];
    spaces[t] = texture.converted ? texture.image.colorSpace : textureSpace(colors, texture);
  }
  const bool texturesInGamut =
      !productSpace.empty() && std::all_of(spaces.begin(), spaces.end(), [&](const std::string& s) {
        return s == productSpace || colors.samePrimaries(s, productSpace);
      });
  const std::optional<glm::mat3> productToWorking =
      productSpace.empty() || productSpace == working || !texturesInGamut
          ? std::nullopt
          : conversionMatrix(colors, productSpace, working);
  if (productToWorking) {
    mesh.albedoToWorking = *productToWorking;
    mesh.convertsAlbedo = true;
  }

  // Base colours, as a row of pixels.
  Image base(int(mesh.materials.size()), 1, 3, {"R", "G", "B"});
  for (size_t i = 0; i < mesh.materials.size(); ++i) {
    const glm::vec3& c = mesh.materials[i].baseColor;
    std::copy_n(&c.x, 3, base.pixels.data() + 3 * i);
  }
  // Base colours and vertex colours are linear in the mesh's colour space.
  std::string baseRead;
  auto toWorking = [&](Image& row) {
    if (colors.has(mesh.colorSpace)) {
      row.colorSpace = colors.resolve(mesh.colorSpace, "the object's base colours");
      baseRead = "'" + row.colorSpace + "'";
      colors.convert(row, working);
    } else if (mesh.colorSpace == "lin_rec709" && colors.chromaticities(working)) {
      colors.convertFromChromaticities(row, color::kRec709Chromaticities, working);
      baseRead = "linear Rec.709 (by its primaries)";
    } else {
      baseRead = "the working space's own (the config knows neither '" + mesh.colorSpace +
                 "' nor the working space's primaries)";
    }
  };
  if (productToWorking) {
    baseRead =
        "'" + productSpace + "', the albedo multiplied there (factor x texture x vertex colour)";
  } else {
    toWorking(base);
    for (size_t i = 0; i < mesh.materials.size(); ++i) {
      const float* p = base.pixels.data() + 3 * i;
      mesh.materials[i].baseColor = glm::vec3(p[0], p[1], p[2]);
    }
    if (!mesh.colors.empty()) {
      Image row(int(mesh.colors.size()), 1, 3, {"R", "G", "B"});
      std::copy_n(&mesh.colors[0].x, 3 * mesh.colors.size(), row.pixels.data());
      toWorking(row);
      std::copy_n(row.pixels.data(), 3 * mesh.colors.size(), &mesh.colors[0].x);
    }
  }
  mesh.colorSpace = productToWorking ? productSpace : working;
  const std::string textureTarget = productToWorking ? productSpace : working;

  std::map<std::string, int> textureSpaces;
  size_t clampedTexels = 0;
  for (size_t t = 0; t < mesh.textures.size(); ++t) {
    render::Texture& texture = mesh.textures[t];
    if (texture.converted) {
      ++textureSpaces["'" + texture.image.colorSpace + "'"];
      continue;
    }
    texture.image.colorSpace = spaces[t];
    ++textureSpaces["'" + texture.image.colorSpace + "'"];
    colors.convert(texture.image, textureTarget);
    // Albedos, 0..1 as base colours are: a float texture may hold anything.
    for (float& v : texture.image.pixels) {
      const float kept = std::isnan(v) ? 0.0f : std::clamp(v, 0.0f, 1.0f);
      if (!(std::abs(kept - v) <= 1e-4f)) ++clampedTexels;
      v = kept;
    }
    // Filtered in linear light; for a cut-out, weighted by what it keeps.
    std::optional<float> keptFrom;
    for (const render::Material& m : mesh.materials) {
      if (m.texture != int(t) || !m.cutOut()) continue;
      keptFrom = m.blend ? -1.0f : (keptFrom && *keptFrom < 0.0f ? *keptFrom : m.alphaCutoff);
    }
    render::buildMipLevels(texture, keptFrom);
    texture.converted = true;
  }
  std::string line = "object: " + std::to_string(mesh.materials.size()) + " material" +
                     (mesh.materials.size() == 1 ? "" : "s") +
                     (mesh.colors.empty() ? "" : " and vertex colours") +
                     ", base colours read as " + baseRead;
  if (!textureSpaces.empty()) {
    std::string read;
    for (const auto& [space, n] : textureSpaces)
      read += (read.empty() ? "" : ", ") + std::to_string(n) + " as " + space;
    line += ", " + std::to_string(mesh.textures.size()) + " texture" +
            (mesh.textures.size() == 1 ? "" : "s") + " (" + read + ")";
  }
  line += ", converted to '" + working + "'";
  if (clampedTexels > 0) {
    line += "; " + std::to_string(clampedTexels) + " texture value" +
            (clampedTexels == 1 ? "" : "s") +
            " outside 0..1 clamped (an albedo reflects at most the light it gets; not a number: 0)";
  }
  // How light goes through them, where it does.
  const auto cut = std::count_if(mesh.materials.begin(), mesh.materials.end(),
                                 [](const render::Material& m) { return m.alphaCutoff >= 0.0f; });
  const auto clear = std::count_if(mesh.materials.begin(), mesh.materials.end(),
                                   [](const render::Material& m) { return m.blend; });
  if (cut > 0)
    line += "; " + std::to_string(cut) + (cut == 1 ? " is" : " are") +
            " cut out where alpha is below the cutoff (MASK)";
  if (clear > 0)
    line += "; " + std::to_string(clear) + (clear == 1 ? " is" : " are") +
            " semi-transparent (BLEND): seen through and from both sides, shadows letting 1 - "
            "alpha through";
  return line;
}

}  // namespace compose::pipeline
