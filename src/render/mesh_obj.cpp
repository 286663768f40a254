// Wavefront OBJ and MTL (see mesh.h for what is read and how).
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <climits>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <string_view>
#include <tuple>
#include <unordered_map>

#include <tiny_obj_loader.h>

#include "core/error.h"
#include "core/limits.h"
#include "core/numbers.h"
#include "core/output_files.h"
#include "render/mesh_formats.h"

namespace compose::render::detail {

namespace fs = std::filesystem;

namespace {

// What the first pass over the text found besides malformed numbers.
struct ObjScan {
  bool smoothingGroups = false;               // an `s` statement
  size_t linesAndPoints = 0;                  // `l` and `p` elements (not rendered)
  size_t vertices = 0, colouredVertices = 0;  // `v` lines, those with a colour (x y z r g b)
  // What follows each `mtllib`, whole: one file whose name has spaces, or several names.
  std::vector<std::string> materialLines;
  // Each face's number of corners, in the file's order (tinyobjloader keeps them in 8 bits).
  std::vector<uint32_t> faceCorners;
  // Each face's material: an index into materialNames (the whole name after `usemtl`, spaces
  // included: tinyobjloader keeps only its first word), or -1 before any `usemtl`.
  std::vector<std::string> materialNames;
  std::vector<int32_t> faceMaterial;
  // The text needs rewriting before tinyobjloader reads it: it starts with a UTF-8 byte-order
  // mark, or a line goes on on the next one (a backslash at its end).
  bool rewrite = false;
};

constexpr std::string_view kUtf8Bom = "\xEF\xBB\xBF";

// One line of an OBJ or MTL file, split where tinyobjloader splits them: at "\n", "\r\n" or a
// lone "\r" (classic Mac files), so that both passes see the same lines. False at the end.
bool objLine(std::streambuf& in, std::string& line) {
  using Traits = std::char_traits<char>;
  line.clear();
  int c = in.sbumpc();
  if (c == Traits::eof()) return false;
  for (; c != Traits::eof(); c = in.sbumpc()) {
    if (c == '\n') break;
    if (c == '\r') {
      if (in.sgetc() == '\n') in.sbumpc();
      break;
    }
    line += char(c);
  }
  return true;
}

// Fields of a line as tinyobjloader separates them: by spaces and tabs.
bool objSpace(char c) {
  return c == ' ' || c == '\t';
}

// Skips a UTF-8 byte-order mark at the start of `in` (Notepad writes one; tinyobjloader would
// take it as part of the first line's keyword and drop that line). True if there was one.
bool skipByteOrderMark(std::istream& in) {
  char head[3] = {};
  in.read(head, 3);
  if (in.gcount() == 3 && std::string_view(head, 3) == kUtf8Bom) return true;
  in.clear();
  in.seekg(0);
  return false;
}

// The lines of an OBJ file as Blender reads them: a line that ends in a backslash (not a
// comment) goes on on the next one. Counts the file's lines read so far, for messages.
class ObjLines {
 public:
  explicit ObjLines(std::streambuf& in) : in_(in) {}
  bool next(std::string& line) {
    if (!objLine(in_, line)) return false;
    first_ = ++read_;
    std::string more;
    while (continues(line)) {
      joined_ = true;
      if (!objLine(in_, more)) break;
      ++read_;
      line += more;
    }
    return true;
  }
  size_t lineNumber() const { return first_; }  // in the file, of the line next() gave
  bool joined() const { return joined_; }       // some line went on on the next

 private:
  // Replaces a closing backslash (and the blanks after it) by a space.
  static bool continues(std::string& line) {
    const size_t last = line.find_last_not_of(" \t");
    if (last == std::string::npos || line[last] != '\\') return false;
    if (line[line.find_first_not_of(" \t")] == '#') return false;
    line.resize(last);
    line += ' ';
    return true;
  }
  std::streambuf& in_;
  size_t read_ = 0, first_ = 0;
  bool joined_ = false;
};

// The whole of what follows a statement's keyword, without the blanks around it (a material's
// name may have spaces).
std::string restOfLine(const std::string& line, std::string_view key) {
  const size_t at = line.find_first_not_of(" \t");  // where the keyword is
  if (at == std::string::npos) return {};
  const size_t from = line.find_first_not_of(" \t", at + key.size());
  if (from == std::string::npos) return {};
  return line.substr(from, line.find_last_not_of(" \t") + 1 - from);
}

// tinyobjloader reads a malformed number ("nan", "inf", "abc") as 0 without saying so, and an
// index beyond int's range wraps around. This pass over the text finds them first and names the
// line: every field of v, vn and vt must be a finite number, and every corner of f an integer
// reference within int's range.
ObjScan scanObj(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("mesh", withSystemReason("cannot open", errno), path);
  ObjScan scan;
  scan.rewrite = skipByteOrderMark(in);
  ObjLines lines(*in.rdbuf());
  std::string line;
  auto fail = [&](const std::string& what) {
    throw Error("mesh", "line " + std::to_string(lines.lineNumber()) + ": " + what, path);
  };
  std::vector<std::string_view> fields;
  std::map<std::string, int32_t, std::less<>> materialIndex;
  int32_t material = -1;
  int64_t triangles = 0;
  while (lines.next(line)) {
    fields.clear();
    for (size_t i = 0; i < line.size();) {
      while (i < line.size() && objSpace(line[i])) ++i;
      size_t j = i;
      while (j < line.size() && !objSpace(line[j])) ++j;
      if (j > i) fields.emplace_back(line.data() + i, j - i);
      i = j;
    }
    if (fields.empty() || fields[0].front() == '#') continue;
    const std::string_view key = fields[0];
    if (key == "v" || key == "vn" || key == "vt") {
      if (key == "v") {
        ++scan.vertices;
        if (fields.size() >= 7) ++scan.colouredVertices;
      }
      const size_t needed = key == "vt" ? 1 : 3;
      if (fields.size() < needed + 1) {
        fail("'" + std::string(key) + "' needs " + std::to_string(needed) + " numbers, has " +
             std::to_string(fields.size() - 1));
      }
      for (size_t f = 1; f < fields.size(); ++f) {
        const std::string text(fields[f]);
        // Decimal only, as the OBJ parser reads numbers (strtod's hexadecimal "0x2" passed here
        // and was read as 0 there); a leading '+' is allowed.
        std::string_view digits = fields[f];
        if (digits.size() > 1 && digits[0] == '+' &&
            (std::isdigit(static_cast<unsigned char>(digits[1])) || digits[1] == '.'))
          digits.remove_prefix(1);
        double v = 0.0;
        const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), v,
                                               std::chars_format::general);
        if (ec == std::errc::result_out_of_range)
          v = std::strtod(text.c_str(), nullptr);  // a subnormal stays; an overflow is infinite
        if (end != digits.data() + digits.size() ||
            (ec != std::errc() && ec != std::errc::result_out_of_range) || !std::isfinite(v)) {
          fail(std::string(key == "v"    ? (f > 3 && fields.size() >= 7 ? "vertex colour component"
                                                                        : "vertex coordinate")
                           : key == "vn" ? "normal component"
                                         : "texture coordinate") +
               " '" + text + "' is not a finite number");
        }
      }
    } else if (key == "f") {
      if (fields.size() < 4) fail("a face needs at least 3 corners");
      triangles += int64_t(fields.size()) - 3;  // a polygon of n corners makes n - 2 triangles
      checkTriangleCount(triangles, path);
      scan.faceCorners.push_back(uint32_t(fields.size() - 1));
      scan.faceMaterial.push_back(material);
      for (size_t f = 1; f < fields.size(); ++f) {
        // v, v/vt, v//vn or v/vt/vn: integers, the first present and none zero.
        const std::string_view corner = fields[f];
        size_t start = 0;
        for (int part = 0; part < 3 && start <= corner.size(); ++part) {
          const size_t slash = std::min(corner.find('/', start), corner.size());
          const std::string_view number = corner.substr(start, slash - start);
          if (!(number.empty() && part > 0)) {
            long long value = 0;
            const auto [ptr, ec] =
                std::from_chars(number.data(), number.data() + number.size(), value);
            if (ec != std::errc() || ptr != number.data() + number.size() || value == 0 ||
                value > INT_MAX || value < -INT_MAX) {
              fail("face corner '" + std::string(corner) + "' is not a valid vertex reference");
            }
          }
          if (slash == corner.size()) break;
          start = slash + 1;
        }
      }
    } else if (key == "mtllib" && fields.size() > 1) {
      scan.materialLines.push_back(restOfLine(line, key));
    } else if (key == "usemtl") {
      const std::string name = restOfLine(line, key);
      if (name.empty()) {
        material = -1;
      } else {
        const auto [it, inserted] =
            materialIndex.try_emplace(name, int32_t(scan.materialNames.size()));
        if (inserted) scan.materialNames.push_back(name);
        material = it->second;
      }
    } else if (key == "s") {
      scan.smoothingGroups = true;
    } else if (key == "l" || key == "p") {
      ++scan.linesAndPoints;
    }
  }
  scan.rewrite = scan.rewrite || lines.joined();
  return scan;
}

// The file's lines as scanObj() read them, for tinyobjloader (ObjScan::rewrite).
std::string rewrittenObj(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("mesh", withSystemReason("cannot open", errno), path);
  skipByteOrderMark(in);
  ObjLines lines(*in.rdbuf());
  std::string text, line;
  while (lines.next(line)) (text += line) += '\n';
  return text;
}

// What a material library says about one material.
struct MtlMaterial {
  std::string name;
  fs::path library;  // the file that defines it
  bool hasKd = false;
  glm::vec3 kd{kDefaultAlbedo};
  std::string badKd;  // a Kd that is not a colour, as written (kd then stays the default)
  // map_Kd: the file as written, without its options; empty when there is none.
  std::string texture;
  glm::vec2 scale{1.0f}, offset{0.0f};  // -s and -o
  bool clamp = false;                   // -clamp on
  std::string textureProblem;           // map_Kd given but unusable (no file named), for a warning
  double opacity = 1.0;                 // d
  std::string opacityGiven;             // the d statement as written, for notes
  std::string trGiven;                  // a Tr between 0 and 1 as written (not read), for a note
  std::string alphaMap;                 // map_d's file as written, without its options
};

// A number as the MTL format writes one: decimal, the whole field, finite.
bool mtlNumber(std::string_view field, double& value) {
  const std::string text(field);
  char* end = nullptr;
  value = std::strtod(text.c_str(), &end);
  return !text.empty() && end == text.c_str() + text.size() && std::isfinite(value) &&
         text.find_first_of("xX") == std::string::npos;
}

// map_Kd's options, as the MTL format defines them, and its file: the rest of the line, spaces
// included. Unknown options are skipped with the numbers and on/off that follow them.
void parseTextureMap(const std::string& rest, MtlMaterial& m) {
  std::vector<std::pair<size_t, std::string_view>> fields;  // (offset in rest, field)
  for (size_t i = 0; i < rest.size();) {
    while (i < rest.size() && objSpace(rest[i])) ++i;
    size_t j = i;
    while (j < rest.size() && !objSpace(rest[j])) ++j;
    if (j > i) fields.emplace_back(i, std::string_view(rest).substr(i, j - i));
    i = j;
  }
  static const std::set<std::string_view> kOneValue = {
      "-blendu", "-blendv", "-cc", "-clamp", "-boost", "-texres", "-bm", "-imfchan", "-type"};
  size_t f = 0;
  double unused = 0.0;
  while (f < fields.size() && fields[f].second.size() > 1 && fields[f].second[0] == '-' &&
         !mtlNumber(fields[f].second, unused)) {
    const std::string_view option = fields[f++].second;
    if (kOneValue.count(option)) {
      if (f < fields.size()) {
        if (option == "-clamp") m.clamp = fields[f].second == "on";
        ++f;
      }
    } else if (option == "-mm") {
      f = std::min(fields.size(), f + 2);
    } else {
      // -o, -s, -t: one to three numbers (v and w may be left out); anything else: what
      // follows it that is a number or on/off.
      std::vector<double> numbers;
      double v = 0.0;
      while (f < fields.size() && numbers.size() < 3 &&
             (mtlNumber(fields[f].second, v) ||
              (option != "-o" && option != "-s" && option != "-t" &&
               (fields[f].second == "on" || fields[f].second == "off")))) {
        numbers.push_back(v);
        ++f;
      }
      if (option == "-s" && !numbers.empty())
        m.scale = glm::vec2(float(numbers[0]), float(numbers.size() > 1 ? numbers[1] : 1.0));
      if (option == "-o" && !numbers.empty())
        m.offset = glm::vec2(float(numbers[0]), float(numbers.size() > 1 ? numbers[1] : 0.0));
    }
  }
  if (f < fields.size()) {
    const size_t from = fields[f].first;
    m.texture = rest.substr(from, rest.find_last_not_of(" \t") + 1 - from);
  } else {
    m.textureProblem = "map_Kd names no file ('" + rest + "')";
  }
}

// An `mtllib` line's names as tinyobjloader reads them (split at spaces, a backslash taking the
// next character as it is, so that `mats\red.mtl` reaches the reader as `matsred.mtl`), each
// with the name as written (backslashes kept).
struct MtllibName {
  std::string asRead, written;
};
std::vector<MtllibName> mtllibNames(const std::string& s) {
  std::vector<MtllibName> out;
  MtllibName name;
  bool escaping = false;
  for (const char c : s) {
    if (!escaping && c == ' ') {
      if (!name.written.empty()) out.push_back(name);
      name = {};
      continue;
    }
    name.written += c;
    if (!escaping && c == '\\') {
      escaping = true;
      continue;
    }
    escaping = false;
    name.asRead += c;
  }
  if (!name.written.empty()) out.push_back(name);
  return out;
}

// Material libraries, found relative to the OBJ's folder (Windows separators accepted), read
// here (tinyobjloader's reading of MTL files keeps only the first word of a `usemtl` name and
// takes the file name of `map_Kd -s 2 2 wood.png` for a number). The ones that cannot be read are
// remembered for a warning instead of failing the load.
class MaterialLibraries : public tinyobj::MaterialReader {
 public:
  // `lines`: what follows each `mtllib` (ObjScan::materialLines).
  MaterialLibraries(fs::path folder, std::vector<std::string> lines)
      : folder_(std::move(folder)), lines_(std::move(lines)) {}
  bool operator()(const std::string& name, std::vector<tinyobj::material_t>*,
                  std::map<std::string, int>*, std::string*, std::string*) override {
    // tinyobjloader splits `mtllib My Chair.mtl` at the space and stops at the first library it
    // reads. Blender reads one file of that whole name when it exists, else every library the
    // line names; so does this, at the line's first word (later words ask again: nothing more).
    std::vector<std::string> files = {name};
    for (const std::string& whole : lines_) {
      const std::vector<MtllibName> names = mtllibNames(whole);
      if (std::none_of(names.begin(), names.end(),
                       [&](const MtllibName& n) { return n.asRead == name; }))
        continue;
      std::error_code ec;
      files.clear();
      if (fs::is_regular_file(folder_ / portable(whole), ec)) {
        files = {whole};
      } else {
        // As written (in `mats\red.mtl` the backslash is a Windows separator), else as
        // tinyobjloader unescapes it (`My\ Chair.mtl` is `My Chair.mtl`).
        for (const MtllibName& n : names)
          files.push_back(fs::is_regular_file(folder_ / portable(n.written), ec) ||
                                  !fs::is_regular_file(folder_ / n.asRead, ec)
                              ? n.written
                              : n.asRead);
      }
      if (!linesRead_.insert(whole).second) return true;  // read for an earlier word
      break;
    }
    bool any = false;
    for (const std::string& f : files) any = read(f) || any;
    return any;
  }

  std::vector<std::string> unreadable;
  std::vector<std::string> redefined;  // warnings: a name defined again (the first one holds)
  std::vector<fs::path> looked;        // every library file asked for
  std::vector<MtlMaterial> materials;  // the first definition of each name, in file order
  std::map<std::string, size_t, std::less<>> byName;

  // A name as written in a file, Windows separators made '/'.
  static std::string portable(std::string name) {
    std::replace(name.begin(), name.end(), '\\', '/');
    return name;
  }

 private:
  fs::path folder_;
  std::vector<std::string> lines_;
  std::set<std::string> linesRead_;
  std::set<fs::path> readFiles_;

  bool read(const std::string& name) {
    const fs::path file = folder_ / portable(name);
    // A library named again (another mtllib line) is read once.
    if (!readFiles_.insert(file.lexically_normal()).second) return true;
    looked.push_back(file);
    std::error_code ec;
    std::ifstream in;
    const fs::file_status status = fs::status(file, ec);
    // Regular files only: a device such as /dev/zero would never end.
    if (fs::is_regular_file(status)) in.open(file, std::ios::binary);
    if (!in.is_open()) {
      const std::string why = !fs::exists(status)            ? std::strerror(ENOENT)
                              : !fs::is_regular_file(status) ? "not a regular file"
                                                             : std::strerror(errno);
      unreadable.push_back("material library '" + name + "' cannot be read (" + why + ")");
      return false;
    }
    skipByteOrderMark(in);
    std::string line;
    MtlMaterial* current = nullptr;
    while (objLine(*in.rdbuf(), line)) {
      std::istringstream fields(line);
      std::string key;
      fields >> key;
      if (key == "newmtl") {
        const std::string material = restOfLine(line, key);
        current = nullptr;
        if (material.empty()) continue;
        if (const auto it = byName.find(material); it != byName.end()) {
          redefined.push_back("material '" + material + "' is defined again in " +
                              file.filename().string() + ": the first definition (" +
                              materials[it->second].library.filename().string() + ") is used");
          continue;
        }
        byName.emplace(material, materials.size());
        MtlMaterial defined;
        defined.name = material;
        defined.library = file;
        materials.push_back(std::move(defined));
        current = &materials.back();
      } else if (!current) {
        continue;
      } else if (key == "Kd") {
        // "Kd r" alone is a grey (the MTL format: g and b are r when not given); a comment may
        // follow the numbers.
        current->hasKd = true;
        std::string value, all;
        std::vector<double> numbers;
        bool finite = true;
        while (numbers.size() < 3 && fields >> value && value[0] != '#') {
          double v = 0.0;
          finite = mtlNumber(value, v) && finite;
          numbers.push_back(v);
          all += (all.empty() ? "" : " ") + value;
        }
        if (!finite || numbers.empty() || numbers.size() == 2) {
          current->badKd = all;
        } else {
          current->kd = numbers.size() == 1
                            ? glm::vec3(float(numbers[0]))
                            : glm::vec3(float(numbers[0]), float(numbers[1]), float(numbers[2]));
        }
      } else if (key == "map_Kd") {
        current->texture.clear();
        current->textureProblem.clear();
        current->scale = glm::vec2(1.0f);
        current->offset = glm::vec2(0.0f);
        current->clamp = false;
        parseTextureMap(restOfLine(line, key), *current);
      } else if (key == "d") {
        std::string value;
        double v = 1.0;
        if (!(fields >> value && mtlNumber(value, v))) continue;
        current->opacity = std::clamp(v, 0.0, 1.0);
        current->opacityGiven = key + " " + value;
      } else if (key == "Tr") {
        // Exporters disagree on Tr: the transparency (1 - d) for some, the opacity (d) for
        // others (OpenMVS, older MeshLab and mvs-texturing write Tr 1 on opaque materials):
        // not read. A value between 0 and 1 is said.
        std::string value;
        double v = 0.0;
        if (fields >> value && mtlNumber(value, v) && v > 0.0 && v < 1.0)
          current->trGiven = key + " " + value;
      } else if (key == "map_d") {
        MtlMaterial map;
        parseTextureMap(restOfLine(line, key), map);
        current->alphaMap = map.texture;
      }
    }
    return true;
  }
};

// Where map_Kd's file is: relative to its material library's folder (where the MTL format and
// Blender look), else to the OBJ's; else, for a path from another machine
// (C:\Users\me\wood.png), its name alone in either folder (`byName` is then set). When none
// exists, the first place looked, for the error.
fs::path locateTexture(const std::string& written, const fs::path& libraryFolder,
                       const fs::path& objFolder, bool& byName) {
  byName = false;
  const fs::path relative = MaterialLibraries::portable(written);
  std::vector<fs::path> places = {libraryFolder / relative};
  if (objFolder != libraryFolder && !relative.is_absolute()) places.push_back(objFolder / relative);
  std::error_code ec;
  for (const fs::path& p : places)
    if (fs::is_regular_file(p, ec)) return p;
  if (relative.has_filename() && relative.filename() != relative) {
    for (const fs::path& folder : {libraryFolder, objFolder}) {
      const fs::path p = folder / relative.filename();
      if (fs::is_regular_file(p, ec)) {
        byName = true;
        return p;
      }
    }
  }
  return places.front();
}

// (position, texture coordinate, normal) indices of a face corner, -1 where absent.
struct CornerKey {
  int v, vt, vn;
  bool operator==(const CornerKey&) const = default;
};
struct CornerHash {
  size_t operator()(const CornerKey& k) const {
    return (size_t(uint32_t(k.v)) * 0x9E3779B97F4A7C15ull) ^
           (size_t(uint32_t(k.vt)) * 0xC2B2AE3D27D4EB4Full) ^ size_t(uint32_t(k.vn));
  }
};

}  // namespace

LoadedMesh loadObj(const fs::path& path) {
  const ObjScan scan = scanObj(path);
  std::ifstream objFile;
  std::istringstream rewritten;
  std::istream* in = &objFile;
  if (scan.rewrite) {
    rewritten.str(rewrittenObj(path));
    in = &rewritten;
  } else {
    objFile.open(path, std::ios::binary);
    if (!objFile) throw Error("mesh", withSystemReason("cannot open", errno), path);
  }
  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> objMaterials;
  std::string warn, err;
  MaterialLibraries libraries(path.parent_path(), scan.materialLines);
  // Polygons are triangulated below, in their own plane (tinyobjloader's fans and
  // shorter-diagonal quads can leave a concave polygon's outline).
  // Colours on some vertices only: the others white (tinyobjloader's fallback), where it would
  // drop them all; said below.
  const bool partialColours = scan.colouredVertices > 0 && scan.colouredVertices < scan.vertices;
  if (!tinyobj::LoadObj(&attrib, &shapes, &objMaterials, &warn, &err, in, &libraries,
                        /*triangulate=*/false, /*default_vcols_fallback=*/partialColours)) {
    while (!err.empty() && (err.back() == '\n' || err.back() == '\r')) err.pop_back();
    throw Error("mesh", "cannot parse OBJ: " + (err.empty() ? std::string("unknown reason") : err),
                path);
  }
  const size_t vertexCount = attrib.vertices.size() / 3;
  const size_t normalCount = attrib.normals.size() / 3;
  const size_t texcoordCount = attrib.texcoords.size() / 2;

  LoadedMesh loaded;
  Mesh& mesh = loaded.mesh;
  for (const std::string& w : libraries.unreadable)
    mesh.warnings.push_back(w + ": its materials render with the default albedo");
  // Vertex colours (`v x y z r g b`, as MeshLab and Blender write them: sRGB-encoded, 0..1),
  // decoded to linear; a colour outside 0..1 or not finite is clamped and counted.
  std::vector<glm::vec3> colours;
  if (!attrib.colors.empty() && attrib.colors.size() == attrib.vertices.size()) {
    colours.resize(vertexCount);
    size_t clamped = 0;
    for (size_t v = 0; v < vertexCount; ++v) {
      for (int c = 0; c < 3; ++c) {
        const double e = double(attrib.colors[3 * v + size_t(c)]);
        const double inRange = std::isfinite(e) ? std::clamp(e, 0.0, 1.0) : 0.0;
        if (inRange != e) ++clamped;
        colours[v][c] = float(srgbDecode(inRange));
      }
    }
    if (clamped > 0)
      mesh.warnings.push_back(
          count(clamped, "vertex colour component", "vertex colour components") +
          " outside 0..1 (or not finite) clamped");
    if (partialColours)
      mesh.warnings.push_back(std::to_string(scan.colouredVertices) + " of " +
                              std::to_string(scan.vertices) +
                              " vertices have a colour (v x y z r g b): the others are white");
  }
  mesh.otherFiles = libraries.looked;

  // Materials in the order faces first use them; -1 (no material, or a name no library
  // defines) becomes a default grey when other faces have materials.
  std::map<int, uint32_t> materialIndex;
  std::vector<int> usedMaterials;
  auto materialOf = [&](int id) {
    if (id < 0 || size_t(id) >= libraries.materials.size()) id = -1;
    const auto [it, inserted] = materialIndex.try_emplace(id, uint32_t(usedMaterials.size()));
    if (inserted) usedMaterials.push_back(id);
    return it->second;
  };

  // A mesh far from its file's origin (a scene exported in place, georeferenced): float
  // positions there are coarse on the object's scale (a 1-unit sphere 5000 units out rounds to
  // 0.0005, enough for its shadows to speckle). The file is parsed in double and the mesh moved
  // to its own middle before its positions are rounded to float, as for glTF.
  // The box of the vertices faces use: a point, a line or a loose vertex elsewhere (at the
  // origin, as CAD exports leave them) kept a far mesh from being moved, and it rendered as
  // float rounding left it (a 0.2-unit cube at 5e6 lost 8 of its 12 triangles).
  {
    std::vector<uint8_t> used(vertexCount, 0);
    for (const tinyobj::shape_t& shape : shapes)
      for (const tinyobj::index_t& idx : shape.mesh.indices)
        if (idx.vertex_index >= 0 && size_t(idx.vertex_index) < vertexCount)
          used[size_t(idx.vertex_index)] = 1;
    glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
    for (size_t v = 0; v < vertexCount; ++v) {
      if (!used[v]) continue;
      const glm::dvec3 p(attrib.vertices[3 * v], attrib.vertices[3 * v + 1],
                         attrib.vertices[3 * v + 2]);
      if (!std::isfinite(p.x + p.y + p.z)) continue;
      lo = glm::min(lo, p);
      hi = glm::max(hi, p);
    }
    const glm::dvec3 middle = 0.5 * (lo + hi);
    const double size = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
    const double far = std::max({std::abs(middle.x), std::abs(middle.y), std::abs(middle.z)});
    if (lo.x <= hi.x && size > 0.0 && far > 100.0 * size) {
      mesh.fileOrigin = middle;
      char line[240];
      std::snprintf(line, sizeof line,
                    "the mesh lies %.4g units from its file's origin (%.4g times its size): moved "
                    "to its own middle before rounding its positions to float "
                    "(compose:worldFromObject still maps the file's coordinates)",
                    far, far / size);
      mesh.warnings.push_back(line);
    }
  }

  std::unordered_map<CornerKey, uint32_t, CornerHash> vertexOf;
  auto vertex = [&](const CornerKey& key) {
    const auto [it, inserted] = vertexOf.try_emplace(key, uint32_t(mesh.positions.size()));
    if (inserted) {
      const tinyobj::real_t* p = &attrib.vertices[3 * size_t(key.v)];
      mesh.positions.emplace_back(glm::dvec3(p[0], p[1], p[2]) - mesh.fileOrigin);
      if (key.vn >= 0) {
        const tinyobj::real_t* n = &attrib.normals[3 * size_t(key.vn)];
        mesh.normals.emplace_back(float(n[0]), float(n[1]), float(n[2]));
      } else {
        mesh.normals.emplace_back(0.0f);
      }
      loaded.hasNormal.push_back(key.vn >= 0 ? 1 : 0);
      if (!colours.empty()) mesh.colors.push_back(colours[size_t(key.v)]);
      if (key.vt >= 0) {
        const tinyobj::real_t* t = &attrib.texcoords[2 * size_t(key.vt)];
        mesh.texcoords.emplace_back(float(t[0]), float(t[1]));
      } else {
        mesh.texcoords.emplace_back(0.0f);
      }
    }
    return it->second;
  };

  // Each `usemtl` name's material (-1: no library defines it), and the faces that named it then.
  std::vector<int> materialOfName;
  for (const std::string& name : scan.materialNames) {
    const auto it = libraries.byName.find(name);
    materialOfName.push_back(it == libraries.byName.end() ? -1 : int(it->second));
  }
  std::vector<size_t> undefinedFaces(scan.materialNames.size(), 0);

  size_t faces = 0, outOfRange = 0, noMaterial = 0;
  std::vector<uint32_t> polygon;
  std::vector<glm::vec3> corners;
  size_t fileFace = 0;
  for (const tinyobj::shape_t& shape : shapes) {
    const tinyobj::mesh_t& m = shape.mesh;
    size_t offset = 0;
    for (size_t f = 0; f < m.num_face_vertices.size(); ++f, ++fileFace) {
      // tinyobjloader counts a face's corners modulo 256; its indices are all there.
      size_t n = m.num_face_vertices[f];
      if (fileFace < scan.faceCorners.size() && scan.faceCorners[fileFace] % 256 == n)
        n = scan.faceCorners[fileFace];
      else
        throw Error("mesh", "the OBJ parser's faces do not match the file's", path);
      const size_t first = offset;
      offset += n;
      ++faces;
      bool valid = n >= 3 && offset <= m.indices.size();
      for (size_t k = first; valid && k < offset; ++k) {
        const tinyobj::index_t& idx = m.indices[k];
        valid = idx.vertex_index >= 0 && size_t(idx.vertex_index) < vertexCount &&
                idx.normal_index < int(std::min<size_t>(normalCount, INT_MAX)) &&
                idx.texcoord_index < int(std::min<size_t>(texcoordCount, INT_MAX)) &&
                idx.normal_index >= -1 && idx.texcoord_index >= -1;
      }
      if (!valid) {
        ++outOfRange;
        continue;
      }
      polygon.clear();
      corners.clear();
      for (size_t k = first; k < offset; ++k) {
        const tinyobj::index_t& idx = m.indices[k];
        polygon.push_back(vertex({idx.vertex_index, idx.texcoord_index, idx.normal_index}));
        corners.push_back(mesh.positions[polygon.back()]);
      }
      // The face's material by the whole name its `usemtl` gave (ObjScan::faceMaterial).
      const int32_t named = scan.faceMaterial[fileFace];
      const int objMaterial = named < 0 ? -1 : materialOfName[size_t(named)];
      if (named >= 0 && objMaterial < 0) ++undefinedFaces[size_t(named)];
      const uint32_t material = materialOf(objMaterial);
      const uint32_t group = f < m.smoothing_group_ids.size() ? m.smoothing_group_ids[f] : 0;
      for (uint32_t c : triangulatePolygon(corners)) mesh.indices.push_back(polygon[c]);
      const size_t triangles = n - 2;
      mesh.triangleMaterial.insert(mesh.triangleMaterial.end(), triangles, material);
      loaded.smoothingGroup.insert(loaded.smoothingGroup.end(), triangles, group);
      if (usedMaterials[material] < 0) noMaterial += 1;
    }
  }
  if (outOfRange) {
    const std::string what =
        "dropped " +
        (faces == 1 ? std::string("the one face")
                    : std::to_string(outOfRange) + " of " + std::to_string(faces) + " faces") +
        " referring to vertices, texture coordinates or normals the "
        "file does not have (it has " +
        count(vertexCount, "vertex", "vertices") + ", " +
        count(texcoordCount, "texture coordinate", "texture coordinates") + ", " +
        count(normalCount, "normal", "normals") + ")";
    if (outOfRange == faces) throw Error("mesh", "nothing renderable: " + what, path);
    mesh.warnings.push_back(what);
  }
  if (scan.linesAndPoints) {
    mesh.warnings.push_back(
        "ignored " +
        count(scan.linesAndPoints, "line or point element", "line and point elements") +
        " (only faces render)");
  }
  if (!scan.smoothingGroups) loaded.smoothingGroup.clear();

  // Materials: Kd is the base colour, map_Kd its texture (read once per file).
  for (const std::string& w : libraries.redefined) mesh.warnings.push_back(w);
  // Names no library defines (with an unreadable library, its warning says it already).
  std::string undefined;
  size_t undefinedCount = 0, undefinedNames = 0;
  for (size_t k = 0; k < undefinedFaces.size(); ++k) {
    if (undefinedFaces[k] == 0) continue;
    undefinedCount += undefinedFaces[k];
    if (++undefinedNames <= 3)
      undefined += (undefined.empty() ? "'" : ", '") + scan.materialNames[k] + "'";
  }
  if (undefinedNames > 3) undefined += " and " + std::to_string(undefinedNames - 3) + " more";
  const std::string faceColour = colours.empty() ? "the default albedo" : "their vertex colours";
  if (undefinedCount > 0 && libraries.unreadable.empty()) {
    mesh.warnings.push_back(count(undefinedCount, "face uses", "faces use") + " " +
                            (undefinedNames == 1 ? "material " : "materials ") + undefined +
                            ", which no material library defines: rendered with " + faceColour);
  }
  const bool anyMaterial =
      std::any_of(usedMaterials.begin(), usedMaterials.end(), [](int id) { return id >= 0; });
  if (anyMaterial) {
    if (noMaterial > undefinedCount || (noMaterial > 0 && !libraries.unreadable.empty())) {
      const size_t none = libraries.unreadable.empty() ? noMaterial - undefinedCount : noMaterial;
      mesh.warnings.push_back(count(none, "face has", "faces have") +
                              " no material: rendered with " + faceColour);
    }
    // A texture per file, wrap mode and use of its alpha: two materials may use one file, one
    // clamped (-clamp on) and one repeated, one cut by its alpha (map_d) and one not.
    std::map<std::tuple<fs::path, bool, bool>, int> textureOf;  // (file, clamped, with alpha)
    std::set<fs::path> listed;                                  // in mesh.otherFiles
    for (int id : usedMaterials) {
      Material material;
      if (id < 0) {
        // With vertex colours, glTF's default (white): the colours are the albedo.
        material.name = colours.empty() ? "(default)" : "(default: the vertex colours)";
        material.baseColor = glm::vec3(colours.empty() ? kDefaultAlbedo : 1.0f);
        mesh.materials.push_back(material);
        continue;
      }
      const MtlMaterial& om = libraries.materials[size_t(id)];
      material.name = om.name;
      // No Kd (Blender writes none with a map_Kd), or one that is not a colour: the texture
      // alone, or the default grey.
      const bool ownColour = om.hasKd && om.badKd.empty();
      material.baseColor =
          ownColour ? om.kd : glm::vec3(om.texture.empty() ? kDefaultAlbedo : 1.0f);
      if (!om.badKd.empty()) {
        mesh.warnings.push_back(
            "material '" + om.name + "' has a Kd that is not a colour ('" + om.badKd +
            "'): " + (om.texture.empty() ? "using the default grey" : "its texture alone"));
      }
      if (!om.textureProblem.empty()) {
        mesh.warnings.push_back("material '" + om.name + "': " + om.textureProblem +
                                ": the material renders with " +
                                (ownColour ? "its Kd" : "the default albedo"));
      }
      // See-through (glTF's BLEND): by d, and by map_Kd's own alpha where map_d names map_Kd's
      // file.
      // d 0 is taken for an exporter's mistake (as obj2gltf takes it): an object that hides
      // nothing is not what anyone composites.
      material.baseAlpha = om.opacity > 0.0 ? float(om.opacity) : 1.0f;
      material.blend = material.baseAlpha < 1.0f;
      if (!om.trGiven.empty() && om.opacityGiven.empty()) {
        mesh.warnings.push_back("material '" + om.name + "': '" + om.trGiven +
                                "' is not read (exporters disagree on whether Tr is the "
                                "transparency or the opacity): it renders opaque; give d, the "
                                "opacity");
      }
      if (om.opacity <= 0.0) {
        mesh.warnings.push_back("material '" + om.name + "' says it is fully transparent ('" +
                                om.opacityGiven +
                                "'), most often an exporter's mistake: rendered opaque");
      }
      if (!om.alphaMap.empty() && om.texture.empty()) {
        mesh.warnings.push_back("material '" + om.name + "': its map_d '" + om.alphaMap +
                                "' is not read (a map_d is read from map_Kd's file, by its alpha "
                                "channel, and this material has no map_Kd)");
      }
      if (!om.texture.empty()) {
        bool byName = false;
        const fs::path file =
            locateTexture(om.texture, om.library.parent_path(), path.parent_path(), byName);
        const bool clamp = om.clamp;
        // The texture's alpha channel is its opacity only where map_d names map_Kd's file: read
        // then alone (a semi-transparent material by d is not cut by its texture's alpha).
        bool alphaByName = false;
        const fs::path alphaFile = om.alphaMap.empty()
                                       ? fs::path()
                                       : locateTexture(om.alphaMap, om.library.parent_path(),
                                                       path.parent_path(), alphaByName);
        const bool withAlpha = !om.alphaMap.empty() && alphaFile == file;
        auto [it, inserted] = textureOf.try_emplace({file, clamp, withAlpha}, -1);
        if (byName) {
          mesh.warnings.push_back("texture '" + om.texture + "' of material '" + om.name +
                                  "' is not where its library says: read " + file.string() +
                                  ", the file of that name beside the library or the OBJ");
        }
        if (inserted) {
          if (listed.insert(file).second) mesh.otherFiles.push_back(file);
          try {
            Texture texture;
            texture.file = file;
            texture.image = readTextureFile(file, "", withAlpha ? &texture.alpha : nullptr);
            if (clamp) texture.wrapU = texture.wrapV = Texture::Wrap::Clamp;
            it->second = int(mesh.textures.size());
            mesh.textures.push_back(std::move(texture));
          } catch (const Error& e) {
            mesh.warnings.push_back("texture '" + om.texture + "' of material '" + om.name +
                                    "' cannot be read (" + e.what() +
                                    "): the material renders with " +
                                    (ownColour ? "its Kd" : "the default albedo"));
          }
        }
        material.texture = it->second;
        if (material.texture < 0 && !ownColour) material.baseColor = glm::vec3(kDefaultAlbedo);
        if (!om.alphaMap.empty() && material.texture >= 0) {
          if (withAlpha && !mesh.textures[size_t(material.texture)].alpha.empty()) {
            material.blend = true;
          } else {
            mesh.warnings.push_back(
                "material '" + om.name + "': its map_d '" + om.alphaMap + "' is not read (" +
                (withAlpha ? "map_Kd's file has no alpha channel"
                           : "it is not map_Kd's file, whose alpha channel is read") +
                "): the texture is opaque");
          }
        }
        if (material.texture >= 0 && ownColour && material.baseColor != glm::vec3(1.0f)) {
          char kd[96];
          std::snprintf(kd, sizeof kd, "%g %g %g", double(material.baseColor.x),
                        double(material.baseColor.y), double(material.baseColor.z));
          mesh.warnings.push_back("material '" + om.name + "': its Kd (" + kd +
                                  ") multiplies its map_Kd, as the MTL format says (Blender, Maya "
                                  "and 3ds Max show the texture alone; Kd 1 1 1 does that here)");
        }
        // map_Kd -s and -o: uv' = uv * scale + offset.
        material.uvTransform = glm::mat3(om.scale.x, 0.0f, 0.0f, 0.0f, om.scale.y, 0.0f,
                                         om.offset.x, om.offset.y, 1.0f);
      }
      mesh.materials.push_back(material);
    }
  } else {
    mesh.triangleMaterial.clear();
  }
  return loaded;
}

}  // namespace compose::render::detail
