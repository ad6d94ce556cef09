#include "penumbra/client/object_moves.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace penumbra::client {

std::optional<float> RayBoxDistance(const Ray& ray, const Bounds3& box) {
  if (box.Empty()) return std::nullopt;
  // Slabs; a zero direction component gives +-inf, which the comparisons handle.
  float tNear = 0.0f, tFar = std::numeric_limits<float>::infinity();
  for (int axis = 0; axis < 3; ++axis) {
    const float o = ray.origin[axis], d = ray.direction[axis];
    if (d == 0.0f) {
      if (o < box.min[axis] || o > box.max[axis]) return std::nullopt;
      continue;
    }
    float t0 = (box.min[axis] - o) / d, t1 = (box.max[axis] - o) / d;
    if (t0 > t1) std::swap(t0, t1);
    tNear = std::max(tNear, t0);
    tFar = std::min(tFar, t1);
    if (tNear > tFar) return std::nullopt;
  }
  return tNear;
}

std::optional<float> RayTriangleDistance(const Ray& ray, const Vec3& a, const Vec3& b, const Vec3& c) {
  // Moller-Trumbore, both faces.
  const Vec3 e1 = b - a, e2 = c - a;
  const Vec3 p = glm::cross(ray.direction, e2);
  const float det = glm::dot(e1, p);
  if (std::abs(det) < 1e-12f) return std::nullopt;
  const float inv = 1.0f / det;
  const Vec3 s = ray.origin - a;
  const float u = glm::dot(s, p) * inv;
  if (u < 0.0f || u > 1.0f) return std::nullopt;
  const Vec3 q = glm::cross(s, e1);
  const float v = glm::dot(ray.direction, q) * inv;
  if (v < 0.0f || u + v > 1.0f) return std::nullopt;
  const float t = glm::dot(e2, q) * inv;
  if (!(t > 0.0f)) return std::nullopt;
  return t;
}

std::optional<ObjectPick> PickObjectBounds(const Ray& ray, std::span<const Bounds3> worldBounds) {
  std::optional<ObjectPick> best;
  for (size_t i = 0; i < worldBounds.size(); ++i) {
    const auto t = RayBoxDistance(ray, worldBounds[i]);
    if (t && (!best || *t < best->distance))
      best = ObjectPick{uint32_t(i + 1), *t, ray.origin + *t * ray.direction};
  }
  return best;
}

std::optional<ObjectPick> PickHeldTriangle(const Ray& ray, const MeshStore& mesh) {
  std::optional<ObjectPick> best;
  const std::span<const GpuVertex> vertices = mesh.VertexSlots();
  for (const TriangleGroup& group : mesh.Groups()) {
    const uint32_t used = group.allocator.HighWater();
    for (uint32_t slot = 0; slot < used; ++slot) {
      const GpuTriangle& t = group.slots[slot];
      if (t.corners[0].material == kEmptyTriangleSlot) continue;
      const auto distance =
          RayTriangleDistance(ray, mesh.WorldPositionOfSlot(t.corners[0].vertexSlot),
                              mesh.WorldPositionOfSlot(t.corners[1].vertexSlot),
                              mesh.WorldPositionOfSlot(t.corners[2].vertexSlot));
      if (distance && (!best || *distance < best->distance))
        best = ObjectPick{uint32_t(vertices[t.corners[0].vertexSlot].position[3]), *distance,
                          ray.origin + *distance * ray.direction};
    }
  }
  return best;
}

ObjectDrag::ObjectDrag(uint32_t object, const RigidTransform& start, const Vec3& grab, const Vec3& viewDirection)
    : object_(object), start_(start), grab_(grab), normal_(glm::normalize(viewDirection)), last_(start) {}

RigidTransform ObjectDrag::At(const Ray& ray) {
  // The plane: points x with dot(normal, x) = dot(normal, grab) + depth.
  const float denominator = glm::dot(normal_, ray.direction);
  if (std::abs(denominator) < 1e-6f) return last_;
  const float t = (glm::dot(normal_, grab_) + depth_ - glm::dot(normal_, ray.origin)) / denominator;
  if (!(t > 0.0f) || !std::isfinite(t)) return last_;
  const Vec3 point = ray.origin + t * ray.direction;
  last_ = RigidTransform{start_.rotation, start_.translation + (point - grab_)};
  return last_;
}

std::optional<MoveThrottle::Pending> MoveThrottle::Due(Clock::time_point now, bool flush) {
  if (!pending_) return std::nullopt;
  if (!flush && lastSent_ && now - *lastSent_ < interval_) return std::nullopt;
  lastSent_ = now;
  return std::exchange(pending_, std::nullopt);
}

void MoveTracker::Sent(uint32_t object, const RigidTransform& t, uint64_t requestId, Clock::time_point now) {
  pending_[object] = Entry{t, requestId, now};
  ++sentCount_;
}

void MoveTracker::Confirm(const MeshStore& mesh) {
  std::erase_if(pending_, [&](const auto& entry) {
    return NearlyEqual(mesh.ConfirmedTransform(entry.first), entry.second.transform, kMoveConfirmTolerance);
  });
}

uint32_t MoveTracker::Refused(uint64_t requestId) {
  for (auto it = pending_.begin(); it != pending_.end(); ++it) {
    if (it->second.requestId != requestId) continue;
    const uint32_t object = it->first;
    pending_.erase(it);
    return object;
  }
  return 0;
}

std::vector<uint32_t> MoveTracker::Expire(Clock::time_point now, Clock::duration timeout) {
  std::vector<uint32_t> expired;
  std::erase_if(pending_, [&](const auto& entry) {
    if (now - entry.second.sentAt <= timeout) return false;
    expired.push_back(entry.first);
    return true;
  });
  return expired;
}

std::optional<RigidTransform> MoveTracker::LastSent(uint32_t object) const {
  auto it = pending_.find(object);
  if (it == pending_.end()) return std::nullopt;
  return it->second.transform;
}

}  // namespace penumbra::client
