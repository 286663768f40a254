#include "pipeline/stage_util.h"

#include <cctype>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <map>
#include <vector>

#include "core/error.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "pipeline/stage.h"

namespace compose::pipeline {

namespace {

void hashBytes(Hash128& hash, const std::filesystem::path& file, const std::string& stage,
               bool withName) {
  protectInput(file);
  std::error_code ec;
  if (!std::filesystem::exists(file, ec)) throw Error(stage, "file not found", file);
  if (std::filesystem::is_directory(file, ec)) throw Error(stage, "is a folder, not a file", file);
  requireRegularFile(file, stage);
  std::ifstream in(file, std::ios::binary);
  if (!in) {
    const int error = errno;
    throw Error(stage, std::string("cannot read: ") + std::strerror(error), file);
  }
  if (withName) hash.bytes(file.filename().string());
  std::vector<char> buffer(size_t(1) << 20);
  while (in) {
    in.read(buffer.data(), std::streamsize(buffer.size()));
    const std::streamsize n = in.gcount();
    if (n > 0) hash.data(buffer.data(), size_t(n));
  }
  if (in.bad()) throw Error(stage, "read error", file);
}

}  // namespace

void hashFile(Hash128& hash, const std::filesystem::path& file, const std::string& stage) {
  hashBytes(hash, file, stage, true);
}

std::string contentKey(const std::filesystem::path& file, const std::string& stage) {
  Hash128 hash;
  hashBytes(hash, file, stage, false);
  return hash.hex();
}

Image toRgb(const Image& in) {
  // The channels by name (the last part of a layered name: "diffuse.R" is R): R, G, B in that
  // order wherever they are; else Y alone as grey, or Y with OpenEXR's chroma RY, BY; else by
  // position, as an image without names has them.
  std::map<std::string, int> named;
  for (int c = 0; c < int(in.channelNames.size()) && c < in.channels; ++c) {
    std::string n = in.channelNames[size_t(c)];
    n = n.substr(n.rfind('.') == std::string::npos ? 0 : n.rfind('.') + 1);
    for (char& ch : n) ch = char(std::toupper(static_cast<unsigned char>(ch)));
    named.emplace(n, c);
  }
  auto at = [&](const char* n) {
    const auto it = named.find(n);
    return it == named.end() ? -1 : it->second;
  };
  const int r = at("R"), g = at("G"), b = at("B"), y = at("Y"), ry = at("RY"), by = at("BY");
  const bool rgb = r >= 0 && g >= 0 && b >= 0;
  const bool chroma = !rgb && y >= 0 && ry >= 0 && by >= 0;
  if (in.channels == 3 && ((rgb && r == 0 && g == 1 && b == 2) || (!rgb && !chroma && y < 0)))
    return in;
  Image out(in.width, in.height, 3, {"R", "G", "B"});
  out.colorSpace = in.colorSpace;
  const int n = in.channels;
  // OpenEXR's luminance weights without a chromaticities attribute (Rec. ITU-R BT.709).
  constexpr float kWr = 0.2126f, kWg = 0.7152f, kWb = 0.0722f;
  for (size_t i = 0; i < in.pixelCount(); ++i) {
    const float* s = in.pixels.data() + i * size_t(n);
    float* d = out.pixels.data() + i * 3;
    if (rgb) {
      d[0] = s[r], d[1] = s[g], d[2] = s[b];
    } else if (chroma) {
      d[0] = s[y] * (1.0f + s[ry]);
      d[2] = s[y] * (1.0f + s[by]);
      d[1] = (s[y] - kWr * d[0] - kWb * d[2]) / kWg;
    } else if (y >= 0) {
      d[0] = d[1] = d[2] = s[y];
    } else if (n < 3) {
      d[0] = d[1] = d[2] = s[0];
    } else {
      d[0] = s[0], d[1] = s[1], d[2] = s[2];
    }
  }
  return out;
}

StageParameter pathParameter(std::string name, std::string help,
                             std::filesystem::path ComposeJob::*member) {
  StageParameter p{
      name, std::move(help),
      [member](const ComposeJob& job) { return nlohmann::json((job.*member).string()); },
      [member, name](ComposeJob& job, const nlohmann::json& value) {
        if (!value.is_string()) throw UsageError(name + " must be a path (a string)");
        job.*member = value.get<std::string>();
      }};
  p.isPath = true;
  return p;
}

StageParameter textParameter(std::string name, std::string help, std::string ComposeJob::*member) {
  return {name, std::move(help),
          [member](const ComposeJob& job) { return nlohmann::json(job.*member); },
          [member, name](ComposeJob& job, const nlohmann::json& value) {
            if (!value.is_string()) throw UsageError(name + " must be a string");
            job.*member = value.get<std::string>();
          }};
}

}  // namespace compose::pipeline
