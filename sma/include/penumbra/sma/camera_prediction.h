#pragma once
// Camera movement prediction (issue 15, part 3; Schöffel & Pomi §3.2): where
// a client's camera will be a short time ahead, extrapolated linearly from
// its recent views, so the SMA can shade what that view will need while the
// renderers have nothing more urgent to do.
//
// The paper extrapolates the transform of a moved object from its last two
// positions (t_0 = c_0 - c_-1, added once per frame ahead) and scales the
// predicted box by s in (1, 1.2] to absorb the prediction's error. Here the
// "object" is the camera: from the last two views (and the times they
// arrived) we get a linear velocity of the eye and an angular velocity of the
// orientation (the rotation between the two camera frames, as an axis and an
// angle per second); both are applied for `horizon` after the latest view,
// and the predicted field of view is widened so that its half-angle tangent
// is `widen` times larger (the frustum's counterpart of scaling the box).
//
// What it refuses to predict (no prediction: nothing is prepared):
//  * fewer than two views, or views arriving out of order;
//  * two views further apart than `maxGap`, or a latest view older than
//    `maxAge` on the caller's clock (a client that stopped moving sends no
//    views): the history says nothing about now;
//  * erratic motion: with a third view, the eye's direction of travel turned
//    by more than 90 degrees between the two intervals, or the camera turned
//    faster than `maxTurnPerSecond` (a jump, not a walk).
// A camera at rest (eye and orientation unchanged within a small tolerance)
// predicts itself: `atRest` is set and there is nothing extra to prepare.
//
// Plain code, no clock of its own (times are passed in), no locks: one per
// client session, used on its strand. Unit-tested in
// sma/tests/camera_prediction_test.cpp.

#include <chrono>
#include <cstddef>
#include <deque>
#include <optional>

#include "penumbra/common/camera.h"

namespace penumbra::sma {

struct CameraPredictionOptions {
  std::chrono::duration<double> horizon{0.5};  // how far ahead of the latest view
  double widen = 1.15;                         // predicted half-fov tangent x this (the paper's s)
  std::chrono::duration<double> maxGap{1.0};   // views further apart predict nothing
  std::chrono::duration<double> maxAge{3.0};   // nor a latest view this old when asked
  double maxTurnPerSecond = 6.2831853;         // faster turning is a jump: nothing predicted (rad/s)
  double restDistance = 1e-4;                  // eye moved less (scene units) ...
  double restAngle = 1e-4;                     // ... and turned less (rad) between views: at rest
};

/// A predicted view: the camera `horizon` after the latest view, widened.
struct PredictedView {
  CameraView view;      // pose extrapolated, fovYDeg widened, the latest view's resolution
  bool atRest = false;  // the camera did not move: `view` is the latest view itself (not widened)
};

class CameraPredictor {
 public:
  using Clock = std::chrono::steady_clock;

  explicit CameraPredictor(CameraPredictionOptions options = {}) : options_(options) {}

  /// A view the client sent, with the time it arrived. Views must have passed
  /// ValidateCameraView. A view arriving before the last one clears the history.
  void Observe(const CameraView& view, Clock::time_point arrived);
  /// The view expected `horizon` after the latest one, judged at `now`;
  /// nullopt when the history predicts nothing (see the header comment).
  std::optional<PredictedView> Predict(Clock::time_point now) const;
  /// Forgets every view.
  void Clear() { history_.clear(); }
  size_t Views() const { return history_.size(); }

 private:
  struct Observed {
    CameraView view;
    Clock::time_point arrived;
  };
  CameraPredictionOptions options_;
  std::deque<Observed> history_;  // at most three, oldest first
};

/// `fovYDeg` widened so that tan(fov/2) grows by `widen`, clamped to 179 degrees.
float WidenFovY(float fovYDeg, double widen);

}  // namespace penumbra::sma
