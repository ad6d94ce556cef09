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

// Static instances (issue 15): a floor at y = 0 over [0, 1]^2, then three
// copies of a unit square (its own mesh, facing up): at height 1, at height 2
// shifted 3 along x, and turned over (180 degrees about x, so facing down)
// at height 1 shifted 6 along x. Each copy shares the square's BVH; a hit
// names a triangle of its own copy, and its normal is that triangle's own.
TEST(RaySceneTest, HitsOnStaticInstancesNameEachCopysTrianglesWithWorldNormals) {
  SceneBuilder squareBuilder;
  AddHorizontalSquare(squareBuilder, Vec3(0.5f, 0.0f, 0.5f), 1.0f,
                      squareBuilder.AddMaterial(MakeMaterial(Rgb(0.5f))), true);
  Scene square;
  square.name = "square";
  ASSERT_TRUE(squareBuilder.BuildInto(square).ok());
  SceneBuilder b;
  AddHorizontalSquare(b, Vec3(0.5f, 0.0f, 0.5f), 1.0f, b.AddMaterial(MakeMaterial(Rgb(0.5f))), true);
  const RigidTransform places[] = {
      RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(0, 1, 0)),
      RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(3, 2, 0)),
      RigidTransform::FromAxisAngle(Vec3(1, 0, 0), kPi, Vec3(6, 1, 1)),
  };
  b.AddInstances(std::move(square), places);
  const TestScene t = Finish(b);
  ASSERT_EQ(t.scene.instances.size(), 3u);
  const Vec3 down(0.0f, -1.0f, 0.0f);
  struct Probe {
    Vec3 origin;
    uint32_t copy;
    float distance;
    float normalY;
  };
  for (const Probe& p : {Probe{Vec3(0.25f, 5, 0.6f), 0, 4.0f, 1.0f}, Probe{Vec3(3.7f, 5, 0.3f), 1, 3.0f, 1.0f},
                         Probe{Vec3(6.4f, 5, 0.8f), 2, 4.0f, -1.0f}}) {
    SCOPED_TRACE(p.copy);
    const auto hit = t.rays->Intersect(p.origin, down, 0.0f, 100.0f);
    ASSERT_TRUE(hit.has_value());
    const StaticInstance& copy = t.scene.instances[p.copy];
    EXPECT_GE(hit->triangle, copy.firstTriangle);
    EXPECT_LT(hit->triangle, copy.firstTriangle + copy.triangleCount);
    EXPECT_NEAR(hit->t, p.distance, 1e-5f);
    EXPECT_NEAR(glm::normalize(hit->normal).y, p.normalY, 1e-5f);
    EXPECT_NEAR(glm::dot(glm::normalize(hit->normal), t.scene.GeometricNormal(hit->triangle)), 1.0f, 1e-5f);
    const Vec3 at = t.scene.PointAt(hit->triangle, hit->b1, hit->b2);
    EXPECT_NEAR(glm::length(at - (p.origin + hit->t * down)), 0.0f, 1e-5f);
    EXPECT_TRUE(t.rays->Occluded(p.origin, down, 0.0f, p.distance + 0.01f));
    EXPECT_FALSE(t.rays->Occluded(p.origin, down, 0.0f, p.distance - 0.01f));
  }
  // Under copy 0, the floor itself.
  const auto floor = t.rays->Intersect(Vec3(0.25f, 0.5f, 0.6f), down, 0.0f, 100.0f);
  ASSERT_TRUE(floor.has_value());
  EXPECT_LT(floor->triangle, 2u);
  EXPECT_NEAR(floor->t, 0.5f, 1e-6f);
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
