// Camera movement prediction on analytic paths: a straight walk, a turn at
// constant rate, a camera at rest, and the histories that predict nothing
// (too short, too old, reversed, a jump).

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>

#include "penumbra/sma/camera_prediction.h"

namespace penumbra::sma {
namespace {

using namespace std::chrono_literals;
using Clock = CameraPredictor::Clock;

constexpr float kDeg = kPi / 180.0f;

CameraView Looking(Vec3 eye, Vec3 direction, Vec3 up = {0.0f, 1.0f, 0.0f}) {
  CameraView v;
  v.pose.eye = eye;
  v.pose.target = eye + direction;
  v.pose.up = up;
  v.fovYDeg = 60.0f;
  v.width = 320;
  v.height = 240;
  return v;
}

// Looking along the xz-plane at `yawDeg` from -z toward +x.
Vec3 Yaw(float yawDeg) { return {std::sin(yawDeg * kDeg), 0.0f, -std::cos(yawDeg * kDeg)}; }

void ExpectNear(Vec3 a, Vec3 b, float tolerance = 1e-4f) {
  EXPECT_NEAR(a.x, b.x, tolerance);
  EXPECT_NEAR(a.y, b.y, tolerance);
  EXPECT_NEAR(a.z, b.z, tolerance);
}

Vec3 Direction(const CameraPose& p) { return glm::normalize(p.target - p.eye); }

TEST(CameraPrediction, StraightWalkIsExtrapolatedByTheHorizon) {
  // 2 units/s along +x, a view every 0.1 s, horizon 0.5 s: 1 unit ahead.
  CameraPredictor predictor({.horizon = 500ms, .widen = 1.0});
  const Clock::time_point t0{};
  predictor.Observe(Looking({0, 1, 0}, Yaw(0)), t0);
  predictor.Observe(Looking({0.2f, 1, 0}, Yaw(0)), t0 + 100ms);
  predictor.Observe(Looking({0.4f, 1, 0}, Yaw(0)), t0 + 200ms);
  auto p = predictor.Predict(t0 + 210ms);
  ASSERT_TRUE(p);
  EXPECT_FALSE(p->atRest);
  ExpectNear(p->view.pose.eye, {1.4f, 1.0f, 0.0f});
  ExpectNear(Direction(p->view.pose), Yaw(0));
  EXPECT_FLOAT_EQ(p->view.fovYDeg, 60.0f);
  EXPECT_EQ(p->view.width, 320);
  EXPECT_EQ(p->view.height, 240);
}

TEST(CameraPrediction, ConstantTurnIsExtrapolatedByItsAngularVelocity) {
  // Turning 10 degrees per 0.1 s (100 deg/s) about +y, standing still:
  // 0.5 s ahead is 50 degrees further.
  CameraPredictor predictor({.horizon = 500ms, .widen = 1.0});
  const Clock::time_point t0{};
  predictor.Observe(Looking({1, 2, 3}, Yaw(0)), t0);
  predictor.Observe(Looking({1, 2, 3}, Yaw(10)), t0 + 100ms);
  auto p = predictor.Predict(t0 + 100ms);
  ASSERT_TRUE(p);
  EXPECT_FALSE(p->atRest);
  ExpectNear(p->view.pose.eye, {1, 2, 3});
  ExpectNear(Direction(p->view.pose), Yaw(60));
  ExpectNear(glm::normalize(p->view.pose.up), {0, 1, 0});
  // The target stays as far from the eye as the client put it.
  EXPECT_NEAR(glm::length(p->view.pose.target - p->view.pose.eye), 1.0f, 1e-4f);
}

TEST(CameraPrediction, WalkAndPitchTogether) {
  // Moving along -z at 1 unit/s while pitching up 5 degrees per 0.1 s.
  CameraPredictor predictor({.horizon = 200ms, .widen = 1.0});
  const Clock::time_point t0{};
  const auto pitched = [](float deg) { return Vec3(0.0f, std::sin(deg * kDeg), -std::cos(deg * kDeg)); };
  predictor.Observe(Looking({0, 0, 0}, pitched(0)), t0);
  predictor.Observe(Looking({0, 0, -0.1f}, pitched(5)), t0 + 100ms);
  auto p = predictor.Predict(t0 + 100ms);
  ASSERT_TRUE(p);
  ExpectNear(p->view.pose.eye, {0, 0, -0.3f});
  ExpectNear(Direction(p->view.pose), pitched(15));
  // Up turns with the camera.
  ExpectNear(glm::normalize(p->view.pose.up), {0, std::cos(15 * kDeg), std::sin(15 * kDeg)});
}

TEST(CameraPrediction, TheFrustumIsWidenedByTheFactor) {
  CameraPredictor predictor({.horizon = 500ms, .widen = 1.15});
  const Clock::time_point t0{};
  predictor.Observe(Looking({0, 0, 0}, Yaw(0)), t0);
  predictor.Observe(Looking({0.1f, 0, 0}, Yaw(0)), t0 + 100ms);
  auto p = predictor.Predict(t0 + 100ms);
  ASSERT_TRUE(p);
  EXPECT_NEAR(std::tan(p->view.fovYDeg * 0.5f * kDeg), 1.15f * std::tan(30.0f * kDeg), 1e-5f);
  // Wide views stay usable views (ValidateCameraView: at most 179 degrees).
  EXPECT_GT(WidenFovY(170.0f, 10.0), 178.0f);
  EXPECT_LE(WidenFovY(170.0f, 10.0), 179.0f);
  EXPECT_LE(WidenFovY(179.0f, 2.0), 179.0f);
}

TEST(CameraPrediction, ACameraAtRestPredictsItself) {
  CameraPredictor predictor;
  const Clock::time_point t0{};
  const CameraView still = Looking({1, 1, 1}, Yaw(30));
  predictor.Observe(still, t0);
  predictor.Observe(still, t0 + 100ms);
  auto p = predictor.Predict(t0 + 150ms);
  ASSERT_TRUE(p);
  EXPECT_TRUE(p->atRest);
  ExpectNear(p->view.pose.eye, still.pose.eye);
  ExpectNear(p->view.pose.target, still.pose.target);
  EXPECT_FLOAT_EQ(p->view.fovYDeg, still.fovYDeg);
}

TEST(CameraPrediction, TooShortOrTooOldHistoryPredictsNothing) {
  CameraPredictor predictor({.maxGap = 1s, .maxAge = 2s});
  const Clock::time_point t0{};
  EXPECT_FALSE(predictor.Predict(t0));
  predictor.Observe(Looking({0, 0, 0}, Yaw(0)), t0);
  EXPECT_FALSE(predictor.Predict(t0));  // one view: no velocity
  // Two views 3 s apart: the motion between them says nothing about now.
  predictor.Observe(Looking({1, 0, 0}, Yaw(0)), t0 + 3s);
  EXPECT_FALSE(predictor.Predict(t0 + 3s));
  predictor.Observe(Looking({1.1f, 0, 0}, Yaw(0)), t0 + 3100ms);
  EXPECT_TRUE(predictor.Predict(t0 + 3100ms));
  EXPECT_TRUE(predictor.Predict(t0 + 5000ms));
  // ... but judged over 2 s after the latest view: the client has stopped sending.
  EXPECT_FALSE(predictor.Predict(t0 + 5200ms));
}

TEST(CameraPrediction, ErraticHistoryPredictsNothing) {
  const Clock::time_point t0{};
  {  // Back and forth: the direction of travel reversed.
    CameraPredictor predictor;
    predictor.Observe(Looking({0, 0, 0}, Yaw(0)), t0);
    predictor.Observe(Looking({0.2f, 0, 0}, Yaw(0)), t0 + 100ms);
    predictor.Observe(Looking({0.0f, 0, 0}, Yaw(0)), t0 + 200ms);
    EXPECT_FALSE(predictor.Predict(t0 + 200ms));
  }
  {  // Turned 120 degrees in 0.1 s: a jump, not a turn to extrapolate.
    CameraPredictor predictor({.maxTurnPerSecond = 6.3});
    predictor.Observe(Looking({0, 0, 0}, Yaw(0)), t0);
    predictor.Observe(Looking({0, 0, 0}, Yaw(120)), t0 + 100ms);
    EXPECT_FALSE(predictor.Predict(t0 + 100ms));
  }
  {  // Views out of order clear the history.
    CameraPredictor predictor;
    predictor.Observe(Looking({0, 0, 0}, Yaw(0)), t0 + 1s);
    predictor.Observe(Looking({0.1f, 0, 0}, Yaw(0)), t0);
    EXPECT_EQ(predictor.Views(), 1u);
    EXPECT_FALSE(predictor.Predict(t0));
  }
}

TEST(CameraPrediction, APredictionFarBeyondAnySceneIsRefused) {
  CameraPredictor predictor({.horizon = 10s, .maxGap = 100s, .maxAge = 100s});
  const Clock::time_point t0{};
  predictor.Observe(Looking({0, 0, 0}, Yaw(0)), t0);
  predictor.Observe(Looking({9.0e8f, 0, 0}, Yaw(0)), t0 + 1ms);
  EXPECT_FALSE(predictor.Predict(t0 + 1ms));
}

}  // namespace
}  // namespace penumbra::sma
