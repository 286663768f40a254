#include "calib/lens.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <numbers>
#include <sstream>

#include <glm/geometric.hpp>
#include <nlohmann/json.hpp>

#include "calib/lens_json.h"
#include "core/error.h"
#include "core/json_number.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/output_files.h"

namespace compose::calib {

namespace fs = std::filesystem;

namespace {

double coefficient(const std::vector<double>& d, size_t i) {
  return i < d.size() ? d[i] : 0.0;
}

// Brown–Conrady (OpenCV): undistorted normalised (x, y) → distorted.
glm::dvec2 distortRectilinear(const std::vector<double>& d, glm::dvec2 p) {
  const double k1 = coefficient(d, 0), k2 = coefficient(d, 1), p1 = coefficient(d, 2),
               p2 = coefficient(d, 3), k3 = coefficient(d, 4);
  const double r2 = p.x * p.x + p.y * p.y;
  const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  return {p.x * radial + 2.0 * p1 * p.x * p.y + p2 * (r2 + 2.0 * p.x * p.x),
          p.y * radial + p1 * (r2 + 2.0 * p.y * p.y) + 2.0 * p2 * p.x * p.y};
}

// θ → θ_d of OpenCV's fisheye model.
double distortTheta(const std::vector<double>& d, double theta) {
  const double t2 = theta * theta;
  return theta * (1.0 + t2 * (coefficient(d, 0) +
                              t2 * (coefficient(d, 1) +
                                    t2 * (coefficient(d, 2) + t2 * coefficient(d, 3)))));
}

}  // namespace

Lens Lens::fromFieldOfView(int width, int height, double fovDegrees, Projection projection) {
  Lens lens;
  lens.width = width;
  lens.height = height;
  lens.projection = projection;
  const double half = 0.5 * fovDegrees * kPi / 180.0;
  lens.fx = lens.fy =
      projection == Projection::Rectilinear ? 0.5 * width / std::tan(half) : 0.5 * width / half;
  lens.cx = 0.5 * width;
  lens.cy = 0.5 * height;
  lens.source = "field of view " + std::to_string(fovDegrees) + " degrees";
  return lens;
}

bool Lens::hasDistortion() const {
  for (double d : distortion)
    if (d != 0.0) return true;
  return false;
}

bool Lens::direction(double px, double py, glm::dvec3& dir) const {
  const glm::dvec2 distorted((px - cx) / fx, (py - cy) / fy);
  if (projection == Projection::Rectilinear) {
    glm::dvec2 p = distorted;
    if (hasDistortion()) {
      // Fixed-point inversion, as OpenCV's undistortPoints, checked for convergence.
      bool converged = false;
      for (int it = 0; it < 100 && !converged; ++it) {
        const glm::dvec2 err = distortRectilinear(distortion, p) - distorted;
        p -= err;
        converged = std::abs(err.x) + std::abs(err.y) < 1e-12;
      }
      // It diverges where the distortion's slope passes 2 (a strong pincushion, k1 = 1 at half
      // the frame's width), though the distortion is invertible there: damped Newton then, from
      // the distorted point. A point the distortion folds back (its Jacobian not positive) has
      // no inverse.
      if (!converged || !std::isfinite(p.x) || !std::isfinite(p.y)) {
        p = distorted;
        auto residual = [&](const glm::dvec2& q) {
          return distortRectilinear(distortion, q) - distorted;
        };
        glm::dvec2 err = residual(p);
        for (int it = 0; it < 100 && !converged; ++it) {
          constexpr double h = 1e-7;
          const glm::dvec2 dx =
              (residual(p + glm::dvec2(h, 0.0)) - residual(p - glm::dvec2(h, 0.0))) / (2.0 * h);
          const glm::dvec2 dy =
              (residual(p + glm::dvec2(0.0, h)) - residual(p - glm::dvec2(0.0, h))) / (2.0 * h);
          const double det = dx.x * dy.y - dy.x * dx.y;
          if (!(det > 0.0)) return false;
          const glm::dvec2 step((dy.y * err.x - dy.x * err.y) / det,
                                (dx.x * err.y - dx.y * err.x) / det);
          double scale = 1.0;
          glm::dvec2 next = p - step, nextErr = residual(next);
          for (int halve = 0; halve < 40 && !(glm::length(nextErr) < glm::length(err)); ++halve) {
            scale *= 0.5;
            next = p - scale * step;
            nextErr = residual(next);
          }
          if (!(glm::length(nextErr) < glm::length(err))) return false;  // no nearer root
          p = next;
          err = nextErr;
          converged = std::abs(err.x) + std::abs(err.y) < 1e-12;
        }
        if (!converged || !std::isfinite(p.x) || !std::isfinite(p.y)) return false;
        // A root where the distortion folds back is not the point's direction.
        constexpr double h = 1e-7;
        const glm::dvec2 dx =
            (residual(p + glm::dvec2(h, 0.0)) - residual(p - glm::dvec2(h, 0.0))) / (2.0 * h);
        const glm::dvec2 dy =
            (residual(p + glm::dvec2(0.0, h)) - residual(p - glm::dvec2(0.0, h))) / (2.0 * h);
        if (!(dx.x * dy.y - dy.x * dx.y > 0.0)) return false;
      }
    }
    dir = glm::normalize(glm::dvec3(p.x, -p.y, -1.0));
    return true;
  }
  const double thetaD = glm::length(distorted);
  if (thetaD < 1e-15) {
    dir = glm::dvec3(0.0, 0.0, -1.0);
    return true;
  }
  double theta = thetaD;
  if (hasDistortion()) {
    // Newton on θ_d(θ) = target; the derivative is computed numerically.
    bool converged = false;
    for (int it = 0; it < 50 && !converged; ++it) {
      const double f = distortTheta(distortion, theta) - thetaD;
      const double h = 1e-7;
      const double df =
          (distortTheta(distortion, theta + h) - distortTheta(distortion, theta - h)) / (2.0 * h);
      if (!(df > 0.0)) return false;
      theta -= f / df;
      converged = std::abs(f) < 1e-13;
    }
    if (!converged) return false;
  }
  if (!(theta >= 0.0 && theta < kPi)) return false;
  const double s = std::sin(theta) / thetaD;
  dir = glm::dvec3(distorted.x * s, -distorted.y * s, -std::cos(theta));
  return true;
}

bool Lens::project(const glm::dvec3& d, glm::dvec2& pixel) const {
  if (projection == Projection::Rectilinear) {
    if (!(d.z < 0.0)) return false;
    glm::dvec2 p(d.x / -d.z, -d.y / -d.z);
    if (hasDistortion()) p = distortRectilinear(distortion, p);
    pixel = glm::dvec2(fx * p.x + cx, fy * p.y + cy);
    return std::isfinite(pixel.x) && std::isfinite(pixel.y);
  }
  const double r = std::sqrt(d.x * d.x + d.y * d.y);
  const double theta = std::atan2(r, -d.z);
  if (!(theta < kPi)) return false;
  if (r < 1e-300) {
    pixel = glm::dvec2(cx, cy);
    return true;
  }
  const double thetaD = hasDistortion() ? distortTheta(distortion, theta) : theta;
  pixel = glm::dvec2(fx * thetaD * d.x / r + cx, fy * thetaD * -d.y / r + cy);
  return std::isfinite(pixel.x) && std::isfinite(pixel.y);
}

Lens Lens::resized(int newWidth, int newHeight) const {
  Lens l = *this;
  const double sx = double(newWidth) / width, sy = double(newHeight) / height;
  l.width = newWidth;
  l.height = newHeight;
  l.fx *= sx;
  l.cx *= sx;
  l.fy *= sy;
  l.cy *= sy;
  return l;
}

Lens Lens::turnedFor(int exifOrientation) const {
  // The mirrored orientations: flipped left to right (stored (x, y) seen at (W - x, y)), then
  // turned as 3, 6 or 8 turn (EXIF: 4 is 2 and 180°, 5 is 2 and 90° anticlockwise, 7 is 2 and
  // 90° clockwise). Under x -> -x, Brown–Conrady's p2 changes sign and p1 does not.
  if (exifOrientation == 2 || exifOrientation == 4 || exifOrientation == 5 ||
      exifOrientation == 7) {
    Lens l = *this;
    l.cx = double(width) - cx;
    if (projection == Projection::Rectilinear && distortion.size() >= 4)
      l.distortion[3] = -distortion[3];
    l.source = source + (source.empty() ? "" : ", ") + "mirrored for the photo's EXIF orientation";
    const int then = exifOrientation == 4   ? 3
                     : exifOrientation == 5 ? 8
                     : exifOrientation == 7 ? 6
                                            : 1;
    if (then == 1) return l;
    Lens turned = l.turnedFor(then);
    turned.source = l.source + " and turned";
    return turned;
  }
  if (exifOrientation == 3) {  // turned 180°: (x, y) is seen at (W - x, H - y), (u, v) at (-u, -v)
    Lens l = *this;
    l.cx = double(width) - cx;
    l.cy = double(height) - cy;
    if (projection == Projection::Rectilinear && distortion.size() >= 4) {
      l.distortion[2] = -distortion[2];
      l.distortion[3] = -distortion[3];
    }
    l.source = source + (source.empty() ? "" : ", ") + "turned for the photo's EXIF orientation";
    return l;
  }
  if (exifOrientation != 6 && exifOrientation != 8) return *this;
  Lens l = *this;
  l.width = height;
  l.height = width;
  l.fx = fy;
  l.fy = fx;
  // Stored (x, y) is seen at (H - y, x) for 6 and at (y, W - x) for 8 (continuous pixels);
  // normalised coordinates (u, v) become (-v, u) and (v, -u).
  const bool clockwise = exifOrientation == 6;
  l.cx = clockwise ? double(height) - cy : cy;
  l.cy = clockwise ? cx : double(width) - cx;
  if (projection == Projection::Rectilinear && distortion.size() >= 4) {
    const double p1 = distortion[2], p2 = distortion[3];
    l.distortion[2] = clockwise ? p2 : -p2;
    l.distortion[3] = clockwise ? -p1 : p1;
  }
  l.source = source + (source.empty() ? "" : ", ") + "turned for the photo's EXIF orientation";
  return l;
}

std::optional<Lens> lensForImage(const Lens& lens, int width, int height, int exifOrientation) {
  const double aspect = double(width) / height;
  // Rounding each side of a resized image to whole pixels changes its aspect ratio by up to a
  // pixel on each side, relative (the smaller image's: it rounds more): half a pixel for rounding
  // to nearest, a whole one for resizers that truncate (int(h * s)) or round up.
  auto fits = [&](const Lens& l) {
    const double tolerance =
        1.0 / std::min(width, l.width) + 1.0 / std::min(height, l.height) + 1e-9;
    return std::abs(double(l.width) / l.height / aspect - 1.0) <= tolerance;
  };
  auto sized = [&](const Lens& l) {
    return l.width == width && l.height == height ? l : l.resized(width, height);
  };
  const Lens turned = lens.turnedFor(exifOrientation);
  if (fits(turned)) return sized(turned);
  if (fits(lens)) return sized(lens);  // a lens file written in the photo's upright frame
  return std::nullopt;
}

double Lens::horizontalFovDegrees() const {
  glm::dvec3 left, right;
  if (!direction(0.0, cy, left) || !direction(double(width), cy, right)) return 0.0;
  return std::acos(std::clamp(glm::dot(left, right), -1.0, 1.0)) * 180.0 / kPi;
}

void Lens::validate(const fs::path& file) const {
  auto fail = [&](const std::string& what) { throw Error("calib", what, file); };
  if (width <= 0 || height <= 0) fail("lens image size must be positive");
  if (!(fx > 0.0 && fy > 0.0 && std::isfinite(fx) && std::isfinite(fy)))
    fail("focal lengths fx, fy must be positive numbers of pixels");
  // Beyond these no lens made the photo: a view wider than 178 degrees through a rectilinear
  // lens, or narrower than a 0.06 degree telescope. fx = 1e308 overflowed the camera's matrices.
  const double side = std::max(width, height);
  for (const double f : {fx, fy}) {
    if (f < 0.01 * side || f > 1000.0 * side) {
      fail("focal length " + numberText(f) + " px is not one of a " + std::to_string(width) + "x" +
           std::to_string(height) + " image's lens (0.01 to 1000 times its longer side)");
    }
  }
  if (!std::isfinite(cx) || !std::isfinite(cy)) fail("principal point cx, cy must be finite");
  if (std::abs(cx - 0.5 * width) > 10.0 * side || std::abs(cy - 0.5 * height) > 10.0 * side)
    fail("principal point (" + numberText(cx) + ", " + numberText(cy) +
         ") lies far outside the image");
  const size_t maxCoefficients = projection == Projection::Rectilinear ? 5 : 4;
  if (distortion.size() > maxCoefficients) {
    fail(std::string(projection == Projection::Rectilinear ? "rectilinear" : "equidistant") +
         " lenses take at most " + std::to_string(maxCoefficients) +
         " distortion coefficients, got " + std::to_string(distortion.size()));
  }
  for (double d : distortion)
    if (!std::isfinite(d)) fail("distortion coefficients must be finite");
}

Lens lensFromJson(const nlohmann::json& j, const fs::path& file) try {
  if (!j.is_object()) throw Error("calib", "lens file must hold a JSON object", file);
  auto number = [&](const char* key) -> double {
    if (!j.contains(key) || !j[key].is_number())
      throw Error("calib", std::string("lens file needs a number '") + key + "'", file);
    return j[key].get<double>();
  };
  Lens lens;
  const std::string model = j.value("model", std::string("rectilinear"));
  if (model == "rectilinear") {
    lens.projection = Projection::Rectilinear;
  } else if (model == "equidistant") {
    lens.projection = Projection::Equidistant;
  } else {
    throw Error("calib", "unknown lens model '" + model + "'; valid: rectilinear, equidistant",
                file);
  }
  const double w = number("width"), h = number("height");
  if (!(w >= 1 && w <= 1e6 && h >= 1 && h <= 1e6 && w == std::floor(w) && h == std::floor(h)))
    throw Error("calib", "lens width and height must be whole numbers of pixels", file);
  lens.width = int(w);
  lens.height = int(h);
  lens.fx = number("fx");
  lens.fy = number("fy");
  lens.cx = number("cx") + 0.5;  // OpenCV's convention → continuous coordinates
  lens.cy = number("cy") + 0.5;
  if (j.contains("dist")) {
    if (!j["dist"].is_array()) throw Error("calib", "'dist' must be an array of numbers", file);
    for (const auto& v : j["dist"]) {
      if (!v.is_number()) throw Error("calib", "'dist' must be an array of numbers", file);
      lens.distortion.push_back(v.get<double>());
    }
  }
  if (j.contains("rms")) lens.rms = number("rms");
  lens.source = "lens file " + file.string();
  lens.validate(file);
  return lens;
} catch (const nlohmann::json::exception& e) {
  // A field of the wrong type (a number where text belongs, ...): nlohmann reports it by
  // exception; it is bad input like any other, named with its file.
  throw Error("calib", std::string("not a valid lens file: ") + jsonMessage(e.what()), file);
}

nlohmann::ordered_json lensToJson(const Lens& lens) {
  nlohmann::ordered_json j;
  j["model"] = lens.projection == Projection::Rectilinear ? "rectilinear" : "equidistant";
  j["width"] = lens.width;
  j["height"] = lens.height;
  j["fx"] = lens.fx;
  j["fy"] = lens.fy;
  j["cx"] = lens.cx - 0.5;
  j["cy"] = lens.cy - 0.5;
  j["dist"] = lens.distortion;
  j["rms"] = lens.rms;
  j["convention"] =
      "pixels as OpenCV: (0, 0) is the centre of the top-left pixel; camera looks along -Z, +Y up";
  return j;
}

Lens readLens(const fs::path& file) {
  protectInput(file);
  requireInputFile(file, "calib", "lens file");
  std::ifstream in(file);
  if (!in) throw Error("calib", "cannot open the lens file", file);
  nlohmann::json j;
  try {
    in >> j;
  } catch (const nlohmann::json::exception& e) {
    throw Error("calib", std::string("not a valid JSON lens file: ") + jsonMessage(e.what()), file);
  }
  return lensFromJson(j, file);
}

std::string lensText(const Lens& lens) {
  lens.validate();
  return lensToJson(lens).dump(2) + "\n";
}

void writeLens(const fs::path& file, const Lens& lens) {
  lens.validate(file);
  // An older lens file may be replaced, nothing else (a capture description or a scene named by
  // mistake was overwritten).
  requireReplaceable(
      file, "lens file",
      [](std::istream& in) {
        const nlohmann::json j = nlohmann::json::parse(in, nullptr, false);
        return j.is_object() && j.contains("model") && j.contains("fx") && j.contains("fy");
      },
      "calib");
  writeTextFile(file, lensToJson(lens).dump(2) + "\n", "calib");
}

}  // namespace compose::calib
