#include "penumbra/renderer/ray_scene.h"

#include <gtest/gtest.h>

#include <vector>

#include "test_scenes.h"

namespace penumbra {
namespace {

using testing::AddHorizontalSquare;
using testing::Finish;
using testing::MakeMaterial;
using testing::TestScene;

// Two unit squares facing up: one at y = 0 over [0,1]^2 (triangles 0, 1) and
// one at y = 1 (triangles 2, 3).
TestScene TwoFloors() {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  AddHorizontalSquare(b, Vec3(0.5f, 0.0f, 0.5f), 1.0f, m, true);
  AddHorizontalSquare(b, Vec3(0.5f, 1.0f, 0.5f), 1.0f, m, true);
  return Finish(b);
}

TEST(RaySceneTest, ClosestHitReportsTriangleDistanceAndBarycentrics) {
  const TestScene t = TwoFloors();
  const Vec3 origin(0.25f, 2.0f, 0.6f);
  const auto hit = t.rays->Intersect(origin, Vec3(0.0f, -1.0f, 0.0f), 0.0f, 100.0f);
  ASSERT_TRUE(hit.has_value());
  EXPECT_GE(hit->triangle, 2u);  // the upper square, not the lower one
  EXPECT_NEAR(hit->t, 1.0f, 1e-6f);
  const Vec3 p = t.scene.PointAt(hit->triangle, hit->b1, hit->b2);
  EXPECT_NEAR(glm::length(p - Vec3(0.25f, 1.0f, 0.6f)), 0.0f, 1e-6f);
  // The normal is the triangle's front side, whichever side was hit.
  EXPECT_NEAR(glm::dot(glm::normalize(hit->normal), t.scene.GeometricNormal(hit->triangle)), 1.0f, 1e-6f);
  const auto fromBelow = t.rays->Intersect(Vec3(0.25f, -1.0f, 0.6f), Vec3(0.0f, 1.0f, 0.0f), 0.0f, 100.0f);
  ASSERT_TRUE(fromBelow.has_value());
  EXPECT_NEAR(glm::dot(glm::normalize(fromBelow->normal), t.scene.GeometricNormal(fromBelow->triangle)), 1.0f, 1e-6f);
}

TEST(RaySceneTest, BackFacesAreHitAndTheIntervalIsRespected) {
  const TestScene t = TwoFloors();
  const Vec3 below(0.5f, -1.0f, 0.3f);
  const Vec3 up(0.0f, 1.0f, 0.0f);
  const auto hit = t.rays->Intersect(below, up, 0.0f, 100.0f);
  ASSERT_TRUE(hit.has_value());
  EXPECT_LT(hit->triangle, 2u);
  EXPECT_NEAR(hit->t, 1.0f, 1e-6f);
  // Starting past the lower square finds the upper one.
  const auto next = t.rays->Intersect(below, up, 1.5f, 100.0f);
  ASSERT_TRUE(next.has_value());
  EXPECT_NEAR(next->t, 2.0f, 1e-6f);
  EXPECT_FALSE(t.rays->Intersect(below, up, 0.0f, 0.9f).has_value());
  EXPECT_TRUE(t.rays->Occluded(below, up, 0.0f, 1.1f));
  EXPECT_FALSE(t.rays->Occluded(below, up, 0.0f, 0.9f));
  EXPECT_FALSE(t.rays->Occluded(below, -up, 0.0f, 100.0f));
}

// Rays aimed exactly at the shared diagonal of a square do not slip through.
TEST(RaySceneTest, RaysThroughASharedEdgeHitOneOfItsTriangles) {
  const TestScene t = TwoFloors();
  for (int i = 1; i < 64; ++i) {
    const float s = float(i) / 64.0f;
    const Vec3 target(s, 0.0f, s);  // on the diagonal of the lower square
    const Vec3 origin(s + 0.3f, -0.7f, s - 0.2f);
    const Vec3 direction = glm::normalize(target - origin);
    EXPECT_TRUE(t.rays->Occluded(origin, direction, 0.0f, 10.0f)) << "s = " << s;
  }
}

TEST(RaySceneTest, RawTracingCountsHits) {
  const TestScene t = TwoFloors();
  const std::vector<Ray> rays = {
      {Vec3(0.5f, 2.0f, 0.5f), Vec3(0.0f, -1.0f, 0.0f)},              // hits
      {Vec3(0.5f, 2.0f, 0.5f), Vec3(0.0f, 1.0f, 0.0f)},               // escapes
      {Vec3(0.5f, 0.5f, 0.5f), Vec3(0.0f, 1.0f, 0.0f), 0.25f},        // stops short
  };
  EXPECT_EQ(t.rays->TraceRaw(rays, RayQuery::kClosestHit), 1u);
  EXPECT_EQ(t.rays->TraceRaw(rays, RayQuery::kOcclusion), 1u);
}

}  // namespace
}  // namespace penumbra
