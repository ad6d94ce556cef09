// Camera paths: loading from a path file or a scene file's named path,
// still views from presets, real-time playback.

#include "penumbra/client/path_player.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "support/fake_sma.h"
#include "support/process.h"

namespace penumbra::client {
namespace {

using namespace std::chrono_literals;

std::string WriteFile(const std::string& name, const std::string& text) {
  const std::string path = testing::MakeTempDir("penumbra-path-test") + "/" + name;
  std::ofstream(path) << text;
  return path;
}

constexpr const char* kTwoKeyframes = R"({"fov_y_deg": 50, "width": 320, "height": 240, "keyframes": [
  {"t": 1, "eye": [0, 0, 4], "target": [0, 0, 0]},
  {"t": 3, "eye": [0, 0, 2], "target": [0, 0, 0]}]})";

TEST(PathSpecTest, LoadsAPathFile) {
  auto path = LoadCameraPathSpec(WriteFile("dolly.json", kTwoKeyframes));
  ASSERT_TRUE(path.ok()) << path.error().message;
  EXPECT_EQ(path->width, 320);
  EXPECT_EQ(path->keyframes.size(), 2u);
}

// Finite but absurd coordinates once passed and aborted the SMA inside Embree.
TEST(PathSpecTest, CoordinatesBeyondAnySceneAreRefused) {
  for (const char* keys : {R"([{"t": 0, "eye": [1e19, 0, 0], "target": [0, 0, 0]}])",
                           R"([{"t": 0, "eye": [3e38, 0, 0], "target": [-3e38, 0, 0]}])"}) {
    auto path = LoadCameraPathSpec(WriteFile("far.json", std::string(R"({"keyframes": )") + keys + "}"));
    ASSERT_FALSE(path.ok()) << keys;
    EXPECT_NE(path.error().message.find("within"), std::string::npos) << path.error().message;
  }
}

TEST(PathSpecTest, LoadsANamedPathOfASceneFile) {
  const std::string scene = std::string(R"({"mesh": "x.obj", "paths": {"dolly": )") + kTwoKeyframes + "}}";
  const std::string file = WriteFile("scene.json", scene);
  auto path = LoadCameraPathSpec(file + "#dolly");
  ASSERT_TRUE(path.ok()) << path.error().message;
  EXPECT_EQ(path->name, "dolly");
  EXPECT_FLOAT_EQ(path->fovYDeg, 50.0f);

  auto missing = LoadCameraPathSpec(file + "#orbit");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("no camera path named 'orbit'"), std::string::npos);
  EXPECT_FALSE(LoadCameraPathSpec("/nonexistent/scene.json#walk").ok());
  EXPECT_FALSE(LoadCameraPathSpec(WriteFile("bad.json", "{\"keyframes\": []}")).ok());
}

TEST(PathSpecTest, ANamedPathInAFileOfItsOwnLoadsRelativeToTheSceneFile) {
  const std::string dir = testing::MakeTempDir("penumbra-path-test");
  std::filesystem::create_directories(dir + "/paths");
  std::ofstream(dir + "/paths/dolly.json") << kTwoKeyframes;
  std::ofstream(dir + "/scene.json") << R"({"mesh": "x.obj", "paths": {"dolly": {"file": "paths/dolly.json"},
    "gone": {"file": "paths/none.json"}, "odd": {"file": 3}}})";
  auto path = LoadCameraPathSpec(dir + "/scene.json#dolly");
  ASSERT_TRUE(path.ok()) << path.error().message;
  EXPECT_EQ(path->name, "dolly");
  EXPECT_EQ(path->keyframes.size(), 2u);
  EXPECT_FALSE(LoadCameraPathSpec(dir + "/scene.json#gone").ok());
  EXPECT_FALSE(LoadCameraPathSpec(dir + "/scene.json#odd").ok());
}

TEST(PathSpecTest, TheSharedSceneFilesPathsLoad) {
  auto walk = LoadCameraPathSpec(std::string(PENUMBRA_SOURCE_DIR) + "/scenes/sponza.json#walk");
  ASSERT_TRUE(walk.ok()) << walk.error().message;
  EXPECT_EQ(walk->keyframes.size(), 4u);
  // The street's walk is a file of its own (scenes/paths/street-walk.json).
  auto street = LoadCameraPathSpec(std::string(PENUMBRA_SOURCE_DIR) + "/scenes/street.json#walk");
  ASSERT_TRUE(street.ok()) << street.error().message;
  EXPECT_GT(street->DurationSeconds(), 300.0);
}

TEST(PathPlayerTest, PlaysFromTheFirstKeyframeAndHoldsTheLast) {
  auto path = LoadCameraPathSpec(WriteFile("dolly.json", kTwoKeyframes));
  ASSERT_TRUE(path.ok());
  const PathPlayer player(*path);
  EXPECT_FLOAT_EQ(player.ViewAt(0s).pose.eye.z, 4.0f);
  EXPECT_FLOAT_EQ(player.ViewAt(1s).pose.eye.z, 3.0f);
  EXPECT_FALSE(player.Finished(1.9s));
  EXPECT_TRUE(player.Finished(2s));
  EXPECT_FLOAT_EQ(player.ViewAt(10s).pose.eye.z, 2.0f);
  EXPECT_EQ(player.ViewAt(0s).width, 320);
}

// A stop (two equal keyframes) is exactly their pose at every time between
// them: a pose off in the last bit would be a new view for the SMA each frame.
TEST(PathPlayerTest, AStopHoldsExactlyItsPose) {
  auto path = LoadCameraPathSpec(WriteFile("stop.json", R"({"keyframes": [
    {"t": 0, "eye": [0.1, 1.45, -1.3], "target": [3.9, 1.0, -1.6]},
    {"t": 4, "eye": [0.1, 1.45, -1.3], "target": [3.9, 1.0, -1.6]}]})"));
  ASSERT_TRUE(path.ok());
  const PathPlayer player(*path);
  const CameraPose first = player.ViewAt(0s).pose;
  for (int ms = 1; ms < 4000; ms += 37) {
    const CameraPose pose = player.ViewAt(std::chrono::milliseconds(ms)).pose;
    ASSERT_TRUE(pose.eye == first.eye && pose.target == first.target && pose.up == first.up) << ms << " ms";
  }
}

TEST(PathPlayerTest, APresetIsAStillPathFinishedAtOnce) {
  const ClientScene scene = testing::UnitSquareScene();
  const PathPlayer player(StillPath(scene.cameras[0], 64, 48));
  EXPECT_TRUE(player.Finished(0s));
  const CameraView view = player.ViewAt(5s);
  EXPECT_EQ(view.width, 64);
  EXPECT_EQ(view.height, 48);
  EXPECT_FLOAT_EQ(view.pose.eye.z, 2.0f);
  EXPECT_FLOAT_EQ(view.fovYDeg, 45.0f);
  EXPECT_TRUE(ValidateCameraView(view).ok());
}

}  // namespace
}  // namespace penumbra::client
