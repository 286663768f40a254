// Reading and writing environment maps in every layout of layouts.h.
//
// Reading. One input names an image file, a folder holding six face files, one face file (its
// five siblings are found by name: env_px.exr → env_nx.exr, ...), or a name pattern in which '%'
// stands for the face (env_%.exr, or exrenvmap's env%.exr → env+X.exr ...). Six inputs are six
// face files: recognised by name, or else taken in OpenEXR's order +X -X +Y -Y +Z -Z (and the
// caller is told). A single image's layout comes from, in order: the caller's explicit layout;
// the OpenEXR `envmap` header attribute (latlong or cube); the aspect ratio where it is
// unambiguous (layouts.h). Every decision is reported in `EnvironmentFile::how`.
//
// Writing. Lat-long maps and OpenEXR cube strips go to EXR through OpenEXR itself, so that the
// `envmap` attribute is set (latlong or cube) and other OpenEXR tools (exrenvmap, Nuke) recognise
// them; crosses and face files go to any format OpenImageIO writes (EXR, HDR, TIFF, PNG...).
// Outputs are registered with an OutputFiles, so a command's files appear together or not at all.
//
// Errors (missing or duplicate faces, faces of different sizes, non-square faces, a layout that
// does not fit the image, an undecidable layout) throw compose::Error with stage "ingest" and the
// file; write errors use stage "output".
#pragma once

#include <array>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/output_files.h"
#include "core/progress.h"
#include "cubemap/layouts.h"
#include "ingest/image_io.h"
#include "lighting/cubemap.h"
#include "lighting/environment.h"

namespace compose::cubemap {

struct ReadOptions {
  std::optional<Layout> layout;  // forced layout (--layout); nullopt: detect
  // When the layout cannot be detected, the error tells how to give it: with --layout (false), or
  // by converting the file first with compose convert (true: a command without --layout).
  bool adviseConvert = false;
};

struct EnvironmentFile {
  Layout layout = Layout::LatLong;
  std::string how;  // how the layout was decided, for the user ("aspect 4:3", "envmap attribute")
  std::vector<std::filesystem::path> files;  // as read; for six face files, in face order
  // LatLong and MirrorBall: the image as read; cube layouts: the faces. Both RGB, from the
  // picture's channels by name (pictureRgb: a layer's beauty.R, G, B; Y alone; Y, RY, BY).
  Image image;
  std::array<Image, lighting::kCubeFaces> faces;
  ingest::CaptureInfo info;        // of the first file
  std::vector<std::string> notes;  // what reading changed (LoadedImage::notes)

  bool isCube() const { return layout != Layout::LatLong && layout != Layout::MirrorBall; }
  // "vertical cross, faces 256²" / "lat-long 1024x512".
  std::string describe() const;
};

EnvironmentFile readEnvironmentFile(const std::vector<std::filesystem::path>& inputs,
                                    const ReadOptions& options = {});

// The files whose contents an environment input depends on, without reading any pixels: the
// six faces of a folder or a '%' pattern, a face file and its siblings, or the one file. Throws
// compose::Error (stage "ingest") for a missing file or face.
std::vector<std::filesystem::path> environmentFiles(const std::filesystem::path& input);

// The layout an EXR's `envmap` attribute declares; nullopt for other files or no attribute.
std::optional<Layout> exrEnvmapLayout(const std::filesystem::path& file);

// The file's cube map: faces validated and sanitised (lighting::CubeMap::fromFaces).
lighting::CubeMap cubeMapOf(const EnvironmentFile& file,
                            lighting::SanitizeReport* report = nullptr);

// What the one-shot pipeline needs from --env: the environment as a lat-long RGB(A) image with
// values as stored (colour conversion is the caller's), its capture metadata, the file whose name
// the colour rules should look at, and notes for the user. Cube layouts are resampled exactly
// (lighting/sphere_resample.h) to a lat-long map of width 4N; mirror balls are refused (convert
// them first: compose convert --from mirrorball).
// Resampling averages light, so a cube's faces are brought to linear light first when `toLinear`
// is given: it converts a face in place (its colour space set; `info` and `file` are the set's,
// as the colour rules read them) and says how it read it. Without
// it, faces are resampled as stored (right for linear light only: the sRGB codes of a PNG cross
// averaged as stored lose light, a checker of 0 and 255 by 30 %).
struct LoadedEnvironment {
  Image image;
  ingest::CaptureInfo info;
  std::filesystem::path file;
  std::vector<std::string> notes;
  // What toLinear said of the faces: the image is already in its space. Empty: values as stored.
  std::string linearised;
};
using FaceToLinear = std::function<std::string(Image& face, const ingest::CaptureInfo& info,
                                               const std::filesystem::path& file)>;
LoadedEnvironment loadEnvironment(const std::filesystem::path& path,
                                  const ReadOptions& options = {}, const Progress& progress = {},
                                  const FaceToLinear& toLinear = {});

struct WriteOptions {
  enum class Depth {
    Auto,
    Half,
    Float
  } depth = Depth::Auto;  // Auto: half unless a value
                          // exceeds half's range (65504)
  int faceNaming = 0;     // layouts.h parseFaceNaming; for Layout::Faces
  // OpenEXR only: the chromaticities of the RGB channels (red, green, blue, white xy), written
  // with the colour-space name (the image's, as the string attribute `colorSpace`), as
  // ingest::writeImage does.
  std::optional<std::array<double, 8>> chromaticities;
  // OpenEXR only: the compression, as OpenImageIO names it (ingest::parseExrCompression).
  std::string exrCompression = "piz";
  // The map was made from pictures of 8- or 16-bit codes (stitched photos): written into codes
  // (PNG, JPEG, TIFF), values above 1 (a clipped sky times an exposure gain) are clipped to 1 with
  // a note. Otherwise such a file is refused when the map holds values above 1.
  bool fromCodes = false;
  // The map was made from 16-bit codes: a PNG or TIFF is written with 16 bits (else 8).
  bool sixteenBit = false;
  // OpenEXR only: string attributes to carry (Make, Model, compose:exposureUnit).
  std::vector<std::pair<std::string, std::string>> strings;
};

// Writes a lat-long environment to `path` (EXR gets envmap=latlong). Returns a note when the depth
// was chosen for the user (Auto went to float).
std::vector<std::string> writeLatLong(OutputFiles& outputs, const std::filesystem::path& path,
                                      const lighting::Environment& environment,
                                      const WriteOptions& options = {});
// Writes a cube map in `layout` (Cube: one EXR, envmap=cube; crosses: one image; Faces: six files
// named from `path`, whose '%' is replaced by the face names, or whose stem gets "_<face>").
// Returns notes (depth decisions, the face files' names).
std::vector<std::string> writeCubeMap(OutputFiles& outputs, const std::filesystem::path& path,
                                      const lighting::CubeMap& cube, Layout layout,
                                      const WriteOptions& options = {});
// The six paths writeCubeMap(.., Layout::Faces) writes for `path`.
std::array<std::filesystem::path, lighting::kCubeFaces> facePaths(const std::filesystem::path& path,
                                                                  int faceNaming);

// Writes RGB float data as an EXR through OpenEXR (scanlines; `compression` as OpenImageIO names
// it, PIZ by default), with an optional envmap attribute, the image's colour-space name and
// optional chromaticities and string attributes. Used by the writers above; exposed for tests
// and other stages.
void writeExr(const std::filesystem::path& path, const Image& rgb, bool useHalf,
              std::optional<Layout> envmap,
              const std::optional<std::array<double, 8>>& chromaticities = std::nullopt,
              const std::string& compression = "piz",
              const std::vector<std::pair<std::string, std::string>>& strings = {});

}  // namespace compose::cubemap
