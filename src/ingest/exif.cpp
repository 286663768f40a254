#include "ingest/exif.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <optional>
#include <string>

namespace compose::ingest::exif {

namespace {

// TIFF field types (TIFF 6.0 §2).
enum Type : uint16_t {
  kByte = 1,
  kAscii = 2,
  kShort = 3,
  kLong = 4,
  kRational = 5,
  kUndefined = 7,
  kSLong = 9,
  kSRational = 10,
  kIfd = 13
};

enum class Ifd { Zero, Exif };

struct Tag {
  uint16_t id;
  Ifd ifd;
  Type type;  // the type it is written as
  const char* name;
};

// The tags read and written (exif.h), named as OpenImageIO names them.
constexpr Tag kTags[] = {
    {0x010F, Ifd::Zero, kAscii, "Make"},
    {0x0110, Ifd::Zero, kAscii, "Model"},
    {0x0112, Ifd::Zero, kShort, "Orientation"},
    {0x011A, Ifd::Zero, kRational, "XResolution"},
    {0x011B, Ifd::Zero, kRational, "YResolution"},
    {0x0128, Ifd::Zero, kShort, "ResolutionUnit"},
    {0x0131, Ifd::Zero, kAscii, "Software"},
    {0x0132, Ifd::Zero, kAscii, "DateTime"},
    {0x829A, Ifd::Exif, kRational, "ExposureTime"},
    {0x829D, Ifd::Exif, kRational, "FNumber"},
    {0x8827, Ifd::Exif, kShort, "Exif:PhotographicSensitivity"},
    {0x8830, Ifd::Exif, kShort, "Exif:SensitivityType"},
    {0x8833, Ifd::Exif, kLong, "Exif:ISOSpeed"},
    {0x9003, Ifd::Exif, kAscii, "Exif:DateTimeOriginal"},
    {0x9291, Ifd::Exif, kAscii, "Exif:SubsecTimeOriginal"},
    {0x920A, Ifd::Exif, kRational, "Exif:FocalLength"},
    {0xA001, Ifd::Exif, kShort, "Exif:ColorSpace"},
    {0xA002, Ifd::Exif, kLong, "Exif:PixelXDimension"},
    {0xA003, Ifd::Exif, kLong, "Exif:PixelYDimension"},
    {0xA20E, Ifd::Exif, kRational, "Exif:FocalPlaneXResolution"},
    {0xA20F, Ifd::Exif, kRational, "Exif:FocalPlaneYResolution"},
    {0xA210, Ifd::Exif, kShort, "Exif:FocalPlaneResolutionUnit"},
    {0xA405, Ifd::Exif, kShort, "Exif:FocalLengthIn35mmFilm"},
};
constexpr uint16_t kExifPointer = 0x8769;

// The tag of this number, in whichever IFD it is found (some writers put Exif tags in IFD0, as
// OpenImageIO's reader allows).
const Tag* tagOf(uint16_t id) {
  for (const Tag& t : kTags)
    if (t.id == id) return &t;
  return nullptr;
}

size_t typeSize(uint16_t type) {
  switch (type) {
    case kByte:
    case kAscii:
    case kUndefined:
      return 1;
    case kShort:
      return 2;
    case kLong:
    case kSLong:
      return 4;
    case kRational:
    case kSRational:
      return 8;
    default:
      return 0;
  }
}

class Reader {
 public:
  explicit Reader(std::span<const unsigned char> data) : data_(data) {}

  bool header(uint32_t& firstIfd) {
    if (data_.size() < 8) return false;
    if (data_[0] == 'I' && data_[1] == 'I') {
      little_ = true;
    } else if (data_[0] == 'M' && data_[1] == 'M') {
      little_ = false;
    } else {
      return false;
    }
    uint16_t magic = 0;
    if (!u16(2, magic) || magic != 42) return false;
    return u32(4, firstIfd);
  }

  bool u16(size_t at, uint16_t& v) const {
    if (at > data_.size() || data_.size() - at < 2) return false;
    v = little_ ? uint16_t(data_[at] | data_[at + 1] << 8)
                : uint16_t(data_[at] << 8 | data_[at + 1]);
    return true;
  }
  bool u32(size_t at, uint32_t& v) const {
    if (at > data_.size() || data_.size() - at < 4) return false;
    const uint32_t b0 = data_[at], b1 = data_[at + 1], b2 = data_[at + 2], b3 = data_[at + 3];
    v = little_ ? (b0 | b1 << 8 | b2 << 16 | b3 << 24) : (b0 << 24 | b1 << 16 | b2 << 8 | b3);
    return true;
  }

  // The entries of the IFD at `offset` that are tags of `ifd`; the Exif sub-IFD's offset, if
  // IFD0 points to one.
  void ifd(uint32_t offset, Ifd which, std::vector<ImageAttribute>& out,
           std::optional<uint32_t>* exifOffset) const {
    uint16_t count = 0;
    if (!u16(offset, count)) return;
    for (uint32_t i = 0; i < count; ++i) {
      const size_t entry = size_t(offset) + 2 + size_t(i) * 12;
      uint16_t id = 0, type = 0;
      uint32_t n = 0;
      if (!u16(entry, id) || !u16(entry + 2, type) || !u32(entry + 4, n)) return;
      if (which == Ifd::Zero && id == kExifPointer && exifOffset) {
        uint32_t at = 0;
        uint16_t shortAt = 0;
        if (n == 1 && (type == kLong || type == kIfd) && u32(entry + 8, at)) *exifOffset = at;
        if (n == 1 && type == kShort && u16(entry + 8, shortAt)) *exifOffset = shortAt;
        continue;
      }
      const Tag* tag = tagOf(id);
      const size_t size = typeSize(type);
      if (!tag || size == 0 || n == 0) continue;
      const uint64_t bytes = uint64_t(size) * n;
      size_t at = entry + 8;  // values of four bytes or fewer are in the entry itself
      if (bytes > 4) {
        uint32_t valueOffset = 0;
        if (!u32(entry + 8, valueOffset)) continue;
        at = valueOffset;
      }
      if (at > data_.size() || data_.size() - at < bytes) continue;
      // A tag seen once already (a damaged pointer that leads back into an IFD read) is not
      // read twice: the first one stands.
      if (std::any_of(out.begin(), out.end(),
                      [&](const ImageAttribute& a) { return a.name == tag->name; }))
        continue;
      if (std::optional<ImageAttribute> a = value(*tag, type, n, at)) out.push_back(std::move(*a));
    }
  }

 private:
  std::optional<ImageAttribute> value(const Tag& tag, uint16_t type, uint32_t n, size_t at) const {
    switch (type) {
      case kAscii: {
        std::string text(reinterpret_cast<const char*>(data_.data() + at), n);
        const size_t nul = text.find('\0');
        if (nul != std::string::npos) text.resize(nul);
        while (!text.empty() && text.back() == ' ') text.pop_back();
        if (text.empty()) return std::nullopt;
        return ImageAttribute{tag.name, text};
      }
      case kShort: {
        uint16_t v = 0;
        if (!u16(at, v)) return std::nullopt;
        return ImageAttribute{tag.name, int(v)};
      }
      case kLong:
      case kSLong: {
        uint32_t v = 0;
        if (!u32(at, v)) return std::nullopt;
        return ImageAttribute{
            tag.name, type == kSLong ? int(int32_t(v)) : int(std::min<uint32_t>(v, INT32_MAX))};
      }
      case kRational:
      case kSRational: {
        uint32_t num = 0, den = 0;
        if (!u32(at, num) || !u32(at + 4, den) || den == 0) return std::nullopt;
        const double v = type == kSRational ? double(int32_t(num)) / double(int32_t(den))
                                            : double(num) / double(den);
        if (!std::isfinite(v)) return std::nullopt;
        return ImageAttribute{tag.name, v};
      }
      case kByte: {
        return ImageAttribute{tag.name, int(data_[at])};
      }
      default:
        return std::nullopt;
    }
  }

  std::span<const unsigned char> data_;
  bool little_ = false;
};

// A value as an unsigned rational: exact for whole numbers and for 1/n (exposure times, n
// found within rounding: 1 / 1e-9 is not a whole double), else the closest fraction of 32-bit
// terms (the continued fraction's last convergent that fits: 1.5e-7 s is 3/20000000, where a
// fixed denominator of 10^6 wrote 0).
std::pair<uint32_t, uint32_t> rational(double v) {
  constexpr double kMax = 4294967295.0;
  if (!(v > 0.0) || !std::isfinite(v)) return {0, 1};
  if (v >= kMax) return {uint32_t(kMax), 1};
  const double inverse = std::round(1.0 / v);
  if (v < 1.0 && inverse <= kMax && std::abs(1.0 / v - inverse) <= 1e-9 * inverse)
    return {1, uint32_t(inverse)};
  // Convergents h/k of v = a0 + 1/(a1 + 1/(a2 + ...)).
  double h0 = 0.0, h1 = 1.0, k0 = 1.0, k1 = 0.0, x = v;
  for (int i = 0; i < 64; ++i) {
    const double a = std::floor(x);
    const double h2 = a * h1 + h0, k2 = a * k1 + k0;
    if (h2 > kMax || k2 > kMax) break;
    h0 = h1, h1 = h2, k0 = k1, k1 = k2;
    const double rest = x - a;
    if (rest <= 1e-12 || std::abs(h1 / k1 - v) <= 1e-12 * v) break;
    x = 1.0 / rest;
  }
  if (k1 == 0.0 || h1 == 0.0) return {1, uint32_t(kMax)};  // below 1/kMax: the smallest there is
  return {uint32_t(h1), uint32_t(k1)};
}

class Writer {
 public:
  void u16(std::vector<unsigned char>& out, uint16_t v) {
    out.push_back(uint8_t(v >> 8));
    out.push_back(uint8_t(v));
  }
  void u32(std::vector<unsigned char>& out, uint32_t v) {
    for (int s = 24; s >= 0; s -= 8) out.push_back(uint8_t(v >> s));
  }

  struct Entry {
    uint16_t id, type;
    uint32_t count;
    std::vector<unsigned char> value;  // big-endian bytes
  };

  static std::optional<Entry> entryOf(const Tag& tag, const ImageAttribute& a) {
    Writer w;
    Entry e{tag.id, tag.type, 0, {}};
    const int* i = std::get_if<int>(&a.value);
    const double* d = std::get_if<double>(&a.value);
    const std::string* t = std::get_if<std::string>(&a.value);
    switch (tag.type) {
      case kAscii:
        if (!t) return std::nullopt;
        e.value.assign(t->begin(), t->end());
        e.value.push_back(0);
        break;
      case kShort: {
        const double v = i ? double(*i) : d ? std::round(*d) : -1.0;
        if (!(v >= 0.0 && v <= 65535.0)) return std::nullopt;
        w.u16(e.value, uint16_t(v));
        break;
      }
      case kLong: {
        const double v = i ? double(*i) : d ? std::round(*d) : -1.0;
        if (!(v >= 0.0 && v <= 4294967295.0)) return std::nullopt;
        w.u32(e.value, uint32_t(v));
        break;
      }
      case kRational: {
        const double v = i ? double(*i) : d ? *d : -1.0;
        if (!(v >= 0.0)) return std::nullopt;
        const auto [num, den] = rational(v);
        w.u32(e.value, num);
        w.u32(e.value, den);
        break;
      }
      default:
        return std::nullopt;
    }
    e.count = uint32_t(e.value.size() / typeSize(tag.type));
    return e;
  }

  // Appends an IFD of `entries` at out.size(), tags in increasing order; values that do not fit
  // in an entry follow the IFD.
  void ifd(std::vector<unsigned char>& out, std::vector<Entry> entries) {
    std::sort(entries.begin(), entries.end(),
              [](const Entry& a, const Entry& b) { return a.id < b.id; });
    const size_t start = out.size();
    size_t extra = start + 2 + entries.size() * 12 + 4;  // where the next long value goes
    std::vector<unsigned char> values;
    u16(out, uint16_t(entries.size()));
    for (const Entry& e : entries) {
      u16(out, e.id);
      u16(out, e.type);
      u32(out, e.count);
      if (e.value.size() <= 4) {
        std::vector<unsigned char> inline4 = e.value;
        inline4.resize(4, 0);
        out.insert(out.end(), inline4.begin(), inline4.end());
      } else {
        u32(out, uint32_t(extra + values.size()));
        values.insert(values.end(), e.value.begin(), e.value.end());
        if (values.size() % 2) values.push_back(0);  // word alignment
      }
    }
    u32(out, 0);  // no next IFD
    out.insert(out.end(), values.begin(), values.end());
  }
};

}  // namespace

std::vector<ImageAttribute> decode(std::span<const unsigned char> tiff) {
  std::vector<ImageAttribute> out;
  Reader reader(tiff);
  uint32_t first = 0;
  if (!reader.header(first)) return out;
  std::optional<uint32_t> exifOffset;
  reader.ifd(first, Ifd::Zero, out, &exifOffset);
  if (exifOffset && *exifOffset != first) reader.ifd(*exifOffset, Ifd::Exif, out, nullptr);
  return out;
}

std::vector<unsigned char> encode(const std::vector<ImageAttribute>& attributes) {
  std::vector<Writer::Entry> zero, exif;
  for (const Tag& tag : kTags) {
    for (const ImageAttribute& a : attributes) {
      if (a.name != tag.name && !(tag.id == 0x8827 && a.name == "Exif:ISOSpeedRatings")) continue;
      if (std::optional<Writer::Entry> e = Writer::entryOf(tag, a))
        (tag.ifd == Ifd::Zero ? zero : exif).push_back(std::move(*e));
      break;
    }
  }
  if (zero.empty() && exif.empty()) return {};
  Writer w;
  std::vector<unsigned char> out = {'M', 'M'};
  w.u16(out, 42);
  w.u32(out, 8);  // IFD0 right after the header
  if (!exif.empty()) {
    // The pointer's value is where the Exif IFD will start: after IFD0 and its values, which
    // are known once IFD0 is laid out; lay it out twice.
    zero.push_back({kExifPointer, kLong, 1, {0, 0, 0, 0}});
    std::vector<unsigned char> probe = out;
    w.ifd(probe, zero);
    const uint32_t exifAt = uint32_t(probe.size());
    zero.back().value.clear();
    w.u32(zero.back().value, exifAt);
  }
  w.ifd(out, zero);
  if (!exif.empty()) w.ifd(out, exif);
  return out;
}

std::string iccDescription(std::span<const unsigned char> p) {
  auto be32 = [&](size_t at) -> uint32_t {
    return at + 4 > p.size() ? 0u
                             : (uint32_t(p[at]) << 24) | (uint32_t(p[at + 1]) << 16) |
                                   (uint32_t(p[at + 2]) << 8) | uint32_t(p[at + 3]);
  };
  if (p.size() < 132) return {};
  const uint32_t tags = be32(128);
  for (uint32_t t = 0; t < tags && 132 + 12 * size_t(t) + 12 <= p.size(); ++t) {
    const size_t entry = 132 + 12 * size_t(t);
    if (std::memcmp(p.data() + entry, "desc", 4) != 0) continue;
    const size_t at = be32(entry + 4), size = be32(entry + 8);
    if (at >= p.size() || size > p.size() - at || size < 12) return {};
    const unsigned char* d = p.data() + at;
    std::string text;
    if (std::memcmp(d, "desc", 4) == 0) {
      const size_t n = std::min<size_t>(be32(at + 8), size - 12);
      text.assign(reinterpret_cast<const char*>(d + 12), n);
    } else if (std::memcmp(d, "mluc", 4) == 0 && size >= 28 && be32(at + 8) >= 1) {
      const size_t length = be32(at + 20), offset = be32(at + 24);
      if (offset > size || length > size - offset) return {};
      for (size_t i = 0; i + 1 < length; i += 2) {
        const unsigned code = (unsigned(d[offset + i]) << 8) | d[offset + i + 1];
        text += code < 128 ? char(code) : '?';  // the names that matter are ASCII
      }
    }
    while (!text.empty() &&
           (text.back() == '\0' || std::isspace(static_cast<unsigned char>(text.back()))))
      text.pop_back();
    return text;
  }
  return {};
}

std::vector<unsigned char> linearRec709Profile() {
  std::vector<unsigned char> out(128, 0);  // the header, filled in below
  auto put32 = [](std::vector<unsigned char>& v, size_t at, uint32_t x) {
    v[at] = uint8_t(x >> 24), v[at + 1] = uint8_t(x >> 16), v[at + 2] = uint8_t(x >> 8),
    v[at + 3] = uint8_t(x);
  };
  auto append32 = [](std::vector<unsigned char>& v, uint32_t x) {
    for (int s = 24; s >= 0; s -= 8) v.push_back(uint8_t(x >> s));
  };
  auto appendText = [](std::vector<unsigned char>& v, const char* four) {
    v.insert(v.end(), four, four + 4);
  };
  auto s15 = [](double x) { return uint32_t(int32_t(std::lround(x * 65536.0))); };
  // The tagged elements, each 4-byte aligned.
  struct Element {
    const char* signature;
    std::vector<unsigned char> data;
  };
  std::vector<Element> elements;
  auto xyz = [&](const char* signature, double x, double y, double z) {
    Element e{signature, {}};
    appendText(e.data, "XYZ ");
    append32(e.data, 0);
    for (double c : {x, y, z}) append32(e.data, s15(c));
    elements.push_back(std::move(e));
  };
  {
    Element e{"desc", {}};  // textDescriptionType: ASCII, then empty Unicode and ScriptCode
    appendText(e.data, "desc");
    append32(e.data, 0);
    const std::string text = kLinearRec709Profile;
    append32(e.data, uint32_t(text.size() + 1));
    e.data.insert(e.data.end(), text.begin(), text.end());
    e.data.push_back(0);
    append32(e.data, 0);                         // Unicode language code
    append32(e.data, 0);                         // Unicode count
    e.data.insert(e.data.end(), 2 + 1 + 67, 0);  // ScriptCode code, count, 67 bytes
    elements.push_back(std::move(e));
  }
  {
    Element e{"cprt", {}};
    appendText(e.data, "text");
    append32(e.data, 0);
    const std::string text = "No copyright, use freely";
    e.data.insert(e.data.end(), text.begin(), text.end());
    e.data.push_back(0);
    elements.push_back(std::move(e));
  }
  xyz("wtpt", 0.9505, 1.0, 1.0891);  // D65, as sRGB's v2 profiles give it
  xyz("rXYZ", 0.4361, 0.2225, 0.0139);
  xyz("gXYZ", 0.3851, 0.7169, 0.0971);
  xyz("bXYZ", 0.1431, 0.0606, 0.7141);
  for (const char* trc : {"rTRC", "gTRC", "bTRC"}) {
    Element e{trc, {}};  // curveType with no entries: the identity
    appendText(e.data, "curv");
    append32(e.data, 0);
    append32(e.data, 0);
    elements.push_back(std::move(e));
  }
  // The tag table, then the elements.
  const size_t tableEnd = 128 + 4 + 12 * elements.size();
  append32(out, uint32_t(elements.size()));
  size_t at = tableEnd;
  std::vector<unsigned char> body;
  for (const Element& e : elements) {
    appendText(out, e.signature);
    append32(out, uint32_t(at));
    append32(out, uint32_t(e.data.size()));
    body.insert(body.end(), e.data.begin(), e.data.end());
    at += e.data.size();
    while (at % 4) body.push_back(0), ++at;
  }
  out.insert(out.end(), body.begin(), body.end());
  // The header (ICC.1:2001-04, version 2.1).
  put32(out, 0, uint32_t(out.size()));
  put32(out, 8, 0x02100000);
  std::memcpy(out.data() + 12, "mntrRGB XYZ ", 12);  // class, colour space, connection space
  const uint16_t date[6] = {2026, 1, 1, 0, 0, 0};
  for (int i = 0; i < 6; ++i)
    out[24 + 2 * i] = uint8_t(date[i] >> 8), out[25 + 2 * i] = uint8_t(date[i]);
  std::memcpy(out.data() + 36, "acsp", 4);
  put32(out, 44, 1);            // flags: embedded in a file
  put32(out, 64, 0);            // perceptual rendering intent
  put32(out, 68, s15(0.9642));  // the connection space's illuminant, D50
  put32(out, 72, s15(1.0));
  put32(out, 76, s15(0.8249));
  return out;
}

}  // namespace compose::ingest::exif
