// Chessboard calibration: lens intrinsics from photos of a printed chessboard, and the pose of a
// plate's camera from a chessboard lying in the scene. OpenCV does the detection and the
// estimation (findChessboardCorners, cornerSubPix, calibrateCamera / fisheye::calibrate,
// solvePnP); this file defines what goes in and what comes out.
//
// Boards are described by their INNER corners, columns x rows, as OpenCV counts them: the
// classic 10 x 7-square board is "9x6".
//
// Plate pose file (JSON, version 1), written by writePose(), read by readPose():
//
//   {"format": "compose-pose", "version": 1,
//    "image": "plate.jpg", "width": 3088, "height": 2056,
//    "board": {"columns": 9, "rows": 6, "square": 0.025},
//    "worldFromCamera": [[r00, r01, r02, tx], [..], [..], [0, 0, 0, 1]],   // rows
//    "cameraPosition": [x, y, z],
//    "rms": 0.31,                                                          // reprojection, px
//    "lens": {... the lens file's fields (calib/lens.h) ...}}
//
// Frames: the world is the board's. Origin at the centre of the grid of inner corners; the board
// lies in the plane y = 0; +Y is the board's normal on the camera's side (up, for a board lying
// on the ground or a table); +X runs along the board's columns (from the first detected corner
// towards the next one in its row); +Z = X × Y. Lengths are in the unit of `square` (metres
// when the square size is given in metres). The camera frame is the project's: +X right, +Y up,
// looking along -Z. The renderer can stand an object on the board by placing it at y = 0.
//
// Errors: compose::Error (stage "calib") naming the file and what is wrong.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <glm/mat4x4.hpp>

#include "calib/lens.h"
#include "core/image.h"
#include "core/progress.h"

namespace compose::calib {

struct Board {
  int columns = 9, rows = 6;  // inner corners
  double square = 1.0;        // side of a square, in the unit poses are wanted in
  // "9x6" → columns 9, rows 6; compose::Error (stage "calib") otherwise.
  static Board parse(const std::string& text);
  std::string name() const;  // "9x6"
  void validate() const;
};

struct CalibrationParams {
  Projection model = Projection::Rectilinear;
  int minPhotos = 3;  // fewer photos with a detected board is an error
  void validate() const;
};

struct CalibrationPhoto {
  std::filesystem::path file;
  const Image* image = nullptr;  // as read (ingest::readImage): encoded values in [0, 1]
  // The EXIF orientation readImage applied (1 upright, 3 turned 180°, 6 and 8 turned 90°): photos
  // held as portraits and as landscapes calibrate one lens, in the sensor's frame (as stored).
  int orientation = 1;
};

struct LensCalibration {
  Lens lens;  // intrinsics, distortion and RMS reprojection error (pixels)
  std::vector<std::filesystem::path> used;      // photos where the board was found
  std::vector<std::filesystem::path> rejected;  // photos where it was not
  std::vector<double> photoRms;                 // per used photo, pixels
  std::vector<std::string> notes;
};

// Finds the board in every photo (all photos must have the same size), refines the corners to
// sub-pixel accuracy and calibrates. Photos without a board are listed in `rejected`, not an
// error, unless fewer than params.minPhotos remain (error naming the board size and the photos).
LensCalibration calibrateLens(const std::vector<CalibrationPhoto>& photos, const Board& board,
                              const CalibrationParams& params, const Progress& progress = {});

struct PlatePose {
  glm::dmat4 worldFromCamera{1.0};
  Board board;
  Lens lens;         // the lens used, at the plate's size
  double rms = 0.0;  // reprojection error of the board's corners, pixels
  std::filesystem::path image;
  int width = 0, height = 0;
  std::vector<std::string> notes;
  glm::dvec3 cameraPosition() const { return glm::dvec3(worldFromCamera[3]); }
};

// The camera's pose relative to a chessboard visible in the plate. The lens is turned for a plate
// the EXIF `orientation` (of the plate file, already applied to `plate`) turned by 90° when it was
// calibrated the other way round, and scaled to the plate's size when it was calibrated at
// another size of the same aspect ratio (both noted); another aspect ratio is an error.
PlatePose estimatePlatePose(const Image& plate, const std::filesystem::path& file, const Lens& lens,
                            const Board& board, int orientation = 1);

void writePose(const std::filesystem::path& file, const PlatePose& pose);
// The JSON text writePose() writes.
std::string poseText(const PlatePose& pose);
PlatePose readPose(const std::filesystem::path& file);

}  // namespace compose::calib
