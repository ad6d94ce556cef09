// The SMA's move invalidation (sma/motion_volume.h) against the renderer's
// path tracer: shade a grid of static points with the box at its old place
// and at its new place, and check that every point whose radiance really
// changed (beyond 4 standard errors of the difference) is in the invalidated
// set computed from the old samples alone -- nothing stale is kept. Links
// both tiers' libraries (which never include each other), like
// shade_codec_test.
//
// The two poses are two static scenes with the box baked at each place: the
// same light transport as one scene with a movable box at two poses, without
// depending on the renderer's pose support.

#include <gtest/gtest.h>

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "penumbra/common/scene.h"
#include "penumbra/renderer/ray_scene.h"
#include "penumbra/renderer/shading.h"
#include "penumbra/sma/motion_volume.h"
#include "test_scenes.h"  // renderer/tests: SampleAt

namespace penumbra {
namespace {

Material Lambert(float albedo, float emission = 0.0f) {
  Material m;
  m.albedo = Rgb(albedo);
  m.emission = Rgb(emission);
  return m;
}

// An axis-aligned box of six outward-facing quads.
void AddBlock(SceneBuilder& b, const Vec3& lo, const Vec3& hi, uint32_t material) {
  const Vec3 size = hi - lo;
  for (int axis = 0; axis < 3; ++axis) {
    for (int side = 0; side < 2; ++side) {
      Vec3 front(0.0f);
      front[axis] = side == 0 ? -1.0f : 1.0f;
      Vec3 corner = lo;
      corner[axis] = side == 0 ? lo[axis] : hi[axis];
      Vec3 e1(0.0f), e2(0.0f);
      e1[(axis + 1) % 3] = size[(axis + 1) % 3];
      e2[(axis + 2) % 3] = size[(axis + 2) % 3];
      if (glm::dot(glm::cross(e1, e2), front) < 0.0f) std::swap(e1, e2);
      b.AddQuad(corner, e1, e2, material);
    }
  }
}

constexpr float kBoxSide = 0.4f;

// A 4 x 4 floor, a back wall, a 0.6 m square light 2 m up facing down, and
// a 0.4 m box floating 0.6 m above the floor with its low corner at `boxLo`.
struct Room {
  Scene scene;
  std::unique_ptr<RayScene> rays;
  Bounds3 box;
};

Room BuildRoom(const Vec3& boxLo, float half) {
  SceneBuilder b;
  const uint32_t grey = b.AddMaterial(Lambert(0.6f));
  const uint32_t light = b.AddMaterial(Lambert(0.0f, 15.0f));
  const uint32_t white = b.AddMaterial(Lambert(0.8f));
  b.AddQuad(Vec3(-half, 0.0f, -half), Vec3(0.0f, 0.0f, 2.0f * half), Vec3(2.0f * half, 0.0f, 0.0f), grey);  // floor, +y
  b.AddQuad(Vec3(-half, 0.0f, -half), Vec3(2.0f * half, 0.0f, 0.0f), Vec3(0.0f, 2.5f, 0.0f), grey);  // back wall, +z
  b.AddQuad(Vec3(-0.3f, 2.0f, -0.3f), Vec3(0.6f, 0.0f, 0.0f), Vec3(0.0f, 0.0f, 0.6f), light); // light, -y
  AddBlock(b, boxLo, boxLo + Vec3(kBoxSide), white);
  Room room;
  room.scene.name = "motion invalidation room";
  const Status built = b.BuildInto(room.scene);
  EXPECT_TRUE(built.ok()) << (built.ok() ? "" : built.error().message);
  auto rays = RayScene::Build(room.scene);
  EXPECT_TRUE(rays.ok()) << (rays.ok() ? "" : rays.error().message);
  if (rays.ok()) room.rays = std::move(*rays);
  room.box.Extend(boxLo);
  room.box.Extend(boxLo + Vec3(kBoxSide));
  return room;
}

struct Point {
  Vec3 position;
  Vec3 normal;
};

// Floor and wall points on a 0.2 m grid, off the edges.
std::vector<Point> GridPoints(float half) {
  std::vector<Point> points;
  const float step = 0.1f * half;
  for (int i = 0; i < 19; ++i) {
    for (int j = 0; j < 19; ++j) {
      points.push_back({Vec3(step * float(i - 9), 0.0f, step * float(j - 9)), Vec3(0.0f, 1.0f, 0.0f)});
    }
  }
  for (int i = 0; i < 19; ++i) {
    for (int j = 0; j < 11; ++j) {
      points.push_back({Vec3(step * float(i - 9), 0.2f + 0.2f * float(j), -half), Vec3(0.0f, 0.0f, 1.0f)});
    }
  }
  return points;
}

struct Shaded {
  std::vector<float> irradiance;  // Luminance(E)
  std::vector<float> stdErr;
  float brightestRadiance = 0.0f;  // Luminance(L_out), over the points and the box's top
};

Shaded ShadeAll(const Room& room, const std::vector<Point>& points, uint64_t seedBase, int maxBounces) {
  ShadingSettings settings;
  settings.pathsPerSample = 1024;
  settings.maxBounces = maxBounces;
  const Shader shader(room.scene, *room.rays, settings);
  Shaded out;
  for (size_t i = 0; i < points.size(); ++i) {
    const ShadeOutput o =
        shader.Shade(testing::SampleAt(room.scene, points[i].position, points[i].normal, seedBase + i), 0, nullptr);
    out.irradiance.push_back(Luminance(o.irradiance));
    out.stdErr.push_back(o.irradianceStdErr);
    out.brightestRadiance = std::max(out.brightestRadiance, Luminance(o.radiance));
  }
  // The box's own top face, the brightest non-emissive surface here.
  const Vec3 top = room.box.Center() + Vec3(0.0f, 0.5f * kBoxSide, 0.0f);
  const ShadeOutput o = shader.Shade(testing::SampleAt(room.scene, top, Vec3(0.0f, 1.0f, 0.0f), seedBase + 999999), 0, nullptr);
  out.brightestRadiance = std::max(out.brightestRadiance, Luminance(o.radiance));
  return out;
}

struct Outcome {
  size_t points = 0;
  size_t changed = 0;      // beyond 4 sigma of the difference
  size_t invalidated = 0;
  size_t direct = 0;       // of which by direct light alone
  size_t changedNotDirect = 0;  // changed, but not invalidated by direct light alone
  size_t missed = 0;       // changed but kept: must be 0
  uint32_t boxes = 0;
};

// `half`: half the room's width. maxBounces 0: direct light only, and then
// no indirect bound either (indirectRadiance 0).
Outcome CheckMove(const Vec3& fromLo, const Vec3& toLo, float half, int maxBounces = 64,
                  sma::InvalidationParams params = {}) {
  const Room before = BuildRoom(fromLo, half);
  const Room after = BuildRoom(toLo, half);
  const std::vector<Point> points = GridPoints(half);
  const Shaded old = ShadeAll(before, points, 0, maxBounces);
  const Shaded now = ShadeAll(after, points, 1u << 20, maxBounces);  // independent streams: the sigmas add

  // What the SMA would do with only the old samples in its cache: L_max is
  // the brightest cached non-emissive radiance times a margin of 2.
  params.indirectRadiance = maxBounces == 0 ? 0.0f : 2.0f * old.brightestRadiance;
  const sma::MotionVolume volume = sma::MotionVolumes(before.box, after.box);
  const sma::MoveInvalidator invalidator(before.scene, volume, params);

  Outcome outcome;
  outcome.points = points.size();
  outcome.boxes = volume.count;
  for (size_t i = 0; i < points.size(); ++i) {
    const float difference = std::abs(now.irradiance[i] - old.irradiance[i]);
    const float sigma = std::sqrt(old.stdErr[i] * old.stdErr[i] + now.stdErr[i] * now.stdErr[i]);
    const sma::VertexSample sample{points[i].position, points[i].normal, old.irradiance[i], old.stdErr[i]};
    // A kept point may be off by its tolerance, and by noise: 4 sigma of the
    // difference of two independent estimates.
    const float tolerance = invalidator.Judge(sample).tolerance;
    const bool changed = difference > tolerance + 4.0f * sigma + 1e-5f * old.irradiance[i];
    const bool invalidated = invalidator.MayChange(sample);
    outcome.changed += changed;
    outcome.invalidated += invalidated;
    const bool direct = invalidated && invalidator.Judge(sample).DirectlyInvalidated();
    outcome.direct += direct;
    outcome.changedNotDirect += changed && !direct;
    if (changed && !invalidated) {
      ++outcome.missed;
      const sma::InvalidationVerdict v = invalidator.Judge(sample);
      ADD_FAILURE() << "kept a changed point at (" << points[i].position.x << ", " << points[i].position.y << ", "
                    << points[i].position.z << "): E " << old.irradiance[i] << " -> " << now.irradiance[i]
                    << " (sigma " << sigma << "), bound " << v.changeBound << ", tolerance " << v.tolerance;
    }
  }
  return outcome;
}

void Print(const char* what, const Outcome& o) {
  std::printf("%s: %zu points, %zu changed beyond 4 sigma, %zu invalidated (%zu by direct light); changed but not "
              "by direct light: %zu\n",
              what, o.points, o.changed, o.invalidated, o.direct, o.changedNotDirect);
}

// Direct light only (the renderer traces no bounce, the invalidator bounds
// no indirect light): the exact shaft tests alone must catch every change,
// and leave most of the room alone.
TEST(MotionInvalidationTest, DirectLightASmallMoveInvalidatesEveryPointItChangesAndFewOthers) {
  // 0.2 m sideways under the light: one union box.
  const Outcome o = CheckMove(Vec3(-0.2f, 0.6f, -0.2f), Vec3(0.0f, 0.6f, -0.2f), 2.0f, /*maxBounces=*/0);
  Print("direct, small move", o);
  EXPECT_EQ(o.boxes, 1u);
  EXPECT_EQ(o.missed, 0u);
  EXPECT_GT(o.changed, 5u) << "the move must change something measurable, or the check is empty";
  EXPECT_LT(o.invalidated, o.points / 4) << o.invalidated << " of " << o.points;
}

TEST(MotionInvalidationTest, DirectLightALargeMoveWithTwoBoxesInvalidatesEveryPointItChanges) {
  // 1.2 m sideways, from under the light to beside it: two boxes.
  const Outcome o = CheckMove(Vec3(-0.2f, 0.6f, -0.2f), Vec3(1.0f, 0.6f, 0.3f), 2.0f, 0);
  Print("direct, large move", o);
  EXPECT_EQ(o.boxes, 2u);
  EXPECT_EQ(o.missed, 0u);
  EXPECT_GT(o.changed, 5u);
  EXPECT_LT(o.invalidated, o.points / 4) << o.invalidated << " of " << o.points;
}

// Full light transport, as the SMA shades. The indirect bound (L_max twice
// the box's bright top) reaches every point of a small room -- a 0.4 m box
// 1-3 m away subtends more than a 1-2 % tolerance allows -- so there the
// check is that nothing changed is kept and that the direct-light class stays
// selective (docs/moving-objects.md).
TEST(MotionInvalidationTest, AllLightASmallMoveInvalidatesEveryPointItChanges) {
  const Outcome o = CheckMove(Vec3(-0.2f, 0.6f, -0.2f), Vec3(0.0f, 0.6f, -0.2f), 2.0f);
  Print("all light, small move", o);
  EXPECT_EQ(o.boxes, 1u);
  EXPECT_EQ(o.missed, 0u);
  EXPECT_GT(o.changed, 5u);
  EXPECT_LT(o.direct, o.points / 4) << o.direct << " of " << o.points;
}

TEST(MotionInvalidationTest, AllLightALargeMoveInvalidatesEveryPointItChanges) {
  const Outcome o = CheckMove(Vec3(-0.2f, 0.6f, -0.2f), Vec3(1.0f, 0.6f, 0.3f), 2.0f);
  Print("all light, large move", o);
  EXPECT_EQ(o.boxes, 2u);
  EXPECT_EQ(o.missed, 0u);
  EXPECT_GT(o.changed, 5u);
  EXPECT_LT(o.direct, o.points / 4) << o.direct << " of " << o.points;
}

}  // namespace
}  // namespace penumbra
