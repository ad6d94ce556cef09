// EmbreeScene at poses (issue 14): a movable object is hit where the pose
// puts it and not where it was; hits through an instance name the right base
// triangle, and the normal Embree reports for an instanced triangle is in
// object space until WorldHitNormal turns it. Static instances (issue 15):
// copies of one mesh share one BVH, and a hit on copy k names a triangle of
// copy k's own range.

#include "penumbra/common/embree_scene.h"

#include <embree3/rtcore.h>
#include <gtest/gtest.h>

#include <glm/trigonometric.hpp>

#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "penumbra/common/scene.h"

namespace penumbra {
namespace {

struct Hit {
  unsigned instance = RTC_INVALID_GEOMETRY_ID;
  unsigned primitive = 0;
  float t = 0.0f;
  float u = 0.0f, v = 0.0f;
  Vec3 ng{0.0f};  // as Embree reports it
};

std::optional<Hit> Trace(const PosedEmbreeScene& posed, const Vec3& origin, const Vec3& direction) {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh{};
  rh.ray.org_x = origin.x;
  rh.ray.org_y = origin.y;
  rh.ray.org_z = origin.z;
  rh.ray.dir_x = direction.x;
  rh.ray.dir_y = direction.y;
  rh.ray.dir_z = direction.z;
  rh.ray.tnear = 0.0f;
  rh.ray.tfar = std::numeric_limits<float>::infinity();
  rh.ray.mask = ~0u;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(posed.Handle(), &context, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return std::nullopt;
  return Hit{rh.hit.instID[0], rh.hit.primID, rh.ray.tfar, rh.hit.u, rh.hit.v, Vec3(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z)};
}

const Vec3 kDown(0.0f, -1.0f, 0.0f);

// Static: a floor at y = 0 over [-10, 10]^2. Movable "box": a unit cube
// centred on its origin, starting at (0, 2, 0). Movable "card": a unit square
// in its y = 0 plane (front +y), starting at (20, 0, 0), out of the way.
Scene FloorBoxAndCard() {
  SceneBuilder b;
  Material white;
  white.name = "white";
  const uint32_t m = b.AddMaterial(white);
  b.AddQuad(Vec3(-10, 0, -10), Vec3(0, 0, 20), Vec3(20, 0, 0), m);  // front +y
  MovableObject box;
  box.name = "box";
  box.objectToWorld = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(0, 2, 0));
  b.BeginObject(box);
  const Vec3 lo(-0.5f), size(1.0f);
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      Vec3 corner = lo;
      corner[axis] += side * size[axis];
      Vec3 e1(0.0f), e2(0.0f);
      e1[(axis + 1) % 3] = 1.0f;
      e2[(axis + 2) % 3] = 1.0f;
      Vec3 out(0.0f);
      out[axis] = side == 0 ? -1.0f : 1.0f;
      if (glm::dot(glm::cross(e1, e2), out) < 0.0f) std::swap(e1, e2);
      b.AddQuad(corner, e1, e2, m);
    }
  MovableObject card;
  card.name = "card";
  card.objectToWorld = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(20, 0, 0));
  b.BeginObject(card);
  b.AddQuad(Vec3(0), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
  Scene s;
  s.name = "floor-box-card";
  const Status built = b.BuildInto(s);
  EXPECT_TRUE(built.ok()) << (built.ok() ? "" : built.error().message);
  return s;
}

std::unique_ptr<EmbreeScene> BuildOrFail(const Scene& s) {
  auto built = EmbreeScene::Build(s, EmbreeSceneOptions{.logger = "test.embree", .robust = true});
  EXPECT_TRUE(built.ok()) << (built.ok() ? "" : built.error().message);
  return built.ok() ? std::move(*built) : nullptr;
}

TEST(EmbreeSceneTest, AMovedObjectIsHitAtItsNewPlaceAndNotAtItsOld) {
  const Scene s = FloorBoxAndCard();
  const auto embree = BuildOrFail(s);
  ASSERT_TRUE(embree);
  ASSERT_TRUE(embree->HasMovableObjects());
  const PosedEmbreeScene& initial = *embree->Initial();

  // At the initial pose the box's top (y = 2.5) is over the origin.
  const auto onBox = Trace(initial, Vec3(0, 10, 0.1f), kDown);
  ASSERT_TRUE(onBox);
  EXPECT_NEAR(onBox->t, 7.5f, 1e-5f);
  EXPECT_EQ(onBox->instance, 1u);
  const uint32_t boxTriangle = initial.Triangle(onBox->instance, onBox->primitive);
  EXPECT_EQ(s.ObjectOfTriangle(boxTriangle), 0u);

  ScenePose moved = ScenePose::Initial(s);
  moved.epoch = 1;
  moved.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(5, 1, 0));
  auto posed = embree->AtPose(moved);
  ASSERT_TRUE(posed.ok()) << posed.error().message;
  // Its old place now shows the floor (static: instance 0, the primitive id
  // is the base triangle)...
  const auto onFloor = Trace(**posed, Vec3(0, 10, 0.1f), kDown);
  ASSERT_TRUE(onFloor);
  EXPECT_NEAR(onFloor->t, 10.0f, 1e-5f);
  EXPECT_EQ(onFloor->instance, 0u);
  EXPECT_EQ(s.ObjectOfTriangle((*posed)->Triangle(onFloor->instance, onFloor->primitive)), kStaticObject);
  // ...and its new place the box's top, at y = 1.5.
  const auto onMovedBox = Trace(**posed, Vec3(5, 10, 0.1f), kDown);
  ASSERT_TRUE(onMovedBox);
  EXPECT_NEAR(onMovedBox->t, 8.5f, 1e-5f);
  const uint32_t t = (*posed)->Triangle(onMovedBox->instance, onMovedBox->primitive);
  EXPECT_EQ(s.ObjectOfTriangle(t), 0u);
  const Vec3 world = WorldPointAt(s, moved, t, onMovedBox->u, onMovedBox->v);
  EXPECT_NEAR(glm::length(world - Vec3(5, 1.5f, 0.1f)), 0.0f, 1e-5f);
  // The older pose is untouched by the newer one.
  const auto stillOnBox = Trace(initial, Vec3(0, 10, 0.1f), kDown);
  ASSERT_TRUE(stillOnBox);
  EXPECT_NEAR(stillOnBox->t, 7.5f, 1e-5f);
}

TEST(EmbreeSceneTest, ARotatedObjectsHitsNameItsTrianglesAndTurnTheirNormalsToWorldSpace) {
  const Scene s = FloorBoxAndCard();
  const auto embree = BuildOrFail(s);
  ASSERT_TRUE(embree);
  // A quarter turn about z takes the card's +y front to -x: it stands in the
  // plane x = 3, spanning y and z in [0, 1].
  ScenePose pose = ScenePose::Initial(s);
  pose.objectToWorld[1] = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), glm::radians(90.0f), Vec3(3, 0, 0));
  auto posed = embree->AtPose(pose);
  ASSERT_TRUE(posed.ok()) << posed.error().message;
  const auto hit = Trace(**posed, Vec3(0, 0.25f, 0.6f), Vec3(1, 0, 0));
  ASSERT_TRUE(hit);
  EXPECT_NEAR(hit->t, 3.0f, 1e-5f);
  EXPECT_EQ(hit->instance, 2u);
  const uint32_t t = (*posed)->Triangle(hit->instance, hit->primitive);
  EXPECT_EQ(s.ObjectOfTriangle(t), 1u);
  EXPECT_GE(t, s.objects[1].firstTriangle);
  EXPECT_LT(t, s.objects[1].firstTriangle + s.objects[1].triangleCount);
  // Embree 3 reports Ng in the instanced object's space: along its y.
  const Vec3 raw = glm::normalize(hit->ng);
  EXPECT_NEAR(std::abs(raw.y), 1.0f, 1e-5f) << "Ng (" << raw.x << ", " << raw.y << ", " << raw.z << ")";
  EXPECT_NEAR(glm::dot(raw, s.GeometricNormal(t)), 1.0f, 1e-5f);
  // WorldHitNormal turns it to the card's world front, -x.
  const Vec3 world = glm::normalize((*posed)->WorldHitNormal(hit->instance, hit->ng));
  EXPECT_NEAR(glm::dot(world, WorldGeometricNormal(s, pose, t)), 1.0f, 1e-5f);
  EXPECT_NEAR(world.x, -1.0f, 1e-5f);
  // The barycentrics place the hit on the triangle where the pose puts it.
  EXPECT_NEAR(glm::length(WorldPointAt(s, pose, t, hit->u, hit->v) - Vec3(3, 0.25f, 0.6f)), 0.0f, 1e-5f);
  // Static hits through the same pose keep their own normals.
  const auto floor = Trace(**posed, Vec3(-5, 3, -5), kDown);
  ASSERT_TRUE(floor);
  EXPECT_EQ(floor->instance, 0u);
  EXPECT_NEAR(glm::normalize((*posed)->WorldHitNormal(floor->instance, floor->ng)).y, 1.0f, 1e-6f);
}

TEST(EmbreeSceneTest, PosesAreReusedAtTheSamePlacesAndRefusedWithTheWrongObjectCount) {
  const Scene s = FloorBoxAndCard();
  const auto embree = BuildOrFail(s);
  ASSERT_TRUE(embree);
  ScenePose a = ScenePose::Initial(s);
  a.objectToWorld[0].translation.x = 4.0f;
  auto first = embree->AtPose(a);
  ASSERT_TRUE(first.ok());
  a.epoch = 7;  // another epoch, the same places
  auto again = embree->AtPose(a);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(first->get(), again->get());
  a.objectToWorld[0].translation.x = 6.0f;
  auto other = embree->AtPose(a);
  ASSERT_TRUE(other.ok());
  EXPECT_NE(first->get(), other->get());

  ScenePose tooFew;
  tooFew.objectToWorld.resize(1);
  auto refused = embree->AtPose(tooFew);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("a pose of 1 objects for a scene of 2"), std::string::npos)
      << refused.error().message;
}

TEST(EmbreeSceneTest, ASceneWithoutMovableObjectsHasNoInstances) {
  SceneBuilder b;
  Material white;
  const uint32_t m = b.AddMaterial(white);
  b.AddQuad(Vec3(-1, 0, -1), Vec3(0, 0, 2), Vec3(2, 0, 0), m);
  Scene s;
  ASSERT_TRUE(b.BuildInto(s).ok());
  const auto embree = BuildOrFail(s);
  ASSERT_TRUE(embree);
  EXPECT_FALSE(embree->HasMovableObjects());
  auto posed = embree->AtPose(ScenePose::Initial(s));
  ASSERT_TRUE(posed.ok());
  EXPECT_EQ(posed->get(), embree->Initial().get());
  const auto hit = Trace(*embree->Initial(), Vec3(0.2f, 1, 0.3f), kDown);
  ASSERT_TRUE(hit);
  EXPECT_EQ(hit->instance, RTC_INVALID_GEOMETRY_ID);  // no instancing: a plain hit
  EXPECT_LT(hit->primitive, 2u);
}

// Static: a floor at y = 0 over [-10, 10]^2. Instances of a unit card (its
// y = 0 plane, x and z in [0, 1], front +y): copy 0 at height 1, copy 1 at
// (3, 2, 0), copy 2 turned over (180 degrees about x: front -y, z in [-1, 0])
// at (6, 1, 0). Movable "box" card at (-5, 4, 0), so that ids mix.
Scene FloorAndCardCopies() {
  SceneBuilder cardBuilder;
  Material grey;
  grey.name = "grey";
  cardBuilder.AddQuad(Vec3(0), Vec3(0, 0, 1), Vec3(1, 0, 0), cardBuilder.AddMaterial(grey));
  Scene card;
  card.name = "card";
  EXPECT_TRUE(cardBuilder.BuildInto(card).ok());

  SceneBuilder b;
  Material white;
  white.name = "white";
  const uint32_t m = b.AddMaterial(white);
  b.AddQuad(Vec3(-10, 0, -10), Vec3(0, 0, 20), Vec3(20, 0, 0), m);
  const RigidTransform places[] = {
      RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(0, 1, 0)),
      RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(3, 2, 0)),
      RigidTransform::FromAxisAngle(Vec3(1, 0, 0), glm::radians(180.0f), Vec3(6, 1, 0)),
  };
  EXPECT_EQ(b.AddInstances(std::move(card), places), 6u);
  MovableObject box;
  box.name = "box";
  box.objectToWorld = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(-5, 4, 0));
  b.BeginObject(box);
  b.AddQuad(Vec3(0), Vec3(0, 0, 1), Vec3(1, 0, 0), m);
  Scene s;
  s.name = "floor-and-cards";
  const Status built = b.BuildInto(s);
  EXPECT_TRUE(built.ok()) << (built.ok() ? "" : built.error().message);
  return s;
}

TEST(EmbreeSceneTest, StaticInstancesShareOneBvhAndHitsNameEachCopysOwnTriangles) {
  const Scene s = FloorAndCardCopies();
  ASSERT_EQ(s.instances.size(), 3u);
  // Floor, then the copies (2 triangles each), then the movable card.
  EXPECT_EQ(s.instances[0].firstTriangle, 2u);
  EXPECT_EQ(s.instances[2].firstTriangle + s.instances[2].triangleCount, s.staticTriangleCount);
  EXPECT_EQ(s.objects[0].firstTriangle, 8u);
  const auto embree = BuildOrFail(s);
  ASSERT_TRUE(embree);
  EXPECT_TRUE(embree->HasStaticInstances());
  const PosedEmbreeScene& posed = *embree->Initial();

  struct Probe {
    Vec3 origin;
    uint32_t instance;  // index into s.instances
    float distance;     // analytic: origin height - card height
    float worldNormalY;
  };
  const Probe probes[] = {
      {Vec3(0.3f, 5, 0.6f), 0, 4.0f, 1.0f},
      {Vec3(3.7f, 5, 0.2f), 1, 3.0f, 1.0f},
      {Vec3(6.5f, 5, -0.5f), 2, 4.0f, -1.0f},  // turned over: z in [-1, 0], front down
  };
  for (const Probe& p : probes) {
    SCOPED_TRACE(p.instance);
    const auto hit = Trace(posed, p.origin, kDown);
    ASSERT_TRUE(hit);
    const StaticInstance& copy = s.instances[p.instance];
    const uint32_t triangle = posed.Triangle(hit->instance, hit->primitive);
    EXPECT_GE(triangle, copy.firstTriangle);
    EXPECT_LT(triangle, copy.firstTriangle + copy.triangleCount);
    EXPECT_NEAR(hit->t, p.distance, 1e-5f);
    // Embree's Ng is in the card's own space; turned to the world it is the
    // copy's stored (world-space) geometric normal.
    const Vec3 world = glm::normalize(posed.WorldHitNormal(hit->instance, hit->ng));
    EXPECT_NEAR(world.y, p.worldNormalY, 1e-5f);
    EXPECT_NEAR(glm::dot(world, s.GeometricNormal(triangle)), 1.0f, 1e-5f);
    // A static triangle's scene normal is already in the world.
    EXPECT_NEAR(glm::dot(posed.WorldNormal(hit->instance, s.GeometricNormal(triangle)), s.GeometricNormal(triangle)),
                1.0f, 1e-6f);
    // The hit point from the stored triangle and Embree's barycentrics is
    // where the ray met the copy.
    const Vec3 at = s.PointAt(triangle, hit->u, hit->v);
    EXPECT_NEAR(glm::length(at - (p.origin + hit->t * kDown)), 0.0f, 1e-5f);
  }
  // Beside the copies: the floor, through the static scene.
  const auto floor = Trace(posed, Vec3(-2, 5, -2), kDown);
  ASSERT_TRUE(floor);
  EXPECT_LT(posed.Triangle(floor->instance, floor->primitive), 2u);
  // The movable card keeps its own id and moves.
  const auto onBox = Trace(posed, Vec3(-4.5f, 9, 0.5f), kDown);
  ASSERT_TRUE(onBox);
  EXPECT_EQ(posed.Triangle(onBox->instance, onBox->primitive) / 2, 4u);  // triangles 8, 9
  ScenePose moved = ScenePose::Initial(s);
  moved.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(-8, 4, 0));
  auto atMoved = embree->AtPose(moved);
  ASSERT_TRUE(atMoved.ok());
  const auto copyStill = Trace(**atMoved, Vec3(3.5f, 5, 0.5f), kDown);
  ASSERT_TRUE(copyStill);
  EXPECT_EQ((*atMoved)->Triangle(copyStill->instance, copyStill->primitive) / 2, 2u);  // copy 1: triangles 4, 5
  const auto boxGone = Trace(**atMoved, Vec3(-4.5f, 9, 0.5f), kDown);
  ASSERT_TRUE(boxGone);
  EXPECT_LT((*atMoved)->Triangle(boxGone->instance, boxGone->primitive), 2u);  // the floor
}

TEST(EmbreeSceneTest, CopiesKeepTheMeshsTopologyAndFinalizeRefusesOnesThatDoNot) {
  Scene s = FloorAndCardCopies();
  for (const StaticInstance& copy : s.instances)
    for (uint32_t j = 0; j < copy.triangleCount; ++j)
      for (int c = 0; c < 3; ++c)
        EXPECT_EQ(s.triangles[copy.firstTriangle + j].v[c] - copy.firstVertex,
                  s.triangles[s.instances[0].firstTriangle + j].v[c] - s.instances[0].firstVertex);
  std::swap(s.triangles[s.instances[1].firstTriangle].v[0], s.triangles[s.instances[1].firstTriangle].v[1]);
  const Status refused = s.Finalize();
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("does not match its prototype"), std::string::npos)
      << refused.error().message;
}

}  // namespace
}  // namespace penumbra
