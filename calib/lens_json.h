// The lens file's JSON object, for files that embed a lens (plate poses). Private to calib/.
#pragma once

#include <filesystem>

#include <nlohmann/json.hpp>

#include "calib/lens.h"

namespace compose::calib {

// Parses a lens object (the lens file format); errors name `file`.
Lens lensFromJson(const nlohmann::json& j, const std::filesystem::path& file);
nlohmann::ordered_json lensToJson(const Lens& lens);

}  // namespace compose::calib
