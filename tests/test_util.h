// Shared helpers for the test suite.
#pragma once

#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <string>

#include "core/error.h"

namespace compose::testing {

// A fresh, empty folder for one test, removed when the object goes away.
class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    path_ = std::filesystem::path(::testing::TempDir()) /
            ("compose-" + std::string(info ? info->name() : "test") + "-" +
             std::to_string(::getpid()) + "-" + std::to_string(counter++));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

inline void writeText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

}  // namespace compose::testing

// Expects `statement` to throw compose::Error whose describe() contains `needle`.
#define COMPOSE_EXPECT_ERROR(statement, needle)                                                   \
  do {                                                                                            \
    try {                                                                                         \
      statement;                                                                                  \
      ADD_FAILURE() << "expected compose::Error containing '" << (needle) << "', nothing thrown"; \
    } catch (const ::compose::Error& e) {                                                         \
      EXPECT_NE(e.describe().find(needle), std::string::npos)                                     \
          << "message: " << e.describe() << "\nexpected to contain: " << (needle);                \
    }                                                                                             \
  } while (0)
