// compose calib lens | pose: lens intrinsics from chessboard photos, and the plate camera's pose
// from a chessboard in the plate.
#include <cmath>
#include <cstdio>

#include "app/cli.h"
#include "calib/chessboard.h"
#include "calib/plate_camera.h"
#include "core/numbers.h"
#include "core/output_files.h"
#include "ingest/capture.h"
#include "ingest/image_io.h"

namespace compose::app {

namespace {

struct CalibOptions {
  // lens
  std::vector<std::filesystem::path> photos;
  std::filesystem::path lensOut;
  std::string lensBoard = "9x6", model = "rectilinear";
  int minPhotos = 3;
  // pose
  std::filesystem::path plate, lensFile, poseOut;
  std::string poseBoard = "9x6";
  double square = 0.0;
  double focal35 = 0.0;
  CLI::Option *squareOption = nullptr, *focal35Option = nullptr;
};

}  // namespace

Runner setupCalib(CLI::App& command, const Globals& globals) {
  auto o = std::make_shared<CalibOptions>();
  command.footer(
      "Camera calibration from chessboard photos (OpenCV).\n\nExamples:\n"
      "  compose calib lens --board 9x6 --out camera.json board/*.jpg\n"
      "  compose calib pose --board 9x6 --square 0.025 --lens camera.json --out pose.json "
      "plate.jpg");
  command.require_subcommand(1, 1);
  CLI::App* lens = command.add_subcommand(
      "lens", "Intrinsics and distortion from photos of a chessboard, written as a lens file");
  lens->add_option("photos", o->photos, "Photos (or folders) of the board, from one camera")
      ->required();
  lens->add_option("--board", o->lensBoard, "Inner corners, columns x rows")->capture_default_str();
  lens->add_option("--out", o->lensOut, "Lens file (JSON: fx, fy, cx, cy, dist, rms)")->required();
  lens->add_option("--model", o->model, "rectilinear (Brown-Conrady) or fisheye (equidistant)")
      ->capture_default_str();
  lens->add_option("--min-photos", o->minPhotos, "Fewer photos with a board is an error")
      ->capture_default_str();

  CLI::App* pose = command.add_subcommand(
      "pose", "The plate camera's pose from a chessboard lying in the scene, as a pose file");
  pose->add_option("plate", o->plate, "The plate photo")->required();
  pose->add_option("--board", o->poseBoard, "Inner corners, columns x rows")->capture_default_str();
  o->squareOption =
      pose->add_option("--square", o->square,
                       "Side of one square, metres (the pose file's unit) [default: 1 = squares]");
  pose->add_option("--lens", o->lensFile, "Lens file of the plate's camera (compose calib lens)");
  o->focal35Option =
      pose->add_option("--focal35", o->focal35,
                       "Without --lens: 35 mm equivalent focal length [default: EXIF, else 50]");
  pose->add_option("--out", o->poseOut, "Pose file (JSON)")->required();

  return [o, lens, &globals]() -> int {
    const std::string out = (lens->parsed() ? o->lensOut : o->poseOut).string();
    if (ingest::lowerExtension(out) != ".json")
      throw UsageError("--out must name a JSON file (.json): the " +
                       std::string(lens->parsed() ? "lens" : "pose") + " file is JSON ('" + out +
                       "' is not one)");
    if (lens->parsed()) {
      calib::Board board;
      calib::CalibrationParams params;
      asUsage([&] { board = calib::Board::parse(o->lensBoard); });
      if (o->model == "rectilinear") {
        params.model = calib::Projection::Rectilinear;
      } else if (o->model == "fisheye" || o->model == "equidistant") {
        params.model = calib::Projection::Equidistant;
      } else {
        throw UsageError("--model must be rectilinear or fisheye, got '" + o->model + "'");
      }
      params.minPhotos = o->minPhotos;
      asUsage([&] { params.validate(); });
      ProgressPrinter printer(globals);
      const auto shots = ingest::scanShots(o->photos, "calib");
      std::vector<ingest::LoadedImage> images;
      images.reserve(shots.size());
      for (size_t i = 0; i < shots.size(); ++i) {
        images.push_back(ingest::readImage(shots[i].file, "calib"));
        printer("read", double(i + 1) / double(shots.size()));
      }
      std::vector<calib::CalibrationPhoto> photos;
      for (size_t i = 0; i < shots.size(); ++i)
        photos.push_back({shots[i].file, &images[i].image, images[i].info.orientation});
      const calib::LensCalibration cal =
          calib::calibrateLens(photos, board, params, printer.callback());
      calib::writeLens(o->lensOut, cal.lens);
      if (!globals.quiet) {
        const calib::Lens& l = cal.lens;
        std::fprintf(stderr,
                     "compose: %zu of %zu photos show the %s board; RMS reprojection %.3f px\n",
                     cal.used.size(), photos.size(), board.name().c_str(), l.rms);
        std::fprintf(stderr,
                     "compose: fx %.2f fy %.2f cx %.2f cy %.2f (pixels, OpenCV convention), "
                     "horizontal field of view %.1f degrees\n",
                     l.fx, l.fy, l.cx - 0.5, l.cy - 0.5, l.horizontalFovDegrees());
        std::string dist;
        for (double d : l.distortion) {
          char text[24];
          std::snprintf(text, sizeof text, "%s%.5f", dist.empty() ? "" : " ", d);
          dist += text;
        }
        std::fprintf(stderr, "compose: distortion %s\n", dist.c_str());
        for (size_t i = 0; i < cal.used.size(); ++i)
          std::fprintf(stderr, "compose:   %-24s %.3f px\n",
                       cal.used[i].filename().string().c_str(), cal.photoRms[i]);
      }
      printNotes(globals, cal.notes);
      std::printf("%s\n", o->lensOut.string().c_str());
      return 0;
    }

    // pose
    // Zero is a value given, not the default: it is refused like any other size that is not one.
    const bool squareGiven = o->squareOption->count() > 0,
               focal35Given = o->focal35Option->count() > 0;
    calib::Board board;
    asUsage([&] { board = calib::Board::parse(o->poseBoard); });
    if (squareGiven) {
      if (!(o->square >= 1e-6 && o->square < 1000.0)) {
        throw UsageError(
            "--square must be the side of one square in metres, at least 1e-6 (a micrometre) "
            "and less than 1000; got " +
            numberText(o->square));
      }
      board.square = o->square;
    }
    asUsage([&] { board.validate(); });
    if (!o->lensFile.empty() && focal35Given)
      throw UsageError("give either --lens or --focal35, not both");
    calib::CameraOptions camera;
    if (focal35Given) camera.focal35mm = o->focal35;
    camera.validate();
    std::vector<std::string> notes;
    if (!squareGiven)
      notes.push_back("no --square: lengths in the pose file are in chessboard squares");
    const ingest::LoadedImage plate = ingest::readImage(o->plate, "calib");
    calib::Lens lensModel;
    if (!o->lensFile.empty()) {
      lensModel = calib::readLens(o->lensFile);
    } else {
      // A pinhole from the 35 mm equivalent focal length, as the plate camera uses.
      const calib::PlateCamera pin =
          calib::plateCamera(plate.image.width, plate.image.height, plate.info, camera);
      lensModel = pin.lens;
      lensModel.source = pin.focalSource;
      notes.push_back("no lens file: an ideal pinhole with the focal length from " +
                      pin.focalSource + " (" + std::to_string(int(std::lround(pin.focal35mm))) +
                      " mm equivalent); calibrate the lens for an accurate pose");
    }
    const calib::PlatePose result = [&] {
      try {
        return calib::estimatePlatePose(plate.image, o->plate, lensModel, board,
                                        plate.info.orientation);
      } catch (const Error& e) {
        // What the lens cannot see is the lens file's fault: named with it.
        if (o->lensFile.empty() ||
            std::string(e.what()).find("the lens's distortion") == std::string::npos)
          throw;
        throw Error(e.stage(), std::string(e.what()) + " (" + o->plate.string() + ")", o->lensFile);
      }
    }();
    calib::writePose(o->poseOut, result);
    if (!globals.quiet) {
      const glm::dvec3 c = result.cameraPosition();
      std::fprintf(stderr,
                   "compose: camera at (%.4f, %.4f, %.4f) in the board's frame, %.4f above the "
                   "board; corners reproject with %.3f px RMS\n",
                   c.x, c.y, c.z, c.y, result.rms);
    }
    notes.insert(notes.end(), result.notes.begin(), result.notes.end());
    printNotes(globals, notes);
    std::printf("%s\n", o->poseOut.string().c_str());
    return 0;
  };
}

}  // namespace compose::app
