// Environment-map layouts: how a lat-long map or the six faces of a cube map sit in image files,
// and how to tell them apart.
//
// Face orientation is OpenEXR's everywhere (lighting/cubemap.h): every face picture is the view
// from the cube's centre, side faces upright, +Y's top towards +Z, -Y's top towards -Z.
//
//   latlong   2:1   OpenEXR lat-long (Imf::LatLongMap axes; environment.h)
//   cube      1:6   OpenEXR's cube layout: the faces +X -X +Y -Y +Z -Z stacked top to bottom
//                   (Imf::CubeMap), as exrenvmap writes it; an EXR says so with envmap=cube
//   hcross    4:3   horizontal cross:        +Y             (a panorama strip -X -Z +X +Z with
//                                        -X  -Z  +X  +Z      the camera's view, -Z, in the
//                                            -Y              middle; cells not used are black)
//   vcross    3:4   vertical cross:          +Y             (HDRShop / Debevec light-probe
//                                        -X  -Z  +X          crosses: the back face, +Z, hangs
//                                            -Y              below -Y, turned 180°)
//                                            +Z
//   faces     six square files, one per face (see faceFromName for the names)
//   mirrorball 1:1  a photo of a chrome ball cropped to the ball (mirror_ball.h)
//
// Detection by aspect ratio is unambiguous for 2:1, 1:6, 4:3 and 3:4; a square image could be a
// mirror ball or a single face, and needs an explicit layout.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "core/image.h"
#include "lighting/cubemap.h"

namespace compose::cubemap {

enum class Layout { LatLong, Cube, HorizontalCross, VerticalCross, Faces, MirrorBall };

// "latlong", "cube", "hcross", "vcross", "faces", "mirrorball".
const char* layoutName(Layout layout);
// Accepts the names above and a few aliases (equirect, equirectangular, strip, cross-h, ...);
// nullopt if unknown.
std::optional<Layout> parseLayout(const std::string& name);
// Every accepted primary name, for help texts and errors.
std::vector<std::string> layoutNames();

// The layout a single image of this size has, if its aspect ratio says so unambiguously
// (2:1 lat-long, 1:6 cube, 4:3 horizontal cross, 3:4 vertical cross). Square images and any other
// aspect return nullopt.
std::optional<Layout> layoutFromAspect(int width, int height);

// Checks that an image of this size can hold `layout` and returns the face size (lat-long: the
// height). Throws compose::Error (stage "ingest", naming `file`) with the expected shape.
int checkShape(Layout layout, int width, int height, const std::filesystem::path& file);

// Where face f sits in a cross of face size n: its top-left texel (in the cross) and whether it is
// turned 180°. Only for HorizontalCross and VerticalCross.
struct CrossCell {
  int column, row;
  bool rotated180;
};
CrossCell crossCell(Layout layout, int face);

// For an image of a cross's shape: the mean magnitude of the six cells outside the cross over
// that of the six faces (0 for a cross with black corners; about 1 for a photo of a 4:3 frame).
double crossCornerRatio(const Image& image, Layout layout);

// Splits a cross or an OpenEXR cube strip into its six faces (channels as in the image).
std::array<Image, lighting::kCubeFaces> unpackFaces(const Image& image, Layout layout);
// Packs six faces (RGB) into a cross or cube strip; unused cross cells are black.
Image packFaces(const lighting::CubeMap& cube, Layout layout);

// Face names in file names. faceFromName looks at the end of a file name's stem for a face token,
// case-insensitively: px nx py ny pz nz, posx negx ..., pos_x neg_x ..., +X -X ... (as exrenvmap's
// '%' names), and right left top/up bottom/down back front (front is -Z, where the camera looks;
// back is +Z). A token must be the whole stem or follow a separator (_ - . space), except the
// +X/-X family, which may follow anything. Returns the face, or nullopt.
struct FaceToken {
  int face;
  std::string token;  // as found in the name
  int family;         // which naming scheme, so that siblings can be derived (faceNameIn)
};
std::optional<FaceToken> faceFromName(const std::string& stem);
// The face a photo's file name points it at: a face token at the end of the stem (room_px.jpg),
// or before a bracket number (px_2.jpg, room-nz-3.jpg, as compose capture-sim names them).
std::optional<FaceToken> faceFromPhotoName(const std::filesystem::path& file);
// A level view named by its turn, as compose capture-sim names a ring of views: "yaw120" (or
// yaw120_2, yaw120.exr) is 120° from -Z towards -X (as stitch's @120,0 says it); `name` is a
// file's stem or a view's name. Returns the degrees (0..359), or nullopt.
std::optional<double> yawFromName(const std::string& name);
// The token for `face` in naming family `family`, in the letter case of `like`.
std::string faceNameIn(int family, int face, const std::string& like);

// Naming schemes for writing six files: "pxnx" (px nx ...), "posneg" (posx negx ...), "exr"
// (+X -X ..., exrenvmap's), "words" (right left top bottom back front).
std::optional<int> parseFaceNaming(const std::string& name);
std::vector<std::string> faceNamingNames();

}  // namespace compose::cubemap
