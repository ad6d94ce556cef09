#pragma once
// Moving objects from the client (issue 14): picking an object under the
// cursor, dragging it in a plane parallel to the image, sending at most
// ~30 moves a second while dragging, and knowing when the SMA has confirmed
// (MOVED) or refused the last move sent. No GL and no network here: the
// window's drag mode and the headless moves script both use these, and the
// unit tests check them with made-up rays, meshes and clocks.
//
// Display policy: optimistic. While an object is dragged, and after that
// until the SMA confirms the last transform sent (its MOVED comes back to
// the mover too) or refuses it, the client draws the object where it sent
// it (MeshStore::SetLocalTransform): the object follows the mouse at the
// frame rate instead of one round trip (plus the SMA's coalescing) behind,
// and its own radiance travels with it (object space). Shadows and other
// lighting follow as RESHADED deltas arrive. A refused move snaps back.
//
// Threads: render thread; plain values.

#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <span>
#include <vector>

#include "penumbra/client/mesh_store.h"
#include "penumbra/common/math.h"
#include "penumbra/common/rigid_transform.h"

namespace penumbra::client {

struct Ray {
  Vec3 origin{0.0f};
  Vec3 direction{0.0f, 0.0f, -1.0f};  // unit
};

/// Distance along `ray` to where it enters `box` (0 when it starts inside),
/// or nullopt when it misses (or the box is empty).
std::optional<float> RayBoxDistance(const Ray& ray, const Bounds3& box);

/// Distance along `ray` to triangle (a, b, c), either side, or nullopt.
std::optional<float> RayTriangleDistance(const Ray& ray, const Vec3& a, const Vec3& b, const Vec3& c);

struct ObjectPick {
  uint32_t object = 0;   // id, 1..N (0: the static part)
  float distance = 0.0f;
  Vec3 point{0.0f};      // world space, where the ray meets it
};

/// The nearest of `worldBounds` (object id i + 1 at index i) the ray
/// enters, or nullopt when it misses them all.
std::optional<ObjectPick> PickObjectBounds(const Ray& ray, std::span<const Bounds3> worldBounds);

/// The nearest held triangle the ray hits, as drawn (objects at their
/// displayed transforms), with its object (0 when the nearest surface is
/// static: a wall in front of the object hides it). O(held triangles): for a
/// click, not per frame.
std::optional<ObjectPick> PickHeldTriangle(const Ray& ray, const MeshStore& mesh);

/// One drag of an object: the grab point moves in the plane through it
/// perpendicular to the view direction (parallel to the image plane), and
/// `depth` moves that plane along the view direction.
class ObjectDrag {
 public:
  /// Starts dragging `object`, now at `start`, grabbed at world point `grab`,
  /// seen along the unit `viewDirection`.
  ObjectDrag(uint32_t object, const RigidTransform& start, const Vec3& grab, const Vec3& viewDirection);

  uint32_t Object() const { return object_; }
  /// Moves the drag plane `amount` scene units along the view direction (away: positive).
  void Push(float amount) { depth_ += amount; }
  /// The object's transform when the cursor's ray is `ray`: translated so the
  /// grab point lies where the ray meets the drag plane, rotation unchanged.
  /// A ray parallel to the plane (or meeting it behind the eye) keeps the
  /// last transform.
  RigidTransform At(const Ray& ray);

 private:
  uint32_t object_;
  RigidTransform start_;
  Vec3 grab_;
  Vec3 normal_;
  float depth_ = 0.0f;
  RigidTransform last_;
};

/// Coalesces a stream of transforms (one per frame while dragging) into at
/// most one send per interval: Offer() keeps only the latest; Due() hands it
/// out once the interval since the last send has passed.
class MoveThrottle {
 public:
  using Clock = std::chrono::steady_clock;
  explicit MoveThrottle(Clock::duration interval = std::chrono::milliseconds(33)) : interval_(interval) {}

  void Offer(uint32_t object, const RigidTransform& t) { pending_ = Pending{object, t}; }
  struct Pending {
    uint32_t object = 0;
    RigidTransform transform;
  };
  /// The latest offer not yet sent, when the interval has passed (or
  /// `flush`: the drag ended, send the last one now); it is then sent.
  std::optional<Pending> Due(Clock::time_point now, bool flush = false);

 private:
  Clock::duration interval_;
  std::optional<Pending> pending_;
  std::optional<Clock::time_point> lastSent_;
};

/// Moves this client sent and the SMA has not yet confirmed or refused.
/// Confirmation is by value: the SMA may coalesce several moves into one
/// MOVED, re-orthonormalises rotations and may place a steady drag's move at
/// its prediction, so an object is settled when its confirmed transform is
/// within kMoveConfirmTolerance (rigid_transform.h) of the last one sent.
/// A move neither confirmed nor refused this long after it was sent is
/// given up on (another client's move of the same object may have won the
/// SMA's coalescing, so ours never comes back as sent).
inline constexpr std::chrono::seconds kMovePendingTimeout{5};

class MoveTracker {
 public:
  using Clock = std::chrono::steady_clock;
  void Sent(uint32_t object, const RigidTransform& t, uint64_t requestId, Clock::time_point now = Clock::now());
  /// Drops the objects whose confirmed transform in `mesh` matches the last one sent.
  void Confirm(const MeshStore& mesh);
  /// Drops the object whose last request is `requestId`; returns it (0: none).
  uint32_t Refused(uint64_t requestId);
  /// Drops moves sent more than `timeout` before `now`; returns their objects.
  std::vector<uint32_t> Expire(Clock::time_point now, Clock::duration timeout = kMovePendingTimeout);
  bool Pending(uint32_t object) const { return pending_.contains(object); }
  /// The last transform sent for `object`, while pending.
  std::optional<RigidTransform> LastSent(uint32_t object) const;
  bool Empty() const { return pending_.empty(); }
  size_t Size() const { return pending_.size(); }
  /// Moves sent since the start (Sent() calls).
  uint64_t SentCount() const { return sentCount_; }
  /// Forgets what is pending (a new connection); SentCount() goes on.
  void Clear() { pending_.clear(); }

 private:
  struct Entry {
    RigidTransform transform;
    uint64_t requestId = 0;
    Clock::time_point sentAt;
  };
  std::map<uint32_t, Entry> pending_;
  uint64_t sentCount_ = 0;
};

}  // namespace penumbra::client
