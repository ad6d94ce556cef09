#include "penumbra/sma/collector.h"

#include <algorithm>
#include <optional>

namespace penumbra::sma {

size_t MemoryCollector::DataInUse(const Hierarchy& hierarchy, const SampleCache& cache, size_t clientBytes) {
  const size_t freedSlots = (hierarchy.VertexCount() - hierarchy.LiveVertexCount()) * SampleCache::SlotBytes();
  const size_t cacheBytes = cache.MemoryBytes();
  return hierarchy.LiveBytes() + (cacheBytes > freedSlots ? cacheBytes - freedSlots : 0) + clientBytes;
}

uint32_t MemoryCollector::LastUse(const Hierarchy& hierarchy, NodeId node) {
  const Node& n = hierarchy.GetNode(node);
  // The youngest child, in tick order (ticks wrap: compare ages, not ticks).
  const uint32_t now = hierarchy.Tick();
  uint32_t youngest = hierarchy.LastTouched(n.firstChild);
  for (uint8_t c = 1; c < n.childCount; ++c) {
    const uint32_t t = hierarchy.LastTouched(n.firstChild + c);
    if (now - t < now - youngest) youngest = t;
  }
  return youngest;
}

void MemoryCollector::Scan(const Hierarchy& hierarchy, const SampleCache& cache) {
  candidates_.clear();
  next_ = 0;
  // Every collapsible node is the parent of a non-root node: visit each
  // family once, from its first child.
  for (NodeId id = NodeId(hierarchy.RootCount()); id < hierarchy.NodeCount(); ++id) {
    if (!hierarchy.Alive(id)) continue;
    const NodeId parent = hierarchy.GetNode(id).parent;
    if (hierarchy.GetNode(parent).firstChild != id || !hierarchy.Collapsible(parent)) continue;
    const uint32_t lastUse = LastUse(hierarchy, parent);
    if (Old(hierarchy, lastUse)) candidates_.emplace_back(lastUse, parent);
  }
  chunkCandidates_ = cache.OldChunks(0, VertexId(hierarchy.BaseVertexCount()), options_.minAgeTicks);
  nextChunk_ = 0;
  const uint32_t now = hierarchy.Tick();
  const auto oldestFirst = [this, now](auto& list) {
    const auto older = [now](const auto& a, const auto& b) {
      return now - a.first != now - b.first ? now - a.first > now - b.first : a.second < b.second;
    };
    if (list.size() > options_.maxCandidates) {
      std::nth_element(list.begin(), list.begin() + ptrdiff_t(options_.maxCandidates), list.end(), older);
      list.resize(options_.maxCandidates);
    }
    std::sort(list.begin(), list.end(), older);
  };
  oldestFirst(candidates_);
  oldestFirst(chunkCandidates_);
}

CollectStep MemoryCollector::Step(Hierarchy& hierarchy, SampleCache& cache, size_t bytesToFree,
                                  const std::function<bool(const Hierarchy::CollapseGroup&)>& keep,
                                  const std::function<bool(VertexId, VertexId)>& keepVertices) {
  CollectStep step;
  const uint32_t now = hierarchy.Tick();
  // Bounded under the exclusive lock: at most maxGroupsPerStep collapses and
  // drops, and four times as many candidates looked at.
  size_t attempts = 0;
  while (HasCandidates() && step.groups + step.chunksDropped < options_.maxGroupsPerStep &&
         step.bytesFreed < bytesToFree && attempts++ < 4 * options_.maxGroupsPerStep) {
    // The older of the two lists' heads (ticks wrap: compare ages).
    const bool chunkFirst =
        nextChunk_ < chunkCandidates_.size() &&
        (next_ == candidates_.size() || now - chunkCandidates_[nextChunk_].first > now - candidates_[next_].first);
    if (chunkFirst) {
      const uint32_t chunk = chunkCandidates_[nextChunk_++].second;
      const std::optional<uint32_t> lastUse = cache.ChunkLastUse(chunk);
      if (!lastUse) continue;  // dropped, or made again and so young
      if (!Old(hierarchy, *lastUse)) {
        ++step.young;
        continue;
      }
      const VertexId first = VertexId(chunk * SampleCache::kChunkVertices);
      const VertexId end = VertexId(first + SampleCache::kChunkVertices);
      if (keepVertices && keepVertices(first, end)) {
        ++step.kept;
        continue;
      }
      const std::optional<size_t> dropped = cache.DropChunk(chunk);
      if (!dropped) {  // a move's state in it
        ++step.kept;
        continue;
      }
      ++step.chunksDropped;
      step.samplesDropped += *dropped;
      step.bytesFreed += SampleCache::ChunkBytes();
      continue;
    }
    const NodeId node = candidates_[next_++].second;
    // Splits and collections since the scan: it may be a leaf now, or a
    // reused id, or in use again.
    if (!hierarchy.Collapsible(node)) continue;
    if (!Old(hierarchy, LastUse(hierarchy, node))) {
      ++step.young;
      continue;
    }
    if (!hierarchy.PlanCollapse(node, options_.maxGroupNodes, group_)) continue;
    bool young = false;
    for (NodeId member : group_.nodes) young = young || !Old(hierarchy, LastUse(hierarchy, member));
    if (young) {
      ++step.young;
      continue;
    }
    if (keep && keep(group_)) {
      ++step.kept;
      continue;
    }
    const size_t before = hierarchy.LiveBytes();
    hierarchy.Collapse(group_);
    size_t dropped = 0;
    for (VertexId v : group_.freedVertices) dropped += cache.Forget(v) ? 1 : 0;
    ++step.groups;
    step.nodesFreed += group_.freedNodes.size();
    step.verticesFreed += group_.freedVertices.size();
    step.samplesDropped += dropped;
    const size_t after = hierarchy.LiveBytes();
    step.bytesFreed += (before > after ? before - after : 0) + group_.freedVertices.size() * SampleCache::SlotBytes();
  }
  return step;
}

}  // namespace penumbra::sma
