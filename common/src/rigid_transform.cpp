#include "penumbra/common/rigid_transform.h"

#include <fmt/format.h>

#include <cmath>
#include <glm/gtc/quaternion.hpp>

namespace penumbra {

RigidTransform RigidTransform::FromAxisAngle(const Vec3& axis, float angleRad, const Vec3& translation) {
  return RigidTransform{glm::mat3_cast(glm::angleAxis(angleRad, glm::normalize(axis))), translation};
}

Expected<RigidTransform> RigidTransform::FromRowMajor(std::span<const float> m) {
  if (m.size() != 12) return Fail(fmt::format("a transform has 12 numbers (3x4, row-major), not {}", m.size()));
  for (size_t i = 0; i < 12; ++i)
    if (!std::isfinite(m[i])) return Fail(fmt::format("transform entry {} is not finite", i));
  RigidTransform t;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) t.rotation[c][r] = m[4 * r + c];
    t.translation[r] = m[4 * r + 3];
  }
  constexpr float kMaxTranslation = 1e7f;
  if (std::abs(t.translation.x) > kMaxTranslation || std::abs(t.translation.y) > kMaxTranslation ||
      std::abs(t.translation.z) > kMaxTranslation)
    return Fail(fmt::format("translation ({}, {}, {}) is beyond {}", t.translation.x, t.translation.y,
                            t.translation.z, kMaxTranslation));
  const glm::mat3 gram = glm::transpose(t.rotation) * t.rotation;
  float worst = 0.0f;
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) worst = std::max(worst, std::abs(gram[c][r] - (r == c ? 1.0f : 0.0f)));
  const float det = glm::determinant(t.rotation);
  if (worst > kRigidTolerance || std::abs(det - 1.0f) > kRigidTolerance)
    return Fail(fmt::format("the 3x3 part is not a rotation (R^T R differs from I by {:.3g}, det {:.6g}): only rigid "
                            "moves are allowed, no scale, shear, mirror or collapse",
                            worst, det));
  // Re-orthonormalise through the quaternion, so composed moves never drift.
  t.rotation = glm::mat3_cast(glm::normalize(glm::quat_cast(t.rotation)));
  return t;
}

std::array<float, 12> RigidTransform::ToRowMajor() const {
  std::array<float, 12> m{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m[4 * r + c] = rotation[c][r];
    m[4 * r + 3] = translation[r];
  }
  return m;
}

RigidTransform RigidTransform::Inverse() const {
  const glm::mat3 inverseRotation = glm::transpose(rotation);
  return RigidTransform{inverseRotation, -(inverseRotation * translation)};
}

RigidTransform RigidTransform::Compose(const RigidTransform& other) const {
  return RigidTransform{rotation * other.rotation, rotation * other.translation + translation};
}

Bounds3 RigidTransform::ApplyBounds(const Bounds3& box) const {
  Bounds3 out;
  if (box.Empty()) return out;
  for (int corner = 0; corner < 8; ++corner)
    out.Extend(ApplyPoint(Vec3(corner & 1 ? box.max.x : box.min.x, corner & 2 ? box.max.y : box.min.y,
                               corner & 4 ? box.max.z : box.min.z)));
  return out;
}

RigidTransform Interpolate(const RigidTransform& a, const RigidTransform& b, float s) {
  const glm::quat qa = glm::quat_cast(a.rotation), qb = glm::quat_cast(b.rotation);
  return RigidTransform{glm::mat3_cast(glm::slerp(qa, qb, s)), a.translation + s * (b.translation - a.translation)};
}

bool NearlyEqual(const RigidTransform& a, const RigidTransform& b, float tolerance) {
  const auto ma = a.ToRowMajor(), mb = b.ToRowMajor();
  for (size_t i = 0; i < ma.size(); ++i)
    if (!(std::abs(ma[i] - mb[i]) <= tolerance)) return false;
  return true;
}

std::string Describe(const RigidTransform& t) {
  const glm::quat q = glm::normalize(glm::quat_cast(t.rotation));
  const float angle = glm::degrees(glm::angle(q));
  const Vec3 axis = angle > 1e-3f ? glm::axis(q) : Vec3(0.0f, 1.0f, 0.0f);
  return fmt::format("translate ({:.4g}, {:.4g}, {:.4g}), rotate {:.3g} deg about ({:.3g}, {:.3g}, {:.3g})",
                     t.translation.x, t.translation.y, t.translation.z, angle, axis.x, axis.y, axis.z);
}

}  // namespace penumbra
