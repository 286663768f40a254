// The runner: plans a job over the registered stages (stage.h) and runs what it must.
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <exception>
#include <fstream>
#include <future>
#include <map>
#include <new>
#include <optional>
#include <string>

#include <tbb/global_control.h>

#include "core/error.h"
#include "core/limits.h"
#include "pipeline/compose_job.h"
#include "pipeline/context.h"
#include "pipeline/stage.h"
#include "pipeline/stage_cache.h"
#include "pipeline/stage_util.h"

namespace compose::pipeline {

namespace fs = std::filesystem;

namespace {

// Peak resident memory of this process so far (VmHWM), in bytes; 0 when unknown.
int64_t peakResidentBytes() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return int64_t(std::stoll(line.substr(6))) * 1024;
  }
  return 0;
}

// Starts a new peak (Linux: "5" to clear_refs resets VmHWM to the current resident size).
void resetPeak() {
  std::ofstream out("/proc/self/clear_refs");
  if (out) out << "5";
}

struct Planned {
  std::vector<StageRecord> records;
  std::vector<std::optional<StageCache>> entries;  // per stage: its cache entry, if it is cached
  std::vector<std::string> problems;  // per stage: what is wrong with its entry (planning only)
  // Per stage reused from the cache, or skipped because what it fed is: the notes its run made
  // (kept in the entry), said again in their place among the stages' notes.
  std::vector<std::vector<std::string>> replay;
};

// The notes an entry keeps (StageCache::meta()["notes"]); none when it keeps none or they are
// not a list of strings.
std::vector<std::string> notesKeptIn(const nlohmann::json& meta) {
  if (!meta.is_object() || !meta.contains("notes") || !meta["notes"].is_array()) return {};
  std::vector<std::string> notes;
  for (const nlohmann::json& n : meta["notes"]) {
    if (!n.is_string()) return {};
    notes.push_back(n.get<std::string>());
  }
  return notes;
}

// The entry of a cached stage: keyed by the keys of all the outputs this job has.
std::optional<StageCache> entryFor(const Context& ctx, const Stage& stage) {
  if (!stage.cached() || ctx.job.cache.empty()) return std::nullopt;
  Hash128 h;
  h.bytes(stage.name());
  bool any = false;
  for (const std::string& o : stage.outputs()) {
    if (!ctx.hasKey(o)) continue;
    h.bytes(o);
    h.combine(ctx.key(o));
    any = true;
  }
  if (!any) return std::nullopt;
  return StageCache(ctx.job.cache / "stages", stage.name(), h.hex());
}

// Whether the request reads this stage's outputs from a file.
const StageInput* inputFor(const RunRequest& request, const Stage& stage) {
  for (const StageInput& in : request.inputs)
    for (const std::string& s : in.stages)
      if (s == stage.name()) return &in;
  return nullptr;
}

// Prepares and keys every stage, then decides backwards from the wanted artefacts what runs,
// what is reused (`load`: restored now; otherwise only looked up) and what is skipped.
Planned planJob(Context& ctx, bool load, const RunRequest& request) {
  ctx.planning = !load;
  const auto& list = stages();
  Planned p;
  p.records.resize(list.size());
  p.entries.resize(list.size());
  p.problems.resize(list.size());
  p.replay.resize(list.size());

  // Which artefacts the wanted ones can come from, through the stages that are not read from a
  // file: a stage none of whose outputs is among them is not part of this run.
  ctx.reachable.insert(request.targets.begin(), request.targets.end());
  std::vector<bool> part(list.size(), false);
  for (size_t i = list.size(); i-- > 0;) {
    const Stage& stage = *list[i];
    if (inputFor(request, stage)) continue;
    for (const std::string& o : stage.outputs()) {
      if (!ctx.reachable.count(o)) continue;
      part[i] = true;
      for (const std::string& in : stage.inputsFor(o)) ctx.reachable.insert(in);
    }
  }

  for (const StageInput& in : request.inputs) {
    const auto start = std::chrono::steady_clock::now();
    in.load(ctx);
    const double seconds = secondsSince(start);
    bool first = true;  // the file is read once: its time counts once, with its first stage
    for (const std::string& name : in.stages) {
      const Stage& stage = findStage(name);
      for (size_t i = 0; i < list.size(); ++i) {
        if (list[i].get() != &stage) continue;
        p.records[i].state = StageState::Reused;
        p.records[i].reason = "read from " + in.file.string();
        p.records[i].seconds = first ? seconds : 0.0;
        first = false;
      }
      for (const std::string& o : stage.outputs()) ctx.provided.insert(o);
    }
  }

  for (size_t i = 0; i < list.size(); ++i) {
    const Stage& stage = *list[i];
    StageRecord& r = p.records[i];
    r.name = stage.name();
    if (inputFor(request, stage)) continue;
    if (!part[i]) {
      r.state = StageState::Skipped;
      r.reason = "not needed for this command's outputs";
      continue;
    }
    const auto start = std::chrono::steady_clock::now();
    stage.prepare(ctx);
    if (std::string why = stage.skip(ctx); !why.empty()) {
      r.state = StageState::Skipped;
      r.reason = std::move(why);
    } else {
      stage.keys(ctx);
    }
    r.seconds += secondsSince(start);
  }

  ctx.needed.insert(request.targets.begin(), request.targets.end());
  for (size_t i = list.size(); i-- > 0;) {
    const Stage& stage = *list[i];
    StageRecord& r = p.records[i];
    if (r.state != StageState::Run || !part[i]) continue;
    std::vector<std::string> wanted;
    for (const std::string& o : stage.outputs())
      if (ctx.needs(o) && ctx.hasKey(o)) wanted.push_back(o);
    if (wanted.empty()) {
      r.state = StageState::Skipped;
      r.reason = "nothing needs its outputs: the stages that use them are reused from the cache";
      // What it said when it made what those stages were made from (the room warning of the
      // lighting a reused render was lit by), from its entry's header alone.
      if (load)
        if (const std::optional<StageCache> entry = entryFor(ctx, stage))
          p.replay[i] = notesKeptIn(entry->peekMeta());
      continue;
    }
    p.entries[i] = entryFor(ctx, stage);
    if (p.entries[i]) {
      StageCache& entry = *p.entries[i];
      const auto start = std::chrono::steady_clock::now();
      bool reused = false;
      if (!load) {
        // Planning only (--explain): an entry whose bytes are damaged is not counted as reused.
        // Its contents are not restored here, so one that checks out but does not fit the job
        // (see below) still shows as reused.
        reused = entry.verify();
        if (!reused && !entry.problem().empty()) p.problems[i] = entry.problem();
      } else if (entry.open()) {
        // A stage's loader may find the entry's contents wrong for this job (or, in an entry
        // forged with a valid checksum, not what it wrote): either way a note, never an error.
        std::string why;
        try {
          reused = stage.load(ctx, entry);
        } catch (const std::exception& e) {
          reused = false;
          why = std::string(" (") + e.what() + ")";
        }
        if (reused) {
          p.replay[i] = notesKeptIn(entry.meta());
        } else {
          ctx.runNote("the cache entry " + entry.path().string() + " (stage " + stage.name() +
                      ") does not fit this job" + why + ": ignored and computed again");
          entry.clear();  // rewritten from nothing of what it held
        }
      } else if (!entry.problem().empty()) {
        ctx.runNote("the cache entry " + entry.path().string() + " (stage " + stage.name() + ") " +
                    entry.problem() + ": ignored and computed again");
      }
      r.seconds += secondsSince(start);
      if (reused) {
        r.state = StageState::Reused;
        r.cacheEntry = entry.path().string();
        r.reason = "reused " + entry.path().string() + " (same inputs and parameters)";
        continue;
      }
    }
    r.state = StageState::Run;
    for (const std::string& o : wanted)
      for (const std::string& in : stage.inputsFor(o)) ctx.needed.insert(in);
  }
  for (const std::string& t : request.targets) {
    if (!ctx.hasKey(t) && !ctx.provided.count(t) && t != artefact::kFiles)
      throw UsageError("nothing in this job makes the " + t + " it is asked for");
  }
  return p;
}

}  // namespace

std::vector<StageRecord> plan(const ComposeJob& job, const color::ColorConfig& colors,
                              const RunRequest& request) {
  validate(job);
  Context ctx(job, colors, {});
  Planned p = planJob(ctx, false, request);
  // A placement the run would refuse as soon as it places the object is refused now (the plan
  // said "run" to a --place above the horizon).
  for (const StageRecord& r : p.records)
    if ((r.name == "ground" || r.name == "render") && r.state == StageState::Run) {
      ctx.checkPlacement();
      break;
    }
  // A cache folder the run could not write (read-only): it would say so, and cache nothing.
  std::string unwritable;
  if (!job.cache.empty())
    if (const std::string problem = cacheFolderProblem(job.cache / "stages"); !problem.empty())
      unwritable = "; not cached: " + problem;
  for (size_t i = 0; i < p.records.size(); ++i) {
    StageRecord& r = p.records[i];
    r.seconds = 0.0;
    if (r.state == StageState::Run) {
      r.reason = stages()[i]->planned(ctx);
      // A stage's own folder may be a link too (compose cache lists "stages/render" so).
      const std::string own = p.entries[i] && unwritable.empty()
                                  ? cacheFolderProblem(p.entries[i]->path().parent_path())
                                  : std::string();
      if (p.entries[i] && !unwritable.empty()) {
        r.reason += unwritable;
      } else if (!own.empty()) {
        r.reason += "; not cached: " + own;
      } else if (p.entries[i]) {
        if (!p.problems[i].empty()) {
          // Only a file is replaced, or a link to one (a folder or a pipe where the entry goes
          // stays).
          std::error_code ec;
          const fs::file_status s = fs::status(p.entries[i]->path(), ec);
          r.reason += "; its cache entry " + p.entries[i]->path().string() + " " + p.problems[i] +
                      (fs::is_regular_file(s) ? ": computed again and rewritten"
                                              : ": computed again, not cached (only a file "
                                                "there can be replaced)");
        } else
          r.reason += "; cached in " + p.entries[i]->path().string();
      }
    }
  }
  return p.records;
}

ComposeResult runCompose(const ComposeJob& job, const color::ColorConfig& colors,
                         const Progress& progress, const RunRequest& request) {
  validate(job);
  std::optional<tbb::global_control> threads;
  if (job.threads > 0)
    threads.emplace(tbb::global_control::max_allowed_parallelism, size_t(job.threads));

  ComposeResult result;
  result.exrPath = exrPathFor(job);
  result.displayPath = displayPathFor(job);
  Context ctx(job, colors, progress);
  resetPeak();
  Planned p = planJob(ctx, true, request);
  const auto& list = stages();
  std::map<std::string, std::vector<std::string>> unstored;  // why -> stages not cached
  // `why`: nothing when the entry was written, else why not (the entry's own error, or what a
  // store on its own thread threw: the cache is a convenience, its failure not the run's; empty:
  // nothing to say).
  using Stored = std::optional<std::string>;
  auto stored = [&](size_t i, const Stored& why) {
    StageRecord& r = p.records[i];
    if (!why) {
      r.cacheEntry = p.entries[i]->path().string();
      r.reason += "; cached in " + r.cacheEntry;
    } else if (!why->empty()) {
      unstored[*why].push_back(list[i]->name());
    }
  };
  auto store = [&p](const Stage& stage, const Context& context, size_t i) -> Stored {
    StageCache& entry = *p.entries[i];
    try {
      if (stage.store(context, entry)) return std::nullopt;
    } catch (const std::exception& e) {
      return Stored(e.what());
    }
    return entry.error();
  };
  // Cache entries written while the later stages run (the render's: tens of megabytes at 1080p),
  // by stage index. Declared after the context and the plan, so that on an exception they are
  // waited for (a std::async future's destructor waits) before what they read goes.
  std::vector<std::pair<size_t, std::future<Stored>>> storing;
  for (size_t i = 0; i < list.size(); ++i) {
    StageRecord& r = p.records[i];
    // A stage reused from the cache, or not needed because what it fed is, says again what it
    // said when it ran (a warning about the placement, a merge's clipped pixels), in the order
    // the stages come.
    for (std::string& n : p.replay[i])
      if (std::find(ctx.notes.begin(), ctx.notes.end(), n) == ctx.notes.end())
        ctx.note(std::move(n));  // not when what it was made from said it again
    if (r.state != StageState::Run) continue;
    const Stage& stage = *list[i];
    if (i > 0) resetPeak();
    const auto start = std::chrono::steady_clock::now();
    const size_t firstNote = ctx.notes.size();
    try {
      r.reason = stage.run(ctx);
    } catch (const MemoryShortfall& e) {
      // Found before allocating: what needed how much.
      throw Error(stage.name(),
                  std::string("out of memory: ") + e.what() + "; " + stage.memoryAdvice());
    } catch (const std::bad_alloc&) {
      // Named like any other failure, with the stage that ran out.
      throw Error(stage.name(),
                  "out of memory (" + std::to_string(peakResidentBytes() >> 20) +
                      " MB in use at the peak): the machine or its limits (ulimit -v) allow less "
                      "than this job needs; " +
                      stage.memoryAdvice());
    }
    if (p.entries[i]) {
      // Kept with the outputs, for the runs that reuse them (stores add to the entry's meta).
      std::vector<std::string> kept = ctx.keptFor[stage.name()];
      for (size_t n = firstNote; n < ctx.notes.size(); ++n)
        if (!ctx.runNotes.count(n)) kept.push_back(ctx.notes[n]);
      p.entries[i]->meta()["notes"] = std::move(kept);
      if (stage.storesWhileLaterStagesRun()) {
        storing.emplace_back(i, std::async(std::launch::async, [&store, &stage, &ctx, i] {
                               return store(stage, ctx, i);
                             }));
      } else {
        stored(i, store(stage, ctx, i));
      }
    }
    r.seconds += secondsSince(start);
    r.peakBytes = peakResidentBytes();
  }
  for (auto& [i, done] : storing) stored(i, done.get());
  if (request.finish) request.finish(ctx);
  // A cache folder that cannot be written (read-only, full) is one note per reason, not one per
  // stage: the run goes on without caching.
  for (const auto& [why, names] : unstored) {
    std::string which;
    for (const std::string& n : names) which += (which.empty() ? "" : ", ") + n;
    // The folder itself, a stage's folder, or only these entries (a folder or a pipe where an
    // entry goes).
    std::string problem = cacheFolderProblem(job.cache / "stages");
    for (size_t k = 0; k < names.size() && problem.empty(); ++k)
      problem = cacheFolderProblem(job.cache / "stages" / names[k]);
    if (!problem.empty())
      ctx.runNote(problem + ": the outputs of " + which + " were not cached");
    else
      ctx.runNote("the cache entries of " + which + " could not be written (" + why +
                  "): their outputs were not cached");
  }
  result.stages = std::move(p.records);
  result.notes = std::move(ctx.notes);
  if (ctx.artefacts.plate) {
    result.width = ctx.artefacts.plate->image.width;
    result.height = ctx.artefacts.plate->image.height;
  }
  if (ctx.artefacts.object) {
    result.objectPixels = ctx.artefacts.object->output.coverage;
    result.exposure = ctx.artefacts.object->exposure;
  }
  return result;
}

}  // namespace compose::pipeline
