// Colour management over OpenColorIO.
//
// The configuration is the one named by $OCIO when that is set, otherwise the project's own
// built-in configuration (src/color/compose.ocio, compiled in). Its role `scene_linear` is the
// working space in which lighting, rendering and compositing happen; with the built-in config that
// is ACEScg. Every Image carries its colour-space name; convert() changes the numbers and the name
// together. Names are resolved through the config, so aliases ("sRGB", "lin_rec709", "acescg")
// work, and an unknown name is an error that lists the valid ones.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "core/image.h"

namespace compose::color {

class ColorConfig {
 public:
  // $OCIO if set (error if it cannot be loaded), else the built-in configuration.
  static ColorConfig fromEnvironment();
  static ColorConfig builtin();
  static ColorConfig fromFile(const std::filesystem::path& file);

  // "built-in" or the path of the config file.
  const std::string& source() const;

  // Canonical name of the working space (role scene_linear).
  std::string workingSpace() const;

  // Canonical name for a colour-space name, alias or role. Throws compose::Error (stage "color")
  // naming `what` (e.g. "--plate-space") and listing the colour spaces the config has.
  std::string resolve(const std::string& name, const std::string& what) const;
  bool has(const std::string& name) const;

  // The colour space to assume for a file read from disk: `declared` (what the file or its reader
  // says) if the config knows it, else the config's file rules, else its default role.
  std::string inputSpaceFor(const std::filesystem::path& file, const std::string& declared) const;

  // Converts the first three channels of `image` from image.colorSpace to `to` in place and sets
  // image.colorSpace. Other channels (alpha, AOVs) are left alone. The image needs >= 3 channels.
  void convert(Image& image, const std::string& to) const;

  std::string defaultDisplay() const;
  std::string defaultView(const std::string& display) const;
  std::vector<std::string> displays() const;
  std::vector<std::string> views(const std::string& display) const;

  // Applies the display/view transform to the first three channels; the result is display-encoded
  // (to be quantised and written as JPEG/PNG) and tagged "<display>/<view>".
  Image toDisplay(const Image& image, const std::string& display, const std::string& view) const;

  struct Impl;  // the OpenColorIO config; defined in color.cpp

 private:
  std::shared_ptr<const Impl> impl_;
};

}  // namespace compose::color
