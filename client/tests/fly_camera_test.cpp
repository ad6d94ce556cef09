// FlyCamera: poses round-trip, mouse turns the expected way, pitch clamps,
// movement follows the heading at the given speed.

#include "penumbra/client/fly_camera.h"

#include <gtest/gtest.h>

#include "expect_near.h"

namespace penumbra::client {
namespace {


TEST(FlyCameraTest, KeepsThePoseItWasGiven) {
  FlyCamera camera;
  camera.SetPose(CameraPose{Vec3(1, 2, 3), Vec3(1, 1, 0), Vec3(0, 1, 0)});
  const CameraPose pose = camera.Pose();
  ExpectNear(pose.eye, Vec3(1, 2, 3));
  ExpectNear(glm::normalize(pose.target - pose.eye), glm::normalize(Vec3(0, -1, -3)));
  ExpectNear(pose.up, Vec3(0, 1, 0));
  EXPECT_TRUE(ValidateCameraView(CameraView{pose, 45.0f, 64, 64}).ok());
}

TEST(FlyCameraTest, MouseRightTurnsRightAndMouseDownLooksDown) {
  FlyCamera camera;
  camera.SetPose(CameraPose{Vec3(0), Vec3(0, 0, -1), Vec3(0, 1, 0)});
  ExpectNear(camera.Right(), Vec3(1, 0, 0));
  camera.Turn(100.0f, 0.0f, kPi / 200.0f);  // a quarter turn to the right
  ExpectNear(camera.Forward(), Vec3(1, 0, 0));
  camera.Turn(0.0f, 50.0f, kPi / 200.0f);  // 45 degrees down
  ExpectNear(camera.Forward(), glm::normalize(Vec3(1, -1, 0)));
}

TEST(FlyCameraTest, PitchStopsShortOfStraightUpOrDown) {
  FlyCamera camera;
  camera.SetPose(CameraPose{Vec3(0), Vec3(0, 0, -1), Vec3(0, 1, 0)});
  camera.Turn(0.0f, -1e6f, 0.01f);
  EXPECT_FLOAT_EQ(camera.Pitch(), FlyCamera::kMaxPitch);
  EXPECT_TRUE(ValidateCameraView(CameraView{camera.Pose(), 45.0f, 64, 64}).ok());
  // A pose looking straight down still yields a usable heading.
  camera.SetPose(CameraPose{Vec3(0), Vec3(0, -5, 0), Vec3(0, 1, 0)});
  EXPECT_FLOAT_EQ(camera.Pitch(), -FlyCamera::kMaxPitch);
  EXPECT_TRUE(ValidateCameraView(CameraView{camera.Pose(), 45.0f, 64, 64}).ok());
}

TEST(FlyCameraTest, MovesAlongTheHeadingAtTheGivenSpeed) {
  FlyCamera camera;
  camera.SetPose(CameraPose{Vec3(0), Vec3(0, 0, -1), Vec3(0, 1, 0)});
  camera.Move(MoveInput{.forward = 1.0f}, 2.0f, 0.5f);
  ExpectNear(camera.Pose().eye, Vec3(0, 0, -1));
  camera.Move(MoveInput{.right = -1.0f, .up = 1.0f}, 1.0f, 1.0f);  // diagonal: still one unit
  ExpectNear(camera.Pose().eye, Vec3(-std::sqrt(0.5f), std::sqrt(0.5f), -1));
}

TEST(FlyCameraTest, TurnsAboutTheUpOfThePose) {
  FlyCamera camera;  // a Z-up world
  camera.SetPose(CameraPose{Vec3(0), Vec3(1, 0, 0), Vec3(0, 0, 1)});
  camera.Turn(100.0f, 0.0f, kPi / 200.0f);
  ExpectNear(camera.Forward(), Vec3(0, -1, 0));  // right of +x, seen from above with z up
  ExpectNear(camera.Pose().up, Vec3(0, 0, 1));
}

}  // namespace
}  // namespace penumbra::client
