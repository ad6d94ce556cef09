#pragma once
// Helpers for tests that read and write files: the committed fixtures, the
// scenes, a scratch directory per test, and the checks they share.

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <unistd.h>

#include "penumbra/common/math.h"

namespace penumbra::testing {

/// common/tests/data in the source tree.
inline std::filesystem::path TestData(std::string_view name) {
  return std::filesystem::path(PENUMBRA_TEST_DATA_DIR) / name;
}

/// The repository root (where scenes/ lives).
inline std::filesystem::path SourceDir() { return std::filesystem::path(PENUMBRA_SOURCE_DIR); }

/// The Cornell box mesh shipped in the repository.
inline std::filesystem::path CornellBoxObj() { return SourceDir() / "scenes/cornell-box/CornellBox-Original.obj"; }

/// A file of ../shared/scenes (beside the repository; tests skip without it).
inline std::filesystem::path SharedScene(std::string_view relative) {
  return SourceDir() / "../shared/scenes" / relative;
}

/// Linear value whose sRGB encoding is exactly 128/255 (the fixtures' grey).
inline constexpr float kLinearOfSrgb128 = 0.2158605f;

/// Each component of `actual` within `tolerance` of `expected`'s.
inline void ExpectNear(const Vec3& actual, const Vec3& expected, float tolerance, const std::string& what = "") {
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(actual[i], expected[i], tolerance) << what << " component " << i;
}

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

/// A PNG of `width` x `height` 8-bit RGB pixels whose image data is a valid
/// but empty zlib stream: its header is all a decoder needs to decide how
/// much to allocate, and the file stays 57 bytes whatever the size declared.
inline std::string PngDeclaringSize(uint32_t width, uint32_t height) {
  auto be32 = [](uint32_t v) {
    return std::string{char(v >> 24), char((v >> 16) & 0xff), char((v >> 8) & 0xff), char(v & 0xff)};
  };
  auto crc32 = [](std::string_view bytes) {
    uint32_t c = 0xffffffffu;
    for (unsigned char b : bytes) {
      c ^= b;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xedb88320u ^ (c >> 1) : c >> 1;
    }
    return ~c;
  };
  auto chunk = [&](std::string_view type, const std::string& data) {
    const std::string body = std::string(type) + data;
    return be32(uint32_t(data.size())) + body + be32(crc32(body));
  };
  const std::string ihdr = be32(width) + be32(height) + std::string("\x08\x02\x00\x00\x00", 5);
  return std::string("\x89PNG\r\n\x1a\n", 8) + chunk("IHDR", ihdr) +
         chunk("IDAT", std::string("\x78\x9c\x03\x00\x00\x00\x00\x01", 8)) + chunk("IEND", "");
}

/// Peak resident memory of this process so far (getrusage), in MiB.
inline long PeakRssMiB() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024;
}

}  // namespace penumbra::testing
