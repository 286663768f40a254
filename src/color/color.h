// Colour management over OpenColorIO.
//
// The configuration is the one named by $OCIO when that is set, otherwise the project's own
// built-in configuration (src/color/compose.ocio, compiled in). Its role `scene_linear` is the
// working space in which lighting, rendering and compositing happen; with the built-in config that
// is ACEScg. Every Image carries its colour-space name; convert() changes the numbers and the name
// together. Names are resolved through the config, so aliases ("sRGB", "lin_rec709", "acescg")
// work, and an unknown name is an error that lists the valid ones.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "core/image.h"

namespace compose::color {

// CIE 1931 xy chromaticities of a linear RGB space, in OpenEXR's order: red x, y, green x, y,
// blue x, y, white x, y.
using Chromaticities = std::array<double, 8>;

// Well-known primaries, for matching and for tests.
inline constexpr Chromaticities kRec709Chromaticities = {0.64, 0.33, 0.30,   0.60,
                                                         0.15, 0.06, 0.3127, 0.3290};
inline constexpr Chromaticities kAcesAp1Chromaticities = {0.713, 0.293, 0.165,   0.830,
                                                          0.128, 0.044, 0.32168, 0.33767};
inline constexpr Chromaticities kAcesAp0Chromaticities = {0.7347, 0.2653,  0.0,     1.0,
                                                          0.0001, -0.0770, 0.32168, 0.33767};

// Why chromaticities describe no RGB space, or empty when they do: a value that is not finite,
// a white with y <= 0, or primaries on one line (as three equal primaries, or all zeros, are).
// CIE XYZ's own, red (1, 0), green (0, 1), blue (0, 0), do describe one.
std::string chromaticitiesProblem(const Chromaticities& c);
// Throws compose::Error (stage "color", naming `file`) saying the chromaticities and the problem
// when there is one.
void requireRgbSpace(const Chromaticities& c, const std::filesystem::path& file);

// How an input file's colour space was chosen (ColorConfig::inputSpace).
struct InputSpace {
  std::string space;     // canonical name in the config
  std::string how;       // for the user: "as the file says", "the config's default rule", ...
  bool assumed = false;  // a guess (no statement in the file, no file rule for it)
};

class ColorConfig {
 public:
  // The config named by useConfig() (the --ocio option), else $OCIO if set (error if it cannot
  // be loaded), else the built-in configuration.
  static ColorConfig fromEnvironment();
  // Makes fromEnvironment() load `file` instead of $OCIO ("builtin": the built-in config);
  // `namedBy` says where the name came from in its errors.
  static void useConfig(const std::string& file, const std::string& namedBy = "--ocio");
  static ColorConfig builtin();
  static ColorConfig fromFile(const std::filesystem::path& file);

  // "built-in" or the path of the config file.
  const std::string& source() const;
  // A string that changes whenever the config's content (or the environment it reads) does, for
  // cache keys: OpenColorIO's cache ID and the content of every file (LUT) its transforms name.
  std::string identity() const;

  // Canonical name of the working space (role scene_linear).
  std::string workingSpace() const;

  // Canonical name for a colour-space name, alias or role. Throws compose::Error (stage "color")
  // naming `what` (e.g. "--plate-space") and listing the colour spaces the config has.
  std::string resolve(const std::string& name, const std::string& what) const;
  bool has(const std::string& name) const;

  // The colour space to assume for a file read from disk: `declared` (what the file says, or its
  // format's convention when `declaredByConvention`: OpenImageIO's "sRGB" for a JPEG, "Linear"
  // for an OpenEXR) if the config knows it, else the config's file rules (its default rule
  // last). An 8- or 16-bit image (`integerData`) that this makes linear or data is taken as
  // sRGB-encoded (srgbEncodedSpace()) when the config has such a space; a float one that this
  // makes sRGB-encoded is taken as linear (the config's linear Rec.709, else scene_linear).
  // `samplesKnown` false: whether the samples are integer or float is not known (no float rule).
  InputSpace inputSpace(const std::filesystem::path& file, const std::string& declared,
                        bool declaredByConvention, bool integerData,
                        bool samplesKnown = true) const;
  // inputSpace(...).space, an image being 8- or 16-bit when its extension is a JPEG's or a PNG's,
  // float when it is an OpenEXR's, a Radiance file's or a PFM's (a TIFF may be either).
  std::string inputSpaceFor(const std::filesystem::path& file, const std::string& declared) const;
  // The config's space for sRGB-encoded images (display-referred sRGB codes of Rec.709 colours):
  // the first of the roles default_byte, matte_paint, texture_paint, color_picking and the spaces
  // named like "sRGB" whose conversion to the working space decodes the sRGB curve (and, when
  // the config's linear Rec.709 space is known, its primaries) within 1 %. Empty when none does.
  std::string srgbEncodedSpace() const;
  // Whether converting `space` to the working space scales greys linearly, or it is a data space.
  bool isLinearOrData(const std::string& space) const;
  // Whether `space` is a data space (never converted: normals, masks).
  bool isData(const std::string& space) const;

  // Converts the first three channels of `image` from image.colorSpace to `to` in place and sets
  // image.colorSpace. Other channels (alpha, AOVs) are left alone. The image needs >= 3 channels.
  void convert(Image& image, const std::string& to) const;
  // The same for an 8-bit image given as its codes (width x height x channels, interleaved, at
  // least 3 channels; only the first three are read) in the space `from`: returns the RGB in `to`,
  // as float. The conversion starts from the codes, so the per-channel part of the transform (an
  // sRGB curve, say) is a table of the 256 codes, each computed exactly as convert() would; the
  // values agree with convert() on the codes divided by 255 to float rounding.
  Image convertCodes(std::span<const uint8_t> codes, int width, int height, int channels,
                     const std::string& from, const std::string& to) const;

  // Chromaticities of a linear colour space of the config, found through the config's
  // interchange role (aces_interchange or cie_xyz_d65_interchange): the space's unit primaries
  // are converted there and read off. A space whose conversion matches a well-known set of
  // primaries (Rec.709, P3-D65, Rec.2020, ACES AP0, AP1) up to the config's white-point adaptation
  // reports that set. A config with no interchange role (OCIO v1: nuke-default, ACES 1.x) says
  // no primaries: there the linear spaces of the usual names ('linear', 'ACES - ACEScg',
  // 'Utility - Linear - sRGB', ...) report theirs. Empty otherwise, or when the space is not
  // linear RGB (an encoded or data space).
  std::optional<Chromaticities> chromaticities(const std::string& space) const;
  // The weights of R, G and B in the luminance (CIE Y) of a linear space: from its chromaticities
  // when known, else the config's `luma` coefficients.
  glm::dvec3 lumaWeights(const std::string& space) const;
  // A linear colour space of the config with these chromaticities (within 1e-3), or empty.
  std::string spaceWithChromaticities(const Chromaticities& c) const;
  // True when converting `from` to `to` keeps each primary pure: the two differ by an encoding
  // alone (sRGB and linear Rec.709), not by their primaries (Display P3's red is
  // (1.22, -0.04, -0.02) in Rec.709).
  bool samePrimaries(const std::string& from, const std::string& to) const;
  // The linear space of the config with the primaries of `space` (an encoded one: 'sRGB - Texture'
  // gives linear Rec.709, 'Display P3' linear P3-D65; a linear one: itself), among those of
  // well-known primaries; empty when there is none.
  std::string linearSpaceWithPrimariesOf(const std::string& space) const;
  // Converts the first three channels of `image` from the linear RGB space with chromaticities
  // `from` to the config space `to` (whose chromaticities must be known), with Bradford
  // adaptation between the white points; tags the image `to`. Throws compose::Error (stage
  // "color", naming `file`) when `from` describe no RGB space (chromaticitiesProblem()) or `to`
  // has no known chromaticities.
  void convertFromChromaticities(Image& image, const Chromaticities& from, const std::string& to,
                                 const std::filesystem::path& file = {}) const;

  std::string defaultDisplay() const;
  std::string defaultView(const std::string& display) const;
  std::vector<std::string> displays() const;
  std::vector<std::string> views(const std::string& display) const;
  // Throws compose::Error (stage "color") listing the valid names when the config has no such
  // display, or no such view for it (toDisplay() checks this first).
  void checkDisplayView(const std::string& display, const std::string& view) const;

  // Applies the display/view transform to the first three channels; the result is display-encoded
  // (to be quantised and written as JPEG/PNG) and tagged "<display>/<view>".
  Image toDisplay(const Image& image, const std::string& display, const std::string& view) const;
  // The same on an image the caller gives up: its pixels are transformed in place and returned,
  // with no copy of the frame.
  Image toDisplay(Image&& image, const std::string& display, const std::string& view) const;

  struct Impl;  // the OpenColorIO config; defined in color.cpp

 private:
  std::shared_ptr<const Impl> impl_;
};

// ColorConfig::inputSpace() for a photo (`file` as named for the config's file rules): the ICC
// profile it embeds named in `how` when that is what declared its space, and a camera's EXIF
// colour space "uncalibrated" (65535, as cameras set to Adobe RGB write) made a guess that says
// so.
InputSpace photoInputSpace(const ColorConfig& colors, const std::filesystem::path& file,
                           const std::string& declared, bool declaredByConvention, bool integerData,
                           const std::string& iccProfile, bool exifUncalibrated);

}  // namespace compose::color
