// The refinement driver (refinement_driver.h) on a real hierarchy and cache,
// with no server: the session's rules for stepping, the sample cap, and the
// liveness rule that once stalled NLD_IS.

#include "penumbra/sma/refinement_driver.h"

#include <shared_mutex>

#include <gtest/gtest.h>

#include "shadow_grid_scene.h"

namespace penumbra::sma {
namespace {

bool ChildrenShaded(const Node& n, const void* c) {
  for (VertexId m : n.mid)
    if (m != kNoVertex && !static_cast<const SampleCache*>(c)->IsShaded(m)) return false;
  return true;
}

// The SMA's shared state and what its session does between steps: samples
// arrive (the renderers), the view is re-mapped.
struct World {
  Scene scene = GridScene();
  Hierarchy hierarchy{scene};
  SampleCache cache;
  std::shared_mutex stateMutex;
  std::unique_ptr<VisibilityTracer> tracer;
  HitBuffer hits;
  VisibleSet visible;
  std::vector<VertexId> requested;  // what steps asked the renderers for

  World() {
    auto t = VisibilityTracer::Build(scene);
    EXPECT_TRUE(t.ok());
    tracer = std::move(*t);
    CameraView view;
    view.pose = CameraPose{Vec3(3, 5, 3), Vec3(3, 0, 3), Vec3(0, 0, -1)};
    view.fovYDeg = 45.0f;
    view.width = view.height = kImage;
    tracer->Trace(view, hits);
    cache.Reserve(hierarchy.VertexCount());
    ShadeRequested(nullptr, AllBaseVertices());
    Remap();
  }
  std::vector<VertexId> AllBaseVertices() const {
    std::vector<VertexId> all;
    for (VertexId v = 0; v < hierarchy.VertexCount(); ++v) all.push_back(v);
    return all;
  }
  RefinementStepContext Context() {
    return RefinementStepContext{stateMutex, hierarchy, cache, DragoParams{}, nullptr,
                                 [this](std::span<const VertexId> created) {
                                   requested.insert(requested.end(), created.begin(), created.end());
                                 }};
  }
  // The renderers answer: a hard shadow edge at x = kShadowEdgeX.
  void ShadeRequested(RefinementDriver* driver, std::vector<VertexId> vertices) {
    std::vector<ShadedSample> samples;
    for (VertexId v : vertices) {
      if (cache.IsShaded(v)) continue;
      const float e = hierarchy.GetVertex(v).position.x < kShadowEdgeX ? 1.0f : 0.01f;
      samples.push_back(ShadedSample{v, Rgb(0.5f * e * kInvPi), Rgb(e)});
    }
    cache.Store(samples);
    if (driver)
      for (VertexId v : vertices) driver->OnSampleArrived(v);
  }
  void ShadeAllRequested(RefinementDriver& driver) { ShadeRequested(&driver, std::exchange(requested, {})); }
  void Remap() { MapHitsToNodes(hierarchy, hits, &ChildrenShaded, &cache, visible); }
  RefinementStep Step(RefinementDriver& driver, bool remapDue = false) {
    return RefinementDriver::RunStep(driver.CurrentRefiner(), hits, visible, driver.Outstanding(remapDue), Context());
  }
};

RefinementParams EdgeParams() {
  RefinementParams p;
  p.criterion = Criterion::kNldOs;
  p.largeFraction = 1.0f;
  p.batch = 16;
  return p;
}

TEST(RefinementDriverTest, KeepsSteppingUntilTheCriterionHasNothingLeft) {
  World w;
  RefinementDriver driver(EdgeParams(), 1'000'000);
  EXPECT_EQ(driver.StartStep(/*stage1Done=*/false), RefinementDriver::Start::kNothing);  // waits for stage 1
  const size_t nodesBefore = w.hierarchy.NodeCount();
  int steps = 0;
  bool finished = false;
  while (!finished && steps < 500) {
    ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep) << "step " << steps;
    EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kNothing);  // one step at a time
    RefinementStep step = w.Step(driver);
    ++steps;
    switch (driver.OnStepDone(std::move(step), w.cache, /*remapPending=*/false)) {
      case RefinementDriver::After::kStepAgain:
      case RefinementDriver::After::kWait:
        // The session: the renderers answer, the arrival re-maps the view.
        EXPECT_FALSE(driver.Finished());
        w.ShadeAllRequested(driver);
        w.Remap();
        break;
      case RefinementDriver::After::kStepNow:
        break;
      case RefinementDriver::After::kFinished:
        finished = true;
        break;
      case RefinementDriver::After::kStale:
        FAIL() << "no new view was taken";
    }
  }
  ASSERT_TRUE(finished) << steps << " steps";
  EXPECT_TRUE(driver.Finished());
  EXPECT_GT(steps, 3);
  EXPECT_GT(w.hierarchy.NodeCount(), nodesBefore);
  EXPECT_GT(driver.Splits(), 0u);
  EXPECT_EQ(driver.Samples(), driver.SamplesTotal());
  EXPECT_EQ(driver.SamplesDone(), driver.SamplesTotal());
  EXPECT_EQ(driver.PendingSamples(), 0u);
  // Nothing is left: a fresh refiner on the final mesh finds nothing to split.
  Refiner fresh(EdgeParams());
  EXPECT_TRUE(fresh.Select(w.hierarchy, w.cache, w.hits, w.visible, DragoParams{}, false).empty());
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kNothing);
}

// The NLD_IS stall, in its general form: a step that finds nothing to split
// because samples were on their way, while those samples arrive and the
// re-map completes before the step reports. Nothing else will wake
// refinement, so the report itself must ask for the next step.
TEST(RefinementDriverTest, NeverStallsWhenTheRefreshWasDoneWhileAStepRan) {
  World w;
  RefinementParams p = EdgeParams();
  p.batch = 100000;  // the first step takes every leaf that qualifies
  RefinementDriver driver(p, 1'000'000);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep first = w.Step(driver);
  ASSERT_GT(first.chosen, 0u);
  ASSERT_EQ(driver.OnStepDone(std::move(first), w.cache, false), RefinementDriver::After::kStepAgain);
  ASSERT_GT(driver.PendingSamples(), 0u);

  // The next step starts with the splits unshaded: it may not conclude.
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep second = w.Step(driver);
  EXPECT_EQ(second.chosen, 0u);
  EXPECT_FALSE(second.exhausted);
  // Meanwhile the samples arrive and the re-map is made.
  w.ShadeAllRequested(driver);
  w.Remap();
  EXPECT_EQ(driver.PendingSamples(), 0u);
  EXPECT_EQ(driver.OnStepDone(std::move(second), w.cache, /*remapPending=*/false), RefinementDriver::After::kStepNow);
  // ... and looking again finds the children along the edge to split.
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep third = w.Step(driver);
  EXPECT_GT(third.chosen, 0u);
  EXPECT_EQ(driver.OnStepDone(std::move(third), w.cache, false), RefinementDriver::After::kStepAgain);
}

TEST(RefinementDriverTest, WaitsWhenARemapOrSamplesWillWakeIt) {
  World w;
  RefinementParams p = EdgeParams();
  p.batch = 100000;
  RefinementDriver driver(p, 1'000'000);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  ASSERT_EQ(driver.OnStepDone(w.Step(driver), w.cache, false), RefinementDriver::After::kStepAgain);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  // Samples still on their way: their arrival (a re-map) wakes it.
  EXPECT_EQ(driver.OnStepDone(w.Step(driver), w.cache, false), RefinementDriver::After::kWait);
  w.ShadeAllRequested(driver);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  // All shaded, but the re-map showing the children is due: it wakes it.
  EXPECT_EQ(driver.OnStepDone(w.Step(driver, /*remapDue=*/true), w.cache, /*remapPending=*/true),
            RefinementDriver::After::kWait);
  EXPECT_FALSE(driver.Finished());
}

TEST(RefinementDriverTest, TheSampleCapEndsTheViewsRefinement) {
  World w;
  RefinementDriver driver(EdgeParams(), /*maxSamplesPerView=*/1);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep step = w.Step(driver);
  const size_t created = step.created.size();
  ASSERT_GT(created, 1u);
  EXPECT_EQ(driver.OnStepDone(std::move(step), w.cache, false), RefinementDriver::After::kStepAgain);
  EXPECT_EQ(driver.Requested(), created);
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kCapReached);
  EXPECT_FALSE(driver.Finished());  // its splits still await samples
  w.ShadeAllRequested(driver);
  EXPECT_TRUE(driver.Finished());
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kNothing);
  // A move restarts the same view's refinement, within the same budget.
  driver.RestartSameView();
  EXPECT_EQ(driver.Requested(), created);
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kCapReached);
  // A new view starts again, with a fresh budget.
  driver.Restart();
  EXPECT_EQ(driver.Requested(), 0u);
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
}

// A move while a step runs replaces its Refiner: the step comes back stale,
// and still counts against the view's cap (an animation moves at every
// step); a step of a view since replaced does not.
TEST(RefinementDriverTest, AStepReplacedByAMoveStillCountsAgainstTheViewsCap) {
  World w;
  RefinementDriver driver(EdgeParams(), /*maxSamplesPerView=*/1);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep step = w.Step(driver);
  const size_t created = step.created.size();
  ASSERT_GT(created, 0u);
  driver.RestartSameView();  // the move, while the step ran
  EXPECT_EQ(driver.OnStepDone(std::move(step), w.cache, false), RefinementDriver::After::kStale);
  EXPECT_EQ(driver.Requested(), created);
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kCapReached);

  RefinementDriver other(EdgeParams(), /*maxSamplesPerView=*/1);
  ASSERT_EQ(other.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep old = w.Step(other);
  other.Restart();  // a new view while the step ran
  EXPECT_EQ(other.OnStepDone(std::move(old), w.cache, false), RefinementDriver::After::kStale);
  EXPECT_EQ(other.Requested(), 0u);
  EXPECT_EQ(other.StartStep(true), RefinementDriver::Start::kStep);
}

TEST(RefinementDriverTest, AStepOfAReplacedRefinerIsStaleAndCountsNothing) {
  World w;
  RefinementDriver driver(EdgeParams(), 1'000'000);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep step = w.Step(driver);
  ASSERT_GT(step.chosen, 0u);
  driver.Restart();  // a new view while the step ran
  EXPECT_EQ(driver.OnStepDone(std::move(step), w.cache, false), RefinementDriver::After::kStale);
  EXPECT_EQ(driver.Splits(), 0u);
  EXPECT_EQ(driver.PendingSamples(), 0u);
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
}

TEST(RefinementDriverTest, SamplesAlreadyShadedWhenTheStepReportsAreNotWaitedFor) {
  World w;
  RefinementDriver driver(EdgeParams(), 1'000'000);
  ASSERT_EQ(driver.StartStep(true), RefinementDriver::Start::kStep);
  RefinementStep step = w.Step(driver);
  ASSERT_FALSE(step.created.empty());
  w.ShadeRequested(&driver, step.created);  // faster than the step's report
  w.requested.clear();
  EXPECT_EQ(driver.OnStepDone(std::move(step), w.cache, false), RefinementDriver::After::kStepAgain);
  EXPECT_EQ(driver.PendingSamples(), 0u);
  EXPECT_EQ(driver.SamplesDone(), driver.SamplesTotal());
  EXPECT_GT(driver.SamplesTotal(), 0u);
}

TEST(RefinementDriverTest, OffWhenTheCriterionIsNone) {
  RefinementParams p;
  p.criterion = Criterion::kNone;
  RefinementDriver driver(p, 100);
  EXPECT_FALSE(driver.Enabled());
  EXPECT_TRUE(driver.Finished());
  EXPECT_EQ(driver.StartStep(true), RefinementDriver::Start::kNothing);
}

}  // namespace
}  // namespace penumbra::sma
