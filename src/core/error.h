// Errors in compose come in two kinds (see the stage contract in pipeline/compose_job.h):
//
//  * A broken invariant is a bug. It is checked with COMPOSE_CHECK, which prints the failed
//    condition with its source location and aborts.
//  * Bad user input or bad data is not a bug. It is reported by throwing compose::Error, which
//    carries the stage that noticed it and the file involved (if any). Only main() catches it and
//    prints `compose: error: <stage>: <what> (<file>)` with a non-zero exit status.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <stdexcept>
#include <string>

namespace compose {

// `text` with the control characters a file can smuggle into a message (ESC sequences that
// retitle or recolour a terminal, a carriage return that overwrites the line, C1 controls such as
// CSI, raw or UTF-8 encoded) written as \xNN; newlines and tabs are kept. For messages and notes
// printed to a terminal, which quote names and text from untrusted files.
inline std::string printable(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  auto escape = [&out](unsigned char c) {
    char escaped[8];
    std::snprintf(escaped, sizeof escaped, "\\x%02x", unsigned(c));
    out += escaped;
  };
  for (size_t i = 0; i < text.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(text[i]);
    const unsigned char next = i + 1 < text.size() ? static_cast<unsigned char>(text[i + 1]) : 0;
    if ((c < 0x20 && c != '\n' && c != '\t') || c == 0x7f || (c >= 0x80 && c <= 0x9f)) {
      escape(c);  // C0, DEL, and a C1 byte that is not inside a UTF-8 sequence
    } else if (c == 0xc2 && next >= 0x80 && next <= 0x9f) {
      escape(c);  // U+0080..U+009F, the C1 controls in UTF-8
      escape(next);
      ++i;
    } else {
      out += char(c);
      // The continuation bytes of a UTF-8 sequence (0x80..0xBF) are copied with their lead.
      const int more = c >= 0xf0 ? 3 : c >= 0xe0 ? 2 : c >= 0xc0 ? 1 : 0;
      for (int k = 0; k < more && i + 1 < text.size() &&
                      (static_cast<unsigned char>(text[i + 1]) & 0xc0) == 0x80;
           ++k)
        out += text[++i];
    }
  }
  return out;
}

class Error : public std::runtime_error {
 public:
  // `stage` is a short lower-case name ("ingest", "color", "lighting", "render", "composite",
  // "cli", ...). `file` may be empty when no file is involved.
  Error(std::string stage, const std::string& what, std::filesystem::path file = {})
      : std::runtime_error(what), stage_(std::move(stage)), file_(std::move(file)) {}

  const std::string& stage() const { return stage_; }
  const std::filesystem::path& file() const { return file_; }

  // "<stage>: <what> (<file>)", the form main() prints after "compose: error: ".
  std::string describe() const {
    std::string s = stage_.empty() ? std::string(what()) : stage_ + ": " + what();
    if (!file_.empty()) s += " (" + file_.string() + ")";
    return s;
  }

 private:
  std::string stage_;
  std::filesystem::path file_;
};

// Bad command-line usage (an option out of range, a malformed value, an unknown name): exit
// status 2, reported before any file is read. Its stage is "cli" unless a library stage that
// validates its own parameters (e.g. "lighting") says otherwise.
class UsageError : public Error {
 public:
  explicit UsageError(const std::string& what, std::string stage = "cli")
      : Error(std::move(stage), what) {}
};

namespace detail {
[[noreturn]] inline void checkFailed(const char* cond, const char* file, int line) {
  std::fprintf(stderr, "compose: internal error: check failed: %s at %s:%d\n", cond, file, line);
  std::abort();
}
}  // namespace detail

}  // namespace compose

// Invariant check, active in every build type.
#define COMPOSE_CHECK(cond) \
  ((cond) ? (void)0 : ::compose::detail::checkFailed(#cond, __FILE__, __LINE__))
