#include "capture/virtual_camera.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>
#include <set>

#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "ingest/capture.h"
#include "ingest/exif.h"

namespace compose::capture {

namespace fs = std::filesystem;

namespace {

constexpr const char* kStage = "capture-sim";
constexpr double kFullFrameDiagonalMm = 43.266615305567875;

// Counter-based random numbers: splitmix64 of a key.
inline uint64_t mix(uint64_t z) {
  z += 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
inline double normalFromKey(uint64_t key) {
  const uint64_t a = mix(key), b = mix(a ^ 0xD1B54A32D192ED03ull);
  const double u1 = (double(a >> 11) + 0.5) * 0x1.0p-53, u2 = double(b >> 11) * 0x1.0p-53;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
}

glm::dmat3 rotationAbout(const glm::dvec3& axis, double radians) {
  const glm::dvec3 a = glm::normalize(axis);
  const double c = std::cos(radians), s = std::sin(radians), t = 1.0 - c;
  // Columns of the rotation matrix (glm is column-major).
  return glm::dmat3(t * a.x * a.x + c, t * a.x * a.y + s * a.z, t * a.x * a.z - s * a.y,
                    t * a.x * a.y - s * a.z, t * a.y * a.y + c, t * a.y * a.z + s * a.x,
                    t * a.x * a.z + s * a.y, t * a.y * a.z - s * a.x, t * a.z * a.z + c);
}

// worldFromCamera for a camera looking along `forward` with image top towards `up`.
glm::dmat3 lookRotation(const glm::dvec3& forward, const glm::dvec3& up) {
  const glm::dvec3 f = glm::normalize(forward);
  const glm::dvec3 right = glm::normalize(glm::cross(f, up));
  const glm::dvec3 trueUp = glm::cross(right, f);
  return glm::dmat3(right, trueUp, -f);
}

nlohmann::ordered_json rows(const glm::dmat3& m) {
  return {{m[0][0], m[1][0], m[2][0]}, {m[0][1], m[1][1], m[2][1]}, {m[0][2], m[1][2], m[2][2]}};
}

// Separable Gaussian blur of an RGB image (the optics' point-spread function), edges clamped.
// Below half a pixel the Gaussian sampled at whole pixels is far narrower than σ (at σ 0.3 its
// variance is a third of σ²): there the kernel is [a, 1 - 2a, a] with a = σ²/2, of variance σ².
void blur(Image& img, double sigma) {
  if (!(sigma > 0.0)) return;
  int radius = 1;
  std::vector<float> kernel;
  if (sigma < 0.5) {
    const float a = float(0.5 * sigma * sigma);
    kernel = {a, 1.0f - 2.0f * a, a};
  } else {
    radius = int(std::ceil(3.0 * sigma));
    kernel.resize(size_t(2 * radius + 1));
    float sum = 0.0f;
    for (int i = -radius; i <= radius; ++i)
      sum += kernel[size_t(i + radius)] = float(std::exp(-0.5 * i * i / (sigma * sigma)));
    for (float& k : kernel) k /= sum;
  }
  Image tmp = img;
  const int w = img.width, h = img.height;
  parallelFor(0, h, [&](int64_t yy) {
    const int y = int(yy);
    for (int x = 0; x < w; ++x) {
      float acc[3] = {0, 0, 0};
      for (int i = -radius; i <= radius; ++i) {
        const float* p = img.at(std::clamp(x + i, 0, w - 1), y);
        for (int c = 0; c < 3; ++c) acc[c] += kernel[size_t(i + radius)] * p[c];
      }
      std::copy(acc, acc + 3, tmp.at(x, y));
    }
  });
  parallelFor(0, h, [&](int64_t yy) {
    const int y = int(yy);
    for (int x = 0; x < w; ++x) {
      float acc[3] = {0, 0, 0};
      for (int i = -radius; i <= radius; ++i) {
        const float* p = tmp.at(x, std::clamp(y + i, 0, h - 1));
        for (int c = 0; c < 3; ++c) acc[c] += kernel[size_t(i + radius)] * p[c];
      }
      std::copy(acc, acc + 3, img.at(x, y));
    }
  });
}

// Renders the radiance K · wb · L seen through `lens` by a camera with orientation
// `worldFromCamera`, image translated by `shift` and rolled by `roll` radians about the
// principal point, with S × S rays per pixel.
Image render(const lighting::Environment& env, const calib::Lens& lens,
             const glm::dmat3& worldFromCamera, glm::dvec2 shift, double roll,
             const VirtualCameraParams& p, int s) {
  Image out(lens.width, lens.height, 3, {"R", "G", "B"});
  const double cr = std::cos(roll), sr = std::sin(roll);
  const glm::dvec3 gain = p.calibration * p.whiteBalance;
  // A fisheye's image circle: rays up to half the field of view from the axis.
  const double circle = lens.projection == calib::Projection::Equidistant
                            ? std::cos(0.5 * p.fovDegrees * kPi / 180.0)
                            : -2.0;
  parallelFor(0, lens.height, [&](int64_t yy) {
    const int y = int(yy);
    for (int x = 0; x < lens.width; ++x) {
      glm::dvec3 sum(0.0);
      for (int j = 0; j < s; ++j) {
        for (int i = 0; i < s; ++i) {
          const double px = x + (i + 0.5) / s - lens.cx - shift.x;
          const double py = y + (j + 0.5) / s - lens.cy - shift.y;
          // Content rolled by +roll: sample the nominal image at the inverse rotation.
          const double qx = cr * px + sr * py + lens.cx;
          const double qy = -sr * px + cr * py + lens.cy;
          glm::dvec3 dir;
          if (!lens.direction(qx, qy, dir) || -dir.z < circle) continue;
          sum += glm::dvec3(env.lookup(glm::vec3(worldFromCamera * dir)));
        }
      }
      float* o = out.at(x, y);
      for (int c = 0; c < 3; ++c) o[c] = float(sum[c] / (s * s) * gain[c]);
    }
  });
  // A pixel integrates the light over its area: a box of variance 1/12 pixel² per axis, which
  // S × S rays hold but 1/(12 S²) of. The rest joins the optics' blur (as a Gaussian of the same
  // variance), so that the photo's sharpness does not depend on the rays taken.
  blur(out, appliedBlur(p.blurPixels, s));
  return out;
}

}  // namespace

CodeThresholds::CodeThresholds(const CameraCurve& curve) {
  for (int k = 0; k < 255; ++k) {
    // The first signal with code k + 1, bisected down to adjacent doubles on f itself.
    auto above = [&](double s) { return std::round(255.0 * curve.encode(s)) >= k + 1; };
    double lo = 0.0, hi = 1.0;
    if (above(lo)) {
      bounds_[size_t(k)] = 0.0;
      continue;
    }
    for (;;) {
      const double m = lo + 0.5 * (hi - lo);
      if (m <= lo || m >= hi) break;
      (above(m) ? hi : lo) = m;
    }
    bounds_[size_t(k)] = hi;
  }
}

int CodeThresholds::operator()(double s) const {
  return int(std::upper_bound(bounds_.begin(), bounds_.end(), s) - bounds_.begin());
}

double appliedBlur(double blurPixels, int supersample) {
  return std::sqrt(blurPixels * blurPixels + 1.0 / (12.0 * supersample * supersample));
}

double CameraCurve::encode(double s) const {
  s = std::clamp(s, 0.0, 1.0);
  switch (kind) {
    case Kind::Filmic:
      return srgbEncode((1.0 + shoulder) * s / (s + shoulder));
    case Kind::Srgb:
      return srgbEncode(s);
    case Kind::Gamma:
      return std::pow(s, 1.0 / gamma);
  }
  return s;
}

double CameraCurve::decode(double v) const {
  v = std::clamp(v, 0.0, 1.0);
  switch (kind) {
    case Kind::Filmic: {
      const double y = srgbDecode(v);
      return y * shoulder / (1.0 + shoulder - y);
    }
    case Kind::Srgb:
      return srgbDecode(v);
    case Kind::Gamma:
      return std::pow(v, gamma);
  }
  return v;
}

std::string CameraCurve::describe() const {
  char text[160];
  switch (kind) {
    case Kind::Filmic:
      std::snprintf(text, sizeof text, "filmic: f(s) = sRGB((1 + c) s / (s + c)), c = %g",
                    shoulder);
      break;
    case Kind::Srgb:
      std::snprintf(text, sizeof text, "srgb: the IEC 61966-2-1 encoding");
      break;
    case Kind::Gamma:
      std::snprintf(text, sizeof text, "gamma: f(s) = s^(1/g), g = %g", gamma);
      break;
  }
  return text;
}

hdr::ResponseCurve CameraCurve::inverseTable() const {
  hdr::ResponseCurve r;
  for (auto& ch : r.inverse) {
    ch.resize(hdr::kCodes);
    for (int z = 0; z < hdr::kCodes; ++z) ch[size_t(z)] = float(decode(z / 255.0));
    ch[0] = float(decode(0.25 / 255.0));
  }
  r.method = "ground truth";
  r.source = "the virtual camera's curve, " + describe();
  return r;
}

CameraCurve CameraCurve::parse(const std::string& text) {
  CameraCurve c;
  const size_t colon = text.find(':');
  const std::string kind = text.substr(0, colon);
  const std::string rest = colon == std::string::npos ? "" : text.substr(colon + 1);
  auto number = [&](const std::string& s) {
    try {
      size_t used = 0;
      const double v = std::stod(s, &used);
      if (used == s.size() && v > 0.0 && std::isfinite(v)) return v;
    } catch (const std::exception&) {
    }
    throw Error(kStage, "bad number '" + s + "' in the response curve '" + text + "'");
  };
  if (kind == "srgb" && rest.empty()) {
    c.kind = Kind::Srgb;
  } else if (kind == "gamma") {
    c.kind = Kind::Gamma;
    if (!rest.empty()) c.gamma = number(rest);
  } else if (kind == "filmic") {
    c.kind = Kind::Filmic;
    if (!rest.empty()) c.shoulder = number(rest);
  } else {
    throw Error(kStage, "unknown response curve '" + text +
                            "'; valid: filmic[:C] (shoulder C), srgb, gamma[:G]");
  }
  return c;
}

void VirtualCameraParams::validate() const {
  auto fail = [](const std::string& what) { throw Error(kStage, what); };
  if (width < 16 || height < 16 || width > 20000 || height > 20000)
    fail("image size must be between 16 and 20000 pixels per side");
  const double maxFov = projection == calib::Projection::Rectilinear ? 170.0 : 360.0;
  // A rectilinear view of 180 degrees is infinitely wide; a fisheye's may reach a full turn.
  if (!(fovDegrees >= 1.0 && fovDegrees <= maxFov))
    fail("field of view must be between 1 and " + std::to_string(int(maxFov)) +
         " degrees for this lens (inclusive)");
  if (int64_t(width) * height > resourceLimits().maxPixels) {
    fail("image size " + std::to_string(width) + "x" + std::to_string(height) +
         " is more pixels than the limit of " +
         std::to_string(resourceLimits().maxPixels / 1000000) +
         " megapixels (raise it with --max-pixels)");
  }
  if (views < 1 || views > 360) fail("views must be between 1 and 360");
  if (brackets < 1 || brackets > 15) fail("brackets must be between 1 and 15");
  if (!(evStep > 0.0 && evStep <= 6.0)) fail("--ev-step must be in (0, 6] stops");
  if (exposureTime && !(*exposureTime >= 1e-9 && *exposureTime <= 3600.0))
    fail("exposure time must be between 1 ns and 3600 s");
  if (exposureTime && *exposureTime >= 1e-9 && *exposureTime <= 3600.0 && evStep > 0.0 &&
      brackets >= 1 && brackets <= 15) {
    // Every shot of the bracket, not only the middle one, within a shutter's range.
    const double spread = std::exp2(0.5 * (brackets - 1) * evStep);
    if (!(*exposureTime / spread >= 1e-9 && *exposureTime * spread <= 3600.0)) {
      char text[200];
      std::snprintf(text, sizeof text,
                    "the bracket's exposures (%.3g s to %.3g s) must be between 1 ns and 3600 s",
                    *exposureTime / spread, *exposureTime * spread);
      fail(text);
    }
  }
  if (!(fNumber >= 0.5 && fNumber <= 128.0)) fail("f-number must be between 0.5 and 128");
  if (!(iso >= 1.0 && iso <= 409600.0)) fail("ISO must be between 1 and 409600");
  if (iso != std::floor(iso)) fail("ISO must be a whole number, as EXIF records it");
  if (!(calibration > 0.0) || !std::isfinite(calibration)) fail("calibration must be positive");
  for (int c = 0; c < 3; ++c)
    if (!(whiteBalance[c] > 0.0) || !std::isfinite(whiteBalance[c]))
      fail("white-balance gains must be positive");
  if (!(curve.gamma > 0.1 && curve.gamma < 10.0)) fail("response gamma must be in (0.1, 10)");
  if (!(curve.shoulder > 0.0 && curve.shoulder < 1e6)) fail("response shoulder must be positive");
  if (!(fullWellElectrons >= 100.0) || !(readNoiseElectrons >= 0.0) ||
      !std::isfinite(fullWellElectrons) || !std::isfinite(readNoiseElectrons))
    fail(
        "noise: full well must be at least 100 electrons and read noise non-negative, both finite");
  if (supersample && (*supersample < 1 || *supersample > 16))
    fail("supersampling must be between 1 and 16");
  if (!(blurPixels >= 0.0 && blurPixels <= 10.0)) fail("optical blur must be 0-10 pixels");
  if (jpegQuality < 1 || jpegQuality > 100) fail("JPEG quality must be between 1 and 100");
  if (!writeJpeg && !writeTiff16) fail("nothing to write: neither JPEG nor TIFF");
  if (!(shakePixels >= 0.0 && shakePixels <= 0.25 * std::min(width, height)))
    fail("shake must be between 0 and a quarter of the image size");
  if (!(shakeRollDegrees >= 0.0 && shakeRollDegrees <= 10.0))
    fail("roll shake must be between 0 and 10 degrees");
  if (!(orientationJitterDegrees >= 0.0 && orientationJitterDegrees <= 30.0))
    fail("orientation jitter must be between 0 and 30 degrees");
  if (!(sensorWidthMm > 1.0 && sensorWidthMm < 100.0)) fail("sensor width must be 1-100 mm");
  if (make.empty() && model.empty()) fail("the camera needs a make or a model");
}

std::vector<std::pair<std::string, glm::dmat3>> viewDirections(int views) {
  std::vector<std::pair<std::string, glm::dmat3>> out;
  const glm::dvec3 up(0.0, 1.0, 0.0);
  if (views == 6) {
    out.emplace_back("px", lookRotation({1, 0, 0}, up));
    out.emplace_back("nx", lookRotation({-1, 0, 0}, up));
    out.emplace_back("py", lookRotation({0, 1, 0}, {0, 0, 1}));
    out.emplace_back("ny", lookRotation({0, -1, 0}, {0, 0, -1}));
    out.emplace_back("pz", lookRotation({0, 0, 1}, up));
    out.emplace_back("nz", lookRotation({0, 0, -1}, up));
    return out;
  }
  for (int i = 0; i < views; ++i) {
    const double yaw = 360.0 * i / views;
    const double r = yaw * kPi / 180.0;
    char name[16];
    std::snprintf(name, sizeof name, "yaw%03d", int(std::lround(yaw)) % 360);
    out.emplace_back(name, lookRotation({-std::sin(r), 0.0, -std::cos(r)}, up));
  }
  return out;
}

SimulatedCapture simulateCapture(const lighting::Environment& env, const VirtualCameraParams& p,
                                 const Progress& progress) {
  p.validate();
  COMPOSE_CHECK(env.width() > 0);
  SimulatedCapture cap;
  cap.params = p;
  cap.lens = calib::Lens::fromFieldOfView(p.width, p.height, p.fovDegrees, p.projection);
  cap.lens.source = "virtual camera";
  // A pixel at the centre spans 1/f radians (either projection); a texel of the lat-long map
  // 2π/W on its equator.
  cap.supersample = p.supersample.value_or(std::clamp(
      int(std::ceil((1.0 / std::min(cap.lens.fx, cap.lens.fy)) / (2.0 * kPi / env.width()) - 1e-9)),
      1, 8));

  std::mt19937_64 rng(p.seed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  const auto directions = viewDirections(p.views);
  const bool shaken = p.shakePixels > 0.0 || p.shakeRollDegrees > 0.0;
  // Steps: every image rendered, and every shot's noise and quantisation.
  const int renders = int(directions.size()) * ((shaken ? p.brackets + 1 : 1) + p.brackets);
  int rendered = 0;
  auto step = [&] { report(progress, kStage, double(++rendered) / renders); };
  report(progress, kStage, 0.0);

  // Orientations, shake, and the noise-free radiance of every view.
  const int mid = p.brackets / 2;
  for (const auto& [name, nominal] : directions) {
    SimulatedView v;
    v.name = name;
    v.nominalWorldFromCamera = nominal;
    glm::dmat3 jitter(1.0);
    if (p.orientationJitterDegrees > 0.0) {
      const double k = p.orientationJitterDegrees * kPi / 180.0;
      // Drawn one at a time: C++ leaves the order in which a call's arguments are evaluated
      // unspecified (GCC and clang differ), and a seed must give the same photos with any
      // compiler. This is the order the GCC builds have always used.
      const double aboutZ = k * unit(rng), aboutX = k * unit(rng), aboutY = k * unit(rng);
      jitter = rotationAbout({0, 1, 0}, aboutY) * rotationAbout({1, 0, 0}, aboutX) *
               rotationAbout({0, 0, 1}, aboutZ);
    }
    v.worldFromCamera = nominal * jitter;
    v.shots.resize(size_t(p.brackets));
    for (SimulatedShot& s : v.shots) {
      const double dy = p.shakePixels * unit(rng), dx = p.shakePixels * unit(rng);  // (see above)
      s.shift = glm::dvec2(dx, dy);
      s.rollDegrees = p.shakeRollDegrees * unit(rng);
    }
    const SimulatedShot& ref = v.shots[size_t(mid)];
    v.truth = render(env, cap.lens, v.worldFromCamera, ref.shift, ref.rollDegrees * kPi / 180.0, p,
                     cap.supersample);
    v.truth.colorSpace = env.colorSpace();
    step();
    cap.views.push_back(std::move(v));
  }

  // Exposure: the median luminance of all views at s = 0.18, rounded to a whole stop.
  double middle = 0.0;
  if (p.exposureTime) {
    middle = *p.exposureTime;
  } else {
    std::vector<float> lum;
    for (const SimulatedView& v : cap.views) {
      for (size_t i = 0; i < v.truth.pixelCount(); i += 3) {
        const float* px = v.truth.pixels.data() + i * 3;
        lum.push_back(0.2126f * px[0] + 0.7152f * px[1] + 0.0722f * px[2]);
      }
    }
    auto percentile = [&](double q) {
      const auto k = ptrdiff_t(q * double(lum.size() - 1));
      std::nth_element(lum.begin(), lum.begin() + k, lum.end());
      return std::max(double(lum[size_t(k)]), 1e-12);
    };
    // Relative exposures t · ISO / N²: mid-grey for the median in the middle shot, unless the
    // shortest shot would then clip the brightest 1 % (a photographer protects highlights).
    const double forMedian = 0.18 / percentile(0.5);
    const double forHighlights =
        0.9 / percentile(0.99) * std::exp2(0.5 * (p.brackets - 1) * p.evStep);
    const double e = std::min(forMedian, forHighlights);
    middle = std::exp2(std::floor(std::log2(e * p.fNumber * p.fNumber / p.iso)));
    // A camera's shutter: the whole bracket between 1 ns and an hour. A map too dark or too
    // bright for it would give photos whose EXIF says 0 s (and black frames).
    const double spread = std::exp2(0.5 * (p.brackets - 1) * p.evStep);
    if (!(middle / spread >= 1e-9 && middle * spread <= 3600.0)) {
      char text[320];
      const double median = percentile(0.5);
      char luminance[48];
      if (median > 1e-12)
        std::snprintf(luminance, sizeof luminance, "%.3g", median);
      else
        std::snprintf(luminance, sizeof luminance, "%s", "0 (below 1e-12)");
      std::snprintf(text, sizeof text,
                    "the environment is too %s for a camera: its median luminance %s would "
                    "need a middle exposure of %.3g s at f/%.3g ISO %.0f (shutter times from 1 ns "
                    "to 3600 s); give --exposure, or scale the map",
                    middle > 1.0 ? "dark" : "bright", luminance, middle, p.fNumber, p.iso);
      throw Error("capture", text);
    }
  }
  cap.middleExposureTime = middle;

  // Lens data for EXIF.
  const double pitchMm = p.sensorWidthMm / p.width;
  const double focalMm = cap.lens.fx * pitchMm;
  const double diagonalMm = std::hypot(p.width * pitchMm, p.height * pitchMm);
  const double fullWell = p.fullWellElectrons * 100.0 / p.iso;
  const double read2 = p.readNoiseElectrons * p.readNoiseElectrons;

  const CodeThresholds codeOf(p.curve);
  for (size_t vi = 0; vi < cap.views.size(); ++vi) {
    SimulatedView& v = cap.views[vi];
    for (int b = 0; b < p.brackets; ++b) {
      SimulatedShot& s = v.shots[size_t(b)];
      s.stem = v.name + "_" + std::to_string(b + 1);
      s.exposureTime = middle * std::exp2((b - 0.5 * (p.brackets - 1)) * p.evStep);
      s.relativeExposure = s.exposureTime * p.iso / (p.fNumber * p.fNumber);
      Image radiance;
      if (shaken) {
        radiance = render(env, cap.lens, v.worldFromCamera, s.shift, s.rollDegrees * kPi / 180.0, p,
                          cap.supersample);
        step();
      }
      const Image& seen = shaken ? radiance : v.truth;
      s.codes = Image(p.width, p.height, 3, {"R", "G", "B"});
      s.codes.colorSpace = "sRGB";
      if (p.writeTiff16) s.linear16 = Image(p.width, p.height, 3, {"R", "G", "B"});
      const uint64_t shotKey = mix(mix(p.seed) ^ (uint64_t(vi) << 40) ^ (uint64_t(b) << 32));
      parallelFor(0, p.height, [&](int64_t yy) {
        const int y = int(yy);
        for (int x = 0; x < p.width; ++x) {
          const float* l = seen.at(x, y);
          float* code = s.codes.at(x, y);
          for (int c = 0; c < 3; ++c) {
            double signal = double(l[c]) * s.relativeExposure;
            if (p.noise) {
              const uint64_t key =
                  shotKey ^ ((uint64_t(y) * uint64_t(p.width) + uint64_t(x)) * 4 + uint64_t(c));
              const double e = std::max(signal, 0.0) * fullWell;
              signal += std::sqrt(e + read2) / fullWell * normalFromKey(key);
            }
            signal = std::clamp(signal, 0.0, 1.0);
            code[c] = float(codeOf(signal)) / 255.0f;
            if (p.writeTiff16)
              s.linear16.at(x, y)[c] = float(std::round(signal * 65535.0) / 65535.0);
          }
        }
      });
      step();

      ingest::CaptureInfo& exif = s.exif;
      exif.exposureTime = s.exposureTime;
      exif.fNumber = p.fNumber;
      exif.iso = p.iso;
      exif.focalLengthMm = focalMm;
      if (p.write35mm) exif.focalLength35mm = focalMm * kFullFrameDiagonalMm / diagonalMm;
      exif.focalPlaneXResolution = 10.0 / pitchMm;  // pixels per centimetre
      exif.focalPlaneYResolution = 10.0 / pitchMm;
      exif.focalPlaneResolutionUnit = 3;
      exif.cameraMake = p.make;
      exif.cameraModel = p.model;
      // One second between shots, half a minute between views, from 2024-06-01 12:00:00 (360
      // views end three hours later: the minutes carry into the hours, as they did not past
      // 12:59, and 12:62:00 is no time).
      const int seconds = int(vi) * 30 + b;
      char when[40];
      std::snprintf(when, sizeof when, "2024:06:01 %02d:%02d:%02d", 12 + seconds / 3600,
                    seconds / 60 % 60, seconds % 60);
      exif.dateTimeOriginal = when;
    }
  }
  report(progress, kStage, 1.0);
  return cap;
}

CaptureFiles writeCapture(const fs::path& folder, const SimulatedCapture& cap,
                          const WriteCaptureOptions& options, const Progress& progress) {
  const VirtualCameraParams& p = cap.params;
  OutputFiles outputs(kStage);
  CaptureFiles files;
  const fs::path absolute = fs::absolute(folder);
  ingest::Capture jpegs, tiffs;
  for (ingest::Capture* c : {&jpegs, &tiffs}) {
    c->cameraMake = p.make;
    c->cameraModel = p.model;
    c->lensFile = absolute / "camera.json";
    c->groundTruth = absolute / "truth.json";
  }
  {
    // Photos of an earlier capture in the folder, which this one does not replace, would be
    // grouped with the new ones by ingest and merge of the folder (the EXIF times are the same
    // for every run): refused before anything is written.
    std::set<std::string> mine;
    for (const SimulatedView& v : cap.views) {
      if (options.truthImages) mine.insert(v.name + "_truth.exr");
      for (const SimulatedShot& s : v.shots) {
        if (p.writeJpeg) mine.insert(s.stem + ".jpg");
        if (p.writeTiff16) mine.insert(s.stem + ".tif");
      }
    }
    std::vector<std::string> stale;
    std::error_code ec;
    for (fs::directory_iterator it(absolute, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string name = it->path().filename().string();
      if (ingest::looksLikeImageFile(it->path()) && !mine.count(name) && name.front() != '.')
        stale.push_back(name);
    }
    if (!stale.empty()) {
      std::sort(stale.begin(), stale.end());
      std::string listed;
      for (size_t i = 0; i < std::min<size_t>(stale.size(), 4); ++i)
        listed += (i ? ", " : "") + stale[i];
      if (stale.size() > 4) listed += ", ...";
      throw Error(kStage,
                  "the output folder holds " + std::to_string(stale.size()) + " image" +
                      (stale.size() == 1 ? "" : "s") + " this capture does not write (" + listed +
                      "): ingest or merge of the folder would take them with the new photos; "
                      "write into an empty folder, or remove them",
                  folder);
    }
  }
  nlohmann::ordered_json truthViews = nlohmann::ordered_json::array();
  size_t done = 0;
  const size_t total = cap.views.size() * size_t(p.brackets);
  for (const SimulatedView& v : cap.views) {
    ingest::View jv{v.name, {}, v.nominalWorldFromCamera}, tv = jv;
    nlohmann::ordered_json shots = nlohmann::ordered_json::array();
    for (const SimulatedShot& s : v.shots) {
      ingest::WriteOptions w;
      w.attributes = ingest::exifAttributes(s.exif);
      w.jpegQuality = p.jpegQuality;
      w.jpegFullChroma = p.jpegFullChroma;
      nlohmann::ordered_json js;
      if (p.writeJpeg) {
        const fs::path dst = absolute / (s.stem + ".jpg");
        w.depth = ingest::WriteOptions::Depth::UInt8;
        ingest::writeImage(outputs, dst, s.codes, w);
        files.photos.push_back(dst);
        jv.shots.push_back({dst, s.exif, s.relativeExposure, "EXIF", options.jpegSpace, {}});
        js["file"] = dst.filename().string();
      }
      if (p.writeTiff16) {
        const fs::path dst = absolute / (s.stem + ".tif");
        w.depth = ingest::WriteOptions::Depth::UInt16;
        Image linear = s.linear16;
        linear.colorSpace = options.linearSpace;
        // A TIFF names no colour space of its own: an ICC profile of linear light says that its
        // codes are not sRGB-encoded (to compose, and to other readers).
        const std::vector<unsigned char> profile = ingest::exif::linearRec709Profile();
        w.attributes.push_back({"ICCProfile", std::string(profile.begin(), profile.end())});
        ingest::writeImage(outputs, dst, linear, w);
        files.photos.push_back(dst);
        tv.shots.push_back({dst, s.exif, s.relativeExposure, "EXIF", options.linearSpace, {}});
        js["tiff"] = dst.filename().string();
      }
      js["exposureTime"] = s.exposureTime;
      js["relativeExposure"] = s.relativeExposure;
      js["shift"] = {s.shift.x, s.shift.y};
      js["rollDegrees"] = s.rollDegrees;
      shots.push_back(js);
      report(progress, "write", double(++done) / double(total));
    }
    nlohmann::ordered_json tvj;
    tvj["name"] = v.name;
    tvj["worldFromCamera"] = rows(v.worldFromCamera);
    tvj["nominalWorldFromCamera"] = rows(v.nominalWorldFromCamera);
    tvj["shots"] = shots;
    if (options.truthImages) {
      const fs::path dst = absolute / (v.name + "_truth.exr");
      ingest::WriteOptions w;
      w.depth = ingest::WriteOptions::Depth::Float;
      Image truth = v.truth;
      truth.colorSpace = options.linearSpace;
      w.chromaticities = options.linearChromaticities;
      w.exrCompression = options.truthCompression;
      ingest::writeImage(outputs, dst, truth, w);
      files.truthImages.push_back(dst);
      tvj["radiance"] = dst.filename().string();
    }
    truthViews.push_back(tvj);
    if (p.writeJpeg) jpegs.views.push_back(std::move(jv));
    if (p.writeTiff16) tiffs.views.push_back(std::move(tv));
  }

  files.lens = absolute / "camera.json";
  {
    // calib::writeLens writes atomically on its own; write to the temporary path instead.
    calib::writeLens(outputs.add(files.lens), cap.lens);
  }
  files.response = absolute / "response_truth.json";
  hdr::ResponseCurve truthCurve = p.curve.inverseTable();
  truthCurve.make = p.make;
  truthCurve.model = p.model;
  {
    const fs::path tmp = outputs.add(files.response);
    writeTextFile(tmp, hdr::responseText(truthCurve), kStage);
  }

  nlohmann::ordered_json truth;
  truth["format"] = "compose-capture-truth";
  truth["version"] = 1;
  truth["environment"] = cap.environmentName;
  truth["camera"] = {{"make", p.make}, {"model", p.model}};
  truth["radiance"] =
      "per view: K * wb * L (linear Rec.709) seen by the middle shot; merged radiance should "
      "match it up to one scale per capture";
  truth["calibration"] = p.calibration;
  truth["whiteBalance"] = {p.whiteBalance.x, p.whiteBalance.y, p.whiteBalance.z};
  truth["response"] = {{"curve", p.curve.describe()}, {"file", files.response.filename().string()}};
  truth["noise"] = {{"enabled", p.noise},
                    {"fullWellElectronsAtIso100", p.fullWellElectrons},
                    {"readNoiseElectrons", p.readNoiseElectrons}};
  truth["seed"] = p.seed;
  truth["fNumber"] = p.fNumber;
  truth["iso"] = p.iso;
  truth["middleExposureTime"] = cap.middleExposureTime;
  truth["evStep"] = p.evStep;
  truth["supersample"] = cap.supersample;
  truth["blurPixels"] = p.blurPixels;
  truth["blurAppliedPixels"] = appliedBlur(p.blurPixels, cap.supersample);
  truth["jpegQuality"] = p.jpegQuality;
  truth["jpegChroma"] = p.jpegFullChroma ? "4:4:4" : "4:2:0";
  truth["lens"] = files.lens.filename().string();
  truth["views"] = truthViews;
  files.truth = absolute / "truth.json";
  writeTextFile(outputs.add(files.truth), truth.dump(2) + "\n", kStage);

  if (p.writeJpeg) {
    files.description = absolute / "capture.json";
    writeTextFile(outputs.add(files.description),
                  ingest::captureDescriptionText(files.description, jpegs), kStage);
  }
  if (p.writeTiff16) {
    const fs::path dst = absolute / (p.writeJpeg ? "capture-tiff.json" : "capture.json");
    writeTextFile(outputs.add(dst), ingest::captureDescriptionText(dst, tiffs), kStage);
    (p.writeJpeg ? files.tiffDescription : files.description) = dst;
  }
  outputs.commit();
  return files;
}

}  // namespace compose::capture
