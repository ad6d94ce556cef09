#pragma once
// Scripted cameras for headless runs: camera paths (common/camera.h) played
// in real time, loaded from a camera-path file or from a scene file's named
// path, or a still view made from one of the SMA's camera presets.

#include <chrono>
#include <string>
#include <string_view>

#include "penumbra/common/camera.h"
#include "penumbra/common/expected.h"

namespace penumbra::client {

/// Loads `spec`: "FILE.json" is a camera-path file (ParseCameraPathJson's
/// format); "FILE.json#NAME" is the path NAME in the "paths" object of a
/// scene file (docs/scenes.md), e.g. "scenes/sponza.json#walk".
Expected<CameraPath> LoadCameraPathSpec(std::string_view spec);

/// A one-keyframe path holding a camera preset (ClientScene::cameras) at width x height.
CameraPath StillPath(const CameraPreset& preset, int width, int height);

/// Plays a path from its first keyframe, in seconds since the start.
class PathPlayer {
 public:
  /// `path` must have at least one keyframe (every loader ensures it).
  explicit PathPlayer(CameraPath path);

  /// The view `elapsed` after the start; the last keyframe's once past the end.
  CameraView ViewAt(std::chrono::duration<double> elapsed) const;
  /// True once `elapsed` has reached the end (at once for a still path).
  bool Finished(std::chrono::duration<double> elapsed) const;
  const CameraPath& Path() const { return path_; }

 private:
  CameraPath path_;
};

}  // namespace penumbra::client
