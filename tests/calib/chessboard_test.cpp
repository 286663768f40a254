// Chessboard calibration on the real opencv-doc photos (left01..left14), and plate poses on a
// synthetic photo of a board seen through a known camera.
#include "calib/chessboard.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <numbers>

#include <glm/geometric.hpp>

#include "ingest/image_io.h"
#include "pipeline/compose_job.h"
#include "test_util.h"

namespace compose::calib {
namespace {

std::string fileText(const std::filesystem::path& file) {
  std::ifstream in(file);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

using compose::testing::TempDir;

// The issue's targets for the left camera of OpenCV's stereo sample.
constexpr double kMaxRms = 0.5;                                     // pixels
constexpr double kFocal = 536.0, kFocalTolerance = 0.02;            // fx, fy within 2 % of 536
constexpr double kCx = 342.0, kCy = 236.0, kCentreTolerance = 5.0;  // pixels, OpenCV convention

std::vector<ingest::LoadedImage> loadLeftPhotos(std::vector<std::filesystem::path>& files) {
  std::vector<ingest::LoadedImage> images;
  const auto dir = pipeline::samplesDirectory() / "chessboard";
  for (int i = 1; i <= 14; ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "left%02d.jpg", i);
    const auto file = dir / name;
    if (!std::filesystem::exists(file)) continue;  // opencv-doc ships no left10
    files.push_back(file);
    images.push_back(ingest::readImage(file));
  }
  return images;
}

std::vector<CalibrationPhoto> photosOf(const std::vector<std::filesystem::path>& files,
                                       const std::vector<ingest::LoadedImage>& images) {
  std::vector<CalibrationPhoto> photos;
  for (size_t i = 0; i < files.size(); ++i) photos.push_back({files[i], &images[i].image});
  return photos;
}

TEST(Chessboard, CalibratesTheOpenCvLeftCameraWithinTheIssueTargets) {
  std::vector<std::filesystem::path> files;
  const auto images = loadLeftPhotos(files);
  ASSERT_GE(files.size(), 10u) << "sample chessboard photos missing (samples/fetch.sh)";
  const LensCalibration cal = calibrateLens(photosOf(files, images), Board::parse("9x6"), {});
  const Lens& l = cal.lens;
  std::printf(
      "[ figures ] %zu of %zu photos used: RMS %.3f px, fx %.2f, fy %.2f, cx %.2f, cy %.2f "
      "(OpenCV convention), dist %.4f %.4f %.4f %.4f %.4f\n",
      cal.used.size(), files.size(), l.rms, l.fx, l.fy, l.cx - 0.5, l.cy - 0.5, l.distortion[0],
      l.distortion[1], l.distortion[2], l.distortion[3], l.distortion[4]);
  EXPECT_LE(l.rms, kMaxRms);
  EXPECT_NEAR(l.fx, kFocal, kFocal * kFocalTolerance);
  EXPECT_NEAR(l.fy, kFocal, kFocal * kFocalTolerance);
  EXPECT_NEAR(l.cx - 0.5, kCx, kCentreTolerance);
  EXPECT_NEAR(l.cy - 0.5, kCy, kCentreTolerance);
  EXPECT_EQ(l.width, 640);
  EXPECT_EQ(l.height, 480);
  EXPECT_EQ(cal.photoRms.size(), cal.used.size());

  // Written through the lens file and read back unchanged (OpenCV convention in the file).
  TempDir dir;
  writeLens(dir / "camera.json", l);
  writeLens(dir / "camera.json", l);  // an older lens file is replaced
  // Another kind of file given by mistake is not.
  compose::testing::writeText(dir / "scene.json", "{\"compose\": \"scene\"}");
  COMPOSE_EXPECT_ERROR(writeLens(dir / "scene.json", l), "scene.json");
  EXPECT_EQ(fileText(dir / "scene.json"), "{\"compose\": \"scene\"}");
  const Lens back = readLens(dir / "camera.json");
  EXPECT_DOUBLE_EQ(back.fx, l.fx);
  EXPECT_DOUBLE_EQ(back.cx, l.cx);
  EXPECT_EQ(back.distortion, l.distortion);
}

// Some of the same photos held as portraits (turned upright by EXIF orientation 6 or 8) or
// upside down (3): their corners go back to the sensor's frame, and the lens is the one the
// landscape photos alone give.
TEST(Chessboard, PortraitAndUpsideDownPhotosCalibrateTheSameLens) {
  std::vector<std::filesystem::path> files;
  const auto images = loadLeftPhotos(files);
  ASSERT_GE(files.size(), 10u) << "sample chessboard photos missing (samples/fetch.sh)";
  const LensCalibration plain = calibrateLens(photosOf(files, images), Board::parse("9x6"), {});
  // Turned as a camera held so would store them, seen upright: 6 turns clockwise to be seen.
  auto turned = [](const Image& img, int orientation) {
    const bool quarter = orientation == 6 || orientation == 8;
    Image out(quarter ? img.height : img.width, quarter ? img.width : img.height, img.channels,
              img.channelNames);
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) {
        const int tx = orientation == 6   ? img.height - 1 - y
                       : orientation == 8 ? y
                                          : img.width - 1 - x;
        const int ty = orientation == 6   ? x
                       : orientation == 8 ? img.width - 1 - x
                                          : img.height - 1 - y;
        for (int c = 0; c < img.channels; ++c) out.at(tx, ty)[c] = img.at(x, y)[c];
      }
    return out;
  };
  // The lens is written in the sensor's frame whichever way the first photo was held.
  for (const int firstHeld : {1, 6}) {
    SCOPED_TRACE(firstHeld);
    std::vector<Image> held(images.size());
    std::vector<CalibrationPhoto> photos;
    const int orientations[] = {firstHeld, 6, 8, 3, 6};
    for (size_t i = 0; i < images.size(); ++i) {
      const int o = i < 5 ? orientations[i] : 1;
      held[i] = o == 1 ? images[i].image : turned(images[i].image, o);
      photos.push_back({files[i], &held[i], o});
    }
    const LensCalibration mixed = calibrateLens(photos, Board::parse("9x6"), {});
    const Lens &a = plain.lens, &b = mixed.lens;
    std::printf(
        "[ figures ] mixed orientations: fx %.3f / %.3f, cx %.3f / %.3f, cy %.3f / %.3f, "
        "RMS %.4f / %.4f px\n",
        b.fx, a.fx, b.cx, a.cx, b.cy, a.cy, b.rms, a.rms);
    EXPECT_EQ(b.width, 640);
    EXPECT_EQ(b.height, 480);
    // Corners found on turned images agree with the upright ones to far below this.
    EXPECT_NEAR(b.fx, a.fx, 0.02);
    EXPECT_NEAR(b.fy, a.fy, 0.02);
    EXPECT_NEAR(b.cx, a.cx, 0.02);
    EXPECT_NEAR(b.cy, a.cy, 0.02);
    EXPECT_NEAR(b.rms, a.rms, 0.005);
    EXPECT_EQ(mixed.used.size(), plain.used.size());
    // Without the orientations the sizes differ; a mirrored photo is no view of the board.
    photos[1].orientation = 1;
    COMPOSE_EXPECT_ERROR(calibrateLens(photos, Board::parse("9x6"), {}), "one sensor size");
    photos[1].orientation = 6;
    photos[5].orientation = 2;
    COMPOSE_EXPECT_ERROR(calibrateLens(photos, Board::parse("9x6"), {}), "mirrors it");
  }
}

// A board size a column short of the photos' board is found as part of it (OpenCV finds 8x6 on
// the 9x6 board, not 9x5): the calibration runs, with a note that the photos show a larger board;
// the right size has no note.
TEST(Chessboard, ABoardSizeThatIsPartOfThePhotosBoardIsNoted) {
  std::vector<std::filesystem::path> files;
  const auto images = loadLeftPhotos(files);
  ASSERT_GE(files.size(), 4u) << "sample chessboard photos missing (samples/fetch.sh)";
  auto noted = [](const LensCalibration& cal) {
    for (const std::string& n : cal.notes)
      if (n.find("shows a board of 9x6 inner corners, more than --board") != std::string::npos)
        return true;
    return false;
  };
  EXPECT_TRUE(noted(calibrateLens(photosOf(files, images), Board::parse("8x6"), {})));
  EXPECT_FALSE(noted(calibrateLens(photosOf(files, images), Board::parse("9x6"), {})));
  // Two columns short: the first photo used shows no 8x6 OpenCV finds, the second does (it
  // was checked on the first alone, and 7x6 passed unsaid).
  bool larger = false;
  for (const std::string& n : calibrateLens(photosOf(files, images), Board::parse("7x6"), {}).notes)
    larger = larger || n.find("inner corners, more than --board 7x6 says") != std::string::npos;
  EXPECT_TRUE(larger);
}

TEST(Chessboard, WrongBoardSizeNamesTheBoardAndThePhotos) {
  std::vector<std::filesystem::path> files;
  const auto images = loadLeftPhotos(files);
  ASSERT_FALSE(files.empty());
  // Only three photos, to keep the failing detection quick.
  files.resize(3);
  COMPOSE_EXPECT_ERROR(calibrateLens(photosOf(files, images), Board::parse("8x5"), {}),
                       "no 8x5 chessboard");
  COMPOSE_EXPECT_ERROR(calibrateLens(photosOf(files, images), Board::parse("8x5"), {}),
                       "left01.jpg");
  // More photos asked for than given: said before any board is looked for (it was "found in
  // only 3 of 3 photos ... (not found in: )").
  CalibrationParams many;
  many.minPhotos = 100;
  COMPOSE_EXPECT_ERROR(
      calibrateLens(photosOf(files, images), Board::parse("9x6"), many),
      "3 photos were given, and the calibration asks for at least 100 with the board");
  // One photo allowed: a result, but a note that one view does not fix the lens; three: none.
  CalibrationParams one;
  one.minPhotos = 1;
  std::vector<std::filesystem::path> first(files.begin(), files.begin() + 1);
  const LensCalibration single = calibrateLens(photosOf(first, images), Board::parse("9x6"), one);
  ASSERT_EQ(single.used.size(), 1u);
  bool said = false;
  for (const std::string& n : single.notes)
    said = said || n.find("calibrated from 1 photo: fewer than three views") == 0;
  EXPECT_TRUE(said);
  const LensCalibration three = calibrateLens(photosOf(files, images), Board::parse("9x6"), {});
  for (const std::string& n : three.notes) EXPECT_EQ(n.find("fewer than three"), std::string::npos);
}

TEST(Chessboard, PhotosWithoutABoardAreListedNotFatal) {
  std::vector<std::filesystem::path> files;
  auto images = loadLeftPhotos(files);
  ASSERT_GE(files.size(), 6u);
  files.resize(6);
  // A blank photo of the same size: no board in it.
  ingest::LoadedImage blank;
  blank.image = Image(640, 480, 3);
  std::fill(blank.image.pixels.begin(), blank.image.pixels.end(), 0.5f);
  images.insert(images.begin() + 6, blank);
  files.push_back("blank.jpg");
  std::vector<CalibrationPhoto> photos;
  for (size_t i = 0; i < files.size(); ++i) photos.push_back({files[i], &images[i].image});
  const LensCalibration cal = calibrateLens(photos, Board::parse("9x6"), {});
  ASSERT_EQ(cal.rejected.size(), 1u);
  EXPECT_EQ(cal.rejected[0], "blank.jpg");
  EXPECT_EQ(cal.used.size(), 6u);
  ASSERT_FALSE(cal.notes.empty());
  EXPECT_NE(cal.notes[0].find("blank.jpg"), std::string::npos);
}

TEST(Chessboard, BoardSizeIsParsedStrictly) {
  EXPECT_EQ(Board::parse("9x6").columns, 9);
  EXPECT_EQ(Board::parse("9x6").rows, 6);
  COMPOSE_EXPECT_ERROR(Board::parse("9"), "COLUMNSxROWS");
  COMPOSE_EXPECT_ERROR(Board::parse("9x6x2"), "COLUMNSxROWS");
  COMPOSE_EXPECT_ERROR(Board::parse("1x6"), "3 to 100");
  // OpenCV's detector refuses two corners a side: refused here first, in our words.
  COMPOSE_EXPECT_ERROR(Board::parse("2x2"), "3 to 100 inner corners each way, got 2x2");
  EXPECT_EQ(Board::parse("3x3").rows, 3);
}

// A photo of a 9x6 board (squares of `square` metres, a white margin) lying on grey ground in
// the plane y = 0, rows running along -Z, seen through `lens` from `worldFromCamera`; 4 x 4 rays
// per pixel.
Image renderBoard(const Lens& lens, const glm::dmat4& worldFromCamera, double square) {
  Image img(lens.width, lens.height, 3);
  const glm::dvec3 origin(worldFromCamera[3]);
  for (int y = 0; y < lens.height; ++y) {
    for (int x = 0; x < lens.width; ++x) {
      double sum = 0.0;
      for (int j = 0; j < 4; ++j) {
        for (int i = 0; i < 4; ++i) {
          glm::dvec3 d;
          double v = 0.3;
          if (lens.direction(x + (i + 0.5) / 4, y + (j + 0.5) / 4, d)) {
            const glm::dvec3 w = glm::dvec3(worldFromCamera * glm::dvec4(d, 0.0));
            if (w.y < 0.0) {
              const glm::dvec3 p = origin + w * (-origin.y / w.y);
              const double a = std::floor(p.x / square + 4.0);       // 9 columns: -1..9 squares
              const double b = std::floor(-p.z / square + 2.5);      // 6 rows: -1..6 squares
              if (a >= -2 && a <= 9 && b >= -2 && b <= 6) v = 0.95;  // margin
              if (a >= -1 && a <= 8 && b >= -1 && b <= 5) v = (int(a + b) % 2 == 0) ? 0.05 : 0.95;
            }
          }
          sum += v;
        }
      }
      float* p = img.at(x, y);
      p[0] = p[1] = p[2] = float(sum / 16.0);
    }
  }
  return img;
}

glm::dmat4 lookAt(const glm::dvec3& eye, const glm::dvec3& target) {
  const glm::dvec3 f = glm::normalize(target - eye);
  const glm::dvec3 r = glm::normalize(glm::cross(f, glm::dvec3(0, 1, 0)));
  const glm::dvec3 u = glm::cross(r, f);
  glm::dmat4 m(1.0);
  m[0] = glm::dvec4(r, 0);
  m[1] = glm::dvec4(u, 0);
  m[2] = glm::dvec4(-f, 0);
  m[3] = glm::dvec4(eye, 1);
  return m;
}

// The camera's position a pose gives, as near the truth as the board's symmetry allows: the board
// looks the same turned by 180 degrees about its normal, so the detected corner order may run the
// other way, and then the world is turned by 180 degrees about +Y.
glm::dvec3 cameraNear(const PlatePose& pose, const glm::dvec3& eye) {
  const glm::dvec3 p = pose.cameraPosition(), turned(-p.x, p.y, -p.z);
  return glm::length(p - eye) > glm::length(turned - eye) ? turned : p;
}

// The pose of a 9x6 board of `square` metres rendered through `lens` from `eye`, looking at it.
PlatePose poseOfBoardSeenFrom(const Lens& lens, const glm::dvec3& eye, double square,
                              const char* name) {
  Board board = Board::parse("9x6");
  board.square = square;
  return estimatePlatePose(renderBoard(lens, lookAt(eye, glm::dvec3(0.0)), square), name, lens,
                           board);
}

TEST(Chessboard, PlatePoseRecoversTheCameraAboveTheBoard) {
  // A slightly distorted lens, so that the pose goes through the lens model's inversion.
  Lens lens = Lens::fromFieldOfView(640, 480, 60.0);
  lens.distortion = {-0.05, 0.01, 0.0, 0.0, 0.0};
  const double square = 0.025;
  const glm::dvec3 eye(0.08, 0.22, 0.25);
  const glm::dmat4 truth = lookAt(eye, glm::dvec3(0.0));
  const Image photo = renderBoard(lens, truth, square);
  Board board = Board::parse("9x6");
  board.square = square;
  const PlatePose pose = estimatePlatePose(photo, "synthetic.png", lens, board);
  const glm::dvec3 p = cameraNear(pose, eye);
  std::printf(
      "[ figures ] pose: camera at (%.4f, %.4f, %.4f), truth (%.4f, %.4f, %.4f), "
      "reprojection %.3f px\n",
      p.x, p.y, p.z, eye.x, eye.y, eye.z, pose.rms);
  // Sub-pixel corners at ~0.35 m: the position is good to a millimetre or two.
  EXPECT_NEAR(glm::length(p - eye), 0.0, 0.002);
  EXPECT_LT(pose.rms, 0.2);
  // The camera's optical axis points at the board's centre (the world origin).
  const glm::dvec3 forward = -glm::dvec3(pose.worldFromCamera[2]);
  const glm::dvec3 toOrigin = glm::normalize(-pose.cameraPosition());
  EXPECT_GT(glm::dot(forward, toOrigin), std::cos(0.2 * std::numbers::pi / 180.0));
  // +Y of the camera's image is up in the world, roughly (the camera is not rolled).
  EXPECT_GT(pose.worldFromCamera[1][1], 0.5);

  // The same photo held as a portrait (stored landscape, EXIF orientation 6: seen turned 90°
  // clockwise), posed with the landscape lens: the lens is turned with it, and the camera is
  // where it was, to the precision of the corners.
  Image portrait(photo.height, photo.width, photo.channels, photo.channelNames);
  for (int y = 0; y < photo.height; ++y)
    for (int x = 0; x < photo.width; ++x)
      for (int c = 0; c < photo.channels; ++c)
        portrait.at(photo.height - 1 - y, x)[c] = photo.at(x, y)[c];
  const PlatePose turned = estimatePlatePose(portrait, "portrait.png", lens, board, 6);
  const glm::dvec3 q = cameraNear(turned, eye);
  EXPECT_NEAR(glm::length(q - eye), 0.0, 0.002);
  EXPECT_LT(turned.rms, 0.2);
  EXPECT_NE(std::find(turned.notes.begin(), turned.notes.end(),
                      "the lens was turned for the plate's EXIF orientation"),
            turned.notes.end());
  // Without the orientation the aspect is another one: an error, as before.
  COMPOSE_EXPECT_ERROR(estimatePlatePose(portrait, "portrait.png", lens, board),
                       "another aspect ratio");

  TempDir dir;
  writePose(dir / "pose.json", pose);
  const PlatePose back = readPose(dir / "pose.json");
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r)
      EXPECT_NEAR(back.worldFromCamera[c][r], pose.worldFromCamera[c][r], 1e-12);
  EXPECT_NEAR(back.lens.fx, lens.fx, 1e-9);
  EXPECT_EQ(back.board.columns, 9);

  // Written over an older pose file only: not over another kind of file given by mistake.
  writePose(dir / "older.json", pose);
  writePose(dir / "older.json", pose);
  compose::testing::writeText(dir / "capture.json", "{\"format\": \"compose-capture\"}");
  COMPOSE_EXPECT_ERROR(writePose(dir / "capture.json", pose), "capture.json");
  EXPECT_EQ(fileText(dir / "capture.json"), "{\"format\": \"compose-capture\"}");
}

// A board size short of the plate's board is part of it, and its pose another frame (shifted by
// squares, or turned half round): refused, naming the board the plate shows. It was taken without
// a word (7x6 on left12's 9x6 board put the camera at -x, -z: the frame turned half round).
TEST(Chessboard, APlatePoseOfPartOfTheBoardIsRefused) {
  const auto file = pipeline::samplesDirectory() / "chessboard" / "left12.jpg";
  ASSERT_TRUE(std::filesystem::exists(file)) << "sample chessboard photos missing";
  const ingest::LoadedImage plate = ingest::readImage(file);
  const Lens lens = Lens::fromFieldOfView(640, 480, 60.0);
  EXPECT_NO_THROW(estimatePlatePose(plate.image, file, lens, Board::parse("9x6")));
  for (const char* part : {"7x6", "8x6"})
    COMPOSE_EXPECT_ERROR(estimatePlatePose(plate.image, file, lens, Board::parse(part)),
                         "more than --board " + std::string(part) + " says");
}

// A board small in the plate (squares of 13 to 17 pixels, as a board on the ground of a wide
// shot): the corners' refinement window stays within their spacing. The 11-pixel half-window of
// a VGA image took in the neighbouring corners: the camera 29 mm off, 3.4 px RMS.
TEST(Chessboard, ASmallBoardInThePlateGivesItsPose) {
  Lens lens = Lens::fromFieldOfView(640, 480, 45.0);
  lens.distortion = {-0.05, 0.01, 0.0, 0.0, 0.0};
  const glm::dvec3 eye(0.1, 0.9, 0.7);
  const PlatePose pose = poseOfBoardSeenFrom(lens, eye, 0.025, "small.png");
  const glm::dvec3 p = cameraNear(pose, eye);
  const glm::dvec3 forward = -glm::dvec3(pose.worldFromCamera[2]);
  const double off =
      std::acos(std::min(1.0, glm::dot(forward, glm::normalize(-pose.cameraPosition())))) * 180.0 /
      std::numbers::pi;
  std::printf(
      "[ figures ] small board: camera %.2f mm from the truth at %.2f m, axis %.3f° off, "
      "reprojection %.3f px\n",
      1000.0 * glm::length(p - eye), glm::length(eye), off, pose.rms);
  EXPECT_LT(glm::length(p - eye), 0.002 * glm::length(eye));
  EXPECT_LT(off, 0.1);
  EXPECT_LT(pose.rms, 0.2);
}

// The same photo twice adds nothing: it is left out with a note, and counts once towards the
// photos needed (eight copies of one photo calibrated a lens 52 % off, without a word).
TEST(Chessboard, TheSamePhotoTwiceCountsOnce) {
  std::vector<std::filesystem::path> files;
  const auto images = loadLeftPhotos(files);
  ASSERT_GE(files.size(), 3u) << "sample chessboard photos missing (samples/fetch.sh)";
  std::vector<CalibrationPhoto> photos;
  for (int i = 0; i < 4; ++i) photos.push_back({files[0], &images[0].image});
  photos.push_back({files[1], &images[1].image});
  COMPOSE_EXPECT_ERROR(calibrateLens(photos, Board::parse("9x6"), {}),
                       "found in only 2 of 5 photos as a view of its own (3 more show the same "
                       "view as another photo: left out); at least 3 are needed");
  photos.push_back({files[2], &images[2].image});
  const LensCalibration cal = calibrateLens(photos, Board::parse("9x6"), {});
  EXPECT_EQ(cal.used.size(), 3u);
  size_t noted = 0;
  for (const std::string& n : cal.notes)
    noted += n.find("shows the board where " + files[0].filename().string()) != std::string::npos;
  EXPECT_EQ(noted, 3u);
}

TEST(Chessboard, PlatePoseErrors) {
  const Lens lens = Lens::fromFieldOfView(640, 480, 60.0);
  Image blank(640, 480, 3);
  COMPOSE_EXPECT_ERROR(estimatePlatePose(blank, "plate.jpg", lens, Board::parse("9x6")),
                       "no 9x6 chessboard");
  Image square(480, 480, 3);
  COMPOSE_EXPECT_ERROR(estimatePlatePose(square, "plate.jpg", lens, Board::parse("9x6")),
                       "another aspect ratio");
  TempDir dir;
  compose::testing::writeText(dir / "pose.json", "{\"format\": \"compose-pose\", \"version\": 2}");
  COMPOSE_EXPECT_ERROR(readPose(dir / "pose.json"), "version");
  // A rotation part of determinant 1 that is no rotation (a shear): refused, not rendered through.
  PlatePose sheared;
  sheared.lens = lens;
  sheared.board = Board::parse("9x6");
  sheared.board.square = 0.025;
  sheared.worldFromCamera = glm::dmat4(1.0);
  sheared.worldFromCamera[0][0] = 2.0;
  sheared.worldFromCamera[1][1] = 0.5;
  sheared.worldFromCamera[3] = glm::dvec4(0.0, 1.0, 1.0, 1.0);
  writePose(dir / "sheared.json", sheared);
  COMPOSE_EXPECT_ERROR(readPose(dir / "sheared.json"), "is not a rigid motion");
}

}  // namespace
}  // namespace compose::calib
