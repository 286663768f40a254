#include "pipeline/scene.h"

#include <fstream>
#include <sstream>

#include "core/error.h"
#include "core/json_keys.h"
#include "core/json_number.h"
#include "core/limits.h"
#include "core/output_files.h"
#include "pipeline/stage.h"

namespace compose::pipeline {

namespace fs = std::filesystem;

namespace {

std::string namesOf(const std::vector<StageParameter>& parameters) {
  std::string s;
  for (const auto& p : parameters) s += (s.empty() ? "" : ", ") + p.name;
  return s;
}

const StageParameter& findParameter(const Stage& stage,
                                    const std::vector<StageParameter>& parameters,
                                    const std::string& name) {
  for (const auto& p : parameters)
    if (p.name == name) return p;
  throw UsageError("the stage " + stage.name() + " has no parameter '" + name + "'" +
                   (parameters.empty() ? std::string(": it has none")
                                       : "; its parameters are " + namesOf(parameters)));
}

// The path as the operating system finds it: symbolic links followed before a ".." is taken
// (proj/../in, proj a link to store/a/proj, is store/a/in, not in), as far as the path exists.
// A file that is itself a link stays the link (a mesh's material library and textures are found
// beside the name it was given); `folder` resolves the last name too.
fs::path physical(const fs::path& path, bool folder = false) {
  const fs::path absolute = fs::absolute(path).lexically_normal();
  const fs::path name = absolute.filename();
  if (folder || name.empty() || name == "." || name == "..") {
    std::error_code ec;
    fs::path resolved = fs::weakly_canonical(absolute, ec);
    return ec ? absolute : resolved;
  }
  std::error_code ec;
  const fs::path parent = fs::weakly_canonical(fs::absolute(path).parent_path(), ec);
  return ec ? absolute : parent / name;
}

void setOne(ComposeJob& job, const Stage& stage, const std::string& name, nlohmann::json value,
            const fs::path& folder) {
  const std::vector<StageParameter> parameters = stage.parameters();
  const StageParameter& p = findParameter(stage, parameters, name);
  if (p.isFile(value) && !folder.empty()) {
    const fs::path path = value.get<std::string>();
    if (path.is_relative()) value = physical(folder / path).string();
  }
  try {
    p.set(job, value);
  } catch (const UsageError& e) {
    throw UsageError(stage.name() + "." + name + ": " + e.what());
  }
}

}  // namespace

nlohmann::ordered_json sceneFromJob(const ComposeJob& job, const fs::path& folder) {
  nlohmann::ordered_json scene;
  scene["compose"] = "scene";
  scene["version"] = kSceneVersion;
  nlohmann::ordered_json all = nlohmann::ordered_json::object();
  // A scene file named without a folder ("x.json") lies in the working folder. Paths are taken
  // as the operating system finds them, links followed: the relative path from the scene's true
  // folder is the one that leads to the file, however the scene is reached later.
  const fs::path base = physical(folder.empty() ? fs::path(".") : folder, true);
  const ComposeJob defaults;
  for (const auto& stage : stages()) {
    nlohmann::ordered_json values = nlohmann::ordered_json::object();
    for (const StageParameter& p : stage->parameters()) {
      nlohmann::json value = p.get(job);
      // A path left at its default (the output, out/compose) is relative to the folder compose
      // runs in, not to the scene: it stays out of the file, so that `compose run` means the
      // same by it.
      if (p.isPath && value == p.get(defaults)) continue;
      if (p.isFile(value)) {
        // Relative when the file is near the scene (below the same top folder), else absolute.
        const fs::path path = physical(value.get<std::string>());
        auto top = [](const fs::path& full) {
          auto it = full.begin();
          return it != full.end() && ++it != full.end() ? *it : fs::path();
        };
        if (!top(path).empty() && top(path) == top(base))
          value = path.lexically_proximate(base).string();
        else
          value = path.string();
      }
      // JSON holds UTF-8 text: a file name in another encoding (Latin-1's "café") cannot be
      // written (the JSON library's own exception said so without naming the file).
      if (value.is_string()) {
        try {
          (void)value.dump();
        } catch (const nlohmann::json::type_error&) {
          throw Error("scene", stage->name() + "." + p.name + ": '" + value.get<std::string>() +
                                   "' is not UTF-8 text, which a scene file (JSON) cannot hold: "
                                   "rename it, or run the job without a scene file");
        }
      }
      values[p.name] = value;
    }
    if (!values.empty()) all[stage->name()] = values;
  }
  scene["stages"] = all;
  return scene;
}

void saveScene(const ComposeJob& job, const fs::path& file) {
  // The scene is written before the inputs are read (a mesh's material library and textures
  // among them): an older scene file may be replaced, nothing else.
  requireReplaceable(
      file, "compose scene file",
      [](std::istream& in) {
        const nlohmann::json j = nlohmann::json::parse(in, nullptr, false);
        return j.is_object() && j.contains("compose") && j["compose"] == "scene";
      },
      "scene");
  const std::string text = sceneFromJob(job, file.parent_path()).dump(2) + "\n";
  OutputFiles outputs("scene");
  const fs::path temp = outputs.add(file);
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    out << text;
    out.close();
    if (!out) throw Error("scene", "cannot write the scene file", file);
  }
  outputs.commit();
}

void applyScene(const nlohmann::json& scene, const fs::path& folder, ComposeJob& job) {
  if (!scene.is_object() || !scene.contains("compose") || scene["compose"] != "scene")
    throw UsageError("not a compose scene (it needs \"compose\": \"scene\")");
  const nlohmann::json version = scene.contains("version") ? scene["version"] : nlohmann::json();
  if (version != kSceneVersion)
    throw UsageError("scene version " + (version.is_null() ? "(none)" : version.dump()) +
                     " is not the one this compose reads (" + std::to_string(kSceneVersion) + ")");
  for (const auto& [key, value] : scene.items()) {
    if (key != "compose" && key != "version" && key != "stages")
      throw UsageError("unknown key '" + key + "'; a scene has compose, version and stages");
  }
  if (!scene.contains("stages")) return;
  if (!scene["stages"].is_object())
    throw UsageError("stages must be an object of stage names to parameters");
  for (const auto& [stageName, values] : scene["stages"].items()) {
    const Stage& stage = findStage(stageName);
    if (!values.is_object())
      throw UsageError("the parameters of " + stageName + " must be an object");
    for (const auto& [name, value] : values.items()) setOne(job, stage, name, value, folder);
  }
}

ComposeJob loadScene(const fs::path& file) {
  protectInput(file);
  requireInputFile(file, "scene", "scene file");
  std::ifstream in(file, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  if (!in) throw Error("scene", "cannot read the scene file", file);
  if (jsonNestedDeeperThan(text.str()))
    throw Error(
        "scene",
        "its JSON nests deeper than " + std::to_string(kMaxJsonDepth) + " levels: not a scene file",
        file);
  nlohmann::json scene;
  try {
    scene = nlohmann::json::parse(text.str());
  } catch (const nlohmann::json::exception& e) {
    throw Error("scene", std::string("not JSON: ") + jsonMessage(e.what()), file);
  }
  if (const std::string key = repeatedJsonKey(text.str()); !key.empty())
    throw Error("scene", "'" + key + "' is given twice: which one counts? Give it once", file);
  ComposeJob job;
  try {
    applyScene(scene, fs::absolute(file).parent_path(), job);
  } catch (const UsageError& e) {
    throw Error("scene", e.what(), file);
  } catch (const nlohmann::json::exception& e) {
    throw Error("scene", std::string("a value does not fit: ") + jsonMessage(e.what()), file);
  }
  return job;
}

void setParameter(ComposeJob& job, const std::string& assignment) {
  const size_t dot = assignment.find('.'), equals = assignment.find('=');
  if (dot == std::string::npos || equals == std::string::npos || dot > equals)
    throw UsageError("--set expects STAGE.PARAMETER=VALUE, got '" + assignment + "'");
  const Stage& stage = findStage(assignment.substr(0, dot));
  const std::string name = assignment.substr(dot + 1, equals - dot - 1);
  const std::string text = assignment.substr(equals + 1);
  nlohmann::json value = nlohmann::json::parse(text, nullptr, false);
  // A list written as the one-shot command writes it (--place 0.5,0.7): X,Y for [X, Y].
  if (value.is_discarded() && text.find(',') != std::string::npos) {
    const nlohmann::json list = nlohmann::json::parse("[" + text + "]", nullptr, false);
    if (!list.is_discarded()) value = list;
  }
  if (value.is_discarded()) value = text;
  try {
    setOne(job, stage, name, value, {});  // relative to where compose runs
  } catch (const UsageError&) {
    // Text that reads as JSON (a path 2024, a name 1,2) is text where the parameter is text.
    if (value.is_string()) throw;
    ComposeJob tried = job;
    bool asText = true;
    try {
      setOne(tried, stage, name, nlohmann::json(text), {});
    } catch (const UsageError&) {
      asText = false;
    }
    if (!asText) throw;  // the value's own error, as it was read
    job = std::move(tried);
  }
}

}  // namespace compose::pipeline
