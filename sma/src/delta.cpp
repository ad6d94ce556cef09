#include "penumbra/sma/delta.h"

#include <algorithm>
#include <iterator>

#include <google/protobuf/io/coded_stream.h>

#include "penumbra/common/check.h"
#include "penumbra/common/framing.h"
#include "penumbra/sma/memory_usage.h"

namespace penumbra::sma {

namespace {

void AddVec3(google::protobuf::RepeatedField<float>* out, const Vec3& v) {
  out->Add(v.x);
  out->Add(v.y);
  out->Add(v.z);
}

// Delta.vertex_objects: 0 for the static part, else the object's index + 1.
uint32_t WireObjectOf(const Scene& scene, uint32_t baseTriangle) {
  const uint32_t object = scene.ObjectOfTriangle(baseTriangle);
  return object == kStaticObject ? 0 : object + 1;
}

}  // namespace

size_t ClientMirror::AppendChanges(std::span<const NodeId> removals, std::span<const NodeId> additions,
                                   const Hierarchy& hierarchy, const SampleCache& cache, wire::Delta& delta) {
  bool removedLingering = false;
  for (NodeId id : removals) {
    if (held_.erase(id) == 0) continue;
    heldTouched_.push_back(id);
    removedLingering = removedLingering || IsLingering(id);
    delta.add_removed_triangles(id);
    for (VertexId v : hierarchy.GetNode(id).v) {
      auto it = vertexRefs_.find(v);
      if (it != vertexRefs_.end() && --it->second == 0) vertexRefs_.erase(it);
    }
  }
  if (removedLingering)
    std::erase_if(lingering_, [&](const Left& left) { return !held_.contains(left.node); });
  const Scene& scene = hierarchy.GetScene();
  const bool objects = !scene.objects.empty();
  size_t added = 0;
  for (NodeId id : additions) {
    if (!held_.insert(id).second) continue;
    heldTouched_.push_back(id);
    ++added;
    const Node& node = hierarchy.GetNode(id);
    for (VertexId v : node.v) {
      if (vertexRefs_[v]++ > 0) continue;
      delta.add_vertex_ids(v);
      // Object space for a movable object's vertex: the client places it
      // with the object's transform, so a move re-sends no geometry.
      const SampleVertex& sv = hierarchy.GetVertex(v);
      AddVec3(delta.mutable_vertex_positions(), sv.position);
      if (objects) delta.add_vertex_objects(WireObjectOf(scene, sv.baseTriangle));
      const CachedSample sample = cache.Read(v).value_or(CachedSample{});  // one version of both
      AddVec3(delta.mutable_vertex_radiance(), sample.radiance);
      AddVec3(delta.mutable_vertex_irradiance(), sample.irradiance);
    }
    delta.add_triangle_ids(id);
    for (VertexId v : node.v) delta.add_triangle_vertices(v);
    const uint32_t material = scene.triangles[node.baseTriangle].material;
    delta.add_triangle_materials(material);
    if (scene.materials[material].albedoTexture >= 0) {
      for (int c = 0; c < 3; ++c) {
        const Vec2 uv = hierarchy.CornerUv(id, c);
        delta.add_triangle_uvs(uv.x);
        delta.add_triangle_uvs(uv.y);
      }
    }
  }
  // Merged now and then even if no plan asks: the changes since a merge
  // stay within a bound of what is held.
  if (heldTouched_.size() > 2 * held_.size() + 4096) SortedHeld();
  return added;
}

size_t ClientMirror::AppendUpdates(std::span<const VertexId> vertices, const SampleCache& cache, wire::Delta& delta,
                                   std::vector<VertexId>* stillOwed) const {
  size_t n = 0;
  for (VertexId v : vertices) {
    if (!HoldsVertex(v)) continue;
    // A sample invalidated by a move since the update was owed: its reshade
    // comes as its own update, never a black one now. A suspect one comes
    // back as it was if its test keeps it, and is then still owed.
    const std::optional<CachedSample> sample = cache.Read(v);
    if (!sample) {
      // (Read again: a test may have kept it since the first read, and its
      // notice may already be on its way.)
      if (stillOwed && (cache.IsSuspect(v) || cache.Read(v))) stillOwed->push_back(v);
      continue;
    }
    delta.add_updated_vertex_ids(v);
    AddVec3(delta.mutable_updated_vertex_radiance(), sample->radiance);
    AddVec3(delta.mutable_updated_vertex_irradiance(), sample->irradiance);
    ++n;
  }
  return n;
}

const std::vector<NodeId>& ClientMirror::SortedHeld() const {
  if (heldTouched_.empty()) return heldSorted_;
  std::sort(heldTouched_.begin(), heldTouched_.end());
  heldTouched_.erase(std::unique(heldTouched_.begin(), heldTouched_.end()), heldTouched_.end());
  std::vector<NodeId> merged;
  merged.reserve(held_.size());
  auto old = heldSorted_.begin();
  for (NodeId touched : heldTouched_) {
    for (; old != heldSorted_.end() && *old < touched; ++old) merged.push_back(*old);
    if (old != heldSorted_.end() && *old == touched) ++old;
    if (held_.contains(touched)) merged.push_back(touched);
  }
  merged.insert(merged.end(), old, heldSorted_.end());
  PENUMBRA_CHECK(merged.size() == held_.size(), "ClientMirror::SortedHeld: the merge lost or invented a node");
  heldSorted_ = std::move(merged);
  heldTouched_.clear();
  return heldSorted_;
}

std::vector<NodeId> ClientMirror::LingeringNodes() const {
  std::vector<NodeId> nodes;
  nodes.reserve(lingering_.size());
  for (const Left& left : lingering_) nodes.push_back(left.node);
  return nodes;
}

namespace {
auto FindLeft(auto& lingering, NodeId node) {
  return std::lower_bound(lingering.begin(), lingering.end(), node,
                          [](const auto& left, NodeId n) { return left.node < n; });
}
}  // namespace

bool ClientMirror::IsLingering(NodeId node) const {
  const auto it = FindLeft(lingering_, node);
  return it != lingering_.end() && it->node == node;
}

uint64_t ClientMirror::LeftViewAt(NodeId node) const {
  const auto it = FindLeft(lingering_, node);
  return it != lingering_.end() && it->node == node ? it->atPlan : plans_;
}

void ClientMirror::SetLingering(std::span<const NodeId> nodes) {
  // A merge of two sorted lists: from one plan to the next most of what
  // lingers stays (a re-map of a resting view changes none of it), and this
  // runs per plan.
  PENUMBRA_CHECK(std::is_sorted(nodes.begin(), nodes.end()), "ClientMirror::SetLingering: nodes must be sorted");
  std::vector<Left> next;
  next.reserve(nodes.size());
  auto old = lingering_.begin();
  for (NodeId id : nodes) {
    PENUMBRA_CHECK(held_.contains(id), "ClientMirror::SetLingering: a lingering node must be held");
    while (old != lingering_.end() && old->node < id) ++old;
    next.push_back(Left{id, old != lingering_.end() && old->node == id ? old->atPlan : plans_});
  }
  lingering_ = std::move(next);
  ++plans_;
}

size_t ClientMirror::MemoryBytes() const {
  return UnorderedMapBytes(held_) + UnorderedMapBytes(vertexRefs_) + lingering_.capacity() * sizeof(Left) +
         (heldSorted_.capacity() + heldTouched_.capacity()) * sizeof(NodeId);
}

void ClientMirror::Clear() {
  // Assigned, not clear()ed: clear() keeps the bucket arrays.
  held_ = {};
  vertexRefs_ = {};
  lingering_ = std::vector<Left>();  // (not "= {}": a vector's keeps its capacity)
  heldSorted_ = std::vector<NodeId>();
  heldTouched_ = std::vector<NodeId>();
}

ViewPlan PlanView(const VisibleSet& visible, const ClientMirror& mirror, const Hierarchy& hierarchy,
                  const SampleCache& cache, size_t lingerTriangles) {
  // Every client's refresh plans on its strand (an I/O thread), up to ten
  // times a second while anyone refines: sorted vectors and binary searches,
  // no hash sets of the ~10^4 visible and held nodes built per call.
  PENUMBRA_CHECK(std::is_sorted(visible.nodes.begin(), visible.nodes.end()),
                 "PlanView: the visible set's nodes must be in increasing order");
  ViewPlan plan;
  uint64_t hits = 0, misses = 0;
  for (NodeId id : visible.nodes) {
    const Node& node = hierarchy.GetNode(id);
    bool shaded = true;
    for (VertexId v : node.v) {
      if (cache.IsShaded(v)) {
        ++hits;
      } else {
        ++misses;
        shaded = false;
        plan.missing.push_back(v);
      }
    }
    if (mirror.Holds(id)) continue;
    (shaded ? plan.addCached : plan.pending).push_back(id);  // both in increasing order
  }
  cache.CountLookups(hits, misses);
  std::sort(plan.missing.begin(), plan.missing.end());
  plan.missing.erase(std::unique(plan.missing.begin(), plan.missing.end()), plan.missing.end());

  // Held but no longer visible. Such a node is "replaced" when an addition
  // covers part of it (its refined children, or a coarser ancestor): the
  // client then swaps them in one delta and never shows a hole.
  const auto in = [](const std::vector<NodeId>& sorted, NodeId id) {
    return std::binary_search(sorted.begin(), sorted.end(), id);
  };
  std::vector<NodeId> gone;  // in increasing order
  const std::vector<NodeId>& held = mirror.SortedHeld();
  std::set_difference(held.begin(), held.end(), visible.nodes.begin(), visible.nodes.end(), std::back_inserter(gone));
  std::vector<NodeId> replaced;  // gone ancestors of an addition
  for (NodeId a : plan.addCached)
    for (NodeId p = hierarchy.GetNode(a).parent; p != kNoNode; p = hierarchy.GetNode(p).parent)
      if (in(gone, p)) replaced.push_back(p);
  std::sort(replaced.begin(), replaced.end());
  replaced.erase(std::unique(replaced.begin(), replaced.end()), replaced.end());
  std::vector<NodeId> unreplaced;
  for (NodeId g : gone) {
    bool isReplaced = in(replaced, g);
    for (NodeId p = hierarchy.GetNode(g).parent; p != kNoNode && !isReplaced; p = hierarchy.GetNode(p).parent)
      isReplaced = in(plan.addCached, p);  // a coarser addition covers it
    (isReplaced ? plan.removeReplaced : unreplaced).push_back(g);  // in increasing order
  }
  if (lingerTriangles == 0 || unreplaced.empty()) {
    plan.removeGone = std::move(unreplaced);
    return plan;
  }

  // Lingering (the header's rule). Held nodes are disjoint, so an unreplaced
  // gone node can overlap only a pending node (an ancestor or descendant of
  // it), or the other side of a base triangle the view sees.
  // (A re-map of a resting view has nothing pending: no walks then.)
  std::vector<NodeId> pendingAncestors;
  for (NodeId a : plan.pending)
    for (NodeId p = hierarchy.GetNode(a).parent; p != kNoNode; p = hierarchy.GetNode(p).parent)
      pendingAncestors.push_back(p);
  std::sort(pendingAncestors.begin(), pendingAncestors.end());
  const auto sideKey = [](const Node& n) { return uint64_t(n.baseTriangle) << 1 | uint64_t(n.back); };
  std::vector<uint64_t> visibleSides;
  visibleSides.reserve(visible.nodes.size());
  for (NodeId id : visible.nodes) visibleSides.push_back(sideKey(hierarchy.GetNode(id)));
  std::sort(visibleSides.begin(), visibleSides.end());
  std::vector<NodeId> candidates;
  for (NodeId g : unreplaced) {
    const Node& node = hierarchy.GetNode(g);
    bool overlaps = std::binary_search(pendingAncestors.begin(), pendingAncestors.end(), g) ||
                    std::binary_search(visibleSides.begin(), visibleSides.end(), sideKey(node) ^ 1);
    for (NodeId p = node.parent; p != kNoNode && !overlaps && !plan.pending.empty(); p = hierarchy.GetNode(p).parent)
      overlaps = in(plan.pending, p);
    (overlaps ? plan.removeGone : candidates).push_back(g);
  }
  if (candidates.size() > lingerTriangles) {
    // The most recently seen stay; ties (left in the same plan) by id, so
    // the choice does not depend on hash order.
    std::sort(candidates.begin(), candidates.end(), [&](NodeId a, NodeId b) {
      const uint64_t ta = mirror.LeftViewAt(a), tb = mirror.LeftViewAt(b);
      return ta != tb ? ta > tb : a < b;
    });
    plan.removeGone.insert(plan.removeGone.end(), candidates.begin() + lingerTriangles, candidates.end());
    candidates.resize(lingerTriangles);
    std::sort(plan.removeGone.begin(), plan.removeGone.end());
    std::sort(candidates.begin(), candidates.end());
  }
  plan.linger = std::move(candidates);
  return plan;
}

size_t DeltaWireBytes(const wire::Delta& delta) {
  // The Envelope wraps the delta in its field's tag and a length varint.
  using google::protobuf::io::CodedOutputStream;
  const size_t body = delta.ByteSizeLong();
  const uint32_t tag = uint32_t(wire::Envelope::kDeltaFieldNumber) << 3 | 2;  // length-delimited
  return kFrameHeaderBytes + CodedOutputStream::VarintSize32(tag) + CodedOutputStream::VarintSize64(body) + body;
}

}  // namespace penumbra::sma
