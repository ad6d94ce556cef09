// Camera movement prediction (issue 15) on real processes: one renderer, two
// SMAs on Sponza -- one with --prediction on, one off -- and the same scripted
// client on each, walking backward in a straight line. With prediction on, the
// SMA asks for samples beyond the current view, and the next view along the
// walk finds more of its newly visible triangles already shaded.

#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <string>
#include <thread>

#include "penumbra/common/scene.h"
#include "support/service.h"
#include "support/sma_client.h"

namespace penumbra::testing {
namespace {

using namespace std::chrono_literals;

const std::string kScene = std::string(PENUMBRA_SOURCE_DIR) + "/scenes/sponza.json";
const std::filesystem::path kMesh =
    std::filesystem::path(PENUMBRA_SOURCE_DIR).parent_path() / "shared/scenes/sponza-dabrovic/sponza.obj";

Service MustStart(const std::string& exe, const std::vector<std::string>& args, const std::string& tag) {
  auto s = StartService(exe, args, tag);
  EXPECT_TRUE(s.ok()) << s.error().message;
  return s.ok() ? std::move(*s) : Service{};
}

double CounterOr(SmaTestClient& c, const std::string& name, double fallback = -1.0) {
  auto v = c.Counter(name);
  return v.ok() ? *v : fallback;
}

bool WaitFor(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    if (done()) return true;
    std::this_thread::sleep_for(20ms);
  }
  return false;
}

// The walk: looking down the atrium (+x), stepping backward 0.25 m per view.
CameraView WalkView(int step) {
  CameraView v;
  const Vec3 forward = glm::normalize(Vec3(1.0f, -0.05f, 0.0f));
  v.pose.eye = Vec3(2.0f, 2.0f, 0.0f) - forward * (0.25f * float(step));
  v.pose.target = v.pose.eye + forward;
  v.pose.up = Vec3(0, 1, 0);
  v.fovYDeg = 60.0f;
  v.width = 160;
  v.height = 120;
  return v;
}

struct WalkResult {
  double predictedViews = 0, samplesPredicted = 0;
  double lastNew = 0, lastNewShaded = 0;  // the last view's newly displayed triangles, and those shaded at once
};

// Views 0 (settled), 1 and 2 (100 ms apart: the camera moves), then, once
// the renderers are idle, view 3 -- one step further along the line.
WalkResult Walk(const Service& sma, bool predictionOn) {
  WalkResult r;
  auto client = SmaTestClient::Connect(sma.port, predictionOn ? "walker-on" : "walker-off");
  EXPECT_TRUE(client.ok()) << (client.ok() ? "" : client.error().message);
  if (!client.ok()) return r;
  SmaTestClient& c = *client;
  EXPECT_TRUE(c.SendView(WalkView(0), 1));
  EXPECT_TRUE(c.WaitConverged(1, 60s).ok()) << sma.process.LogTail();
  EXPECT_TRUE(c.SendView(WalkView(1), 2));
  std::this_thread::sleep_for(100ms);
  EXPECT_TRUE(c.SendView(WalkView(2), 3));
  EXPECT_TRUE(c.WaitConverged(3, 60s).ok()) << sma.process.LogTail();
  if (predictionOn) {
    EXPECT_TRUE(WaitFor([&] { return CounterOr(c, "predicted_views") >= 1.0; }, 10s))
        << "no predicted view traced\n" << sma.process.LogTail();
  }
  // Whatever was asked for is shaded before the next view is sent.
  EXPECT_TRUE(WaitFor(
      [&] {
        return CounterOr(c, "samples_queued_visible") == 0.0 && CounterOr(c, "samples_queued_predicted") == 0.0 &&
               CounterOr(c, "samples_in_flight") == 0.0;
      },
      30s))
      << sma.process.LogTail();
  r.predictedViews = CounterOr(c, "predicted_views");
  r.samplesPredicted = CounterOr(c, "samples_requested_predicted");
  const double newBefore = CounterOr(c, "view_triangles_new");
  const double shadedBefore = CounterOr(c, "view_triangles_new_shaded");
  EXPECT_TRUE(c.SendView(WalkView(3), 4));
  EXPECT_TRUE(c.WaitConverged(4, 60s).ok()) << sma.process.LogTail();
  r.lastNew = CounterOr(c, "view_triangles_new") - newBefore;
  r.lastNewShaded = CounterOr(c, "view_triangles_new_shaded") - shadedBefore;
  return r;
}

TEST(SmaPredictionTest, AStraightWalkIsShadedAheadOfTheClient) {
  if (!std::filesystem::exists(kMesh)) GTEST_SKIP() << kMesh << " is not there (../shared scenes)";
  Service renderer = MustStart(PENUMBRA_RENDERER_EXE,
                               {"--scene", kScene, "--threads", "2", "--spp", "16", "--max-bounces", "2"}, "renderer");
  ASSERT_FALSE(HasFailure());
  // No refinement or improvement: nothing but views and predictions asks for
  // samples, so the comparison is about prediction alone.
  const auto startSma = [&](const std::string& prediction) {
    return MustStart(PENUMBRA_SMA_EXE,
                     {"--scene", kScene, "--renderer", renderer.Address(), "--criterion", "none", "--improve-paths",
                      "0", "--prediction", prediction, "--prediction-horizon", "0.5"},
                     "sma-prediction-" + prediction);
  };
  WalkResult off, on;
  {
    Service sma = startSma("off");
    ASSERT_FALSE(HasFailure());
    off = Walk(sma, false);
    ASSERT_FALSE(HasFailure());
  }
  {
    Service sma = startSma("on");
    ASSERT_FALSE(HasFailure());
    on = Walk(sma, true);
    ASSERT_FALSE(HasFailure());
  }
  std::printf("prediction off: %g of %g newly displayed triangles shaded at once; on: %g of %g "
              "(%g predicted views, %g samples asked by prediction)\n",
              off.lastNewShaded, off.lastNew, on.lastNewShaded, on.lastNew, on.predictedViews, on.samplesPredicted);
  EXPECT_EQ(off.predictedViews, 0.0);
  EXPECT_EQ(off.samplesPredicted, 0.0);
  EXPECT_GE(on.predictedViews, 1.0);
  EXPECT_GT(on.samplesPredicted, 0.0) << "prediction asked for nothing beyond the current view";
  // The same views on the same scene: visibility, and so the triangles newly
  // displayed, are the same; only what was shaded before the view differs.
  EXPECT_EQ(on.lastNew, off.lastNew);
  ASSERT_GT(off.lastNew, 0.0) << "the step revealed nothing: the walk does not test prediction";
  EXPECT_GT(on.lastNewShaded, off.lastNewShaded) << "prediction prepared none of the next view's new triangles";
}

}  // namespace
}  // namespace penumbra::testing
