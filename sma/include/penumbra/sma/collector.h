#pragma once
// The age-based garbage collector (issue 15; Schöffel & Pomi §3, Fig. 2 in
// ../shared/seeds/000_*): keeps the SMA's data within --memory-budget by
// collapsing the refined subtrees used longest ago back into their parents.
//
// Ages. Every node a split makes carries the tick of its last use
// (Hierarchy::Touch: a view displayed it, a prediction asked for it; its
// making counts as a use). A collapsible node -- split, its children all
// leaves -- is as old as its youngest child. The collector starts once the
// data in use passes `startFraction` of the budget (the paper's T_shafts)
// and collapses the oldest first until it is down to `stopFraction`
// (T_min). Nothing used within `minAgeTicks` is collected, whatever the
// pressure: a walk whose working set exceeds the budget stays over it (the
// SMA logs it) rather than thrash the view it is showing.
//
// Samples of base vertices. Their ids are never freed, so their samples go
// with no collapse: the collector drops them a cache chunk (1 Ki vertices)
// at a time (SampleCache::DropChunk), as old as the chunk's last use -- a
// view or prediction that touched a node with a corner there -- and in the
// same oldest-first order as the subtrees. A chunk any client holds a
// vertex of, or a renderer is shading, stays (`keepVertices`).
//
// What is never collected (`keep`, the SMA's policy): a node a client holds
// or a vertex it holds (no hole or T-vertex ever appears in a client's
// mesh), and a vertex a renderer is shading (its reply would land in a
// reused slot). Conformity is the hierarchy's: a group collapses together
// (Hierarchy::PlanCollapse). Evicted work that is needed again is simply
// split and shaded again (RefineResult::remadeVertices counts it).
//
// Bounded steps. Scan() reads the hierarchy under the SMA's state lock
// shared (views go on); Step() changes it under the lock exclusive and does
// at most `maxGroupsPerStep` collapses, so a view waits at most one step.
//
// Threads: not synchronised; the SMA runs one collection job at a time.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "penumbra/sma/hierarchy.h"
#include "penumbra/sma/sample_cache.h"

namespace penumbra::sma {

struct CollectorOptions {
  size_t budgetBytes = 0;        // 0: never collect
  double startFraction = 0.9;    // T_shafts: start above this share of the budget
  double stopFraction = 0.75;    // T_min: stop at or below this share
  uint32_t minAgeTicks = 20;     // never collect what was used more recently (ticks)
  size_t maxGroupNodes = 256;    // a larger group (a long propagation) waits for its parts to age apart
  size_t maxGroupsPerStep = 256; // collapses per exclusive hold
  size_t maxCandidates = 1 << 16;  // oldest candidates one Scan keeps
};

/// What one Step did.
struct CollectStep {
  size_t groups = 0;          // groups collapsed
  size_t nodesFreed = 0;
  size_t verticesFreed = 0;
  size_t samplesDropped = 0;  // freed vertices that had a sample, and samples of dropped chunks
  size_t chunksDropped = 0;   // cache chunks of base vertices dropped
  size_t kept = 0;            // groups and chunks kept (held by a client, or being shaded)
  size_t young = 0;           // candidates used since the scan, or whose group has a young member
  size_t bytesFreed = 0;      // the hierarchy's live bytes, the cache slots freed and chunks dropped
};

class MemoryCollector {
 public:
  explicit MemoryCollector(CollectorOptions options) : options_(options) {}
  const CollectorOptions& Options() const { return options_; }

  bool Enabled() const { return options_.budgetBytes > 0; }
  /// Whether data in use of `bytes` should start a collection.
  bool ShouldStart(size_t bytes) const {
    return Enabled() && double(bytes) > options_.startFraction * double(options_.budgetBytes);
  }
  /// The level a collection brings the data down to.
  size_t StopBytes() const { return size_t(options_.stopFraction * double(options_.budgetBytes)); }

  /// The data in use the collector steers by: the hierarchy's live bytes,
  /// the cache less the slots of freed vertices, and `clientBytes`.
  static size_t DataInUse(const Hierarchy& hierarchy, const SampleCache& cache, size_t clientBytes);

  /// State lock shared: finds the collapsible nodes and the cache chunks of
  /// base vertices unused for minAgeTicks, oldest first (at most
  /// maxCandidates of each). Replaces the previous lists. The cache's clock
  /// must be the hierarchy's (SampleCache::SetTick).
  void Scan(const Hierarchy& hierarchy, const SampleCache& cache);
  bool HasCandidates() const { return next_ < candidates_.size() || nextChunk_ < chunkCandidates_.size(); }

  /// State lock exclusive: collapses candidates and drops chunks, oldest
  /// first, until `bytesToFree` are freed or maxGroupsPerStep groups and
  /// chunks are done; skips a candidate no longer collapsible (or no longer
  /// in use) or used since the scan, a group with a young member, a group
  /// `keep` says must stay and a chunk whose vertices [first, end)
  /// `keepVertices` says must stay. Each freed vertex is forgotten in `cache`.
  CollectStep Step(Hierarchy& hierarchy, SampleCache& cache, size_t bytesToFree,
                   const std::function<bool(const Hierarchy::CollapseGroup&)>& keep,
                   const std::function<bool(VertexId first, VertexId end)>& keepVertices = nullptr);

  /// The tick a collapsible node was last used at: its youngest child's.
  static uint32_t LastUse(const Hierarchy& hierarchy, NodeId node);

 private:
  bool Old(const Hierarchy& hierarchy, uint32_t lastUse) const {
    return hierarchy.Tick() - lastUse >= options_.minAgeTicks;  // unsigned: wraps with the tick
  }

  CollectorOptions options_;
  std::vector<std::pair<uint32_t, NodeId>> candidates_;  // (last use, node), oldest first
  size_t next_ = 0;
  std::vector<std::pair<uint32_t, uint32_t>> chunkCandidates_;  // (last use, cache chunk), oldest first
  size_t nextChunk_ = 0;
  Hierarchy::CollapseGroup group_;  // reused
};

}  // namespace penumbra::sma
