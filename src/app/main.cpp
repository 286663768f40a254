// compose: put a synthetic diffuse object into a photograph, lit by the place the photo shows.
// This file only parses the command line and maps errors to exit statuses; the commands are in
// cmd_*.cpp and the work is in the libraries.
#include <algorithm>
#include <csignal>
#include <cstdio>
#include <iostream>
#include <new>
#include <regex>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "app/cli.h"
#include "color/color.h"
#include "core/error.h"

namespace {

// An option given an empty value (--yaw "", --env "") is a mistake, never "the default": CLI11
// reads "" as 0 for numbers and keeps it as an empty path. Throws UsageError naming the option.
// CLI11's wording of two common mistakes, in the user's terms.
std::string cliMessage(const std::string& what) {
  std::smatch m;
  static const std::regex conversion(R"(^Could not convert: (\S+) = (.*)$)");
  static const std::regex repeated(R"(^(\S+): At Most 1 required but received (\d+)$)");
  if (std::regex_match(what, m, conversion))
    return m[1].str() + " cannot take '" + m[2].str() +
           "': not a number of the kind it takes, or out of its range";
  if (std::regex_match(what, m, repeated))
    return m[1].str() + " is given " + m[2].str() + " times: give it once";
  return what;
}

void requireValues(const CLI::App& app) {
  for (const CLI::Option* option : app.get_options()) {
    if (option->count() == 0 || option->get_expected_min() == 0) continue;  // absent, or a flag
    for (const std::string& value : option->results()) {
      if (value.empty()) throw compose::UsageError(option->get_name() + " is given an empty value");
    }
  }
  for (const CLI::App* sub : app.get_subcommands()) requireValues(*sub);
}

// A command given an option that only the one-shot command has (compose composite --yaw 45), or
// one of its own options before its name (compose --exposure 1 render ...): CLI11 passes it to the
// top level, where it would be taken and silently not used. Throws UsageError naming it.
void refuseOneShotOptions(const CLI::App& app, const CLI::App& command,
                          const std::vector<const CLI::Option*>& everyCommand) {
  // The command's full name and its innermost parsed level (compose calib lens).
  std::string name = command.get_name();
  const CLI::App* innermost = &command;
  for (bool deeper = true; deeper;) {
    deeper = false;
    for (const CLI::App* sub : innermost->get_subcommands()) {
      if (!sub->parsed()) continue;
      name += " " + sub->get_name();
      innermost = sub;
      deeper = true;
      break;
    }
  }
  for (const CLI::Option* option : app.get_options()) {
    if (option->count() == 0) continue;
    if (std::find(everyCommand.begin(), everyCommand.end(), option) != everyCommand.end()) continue;
    bool own = false;
    for (const std::string& n : option->get_lnames())
      own = own || innermost->get_option_no_throw("--" + n) != nullptr;
    if (own) {
      throw compose::UsageError(option->get_name() + " is an option of compose " + name +
                                ": give it after the command's name");
    }
    throw compose::UsageError(option->get_name() + " is not an option of compose " + name +
                              " (the one-shot command takes it; compose " + name +
                              " --help lists this command's options)");
  }
}

}  // namespace

int main(int argc, char** argv) {
  using namespace compose::app;
  CLI::App app{
      "compose: insert a synthetic diffuse object into a photograph, lit by an HDR environment of "
      "the place.\n\n"
      "One shot:   compose --plate PHOTO --object MESH [--env ENV] [--out BASE]\n"
      "            writes BASE.exr (scene-linear, with the object layer and AOVs) and BASE.jpg\n"
      "Stage by stage: compose COMMAND ... (compose COMMAND --help for each)",
      "compose"};
  app.require_subcommand(0, 1);
  app.set_version_flag("--version", std::string("compose ") + COMPOSE_VERSION);
  Globals globals;
  // The options every command takes. The others of the top level are the one-shot command's: a
  // command reaches them only through CLI11's fallthrough, and they are refused there below.
  const std::vector<const CLI::Option*> everyCommand = {
      app.add_flag("-q,--quiet", globals.quiet, "Print only the output paths and errors"),
      app.add_option("--max-pixels", globals.limits.maxPixels,
                     "Refuse images larger than this many pixels, before decoding them (any "
                     "command)")
          ->capture_default_str(),
      app.add_option("--max-triangles", globals.limits.maxTriangles,
                     "Refuse meshes of more triangles than this, before loading them (any "
                     "command)")
          ->capture_default_str(),
      app.add_option("--ocio", globals.ocio,
                     "OpenColorIO config file to use instead of $OCIO ('builtin': the built-in "
                     "one; any command)")};

  std::vector<std::pair<CLI::App*, Runner>> runners;
  for (const Command& c : commands()) {
    CLI::App* sub = app.add_subcommand(c.name, c.summary);
    sub->fallthrough();
    runners.emplace_back(sub, c.setup(*sub, globals));
  }
  Runner oneShot = setupCompose(app, globals);

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    // A one-shot option given before a command's name is the first thing to say (a value the
    // command misses may be that very option).
    for (auto& [sub, run] : runners) {
      if (!sub->parsed()) continue;
      try {
        refuseOneShotOptions(app, *sub, everyCommand);
        // An option only the command has, given before its name.
        for (int i = 1; i < argc && argv[i] != sub->get_name(); ++i) {
          const std::string word = argv[i];
          if (word.size() < 2 || word[0] != '-') continue;
          const std::string name = word.substr(0, word.find('='));
          if (sub->get_option_no_throw(name) && !app.get_option_no_throw(name))
            throw compose::UsageError(name + " is an option of compose " + sub->get_name() +
                                      ": give it after the command's name");
        }
      } catch (const compose::UsageError& u) {
        std::fprintf(stderr, "compose: error: %s\n(run compose --help for usage)\n",
                     compose::printable(u.describe()).c_str());
        return 2;
      }
    }
    std::cerr << "compose: error: cli: " << compose::printable(cliMessage(e.what()))
              << "\n(run compose --help for usage)\n";
    return 2;
  }

  // A file-size limit (ulimit -f) makes a write fail with "File too large" instead of killing
  // the process: the failed write is then reported, and the outputs stay as they were.
  std::signal(SIGXFSZ, SIG_IGN);
  try {
    requireValues(app);
    compose::setResourceLimits(globals.limits);
    if (!globals.ocio.empty()) compose::color::ColorConfig::useConfig(globals.ocio);
    for (auto& [sub, run] : runners) {
      if (!sub->parsed()) continue;
      refuseOneShotOptions(app, *sub, everyCommand);
      return run();
    }
    return oneShot();
  } catch (const compose::UsageError& e) {
    std::fprintf(stderr, "compose: error: %s\n(run compose --help for usage)\n",
                 compose::printable(e.describe()).c_str());
    return 2;
  } catch (const compose::Error& e) {
    std::fprintf(stderr, "compose: error: %s\n", compose::printable(e.describe()).c_str());
    return 1;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr,
                 "compose: error: out of memory: the machine or its limits (ulimit -v) allow less "
                 "than this job needs\n");
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "compose: error: %s\n", compose::printable(e.what()).c_str());
    return 1;
  }
}
