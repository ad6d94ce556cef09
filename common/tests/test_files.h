#pragma once
// Helpers for tests that read and write files: the committed fixtures and a
// scratch directory per test.

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include <gtest/gtest.h>
#include <unistd.h>

namespace penumbra::testing {

/// common/tests/data in the source tree.
inline std::filesystem::path TestData(std::string_view name) {
  return std::filesystem::path(PENUMBRA_TEST_DATA_DIR) / name;
}

/// The repository root (where scenes/ lives).
inline std::filesystem::path SourceDir() { return std::filesystem::path(PENUMBRA_SOURCE_DIR); }

/// A fresh directory for the running test, removed when the object dies.
class ScratchDir {
 public:
  ScratchDir() {
    const auto* test = ::testing::UnitTest::GetInstance()->current_test_info();
    // Parameterised tests have '/' in their names.
    std::string name = std::string(test->test_suite_name()) + "_" + test->name();
    std::replace(name.begin(), name.end(), '/', '_');
    path_ = std::filesystem::temp_directory_path() / ("penumbra_" + name + "_" + std::to_string(getpid()));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(std::string_view name) const { return path_ / name; }

  /// Writes `content` to `name` in the directory and returns its path.
  std::filesystem::path Write(std::string_view name, std::string_view content) const {
    const auto file = path_ / name;
    std::ofstream(file, std::ios::binary) << content;
    return file;
  }

 private:
  std::filesystem::path path_;
};

}  // namespace penumbra::testing
