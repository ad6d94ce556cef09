#pragma once
// RigidTransform: a rotation followed by a translation, the only motion a
// movable object may make (issue 14). Rigid, so lengths, angles, areas and
// barycentric coordinates are the same in object space and in world space:
// an object's subdivision hierarchy and its samples' places on it travel with
// it unchanged, and only the points where they are shaded move.
//
// On the wire and in scene files a transform is 12 floats, a 3x4 matrix in
// row-major order: rows (r00 r01 r02 tx), (r10 r11 r12 ty), (r20 r21 r22 tz).

#include <array>
#include <span>
#include <string>

#include <glm/mat3x3.hpp>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"

namespace penumbra {

/// Largest deviation of R^T R from the identity (and of det R from 1) that
/// FromMatrix accepts: a matrix written by hand with 6 decimal places, or
/// composed from a few float rotations, passes; a scale of 1.001 does not.
inline constexpr float kRigidTolerance = 1e-4f;

struct RigidTransform {
  glm::mat3 rotation{1.0f};  // column-major (glm): rotation[c][r]
  Vec3 translation{0.0f};

  static RigidTransform Identity() { return {}; }
  /// Rotation of `angleRad` about the unit `axis`, then the translation.
  static RigidTransform FromAxisAngle(const Vec3& axis, float angleRad, const Vec3& translation);
  /// From 12 row-major floats (see the file comment). Fails with a message
  /// naming the problem for a non-finite entry, a matrix that is not a
  /// rotation within kRigidTolerance (scale, shear, mirror, degenerate) or a
  /// translation beyond 1e7. The rotation is re-orthonormalised.
  static Expected<RigidTransform> FromRowMajor(std::span<const float> m12);
  std::array<float, 12> ToRowMajor() const;

  Vec3 ApplyPoint(const Vec3& p) const { return rotation * p + translation; }
  Vec3 ApplyVector(const Vec3& v) const { return rotation * v; }  // directions and normals alike
  RigidTransform Inverse() const;
  /// this * other: apply `other` first, then this.
  RigidTransform Compose(const RigidTransform& other) const;
  /// Bounding box of `box` (in this transform's source frame) after the transform.
  Bounds3 ApplyBounds(const Bounds3& box) const;
  /// Componentwise equality (used to skip moves that change nothing).
  bool operator==(const RigidTransform& other) const = default;
};

/// Interpolates between two rigid transforms at s in [0, 1]: translation
/// linearly, rotation by quaternion slerp (the shortest way round).
RigidTransform Interpolate(const RigidTransform& a, const RigidTransform& b, float s);

/// Whether two transforms place things within `tolerance` of each other
/// (every matrix entry and translation component; NaN is never near).
bool NearlyEqual(const RigidTransform& a, const RigidTransform& b, float tolerance);

/// How far a client's move and the SMA's MOVED may differ and still be the
/// same move: the client holds a move it sent as pending until a MOVED puts
/// the object within this of it (NearlyEqual) -- the SMA may coalesce moves
/// and re-orthonormalises rotations --, and the SMA places a client's move at
/// its prediction only within it (sma/move_prediction.h). Scene units.
inline constexpr float kMoveConfirmTolerance = 1e-3f;

/// "translate (x, y, z), rotate a deg about (ax, ay, az)" for logs and errors.
std::string Describe(const RigidTransform& t);

}  // namespace penumbra
