#include "penumbra/client/fly_camera.h"

#include <algorithm>
#include <cmath>

namespace penumbra::client {

namespace {

// A unit vector perpendicular to unit `up`, for when the view looks straight
// along it and gives no heading.
Vec3 AnyPerpendicular(const Vec3& up) {
  const Vec3 axis = std::abs(up.x) < 0.9f ? Vec3(1.0f, 0.0f, 0.0f) : Vec3(0.0f, 0.0f, 1.0f);
  return glm::normalize(glm::cross(up, axis));
}

}  // namespace

void FlyCamera::SetPose(const CameraPose& pose) {
  eye_ = pose.eye;
  up_ = glm::length(pose.up) > 0.0f ? glm::normalize(pose.up) : Vec3(0.0f, 1.0f, 0.0f);
  const Vec3 view = pose.target - pose.eye;
  const Vec3 forward = glm::length(view) > 0.0f ? glm::normalize(view) : -AnyPerpendicular(up_);
  const Vec3 horizontal = forward - glm::dot(forward, up_) * up_;
  north_ = glm::length(horizontal) > 1e-6f ? glm::normalize(horizontal) : AnyPerpendicular(up_);
  yaw_ = 0.0f;
  pitch_ = std::clamp(std::asin(std::clamp(glm::dot(forward, up_), -1.0f, 1.0f)), -kMaxPitch, kMaxPitch);
}

Vec3 FlyCamera::Right() const {
  // Right-handed: forward x up points right.
  const Vec3 east = glm::cross(north_, up_);
  return std::cos(yaw_) * east - std::sin(yaw_) * north_;
}

Vec3 FlyCamera::Forward() const {
  const Vec3 east = glm::cross(north_, up_);
  const Vec3 heading = std::cos(yaw_) * north_ + std::sin(yaw_) * east;
  return std::cos(pitch_) * heading + std::sin(pitch_) * up_;
}

CameraPose FlyCamera::Pose() const { return CameraPose{eye_, eye_ + Forward(), up_}; }

void FlyCamera::Turn(float dxPixels, float dyPixels, float radiansPerPixel) {
  yaw_ = std::remainder(yaw_ + dxPixels * radiansPerPixel, 2.0f * kPi);
  pitch_ = std::clamp(pitch_ - dyPixels * radiansPerPixel, -kMaxPitch, kMaxPitch);
}

void FlyCamera::Move(const MoveInput& input, float speed, float seconds) {
  const Vec3 direction = input.forward * Forward() + input.right * Right() + input.up * up_;
  const float length = glm::length(direction);
  if (length <= 0.0f) return;
  // Diagonal movement is no faster than straight movement.
  eye_ += direction / std::max(length, 1.0f) * speed * seconds;
}

}  // namespace penumbra::client
