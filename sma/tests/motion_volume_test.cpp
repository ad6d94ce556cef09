// Motion volumes and move invalidation on analytic configurations: a floor,
// a square light above it and a box between them, with the expected verdict
// derived by hand for each vertex.

#include "penumbra/sma/motion_volume.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>

namespace penumbra::sma {
namespace {

Bounds3 Box(const Vec3& lo, const Vec3& hi) {
  Bounds3 b;
  b.Extend(lo);
  b.Extend(hi);
  return b;
}

const Vec3 kUp(0.0f, 1.0f, 0.0f);

// A 10 x 10 floor at y = 0 (front up), a 1 x 1 light at y = 4 facing down
// (luminance 10), optionally a sun straight up and a uniform sky.
Scene LitFloor(bool withLight = true, std::optional<SunLight> sun = {}, std::optional<SkyLight> sky = {}) {
  SceneBuilder b;
  Material floor;
  floor.albedo = Rgb(0.5f);
  const uint32_t floorMaterial = b.AddMaterial(floor);
  b.AddQuad(Vec3(-5.0f, 0.0f, -5.0f), Vec3(0.0f, 0.0f, 10.0f), Vec3(10.0f, 0.0f, 0.0f), floorMaterial);
  if (withLight) {
    Material light;
    light.albedo = Rgb(0.0f);
    light.emission = Rgb(10.0f);
    const uint32_t lightMaterial = b.AddMaterial(light);
    // cross(x, z) = -y: the light's front faces down, towards the floor.
    b.AddQuad(Vec3(-0.5f, 4.0f, -0.5f), Vec3(1.0f, 0.0f, 0.0f), Vec3(0.0f, 0.0f, 1.0f), lightMaterial);
  }
  Scene scene;
  scene.name = "lit floor";
  scene.sun = sun;
  scene.sky = sky;
  const Status built = b.BuildInto(scene);
  EXPECT_TRUE(built.ok()) << (built.ok() ? "" : built.error().message);
  return scene;
}

// The moving box: a 1 m cube floating 1.5 m above the floor's centre.
const Bounds3 kBoxUnderLight = Box(Vec3(-0.5f, 1.5f, -0.5f), Vec3(0.5f, 2.5f, 0.5f));

InvalidationParams TestParams() {
  InvalidationParams p;
  p.indirectRadiance = 0.2f;  // brighter than any lit surface here (albedo 0.5 under this light)
  return p;
}

VertexSample OnFloor(float x, float z, float irradiance = 1.0f, float stdErr = 0.05f) {
  return VertexSample{Vec3(x, 0.0f, z), kUp, irradiance, stdErr};
}

TEST(MotionVolumesTest, ASmallMoveIsOneUnionBox) {
  const Bounds3 before = kBoxUnderLight;
  const Bounds3 after = Box(before.min + Vec3(0.1f, 0.0f, 0.0f), before.max + Vec3(0.1f, 0.0f, 0.0f));
  const MotionVolume v = MotionVolumes(before, after);
  ASSERT_EQ(v.count, 1u);
  EXPECT_EQ(v.boxes[0].min, before.min);
  EXPECT_EQ(v.boxes[0].max, after.max);
}

TEST(MotionVolumesTest, ALargeMoveIsTwoSeparateBoxes) {
  const Bounds3 before = kBoxUnderLight;
  const Bounds3 after = Box(before.min + Vec3(3.0f, 0.0f, 0.0f), before.max + Vec3(3.0f, 0.0f, 0.0f));
  const MotionVolume v = MotionVolumes(before, after);
  ASSERT_EQ(v.count, 2u);
  EXPECT_EQ(v.boxes[0].min, before.min);
  EXPECT_EQ(v.boxes[1].max, after.max);
  // The boundary of the rule: a diagonal move whose union is just above the
  // two volumes together splits; one just below stays whole.
  const auto diagonal = [&](float d) {
    return MotionVolumes(before, Box(before.min + Vec3(d, 0.0f, d), before.max + Vec3(d, 0.0f, d))).count;
  };
  EXPECT_EQ(diagonal(0.40f), 1u);  // (1.40)^2 = 1.96 <= 2
  EXPECT_EQ(diagonal(0.43f), 2u);  // (1.43)^2 = 2.04 > 2
}

TEST(MotionVolumesTest, AFlatObjectHasAVolumeAndAnEmptyBoxIsIgnored) {
  // A 1 m square of no thickness moved 5 cm sideways: one box, not split
  // because its volume is zero.
  const Bounds3 plate = Box(Vec3(0.0f), Vec3(1.0f, 0.0f, 1.0f));
  const Bounds3 moved = Box(Vec3(0.05f, 0.0f, 0.0f), Vec3(1.05f, 0.0f, 1.0f));
  EXPECT_EQ(MotionVolumes(plate, moved).count, 1u);
  const MotionVolume one = MotionVolumes(Bounds3{}, plate);
  ASSERT_EQ(one.count, 1u);
  EXPECT_EQ(one.boxes[0].max, plate.max);
  EXPECT_EQ(MotionVolumes(Bounds3{}, Bounds3{}).count, 0u);
}

TEST(MoveInvalidatorTest, AVertexInTheShaftUnderTheBoxIsInvalidated) {
  const Scene scene = LitFloor();
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), TestParams());
  EXPECT_EQ(inv.RelevantLightCount(), 2u);  // both triangles of the light face the box
  const InvalidationVerdict v = inv.Judge(OnFloor(0.0f, 0.0f));
  EXPECT_TRUE(v.facing);
  EXPECT_TRUE(v.inLightShaft);
  EXPECT_TRUE(v.invalidate);
  // Directly under the box, the light's whole solid angle (about 1/16 sr) is
  // behind it: the bound holds the light's full 10 * omega.
  EXPECT_GT(v.changeBound, 10.0f * 0.06f);
}

TEST(MoveInvalidatorTest, AVertexBesideTheShaftWithATinySolidAngleIsKept) {
  const Scene scene = LitFloor();
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), TestParams());
  // From (4.5, 0, 4.5) the shaft to the light passes 2 m above the floor at
  // x, z ~ 2.25 +- 0.25, far from the box; the box's bounding sphere (radius
  // 0.87 m at 6.7 m, seen 73 degrees from the normal) subtends a projected
  // solid angle of about 0.02 sr: 0.2 * 0.02 = 0.004 < tau = 0.05.
  const InvalidationVerdict v = inv.Judge(OnFloor(4.5f, 4.5f));
  EXPECT_TRUE(v.facing);
  EXPECT_FALSE(v.inLightShaft);
  EXPECT_FALSE(v.inSunCone);
  EXPECT_LT(v.changeBound, 0.01f);
  EXPECT_GT(v.changeBound, 0.0f);
  EXPECT_FALSE(v.invalidate);
  EXPECT_FALSE(inv.MayChange(OnFloor(4.5f, 4.5f)));
}

TEST(MoveInvalidatorTest, TheShaftTestIsExactNotABoundingBoxTest) {
  // A slanted shaft whose bounding box contains the box but which passes
  // beside it: from (3, 0, -3) to the light (x, z in [-0.5, 0.5] at y = 4)
  // the shaft's bounding box is x in [-0.5, 3], z in [-3, 0.5]; at the box's
  // heights (y in [1.5, 2.5]) the shaft's cross-section lies at z < -0.8,
  // and the box at z in [-0.4, 0].
  const Scene scene = LitFloor();
  const Bounds3 box = Box(Vec3(2.0f, 1.5f, -0.4f), Vec3(2.4f, 2.5f, 0.0f));
  InvalidationParams params = TestParams();
  params.indirectRadiance = 0.0f;
  const MoveInvalidator inv(scene, MotionVolumes(box, box), params);
  const InvalidationVerdict beside = inv.Judge(OnFloor(3.0f, -3.0f));
  EXPECT_TRUE(beside.facing);
  EXPECT_FALSE(beside.inLightShaft);
  EXPECT_FALSE(beside.invalidate);
  // ... while from (4.4, 0, -0.4) the line through the box's centre
  // (2.2, 2, -0.2) reaches the light's centre.
  EXPECT_TRUE(inv.Judge(OnFloor(4.4f, -0.4f)).inLightShaft);
}

TEST(MoveInvalidatorTest, AVertexFacingAwayIsKept) {
  const Scene scene = LitFloor();
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), TestParams());
  // Under the box but shading the floor's underside.
  const InvalidationVerdict under = inv.Judge(VertexSample{Vec3(0.0f), -kUp, 0.0f, 0.0f});
  EXPECT_FALSE(under.facing);
  EXPECT_FALSE(under.invalidate);
  // A wall at x = 2 facing +x, away from the box.
  const InvalidationVerdict wall = inv.Judge(VertexSample{Vec3(2.0f, 2.0f, 0.0f), Vec3(1.0f, 0.0f, 0.0f), 0.0f, 0.0f});
  EXPECT_FALSE(wall.facing);
  EXPECT_FALSE(wall.invalidate);
  // The same wall facing -x, towards the box, is in its reach.
  EXPECT_TRUE(inv.Judge(VertexSample{Vec3(2.0f, 2.0f, 0.0f), Vec3(-1.0f, 0.0f, 0.0f), 0.0f, 0.0f}).facing);
}

TEST(MoveInvalidatorTest, TwoBoxesForALargeMoveKeepWhatTheirUnionWouldInvalidate) {
  const Scene scene = LitFloor();
  // The box moves 4 m along x, from under x = -2 to x = +2; the light is at
  // x = 0. The floor point at (0, 0, 0) sees the light straight up, past
  // both boxes; the union box (x in [-2.5, 2.5]) would block that shaft.
  const Bounds3 before = Box(Vec3(-2.5f, 1.5f, -0.5f), Vec3(-1.5f, 2.5f, 0.5f));
  const Bounds3 after = Box(Vec3(1.5f, 1.5f, -0.5f), Vec3(2.5f, 2.5f, 0.5f));
  const MotionVolume split = MotionVolumes(before, after);
  ASSERT_EQ(split.count, 2u);
  MotionVolume merged;
  merged.boxes[0] = Box(before.min, after.max);
  merged.count = 1;
  InvalidationParams params = TestParams();
  params.indirectRadiance = 0.05f;
  const MoveInvalidator twoBoxes(scene, split, params);
  const MoveInvalidator oneBox(scene, merged, params);
  const VertexSample centre = OnFloor(0.0f, 0.0f, 2.0f, 0.1f);
  EXPECT_TRUE(oneBox.Judge(centre).inLightShaft);
  EXPECT_FALSE(twoBoxes.Judge(centre).inLightShaft);
  EXPECT_FALSE(twoBoxes.MayChange(centre));
  // Under either box's new or old place, the shadow changes.
  EXPECT_TRUE(twoBoxes.MayChange(OnFloor(2.6f, 0.0f)));
  EXPECT_TRUE(twoBoxes.MayChange(OnFloor(-2.6f, 0.0f)));
}

TEST(MoveInvalidatorTest, TheSunsConeThroughTheBox) {
  SunLight sun;
  sun.directionToSun = kUp;
  sun.radiance = Rgb(1.0e5f);  // irradiance about 6.8 at normal incidence
  const Scene scene = LitFloor(/*withLight=*/false, sun);
  InvalidationParams params = TestParams();
  params.indirectRadiance = 0.01f;
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), params);
  // Under the box's edge (its shadow is sharp at 1.5 - 2.5 m under a
  // half-degree sun): in the cone; the bound is the sun's whole irradiance.
  const InvalidationVerdict under = inv.Judge(OnFloor(0.49f, 0.0f, 6.8f, 0.0f));
  EXPECT_TRUE(under.inSunCone);
  EXPECT_TRUE(under.invalidate);
  EXPECT_NEAR(under.changeBound, 1.0e5f * sun.SolidAngle(), 0.05f);  // + at most 0.01 pi of indirect
  // 3 cm outside the shadow: the cone (radius 2.5 m * 0.0047 = 1.2 cm) misses.
  const InvalidationVerdict beside = inv.Judge(OnFloor(0.53f, 0.0f, 6.8f, 0.0f));
  EXPECT_FALSE(beside.inSunCone);
  EXPECT_FALSE(beside.invalidate);  // 1 % of 6.8 = 0.068 > 0.01 * pi
  // A sun below the horizon of a surface lights nothing there to block.
  SunLight low = sun;
  low.directionToSun = glm::normalize(Vec3(1.0f, -0.2f, 0.0f));
  const Scene dusk = LitFloor(false, low);
  const MoveInvalidator duskInv(dusk, MotionVolumes(kBoxUnderLight, kBoxUnderLight), params);
  EXPECT_FALSE(duskInv.Judge(OnFloor(-3.0f, 0.0f, 6.8f, 0.0f)).inSunCone);
}

TEST(MoveInvalidatorTest, TheSkyThroughTheBox) {
  SkyLight sky;
  sky.zenith = sky.horizon = sky.ground = Rgb(1.0f);  // E = pi on an open floor
  const Scene scene = LitFloor(false, {}, sky);
  InvalidationParams params = TestParams();
  params.indirectRadiance = 0.0f;
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), params);
  // Under the box: it hides the sky behind its bottom face, a 1 m square
  // 1.5 m up (projected solid angle 0.387 = pi times its form factor): far
  // above tau.
  const InvalidationVerdict under = inv.Judge(OnFloor(0.0f, 0.0f, kPi, 0.01f));
  EXPECT_TRUE(under.invalidate);
  EXPECT_NEAR(under.changeBound, 0.387f, 0.01f);
  // Far away the box is a speck of sky: kept.
  EXPECT_FALSE(inv.MayChange(OnFloor(4.9f, 4.9f, kPi, 0.01f)));
  // Facing away from it: nothing of the sky through the box reaches it.
  EXPECT_FALSE(inv.MayChange(VertexSample{Vec3(0.0f), -kUp, kPi, 0.01f}));
}

TEST(MoveInvalidatorTest, ObjectsMovedTogetherAreJudgedTogether) {
  // Two boxes moved in one epoch, either side of a floor point under a
  // uniform sky: each alone changes it by less than the tolerance, both
  // together by more.
  SkyLight sky;
  sky.zenith = sky.horizon = sky.ground = Rgb(1.0f);
  const Scene scene = LitFloor(false, {}, sky);
  InvalidationParams params = TestParams();
  params.indirectRadiance = 0.0f;
  const Bounds3 left = Box(Vec3(-2.5f, 1.5f, -0.5f), Vec3(-1.5f, 2.5f, 0.5f));
  const Bounds3 right = Box(Vec3(1.5f, 1.5f, -0.5f), Vec3(2.5f, 2.5f, 0.5f));
  const VertexSample centre = OnFloor(0.0f, 0.0f, kPi, 0.0f);
  const float leftBound = MoveInvalidator(scene, MotionVolumes(left, left), params).Judge(centre).changeBound;
  const float rightBound = MoveInvalidator(scene, MotionVolumes(right, right), params).Judge(centre).changeBound;
  ASSERT_GT(leftBound, 0.0f);
  params.relativeFloor = 0.0f;
  params.absoluteFloor = 0.75f * (leftBound + rightBound);  // above each, below their sum
  ASSERT_GT(params.absoluteFloor, std::max(leftBound, rightBound));
  const std::array<MotionVolume, 2> both{MotionVolumes(left, left), MotionVolumes(right, right)};
  const MoveInvalidator together(scene, both, params);
  EXPECT_EQ(together.BoxCount(), 2u);
  EXPECT_TRUE(together.MayChange(centre));
  EXPECT_NEAR(together.Judge(centre).changeBound, leftBound + rightBound, 1e-4f);
  EXPECT_FALSE(MoveInvalidator(scene, MotionVolumes(left, left), params).MayChange(centre));
  EXPECT_FALSE(MoveInvalidator(scene, MotionVolumes(right, right), params).MayChange(centre));

  // Many objects: more than kMaxBoxes boxes become their union.
  std::vector<MotionVolume> many;
  for (int i = 0; i < 9; ++i) {
    const Vec3 at(float(i) - 4.0f, 1.0f, 0.0f);
    many.push_back(MotionVolumes(Box(at, at + Vec3(0.2f)), Box(at + Vec3(0.0f, 0.0f, 3.0f), at + Vec3(0.2f, 0.2f, 3.2f))));
  }
  const MoveInvalidator merged(scene, many, params);
  EXPECT_EQ(merged.BoxCount(), 1u);
  EXPECT_TRUE(merged.Judge(OnFloor(0.1f, 1.5f, kPi, 0.0f)).facing);
}

TEST(MoveInvalidatorTest, ASampleWithNonFiniteValuesIsInvalidated) {
  const Scene scene = LitFloor();
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), TestParams());
  const float nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_TRUE(inv.MayChange(VertexSample{Vec3(nan, 0.0f, 0.0f), kUp, 1.0f, 0.1f}));
  EXPECT_TRUE(inv.MayChange(VertexSample{Vec3(4.5f, 0.0f, 4.5f), kUp, nan, 0.1f}));
  EXPECT_TRUE(inv.MayChange(VertexSample{Vec3(4.5f, 0.0f, 4.5f), kUp, 1.0f, std::numeric_limits<float>::infinity()}));
  EXPECT_FALSE(inv.MayChange(VertexSample{Vec3(4.5f, 0.0f, 4.5f), kUp, 1.0f, 0.05f}));
}

TEST(MoveInvalidatorTest, ATighterToleranceNeverInvalidatesFewer) {
  SunLight sun;
  sun.directionToSun = glm::normalize(Vec3(0.3f, 1.0f, 0.2f));
  sun.radiance = Rgb(2.0e4f);
  SkyLight sky;
  sky.zenith = Rgb(0.3f);
  sky.horizon = Rgb(0.6f);
  const Scene scene = LitFloor(true, sun, sky);
  const Bounds3 before = kBoxUnderLight;
  const Bounds3 after = Box(before.min + Vec3(0.7f, 0.0f, 0.3f), before.max + Vec3(0.7f, 0.0f, 0.3f));
  std::mt19937 rng(14);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<VertexSample> samples;
  for (int i = 0; i < 4000; ++i) {
    Vec3 n = glm::normalize(Vec3(u(rng) - 0.5f, u(rng) - 0.5f, u(rng) - 0.5f));
    samples.push_back(VertexSample{Vec3(10.0f * u(rng) - 5.0f, 4.0f * u(rng), 10.0f * u(rng) - 5.0f), n,
                                   3.0f * u(rng), 0.1f * u(rng)});
  }
  InvalidationParams loose = TestParams();
  loose.noiseZ = 3.0f;
  loose.relativeFloor = 0.05f;
  loose.absoluteFloor = 0.01f;
  size_t looseCount = 0, tightCount = 0;
  for (int step = 0; step < 4; ++step) {
    InvalidationParams tight = loose;
    tight.noiseZ *= 0.5f;
    tight.relativeFloor *= 0.5f;
    tight.absoluteFloor *= 0.5f;
    const MoveInvalidator looseInv(scene, MotionVolumes(before, after), loose);
    const MoveInvalidator tightInv(scene, MotionVolumes(before, after), tight);
    looseCount = tightCount = 0;
    for (const VertexSample& s : samples) {
      const bool l = looseInv.MayChange(s), t = tightInv.MayChange(s);
      EXPECT_TRUE(!l || t) << "kept by the tighter tolerance but not the looser one";
      looseCount += l;
      tightCount += t;
    }
    EXPECT_LE(looseCount, tightCount);
    loose = tight;
  }
  // The samples are spread enough that the decision really varies.
  EXPECT_GT(tightCount, 0u);
  EXPECT_LT(tightCount, samples.size());
}

TEST(MoveInvalidatorTest, TheEarlyDecisionMatchesTheCompleteOne) {
  SunLight sun;
  sun.directionToSun = glm::normalize(Vec3(-0.2f, 1.0f, 0.1f));
  sun.radiance = Rgb(2.0e4f);
  const Scene scene = LitFloor(true, sun);
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), TestParams());
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int i = 0; i < 4000; ++i) {
    const VertexSample s{Vec3(10.0f * u(rng) - 5.0f, 0.0f, 10.0f * u(rng) - 5.0f), kUp, 2.0f * u(rng), 0.05f * u(rng)};
    const InvalidationVerdict complete = inv.Judge(s, true);
    EXPECT_EQ(inv.MayChange(s), complete.invalidate) << "at " << s.position.x << ", " << s.position.z;
    EXPECT_EQ(complete.invalidate, complete.changeBound > complete.tolerance);
  }
}

TEST(MoveInvalidatorTest, AnyPointOfTheShaftInsideTheBoxPutsTheVertexInTheShaft) {
  // Conservativeness of the separating-axis test: random boxes and floor
  // points; whenever a random point of the hull of the vertex and a light
  // triangle falls inside the box, the verdict must say "in the shaft".
  const Scene scene = LitFloor();
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  InvalidationParams params = TestParams();
  params.padding = 0.0f;
  int hits = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const Vec3 lo(4.0f * u(rng) - 2.0f, 0.5f + 2.5f * u(rng), 4.0f * u(rng) - 2.0f);
    const Vec3 size(0.05f + 0.6f * u(rng), 0.05f + 0.6f * u(rng), 0.05f + 0.6f * u(rng));
    const Bounds3 box = Box(lo, lo + size);
    const MoveInvalidator inv(scene, MotionVolumes(box, box), params);
    const Vec3 p(8.0f * u(rng) - 4.0f, 0.0f, 8.0f * u(rng) - 4.0f);
    const InvalidationVerdict v = inv.Judge(OnFloor(p.x, p.z));
    for (int k = 0; k < 2000; ++k) {
      // A uniform-ish point of hull(p, light): the light is the square
      // [-0.5, 0.5]^2 at y = 4 (both triangles together).
      const Vec3 onLight(u(rng) - 0.5f, 4.0f, u(rng) - 0.5f);
      const Vec3 q = glm::mix(p, onLight, std::cbrt(u(rng)));
      if (glm::all(glm::greaterThanEqual(q, box.min)) && glm::all(glm::lessThanEqual(q, box.max))) {
        ++hits;
        EXPECT_TRUE(v.inLightShaft) << "trial " << trial;
        break;
      }
    }
  }
  EXPECT_GT(hits, 10);  // the trials really exercise the test
}

bool RayHitsBox(const Vec3& o, const Vec3& d, const Bounds3& b) {
  float t0 = 0.0f, t1 = 1e30f;
  for (int a = 0; a < 3; ++a) {
    if (std::abs(d[a]) < 1e-12f) {
      if (o[a] < b.min[a] || o[a] > b.max[a]) return false;
      continue;
    }
    float ta = (b.min[a] - o[a]) / d[a], tb = (b.max[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  return t0 <= t1;
}

// The box's projected solid angle from p (normal frame.n) estimated by
// `count` cosine-weighted directions: pi times the fraction that hit it,
// and the estimate's standard error.
struct ProjectedEstimate {
  float value = 0.0f;
  float sigma = 0.0f;
};
ProjectedEstimate EstimateProjectedSolidAngle(const Vec3& p, const Frame& frame, const Bounds3& box, int count,
                                              std::mt19937& rng) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  int hit = 0;
  for (int k = 0; k < count; ++k) {
    const float r = std::sqrt(u(rng)), phi = 2.0f * kPi * u(rng);
    const Vec3 d = frame.ToWorld(Vec3(r * std::cos(phi), r * std::sin(phi), std::sqrt(std::max(0.0f, 1.0f - r * r))));
    hit += RayHitsBox(p, d, box);
  }
  const float fraction = float(hit) / float(count);
  return {kPi * fraction, kPi * std::sqrt(fraction * (1.0f - fraction) / float(count))};
}

TEST(MoveInvalidatorTest, AnyDirectionOfTheSunsConeThroughTheBoxPutsTheVertexInTheCone) {
  // Conservativeness of the cone test, with a large sun (10 degrees) so that
  // the cone's width matters: directions drawn in the cone, and whenever one
  // hits the box, the verdict must say "in the cone".
  SunLight sun;
  sun.directionToSun = glm::normalize(Vec3(0.3f, 1.0f, -0.2f));
  sun.radiance = Rgb(100.0f);
  sun.angularDiameterRad = 20.0f * kPi / 180.0f;
  const Scene scene = LitFloor(false, sun);
  const Frame frame = Frame::FromNormal(sun.directionToSun);
  const float cosMax = sun.CosHalfAngle();
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  InvalidationParams params = TestParams();
  params.padding = 0.0f;
  int hits = 0, inCone = 0;
  for (int trial = 0; trial < 400; ++trial) {
    const Vec3 lo(4.0f * u(rng) - 2.0f, 0.5f + 2.5f * u(rng), 4.0f * u(rng) - 2.0f);
    const Bounds3 box = Box(lo, lo + Vec3(0.05f + 0.5f * u(rng), 0.05f + 0.5f * u(rng), 0.05f + 0.5f * u(rng)));
    const MoveInvalidator inv(scene, MotionVolumes(box, box), params);
    // A floor point whose line to the sun passes near the box: where the
    // box's shadow and penumbra fall, give or take 0.8 m.
    const Vec3 c = box.Center();
    const Vec3 shadow = c - sun.directionToSun * (c.y / sun.directionToSun.y);
    const Vec3 p(shadow.x + 1.6f * u(rng) - 0.8f, 0.0f, shadow.z + 1.6f * u(rng) - 0.8f);
    const InvalidationVerdict v = inv.Judge(OnFloor(p.x, p.z));
    inCone += v.inSunCone;
    for (int k = 0; k < 500; ++k) {
      const float cosTheta = 1.0f - u(rng) * (1.0f - cosMax);
      const float sinTheta = std::sqrt(1.0f - cosTheta * cosTheta), phi = 2.0f * kPi * u(rng);
      const Vec3 d = frame.ToWorld(Vec3(sinTheta * std::cos(phi), sinTheta * std::sin(phi), cosTheta));
      if (RayHitsBox(p, d, box)) {
        ++hits;
        EXPECT_TRUE(v.inSunCone) << "trial " << trial;
        break;
      }
    }
  }
  EXPECT_GT(hits, 50);
  EXPECT_LT(inCone, 400);  // and the test is not "always in the cone"
  // The test grows the box by the cone's widest radius, so it is loose by a
  // little for a sun this large (by ~1 cm for the real one), not by much.
  EXPECT_LT(inCone, 2 * hits) << "far more in the cone than directions hitting the box";
}

TEST(MoveInvalidatorTest, TheSolidAngleBoundIsAboveTheBoxsProjectedSolidAngle) {
  // The indirect bound is indirectRadiance times a projected solid angle;
  // estimate the box's true projected solid angle by cosine-weighted
  // directions (pi times the fraction that hit it) and compare.
  const Scene scene = LitFloor(false);
  std::mt19937 rng(9);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  InvalidationParams params = TestParams();
  params.indirectRadiance = 1.0f;
  params.padding = 0.0f;
  const Frame frame = Frame::FromNormal(kUp);
  for (int trial = 0; trial < 100; ++trial) {
    const Vec3 lo(6.0f * u(rng) - 3.0f, 0.2f + 2.0f * u(rng), 6.0f * u(rng) - 3.0f);
    const Bounds3 box = Box(lo, lo + Vec3(0.1f + 1.5f * u(rng), 0.05f + 1.0f * u(rng), 0.1f + 1.5f * u(rng)));
    const MoveInvalidator inv(scene, MotionVolumes(box, box), params);
    const Vec3 p(6.0f * u(rng) - 3.0f, 0.0f, 6.0f * u(rng) - 3.0f);
    const ProjectedEstimate projected = EstimateProjectedSolidAngle(p, frame, box, 20000, rng);
    const InvalidationVerdict v = inv.Judge(OnFloor(p.x, p.z, 1.0f, 0.0f));
    EXPECT_GE(v.changeBound + 4.0f * projected.sigma + 1e-4f, projected.value) << "trial " << trial;
  }
}

TEST(BoxProjectedSolidAngleTest, AFaceOnSquareMatchesTheClosedForm) {
  // A flat box (a 2a x 2a square) centred h above p, parallel to p's
  // surface: four corner rectangles a x a, each with the form factor
  // F = 1/(2 pi) [X/sqrt(1+X^2) atan(X/sqrt(1+X^2)) * 2] for X = a / h, and
  // the projected solid angle is pi times their sum.
  for (const float a : {0.1f, 0.5f, 1.0f, 3.0f}) {
    const float h = 1.0f;
    const float x = a / h;
    const float s = x / std::sqrt(1.0f + x * x);
    const float formFactor = 4.0f * (2.0f * s * std::atan(s)) / (2.0f * kPi);
    const float got = BoxProjectedSolidAngle(Vec3(0.0f), kUp, Vec3(0.0f, h, 0.0f), Vec3(a, 0.0f, a));
    EXPECT_NEAR(got, kPi * formFactor, 1e-5f * kPi) << "a = " << a;
  }
  // The whole sky of a point just under a huge square: pi. Inside the box: pi.
  EXPECT_NEAR(BoxProjectedSolidAngle(Vec3(0.0f), kUp, Vec3(0.0f, 0.01f, 0.0f), Vec3(1e3f, 0.0f, 1e3f)), kPi, 1e-3f);
  EXPECT_EQ(BoxProjectedSolidAngle(Vec3(0.0f), kUp, Vec3(0.0f), Vec3(1.0f)), kPi);
  // Wholly below the tangent plane: nothing; half below: half of the
  // symmetric whole, seen edge-on from a normal along x.
  EXPECT_EQ(BoxProjectedSolidAngle(Vec3(0.0f), kUp, Vec3(0.0f, -3.0f, 0.0f), Vec3(1.0f)), 0.0f);
  const float whole = BoxProjectedSolidAngle(Vec3(0.0f), Vec3(1.0f, 0.0f, 0.0f), Vec3(3.0f, 0.0f, 0.0f), Vec3(1.0f));
  const float half = BoxProjectedSolidAngle(Vec3(0.0f), kUp, Vec3(3.0f, 0.0f, 0.0f), Vec3(1.0f));
  EXPECT_GT(whole, 0.0f);
  EXPECT_GT(half, 0.0f);
  EXPECT_LT(half, whole);
}

TEST(BoxProjectedSolidAngleTest, EqualsTheCosineWeightedFractionOfDirectionsThatHitTheBox) {
  // Random boxes and tilted normals, including boxes that straddle the
  // tangent plane: the exact value within 4 sigma of a cosine-weighted
  // estimate, both ways (it is the true value, not only a bound).
  std::mt19937 rng(21);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (int trial = 0; trial < 60; ++trial) {
    const Vec3 lo(6.0f * u(rng) - 3.0f, 4.0f * u(rng) - 1.5f, 6.0f * u(rng) - 3.0f);
    const Bounds3 box = Box(lo, lo + Vec3(0.1f + 1.5f * u(rng), 0.05f + 1.0f * u(rng), 0.1f + 1.5f * u(rng)));
    const Vec3 p(6.0f * u(rng) - 3.0f, 0.0f, 6.0f * u(rng) - 3.0f);
    if (glm::all(glm::greaterThanEqual(p, box.min)) && glm::all(glm::lessThanEqual(p, box.max))) continue;
    const Vec3 n = glm::normalize(Vec3(u(rng) - 0.5f, 1.0f, u(rng) - 0.5f));
    const ProjectedEstimate estimate = EstimateProjectedSolidAngle(p, Frame::FromNormal(n), box, 40000, rng);
    const float exact = BoxProjectedSolidAngle(p, n, box.Center(), 0.5f * box.Diagonal());
    EXPECT_NEAR(exact, estimate.value, 4.0f * estimate.sigma + 1e-4f) << "trial " << trial;
  }
}

TEST(MoveInvalidatorTest, TheBulkHelperAgreesWithTheSingleTest) {
  const Scene scene = LitFloor();
  InvalidationParams params = TestParams();
  params.indirectRadiance = 0.5f;  // reaches beyond the light's shaft
  const MoveInvalidator inv(scene, MotionVolumes(kBoxUnderLight, kBoxUnderLight), params);
  std::vector<Vec3> positions, normals;
  std::vector<float> irradiance, stdErr;
  for (int i = 0; i <= 100; ++i) {
    for (int j = 0; j <= 100; ++j) {
      positions.emplace_back(0.1f * float(i) - 5.0f, 0.0f, 0.1f * float(j) - 5.0f);
      normals.push_back((i + j) % 7 == 0 ? -kUp : kUp);
      irradiance.push_back(1.0f);
      stdErr.push_back(0.05f);
    }
  }
  const auto bulk = inv.InvalidatedVertices({positions, normals, irradiance, stdErr});
  ASSERT_TRUE(bulk.ok());
  std::vector<uint32_t> one;
  for (uint32_t i = 0; i < positions.size(); ++i) {
    if (inv.MayChange(VertexSample{positions[i], normals[i], irradiance[i], stdErr[i]})) one.push_back(i);
  }
  EXPECT_EQ(*bulk, one);
  // Split by why: together the same set; the shaft under the box is direct.
  const auto classified = inv.ClassifyInvalidated({positions, normals, irradiance, stdErr});
  ASSERT_TRUE(classified.ok());
  std::vector<uint32_t> merged = classified->direct;
  merged.insert(merged.end(), classified->indirectOnly.begin(), classified->indirectOnly.end());
  std::sort(merged.begin(), merged.end());
  EXPECT_EQ(merged, one);
  const uint32_t centre = 50 * 101 + 50;  // (0, 0, 0), facing up
  EXPECT_TRUE(std::binary_search(classified->direct.begin(), classified->direct.end(), centre));
  EXPECT_GT(classified->indirectOnly.size(), 0u);
  EXPECT_GT(one.size(), 0u);
  EXPECT_LT(one.size(), positions.size() / 2);

  const auto mismatched = inv.InvalidatedVertices({positions, normals, irradiance, std::span<const float>(stdErr).first(3)});
  ASSERT_FALSE(mismatched.ok());
  EXPECT_NE(mismatched.error().message.find("unequal"), std::string::npos);
}

}  // namespace
}  // namespace penumbra::sma
