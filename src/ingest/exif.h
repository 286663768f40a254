// EXIF metadata as a JPEG's APP1 segment holds it: a TIFF structure (byte order mark, IFD0, the
// Exif sub-IFD), read into and written from ImageAttributes named as OpenImageIO names them, so
// that the capture metadata (image_io.h, CaptureInfo) comes out the same whichever library read
// the file.
//
// Read: every entry of IFD0 and of the Exif sub-IFD whose tag is listed below (in either IFD),
// in either byte order; ASCII as text (trailing NULs and spaces removed), SHORT and LONG as int,
// RATIONAL and SRATIONAL as double (a zero denominator makes the entry absent). Unknown tags, maker
// notes, GPS and thumbnails are skipped. The block is untrusted: offsets and counts are checked
// against its size, a loop of IFDs is not followed, and a damaged block yields the entries read
// before the damage (never a crash or an exception).
//
// Written: the same tags from attributes of the matching names and types (numbers as the tag's
// own type; exposure times and other rationals as exact fractions where the value is one: 1/64 s
// stays 1/64), IFD0 first with a pointer to the Exif sub-IFD; big-endian ("MM"), as cameras
// commonly write it. Attributes with other names are not written.
//
//   IFD0:  Make, Model, Orientation, XResolution, YResolution, ResolutionUnit, Software,
//          DateTime
//   Exif:  ExposureTime, FNumber, Exif:PhotographicSensitivity (ISOSpeedRatings),
//          Exif:DateTimeOriginal, Exif:SubsecTimeOriginal, Exif:FocalLength,
//          Exif:FocalPlaneXResolution, Exif:FocalPlaneYResolution,
//          Exif:FocalPlaneResolutionUnit, Exif:FocalLengthIn35mmFilm, Exif:ColorSpace,
//          Exif:PixelXDimension, Exif:PixelYDimension
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "ingest/image_io.h"

namespace compose::ingest::exif {

// The entries of a TIFF-structured EXIF block (what follows "Exif\0\0" in APP1).
std::vector<ImageAttribute> decode(std::span<const unsigned char> tiff);

// The TIFF-structured block for `attributes` (without the "Exif\0\0" prefix); empty when none of
// them is an EXIF tag.
std::vector<unsigned char> encode(const std::vector<ImageAttribute>& attributes);

// The description ('desc' tag) of an ICC profile, version 2 (ASCII) or 4 (the first record of a
// multi-localised string): "Display P3", "sRGB IEC61966-2.1". Empty when the profile has none or
// is malformed.
std::string iccDescription(std::span<const unsigned char> profile);

// A small ICC v2 display profile (monitor class, RGB to XYZ) for linear light with the sRGB /
// Rec.709 primaries and D65 white (the primaries adapted to D50 by Bradford, as sRGB's own
// profiles give them), its tone curves the identity, its description `kLinearRec709Profile`.
// Embedded in a linear 16-bit TIFF it tells compose and other readers that the file is not
// sRGB-encoded.
inline constexpr const char* kLinearRec709Profile = "Linear Rec.709 (sRGB primaries)";
std::vector<unsigned char> linearRec709Profile();

}  // namespace compose::ingest::exif
