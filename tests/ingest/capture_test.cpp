// EXIF capture information, grouping photos into views, capture descriptions.
#include "ingest/capture.h"

#include <cmath>
#include <fstream>

#include <OpenImageIO/imageio.h>
#include <glm/mat3x3.hpp>

#include "ingest/image_io.h"
#include "test_util.h"

namespace compose::ingest {
namespace {

using compose::testing::TempDir;

// EXIF rationals written by OpenImageIO carry six decimals: relative tolerance for exposures.
constexpr double kExifRational = 1e-4;

Image grey(int w, int h, float v = 0.5f) {
  Image img(w, h, 3, {"R", "G", "B"});
  std::fill(img.pixels.begin(), img.pixels.end(), v);
  return img;
}

CaptureInfo cameraShot(double t, const std::string& when) {
  CaptureInfo i;
  i.exposureTime = t;
  i.fNumber = 5.6;
  i.iso = 200;
  i.focalLengthMm = 4.2;
  i.cameraMake = "Acme";
  i.cameraModel = "Phone 3";
  i.dateTimeOriginal = when;
  return i;
}

void writeShot(const std::filesystem::path& file, const CaptureInfo& info, int w = 32, int h = 24) {
  WriteOptions o;
  o.attributes = exifAttributes(info);
  writeImage(file, grey(w, h), o);
}

TEST(CaptureInfo, ExifWrittenByUsIsReadBack) {
  TempDir dir;
  CaptureInfo in = cameraShot(1.0 / 64.0, "2024:05:01 12:00:03.25");
  in.focalLength35mm = 26.0;
  writeShot(dir / "a.jpg", in);
  const CaptureInfo out = readCaptureInfo(dir / "a.jpg");
  ASSERT_TRUE(out.exposureTime && out.fNumber && out.iso && out.focalLengthMm);
  EXPECT_NEAR(*out.exposureTime, 1.0 / 64.0, kExifRational / 64.0);  // a binary fraction
  EXPECT_NEAR(*out.fNumber, 5.6, 1e-5);
  EXPECT_EQ(*out.iso, 200.0);
  EXPECT_NEAR(*out.focalLengthMm, 4.2, 1e-5);
  ASSERT_TRUE(out.focalLength35mm);
  EXPECT_EQ(*out.focalLength35mm, 26.0);
  EXPECT_EQ(out.focal35mmSource, "EXIF FocalLengthIn35mmFilm");
  EXPECT_EQ(out.camera(), "Acme Phone 3");
  EXPECT_EQ(out.sampleType, "uint8");
  EXPECT_EQ(out.dateTimeOriginal, "2024:05:01 12:00:03");
  ASSERT_TRUE(out.captureSeconds);
  // Relative exposure t · ISO / N².
  EXPECT_NEAR(*out.relativeExposure(), (1.0 / 64.0) * 200.0 / (5.6 * 5.6), 1e-4);
  EXPECT_TRUE(out.exposureAssumptions().empty());

  // The sub-second part orders shots taken within one second.
  CaptureInfo later = in;
  later.dateTimeOriginal = "2024:05:01 12:00:03.75";
  writeShot(dir / "b.jpg", later);
  EXPECT_NEAR(*readCaptureInfo(dir / "b.jpg").captureSeconds - *out.captureSeconds, 0.5, 1e-6);
}

TEST(CaptureInfo, ThirtyFiveMillimetreEquivalentFromTheFocalPlaneResolution) {
  TempDir dir;
  // A phone: FocalLengthIn35mmFilm = 0, a 4.2 mm lens on a 6.4 x 4.8 mm sensor written as
  // 4000 x 3000 pixels, i.e. 625 pixels per mm = 6250 per cm (unit 3).
  CaptureInfo in = cameraShot(0.01, "2024:05:01 12:00:00");
  in.focalPlaneXResolution = 6250.0;
  in.focalPlaneYResolution = 6250.0;
  in.focalPlaneResolutionUnit = 3;
  writeShot(dir / "phone.jpg", in, 4000, 3000);
  const CaptureInfo out = readCaptureInfo(dir / "phone.jpg");
  ASSERT_TRUE(out.focalLength35mm);
  // 4.2 mm · 43.27 / 8.0 mm (the diagonal of 6.4 x 4.8).
  EXPECT_NEAR(*out.focalLength35mm, 4.2 * 43.266615305567875 / 8.0, 1e-3);
  EXPECT_NE(out.focal35mmSource.find("derived"), std::string::npos);

  // With FocalLengthIn35mmFilm too: the tag is whole millimetres (23 for 22.71 mm), so the
  // derived value is taken where the tag is its rounding; where it is not (a resized photo keeps
  // the sensor's focal-plane resolution, which then says another sensor), the tag is.
  CaptureInfo both = in;
  both.focalLength35mm = 23.0;
  writeShot(dir / "both.jpg", both, 4000, 3000);
  const CaptureInfo precise = readCaptureInfo(dir / "both.jpg");
  ASSERT_TRUE(precise.focalLength35mm);
  EXPECT_NEAR(*precise.focalLength35mm, 4.2 * 43.266615305567875 / 8.0, 1e-3);
  EXPECT_NE(precise.focal35mmSource.find("which FocalLengthIn35mmFilm rounds to 23 mm"),
            std::string::npos)
      << precise.focal35mmSource;
  writeShot(dir / "resized.jpg", both, 2000, 1500);
  const CaptureInfo resized = readCaptureInfo(dir / "resized.jpg");
  ASSERT_TRUE(resized.focalLength35mm);
  EXPECT_EQ(*resized.focalLength35mm, 23.0);
  EXPECT_EQ(resized.focal35mmSource, "EXIF FocalLengthIn35mmFilm");

  // Without the resolution tags nothing can be derived: the field stays empty.
  writeShot(dir / "bare.jpg", cameraShot(0.01, "2024:05:01 12:00:00"));
  EXPECT_FALSE(readCaptureInfo(dir / "bare.jpg").focalLength35mm);
}

TEST(CaptureInfo, MissingFieldsAreAssumedAndSaid) {
  TempDir dir;
  CaptureInfo in;
  in.exposureTime = 0.5;
  writeShot(dir / "a.png", in);  // PNG keeps no EXIF: nothing comes back
  EXPECT_FALSE(readCaptureInfo(dir / "a.png").relativeExposure());
  CaptureInfo partial;
  partial.exposureTime = 0.5;
  EXPECT_NEAR(*partial.relativeExposure(), 0.5 * 100.0, 1e-12);
  EXPECT_NE(partial.exposureAssumptions().find("ISO 100"), std::string::npos);
}

TEST(Capture, NoExposureAnywhereNamesTheFile) {
  TempDir dir;
  writeImage(dir / "a.jpg", grey(8, 8));
  writeImage(dir / "b.jpg", grey(8, 8));
  Capture c;
  c.views.push_back(View{"v", {}, {}});
  for (const auto& s : scanShots({dir / "a.jpg", dir / "b.jpg"})) c.views[0].shots.push_back(s);
  COMPOSE_EXPECT_ERROR(resolveExposures(c), "no exposure time in EXIF and no exposure given");
  COMPOSE_EXPECT_ERROR(resolveExposures(c), "a.jpg)");
  // With a list, it works, and the shots are sorted by exposure.
  setExposures(c.views[0], {4.0, 1.0}, "--exposures");
  resolveExposures(c);
  EXPECT_EQ(c.views[0].shots[0].file.filename(), "b.jpg");
  EXPECT_EQ(*c.views[0].shots[1].exposure, 4.0);
  COMPOSE_EXPECT_ERROR(setExposures(c.views[0], {1.0}, "--exposures"),
                       "1 exposure given for 2 photos");
}

// A folder's hidden files are not photos (macOS writes "._IMG_0001.jpg" beside each photo on
// other file systems: not an image at all).
TEST(Capture, HiddenFilesOfAFolderAreNotPhotos) {
  TempDir dir;
  writeShot(dir / "a.jpg", cameraShot(0.01, "2024:05:01 12:00:00"));
  compose::testing::writeText(dir / "._a.jpg", "Mac OS X resource fork");
  const std::vector<Shot> shots = scanShots({dir.path()});
  ASSERT_EQ(shots.size(), 1u);
  EXPECT_EQ(shots[0].file.filename(), "a.jpg");
}

TEST(Capture, AllEqualExposuresAreRefused) {
  TempDir dir;
  writeShot(dir / "a.jpg", cameraShot(0.01, "2024:05:01 12:00:00"));
  writeShot(dir / "b.jpg", cameraShot(0.01, "2024:05:01 12:00:01"));
  Capture c;
  c.views.push_back(View{"front", scanShots({dir.path()}), {}});
  COMPOSE_EXPECT_ERROR(resolveExposures(c), "exposures of view 'front' are all equal");
}

// A response is one camera's, and a shot is one photo: photos of two cameras, a camera other
// than the description's, and a file given twice (by another name) are refused.
TEST(Capture, OneCameraAndEachPhotoOnce) {
  TempDir dir;
  writeShot(dir / "a.jpg", cameraShot(0.01, "2024:05:01 12:00:00"));
  CaptureInfo other = cameraShot(0.04, "2024:05:01 12:00:01");
  other.cameraMake = "Canon";
  other.cameraModel = "EOS R5";
  writeShot(dir / "b.jpg", other);
  writeShot(dir / "c.jpg", cameraShot(0.04, "2024:05:01 12:00:01"));
  Capture mixed;
  mixed.views.push_back(View{"front", scanShots({dir / "a.jpg", dir / "b.jpg"}), {}});
  COMPOSE_EXPECT_ERROR(resolveExposures(mixed), "the photos come from more than one camera");
  COMPOSE_EXPECT_ERROR(resolveExposures(mixed), "'Canon EOS R5' here");

  Capture one;
  one.views.push_back(View{"front", scanShots({dir / "a.jpg", dir / "c.jpg"}), {}});
  resolveExposures(one);
  Capture described = one;
  described.cameraMake = "Canon";
  described.cameraModel = "EOS R5";
  COMPOSE_EXPECT_ERROR(resolveExposures(described), "the capture description 'Canon EOS R5'");

  // One camera however its firmware or an editor spells it: letter case, the make repeated in
  // the model, a make left out.
  CaptureInfo shouted = cameraShot(0.04, "2024:05:01 12:00:01");
  shouted.cameraMake = "ACME";
  shouted.cameraModel = "Acme Phone 3";
  writeShot(dir / "d.jpg", shouted);
  CaptureInfo modelOnly = cameraShot(0.16, "2024:05:01 12:00:02");
  modelOnly.cameraMake.clear();
  writeShot(dir / "e.jpg", modelOnly);
  Capture spelled;
  spelled.views.push_back(
      View{"front", scanShots({dir / "a.jpg", dir / "d.jpg", dir / "e.jpg"}), {}});
  resolveExposures(spelled);

  Capture twice;
  twice.views.push_back(
      View{"front", scanShots({dir / "a.jpg", dir / "c.jpg", dir / "." / "a.jpg"}), {}});
  COMPOSE_EXPECT_ERROR(resolveExposures(twice), "the same photo is given twice");
  Capture acrossViews;
  acrossViews.views.push_back(View{"front", scanShots({dir / "a.jpg", dir / "c.jpg"}), {}});
  acrossViews.views.push_back(View{"back", scanShots({dir / "c.jpg"}), {}});
  COMPOSE_EXPECT_ERROR(resolveExposures(acrossViews), "the same photo is given twice");
}

// Exposures given on the command line win over EXIF; where they contradict it (another order, or
// ratios other than EXIF's beyond its rounding), that is said.
TEST(Capture, GivenExposuresThatContradictExifAreSaid) {
  TempDir dir;
  writeShot(dir / "a.jpg", cameraShot(1.0 / 64.0, "2024:05:01 12:00:00"));
  writeShot(dir / "b.jpg", cameraShot(1.0 / 16.0, "2024:05:01 12:00:01"));
  writeShot(dir / "c.jpg", cameraShot(1.0 / 4.0, "2024:05:01 12:00:02"));
  View view{"v", scanShots({dir / "a.jpg", dir / "b.jpg", dir / "c.jpg"}), {}};
  EXPECT_EQ(exposureContradiction(view), "");  // nothing given: nothing to contradict
  setExposures(view, {1.0, 4.0, 16.0}, "--exposures");
  EXPECT_EQ(exposureContradiction(view), "") << "the same ratios in other units";
  setExposures(view, {1.0, 3.5, 16.0}, "--exposures");
  EXPECT_EQ(exposureContradiction(view), "") << "within a third of a stop";
  setExposures(view, {1.0, 2.0, 4.0}, "--exposures");
  EXPECT_NE(exposureContradiction(view).find("differ from their EXIF: a.jpg to c.jpg is +2.0 "
                                             "stops given, +4.0 stops by EXIF"),
            std::string::npos)
      << exposureContradiction(view);
  setExposures(view, {16.0, 1.0, 4.0}, "--exposures");
  EXPECT_NE(exposureContradiction(view).find("order the photos otherwise than their EXIF"),
            std::string::npos)
      << exposureContradiction(view);
}

TEST(Capture, GroupsByCaptureTimeAndExposureSequence) {
  TempDir dir;
  // Two views of an auto-bracketed sequence in the camera's order 0, -2, +2 EV; the second view
  // 20 s later. A third view follows without a pause: only the exposure sequence restarting
  // shows it.
  const double t[3] = {1.0 / 60, 1.0 / 240, 1.0 / 15};
  const char* times[9] = {"12:00:00", "12:00:01", "12:00:01", "12:00:21", "12:00:21",
                          "12:00:22", "12:00:22", "12:00:23", "12:00:23"};
  for (int i = 0; i < 9; ++i) {
    char name[16];
    std::snprintf(name, sizeof name, "IMG_%04d.jpg", 100 + i);
    writeShot(dir / name, cameraShot(t[i % 3], std::string("2024:05:01 ") + times[i]));
  }
  Capture c = groupByExif(scanShots({dir.path()}), {});
  ASSERT_EQ(c.views.size(), 3u);
  for (const View& v : c.views) EXPECT_EQ(v.shots.size(), 3u);
  EXPECT_EQ(c.views[1].shots[0].file.filename(), "IMG_0103.jpg");
  EXPECT_EQ(c.cameraModel, "Phone 3");
  resolveExposures(c);
  // Sorted darkest first.
  EXPECT_NEAR(*c.views[0].shots[0].info.exposureTime, 1.0 / 240, 1e-5);
  const auto lines = describeCapture(c);
  ASSERT_EQ(lines.size(), 3u);
  EXPECT_NE(lines[0].find("4.0 EV range"), std::string::npos) << lines[0];

  // A known bracket size cuts views as well (here with the pauses ignored).
  ExifGrouping g;
  g.bracketSize = 3;
  g.maxGapSeconds = 1000.0;
  EXPECT_EQ(groupByExif(scanShots({dir.path()}), g).views.size(), 3u);
  // It is the grouping: runs of exactly that many photos, whatever the pauses and exposures say
  // (the exposure sequence of 3 was taken over a size of 9 given), and a count it does not divide
  // is an error.
  g.maxGapSeconds = 3.0;
  g.bracketSize = 9;
  const Capture one = groupByExif(scanShots({dir.path()}), g);
  ASSERT_EQ(one.views.size(), 1u);
  EXPECT_EQ(one.views[0].shots.size(), 9u);
  g.bracketSize = 4;
  COMPOSE_EXPECT_ERROR(groupByExif(scanShots({dir.path()}), g),
                       "9 photos do not make brackets of 4 (the bracket size given): 1 left over");
}

// A panoramic head with auto-exposure bracketing: each direction is metered anew, and the next
// bracket follows without a pause. Its exposures (a stop brighter here) lie off the first
// bracket's 2 EV steps: a new view (the six photos were one view of 5 EV, merged as one).
// Shutter speeds rounded to a third of a stop (1/250 for 1/240) stay on the steps.
TEST(Capture, ABracketMeteredAnewIsTheNextView) {
  TempDir dir;
  const double t[6] = {1.0 / 60, 1.0 / 250, 1.0 / 15, 1.0 / 30, 1.0 / 125, 1.0 / 8};
  for (int i = 0; i < 6; ++i) {
    char name[16], when[32];
    std::snprintf(name, sizeof name, "IMG_%04d.jpg", 300 + i);
    std::snprintf(when, sizeof when, "2024:05:01 12:00:%02d", i);
    writeShot(dir / name, cameraShot(t[i], when));
  }
  const Capture c = groupByExif(scanShots({dir.path()}), {});
  ASSERT_EQ(c.views.size(), 2u);
  EXPECT_EQ(c.views[0].shots.size(), 3u);
  EXPECT_EQ(c.views[1].shots[0].file.filename(), "IMG_0303.jpg");

  // Long brackets of rounded shutter speeds stay one view: seven 1 EV apart (1/125 to 1/60 is
  // 1.06 stops, and measured from the first shot the rounding added up to 0.39 stops), five
  // 2 EV apart in a camera's order 0, -, +, --, ++ (1/6, 1/25, 0.6, 1/100, 2.5 s).
  for (const std::vector<double>& bracket :
       {std::vector<double>{1.0 / 125, 1.0 / 60, 1.0 / 30, 1.0 / 15, 1.0 / 8, 1.0 / 4, 1.0 / 2},
        std::vector<double>{1.0 / 6, 1.0 / 25, 0.6, 1.0 / 100, 2.5}}) {
    TempDir long_;
    for (size_t i = 0; i < bracket.size(); ++i) {
      char name[40], when[48];
      std::snprintf(name, sizeof name, "IMG_%04zu.jpg", 400 + i);
      std::snprintf(when, sizeof when, "2024:05:01 12:00:%02zu", i);
      writeShot(long_ / name, cameraShot(bracket[i], when));
    }
    const Capture one = groupByExif(scanShots({long_.path()}), {});
    EXPECT_EQ(one.views.size(), 1u) << bracket.size() << " shots";
  }
}

// One photo of a bracket without the ISO (or the f-number) the others state: it takes theirs,
// and merge says so (ISO 100 was assumed: that photo a stop off, the merge 34 % off the truth).
// Photos that state different ones leave it unknown: an error naming the file.
TEST(Capture, AFieldOnePhotoOfABracketLacksIsTakenFromTheOthers) {
  TempDir dir;
  const double t[3] = {1.0 / 240, 1.0 / 60, 1.0 / 15};
  for (int i = 0; i < 3; ++i) {
    CaptureInfo info = cameraShot(t[i], "2024:05:01 12:00:0" + std::to_string(i));
    if (i == 2) info.iso.reset();
    if (i == 0) info.fNumber.reset();
    writeShot(dir / ("IMG_" + std::to_string(i) + ".jpg"), info);
  }
  Capture c = groupByExif(scanShots({dir.path()}), {});
  ASSERT_EQ(c.views.size(), 1u);
  resolveExposures(c);
  const View& v = c.views[0];
  ASSERT_EQ(v.shots.size(), 3u);
  EXPECT_NEAR(*v.shots[1].exposure / *v.shots[0].exposure, 4.0, 4.0 * kExifRational);
  EXPECT_NEAR(*v.shots[2].exposure / *v.shots[1].exposure, 4.0, 4.0 * kExifRational);
  std::string warnings;
  for (const std::string& w : captureWarnings(c)) warnings += w + "\n";
  EXPECT_NE(warnings.find("IMG_2.jpg's EXIF lacks what the other photos of view 'view1' state: "
                          "taken as ISO 200"),
            std::string::npos)
      << warnings;
  EXPECT_NE(warnings.find("IMG_0.jpg's EXIF lacks what the other photos of view 'view1' state: "
                          "taken as f/5.6"),
            std::string::npos)
      << warnings;

  CaptureInfo other = cameraShot(1.0 / 120, "2024:05:01 12:00:01");
  other.iso = 400;
  const std::filesystem::path mixedDir = dir / "mixed";
  std::filesystem::create_directories(mixedDir);
  writeShot(mixedDir / "IMG_0.jpg", cameraShot(1.0 / 240, "2024:05:01 12:00:00"));
  writeShot(mixedDir / "IMG_1.jpg", other);
  CaptureInfo last = cameraShot(1.0 / 30, "2024:05:01 12:00:02");
  last.iso.reset();
  writeShot(mixedDir / "IMG_2.jpg", last);
  Capture mixed = groupByExif(scanShots({mixedDir}), {});
  ASSERT_EQ(mixed.views.size(), 1u);
  COMPOSE_EXPECT_ERROR(resolveExposures(mixed),
                       "no ISO in EXIF, and the other photos of view 'view1' state different "
                       "ones (ISO 200 to ISO 400)");
}

// A pause is from the end of one exposure to the start of the next: a night bracket of 4, 1 and
// 16 s shots, each started half a second after the last one ended, is one view (the starts
// 4.5 and 1.3 s apart split it into three), and the next bracket, 35 s later, another.
TEST(Capture, ALongExposureIsNoPause) {
  TempDir dir;
  const double t[3] = {4.0, 1.0, 16.0};
  const char* starts[6] = {"12:00:00", "12:00:04.5", "12:00:05.8",
                           "12:00:57", "12:01:01.5", "12:01:02.8"};
  for (int i = 0; i < 6; ++i) {
    char name[16];
    std::snprintf(name, sizeof name, "IMG_%04d.jpg", 200 + i);
    writeShot(dir / name, cameraShot(t[i % 3], std::string("2024:05:01 ") + starts[i]));
  }
  const Capture c = groupByExif(scanShots({dir.path()}), {});
  ASSERT_EQ(c.views.size(), 2u);
  EXPECT_EQ(c.views[0].shots.size(), 3u);
  EXPECT_EQ(c.views[1].shots.size(), 3u);
  EXPECT_EQ(c.views[1].shots[0].file.filename(), "IMG_0203.jpg");
}

// A camera set to RAW+JPEG writes IMG_n.CR2 and IMG_n.JPG of each shot: the pair made a view of
// two shots of one exposure each (four views for a bracket of three). The JPEG of a pair (same
// name and time beside a raw file) is left out and listed; a JPEG of another time is kept.
TEST(Capture, TheJpegOfARawPlusJpegPairIsLeftOut) {
  TempDir dir;
  const double t[3] = {1.0 / 1600, 1.0 / 400, 1.0 / 100};
  for (int i = 0; i < 3; ++i) {
    const CaptureInfo info = cameraShot(t[i], "2024:05:01 12:00:0" + std::to_string(i));
    const std::string stem = "IMG_" + std::to_string(5952 + i);
    WriteOptions o;
    o.attributes = exifAttributes(info);
    o.depth = WriteOptions::Depth::UInt16;
    writeImage(dir / (stem + ".tif"), grey(32, 24), o);
    std::filesystem::rename(dir / (stem + ".tif"), dir / (stem + ".DNG"));
    writeShot(dir / (stem + ".JPG"), info);
  }
  writeShot(dir / "IMG_5954b.jpg", cameraShot(t[2], "2024:05:01 12:00:02"));
  CaptureInfo later = cameraShot(t[0], "2024:05:01 12:00:09");
  std::vector<std::filesystem::path> leftOut, pairs;
  const std::vector<Shot> shots = scanShots({dir.path()}, "ingest", &leftOut, &pairs);
  ASSERT_EQ(pairs.size(), 3u);
  EXPECT_EQ(pairs[0].filename(), "IMG_5952.JPG");
  EXPECT_TRUE(leftOut.empty());
  ASSERT_EQ(shots.size(), 4u) << "three raw files and a JPEG of another name";
  // Without the list, every file is a shot (as before).
  EXPECT_EQ(scanShots({dir.path()}).size(), 7u);
  // The same name at another time is not a pair.
  TempDir other;
  std::filesystem::copy_file(dir / "IMG_5952.DNG", other / "IMG_5952.DNG");
  writeShot(other / "IMG_5952.JPG", later);
  pairs.clear();
  EXPECT_EQ(scanShots({other.path()}, "ingest", nullptr, &pairs).size(), 2u);
  EXPECT_TRUE(pairs.empty());
}

TEST(Capture, GroupsByFileNamePattern) {
  TempDir dir;
  for (const char* v : {"front", "left", "up"})
    for (int b = 1; b <= 3; ++b)
      writeImage(dir / (std::string(v) + "_" + std::to_string(b) + ".jpg"), grey(8, 8));
  const Capture c = groupByPattern(scanShots({dir.path()}), "{view}_{bracket}.jpg");
  ASSERT_EQ(c.views.size(), 3u);
  EXPECT_EQ(c.views[0].name, "front");
  EXPECT_EQ(c.views[2].name, "up");
  EXPECT_EQ(c.views[1].shots.size(), 3u);
  COMPOSE_EXPECT_ERROR(groupByPattern(scanShots({dir.path()}), "{view}_{bracket}.png"),
                       "does not match");
  // A view's name may hold the pattern's separator: garden_px_1.jpg is view garden_px (it was
  // view garden, bracket px_1: six directions in one view, which a merge averaged).
  TempDir named;
  for (const char* v : {"garden_px", "garden_nx"})
    for (int b = 1; b <= 2; ++b)
      writeImage(named / (std::string(v) + "_" + std::to_string(b) + ".jpg"), grey(8, 8));
  const Capture g = groupByPattern(scanShots({named.path()}), "{view}_{bracket}.jpg");
  ASSERT_EQ(g.views.size(), 2u);
  EXPECT_EQ(g.views[0].name, "garden_nx");
  EXPECT_EQ(g.views[1].name, "garden_px");
  // A bracket part holding the separator is said by the pattern.
  TempDir tagged;
  for (const char* name : {"px_1_m2ev.jpg", "px_2_0ev.jpg", "nx_1_m2ev.jpg", "nx_2_0ev.jpg"})
    writeImage(tagged / name, grey(8, 8));
  const Capture t = groupByPattern(scanShots({tagged.path()}), "{view}_{bracket}_*.jpg");
  ASSERT_EQ(t.views.size(), 2u);
  EXPECT_EQ(t.views[0].name, "nx");
  EXPECT_EQ(t.views[1].shots.size(), 2u);
  COMPOSE_EXPECT_ERROR(groupByPattern(scanShots({dir.path()}), "*.jpg"), "no {view}");
}

TEST(Capture, DescriptionRoundTripKeepsViewsExposuresAndOrientation) {
  TempDir dir;
  writeImage(dir / "a.jpg", grey(8, 8));
  writeImage(dir / "b.jpg", grey(8, 8));
  Capture c;
  c.cameraMake = "Acme";
  c.cameraModel = "X";
  View v{"up", scanShots({dir / "a.jpg", dir / "b.jpg"}), {}};
  // Looking up, image top towards +Z.
  v.worldFromCamera = glm::dmat3(glm::dvec3(1, 0, 0), glm::dvec3(0, 0, 1), glm::dvec3(0, -1, 0));
  setExposures(v, {0.25, 1.0}, "test");
  c.views.push_back(v);
  writeCaptureDescription(dir / "capture.json", c);
  const Capture back = readCaptureDescription(dir / "capture.json");
  ASSERT_EQ(back.views.size(), 1u);
  EXPECT_EQ(back.views[0].name, "up");
  EXPECT_EQ(back.cameraMake, "Acme");
  ASSERT_TRUE(back.views[0].worldFromCamera);
  EXPECT_EQ((*back.views[0].worldFromCamera)[1][2], 1.0);
  EXPECT_EQ(*back.views[0].shots[1].exposure, 1.0);
  EXPECT_EQ(back.views[0].shots[0].file, dir / "a.jpg");
}

TEST(Capture, BadDescriptionsAreNamedErrors) {
  TempDir dir;
  writeImage(dir / "a.jpg", grey(8, 8));
  auto expect = [&](const std::string& text, const std::string& needle) {
    compose::testing::writeText(dir / "c.json", text);
    COMPOSE_EXPECT_ERROR(readCaptureDescription(dir / "c.json"), needle);
  };
  expect("{", "not a valid JSON capture description");
  expect(R"({"format": "other", "version": 1})", "not a capture description");
  expect(R"({"format": "compose-capture", "version": 1, "views": []})", "non-empty \"views\"");
  expect(R"({"format": "compose-capture", "version": 1, "views": [{"name": "v",
           "exposures": [{"file": "missing.jpg"}]}]})",
         "file not found");
  expect(R"({"format": "compose-capture", "version": 1, "views": [{"name": "v",
           "worldFromCamera": [[2,0,0],[0,1,0],[0,0,1]], "exposures": [{"file": "a.jpg"}]}]})",
         "not a rotation");
  expect(R"({"format": "compose-capture", "version": 1, "views": [{"name": "v",
           "exposures": [{"file": "a.jpg", "exposureTime": -1}]}]})",
         "must be a positive number");
  expect(R"({"format": "compose-capture", "version": 1, "views": [
           {"name": "v", "exposures": [{"file": "a.jpg"}]},
           {"name": "v", "exposures": [{"file": "a.jpg"}]}]})",
         "two views are named 'v'");
  // A key this reader does not know is named (a misspelt one silently did not count).
  expect(R"({"format": "compose-capture", "version": 1, "views": [{"name": "v",
           "exposures": [{"file": "a.jpg", "exposuretime": 0.01}]}]})",
         "\"exposuretime\" is not a field");
  expect(R"({"format": "compose-capture", "version": 1, "bogus": 1, "views": [{"name": "v",
           "exposures": [{"file": "a.jpg"}]}]})",
         "\"bogus\" is not a field");
  expect(R"({"format": "compose-capture", "version": 1, "views": [{"name": "v", "yaw": 90,
           "exposures": [{"file": "a.jpg"}]}]})",
         "\"yaw\" is not a field");
}

// What makes a capture's views disagree is said: a view whose photos lack an f-number (taken as
// f/1, 64 times too dark at f/8) beside views whose photos say theirs; one view's exposures given
// at another scale to its EXIF than the others'; one exposure several times in a view. A
// description's ISO alone counts, the rest from EXIF (it was dropped without a time). Views of
// 8-bit and 16-bit photos are refused (their radiance comes out in different units).
TEST(Capture, WhatMakesViewsDisagreeIsSaid) {
  TempDir dir;
  auto shoot = [&](const std::string& name, double t, bool withFNumber) {
    CaptureInfo i = cameraShot(t, "2024:05:01 12:00:00");
    if (!withFNumber) i.fNumber.reset();
    writeShot(dir / name, i);
    return dir / name;
  };
  Capture c;
  c.views.push_back(
      {"px", scanShots({shoot("px_1.jpg", 0.01, true), shoot("px_2.jpg", 0.04, true)}), {}});
  c.views.push_back(
      {"nz", scanShots({shoot("nz_1.jpg", 0.01, false), shoot("nz_2.jpg", 0.04, false)}), {}});
  Capture consistent = c;
  consistent.views.pop_back();
  consistent.views.push_back(
      {"nx", scanShots({shoot("nx_1.jpg", 0.01, true), shoot("nx_2.jpg", 0.04, true)}), {}});
  resolveExposures(consistent);
  EXPECT_TRUE(captureWarnings(consistent).empty());
  resolveExposures(c);
  const std::vector<std::string> w = captureWarnings(c);
  ASSERT_EQ(w.size(), 1u);
  EXPECT_NE(w[0].find("view nz assume f/1"), std::string::npos) << w[0];

  Capture scaled = consistent;
  setExposures(scaled.views[0], {1.0, 4.0}, "capture description");
  const std::vector<std::string> s = captureWarnings(scaled);
  ASSERT_EQ(s.size(), 1u);
  EXPECT_NE(s[0].find("different scales to the photos' EXIF"), std::string::npos) << s[0];

  Capture merged = consistent;
  merged.views[0].shots.insert(merged.views[0].shots.end(), merged.views[1].shots.begin(),
                               merged.views[1].shots.end());
  merged.views.pop_back();
  resolveExposures(merged);
  const std::vector<std::string> m = captureWarnings(merged);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_NE(m[0].find("2 of them at an exposure another of its photos has"), std::string::npos)
      << m[0];

  compose::testing::writeText(dir / "iso.json", R"({"format": "compose-capture", "version": 1,
      "views": [{"name": "v", "exposures": [{"file": "px_1.jpg", "iso": 800},
                                            {"file": "px_2.jpg"}]}]})");
  const Capture iso = readCaptureDescription(dir / "iso.json");
  ASSERT_TRUE(iso.views[0].shots[0].exposure);
  EXPECT_NEAR(*iso.views[0].shots[0].exposure, 0.01 * 800.0 / (5.6 * 5.6), 1e-4);

  Capture mixed = consistent;
  WriteOptions deep;
  deep.depth = WriteOptions::Depth::UInt16;
  deep.attributes = exifAttributes(cameraShot(0.01, "2024:05:01 12:00:00"));
  writeImage(dir / "nx_1.tif", grey(32, 24), deep);
  deep.attributes = exifAttributes(cameraShot(0.04, "2024:05:01 12:00:00"));
  writeImage(dir / "nx_2.tif", grey(32, 24), deep);
  mixed.views[1] = {"nx", scanShots({dir / "nx_1.tif", dir / "nx_2.tif"}), {}};
  COMPOSE_EXPECT_ERROR(resolveExposures(mixed), "the views mix 8-bit photos");
}

TEST(ImageIoTruncation, TruncatedJpegIsAnErrorNotAGreyPicture) {
  TempDir dir;
  Image img(256, 256, 3);
  for (size_t i = 0; i < img.pixels.size(); ++i) img.pixels[i] = float((i * 37) % 251) / 250.0f;
  writeImage(dir / "full.jpg", img);
  std::ifstream in(dir / "full.jpg", std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  compose::testing::writeText(dir / "cut.jpg", bytes.substr(0, bytes.size() / 2));
  try {
    readImage(dir / "full.jpg");
  } catch (const Error& e) {
    ADD_FAILURE() << e.describe();
  }
  COMPOSE_EXPECT_ERROR(readImage(dir / "cut.jpg"), "truncated file");
  COMPOSE_EXPECT_ERROR(readImage(dir / "cut.jpg"), "cut.jpg)");
  // A PNG cut short (read through OpenImageIO): called truncated too, on one line.
  writeImage(dir / "full.png", img);
  std::ifstream png(dir / "full.png", std::ios::binary);
  std::string pngBytes((std::istreambuf_iterator<char>(png)), std::istreambuf_iterator<char>());
  compose::testing::writeText(dir / "cut.png", pngBytes.substr(0, pngBytes.size() / 2));
  try {
    readImage(dir / "cut.png");
    ADD_FAILURE() << "a PNG cut in half was read";
  } catch (const Error& e) {
    EXPECT_NE(e.describe().find("ingest: truncated file: "), std::string::npos) << e.describe();
    EXPECT_EQ(e.describe().find('\n'), std::string::npos) << e.describe();
  }
  // Said before libpng reads it (libpng writes its own message to the terminal first): which
  // chunk the file ends in; from memory (a glTF's embedded texture) too; and a PNG whose last
  // chunk is whole but has no IEND after it.
  COMPOSE_EXPECT_ERROR(readImage(dir / "cut.png"),
                       "truncated file: the PNG ends inside its IDAT chunk (");
  const std::span<const unsigned char> cut(reinterpret_cast<const unsigned char*>(pngBytes.data()),
                                           pngBytes.size() / 2);
  COMPOSE_EXPECT_ERROR(readImageFromMemory(cut, "texture.png", "mesh"),
                       "mesh: truncated file: the PNG ends inside its IDAT chunk (");
  const size_t iend = pngBytes.rfind("IEND");
  ASSERT_NE(iend, std::string::npos);
  compose::testing::writeText(dir / "noend.png", pngBytes.substr(0, iend - 4));
  COMPOSE_EXPECT_ERROR(readImage(dir / "noend.png"),
                       "truncated file: the PNG ends before its IEND chunk (");
}

}  // namespace
}  // namespace compose::ingest

namespace compose::ingest {
namespace {

TEST(ImageIoCodes, EightBitFilesCanBeReadAsCodesWithOrientationApplied) {
  compose::testing::TempDir dir;
  // A 4x2 8-bit image whose top-left pixel is code 200, stored with Orientation 6: upright it is
  // 2x4 with that pixel at the top right (as ImageIo.AppliesExifOrientation checks for floats).
  const auto path = dir / "rotated.tif";
  {
    std::vector<uint8_t> px(4 * 2 * 3, 10);
    px[0] = 200;
    auto out = OIIO::ImageOutput::create(path.string());
    OIIO::ImageSpec spec(4, 2, 3, OIIO::TypeDesc::UINT8);
    spec.attribute("Orientation", 6);
    ASSERT_TRUE(out->open(path.string(), spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px.data()));
    out->close();
  }
  ReadOptions codes;
  codes.codesForEightBit = true;
  const LoadedImage img = readImage(path, "ingest", codes);
  EXPECT_FALSE(img.hasPixels());
  ASSERT_EQ(img.image.width, 2);
  ASSERT_EQ(img.image.height, 4);
  ASSERT_EQ(img.codes.size(), 2u * 4u * 3u);
  EXPECT_EQ(img.codes[(0 * 2 + 1) * 3], 200);  // row 0, column 1
  EXPECT_EQ(img.codes[0], 10);
  // Deeper files are still read as floats.
  writeImage(dir / "deep.exr", Image(4, 2, 3));
  EXPECT_TRUE(readImage(dir / "deep.exr", "ingest", codes).hasPixels());
}

}  // namespace
}  // namespace compose::ingest
