#pragma once
// An independent model of what a Penumbra client holds, built only from the
// Delta messages it receives. Every rule of docs/protocol.md is checked, so
// a test that feeds an SMA's deltas through it checks the SMA's protocol.

#include <array>
#include <cstdint>
#include <map>
#include <set>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/wire.pb.h"

namespace penumbra::testing {

class HeldMesh {
 public:
  struct Vertex {
    Vec3 position;     // as sent: object space for a vertex of a movable object
    uint32_t object = 0;  // Delta.vertex_objects: 0 static, else the movable object's id
    Rgb radiance;
    Rgb irradiance;
    uint32_t refs = 0;
  };

  /// Applies a delta: removals, then vertices, then triangles. Fails (and
  /// leaves the model in an unspecified state) on any violation: a removal of
  /// a triangle not held, a vertex sent while held, a triangle held twice or
  /// using a vertex not held, inconsistent array lengths, a sequence gap.
  Status Apply(const wire::Delta& delta);

  const std::map<uint64_t, std::array<uint64_t, 3>>& Triangles() const { return triangles_; }
  const std::map<uint64_t, Vertex>& Vertices() const { return vertices_; }
  std::set<uint64_t> TriangleIds() const;

  /// Corners of held triangles lying strictly inside an edge of another held
  /// triangle: T-vertices, which a conforming mesh has none of. Only
  /// vertices of id `firstId` or more count: a real model's own mesh may
  /// have T-junctions between its base vertices (Sponza has), and those the
  /// SMA's refinement could make are at its midpoints, whose ids follow the
  /// base vertices' (Hierarchy: "Ids").
  size_t CountTVertices(uint64_t firstId = 0) const;

  uint64_t LastViewId() const { return viewId_; }
  /// The scene epoch of the last delta (never decreases).
  uint64_t SceneEpoch() const { return sceneEpoch_; }
  bool Converged() const { return converged_; }
  uint32_t PendingSamples() const { return pending_; }
  uint64_t DeltasApplied() const { return sequence_; }
  /// Triangles added and removed by each DeltaKind, over all deltas.
  std::map<int, uint64_t> added;
  std::map<int, uint64_t> removed;
  /// Vertex radiance updates applied (IMPROVED deltas), over all deltas.
  uint64_t updates = 0;

 private:
  std::map<uint64_t, std::array<uint64_t, 3>> triangles_;
  std::map<uint64_t, Vertex> vertices_;
  uint64_t sequence_ = 0;
  uint64_t viewId_ = 0;
  uint64_t sceneEpoch_ = 0;
  bool converged_ = false;
  uint32_t pending_ = 0;
};

}  // namespace penumbra::testing
