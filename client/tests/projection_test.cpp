// WorldToClip agrees with PinholeCamera: a point on the ray through a pixel
// position projects back to that position.

#include "penumbra/client/projection.h"

#include <gtest/gtest.h>

namespace penumbra::client {
namespace {

TEST(ProjectionTest, PixelPositionsMatchThePinholeCamerasRays) {
  CameraView view;
  view.pose = CameraPose{Vec3(0.3f, 1.2f, 3.9f), Vec3(-0.2f, 0.8f, 0.0f), Vec3(0.1f, 1.0f, 0.0f)};
  view.fovYDeg = 55.0f;
  view.width = 320;
  view.height = 240;
  Bounds3 bounds;
  bounds.Extend(Vec3(-1, 0, -1));
  bounds.Extend(Vec3(1, 2, 1));
  const glm::mat4 worldToClip = WorldToClip(view, bounds);
  const PinholeCamera camera(view);
  for (const Vec2 pixel : {Vec2(0.5f, 0.5f), Vec2(160.0f, 120.0f), Vec2(319.5f, 10.25f), Vec2(3.0f, 239.0f)}) {
    const Vec3 point = camera.Origin() + 2.5f * camera.DirectionThrough(pixel.x, pixel.y);
    const glm::vec4 clip = worldToClip * glm::vec4(point, 1.0f);
    ASSERT_GT(clip.w, 0.0f);
    const Vec3 ndc = Vec3(clip) / clip.w;
    EXPECT_NEAR((ndc.x + 1.0f) * 0.5f * float(view.width), pixel.x, 1e-3f);
    EXPECT_NEAR((1.0f - ndc.y) * 0.5f * float(view.height), pixel.y, 1e-3f) << "row 0 is the top";
    EXPECT_GT(ndc.z, -1.0f);
    EXPECT_LT(ndc.z, 1.0f);
  }
}

TEST(ProjectionTest, TheWholeSceneLiesBetweenNearAndFar) {
  CameraView view;
  view.pose = CameraPose{Vec3(0.0f, 1.0f, 30.0f), Vec3(0.0f, 1.0f, 0.0f), Vec3(0, 1, 0)};
  Bounds3 bounds;
  bounds.Extend(Vec3(-10, -10, -10));
  bounds.Extend(Vec3(10, 10, 10));
  const glm::mat4 worldToClip = WorldToClip(view, bounds);
  for (float z : {-10.0f, 10.0f}) {
    const glm::vec4 clip = worldToClip * glm::vec4(0.0f, 1.0f, z, 1.0f);
    const float depth = clip.z / clip.w;
    EXPECT_GT(depth, -1.0f) << z;
    EXPECT_LT(depth, 1.0f) << z;
  }
}

}  // namespace
}  // namespace penumbra::client
