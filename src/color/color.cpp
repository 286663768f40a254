#include "color/color.h"

#include <cstdlib>
#include <sstream>

#include <OpenColorIO/OpenColorIO.h>

#include "color/builtin_config.h"
#include "core/error.h"
#include "core/parallel.h"

namespace OCIO = OCIO_NAMESPACE;

namespace compose::color {

struct ColorConfig::Impl {
  OCIO::ConstConfigRcPtr config;
  std::string source;
};

namespace {

ColorConfig::Impl load(const std::string& source,
                       const std::function<OCIO::ConstConfigRcPtr()>& make,
                       const std::filesystem::path& file) {
  try {
    ColorConfig::Impl impl{make(), source};
    impl.config->validate();
    return impl;
  } catch (const OCIO::Exception& e) {
    throw Error("color", std::string("cannot load OpenColorIO config: ") + e.what(), file);
  }
}

std::string listSpaces(const OCIO::ConstConfigRcPtr& config) {
  std::string s;
  for (int i = 0; i < config->getNumColorSpaces(); ++i) {
    if (i) s += ", ";
    s += config->getColorSpaceNameByIndex(i);
  }
  return s;
}

// Applies `processor` to the first three channels of every pixel, rows in parallel.
void applyRgb(const OCIO::ConstProcessorRcPtr& processor, Image& image) {
  COMPOSE_CHECK(image.channels >= 3);
  OCIO::ConstCPUProcessorRcPtr cpu =
      processor->getOptimizedCPUProcessor(OCIO::OPTIMIZATION_LOSSLESS);
  const auto pixelStride = ptrdiff_t(sizeof(float)) * image.channels;
  constexpr int kRowsPerTask = 16;
  const int tasks = (image.height + kRowsPerTask - 1) / kRowsPerTask;
  parallelFor(0, tasks, [&](int64_t t) {
    const int y0 = int(t) * kRowsPerTask;
    const int rows = std::min(kRowsPerTask, image.height - y0);
    OCIO::PackedImageDesc desc(image.row(y0).data(), image.width, rows, OCIO::CHANNEL_ORDERING_RGB,
                               OCIO::BIT_DEPTH_F32, ptrdiff_t(sizeof(float)), pixelStride,
                               pixelStride * image.width);
    cpu->apply(desc);
  });
}

}  // namespace

ColorConfig ColorConfig::builtin() {
  ColorConfig c;
  c.impl_ = std::make_shared<Impl>(load("built-in",
                                        [] {
                                          std::istringstream in(detail::kBuiltinConfig);
                                          return OCIO::Config::CreateFromStream(in);
                                        },
                                        {}));
  return c;
}

ColorConfig ColorConfig::fromFile(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::exists(file, ec))
    throw Error("color", "OpenColorIO config not found", file);
  ColorConfig c;
  c.impl_ = std::make_shared<Impl>(load(
      file.string(), [&] { return OCIO::Config::CreateFromFile(file.string().c_str()); }, file));
  return c;
}

ColorConfig ColorConfig::fromEnvironment() {
  const char* env = std::getenv("OCIO");
  if (env && *env) return fromFile(env);
  return builtin();
}

const std::string& ColorConfig::source() const {
  return impl_->source;
}

std::string ColorConfig::workingSpace() const {
  return resolve(OCIO::ROLE_SCENE_LINEAR, "the scene_linear role");
}

bool ColorConfig::has(const std::string& name) const {
  return !name.empty() && impl_->config->getColorSpace(name.c_str()) != nullptr;
}

std::string ColorConfig::resolve(const std::string& name, const std::string& what) const {
  OCIO::ConstColorSpaceRcPtr cs =
      name.empty() ? nullptr : impl_->config->getColorSpace(name.c_str());
  if (!cs) {
    throw Error("color", "unknown colour space '" + name + "' for " + what + "; the config (" +
                             impl_->source + ") has: " + listSpaces(impl_->config));
  }
  return cs->getName();
}

std::string ColorConfig::inputSpaceFor(const std::filesystem::path& file,
                                       const std::string& declared) const {
  if (has(declared)) return resolve(declared, file.string());
  const char* byRule = impl_->config->getColorSpaceFromFilepath(file.string().c_str());
  if (byRule && has(byRule)) return resolve(byRule, file.string());
  return resolve(OCIO::ROLE_DEFAULT, "the default role");
}

void ColorConfig::convert(Image& image, const std::string& to) const {
  const std::string src = resolve(image.colorSpace, "an image");
  const std::string dst = resolve(to, "a conversion target");
  if (src != dst) {
    try {
      applyRgb(impl_->config->getProcessor(src.c_str(), dst.c_str()), image);
    } catch (const OCIO::Exception& e) {
      throw Error("color", "cannot convert " + src + " to " + dst + ": " + e.what());
    }
  }
  image.colorSpace = dst;
}

std::string ColorConfig::defaultDisplay() const {
  return impl_->config->getDefaultDisplay();
}

std::string ColorConfig::defaultView(const std::string& display) const {
  return impl_->config->getDefaultView(display.c_str());
}

std::vector<std::string> ColorConfig::displays() const {
  std::vector<std::string> out;
  for (int i = 0; i < impl_->config->getNumDisplays(); ++i)
    out.emplace_back(impl_->config->getDisplay(i));
  return out;
}

std::vector<std::string> ColorConfig::views(const std::string& display) const {
  std::vector<std::string> out;
  for (int i = 0; i < impl_->config->getNumViews(display.c_str()); ++i) {
    out.emplace_back(impl_->config->getView(display.c_str(), i));
  }
  return out;
}

Image ColorConfig::toDisplay(const Image& image, const std::string& display,
                             const std::string& view) const {
  auto join = [](const std::vector<std::string>& v) {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
    return s;
  };
  const std::vector<std::string> known = displays();
  if (std::find(known.begin(), known.end(), display) == known.end()) {
    throw Error("color", "unknown display '" + display + "'; the config has: " + join(known));
  }
  const std::vector<std::string> knownViews = views(display);
  if (std::find(knownViews.begin(), knownViews.end(), view) == knownViews.end()) {
    throw Error("color", "unknown view '" + view + "' for display '" + display +
                             "'; it has: " + join(knownViews));
  }
  Image out = image;
  try {
    OCIO::DisplayViewTransformRcPtr t = OCIO::DisplayViewTransform::Create();
    t->setSrc(resolve(image.colorSpace, "an image").c_str());
    t->setDisplay(display.c_str());
    t->setView(view.c_str());
    applyRgb(impl_->config->getProcessor(t), out);
  } catch (const OCIO::Exception& e) {
    throw Error("color",
                "cannot apply display transform " + display + "/" + view + ": " + e.what());
  }
  out.colorSpace = display + "/" + view;
  return out;
}

}  // namespace compose::color
