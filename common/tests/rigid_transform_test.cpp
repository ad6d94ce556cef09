// RigidTransform (issue 14): what FromRowMajor accepts and refuses, and the
// algebra (inverse, composition, interpolation) on cases with known answers.

#include "penumbra/common/rigid_transform.h"

#include <gtest/gtest.h>

#include <glm/trigonometric.hpp>

#include <array>
#include <cmath>
#include <limits>
#include <string>

namespace penumbra {
namespace {

constexpr float kEps = 1e-5f;

void ExpectNear(const Vec3& a, const Vec3& b, float eps = kEps) {
  EXPECT_NEAR(a.x, b.x, eps);
  EXPECT_NEAR(a.y, b.y, eps);
  EXPECT_NEAR(a.z, b.z, eps);
}

void ExpectSameTransform(const RigidTransform& a, const RigidTransform& b, float eps = kEps) {
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) EXPECT_NEAR(a.rotation[c][r], b.rotation[c][r], eps) << "entry row " << r << " col " << c;
  ExpectNear(a.translation, b.translation, eps);
}

// A quarter turn about +z: x -> y, y -> -x.
std::array<float, 12> QuarterTurnAboutZ(float tx, float ty, float tz) {
  return {0.0f, -1.0f, 0.0f, tx,  //
          1.0f, 0.0f,  0.0f, ty,  //
          0.0f, 0.0f,  1.0f, tz};
}

std::string ErrorOf(std::span<const float> m) {
  auto t = RigidTransform::FromRowMajor(m);
  return t ? std::string() : t.error().message;
}

TEST(RigidTransformTest, FromRowMajorReadsRowsWithTheTranslationLast) {
  const auto m = QuarterTurnAboutZ(1.0f, 2.0f, 3.0f);
  auto t = RigidTransform::FromRowMajor(m);
  ASSERT_TRUE(t.ok()) << t.error().message;
  ExpectNear(t->ApplyPoint(Vec3(1.0f, 0.0f, 0.0f)), Vec3(1.0f, 3.0f, 3.0f));
  ExpectNear(t->ApplyPoint(Vec3(0.0f, 1.0f, 0.0f)), Vec3(0.0f, 2.0f, 3.0f));
  ExpectNear(t->ApplyVector(Vec3(1.0f, 0.0f, 0.0f)), Vec3(0.0f, 1.0f, 0.0f));  // directions do not translate
  const auto back = t->ToRowMajor();
  for (size_t i = 0; i < 12; ++i) EXPECT_NEAR(back[i], m[i], kEps) << "entry " << i;
}

TEST(RigidTransformTest, FromRowMajorAcceptsRotationsWrittenToSixDecimals) {
  // 30 degrees about (1, 1, 1)/sqrt(3), rounded to 6 decimals as a person or a file would write it.
  const RigidTransform exact = RigidTransform::FromAxisAngle(Vec3(1.0f), glm::radians(30.0f), Vec3(0.5f, -2.0f, 7.0f));
  std::array<float, 12> m = exact.ToRowMajor();
  for (float& v : m) v = std::round(v * 1e6f) / 1e6f;
  auto t = RigidTransform::FromRowMajor(m);
  ASSERT_TRUE(t.ok()) << t.error().message;
  ExpectSameTransform(*t, exact, 1e-5f);
  // The result is orthonormal to float precision (re-orthonormalised).
  const glm::mat3 gram = glm::transpose(t->rotation) * t->rotation;
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) EXPECT_NEAR(gram[c][r], r == c ? 1.0f : 0.0f, 1e-6f);
}

TEST(RigidTransformTest, FromRowMajorRefusesScaleShearMirrorAndCollapse) {
  std::array<float, 12> scaled = {1.001f, 0, 0, 0, 0, 1.001f, 0, 0, 0, 0, 1.001f, 0};
  EXPECT_NE(ErrorOf(scaled).find("not a rotation"), std::string::npos) << ErrorOf(scaled);
  std::array<float, 12> shear = {1, 0.1f, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
  EXPECT_NE(ErrorOf(shear).find("not a rotation"), std::string::npos) << ErrorOf(shear);
  std::array<float, 12> mirror = {-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};  // orthonormal, det -1
  EXPECT_NE(ErrorOf(mirror).find("det -1"), std::string::npos) << ErrorOf(mirror);
  std::array<float, 12> zero{};
  EXPECT_NE(ErrorOf(zero).find("not a rotation"), std::string::npos) << ErrorOf(zero);
  EXPECT_NE(ErrorOf(zero).find("no scale, shear, mirror"), std::string::npos) << ErrorOf(zero);
}

TEST(RigidTransformTest, FromRowMajorRefusesNonFiniteEntriesFarTranslationsAndWrongCounts) {
  std::array<float, 12> m = QuarterTurnAboutZ(0, 0, 0);
  m[5] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(ErrorOf(m), "transform entry 5 is not finite");
  m = QuarterTurnAboutZ(0, 0, 0);
  m[11] = std::numeric_limits<float>::infinity();
  EXPECT_EQ(ErrorOf(m), "transform entry 11 is not finite");
  m = QuarterTurnAboutZ(2e7f, 0, 0);
  EXPECT_NE(ErrorOf(m).find("beyond"), std::string::npos) << ErrorOf(m);
  const std::array<float, 9> nine{1, 0, 0, 0, 1, 0, 0, 0, 1};
  EXPECT_NE(ErrorOf(nine).find("not 9"), std::string::npos) << ErrorOf(nine);
}

TEST(RigidTransformTest, InverseUndoesAndComposeAppliesTheRightOneFirst) {
  const RigidTransform a = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), glm::radians(90.0f), Vec3(1, 2, 3));
  const RigidTransform b = RigidTransform::FromAxisAngle(Vec3(1, 0, 0), glm::radians(90.0f), Vec3(0, 0, 5));
  const Vec3 p(0.3f, -1.2f, 2.5f);
  ExpectNear(a.Inverse().ApplyPoint(a.ApplyPoint(p)), p);
  ExpectSameTransform(a.Compose(a.Inverse()), RigidTransform::Identity());
  // a * b: b first. b takes (1, 0, 0) to (1, 0, 5) (x is its axis); a turns that to (0, 1, 5) and adds (1, 2, 3).
  ExpectNear(a.Compose(b).ApplyPoint(Vec3(1, 0, 0)), Vec3(1, 3, 8));
  ExpectNear(a.Compose(b).ApplyPoint(p), a.ApplyPoint(b.ApplyPoint(p)));
  // Rotations do not commute: b * a is another transform.
  EXPECT_GT(glm::length(b.Compose(a).ApplyPoint(p) - a.Compose(b).ApplyPoint(p)), 0.1f);
}

TEST(RigidTransformTest, InterpolateMovesLinearlyAndTurnsTheShortWayAtConstantSpeed) {
  const RigidTransform a = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), 0.0f, Vec3(0, 0, 0));
  const RigidTransform b = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(90.0f), Vec3(2, 4, -6));
  ExpectSameTransform(Interpolate(a, b, 0.0f), a);
  ExpectSameTransform(Interpolate(a, b, 1.0f), b);
  const RigidTransform half = Interpolate(a, b, 0.5f);
  ExpectNear(half.translation, Vec3(1, 2, -3));
  ExpectSameTransform(half, RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(45.0f), Vec3(1, 2, -3)));
  const RigidTransform quarter = Interpolate(a, b, 0.25f);
  ExpectSameTransform(quarter, RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(22.5f), Vec3(0.5f, 1, -1.5f)));
  // From +170 to -170 degrees about y, the short way is through 180, not through 0.
  const RigidTransform c = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(170.0f), Vec3(0));
  const RigidTransform d = RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(-170.0f), Vec3(0));
  ExpectSameTransform(Interpolate(c, d, 0.5f), RigidTransform::FromAxisAngle(Vec3(0, 1, 0), glm::radians(180.0f), Vec3(0)),
                      1e-4f);
}

TEST(RigidTransformTest, ApplyBoundsEnclosesTheTurnedBox) {
  Bounds3 box;
  box.Extend(Vec3(0, 0, 0));
  box.Extend(Vec3(2, 1, 1));
  // 90 degrees about z takes x to y: the box spans x in [-1, 0], y in [0, 2].
  const RigidTransform t = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), glm::radians(90.0f), Vec3(10, 0, 0));
  const Bounds3 out = t.ApplyBounds(box);
  ExpectNear(out.min, Vec3(9, 0, 0));
  ExpectNear(out.max, Vec3(10, 2, 1));
  EXPECT_TRUE(t.ApplyBounds(Bounds3{}).Empty());
}

TEST(RigidTransformTest, NearlyEqualComparesEveryEntryWithinTheTolerance) {
  const RigidTransform a = RigidTransform::FromAxisAngle(Vec3(0, 0, 1), 0.5f, Vec3(1, 2, 3));
  RigidTransform b = a;
  EXPECT_TRUE(NearlyEqual(a, b, 0.0f));
  b.translation.z += 0.01f;
  EXPECT_FALSE(NearlyEqual(a, b, 1e-3f));
  EXPECT_TRUE(NearlyEqual(a, b, 0.02f));
  b = a;
  b.rotation[1][0] = std::nanf("");
  EXPECT_FALSE(NearlyEqual(a, b, 1.0f));
}

TEST(RigidTransformTest, DescribeNamesTranslationAndAngle) {
  const std::string text = Describe(RigidTransform::FromAxisAngle(Vec3(0, 0, 1), glm::radians(90.0f), Vec3(1, 2, 3)));
  EXPECT_NE(text.find("translate (1, 2, 3)"), std::string::npos) << text;
  EXPECT_NE(text.find("rotate 90 deg about (0, 0, 1)"), std::string::npos) << text;
}

}  // namespace
}  // namespace penumbra
