#include "pipeline/stage_util.h"

#include <cerrno>
#include <cstring>
#include <fstream>
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
  if (in.channels == 3) return in;
  Image out(in.width, in.height, 3, {"R", "G", "B"});
  out.colorSpace = in.colorSpace;
  for (size_t i = 0; i < in.pixelCount(); ++i) {
    const float* s = in.pixels.data() + i * size_t(in.channels);
    float* d = out.pixels.data() + i * 3;
    if (in.channels < 3) {
      d[0] = d[1] = d[2] = s[0];
    } else {
      d[0] = s[0];
      d[1] = s[1];
      d[2] = s[2];
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
