#include "penumbra/common/image_metrics.h"

#include <random>

#include <gtest/gtest.h>

namespace penumbra {
namespace {

RgbImage Noise(int w, int h, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.05f, 2.0f);
  RgbImage img{w, h, {}};
  for (int i = 0; i < w * h; ++i) img.pixels.push_back(Rgb(u(rng), u(rng), u(rng)));
  return img;
}

TEST(ImageMetricsTest, IdenticalImagesHaveNoErrorAndSsimOne) {
  const RgbImage a = Noise(32, 24, 1);
  EXPECT_EQ(*RelativeMeanAbsoluteError(a, a), 0.0);
  EXPECT_NEAR(*ToneMappedSsim(a, a), 1.0, 1e-12);
}

TEST(ImageMetricsTest, RelativeErrorOfAScaledImage) {
  const RgbImage a = Noise(16, 16, 2);
  RgbImage b = a;
  for (Rgb& p : b.pixels) p *= 1.1f;
  // |1.1 x - x| / |x| = 0.1 everywhere.
  EXPECT_NEAR(*RelativeMeanAbsoluteError(b, a), 0.1, 1e-6);
}

TEST(ImageMetricsTest, MeanRatioOfAScaledImage) {
  const RgbImage a = Noise(16, 16, 3);
  RgbImage b = a;
  for (Rgb& p : b.pixels) p *= 0.9f;
  EXPECT_NEAR(*MeanLuminanceRatio(b, a), 0.9, 1e-6);
}

// A box blur keeps flat regions and the mean of a periodic pattern, and takes
// pixel noise down by the square root of its window.
TEST(ImageMetricsTest, BoxBlurAveragesItsWindow) {
  RgbImage flat{8, 6, std::vector<Rgb>(48, Rgb(0.5f, 1.0f, 2.0f))};
  for (const Rgb& p : BoxBlur(flat, 2).pixels) EXPECT_EQ(p, Rgb(0.5f, 1.0f, 2.0f));
  const RgbImage noise = Noise(200, 200, 4);
  const RgbImage blurred = BoxBlur(noise, 2);
  double mean = 0.0, varianceBefore = 0.0, varianceAfter = 0.0;
  for (const Rgb& p : noise.pixels) mean += p.r;
  mean /= double(noise.pixels.size());
  for (size_t i = 0; i < noise.pixels.size(); ++i) {
    varianceBefore += (noise.pixels[i].r - mean) * (noise.pixels[i].r - mean);
    varianceAfter += (blurred.pixels[i].r - mean) * (blurred.pixels[i].r - mean);
  }
  EXPECT_NEAR(varianceAfter / varianceBefore, 1.0 / 25.0, 0.01);
}

TEST(ImageMetricsTest, SsimDropsWithNoiseAndIsTheLuminanceTermOnFlatImages) {
  const int w = 64, h = 48;
  RgbImage smooth{w, h, {}};
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) smooth.pixels.push_back(Rgb(0.2f + float(x) / float(w)));
  RgbImage noisy = smooth;
  std::mt19937 rng(3);
  std::normal_distribution<float> n(0.0f, 0.1f);
  for (Rgb& p : noisy.pixels) p = glm::max(p + Rgb(n(rng)), Rgb(0.0f));
  const double ssim = *ToneMappedSsim(noisy, smooth);
  EXPECT_LT(ssim, 0.95);
  EXPECT_GT(ssim, 0.0);
  // Two flat images: no structure, so SSIM is its luminance term alone.
  const float la = 0.5f, lb = 0.6f;
  const std::vector<float> a(size_t(w * h), la), b(size_t(w * h), lb);
  const double expected = (2.0 * la * lb + 1e-4) / (double(la) * la + double(lb) * lb + 1e-4);
  EXPECT_NEAR(*Ssim(a, b, w, h), expected, 1e-9);
}

TEST(ImageMetricsTest, MismatchedSizesAreErrors) {
  EXPECT_FALSE(RelativeMeanAbsoluteError(Noise(4, 4, 1), Noise(4, 5, 1)).ok());
  RgbImage black{2, 2, std::vector<Rgb>(4, Rgb(0.0f))};
  EXPECT_FALSE(RelativeMeanAbsoluteError(black, black).ok());
}

}  // namespace
}  // namespace penumbra
