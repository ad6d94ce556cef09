// The headless client's scripted moves (--moves FILE): the text format,
// every mistake named with its line, names resolved against the SceneInfo,
// parts left out kept from the move before, and playback in time.

#include "penumbra/client/moves_file.h"

#include <cmath>
#include <filesystem>
#include <fstream>

#include <fmt/format.h>
#include <glm/trigonometric.hpp>
#include <gtest/gtest.h>

#include "support/process.h"

namespace penumbra::client {
namespace {

using namespace std::chrono_literals;

std::string Refusal(std::string_view text) {
  auto moves = ParseMoves(text);
  return moves ? std::string("accepted") : moves.error().message;
}

ClientScene SceneWithBoxAndFan() {
  ClientScene scene;
  scene.name = "cornell";
  ClientObject box;
  box.name = "box";
  box.objectToWorld = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(15.0f), Vec3(0.3f, 0.4f, 0.5f));
  ClientObject fan;
  fan.name = "ceiling fan";
  fan.animated = true;
  ClientObject chair;
  chair.name = "my chair";
  scene.objects = {box, fan, chair};
  return scene;
}

TEST(MovesFileTest, ParsesTranslationsRotationsCommentsAndQuotedNames) {
  auto moves = ParseMoves(
      "# the box floats up, then turns\n"
      "\n"
      "0   box translate 0.1 0.2 -0.3\n"
      "0.5 box rotate 90 about 0 2 0   # the axis need not be unit\n"
      "1.5 \"my chair\" translate 1 0 1 rotate -45 about 1 0 0\n"
      "1.5 box rotate 1e1 about 0 0 1 translate 0 0 0\r\n");
  ASSERT_TRUE(moves.ok()) << moves.error().message;
  ASSERT_EQ(moves->size(), 4u);
  const ScriptedMove& first = (*moves)[0];
  EXPECT_EQ(first.timeS, 0.0);
  EXPECT_EQ(first.object, "box");
  EXPECT_EQ(first.line, 3);
  ASSERT_TRUE(first.translation.has_value());
  EXPECT_EQ(*first.translation, Vec3(0.1f, 0.2f, -0.3f));
  EXPECT_FALSE(first.rotation.has_value());
  const ScriptedMove& second = (*moves)[1];
  EXPECT_FALSE(second.translation.has_value());
  ASSERT_TRUE(second.rotation.has_value());
  EXPECT_EQ(second.rotation->angleDeg, 90.0f);
  EXPECT_EQ(second.rotation->axis, Vec3(0, 1, 0));
  EXPECT_EQ((*moves)[2].object, "my chair");
  EXPECT_EQ((*moves)[2].rotation->axis, Vec3(1, 0, 0));
  EXPECT_EQ((*moves)[3].rotation->angleDeg, 10.0f);
  EXPECT_EQ((*moves)[3].line, 6);
}

TEST(MovesFileTest, EveryMistakeIsNamedWithItsLine) {
  EXPECT_EQ(Refusal("0 box translate 1 2 3\nx box translate 1 2 3\n"),
            "line 2: the time 'x' is not a finite number");
  EXPECT_EQ(Refusal("nan box translate 1 2 3"), "line 1: the time 'nan' is not a finite number");
  EXPECT_EQ(Refusal("-1 box translate 1 2 3"), "line 1: the time -1 is negative");
  EXPECT_EQ(Refusal("2 box translate 1 2 3\n1 box translate 1 2 3"),
            "line 2: the time 1 is earlier than the move before it (2)");
  EXPECT_EQ(Refusal("1"), "line 1: the object's name is missing");
  EXPECT_EQ(Refusal("1 box"), "line 1: the move has neither 'translate' nor 'rotate'");
  EXPECT_EQ(Refusal("1 box translate 1 2"), "line 1: translate z is missing");
  EXPECT_EQ(Refusal("1 box translate 1 inf 2"), "line 1: translate y 'inf' is not a finite number");
  EXPECT_EQ(Refusal("1 box translate 1 2 1e39"), "line 1: translate z is out of range");
  EXPECT_EQ(Refusal("1 box translate 1 2 2e7"), "line 1: translate (1, 2, 20000000) is beyond 10000000");
  EXPECT_EQ(Refusal("1 box translate 1 2 3 translate 1 2 3"), "line 1: 'translate' is given twice");
  EXPECT_EQ(Refusal("1 box rotate 30 0 1 0"), "line 1: 'rotate DEG' is followed by 'about AX AY AZ'");
  EXPECT_EQ(Refusal("1 box rotate 30 about 0 0 0"), "line 1: the rotation axis is zero");
  EXPECT_EQ(Refusal("1 box rotate x about 0 1 0"),
            "line 1: the rotation angle (degrees) 'x' is not a finite number");
  EXPECT_EQ(Refusal("1 box scale 2"),
            "line 1: unknown word 'scale' (expected 'translate X Y Z' or 'rotate DEG about AX AY AZ')");
  EXPECT_EQ(Refusal("1 \"my chair translate 1 2 3"), "line 1: a quoted name has no closing quote");
  EXPECT_EQ(Refusal("# nothing but a comment\n\n"),
            "no moves (each line: <t_seconds> <object> [translate X Y Z] [rotate DEG about AX AY AZ])");
  std::string tooMany;
  for (size_t i = 0; i <= kMaxScriptedMoves; ++i) tooMany += "1 b translate 0 0 0\n";
  EXPECT_EQ(Refusal(tooMany), fmt::format("line {}: more than {} moves", kMaxScriptedMoves + 1, kMaxScriptedMoves));
}

TEST(MovesFileTest, LoadingNamesTheFile) {
  const std::filesystem::path dir = testing::MakeTempDir("penumbra-moves-test");
  const auto good = dir / "good.txt";
  std::ofstream(good) << "0.25 box translate 1 2 3\n";
  auto moves = LoadMovesFile(good);
  ASSERT_TRUE(moves.ok()) << moves.error().message;
  EXPECT_EQ(moves->size(), 1u);
  const auto bad = dir / "bad.txt";
  std::ofstream(bad) << "0.25 box jump\n";
  auto refused = LoadMovesFile(bad);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.error().message.rfind("moves file " + bad.string() + ": line 1: unknown word 'jump'", 0), 0u)
      << refused.error().message;
  auto missing = LoadMovesFile(dir / "none.txt");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("cannot open it"), std::string::npos);
  const auto huge = dir / "huge.txt";
  std::ofstream(huge) << std::string(kMaxMovesFileBytes + 1, '#');
  auto tooLarge = LoadMovesFile(huge);
  ASSERT_FALSE(tooLarge.ok());
  EXPECT_NE(tooLarge.error().message.find("larger than"), std::string::npos);
}

TEST(MovesFileTest, BindingResolvesNamesAndKeepsPartsLeftOut) {
  const ClientScene scene = SceneWithBoxAndFan();
  auto moves = ParseMoves(
      "0 box translate 1 2 3\n"                  // keeps the scene's 15 degrees
      "1 box rotate 90 about 0 0 1\n"           // keeps (1, 2, 3)
      "2 \"my chair\" translate 0 0 1\n");
  ASSERT_TRUE(moves.ok()) << moves.error().message;
  auto bound = BindMoves(*moves, scene);
  ASSERT_TRUE(bound.ok()) << bound.error().message;
  ASSERT_EQ(bound->size(), 3u);
  EXPECT_EQ((*bound)[0].object, 1u);
  EXPECT_EQ((*bound)[0].objectToWorld.translation, Vec3(1, 2, 3));
  EXPECT_EQ((*bound)[0].objectToWorld.rotation, scene.objects[0].objectToWorld.rotation);
  EXPECT_EQ((*bound)[1].objectToWorld.translation, Vec3(1, 2, 3));
  const Vec3 x = (*bound)[1].objectToWorld.ApplyVector(Vec3(1, 0, 0));
  EXPECT_NEAR(x.x, 0.0f, 1e-6f);
  EXPECT_NEAR(x.y, 1.0f, 1e-6f);
  EXPECT_EQ((*bound)[2].object, 3u);
  EXPECT_EQ((*bound)[2].objectToWorld.translation, Vec3(0, 0, 1));

  auto unknown = BindMoves(*ParseMoves("0 chair translate 0 0 0"), scene);
  ASSERT_FALSE(unknown.ok());
  EXPECT_EQ(unknown.error().message,
            "line 1: the scene 'cornell' has no movable object 'chair' (it has: box, ceiling fan, my chair)");
  auto animated = BindMoves(*ParseMoves("0 \"ceiling fan\" translate 0 0 0"), scene);
  ASSERT_FALSE(animated.ok());
  EXPECT_EQ(animated.error().message,
            "line 1: object 'ceiling fan' follows its animation path; the SMA refuses moves of it");
  auto none = BindMoves(*ParseMoves("0 box translate 0 0 0"), ClientScene{});
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.error().message.find("(it has: none)"), std::string::npos);
}

TEST(MovesFileTest, ThePlayerHandsOutEachMoveOnceWhenItsTimeHasCome) {
  MovesPlayer player(*BindMoves(*ParseMoves("0 box translate 0 0 0\n"
                                            "0.5 box translate 1 0 0\n"
                                            "0.5 box translate 2 0 0\n"
                                            "2 box translate 3 0 0\n"),
                                SceneWithBoxAndFan()));
  EXPECT_EQ(player.Total(), 4u);
  EXPECT_EQ(player.Due(0s).size(), 1u);
  EXPECT_EQ(player.Due(0.4s).size(), 0u);
  const auto both = player.Due(1s);
  ASSERT_EQ(both.size(), 2u);
  EXPECT_EQ(both[1].objectToWorld.translation.x, 2.0f);
  EXPECT_FALSE(player.Finished());
  EXPECT_EQ(player.Sent(), 3u);
  EXPECT_EQ(player.Due(5s).size(), 1u);
  EXPECT_TRUE(player.Finished());
  EXPECT_TRUE(player.Due(9s).empty());
}

}  // namespace
}  // namespace penumbra::client
