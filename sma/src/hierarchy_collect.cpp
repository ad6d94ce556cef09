// Hierarchy: collection (issue 15) -- collapsing refined subtrees back into
// their parents, the free lists that let later splits reuse their ids, and
// the accounting the collector steers by. The splits themselves are in
// hierarchy.cpp; the policy (what to collect, when, and what must be kept)
// is the collector's (collector.h).

#include <algorithm>
#include <unordered_set>

#include "penumbra/common/check.h"
#include "penumbra/sma/hierarchy.h"

namespace penumbra::sma {

bool Hierarchy::Collapsible(NodeId id) const {
  if (!Alive(id)) return false;
  if (IsRoot(id) && RootIsLeaf(id)) return false;  // without making its record
  const Node& n = NodeRef(id);
  if (n.IsLeaf()) return false;
  for (uint8_t c = 0; c < n.childCount; ++c)
    if (!NodeRef(n.firstChild + c).IsLeaf()) return false;
  return true;
}

bool Hierarchy::SplitsPointEdge(NodeId id, EdgeKey key) const {
  const Node& n = NodeRef(id);
  for (int k = 0; k < 3; ++k)
    if (n.mid[k] != kNoVertex && PointEdge(id, k) == key) return true;
  return false;
}

bool Hierarchy::PlanCollapse(NodeId node, size_t maxNodes, CollapseGroup& group) const {
  group.nodes.clear();
  group.freedNodes.clear();
  group.freedVertices.clear();
  if (!Alive(node) || (IsRoot(node) && RootIsLeaf(node)) || NodeRef(node).IsLeaf()) return false;
  std::unordered_set<NodeId> members;
  // A collapse takes a node's whole subtree: every split node under it.
  const auto addSubtree = [&](NodeId top) {
    boost::container::small_vector<NodeId, 64> stack{top};
    while (!stack.empty()) {
      const NodeId id = stack.back();
      stack.pop_back();
      const Node& n = NodeRef(id);
      if (n.IsLeaf() || !members.insert(id).second) continue;
      group.nodes.push_back(id);
      for (uint8_t c = 0; c < n.childCount; ++c) stack.push_back(n.firstChild + c);
    }
    return group.nodes.size() <= maxNodes;
  };
  if (!addSubtree(node)) return false;
  // Refine's propagation backwards. A member's split put a midpoint on its
  // point edge E; once it collapses E is whole again, so every node on the
  // other side split on E must collapse too (its whole subtree), or a leaf
  // there would keep a vertex inside E. Those nodes are found from the
  // leaves along E -- on E's halves, or on their halves where those are
  // split in turn -- by climbing to the ancestor split on E.
  boost::container::small_vector<EdgeKey, 16> segments;
  for (size_t next = 0; next < group.nodes.size(); ++next) {
    const Node& n = NodeRef(group.nodes[next]);
    for (int k = 0; k < 3; ++k) {
      if (n.mid[k] == kNoVertex) continue;
      const EdgeKey whole = PointEdge(group.nodes[next], k);
      segments.assign(1, whole);
      while (!segments.empty()) {
        const EdgeKey segment = segments.back();
        segments.pop_back();
        const auto mid = midpointOfPointEdge_.find(segment);
        if (mid != midpointOfPointEdge_.end()) {
          const uint32_t a = uint32_t(segment >> 32), b = uint32_t(segment);
          segments.push_back(KeyOf(a, mid->second));
          segments.push_back(KeyOf(mid->second, b));
          continue;
        }
        for (const NodeId leaf : LeavesOnPointEdge(segment)) {
          NodeId splitter = NodeRef(leaf).parent;
          while (splitter != kNoNode && !SplitsPointEdge(splitter, whole)) splitter = NodeRef(splitter).parent;
          if (splitter == kNoNode) return false;  // not made by a split of E: cannot happen in a conforming mesh
          // A member's whole subtree is in the group already. (A leaf whose
          // parent is a member but whose splitter is not would stay on E:
          // collapsing the parent alone leaves it there.)
          if (!members.contains(splitter) && !addSubtree(splitter)) return false;
        }
      }
    }
  }
  for (const NodeId id : group.nodes) {
    const Node& n = NodeRef(id);
    for (uint8_t c = 0; c < n.childCount; ++c) group.freedNodes.push_back(n.firstChild + c);
    for (int k = 0; k < 3; ++k)
      if (n.mid[k] != kNoVertex) group.freedVertices.push_back(n.mid[k]);
  }
  // Neighbours on one side of an edge share its midpoint vertex.
  std::sort(group.freedVertices.begin(), group.freedVertices.end());
  group.freedVertices.erase(std::unique(group.freedVertices.begin(), group.freedVertices.end()),
                            group.freedVertices.end());
  // Collapse() goes bottom-up: the deepest first.
  std::stable_sort(group.nodes.begin(), group.nodes.end(),
                   [this](NodeId x, NodeId y) { return NodeRef(x).depth > NodeRef(y).depth; });
  return true;
}

void Hierarchy::Collapse(const CollapseGroup& group) {
  // The members' midpoints leave the edge maps (read before any record changes).
  for (const NodeId id : group.nodes) {
    const Node& n = NodeRef(id);
    for (int k = 0; k < 3; ++k) {
      if (n.mid[k] == kNoVertex) continue;
      const VertexId a = n.v[(k + 1) % 3], b = n.v[(k + 2) % 3];
      midpointOfVertexEdge_.erase(KeyOf(a, b));
      midpointOfPointEdge_.erase(KeyOf(VertexRef(a).point, VertexRef(b).point));
    }
  }
  // Deepest first, so each member's children are leaves when it collapses.
  for (const NodeId id : group.nodes) {
    PENUMBRA_CHECK(Collapsible(id), "collapsing a node whose children are not leaves");
    Node& n = MutableNode(id);
    for (uint8_t c = 0; c < n.childCount; ++c) {
      const NodeId child = n.firstChild + c;
      UnlinkEdges(child);
      nodes_[child - RootCount()] = Node{};  // depth 0: a freed slot (Alive() is false)
    }
    (n.childCount == 4 ? freeBlocks4_ : freeBlocks2_).push_back(n.firstChild);
    n.firstChild = kNoNode;
    n.childCount = 0;
    n.splitEdge = 0;
    n.mid = {kNoVertex, kNoVertex, kNoVertex};
    n.collapsed = true;
    LinkEdges(id);  // a leaf again (a root is one by having no children); a freed member leaves again
  }
  for (const VertexId v : group.freedVertices) {
    MutableMidpoint(v).depth = 0;  // a freed slot (VertexAlive() is false)
    freeVertices_.push_back(v);
  }
  ++generation_;
}

size_t Hierarchy::ReleaseSceneRecords() {
  size_t freed = 0;
  {
    std::lock_guard lock(*rootMutex_);
    std::erase_if(rootChunkStore_, [&](const auto& entry) {
      const auto& [chunk, records] = entry;
      for (size_t i = 0; i < kRootChunkNodes && chunk * kRootChunkNodes + i < RootCount(); ++i)
        if (!records[i].IsLeaf()) return false;
      rootChunks_[chunk].store(nullptr, std::memory_order_release);
      freed += kRootChunkNodes * sizeof(Node);
      return true;
    });
  }
  {
    std::lock_guard lock(*baseMutex_);
    for (const auto& [chunk, records] : baseChunkStore_) baseChunks_[chunk].store(nullptr, std::memory_order_release);
    freed += baseChunkStore_.size() * kBaseChunkVertices * sizeof(SampleVertex);
    baseChunkStore_.clear();
  }
  return freed;
}

size_t Hierarchy::LiveBytes() const {
  const size_t freeNodes = 4 * freeBlocks4_.size() + 2 * freeBlocks2_.size();
  // Neither the freed slots nor the tables' last chunk's unused tail: what
  // the live nodes and vertices take. What is allocated beyond that is at
  // most a chunk per table and the free slots, which splits use first.
  return TableBytes() - nodes_.TailBytes() - touched_.TailBytes() - vertices_.TailBytes() -
         freeNodes * (sizeof(Node) + sizeof(uint32_t)) - freeVertices_.size() * sizeof(SampleVertex);
}

}  // namespace penumbra::sma
