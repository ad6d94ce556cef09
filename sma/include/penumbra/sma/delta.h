#pragma once
// What a client holds, and how to change it (paper §2, "incremental
// communication protocol"). Plain code, no sockets: unit-tested directly.
//
// ClientMirror is the SMA's exact copy of the client's state: the triangles
// (hierarchy nodes) sent and not removed, and the vertices they use, counted
// by reference so a vertex's data crosses the network once while any held
// triangle uses it. Clients apply each Delta as removals, then vertices,
// then triangles -- the mirror builds deltas in that same order, so both
// sides agree on which vertices the client holds.
//
// PlanView compares a visible set with the mirror and sorts the difference
// into the paper's three lists: additions found shaded in the cache,
// removals, and additions that wait for samples.
//
// Lingering. The paper removes a triangle the moment it leaves the view; a
// client that turns back then waits a round trip, a trace and the other
// clients' jobs for what it showed a second ago (with four clients on two
// cores the first frame back was 10-34 % off; docs/refinement.md,
// "Walkthrough"). So a triangle that left the view may stay held -- drawn,
// hidden by the depth test or outside the frustum -- up to a budget, the
// ones that left longest ago removed first. A lingering triangle never
// overlaps one the view needs: not an ancestor or descendant of a visible
// node (those are replaced or removed as before), nor on the other side of
// a base triangle the view sees (the two sides share a plane and clients
// draw both).

#include <cstdint>
#include <span>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"
#include "penumbra/sma/visibility.h"
#include "penumbra/wire.pb.h"

namespace penumbra::sma {

class ClientMirror {
 public:
  bool Holds(NodeId node) const { return held_.contains(node); }
  bool HoldsVertex(VertexId v) const { return vertexRefs_.contains(v); }
  size_t TriangleCount() const { return held_.size(); }
  /// Held triangles that are not in the view (PlanView's `linger`), in
  /// increasing order.
  std::vector<NodeId> LingeringNodes() const;
  size_t LingeringCount() const { return lingering_.size(); }
  bool IsLingering(NodeId node) const;
  /// When `node` left the view (a plan count), or now if it has not.
  uint64_t LeftViewAt(NodeId node) const;
  /// Records the nodes that linger after the plan just applied (held, not
  /// visible: `ViewPlan::linger`, increasing); every other held node is in
  /// the view.
  void SetLingering(std::span<const NodeId> nodes);
  size_t VertexCount() const { return vertexRefs_.size(); }
  /// The held nodes in increasing order. Kept up to date from the changes
  /// since the last call (a merge), not rebuilt: PlanView walks it on every
  /// plan, and walking the hash set -- some 10^5 nodes with lingering --
  /// was most of the SMA's planning time (issue 11, bench/walkthrough).
  const std::vector<NodeId>& SortedHeld() const;
  /// Calls f(vertex) for every vertex the client holds.
  template <class F>
  void ForEachVertex(F&& f) const {
    for (const auto& entry : vertexRefs_) f(entry.first);
  }

  /// Appends to `delta` the removal of `removals` (nodes not held are
  /// skipped), then the addition of `additions` (nodes already held are
  /// skipped) with every vertex the client lacks. Every corner of an added
  /// node must be shaded in `cache`. Vertex positions are in their object's
  /// space (hierarchy.h); when the scene has movable objects each new vertex
  /// also gets its object id (vertex_objects: index + 1, 0 static). Returns
  /// the number of triangles added.
  size_t AppendChanges(std::span<const NodeId> removals, std::span<const NodeId> additions,
                       const Hierarchy& hierarchy, const SampleCache& cache, wire::Delta& delta);

  /// Appends to `delta` the cache's current radiance of every vertex of
  /// `vertices` the client holds (updated_vertex_*), skipping vertices with
  /// no sample now (invalidated by a move: their reshade is sent when it
  /// arrives). A held vertex skipped because its sample is suspect (held
  /// back for a move's test, SampleCache::Suspect) is added to `stillOwed`
  /// when given: if the test keeps the sample, nothing else will send it,
  /// so whoever owes the update keeps owing it. Returns how many were added.
  size_t AppendUpdates(std::span<const VertexId> vertices, const SampleCache& cache, wire::Delta& delta,
                       std::vector<VertexId>* stillOwed = nullptr) const;
  /// Estimated heap bytes of what the mirror keeps (its hash tables and vectors;
  /// memory_usage.h). Not synchronised: the owner's thread (the session's strand).
  size_t MemoryBytes() const;
  /// Forgets everything (the client reconnected or was reset).
  void Clear();

 private:
  struct Left {
    NodeId node;
    uint64_t atPlan;  // the plan count when it left the view
  };
  std::unordered_set<NodeId> held_;
  std::unordered_map<VertexId, uint32_t> vertexRefs_;
  std::vector<Left> lingering_;  // a subset of held_, by increasing node
  uint64_t plans_ = 0;           // SetLingering calls
  // SortedHeld(): held_ in order as of the last call, and the nodes added
  // or removed since (each may be either now: held_ says which).
  mutable std::vector<NodeId> heldSorted_;
  mutable std::vector<NodeId> heldTouched_;
};

struct ViewPlan {
  std::vector<NodeId> addCached;       // (a) visible, all corners shaded, not held
  std::vector<NodeId> removeReplaced;  // held, not visible, overlapping an addition (sent with it)
  std::vector<NodeId> removeGone;      // (b) held, not visible, nothing replaces it now, not lingering
  std::vector<NodeId> linger;          // held, not visible, kept (ClientMirror "Lingering")
  std::vector<NodeId> pending;         // (c) visible, not held, some corner unshaded
  std::vector<VertexId> missing;       // the unshaded corners of `pending`, each once
};

/// Plans the change from what `mirror` holds to `visible`, letting at most
/// `lingerTriangles` held triangles that left the view stay (the most
/// recently seen first; 0: the paper's eager removal). Also counts cache
/// hits and misses (a visible node's corners) in `cache`.
ViewPlan PlanView(const VisibleSet& visible, const ClientMirror& mirror, const Hierarchy& hierarchy,
                  const SampleCache& cache, size_t lingerTriangles = 0);

/// Bytes a delta takes on the wire (its encoded frame, header included).
size_t DeltaWireBytes(const wire::Delta& delta);

}  // namespace penumbra::sma
