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
  bool smoothingGroups = false;  // an `s` statement
  size_t linesAndPoints = 0;     // `l` and `p` elements (not rendered)
  // What follows each `mtllib`, whole: one file whose name has spaces, or several names.
  std::vector<std::string> materialLines;
  // Each face's number of corners, in the file's order (tinyobjloader keeps them in 8 bits).
  std::vector<uint32_t> faceCorners;
};

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

// tinyobjloader reads a malformed number ("nan", "inf", "abc") as 0 without saying so, and an
// index beyond int's range wraps around. This pass over the text finds them first and names the
// line: every field of v, vn and vt must be a finite number, and every corner of f an integer
// reference within int's range.
ObjScan scanObj(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("mesh", withSystemReason("cannot open", errno), path);
  ObjScan scan;
  std::string line;
  size_t lineNo = 0;
  auto fail = [&](const std::string& what) {
    throw Error("mesh", "line " + std::to_string(lineNo) + ": " + what, path);
  };
  std::vector<std::string_view> fields;
  int64_t triangles = 0;
  while (objLine(*in.rdbuf(), line)) {
    ++lineNo;
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
    } else if (key == "mtllib" && fields.size() > 2) {
      const size_t from = size_t(fields[1].data() - line.data());
      const size_t to = size_t(fields.back().data() + fields.back().size() - line.data());
      scan.materialLines.push_back(line.substr(from, to - from));
    } else if (key == "s") {
      scan.smoothingGroups = true;
    } else if (key == "l" || key == "p") {
      ++scan.linesAndPoints;
    }
  }
  return scan;
}

// Material libraries, found relative to the OBJ's folder (Windows separators accepted); the ones
// that cannot be read are remembered for a warning instead of failing the load.
class MaterialLibraries : public tinyobj::MaterialReader {
 public:
  // `wholeLines`: what follows each `mtllib` of more than one word (ObjScan::materialLines).
  MaterialLibraries(fs::path folder, std::vector<std::string> wholeLines)
      : folder_(std::move(folder)), wholeLines_(std::move(wholeLines)) {}
  bool operator()(const std::string& name, std::vector<tinyobj::material_t>* materials,
                  std::map<std::string, int>* names, std::string* warn, std::string* err) override {
    // tinyobjloader splits `mtllib My Chair.mtl` at the space and stops at the first library it
    // reads. Blender reads one file of that whole name when it exists, else every library the
    // line names; so does this, at the line's first word (later words ask again: nothing more).
    std::vector<std::string> files = {name};
    for (const std::string& whole : wholeLines_) {
      std::istringstream split(whole);
      std::vector<std::string> words;
      for (std::string w; split >> w;) words.push_back(w);
      if (std::find(words.begin(), words.end(), name) == words.end()) continue;
      std::error_code ec;
      files = fs::is_regular_file(folder_ / whole, ec) ? std::vector<std::string>{whole} : words;
      if (!linesRead_.insert(whole).second) return true;  // read for an earlier word
      break;
    }
    bool any = false;
    for (const std::string& f : files) any = read(f, materials, names, warn, err) || any;
    return any;
  }
  std::vector<std::string> unreadable;
  std::vector<fs::path> looked;  // every library file asked for
  std::set<std::string> withKd;  // materials that give Kd
  // Materials whose Kd holds something that is not a finite number (tinyobjloader reads "nan"
  // as 0), with the Kd line as written.
  std::map<std::string, std::string> badKd;
  std::map<std::string, double> greyKd;  // materials whose Kd gives one number: r = g = b

 private:
  fs::path folder_;
  std::vector<std::string> wholeLines_;
  std::set<std::string> linesRead_;

  bool read(const std::string& name, std::vector<tinyobj::material_t>* materials,
            std::map<std::string, int>* names, std::string* warn, std::string* err) {
    std::string relative = name;
    std::replace(relative.begin(), relative.end(), '\\', '/');
    const fs::path file = folder_ / relative;
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
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    // tinyobjloader gives a material without Kd a black one: remember which have it.
    std::istringstream lines(text);
    std::string line, current;
    while (objLine(*lines.rdbuf(), line)) {
      std::istringstream fields(line);
      std::string key;
      fields >> key;
      if (key == "newmtl") {
        std::getline(fields >> std::ws, current);
        while (!current.empty() && std::isspace(static_cast<unsigned char>(current.back())))
          current.pop_back();
      } else if (key == "Kd") {
        withKd.insert(current);
        // Up to three numbers, as tinyobjloader reads them; a comment may follow.
        std::string value, all;
        std::vector<double> numbers;
        bool finite = true;
        while (numbers.size() < 3 && fields >> value && value[0] != '#') {
          char* end = nullptr;
          const double v = std::strtod(value.c_str(), &end);
          finite = finite && end != value.c_str() && *end == '\0' && std::isfinite(v) &&
                   value.find_first_of("xX") == std::string::npos;
          numbers.push_back(v);
          all += (all.empty() ? "" : " ") + value;
        }
        if (!finite || numbers.empty()) badKd[current] = all;
        // "Kd r" alone is a grey (the MTL format: g and b are r when not given).
        else if (numbers.size() == 1)
          greyKd[current] = numbers[0];
      }
    }
    std::istringstream stream(text);
    tinyobj::LoadMtl(names, materials, &stream, warn, err);
    return true;
  }
};

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
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("mesh", withSystemReason("cannot open", errno), path);
  tinyobj::attrib_t attrib;
  std::vector<tinyobj::shape_t> shapes;
  std::vector<tinyobj::material_t> objMaterials;
  std::string warn, err;
  MaterialLibraries libraries(path.parent_path(), scan.materialLines);
  // Polygons are triangulated below, in their own plane (tinyobjloader's fans and
  // shorter-diagonal quads can leave a concave polygon's outline).
  if (!tinyobj::LoadObj(&attrib, &shapes, &objMaterials, &warn, &err, &in, &libraries,
                        /*triangulate=*/false, /*default_vcols_fallback=*/false)) {
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
  }
  mesh.otherFiles = libraries.looked;

  // Materials in the order faces first use them; -1 (no material, or a name no library
  // defines) becomes a default grey when other faces have materials.
  std::map<int, uint32_t> materialIndex;
  std::vector<int> usedMaterials;
  auto materialOf = [&](int id) {
    if (id < 0 || size_t(id) >= objMaterials.size()) id = -1;
    const auto [it, inserted] = materialIndex.try_emplace(id, uint32_t(usedMaterials.size()));
    if (inserted) usedMaterials.push_back(id);
    return it->second;
  };

  // A mesh far from its file's origin (a scene exported in place, georeferenced): float
  // positions there are coarse on the object's scale (a 1-unit sphere 5000 units out rounds to
  // 0.0005, enough for its shadows to speckle). The file is parsed in double and the mesh moved
  // to its own middle before its positions are rounded to float, as for glTF.
  {
    glm::dvec3 lo(std::numeric_limits<double>::max()), hi(-std::numeric_limits<double>::max());
    for (size_t v = 0; v < vertexCount; ++v) {
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
      const int objMaterial = f < m.material_ids.size() ? m.material_ids[f] : -1;
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
  const bool anyMaterial =
      std::any_of(usedMaterials.begin(), usedMaterials.end(), [](int id) { return id >= 0; });
  if (anyMaterial) {
    if (noMaterial) {
      mesh.warnings.push_back(count(noMaterial, "face has", "faces have") +
                              " no material (or one no material library defines): rendered "
                              "with " +
                              (colours.empty() ? "the default albedo" : "their vertex colours"));
    }
    // A texture per file and wrap mode: two materials may use one file, one clamped (-clamp on)
    // and one repeated.
    std::map<std::pair<fs::path, bool>, int> textureOf;
    for (int id : usedMaterials) {
      Material material;
      if (id < 0) {
        // With vertex colours, glTF's default (white): the colours are the albedo.
        material.name = colours.empty() ? "(default)" : "(default: the vertex colours)";
        material.baseColor = glm::vec3(colours.empty() ? kDefaultAlbedo : 1.0f);
        mesh.materials.push_back(material);
        continue;
      }
      const tinyobj::material_t& om = objMaterials[size_t(id)];
      material.name = om.name;
      material.baseColor =
          glm::vec3(float(om.diffuse[0]), float(om.diffuse[1]), float(om.diffuse[2]));
      if (!libraries.withKd.count(om.name)) {
        // No Kd: the texture alone, or the default grey.
        material.baseColor = glm::vec3(om.diffuse_texname.empty() ? kDefaultAlbedo : 1.0f);
      }
      if (const auto grey = libraries.greyKd.find(om.name); grey != libraries.greyKd.end())
        material.baseColor = glm::vec3(float(grey->second));
      if (const auto bad = libraries.badKd.find(om.name); bad != libraries.badKd.end()) {
        // As if there were no Kd: the texture alone, or the default grey.
        mesh.warnings.push_back(
            "material '" + om.name + "' has a Kd that is not a colour ('" + bad->second +
            "'): " + (om.diffuse_texname.empty() ? "using the default grey" : "its texture alone"));
        material.baseColor = glm::vec3(om.diffuse_texname.empty() ? kDefaultAlbedo : 1.0f);
      } else if (!std::isfinite(material.baseColor.x + material.baseColor.y +
                                material.baseColor.z)) {
        mesh.warnings.push_back("material '" + om.name +
                                "' has a non-finite Kd: using the default");
        material.baseColor = glm::vec3(kDefaultAlbedo);
      }
      if (!om.diffuse_texname.empty()) {
        std::string relative = om.diffuse_texname;
        std::replace(relative.begin(), relative.end(), '\\', '/');
        const fs::path file = path.parent_path() / relative;
        const bool clamp = om.diffuse_texopt.clamp;
        auto [it, inserted] = textureOf.try_emplace({file, clamp}, -1);
        if (inserted) {
          if (!textureOf.count({file, !clamp})) mesh.otherFiles.push_back(file);
          try {
            Texture texture;
            texture.file = file;
            texture.image = readTextureFile(file, "");
            if (clamp) texture.wrapU = texture.wrapV = Texture::Wrap::Clamp;
            it->second = int(mesh.textures.size());
            mesh.textures.push_back(std::move(texture));
          } catch (const Error& e) {
            mesh.warnings.push_back("texture '" + om.diffuse_texname + "' of material '" + om.name +
                                    "' cannot be read (" + e.what() +
                                    "): the material renders with its Kd");
          }
        }
        material.texture = it->second;
        if (material.texture >= 0 && libraries.withKd.count(om.name) &&
            material.baseColor != glm::vec3(1.0f)) {
          char kd[96];
          std::snprintf(kd, sizeof kd, "%g %g %g", double(material.baseColor.x),
                        double(material.baseColor.y), double(material.baseColor.z));
          mesh.warnings.push_back("material '" + om.name + "': its Kd (" + kd +
                                  ") multiplies its map_Kd, as the MTL format says (Blender, Maya "
                                  "and 3ds Max show the texture alone; Kd 1 1 1 does that here)");
        }
        // map_Kd -s and -o: uv' = uv * scale + offset.
        const tinyobj::texture_option_t& o = om.diffuse_texopt;
        material.uvTransform =
            glm::mat3(float(o.scale[0]), 0.0f, 0.0f, 0.0f, float(o.scale[1]), 0.0f,
                      float(o.origin_offset[0]), float(o.origin_offset[1]), 1.0f);
      }
      mesh.materials.push_back(material);
    }
  } else {
    mesh.triangleMaterial.clear();
  }
  return loaded;
}

}  // namespace compose::render::detail
