// The pipeline's stages as commands, file in, file out: compose color, precompute, render,
// composite, and compose run (a whole job from a scene file). Chained by hand they give what the
// one-shot command gives (tests/e2e/stages_e2e_test.cpp checks it).
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <istream>
#include <string>
#include <string_view>

#include "app/cli.h"
#include "app/compose_options.h"
#include "color/color.h"
#include "core/channels.h"
#include "core/error.h"
#include "core/output_files.h"
#include "core/parallel.h"
#include "ingest/exr_io.h"
#include "ingest/image_io.h"
#include "pipeline/context.h"
#include "pipeline/scene.h"
#include "pipeline/stage_files.h"
#include "pipeline/stage_util.h"
#include "pipeline/stages.h"

namespace compose::app {

namespace fs = std::filesystem;

Runner setupColor(CLI::App& cmd, const Globals& globals) {
  struct Options {
    std::string in, out, from, to, depth = "half", compression = "piz";
  };
  auto o = std::make_shared<Options>();
  cmd.description(
      "Convert an image to the working space (role scene_linear of the OpenColorIO config) or to "
      "another colour space, as the pipeline's colour stage reads plates and environments, and "
      "write it as OpenEXR with the space's chromaticities and name in the header.\n\n"
      "Example:\n"
      "  compose color plate.jpg --out plate_linear.exr\n"
      "  compose color env.hdr --from lin_rec709 --to ACEScg --out env_acescg.exr");
  cmd.add_option("image", o->in, "Image to convert (JPEG, PNG, TIFF, EXR, HDR, ...)")->required();
  cmd.add_option("--out", o->out, "Output OpenEXR")->required();
  cmd.add_option("--from", o->from, "Colour space of the input [default: from the file]");
  cmd.add_option("--to", o->to, "Colour space to write [default: the working space]");
  cmd.add_option("--depth", o->depth, "half or float")->capture_default_str();
  addCompressionOption(cmd, o->compression);
  return [o, &globals]() -> int {
    if (o->depth != "half" && o->depth != "float")
      throw UsageError("--depth must be half or float, got '" + o->depth + "'");
    if (o->out.empty()) throw UsageError("--out is empty: give the EXR to write");
    requireExrName(o->out, "compose color writes scene-linear values");
    OutputFiles::check(o->out, "output");
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    // The spaces named on the command line are checked before the image is read.
    std::string target;
    asUsage([&] {
      target = o->to.empty() ? colors.workingSpace() : colors.resolve(o->to, "--to");
      if (!o->from.empty()) colors.resolve(o->from, "--from");
    });
    // Of a multi-part OpenEXR the part that holds the picture, as a plate's (a note says which).
    ingest::LoadedImage loaded = ingest::readImage(o->in, "color", {.picturePart = true});
    Image& image = loaded.image;
    ingest::requireFinite(image, o->in, "color", "the image");
    // Colour by channel name, as the pipeline reads plates and environments (core/channels.h:
    // a layer's beauty.R, G, B; Y alone as grey), with the alpha that goes with it; other
    // channels (normals, depth, other layers) are not colours and are left out, said below.
    ingest::requireColourChannels(image, o->in, "color", "the image");
    std::vector<std::string> leftOut;
    {
      const PictureChannels picture = pictureChannels(image);
      for (int c = 0; c < image.channels; ++c)
        if (c != picture.alpha &&
            std::find(picture.colour.begin(), picture.colour.end(), c) == picture.colour.end())
          leftOut.push_back(c < int(image.channelNames.size()) ? image.channelNames[size_t(c)]
                                                               : std::to_string(c));
      Image converted = pipeline::toRgb(image);
      converted.channelNames = {"R", "G", "B"};  // rgba.red, beauty.R: written as R, G, B
      if (picture.alpha >= 0) {
        Image withAlpha(image.width, image.height, 4, {"R", "G", "B", "A"});
        for (size_t i = 0; i < image.pixelCount(); ++i) {
          std::copy_n(&converted.pixels[3 * i], 3, &withAlpha.pixels[4 * i]);
          withAlpha.pixels[4 * i + 3] =
              image.pixels[i * size_t(image.channels) + size_t(picture.alpha)];
        }
        converted = std::move(withAlpha);
      }
      converted.colorSpace = image.colorSpace;
      image = std::move(converted);
    }
    // Codes premultiplied in their encoding (a TIFF with associated alpha) are made straight
    // before they are decoded, and premultiplied again below, as the pipeline reads a plate.
    const bool encodedPremultiplied =
        image.channels == 4 && !loaded.info.unassociatedAlpha && loaded.info.integerSamples();
    if (encodedPremultiplied) {
      parallelFor(0, image.height, [&](int64_t y) {
        for (float *p = image.row(int(y)).data(), *end = p + size_t(image.width) * 4; p != end;
             p += 4) {
          if (p[3] <= 0.0f) continue;  // light added over what is behind (a glow): kept
          for (int c = 0; c < 3; ++c) p[c] /= p[3];
        }
      });
    }
    const std::string read =
        pipeline::toWorkingSpace(image, o->in, loaded.info, o->from, "--from", colors);
    if (target != image.colorSpace) colors.convert(image, target);
    // OpenEXR's colour is premultiplied: a PNG's or TIFF's unassociated colour is multiplied by
    // its alpha, after the conversion (in linear light for a linear target), as the pipeline
    // reads a plate. Written as it was, a reader took the colour of a transparent pixel for
    // light added over the background.
    const bool premultiplied =
        image.channels == 4 && (loaded.info.unassociatedAlpha || encodedPremultiplied);
    if (premultiplied) {
      parallelFor(0, image.height, [&](int64_t y) {
        for (float *p = image.row(int(y)).data(), *end = p + size_t(image.width) * 4; p != end;
             p += 4) {
          if (encodedPremultiplied && p[3] <= 0.0f) continue;  // kept, as made straight above
          p[0] *= p[3];
          p[1] *= p[3];
          p[2] *= p[3];
        }
      });
    }
    ingest::WriteOptions options;
    options.depth = o->depth == "float" ? ingest::WriteOptions::Depth::Float
                                        : ingest::WriteOptions::Depth::Half;
    if (image.channels >= 4) options.alphaChannel = 3;
    options.chromaticities = colors.chromaticities(target);
    options.exrCompression = o->compression;
    const ingest::WriteReport report = ingest::writeImage(o->out, image, options);
    if (!globals.quiet) {
      std::fprintf(
          stderr, "compose: read %s as %s, wrote '%s'%s\n", printable(o->in).c_str(),
          printable(read).c_str(), target.c_str(),
          premultiplied ? ", its colour premultiplied by its alpha (OpenEXR's convention)" : "");
      for (const std::string& n : loaded.notes)  // what the reader made of the file
        std::fprintf(stderr, "compose: note: %s\n", printable(n).c_str());
      if (!leftOut.empty()) {
        std::string names;
        for (const std::string& n : leftOut) names += (names.empty() ? "" : ", ") + n;
        std::fprintf(stderr,
                     "compose: note: %zu channel%s not converted and not written (not the image's "
                     "colour or its alpha): %s\n",
                     leftOut.size(), leftOut.size() == 1 ? "" : "s", printable(names).c_str());
      }
      if (!options.chromaticities)
        std::fprintf(stderr,
                     "compose: note: the config does not say what the primaries of '%s' are: the "
                     "EXR carries its name but no chromaticities\n",
                     target.c_str());
      if (report.promotedToFloat)
        std::fprintf(stderr,
                     "compose: note: values up to %g exceed half float's range: written as float\n",
                     double(report.largestMagnitude));
    }
    std::printf("%s\n", o->out.c_str());
    return 0;
  };
}

Runner setupPrecompute(CLI::App& cmd, const Globals& globals) {
  auto o = std::make_shared<ComposeOptions>();
  auto out = std::make_shared<std::string>();
  cmd.description(
      "Project an environment onto the lighting basis (the pipeline's precompute stage) and split "
      "off its brightest sources for the shadows; write both to a lighting file for compose "
      "render. The file fixes the basis, its parameters, the shadow parameters and the "
      "environment's turn (--env-yaw).\n"
      "With parallax (--room or --env-radius) the environment is seen from the object's centre: "
      "give the plate and the object with the placement compose render will take (--plate, "
      "--object, --place, --scale, --yaw, camera options); a render that places the object "
      "elsewhere says so.\n\n"
      "Example:\n"
      "  compose precompute --env forest.exr --out forest.lighting\n"
      "  compose render --plate plate.jpg --object bunny.obj --lighting-file forest.lighting "
      "--out bunny.exr\n"
      "  compose composite --plate plate.jpg --layer bunny.exr --out final\n"
      "  compose precompute --env room.exr --room 5,3,4 --plate plate.jpg --object bunny.obj "
      "--place 0.4,0.8 --out room.lighting\n"
      "  compose render --plate plate.jpg --object bunny.obj --place 0.4,0.8 --lighting-file "
      "room.lighting --out bunny.exr");
  o->addEnvironment(cmd, true);
  o->addLighting(cmd);
  o->addShadows(cmd, true);
  // The object's placement, for parallax alone.
  o->addPlate(cmd);
  o->addObject(cmd, false);
  o->addRun(cmd);
  cmd.add_option("--out", *out, "Lighting file to write")->required();
  return [o, out, &cmd, &globals]() -> int {
    o->apply(cmd);
    // Parallax sees the environment from the object's centre, which the plate and the
    // placement put somewhere; without parallax the lighting does not depend on them.
    const bool parallax = o->job.room || o->job.environmentRadius;
    // (Both given: the job's own check says to give one.)
    if (parallax && !(o->job.room && o->job.environmentRadius) &&
        (o->job.plate.empty() || o->job.object.empty()))
      throw UsageError(
          std::string(o->job.room ? "--room" : "--env-radius") +
          ": with parallax the environment is seen from the object's centre; give the plate and "
          "the object (--plate, --object) with the placement compose render will take (--place, "
          "--scale, --yaw, camera options)");
    if (!parallax) {
      for (const char* name :
           {"--plate", "--plate-space", "--object", "--crease", "--place", "--scale", "--yaw",
            "--focal35", "--camera-height", "--pitch", "--calib", "--pose"}) {
        const CLI::Option* option = cmd.get_option_no_throw(name);
        if (option != nullptr && option->count() > 0)
          throw UsageError(std::string(name) +
                           " places the object for parallax (--room or --env-radius); without "
                           "it the lighting file does not depend on where the object stands: "
                           "leave it out");
      }
    }
    OutputFiles::check(*out, "precompute");
    // A lighting file is not an image: an image's name would mislead every tool that opens it.
    if (ingest::looksLikeImageFile(*out))
      throw UsageError("--out " + *out +
                       ": a lighting file is not an image; give it another name (such as "
                       "forest.lighting)");
    // The lighting file keeps the bright sources for both shadows or for neither: one option
    // alone would change nothing in it.
    if (o->job.shadows != o->job.groundShadow)
      throw UsageError(
          "precompute takes --shadows off together with --no-shadow (a lighting file without the "
          "bright light sources the shadows need); either alone changes nothing in the file: the "
          "render decides which shadows it draws");
    // Lighting kept as a file needs a basis with state to save.
    if (o->job.lighting == "sh" || o->job.lighting == "mc" || o->job.lighting == "exact")
      throw UsageError("--lighting " + o->job.lighting +
                       " is not kept in lighting files (sh projects in milliseconds; mc and exact "
                       "read the environment while shading): precompute takes cheb-local (the "
                       "default), cheb-latlong or cheb-face; the one-shot command takes every "
                       "basis");
    {
      std::error_code ec;
      const fs::path env = o->job.environment;
      if (!env.empty() && fs::exists(*out, ec) && fs::equivalent(*out, env, ec))
        throw Error(
            "precompute",
            "the output would replace an input (" + env.string() + "): choose another output path",
            *out);
    }
    // An older lighting file may be replaced, nothing else (a scene file, a mesh).
    requireReplaceable(
        *out, "compose lighting file",
        [](std::istream& in) {
          char magic[7] = {};
          return bool(in.read(magic, sizeof magic)) &&
                 std::string(magic, sizeof magic) == "COMPSTG";
        },
        "precompute");
    pipeline::RunRequest request;
    request.targets = {pipeline::artefact::kLighting};
    if (o->job.shadows || o->job.groundShadow)
      request.targets.push_back(pipeline::artefact::kShadowLighting);
    // Parallax places the object: the plate's camera and the mesh's bounds.
    if (parallax)
      request.targets.insert(request.targets.end(),
                             {pipeline::artefact::kPlate, pipeline::artefact::kMesh});
    const fs::path file = *out;
    request.finish = [file](pipeline::Context& ctx) { pipeline::savePrecompute(ctx, file); };
    request.outputFiles = {file};
    const int status = runJob(*o, globals, request, false);
    if (!o->explain) std::printf("%s\n", file.c_str());
    return status;
  };
}

Runner setupRender(CLI::App& cmd, const Globals& globals) {
  auto o = std::make_shared<ComposeOptions>();
  auto out = std::make_shared<std::string>();
  auto lightingFile = std::make_shared<std::string>();
  auto compression = std::make_shared<std::string>("zip");
  cmd.description(
      "Render the object as the plate's camera sees it (the pipeline's shadows, ground and render "
      "stages), lit by a lighting file of compose precompute, into the object's layer: a float "
      "multi-part OpenEXR the plate's size (part object: premultiplied RGBA and the AOVs; part "
      "shadow: the ground shadow's ratio), with the camera and placement in its header.\n\n"
      "Example:\n"
      "  compose render --plate plate.jpg --object bunny.obj --lighting-file forest.lighting "
      "--place 0.5,0.7 --scale 0.3 --out bunny.exr");
  o->addPlate(cmd);
  o->addObject(cmd);
  o->addShadows(cmd, false);
  o->addRun(cmd);
  cmd.add_option("--lighting-file", *lightingFile, "Lighting file (compose precompute)")
      ->required();
  cmd.add_option("--out", *out, "Object layer to write (OpenEXR)")->required();
  addCompressionOption(cmd, *compression)
      ->description(
          "OpenEXR compression of the layer, lossless (compose composite reads its numbers "
          "back): none, rle, zips, zip, piz (zip:0..9, zips:0..9)");
  return [o, out, lightingFile, compression, &cmd, &globals]() -> int {
    o->apply(cmd);
    requireLosslessCompression(*compression, "compose composite reads the layer's numbers back");
    requireExrName(*out, "the object's layer is a multi-part OpenEXR");
    OutputFiles::check(*out, "render");
    // An older layer may be replaced, nothing else (an HDRI or a graded plate named by mistake
    // was overwritten): an OpenEXR whose first header names compose:layer. One of the job's
    // inputs there is refused as such by runJob.
    bool anInput = false;
    for (const fs::path& in :
         {o->job.plate, o->job.holdout, o->job.environment, fs::path(*lightingFile)}) {
      std::error_code same;
      anInput = anInput || (!in.empty() && fs::equivalent(*out, in, same));
    }
    if (!anInput)
      requireReplaceable(
          *out, "compose object layer",
          [](std::istream& in) {
            std::string head(1 << 16, '\0');
            in.read(head.data(), std::streamsize(head.size()));
            head.resize(size_t(in.gcount()));
            return head.rfind("\x76\x2f\x31\x01", 0) == 0 &&
                   head.find("compose:layer") != std::string::npos;
          },
          "render");
    pipeline::RunRequest request;
    request.inputs.push_back(pipeline::precomputeInput(*lightingFile, o->job));
    // The layer's header carries the camera, made from the plate and the mesh: those are read
    // even when the render and the ground shadow come from the cache.
    request.targets = {pipeline::artefact::kObject, pipeline::artefact::kPlate,
                       pipeline::artefact::kMesh};
    if (o->job.groundShadow) request.targets.push_back(pipeline::artefact::kGroundShadow);
    // The automatic exposure matches the object to the plate's pixels.
    if (!o->job.exposureStops) request.targets.push_back(pipeline::artefact::kPlateLinear);
    const fs::path file = *out;
    request.finish = [file, compression](pipeline::Context& ctx) {
      pipeline::saveObjectLayer(ctx, file, *compression);
    };
    request.outputFiles = {file};
    request.inputFiles = {*lightingFile};
    const int status = runJob(*o, globals, request, false);
    if (!o->explain) std::printf("%s\n", file.c_str());
    return status;
  };
}

Runner setupComposite(CLI::App& cmd, const Globals& globals) {
  auto o = std::make_shared<ComposeOptions>();
  auto layer = std::make_shared<std::string>();
  cmd.description(
      "Composite an object's layer (compose render) into the plate (the pipeline's composite and "
      "output stages): the plate darkened by the ground shadow's ratio in linear light, the "
      "object over it, a holdout's plate in front; writes BASE.exr and BASE.jpg as the one-shot "
      "command does.\n\n"
      "Example:\n"
      "  compose composite --plate plate.jpg --layer bunny.exr --holdout post_mask.png --out "
      "final");
  o->addPlate(cmd);
  o->addOutput(cmd);
  o->addRun(cmd);
  cmd.add_option("--layer", *layer, "Object layer (compose render)")->required();
  return [o, layer, &cmd, &globals]() -> int {
    o->apply(cmd);
    // A layer rendered for a plate of another size fails the run when the plate is read: said
    // by --explain too, from the two headers (it approved the job).
    std::error_code ec;
    if (o->explain && !o->job.plate.empty() && fs::is_regular_file(*layer, ec) &&
        ingest::hasExrMagic(*layer) && fs::is_regular_file(o->job.plate, ec)) {
      const ingest::ExrReader reader(*layer, "composite");
      const ingest::ExrPartHeader& frame = reader.header(0);
      const ingest::CaptureInfo plate = ingest::readCaptureInfo(o->job.plate, "ingest", true);
      const auto [width, height] = plate.shownSize();
      // An EXR that is not a layer is named as such when the plan reads it (below), not blamed
      // for its size.
      if (frame.find("compose:layer") && (frame.fullWidth != width || frame.fullHeight != height)) {
        throw Error("composite",
                    "the object was rendered for a " + std::to_string(frame.fullWidth) + "x" +
                        std::to_string(frame.fullHeight) + " plate; this plate is " +
                        std::to_string(width) + "x" + std::to_string(height),
                    o->job.plate);
      }
    }
    pipeline::RunRequest request;
    request.inputs.push_back(pipeline::objectLayerInput(*layer));
    request.inputFiles = {*layer};
    return runJob(*o, globals, request);
  };
}

Runner setupRun(CLI::App& cmd, const Globals& globals) {
  auto o = std::make_shared<ComposeOptions>();
  auto scene = std::make_shared<std::string>();
  auto sets = std::make_shared<std::vector<std::string>>();
  cmd.description(
      "Run the whole job a scene file (JSON) describes. Write one from a command line with "
      "compose --save-scene SCENE ...; every stage's parameters may appear under its name, paths "
      "relative to the scene file.\n\n"
      "Example:\n"
      "  compose --plate plate.jpg --object bunny.obj --env forest.exr --save-scene bunny.json\n"
      "  compose run bunny.json --set render.scale=0.4 --set output.out=out/bigger");
  cmd.add_option("scene", *scene, "Scene file (JSON)")->required();
  cmd.add_option("--set", *sets,
                 "Override a parameter: STAGE.PARAMETER=VALUE (VALUE as JSON, else a string); "
                 "repeatable");
  o->addRun(cmd);
  return [o, scene, sets, &globals]() -> int {
    {
      // A malformed --set is a bad command line: refused before the scene is read.
      pipeline::ComposeJob scratch;
      std::vector<std::string> names;
      for (const std::string& s : *sets) {
        pipeline::setParameter(scratch, s);
        const std::string name = s.substr(0, s.find('='));
        if (std::find(names.begin(), names.end(), name) != names.end())
          throw UsageError("--set " + name + " is given twice");
        names.push_back(name);
      }
    }
    const fs::path cache = o->job.cache;
    const int threads = o->job.threads;
    o->job = pipeline::loadScene(*scene);
    if (!globals.ocio.empty()) o->job.ocio = globals.ocio;
    o->job.cache = o->noCache ? fs::path() : cache;
    o->job.threads = threads;
    const pipeline::ComposeJob fromScene = o->job;
    for (const std::string& s : *sets) pipeline::setParameter(o->job, s);
    // A whole job needs a plate and an object: the scene file's fault when neither it nor a --set
    // gives one, the command line's when a --set took it away.
    if (o->job.plate.empty() && !fromScene.plate.empty())
      throw UsageError("--set ingest.plate= leaves the job without a plate");
    if (o->job.object.empty() && !fromScene.object.empty())
      throw UsageError("--set ingest.object= leaves the job without an object");
    if (o->job.plate.empty())
      throw Error(
          "scene",
          "the scene gives no plate: set ingest.plate (a path from the scene file's folder)",
          *scene);
    if (o->job.object.empty())
      throw Error(
          "scene",
          "the scene gives no object: set ingest.object (a path from the scene file's folder)",
          *scene);
    // An input the scene names that is not there is said with its key, before anything runs:
    // paths in a scene are read from the scene file's folder (the folder of the name given, a
    // link's own folder for a link).
    const std::pair<const char*, fs::path pipeline::ComposeJob::*> inputs[] = {
        {"ingest.plate", &pipeline::ComposeJob::plate},
        {"ingest.object", &pipeline::ComposeJob::object},
        {"ingest.environment", &pipeline::ComposeJob::environment},
        {"render.calib", &pipeline::ComposeJob::lensFile},
        {"render.pose", &pipeline::ComposeJob::poseFile},
        {"composite.holdout", &pipeline::ComposeJob::holdout}};
    for (const auto& [key, member] : inputs) {
      const fs::path& path = o->job.*member;
      std::error_code ec;
      if (path.empty() || path.string().find('%') != std::string::npos || fs::exists(path, ec))
        continue;
      if (path != fromScene.*member)
        throw UsageError(std::string(key) +
                         " (given with --set) names a file that is not there: " + path.string());
      throw Error("scene",
                  std::string(key) + " names a file that is not there: " + path.string() +
                      " (a path in a scene is read from the scene file's folder)",
                  *scene);
    }
    // A value out of range is the scene file's fault when the scene alone has it (exit 1, naming
    // the file), the command line's when a --set brought it (exit 2).
    const bool ocioSet = o->job.ocio != fromScene.ocio;
    const color::ColorConfig colors = [&] {
      try {
        return jobConfig(o->job, globals, ocioSet ? "--set color.ocio" : "the scene's color.ocio");
      } catch (const Error& e) {
        if (!ocioSet) throw;
        // The config a --set names: the command line's fault.
        throw UsageError(
            std::string(e.what()) + (e.file().empty() ? "" : " (" + e.file().string() + ")"),
            e.stage());
      }
    }();
    try {
      validateJob(o->job, colors);
    } catch (const UsageError& e) {
      try {
        validateJob(fromScene, colors);
      } catch (const UsageError& alone) {
        if (std::string(alone.what()) == e.what())
          throw Error("scene", std::string(e.what()) + " (the value in the scene file)", *scene);
      }
      throw;
    }
    return runJob(*o, globals);
  };
}

Runner setupBench(CLI::App& cmd, const Globals& globals) {
  auto o = std::make_shared<ComposeOptions>();
  auto repeat = std::make_shared<int>(3);
  cmd.description(
      "Time a compose job stage by stage: one cold run (an empty cache: every stage computes) and "
      "then warm runs (the cache filled: what is unchanged is reused), with each stage's median "
      "time and the peak resident memory. The outputs go to a temporary folder.\n\n"
      "Example:\n"
      "  compose bench --plate meadow.jpg --object bunny.obj --env forest.exr --repeat 5");
  o->addPlate(cmd);
  o->addObject(cmd);
  o->addEnvironment(cmd);
  o->addLighting(cmd);
  o->addShadows(cmd, true);
  cmd.add_option("--holdout", o->job.holdout, "Holdout mask, as for compose");
  cmd.add_option("--threads", o->job.threads, "Worker threads [default: every core]");
  cmd.add_option("--repeat", *repeat, "Warm runs")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  return [o, repeat, &cmd, &globals]() -> int {
    o->apply(cmd);
    if (o->job.plate.empty() || o->job.object.empty())
      throw UsageError("compose bench needs --plate and --object");
    std::error_code ec;
    const fs::path temporary = fs::temp_directory_path(ec);
    if (ec) {
      const char* tmpdir = std::getenv("TMPDIR");
      throw Error("bench", "no folder for its temporary files" +
                               (tmpdir ? std::string(" (TMPDIR=") + tmpdir + ")" : std::string()) +
                               ": " + ec.message());
    }
    // A bench's folder holds this file, written first: only such folders are ever removed (a
    // folder of the user's own that happens to have the name stays).
    constexpr const char* kMarker = ".compose-bench";
    auto madeByBench = [&](const fs::path& folder) {
      std::error_code e;
      return fs::is_directory(folder, e) && fs::is_regular_file(folder / kMarker, e);
    };
    // What an interrupted bench left (Ctrl-C, a SIGTERM: its folder of caches and outputs,
    // hundreds of megabytes), once its process is gone.
    for (fs::directory_iterator it(temporary, ec), end; !ec && it != end; it.increment(ec)) {
      const std::string name = it->path().filename().string();
      constexpr std::string_view kPrefix = "compose-bench-";
      if (name.size() <= kPrefix.size() || name.compare(0, kPrefix.size(), kPrefix) != 0 ||
          !std::all_of(name.begin() + ptrdiff_t(kPrefix.size()), name.end(),
                       [](unsigned char c) { return std::isdigit(c) != 0; }))
        continue;
      const long pid = std::strtol(name.c_str() + kPrefix.size(), nullptr, 10);
      std::error_code e;
      if (pid > 0 && ::kill(pid_t(pid), 0) != 0 && errno == ESRCH && madeByBench(it->path()))
        fs::remove_all(it->path(), e);
    }
    ec.clear();
    const fs::path scratch = temporary / ("compose-bench-" + std::to_string(::getpid()));
    if (fs::exists(scratch, ec) && !madeByBench(scratch))
      throw Error("bench",
                  "its temporary folder's name is taken by something it did not make: move it, "
                  "or give another folder in TMPDIR",
                  scratch);
    fs::remove_all(scratch, ec);
    fs::create_directories(scratch, ec);
    if (ec) throw Error("bench", "cannot make its temporary folder: " + ec.message(), scratch);
    writeTextFile(scratch / kMarker, "compose bench's temporary folder, removed when it ends\n",
                  "bench");
    struct Cleanup {
      fs::path path;
      ~Cleanup() {
        std::error_code e;
        fs::remove_all(path, e);
      }
    } cleanup{scratch};
    o->job.cache = scratch / "cache";
    o->job.output = scratch / "out" / "compose";
    // Checked as the one-shot command checks it: a colour space the config does not know is a
    // bad command line (exit 2), before anything runs.
    const color::ColorConfig colors = color::ColorConfig::fromEnvironment();
    validateJob(o->job, colors);
    std::vector<pipeline::ComposeResult> runs;
    for (int i = 0; i <= *repeat; ++i) {
      if (!globals.quiet)
        std::fprintf(stderr, "compose: bench: %s run %d\n", i == 0 ? "cold" : "warm", i);
      runs.push_back(pipeline::runCompose(o->job, colors));
    }
    auto median = [](std::vector<double> v) {
      std::sort(v.begin(), v.end());
      return v.empty() ? 0.0 : v[v.size() / 2];
    };
    std::printf("%-10s %10s %10s %8s  %s\n", "stage", "cold s", "warm s", "peak MB", "warm state");
    double coldTotal = 0.0;
    std::vector<double> warmTotals(runs.size() - 1, 0.0);
    int64_t peak = 0;
    for (size_t s = 0; s < runs[0].stages.size(); ++s) {
      const pipeline::StageRecord& cold = runs[0].stages[s];
      std::vector<double> warm;
      for (size_t r = 1; r < runs.size(); ++r) {
        warm.push_back(runs[r].stages[s].seconds);
        warmTotals[r - 1] += runs[r].stages[s].seconds;
      }
      coldTotal += cold.seconds;
      peak = std::max(peak, cold.peakBytes);
      std::printf("%-10s %10.3f %10.3f %8.0f  %s\n", cold.name.c_str(), cold.seconds, median(warm),
                  double(cold.peakBytes) / 1e6, pipeline::stateName(runs.back().stages[s].state));
    }
    std::printf("%-10s %10.3f %10.3f %8.0f  (%dx%d plate, %d warm runs)\n", "total", coldTotal,
                median(warmTotals), double(peak) / 1e6, runs[0].width, runs[0].height, *repeat);
    return 0;
  };
}

}  // namespace compose::app
