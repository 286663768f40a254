#include "calib/chessboard.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <optional>

#include <glm/geometric.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "calib/lens_json.h"
#include "core/error.h"
#include "core/json_number.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/output_files.h"

namespace compose::calib {

namespace fs = std::filesystem;

namespace {

constexpr const char* kStage = "calib";

// 8-bit grey of an image as read (values in [0, 1]; linear HDR input is clipped).
cv::Mat grey8(const Image& image) {
  cv::Mat out(image.height, image.width, CV_8UC1);
  const int ch = image.channels;
  for (int y = 0; y < image.height; ++y) {
    const float* src = image.row(y).data();
    uchar* dst = out.ptr<uchar>(y);
    for (int x = 0; x < image.width; ++x) {
      const float* p = src + size_t(x) * size_t(ch);
      const float v = ch >= 3 ? 0.299f * p[0] + 0.587f * p[1] + 0.114f * p[2] : p[0];
      dst[x] = cv::saturate_cast<uchar>(v * 255.0f + 0.5f);
    }
  }
  return out;
}

std::vector<cv::Point3f> boardPoints(const Board& board) {
  std::vector<cv::Point3f> pts;
  for (int r = 0; r < board.rows; ++r)
    for (int c = 0; c < board.columns; ++c)
      pts.emplace_back(float(c * board.square), float(r * board.square), 0.0f);
  return pts;
}

// Corners in OpenCV's pixel convention (centres on integers), refined; empty if not found.
std::vector<cv::Point2f> findCorners(const cv::Mat& grey, const Board& board, bool bent = false) {
  std::vector<cv::Point2f> corners;
  const cv::Size size(board.columns, board.rows);
  // OpenCV's fast check rejects a photo without a board at once; it also rejects a board that a
  // fisheye lens bends strongly (none found in 72 fisheye views where OpenCV finds 13 without
  // it). So with a fisheye (`bent`) a photo it rejects is searched again without it: the full
  // search is slow, and a rectilinear lens does not need it.
  const int flags = cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE;
  if (!cv::findChessboardCorners(grey, size, corners, flags | cv::CALIB_CB_FAST_CHECK) &&
      !(bent && cv::findChessboardCorners(grey, size, corners, flags)))
    return {};
  // The refinement window grows with the image, as squares do (11 x 11 half-size at VGA), but
  // stays within 0.45 of the closest corners' spacing: a window over the neighbouring corners
  // pulls every corner off (a small board on the ground of a plate: 15 px squares under an 11 px
  // half-window gave a pose 2° and 4 cm off).
  double spacing = std::numeric_limits<double>::infinity();
  for (int r = 0; r < board.rows; ++r) {
    for (int c = 0; c < board.columns; ++c) {
      const cv::Point2f& p = corners[size_t(r * board.columns + c)];
      if (c + 1 < board.columns)
        spacing =
            std::min(spacing, double(cv::norm(corners[size_t(r * board.columns + c + 1)] - p)));
      if (r + 1 < board.rows)
        spacing =
            std::min(spacing, double(cv::norm(corners[size_t((r + 1) * board.columns + c)] - p)));
    }
  }
  const int scaled =
      std::clamp(int(std::lround(11.0 * std::max(grey.cols, grey.rows) / 640.0)), 5, 31);
  const int half = std::max(2, std::min(scaled, std::isfinite(spacing) ? int(0.45 * spacing) : 31));
  cv::cornerSubPix(grey, corners, cv::Size(half, half), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 50, 0.001));
  return corners;
}

// A board with a column or a row more than `board` in the photo: OpenCV finds part of a larger
// board when asked for a smaller one. It also "finds" a larger board along a board's printed
// edge (10x6 on the 9x6 board of the opencv-doc photo left12, 8x7 on left05's when asked for
// 8x6): such a row or column does not continue the grid. So both end lines of the larger board
// (its first and last column, or row) must continue it: each corner within 8 % of a square, at
// the median, of where the three before it along its line put it (quadratic extrapolation:
// perspective and the lens's distortion bend the spacing smoothly; linear where the board is
// three deep). On the opencv-doc photos the corners of real larger boards lie 1-4 % of a square
// from it, the edges' 14-44 %.
std::optional<cv::Size> largerBoard(const cv::Mat& grey, const Board& board) {
  for (const bool column : {true, false}) {
    Board larger = board;
    (column ? larger.columns : larger.rows) += 1;
    const std::vector<cv::Point2f> found = findCorners(grey, larger);
    if (found.empty()) continue;
    const int C = larger.columns, R = larger.rows;
    const int n = column ? R : C, depth = column ? C : R;
    if (depth < 3) continue;  // too short to tell
    auto at = [&](int r, int c) { return found[size_t(r * C + c)]; };
    bool continues = true;
    for (const int line : {0, depth - 1}) {
      const int step = line == 0 ? 1 : -1;
      std::vector<double> off;
      for (int k = 0; k < n; ++k) {
        auto point = [&](int i) {  // i steps in from the end line
          return column ? at(k, line + i * step) : at(line + i * step, k);
        };
        const cv::Point2f p1 = point(1), p2 = point(2);
        const cv::Point2f predicted =
            depth >= 4 ? 3.0f * p1 - 3.0f * p2 + point(3) : 2.0f * p1 - p2;
        off.push_back(cv::norm(predicted - point(0)) / std::max(1e-6, cv::norm(p1 - p2)));
      }
      std::nth_element(off.begin(), off.begin() + ptrdiff_t(off.size() / 2), off.end());
      continues = continues && off[off.size() / 2] < 0.08;
    }
    if (continues) return cv::Size(C, R);
  }
  return std::nullopt;
}

std::string fixed(double v, int digits) {
  char text[48];
  std::snprintf(text, sizeof text, "%.*f", digits, v);
  return text;
}

nlohmann::ordered_json rows4(const glm::dmat4& m) {
  nlohmann::ordered_json j = nlohmann::ordered_json::array();
  for (int r = 0; r < 4; ++r) j.push_back({m[0][r], m[1][r], m[2][r], m[3][r]});
  return j;
}

}  // namespace

Board Board::parse(const std::string& text) {
  Board b;
  char x = 0;
  int c = 0, r = 0;
  char extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &c, &x, &r, &extra) != 3 || (x != 'x' && x != 'X'))
    throw Error(kStage,
                "a board is given as COLUMNSxROWS of inner corners, e.g. 9x6; got '" + text + "'");
  b.columns = c;
  b.rows = r;
  b.validate();
  return b;
}

std::string Board::name() const {
  return std::to_string(columns) + "x" + std::to_string(rows);
}

void Board::validate() const {
  // OpenCV's detector needs more than two inner corners each way.
  if (columns < 3 || rows < 3 || columns > 100 || rows > 100)
    throw Error(kStage, "a chessboard needs 3 to 100 inner corners each way, got " + name());
  // At a micrometre or less the scene's lengths reach the tracer's limits (Embree refuses rays
  // whose object-space directions are that long, and stopped the process).
  if (!(square >= 1e-6) || !std::isfinite(square))
    throw Error(kStage,
                "the chessboard's square size must be at least 1e-6, got " + numberText(square));
}

void CalibrationParams::validate() const {
  if (minPhotos < 1) throw Error(kStage, "at least one photo is needed");
}

LensCalibration calibrateLens(const std::vector<CalibrationPhoto>& photos, const Board& board,
                              const CalibrationParams& params, const Progress& progress) {
  board.validate();
  params.validate();
  if (photos.empty()) throw Error(kStage, "no photos to calibrate from");
  if (int(photos.size()) < params.minPhotos) {
    throw Error(kStage, std::to_string(photos.size()) + " photo" +
                            (photos.size() == 1 ? " was" : "s were") +
                            " given, and the calibration asks for at least " +
                            std::to_string(params.minPhotos) + " with the board (--min-photos)");
  }
  // Photos turned upright by their EXIF orientation (a portrait among landscapes) are one
  // sensor's: their corners are taken back to the sensor's frame, in which the lens is written
  // (and turned again for each photo that uses it: calib::lensForImage).
  auto turnsBy90 = [](int o) { return o == 6 || o == 8; };
  auto stored = [&](const CalibrationPhoto& p) {  // the sensor's size of a photo
    return turnsBy90(p.orientation) ? cv::Size(p.image->height, p.image->width)
                                    : cv::Size(p.image->width, p.image->height);
  };
  for (const CalibrationPhoto& p : photos) {
    if (p.orientation != 1 && p.orientation != 3 && !turnsBy90(p.orientation)) {
      throw Error(kStage,
                  "the photo's EXIF orientation " + std::to_string(p.orientation) +
                      " mirrors it: a mirrored photo is not a camera's view of the board",
                  p.file);
    }
    if (stored(p) != stored(photos.front())) {
      const cv::Size a = stored(p), b = stored(photos.front());
      throw Error(kStage,
                  "calibration photos must all come from one sensor size: this one is " +
                      std::to_string(a.width) + "x" + std::to_string(a.height) + ", " +
                      photos.front().file.filename().string() + " is " + std::to_string(b.width) +
                      "x" + std::to_string(b.height) + " (before their EXIF orientations)",
                  p.file);
    }
  }
  const cv::Size sensor = stored(photos.front());
  // Pixel centres (OpenCV's convention) of the upright photo to the sensor's frame and back.
  auto toSensor = [&](cv::Point2f q, int o) {
    const float w = float(sensor.width - 1), h = float(sensor.height - 1);
    switch (o) {
      case 3:
        return cv::Point2f(w - q.x, h - q.y);
      case 6:
        return cv::Point2f(q.y, h - q.x);
      case 8:
        return cv::Point2f(w - q.y, q.x);
      default:
        return q;
    }
  };
  LensCalibration out;
  std::vector<std::vector<cv::Point2f>> imagePoints;
  size_t repeated = 0;      // photos of a view another photo shows
  bool largerSaid = false;  // a board larger than --board found in a photo used
  for (size_t i = 0; i < photos.size(); ++i) {
    report(progress, "calib", double(i) / double(photos.size() + 1));
    auto corners =
        findCorners(grey8(*photos[i].image), board, params.model == Projection::Equidistant);
    if (corners.empty()) {
      out.rejected.push_back(photos[i].file);
    } else {
      if (photos[i].orientation != 1)
        for (cv::Point2f& c : corners) c = toSensor(c, photos[i].orientation);
      // The same view twice (a photo copied, a burst of a still camera) adds nothing the
      // calibration can use, yet would count towards --min-photos and weigh twice: eight copies
      // of one photo gave an RMS of 0.16 px and a focal length 52 % off, without a word.
      size_t same = imagePoints.size();
      for (size_t k = 0; k < imagePoints.size() && same == imagePoints.size(); ++k) {
        float apart = 0.0f;
        for (size_t c = 0; c < corners.size(); ++c)
          apart = std::max(apart, float(cv::norm(corners[c] - imagePoints[k][c])));
        if (apart < 0.05f) same = k;
      }
      if (same < imagePoints.size()) {
        ++repeated;
        out.notes.push_back(photos[i].file.filename().string() + " shows the board where " +
                            out.used[same].filename().string() +
                            " does, every corner within 0.05 px (the same photo twice?): left "
                            "out, a view counts once");
        continue;
      }
      out.used.push_back(photos[i].file);
      imagePoints.push_back(std::move(corners));
      // A board with a row or a column more also holds the one asked for: OpenCV finds part of
      // it, and the calibration is plausible but not what the photos show. Checked on the first
      // three photos used until one shows it (on the first alone, --board 7x6 for the 9x6 board
      // of the opencv-doc photos passed unsaid: left01 shows no 8x6 OpenCV finds).
      if (!largerSaid && out.used.size() <= 3) {
        if (const auto larger = largerBoard(grey8(*photos[i].image), board)) {
          largerSaid = true;
          out.notes.push_back(photos[i].file.filename().string() + " shows a board of " +
                              std::to_string(larger->width) + "x" + std::to_string(larger->height) +
                              " inner corners, more than --board " + board.name() +
                              " says: the calibration used part of it; count the inner corners "
                              "again");
        }
      }
    }
  }
  if (int(out.used.size()) < params.minPhotos) {
    std::string names;
    for (const auto& f : out.rejected) names += (names.empty() ? "" : ", ") + f.filename().string();
    const std::string what =
        out.used.empty()
            ? "no " + board.name() +
                  " chessboard (inner corners, columns x rows) found in any of the " +
                  std::to_string(photos.size()) + " photos (" + names +
                  "); check --board: count the inner corners"
            : "a " + board.name() + " chessboard was found in only " +
                  std::to_string(out.used.size()) + " of " + std::to_string(photos.size()) +
                  " photos" +
                  (repeated > 0 ? " as a view of its own (" + std::to_string(repeated) +
                                      " more show the same view as another photo: left out)"
                                : std::string()) +
                  "; at least " + std::to_string(params.minPhotos) + " are needed" +
                  (names.empty() ? std::string() : " (not found in: " + names + ")");
    throw Error(kStage, what, photos.front().file);
  }
  const std::vector<std::vector<cv::Point3f>> objectPoints(imagePoints.size(), boardPoints(board));
  const cv::Size size = sensor;
  cv::Mat K, dist;
  std::vector<cv::Mat> rvecs, tvecs;
  double rms = 0.0;
  Lens& lens = out.lens;
  lens.width = sensor.width;
  lens.height = sensor.height;
  lens.projection = params.model;
  try {
    if (params.model == Projection::Rectilinear) {
      rms = cv::calibrateCamera(objectPoints, imagePoints, size, K, dist, rvecs, tvecs);
    } else {
      std::vector<std::vector<cv::Point3d>> obj;
      std::vector<std::vector<cv::Point2d>> img;
      for (size_t i = 0; i < imagePoints.size(); ++i) {
        obj.emplace_back(objectPoints[i].begin(), objectPoints[i].end());
        img.emplace_back(imagePoints[i].begin(), imagePoints[i].end());
      }
      rms = cv::fisheye::calibrate(
          obj, img, size, K, dist, rvecs, tvecs,
          cv::fisheye::CALIB_RECOMPUTE_EXTRINSIC | cv::fisheye::CALIB_FIX_SKEW);
    }
  } catch (const cv::Exception& e) {
    throw Error(kStage, std::string("calibration failed: ") + e.err, photos.front().file);
  }
  K.convertTo(K, CV_64F);
  dist.convertTo(dist, CV_64F);
  lens.fx = K.at<double>(0, 0);
  lens.fy = K.at<double>(1, 1);
  lens.cx = K.at<double>(0, 2) + 0.5;  // OpenCV → continuous pixel coordinates
  lens.cy = K.at<double>(1, 2) + 0.5;
  for (int i = 0; i < int(dist.total()); ++i) lens.distortion.push_back(dist.at<double>(i));
  lens.rms = rms;
  lens.source = "chessboard calibration (" + std::to_string(out.used.size()) + " photos)";
  lens.validate();

  // Per-photo reprojection error, to point at a bad photo.
  for (size_t i = 0; i < imagePoints.size(); ++i) {
    std::vector<cv::Point2f> projected;
    if (params.model == Projection::Rectilinear) {
      cv::projectPoints(objectPoints[i], rvecs[i], tvecs[i], K, dist, projected);
    } else {
      cv::fisheye::projectPoints(objectPoints[i], projected, rvecs[i], tvecs[i], K, dist);
    }
    double sum = 0.0;
    for (size_t k = 0; k < projected.size(); ++k) {
      const cv::Point2f d = projected[k] - imagePoints[i][k];
      sum += double(d.x) * d.x + double(d.y) * d.y;
    }
    out.photoRms.push_back(std::sqrt(sum / double(projected.size())));
  }
  // Zhang's method needs at least three views of a plane to fix the focal lengths, the principal
  // point and the distortion together (--min-photos may allow fewer).
  if (out.used.size() < 3) {
    out.notes.push_back(
        "calibrated from " + std::to_string(out.used.size()) + " photo" +
        (out.used.size() == 1 ? "" : "s") +
        ": fewer than three views of the board do not fix the focal lengths, the principal point "
        "and the distortion together (a low reprojection error does not say they are right); "
        "photograph the board from more directions");
  }
  if (!out.rejected.empty()) {
    std::string names;
    for (const auto& f : out.rejected) names += (names.empty() ? "" : ", ") + f.filename().string();
    out.notes.push_back("no " + board.name() + " chessboard found in " +
                        std::to_string(out.rejected.size()) + " photo(s), left out: " + names);
  }
  report(progress, "calib", 1.0);
  return out;
}

PlatePose estimatePlatePose(const Image& plate, const fs::path& file, const Lens& lensIn,
                            const Board& board, int orientation) {
  board.validate();
  PlatePose pose;
  pose.board = board;
  pose.image = file;
  pose.width = plate.width;
  pose.height = plate.height;
  // Turned by the plate's EXIF orientation (the lens is in the sensor's frame) and scaled.
  const std::optional<Lens> fitted = lensForImage(lensIn, plate.width, plate.height, orientation);
  if (!fitted) {
    throw Error(kStage,
                "the lens was calibrated for " + std::to_string(lensIn.width) + "x" +
                    std::to_string(lensIn.height) + " images, the plate is " +
                    std::to_string(plate.width) + "x" + std::to_string(plate.height) +
                    " (another aspect ratio: a crop, which the calibration cannot follow, or a "
                    "photo turned without an EXIF orientation that says so)",
                file);
  }
  const Lens lens = *fitted;
  if (lens.source != lensIn.source)  // lensForImage says when it turned the lens
    pose.notes.push_back("the lens was turned for the plate's EXIF orientation");
  const bool sameSize = (lensIn.width == plate.width && lensIn.height == plate.height) ||
                        (lensIn.width == plate.height && lensIn.height == plate.width);
  if (!sameSize)
    pose.notes.push_back("the lens (" + std::to_string(lensIn.width) + "x" +
                         std::to_string(lensIn.height) + ") was scaled to the plate's size");
  pose.lens = lens;
  const cv::Mat grey = grey8(plate);
  const auto corners = findCorners(grey, board, lens.projection == Projection::Equidistant);
  if (corners.empty()) {
    throw Error(kStage,
                "no " + board.name() +
                    " chessboard (inner corners, columns x rows) found in the plate; check --board",
                file);
  }
  // Part of a larger board is a frame that does not stand where the board does: shifted by
  // squares, or turned half round (a 9x6 board taken as 7x6 put the camera at -x, -z).
  if (const auto larger = largerBoard(grey, board)) {
    throw Error(kStage,
                "the plate shows a board of " + std::to_string(larger->width) + "x" +
                    std::to_string(larger->height) + " inner corners, more than --board " +
                    board.name() +
                    " says: the pose would be that of part of it, its frame shifted or turned; "
                    "count the inner corners again",
                file);
  }
  // Undistort through the project's lens model: normalised OpenCV camera coordinates (x right,
  // y down, z forward) of every corner; then a distortion-free PnP with K = identity.
  std::vector<cv::Point2d> normalised;
  for (const cv::Point2f& c : corners) {
    glm::dvec3 d;
    if (!lens.direction(c.x + 0.5, c.y + 0.5, d) || !(d.z < 0.0)) {
      char at[64];
      std::snprintf(at, sizeof at, "(%.1f, %.1f)", double(c.x), double(c.y));
      throw Error(kStage,
                  std::string("the chessboard corner at ") + at +
                      " lies where the lens's distortion folds the frame back (the lens cannot "
                      "see it): a lens of another camera, or distortion coefficients out of range",
                  file);
    }
    normalised.emplace_back(d.x / -d.z, -d.y / -d.z);
  }
  const auto objectF = boardPoints(board);
  std::vector<cv::Point3d> object(objectF.begin(), objectF.end());
  cv::Mat rvec, tvec;
  const cv::Mat K = cv::Mat::eye(3, 3, CV_64F);
  if (!cv::solvePnP(object, normalised, K, cv::noArray(), rvec, tvec, false, cv::SOLVEPNP_IPPE) ||
      !cv::solvePnP(object, normalised, K, cv::noArray(), rvec, tvec, true,
                    cv::SOLVEPNP_ITERATIVE)) {
    throw Error(kStage, "cannot solve for the camera's pose from the chessboard", file);
  }
  cv::Mat Rm;
  cv::Rodrigues(rvec, Rm);
  // X_cv = R X_board + t.
  glm::dmat3 R;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R[c][r] = Rm.at<double>(r, c);
  const glm::dvec3 t(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2));
  const glm::dmat3 boardFromCv = glm::transpose(R);
  const glm::dvec3 cameraInBoard = -(boardFromCv * t);
  // World axes in board coordinates: X along the columns, Y the normal towards the camera.
  const glm::dvec3 xAxis(1.0, 0.0, 0.0);
  const glm::dvec3 yAxis = cameraInBoard.z >= 0.0 ? glm::dvec3(0, 0, 1) : glm::dvec3(0, 0, -1);
  const glm::dvec3 zAxis = glm::cross(xAxis, yAxis);
  const glm::dvec3 origin(0.5 * (board.columns - 1) * board.square,
                          0.5 * (board.rows - 1) * board.square, 0.0);
  // worldFromBoard: rows are the world axes.
  const glm::dmat3 worldFromBoard = glm::transpose(glm::dmat3(xAxis, yAxis, zAxis));
  const glm::dmat3 cvFromCamera(glm::dvec3(1, 0, 0), glm::dvec3(0, -1, 0), glm::dvec3(0, 0, -1));
  const glm::dmat3 rotation = worldFromBoard * boardFromCv * cvFromCamera;
  const glm::dvec3 position = worldFromBoard * (cameraInBoard - origin);
  pose.worldFromCamera = glm::dmat4(rotation);
  pose.worldFromCamera[3] = glm::dvec4(position, 1.0);

  // Reprojection error through the lens model, pixels.
  const glm::dmat4 cameraFromWorld = glm::inverse(pose.worldFromCamera);
  double sum = 0.0;
  for (size_t i = 0; i < corners.size(); ++i) {
    const glm::dvec3 pb(object[i].x, object[i].y, object[i].z);
    const glm::dvec3 pw = worldFromBoard * (pb - origin);
    const glm::dvec3 pc = glm::dvec3(cameraFromWorld * glm::dvec4(pw, 1.0));
    glm::dvec2 px;
    if (!lens.project(pc, px))
      throw Error(kStage, "the board's pose puts it behind the camera", file);
    const double dx = px.x - (corners[i].x + 0.5), dy = px.y - (corners[i].y + 0.5);
    sum += dx * dx + dy * dy;
  }
  pose.rms = std::sqrt(sum / double(corners.size()));
  if (pose.rms > 2.0) {
    pose.notes.push_back("the board's corners reproject with " + fixed(pose.rms, 2) +
                         " px RMS: the lens calibration may not fit this photo");
  }
  return pose;
}

std::string poseText(const PlatePose& pose) {
  pose.board.validate();
  nlohmann::ordered_json j;
  j["format"] = "compose-pose";
  j["version"] = 1;
  j["image"] = pose.image.filename().string();
  j["width"] = pose.width;
  j["height"] = pose.height;
  j["board"] = {
      {"columns", pose.board.columns}, {"rows", pose.board.rows}, {"square", pose.board.square}};
  j["worldFromCamera"] = rows4(pose.worldFromCamera);
  const glm::dvec3 p = pose.cameraPosition();
  j["cameraPosition"] = {p.x, p.y, p.z};
  j["rms"] = pose.rms;
  j["frame"] =
      "world: origin at the centre of the board's inner corners, the board in the plane y = 0, "
      "+Y out of the board towards the camera, +X along the board's columns; camera: +X right, "
      "+Y up, looking along -Z; lengths in the unit of 'square'";
  j["lens"] = lensToJson(pose.lens);
  return j.dump(2) + "\n";
}

void writePose(const fs::path& file, const PlatePose& pose) {
  // An older pose file may be replaced, nothing else.
  requireReplaceable(
      file, "pose file",
      [](std::istream& in) {
        const nlohmann::json j = nlohmann::json::parse(in, nullptr, false);
        return j.is_object() && j.value("format", std::string()) == "compose-pose";
      },
      kStage);
  writeTextFile(file, poseText(pose), kStage);
}

PlatePose readPose(const fs::path& file) try {
  protectInput(file);
  requireInputFile(file, kStage, "pose file");
  std::ifstream in(file);
  nlohmann::json j;
  try {
    in >> j;
  } catch (const nlohmann::json::exception& e) {
    throw Error(kStage, std::string("not a valid JSON pose file: ") + jsonMessage(e.what()), file);
  }
  auto fail = [&](const std::string& what) { throw Error(kStage, what, file); };
  if (!j.is_object() || j.value("format", std::string()) != "compose-pose")
    fail("not a pose file (\"format\" must be \"compose-pose\")");
  if (wholeMember(j, "version") != 1) fail("unsupported pose file version (this compose reads 1)");
  PlatePose pose;
  pose.image = j.value("image", std::string());
  pose.width = int(wholeMember(j, "width").value_or(0));
  pose.height = int(wholeMember(j, "height").value_or(0));
  if (!j.contains("board") || !j["board"].is_object()) fail("a pose file needs \"board\"");
  pose.board.columns = int(wholeMember(j["board"], "columns").value_or(0));
  pose.board.rows = int(wholeMember(j["board"], "rows").value_or(0));
  pose.board.square = j["board"].value("square", 0.0);
  pose.board.validate();
  const auto& m = j.value("worldFromCamera", nlohmann::json());
  bool ok = m.is_array() && m.size() == 4;
  for (int r = 0; ok && r < 4; ++r) {
    ok = m[r].is_array() && m[r].size() == 4;
    for (int c = 0; ok && c < 4; ++c) {
      ok = m[r][c].is_number();
      if (ok) pose.worldFromCamera[c][r] = m[r][c].get<double>();
    }
  }
  if (!ok) fail("\"worldFromCamera\" must be 4 rows of 4 numbers");
  // A rotation and a translation: RᵀR = I (a shear or a scale of determinant 1 passed the
  // determinant alone, and the object was rendered through a camera that bends space), det = 1,
  // and a last row of 0, 0, 0, 1.
  const glm::dmat3 rot(pose.worldFromCamera);
  const glm::dmat3 gram = glm::transpose(rot) * rot;
  double off = std::abs(glm::determinant(rot) - 1.0);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) off = std::max(off, std::abs(gram[c][r] - (r == c ? 1.0 : 0.0)));
  for (int c = 0; c < 4; ++c)
    off = std::max(off, std::abs(pose.worldFromCamera[c][3] - (c == 3 ? 1.0 : 0.0)));
  if (!(off <= 1e-3))
    fail(
        "\"worldFromCamera\" is not a rigid motion (its rotation part is not a rotation, or "
        "its last row is not 0, 0, 0, 1)");
  if (!j.contains("lens")) fail("a pose file needs \"lens\"");
  pose.lens = lensFromJson(j["lens"], file);
  pose.rms = j.value("rms", 0.0);
  return pose;
} catch (const nlohmann::json::exception& e) {
  // A field of the wrong type (a number where text belongs, ...): nlohmann reports it by
  // exception; it is bad input like any other, named with its file.
  throw Error(kStage, std::string("not a valid pose file: ") + jsonMessage(e.what()), file);
}

}  // namespace compose::calib
