#include "penumbra/sma/collector.h"

#include <algorithm>

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

void MemoryCollector::Scan(const Hierarchy& hierarchy) {
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
  const uint32_t now = hierarchy.Tick();
  const auto older = [now](const auto& a, const auto& b) {
    return now - a.first != now - b.first ? now - a.first > now - b.first : a.second < b.second;
  };
  if (candidates_.size() > options_.maxCandidates) {
    std::nth_element(candidates_.begin(), candidates_.begin() + ptrdiff_t(options_.maxCandidates), candidates_.end(),
                     older);
    candidates_.resize(options_.maxCandidates);
  }
  std::sort(candidates_.begin(), candidates_.end(), older);
}

CollectStep MemoryCollector::Step(Hierarchy& hierarchy, SampleCache& cache, size_t bytesToFree,
                                  const std::function<bool(const Hierarchy::CollapseGroup&)>& keep) {
  CollectStep step;
  // Bounded under the exclusive lock: at most maxGroupsPerStep collapses and
  // four times as many groups looked at.
  size_t attempts = 0;
  while (next_ < candidates_.size() && step.groups < options_.maxGroupsPerStep && step.bytesFreed < bytesToFree &&
         attempts++ < 4 * options_.maxGroupsPerStep) {
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
