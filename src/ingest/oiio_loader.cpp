// Loading the OpenImageIO module (oiio_module.h) on first use.
#include <dlfcn.h>
#include <unistd.h>

#include <cstdlib>
#include <mutex>

#include "core/error.h"
#include "ingest/oiio_module.h"

namespace compose::ingest::oiio {

namespace fs = std::filesystem;

namespace {

constexpr const char* kModuleFile = "libcompose_oiio.so";

// Where the module may be, in the order they are tried (oiio_module.h).
std::vector<fs::path> candidates() {
  std::vector<fs::path> out;
  if (const char* given = std::getenv("COMPOSE_OIIO_MODULE"); given && *given)
    out.emplace_back(given);
  std::error_code ec;
  const fs::path program = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    out.push_back(program.parent_path() / kModuleFile);
    out.push_back(program.parent_path().parent_path() / "lib" / "compose" / kModuleFile);
  }
#ifdef COMPOSE_OIIO_MODULE_PATH
  out.emplace_back(COMPOSE_OIIO_MODULE_PATH);
#endif
  return out;
}

struct Loaded {
  Module* module = nullptr;
  std::string failure;  // why it could not be loaded
};

Loaded load() {
  Loaded out;
  for (const fs::path& path : candidates()) {
    std::error_code ec;
    if (!fs::exists(path, ec)) continue;
    void* handle = dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
    if (!handle) {
      const char* why = dlerror();
      out.failure += (out.failure.empty() ? "" : "; ") + path.string() + ": " +
                     (why ? why : "cannot be loaded");
      continue;
    }
    using Entry = Module* (*)();
    auto entry = reinterpret_cast<Entry>(dlsym(handle, "compose_oiio_module"));
    if (!entry) {
      out.failure += (out.failure.empty() ? "" : "; ") + path.string() + ": not the module";
      continue;
    }
    out.module = entry();  // the handle stays open for the rest of the process
    return out;
  }
  if (out.failure.empty()) out.failure = std::string(kModuleFile) + " not found";
  return out;
}

}  // namespace

Module& module(const std::string& stage, const fs::path& file) {
  static std::once_flag once;
  static Loaded loaded;
  std::call_once(once, [] { loaded = load(); });
  if (!loaded.module)
    throw Error(stage,
                "this file needs OpenImageIO, whose module could not be loaded (" + loaded.failure +
                    "; set COMPOSE_OIIO_MODULE to its path)",
                file);
  return *loaded.module;
}

}  // namespace compose::ingest::oiio
