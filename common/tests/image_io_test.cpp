#include "penumbra/common/image_io.h"

#include <cmath>
#include <fstream>
#include <iterator>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "penumbra/common/math.h"
#include "test_files.h"

namespace penumbra {
namespace {

using testing::kLinearOfSrgb128;
using testing::ScratchDir;
using testing::TestData;


// A 57-byte PNG declaring 8192 x 8191 pixels (just under kMaxImagePixels)
// used to cost 1.6 GiB before its error: the decoded bytes are bounded too,
// and checked before anything is allocated.
TEST(ImageIoTest, ImageThatWouldDecodeTooLargeIsRefusedBeforeAllocating) {
  ScratchDir dir;
  const long rssBefore = testing::PeakRssMiB();
  for (auto [w, h] : {std::pair{8192u, 8191u}, std::pair{5000u, 5000u}}) {
    const auto file = dir.Write("big.png", testing::PngDeclaringSize(w, h));
    auto image = ReadImage(file);
    ASSERT_FALSE(image.ok()) << w << "x" << h;
    EXPECT_NE(image.error().message.find("MiB decoded"), std::string::npos) << image.error().message;
    EXPECT_NE(image.error().message.find("big.png"), std::string::npos) << image.error().message;
  }
  EXPECT_LT(testing::PeakRssMiB() - rssBefore, 64) << "MiB taken by refused images";
  // Within the limits, the same header is read and fails on its missing data.
  auto small = ReadImage(dir.Write("small.png", testing::PngDeclaringSize(64, 64)));
  ASSERT_FALSE(small.ok());
  EXPECT_EQ(small.error().message.find("MiB decoded"), std::string::npos) << small.error().message;
}

TEST(ImageIoTest, PngStoresSrgbEncodedBytes) {
  ScratchDir dir;
  // 2x1: black, linear 0.2158605 (sRGB 128), white / overexposed, and a NaN.
  const std::vector<float> linear = {0.0f, kLinearOfSrgb128, 1.0f, 4.0f, NAN, -1.0f};
  ASSERT_TRUE(WriteImage(dir / "out.png", 2, 1, linear).ok());
  auto image = ReadImage(dir / "out.png");
  ASSERT_TRUE(image.ok()) << image.error().message;
  EXPECT_EQ(image->width, 2);
  EXPECT_EQ(image->height, 1);
  EXPECT_FALSE(image->storedAsFloat);
  const std::vector<float> stored = {0.0f, 128.0f / 255.0f, 1.0f, 1.0f, 0.0f, 0.0f};
  ASSERT_EQ(image->rgb.size(), stored.size());
  for (size_t i = 0; i < stored.size(); ++i) EXPECT_NEAR(image->rgb[i], stored[i], 1e-6f) << i;
}

TEST(ImageIoTest, ExrKeepsLinearFloatsExactly) {
  ScratchDir dir;
  const std::vector<float> linear = {0.0f, 0.25f, 1.0f, 17.0f, 12.5f, 1e-3f};
  ASSERT_TRUE(WriteImage(dir / "out.EXR", 1, 2, linear).ok());
  auto image = ReadImage(dir / "out.EXR");
  ASSERT_TRUE(image.ok()) << image.error().message;
  EXPECT_TRUE(image->storedAsFloat);
  EXPECT_EQ(image->width, 1);
  EXPECT_EQ(image->height, 2);
  EXPECT_EQ(image->rgb, linear);
}

// Screenshots carry their coverage in alpha: an RGBA .exr keeps colour and
// alpha exactly and unassociated (a pixel drawn black is not background).
TEST(ImageIoTest, ExrAlphaRoundTripsUnassociatedAndOnlyWhereAsked) {
  ScratchDir dir;
  const std::vector<float> linear = {0.0f, 0.0f, 0.0f, 0.5f, 2.0f, 0.25f, 3.0f, 1.0f, 0.0f};
  const std::vector<float> alpha = {1.0f, 0.25f, 0.0f};
  ASSERT_TRUE(WriteImage(dir / "rgba.exr", 3, 1, linear, alpha).ok());
  auto withAlpha = ReadImageWithAlpha(dir / "rgba.exr");
  ASSERT_TRUE(withAlpha.ok()) << withAlpha.error().message;
  EXPECT_EQ(withAlpha->rgb, linear) << "colour not premultiplied by alpha either way";
  EXPECT_EQ(withAlpha->alpha, alpha);
  auto plain = ReadImage(dir / "rgba.exr");
  ASSERT_TRUE(plain.ok()) << plain.error().message;
  EXPECT_EQ(plain->rgb, linear);
  EXPECT_TRUE(plain->alpha.empty()) << "ReadImage drops alpha";
  // An RGB file has no alpha to keep.
  ASSERT_TRUE(WriteImage(dir / "rgb.exr", 3, 1, linear).ok());
  auto noAlpha = ReadImageWithAlpha(dir / "rgb.exr");
  ASSERT_TRUE(noAlpha.ok()) << noAlpha.error().message;
  EXPECT_TRUE(noAlpha->alpha.empty());
  // Alpha goes to .exr only, and must have one value a pixel.
  for (const char* other : {"rgba.png", "rgba.hdr", "rgba.jpg"}) {
    const auto wrote = WriteImage(dir / other, 3, 1, linear, alpha);
    ASSERT_FALSE(wrote.ok()) << other;
    EXPECT_NE(wrote.error().message.find(other), std::string::npos) << wrote.error().message;
  }
  EXPECT_FALSE(WriteImage(dir / "short.exr", 3, 1, linear, std::vector<float>{1.0f, 1.0f}).ok());
}

TEST(ImageIoTest, HdrAndJpegRoundTripApproximately) {
  ScratchDir dir;
  const std::vector<float> linear = {0.5f, 2.0f, 8.0f};
  ASSERT_TRUE(WriteImage(dir / "out.hdr", 1, 1, linear).ok());
  auto hdr = ReadImage(dir / "out.hdr");
  ASSERT_TRUE(hdr.ok()) << hdr.error().message;
  EXPECT_TRUE(hdr->storedAsFloat);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(hdr->rgb[c], linear[c], 0.01f * linear[c]);  // RGBE: 8-bit mantissas

  const std::vector<float> grey(8 * 8 * 3, kLinearOfSrgb128);
  ASSERT_TRUE(WriteImage(dir / "out.jpg", 8, 8, grey).ok());
  auto jpeg = ReadImage(dir / "out.jpg");
  ASSERT_TRUE(jpeg.ok()) << jpeg.error().message;
  EXPECT_FALSE(jpeg->storedAsFloat);
  EXPECT_NEAR(jpeg->rgb[0], 128.0f / 255.0f, 2.0f / 255.0f);
}

TEST(ImageIoTest, ReadsTopRowFirst) {
  auto image = ReadImage(TestData("checker_2x2.png"));
  ASSERT_TRUE(image.ok()) << image.error().message;
  // Top row red, green; bottom row blue, grey 128 (see make_fixtures.py).
  const std::vector<float> expected = {1, 0, 0, 0, 1, 0, 0, 0, 1, 128 / 255.0f, 128 / 255.0f, 128 / 255.0f};
  ASSERT_EQ(image->rgb.size(), expected.size());
  for (size_t i = 0; i < expected.size(); ++i) EXPECT_NEAR(image->rgb[i], expected[i], 1e-6f) << i;
}

TEST(ImageIoTest, ReadsFromMemory) {
  std::ifstream in(TestData("checker_2x2.png"), std::ios::binary);
  const std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto image = ReadImageFromMemory(std::as_bytes(std::span(bytes)), "png", "embedded checker");
  ASSERT_TRUE(image.ok()) << image.error().message;
  EXPECT_EQ(image->width, 2);
  EXPECT_NEAR(image->rgb[3 * 2 + 2], 1.0f, 1e-6f);  // bottom-left is blue

  auto garbage = ReadImageFromMemory(std::as_bytes(std::span(bytes).first(20)), "png", "embedded checker");
  ASSERT_FALSE(garbage.ok());
  EXPECT_NE(garbage.error().message.find("embedded checker"), std::string::npos) << garbage.error().message;
}

TEST(ImageIoTest, BadRequestsAreErrorsNamingTheFile) {
  ScratchDir dir;
  const std::vector<float> pixel = {0.5f, 0.5f, 0.5f};
  auto expectError = [](const Status& status, const std::string& mention) {
    ASSERT_FALSE(status.ok());
    EXPECT_NE(status.error().message.find(mention), std::string::npos) << status.error().message;
  };
  expectError(WriteImage(dir / "out.tif", 1, 1, pixel), "out.tif");
  expectError(WriteImage(dir / "short.png", 2, 1, pixel), "short.png");
  expectError(WriteImage(dir / "empty.png", 0, 0, {}), "empty.png");
  expectError(WriteImage(dir / "no_such_dir" / "out.png", 1, 1, pixel), "out.png");

  auto status = [](const Expected<Image>& image) { return image.ok() ? Status::Ok() : Status(image.error()); };
  expectError(status(ReadImage(dir / "missing.png")), "missing.png");
  expectError(status(ReadImage(dir.path())), dir.path().string());
  expectError(status(ReadImage(dir.Write("garbage.png", "definitely not a PNG file"))), "garbage.png");
  expectError(status(ReadImage(dir.Write("empty.jpg", ""))), "empty.jpg");
}

}  // namespace
}  // namespace penumbra
