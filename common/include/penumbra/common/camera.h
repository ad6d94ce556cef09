#pragma once
// Camera conventions shared by every tier (SMA visibility, GL client,
// reference renderer), so that one camera path means one image everywhere.
//
// World space is right-handed. A camera looks from `eye` toward `target`;
// `up` need not be orthogonal to the view direction. Pixel (0,0) is the
// top-left corner of the image; pixel centres are at (x + 0.5, y + 0.5).
// The vertical field of view spans the image height.

#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"

namespace penumbra {

struct CameraPose {
  Vec3 eye{0.0f, 0.0f, 1.0f};
  Vec3 target{0.0f};
  Vec3 up{0.0f, 1.0f, 0.0f};
};

/// What a client sends the SMA and what a renderer of images needs: where the
/// camera is and how many pixels it has.
struct CameraView {
  CameraPose pose;
  float fovYDeg = 45.0f;
  int width = 640;
  int height = 480;
};

/// The largest |coordinate| a camera's eye, target or up may have: far
/// beyond any scene (metres), far below where Embree's ray arithmetic or
/// eye - target overflow.
inline constexpr float kMaxCameraCoordinate = 1.0e9f;

/// Checks that a view is usable: finite, every coordinate within
/// +-kMaxCameraCoordinate, eye != target, up not parallel to the
/// view direction, 1 <= fov <= 179 degrees, 1 <= width,height <= 16384.
Status ValidateCameraView(const CameraView& view);

/// A pinhole camera derived from a CameraView, for generating primary rays.
class PinholeCamera {
 public:
  explicit PinholeCamera(const CameraView& view);

  /// World-space unit direction through image position (px, py) in pixels,
  /// measured from the top-left corner (pixel centres at +0.5).
  Vec3 DirectionThrough(float px, float py) const;
  /// Where world point `p` appears, in DirectionThrough's pixel coordinates
  /// (DirectionThrough(PixelOf(p)) points at p), inside the image or not;
  /// nullopt for a point not in front of the camera.
  std::optional<Vec2> PixelOf(const Vec3& p) const;
  /// The side of one pixel at `depth` along Forward(), in world units.
  float PixelSizeAt(float depth) const { return 2.0f * depth * tanHalfFovY_ / float(height_); }
  const Vec3& Origin() const { return origin_; }
  const Vec3& Forward() const { return forward_; }
  const Vec3& Right() const { return right_; }
  const Vec3& Up() const { return up_; }
  int Width() const { return width_; }
  int Height() const { return height_; }

 private:
  Vec3 origin_, forward_, right_, up_;
  float tanHalfFovY_, aspect_;
  int width_, height_;
};

/// A named still view from a scene file.
struct CameraPreset {
  std::string name;
  CameraPose pose;
  float fovYDeg = 45.0f;
};

struct CameraKeyframe {
  double timeSeconds = 0.0;
  CameraPose pose;
};

/// A camera path: keyframes in increasing time, poses interpolated linearly
/// between them (eye, target and up each). A single keyframe is a still view.
/// Where the interpolated view direction passes (nearly) through the
/// interpolated up -- a path that tilts from looking down one way to looking
/// down the other crosses the vertical -- up is taken perpendicular to the
/// view, from the segment's first keyframe's right vector: every pose of a
/// path is a valid view (ValidateCameraView), never a degenerate one.
struct CameraPath {
  std::string name;
  float fovYDeg = 45.0f;
  int width = 640;
  int height = 480;
  std::vector<CameraKeyframe> keyframes;

  double DurationSeconds() const;
  /// Pose at time t, clamped to [0, duration]. Requires at least one keyframe.
  CameraPose PoseAt(double timeSeconds) const;
  CameraView ViewAt(double timeSeconds) const;
};

/// Parses the camera-path JSON documented in docs/scenes.md:
/// {"fov_y_deg": 40, "width": 640, "height": 480,
///  "keyframes": [{"t": 0.0, "eye": [x,y,z], "target": [x,y,z], "up": [x,y,z]}, ...]}
/// `sourceName` prefixes every error message.
Expected<CameraPath> ParseCameraPathJson(std::string_view text, std::string_view sourceName);
Expected<CameraPath> LoadCameraPath(const std::filesystem::path& path);

}  // namespace penumbra
