// compose-bench-pipeline: the one-shot compose on a 12-megapixel plate and on a 1920x1080 plate,
// cold and warm, against OpenImageIO alone decoding the same inputs and encoding the same outputs;
// and the renderer alone at 1920x1080 (issue 9 §5, issue 8's performance goals).
//
//   compose-bench-pipeline [--out DIR] [--quick] [--repeat N] [--plate FILE] [--pipeline-only]
//                          [--keep DIR]
//
// The plates are made first (not timed): tabletop.jpg cut to the frame's aspect ratio and resized
// with OpenImageIO to 4000x3000 and 1920x1080, saved as JPEG (quality 95); --plate FILE takes
// that file instead of the 12 MP one. --pipeline-only measures the large plate against
// OpenImageIO alone and nothing else. The object is the Stanford bunny, 0.6 of the plate high (a
// large object), lit by the forest HDRI, self-shadowed and casting its shadow on the ground, 4x4
// samples per pixel: compose's defaults otherwise.
//
// Every measurement runs in a child process of its own (this program again, with an internal
// --child-... command), so that its memory is its own:
//  * compose: pipeline::runCompose() through the public API, cold (an empty cache folder) and warm
//    (the same folder again: every stage up to the render reused from the stage cache), with the
//    stage times and per-stage peak memory (VmHWM) the runner reports;
//  * process: the compose executable itself, warm, as a user runs it (whole-process wall time,
//    peak memory from its --timings); at 1080p also with the object moved at each run, rendered
//    again at each run, and on another take from the same camera at each run (the plate's pixels
//    scaled: the render and the ground shadow reused);
//  * baseline: OpenImageIO alone on the same files: decoding the plate and the environment to
//    float, encoding the EXR (the parts, channels, data windows and compression of compose's own
//    output, from its pixels) and the JPEG (quality 95, 4:4:4, from the display pixels), with
//    OpenImageIO's defaults (its own threads for OpenEXR);
//  * render: the BVH build, the visibility pass (cold, then cached), the per-point shading with
//    self-shadowing and renderDiffuse() at 1920x1080, 4x4 samples per pixel, at the default
//    object height (0.3) and at 0.6.
//  * buffers: what a full-frame copy costs at 12 MP (the buffers the pipeline holds, measured on
//    their own: allocation, first touch and copy).
// Warm runs and the baseline are repeated (--repeat, default 3; --quick 1) and the median is
// reported. The load average is printed beside every figure: the machine has 2 cores and other
// work may run.
//
// Writes pipeline.md and pipeline_console.txt (everything printed) into DIR (default out/bench).
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>
#include <glm/gtc/matrix_transform.hpp>

#include "bench_util.h"
#include "calib/plate_camera.h"
#include "color/color.h"
#include "composite/composite.h"
#include "core/parallel.h"
#include "cubemap/environment_io.h"
#include "ingest/image_io.h"
#include "lighting/environment.h"
#include "pipeline/compose_job.h"
#include "pipeline/shadows.h"
#include "render/embree_scene.h"
#include "render/mesh.h"
#include "render/renderer.h"

namespace {

using namespace compose;
namespace fs = std::filesystem;

double loadAverage() {
  double l[3] = {0, 0, 0};
  return getloadavg(l, 3) > 0 ? l[0] : -1.0;
}

std::string num(const char* f, double v) {
  char b[64];
  std::snprintf(b, sizeof b, f, v);
  return b;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Resident memory now (MB), from /proc/self/statm.
double residentMb() {
  static const long page = sysconf(_SC_PAGESIZE);
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return 0.0;
  long size = 0, resident = 0;
  const int n = std::fscanf(f, "%ld %ld", &size, &resident);
  std::fclose(f);
  return n == 2 ? double(resident) * double(page) / (1024.0 * 1024.0) : 0.0;
}

// Samples the resident memory every 2 ms on a thread of its own.
class MemorySampler {
 public:
  MemorySampler() : start_(bench::Clock::now()) {
    thread_ = std::thread([this] {
      while (!stop_) {
        samples_.push_back({bench::secondsSince(start_), residentMb()});
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
      }
    });
  }
  ~MemorySampler() { stop(); }
  void stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  double now() const { return bench::secondsSince(start_); }
  // The largest sample in [t0, t1] (seconds from the start), 0 when there is none.
  double peak(double t0, double t1) const {
    double m = 0.0;
    for (const auto& [t, mb] : samples_)
      if (t >= t0 && t <= t1) m = std::max(m, mb);
    return m;
  }

 private:
  bench::Clock::time_point start_;
  std::atomic<bool> stop_{false};
  std::vector<std::pair<double, double>> samples_;
  std::thread thread_;
};

// ---------------------------------------------------------------------------------------------
// Children. Each prints "key value..." lines on stdout for the parent.

pipeline::ComposeJob benchJob(const fs::path& plate, const fs::path& cache, const fs::path& out) {
  pipeline::ComposeJob job;
  job.plate = plate;
  job.object = pipeline::samplesDirectory() / "bunny.obj";
  job.environment = pipeline::samplesDirectory() / "forest.exr";
  job.cache = cache;
  job.output = out;
  job.placement.heightFraction = 0.6;
  return job;
}

int childCompose(const fs::path& plate, const fs::path& cache, const fs::path& out) {
  const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
  const pipeline::ComposeJob job = benchJob(plate, cache, out);
  MemorySampler memory;
  const double t0 = memory.now();
  const pipeline::ComposeResult result = pipeline::runCompose(job, colors);
  const double t1 = memory.now();
  memory.stop();
  std::printf("total %.6f\n", t1 - t0);
  std::printf("size %d %d\n", result.width, result.height);
  // Per stage: its state, its seconds and the peak resident memory while it ran, as the runner
  // measures them (VmHWM, reset before each stage that runs).
  double stagePeak = 0.0;
  for (const pipeline::StageRecord& s : result.stages) {
    const double mb = double(s.peakBytes) / (1024.0 * 1024.0);
    stagePeak = std::max(stagePeak, mb);
    std::printf("stage %s %s %.6f %.1f\n", s.name.c_str(), pipeline::stateName(s.state), s.seconds,
                mb);
  }
  // The runner resets VmHWM before each stage, so the process's own high-water mark covers only
  // the last stages: the peak of the run is the largest of the stages' peaks and of the resident
  // memory sampled every 2 ms.
  std::printf("peakall %.1f\n", std::max(stagePeak, memory.peak(0.0, t1 + 1.0)));
  return 0;
}

struct ExrFile {
  std::vector<OIIO::ImageSpec> specs;
  std::vector<std::vector<float>> pixels;
};

ExrFile readExr(const fs::path& file) {
  ExrFile e;
  auto in = OIIO::ImageInput::open(file.string());
  if (!in) throw std::runtime_error("cannot open " + file.string());
  for (int sub = 0; in->seek_subimage(sub, 0); ++sub) {
    e.specs.push_back(in->spec());
    std::vector<float> px(in->spec().image_pixels() * size_t(in->spec().nchannels));
    if (!in->read_image(sub, 0, 0, in->spec().nchannels, OIIO::TypeDesc::FLOAT, px.data()))
      throw std::runtime_error("cannot read " + file.string());
    e.pixels.push_back(std::move(px));
  }
  return e;
}

// Into a buffer that is not zeroed first (compose's own frames are not either).
Pixels decode(const fs::path& file) {
  auto in = OIIO::ImageInput::open(file.string());
  if (!in) throw std::runtime_error("cannot open " + file.string());
  const OIIO::ImageSpec& s = in->spec();
  Pixels px(s.image_pixels() * size_t(s.nchannels));
  if (!in->read_image(0, 0, 0, s.nchannels, OIIO::TypeDesc::FLOAT, px.data()))
    throw std::runtime_error("cannot decode " + file.string());
  return px;
}

// OpenImageIO alone: the inputs decoded, the outputs encoded, with its defaults.
int childBaseline(const fs::path& plate, const fs::path& env, const fs::path& exr,
                  const fs::path& jpeg, const fs::path& scratch) {
  const ExrFile reference = readExr(exr);
  OIIO::ImageSpec displaySpec;
  std::vector<float> display;
  {
    auto in = OIIO::ImageInput::open(jpeg.string());
    displaySpec = in->spec();
    display.resize(displaySpec.image_pixels() * size_t(displaySpec.nchannels));
    in->read_image(0, 0, 0, displaySpec.nchannels, OIIO::TypeDesc::FLOAT, display.data());
  }
  auto t = bench::Clock::now();
  const Pixels platePixels = decode(plate);
  std::printf("decode_plate %.6f\n", bench::secondsSince(t));
  t = bench::Clock::now();
  const Pixels envPixels = decode(env);
  std::printf("decode_env %.6f\n", bench::secondsSince(t));

  t = bench::Clock::now();
  {
    const fs::path file = scratch / "baseline.exr";
    auto out = OIIO::ImageOutput::create(file.string());
    if (!out->open(file.string(), int(reference.specs.size()), reference.specs.data()))
      throw std::runtime_error(out->geterror());
    for (size_t p = 0; p < reference.specs.size(); ++p) {
      if (p > 0 && !out->open(file.string(), reference.specs[p], OIIO::ImageOutput::AppendSubimage))
        throw std::runtime_error(out->geterror());
      if (!out->write_image(OIIO::TypeDesc::FLOAT, reference.pixels[p].data()))
        throw std::runtime_error(out->geterror());
    }
    out->close();
  }
  std::printf("encode_exr %.6f\n", bench::secondsSince(t));
  t = bench::Clock::now();
  {
    const fs::path file = scratch / "baseline.jpg";
    OIIO::ImageSpec spec(displaySpec.width, displaySpec.height, displaySpec.nchannels,
                         OIIO::TypeDesc::UINT8);
    spec.attribute("Compression", "jpeg:95");
    spec.attribute("jpeg:subsampling", "4:4:4");  // as compose writes its display image
    auto out = OIIO::ImageOutput::create(file.string());
    if (!out->open(file.string(), spec) || !out->write_image(OIIO::TypeDesc::FLOAT, display.data()))
      throw std::runtime_error(out->geterror());
    out->close();
  }
  std::printf("encode_jpeg %.6f\n", bench::secondsSince(t));
  std::printf("parts %zu\n", reference.specs.size());
  for (const OIIO::ImageSpec& s : reference.specs) {
    std::printf("part %s %dx%d+%d+%d %d %s %s\n", s.get_string_attribute("name").c_str(), s.width,
                s.height, s.x, s.y, s.nchannels, s.format.c_str(),
                s.get_string_attribute("compression").c_str());
  }
  std::printf("hwm %.1f\n", bench::peakResidentMb());
  return platePixels.empty() || envPixels.empty() ? 1 : 0;
}

// The renderer alone at 1920x1080.
int childRender(const fs::path& cache, int repeat) {
  const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
  const fs::path samples = pipeline::samplesDirectory();
  const render::Mesh mesh = [&] {  // as the pipeline reads it: open pieces with back sides
    render::Mesh read = render::loadMesh(samples / "bunny.obj");
    render::addBackSides(read);
    return read;
  }();
  // The environment in the working space, as the pipeline has it.
  cubemap::LoadedEnvironment loaded = cubemap::loadEnvironment(samples / "forest.exr", {});
  Image envImage = std::move(loaded.image);
  envImage.colorSpace = colors.inputSpaceFor(loaded.file, loaded.info.fileColorSpace);
  colors.convert(envImage, colors.workingSpace());
  const lighting::Environment environment = lighting::Environment::fromLatLong(envImage);
  auto lighting = lighting::createLighting("cheb-local");
  lighting->project(environment);

  std::vector<double> bvh;
  for (int i = 0; i < repeat; ++i) {
    const auto t = bench::Clock::now();
    const render::EmbreeScene s(mesh);
    bvh.push_back(bench::secondsSince(t));
  }
  std::printf("bvh %.6f\n", median(bvh));
  const render::EmbreeScene scene(mesh);
  const pipeline::ShadowPlan plan = pipeline::ShadowPlan::parse("");
  auto t = bench::Clock::now();
  const pipeline::ShadowLighting coldLighting =
      pipeline::prepareShadowLighting(environment, plan, cache);
  std::printf("shadow_lighting_cold %.6f\n", bench::secondsSince(t));
  t = bench::Clock::now();
  const pipeline::ShadowLighting shadowLighting =
      pipeline::prepareShadowLighting(environment, plan, cache);
  std::printf("shadow_lighting_warm %.6f\n", bench::secondsSince(t));

  const calib::PlateCamera camera = calib::plateCamera(1920, 1080, {}, {});
  for (const double height : {0.3, 0.6}) {
    calib::Placement place;
    place.heightFraction = height;
    const glm::dmat4 worldFromObject = calib::placeOnGround(
        camera, place, glm::dvec3(mesh.boundsMin()), glm::dvec3(mesh.boundsMax()));
    glm::mat3 envFromObject = glm::mat3(worldFromObject);
    for (int c = 0; c < 3; ++c) envFromObject[c] = glm::normalize(envFromObject[c]);
    if (height == 0.3) {
      // The visibility pass, without a cache and then through one (cold, then warm).
      t = bench::Clock::now();
      const pipeline::ShadowResult cold =
          pipeline::computeSelfShadowing(mesh, scene, shadowLighting, envFromObject, plan, {});
      std::printf("visibility_cold %.6f %zu\n", bench::secondsSince(t), cold.points.count());
      pipeline::computeSelfShadowing(mesh, scene, shadowLighting, envFromObject, plan, cache);
    }
    std::vector<double> shade, draw;
    render::RenderOutput out;
    for (int i = 0; i < repeat; ++i) {
      t = bench::Clock::now();
      const pipeline::ShadowResult shadows =
          pipeline::computeSelfShadowing(mesh, scene, shadowLighting, envFromObject, plan, cache);
      shade.push_back(bench::secondsSince(t));
      render::RenderSettings settings;
      settings.points = &shadows.points;
      settings.shadows = &shadows.irradiance;
      settings.occlusion = &shadows.occlusion;
      settings.sources = &shadows.sources;
      t = bench::Clock::now();
      out = render::renderDiffuse(mesh, scene, worldFromObject, camera, *lighting, settings);
      draw.push_back(bench::secondsSince(t));
    }
    std::printf("render %.1f %.6f %.6f %d %d %lld %.1f\n", height, median(shade), median(draw),
                out.x1 - out.x0, out.y1 - out.y0, static_cast<long long>(out.rays), out.coverage);
  }
  std::printf("hwm %.1f\n", bench::peakResidentMb());
  return 0;
}

// What a full-frame buffer costs at `width` x `height`: allocating and filling one (first touch),
// copying one, and the conversions the pipeline makes on its way out.
int childBuffers(int width, int height, int repeat) {
  const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
  Image rgb(width, height, 3, {"R", "G", "B"});
  for (size_t i = 0; i < rgb.pixels.size(); ++i) rgb.pixels[i] = float(i % 1013) / 1013.0f;
  rgb.colorSpace = colors.workingSpace();
  auto measure = [&](const char* name, auto&& body) {
    std::vector<double> s;
    for (int i = 0; i < repeat; ++i) {
      const auto t = bench::Clock::now();
      body();
      s.push_back(bench::secondsSince(t));
    }
    std::printf("buffer %s %.6f\n", name, median(s));
  };
  measure("copy_rgb", [&] {
    const Image copy = rgb;
    if (copy.pixels.empty()) std::abort();
  });
  measure("rgba_interleave", [&] {
    Image rgba(width, height, 4, {"R", "G", "B", "A"});
    parallelFor(0, height, [&](int64_t y) {
      const float* s = rgb.row(int(y)).data();
      float* d = rgba.row(int(y)).data();
      for (int x = 0; x < width; ++x) {
        std::copy_n(s + 3 * x, 3, d + 4 * x);
        d[4 * x + 3] = 1.0f;
      }
    });
  });
  Image fg(width / 2, height / 2, 4, {"R", "G", "B", "A"});
  fg.colorSpace = rgb.colorSpace;
  for (size_t i = 0; i < fg.pixels.size(); ++i) fg.pixels[i] = 0.25f;
  measure("over_copy", [&] {
    const Image c = composite::over(fg, width / 4, height / 4, rgb);
    if (c.pixels.empty()) std::abort();
  });
  Image target = rgb;
  measure("over_in_place", [&] { composite::overInPlace(target, fg, width / 4, height / 4); });
  const std::string display = colors.defaultDisplay();
  const std::string view = colors.defaultView(display);
  measure("display_copy", [&] {
    const Image shown = colors.toDisplay(rgb, display, view);
    if (shown.pixels.empty()) std::abort();
  });
  measure("display_in_place", [&] {
    Image mine = rgb;  // the copy is what the in-place conversion saves; timed apart above
    const auto t = bench::Clock::now();
    const Image shown = colors.toDisplay(std::move(mine), display, view);
    std::printf("buffer display_in_place_only %.6f\n", bench::secondsSince(t));
  });
  return 0;
}

// ---------------------------------------------------------------------------------------------
// The parent.

struct Child {
  int status = -1;
  double seconds = 0.0;
  double peakMb = 0.0;
  std::map<std::string, std::vector<std::string>> lines;  // first word -> the rest, in order
  std::vector<std::string> all;
  std::string err;

  double number(const std::string& key, size_t field = 0) const {
    auto it = lines.find(key);
    if (it == lines.end() || it->second.empty()) return 0.0;
    std::istringstream in(it->second.front());
    std::string w;
    for (size_t i = 0; i <= field && in >> w; ++i) {
      if (i == field) return std::atof(w.c_str());
    }
    return 0.0;
  }
};

// Runs `exe args...`, collecting its standard output; ru_maxrss of the child is its peak memory.
Child run(const std::string& exe, const std::vector<std::string>& args, const fs::path& errFile) {
  int pipeFd[2];
  if (pipe(pipeFd) != 0) std::abort();
  const auto start = bench::Clock::now();
  const pid_t pid = fork();
  if (pid == 0) {
    std::vector<std::string> copy = args;
    std::vector<char*> argv;
    std::string e = exe;
    argv.push_back(e.data());
    for (auto& a : copy) argv.push_back(a.data());
    argv.push_back(nullptr);
    dup2(pipeFd[1], 1);
    close(pipeFd[0]);
    close(pipeFd[1]);
    if (!std::freopen(errFile.c_str(), "w", stderr)) _exit(127);
    execv(e.c_str(), argv.data());
    _exit(127);
  }
  close(pipeFd[1]);
  std::string text;
  char buf[4096];
  ssize_t n;
  while ((n = read(pipeFd[0], buf, sizeof buf)) > 0) text.append(buf, size_t(n));
  close(pipeFd[0]);
  Child c;
  int status = 0;
  struct rusage usage {};
  wait4(pid, &status, 0, &usage);
  c.seconds = bench::secondsSince(start);
  c.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  c.peakMb = double(usage.ru_maxrss) / 1024.0;
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    c.all.push_back(line);
    const size_t sp = line.find(' ');
    c.lines[line.substr(0, sp)].push_back(sp == std::string::npos ? "" : line.substr(sp + 1));
  }
  std::ifstream e(errFile);
  std::stringstream ss;
  ss << e.rdbuf();
  c.err = ss.str();
  return c;
}

class Report {
 public:
  void say(const std::string& s) {
    std::printf("%s", s.c_str());
    std::fflush(stdout);
    console_ += s;
  }
  void md(const std::string& s) { md_ += s; }
  void both(const std::string& s) {
    say(s);
    md(s);
  }
  const std::string& console() const { return console_; }
  const std::string& markdown() const { return md_; }

 private:
  std::string console_, md_;
};

struct StageFigure {
  std::string name, state;  // state: run, reused or skipped
  double seconds = 0.0, peakMb = 0.0;
};

struct ComposeRun {
  double total = 0.0, process = 0.0, peakMb = 0.0, load = 0.0;
  std::vector<StageFigure> stages;
  Child child;
};

ComposeRun parseCompose(const Child& c, double load) {
  ComposeRun r;
  r.child = c;
  r.total = c.number("total");
  r.process = c.seconds;
  r.peakMb = std::max(c.peakMb, c.number("peakall"));
  r.load = load;
  if (auto it = c.lines.find("stage"); it != c.lines.end()) {
    for (const std::string& s : it->second) {
      std::istringstream in(s);
      std::string name, state;
      double sec = 0.0, mb = 0.0;
      in >> name >> state >> sec >> mb;
      r.stages.push_back({name, state, sec, mb});
    }
  }
  return r;
}

// The peak memory the compose executable prints with --timings ("compose: total ... MB").
double timingsPeakMb(const std::string& err) {
  std::istringstream in(err);
  std::string line;
  double mb = 0.0;
  while (std::getline(in, line)) {
    if (line.rfind("compose: total", 0) != 0) continue;
    const size_t s = line.find(" s ");
    if (s != std::string::npos) mb = std::atof(line.c_str() + s + 3) * 1e6 / (1024.0 * 1024.0);
  }
  return mb;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 2 && std::string(argv[1]).rfind("--child-", 0) == 0) {
    const std::string what = argv[1];
    try {
      if (what == "--child-compose" && argc == 5) return childCompose(argv[2], argv[3], argv[4]);
      if (what == "--child-baseline" && argc == 7)
        return childBaseline(argv[2], argv[3], argv[4], argv[5], argv[6]);
      if (what == "--child-render" && argc == 4) return childRender(argv[2], std::atoi(argv[3]));
      if (what == "--child-buffers" && argc == 5)
        return childBuffers(std::atoi(argv[2]), std::atoi(argv[3]), std::atoi(argv[4]));
    } catch (const std::exception& e) {
      std::fprintf(stderr, "%s: %s\n", what.c_str(), e.what());
      return 1;
    }
    std::fprintf(stderr, "bad child command\n");
    return 2;
  }

  fs::path outDir = "out/bench";
  fs::path work;
  fs::path givenPlate;
  bool quick = false, keep = false, pipelineOnly = false;
  int repeat = 3;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--out" && i + 1 < argc) {
      outDir = argv[++i];
    } else if (a == "--quick") {
      quick = true;
      repeat = 1;
    } else if (a == "--repeat" && i + 1 < argc) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--plate" && i + 1 < argc) {
      givenPlate = fs::absolute(argv[++i]);
    } else if (a == "--pipeline-only") {
      pipelineOnly = true;
    } else if (a == "--keep" && i + 1 < argc) {
      work = argv[++i];
      keep = true;
    } else {
      std::fprintf(stderr,
                   "usage: %s [--out DIR] [--quick] [--repeat N] [--plate FILE] "
                   "[--pipeline-only] [--keep DIR]\n",
                   argv[0]);
      return 2;
    }
  }
  if (work.empty())
    work = fs::temp_directory_path() / ("compose-bench-pipeline-" + std::to_string(getpid()));
  fs::create_directories(outDir);
  fs::create_directories(work);
  const std::string self = fs::read_symlink("/proc/self/exe").string();
  const fs::path samples = pipeline::samplesDirectory();
  const fs::path env = samples / "forest.exr";
  if (!fs::exists(samples / "tabletop.jpg") || !fs::exists(env) ||
      !fs::exists(samples / "bunny.obj")) {
    std::fprintf(stderr, "sample data missing in %s: run samples/fetch.sh\n", samples.c_str());
    return 1;
  }
  Report rep;
  char line[512];
  std::snprintf(line, sizeof line,
                "# The one-shot compose: time and memory against OpenImageIO alone\n\n"
                "Produced by `compose-bench-pipeline%s` on %ld cores (load average %.2f at the "
                "start). The bunny, 0.6 of the plate high, in the forest HDRI, self-shadowed and "
                "casting its ground shadow, 4x4 samples per pixel; plates made from tabletop.jpg "
                "(JPEG, quality 95). Warm figures are the median of %d runs. Each measurement is "
                "a process of its own; peak memory is its maximum resident set.\n\n",
                quick ? " --quick" : "", sysconf(_SC_NPROCESSORS_ONLN), loadAverage(), repeat);
  rep.both(line);

  // The plates (not timed).
  struct Plate {
    std::string name;
    int width, height;
    fs::path file;
    bool large;  // compared with OpenImageIO alone
  };
  std::vector<Plate> plates = {{"12 MP", 4000, 3000, work / "plate_4000x3000.jpg", true}};
  if (!pipelineOnly) plates.push_back({"1080p", 1920, 1080, work / "plate_1920x1080.jpg", false});
  if (!givenPlate.empty()) {
    std::unique_ptr<OIIO::ImageInput> in = OIIO::ImageInput::open(givenPlate.string());
    if (!in) {
      std::fprintf(stderr, "cannot read %s: %s\n", givenPlate.c_str(), OIIO::geterror().c_str());
      return 1;
    }
    const OIIO::ImageSpec& s = in->spec();
    plates.front() = {num("%.1f MP", double(s.width) * s.height / 1e6), s.width, s.height,
                      givenPlate, true};
  }
  {
    const OIIO::ImageBuf source((samples / "tabletop.jpg").string());
    const OIIO::ImageSpec& s = source.spec();
    for (const Plate& p : plates) {
      if (fs::exists(p.file)) continue;
      // The largest centred window of the plate's aspect ratio, resized.
      int cw = s.width, ch = int(std::lround(double(s.width) * p.height / p.width));
      if (ch > s.height) {
        ch = s.height;
        cw = int(std::lround(double(s.height) * p.width / p.height));
      }
      const OIIO::ROI window((s.width - cw) / 2, (s.width - cw) / 2 + cw, (s.height - ch) / 2,
                             (s.height - ch) / 2 + ch);
      const OIIO::ImageBuf cut = OIIO::ImageBufAlgo::cut(source, window);
      OIIO::ImageBuf resized =
          OIIO::ImageBufAlgo::resize(cut, "", 0.0f, OIIO::ROI(0, p.width, 0, p.height));
      resized.specmod().attribute("Compression", "jpeg:95");
      if (!resized.write(p.file.string())) {
        std::fprintf(stderr, "cannot write %s: %s\n", p.file.c_str(), resized.geterror().c_str());
        return 1;
      }
    }
  }

  struct Goal {
    std::string what;
    bool holds;
    std::string figure;
  };
  std::vector<Goal> goals;
  auto stageTable = [&](const std::vector<std::pair<std::string, const ComposeRun*>>& runs) {
    std::string header = "| stage |", rule = "|---|";
    for (const auto& [label, r] : runs) {
      header += " " + label + " | peak memory |";
      rule += "---|---|";
    }
    rep.both(header + "\n" + rule + "\n");
    const ComposeRun& first = *runs.front().second;
    for (size_t i = 0; i < first.stages.size(); ++i) {
      const std::string& name = first.stages[i].name;
      std::string row = "| " + name + " |";
      for (const auto& [label, r] : runs) {
        if (i >= r->stages.size() || r->stages[i].state == "skipped") {
          row += " skipped | |";
          continue;
        }
        const StageFigure& f = r->stages[i];
        row += " " + num("%.3f s", f.seconds) + (f.state == "reused" ? " (reused)" : "") + " |";
        row += f.state == "run" && f.peakMb > 0 ? " " + num("%.0f MB", f.peakMb) + " |" : " |";
      }
      rep.both(row + "\n");
    }
    std::string total = "| **runCompose** |", process = "| whole process (peak memory) |",
                load = "| load average |";
    for (const auto& [label, r] : runs) {
      total += " **" + num("%.3f s", r->total) + "** | |";
      process += " " + num("%.3f s", r->process) + " (" + num("%.0f MB", r->peakMb) + ") | |";
      load += " " + num("%.2f", r->load) + " | |";
    }
    rep.both(total + "\n" + process + "\n" + load + "\n\n");
  };

  // --- the one-shot compose, 12 MP and 1080p --------------------------------------------------
  std::map<std::string, ComposeRun> warmRuns;
  std::map<std::string, double> warmProcess, warmProcessMb;
  for (const Plate& p : plates) {
    const fs::path cache = work / ("cache_" + std::to_string(p.width));
    const fs::path out = work / ("out_" + std::to_string(p.width)) / "";
    fs::remove_all(cache);
    fs::create_directories(out);
    rep.say("\n" + std::string(p.name) + " (" + std::to_string(p.width) + "x" +
            std::to_string(p.height) + "): cold run ...\n");
    const double coldLoad = loadAverage();
    const Child coldChild =
        run(self, {"--child-compose", p.file.string(), cache.string(), out.string()},
            work / "stderr.txt");
    if (coldChild.status != 0) {
      std::fprintf(stderr, "compose failed:\n%s\n", coldChild.err.c_str());
      return 1;
    }
    const ComposeRun cold = parseCompose(coldChild, coldLoad);
    std::vector<ComposeRun> warms;
    for (int i = 0; i < repeat; ++i) {
      rep.say("  warm run " + std::to_string(i + 1) + " ...\n");
      const double l = loadAverage();
      warms.push_back(
          parseCompose(run(self, {"--child-compose", p.file.string(), cache.string(), out.string()},
                           work / "stderr.txt"),
                       l));
    }
    std::sort(warms.begin(), warms.end(),
              [](const ComposeRun& a, const ComposeRun& b) { return a.total < b.total; });
    const ComposeRun warm = warms[warms.size() / 2];
    warmRuns[p.name] = warm;
    // The compose executable as a user runs it, the bunny in the environment on this plate with
    // the same cache, and `extra` options; empty (the error printed) when it fails.
    auto composeProcess = [&](const std::vector<std::string>& extra,
                              const fs::path& plate = {}) -> std::optional<Child> {
      std::vector<std::string> args = {"--plate",  (plate.empty() ? p.file : plate).string(),
                                       "--object", (samples / "bunny.obj").string(),
                                       "--env",    env.string(),
                                       "--cache",  cache.string(),
                                       "--out",    out.string(),
                                       "-q"};
      args.insert(args.end(), extra.begin(), extra.end());
      Child c = run(COMPOSE_EXECUTABLE, args, work / "stderr.txt");
      if (c.status != 0) {
        std::fprintf(stderr, "compose executable failed:\n%s\n", c.err.c_str());
        return std::nullopt;
      }
      return c;
    };
    // Warm cache.
    std::vector<double> proc, procMb;
    for (int i = 0; i < repeat; ++i) {
      const std::optional<Child> c = composeProcess({"--scale", "0.6", "--timings"});
      if (!c) return 1;
      proc.push_back(c->seconds);
      procMb.push_back(std::max(c->peakMb, timingsPeakMb(c->err)));
    }
    warmProcess[p.name] = median(proc);
    warmProcessMb[p.name] = median(procMb);
    // The object moved at each run (a new --place from `firstY` down): the visibility pass and
    // the self-shadowing come from the cache, the ground shadow and the render are computed, as
    // when a user places the object by hand. False when a run failed.
    auto movedRuns = [&](double firstY, std::vector<std::string> sizing,
                         std::vector<double>& seconds) {
      for (int i = 0; i < std::max(repeat, 3); ++i) {
        std::vector<std::string> args = sizing;
        args.insert(args.end(),
                    {"--place", "0.5," + std::to_string(firstY + 0.01 * i), "--timings"});
        const std::optional<Child> c = composeProcess(args);
        if (!c) return false;
        seconds.push_back(c->seconds);
      }
      return true;
    };
    // The object 0.6 high (the stricter reading), and at its default size (0.3 of the plate
    // high): issue 8's whole-process goal as a user placing the bunny by hand meets it.
    std::vector<double> moved, movedDefault;
    if (!p.large &&
        !(movedRuns(0.80, {"--scale", "0.6"}, moved) && movedRuns(0.70, {}, movedDefault)))
      return 1;

    // The object at its default size and place, rendered again at each run (a new --albedo:
    // the visibility pass, the self-shadowing and the ground shadow come from the cache, the
    // render is computed; a new --exposure reuses the render): issue 8's "visibility cached"
    // with nothing of the render kept.
    std::vector<double> rerendered;
    if (!p.large) {
      for (int i = 0; i <= std::max(repeat, 3); ++i) {
        const std::optional<Child> c = composeProcess({"--albedo", std::to_string(0.5 + 0.01 * i)});
        if (!c) return 1;
        if (i > 0) rerendered.push_back(c->seconds);  // the first run makes the ground shadow
      }
    }

    // Another take from the same camera at each run (the plate's pixels scaled, its EXIF the
    // same: a plate sequence from a locked-off camera): the render and the ground shadow depend
    // on the plate only through its camera and are reused; the plate is read, converted and
    // composited.
    std::vector<double> takes, takesDefault;
    if (!p.large) {
      auto takeRuns = [&](const std::vector<std::string>& sizing, std::vector<double>& seconds) {
        for (int i = 0; i <= std::max(repeat, 3); ++i) {
          const fs::path take = work / ("take_" + std::to_string(i) + ".jpg");
          if (!fs::exists(take)) {
            OIIO::ImageBuf scaled =
                OIIO::ImageBufAlgo::mul(OIIO::ImageBuf(p.file.string()), 0.95f - 0.05f * float(i));
            scaled.specmod().attribute("Compression", "jpeg:95");
            if (!scaled.write(take.string())) {
              std::fprintf(stderr, "cannot write %s: %s\n", take.c_str(),
                           scaled.geterror().c_str());
              return false;
            }
          }
          const std::optional<Child> c = composeProcess(sizing, take);
          if (!c) return false;
          // The first run at the default size makes its render and ground shadow.
          if (i > 0) seconds.push_back(c->seconds);
        }
        return true;
      };
      if (!(takeRuns({"--scale", "0.6"}, takes) && takeRuns({}, takesDefault))) return 1;
    }

    rep.both("\n## " + std::string(p.name) + " plate, " + std::to_string(p.width) + "x" +
             std::to_string(p.height) + "\n\n");
    rep.both(
        "Stage times and peak memory (VmHWM while the stage ran) as runCompose reports them; "
        "the warm run is the median of the runs by total time.\n\n");
    stageTable({{"cold", &cold}, {"warm", &warm}});
    std::snprintf(line, sizeof line,
                  "The compose executable, warm, whole process: %.3f s, peak memory %.0f MB "
                  "(median of %d; load average %.2f).\n\n",
                  warmProcess[p.name], warmProcessMb[p.name], repeat, loadAverage());
    rep.both(line);
    if (!p.large) {
      std::snprintf(line, sizeof line,
                    "The compose executable with the object moved at each run (a new --place: the "
                    "visibility pass and the self-shadowing from the cache, the ground shadow and "
                    "the render computed), whole process: %.3f s (median of %zu).\n\n",
                    median(moved), moved.size());
      rep.both(line);
      goals.push_back(
          {"1080p whole compose with the visibility cached and the object moved (ground shadow "
           "and render computed), < 0.5 s (issue 8, the stricter reading)",
           median(moved) < 0.5, num("%.3f s", median(moved)) + " whole process"});
      std::snprintf(line, sizeof line,
                    "The same with the bunny at its default size (0.3 of the plate high), moved "
                    "at each run: %.3f s (median of %zu).\n\n",
                    median(movedDefault), movedDefault.size());
      rep.both(line);
      goals.push_back(
          {"1080p whole compose with the visibility cached and the object moved (ground shadow "
           "and render computed), bunny at its default size, < 0.5 s (issue 8)",
           median(movedDefault) < 0.5, num("%.3f s", median(movedDefault)) + " whole process"});
      std::snprintf(line, sizeof line,
                    "The compose executable with the bunny at its default size and place (0.3 of "
                    "the plate high), rendered again at each run (a new --albedo: the visibility "
                    "pass, the self-shadowing and the ground shadow from the cache, the render "
                    "computed), whole process: %.3f s (median of %zu).\n\n",
                    median(rerendered), rerendered.size());
      rep.both(line);
      goals.push_back(
          {"1080p whole compose with the visibility cached and the render computed, bunny at its "
           "default size, < 0.5 s (issue 8)",
           median(rerendered) < 0.5, num("%.3f s", median(rerendered)) + " whole process"});
      std::snprintf(line, sizeof line,
                    "The compose executable on another take from the same camera at each run (the "
                    "plate's pixels scaled, its EXIF the same: the ground shadow and the render "
                    "reused, the plate read, converted and composited), whole process: %.3f s with "
                    "the bunny 0.6 of the plate high, %.3f s at its default size (medians of "
                    "%zu).\n\n",
                    median(takes), median(takesDefault), takes.size());
      rep.both(line);
      goals.push_back(
          {"1080p whole compose with the visibility cached, another take from the same camera at "
           "each run (ground shadow and render reused), bunny 0.6 high, < 0.5 s (issue 8)",
           median(takes) < 0.5, num("%.3f s", median(takes)) + " whole process"});
      goals.push_back({"1080p whole compose, caches warm, < 0.5 s (issue 8)",
                       warmProcess[p.name] < 0.5,
                       num("%.3f s", warmProcess[p.name]) + " whole process, " +
                           num("%.3f s", warm.total) + " in runCompose"});
    }

    if (p.large) {
      // --- the baseline ------------------------------------------------------------------------
      rep.say("  baseline (OpenImageIO alone) ...\n");
      std::vector<double> dp, de, ee, ej, total;
      Child last;
      for (int i = 0; i < repeat; ++i) {
        last = run(self,
                   {"--child-baseline", p.file.string(), env.string(),
                    (out / "compose.exr").string(), (out / "compose.jpg").string(), work.string()},
                   work / "stderr.txt");
        if (last.status != 0) {
          std::fprintf(stderr, "baseline failed:\n%s\n", last.err.c_str());
          return 1;
        }
        dp.push_back(last.number("decode_plate"));
        de.push_back(last.number("decode_env"));
        ee.push_back(last.number("encode_exr"));
        ej.push_back(last.number("encode_jpeg"));
        total.push_back(dp.back() + de.back() + ee.back() + ej.back());
      }
      const double baseline = median(total);
      rep.both(
          "### Against OpenImageIO alone\n\nOpenImageIO 2.4 with its defaults decodes the same "
          "inputs to float and encodes the same outputs from compose's own pixels: the EXR with "
          "the same parts, channels, data windows, pixel types and compression, and the JPEG "
          "(quality 95):\n\n");
      rep.both("| step | seconds |\n|---|---|\n");
      rep.both("| decode the plate (JPEG) | " + num("%.3f", median(dp)) + " |\n");
      rep.both("| decode the environment (EXR) | " + num("%.3f", median(de)) + " |\n");
      rep.both("| encode the EXR | " + num("%.3f", median(ee)) + " |\n");
      rep.both("| encode the JPEG | " + num("%.3f", median(ej)) + " |\n");
      rep.both("| **total** | **" + num("%.3f", baseline) + "** |\n\n");
      std::string parts = "The EXR's parts: ";
      if (auto it = last.lines.find("part"); it != last.lines.end()) {
        for (size_t i = 0; i < it->second.size(); ++i)
          parts += (i ? "; " : "") + std::string("`") + it->second[i] + "`";
      }
      rep.both(parts + " (name, data window, channels, type, compression).\n\n");
      // Any OpenImageIO tool pays for starting: a process linked to OpenImageIO alone that
      // does nothing. The whole compose process is compared with the baseline plus that.
      std::vector<double> startups;
      for (int i = 0; i < std::max(5, repeat); ++i) {
        const Child c = run(COMPOSE_OIIO_STARTUP, {}, work / "stderr.txt");
        if (c.status != 0) {
          std::fprintf(stderr, "%s failed\n", COMPOSE_OIIO_STARTUP);
          return 1;
        }
        startups.push_back(c.seconds);
      }
      const double startup = median(startups);
      const double ratio = warm.total / baseline;
      const double processRatio = warmProcess[p.name] / (baseline + startup);
      std::snprintf(line, sizeof line,
                    "**Warm compose / OpenImageIO alone: %.2f** (runCompose %.3f s / %.3f s). "
                    "Whole processes: a program linked to OpenImageIO alone takes %.3f s to start "
                    "and exit (the dynamic loader; median of %zu), so OpenImageIO alone as a "
                    "process would take %.3f s; the whole compose process takes %.3f s: **%.2f**. "
                    "Goal: at most 1.2.\n\n",
                    ratio, warm.total, baseline, startup, startups.size(), baseline + startup,
                    warmProcess[p.name], processRatio);
      rep.both(line);
      goals.push_back({p.name + " warm compose at most 1.2x OpenImageIO alone (issue 9)",
                       ratio <= 1.2 && processRatio <= 1.2,
                       num("%.2f", ratio) + " (runCompose), " + num("%.2f", processRatio) +
                           " (whole processes, start-up included on both sides)"});
      // Peak memory against the size of the images: a float RGB frame of the plate, and the
      // files' own pixels (the EXR's parts at their pixel type, the JPEG's bytes).
      const double frameMb = double(p.width) * p.height * 3 * sizeof(float) / (1024.0 * 1024.0);
      std::snprintf(line, sizeof line,
                    "**Peak memory**: %.0f MB warm, %.0f MB cold (the largest resident set of any "
                    "stage); a float RGB frame of the plate is %.0f MB, so the warm peak is %.1f "
                    "such frames (the process's code and libraries included).\n\n",
                    warm.peakMb, cold.peakMb, frameMb, warm.peakMb / frameMb);
      rep.both(line);
      goals.push_back({"peak memory printed; cold run per-stage times (issue 9)", true,
                       num("%.0f MB", warm.peakMb) + " warm, " + num("%.0f MB", cold.peakMb) +
                           " cold, " + num("%.1f", warm.peakMb / frameMb) + " float RGB frames"});
    }
  }

  if (!pipelineOnly) {
    // --- the renderer alone
    // -----------------------------------------------------------------------
    rep.say("\nrender alone ...\n");
    const fs::path renderCache = work / "cache_render";
    fs::remove_all(renderCache);
    const double renderLoad = loadAverage();
    const int renderRepeat = quick ? 1 : repeat + 2;
    const Child r =
        run(self, {"--child-render", renderCache.string(), std::to_string(renderRepeat)},
            work / "stderr.txt");
    if (r.status != 0) {
      std::fprintf(stderr, "render failed:\n%s\n", r.err.c_str());
      return 1;
    }
    rep.both("\n## The renderer alone, 1920x1080, 4x4 samples per pixel\n\n");
    std::snprintf(
        line, sizeof line,
        "The bunny in the forest HDRI, self-shadowed (Chebyshev transfer k=16 with 64 sources, the "
        "defaults). BVH build %.1f ms; the visibility pass without a cache %.2f s (%d surface "
        "points; goal < 2 s); the shadow lighting projected %.2f s cold, %.3f s from its cache. "
        "Medians of %d; load average %.2f; peak memory %.0f MB.\n\n",
        1e3 * r.number("bvh"), r.number("visibility_cold"), int(r.number("visibility_cold", 1)),
        r.number("shadow_lighting_cold"), r.number("shadow_lighting_warm"), renderRepeat,
        renderLoad, r.peakMb);
    rep.both(line);
    rep.both(
        "| object height | traced rectangle | rays | per-point shading (visibility cached) | "
        "renderDiffuse | rays/s | BVH + shading + render |\n|---|---|---|---|---|---|---|\n");
    if (auto it = r.lines.find("render"); it != r.lines.end()) {
      for (const std::string& s : it->second) {
        std::istringstream in(s);
        double height = 0, shade = 0, draw = 0, coverage = 0;
        int w = 0, h = 0;
        long long rays = 0;
        in >> height >> shade >> draw >> w >> h >> rays >> coverage;
        const double sum = r.number("bvh") + shade + draw;
        std::snprintf(line, sizeof line,
                      "| %.1f | %dx%d | %.1f M | %.1f ms | %.1f ms | %.1f M | %.1f ms |\n", height,
                      w, h, double(rays) / 1e6, 1e3 * shade, 1e3 * draw, double(rays) / draw / 1e6,
                      1e3 * sum);
        rep.both(line);
        if (height == 0.3) {
          goals.push_back(
              {"BVH + 1080p bunny render at 4x4 spp with self-shadowing < 300 ms, "
               "default height 0.3 (issue 8)",
               sum < 0.3, num("%.0f ms", 1e3 * sum)});
        } else {
          goals.push_back({"the same at height 0.6 (the large object of these runs)", sum < 0.3,
                           num("%.0f ms", 1e3 * sum)});
        }
      }
    }
    rep.both("\n");
    goals.push_back({"visibility pass for the bunny < 2 s (issue 8)",
                     r.number("visibility_cold") < 2.0,
                     num("%.2f s", r.number("visibility_cold"))});

    // --- buffers --------------------------------------------------------------------------------
    rep.say("\nfull-frame buffers ...\n");
    const Child b = run(self, {"--child-buffers", "4000", "3000", std::to_string(repeat + 2)},
                        work / "stderr.txt");
    if (b.status == 0) {
      auto buffer = [&](const std::string& name) {
        if (auto it = b.lines.find("buffer"); it != b.lines.end()) {
          for (const std::string& s : it->second) {
            if (s.rfind(name + " ", 0) == 0) return 1e3 * std::atof(s.c_str() + name.size() + 1);
          }
        }
        return 0.0;
      };
      rep.both("\n## What a full-frame buffer costs at 12 MP\n\n");
      rep.both(
          "A float RGB frame of 4000x3000 is 137 MiB (144 MB), RGBA 183 MiB. Times on their own "
          "(medians, load average " +
          num("%.2f", loadAverage()) + "):\n\n| operation | ms |\n|---|---|\n");
      rep.both("| copy an RGB frame (allocate, touch, copy) | " + num("%.1f", buffer("copy_rgb")) +
               " |\n");
      rep.both("| interleave an RGB frame into a new RGBA one | " +
               num("%.1f", buffer("rgba_interleave")) + " |\n");
      rep.both("| composite::over (copies the frame) | " + num("%.1f", buffer("over_copy")) +
               " |\n");
      rep.both("| composite::overInPlace | " + num("%.1f", buffer("over_in_place")) + " |\n");
      rep.both("| toDisplay(const Image&) (copies the frame) | " +
               num("%.1f", buffer("display_copy")) + " |\n");
      rep.both("| toDisplay(Image&&), in place | " + num("%.1f", buffer("display_in_place_only")) +
               " |\n\n");
    }
  }

  // --- goals ------------------------------------------------------------------------------------
  rep.both("## Goals\n\n| goal | holds | figure |\n|---|---|---|\n");
  for (const Goal& g : goals)
    rep.both("| " + g.what + " | " + (g.holds ? "yes" : "**no**") + " | " + g.figure + " |\n");
  rep.both("\nLoad average at the end: " + num("%.2f", loadAverage()) + ".\n");

  std::ofstream(outDir / "pipeline.md") << rep.markdown();
  std::ofstream(outDir / "pipeline_console.txt") << rep.console();
  std::printf("\nWrote %s and %s\n", (outDir / "pipeline.md").c_str(),
              (outDir / "pipeline_console.txt").c_str());
  if (!keep) fs::remove_all(work);
  return 0;
}
