// Picking and dragging objects, and the bookkeeping of moves sent
// (object_moves.h): rays against boxes and held triangles (nearest wins, a
// miss is a miss, a static wall in front hides the object), a drag in the
// plane parallel to the image, at most one move per interval, and moves
// settled by the SMA's MOVED or refused.

#include "penumbra/client/object_moves.h"

#include <vector>

#include <gtest/gtest.h>

#include "expect_near.h"

#include "support/delta_builder.h"

namespace penumbra::client {
namespace {

using namespace std::chrono_literals;
using testing::DeltaBuilder;

Bounds3 Box(const Vec3& lo, const Vec3& hi) {
  Bounds3 b;
  b.Extend(lo);
  b.Extend(hi);
  return b;
}


TEST(ObjectPickingTest, RayBoxDistanceEntersMissesAndStartsInside) {
  const Bounds3 box = Box(Vec3(-1, -1, -6), Vec3(1, 1, -4));
  const Ray down{Vec3(0), Vec3(0, 0, -1)};
  EXPECT_FLOAT_EQ(*RayBoxDistance(down, box), 4.0f);
  EXPECT_FALSE(RayBoxDistance(Ray{Vec3(0), Vec3(0, 0, 1)}, box).has_value()) << "behind the eye";
  EXPECT_FALSE(RayBoxDistance(Ray{Vec3(2, 0, 0), Vec3(0, 0, -1)}, box).has_value()) << "beside it";
  EXPECT_FLOAT_EQ(*RayBoxDistance(Ray{Vec3(0, 0, -5), Vec3(0, 0, -1)}, box), 0.0f) << "inside";
  const Vec3 diagonal = glm::normalize(Vec3(1, 0, -5));
  ASSERT_TRUE(RayBoxDistance(Ray{Vec3(0), diagonal}, box).has_value());
  EXPECT_FALSE(RayBoxDistance(down, Bounds3{}).has_value()) << "an empty box";
}

TEST(ObjectPickingTest, TheNearestBoxWinsAndAMissIsNothing) {
  // Object 1 far, object 2 near, object 3 off to the side.
  const std::vector<Bounds3> boxes = {Box(Vec3(-1, -1, -10), Vec3(1, 1, -8)), Box(Vec3(-1, -1, -4), Vec3(1, 1, -3)),
                                      Box(Vec3(5, 5, -4), Vec3(6, 6, -3))};
  auto pick = PickObjectBounds(Ray{Vec3(0), Vec3(0, 0, -1)}, boxes);
  ASSERT_TRUE(pick.has_value());
  EXPECT_EQ(pick->object, 2u);
  EXPECT_FLOAT_EQ(pick->distance, 3.0f);
  ExpectNear(pick->point, Vec3(0, 0, -3));
  // Through the far one only (beside the near one).
  pick = PickObjectBounds(Ray{Vec3(0.0f, 0.0f, -5.0f), Vec3(0, 0, -1)}, boxes);
  ASSERT_TRUE(pick.has_value());
  EXPECT_EQ(pick->object, 1u);
  EXPECT_FALSE(PickObjectBounds(Ray{Vec3(0), Vec3(0, 1, 0)}, boxes).has_value());
  EXPECT_FALSE(PickObjectBounds(Ray{Vec3(0), Vec3(0, 0, -1)}, {}).has_value());
}

TEST(ObjectPickingTest, RayTriangleHitsEitherSideAndMissesOutside) {
  const Vec3 a(-1, -1, -2), b(1, -1, -2), c(0, 1, -2);
  EXPECT_FLOAT_EQ(*RayTriangleDistance(Ray{Vec3(0), Vec3(0, 0, -1)}, a, b, c), 2.0f);
  EXPECT_FLOAT_EQ(*RayTriangleDistance(Ray{Vec3(0), Vec3(0, 0, -1)}, a, c, b), 2.0f) << "back face";
  EXPECT_FALSE(RayTriangleDistance(Ray{Vec3(3, 0, 0), Vec3(0, 0, -1)}, a, b, c).has_value());
  EXPECT_FALSE(RayTriangleDistance(Ray{Vec3(0), Vec3(0, 0, 1)}, a, b, c).has_value());
  EXPECT_FALSE(RayTriangleDistance(Ray{Vec3(0), Vec3(1, 0, 0)}, a, b, c).has_value()) << "parallel";
}

// A store holding a static wall at z = -5 (vertices 1-3) and a triangle of
// object 1 (vertices 4-6) in object space at z = 0, placed at z = -3 or
// moved behind the wall.
class PickHeldTriangleTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::vector<int32_t> materialTextures = {-1};
    const std::vector<RigidTransform> objects = {RigidTransform{glm::mat3(1.0f), Vec3(0, 0, -3)}};
    mesh_.Reset(materialTextures, 0, objects, 0);
    DeltaBuilder d(1, 1);
    d.Vertex(1, Vec3(-10, -10, -5), Rgb(1)).Vertex(2, Vec3(10, -10, -5), Rgb(1)).Vertex(3, Vec3(0, 10, -5), Rgb(1));
    d.Vertex(4, Vec3(-1, -1, 0), Rgb(1)).Vertex(5, Vec3(1, -1, 0), Rgb(1)).Vertex(6, Vec3(0, 1, 0), Rgb(1));
    d.Triangle(10, {1, 2, 3}).Triangle(11, {4, 5, 6});
    for (uint32_t o : {0u, 0u, 0u, 1u, 1u, 1u}) d.Mutable().add_vertex_objects(o);
    ASSERT_TRUE(mesh_.Apply(d.Delta()).ok());
  }
  MeshStore mesh_;
};

TEST_F(PickHeldTriangleTest, TheVisibleSurfaceUnderTheCursorDecides) {
  const Ray ray{Vec3(0), Vec3(0, 0, -1)};
  auto pick = PickHeldTriangle(ray, mesh_);
  ASSERT_TRUE(pick.has_value());
  EXPECT_EQ(pick->object, 1u);
  EXPECT_FLOAT_EQ(pick->distance, 3.0f);
  // Beside the object: the wall, which is static.
  pick = PickHeldTriangle(Ray{Vec3(5, -5, 0), Vec3(0, 0, -1)}, mesh_);
  ASSERT_TRUE(pick.has_value());
  EXPECT_EQ(pick->object, 0u);
  EXPECT_FLOAT_EQ(pick->distance, 5.0f);
  // Moved behind the wall (as drawn), the object is hidden.
  mesh_.SetLocalTransform(1, RigidTransform{glm::mat3(1.0f), Vec3(0, 0, -7)});
  pick = PickHeldTriangle(ray, mesh_);
  ASSERT_TRUE(pick.has_value());
  EXPECT_EQ(pick->object, 0u);
  // Nothing at all up there.
  EXPECT_FALSE(PickHeldTriangle(Ray{Vec3(0), Vec3(0, 0, 1)}, mesh_).has_value());
  // A removed triangle is not picked.
  mesh_.SetLocalTransform(1, std::nullopt);
  ASSERT_TRUE(mesh_.Apply(DeltaBuilder(2, 1, wire::DELTA_KIND_REMOVED).Remove(11).Delta()).ok());
  EXPECT_EQ(PickHeldTriangle(ray, mesh_)->object, 0u);
}

TEST(ObjectDragTest, TheGrabPointFollowsTheCursorInAPlaneParallelToTheImage) {
  // Looking down -z; the object's grab point at (0, 0, -4).
  const RigidTransform start = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.3f, Vec3(0, 0, -4.5f));
  ObjectDrag drag(7, start, Vec3(0, 0, -4), Vec3(0, 0, -1));
  EXPECT_EQ(drag.Object(), 7u);
  // The cursor's ray now meets the plane z = -4 at (1, 2, -4).
  RigidTransform t = drag.At(Ray{Vec3(0), glm::normalize(Vec3(1, 2, -4))});
  ExpectNear(t.translation, Vec3(1, 2, -4.5f));
  EXPECT_EQ(t.rotation, start.rotation) << "a drag only translates";
  // The wheel pushes the plane away: now z = -6.
  drag.Push(2.0f);
  t = drag.At(Ray{Vec3(0), Vec3(0, 0, -1)});
  ExpectNear(t.translation, Vec3(0, 0, -6.5f));
  // A ray parallel to the plane, or meeting it behind the eye, keeps the last place.
  EXPECT_EQ(drag.At(Ray{Vec3(0), Vec3(1, 0, 0)}).translation, t.translation);
  EXPECT_EQ(drag.At(Ray{Vec3(0), Vec3(0, 0, 1)}).translation, t.translation);
}

TEST(MoveThrottleTest, AtMostOneMovePerIntervalAndTheLatestWins) {
  MoveThrottle throttle(100ms);
  const auto t0 = MoveThrottle::Clock::time_point{} + 10s;
  EXPECT_FALSE(throttle.Due(t0).has_value()) << "nothing offered";
  auto at = [](float x) { return RigidTransform{glm::mat3(1.0f), Vec3(x, 0, 0)}; };
  throttle.Offer(1, at(1));
  auto sent = throttle.Due(t0);
  ASSERT_TRUE(sent.has_value()) << "the first goes at once";
  EXPECT_EQ(sent->transform.translation.x, 1.0f);
  throttle.Offer(1, at(2));
  throttle.Offer(1, at(3));
  EXPECT_FALSE(throttle.Due(t0 + 50ms).has_value());
  sent = throttle.Due(t0 + 100ms);
  ASSERT_TRUE(sent.has_value());
  EXPECT_EQ(sent->transform.translation.x, 3.0f) << "coalesced to the latest";
  EXPECT_FALSE(throttle.Due(t0 + 120ms).has_value()) << "sent once";
  // The end of a drag flushes the last one at once.
  throttle.Offer(1, at(4));
  EXPECT_FALSE(throttle.Due(t0 + 150ms).has_value());
  sent = throttle.Due(t0 + 150ms, /*flush=*/true);
  ASSERT_TRUE(sent.has_value());
  EXPECT_EQ(sent->transform.translation.x, 4.0f);
}

TEST_F(PickHeldTriangleTest, AMoveIsPendingUntilTheSmaConfirmsOrRefusesIt) {
  MoveTracker tracker;
  EXPECT_TRUE(tracker.Empty());
  const RigidTransform first = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.2f, Vec3(1, 0, -3));
  const RigidTransform second = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.4f, Vec3(2, 0, -3));
  tracker.Sent(1, first, 101);
  tracker.Sent(1, second, 102);
  EXPECT_TRUE(tracker.Pending(1));
  EXPECT_EQ(tracker.Size(), 1u) << "one object, two moves";
  EXPECT_EQ(tracker.SentCount(), 2u);
  EXPECT_EQ(*tracker.LastSent(1), second);
  // The SMA's MOVED for the first move does not settle the second.
  DeltaBuilder movedFirst(2, 1, wire::DELTA_KIND_MOVED);
  movedFirst.Mutable().add_moved_objects(1);
  for (float v : first.ToRowMajor()) movedFirst.Mutable().add_moved_object_transforms(v);
  ASSERT_TRUE(mesh_.Apply(movedFirst.Delta()).ok());
  tracker.Confirm(mesh_);
  EXPECT_TRUE(tracker.Pending(1));
  // Refusing an older request changes nothing; its MOVED (rounded by the
  // SMA's re-orthonormalisation) settles it.
  EXPECT_EQ(tracker.Refused(101), 0u);
  DeltaBuilder movedSecond(3, 1, wire::DELTA_KIND_MOVED);
  movedSecond.Mutable().add_moved_objects(1);
  for (float v : second.ToRowMajor()) movedSecond.Mutable().add_moved_object_transforms(v + 1e-6f);
  ASSERT_TRUE(mesh_.Apply(movedSecond.Delta()).ok());
  tracker.Confirm(mesh_);
  EXPECT_FALSE(tracker.Pending(1));
  EXPECT_TRUE(tracker.Empty());
  // A refusal of the last request settles it too.
  tracker.Sent(1, first, 103);
  EXPECT_EQ(tracker.Refused(103), 1u);
  EXPECT_TRUE(tracker.Empty());
  EXPECT_FALSE(tracker.LastSent(1).has_value());
}

TEST(MoveTrackerTest, AMoveNeverConfirmedIsGivenUpAfterTheTimeout) {
  MoveTracker tracker;
  const auto t0 = MoveTracker::Clock::time_point{} + 100s;
  tracker.Sent(1, RigidTransform::Identity(), 7, t0);
  tracker.Sent(2, RigidTransform::Identity(), 8, t0 + 3s);
  EXPECT_TRUE(tracker.Expire(t0 + kMovePendingTimeout).empty());
  EXPECT_EQ(tracker.Expire(t0 + kMovePendingTimeout + 1ms), std::vector<uint32_t>{1});
  EXPECT_FALSE(tracker.Pending(1));
  EXPECT_TRUE(tracker.Pending(2));
  // A newer send restarts the clock.
  tracker.Sent(2, RigidTransform::Identity(), 9, t0 + 7s);
  EXPECT_TRUE(tracker.Expire(t0 + 9s).empty());
  EXPECT_EQ(tracker.Expire(t0 + 13s), std::vector<uint32_t>{2});
  EXPECT_TRUE(tracker.Empty());
}

}  // namespace
}  // namespace penumbra::client
