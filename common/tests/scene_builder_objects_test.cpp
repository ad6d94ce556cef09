// Movable objects in a Scene (issue 14): SceneBuilder's ranges and welding,
// the object lookups, world placement at a pose, Finalize's refusals, and
// ObjectAnimation::At.

#include <gtest/gtest.h>

#include <glm/trigonometric.hpp>

#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/scene.h"

namespace penumbra {
namespace {

uint32_t White(SceneBuilder& b) {
  Material m;
  m.name = "white";
  return b.AddMaterial(m);
}

MovableObject Named(std::string name, RigidTransform objectToWorld = RigidTransform::Identity()) {
  MovableObject o;
  o.name = std::move(name);
  o.objectToWorld = objectToWorld;
  return o;
}

// A unit square in the y = 0 plane, front +y, from `corner`.
void AddFloorSquare(SceneBuilder& b, const Vec3& corner, uint32_t material) {
  b.AddQuad(corner, Vec3(0, 0, 1), Vec3(1, 0, 0), material);
}

std::string ErrorOf(SceneBuilder& b, Scene& s) {
  auto st = b.BuildInto(s);
  return st.ok() ? std::string() : st.error().message;
}

TEST(SceneBuilderObjectsTest, ObjectsFollowTheStaticPartInContiguousRangesInTheirOrder) {
  SceneBuilder b;
  const uint32_t m = White(b);
  AddFloorSquare(b, Vec3(0, 0, 0), m);  // static
  EXPECT_EQ(b.BeginObject(Named("box")), 0u);
  AddFloorSquare(b, Vec3(5, 0, 0), m);
  AddFloorSquare(b, Vec3(6, 0, 0), m);
  b.EndObject();
  AddFloorSquare(b, Vec3(1, 0, 0), m);  // static again, after the object
  EXPECT_EQ(b.BeginObject(Named("lid")), 1u);
  AddFloorSquare(b, Vec3(9, 0, 0), m);
  Scene s;
  ASSERT_EQ(ErrorOf(b, s), "");

  ASSERT_EQ(s.objects.size(), 2u);
  EXPECT_EQ(s.staticTriangleCount, 4u);
  const MovableObject& box = s.objects[0];
  const MovableObject& lid = s.objects[1];
  EXPECT_EQ(box.name, "box");
  EXPECT_EQ(box.firstTriangle, 4u);
  EXPECT_EQ(box.triangleCount, 4u);
  EXPECT_EQ(lid.firstTriangle, 8u);
  EXPECT_EQ(lid.triangleCount, 2u);
  EXPECT_EQ(s.triangles.size(), 10u);
  // The two static squares share an edge and weld (6 vertices); the box's two
  // squares weld among themselves (6); the lid has its own 4.
  EXPECT_EQ(s.staticVertexCount, 6u);
  EXPECT_EQ(box.firstVertex, 6u);
  EXPECT_EQ(box.vertexCount, 6u);
  EXPECT_EQ(lid.firstVertex, 12u);
  EXPECT_EQ(lid.vertexCount, 4u);
  EXPECT_EQ(s.vertices.size(), 16u);

  for (uint32_t t = 0; t < s.triangles.size(); ++t) {
    const uint32_t expected = t < 4 ? kStaticObject : t < 8 ? 0u : 1u;
    EXPECT_EQ(s.ObjectOfTriangle(t), expected) << "triangle " << t;
    for (uint32_t v : s.triangles[t].v) EXPECT_EQ(s.ObjectOfVertex(v), expected) << "triangle " << t << " vertex " << v;
  }
  // Within each part the order of addition is kept: the static part's first
  // square (at x in [0, 1]) comes first.
  EXPECT_LE(s.Position(0, 0).x, 1.0f);
  EXPECT_GE(s.Position(2, 0).x, 1.0f);
  EXPECT_EQ(s.FindObject("lid"), 1u);
  EXPECT_EQ(s.FindObject("chair"), kStaticObject);
}

TEST(SceneBuilderObjectsTest, CornersOfDifferentPartsNeverWeld) {
  SceneBuilder b;
  const uint32_t m = White(b);
  AddFloorSquare(b, Vec3(0, 0, 0), m);
  b.BeginObject(Named("a"));
  AddFloorSquare(b, Vec3(1, 0, 0), m);  // shares an edge with the static square
  b.BeginObject(Named("b"));
  AddFloorSquare(b, Vec3(1, 0, 0), m);  // exactly on object a: not a duplicate of it either
  Scene s;
  ASSERT_EQ(ErrorOf(b, s), "");
  EXPECT_EQ(s.triangles.size(), 6u);
  EXPECT_EQ(s.vertices.size(), 12u);
  EXPECT_EQ(b.DuplicateTriangles(), 0u);
  // Without objects the same squares weld along the shared edge.
  SceneBuilder plain;
  const uint32_t pm = White(plain);
  AddFloorSquare(plain, Vec3(0, 0, 0), pm);
  AddFloorSquare(plain, Vec3(1, 0, 0), pm);
  Scene p;
  ASSERT_EQ(ErrorOf(plain, p), "");
  EXPECT_EQ(p.vertices.size(), 6u);
}

TEST(SceneBuilderObjectsTest, ObjectGeometryIsInObjectSpaceAndAPosePlacesIt) {
  SceneBuilder b;
  const uint32_t m = White(b);
  AddFloorSquare(b, Vec3(0, 0, 0), m);
  // Initially a quarter turn about z and lifted by 2: the object's +y face
  // faces -x in the world.
  const RigidTransform initial = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), glm::radians(90.0f), Vec3(0, 2, 0));
  b.BeginObject(Named("card", initial));
  AddFloorSquare(b, Vec3(0, 0, 0), m);
  Scene s;
  ASSERT_EQ(ErrorOf(b, s), "");
  const uint32_t card = s.objects[0].firstTriangle;
  // Stored in object space.
  EXPECT_NEAR(s.GeometricNormal(card).y, 1.0f, 1e-6f);
  EXPECT_NEAR(s.objects[0].objectBounds.max.x, 1.0f, 1e-6f);
  EXPECT_NEAR(s.objects[0].objectBounds.max.y, 0.0f, 1e-6f);
  // The scene's bounds hold the card where it starts: standing, y in [2, 3].
  EXPECT_NEAR(s.bounds.max.y, 3.0f, 1e-5f);

  ScenePose pose = ScenePose::Initial(s);
  EXPECT_EQ(pose.epoch, 0u);
  ASSERT_EQ(pose.objectToWorld.size(), 1u);
  const Vec3 n = WorldGeometricNormal(s, pose, card);
  EXPECT_NEAR(n.x, -1.0f, 1e-5f);
  // Object point (1, 0, 0) turns to (0, 1, 0) and rises to (0, 3, 0).
  const Triangle& tri = s.triangles[card];
  for (int c = 0; c < 3; ++c) {
    const Vec3 world = WorldPointAt(s, pose, card, c == 1 ? 1.0f : 0.0f, c == 2 ? 1.0f : 0.0f);
    const Vec3 expected = initial.ApplyPoint(s.vertices[tri.v[c]].position);
    EXPECT_NEAR(glm::length(world - expected), 0.0f, 1e-5f) << "corner " << c;
  }
  // Static triangles are world space whatever the pose.
  pose.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), 1.0f, Vec3(7, 7, 7));
  EXPECT_EQ(WorldPointAt(s, pose, 0, 0.25f, 0.25f), s.PointAt(0, 0.25f, 0.25f));
  EXPECT_EQ(WorldGeometricNormal(s, pose, 0), s.GeometricNormal(0));
  const Bounds3 moved = WorldBounds(s, pose, 0);
  EXPECT_GT(moved.min.x, 6.5f);
  EXPECT_EQ(pose.Of(kStaticObject), RigidTransform::Identity());
  // Places compare without the epoch.
  ScenePose later = pose;
  later.epoch = 9;
  EXPECT_TRUE(later.SamePlaces(pose));
  EXPECT_FALSE(later.SamePlaces(ScenePose::Initial(s)));
}

TEST(SceneBuilderObjectsTest, IdentityCoversTheObjectsNamesAndPlaces) {
  auto make = [](const std::string& name, float lift) {
    SceneBuilder b;
    const uint32_t m = White(b);
    AddFloorSquare(b, Vec3(0, 0, 0), m);
    b.BeginObject(Named(name, RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(0, lift, 0))));
    AddFloorSquare(b, Vec3(0, 0, 0), m);
    Scene s;
    EXPECT_TRUE(b.BuildInto(s).ok());
    return s.identity;
  };
  EXPECT_EQ(make("box", 1.0f), make("box", 1.0f));
  EXPECT_NE(make("box", 1.0f), make("box", 2.0f));
  EXPECT_NE(make("box", 1.0f), make("crate", 1.0f));
}

// Two animation paths from the same place are different scenes (the SMA
// plays them; snapshots hold samples of their poses); a scene without one
// keeps the identity it had before paths counted.
TEST(SceneBuilderObjectsTest, IdentityCoversAnimationPaths) {
  auto make = [](std::optional<float> endLift, bool loop) {
    SceneBuilder b;
    const uint32_t m = White(b);
    AddFloorSquare(b, Vec3(0, 0, 0), m);
    MovableObject o = Named("box", RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(0, 1.0f, 0)));
    if (endLift) {
      ObjectAnimation path;
      path.loop = loop;
      path.keys = {ObjectKeyframe{0.0f, o.objectToWorld},
                   ObjectKeyframe{2.0f, RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(0, *endLift, 0))}};
      o.animation = path;
    }
    b.BeginObject(o);
    AddFloorSquare(b, Vec3(0, 0, 0), m);
    Scene s;
    EXPECT_TRUE(b.BuildInto(s).ok());
    return s.identity;
  };
  EXPECT_EQ(make(2.0f, true), make(2.0f, true));
  EXPECT_NE(make(2.0f, true), make(3.0f, true));
  EXPECT_NE(make(2.0f, true), make(2.0f, false));
  EXPECT_NE(make(2.0f, true), make(std::nullopt, true));
}

TEST(SceneBuilderObjectsTest, FinalizeRefusesEmissiveObjectsDuplicateNamesAndEmptyObjects) {
  {
    SceneBuilder b;
    const uint32_t m = White(b);
    Material lamp;
    lamp.name = "lamp";
    lamp.emission = Rgb(5.0f);
    const uint32_t l = b.AddMaterial(lamp);
    AddFloorSquare(b, Vec3(0), m);
    b.BeginObject(Named("torch"));
    AddFloorSquare(b, Vec3(0, 1, 0), l);
    Scene s;
    s.name = "lit";
    const std::string error = ErrorOf(b, s);
    EXPECT_NE(error.find("movable object 'torch' has an emissive material ('lamp')"), std::string::npos) << error;
    EXPECT_NE(error.find("lit"), std::string::npos) << error;
  }
  {
    SceneBuilder b;
    const uint32_t m = White(b);
    AddFloorSquare(b, Vec3(0), m);
    b.BeginObject(Named("chair"));
    AddFloorSquare(b, Vec3(2, 0, 0), m);
    b.BeginObject(Named("chair"));
    AddFloorSquare(b, Vec3(4, 0, 0), m);
    Scene s;
    const std::string error = ErrorOf(b, s);
    EXPECT_NE(error.find("two movable objects are called 'chair'"), std::string::npos) << error;
  }
  {
    SceneBuilder b;
    const uint32_t m = White(b);
    AddFloorSquare(b, Vec3(0), m);
    b.BeginObject(Named(""));
    AddFloorSquare(b, Vec3(2, 0, 0), m);
    Scene s;
    const std::string error = ErrorOf(b, s);
    EXPECT_NE(error.find("has no name"), std::string::npos) << error;
  }
  {
    SceneBuilder b;
    const uint32_t m = White(b);
    AddFloorSquare(b, Vec3(0), m);
    b.BeginObject(Named("flat"));
    b.AddTriangle({Vec3(0), Vec3(1, 0, 0), Vec3(2, 0, 0)}, m);  // no area: dropped
    Scene s;
    const std::string error = ErrorOf(b, s);
    EXPECT_NE(error.find("movable object 'flat' has no triangles"), std::string::npos) << error;
  }
}

ObjectAnimation Slide(std::vector<float> times, bool loop = true) {
  ObjectAnimation a;
  a.loop = loop;
  for (size_t k = 0; k < times.size(); ++k)
    a.keys.push_back(ObjectKeyframe{times[k], RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(float(k), 0, 0))});
  return a;
}

TEST(SceneBuilderObjectsTest, FinalizeRefusesBadAnimations) {
  const struct {
    ObjectAnimation animation;
    const char* message;
  } cases[] = {
      {Slide({0.0f}), "at least 2 keyframes"},
      {Slide({0.5f, 1.0f}), "first keyframe must be at t = 0"},
      {Slide({0.0f, 1.0f, 1.0f}), "keyframe 2 at t = 1 is not after the one before"},
      {Slide({0.0f, 2.0f, 1.0f}), "keyframe 2 at t = 1 is not after the one before"},
      {Slide({0.0f, std::numeric_limits<float>::quiet_NaN()}), "keyframe 1"},
  };
  for (const auto& c : cases) {
    SceneBuilder b;
    const uint32_t m = White(b);
    AddFloorSquare(b, Vec3(0), m);
    MovableObject o = Named("slider");
    o.animation = c.animation;
    b.BeginObject(o);
    AddFloorSquare(b, Vec3(2, 0, 0), m);
    Scene s;
    const std::string error = ErrorOf(b, s);
    EXPECT_NE(error.find("object 'slider'"), std::string::npos) << error;
    EXPECT_NE(error.find(c.message), std::string::npos) << "expected '" << c.message << "' in: " << error;
  }
  // A good one passes.
  SceneBuilder b;
  const uint32_t m = White(b);
  AddFloorSquare(b, Vec3(0), m);
  MovableObject o = Named("slider");
  o.animation = Slide({0.0f, 1.0f, 3.0f});
  b.BeginObject(o);
  AddFloorSquare(b, Vec3(2, 0, 0), m);
  Scene s;
  EXPECT_EQ(ErrorOf(b, s), "");
}

TEST(ObjectAnimationTest, InterpolatesBetweenKeysAndLoopsOrHoldsAfterTheLast) {
  // x = 0 at t = 0, x = 1 at t = 1, x = 2 at t = 3.
  const ObjectAnimation looped = Slide({0.0f, 1.0f, 3.0f}, true);
  const ObjectAnimation held = Slide({0.0f, 1.0f, 3.0f}, false);
  EXPECT_DOUBLE_EQ(looped.DurationS(), 3.0);
  const auto x = [](const ObjectAnimation& a, double t) { return a.At(t).translation.x; };
  EXPECT_NEAR(x(looped, 0.0), 0.0f, 1e-6f);
  EXPECT_NEAR(x(looped, 0.5), 0.5f, 1e-6f);
  EXPECT_NEAR(x(looped, 1.0), 1.0f, 1e-6f);
  EXPECT_NEAR(x(looped, 2.0), 1.5f, 1e-6f);
  EXPECT_NEAR(x(looped, -1.0), 0.0f, 1e-6f);  // before the start: the first key
  // Looped: t = 3.5 is t = 0.5 again, and t = 3 the start.
  EXPECT_NEAR(x(looped, 3.5), 0.5f, 1e-5f);
  EXPECT_NEAR(x(looped, 3.0), 0.0f, 1e-6f);
  EXPECT_NEAR(x(looped, 3.0 * 1000 + 2.0), 1.5f, 1e-4f);
  // Held: the last key from t = 3 on.
  EXPECT_NEAR(x(held, 2.0), 1.5f, 1e-6f);
  EXPECT_NEAR(x(held, 3.0), 2.0f, 1e-6f);
  EXPECT_NEAR(x(held, 100.0), 2.0f, 1e-6f);
  // Rotation goes by slerp: half way between 0 and 90 degrees is 45.
  ObjectAnimation turn;
  turn.keys = {ObjectKeyframe{0.0f, RigidTransform::Identity()},
               ObjectKeyframe{2.0f, RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(90.0f), Vec3(0))}};
  const Vec3 d = turn.At(1.0).ApplyVector(Vec3(1, 0, 0));
  EXPECT_NEAR(d.x, std::sqrt(0.5f), 1e-5f);
  EXPECT_NEAR(d.z, -std::sqrt(0.5f), 1e-5f);
}

}  // namespace
}  // namespace penumbra
