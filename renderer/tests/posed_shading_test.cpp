// Movable objects in the renderer (issue 14): ray queries at a pose, shading
// at a pose against closed forms, the wire pose's validation, and reference
// images of a moved scene.

#include <gtest/gtest.h>

#include <glm/trigonometric.hpp>

#include <chrono>
#include <cmath>
#include <condition_variable>
#include <limits>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/reference.h"
#include "penumbra/renderer/shade_batch.h"
#include "penumbra/renderer/shading.h"
#include "penumbra/renderer/shading_pool.h"
#include "test_scenes.h"

namespace penumbra {
namespace {

using testing::AddHorizontalSquare;
using testing::Agrees;
using testing::Estimate;
using testing::Finish;
using testing::ParallelRectangleIrradiance;
using testing::MakeMaterial;
using testing::SampleAt;
using testing::DirectOnly;
using testing::kUp;
using testing::TestScene;

constexpr float kInfinity = std::numeric_limits<float>::infinity();

RigidTransform Translation(const Vec3& t) { return RigidTransform{glm::mat3(1.0f), t}; }


// A floor (y = 0, side 20; black unless asked), a static square light of side 0.5 facing
// down at y = 2, and a movable black "occluder": a unit square in its own
// y = 0 plane, front up, starting at (0, 1, 0) -- right under the light.
struct OccluderScene {
  TestScene t;
  static constexpr float kLightHeight = 2.0f, kLightSide = 0.5f, kRadiance = 5.0f;
};

OccluderScene MakeOccluderScene(float floorAlbedo = 0.0f, float occluderAlbedo = 0.0f) {
  OccluderScene s;
  SceneBuilder b;
  const uint32_t black = b.AddMaterial(MakeMaterial(Rgb(occluderAlbedo)));
  const uint32_t light = b.AddMaterial(MakeMaterial(Rgb(0.0f), Rgb(OccluderScene::kRadiance)));
  const uint32_t floor = b.AddMaterial(MakeMaterial(Rgb(floorAlbedo)));
  AddHorizontalSquare(b, Vec3(0.0f), 20.0f, floor, true);
  AddHorizontalSquare(b, Vec3(0.0f, OccluderScene::kLightHeight, 0.0f), OccluderScene::kLightSide, light, false);
  MovableObject occluder;
  occluder.name = "occluder";
  occluder.objectToWorld = Translation(Vec3(0.0f, 1.0f, 0.0f));
  b.BeginObject(occluder);
  AddHorizontalSquare(b, Vec3(0.0f), 1.0f, black, true);
  s.t = Finish(b);
  return s;
}

// The irradiance of the light at floor point p (no occluder in the way).
double LightAt(const Vec3& p) {
  const double half = 0.5 * OccluderScene::kLightSide;
  return ParallelRectangleIrradiance(OccluderScene::kRadiance, OccluderScene::kLightHeight - p.y, -half - p.x,
                                     half - p.x, -half - p.z, half - p.z);
}

Estimate EstimateAt(const Shader& shader, const PosedRayScene& at, ShadeInput input, int batches, int paths) {
  Rgb sum(0.0f), sumSquares(0.0f);
  for (int i = 0; i < batches; ++i) {
    input.sampleId = 1000 + uint64_t(i);
    const Rgb value = shader.Shade(at, input, paths, nullptr).irradiance;
    sum += value;
    sumSquares += value * value;
  }
  const float n = float(batches);
  Estimate e;
  e.mean = sum / n;
  e.standardError = glm::sqrt(glm::max(Rgb(0.0f), (sumSquares - n * e.mean * e.mean) / (n - 1.0f)) / n);
  return e;
}

std::shared_ptr<const PosedRayScene> PoseOrFail(const RayScene& rays, const ScenePose& pose) {
  auto posed = rays.AtPose(pose);
  EXPECT_TRUE(posed.ok()) << (posed.ok() ? "" : posed.error().message);
  return posed.ok() ? *posed : nullptr;
}

// --- Ray queries at a pose -------------------------------------------------------

TEST(PosedRaySceneTest, HitsFindAMovedObjectWhereThePosePutsItWithWorldNormalsAndBaseTriangles) {
  const OccluderScene s = MakeOccluderScene();
  const Scene& scene = s.t.scene;
  const RayScene& rays = *s.t.rays;
  ASSERT_EQ(rays.MovableObjectCount(), 1u);
  const MovableObject& occluder = scene.objects[0];

  // Initially the occluder's top is at y = 1 over the origin.
  const auto before = rays.Initial()->Intersect(Vec3(0.1f, 1.5f, 0.2f), -kUp, 0.0f, kInfinity);
  ASSERT_TRUE(before);
  EXPECT_NEAR(before->t, 0.5f, 1e-5f);
  EXPECT_EQ(scene.ObjectOfTriangle(before->triangle), 0u);
  EXPECT_EQ(rays.Intersect(Vec3(0.1f, 1.5f, 0.2f), -kUp, 0.0f, kInfinity)->triangle, before->triangle);

  // Turned upside down (half a turn about x) and moved to (4, 0.5, 0): its
  // front now faces down.
  ScenePose pose = ScenePose::Initial(scene);
  pose.epoch = 3;
  pose.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), glm::radians(180.0f), Vec3(4.0f, 0.5f, 0.0f));
  const auto posed = PoseOrFail(rays, pose);
  ASSERT_TRUE(posed);
  EXPECT_EQ(posed->Pose().epoch, 3u);
  // Its old place shows the floor.
  const auto floor = posed->Intersect(Vec3(0.1f, 1.5f, 0.2f), -kUp, 0.0f, kInfinity);
  ASSERT_TRUE(floor);
  EXPECT_NEAR(floor->t, 1.5f, 1e-5f);
  EXPECT_EQ(scene.ObjectOfTriangle(floor->triangle), kStaticObject);
  EXPECT_GT(glm::normalize(floor->normal).y, 0.999f);
  EXPECT_FALSE(posed->Occluded(Vec3(0.1f, 1.5f, 0.2f), -kUp, 0.0f, 1.4f));
  // Its new place: hit from above on its back, the normal is world space (down).
  const auto moved = posed->Intersect(Vec3(4.1f, 1.5f, 0.2f), -kUp, 0.0f, kInfinity);
  ASSERT_TRUE(moved);
  EXPECT_NEAR(moved->t, 1.0f, 1e-5f);
  EXPECT_GE(moved->triangle, occluder.firstTriangle);
  EXPECT_LT(moved->triangle, occluder.firstTriangle + occluder.triangleCount);
  EXPECT_LT(glm::normalize(moved->normal).y, -0.999f);
  EXPECT_NEAR(glm::dot(glm::normalize(moved->normal), WorldGeometricNormal(scene, pose, moved->triangle)), 1.0f, 1e-5f);
  EXPECT_NEAR(glm::length(WorldPointAt(scene, pose, moved->triangle, moved->b1, moved->b2) - Vec3(4.1f, 0.5f, 0.2f)),
              0.0f, 1e-5f);
  EXPECT_TRUE(posed->Occluded(Vec3(4.1f, 1.5f, 0.2f), -kUp, 0.0f, 1.1f));
  // The initial pose answers as before.
  EXPECT_NEAR(rays.Initial()->Intersect(Vec3(0.1f, 1.5f, 0.2f), -kUp, 0.0f, kInfinity)->t, 0.5f, 1e-5f);
}

TEST(PosedRaySceneTest, AStaticSceneHasOnePoseAndRefusesObjectTransforms) {
  SceneBuilder b;
  AddHorizontalSquare(b, Vec3(0.0f), 2.0f, b.AddMaterial(MakeMaterial(Rgb(0.5f))), true);
  const TestScene t = Finish(b);
  EXPECT_EQ(t.rays->MovableObjectCount(), 0u);
  auto same = t.rays->AtPose(ScenePose::Initial(t.scene));
  ASSERT_TRUE(same.ok());
  EXPECT_EQ(same->get(), t.rays->Initial().get());
  ScenePose later;
  later.epoch = 5;
  auto atLater = t.rays->AtPose(later);
  ASSERT_TRUE(atLater.ok());
  EXPECT_EQ((*atLater)->Pose().epoch, 5u);
  EXPECT_TRUE((*atLater)->Occluded(Vec3(0.0f, 1.0f, 0.0f), -kUp, 0.0f, 2.0f));
  ScenePose wrong;
  wrong.objectToWorld.resize(1);
  EXPECT_FALSE(t.rays->AtPose(wrong).ok());
}

// --- Shading at a pose --------------------------------------------------------------

// The analytic case: the floor under a static light, with a movable
// occluder that blocks all of it at one pose and none of it at another.
TEST(PosedShadingTest, FloorUnderTheLightIsDarkWhereTheOccluderBlocksItAndLitWhereItHasMoved) {
  const OccluderScene s = MakeOccluderScene();
  const Shader shader(s.t.scene, *s.t.rays, DirectOnly());
  const ShadeInput underLight = SampleAt(s.t.scene, Vec3(0.0f), kUp);
  ASSERT_EQ(s.t.scene.ObjectOfTriangle(underLight.triangle), kStaticObject);

  // Initial pose: every line from the origin to the light crosses the unit
  // occluder at y = 1 (it spans x, z in [-0.5, 0.5]; the lines cross y = 1
  // within [-0.125, 0.125]).
  const Estimate blocked = EstimateAt(shader, *s.t.rays->Initial(), underLight, 16, 64);
  EXPECT_EQ(blocked.mean, Rgb(0.0f));

  // Moved 3 to the side: nothing between the origin and the light.
  ScenePose aside = ScenePose::Initial(s.t.scene);
  aside.epoch = 1;
  aside.objectToWorld[0] = Translation(Vec3(3.0f, 1.0f, 0.0f));
  const auto posed = PoseOrFail(*s.t.rays, aside);
  ASSERT_TRUE(posed);
  const double exact = LightAt(Vec3(0.0f));
  ASSERT_GT(exact, 0.1);
  EXPECT_TRUE(Agrees(EstimateAt(shader, *posed, underLight, 32, 64), Rgb(float(exact)), 0.01f));

  // And back: the same pose as the start shades as the start did.
  ScenePose back = ScenePose::Initial(s.t.scene);
  back.epoch = 2;
  const auto again = PoseOrFail(*s.t.rays, back);
  ASSERT_TRUE(again);
  EXPECT_EQ(EstimateAt(shader, *again, underLight, 4, 64).mean, Rgb(0.0f));
}

// --- The change through a motion volume (EstimateChangeThrough) ---------------------

Estimate AsEstimate(const ChangeEstimate& c) { return Estimate{Rgb(c.irradianceChange), Rgb(c.standardError)}; }

// The occluder's world box at a pose (a unit square: no thickness).
Bounds3 OccluderBox(const OccluderScene& s, const ScenePose& pose) { return WorldBounds(s.t.scene, pose, 0); }

// The analytic case again, as a change: the whole light the occluder blocked
// arrives once it has moved aside. The light is found by its own samples
// (only ~1 % of the region's directions would find it).
TEST(ChangeThroughTest, TheLightTheOccluderStopsBlockingArrivesThroughTheRegion) {
  const OccluderScene s = MakeOccluderScene();
  const Shader shader(s.t.scene, *s.t.rays, ShadingSettings{});
  const ShadeInput underLight = SampleAt(s.t.scene, Vec3(0.0f), kUp, 7);
  const ScenePose initial = ScenePose::Initial(s.t.scene);
  ScenePose aside = initial;
  aside.epoch = 1;
  aside.objectToWorld[0] = Translation(Vec3(3.0f, 1.0f, 0.0f));
  const auto posed = PoseOrFail(*s.t.rays, aside);
  ASSERT_TRUE(posed);
  const std::array<Bounds3, 2> region{OccluderBox(s, initial), OccluderBox(s, aside)};
  ShadeCounters work;
  const ChangeEstimate c = shader.EstimateChangeThrough(*s.t.rays->Initial(), *posed, underLight, region, 1024, &work);
  EXPECT_TRUE(Agrees(AsEstimate(c), Rgb(float(LightAt(Vec3(0.0f)))), 0.01f, 4.0f));
  EXPECT_EQ(c.paths, 1024u);
  EXPECT_GT(c.pathsThroughRegion, c.paths / 4);
  EXPECT_EQ(work.paths, 2u * 1024u);
  // Moved back the other way, the change is the opposite.
  const ChangeEstimate back = shader.EstimateChangeThrough(*posed, *s.t.rays->Initial(), underLight, region, 1024, nullptr);
  EXPECT_EQ(back.irradianceChange, -c.irradianceChange);
  EXPECT_EQ(back.standardError, c.standardError);
}

// Under a uniform sky, a black square's move from overhead to aside changes
// the floor's irradiance by the sky it uncovers minus the sky it covers
// (two parallel-rectangle form factors).
TEST(ChangeThroughTest, AnOccluderMovedUnderASkyChangesTheSkyItCoversAndUncovers) {
  constexpr float kSky = 0.8f;
  SceneBuilder b;
  const uint32_t black = b.AddMaterial(MakeMaterial(Rgb(0.0f)));
  AddHorizontalSquare(b, Vec3(0.0f), 20.0f, black, true);
  MovableObject occluder;
  occluder.name = "occluder";
  occluder.objectToWorld = Translation(Vec3(0.0f, 2.0f, 0.0f));
  b.BeginObject(occluder);
  AddHorizontalSquare(b, Vec3(0.0f), 1.0f, black, true);
  Scene withSky;
  withSky.sky = SkyLight{kUp, Rgb(kSky), Rgb(kSky), Rgb(kSky)};
  const TestScene t = Finish(b, std::move(withSky));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  const ScenePose initial = ScenePose::Initial(t.scene);
  ScenePose aside = initial;
  aside.epoch = 1;
  aside.objectToWorld[0] = Translation(Vec3(2.0f, 2.0f, 0.0f));
  const auto posed = PoseOrFail(*t.rays, aside);
  ASSERT_TRUE(posed);
  const std::array<Bounds3, 2> region{WorldBounds(t.scene, initial, 0), WorldBounds(t.scene, aside, 0)};
  const ShadeInput atOrigin = SampleAt(t.scene, Vec3(0.0f), kUp, 3);
  const double exact = ParallelRectangleIrradiance(kSky, 2.0, -0.5, 0.5, -0.5, 0.5) -
                       ParallelRectangleIrradiance(kSky, 2.0, 1.5, 2.5, -0.5, 0.5);
  ASSERT_GT(exact, 0.05);
  const ChangeEstimate c = shader.EstimateChangeThrough(*t.rays->Initial(), *posed, atOrigin, region, 4096, nullptr);
  EXPECT_TRUE(Agrees(AsEstimate(c), Rgb(float(exact)), 0.05f, 4.0f));
  // A region whose one box holds the sample too (its hemisphere is
  // sampled), and the same with an overlapping box added (densities add
  // up where silhouettes overlap): the same change.
  Bounds3 around;
  around.Extend(Vec3(-3.0f, -1.0f, -3.0f));
  around.Extend(Vec3(3.0f, 3.0f, 3.0f));
  const std::array<Bounds3, 1> enclosing{around};
  EXPECT_TRUE(Agrees(AsEstimate(shader.EstimateChangeThrough(*t.rays->Initial(), *posed, atOrigin, enclosing, 1 << 16,
                                                            nullptr)),
                     Rgb(float(exact)), 0.05f, 4.0f));
  const std::array<Bounds3, 3> overlapping{region[0], region[1], around};
  EXPECT_TRUE(Agrees(AsEstimate(shader.EstimateChangeThrough(*t.rays->Initial(), *posed, atOrigin, overlapping,
                                                            1 << 16, nullptr)),
                     Rgb(float(exact)), 0.05f, 4.0f));
  // Independent full shadings at each pose with as many paths measure the
  // same change with more noise: the hemisphere's paths mostly miss the
  // region (the squares' 0.3 sr of the hemisphere's 2 pi; the smaller the
  // region, the larger the gain). 1.8x here against the change's reported
  // error, which overstates its noise (stratified paths, an independent
  // samples' spread); 3.3x before full shadings stratified their paths too.
  const Estimate full0 = EstimateAt(shader, *t.rays->Initial(), atOrigin, 16, 256);
  const Estimate full1 = EstimateAt(shader, *posed, atOrigin, 16, 256);
  const float fullChangeError = std::hypot(full0.standardError.r, full1.standardError.r);
  EXPECT_GT(fullChangeError, 1.5f * c.standardError);
}

// Common random numbers: at the same pose every path is traced identically
// twice, so the change is exactly 0 with no noise, though the paths bounce
// off a grey occluder and floor; and a region behind the sample changes
// nothing it could see.
TEST(ChangeThroughTest, NoMoveIsExactlyNoChangeAndARegionBehindTheSampleIsNotSampled) {
  const OccluderScene s = MakeOccluderScene(0.5f, 0.5f);
  const Shader shader(s.t.scene, *s.t.rays, ShadingSettings{});
  const ScenePose initial = ScenePose::Initial(s.t.scene);
  const std::array<Bounds3, 1> region{OccluderBox(s, initial)};
  const ShadeInput nearby = SampleAt(s.t.scene, Vec3(0.7f, 0.0f, 0.2f), kUp, 11);
  const ChangeEstimate none = shader.EstimateChangeThrough(*s.t.rays->Initial(), *s.t.rays->Initial(), nearby, region, 512, nullptr);
  EXPECT_EQ(none.irradianceChange, 0.0f);
  EXPECT_EQ(none.standardError, 0.0f);
  EXPECT_GT(none.pathsThroughRegion, 100u);

  Bounds3 below;
  below.Extend(Vec3(-1.0f, -2.0f, -1.0f));
  below.Extend(Vec3(1.0f, -1.0f, 1.0f));
  const std::array<Bounds3, 1> behind{below};
  const ChangeEstimate hidden = shader.EstimateChangeThrough(*s.t.rays->Initial(), *s.t.rays->Initial(), nearby, behind, 512, nullptr);
  EXPECT_EQ(hidden.pathsThroughRegion, 0u);
  EXPECT_EQ(hidden.irradianceChange, 0.0f);
}

// Where light bounces off the moving object (a grey occluder over a grey
// floor lit around it), the change through the region agrees with the
// difference of two full shadings: a floor point sees nothing else change
// (it sees only the light, the occluder and the dark above), so the first
// order is all there is.
TEST(ChangeThroughTest, AgreesWithTheDifferenceOfFullShadingsWhereLightBouncesOffTheObject) {
  const OccluderScene s = MakeOccluderScene(0.5f, 0.6f);
  const Shader shader(s.t.scene, *s.t.rays, ShadingSettings{});
  const ScenePose initial = ScenePose::Initial(s.t.scene);
  ScenePose moved = initial;
  moved.epoch = 1;
  moved.objectToWorld[0] = Translation(Vec3(0.6f, 0.7f, 0.0f));
  const auto posed = PoseOrFail(*s.t.rays, moved);
  ASSERT_TRUE(posed);
  const std::array<Bounds3, 2> region{OccluderBox(s, initial), OccluderBox(s, moved)};
  const ShadeInput in = SampleAt(s.t.scene, Vec3(1.2f, 0.0f, 0.3f), kUp, 5);
  const Estimate e0 = EstimateAt(shader, *s.t.rays->Initial(), in, 32, 1024);
  const Estimate e1 = EstimateAt(shader, *posed, in, 32, 1024);
  const ChangeEstimate c = shader.EstimateChangeThrough(*s.t.rays->Initial(), *posed, in, region, 1 << 15, nullptr);
  const float full = Luminance(e1.mean) - Luminance(e0.mean);
  const float sigma = std::sqrt(std::pow(Luminance(e0.standardError), 2.0f) + std::pow(Luminance(e1.standardError), 2.0f) +
                                c.standardError * c.standardError);
  ASSERT_GT(std::abs(full), 8.0f * sigma) << "the move must change the point measurably";
  EXPECT_NEAR(c.irradianceChange, full, 4.0f * sigma) << "full change " << full << ", through the region " << c.irradianceChange;
}

// A sample on the moving object itself is shaded where the pose puts it:
// its world position and its triangle's world normal, not its object-space ones.
TEST(PosedShadingTest, ASampleOnTheMovedObjectIsShadedAtItsWorldPlace) {
  const OccluderScene s = MakeOccluderScene();
  const Scene& scene = s.t.scene;
  const Shader shader(scene, *s.t.rays, DirectOnly());
  const uint32_t triangle = scene.objects[0].firstTriangle;

  // Lowered to y = 0.5 and moved to x = 1.5: its centre sees the light 1.5 up
  // and 1.5 across.
  ScenePose pose = ScenePose::Initial(scene);
  pose.objectToWorld[0] = Translation(Vec3(1.5f, 0.5f, 0.0f));
  const auto posed = PoseOrFail(*s.t.rays, pose);
  ASSERT_TRUE(posed);
  // The triangle's point nearest the object's centre: its centroid.
  ShadeInput in;
  in.triangle = triangle;
  in.b1 = in.b2 = 1.0f / 3.0f;
  in.position = WorldPointAt(scene, pose, triangle, in.b1, in.b2);
  in.normal = WorldGeometricNormal(scene, pose, triangle);
  ASSERT_NEAR(in.normal.y, 1.0f, 1e-6f);
  EXPECT_TRUE(ValidateShadeInput(scene, pose, in).ok());
  // At the initial pose that position is off the triangle (it is 0.5 lower and 1.5 across).
  EXPECT_FALSE(ValidateShadeInput(scene, in).ok());
  const double exact = LightAt(in.position);
  EXPECT_TRUE(Agrees(EstimateAt(shader, *posed, in, 32, 64), Rgb(float(exact)), 0.01f)) << "exact " << exact;

  // Turned upside down at the same place, its front faces the floor: the
  // side facing up is now its back, lit the same (both sides reflect), and
  // its front sees nothing (a black floor, no sky).
  ScenePose flipped = pose;
  flipped.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), glm::radians(180.0f), Vec3(1.5f, 0.5f, 0.0f));
  const auto flippedPosed = PoseOrFail(*s.t.rays, flipped);
  ASSERT_TRUE(flippedPosed);
  ShadeInput back = in;
  back.position = WorldPointAt(scene, flipped, triangle, in.b1, in.b2);
  back.normal = kUp;
  ASSERT_LT(WorldGeometricNormal(scene, flipped, triangle).y, -0.999f);
  ASSERT_TRUE(ValidateShadeInput(scene, flipped, back).ok());
  EXPECT_TRUE(Agrees(EstimateAt(shader, *flippedPosed, back, 32, 64), Rgb(float(LightAt(back.position))), 0.01f));
  ShadeInput front = back;
  front.normal = -kUp;
  EXPECT_EQ(EstimateAt(shader, *flippedPosed, front, 4, 64).mean, Rgb(0.0f));

  // Stood on edge by a quarter turn about z, at x = 1, its front faces -x,
  // toward the light. A sample whose smooth normal leans a little down from
  // -x sees the light above it through the face's world plane (x = 1). Were
  // the face taken in object space (its plane y = const), that normal would
  // pick the face's lower side and the light would be behind it: black.
  ScenePose standing = pose;
  standing.objectToWorld[0] = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), glm::radians(90.0f), Vec3(1.0f, 1.0f, 0.0f));
  const auto standingPosed = PoseOrFail(*s.t.rays, standing);
  ASSERT_TRUE(standingPosed);
  ShadeInput edge = in;
  edge.position = WorldPointAt(scene, standing, triangle, in.b1, in.b2);
  edge.normal = glm::normalize(Vec3(-1.0f, -0.2f, 0.0f));
  ASSERT_LT(WorldGeometricNormal(scene, standing, triangle).x, -0.999f);
  ASSERT_TRUE(ValidateShadeInput(scene, standing, edge).ok());
  // E = integral over the light of L cos(at the sample) cos(at the light) / r^2, by the midpoint rule.
  double edgeExact = 0.0;
  constexpr int kCells = 200;
  const double cell = OccluderScene::kLightSide / kCells;
  for (int i = 0; i < kCells; ++i)
    for (int k = 0; k < kCells; ++k) {
      const Vec3 onLight(float(-0.5 * OccluderScene::kLightSide + (i + 0.5) * cell), OccluderScene::kLightHeight,
                         float(-0.5 * OccluderScene::kLightSide + (k + 0.5) * cell));
      const Vec3 toLight = onLight - edge.position;
      const double r2 = glm::dot(toLight, toLight);
      const Vec3 d = toLight / float(std::sqrt(r2));
      edgeExact += OccluderScene::kRadiance * std::max(0.0f, glm::dot(d, edge.normal)) * std::max(0.0f, d.y) / r2 * cell * cell;
    }
  ASSERT_GT(edgeExact, 0.1);
  EXPECT_TRUE(Agrees(EstimateAt(shader, *standingPosed, edge, 32, 64), Rgb(float(edgeExact)), 0.01f))
      << "exact " << edgeExact;
}

// A scene without movable objects shades exactly as before through any
// pose object, and the initial pose of a scene with objects exactly as the
// pose-less call: no change for static work.
TEST(PosedShadingTest, TheInitialPoseShadesBitIdenticallyToThePoselessCall) {
  const OccluderScene s = MakeOccluderScene();
  const Shader shader(s.t.scene, *s.t.rays, ShadingSettings{});
  ScenePose again = ScenePose::Initial(s.t.scene);
  again.epoch = 4;
  const auto posed = PoseOrFail(*s.t.rays, again);
  ASSERT_TRUE(posed);
  for (const Vec3 p : {Vec3(0.0f), Vec3(0.7f, 0.0f, -0.3f), Vec3(2.0f, 0.0f, 1.0f)}) {
    const ShadeInput in = SampleAt(s.t.scene, p, kUp, 77);
    const ShadeOutput a = shader.Shade(in, 32, nullptr);
    const ShadeOutput b = shader.Shade(*posed, in, 32, nullptr);
    EXPECT_EQ(a.irradiance, b.irradiance);
    EXPECT_EQ(a.radiance, b.radiance);
    EXPECT_EQ(a.irradianceStdErr, b.irradianceStdErr);
  }
}

// Moving an object far out of the scene (as a client may) changes nothing
// for the static points it does not shadow: their rays leave surfaces by the
// same offsets as before, bit for bit.
TEST(PosedShadingTest, AnObjectMovedFarAwayLeavesTheStaticShadingAsItWas) {
  const OccluderScene s = MakeOccluderScene(0.5f);
  const Shader shader(s.t.scene, *s.t.rays, ShadingSettings{});
  ScenePose far = ScenePose::Initial(s.t.scene);
  far.epoch = 1;
  far.objectToWorld[0] = Translation(Vec3(5e4f, 1.0f, -3e4f));
  const auto posed = PoseOrFail(*s.t.rays, far);
  ASSERT_TRUE(posed);
  // (3, 0, 0) sees the whole light past the occluder's first place too.
  const ShadeInput in = SampleAt(s.t.scene, Vec3(3.0f, 0.0f, 0.0f), kUp, 5);
  const ShadeOutput before = shader.Shade(in, 64, nullptr);
  const ShadeOutput after = shader.Shade(*posed, in, 64, nullptr);
  EXPECT_GT(before.irradiance.r, 0.0f);
  EXPECT_EQ(before.irradiance, after.irradiance);
  EXPECT_EQ(before.radiance, after.radiance);
  // And a sample on the far object is still checked and shaded there.
  ShadeInput onFar;
  onFar.triangle = s.t.scene.objects[0].firstTriangle;
  onFar.b1 = onFar.b2 = 0.25f;
  onFar.position = WorldPointAt(s.t.scene, far, onFar.triangle, onFar.b1, onFar.b2);
  onFar.normal = kUp;
  ASSERT_TRUE(ValidateShadeInput(s.t.scene, far, onFar).ok());
  const ShadeOutput out = shader.Shade(*posed, onFar, 16, nullptr);
  EXPECT_TRUE(std::isfinite(out.irradiance.r) && out.irradiance.r >= 0.0f);
}

// A batch a client waits for (ShadeRequest::urgent) overtakes what its
// connection has queued, and one a client is expected to want
// (ShadeRequest::soon) what is neither: with one worker busy on a long
// background batch and a test batch queued behind it, a soon batch, then two
// urgent ones, then a second soon one are answered urgent first, soon next,
// each rank in the order it came.
TEST(PosedShadingTest, UrgentThenSoonJobsOvertakeTheQueuedChunksOfTheirSource) {
  const OccluderScene s = MakeOccluderScene();
  const Shader shader(s.t.scene, *s.t.rays, DirectOnly());
  const ShadeInput underLight = SampleAt(s.t.scene, Vec3(0.0f), kUp);
  ShadingPool pool(shader, 1);
  const auto source = pool.AddSource();
  std::mutex mutex;
  std::condition_variable done;
  std::vector<uint64_t> finishedOrder;
  enum Rank { kNeither, kSoon, kUrgent };
  const auto makeJob = [&](uint64_t id, int samples, Rank rank) {
    auto job = std::make_shared<ShadeJob>();
    job->batchId = id;
    job->paths = 64;
    job->urgent = rank == kUrgent;
    job->soon = rank == kSoon;
    for (int i = 0; i < samples; ++i) {
      ShadeInput in = underLight;
      in.sampleId = id * 1000 + uint64_t(i);
      job->inputs.push_back(in);
    }
    job->onPart = [&](const ShadeJob& j, size_t, size_t, const ShadeCounters&, size_t remaining) {
      if (remaining != 0) return;
      std::lock_guard lock(mutex);
      finishedOrder.push_back(j.batchId);
      done.notify_all();
    };
    return job;
  };
  // 1 worker: chunks of 64 samples; the background batch is 16 chunks.
  pool.Submit(source, makeJob(1, 1024, kNeither));
  pool.Submit(source, makeJob(2, 256, kNeither));
  pool.Submit(source, makeJob(5, 64, kSoon));
  pool.Submit(source, makeJob(3, 64, kUrgent));
  pool.Submit(source, makeJob(4, 64, kUrgent));
  pool.Submit(source, makeJob(6, 64, kSoon));
  {
    std::unique_lock lock(mutex);
    ASSERT_TRUE(done.wait_for(lock, std::chrono::seconds(120), [&] { return finishedOrder.size() == 6; }));
  }
  EXPECT_EQ(finishedOrder, (std::vector<uint64_t>{3, 4, 5, 6, 1, 2}))
      << "urgent jobs first, then soon ones, each in their order; the others in theirs";
}

// Batches at different poses -- two SMAs, or one across a move -- share the
// pool's workers, each shaded at its own pose, whatever the interleaving.
TEST(PosedShadingTest, ThePoolShadesEachJobAtItsOwnPose) {
  const OccluderScene s = MakeOccluderScene();
  const Shader shader(s.t.scene, *s.t.rays, DirectOnly());
  ScenePose aside = ScenePose::Initial(s.t.scene);
  aside.epoch = 1;
  aside.objectToWorld[0] = Translation(Vec3(3.0f, 1.0f, 0.0f));
  const auto blocked = s.t.rays->Initial();
  const auto open = PoseOrFail(*s.t.rays, aside);
  ASSERT_TRUE(open);
  const ShadeInput underLight = SampleAt(s.t.scene, Vec3(0.0f), kUp);

  ShadingPool pool(shader, 3);
  const auto source = pool.AddSource();
  constexpr int kJobs = 24, kSamples = 40;
  std::mutex mutex;
  std::condition_variable done;
  int finished = 0;
  std::vector<std::shared_ptr<ShadeJob>> jobs;
  for (int j = 0; j < kJobs; ++j) {
    auto job = std::make_shared<ShadeJob>();
    job->batchId = uint64_t(j);
    job->paths = 16;
    job->pose = j % 2 == 0 ? blocked : open;
    for (int i = 0; i < kSamples; ++i) {
      ShadeInput in = underLight;
      in.sampleId = uint64_t(j * kSamples + i);
      job->inputs.push_back(in);
    }
    job->onPart = [&](const ShadeJob&, size_t, size_t, const ShadeCounters&, size_t remaining) {
      if (remaining != 0) return;
      std::lock_guard lock(mutex);
      ++finished;
      done.notify_all();
    };
    jobs.push_back(job);
    pool.Submit(source, job);
  }
  {
    std::unique_lock lock(mutex);
    ASSERT_TRUE(done.wait_for(lock, std::chrono::seconds(60), [&] { return finished == kJobs; }));
  }
  const float exact = float(LightAt(Vec3(0.0f)));
  for (const auto& job : jobs) {
    for (const ShadeOutput& out : job->outputs) {
      if (job->batchId % 2 == 0)
        EXPECT_EQ(out.irradiance.r, 0.0f) << "batch " << job->batchId;
      else
        EXPECT_NEAR(out.irradiance.r, exact, 0.3f * exact) << "batch " << job->batchId;
    }
  }
}

// --- The wire pose ------------------------------------------------------------------

wire::ShadeRequest OneSampleRequest(const Scene& scene, const ShadeInput& in) {
  wire::ShadeRequest r;
  r.set_batch_id(42);
  r.add_sample_ids(in.sampleId);
  for (int k = 0; k < 3; ++k) r.add_positions(in.position[k]);
  for (int k = 0; k < 3; ++k) r.add_normals(in.normal[k]);
  r.add_triangle_ids(in.triangle);
  r.add_barycentrics(in.b1);
  r.add_barycentrics(in.b2);
  (void)scene;
  return r;
}

void AddTransform(wire::ShadeRequest& r, const RigidTransform& t) {
  for (float v : t.ToRowMajor()) r.add_object_transforms(v);
}

std::string ErrorOf(const Expected<ScenePose>& pose) { return pose.ok() ? std::string() : pose.error().message; }

TEST(ShadePoseTest, NoTransformsIsTheInitialPoseAtEpochZeroOnly) {
  const OccluderScene s = MakeOccluderScene();
  const wire::ShadeRequest r = OneSampleRequest(s.t.scene, SampleAt(s.t.scene, Vec3(0.0f), kUp));
  auto pose = DecodeShadePose(r, s.t.scene);
  ASSERT_TRUE(pose.ok()) << pose.error().message;
  EXPECT_EQ(pose->epoch, 0u);
  EXPECT_TRUE(pose->SamePlaces(ScenePose::Initial(s.t.scene)));

  wire::ShadeRequest later = r;
  later.set_scene_epoch(3);
  const std::string error = ErrorOf(DecodeShadePose(later, s.t.scene));
  EXPECT_NE(error.find("batch 42: scene_epoch 3 without object_transforms"), std::string::npos) << error;

  // A scene without movable objects has one pose, whatever its number.
  SceneBuilder b;
  AddHorizontalSquare(b, Vec3(0.0f), 2.0f, b.AddMaterial(MakeMaterial(Rgb(0.5f))), true);
  const TestScene plain = Finish(b);
  auto plainPose = DecodeShadePose(later, plain.scene);
  ASSERT_TRUE(plainPose.ok()) << plainPose.error().message;
  EXPECT_EQ(plainPose->epoch, 3u);
  EXPECT_TRUE(plainPose->objectToWorld.empty());
}

TEST(ShadePoseTest, TransformsAreTwelvePerObjectFiniteAndRigid) {
  const OccluderScene s = MakeOccluderScene();
  const Scene& scene = s.t.scene;
  // A sample on the floor: its place does not depend on the pose.
  wire::ShadeRequest r = OneSampleRequest(scene, SampleAt(scene, Vec3(0.5f, 0.0f, 0.5f), kUp));
  r.set_scene_epoch(8);
  const RigidTransform moved = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(30.0f), Vec3(2, 1, 0));
  AddTransform(r, moved);
  auto pose = DecodeShadePose(r, scene);
  ASSERT_TRUE(pose.ok()) << pose.error().message;
  EXPECT_EQ(pose->epoch, 8u);
  ASSERT_EQ(pose->objectToWorld.size(), 1u);
  EXPECT_NEAR(glm::length(pose->objectToWorld[0].translation - Vec3(2, 1, 0)), 0.0f, 1e-6f);
  EXPECT_TRUE(DecodeShadeRequest(r, scene, ShadeLimits{}).ok());

  wire::ShadeRequest tooMany = r;
  AddTransform(tooMany, moved);
  std::string error = ErrorOf(DecodeShadePose(tooMany, scene));
  EXPECT_NE(error.find("object_transforms has 24 values, expected 12"), std::string::npos) << error;
  wire::ShadeRequest partial = r;
  partial.mutable_object_transforms()->RemoveLast();
  error = ErrorOf(DecodeShadePose(partial, scene));
  EXPECT_NE(error.find("has 11 values"), std::string::npos) << error;

  wire::ShadeRequest nan = r;
  nan.set_object_transforms(4, std::numeric_limits<float>::quiet_NaN());
  error = ErrorOf(DecodeShadePose(nan, scene));
  EXPECT_NE(error.find("object 1 ('occluder'): transform entry 4 is not finite"), std::string::npos) << error;
  wire::ShadeRequest scaled = r;
  for (int i : {0, 5, 10}) scaled.set_object_transforms(i, 2.0f * scaled.object_transforms(i));
  error = ErrorOf(DecodeShadePose(scaled, scene));
  EXPECT_NE(error.find("not a rotation"), std::string::npos) << error;
  // The two-argument decode refuses the batch for its pose too.
  auto decoded = DecodeShadeRequest(scaled, scene, ShadeLimits{});
  ASSERT_FALSE(decoded.ok());
  EXPECT_NE(decoded.error().message.find("not a rotation"), std::string::npos);
}

TEST(ShadePoseTest, SamplesOnAMovedObjectAreCheckedAtTheRequestsPose) {
  const OccluderScene s = MakeOccluderScene();
  const Scene& scene = s.t.scene;
  const uint32_t triangle = scene.objects[0].firstTriangle;
  ScenePose pose = ScenePose::Initial(scene);
  pose.objectToWorld[0] = Translation(Vec3(-2.0f, 0.25f, 1.0f));
  ShadeInput in;
  in.triangle = triangle;
  in.b1 = 0.2f;
  in.b2 = 0.3f;
  in.position = WorldPointAt(scene, pose, triangle, in.b1, in.b2);
  in.normal = kUp;
  wire::ShadeRequest r = OneSampleRequest(scene, in);
  AddTransform(r, pose.objectToWorld[0]);
  r.set_scene_epoch(1);
  auto inputs = DecodeShadeRequest(r, scene, ShadeLimits{});
  ASSERT_TRUE(inputs.ok()) << inputs.error().message;
  // The same sample sent with the initial pose's transform is off its triangle.
  wire::ShadeRequest stale = OneSampleRequest(scene, in);
  AddTransform(stale, scene.objects[0].objectToWorld);
  stale.set_scene_epoch(1);
  auto refused = DecodeShadeRequest(stale, scene, ShadeLimits{});
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("away from triangle"), std::string::npos) << refused.error().message;
}

// A verification batch (verify_change): the baseline pose and the boxes are
// decoded and checked, a sample on the moving object is refused, and the
// reply carries the changes.
TEST(VerifyChangeTest, DecodesTheBaselineAndTheBoxesAndRefusesWhatCannotBeVerified) {
  const OccluderScene s = MakeOccluderScene();
  const Scene& scene = s.t.scene;
  const ShadeInput floor = SampleAt(scene, Vec3(0.0f), kUp, 3);
  ScenePose aside = ScenePose::Initial(scene);
  aside.epoch = 4;
  aside.objectToWorld[0] = Translation(Vec3(3.0f, 1.0f, 0.0f));
  const auto request = [&](const ShadeInput& in) {
    wire::ShadeRequest r = OneSampleRequest(scene, in);
    r.set_scene_epoch(4);
    AddTransform(r, aside.objectToWorld[0]);
    auto* v = r.mutable_verify_change();
    v->set_baseline_epoch(2);
    for (float x : scene.objects[0].objectToWorld.ToRowMajor()) v->add_baseline_object_transforms(x);
    for (const ScenePose& p : {ScenePose::Initial(scene), aside}) {
      const Bounds3 b = WorldBounds(scene, p, 0);
      for (float x : {b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z}) v->add_region_boxes(x);
    }
    return r;
  };
  const std::vector<ShadeInput> inputs{floor};
  auto decoded = DecodeVerifyChange(request(floor), scene, inputs);
  ASSERT_TRUE(decoded.ok()) << decoded.error().message;
  EXPECT_EQ(decoded->baseline.epoch, 2u);
  EXPECT_TRUE(decoded->baseline.SamePlaces(ScenePose::Initial(scene)));
  ASSERT_EQ(decoded->region.size(), 2u);
  EXPECT_EQ(decoded->region[1].min, WorldBounds(scene, aside, 0).min);

  const auto refused = [&](wire::ShadeRequest r, const std::vector<ShadeInput>& in, const std::string& mention) {
    auto d = DecodeVerifyChange(r, scene, in);
    ASSERT_FALSE(d.ok()) << mention;
    EXPECT_NE(d.error().message.find(mention), std::string::npos) << d.error().message;
  };
  {
    wire::ShadeRequest r = request(floor);
    r.mutable_verify_change()->set_region_boxes(4, std::nanf(""));
    refused(r, inputs, "box 0 is not finite");
  }
  {
    wire::ShadeRequest r = request(floor);
    r.mutable_verify_change()->set_region_boxes(9, -5.0f);  // box 1's max y under its min
    refused(r, inputs, "box 1 has a min above its max");
  }
  {
    wire::ShadeRequest r = request(floor);
    r.mutable_verify_change()->add_region_boxes(1.0f);
    refused(r, inputs, "region_boxes has 13 values");
  }
  {
    wire::ShadeRequest r = request(floor);
    r.mutable_verify_change()->clear_region_boxes();
    refused(r, inputs, "region_boxes has 0 values");
  }
  {
    wire::ShadeRequest r = request(floor);
    for (int i = 0; i < 6 * 16; ++i) r.mutable_verify_change()->add_region_boxes(0.0f);  // 18 boxes
    refused(r, inputs, "1 to 16 boxes");
  }
  {
    wire::ShadeRequest r = request(floor);
    r.mutable_verify_change()->set_baseline_object_transforms(0, 3.0f);  // a scale
    refused(r, inputs, "verify_change.baseline_object_transforms of object 1");
  }
  {
    wire::ShadeRequest r = request(floor);
    r.mutable_verify_change()->clear_baseline_object_transforms();  // a later epoch without its pose
    refused(r, inputs, "verify_change.baseline_epoch 2 without");
  }
  {
    ShadeInput onOccluder;
    onOccluder.triangle = scene.objects[0].firstTriangle;
    onOccluder.b1 = onOccluder.b2 = 0.25f;
    onOccluder.position = WorldPointAt(scene, aside, onOccluder.triangle, 0.25f, 0.25f);
    onOccluder.normal = kUp;
    refused(request(onOccluder), {onOccluder}, "lies on movable object 'occluder'");
  }

  // The reply: one change and its standard error per sample.
  const std::vector<ChangeEstimate> changes{ChangeEstimate{0.25f, 0.01f, 64, 60, 1.5f}};
  wire::ShadeReply reply;
  FillChangeReply(42, inputs, changes, 0, ShadeCounters{128, 300, 100, 0}, &reply);
  EXPECT_EQ(reply.batch_id(), 42u);
  ASSERT_EQ(reply.sample_ids_size(), 1);
  EXPECT_EQ(reply.sample_ids(0), floor.sampleId);
  ASSERT_EQ(reply.irradiance_change_size(), 1);
  EXPECT_EQ(reply.irradiance_change(0), 0.25f);
  EXPECT_EQ(reply.irradiance_change_stderr(0), 0.01f);
  EXPECT_EQ(reply.irradiance_size(), 0);
  EXPECT_EQ(reply.paths_traced(), 128u);
}

// --- Reference images of a moved scene ------------------------------------------------

TEST(PlaceObjectTest, ReadsATransformOrATranslationAndRefusesTheRest) {
  const OccluderScene s = MakeOccluderScene();
  const Scene& scene = s.t.scene;
  ScenePose pose = ScenePose::Initial(scene);
  ASSERT_TRUE(PlaceObject(scene, "occluder=translate:3,+0.5,-1e-1", &pose).ok());
  EXPECT_NEAR(glm::length(pose.objectToWorld[0].translation - Vec3(3.0f, 1.5f, -0.1f)), 0.0f, 1e-6f);
  const Status full = PlaceObject(scene, "occluder=0,-1,0,4,1,0,0,5,0,0,1,6", &pose);
  ASSERT_TRUE(full.ok()) << full.error().message;
  EXPECT_NEAR(glm::length(pose.objectToWorld[0].ApplyPoint(Vec3(1, 0, 0)) - Vec3(4, 6, 6)), 0.0f, 1e-6f);

  const auto errorOf = [&](const std::string& spec) {
    ScenePose p = ScenePose::Initial(scene);
    const Status st = PlaceObject(scene, spec, &p);
    EXPECT_TRUE(p.SamePlaces(ScenePose::Initial(scene))) << spec << " changed the pose";
    return st.ok() ? std::string() : st.error().message;
  };
  EXPECT_NE(errorOf("chair=translate:1,2,3").find("no movable object 'chair' (it has occluder)"), std::string::npos);
  EXPECT_NE(errorOf("occluder").find("expected NAME="), std::string::npos);
  EXPECT_NE(errorOf("occluder=translate:1,2").find("expected 3 numbers, got 2"), std::string::npos);
  EXPECT_NE(errorOf("occluder=1,0,0,0,0,1,0,0,0,0,1").find("expected 12 numbers, got 11"), std::string::npos);
  EXPECT_NE(errorOf("occluder=translate:1,x,3").find("'x' is not a number"), std::string::npos);
  EXPECT_NE(errorOf("occluder=translate:1, 2,3").find("' 2' is not a number"), std::string::npos);
  EXPECT_NE(errorOf("occluder=translate:1,nan,3").find("not finite"), std::string::npos);
  EXPECT_NE(errorOf("occluder=2,0,0,0,0,2,0,0,0,0,2,0").find("not a rotation"), std::string::npos);
  EXPECT_NE(errorOf("occluder=translate:1e30,0,0").find("beyond"), std::string::npos);
}

TEST(PlaceObjectTest, AnimatedObjectsArePlacedAtTheirAnimationsTime) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  AddHorizontalSquare(b, Vec3(0.0f), 4.0f, m, true);
  MovableObject slider;
  slider.name = "slider";
  ObjectAnimation animation;
  animation.loop = false;
  animation.keys = {ObjectKeyframe{0.0f, Translation(Vec3(0.0f, 1.0f, 0.0f))},
                    ObjectKeyframe{2.0f, Translation(Vec3(4.0f, 1.0f, 0.0f))}};
  slider.objectToWorld = animation.keys[0].objectToWorld;
  slider.animation = animation;
  b.BeginObject(slider);
  AddHorizontalSquare(b, Vec3(0.0f), 0.5f, m, true);
  MovableObject still;
  still.name = "still";
  still.objectToWorld = Translation(Vec3(-1.0f, 2.0f, 0.0f));
  b.BeginObject(still);
  AddHorizontalSquare(b, Vec3(0.0f), 0.5f, m, true);
  const TestScene t = Finish(b);
  ASSERT_EQ(t.scene.objects.size(), 2u);

  ScenePose pose = ScenePose::Initial(t.scene);
  PlaceAnimatedObjects(t.scene, 0.5, &pose);
  EXPECT_NEAR(glm::length(pose.objectToWorld[0].translation - Vec3(1.0f, 1.0f, 0.0f)), 0.0f, 1e-6f);
  EXPECT_EQ(pose.objectToWorld[1], t.scene.objects[1].objectToWorld);
  PlaceAnimatedObjects(t.scene, 10.0, &pose);  // held at the end
  EXPECT_NEAR(glm::length(pose.objectToWorld[0].translation - Vec3(4.0f, 1.0f, 0.0f)), 0.0f, 1e-6f);
  // --object then moves one of them from there.
  ASSERT_TRUE(PlaceObject(t.scene, "slider=translate:0,0,1", &pose).ok());
  EXPECT_NEAR(glm::length(pose.objectToWorld[0].translation - Vec3(4.0f, 1.0f, 1.0f)), 0.0f, 1e-6f);
}

TEST(PosedReferenceTest, TheImageShowsTheShadowWhereThePosePutsTheOccluder) {
  const OccluderScene s = MakeOccluderScene(0.5f);
  ShadingSettings settings = DirectOnly();
  settings.pathsPerSample = 64;
  const Shader shader(s.t.scene, *s.t.rays, settings);
  // Looking straight down at the floor around the origin from just under
  // the occluder's first place (y = 1).
  CameraView view;
  view.pose.eye = Vec3(0.0f, 0.9f, 0.0f);
  view.pose.target = Vec3(0.0f);
  view.pose.up = Vec3(0.0f, 0.0f, -1.0f);
  view.fovYDeg = 10.0f;
  view.width = 4;
  view.height = 4;
  ASSERT_TRUE(ValidateCameraView(view).ok());
  const auto meanRed = [](const Image& image) {
    double sum = 0.0;
    for (size_t i = 0; i < image.rgb.size(); i += 3) sum += image.rgb[i];
    return sum / double(image.rgb.size() / 3);
  };
  // Initially the floor there is in the occluder's umbra.
  const Image shadowed = RenderReference(shader, *s.t.rays->Initial(), view, 2, nullptr, PixelFilter::kCentre);
  EXPECT_EQ(meanRed(shadowed), 0.0);
  // With the occluder 3 to the side (as penumbra-reference --object places
  // it), the floor reads albedo / pi times the light's irradiance.
  ScenePose pose = ScenePose::Initial(s.t.scene);
  ASSERT_TRUE(PlaceObject(s.t.scene, "occluder=translate:3,0,0", &pose).ok());
  const auto posed = PoseOrFail(*s.t.rays, pose);
  ASSERT_TRUE(posed);
  const Image lit = RenderReference(shader, *posed, view, 2, nullptr, PixelFilter::kCentre);
  const double expected = 0.5 / kPi * LightAt(Vec3(0.0f));
  EXPECT_NEAR(meanRed(lit), expected, 0.1 * expected);
}

}  // namespace
}  // namespace penumbra
