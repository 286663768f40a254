// Triangle meshes for rendering: loading, validation, normals, materials.
//
// loadMesh() reads, by the file's extension:
//  * Wavefront OBJ (.obj, through tinyobjloader): groups and objects are merged into one mesh;
//    polygons of any size are triangulated (ear clipping in the polygon's own plane, so concave
//    ones stay inside their outline); `mtllib`/`usemtl` materials give each face a base colour
//    (`Kd`) and an albedo texture (`map_Kd`, with its `-s`, `-o` and `-clamp` options, found
//    from its library's folder). The lines are read as Blender reads them: a UTF-8 byte-order
//    mark skipped, a line ending in a backslash joined to the next, a material's whole name
//    (spaces included), Windows separators in paths; `d` (not `Tr`) and a `map_d` naming
//    `map_Kd`'s file (its alpha channel) make a material semi-transparent (BLEND). `Kd` is
//    taken as linear Rec.709, the way Blender writes and reads it; a `map_Kd` image is decoded as
//    the colour space its file declares (sRGB for 8-bit images). `map_Kd` multiplies `Kd`, as the
//    MTL format defines it. Smoothing groups (`s`) of a file without normals split the computed
//    normals: faces in different groups meet at a sharp edge, and faces in no group (`s off`)
//    are flat.
//  * glTF 2.0 (.gltf with its buffers and images, or binary .glb, through tinygltf): the default
//    scene (else the first; else every root node) with its node hierarchy flattened into object
//    space (translation/rotation/scale or matrix, a node mirrored by a negative determinant keeps
//    its triangles wound outwards); every mesh and primitive: triangles, strips and fans (points
//    and lines are skipped with a warning), indexed (8-, 16- or 32-bit) or not, POSITION, NORMAL
//    and the TEXCOORD set the base-colour texture uses, in any component type (normalised
//    integers included, as KHR_mesh_quantization writes them) and with sparse accessors. The
//    metallic-roughness material gives the base colour: `baseColorFactor` (linear Rec.709) times
//    `baseColorTexture` (sRGB unless its image declares otherwise), with the texture's sampler
//    wrap modes and KHR_texture_transform; alphaMode MASK cuts the surface away where the base
//    colour's alpha (factor x texture x COLOR_0's alpha) is below alphaCutoff
//    (Material::alphaCutoff); BLEND makes it semi-transparent (Material::blend). COLOR_0
//    multiplies the base colour. A file that requires an extension compose cannot honour
//    (Draco or meshopt compression, ...) is an error naming it. Skins and morph targets are
//    ignored with a warning (skinned meshes render in their bind pose).
//  * Geomview bicubic Bézier patches (.bez), tessellated (see mesh.cpp).
//
// Normals. Normals in the file are kept (normalised). Vertices without one get smooth normals:
// the angle-weighted mean of the faces around the vertex that are joined to it by edges no
// sharper than MeshOptions::creaseDegrees (the angle between the two faces' normals); a vertex
// where sharper edges meet is split, one copy per smooth fan. Sharper edges split only along
// crease lines: a line of edges less than 25° sharper than the crease that stops in the middle of
// a smooth surface (a ridge of a scan) is shaded smooth (mesh.cpp). 0° gives flat faces (what the
// glTF specification asks for when a primitive has no normals), 180° one smooth normal per
// position. Before normals are computed for a mesh that has none, every connected piece is wound
// one way and outwards (orientConsistently()).
//
// Robustness. Real files are untrusted input. What can be dropped is dropped with a warning that
// counts it (Mesh::warnings; loading never prints): faces that refer to vertices the file does not
// have, triangles with a non-finite corner, degenerate and duplicate triangles, zero or
// non-finite normals (recomputed), unreadable material libraries and textures (the material
// renders with its base colour), primitives with broken accessors. A mesh with nothing renderable
// left, a file that cannot be parsed, and (in OBJ) a malformed number are errors. Errors throw
// compose::Error (stage "mesh") naming the file and what is wrong.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <glm/mat3x3.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "core/image.h"

namespace compose::render {

// An albedo texture: RGB float in `image.colorSpace` (the colour space its file declares, or
// empty when the file declares none; the pipeline converts it to the working space, or to the
// base colours' space (Mesh::albedoToWorking), before rendering), sampled bilinearly at texture
// coordinates (u to the right, v up: v = 0 is the image's bottom row, as in OBJ; the glTF loader
// stores 1 - v so that this holds).
struct Texture {
  enum class Wrap { Repeat, Clamp, Mirror };
  std::filesystem::path file;  // the image file, or a description of where an embedded one was
  Image image;
  // The file's alpha (straight, one channel, the image's size): empty when it has none or it is
  // 1 everywhere. Only a cut-out material (Material::alphaCutoff) reads it.
  Image alpha;
  Wrap wrapU = Wrap::Repeat, wrapV = Wrap::Repeat;
  // Magnified as blocks of texels (glTF's magFilter NEAREST: pixel art, label atlases) instead of
  // bilinearly.
  bool nearest = false;
  // The format says the colour is sRGB-encoded whatever the image file says (glTF's base colour
  // textures): the file's own tag (a PNG's gAMA) is not followed.
  bool srgbByFormat = false;
  // The pipeline has converted it (pipeline/materials.h): a second conversion leaves it alone.
  bool converted = false;
  // Its mip levels for minification (buildMipLevels): level k is level k - 1 halved, area
  // averaged, down to 1 x 1; level 0 is `image`. Empty until built: only `image` is then
  // sampled, however small the texture appears.
  std::vector<Image> levels;  // levels 1, 2, ...
  // For a cut-out material using it: the levels 1, 2, ... of its colour weighted by what the
  // cut-out keeps of each texel, and those weights at levels 0, 1, 2, ... (so that texels that
  // are not there do not tint the ones that are). Empty when no cut-out uses it.
  std::vector<Image> keptLevels, keptWeights;
};

// Builds `texture`'s mip levels from its image as it is: call it once the colour is in the space
// it is filtered in (linear: the working space, or the base colours' space). `keptFrom`, for a
// texture with alpha that a cut-out material uses: its alphaCutoff (MASK: a texel is kept whole
// where its alpha reaches it), or negative for a semi-transparent material (BLEND: its alpha is
// what is kept).
void buildMipLevels(Texture& texture, std::optional<float> keptFrom = std::nullopt);

// A diffuse material: the albedo is baseColor times the texture's colour (when there is one).
// baseColor is linear, in the colour space named by Mesh::colorSpace.
struct Material {
  std::string name;
  glm::vec3 baseColor{1.0f};
  int texture = -1;  // index into Mesh::textures, or -1
  // Applied to (u, v, 1) before the texture is sampled (OBJ's -s/-o, glTF's
  // KHR_texture_transform), in this file's convention (v up).
  glm::mat3 uvTransform{1.0f};
  // A cut-out (glTF's alphaMode MASK): where baseAlpha times the texture's alpha is below
  // alphaCutoff the surface is not there (rays pass through it: the camera's, the shadows').
  // Negative: opaque.
  float alphaCutoff = -1.0f;
  float baseAlpha = 1.0f;
  // Semi-transparent (glTF's alphaMode BLEND): the surface covers alpha (baseAlpha times the
  // texture's) of what lies behind it. The camera's rays go on through it layer by layer, shadow
  // rays carry 1 - alpha through it, and boolean queries find it with a probability of alpha
  // (Mesh::passes; embree_scene.h). Where alpha is 0 it is not there at all. Seen from
  // both sides: the pipeline gives each of its triangles a back side of its own (addBackSides).
  bool blend = false;
  // Rays can pass through the surface somewhere (MASK or BLEND).
  bool cutOut() const { return alphaCutoff >= 0.0f || blend; }
};

// The albedo of faces that have no material in a mesh where others have one (and the default of
// --albedo): a mid grey.
inline constexpr float kDefaultAlbedo = 0.5f;

struct Mesh {
  std::vector<glm::vec3> positions;  // object space
  // Where the object space's origin lies in the mesh file's own coordinates (file = positions +
  // fileOrigin): zero unless the loader moved a mesh lying far from its file's origin.
  glm::dvec3 fileOrigin{0.0};
  std::vector<glm::vec3> normals;     // unit, one per position
  std::vector<uint32_t> indices;      // three per triangle, counter-clockwise seen from outside
  bool normalsFromFile = false;       // every normal came from the file
  std::string normalsSource;          // how the normals were obtained, for the user
  std::vector<std::string> warnings;  // what loading dropped, ignored or repaired, for the user
  // Every file besides the mesh file itself that loading read or looked for (material
  // libraries, textures, glTF buffers and images): empty when the mesh file alone gives the mesh.
  std::vector<std::filesystem::path> otherFiles;

  // Materials: empty when the file has none (the renderer then uses --albedo everywhere).
  std::vector<glm::vec2> texcoords;  // one per position, or empty
  // Vertex colours (glTF's COLOR_0, OBJ's `v x y z r g b`), linear in `colorSpace`, one per
  // position or empty: they multiply the material's albedo. A mesh with colours and no
  // materials gets one white material, so that its colours are its albedo.
  std::vector<glm::vec3> colors;
  // Their alpha (glTF's COLOR_0 RGBA), one per position or empty: it multiplies the alpha of a
  // cut-out or semi-transparent material (Material::cutOut()); empty when no such material
  // uses it or it is 1 everywhere.
  std::vector<float> alphas;
  std::vector<uint32_t> triangleMaterial;  // one per triangle, or empty (all material 0)
  // Per triangle, or empty when none has a back side of its own (addBackSides): 0 for a
  // triangle that rays meet from either side; kFrontSide for one that rays meet from its front
  // only, its back being a triangle of its own, appended after the mesh's others and marked
  // kBackSide.
  std::vector<uint8_t> sides;
  static constexpr uint8_t kFrontSide = 1, kBackSide = 2;
  std::vector<Material> materials;
  std::vector<Texture> textures;
  // The colour space of the base colours (linear); textures carry their own. The pipeline
  // converts both to the working space before rendering, or textures to the base colours' space
  // and the product by `albedoToWorking`.
  std::string colorSpace = "lin_rec709";
  // The albedo's last step, factor x texture x vertex colour being multiplied in the space they
  // are given in (glTF's linear Rec.709) and the product converted, as glTF defines it: the
  // product of the converted factors is another colour wherever the conversion mixes channels
  // (a texture's red under a blue-ish factor came out 60 % too bright in ACEScg).
  glm::mat3 albedoToWorking{1.0f};
  bool convertsAlbedo = false;

  size_t triangleCount() const { return indices.size() / 3; }
  // The triangles without the back sides addBackSides() added: those the file gave.
  size_t frontTriangleCount() const;
  glm::vec3 boundsMin() const;
  glm::vec3 boundsMax() const;
  bool hasMaterials() const { return !materials.empty(); }
  // The albedo at barycentrics (u, v) of `triangle` (Embree's: u for corner 1, v for corner 2):
  // its material's base colour times its texture at the interpolated texture coordinates, times
  // the interpolated vertex colour. Only meaningful when hasMaterials().
  glm::vec3 albedoAt(uint32_t triangle, float u, float v) const;
  // The same, its texture filtered over a sample's footprint, whose edges (across and down the
  // image) span dPdx and dPdy on the triangle's plane (object space): the mip level whose texels
  // are the footprint's width, with up to 8 taps along its length where it is elongated (a surface
  // seen at a grazing angle). The footprint's texels are averaged instead of one being picked: a
  // texture finer than the samples does not alias into grain.
  glm::vec3 albedoAt(uint32_t triangle, float u, float v, const glm::vec3& dPdx,
                     const glm::vec3& dPdy) const;
  // Point p at barycentrics (u, v) of `triangle`, lifted towards the smooth surface that its
  // vertex normals describe (Hanika 2021, "Hacking the shadow terminator"):
  // p + Σ w_i max(0, (v_i - p)·n_i) n_i, the vertex normals n_i turned round for `back`. Where
  // the surface bulges (the vertices' tangent planes pass above p) a flat triangle lies inside
  // the surface it stands for; rays to the light leave from here, so that the coarse facets next
  // to it do not cast hard-edged shadows across smooth shading near the terminator. Where it is
  // hollow, p itself (at a saddle, the bulging corners' share). The lift is at most an eighth of
  // the triangle's longest edge; whoever traces from the point checks that nothing of the object
  // lies between p and it (transfer.h: keepLiftsClear).
  glm::vec3 smoothPoint(uint32_t triangle, float u, float v, const glm::vec3& p,
                        bool back = false) const;
  // Some material is a cut-out or semi-transparent (Material::cutOut()).
  bool hasCutouts() const;
  // Whether the point at barycentrics (u, v) of `triangle` is cut away: its material is a
  // cut-out and its alpha there is below the cutoff, or semi-transparent and its alpha is 0.
  bool cutAway(uint32_t triangle, float u, float v) const;
  // Whether a ray whose random number (uniform in [0, 1)) is `xi` passes through the point:
  // cutAway() for a cut-out; for a semi-transparent material, where alpha <= xi (with
  // probability 1 - alpha).
  bool passes(uint32_t triangle, float u, float v, float xi) const;
  // The alpha at the point: its material's base alpha times its texture's (1 for a material
  // that is neither a cut-out nor semi-transparent, and where there are no materials).
  float alphaAt(uint32_t triangle, float u, float v) const;
  // Rays meet the triangle from its front only: it has a back side of its own (addBackSides),
  // or is one.
  bool oneSided(uint32_t triangle) const;
  // Its material is semi-transparent (Material::blend).
  bool semiTransparent(uint32_t triangle) const;
  // The bounds of the surface that is there: boundsMin/Max, but with cut-outs those of what they
  // keep. A cut-out triangle whose alpha cannot vary (no alpha texture, texture coordinates that
  // do not move) is there whole or not at all; another is tested on a grid of about two points
  // per texel of its alpha along its longest edge (grids coarsened to keep to about `budget`
  // points in all, but never below a triangle's corners; what is kept between grid points is not
  // seen). The object stands on, and is sized by, these bounds.
  // Returns false when the cut-outs keep nothing (the whole mesh's box is given then).
  bool keptBounds(glm::vec3& lo, glm::vec3& hi, size_t budget = 1u << 20) const;
};

struct MeshOptions {
  // Vertices without a normal in the file get the mean normal of the faces around them that are
  // joined by edges of at most this dihedral angle (degrees, 0..180).
  double creaseDegrees = 60.0;
};

Mesh loadMesh(const std::filesystem::path& path, const MeshOptions& options = {});

// The turn loadMesh() gives a format's axes, from the file's coordinates to the mesh's (Y up):
// Geomview's .bez patches are Z up, (x, y, z) -> (x, z, -y); the identity for the others. The
// mesh's fileOrigin is taken off after it.
glm::dmat3 meshFromFileAxes(const std::filesystem::path& path);

// Smooth vertex normals for every vertex (see the header comment): the angle-weighted mean of the
// adjacent face normals across edges of at most `creaseDegrees`, vertices split where sharper
// edges meet on crease lines. Positions are welded by value first, so that vertices split by
// texture seams are smoothed as one.
void computeVertexNormals(Mesh& mesh, double creaseDegrees = 180.0);

// Surfaces seen from both sides get a back side of their own: a triangle after the mesh's
// others, over its own vertices (normals turned round) and wound the other way, so that each
// side has its own surface points and its own shadows; rays meet only the side that faces them
// (Mesh::oneSided, Mesh::sides). Without it the inside of an open box would be shaded with the
// visibility of its outside: lit as if nothing hid the sky from it. These are
// - semi-transparent triangles (Material::blend): through them the inside of a glass box
//   faces the camera;
// - every connected piece of the others (triangles joined by edges, corners by position) that
//   is open: one with an edge of a single triangle (a sheet, a cup without thickness, a mesh
//   with a hole), or where a semi-transparent triangle or a cut-out material (a window, a
//   leaf's outline) lets the camera see in. A triangle whose vertex normals point against its
//   winding is first wound to agree with them, so that its front is the side its normals face.
// Returns the number of triangles of open pieces given a back side (and says so in the mesh's
// warnings). For rendering: loadMesh() gives the triangles the file has, the pipeline adds their
// back sides once it has read the mesh.
size_t addBackSides(Mesh& mesh);

// Winds every connected piece of the mesh one way (each triangle against its neighbours across
// shared edges), then outwards (a positive signed volume about the piece's centre). Used for
// meshes whose normals are computed, where a triangle wound the wrong way would turn its corner
// normals inside out. Returns how many triangles were turned.
int orientConsistently(Mesh& mesh);

// Triangulates one polygon (corners in order, roughly planar, convex or not) by ear clipping in
// the plane of its Newell normal; quads take the 0-2 diagonal unless that lies outside them.
// Returns corner-index triples wound like the polygon. A polygon with no area is split as a fan
// (its triangles are degenerate and dropped later).
std::vector<uint32_t> triangulatePolygon(const std::vector<glm::vec3>& corners);

}  // namespace compose::render
