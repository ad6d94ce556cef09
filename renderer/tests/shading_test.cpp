// Analytic checks of the path tracer. Each Monte Carlo result is compared to
// its closed form within 5 standard errors measured from independent sample
// ids (test_scenes.h), and is required to be precise enough for that
// comparison to mean something.

#include "penumbra/renderer/shading.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "penumbra/renderer/ray_scene.h"
#include "test_scenes.h"

namespace penumbra {
namespace {

using testing::AddBox;
using testing::AddHorizontalSquare;
using testing::Agrees;
using testing::ParallelRectangleIrradiance;
using testing::EstimateOutput;
using testing::Finish;
using testing::MakeMaterial;
using testing::SampleAt;
using testing::DirectOnly;
using testing::kUp;
using testing::TestScene;


// --- White furnace ------------------------------------------------------------

struct FurnaceCase {
  int maxBounces;  // < 0: the defaults of ShadingSettings, as the renderer ships
  int russianRouletteDepth;
};

class WhiteFurnaceTest : public ::testing::TestWithParam<FurnaceCase> {};

// Inside a closed box whose walls all emit Le and reflect albedo rho, the
// radiance everywhere is Le (1 + rho + ... + rho^D) for paths of D segments
// (D - 1 bounces), Le / (1 - rho) in the limit -- which the default settings
// must reach: a default that truncates paths makes every interior too dark. The corner and edge samples would read low if
// rays leaked out of the box between its walls.
TEST_P(WhiteFurnaceTest, EveryPointReadsTheGeometricSeries) {
  const Rgb emission(1.0f, 0.5f, 2.0f);
  const Rgb albedo(0.3f, 0.5f, 0.7f);
  SceneBuilder b;
  AddBox(b, Vec3(0.0f), Vec3(1.0f, 0.7f, 1.3f), b.AddMaterial(MakeMaterial(albedo, emission)), true);
  const TestScene t = Finish(b);

  ShadingSettings settings;
  Rgb exact = emission / (Rgb(1.0f) - albedo);
  if (GetParam().maxBounces >= 0) {
    settings.maxBounces = GetParam().maxBounces;
    settings.russianRouletteDepth = GetParam().russianRouletteDepth;
    Rgb series(0.0f), power(1.0f);
    for (int k = 0; k <= settings.MaxSegments(); ++k, power *= albedo) series += power;
    exact = emission * series;
  }
  const Shader shader(t.scene, *t.rays, settings);

  const struct {
    Vec3 position, normal;
  } samples[] = {
      {Vec3(0.0f, 0.0f, 0.0f), kUp},                 // floor corner
      {Vec3(0.5f, 0.7f, 1.3f), Vec3(0.0f, 0.0f, -1.0f)},  // edge midpoint, back wall
      {Vec3(0.0f, 0.2f, 1.0f), Vec3(1.0f, 0.0f, 0.0f)},   // inside the -x wall
  };
  for (const auto& s : samples) {
    const auto e = EstimateOutput(shader, SampleAt(t.scene, s.position, s.normal), 32, 64, &ShadeOutput::radiance);
    EXPECT_TRUE(Agrees(e, exact, 0.01f)) << "at (" << s.position.x << ", " << s.position.y << ", " << s.position.z << ")";
  }
}

INSTANTIATE_TEST_SUITE_P(Depths, WhiteFurnaceTest,
                         ::testing::Values(FurnaceCase{-1, 0},     // the shipped defaults: the limit
                                           FurnaceCase{63, 3},     // converged, with Russian roulette
                                           FurnaceCase{0, 64},     // direct light only
                                           FurnaceCase{2, 64}),    // truncated, no roulette
                         [](const ::testing::TestParamInfo<FurnaceCase>& param) {
                           if (param.param.maxBounces < 0) return std::string("Defaults");
                           return "MaxBounces" + std::to_string(param.param.maxBounces) + "Roulette" +
                                  std::to_string(param.param.russianRouletteDepth);
                         });

// --- Sky ------------------------------------------------------------------------

TestScene PlaneUnderSky(const SkyLight& sky) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  AddHorizontalSquare(b, Vec3(0.0f), 10.0f, m, true);
  Scene scene;
  scene.sky = sky;
  return Finish(b, std::move(scene));
}

SkyLight UniformSky(Rgb radiance) {
  SkyLight sky;
  sky.zenith = sky.horizon = sky.ground = radiance;
  return sky;
}

// --- Buried samples -----------------------------------------------------------------

// A stair riser (z = 0, facing +z) whose top edge runs into a tread slab with
// a 5 cm nosing, on a floor, under a uniform sky. The riser's top corners lie
// inside the slab: shaded there they would see only its inside and read
// black. They are shaded where the riser emerges below the slab instead; a
// corner merely in a crease (riser meets floor) is shaded where it is.
TEST(ShadingTest, ABuriedSampleIsShadedWhereItsSurfaceEmerges) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  b.AddQuad(Vec3(-0.5f, 0.0f, 0.0f), Vec3(1.0f, 0.0f, 0.0f), Vec3(0.0f, 0.3f, 0.0f), m);  // riser, +z
  AddHorizontalSquare(b, Vec3(0.0f, 0.0f, 1.0f), 2.0f, m, true);                          // floor, +y
  AddBox(b, Vec3(-1.0f, 0.28f, -0.5f), Vec3(1.0f, 0.32f, 0.05f), m, false);              // the slab, a solid
  Scene scene;
  scene.sky = UniformSky(Rgb(1.0f));
  const TestScene t = Finish(b, std::move(scene));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  const Vec3 kFront(0.0f, 0.0f, 1.0f);

  ShadeCounters buried;
  const ShadeOutput top = shader.Shade(SampleAt(t.scene, Vec3(-0.5f, 0.3f, 0.0f), kFront), 1024, &buried);
  EXPECT_EQ(buried.buriedSamples, 1u);
  // Where it emerges, just under the slab, the nosing hides the upper half
  // of the sky and the lower half is mostly the floor (albedo 0.5, lit by
  // the sky): about (0 + 0.5 * 0.5) pi, with some sky past the floor's edge.
  EXPECT_GT(Luminance(top.irradiance), 0.25f * kPi);
  EXPECT_LT(Luminance(top.irradiance), 0.5f * kPi);

  ShadeCounters crease;
  const ShadeOutput bottom = shader.Shade(SampleAt(t.scene, Vec3(-0.5f, 0.0f, 0.0f), kFront), 1024, &crease);
  EXPECT_EQ(crease.buriedSamples, 0u);
  EXPECT_GT(Luminance(bottom.irradiance), 0.5f * kPi);
}

// A floor quad (y = 0, 1 m square, facing +y) whose corner vertex sits at the
// centre of a closed 4 cm cube, under a uniform sky. Real models wind such
// solids any way -- outward, inward, some faces each way -- so which way the
// cube's faces point must not matter: from the corner every direction meets
// the cube within 2-4 cm, far nearer than the floor triangle extends (its
// centroid is 75 cm away), and the sample is shaded just outside the cube,
// where it sees the sky. The opposite corner, in the open, is not moved.
class EnclosedCornerTest : public ::testing::TestWithParam<int> {};

TEST_P(EnclosedCornerTest, IsShadedJustOutsideTheBoxWhateverItsWinding) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  b.AddQuad(Vec3(0.0f), Vec3(0.0f, 0.0f, 1.0f), Vec3(1.0f, 0.0f, 0.0f), m);  // floor, cross(z, x) = +y
  // The cube's six faces, each inward or outward by a bit of the parameter.
  for (int face = 0; face < 6; ++face)
    testing::AddBoxFace(b, Vec3(-0.02f), Vec3(0.02f), face / 2, face % 2, m, /*inward=*/(GetParam() >> face) & 1);
  Scene scene;
  scene.sky = UniformSky(Rgb(1.0f));
  const TestScene t = Finish(b, std::move(scene));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});

  ShadeCounters enclosed;
  const ShadeOutput corner = shader.Shade(SampleAt(t.scene, Vec3(0.0f), kUp), 256, &enclosed);
  EXPECT_EQ(enclosed.buriedSamples, 1u);
  // Just outside the cube the sky fills most of the hemisphere (the cube
  // hides a wedge of it, the floor's edge lets the ground's sky in): well
  // above half of pi L, where inside the cube it would be 0.
  EXPECT_GT(Luminance(corner.irradiance), 0.6f * kPi);

  ShadeCounters open;
  const ShadeOutput far = shader.Shade(SampleAt(t.scene, Vec3(1.0f, 0.0f, 1.0f), kUp), 256, &open);
  EXPECT_EQ(open.buriedSamples, 0u);
  EXPECT_GT(Luminance(far.irradiance), 0.9f * kPi);
}

// All outward (0), all inward (63), and two mixtures.
INSTANTIATE_TEST_SUITE_P(Windings, EnclosedCornerTest, ::testing::Values(0, 63, 0b010101, 0b100110),
                         [](const ::testing::TestParamInfo<int>& param) {
                           return param.param == 0 ? std::string("Outward")
                                  : param.param == 63 ? std::string("Inward")
                                                      : "Mixed" + std::to_string(param.param);
                         });

// A wall (z = 0, 2 m square, facing +z) on a floor, with a skirting board laid
// over its foot: a thin two-sided board (one quad, no thickness) 1 mm in
// front of it and 15 cm high, under a uniform sky. The wall's bottom corner
// sits in the 1 mm gap between the two: whichever side of the board it
// looks at, nearly every direction meets the board or the floor within
// millimetres, and nothing on the way up the wall crosses a surface (the gap
// is open at the top), so only the enclosure finds it. It is shaded above
// the board, where the sky and the lit floor are seen.
TEST(ShadingTest, AVertexInTheGapBehindAThinBoardIsShadedWhereTheWallEmerges) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  b.AddQuad(Vec3(0.0f), Vec3(2.0f, 0.0f, 0.0f), Vec3(0.0f, 2.0f, 0.0f), m);          // wall, +z
  AddHorizontalSquare(b, Vec3(1.0f, 0.0f, 1.0f), 4.0f, m, true);                      // floor, +y
  // The board runs on past both ends of the wall, as into a room's corners.
  b.AddQuad(Vec3(-1.0f, 0.0f, 0.001f), Vec3(0.0f, 0.15f, 0.0f), Vec3(4.0f, 0.0f, 0.0f), m);  // board, -z
  Scene scene;
  scene.sky = UniformSky(Rgb(1.0f));
  const TestScene t = Finish(b, std::move(scene));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  const Vec3 kFront(0.0f, 0.0f, 1.0f);

  ShadeCounters gap;
  const ShadeOutput foot = shader.Shade(SampleAt(t.scene, Vec3(0.0f), kFront), 1024, &gap);
  EXPECT_EQ(gap.buriedSamples, 1u);
  // Above the board the upper half of the hemisphere is sky (pi L / 2) and
  // most of the lower half is the sky-lit floor of albedo 0.5.
  EXPECT_GT(Luminance(foot.irradiance), 0.55f * kPi);
  EXPECT_LT(Luminance(foot.irradiance), 1.0f * kPi);
}

// A thin two-sided wall (x = 1, one quad) meeting another wall (z = 0) in a
// T-junction, under a uniform sky. Its corner in the junction is in a crease
// on both of its sides -- half of each side's hemisphere is the other wall,
// half is open -- and is shaded where it is, on either side.
TEST(ShadingTest, AThinWallsCornerInAJunctionIsACreaseOnBothSides) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  b.AddQuad(Vec3(0.0f), Vec3(2.0f, 0.0f, 0.0f), Vec3(0.0f, 2.0f, 0.0f), m);  // wall, +z
  b.AddQuad(Vec3(1.0f, 0.0f, 0.0f), Vec3(0.0f, 2.0f, 0.0f), Vec3(0.0f, 0.0f, 1.0f), m);  // thin wall, +x
  Scene scene;
  scene.sky = UniformSky(Rgb(1.0f));
  const TestScene t = Finish(b, std::move(scene));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  for (const Vec3& side : {Vec3(1.0f, 0.0f, 0.0f), Vec3(-1.0f, 0.0f, 0.0f)}) {
    ShadeCounters counters;
    const ShadeOutput out = shader.Shade(SampleAt(t.scene, Vec3(1.0f, 1.0f, 0.0f), side), 1024, &counters);
    EXPECT_EQ(counters.buriedSamples, 0u) << "side " << side.x;
    // Half the hemisphere is sky (pi L / 2) and half the wall, lit by the
    // sky over at most half its own hemisphere: between 1/2 and 3/4 of pi L.
    EXPECT_GT(Luminance(out.irradiance), 0.5f * kPi) << "side " << side.x;
    EXPECT_LT(Luminance(out.irradiance), 0.8f * kPi) << "side " << side.x;
  }
}

// Every cosine-sampled direction escapes and carries L: E = pi L exactly, on
// either side of the plane, at a vertex as well as inside.
TEST(ShadingTest, UnoccludedPlaneUnderUniformSkyReceivesPiL) {
  const Rgb sky(0.2f, 0.5f, 1.0f);
  const TestScene t = PlaneUnderSky(UniformSky(sky));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  for (const Vec3 p : {Vec3(0.0f), Vec3(-5.0f, 0.0f, -5.0f), Vec3(1.0f, 0.0f, 2.0f)}) {
    for (const Vec3 n : {kUp, -kUp}) {
      const auto e = EstimateOutput(shader, SampleAt(t.scene, p, n), 4, 16, &ShadeOutput::irradiance);
      EXPECT_TRUE(Agrees(e, kPi * sky, 0.0f));
      EXPECT_TRUE(Agrees(EstimateOutput(shader, SampleAt(t.scene, p, n), 4, 16, &ShadeOutput::radiance),
                         0.5f * sky, 0.0f));
    }
  }
}

// A smoothed vertex normal tilted by alpha from its face: the part of its
// hemisphere below the face is blocked by the surface itself (no light
// leaks through it), leaving the sky-view factor (1 + cos alpha) / 2.
TEST(ShadingTest, TiltedNormalSeesOnlyTheSkyAboveItsFace) {
  const Rgb sky(0.2f, 0.5f, 1.0f);
  const TestScene t = PlaneUnderSky(UniformSky(sky));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  const float alpha = 30.0f * kPi / 180.0f;
  ShadeInput in = SampleAt(t.scene, Vec3(1.0f, 0.0f, 1.0f), kUp);
  in.normal = Vec3(std::sin(alpha), std::cos(alpha), 0.0f);
  EXPECT_TRUE(Agrees(EstimateOutput(shader, in, 32, 64, &ShadeOutput::irradiance),
                     kPi * sky * (0.5f * (1.0f + std::cos(alpha))), 0.01f));
}

// With L(c) = h + (z - h) c for c = cos(theta) > 0, E = 2 pi (h/2 + (z - h)/3).
TEST(ShadingTest, PlaneUnderGradientSkyMatchesItsCosineIntegral) {
  SkyLight sky;
  sky.zenith = Rgb(1.0f, 0.8f, 0.6f);
  sky.horizon = Rgb(0.2f, 0.3f, 0.4f);
  sky.ground = Rgb(0.0f);
  const TestScene t = PlaneUnderSky(sky);
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  const Rgb exact = 2.0f * kPi * (0.5f * sky.horizon + (sky.zenith - sky.horizon) / 3.0f);
  EXPECT_TRUE(Agrees(EstimateOutput(shader, SampleAt(t.scene, Vec3(0.5f, 0.0f, 0.25f), kUp), 32, 64,
                                    &ShadeOutput::irradiance),
                     exact, 0.01f));
}

// --- Area lights ----------------------------------------------------------------


struct AreaLightScene {
  TestScene t;
  float lightHeight, lightSide, lightRadiance;
};

// A black floor, a black-backed square emitter facing down, and optionally a
// black square occluder halfway up.
AreaLightScene MakeAreaLightScene(float occluderSide) {
  AreaLightScene s{{}, 2.0f, 0.5f, 5.0f};
  SceneBuilder b;
  const uint32_t black = b.AddMaterial(MakeMaterial(Rgb(0.0f)));
  const uint32_t light = b.AddMaterial(MakeMaterial(Rgb(0.0f), Rgb(s.lightRadiance)));
  AddHorizontalSquare(b, Vec3(0.0f), 20.0f, black, true);
  AddHorizontalSquare(b, Vec3(0.0f, s.lightHeight, 0.0f), s.lightSide, light, false);
  if (occluderSide > 0.0f) AddHorizontalSquare(b, Vec3(0.0f, 1.0f, 0.0f), occluderSide, black, true);
  s.t = Finish(b);
  return s;
}

TEST(ShadingTest, SmallParallelEmitterMatchesTheFormFactor) {
  const AreaLightScene s = MakeAreaLightScene(0.0f);
  const Shader shader(s.t.scene, *s.t.rays, DirectOnly());
  const float half = 0.5f * s.lightSide;
  for (const Vec3 p : {Vec3(0.0f), Vec3(0.6f, 0.0f, 0.3f), Vec3(-1.5f, 0.0f, 2.0f)}) {
    const double exact = ParallelRectangleIrradiance(s.lightRadiance, s.lightHeight, -half - p.x, half - p.x,
                                                     -half - p.z, half - p.z);
    const auto e = EstimateOutput(shader, SampleAt(s.t.scene, p, kUp), 32, 64, &ShadeOutput::irradiance);
    EXPECT_TRUE(Agrees(e, Rgb(float(exact)), 0.01f)) << "at x = " << p.x << ", z = " << p.z;
  }
}

TEST(ShadingTest, UmbraOfAnOccluderGetsNoDirectLightAndItsSurroundingsDo) {
  const AreaLightScene s = MakeAreaLightScene(1.0f);
  const Shader shader(s.t.scene, *s.t.rays, DirectOnly());
  // Under the occluder's centre every line to the light crosses it.
  const auto umbra = EstimateOutput(shader, SampleAt(s.t.scene, Vec3(0.0f), kUp), 16, 64, &ShadeOutput::irradiance);
  EXPECT_EQ(umbra.mean, Rgb(0.0f));
  // At x = 3 the whole light is in view: lines to it pass the occluder's edge
  // at x >= 1.375.
  const Vec3 lit(3.0f, 0.0f, 0.0f);
  const float half = 0.5f * s.lightSide;
  const double exact =
      ParallelRectangleIrradiance(s.lightRadiance, s.lightHeight, -half - lit.x, half - lit.x, -half, half);
  EXPECT_TRUE(Agrees(EstimateOutput(shader, SampleAt(s.t.scene, lit, kUp), 32, 64, &ShadeOutput::irradiance),
                     Rgb(float(exact)), 0.01f));
}

// An emitter facing down (albedo 0.5) under a uniform sky L, with a black
// receiver beside it. On the emitter, the front side reads Le + 0.5 L and the
// back side 0.5 L. A receiver below sees the emitter's front (Le instead of
// the sky over the emitter's form factor); one above sees its back, which
// emits nothing and, at depth 1, reflects nothing.
class EmitterSideTest : public ::testing::TestWithParam<bool> {};

TEST_P(EmitterSideTest, EmittersEmitFromTheirFrontFaceOnly) {
  const bool receiverBelow = GetParam();
  const Rgb emission(4.0f, 2.0f, 1.0f);
  const Rgb sky(0.25f, 0.5f, 0.5f);
  const float gap = 1.0f;
  SceneBuilder b;
  AddHorizontalSquare(b, Vec3(0.0f), 1.0f, b.AddMaterial(MakeMaterial(Rgb(0.5f), emission)), false);
  const Vec3 receiver(0.0f, receiverBelow ? -gap : gap, 0.0f);
  const Vec3 towardEmitter = receiverBelow ? kUp : -kUp;
  AddHorizontalSquare(b, receiver, 0.2f, b.AddMaterial(MakeMaterial(Rgb(0.0f))), receiverBelow);
  Scene scene;
  scene.sky = UniformSky(sky);
  const TestScene t = Finish(b, std::move(scene));
  const Shader shader(t.scene, *t.rays, DirectOnly());

  const Rgb formFactorTimesPi(float(ParallelRectangleIrradiance(1.0, gap, -0.5, 0.5, -0.5, 0.5)));
  const Rgb seen = receiverBelow ? emission : Rgb(0.0f);
  const Rgb exact = kPi * sky + (seen - sky) * formFactorTimesPi;
  EXPECT_TRUE(Agrees(EstimateOutput(shader, SampleAt(t.scene, receiver, towardEmitter), 64, 128,
                                    &ShadeOutput::irradiance),
                     exact, 0.01f));

  // The emitter itself: its front (down) sees the sky below and the small
  // black receiver if it is there; its back likewise above.
  const Vec3 onEmitter(0.3f, 0.0f, 0.3f);
  const ShadeInput front = SampleAt(t.scene, onEmitter, -kUp);
  const ShadeInput back = SampleAt(t.scene, onEmitter, kUp);
  const ShadeOutput f = shader.Shade(front, 16, nullptr);
  const ShadeOutput k = shader.Shade(back, 16, nullptr);
  EXPECT_TRUE(Agrees({f.radiance - 0.5f * kInvPi * f.irradiance, Rgb(0.0f)}, emission, 0.0f));
  EXPECT_TRUE(Agrees({k.radiance - 0.5f * kInvPi * k.irradiance, Rgb(0.0f)}, Rgb(0.0f), 0.0f));
  EXPECT_GT(Luminance(k.irradiance), 0.0f);
}

INSTANTIATE_TEST_SUITE_P(Receiver, EmitterSideTest, ::testing::Bool(),
                         [](const ::testing::TestParamInfo<bool>& param) {
                           return std::string(param.param ? "Below" : "Above");
                         });

// --- Sun ------------------------------------------------------------------------

// Irradiance from a uniform disc of half-angle alpha entirely above the
// surface, at angle theta from its normal: L pi sin^2(alpha) cos(theta). (The
// solid angle is 2 pi (1 - cos alpha); the mean cosine over the cone is
// cos(theta) (1 + cos alpha) / 2.)
float SunIrradiance(const SunLight& sun, const Vec3& normal) {
  const float sinHalf = std::sin(0.5f * sun.angularDiameterRad);
  return sun.radiance.r * kPi * sinHalf * sinHalf * glm::dot(sun.directionToSun, normal);
}

TestScene SunScene(const Vec3& directionToSun) {
  SceneBuilder b;
  const uint32_t black = b.AddMaterial(MakeMaterial(Rgb(0.0f)));
  AddHorizontalSquare(b, Vec3(0.0f), 20.0f, black, true);
  AddHorizontalSquare(b, Vec3(0.0f, 1.0f, 0.0f), 2.0f, black, true);  // occluder over [-1, 1]^2
  Scene scene;
  SunLight sun;
  sun.directionToSun = directionToSun;
  sun.radiance = Rgb(100.0f);
  sun.angularDiameterRad = 0.1f;  // broad, to make the penumbra easy to hit
  scene.sun = sun;
  return Finish(b, std::move(scene));
}

TEST(ShadingTest, SunShadowsAreDarkAndSunlitPointsGetTheConeIrradiance) {
  const float theta = 30.0f * kPi / 180.0f;
  const TestScene t = SunScene(Vec3(std::sin(theta), std::cos(theta), 0.0f));
  const Shader shader(t.scene, *t.rays, DirectOnly());
  // The occluder's shadow is displaced by -tan(30 deg) in x.
  const Vec3 shadowed(-std::tan(theta), 0.0f, 0.0f);
  EXPECT_EQ(EstimateOutput(shader, SampleAt(t.scene, shadowed, kUp), 8, 64, &ShadeOutput::irradiance).mean, Rgb(0.0f));
  const float exact = SunIrradiance(*t.scene.sun, kUp);
  EXPECT_TRUE(Agrees(EstimateOutput(shader, SampleAt(t.scene, Vec3(3.0f, 0.0f, 0.0f), kUp), 32, 16,
                                    &ShadeOutput::irradiance),
                     Rgb(exact), 0.01f));
}

// Straight under the occluder's edge, with the sun at the zenith, the edge's
// plane splits the sun's cone into two mirror halves: half the irradiance.
TEST(ShadingTest, SunPenumbraUnderAnEdgeIsHalfLit) {
  const TestScene t = SunScene(kUp);
  const Shader shader(t.scene, *t.rays, DirectOnly());
  const float full = SunIrradiance(*t.scene.sun, kUp);
  // Each path is lit or not, so the per-path deviation is as large as the
  // mean: 8192 paths for a 1.1% standard error.
  const auto e = EstimateOutput(shader, SampleAt(t.scene, Vec3(1.0f, 0.0f, 0.0f), kUp), 64, 128,
                                &ShadeOutput::irradiance);
  EXPECT_GT(e.mean.r, 0.0f);
  EXPECT_LT(e.mean.r, full);
  EXPECT_TRUE(Agrees(e, Rgb(0.5f * full), 0.02f));
}

// --- Textures -------------------------------------------------------------------

// A 2x2 texture on a unit quad under a uniform sky: at each texel centre the
// radiance is Kd x texel x L exactly. Row 0 of the texture is the top of the
// image, which is v = 1.
TEST(ShadingTest, TexturedAlbedoIsReadAtTheSampleUv) {
  Texture texture;
  texture.path = "checker";
  texture.width = 2;
  texture.height = 2;
  const Rgb topLeft(0.9f, 0.1f, 0.1f), topRight(0.1f, 0.9f, 0.1f), bottomLeft(0.1f, 0.1f, 0.9f),
      bottomRight(0.5f, 0.5f, 0.2f);
  texture.texels = {topLeft, topRight, bottomLeft, bottomRight};
  SceneBuilder b;
  Material m = MakeMaterial(Rgb(0.8f));
  m.albedoTexture = b.AddTexture(texture);
  // AddQuad's uv: corner (0,0), +edge1 (1,0), +edge2 (0,1). Edge1 along x
  // and edge2 along -z put the front face up.
  b.AddQuad(Vec3(0.0f), Vec3(1.0f, 0.0f, 0.0f), Vec3(0.0f, 0.0f, -1.0f), b.AddMaterial(m));
  Scene scene;
  const Rgb sky(0.5f, 1.0f, 2.0f);
  scene.sky = UniformSky(sky);
  const TestScene t = Finish(b, std::move(scene));
  const Shader shader(t.scene, *t.rays, ShadingSettings{});

  const struct {
    Vec2 uv;
    Rgb texel;
  } cases[] = {{{0.25f, 0.75f}, topLeft}, {{0.75f, 0.75f}, topRight},
               {{0.25f, 0.25f}, bottomLeft}, {{0.75f, 0.25f}, bottomRight}};
  for (const auto& c : cases) {
    const Vec3 p(c.uv.x, 0.0f, -c.uv.y);
    const auto e = EstimateOutput(shader, SampleAt(t.scene, p, kUp), 2, 8, &ShadeOutput::radiance);
    EXPECT_TRUE(Agrees(e, 0.8f * c.texel * sky, 0.0f)) << "uv (" << c.uv.x << ", " << c.uv.y << ")";
  }
}

// --- Standard error -------------------------------------------------------------

// The reported standard error must describe the estimate's actual spread:
// over K independent sample ids, the standard deviation of the estimates
// should match the mean reported error. With K = 64 the sample standard
// deviation is itself known to about 1/sqrt(2K) = 9%; 4 of those bound the
// ratio.
TEST(ShadingTest, StandardErrorMatchesTheSpreadOfIndependentEstimates) {
  const AreaLightScene s = MakeAreaLightScene(0.0f);
  const Shader shader(s.t.scene, *s.t.rays, DirectOnly());
  ShadeInput in = SampleAt(s.t.scene, Vec3(0.6f, 0.0f, 0.3f), kUp);
  constexpr int kIds = 64;
  double sum = 0.0, sumSquares = 0.0, reported = 0.0;
  for (int k = 0; k < kIds; ++k) {
    in.sampleId = 1000 + uint64_t(k);
    const ShadeOutput out = shader.Shade(in, 64, nullptr);
    const double l = Luminance(out.irradiance);
    sum += l;
    sumSquares += l * l;
    reported += out.irradianceStdErr;
  }
  const double mean = sum / kIds;
  const double spread = std::sqrt((sumSquares / kIds - mean * mean) * kIds / (kIds - 1));
  const double ratio = (reported / kIds) / spread;
  EXPECT_GT(ratio, 1.0 - 4.0 / std::sqrt(2.0 * kIds)) << "reported " << reported / kIds << ", observed " << spread;
  EXPECT_LT(ratio, 1.0 + 4.0 / std::sqrt(2.0 * kIds)) << "reported " << reported / kIds << ", observed " << spread;
}

TEST(ShadingTest, StandardErrorIsZeroWhenEveryPathAgrees) {
  // Every cosine-sampled path escapes to a uniform sky and reads pi L.
  const TestScene t = PlaneUnderSky(UniformSky(Rgb(0.7f)));
  const Shader shader(t.scene, *t.rays, DirectOnly());
  const ShadeOutput out = shader.Shade(SampleAt(t.scene, Vec3(0.0f), kUp), 32, nullptr);
  EXPECT_NEAR(out.irradianceStdErr, 0.0f, 1e-5f);
}

// --- Adaptive sampling ------------------------------------------------------------

TEST(ShadingTest, AdaptiveSamplingAddsNoPathWhereEveryPathAgrees) {
  const TestScene t = PlaneUnderSky(UniformSky(Rgb(0.7f)));
  ShadingSettings settings = DirectOnly();
  settings.maxPathsPerSample = 1024;
  const Shader shader(t.scene, *t.rays, settings);
  ShadeCounters counters;
  shader.Shade(SampleAt(t.scene, Vec3(0.0f), kUp), 32, &counters);
  EXPECT_EQ(counters.paths, 32u);
}

// Paths that all found nothing do not show there is nothing to find: a
// black estimate gets further rounds up to the cap. (A sample on the floor of
// a sealed box: nothing ever reaches it, so it takes them all.)
TEST(ShadingTest, AdaptiveSamplingKeepsLookingWhereEveryPathFoundNothing) {
  SceneBuilder b;
  const uint32_t m = b.AddMaterial(MakeMaterial(Rgb(0.5f)));
  AddBox(b, Vec3(-1.0f, 0.0f, -1.0f), Vec3(1.0f, 2.0f, 1.0f), m, true);
  Scene scene;
  scene.sky = UniformSky(Rgb(1.0f));
  const TestScene t = Finish(b, std::move(scene));
  ShadingSettings settings;
  settings.maxPathsPerSample = 256;
  ShadeCounters counters;
  const ShadeOutput out = Shader(t.scene, *t.rays, settings).Shade(SampleAt(t.scene, Vec3(0.0f), kUp), 16, &counters);
  EXPECT_EQ(Luminance(out.irradiance), 0.0f);
  EXPECT_EQ(counters.paths, 256u);
}

TEST(ShadingTest, AdaptiveSamplingStopsAtTheTargetErrorOrAtTheCap) {
  // A point lit by a small area light: the light samples disagree, so the
  // first 32 paths leave the relative error above 1 %.
  const AreaLightScene s = MakeAreaLightScene(0.0f);
  const ShadeInput in = SampleAt(s.t.scene, Vec3(0.6f, 0.0f, 0.3f), kUp);
  const ShadeOutput fixed = Shader(s.t.scene, *s.t.rays, DirectOnly()).Shade(in, 32, nullptr);
  ASSERT_GT(fixed.irradianceStdErr, 0.01f * Luminance(fixed.irradiance));

  ShadingSettings adaptive = DirectOnly();
  adaptive.maxPathsPerSample = 1 << 16;
  adaptive.targetRelativeError = 0.004f;
  ShadeCounters counters;
  const ShadeOutput out = Shader(s.t.scene, *s.t.rays, adaptive).Shade(in, 32, &counters);
  EXPECT_GT(counters.paths, 32u);
  EXPECT_LT(counters.paths, uint64_t(adaptive.maxPathsPerSample)) << "the target is reachable";
  EXPECT_LE(out.irradianceStdErr, 0.004f * Luminance(out.irradiance));
  // Same answer as the fixed count, within their combined noise.
  EXPECT_NEAR(Luminance(out.irradiance), Luminance(fixed.irradiance),
              4.0f * std::hypot(fixed.irradianceStdErr, out.irradianceStdErr));

  adaptive.maxPathsPerSample = 100;  // not a multiple of the round: the cap still holds exactly
  ShadeCounters capped;
  Shader(s.t.scene, *s.t.rays, adaptive).Shade(in, 32, &capped);
  EXPECT_EQ(capped.paths, 100u);
}

// --- Determinism ----------------------------------------------------------------

TestScene CornellLikeBox() {
  SceneBuilder b;
  const uint32_t white = b.AddMaterial(MakeMaterial(Rgb(0.73f)));
  const uint32_t red = b.AddMaterial(MakeMaterial(Rgb(0.65f, 0.05f, 0.05f)));
  const uint32_t green = b.AddMaterial(MakeMaterial(Rgb(0.12f, 0.45f, 0.15f)));
  const uint32_t light = b.AddMaterial(MakeMaterial(Rgb(0.78f), Rgb(15.0f, 12.0f, 8.0f)));
  AddBox(b, Vec3(0.0f), Vec3(1.0f), {red, green, white, white, white, white}, true);
  AddHorizontalSquare(b, Vec3(0.5f, 0.999f, 0.5f), 0.25f, light, false);
  AddBox(b, Vec3(0.2f, 0.0f, 0.2f), Vec3(0.45f, 0.6f, 0.45f), white, false);
  return Finish(b);
}

std::vector<ShadeInput> VertexSamples(const Scene& scene) {
  std::vector<ShadeInput> inputs;
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) {
    ShadeInput in;
    in.sampleId = 3 * uint64_t(t);
    in.triangle = t;
    in.b1 = 1.0f;  // corner 1
    in.position = scene.Position(t, 1);
    in.normal = scene.vertices[scene.triangles[t].v[1]].normal;
    inputs.push_back(in);
  }
  return inputs;
}

bool BitIdentical(const ShadeOutput& a, const ShadeOutput& b) {
  return std::memcmp(&a.radiance, &b.radiance, sizeof(Rgb)) == 0 &&
         std::memcmp(&a.irradiance, &b.irradiance, sizeof(Rgb)) == 0;
}

TEST(ShadingTest, SameInputGivesBitIdenticalOutputOnAnyThreadInAnyOrder) {
  const TestScene t = CornellLikeBox();
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  const std::vector<ShadeInput> inputs = VertexSamples(t.scene);
  EnableFlushToZero();
  std::vector<ShadeOutput> serial;
  for (const ShadeInput& in : inputs) serial.push_back(shader.Shade(in, 8, nullptr));

  // Two threads, each taking every other input, backwards.
  std::vector<ShadeOutput> parallel(inputs.size());
  std::vector<std::thread> threads;
  for (size_t first = 0; first < 2; ++first)
    threads.emplace_back([&, first] {
      EnableFlushToZero();
      for (size_t k = first; k < inputs.size(); k += 2) {
        const size_t i = inputs.size() - 1 - k;
        parallel[i] = shader.Shade(inputs[i], 8, nullptr);
      }
    });
  for (std::thread& th : threads) th.join();
  for (size_t i = 0; i < inputs.size(); ++i) EXPECT_TRUE(BitIdentical(serial[i], parallel[i])) << "input " << i;

  // A second shader over the same scene agrees too: no hidden state.
  const Shader again(t.scene, *t.rays, ShadingSettings{});
  EXPECT_TRUE(BitIdentical(again.Shade(inputs[5], 8, nullptr), serial[5]));
}

TEST(ShadingTest, DifferentSampleIdsAndSeedsGiveDifferentEstimates) {
  const TestScene t = CornellLikeBox();
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  ShadingSettings reseeded;
  reseeded.seed = 99;
  const Shader other(t.scene, *t.rays, reseeded);
  ShadeInput in = SampleAt(t.scene, Vec3(0.7f, 0.0f, 0.7f), kUp, 1);
  const ShadeOutput a = shader.Shade(in, 8, nullptr);
  const ShadeOutput c = other.Shade(in, 8, nullptr);
  in.sampleId = 2;
  const ShadeOutput b = shader.Shade(in, 8, nullptr);
  EXPECT_FALSE(BitIdentical(a, b));
  EXPECT_FALSE(BitIdentical(a, c));
}

TEST(ShadingTest, CountersAddUpPathsAndRays) {
  const TestScene t = CornellLikeBox();
  const Shader shader(t.scene, *t.rays, ShadingSettings{});
  ShadeCounters counters;
  shader.Shade(SampleAt(t.scene, Vec3(0.7f, 0.0f, 0.7f), kUp), 16, &counters);
  shader.Shade(SampleAt(t.scene, Vec3(0.7f, 0.0f, 0.7f), kUp), 0, &counters);
  EXPECT_EQ(counters.paths, 16u + uint64_t(ShadingSettings{}.pathsPerSample));
  // Each path traces at least one bounce and one shadow ray in a closed,
  // lit box.
  EXPECT_GE(counters.shadowRays, counters.paths);
  EXPECT_GE(counters.rays - counters.shadowRays, counters.paths);
}

// --- Validation -----------------------------------------------------------------

class ValidateShadeInputTest : public ::testing::Test {
 protected:
  void SetUp() override { valid_ = SampleAt(t_.scene, Vec3(0.5f, 0.0f, 0.25f), kUp); }
  void ExpectRejected(const ShadeInput& in, const std::string& field) {
    const Status st = ValidateShadeInput(t_.scene, in);
    ASSERT_FALSE(st.ok());
    EXPECT_NE(st.error().message.find(field), std::string::npos) << st.error().message;
  }
  TestScene t_ = CornellLikeBox();
  ShadeInput valid_;
};

TEST_F(ValidateShadeInputTest, AcceptsASampleOnItsTriangle) {
  EXPECT_TRUE(ValidateShadeInput(t_.scene, valid_).ok());
  for (const ShadeInput& in : VertexSamples(t_.scene)) EXPECT_TRUE(ValidateShadeInput(t_.scene, in).ok());
}

TEST_F(ValidateShadeInputTest, RejectsNonFiniteFields) {
  ShadeInput in = valid_;
  in.position.y = std::nanf("");
  ExpectRejected(in, "position");
  in = valid_;
  in.normal.x = std::numeric_limits<float>::infinity();
  ExpectRejected(in, "normal");
  in = valid_;
  in.b2 = std::nanf("");
  ExpectRejected(in, "barycentrics");
}

TEST_F(ValidateShadeInputTest, RejectsANonUnitNormal) {
  ShadeInput in = valid_;
  in.normal = Vec3(0.0f, 1.05f, 0.0f);
  ExpectRejected(in, "normal");
  in.normal = Vec3(0.0f);
  ExpectRejected(in, "normal");
}

TEST_F(ValidateShadeInputTest, RejectsAnUnknownTriangle) {
  ShadeInput in = valid_;
  in.triangle = uint32_t(t_.scene.triangles.size());
  ExpectRejected(in, "triangle");
}

TEST_F(ValidateShadeInputTest, RejectsBarycentricsOutsideTheTriangle) {
  ShadeInput in = valid_;
  in.b1 = -0.01f;
  ExpectRejected(in, "barycentrics");
  in.b1 = 0.6f;
  in.b2 = 0.41f;
  ExpectRejected(in, "barycentrics");
}

TEST_F(ValidateShadeInputTest, RejectsAPositionOffTheTriangle) {
  ShadeInput in = valid_;
  in.position.y += 0.01f;
  ExpectRejected(in, "position");
}

}  // namespace
}  // namespace penumbra
