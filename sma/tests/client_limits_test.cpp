// The pure logic of the per-client resource limits (client_limits.h) and
// of the texture frames every client shares (texture_frames.h).

#include <gtest/gtest.h>

#include <functional>
#include <vector>

#include "penumbra/common/math.h"
#include "penumbra/sma/client_limits.h"
#include "penumbra/sma/texture_frames.h"

namespace penumbra::sma {
namespace {

TEST(VisibilityBudgetTest, GrowsWithinTheCapacityAndAlwaysShrinks) {
  VisibilityBudget budget(100);
  uint64_t a = 0, b = 0;
  EXPECT_TRUE(budget.Resize(a, 60));
  EXPECT_EQ(a, 60u);
  EXPECT_FALSE(budget.Resize(b, 41));  // 101 > 100: refused, nothing changes
  EXPECT_EQ(b, 0u);
  EXPECT_EQ(budget.Used(), 60u);
  EXPECT_TRUE(budget.Resize(b, 40));  // exactly full
  EXPECT_EQ(budget.Used(), 100u);
  EXPECT_FALSE(budget.Resize(a, 61));
  EXPECT_EQ(a, 60u);
  // A holder replacing its view counts only the difference: a client moving
  // its camera in a full budget is not refused.
  EXPECT_TRUE(budget.Resize(a, 60));
  EXPECT_TRUE(budget.Resize(a, 10));  // shrinking
  EXPECT_EQ(budget.Used(), 50u);
  EXPECT_TRUE(budget.Resize(b, 90));
  EXPECT_TRUE(budget.Resize(a, 0));
  EXPECT_TRUE(budget.Resize(b, 0));
  EXPECT_EQ(budget.Used(), 0u);
}

TEST(ClientRefinementLimitsTest, TheFuzzedOptionsAreEachRefusedByName) {
  const ClientRefinementLimits limits;  // defaults: s_req >= 0.01, min_pixels >= 1, depth <= 16, R <= 1024
  const RefinementParams current;       // the operator's defaults
  auto refused = [&](const RefinementParams& p, const std::string& field) {
    auto ok = CheckClientRefinement(p, current, limits);
    ASSERT_FALSE(ok) << field;
    EXPECT_NE(ok.error().message.find(field), std::string::npos) << ok.error().message;
    EXPECT_NE(ok.error().message.find("--client-"), std::string::npos) << ok.error().message;
  };
  RefinementParams p = current;
  p.sReq = 0.0f;
  refused(p, "s_req");
  p = current;
  p.minPixels = 0.0f;
  refused(p, "min_pixels");
  p = current;
  p.maxDepth = 20;
  refused(p, "max_depth");
  p = current;
  p.batch = 1000000;
  refused(p, "batch");
  // At the limits, and anything unchanged, is taken.
  p = current;
  p.sReq = limits.minSReq;
  p.minPixels = limits.minMinPixels;
  p.maxDepth = uint8_t(limits.maxDepth);
  p.batch = limits.maxBatch;
  EXPECT_TRUE(CheckClientRefinement(p, current, limits));
  // The operator's own defaults are not the client's to be refused for.
  RefinementParams generous = current;
  generous.sReq = 0.001f;
  generous.maxDepth = 20;
  EXPECT_TRUE(CheckClientRefinement(generous, generous, limits));
}

TEST(TextureRequestLimitTest, AtMostTheLimitOutstanding) {
  EXPECT_TRUE(TextureRequestAllowed(0, 2));
  EXPECT_TRUE(TextureRequestAllowed(1, 2));
  EXPECT_FALSE(TextureRequestAllowed(2, 2));
}

Texture Uniform(int width, int height, float value) {
  Texture t;
  t.width = width;
  t.height = height;
  t.texels.assign(size_t(width) * size_t(height), Rgb(value));
  return t;
}

TEST(TextureFramesTest, BoxFiltersInLinearSpaceUntilItFits) {
  // 4x2 texels: left half black, right half white. With room for 2 texels
  // it is halved once: 2x1, each the average of a 2x2 block.
  Texture t = Uniform(4, 2, 0.0f);
  for (int y = 0; y < 2; ++y) {
    t.texels[size_t(y) * 4 + 2] = Rgb(1.0f);
    t.texels[size_t(y) * 4 + 3] = Rgb(1.0f);
  }
  t.texels[0] = Rgb(1.0f);  // the left block averages 0.25 (linear)
  const wire::TextureData d = EncodeTextureData(t, 7, 2 * 3);
  EXPECT_EQ(d.texture(), 7u);
  ASSERT_EQ(d.width(), 2u);
  ASSERT_EQ(d.height(), 1u);
  ASSERT_EQ(d.rgb8().size(), 6u);
  EXPECT_EQ(uint8_t(d.rgb8()[0]), uint8_t(std::lround(LinearToSrgb(0.25f) * 255.0f)));  // 137, not 64
  EXPECT_EQ(uint8_t(d.rgb8()[3]), 255);
  // Room for all: unchanged size.
  EXPECT_EQ(EncodeTextureData(t, 0, 4 * 2 * 3).width(), 4u);
}

TEST(TextureFramesTest, EachTextureIsEncodedOnceWhateverTheRequests) {
  Scene scene;
  scene.textures.push_back(Uniform(8, 8, 0.5f));
  scene.textures.push_back(Uniform(4, 4, 1.0f));
  std::vector<std::function<void()>> jobs;  // run by hand: "another thread"
  TextureFrames frames(scene, 1 << 20, [&](std::function<void()> job) { jobs.push_back(std::move(job)); });
  int ready = 0;
  std::vector<TextureFrames::Frame> got;
  for (int i = 0; i < 300; ++i)
    EXPECT_EQ(frames.Get(0, [&](TextureFrames::Frame f) {
      ++ready;
      got.push_back(f);
    }),
              nullptr);
  ASSERT_EQ(jobs.size(), 1u);  // one encoding for 300 requests
  EXPECT_EQ(frames.EncodedCount(), 0u);
  jobs[0]();
  EXPECT_EQ(ready, 300);
  EXPECT_EQ(frames.EncodedCount(), 1u);
  for (const auto& f : got) EXPECT_EQ(f, got[0]);  // one shared frame
  // Now served at once, with no job.
  EXPECT_EQ(frames.Get(0, [](TextureFrames::Frame) { ADD_FAILURE() << "not called when ready"; }), got[0]);
  EXPECT_EQ(jobs.size(), 1u);
  EXPECT_EQ(frames.Get(1, [](TextureFrames::Frame) {}), nullptr);
  EXPECT_EQ(jobs.size(), 2u);
}

TEST(TextureFramesTest, PreparedAtLoadRequestsWaitForTheEncodingAlreadyStarted) {
  Scene scene;
  scene.textures.push_back(Uniform(8, 8, 0.5f));
  scene.textures.push_back(Uniform(4, 4, 1.0f));
  scene.textures.push_back(Uniform(2, 2, 0.25f));
  std::vector<std::function<void()>> jobs;
  TextureFrames frames(scene, 1 << 20, [&](std::function<void()> job) { jobs.push_back(std::move(job)); });
  frames.PrepareAll();
  ASSERT_EQ(jobs.size(), 3u);  // every texture, before any request
  jobs[0]();
  // Encoded: served at once. Being encoded: waits for that job, starts none.
  EXPECT_NE(frames.Get(0, [](TextureFrames::Frame) { ADD_FAILURE() << "not called when ready"; }), nullptr);
  TextureFrames::Frame later;
  EXPECT_EQ(frames.Get(2, [&](TextureFrames::Frame f) { later = f; }), nullptr);
  EXPECT_EQ(jobs.size(), 3u);
  frames.PrepareAll();  // nothing new to start
  EXPECT_EQ(jobs.size(), 3u);
  jobs[2]();
  ASSERT_NE(later, nullptr);
  jobs[1]();
  EXPECT_EQ(frames.EncodedCount(), 3u);
}

}  // namespace
}  // namespace penumbra::sma
