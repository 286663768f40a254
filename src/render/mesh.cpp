#include "render/mesh.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <numbers>
#include <numeric>
#include <optional>
#include <unordered_map>
#include <unordered_set>

#include <glm/geometric.hpp>
#include <glm/mat2x2.hpp>

#include "core/error.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "ingest/image_io.h"
#include "render/mesh_formats.h"

namespace compose::render {

namespace fs = std::filesystem;

glm::vec3 Mesh::boundsMin() const {
  glm::vec3 lo(std::numeric_limits<float>::max());
  for (const auto& p : positions) lo = glm::min(lo, p);
  return lo;
}

glm::vec3 Mesh::boundsMax() const {
  glm::vec3 hi(-std::numeric_limits<float>::max());
  for (const auto& p : positions) hi = glm::max(hi, p);
  return hi;
}

glm::vec3 Mesh::smoothPoint(uint32_t triangle, float u, float v, const glm::vec3& p,
                            bool back) const {
  const uint32_t* corner = &indices[3 * size_t(triangle)];
  const float w[3] = {1.0f - u - v, u, v};
  glm::vec3 lift(0.0f);
  for (int i = 0; i < 3; ++i) {
    const glm::vec3 n = back ? -normals[corner[i]] : normals[corner[i]];
    lift += (w[i] * std::max(0.0f, glm::dot(positions[corner[i]] - p, n))) * n;
  }
  // At most an eighth of the longest edge: normals averaged across a hard edge (a smooth-shaded
  // box) would otherwise lift the middle of a face far off it.
  const glm::vec3 a = positions[corner[0]], b = positions[corner[1]], c = positions[corner[2]];
  const float most =
      0.125f *
      std::sqrt(std::max({glm::dot(b - a, b - a), glm::dot(c - b, c - b), glm::dot(a - c, a - c)}));
  const float length = glm::length(lift);
  if (length > most) lift *= most / length;
  return p + lift;
}

namespace {

// A texture coordinate brought into one period of its wrap mode (so that texel indices stay
// small), then a texel index wrapped into [0, n).
float reduce(float t, Texture::Wrap wrap) {
  switch (wrap) {
    case Texture::Wrap::Repeat:
      return t - std::floor(t);
    case Texture::Wrap::Mirror:
      return t - 2.0f * std::floor(0.5f * t);
    case Texture::Wrap::Clamp:
      break;
  }
  return std::clamp(t, -1.0f, 2.0f);
}

int wrapIndex(int i, int n, Texture::Wrap wrap) {
  switch (wrap) {
    case Texture::Wrap::Repeat:
      return ((i % n) + n) % n;
    case Texture::Wrap::Mirror: {
      const int m = ((i % (2 * n)) + 2 * n) % (2 * n);
      return m < n ? m : 2 * n - 1 - m;
    }
    case Texture::Wrap::Clamp:
      break;
  }
  return std::clamp(i, 0, n - 1);
}

}  // namespace

bool Mesh::hasCutouts() const {
  return std::any_of(materials.begin(), materials.end(),
                     [](const Material& m) { return m.cutOut(); });
}

namespace {

// The texture coordinates of barycentrics (u, v) of `triangle` through `mat`'s transform; false
// where they are not finite.
bool materialUv(const Mesh& mesh, const Material& mat, uint32_t triangle, float u, float v,
                glm::vec2& uv) {
  const uint32_t* c = &mesh.indices[3 * size_t(triangle)];
  const glm::vec2 interpolated =
      (1.0f - u - v) * mesh.texcoords[c[0]] + u * mesh.texcoords[c[1]] + v * mesh.texcoords[c[2]];
  const glm::vec3 t = mat.uvTransform * glm::vec3(interpolated, 1.0f);
  uv = glm::vec2(t);
  return std::isfinite(t.x) && std::isfinite(t.y);
}

// The first `channels` (1 or 3) channels of `img` at texture coordinates `uv`, bilinear (or the
// nearest texel, Texture::nearest) with the texture's wrap modes. Texel centres lie at (i + 0.5) /
// width; v = 0 is the bottom row (OBJ and glTF flip differently: loaders store v so that this
// holds).
glm::vec3 bilinear(const Texture& tex, const Image& img, const glm::vec2& uv,
                   const Image* weights = nullptr, bool magnified = true) {
  const float x = reduce(uv.x, tex.wrapU) * float(img.width) - 0.5f;
  const float y = (1.0f - reduce(uv.y, tex.wrapV)) * float(img.height) - 0.5f;
  const float fx = std::floor(x), fy = std::floor(y);
  const float ax = x - fx, ay = y - fy;
  const int x0 = int(fx), y0 = int(fy);
  auto texel = [&](int ix, int iy) {
    const float* p =
        img.at(wrapIndex(ix, img.width, tex.wrapU), wrapIndex(iy, img.height, tex.wrapV));
    return img.channels >= 3 ? glm::vec3(p[0], p[1], p[2]) : glm::vec3(p[0]);
  };
  if (tex.nearest && magnified) return texel(int(std::floor(x + 0.5f)), int(std::floor(y + 0.5f)));
  if (weights) {
    // Weighted by the texels' alpha (a cut-out's colour, premultiplied as a filter takes it): the
    // colour of texels that are not there does not bleed into the edge of those that are.
    auto at = [&](const Image& image, int ix, int iy) {
      return image.at(wrapIndex(ix, image.width, tex.wrapU),
                      wrapIndex(iy, image.height, tex.wrapV))[0];
    };
    const float w[4] = {(1.0f - ax) * (1.0f - ay) * at(*weights, x0, y0),
                        ax * (1.0f - ay) * at(*weights, x0 + 1, y0),
                        (1.0f - ax) * ay * at(*weights, x0, y0 + 1),
                        ax * ay * at(*weights, x0 + 1, y0 + 1)};
    const float sum = w[0] + w[1] + w[2] + w[3];
    if (sum > 1e-6f)
      return (texel(x0, y0) * w[0] + texel(x0 + 1, y0) * w[1] + texel(x0, y0 + 1) * w[2] +
              texel(x0 + 1, y0 + 1) * w[3]) /
             sum;
  }
  return (texel(x0, y0) * (1.0f - ax) + texel(x0 + 1, y0) * ax) * (1.0f - ay) +
         (texel(x0, y0 + 1) * (1.0f - ax) + texel(x0 + 1, y0 + 1) * ax) * ay;
}

// Level k of the texture's colour (0: the image itself), plain or weighted by what a cut-out
// keeps (Texture::keptLevels), and the weights of the latter.
const Image& colourLevel(const Texture& tex, size_t k, bool weighted) {
  if (k == 0) return tex.image;
  return weighted ? tex.keptLevels[k - 1] : tex.levels[k - 1];
}
const Image* weightLevel(const Texture& tex, size_t k) {
  if (tex.alpha.empty()) return nullptr;
  if (!tex.keptWeights.empty()) return &tex.keptWeights[k];
  return k == 0 ? &tex.alpha : nullptr;
}

// Trilinear: bilinear in the two levels around `lod` (0: full size), blended. `weighted`: a
// cut-out's colour, the texels weighted by what it keeps.
glm::vec3 trilinear(const Texture& tex, const glm::vec2& uv, float lod, bool weighted) {
  weighted = weighted && !tex.alpha.empty();
  const size_t top = tex.levels.size();
  if (!(lod > 0.0f) || top == 0)
    return bilinear(tex, tex.image, uv, weighted ? weightLevel(tex, 0) : nullptr);
  if (weighted && tex.keptLevels.size() != top) weighted = false;  // built without them
  lod = std::min(lod, float(top));
  const size_t k = std::min(size_t(lod), top);
  const float f = lod - float(k);
  const glm::vec3 a = bilinear(tex, colourLevel(tex, k, weighted), uv,
                               weighted ? weightLevel(tex, k) : nullptr, false);
  if (k == top || f <= 0.0f) return a;
  const glm::vec3 b = bilinear(tex, colourLevel(tex, k + 1, weighted), uv,
                               weighted ? weightLevel(tex, k + 1) : nullptr, false);
  return a + (b - a) * f;
}

// One dimension's area weights from n samples down to m: for each output index, its inputs and
// their shares (summing to 1).
struct AreaTap {
  int index;
  float weight;
};
std::vector<std::vector<AreaTap>> areaTaps(int n, int m) {
  std::vector<std::vector<AreaTap>> taps(static_cast<size_t>(m));
  const double scale = double(n) / double(m);
  for (int i = 0; i < m; ++i) {
    const double lo = i * scale, hi = (i + 1) * scale;
    for (int k = int(std::floor(lo)); k < int(std::ceil(hi)) && k < n; ++k) {
      const double w = std::min(hi, double(k + 1)) - std::max(lo, double(k));
      if (w > 0.0) taps[size_t(i)].push_back({k, float(w / scale)});
    }
  }
  return taps;
}

// `img` reduced to width x height, each output texel the area average of the inputs it covers;
// with `weights` (one channel, img's size) the average weighted by them (the plain one where they
// are all 0), and their own area average in `reducedWeights`. Row by row, without a copy.
Image areaReduce(const Image& img, int width, int height, const Image* weights = nullptr,
                 Image* reducedWeights = nullptr) {
  const auto across = areaTaps(img.width, width), down = areaTaps(img.height, height);
  const int c = img.channels;
  Image out(width, height, c, img.channelNames);
  out.colorSpace = img.colorSpace;
  if (weights) *reducedWeights = Image(width, height, 1, weights->channelNames);
  parallelFor(0, height, [&](int64_t yy) {
    const int y = int(yy);
    thread_local std::vector<float> weighted;
    weighted.assign(weights ? size_t(c) : 0, 0.0f);
    for (int x = 0; x < width; ++x) {
      float* o = out.at(x, y);
      float sum = 0.0f;
      std::fill(weighted.begin(), weighted.end(), 0.0f);
      for (const AreaTap& ty : down[size_t(y)]) {
        for (const AreaTap& tx : across[size_t(x)]) {
          const float t = ty.weight * tx.weight;
          const float* p = img.at(tx.index, ty.index);
          for (int k = 0; k < c; ++k) o[k] += t * p[k];
          if (weights) {
            const float w = t * weights->at(tx.index, ty.index)[0];
            sum += w;
            for (int k = 0; k < c; ++k) weighted[size_t(k)] += w * p[k];
          }
        }
      }
      if (weights) {
        reducedWeights->at(x, y)[0] = sum;
        if (sum > 1e-12f)
          for (int k = 0; k < c; ++k) o[k] = weighted[size_t(k)] / sum;
      }
    }
  });
  return out;
}

const Material& materialOf(const Mesh& mesh, uint32_t triangle) {
  const uint32_t m = mesh.triangleMaterial.empty() ? 0u : mesh.triangleMaterial[triangle];
  return mesh.materials[std::min<size_t>(m, mesh.materials.size() - 1)];
}

// The alpha of `mat` at barycentrics (u, v) of `triangle`: its base alpha times its texture's.
float materialAlpha(const Mesh& mesh, const Material& mat, uint32_t triangle, float u, float v) {
  float alpha = mat.baseAlpha;
  if (!mesh.alphas.empty()) {
    const uint32_t* c = &mesh.indices[3 * size_t(triangle)];
    alpha *= (1.0f - u - v) * mesh.alphas[c[0]] + u * mesh.alphas[c[1]] + v * mesh.alphas[c[2]];
  }
  glm::vec2 uv;
  if (mat.texture >= 0 && !mesh.texcoords.empty()) {
    const Texture& tex = mesh.textures[size_t(mat.texture)];
    if (!tex.alpha.empty() && materialUv(mesh, mat, triangle, u, v, uv))
      alpha *= bilinear(tex, tex.alpha, uv).x;  // bilinear, as the colour (albedoAt)
  }
  return alpha;
}

}  // namespace

bool Mesh::cutAway(uint32_t triangle, float u, float v) const {
  return passes(triangle, u, v, 0.0f);
}

float Mesh::alphaAt(uint32_t triangle, float u, float v) const {
  if (materials.empty()) return 1.0f;
  const Material& mat = materialOf(*this, triangle);
  return mat.cutOut() ? materialAlpha(*this, mat, triangle, u, v) : 1.0f;
}

bool Mesh::oneSided(uint32_t triangle) const {
  return !sides.empty() && sides[triangle] != 0;
}

bool Mesh::semiTransparent(uint32_t triangle) const {
  return !materials.empty() && materialOf(*this, triangle).blend;
}

size_t Mesh::frontTriangleCount() const {
  if (sides.empty()) return triangleCount();
  return size_t(
      std::count_if(sides.begin(), sides.end(), [](uint8_t s) { return s != kBackSide; }));
}

bool Mesh::passes(uint32_t triangle, float u, float v, float xi) const {
  if (materials.empty()) return false;
  const Material& mat = materialOf(*this, triangle);
  if (!mat.cutOut()) return false;
  const float alpha = materialAlpha(*this, mat, triangle, u, v);
  return mat.blend ? !(alpha > xi) : alpha < mat.alphaCutoff;
}

glm::vec3 Mesh::albedoAt(uint32_t triangle, float u, float v) const {
  const Material& mat = materialOf(*this, triangle);
  glm::vec3 albedo = mat.baseColor;
  if (mat.texture >= 0 && !texcoords.empty()) {
    const Texture& tex = textures[size_t(mat.texture)];
    glm::vec2 uv;
    if (!tex.image.empty() && materialUv(*this, mat, triangle, u, v, uv))
      albedo *=
          bilinear(tex, tex.image, uv, mat.cutOut() && !tex.alpha.empty() ? &tex.alpha : nullptr);
  }
  if (!colors.empty()) {
    const uint32_t* c = &indices[3 * size_t(triangle)];
    albedo *= (1.0f - u - v) * colors[c[0]] + u * colors[c[1]] + v * colors[c[2]];
  }
  return convertsAlbedo ? albedoToWorking * albedo : albedo;
}

glm::vec3 Mesh::albedoAt(uint32_t triangle, float u, float v, const glm::vec3& dPdx,
                         const glm::vec3& dPdy) const {
  const Material& mat = materialOf(*this, triangle);
  if (mat.texture < 0 || texcoords.empty() || textures[size_t(mat.texture)].levels.empty())
    return albedoAt(triangle, u, v);
  const Texture& tex = textures[size_t(mat.texture)];
  glm::vec2 uv;
  glm::vec3 albedo = mat.baseColor;
  if (tex.image.empty() || !materialUv(*this, mat, triangle, u, v, uv))
    return albedoAt(triangle, u, v);
  // The footprint in texture coordinates: dP on the triangle's plane as barycentric steps (by the
  // dual basis of its edges), then as steps of the corners' texture coordinates.
  const uint32_t* c = &indices[3 * size_t(triangle)];
  const glm::vec3 e1 = positions[c[1]] - positions[c[0]], e2 = positions[c[2]] - positions[c[0]];
  const glm::vec3 n = glm::cross(e1, e2);
  const float nn = glm::dot(n, n);
  const glm::vec3 g1 = glm::cross(e2, n) / nn, g2 = glm::cross(n, e1) / nn;
  const glm::mat2 linear(mat.uvTransform);
  const glm::vec2 t1 = linear * (texcoords[c[1]] - texcoords[c[0]]),
                  t2 = linear * (texcoords[c[2]] - texcoords[c[0]]);
  const glm::vec2 size(float(tex.image.width), float(tex.image.height));
  glm::vec2 ax = glm::dot(dPdx, g1) * t1 + glm::dot(dPdx, g2) * t2;
  glm::vec2 ay = glm::dot(dPdy, g1) * t1 + glm::dot(dPdy, g2) * t2;
  // A clamped axis outside 0..1 is the edge texel wherever the footprint reaches: no extent.
  if (tex.wrapU == Texture::Wrap::Clamp && (uv.x < 0.0f || uv.x > 1.0f)) ax.x = ay.x = 0.0f;
  if (tex.wrapV == Texture::Wrap::Clamp && (uv.y < 0.0f || uv.y > 1.0f)) ax.y = ay.y = 0.0f;
  float lx = glm::length(ax * size), ly = glm::length(ay * size);  // in texels
  if (ly > lx) {
    std::swap(ax, ay);
    std::swap(lx, ly);
  }
  const bool weighted = mat.cutOut() && !tex.alpha.empty();
  glm::vec3 colour;
  if (!(nn > 0.0f) || !std::isfinite(lx) || !std::isfinite(ly)) {
    colour = trilinear(tex, uv, float(tex.levels.size()), weighted);  // the mean colour
  } else if (!(lx > 1.0f)) {
    colour = bilinear(tex, tex.image, uv, weighted ? &tex.alpha : nullptr);
  } else {
    // Elongated: taps along the long axis, each at the level of the short one (at most 8 taps;
    // beyond that the level of a longer segment).
    constexpr int kMaxTaps = 8;
    const int taps = std::clamp(int(std::ceil(lx / std::max(ly, 1e-6f))), 1, kMaxTaps);
    const float lod = std::log2(lx / float(taps));
    colour = glm::vec3(0.0f);
    for (int k = 0; k < taps; ++k)
      colour += trilinear(tex, uv + ax * ((float(k) + 0.5f) / float(taps) - 0.5f), lod, weighted);
    colour /= float(taps);
  }
  albedo *= colour;
  if (!colors.empty())
    albedo *= (1.0f - u - v) * colors[c[0]] + u * colors[c[1]] + v * colors[c[2]];
  return convertsAlbedo ? albedoToWorking * albedo : albedo;
}

void buildMipLevels(Texture& texture, std::optional<float> keptFrom) {
  texture.levels.clear();
  texture.keptLevels.clear();
  texture.keptWeights.clear();
  if (texture.image.empty()) return;
  for (const Image* plain = &texture.image; plain->width > 1 || plain->height > 1;) {
    const int w = std::max(1, plain->width / 2), h = std::max(1, plain->height / 2);
    texture.levels.push_back(areaReduce(*plain, w, h));
    plain = &texture.levels.back();
  }
  if (!keptFrom || texture.alpha.empty()) return;
  // What a cut-out keeps of each texel: all of it where its alpha reaches the cutoff (MASK), its
  // alpha for a semi-transparent material (BLEND, *keptFrom < 0).
  texture.keptLevels.reserve(texture.levels.size());
  texture.keptWeights.reserve(texture.levels.size() + 1);
  texture.keptWeights.push_back(texture.alpha);
  if (*keptFrom >= 0.0f)
    for (float& a : texture.keptWeights[0].pixels) a = a >= *keptFrom ? 1.0f : 0.0f;
  const Image* colour = &texture.image;
  const Image* weights = &texture.keptWeights[0];
  for (size_t k = 0; k < texture.levels.size(); ++k) {
    const Image& size = texture.levels[k];
    Image reduced;
    texture.keptLevels.push_back(areaReduce(*colour, size.width, size.height, weights, &reduced));
    texture.keptWeights.push_back(std::move(reduced));
    colour = &texture.keptLevels.back();
    weights = &texture.keptWeights.back();
  }
}

bool Mesh::keptBounds(glm::vec3& lo, glm::vec3& hi, size_t budget) const {
  lo = glm::vec3(std::numeric_limits<float>::max());
  hi = glm::vec3(-std::numeric_limits<float>::max());
  if (!hasCutouts()) {
    lo = boundsMin();
    hi = boundsMax();
    return true;
  }
  // Per cut-out triangle, the steps of its test grid: about two per texel of its alpha along
  // its longest edge in texture space; 0 where its alpha cannot vary (no alpha texture, or
  // texture coordinates that do not move across it): one test then says whether it is there.
  const size_t triangles = triangleCount();
  enum : uint8_t { kWhole, kUniform, kGrid };
  std::vector<uint8_t> kind(triangles, kWhole);
  std::vector<uint16_t> steps(triangles, 0);
  double points = 0.0;
  for (size_t t = 0; t < triangles; ++t) {
    const Material& mat = materialOf(*this, uint32_t(t));
    if (!mat.cutOut()) continue;
    kind[t] = kUniform;
    const uint32_t* c = &indices[3 * t];
    // Vertex alphas that differ across the triangle: alpha is linear over it, cut along a line
    // found to a sixteenth of the triangle.
    if (!alphas.empty() && (alphas[c[0]] != alphas[c[1]] || alphas[c[0]] != alphas[c[2]])) {
      kind[t] = kGrid;
      steps[t] = 16;
    }
    if (mat.texture < 0 || texcoords.empty() || textures[size_t(mat.texture)].alpha.empty()) {
      if (kind[t] == kGrid) points += 0.5 * double(steps[t] + 1) * double(steps[t] + 2);
      continue;
    }
    const Image& alpha = textures[size_t(mat.texture)].alpha;
    double longest = 0.0;
    for (int e = 0; e < 3; ++e) {
      const glm::vec3 a = mat.uvTransform * glm::vec3(texcoords[c[e]], 1.0f);
      const glm::vec3 b = mat.uvTransform * glm::vec3(texcoords[c[(e + 1) % 3]], 1.0f);
      longest = std::max({longest, std::abs(double(b.x - a.x)) * alpha.width,
                          std::abs(double(b.y - a.y)) * alpha.height});
    }
    if (longest > 1e-6 && std::isfinite(longest)) {
      kind[t] = kGrid;
      steps[t] = std::max(steps[t], uint16_t(std::clamp(std::ceil(2.0 * longest), 1.0, 4096.0)));
    }
    if (kind[t] == kGrid) points += 0.5 * double(steps[t] + 1) * double(steps[t] + 2);
  }
  // Over the budget: every grid coarsened by the same factor.
  const double coarsen = points > double(budget) ? std::sqrt(double(budget) / points) : 1.0;
  const float third = 1.0f / 3.0f;
  auto add = [&](const uint32_t* c, float u, float v) {
    const glm::vec3 p =
        (1.0f - u - v) * positions[c[0]] + u * positions[c[1]] + v * positions[c[2]];
    lo = glm::min(lo, p);
    hi = glm::max(hi, p);
  };
  for (size_t t = 0; t < triangles; ++t) {
    const uint32_t* c = &indices[3 * t];
    if (kind[t] == kWhole || (kind[t] == kUniform && !cutAway(uint32_t(t), third, third))) {
      for (int k = 0; k < 3; ++k) add(c, k == 1 ? 1.0f : 0.0f, k == 2 ? 1.0f : 0.0f);
      continue;
    }
    if (kind[t] == kUniform) continue;  // wholly cut away
    // Barycentric grid points (i, j) / n. One on the triangle's edge must also be kept just
    // inside it: exactly on an edge a repeating texture's bilinear alpha mixes in the far side's
    // texels (a card whose transparent bottom rows meet opaque top rows would keep its bottom
    // edge, alone).
    const int n = std::max(1, int(double(steps[t]) * coarsen));
    for (int i = 0; i <= n; ++i)
      for (int j = 0; i + j <= n; ++j) {
        const float u = float(i) / float(n), v = float(j) / float(n);
        if (cutAway(uint32_t(t), u, v)) continue;
        if (i == 0 || j == 0 || i + j == n) {
          constexpr float kInside = 1e-4f;
          if (cutAway(uint32_t(t), u + (third - u) * kInside, v + (third - v) * kInside)) continue;
        }
        add(c, u, v);
      }
  }
  if (!(lo.x <= hi.x)) {  // everything cut away: nothing is drawn, the whole mesh stands in
    lo = boundsMin();
    hi = boundsMax();
    return false;
  }
  return true;
}

namespace detail {

std::string count(size_t n, const std::string& singular, const std::string& plural) {
  return std::to_string(n) + " " + (n == 1 ? singular : plural);
}

Image textureImage(Image decoded, const std::string& fallbackSpace, Image* alpha) {
  if (alpha) {
    *alpha = Image();
    const int channels = decoded.channels;
    if (channels == 2 || channels == 4) {
      Image a(decoded.width, decoded.height, 1, {"A"});
      bool partial = false;
      for (size_t i = 0; i < a.pixelCount(); ++i) {
        const float value = decoded.pixels[i * size_t(channels) + size_t(channels - 1)];
        a.pixels[i] = value;
        partial = partial || !(value >= 1.0f);
      }
      if (partial) *alpha = std::move(a);
    }
  }
  Image out(decoded.width, decoded.height, 3, {"R", "G", "B"});
  out.colorSpace = decoded.colorSpace.empty() ? fallbackSpace : decoded.colorSpace;
  const int channels = decoded.channels;
  for (size_t i = 0; i < out.pixelCount(); ++i) {
    const float* s = decoded.pixels.data() + i * size_t(channels);
    float* d = out.pixels.data() + i * 3;
    if (channels < 3) {
      d[0] = d[1] = d[2] = s[0];  // grey, or grey and alpha
    } else {
      d[0] = s[0];
      d[1] = s[1];
      d[2] = s[2];
    }
  }
  return out;
}

Image readTextureFile(const fs::path& file, const std::string& fallbackSpace, Image* alpha) {
  std::error_code ec;
  const fs::file_status status = fs::status(file, ec);
  if (fs::exists(status) && !fs::is_regular_file(status) && !fs::is_directory(status))
    throw Error("mesh", "not a regular file", file);
  ingest::ReadOptions stored;
  stored.upright = false;  // UVs are laid on the pixels as stored
  return textureImage(ingest::readImage(file, "mesh", stored).image, fallbackSpace, alpha);
}

}  // namespace detail

namespace {

// Positions welded by value (-0 and +0 alike): an id per vertex, equal for equal positions.
std::vector<uint32_t> weldPositions(const std::vector<glm::vec3>& positions) {
  struct KeyHash {
    size_t operator()(const std::array<uint32_t, 3>& k) const {
      return (size_t(k[0]) * 0x9E3779B97F4A7C15ull) ^ (size_t(k[1]) * 0xC2B2AE3D27D4EB4Full) ^
             size_t(k[2]);
    }
  };
  std::unordered_map<std::array<uint32_t, 3>, uint32_t, KeyHash> ids;
  ids.reserve(positions.size());
  std::vector<uint32_t> id(positions.size());
  for (size_t i = 0; i < positions.size(); ++i) {
    std::array<uint32_t, 3> key;
    const glm::vec3 p = positions[i] + glm::vec3(0.0f);  // -0 becomes +0
    std::memcpy(key.data(), &p, sizeof key);
    id[i] = ids.try_emplace(key, uint32_t(ids.size())).first->second;
  }
  return id;
}

// Union-find over triangle corners, with path halving.
struct CornerSets {
  std::vector<uint32_t> parent;
  explicit CornerSets(size_t n) : parent(n) {
    for (size_t i = 0; i < n; ++i) parent[i] = uint32_t(i);
  }
  uint32_t find(uint32_t c) {
    while (parent[c] != c) c = parent[c] = parent[parent[c]];
    return c;
  }
  void join(uint32_t a, uint32_t b) {
    a = find(a);
    b = find(b);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
};

struct NormalStats {
  size_t computed = 0;  // vertices whose normal was computed
  size_t added = 0;     // vertices added by splitting at sharp edges
  size_t ridges = 0;    // edges sharper than the crease angle shaded smooth (danglingRidges)
};

// More faces than this on one edge: a pathological fin, left sharp rather than compared
// pairwise.
constexpr size_t kMaxFacesOnEdge = 8;

// How much sharper than the crease angle an edge may be and still be taken for a ridge of the
// surface's sampling rather than a crease (danglingRidges).
constexpr double kRidgeMarginDegrees = 25.0;

// The edges sharper than the crease angle that do not belong to a crease line: marked 1 at the
// first entry of their run in `edges` (sorted edge keys of welded positions, one entry per corner
// that starts the edge). On a piecewise-smooth surface sharp edges form lines that close on
// themselves, meet other sharp lines, or run to the mesh's boundary; a line of edges barely
// sharper than the crease that stops in the middle of a smooth surface is a ridge of a scan or of
// coarse tessellation (the Stanford bunny's ear has such a chain of seven edges of 61-71°), and
// split normals along it show as a stair-stepped line that ends abruptly. Such edges are removed
// one at a time from a free end (a position with one sharp edge, not on the mesh's boundary or a
// non-manifold edge) until none is left: a line with a free end goes back to where it meets
// lines that stay. `comparable(a, b)` says whether the angle decides between two faces (the same
// smoothing group, not flat), `smooth(a, b)` whether their angle is within the crease and
// `slight(a, b)` whether it is within kRidgeMarginDegrees beyond it. Edges that smoothing groups
// make sharp and edges sharper than the margin (a blade's cutting edge, a box's edge) are never
// removed, and anchor the lines that reach them.
template <class Comparable, class Smooth, class Slight>
std::vector<uint8_t> danglingRidges(const std::vector<std::pair<uint64_t, uint32_t>>& edges,
                                    uint32_t positions, Comparable comparable, Smooth smooth,
                                    Slight slight) {
  std::vector<uint32_t> degree(positions, 0);
  std::vector<uint8_t> anchored(positions, 0);
  std::vector<uint32_t> candidates;  // first entries of the runs of edges sharp by angle alone
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && edges[j].first == edges[i].first) ++j;
    const uint32_t a = uint32_t(edges[i].first >> 32), b = uint32_t(edges[i].first);
    const size_t ta = edges[i].second / 3, tb = j - i == 2 ? edges[i + 1].second / 3 : ta;
    if (j - i != 2 || ta == tb) {
      anchored[a] = anchored[b] = 1;  // boundary or non-manifold
    } else if (!smooth(ta, tb)) {
      ++degree[a];
      ++degree[b];
      if (comparable(ta, tb) && slight(ta, tb)) candidates.push_back(uint32_t(i));
    }
    i = j;
  }
  // Each position's candidate edges, to find a free end's edge.
  std::vector<uint32_t> start(size_t(positions) + 1, 0), incident(2 * candidates.size());
  for (uint32_t i : candidates) {
    ++start[edges[i].first >> 32];
    ++start[uint32_t(edges[i].first)];
  }
  for (size_t v = 0; v < positions; ++v) start[v + 1] += start[v];
  for (uint32_t i : candidates) {
    incident[--start[edges[i].first >> 32]] = i;
    incident[--start[uint32_t(edges[i].first)]] = i;
  }
  std::vector<uint8_t> ridge(edges.size(), 0), removed(edges.size(), 0);
  std::vector<uint32_t> free;
  for (size_t v = 0; v < positions; ++v)
    if (degree[v] == 1 && !anchored[v]) free.push_back(uint32_t(v));
  while (!free.empty()) {
    const uint32_t v = free.back();
    free.pop_back();
    if (degree[v] != 1 || anchored[v]) continue;
    for (uint32_t k = start[v]; k < start[v + 1]; ++k) {
      const uint32_t i = incident[k];
      if (removed[i]) continue;
      removed[i] = ridge[i] = 1;
      const uint32_t a = uint32_t(edges[i].first >> 32), b = uint32_t(edges[i].first);
      --degree[a];
      --degree[b];
      const uint32_t other = a == v ? b : a;
      if (degree[other] == 1 && !anchored[other]) free.push_back(other);
      break;
    }
  }
  return ridge;
}

// Normals for every vertex with fromFile[v] == 0: the corners around a position are joined into
// smooth fans across edges whose faces differ by at most `creaseDegrees` (and, with smoothing
// groups, share a non-zero group); each fan gets the angle-weighted mean normal of its faces, and
// a vertex whose corners fall into several fans is split, one copy per fan. Vertices with file
// normals keep them. `fromFile` grows with the mesh.
NormalStats computeNormals(Mesh& mesh, std::vector<uint8_t>& fromFile,
                           const std::vector<uint32_t>& groups, double creaseDegrees) {
  NormalStats stats;
  const size_t triangles = mesh.triangleCount();
  const size_t corners = 3 * triangles;
  mesh.normals.resize(mesh.positions.size(), glm::vec3(0.0f));
  const std::vector<uint32_t> pid = weldPositions(mesh.positions);
  // Unit face normals and the angle of each corner.
  std::vector<glm::dvec3> faceNormal(triangles, glm::dvec3(0.0));
  std::vector<double> angle(corners, 0.0);
  for (size_t t = 0; t < triangles; ++t) {
    glm::dvec3 p[3];
    for (int k = 0; k < 3; ++k) p[k] = glm::dvec3(mesh.positions[mesh.indices[3 * t + size_t(k)]]);
    const glm::dvec3 n = glm::cross(p[1] - p[0], p[2] - p[0]);
    const double len = glm::length(n);
    if (!(len > 0.0)) continue;
    faceNormal[t] = n / len;
    for (int k = 0; k < 3; ++k) {
      const glm::dvec3 a = p[(k + 1) % 3] - p[k], b = p[(k + 2) % 3] - p[k];
      const double la = glm::length(a), lb = glm::length(b);
      if (la > 0.0 && lb > 0.0)
        angle[3 * t + size_t(k)] = std::acos(std::clamp(glm::dot(a, b) / (la * lb), -1.0, 1.0));
    }
  }
  auto group = [&](size_t t) { return groups.empty() ? 1u : groups[t]; };
  const bool fullySmooth = creaseDegrees >= 180.0;
  const double cosCrease = std::cos(creaseDegrees * std::numbers::pi / 180.0);
  // Flat faces (group 0) join only their coplanar neighbours in group 0 (the triangles of one
  // polygon), so that a flat polygon keeps one vertex per corner.
  auto smooth = [&](size_t a, size_t b) {
    if (group(a) != group(b)) return false;
    const double cosine = glm::dot(faceNormal[a], faceNormal[b]);
    if (group(a) == 0) return cosine >= 1.0 - 1e-9;
    return fullySmooth || cosine >= cosCrease - 1e-9;
  };

  CornerSets sets(corners);
  auto cornerPid = [&](size_t c) { return pid[mesh.indices[c]]; };
  auto next = [](size_t c) { return c - c % 3 + (c % 3 + 1) % 3; };
  // Edges (by welded position) and the corners they start from, sorted so that the faces
  // sharing an edge are adjacent.
  std::vector<std::pair<uint64_t, uint32_t>> edges(corners);
  for (size_t c = 0; c < corners; ++c) {
    const uint32_t a = cornerPid(c), b = cornerPid(next(c));
    edges[c] = {(uint64_t(std::min(a, b)) << 32) | std::max(a, b), uint32_t(c)};
  }
  std::sort(edges.begin(), edges.end());
  std::vector<uint8_t> ridge;
  if (creaseDegrees > 0.0 && !fullySmooth) {
    const uint32_t positions = pid.empty() ? 0 : *std::max_element(pid.begin(), pid.end()) + 1;
    auto comparable = [&](size_t a, size_t b) { return group(a) == group(b) && group(a) != 0; };
    const double cosMargin =
        std::cos(std::min(creaseDegrees + kRidgeMarginDegrees, 180.0) * std::numbers::pi / 180.0);
    auto slight = [&](size_t a, size_t b) {
      return glm::dot(faceNormal[a], faceNormal[b]) >= cosMargin;
    };
    ridge = danglingRidges(edges, positions, comparable, smooth, slight);
  }
  // The ridges that change a normal: those with a computed normal at an end.
  for (size_t i = 0; i < ridge.size(); ++i) {
    if (!ridge[i]) continue;
    const size_t c = edges[i].second, d = edges[i + 1].second;
    if (!fromFile[mesh.indices[c]] || !fromFile[mesh.indices[next(c)]] ||
        !fromFile[mesh.indices[d]] || !fromFile[mesh.indices[next(d)]])
      ++stats.ridges;
  }
  for (size_t i = 0; i < edges.size();) {
    size_t j = i;
    while (j < edges.size() && edges[j].first == edges[i].first) ++j;
    if (j - i >= 2 && j - i <= kMaxFacesOnEdge) {
      for (size_t a = i; a < j; ++a) {
        for (size_t b = a + 1; b < j; ++b) {
          const size_t ca = edges[a].second, cb = edges[b].second;
          if (ca / 3 == cb / 3 || (!smooth(ca / 3, cb / 3) && !(ridge.size() && ridge[i])))
            continue;
          // Join the corners that sit at the same end of the shared edge.
          if (cornerPid(ca) == cornerPid(cb)) {
            sets.join(uint32_t(ca), uint32_t(cb));
            sets.join(uint32_t(next(ca)), uint32_t(next(cb)));
          } else {
            sets.join(uint32_t(ca), uint32_t(next(cb)));
            sets.join(uint32_t(next(ca)), uint32_t(cb));
          }
        }
      }
    }
    i = j;
  }
  if (fullySmooth) {
    // One normal per position (and smoothing group), even where fans meet only at a vertex.
    std::unordered_map<uint64_t, uint32_t> first;
    for (size_t c = 0; c < corners; ++c) {
      if (group(c / 3) == 0) continue;
      const uint64_t key = (uint64_t(cornerPid(c)) << 32) | group(c / 3);
      const auto [it, inserted] = first.try_emplace(key, uint32_t(c));
      if (!inserted) sets.join(it->second, uint32_t(c));
    }
  }

  std::vector<glm::dvec3> sum(corners, glm::dvec3(0.0));
  for (size_t c = 0; c < corners; ++c) sum[sets.find(uint32_t(c))] += angle[c] * faceNormal[c / 3];
  auto fanNormal = [&](uint32_t root, size_t c) {
    const double len = glm::length(sum[root]);
    if (len > 0.0) return glm::vec3(sum[root] / len);
    const glm::dvec3& f = faceNormal[c / 3];
    return glm::dot(f, f) > 0.0 ? glm::vec3(f) : glm::vec3(0.0f, 1.0f, 0.0f);
  };
  // The first fan met at a vertex keeps the vertex; every other fan gets a copy.
  const size_t originalVertices = mesh.positions.size();
  std::vector<uint32_t> fanOf(originalVertices, UINT32_MAX);
  std::unordered_map<uint64_t, uint32_t> copies;
  for (size_t c = 0; c < corners; ++c) {
    const uint32_t v = mesh.indices[c];
    if (fromFile[v]) continue;
    const uint32_t root = sets.find(uint32_t(c));
    if (fanOf[v] == UINT32_MAX) {
      fanOf[v] = root;
      mesh.normals[v] = fanNormal(root, c);
      ++stats.computed;
      continue;
    }
    if (fanOf[v] == root) continue;
    const auto [it, inserted] =
        copies.try_emplace((uint64_t(v) << 32) | root, uint32_t(mesh.positions.size()));
    if (inserted) {
      mesh.positions.push_back(mesh.positions[v]);
      if (!mesh.texcoords.empty()) mesh.texcoords.push_back(mesh.texcoords[v]);
      if (!mesh.colors.empty()) mesh.colors.push_back(mesh.colors[v]);
      if (!mesh.alphas.empty()) mesh.alphas.push_back(mesh.alphas[v]);
      mesh.normals.push_back(fanNormal(root, c));
      fromFile.push_back(0);
      ++stats.added;
    }
    mesh.indices[c] = it->second;
  }
  return stats;
}

// Keeps the triangles with keep[t] != 0, with their materials and smoothing groups.
void keepTriangles(detail::LoadedMesh& loaded, const std::vector<uint8_t>& keep) {
  Mesh& mesh = loaded.mesh;
  size_t out = 0;
  for (size_t t = 0; t < keep.size(); ++t) {
    if (!keep[t]) continue;
    for (int k = 0; k < 3; ++k) mesh.indices[3 * out + size_t(k)] = mesh.indices[3 * t + size_t(k)];
    if (!mesh.triangleMaterial.empty()) mesh.triangleMaterial[out] = mesh.triangleMaterial[t];
    if (!loaded.smoothingGroup.empty()) loaded.smoothingGroup[out] = loaded.smoothingGroup[t];
    ++out;
  }
  mesh.indices.resize(3 * out);
  if (!mesh.triangleMaterial.empty()) mesh.triangleMaterial.resize(out);
  if (!loaded.smoothingGroup.empty()) loaded.smoothingGroup.resize(out);
}

// Removes the vertices no triangle uses (so that bounds, placement and hashing see only what
// renders), keeping the order of the rest.
void dropUnusedVertices(detail::LoadedMesh& loaded) {
  Mesh& mesh = loaded.mesh;
  std::vector<uint32_t> remap(mesh.positions.size(), UINT32_MAX);
  for (uint32_t i : mesh.indices) remap[i] = 0;
  uint32_t next = 0;
  for (size_t v = 0; v < remap.size(); ++v) {
    if (remap[v] == UINT32_MAX) continue;
    remap[v] = next;
    mesh.positions[next] = mesh.positions[v];
    if (v < mesh.normals.size()) mesh.normals[next] = mesh.normals[v];
    if (!mesh.texcoords.empty()) mesh.texcoords[next] = mesh.texcoords[v];
    if (!mesh.colors.empty()) mesh.colors[next] = mesh.colors[v];
    if (!mesh.alphas.empty()) mesh.alphas[next] = mesh.alphas[v];
    if (!loaded.hasNormal.empty()) loaded.hasNormal[next] = loaded.hasNormal[v];
    ++next;
  }
  mesh.positions.resize(next);
  if (mesh.normals.size() > next) mesh.normals.resize(next);
  if (!mesh.texcoords.empty()) mesh.texcoords.resize(next);
  if (!mesh.colors.empty()) mesh.colors.resize(next);
  if (!mesh.alphas.empty()) mesh.alphas.resize(next);
  if (!loaded.hasNormal.empty()) loaded.hasNormal.resize(next);
  for (uint32_t& i : mesh.indices) i = remap[i];
}

// Drops the triangles that cannot render, with a warning that counts each kind: a corner with a
// non-finite coordinate, no area (zero area, or a repeated corner), or the same three positions
// as an earlier triangle (in any order or winding). A mesh with nothing left is an error.
void dropUnrenderableTriangles(detail::LoadedMesh& loaded, const fs::path& path) {
  Mesh& mesh = loaded.mesh;
  const size_t total = mesh.triangleCount();
  std::vector<uint8_t> keep(total, 1);
  size_t nonFinite = 0;
  for (size_t t = 0; t < total; ++t) {
    for (int k = 0; k < 3; ++k) {
      const glm::vec3& p = mesh.positions[mesh.indices[3 * t + size_t(k)]];
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) keep[t] = 0;
    }
    nonFinite += keep[t] ? 0 : 1;
  }
  if (nonFinite == total) {
    throw Error("mesh",
                std::string("nothing renderable: ") +
                    (total == 1 ? "the one triangle has"
                                : "all " + std::to_string(total) + " triangles have") +
                    " a corner whose coordinates are not finite numbers (NaN, infinite, or beyond "
                    "single precision's 3.4e38)",
                path);
  }
  if (nonFinite) {
    keepTriangles(loaded, keep);
    mesh.warnings.push_back("dropped " + std::to_string(nonFinite) + " of " +
                            std::to_string(total) +
                            " triangles with a corner whose coordinates are not finite numbers "
                            "(NaN, infinite, or beyond single precision's 3.4e38)");
  }
  dropUnusedVertices(loaded);
  const glm::vec3 extent = mesh.boundsMax() - mesh.boundsMin();
  const float size = std::max({extent.x, extent.y, extent.z});
  if (!(size > 0.0f)) throw Error("mesh", "mesh has zero size (all vertices coincide)", path);
  // Areas and normals are products of two coordinates, a ray's test against a triangle of three
  // (edge x edge . direction, the direction carried into the object's frame as long as the
  // object is large): beyond about 5e12 units they overflow single precision, and the object
  // rendered as a streak (2e13) or not at all. 1e12 keeps a margin.
  if (!(size < 1e12f)) {
    throw Error("mesh",
                "mesh spans " + numberText(size) +
                    " units: coordinates this large overflow single precision (up to 1e12 "
                    "render); scale the file down (--scale sets the size in the plate)",
                path);
  }
  // At the other end, a normal's squared length underflows: from about 3e-10 units every
  // triangle looked degenerate ("nothing renderable", a wrong reason).
  if (size < 1e-7f) {
    throw Error("mesh",
                "mesh spans " + numberText(size) +
                    " units: coordinates this small underflow single precision (from 1e-7 "
                    "render); scale the file up (--scale sets the size in the plate)",
                path);
  }

  // Area below (1e-7 of the object's size)² is rounding noise in float coordinates.
  const float minDoubleArea = 1e-14f * size * size;
  // Positions by value, so that vertices split by normals still count as one position.
  const std::vector<uint32_t> positionId = weldPositions(mesh.positions);
  struct TripleHash {
    size_t operator()(const std::array<uint32_t, 3>& t) const {
      return (size_t(t[0]) * 73856093u) ^ (size_t(t[1]) * 19349663u) ^ (size_t(t[2]) * 83492791u);
    }
  };
  std::unordered_map<std::array<uint32_t, 3>, uint32_t, TripleHash> seen;  // → first triangle
  const size_t remaining = mesh.triangleCount();
  keep.assign(remaining, 1);
  size_t degenerate = 0, duplicate = 0, otherSide = 0;
  for (size_t t = 0; t < remaining; ++t) {
    const uint32_t* v = &mesh.indices[3 * t];
    std::array<uint32_t, 3> ids = {positionId[v[0]], positionId[v[1]], positionId[v[2]]};
    const glm::vec3 n = glm::cross(mesh.positions[v[1]] - mesh.positions[v[0]],
                                   mesh.positions[v[2]] - mesh.positions[v[0]]);
    if (ids[0] == ids[1] || ids[1] == ids[2] || ids[0] == ids[2] ||
        !(glm::length(n) > minDoubleArea)) {
      ++degenerate;
      keep[t] = 0;
      continue;
    }
    std::sort(ids.begin(), ids.end());
    const auto [first, inserted] = seen.try_emplace(ids, uint32_t(t));
    if (!inserted) {
      ++duplicate;
      keep[t] = 0;
      // The other side of a two-sided card: another material on the same triangle.
      if (!mesh.triangleMaterial.empty() &&
          mesh.triangleMaterial[t] != mesh.triangleMaterial[first->second])
        ++otherSide;
    }
  }
  if (degenerate + duplicate == remaining) {
    throw Error(
        "mesh",
        std::string("nothing renderable: ") +
            (remaining == 1 ? "the one triangle is degenerate"
                            : "all " + std::to_string(remaining) + " triangles are degenerate" +
                                  (duplicate ? " or duplicates" : "")),
        path);
  }
  if (degenerate) {
    mesh.warnings.push_back("dropped " + std::to_string(degenerate) + " of " +
                            std::to_string(total) + " triangles with no area");
  }
  if (duplicate) {
    mesh.warnings.push_back("dropped " + std::to_string(duplicate) + " of " +
                            std::to_string(total) + " triangles that repeat another one" +
                            (otherSide ? " (" + std::to_string(otherSide) +
                                             " of them with another material: the back of a "
                                             "two-sided card, whose material is lost; give the "
                                             "card some thickness to keep both sides)"
                                       : std::string()));
  }
  if (degenerate + duplicate) {
    keepTriangles(loaded, keep);
    dropUnusedVertices(loaded);
  }
}

// Validation and normals shared by every format (see the header comment).
}  // namespace

size_t addBackSides(Mesh& mesh) {
  const size_t triangles = mesh.triangleCount();
  COMPOSE_CHECK(mesh.sides.empty());  // once
  if (triangles == 0) return 0;
  auto materialAt = [&](size_t t) -> const Material* {
    if (mesh.materials.empty()) return nullptr;
    const uint32_t m = mesh.triangleMaterial.empty() ? 0u : mesh.triangleMaterial[t];
    return &mesh.materials[std::min<size_t>(m, mesh.materials.size() - 1)];
  };
  std::vector<uint8_t> twoSided(triangles, 0), blend(triangles, 0);
  for (size_t t = 0; t < triangles; ++t) {
    const Material* m = materialAt(t);
    blend[t] = twoSided[t] = uint8_t(m && m->blend);
  }

  // The pieces of the other triangles, joined across edges whose corners are one by position:
  // vertices split for normals or texture seams are one corner, and so are an exporter's seam
  // vertices a few bits apart (positions snapped to a millionth of the object's size, as
  // isConvex() snaps them; a pair the snapping splits opens the piece, which costs time only).
  const size_t n = mesh.positions.size();
  std::vector<uint32_t> order(n), corner(n);
  std::iota(order.begin(), order.end(), 0u);
  const glm::vec3 size = mesh.boundsMax() - mesh.boundsMin();
  const double snap = std::max(1e-30, 1e-6 * double(std::max({size.x, size.y, size.z})));
  std::vector<std::array<int64_t, 3>> cells(n);
  for (size_t v = 0; v < n; ++v)
    for (int c = 0; c < 3; ++c)
      cells[v][size_t(c)] =
          std::llround(std::clamp(double(mesh.positions[v][c]) / snap, -4e18, 4e18));
  auto key = [&](uint32_t v) { return cells[v]; };
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) { return key(a) < key(b); });
  for (size_t i = 0; i < n; ++i)
    corner[order[i]] =
        i > 0 && key(order[i]) == key(order[i - 1]) ? corner[order[i - 1]] : order[i];
  struct Edge {
    uint64_t corners;
    uint32_t triangle;
  };
  std::vector<Edge> edges;
  edges.reserve(3 * triangles);
  for (size_t t = 0; t < triangles; ++t) {
    if (blend[t]) continue;
    for (size_t k = 0; k < 3; ++k) {
      const uint32_t a = corner[mesh.indices[3 * t + k]];
      const uint32_t b = corner[mesh.indices[3 * t + (k + 1) % 3]];
      if (a != b) edges.push_back({uint64_t(std::min(a, b)) << 32 | std::max(a, b), uint32_t(t)});
    }
  }
  std::sort(edges.begin(), edges.end(), [](const Edge& p, const Edge& q) {
    return p.corners < q.corners || (p.corners == q.corners && p.triangle < q.triangle);
  });
  std::vector<uint32_t> parent(triangles);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  // What opens a piece: an edge of one triangle, a cut-out material.
  std::vector<uint8_t> opens(triangles, 0);
  for (size_t i = 0; i < edges.size();) {
    size_t j = i + 1;
    while (j < edges.size() && edges[j].corners == edges[i].corners) ++j;
    if (j - i == 1) opens[edges[i].triangle] = 1;
    for (size_t e = i + 1; e < j; ++e) parent[find(edges[e].triangle)] = find(edges[i].triangle);
    i = j;
  }
  for (size_t t = 0; t < triangles; ++t) {
    const Material* m = materialAt(t);
    if (!blend[t] && m && m->cutOut()) opens[t] = 1;
  }
  std::vector<uint8_t> open(triangles, 0);
  for (size_t t = 0; t < triangles; ++t)
    if (opens[t]) open[find(uint32_t(t))] = 1;
  size_t opened = 0;
  for (size_t t = 0; t < triangles; ++t) {
    if (blend[t] || !open[find(uint32_t(t))]) continue;
    twoSided[t] = 1;
    ++opened;
  }
  if (std::none_of(twoSided.begin(), twoSided.end(), [](uint8_t s) { return s != 0; })) return 0;

  mesh.sides.assign(triangles, 0);
  std::vector<uint32_t> copyOf(mesh.positions.size(), UINT32_MAX);
  for (size_t t = 0; t < triangles; ++t) {
    if (!twoSided[t]) continue;
    mesh.sides[t] = Mesh::kFrontSide;
    // Its front is the side its normals face: rays meet only that side of it.
    uint32_t* tri = &mesh.indices[3 * t];
    const glm::vec3 facing = glm::cross(mesh.positions[tri[1]] - mesh.positions[tri[0]],
                                        mesh.positions[tri[2]] - mesh.positions[tri[0]]);
    if (glm::dot(facing, mesh.normals[tri[0]] + mesh.normals[tri[1]] + mesh.normals[tri[2]]) < 0.0f)
      std::swap(tri[1], tri[2]);
    const uint32_t m = mesh.triangleMaterial.empty() ? 0u : mesh.triangleMaterial[t];
    uint32_t c[3];
    for (int k = 0; k < 3; ++k) {
      const uint32_t v = mesh.indices[3 * t + size_t(k)];
      if (copyOf[v] == UINT32_MAX) {
        copyOf[v] = uint32_t(mesh.positions.size());
        mesh.positions.push_back(mesh.positions[v]);
        mesh.normals.push_back(-mesh.normals[v]);
        if (!mesh.texcoords.empty()) mesh.texcoords.push_back(mesh.texcoords[v]);
        if (!mesh.colors.empty()) mesh.colors.push_back(mesh.colors[v]);
        if (!mesh.alphas.empty()) mesh.alphas.push_back(mesh.alphas[v]);
      }
      c[k] = copyOf[v];
    }
    mesh.indices.insert(mesh.indices.end(), {c[0], c[2], c[1]});
    if (!mesh.triangleMaterial.empty()) mesh.triangleMaterial.push_back(m);
    mesh.sides.push_back(Mesh::kBackSide);
  }
  if (opened > 0) {
    mesh.warnings.push_back(
        (opened == triangles
             ? std::string("every triangle is")
             : std::to_string(opened) + " of " + std::to_string(triangles) + " triangles are") +
        " in an open piece (an edge of one triangle, or a cut-out material): its inside can be "
        "seen, and is shaded and shadowed as a surface of its own");
  }
  return opened;
}

namespace {

Mesh finish(detail::LoadedMesh loaded, const MeshOptions& options, const fs::path& path) {
  Mesh& mesh = loaded.mesh;
  if (mesh.indices.empty()) throw Error("mesh", "mesh has no triangles", path);
  COMPOSE_CHECK(mesh.indices.size() % 3 == 0);
  for (uint32_t i : mesh.indices) COMPOSE_CHECK(i < mesh.positions.size());
  COMPOSE_CHECK(mesh.triangleMaterial.empty() ||
                mesh.triangleMaterial.size() == mesh.triangleCount());
  COMPOSE_CHECK(mesh.texcoords.empty() || mesh.texcoords.size() == mesh.positions.size());
  COMPOSE_CHECK(mesh.colors.empty() || mesh.colors.size() == mesh.positions.size());
  COMPOSE_CHECK(mesh.alphas.empty() || mesh.alphas.size() == mesh.positions.size());
  loaded.hasNormal.resize(mesh.positions.size(), 0);
  mesh.normals.resize(mesh.positions.size(), glm::vec3(0.0f));

  dropUnrenderableTriangles(loaded, path);

  // Base colours are albedos, 0..1: more reflects more light than arrives, less is not light. A
  // value outside is clamped, a non-finite one replaced by the default, and both are said.
  {
    std::string first;
    size_t outside = 0;
    for (Material& m : mesh.materials) {
      const glm::vec3 given = m.baseColor;
      for (int c = 0; c < 3; ++c) {
        float& v = m.baseColor[c];
        v = std::isfinite(v) ? std::clamp(v, 0.0f, 1.0f) : kDefaultAlbedo;
      }
      if (m.baseColor != given) {
        if (outside++ == 0) {
          char text[160];
          std::snprintf(text, sizeof text, " ('%s': %g %g %g)", m.name.c_str(), double(given.x),
                        double(given.y), double(given.z));
          first = text;
        }
      }
    }
    if (outside) {
      mesh.warnings.push_back(detail::count(outside, "material has", "materials have") +
                              " a base colour outside 0..1" + first +
                              ": clamped to 0..1 (a value that is not a number: the default "
                              "albedo)");
    }
  }

  // Normals from the file: normalised; a zero or non-finite one is computed instead.
  size_t badNormals = 0, fileNormals = 0;
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    if (!loaded.hasNormal[i]) continue;
    glm::vec3& n = mesh.normals[i];
    const float len = glm::length(n);
    if (!std::isfinite(len) || !(len > 0.0f)) {
      loaded.hasNormal[i] = 0;
      ++badNormals;
      continue;
    }
    n /= len;
    ++fileNormals;
  }
  if (badNormals) {
    mesh.warnings.push_back(
        detail::count(badNormals, "normal in the file was", "normals in the file were") +
        " zero or not finite: computed instead");
  }
  const size_t vertices = mesh.positions.size();
  char crease[64];
  std::snprintf(crease, sizeof crease, "%g°", options.creaseDegrees);
  if (fileNormals == vertices) {
    mesh.normalsFromFile = true;
    mesh.normalsSource = "from the file";
  } else {
    if (fileNormals == 0) {
      const int flipped = orientConsistently(mesh);
      if (flipped > 0) {
        mesh.warnings.push_back("turned " + std::to_string(flipped) +
                                " triangles wound against their neighbours to face outwards");
      }
    }
    const NormalStats stats =
        computeNormals(mesh, loaded.hasNormal, loaded.smoothingGroup, options.creaseDegrees);
    mesh.normalsFromFile = false;
    mesh.normalsSource =
        std::string(fileNormals ? "from the file for " + std::to_string(fileNormals) + " of " +
                                      std::to_string(vertices) + " vertices; the others "
                    : badNormals ? "in the file but none usable: "
                                 : "not in the file: ") +
        "computed as smooth angle-weighted normals with a crease angle of " + crease;
    if (stats.added > 0) {
      mesh.normalsSource += " (" + detail::count(stats.added, "vertex", "vertices") +
                            " added where sharper edges meet)";
    }
    if (!loaded.smoothingGroup.empty()) mesh.normalsSource += " and the file's smoothing groups";
    if (stats.ridges > 0) {
      mesh.normalsSource += "; " + detail::count(stats.ridges, "sharper edge", "sharper edges") +
                            " on lines that end in a smooth surface shaded smooth";
    }
  }
  // Colours that are white wherever they are left (the coloured triangles dropped) say nothing.
  if (std::all_of(mesh.colors.begin(), mesh.colors.end(),
                  [](const glm::vec3& c) { return c == glm::vec3(1.0f); }))
    mesh.colors.clear();
  if (!mesh.colors.empty() && mesh.materials.empty()) {
    // The colours alone give the albedo.
    Material white;
    white.name = "vertex colours";
    mesh.materials.push_back(white);
    mesh.triangleMaterial.assign(mesh.triangleCount(), 0u);
  }
  if (mesh.materials.empty()) {
    mesh.triangleMaterial.clear();
    mesh.textures.clear();
  }
  bool textured = false;
  for (const Material& m : mesh.materials) textured = textured || m.texture >= 0;
  if (!textured) mesh.texcoords.clear();
  // Vertex alpha matters to cut-out and semi-transparent materials only, and only below 1.
  if (!mesh.hasCutouts() ||
      std::all_of(mesh.alphas.begin(), mesh.alphas.end(), [](float a) { return a == 1.0f; }))
    mesh.alphas.clear();
  return std::move(loaded.mesh);
}

// Geomview's bicubic Bézier patches ("BBP": 16 control points of 3 numbers per patch, rows of
// four), such as the Newell teapot of its sample data. Each patch is tessellated into
// kSteps x kSteps quads; vertices on shared patch edges coincide exactly (a Bézier patch's edge
// depends on its edge control points only) and are welded. Geomview's models are Z-up: they are
// turned to this project's Y-up frame, (x, y, z) → (x, z, -y). Normals are computed afterwards.
detail::LoadedMesh loadBezierPatches(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw Error("mesh", withSystemReason("cannot open", errno), path);
  std::string header;
  if (!(in >> header) || header != "BBP") {
    throw Error(
        "mesh",
        "not a Geomview bicubic patch file: expected the keyword BBP, found '" + header + "'",
        path);
  }
  std::vector<glm::dvec3> control;
  std::string token;
  std::vector<double> numbers;
  while (in >> token) {
    char* end = nullptr;
    const double v = std::strtod(token.c_str(), &end);
    if (end != token.c_str() + token.size() || !std::isfinite(v)) {
      throw Error("mesh", "'" + token + "' is not a finite number", path);
    }
    numbers.push_back(v);
    // Every 48 numbers make a patch of 2 kSteps² triangles: refuse a file beyond the limit early.
    if (numbers.size() % 48 == 0) checkTriangleCount(int64_t(numbers.size() / 48) * 512, path);
  }
  if (numbers.empty() || numbers.size() % 48 != 0) {
    throw Error("mesh",
                "a bicubic patch file holds 16 points of 3 numbers per patch; this one has " +
                    std::to_string(numbers.size()) + " numbers",
                path);
  }
  constexpr int kSteps = 16;
  const glm::dmat3 zUp = meshFromFileAxes(path);  // the patches are Z up
  static_assert(2 * kSteps * kSteps == 512, "the triangle count checked while reading");
  auto bernstein = [](double t, double b[4]) {
    const double s = 1.0 - t;
    b[0] = s * s * s;
    b[1] = 3.0 * t * s * s;
    b[2] = 3.0 * t * t * s;
    b[3] = t * t * t;
  };
  detail::LoadedMesh loaded;
  Mesh& mesh = loaded.mesh;
  std::map<std::array<float, 3>, uint32_t> weld;
  const size_t patches = numbers.size() / 48;
  for (size_t patch = 0; patch < patches; ++patch) {
    const double* c = numbers.data() + patch * 48;
    std::vector<uint32_t> ids;
    for (int i = 0; i <= kSteps; ++i) {
      double bu[4];
      bernstein(double(i) / kSteps, bu);
      for (int j = 0; j <= kSteps; ++j) {
        double bv[4];
        bernstein(double(j) / kSteps, bv);
        glm::dvec3 p(0.0);
        for (int a = 0; a < 4; ++a)
          for (int b = 0; b < 4; ++b) {
            const double* q = c + 3 * (4 * a + b);
            p += bu[a] * bv[b] * glm::dvec3(q[0], q[1], q[2]);
          }
        const glm::dvec3 turned = zUp * p;
        const std::array<float, 3> key = {float(turned.x), float(turned.y), float(turned.z)};
        auto [it, inserted] = weld.try_emplace(key, uint32_t(mesh.positions.size()));
        if (inserted) mesh.positions.emplace_back(key[0], key[1], key[2]);
        ids.push_back(it->second);
      }
    }
    for (int i = 0; i < kSteps; ++i) {
      for (int j = 0; j < kSteps; ++j) {
        const uint32_t a = ids[size_t(i * (kSteps + 1) + j)];
        const uint32_t b = ids[size_t(i * (kSteps + 1) + j + 1)];
        const uint32_t cc = ids[size_t((i + 1) * (kSteps + 1) + j)];
        const uint32_t d = ids[size_t((i + 1) * (kSteps + 1) + j + 1)];
        mesh.indices.insert(mesh.indices.end(), {a, cc, d, a, d, b});
      }
    }
  }
  return loaded;
}

}  // namespace

void computeVertexNormals(Mesh& mesh, double creaseDegrees) {
  std::vector<uint8_t> fromFile(mesh.positions.size(), 0);
  computeNormals(mesh, fromFile, {}, creaseDegrees);
  mesh.normalsFromFile = false;
}

std::vector<uint32_t> triangulatePolygon(const std::vector<glm::vec3>& corners) {
  const size_t n = corners.size();
  std::vector<uint32_t> out;
  if (n < 3) return out;
  if (n == 3) return {0, 1, 2};
  // Newell's normal: the polygon's area vector, robust for non-planar and concave polygons.
  glm::dvec3 normal(0.0);
  for (size_t i = 0; i < n; ++i) {
    const glm::dvec3 a(corners[i]), b(corners[(i + 1) % n]);
    normal +=
        glm::dvec3((a.y - b.y) * (a.z + b.z), (a.z - b.z) * (a.x + b.x), (a.x - b.x) * (a.y + b.y));
  }
  const double area = glm::length(normal);
  auto fan = [&] {
    for (uint32_t i = 1; i + 1 < n; ++i) out.insert(out.end(), {0u, i, i + 1});
    return out;
  };
  if (!(area > 0.0) || !std::isfinite(area)) return fan();
  normal /= area;
  // 2D coordinates in the polygon's plane, counter-clockwise about the normal.
  const glm::dvec3 helper =
      std::abs(normal.x) < 0.9 ? glm::dvec3(1.0, 0.0, 0.0) : glm::dvec3(0.0, 1.0, 0.0);
  const glm::dvec3 ex = glm::normalize(glm::cross(helper, normal));
  const glm::dvec3 ey = glm::cross(normal, ex);
  std::vector<glm::dvec2> q(n);
  for (size_t i = 0; i < n; ++i) {
    const glm::dvec3 p(corners[i]);
    q[i] = glm::dvec2(glm::dot(p, ex), glm::dot(p, ey));
  }
  auto cross2 = [](const glm::dvec2& o, const glm::dvec2& a, const glm::dvec2& b) {
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
  };
  // Tolerance for "on the left" in units of the polygon's area.
  const double eps = 1e-12 * area;
  if (n == 4) {
    // A quad: the 0-2 diagonal (as most modelling tools split quads) unless it lies outside.
    const bool valid02 = cross2(q[0], q[1], q[2]) > eps && cross2(q[0], q[2], q[3]) > eps;
    if (valid02) return {0, 1, 2, 0, 2, 3};
    const bool valid13 = cross2(q[1], q[2], q[3]) > eps && cross2(q[1], q[3], q[0]) > eps;
    if (valid13) return {0, 1, 3, 1, 2, 3};
    return {0, 1, 2, 0, 2, 3};
  }
  // Ear clipping: cut off a convex corner whose triangle holds no other corner, until three
  // remain. The search resumes beside the last ear and tests only reflex corners, so ordinary
  // polygons take O(n²) time.
  std::vector<uint32_t> ring(n);
  for (size_t i = 0; i < n; ++i) ring[i] = uint32_t(i);
  auto inside = [&](const glm::dvec2& p, const glm::dvec2& a, const glm::dvec2& b,
                    const glm::dvec2& c) {
    return cross2(a, b, p) >= -eps && cross2(b, c, p) >= -eps && cross2(c, a, p) >= -eps;
  };
  size_t start = 0;  // where the search for the next ear begins: next to the last one
  std::vector<uint32_t> reflex;
  while (ring.size() > 3) {
    const size_t m = ring.size();
    // Only reflex (or flat) corners can lie inside an ear.
    reflex.clear();
    for (size_t j = 0; j < m; ++j)
      if (!(cross2(q[ring[(j + m - 1) % m]], q[ring[j]], q[ring[(j + 1) % m]]) > eps))
        reflex.push_back(ring[j]);
    size_t ear = m;
    for (size_t tried = 0; tried < m && ear == m; ++tried) {
      const size_t i = (start + tried) % m;
      const uint32_t a = ring[(i + m - 1) % m], b = ring[i], c = ring[(i + 1) % m];
      if (!(cross2(q[a], q[b], q[c]) > eps)) continue;  // reflex or flat corner
      bool empty = true;
      for (size_t j = 0; j < reflex.size() && empty; ++j) {
        const uint32_t p = reflex[j];
        if (p == a || p == b || p == c) continue;
        if (q[p] == q[a] || q[p] == q[b] || q[p] == q[c]) continue;  // a repeated corner
        empty = !inside(q[p], q[a], q[b], q[c]);
      }
      if (empty) ear = i;
    }
    if (ear == m) {
      // No ear (a self-intersecting or numerically flat outline): cut the most convex corner.
      double best = -std::numeric_limits<double>::infinity();
      for (size_t i = 0; i < m; ++i) {
        const double turn = cross2(q[ring[(i + m - 1) % m]], q[ring[i]], q[ring[(i + 1) % m]]);
        if (turn > best) {
          best = turn;
          ear = i;
        }
      }
    }
    out.insert(out.end(), {ring[(ear + m - 1) % m], ring[ear], ring[(ear + 1) % m]});
    ring.erase(ring.begin() + std::ptrdiff_t(ear));
    start = ear == 0 ? 0 : ear - 1;
  }
  out.insert(out.end(), {ring[0], ring[1], ring[2]});
  return out;
}

int orientConsistently(Mesh& mesh) {
  const size_t triangles = mesh.triangleCount();
  if (triangles == 0) return 0;
  // Corners by position, so that vertices split by normals or texture seams count as one.
  std::map<std::array<float, 3>, uint32_t> ids;
  std::vector<uint32_t> id(mesh.positions.size());
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const glm::vec3& p = mesh.positions[i];
    id[i] = ids.try_emplace({p.x, p.y, p.z}, uint32_t(ids.size())).first->second;
  }
  auto corner = [&](size_t t, int k) { return id[mesh.indices[3 * t + size_t(k)]]; };
  std::unordered_map<uint64_t, std::vector<uint32_t>> edges;  // undirected edge → triangles
  auto edgeKey = [](uint32_t a, uint32_t b) {
    return (uint64_t(std::min(a, b)) << 32) | std::max(a, b);
  };
  for (size_t t = 0; t < triangles; ++t)
    for (int k = 0; k < 3; ++k)
      edges[edgeKey(corner(t, k), corner(t, (k + 1) % 3))].push_back(uint32_t(t));
  // Whether triangle t, as currently wound, runs from a to b.
  auto runs = [&](size_t t, bool flip, uint32_t a, uint32_t b) {
    for (int k = 0; k < 3; ++k) {
      uint32_t u = corner(t, k), v = corner(t, (k + 1) % 3);
      if (flip) std::swap(u, v);
      if (u == a && v == b) return true;
    }
    return false;
  };
  std::vector<int8_t> state(triangles, -1);  // -1 unvisited, 0 keep, 1 flip
  int flippedTotal = 0;
  for (size_t seed = 0; seed < triangles; ++seed) {
    if (state[seed] >= 0) continue;
    // Walk the connected piece, winding each neighbour against the shared edge.
    std::vector<uint32_t> piece = {uint32_t(seed)}, queue = {uint32_t(seed)};
    state[seed] = 0;
    while (!queue.empty()) {
      const uint32_t t = queue.back();
      queue.pop_back();
      for (int k = 0; k < 3; ++k) {
        uint32_t a = corner(t, k), b = corner(t, (k + 1) % 3);
        if (state[t]) std::swap(a, b);  // t runs a → b
        for (uint32_t n : edges[edgeKey(a, b)]) {
          if (n == t || state[n] >= 0) continue;
          // A consistent neighbour runs b → a.
          state[n] = runs(n, false, a, b) ? 1 : 0;
          piece.push_back(n);
          queue.push_back(n);
        }
      }
    }
    // Outwards: the piece's signed volume about its own centre must be positive.
    glm::dvec3 centre(0.0);
    for (uint32_t t : piece)
      for (int k = 0; k < 3; ++k)
        centre += glm::dvec3(mesh.positions[mesh.indices[3 * t + size_t(k)]]);
    centre /= double(3 * piece.size());
    double volume = 0.0;
    for (uint32_t t : piece) {
      glm::dvec3 p[3];
      for (int k = 0; k < 3; ++k)
        p[k] = glm::dvec3(mesh.positions[mesh.indices[3 * t + size_t(k)]]) - centre;
      if (state[t]) std::swap(p[1], p[2]);
      volume += glm::dot(p[0], glm::cross(p[1], p[2]));
    }
    const bool invert = volume < 0.0;
    for (uint32_t t : piece) {
      const bool flip = (state[t] != 0) != invert;
      if (flip) {
        std::swap(mesh.indices[3 * size_t(t) + 1], mesh.indices[3 * size_t(t) + 2]);
        ++flippedTotal;
      }
    }
  }
  return flippedTotal;
}

glm::dmat3 meshFromFileAxes(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  if (ext != ".bez") return glm::dmat3(1.0);
  // Columns: where the file's x, y and z axes go. Z up -> Y up.
  return glm::dmat3(glm::dvec3(1, 0, 0), glm::dvec3(0, 0, -1), glm::dvec3(0, 1, 0));
}

Mesh loadMesh(const fs::path& path, const MeshOptions& options) {
  COMPOSE_CHECK(options.creaseDegrees >= 0.0 && options.creaseDegrees <= 180.0);
  protectInput(path);
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("mesh", "file not found", path);
  if (fs::is_directory(path, ec)) throw Error("mesh", "is a folder, expected a mesh file", path);
  requireRegularFile(path, "mesh");
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  detail::LoadedMesh loaded;
  if (ext == ".obj") {
    loaded = detail::loadObj(path);
  } else if (ext == ".gltf" || ext == ".glb") {
    loaded = detail::loadGltf(path);
  } else if (ext == ".bez") {
    loaded = loadBezierPatches(path);
  } else {
    throw Error("mesh", "unsupported mesh format '" + ext + "'; supported: .obj, .gltf, .glb, .bez",
                path);
  }
  return finish(std::move(loaded), options, path);
}

}  // namespace compose::render
