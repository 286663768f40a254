// Shared pieces of the libFuzzer targets (tests/fuzz/README.md).
//
// A target feeds one input to one of our readers and checks two things: the reader either
// succeeds with a result that keeps its documented invariants, or throws compose::Error naming a
// stage and saying what is wrong. Any other exception (a JSON library's type error, std::bad_alloc,
// std::out_of_range) escapes to libFuzzer and is reported as a crash: main() would print it
// without the stage or the file. A broken invariant is checked with FUZZ_CHECK and aborts.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include "core/error.h"

namespace compose::fuzz {

// A scratch folder for this process (readers take paths): $TMPDIR/compose-fuzz-<pid>, removed at
// exit.
inline const std::filesystem::path& scratch() {
  static const std::filesystem::path dir = [] {
    const char* tmp = std::getenv("TMPDIR");
    std::filesystem::path d = std::filesystem::path(tmp && *tmp ? tmp : "/tmp") /
                              ("compose-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(d);
    std::atexit([] {
      std::error_code ec;
      std::filesystem::remove_all(scratch(), ec);
    });
    return d;
  }();
  return dir;
}

// Writes `size` bytes to `name` in the scratch folder and returns its path.
inline std::filesystem::path writeInput(const std::string& name, const uint8_t* data, size_t size) {
  const std::filesystem::path p = scratch() / name;
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), std::streamsize(size));
  return p;
}

// A compose::Error must say something and name a stage.
inline void checkNamed(const Error& e) {
  if (e.stage().empty() || std::string_view(e.what()).empty()) {
    std::fprintf(stderr, "error without a stage or a message: '%s'\n", e.describe().c_str());
    std::abort();
  }
}

// Reads the input as a stream of small numbers and bytes.
class Bytes {
 public:
  Bytes(const uint8_t* data, size_t size) : data_(data), size_(size) {}
  bool empty() const { return pos_ >= size_; }
  uint8_t byte() { return pos_ < size_ ? data_[pos_++] : 0; }
  uint32_t u32() {
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v = (v << 8) | byte();
    return v;
  }
  float f32() {
    const uint32_t bits = u32();
    float f;
    static_assert(sizeof f == sizeof bits);
    __builtin_memcpy(&f, &bits, sizeof f);
    return f;
  }
  // The rest up to the next '\n' (or the end) as text.
  std::string line() {
    std::string s;
    while (pos_ < size_ && data_[pos_] != '\n') s.push_back(char(data_[pos_++]));
    if (pos_ < size_) ++pos_;
    return s;
  }
  std::string rest() {
    std::string s(reinterpret_cast<const char*>(data_ + pos_), size_ - pos_);
    pos_ = size_;
    return s;
  }

 private:
  const uint8_t* data_;
  size_t size_, pos_ = 0;
};

}  // namespace compose::fuzz

// An invariant of a reader's result; a failure is a bug the fuzzer found.
#define FUZZ_CHECK(cond)                                                                   \
  do {                                                                                     \
    if (!(cond)) {                                                                         \
      std::fprintf(stderr, "fuzz check failed: %s at %s:%d\n", #cond, __FILE__, __LINE__); \
      std::abort();                                                                        \
    }                                                                                      \
  } while (0)
