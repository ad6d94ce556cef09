// The headless run's policy (headless_run.h) on made-up observations and a
// made-up clock: when a run is done, when it has failed and why, which
// snapshots it writes, and the screenshots' formats and pixel filter.

#include "penumbra/client/headless_run.h"

#include <gtest/gtest.h>

namespace penumbra::client {
namespace {

using Clock = std::chrono::steady_clock;
using std::chrono::milliseconds;
using std::chrono::seconds;

const Clock::time_point kStart = Clock::time_point() + std::chrono::hours(1);

HeadlessObservation Connected() {
  HeadlessObservation seen;
  seen.connection = ConnectionState::kConnected;
  seen.disconnectedSince = kStart;
  return seen;
}

TEST(HeadlessRunTest, FramesAndSecondsEndTheRunWhateverTheView) {
  HeadlessGoal frames;
  frames.stopWhen = StopWhen::kFrames;
  frames.frames = 3;
  HeadlessRun byFrames(frames, "sma:7200", kStart);
  HeadlessObservation seen = Connected();
  seen.framesDrawn = 1;
  EXPECT_FALSE(byFrames.GoalMet(seen, kStart));
  seen.framesDrawn = 2;  // the third frame is the last
  EXPECT_TRUE(byFrames.GoalMet(seen, kStart));

  HeadlessGoal time;
  time.stopWhen = StopWhen::kSeconds;
  time.seconds = 1.5;
  HeadlessRun bySeconds(time, "sma:7200", kStart);
  EXPECT_FALSE(bySeconds.GoalMet(Connected(), kStart + milliseconds(1499)));
  EXPECT_TRUE(bySeconds.GoalMet(Connected(), kStart + milliseconds(1500)));
  // Neither fails for want of convergence.
  EXPECT_FALSE(bySeconds.Failure(Connected(), kStart + seconds(100000)).has_value());
}

TEST(HeadlessRunTest, ConvergedNeedsTheWholePathAndTheSmasCountersOrTheirGrace) {
  HeadlessRun run(HeadlessGoal{}, "sma:7200", kStart);
  HeadlessObservation seen = Connected();
  seen.converged = true;
  EXPECT_FALSE(run.GoalMet(seen, kStart + seconds(1))) << "the path has not ended";
  seen.pathFinished = true;
  seen.converged = false;
  EXPECT_FALSE(run.GoalMet(seen, kStart + seconds(2))) << "not converged";

  // Converged, counters not yet confirming: wait up to the grace (2 s).
  seen.converged = true;
  EXPECT_FALSE(run.GoalMet(seen, kStart + seconds(3)));
  EXPECT_FALSE(run.GoalMet(seen, kStart + seconds(4)));
  seen.countersCurrent = true;
  EXPECT_TRUE(run.GoalMet(seen, kStart + seconds(4)));
  seen.countersCurrent = false;
  EXPECT_TRUE(run.GoalMet(seen, kStart + seconds(5)));  // 2 s after convergence

  // A view that stops being converged (a new delta) restarts the grace.
  seen.converged = false;
  EXPECT_FALSE(run.GoalMet(seen, kStart + seconds(6)));
  seen.converged = true;
  EXPECT_FALSE(run.GoalMet(seen, kStart + seconds(7)));
  EXPECT_TRUE(run.GoalMet(seen, kStart + seconds(9)));
}

TEST(HeadlessRunTest, FailuresSayWhatWasMissing) {
  HeadlessGoal goal;
  goal.connectTimeout = seconds(15);
  goal.convergeTimeout = seconds(600);
  HeadlessRun run(goal, "sma.example:7200", kStart);

  HeadlessObservation waiting;
  waiting.connection = ConnectionState::kWaiting;
  waiting.disconnectedSince = kStart + seconds(5);
  waiting.lastError = "connection refused";
  EXPECT_FALSE(run.Failure(waiting, kStart + seconds(20)).has_value());
  auto failure = run.Failure(waiting, kStart + seconds(21));
  ASSERT_TRUE(failure.has_value());
  EXPECT_EQ(*failure, "no connection to the SMA at sma.example:7200 for 15 s (last error: connection refused)");
  waiting.lastError.clear();
  EXPECT_NE(run.Failure(waiting, kStart + seconds(21))->find("(last error: none)"), std::string::npos);

  HeadlessObservation slow = Connected();
  slow.samplesPending = 12;
  slow.trianglesHeld = 3400;
  EXPECT_FALSE(run.Failure(slow, kStart + seconds(600)).has_value());
  failure = run.Failure(slow, kStart + seconds(601));
  ASSERT_TRUE(failure.has_value());
  EXPECT_EQ(*failure, "the view did not converge within 600 s (12 samples pending, 3400 triangles held)");
}

TEST(HeadlessRunTest, SnapshotsAreTakenWhenTheImageChangedAndTheIntervalPassed) {
  SnapshotSchedule none(seconds(0), "run/snap");
  EXPECT_FALSE(none.Due(kStart, 10, 1, 0).has_value());

  SnapshotSchedule every(seconds(2), "run/snap");
  EXPECT_FALSE(every.Due(kStart, 0, 1, 0).has_value()) << "nothing held";
  EXPECT_FALSE(every.Due(kStart, 10, 0, 0).has_value()) << "no delta applied yet";
  auto first = every.Due(kStart, 10, 4, 7);
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->string(), "run/snap_000007.exr");
  every.Written(kStart, 4);
  EXPECT_FALSE(every.Due(kStart + seconds(5), 10, 4, 30).has_value()) << "unchanged image";
  EXPECT_FALSE(every.Due(kStart + seconds(1), 10, 5, 12).has_value()) << "too soon";
  EXPECT_EQ(every.Due(kStart + seconds(2), 10, 5, 14)->string(), "run/snap_000014.exr");
  every.Stop();
  EXPECT_FALSE(every.Due(kStart + seconds(9), 10, 6, 99).has_value()) << "stopped after a failure";
}

TEST(HeadlessRunTest, ScreenshotStemsAreSafeFileNamesWhateverTheSmaCallsItsScene) {
  EXPECT_EQ(ScreenshotStem("cornell-box", "20261124-1600"), "penumbra-cornell-box-20261124-1600");
  EXPECT_EQ(ScreenshotStem("../../etc/passwd", "t"), "penumbra-_._.._etc_passwd-t");
  EXPECT_EQ(ScreenshotStem("..", "t"), "penumbra-_.-t");
  EXPECT_EQ(ScreenshotStem("/abs\\path", "t"), "penumbra-_abs_path-t");
  EXPECT_EQ(ScreenshotStem("", "t"), "penumbra-scene-t");
  EXPECT_EQ(ScreenshotStem("caf\xc3\xa9 bar", "t"), "penumbra-caf___bar-t");
  EXPECT_EQ(ScreenshotStem(std::string(1000, 'a'), "t"), "penumbra-" + std::string(64, 'a') + "-t");
  for (const char* hostile : {"../x", "a/b", "..", ".", "x\0y"}) {
    const std::string stem = ScreenshotStem(hostile, "t");
    EXPECT_EQ(stem.find('/'), std::string::npos) << hostile;
    EXPECT_EQ(std::filesystem::path(stem).filename().string(), stem) << hostile;
  }
}

TEST(HeadlessRunTest, ScreenshotFormatsAndTheBoxFilter) {
  EXPECT_TRUE(IsRadianceFile("a/b.exr"));
  EXPECT_TRUE(IsRadianceFile("B.HDR"));
  EXPECT_FALSE(IsRadianceFile("shot.png"));
  EXPECT_FALSE(IsRadianceFile("exr"));
  EXPECT_TRUE(StoresCoverage("a/b.EXR"));
  EXPECT_FALSE(StoresCoverage("b.hdr"));
  EXPECT_FALSE(StoresCoverage("shot.png"));

  // 4x2 pixels, 2x2 boxes: two pixels, each its box's mean; a fifth column
  // that does not fill a box is dropped.
  const std::vector<float> pixels = {
      1, 0, 0, 3, 0, 0, 10, 1, 0, 10, 1, 0, 99, 99, 99,  //
      1, 0, 4, 3, 0, 4, 10, 1, 0, 10, 1, 0, 99, 99, 99,
  };
  const std::vector<float> filtered = BoxFilter(pixels, 5, 2, 2);
  ASSERT_EQ(filtered.size(), 6u);
  EXPECT_FLOAT_EQ(filtered[0], 2.0f);
  EXPECT_FLOAT_EQ(filtered[2], 2.0f);
  EXPECT_FLOAT_EQ(filtered[3], 10.0f);
  EXPECT_FLOAT_EQ(filtered[4], 1.0f);
  EXPECT_EQ(BoxFilter(pixels, 5, 2, 1), pixels);
  // One channel (a coverage mask): a box half drawn is 0.5.
  const std::vector<float> coverage = {1, 1, 0, 1, 1, 1, 1, 0};
  EXPECT_EQ(BoxFilter(coverage, 4, 2, 2, 1), (std::vector<float>{1.0f, 0.5f}));
}

}  // namespace
}  // namespace penumbra::client
