// Running the compose executable from the end-to-end tests, as a user runs it from a shell: its
// exit status and what it printed, captured in files of the test's scratch folder.
//
// Every end-to-end test target is compiled with COMPOSE_EXECUTABLE, the path of the compose
// executable it tests.
#pragma once

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace compose::testing {

struct CommandResult {
  int status = -1;  // the exit status; -1 when the command did not exit (a signal)
  std::string out, err;
};

// The whole content of a file ("" when it cannot be read).
inline std::string slurp(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// One word for sh: in single quotes, a single quote inside closed, escaped and reopened.
inline std::string quote(const std::string& text) {
  std::string q = "'";
  for (char c : text) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}
inline std::string quote(const std::filesystem::path& path) {
  return quote(path.string());
}
inline std::string quote(const char* text) {
  return quote(std::string(text));
}

// Runs a command line with sh, its input from /dev/null, its output and errors to the two files
// (and read back).
inline CommandResult runShell(const std::string& command, const std::filesystem::path& outFile,
                              const std::filesystem::path& errFile) {
  const std::string line =
      "{ " + command + "; } >" + quote(outFile) + " 2>" + quote(errFile) + " </dev/null";
  const int raw = std::system(line.c_str());
  CommandResult r;
  r.status = WIFEXITED(raw) ? WEXITSTATUS(raw) : -1;
  r.out = slurp(outFile);
  r.err = slurp(errFile);
  return r;
}

// Runs compose with `args` (each word already quoted where it needs to be), its output and errors
// captured in `scratch`/stdout.txt and stderr.txt. `environment` goes before the command
// ("COMPOSE_RESPONSE_DIR='...'").
inline CommandResult runCompose(const std::string& args, const std::filesystem::path& scratch,
                                const std::string& environment = {}) {
  return runShell(
      environment + (environment.empty() ? "" : " ") + quote(COMPOSE_EXECUTABLE) + " " + args,
      scratch / "stdout.txt", scratch / "stderr.txt");
}

}  // namespace compose::testing
