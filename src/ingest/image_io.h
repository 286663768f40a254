// Image input and output.
//
// OpenEXR files go through the OpenEXR library (exr_io.h) and JPEGs through libjpeg-turbo
// (jpeg_io.h, EXIF by exif.h); every other format through OpenImageIO, loaded as a module when a
// file needs it (oiio_module.h), so that a run on OpenEXR and JPEG files does not pay for loading
// it. A file goes to a reader by its first bytes, not its name. Each reader gives what OpenImageIO
// gives for the same file: the same pixels, channels in the same order, the same metadata under
// the same names; and each writer writes files OpenImageIO reads as its own.
//
// readImage() decodes any format OpenImageIO can read (JPEG, PNG, TIFF, EXR, HDR, camera RAW where
// the plugin is present) to float, applies the EXIF orientation so that pixel (0, 0) is the top
// left of the picture as a person sees it, and returns the capture metadata that later stages need
// (exposure for merging, focal length for the camera). Values are returned as stored: an 8-bit
// sRGB JPEG comes back as encoded values in [0, 1] (code · (1/255) in float, as OpenImageIO
// converts them), a 16-bit TIFF as
// code / 65535, tagged with the colour space the file declares. A file the decoder had to give up
// on part-way (a truncated JPEG) is an error, not a picture with a grey bottom.
//
// writeImage() never leaves a half-written file at the destination: it writes a temporary file in
// the same folder and renames it into place only when the write has succeeded. Several outputs
// that belong together are written into one OutputFiles set (core/output_files.h) and appear
// together on commit().
//
// OpenEXR files say what their numbers are: the chromaticities of their RGB space (the standard
// `chromaticities` attribute, read back by readImage) and the colour-space name
// (`colorSpace`, a string attribute). Half-float output is checked against half's range: an
// image with a value beyond ±65504 is written as 32-bit float instead of turning into Inf, and
// the write reports it.
//
// Threads and memory: OpenEXR compresses and decompresses blocks of scanlines on its own thread
// pool, sized to every core oneTBB may use. Writers convert the float pixels to the file's type a
// band of rows at a time on every core and hand the bands over in that type, so that a write
// holds no full-size converted copy of the image; the values are those OpenImageIO's own
// conversion gives (integers rounded half away from zero and clamped, halves as Imath rounds).
//
// Errors (missing file, undecodable data, unwritable folder) throw compose::Error with stage
// "ingest" (or "output" for writes) and the file name.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <variant>
#include <vector>

#include "core/image.h"
#include "core/output_files.h"

namespace compose::ingest {

// Capture metadata from EXIF (and the file header). Absent fields are empty; EXIF values of 0
// (which many cameras write for "unknown") count as absent.
// compose:exposureUnit of merged radiance whose unit is the camera's EXIF relative exposure
// (t · ISO / N²) as an 8-bit photo shows it decoded as sRGB (hdr/capture_merge.h, Units): a plate
// of the same camera, decoded so, shows radiance L as about L times its own relative exposure. The
// merge writes it, stitch and convert carry it, the one-shot command's exposure reads it.
inline constexpr const char* kExifExposureUnit = "EXIF";

struct CaptureInfo {
  std::optional<double> exposureTime;   // seconds (EXIF ExposureTime)
  std::optional<double> fNumber;        // EXIF FNumber
  std::optional<double> iso;            // EXIF PhotographicSensitivity (ISOSpeedRatings)
  std::optional<double> focalLengthMm;  // true focal length (EXIF FocalLength)
  // 35 mm equivalent focal length: derived from FocalLength and the focal-plane resolution tags
  // when EXIF FocalLengthIn35mmFilm is that value rounded to whole millimetres, or is 0 or
  // missing; else FocalLengthIn35mmFilm (see focal35mmSource).
  std::optional<double> focalLength35mm;
  std::string focal35mmSource;  // where focalLength35mm came from; empty when it is unknown
  // An OpenEXR's pixelAspectRatio: a stored pixel's width over its height as shown (2 for an
  // anamorphic plate squeezed 2:1); 1 for square pixels and for other formats.
  double pixelAspectRatio = 1.0;
  // EXIF FocalPlaneX/YResolution: sensor pixels per unit of FocalPlaneResolutionUnit (2 inch,
  // 3 centimetre; 4 millimetre and 5 micrometre are non-standard but written by some cameras).
  std::optional<double> focalPlaneXResolution, focalPlaneYResolution;
  int focalPlaneResolutionUnit = 0;
  // EXIF DateTimeOriginal ("YYYY:MM:DD HH:MM:SS") and SubSecTimeOriginal, as text and as seconds
  // on a monotonic scale (days since 2000-01-01 times 86400 plus the time of day); the seconds are
  // only for ordering shots and measuring the gaps between them.
  std::string dateTimeOriginal;
  std::optional<double> captureSeconds;
  int orientation = 1;  // EXIF orientation of the file (already applied)
  std::string cameraMake, cameraModel;
  // compose:exposureUnit of an EXR that compose merged from photos (kExifExposureUnit: the
  // radiance is in the unit of the camera's EXIF relative exposures), or empty.
  std::string exposureUnit;
  // compose:sensorOrientation of an EXR that compose merged from photos turned upright by their
  // EXIF orientation (which the EXR, stored upright, no longer has): how the camera's sensor
  // frame was turned, for a lens calibrated in it. 1 otherwise.
  int sensorOrientation = 1;
  std::string fileColorSpace;  // colour space the file or its reader declares
  // fileColorSpace is only the format's convention as the reader states it (OpenImageIO's
  // "Linear" for OpenEXR and Radiance HDR, "sRGB" for JPEG and PNG), not a statement of the file.
  bool colorSpaceByConvention = false;
  // The description of an embedded ICC profile ("Display P3"), empty when there is none. A
  // profile other than sRGB's makes fileColorSpace its space ("Display P3", "Adobe RGB (1998)",
  // else the description itself, which a config will not know: then the note says so).
  std::string iccProfile;
  // EXIF ColorSpace 65535 ("uncalibrated", how cameras set to Adobe RGB mark their JPEGs) and no
  // profile that says more.
  bool exifUncalibrated = false;
  // The alpha channel is unassociated (a PNG's, a TIFF's so marked): colour not multiplied by it.
  bool unassociatedAlpha = false;
  // 8- or 16-bit integer samples (display-encoded unless the file says otherwise).
  bool integerSamples() const { return sampleType == "uint8" || sampleType == "uint16"; }
  // CIE xy of red, green, blue, white from an OpenEXR `chromaticities` attribute, if present.
  std::optional<std::array<double, 8>> chromaticities;
  std::string format;                 // reader name, e.g. "jpeg", "openexr"
  std::string sampleType;             // pixel type as stored: "uint8", "uint16", "half", "float"...
  int bitsPerSample = 0;              // 8, 16, 32...
  int fileWidth = 0, fileHeight = 0;  // as stored, before orientation
  // The size as shown, after the EXIF orientation (5 to 8 turn the picture a quarter turn).
  std::pair<int, int> shownSize() const {
    const bool turned = orientation >= 5 && orientation <= 8;
    return {turned ? fileHeight : fileWidth, turned ? fileWidth : fileHeight};
  }
  // An OpenEXR whose data window is smaller than its display window: the part of the frame that
  // holds stored pixels, [x0, x1) x [y0, y1) (the rest of the image is 0, no picture). Empty
  // (partlyStored false) when every pixel is stored.
  bool partlyStored = false;
  int storedX0 = 0, storedY0 = 0, storedX1 = 0, storedY1 = 0;
  int channels = 0;  // as stored

  // Relative exposure t · ISO / N² (time in seconds, N the f-number): proportional to the light
  // a pixel collects from a given radiance. Empty without an exposure time; a missing ISO counts
  // as 100 and a missing f-number as 1 (see exposureAssumptions()), which is harmless when all
  // shots of a bracket miss the same field.
  std::optional<double> relativeExposure() const;
  // What relativeExposure() had to assume ("ISO 100 (no ISO in EXIF)"), empty if nothing.
  std::string exposureAssumptions() const;
  // "Make Model" trimmed, or empty when neither is known.
  std::string camera() const;
};

// Reads only the header of an image file (no pixels are decoded): size, pixel type, colour space
// and EXIF. Fast enough to scan a folder of photos. Errors as readImage().
// `picturePart`: of a multi-part OpenEXR, the part that holds the picture (ReadOptions), as the
// pixels of a plate or an environment are read; else the first.
CaptureInfo readCaptureInfo(const std::filesystem::path& path, const std::string& stage = "ingest",
                            bool picturePart = false);

// Whether `path` has the extension of an image format readImage() is meant for (JPEG, PNG, TIFF,
// OpenEXR, Radiance HDR, and camera raw formats), for scanning folders.
bool looksLikeImageFile(const std::filesystem::path& path);
// The path's extension in lower case, with its dot (".exr"; "" when it has none).
std::string lowerExtension(const std::filesystem::path& path);

// The name the colour config's file rules are to see for `file`, whose bytes are `info.format`:
// the file's own, or, when its extension names another format (a PNG named .exr, a JPEG named
// .hdr), the same name with its format's extension. Files go to a reader by their bytes; their
// colour must not follow a name the bytes contradict (a PNG's codes read as linear light).
std::filesystem::path nameForRules(const std::filesystem::path& file, const std::string& format);

struct LoadedImage {
  Image image;  // float, channels as stored (1-4 or more), orientation applied
  CaptureInfo info;
  // With ReadOptions::codesForEightBit and an 8-bit file: the stored codes, interleaved, channels
  // as stored, orientation applied; `image` then has its size, channels, names and colour space
  // but no pixels.
  std::vector<uint8_t> codes;
  // What reading changed, for the user (an OpenEXR's data window put in its display window).
  std::vector<std::string> notes;
  bool hasPixels() const { return !image.pixels.empty(); }
};

// Gives an image read as its 8-bit codes its float pixels (code / 255, as OpenImageIO converts)
// and drops the codes. Multi-threaded.
void floatsFromCodes(LoadedImage& loaded);

struct ReadOptions {
  // An 8-bit file is returned as its codes (LoadedImage::codes) instead of floats: a quarter of
  // the memory, and no conversion for stages that work on codes (exposure merging).
  bool codesForEightBit = false;
  // A multi-part OpenEXR is read from the part that holds the picture (the first with R, G and
  // B, else with a layer's colour or Y), with a note naming it, instead of its first part (as
  // masks are read): for plates and environments, whose depth or data passes may come first.
  bool picturePart = false;
  // The image turned upright by its EXIF orientation, as a photo is shown. A texture keeps its
  // pixels as stored: UVs are laid on them, and Blender and glTF viewers ignore the tag.
  bool upright = true;
};

// Reads an image file. `stage` names the pipeline stage on whose behalf it is read, for errors.
// An image whose header claims more pixels (or values) than resourceLimits() allows is refused
// before any pixel is decoded (core/limits.h).
LoadedImage readImage(const std::filesystem::path& path, const std::string& stage = "ingest",
                      const ReadOptions& options = {});

// Throws compose::Error (`stage`, naming `file`) when `image` names its channels and none is a
// colour one (R, G, B, a layer's R, G, B, or Y for grey): a depth or data image (Z, depth, N.X)
// taken for a
// picture would be read as grey. `what`: "the plate", "the environment".
void requireColourChannels(const Image& image, const std::filesystem::path& file,
                           const std::string& stage, const std::string& what);

// Throws compose::Error (`stage`, naming `file`) when a value of `image` is NaN or infinite, or
// larger in magnitude than `limit`, saying where: "NaN in the plate at pixel (12, 7)" for
// what = "the plate". Float files can hold them; every stage downstream needs light, which is
// finite, and sums of it (a stitch's blend, a merge's average) must stay finite too.
void requireFinite(const Image& image, const std::filesystem::path& file, const std::string& stage,
                   const std::string& what, float limit = std::numeric_limits<float>::infinity());

// The largest radiance a photo or environment may hold: beyond it a file is damaged (the largest
// half float is 65504; a sun in absolute units about 1e9).
inline constexpr float kMaxPhotoValue = 1e32f;

// Whether an image tagged `space` holds sRGB codes: "sRGB", or a display transform's output
// ("<display>/<view>", ColorConfig::toDisplay) whose display or view is an sRGB one (OpenColorIO 2
// configs name the display so, version 1 configs the view) and whose view is not Raw or None.
// Such images are tagged sRGB in the JPEGs and PNGs written (EXIF ColorSpace 1, PNG's sRGB
// chunk); no others are tagged.
bool isSrgbEncoded(const std::string& space);

// Decodes an image held in memory, such as one embedded in a glTF buffer or data URI. `name`
// stands for the file in errors, and its extension tells the format (".png", ".jpg", ...).
// Otherwise as readImage(); `bytes` need only live for the call.
LoadedImage readImageFromMemory(std::span<const unsigned char> bytes,
                                const std::filesystem::path& name,
                                const std::string& stage = "ingest",
                                const ReadOptions& options = {});

// A metadata attribute written into the file header: standard names ("ExposureTime", "FNumber",
// "Exif:PhotographicSensitivity", "Make", ...) land in the EXIF block of JPEG and TIFF files;
// any other name is kept as a custom attribute where the format allows it (OpenEXR).
struct ImageAttribute {
  std::string name;
  std::variant<int, double, std::string, std::vector<float>> value;
};

struct WriteOptions {
  enum class Depth {
    Auto,
    UInt8,
    UInt16,
    Half,
    Float
  } depth = Depth::Auto;  // Auto: half for EXR, 8 bit otherwise
  int jpegQuality = 95;
  // JPEG only: chroma at full resolution (4:4:4) instead of libjpeg's and most cameras' 4:2:0, for
  // a picture whose colour edges must stay where they are (a composite over a photo).
  bool jpegFullChroma = false;
  int alphaChannel = -1;  // index of the alpha channel, or -1
  // OpenEXR only: chromaticities of the RGB channels (red, green, blue, white xy).
  std::optional<std::array<double, 8>> chromaticities;
  // OpenEXR only: the compression, as OpenImageIO names it ("zip", "zip:1", "piz", "dwaa", ...).
  // Lossless ZIP by default; PIZ (lossless too) takes about half ZIP's time on noisy photographic
  // halves, for files about a fifth larger.
  std::string exrCompression = "zip";
  std::vector<ImageAttribute> attributes;
};

struct WriteReport {
  bool promotedToFloat = false;  // half was asked for, a value did not fit, float was written
  float largestMagnitude = 0.0f;
};

// The EXIF attributes of `info` (exposure, focal lengths, focal-plane resolution, camera, time),
// for WriteOptions::attributes, so that readImage() reads them back.
std::vector<ImageAttribute> exifAttributes(const CaptureInfo& info);

// The capture metadata that a file header with these attributes (named as OpenImageIO names them:
// "ExposureTime", "Exif:FocalLength", "Orientation", ...) gives: what readCaptureInfo() makes of a
// real file's EXIF, without encoding one. For tests and fuzzing of the EXIF interpretation.
CaptureInfo captureInfoFromAttributes(int width, int height, int channels,
                                      const std::vector<ImageAttribute>& attributes);

// Throws compose::Error (stage `stage`) when no writer takes `path`'s extension (or it has
// none), before anything is computed for it.
void requireImageWriter(const std::filesystem::path& path, const std::string& stage = "output");

// Writes `image` to `path`, format chosen from the extension. Atomic: temp file + rename.
WriteReport writeImage(const std::filesystem::path& path, const Image& image,
                       const WriteOptions& options = {});
// Writes `image` as one of a set of outputs: into a temporary of `outputs`; it appears at `path`
// when the caller commits the set.
WriteReport writeImage(OutputFiles& outputs, const std::filesystem::path& path, const Image& image,
                       const WriteOptions& options = {});

// One part of a multi-part OpenEXR file (as Nuke reads them: each part a layer group with its own
// data window). The image covers [x, x + width) x [y, y + height) of the full frame
// fullWidth x fullHeight (the display window).
//
// The part's channels are those of `image`, then those of each of `moreImages` (the same size as
// `image`), then `constantChannels` (one value everywhere, such as an opaque alpha {"A", 1}):
// layers held apart (a beauty and its AOVs, an RGB composite and its alpha) are written without
// first being copied into one interleaved image. `channelNames`, when given, names the channels of
// the images (else each image's own names); options.alphaChannel counts every channel of the part.
// `channelScales` multiplies the named channels of the images on the way (an object's colour and
// irradiance by the exposure chosen after its render), before the check for half's range.
struct ExrPart {
  ExrPart() = default;
  ExrPart(std::string partName, const Image* partImage, int partX = 0, int partY = 0,
          int partFullWidth = 0, int partFullHeight = 0, WriteOptions partOptions = {})
      : name(std::move(partName)),
        image(partImage),
        x(partX),
        y(partY),
        fullWidth(partFullWidth),
        fullHeight(partFullHeight),
        options(std::move(partOptions)) {}

  std::string name;
  const Image* image = nullptr;
  int x = 0, y = 0;
  int fullWidth = 0, fullHeight = 0;
  WriteOptions options;
  std::vector<const Image*> moreImages;
  std::vector<std::pair<std::string, float>> constantChannels;
  std::vector<std::pair<std::string, float>> channelScales;
  std::vector<std::string> channelNames;
  std::string colorSpace;  // the part's colour space attribute; empty: `image`'s
  // Channels written as 32-bit float whatever options.depth says: positions and depths, which
  // half's 11 bits of precision would misplace (a point 10 m away by a centimetre).
  std::vector<std::string> floatChannels;
};

// Attributes written on every part of an OpenEXR file: 4x4 matrices (OpenEXR's m44f, or m44d
// for `doubleMatrices`, stored as Imath reads them: row vectors, translation in the last row)
// and strings.
struct ExrHeader {
  float pixelAspectRatio = 1.0f;  // OpenEXR's pixelAspectRatio of every part
  std::vector<std::pair<std::string, std::array<float, 16>>> matrices;
  std::vector<std::pair<std::string, std::array<double, 16>>> doubleMatrices;
  std::vector<std::pair<std::string, std::string>> strings;
};

// Writes a multi-part OpenEXR into a temporary of `outputs` (it appears at `path` on commit).
// Returns a report per part. Half-float parts keep exactly the values Imath's half conversion
// gives; nothing else is rounded.
std::vector<WriteReport> writeExrParts(OutputFiles& outputs, const std::filesystem::path& path,
                                       const std::vector<ExrPart>& parts,
                                       const ExrHeader& header = {});

// The largest value half float represents.
inline constexpr float kHalfMax = 65504.0f;

}  // namespace compose::ingest
