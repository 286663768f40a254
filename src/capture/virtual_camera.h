// The virtual camera: bracketed photos of a real HDR environment, taken through a documented
// camera model, with the ground truth kept. No package ships bracketed exposure sequences, so
// merging and stitching are tested on these.
//
// The camera model, per pixel and channel, in this order:
//  1. Optics. The lens (calib/lens.h: rectilinear, or equidistant fisheye) maps the pixel to a
//     ray; the environment's radiance L is looked up (bilinear) along it. Each pixel averages
//     S × S rays on a regular sub-pixel grid (the sensor integrates light over the pixel: S as
//     the map's detail needs unless given, see `supersample`), and the image is blurred by a
//     Gaussian of σ = blurPixels (lens, anti-aliasing filter and demosaicing together; real
//     cameras do not resolve single pixels) widened by the part of the pixel's area the S × S
//     rays do not integrate (variance 1/(12 S²) pixel²). A fisheye's image circle
//     holds the rays up to half the field of view from the axis (the field of view is measured
//     across the width); pixels outside it see nothing (0).
//  2. Exposure. Sensor signal s = K · wb_c · L_c · e, with e = t · ISO / N² the relative exposure
//     (t seconds, N the f-number), K the calibration constant (`calibration`) and wb the
//     white-balance gains. s = 1 is the clipping level.
//  3. Noise (optional). Shot noise and read noise in electrons: with F = fullWell · 100 / ISO
//     electrons at s = 1, s' = s + sqrt(s F + r²) / F · n, n ~ N(0, 1) from a counter-based
//     generator keyed by (seed, view, shot, pixel, channel), so results do not depend on threads.
//  4. Clipping to [0, 1], the response curve v = f(s') (see CameraCurve), 8-bit quantisation
//     (round(255 v)), JPEG compression (quality `jpegQuality`; chroma at half resolution both
//     ways, 4:2:0, libjpeg's default and what most cameras write, or at full resolution, 4:4:4,
//     with `jpegFullChroma`, as some cameras do at their finest setting).
//     Optional 16-bit TIFFs hold s' itself (linear, as a raw converter would write), quantised to
//     16 bits, without the curve.
//
// Views: with `views` = 6 the six cube directions in OpenEXR's face order (px, nx, py, ny, pz,
// nz), held as a photographer would (issue 7 §2): the four side views upright (image top = world
// +Y), the up and down views tilted from the -Z view (the up view's image top points to +Z, the
// down view's to -Z). Any other count is a ring of views around the horizon, the first looking
// along -Z, turning towards -X (yaw 0, 360/n, ...), named yaw000, yaw060, ...
//
// Exposure: one manual exposure for the whole capture (as for an HDR panorama). Unless
// `exposureTime` is given, the middle exposure puts the median luminance of all views at
// s = 0.18, or less if the shortest exposure would then clip the brightest 1 % of pixels
// (s > 0.9), rounded down to a whole stop; brackets are spread `evStep` stops apart around it.
//
// Hand-held shake (optional): every shot gets a random image translation (uniform in
// ±shakePixels per axis) and roll about the principal point (±shakeRollDegrees); each view's
// orientation can be off its nominal one by up to ±orientationJitterDegrees about each camera
// axis. Everything random comes from `seed`.
//
// Ground truth: per view, the radiance K · wb · L as seen by the view's middle shot (the shot
// merging aligns to), before noise and clipping; the true orientations, shifts and rolls; the
// response curve. writeCapture() writes the photos (EXIF: ExposureTime, FNumber,
// PhotographicSensitivity, FocalLength, FocalLengthIn35mmFilm, FocalPlaneX/YResolution, Make,
// Model, DateTimeOriginal), a capture description (ingest/capture.h) that lists the photos with
// the nominal orientations and names the lens and ground-truth files, the lens file
// (calib/lens.h), `truth.json` and the true response as a response file (hdr/response.h).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <glm/mat3x3.hpp>
#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "calib/lens.h"
#include "core/image.h"
#include "core/progress.h"
#include "hdr/response.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"

namespace compose::capture {

// The virtual camera's response f: linear sensor signal s in [0, 1] → encoded value in [0, 1].
//  * filmic (default): f(s) = sRGB((1 + c) s / (s + c)), the sRGB encoding (with its linear toe)
//    of a soft highlight shoulder of strength c (c = 1: mid-grey 0.18 → code 151, highlights
//    compressed as in a camera JPEG; f(1) = 1);
//  * srgb: the IEC 61966-2-1 encoding;
//  * gamma: s^(1/γ), no toe.
struct CameraCurve {
  enum class Kind { Filmic, Srgb, Gamma } kind = Kind::Filmic;
  double gamma = 2.2;     // gamma only
  double shoulder = 1.0;  // filmic only

  double encode(double s) const;  // f(s), s clamped to [0, 1]
  double decode(double v) const;  // f⁻¹(v), v clamped to [0, 1]
  std::string describe() const;   // the formula with its parameters
  // As a response file would hold it: inverse[c][z] = f⁻¹(z / 255) (code 0: f⁻¹(0.25 / 255)).
  hdr::ResponseCurve inverseTable() const;
  // "filmic", "filmic:C", "srgb", "gamma", "gamma:G"; compose::Error otherwise.
  static CameraCurve parse(const std::string& text);
};

struct VirtualCameraParams {
  int width = 1024, height = 768;
  double fovDegrees = 100.0;  // horizontal, across the width
  calib::Projection projection = calib::Projection::Rectilinear;
  int views = 6;
  int brackets = 3;
  double evStep = 2.0;
  std::optional<double> exposureTime;  // seconds for the middle exposure; empty = automatic
  double fNumber = 8.0;
  double iso = 100.0;
  double calibration = 1.0;  // K: sensor signal per unit radiance and relative exposure
  glm::dvec3 whiteBalance{1.0, 1.0, 1.0};
  CameraCurve curve;
  bool noise = true;
  double fullWellElectrons = 40000.0;  // at ISO 100
  double readNoiseElectrons = 3.0;
  uint64_t seed = 1;
  // S: S × S rays per pixel. Empty: as many as the environment needs, the fewest rays whose
  // spacing at the image centre (the widest pixel) is at most one of its texels on the equator
  // (2π/W; towards the poles a lat-long map's texels narrow in longitude only, stretching the
  // detail of the equator's spacing): 1 when the photo is finer than the map (its bilinear
  // lookups are smooth already), up to 8.
  std::optional<int> supersample;
  double blurPixels = 0.6;  // σ of the optics' Gaussian point-spread function, pixels
  int jpegQuality = 95;
  bool jpegFullChroma = false;  // 4:4:4 instead of 4:2:0
  bool writeJpeg = true;
  bool writeTiff16 = false;
  double shakePixels = 0.0;
  double shakeRollDegrees = 0.0;
  double orientationJitterDegrees = 0.0;
  double sensorWidthMm = 23.6;  // APS-C: FocalLength and the focal-plane resolution follow
  bool write35mm = true;        // false: FocalLengthIn35mmFilm = 0, as many phones write
  std::string make = "compose";
  std::string model = "virtual camera";
  void validate() const;  // compose::Error (stage "capture-sim")
};

struct SimulatedShot {
  std::string stem;          // file name without extension: "<view>_<index from 1>"
  Image codes;               // RGB, 8-bit codes / 255 (what the JPEG is written from)
  Image linear16;            // RGB, linear s' quantised to 16 bits (only with writeTiff16)
  ingest::CaptureInfo exif;  // what the files carry
  double exposureTime = 0.0;
  double relativeExposure = 0.0;  // t · ISO / N²
  glm::dvec2 shift{0.0, 0.0};     // image translation, pixels (content moves by +shift)
  double rollDegrees = 0.0;
};

struct SimulatedView {
  std::string name;
  glm::dmat3 nominalWorldFromCamera{1.0};  // the intended orientation
  glm::dmat3 worldFromCamera{1.0};         // the true one (with jitter)
  std::vector<SimulatedShot> shots;        // by increasing exposure
  Image truth;                             // K · wb · L seen by the middle shot, RGB
};

struct SimulatedCapture {
  VirtualCameraParams params;
  calib::Lens lens;
  std::vector<SimulatedView> views;
  double middleExposureTime = 0.0;
  int supersample = 1;          // the S rendered with (params.supersample, or the automatic choice)
  std::string environmentName;  // for the ground-truth file
};

// The 8-bit code round(255 · f(s)) of a response f, for s in [0, 1], by search among the signals
// where f crosses the code boundaries (f is increasing): a handful of comparisons instead of a
// pow per sample, and the same code as rounding f (but within a few units of the last place of a
// boundary, where f evaluated in floating point is not monotone and either code is as right).
class CodeThresholds {
 public:
  explicit CodeThresholds(const CameraCurve& curve);
  int operator()(double s) const;

 private:
  std::array<double, 255> bounds_{};  // bounds_[k]: the least signal of code k + 1
};

// The σ, in pixels, of the Gaussian blur applied after S × S rays per pixel: the optics' blur
// and the part of the pixel's area the rays do not integrate (variance 1/(12 S²)).
double appliedBlur(double blurPixels, int supersample);

// The environment's radiance is taken as linear Rec.709 (the camera's RGB); convert it first if
// it is in another space. Reports progress per rendered image (stage "capture-sim").
SimulatedCapture simulateCapture(const lighting::Environment& environment,
                                 const VirtualCameraParams& params, const Progress& progress = {});

// The nominal orientations of the views simulateCapture() takes, with their names.
std::vector<std::pair<std::string, glm::dmat3>> viewDirections(int views);

struct CaptureFiles {
  std::filesystem::path description;      // capture.json (JPEGs if written, else TIFFs)
  std::filesystem::path tiffDescription;  // capture-tiff.json when both are written
  std::filesystem::path truth, response, lens;
  std::vector<std::filesystem::path> photos, truthImages;
};

struct WriteCaptureOptions {
  bool truthImages = false;  // also write <view>_truth.exr (float, linear Rec.709)
  // Their OpenEXR compression (ingest::parseExrCompression): a lossless codec, they are the truth.
  std::string truthCompression = "zip";
  // Colour-space names written into the descriptions, as the colour config in use spells them.
  std::string jpegSpace = "sRGB";
  std::string linearSpace = "lin_rec709";
  // Written into the truth EXRs' header (Rec.709 primaries, D65).
  std::optional<std::array<double, 8>> linearChromaticities =
      std::array<double, 8>{0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290};
};

// Writes everything into `folder` (created if needed); all files appear together or none do.
CaptureFiles writeCapture(const std::filesystem::path& folder, const SimulatedCapture& capture,
                          const WriteCaptureOptions& options = {}, const Progress& progress = {});

}  // namespace compose::capture
