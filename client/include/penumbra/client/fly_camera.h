#pragma once
// The walkthrough camera: a position and a heading (yaw about the world's up
// axis, pitch toward it), moved by keys and turned by the mouse. It produces
// CameraPoses in the conventions of common/camera.h. Pure math, no GL, no
// window; owned by the render thread.

#include "penumbra/common/camera.h"
#include "penumbra/common/math.h"

namespace penumbra::client {

/// Movement wanted this frame, each axis in [-1, 1] (keys held).
struct MoveInput {
  float forward = 0.0f;  // + along the view direction
  float right = 0.0f;    // + to the camera's right
  float up = 0.0f;       // + along the world's up axis
};

class FlyCamera {
 public:
  /// Pitch stays this far (radians) from straight up or down, so the view
  /// direction never becomes parallel to up.
  static constexpr float kMaxPitch = 1.5533f;  // 89 degrees

  /// Places the camera at `pose`: `pose.up` becomes the world's up axis for
  /// turning; the heading is the pose's view direction (its pitch clamped).
  void SetPose(const CameraPose& pose);
  /// Eye, a target one unit ahead, and the world up.
  CameraPose Pose() const;

  /// Turns by a mouse motion in pixels (x right, y down, as windows report
  /// it): moving right turns right, moving down looks down.
  void Turn(float dxPixels, float dyPixels, float radiansPerPixel);
  /// Moves by `input` at `speed` world units per second for `seconds`.
  void Move(const MoveInput& input, float speed, float seconds);

  float Yaw() const { return yaw_; }
  float Pitch() const { return pitch_; }
  Vec3 Forward() const;
  Vec3 Right() const;

 private:
  Vec3 eye_{0.0f};
  Vec3 up_{0.0f, 1.0f, 0.0f};   // unit world up
  Vec3 north_{0.0f, 0.0f, -1.0f};  // unit, perpendicular to up_: the heading at yaw 0
  float yaw_ = 0.0f;    // radians, positive turns right
  float pitch_ = 0.0f;  // radians, positive looks up
};

}  // namespace penumbra::client
