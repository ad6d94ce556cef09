// The HUD's words (issue 16): the no-renderer warning, progress with totals
// and units, and refinement as open-ended.

#include "penumbra/client/hud_text.h"

#include <gtest/gtest.h>

namespace penumbra::client {
namespace {

using namespace std::chrono_literals;

HudState ConnectedHud() {
  HudState s;
  s.scene = "cornell-box";
  s.connected = true;
  s.connection = "connected";
  return s;
}

TEST(HudTextTest, NoRendererConnectedSaysHowManySamplesWait) {
  HudState s = ConnectedHud();
  s.progress.renderersConnected = 0;
  s.pendingSamples = 1234;
  s.progress.stage1Total = 1234;
  const HudProgressText text = DescribeProgress(s);
  EXPECT_EQ(text.warning, "No renderer connected \u2014 1,234 samples waiting");
  EXPECT_EQ(text.barText, "0 of 1,234 samples");
  EXPECT_TRUE(text.rate.empty()) << "no rate or time left while nothing can arrive: " << text.rate;
}

TEST(HudTextTest, BeforeTheFirstDeltaItSaysWhatIsGoingOnInsteadOfZeroCounts) {
  HudState s = ConnectedHud();
  s.scene.clear();
  EXPECT_EQ(DescribeProgress(s).stage, "Waiting for the scene's description from the SMA");
  EXPECT_FALSE(DescribeProgress(s).showBar);
  s = ConnectedHud();
  HudProgressText text = DescribeProgress(s);
  EXPECT_EQ(text.stage, "Finding the visible triangles: the SMA traces the view");
  EXPECT_FALSE(text.showBar) << "no '0 of 0 samples'";
  // Once stage 1 has a count, or triangles arrived (all of them cached), the bar is back.
  s.progress.stage1Total = 10;
  EXPECT_EQ(DescribeProgress(s).stage, "Shading the view");
  s.progress.stage1Total = 0;
  s.triangles = 5;
  EXPECT_EQ(DescribeProgress(s).stage, "Shading the view");
}

TEST(HudTextTest, Stage1ShowsCountsRateAndTimeLeftWithUnits) {
  HudState s = ConnectedHud();
  s.progress.renderersConnected = 2;
  s.pendingSamples = 3000;
  s.progress.stage1Total = 4000;
  s.progress.stage1Done = 1000;
  s.stage1PerSecond = 850.0;
  s.stage1Left = 4s;
  const HudProgressText text = DescribeProgress(s);
  EXPECT_TRUE(text.warning.empty());
  EXPECT_EQ(text.renderers, "2 renderers connected");
  EXPECT_EQ(text.stage, "Shading the view");
  EXPECT_TRUE(text.showBar);
  EXPECT_FLOAT_EQ(text.barFraction, 0.25f);
  EXPECT_EQ(text.barText, "1,000 of 4,000 samples");
  EXPECT_EQ(text.rate, "850 samples/s, about 4 s left");
}

TEST(HudTextTest, RefinementIsOpenEndedAndConvergenceIsFinal) {
  HudState s = ConnectedHud();
  s.progress.renderersConnected = 1;
  s.refining = true;
  s.progress.refinementTotal = 200;
  s.progress.refinementDone = 150;
  HudProgressText text = DescribeProgress(s);
  EXPECT_EQ(text.renderers, "1 renderer connected");
  EXPECT_EQ(text.barText, "150 of 200 new samples");
  EXPECT_NE(text.rate.find("more may follow"), std::string::npos);

  s.converged = true;
  s.pendingSamples = 0;
  text = DescribeProgress(s);
  EXPECT_FALSE(text.showBar);
  EXPECT_EQ(text.stage, "Done: the image is final until the camera moves");
}

TEST(HudTextTest, AnSmaThatDoesNotSayGivesNoRendererLine) {
  HudState s = ConnectedHud();
  s.pendingSamples = 10;  // progress.renderersConnected unset: an older SMA
  const HudProgressText text = DescribeProgress(s);
  EXPECT_TRUE(text.warning.empty());
  EXPECT_TRUE(text.renderers.empty());
}

TEST(HudTextTest, EveryFigureCarriesItsUnit) {
  HudState s = ConnectedHud();
  s.triangles = 12345;
  s.vertices = 6789;
  s.framesPerSecond = 59.7;
  s.bytesPerSecond = 1.5e6;
  s.moveToFirstUpdateMs = 35.4;
  s.walkSpeed = 0.52f;
  const auto lines = DescribeFigures(s);
  ASSERT_EQ(lines.size(), 4u);
  EXPECT_EQ(lines[0], "12,345 triangles, 6,789 vertices held");
  EXPECT_EQ(lines[1], "60 frames/s, receiving 1.5 MB/s");
  EXPECT_EQ(lines[2], "Response to the last camera move: 35 ms");
  EXPECT_EQ(lines[3], "Walking speed: 0.52 scene units/s");
  s.framesPerSecond = 0.4;  // software GL on a loaded machine
  EXPECT_EQ(DescribeFigures(s)[1], "0.4 frames/s, receiving 1.5 MB/s");
  s.scene.clear();  // before the SMA's SceneInfo: no walking speed yet
  EXPECT_EQ(DescribeFigures(s).size(), 3u);
}

}  // namespace
}  // namespace penumbra::client
