// compose cache: what the caches hold, and removing old entries. Only compose's own cache folders
// (stages, meshes, visibility, lighting) are looked at; the samples and the stored camera
// responses beside them in the default folder are never touched.

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include "app/cli.h"
#include "core/error.h"
#include "core/output_files.h"
#include "pipeline/compose_job.h"

namespace compose::app {

namespace fs = std::filesystem;

namespace {

// The folders under the cache root that compose writes entries into.
constexpr const char* kCacheFolders[] = {"stages", "meshes", "visibility", "lighting"};

struct Entry {
  fs::path path;
  std::string group;  // "stages/render", "visibility", ...
  uintmax_t bytes = 0;
  fs::file_time_type written;
  bool temporary = false;  // an entry being written (KEY.kind.partial-PID-N)
  bool orphan = false;     // a temporary a killed run left (its process is gone)
};

// Whether a file is one compose wrote into its cache: a key of 32 hexadecimal digits, a dot and
// the entry's kind (ABCD....stage, ....visibility, ....lighting), or such a file's temporary.
bool isEntryName(const std::string& name) {
  if (name.size() < 34 || name[32] != '.') return false;
  for (int i = 0; i < 32; ++i)
    if (!std::isxdigit(static_cast<unsigned char>(name[size_t(i)]))) return false;
  return true;
}

// "500M", "2G", "1.5G", "800000" (bytes; K, M, G, T and KB, MB, GB, TB are powers of 1000, KiB,
// MiB, GiB, TiB powers of 1024; any case). A size beyond what a file system can hold keeps
// everything.
uintmax_t parseSize(const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  double scale = 1.0;
  const std::string unit = end ? std::string(end) : std::string();
  std::string lower = unit;
  for (char& c : lower) c = char(std::tolower(static_cast<unsigned char>(c)));
  const char* const prefixes = "kmgt";
  for (int power = 1; power <= 4; ++power) {
    const std::string p(1, prefixes[power - 1]);
    if (lower == p || lower == p + "b") scale = std::pow(1000.0, power);
    if (lower == p + "ib") scale = std::pow(1024.0, power);
  }
  if (scale == 1.0 && !unit.empty() && lower != "b")
    throw UsageError("--max-size expects a size such as 500M or 2G, got '" + text + "'");
  if (end == text.c_str() || !std::isfinite(v) || v < 0.0)
    throw UsageError("--max-size expects a size such as 500M or 2G, got '" + text + "'");
  const double bytes = v * scale;
  // 2^63 bytes and more: no file system holds that; converting it would overflow.
  if (!(bytes < 9.2e18)) return std::numeric_limits<uintmax_t>::max();
  return uintmax_t(bytes);
}

std::string megabytes(uintmax_t bytes) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f MB", double(bytes) / 1e6);
  return text;
}

std::string age(fs::file_time_type when, fs::file_time_type now) {
  const double hours = std::chrono::duration<double, std::ratio<3600>>(now - when).count();
  char text[32];
  if (hours < 48.0)
    std::snprintf(text, sizeof text, "%.0f h", std::max(0.0, hours));
  else
    std::snprintf(text, sizeof text, "%.0f days", hours / 24.0);
  return text;
}

}  // namespace

Runner setupCache(CLI::App& cmd, const Globals& globals) {
  struct Options {
    std::string cache;
    double olderThanDays = -1.0;
    std::string maxSize;
    bool dryRun = false;
  };
  auto o = std::make_shared<Options>();
  cmd.description(
      "Show what compose's caches hold (stage outputs, meshes as read, visibility passes, "
      "lighting projections), and remove entries: those written more than --older-than days "
      "ago, then the oldest until the rest fits --max-size. Temporaries a killed run left are "
      "removed too. The samples and the stored camera responses in the default folder are never "
      "touched; a removed entry is computed again when a job needs it.\n\n"
      "Example:\n"
      "  compose cache\n"
      "  compose cache --older-than 30 --max-size 2G");
  cmd.add_option("--cache", o->cache,
                 "Cache folder [default: $COMPOSE_CACHE_DIR, else $XDG_CACHE_HOME/compose, else "
                 "~/.cache/compose]");
  cmd.add_option("--older-than", o->olderThanDays,
                 "Remove entries written more than this many days ago")
      ->check(nonNegativeNumber());
  cmd.add_option("--max-size", o->maxSize,
                 "Then remove the oldest entries until the rest is at most this size (500M, 2G)");
  cmd.add_flag("--dry-run", o->dryRun, "Say what would be removed, and remove nothing");
  return [o, &globals]() -> int {
    const bool pruning = o->olderThanDays >= 0.0 || !o->maxSize.empty();
    const uintmax_t maxBytes =
        o->maxSize.empty() ? std::numeric_limits<uintmax_t>::max() : parseSize(o->maxSize);
    const fs::path root = o->cache.empty() ? pipeline::cacheDirectory() : fs::path(o->cache);
    std::error_code ec;
    if (!fs::exists(root, ec)) {
      if (!globals.quiet) std::printf("no cache at %s: nothing to show\n", root.c_str());
      return 0;
    }
    if (!fs::is_directory(root, ec)) throw Error("cache", "not a folder", root);

    std::vector<Entry> entries;
    std::vector<std::string> links;
    size_t running = 0;  // temporaries of runs still writing them: neither listed nor removed
    for (const char* folder : kCacheFolders) {
      const fs::path dir = root / folder;
      // A folder moved elsewhere and linked here (to a larger disk) is the cache's as runs use
      // it; links further down are not followed.
      if (!fs::is_directory(dir, ec)) continue;
      if (fs::is_symlink(dir, ec))
        links.push_back(std::string(folder) + " is a link to " +
                        fs::read_symlink(dir, ec).string());
      for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
        std::error_code e;
        if (!it->is_regular_file(e) || it->is_symlink(e)) continue;
        if (!isEntryName(it->path().filename().string())) continue;  // not an entry of compose's
        Entry entry;
        entry.path = it->path();
        // By name: a folder linked elsewhere keeps its name in the cache ("stages/render").
        const fs::path relative = entry.path.parent_path().lexically_relative(root);
        entry.group = relative.empty() ? std::string(folder) : relative.generic_string();
        entry.bytes = it->file_size(e);
        entry.written = fs::last_write_time(entry.path, e);
        entry.temporary = entry.path.filename().string().find(".partial-") != std::string::npos;
        entry.orphan = entry.temporary && isAbandonedTemporary(entry.path);
        if (entry.temporary && !entry.orphan) {
          ++running;  // a run writes it now, or did within the minute
          continue;
        }
        entries.push_back(std::move(entry));
      }
      if (ec) throw Error("cache", "cannot list the folder: " + ec.message(), dir);
    }

    const auto now = fs::file_time_type::clock::now();
    // What goes: temporaries of gone runs, entries older than asked, then the oldest until the
    // rest fits (never a temporary a run is writing: removing one lost that run's entry).
    std::vector<bool> remove(entries.size(), false);
    if (pruning) {
      for (size_t i = 0; i < entries.size(); ++i) {
        const double days =
            std::chrono::duration<double, std::ratio<86400>>(now - entries[i].written).count();
        remove[i] = entries[i].orphan || (o->olderThanDays >= 0.0 && days > o->olderThanDays);
      }
      uintmax_t kept = 0;
      for (size_t i = 0; i < entries.size(); ++i)
        if (!remove[i]) kept += entries[i].bytes;
      std::vector<size_t> byAge(entries.size());
      for (size_t i = 0; i < byAge.size(); ++i) byAge[i] = i;
      std::sort(byAge.begin(), byAge.end(),
                [&](size_t a, size_t b) { return entries[a].written < entries[b].written; });
      for (const size_t i : byAge) {
        if (kept <= maxBytes) break;
        if (remove[i]) continue;
        remove[i] = true;
        kept -= entries[i].bytes;
      }
    }

    struct Group {
      size_t count = 0, removed = 0;
      uintmax_t bytes = 0, removedBytes = 0;
      fs::file_time_type oldest = fs::file_time_type::max(), newest = fs::file_time_type::min();
    };
    std::map<std::string, Group> groups;
    Group total, leftovers;  // entries; temporaries of runs that stopped (not entries)
    size_t failed = 0;
    for (size_t i = 0; i < entries.size(); ++i) {
      const Entry& e = entries[i];
      bool removed = remove[i];
      if (remove[i] && !o->dryRun) {
        std::error_code r;
        fs::remove(e.path, r);  // one gone already (renamed by its writer) is as good as removed
        if (r && fs::exists(e.path)) {
          ++failed;
          removed = false;  // said as kept: it is there still
        }
      }
      if (e.orphan) {
        ++leftovers.count;
        leftovers.bytes += e.bytes;
        if (removed) ++leftovers.removed, leftovers.removedBytes += e.bytes;
        continue;
      }
      for (Group* g : {&groups[e.group], &total}) {
        ++g->count;
        g->bytes += e.bytes;
        g->oldest = std::min(g->oldest, e.written);
        g->newest = std::max(g->newest, e.written);
        if (removed) {
          ++g->removed;
          g->removedBytes += e.bytes;
        }
      }
    }
    if (!globals.quiet) {
      std::printf("cache %s\n", root.c_str());
      for (const auto& [name, g] : groups) {
        std::printf("  %-22s %6zu entries %12s  written %s to %s ago\n", name.c_str(), g.count,
                    megabytes(g.bytes).c_str(), age(g.newest, now).c_str(),
                    age(g.oldest, now).c_str());
      }
      std::printf("  %-22s %6zu entries %12s\n", "total", total.count,
                  megabytes(total.bytes).c_str());
      for (const std::string& link : links) std::printf("  (%s)\n", link.c_str());
      if (running > 0)
        std::printf(
            "  (%zu entr%s being written by running jobs, or left within the last minute by one "
            "that stopped: not counted, not removed)\n",
            running, running == 1 ? "y" : "ies");
      if (leftovers.count > 0)
        std::printf(
            "  (%zu unfinished entr%s left by runs that stopped, %s: %s)\n", leftovers.count,
            leftovers.count == 1 ? "y" : "ies", megabytes(leftovers.bytes).c_str(),
            leftovers.removed == leftovers.count ? (o->dryRun ? "would be removed" : "removed")
            : pruning                            ? "not all could be removed"
                      : "compose cache --max-size or --older-than removes them");
      if (pruning) {
        std::printf("%s %zu entries (%s); %zu kept (%s)\n", o->dryRun ? "would remove" : "removed",
                    total.removed, megabytes(total.removedBytes).c_str(),
                    total.count - total.removed,
                    megabytes(total.bytes - total.removedBytes).c_str());
      }
    }
    if (failed > 0) {
      throw Error("cache", std::to_string(failed) + " entries could not be removed (permissions?)",
                  root);
    }
    return 0;
  };
}

}  // namespace compose::app
