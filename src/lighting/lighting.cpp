#include "lighting/lighting.h"

#include "core/error.h"
#include "lighting/exact.h"
#include "lighting/sh.h"

namespace compose::lighting {

const std::vector<std::string>& lightingNames() {
  static const std::vector<std::string> names = {"sh", "exact"};
  return names;
}

std::unique_ptr<DiffuseLighting> createLighting(const std::string& name, ParamSet params) {
  std::unique_ptr<DiffuseLighting> basis;
  if (name == "sh") {
    basis = std::make_unique<ShLighting>(params.getInt("order", 2, "lighting"));
  } else if (name == "exact") {
    basis = std::make_unique<ExactLighting>();
  } else {
    std::string valid;
    for (const auto& n : lightingNames()) valid += (valid.empty() ? "" : ", ") + n;
    throw Error("lighting", "unknown lighting basis '" + name + "'; valid: " + valid);
  }
  params.requireAllUsed("lighting", "lighting basis '" + name + "'");
  return basis;
}

}  // namespace compose::lighting
