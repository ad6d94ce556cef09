#include "penumbra/sma/camera_prediction.h"

#include <algorithm>
#include <cmath>

#include <glm/gtc/quaternion.hpp>
#include <glm/mat3x3.hpp>

namespace penumbra::sma {

namespace {

// The camera's orientation as a rotation from camera space (x right, y up,
// looking down -z, as in PinholeCamera) to world space.
glm::quat Orientation(const CameraPose& pose) {
  const Vec3 forward = glm::normalize(pose.target - pose.eye);
  const Vec3 right = glm::normalize(glm::cross(forward, pose.up));
  const Vec3 up = glm::cross(right, forward);
  return glm::normalize(glm::quat_cast(glm::mat3(right, up, -forward)));
}

// The rotation taking frame `from` to frame `to` (world space), as an axis
// and an angle in [0, pi].
struct AxisAngle {
  Vec3 axis{0.0f, 1.0f, 0.0f};
  double angle = 0.0;
};
AxisAngle Turn(const glm::quat& from, const glm::quat& to) {
  glm::quat delta = glm::normalize(to * glm::inverse(from));
  if (delta.w < 0.0f) delta = -delta;  // the short way round
  AxisAngle out;
  const float s = std::sqrt(std::max(0.0f, 1.0f - delta.w * delta.w));
  out.angle = 2.0 * std::acos(std::clamp(double(delta.w), -1.0, 1.0));
  if (s > 1e-7f) out.axis = Vec3(delta.x, delta.y, delta.z) / s;
  else out.angle = 0.0;
  return out;
}

double Seconds(CameraPredictor::Clock::duration d) { return std::chrono::duration<double>(d).count(); }

}  // namespace

float WidenFovY(float fovYDeg, double widen) {
  const double half = double(fovYDeg) * 0.5 * double(kPi) / 180.0;
  const double widened = 2.0 * std::atan(std::tan(half) * std::max(1.0, widen)) * 180.0 / double(kPi);
  return float(std::min(widened, 179.0));
}

void CameraPredictor::Observe(const CameraView& view, Clock::time_point arrived) {
  if (!history_.empty() && arrived < history_.back().arrived) history_.clear();
  history_.push_back({view, arrived});
  while (history_.size() > 3) history_.pop_front();
}

std::optional<PredictedView> CameraPredictor::Predict(Clock::time_point now) const {
  if (history_.size() < 2) return std::nullopt;
  const Observed& latest = history_.back();
  const Observed& before = history_[history_.size() - 2];
  const double dt = Seconds(latest.arrived - before.arrived);
  if (!(dt > 0.0) || dt > options_.maxGap.count() || Seconds(now - latest.arrived) > options_.maxAge.count())
    return std::nullopt;

  const CameraPose& p0 = before.view.pose;
  const CameraPose& p1 = latest.view.pose;
  const Vec3 moved = p1.eye - p0.eye;
  const glm::quat q1 = Orientation(p1);
  const AxisAngle turn = Turn(Orientation(p0), q1);
  if (turn.angle / dt > options_.maxTurnPerSecond) return std::nullopt;
  if (history_.size() == 3) {
    // A reversal of the direction of travel: the walk is not a line.
    const Vec3 movedBefore = p0.eye - history_[0].view.pose.eye;
    if (glm::length(movedBefore) > options_.restDistance && glm::length(moved) > options_.restDistance &&
        glm::dot(movedBefore, moved) < 0.0f)
      return std::nullopt;
  }
  if (glm::length(moved) < options_.restDistance && turn.angle < options_.restAngle)
    return PredictedView{latest.view, true};

  const double ahead = options_.horizon.count() / dt;  // intervals ahead of the latest view
  PredictedView out;
  out.view = latest.view;
  CameraPose& pose = out.view.pose;
  pose.eye = p1.eye + moved * float(ahead);
  const glm::quat spin = glm::angleAxis(float(turn.angle * ahead), turn.axis);
  const glm::quat q = glm::normalize(spin * q1);
  const float distance = glm::length(p1.target - p1.eye);
  pose.target = pose.eye + (q * Vec3(0.0f, 0.0f, -1.0f)) * distance;
  pose.up = q * Vec3(0.0f, 1.0f, 0.0f);
  out.view.fovYDeg = WidenFovY(latest.view.fovYDeg, options_.widen);
  // Far beyond any scene or otherwise unusable: predict nothing.
  if (!ValidateCameraView(out.view)) return std::nullopt;
  return out;
}

}  // namespace penumbra::sma
