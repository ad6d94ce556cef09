#include "penumbra/renderer/reference.h"

#include <gtest/gtest.h>

#include <cstring>
#include <vector>

#include "penumbra/renderer/ray_scene.h"
#include "test_scenes.h"

namespace penumbra {
namespace {

using testing::AddHorizontalSquare;
using testing::Finish;
using testing::MakeMaterial;
using testing::TestScene;

// A grey plane (albedo 0.5, side 10) under a uniform sky L, seen from above
// at a slant: pixels on the plane read 0.5 L exactly (every cosine ray
// escapes: E = pi L), pixels past its far edge read L.
class ReferenceTest : public ::testing::Test {
 protected:
  ReferenceTest() {
    SceneBuilder b;
    AddHorizontalSquare(b, Vec3(0.0f), 10.0f, b.AddMaterial(MakeMaterial(Rgb(0.5f))), true);
    Scene scene;
    SkyLight sky;
    sky.zenith = sky.horizon = sky.ground = kSky;
    scene.sky = sky;
    t_ = Finish(b, std::move(scene));
    view_.pose.eye = Vec3(0.0f, 1.0f, 3.0f);
    view_.pose.target = Vec3(0.0f);
    view_.fovYDeg = 45.0f;
    view_.width = 24;
    view_.height = 16;
  }
  static constexpr Rgb kSky{0.2f, 0.4f, 0.8f};
  TestScene t_;
  CameraView view_;
};

Rgb Pixel(const Image& image, int x, int y) {
  const float* p = image.rgb.data() + 3 * (size_t(y) * size_t(image.width) + size_t(x));
  return Rgb(p[0], p[1], p[2]);
}

bool Near(const Rgb& a, const Rgb& b) { return glm::length(a - b) <= 1e-5f * glm::length(b); }

TEST_F(ReferenceTest, PixelsReadTheLitPlaneOrTheSky) {
  ShadingSettings settings;
  settings.pathsPerSample = 4;
  const Shader shader(t_.scene, *t_.rays, settings);
  ShadeCounters work;
  const Image image = RenderReference(shader, *t_.rays->Initial(), view_, 2, &work, PixelFilter::kCentre);
  ASSERT_EQ(image.width, view_.width);
  ASSERT_EQ(image.height, view_.height);
  ASSERT_EQ(image.rgb.size(), size_t(view_.width * view_.height * 3));

  EXPECT_TRUE(Near(Pixel(image, 12, 0), kSky));                 // above the far edge
  EXPECT_TRUE(Near(Pixel(image, 12, 15), 0.5f * kSky));         // the plane below the camera
  int planePixels = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const Rgb p = Pixel(image, x, y);
      EXPECT_TRUE(Near(p, kSky) || Near(p, 0.5f * kSky)) << "pixel " << x << ", " << y;
      planePixels += Near(p, 0.5f * kSky);
    }
  EXPECT_EQ(work.paths, uint64_t(planePixels) * 4u);
}

TEST_F(ReferenceTest, BoxFilterAveragesThePixelAreaAcrossTheHorizon) {
  ShadingSettings settings;
  settings.pathsPerSample = 256;
  const Shader shader(t_.scene, *t_.rays, settings);
  ShadeCounters work;
  const Image image = RenderReference(shader, *t_.rays->Initial(), view_, 2, &work, PixelFilter::kBox);
  // Pixels wholly on the plane or the sky read exactly those values; the
  // ones the plane's far edge crosses read something in between.
  int inBetween = 0;
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const Rgb p = Pixel(image, x, y);
      if (Near(p, kSky) || Near(p, 0.5f * kSky)) continue;
      // p = f * plane + (1 - f) * sky: recover f from the blue channel.
      const float f = (kSky.b - p.b) / (0.5f * kSky.b);
      EXPECT_GT(f, 0.0f) << "pixel " << x << ", " << y;
      EXPECT_LT(f, 1.0f) << "pixel " << x << ", " << y;
      EXPECT_TRUE(Near(p, f * 0.5f * kSky + (1.0f - f) * kSky)) << "pixel " << x << ", " << y;
      ++inBetween;
    }
  }
  EXPECT_GE(inBetween, view_.width / 2) << "the edge crosses every column of the image";
  EXPECT_LE(inBetween, 2 * view_.width);
  // Every path that hit the plane was counted once.
  EXPECT_GT(work.paths, 0u);
  EXPECT_LT(work.paths, uint64_t(image.width * image.height) * 256u);
}

TEST_F(ReferenceTest, ImageDoesNotDependOnTheThreadCount) {
  // A box so that paths bounce and differ from pixel to pixel.
  SceneBuilder b;
  testing::AddBox(b, Vec3(-2.0f, -1.0f, -2.0f), Vec3(2.0f, 2.0f, 4.0f), b.AddMaterial(MakeMaterial(Rgb(0.6f))), true);
  AddHorizontalSquare(b, Vec3(0.0f, 1.99f, 0.0f), 1.0f, b.AddMaterial(MakeMaterial(Rgb(0.0f), Rgb(10.0f))), false);
  const TestScene box = Finish(b);
  ShadingSettings settings;
  settings.pathsPerSample = 2;
  const Shader shader(box.scene, *box.rays, settings);
  const Image one = RenderReference(shader, *box.rays->Initial(), view_, 1);
  const Image three = RenderReference(shader, *box.rays->Initial(), view_, 3);
  ASSERT_EQ(one.rgb.size(), three.rgb.size());
  EXPECT_EQ(std::memcmp(one.rgb.data(), three.rgb.data(), one.rgb.size() * sizeof(float)), 0);
}

TEST_F(ReferenceTest, ProgressivePassesAverageToTheBoxFilteredImage) {
  ShadingSettings settings;
  const Shader shader(t_.scene, *t_.rays, settings);
  std::vector<float> sum;
  constexpr int kPasses = 64;
  for (int pass = 0; pass < kPasses; ++pass) AddProgressivePass(shader, *t_.rays->Initial(), view_, 2, uint64_t(pass), &sum);
  ASSERT_EQ(sum.size(), size_t(view_.width * view_.height * 3));
  // Each path reads the plane or the sky exactly, so the mean is one of
  // them where the pixel lies wholly on one, and in between across the edge.
  int inBetween = 0;
  for (int y = 0; y < view_.height; ++y)
    for (int x = 0; x < view_.width; ++x) {
      const float* s = sum.data() + 3 * (size_t(y) * size_t(view_.width) + size_t(x));
      const Rgb p = Rgb(s[0], s[1], s[2]) / float(kPasses);
      if (Near(p, kSky) || Near(p, 0.5f * kSky)) continue;
      const float f = (kSky.b - p.b) / (0.5f * kSky.b);
      EXPECT_GT(f, 0.0f) << "pixel " << x << ", " << y;
      EXPECT_LT(f, 1.0f) << "pixel " << x << ", " << y;
      ++inBetween;
    }
  EXPECT_GE(inBetween, view_.width / 2) << "the edge crosses every column of the image";
  EXPECT_LE(inBetween, 2 * view_.width);
}

TEST_F(ReferenceTest, ProgressivePassesAreDeterministicAndIndependent) {
  SceneBuilder b;
  testing::AddBox(b, Vec3(-2.0f, -1.0f, -2.0f), Vec3(2.0f, 2.0f, 4.0f), b.AddMaterial(MakeMaterial(Rgb(0.6f))), true);
  AddHorizontalSquare(b, Vec3(0.0f, 1.99f, 0.0f), 1.0f, b.AddMaterial(MakeMaterial(Rgb(0.0f), Rgb(10.0f))), false);
  const TestScene box = Finish(b);
  const Shader shader(box.scene, *box.rays, ShadingSettings{});
  std::vector<float> one, three, next;
  AddProgressivePass(shader, *box.rays->Initial(), view_, 1, 5, &one);
  AddProgressivePass(shader, *box.rays->Initial(), view_, 3, 5, &three);
  AddProgressivePass(shader, *box.rays->Initial(), view_, 2, 6, &next);
  ASSERT_EQ(one.size(), three.size());
  EXPECT_EQ(std::memcmp(one.data(), three.data(), one.size() * sizeof(float)), 0);
  EXPECT_NE(std::memcmp(one.data(), next.data(), one.size() * sizeof(float)), 0) << "pass 6 repeats pass 5";

  // Many passes converge to the reference: the mean radiance of 256 passes
  // is within 3 % of a 256-path box-filtered image's.
  std::vector<float> sum;
  for (int pass = 0; pass < 256; ++pass) AddProgressivePass(shader, *box.rays->Initial(), view_, 2, uint64_t(pass), &sum);
  ShadingSettings many;
  many.pathsPerSample = 256;
  const Shader reference(box.scene, *box.rays, many);
  const Image image = RenderReference(reference, *box.rays->Initial(), view_, 2);
  double progressiveTotal = 0.0, referenceTotal = 0.0;
  for (size_t i = 0; i < sum.size(); ++i) {
    progressiveTotal += sum[i] / 256.0;
    referenceTotal += image.rgb[i];
  }
  EXPECT_GT(referenceTotal, 0.0);
  EXPECT_NEAR(progressiveTotal / referenceTotal, 1.0, 0.03);
}

}  // namespace
}  // namespace penumbra
