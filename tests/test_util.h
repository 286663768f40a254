// Shared helpers for the test suite.
#pragma once

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include <glm/vec3.hpp>

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

// `count` unit vectors spread uniformly over the sphere, reproducible from `seed`.
inline std::vector<glm::vec3> randomNormals(int count, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> g;
  std::vector<glm::vec3> out;
  while (int(out.size()) < count) {
    // One draw at a time: the order of a call's argument evaluation is unspecified in C++ (GCC
    // and clang differ); this is the order the GCC builds used.
    const float z = g(rng), y = g(rng), x = g(rng);
    const glm::vec3 v(x, y, z);
    const float len = std::sqrt(v.x * v.x + v.y * v.y + v.z * v.z);
    if (len > 1e-3f) out.push_back(v / len);
  }
  return out;
}

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
