#pragma once
// The hierarchical subdivision mesh (founding paper §2, §4.2).
//
// Every base triangle of the scene is the root of its own tree. A node is a
// triangle on its base triangle's plane, given by three corner vertices and
// their barycentric coordinates on the base triangle. A node is split at most
// once, either
//   1 -> 4 at its three edge midpoints (Loop-style topology; positions stay on
//          the base triangle's plane), or
//   1 -> 2 across one edge: the opposite corner joins that edge's midpoint.
// Leaves (nodes without children) form the refined mesh.
//
// Vertices (shading samples). The corners of root nodes are the scene's
// vertices. A midpoint vertex is identified by the edge it splits, given by
// its two endpoint vertices, so the nodes on both sides of an edge share it:
// one sample, no duplicate work. Because the scene splits vertices at creases,
// the two sides of a crease edge have different endpoint vertices and so
// different midpoints (same position, each with its side's normal).
//
// Conformity. Adjacency is by position: two leaves are neighbours across an
// edge when their edges join the same two points, whatever the vertices'
// normals -- within one part of the scene: the static part and each movable
// object (whose positions are in its own object space, see SampleVertex)
// have points of their own, so adjacency never crosses between parts. Refine() splits a leaf 1 -> 4 and then every neighbour that would
// otherwise have a T-vertex: a neighbour whose height over the shared edge is
// less than `aspectThreshold` times the edge's length splits 1 -> 2 and the
// propagation stops there; otherwise it splits 1 -> 4 and propagation goes on
// from its other edges -- across base-triangle boundaries too. After every
// Refine() no leaf edge has a vertex of another leaf at its midpoint (input
// meshes may carry T-junctions of their own; Refine never adds any).
//
// Sides. Surfaces reflect on both sides (Scene::twoSided), and each side is
// shaded on its own: a base triangle has a front root, and in a two-sided
// scene also a back root, a surface of its own on the same plane -- corners
// in reverse order (so it is counter-clockwise seen from behind), vertices of
// its own with the normals negated, points of its own (so the two sides are
// never each other's neighbours). Its samples go to the renderer with the
// negated normal, which is how the renderer is told which side to shade.
//
// Ids. NodeId and VertexId are dense indices, stable until the collector
// frees them ("Collection" below: roots and base vertices never are; a
// freed id is reused by a later split). Front root id == base
// triangle index t; back root id == BaseTriangleCount() + t. Front base
// vertex id == scene vertex index v; back base vertex id == scene vertex
// count + v. Clients key their triangles and vertices by these ids (widened
// to 64 bits on the wire). Every other id is assigned by a split, in the order
// splits happen: the same splits made in the same order give the same ids,
// which is how a cache snapshot (cache_snapshot.h) brings them back after a
// restart -- as long as nothing was collected (the SMA refuses a cache
// directory together with a memory budget). A change to how Split4/Split2
// number children or midpoints must bump CacheSnapshot's format version.
//
// Storage (issue 15). Root records and base vertices' SampleVertex records
// are made on first use, a chunk at a time, from the scene (a root's record
// is a pure function of it until the root is split, a base vertex's always;
// midpoints are made by splits, as before); what cannot be recomputed cheaply is
// kept per scene vertex, shared by both sides: its point id and the base
// triangle it lies on (8 bytes). Roots' adjacency lives in a compact table of
// the front roots' edges grouped by their smaller point (4 bytes per edge, 4
// per front point); a back root's edges are the front's, their points shifted
// by the front's point count. So an unvisited base triangle costs about 12
// bytes of that table, and its vertices 8 bytes each, whatever the sides.
//
// Threads: not synchronised. The SMA guards a Hierarchy with its state lock;
// const member functions may run concurrently with each other (making root
// and base vertex records on first use is synchronised inside).

#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <span>
#include <unordered_map>
#include <vector>

#include <boost/container/small_vector.hpp>

#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/chunked_array.h"

namespace penumbra::sma {

using NodeId = uint32_t;
using VertexId = uint32_t;
inline constexpr NodeId kNoNode = ~NodeId(0);
inline constexpr VertexId kNoVertex = ~VertexId(0);

/// A shading sample's place: what the renderer needs to shade it.
///
/// Movable objects (issue 14): position and normal are in the space of the
/// vertex's object -- the object of its base triangle
/// (Scene::ObjectOfTriangle(baseTriangle)) -- and world space only for the
/// static part. An object's subtree travels with it: a move changes no
/// vertex, only the pose that places it (ScenePose; the SMA turns them into
/// the world when it asks a renderer, shade_codec.h). Clients get them in
/// object space too (Delta.vertex_objects names the object).
struct SampleVertex {
  Vec3 position;          // object space (world space for the static part)
  Vec3 normal;            // object space, unit
  uint32_t point = 0;     // position identity: vertices at the same point share it
  uint32_t baseTriangle = 0;  // a base triangle the vertex lies on
  Vec2 bary{0.0f};        // (b1, b2) of `position` on `baseTriangle`
  uint8_t depth = 0;      // 0 for scene vertices (and freed slots), else the depth of the node whose split made it
};

struct Node {
  uint32_t baseTriangle = 0;
  std::array<VertexId, 3> v{};  // corners, counter-clockwise like the base triangle
  std::array<Vec2, 3> bary{};   // corners' (b1, b2) on the base triangle
  NodeId parent = kNoNode;
  NodeId firstChild = kNoNode;  // children are contiguous: firstChild .. firstChild+childCount-1
  uint8_t childCount = 0;       // 0 (leaf), 2 or 4
  uint8_t splitEdge = 0;        // 1 -> 2 splits: the edge split, named by its opposite corner
  uint8_t depth = 0;            // 0 for roots (and for freed slots: a node made by a split is at depth >= 1)
  bool back : 1 = false;        // in a back root's tree (Hierarchy: "Sides")
  bool collapsed : 1 = false;   // its children were collected once (Hierarchy: "Collection")
  /// Vertices this node's split added: midpoints of edges 0, 1, 2 (edge k is
  /// opposite corner k) for 1 -> 4; only [splitEdge] for 1 -> 2; else kNoVertex.
  std::array<VertexId, 3> mid{kNoVertex, kNoVertex, kNoVertex};

  bool IsLeaf() const { return childCount == 0; }
};

/// Nodes at this depth are never split 1 -> 4 (float precision); 1 -> 2
/// splits, which keep the mesh conforming, still may be.
inline constexpr uint8_t kMaxSplitDepth = 20;

struct RefineOptions {
  /// A neighbour whose height over the shared edge is below this multiple of
  /// the edge's length is "slim": it splits 1 -> 2 and propagation stops.
  /// 1.2 lets common shapes (equilateral 0.87, right isosceles across a leg
  /// 1.0) stop the wave, while elongated neighbours, which 1 -> 2 would cut
  /// into slivers, split 1 -> 4 and pass it on.
  float aspectThreshold = 1.2f;
  /// Most 1 -> 4 splits one Refine() makes; beyond it neighbours split 1 -> 2
  /// (which always ends propagation), so a pathological mesh stays bounded.
  uint32_t maxSplits4 = 4096;
  uint8_t maxDepth = kMaxSplitDepth;  // at most kMaxSplitDepth: nodes this deep are never split 1 -> 4
};

/// What one Refine() did.
struct RefineResult {
  std::vector<NodeId> split;            // nodes that received children
  std::vector<VertexId> newVertices;    // vertices created (to be shaded)
  /// Of newVertices, those made by splits of nodes collapsed before: work
  /// the collector undid and that is done again (issue 15's re-shading cost).
  size_t remadeVertices = 0;
};

class Hierarchy {
 public:
  /// Roots for every scene triangle; base vertices for every scene vertex.
  /// The scene must outlive the hierarchy.
  explicit Hierarchy(const Scene& scene);

  const Scene& GetScene() const { return scene_; }
  size_t NodeCount() const { return RootCount() + nodes_.size(); }
  size_t VertexCount() const { return BaseVertexCount() + vertices_.size(); }
  size_t BaseTriangleCount() const { return scene_.triangles.size(); }
  /// Whether base triangles have back roots (the scene is two-sided).
  bool TwoSided() const { return scene_.twoSided; }
  /// Base vertices (the scene's, per side); every later vertex is a midpoint.
  size_t BaseVertexCount() const { return (TwoSided() ? 2 : 1) * scene_.vertices.size(); }
  /// Roots: one per base triangle and side.
  size_t RootCount() const { return (TwoSided() ? 2 : 1) * BaseTriangleCount(); }
  /// The root of the side of `baseTriangle` that a ray meets first when it
  /// travels along -normal (front) or along +normal (`backFace`). One-sided
  /// scenes have front roots only.
  NodeId RootOf(uint32_t baseTriangle, bool backFace) const {
    return backFace && TwoSided() ? NodeId(BaseTriangleCount() + baseTriangle) : NodeId(baseTriangle);
  }
  /// Whether `id` belongs to a back root's tree.
  bool IsBack(NodeId id) const { return NodeRef(id).back; }
  /// A root's record is made on first use, with the others of its chunk
  /// (from the scene: it is a pure function of it until the root is split),
  /// under a small leaf mutex of its own, so that const readers under the
  /// shared state lock may make it; the reference stays valid until the
  /// hierarchy next changes under exclusive use (a split, a collapse,
  /// ReleaseSceneRecords): hold it no longer than the lock.
  const Node& GetNode(NodeId id) const { return NodeRef(id); }
  /// A base vertex's record is made on first use like a root's (with the
  /// others of its chunk, by any reader, under a leaf mutex of its own); the
  /// reference stays valid like a node's (until a change under exclusive
  /// use: ReleaseSceneRecords, or a collapse that frees a midpoint).
  const SampleVertex& GetVertex(VertexId id) const { return VertexRef(id); }

  /// The node containing point (b1, b2) of `baseTriangle`, on the side
  /// RootOf(baseTriangle, backFace), reached by descending from that root
  /// while `descend(node)` is true for nodes with children. Points on a
  /// shared edge go to one side deterministically.
  template <class DescendPredicate>
  NodeId Locate(uint32_t baseTriangle, bool backFace, float b1, float b2, DescendPredicate descend) const;

  /// From node `from` (containing the point with node-local barycentrics
  /// `lambda`), descends further while `descend` holds; updates `lambda`.
  template <class DescendPredicate>
  NodeId Descend(NodeId from, std::array<float, 3>& lambda, DescendPredicate descend) const;

  /// Splits leaf `leaf` 1 -> 4 and propagates to neighbours as described
  /// above. Returns what changed; splitting a non-leaf does nothing.
  RefineResult Refine(NodeId leaf, const RefineOptions& options);

  /// Repeats one split exactly as Refine() made it, without propagation
  /// (replaying a snapshot): `childCount` 4 for 1 -> 4, 2 for 1 -> 2 across
  /// `splitEdge`. The splits Refine() made, repeated in the order it made
  /// them (the order of their children's ids), give the same node and vertex
  /// ids. Fails, changing nothing, for a node that is not a leaf, an unknown
  /// shape, or a 1 -> 4 split at kMaxSplitDepth.
  Status ApplySplit(NodeId node, uint8_t childCount, uint8_t splitEdge);

  /// Makes room for `nodes` nodes and `vertices` vertices in all, so that a
  /// replay of known size does not grow its tables step by step.
  void Reserve(size_t nodes, size_t vertices);

  /// Whether no leaf edge has been split on its other side (a T-vertex made
  /// by splits; the scene's own T-junctions do not count): always true after
  /// Refine(), and what replayed splits must restore.
  bool Conforming() const;

  /// The leaves whose edge joins the same two points as edge `edge` of leaf
  /// `leaf` (the leaf itself excluded).
  boost::container::small_vector<NodeId, 2> EdgeNeighbours(NodeId leaf, int edge) const;

  /// Area of a node in world units (for tests and statistics).
  float Area(NodeId id) const;
  /// Texture coordinates of a node's corner, interpolated from the base triangle.
  Vec2 CornerUv(NodeId id, int corner) const;

  /// Bytes the hierarchy's tables occupy: node and vertex arrays by capacity,
  /// and its hash maps estimated from their bucket arrays and entries (one
  /// heap node per entry: the entry, a next pointer, rounded up to the
  /// allocator's 16 bytes). An estimate, not a malloc count: what issue 15's
  /// memory budget compares. Const: callers hold the state lock shared.
  size_t MemoryBytes() const;

  /// Calls f(leafId) for every leaf under `root` (or under every root, both sides).
  template <class F>
  void ForEachLeaf(NodeId root, F&& f) const;

  // --- Collection (issue 15: the age-based collector, collector.h) --------
  //
  // A refined subtree can collapse back into its parent: the children go,
  // and so do the midpoints the parent's split added. To keep the mesh
  // conforming, every node split on the same point edge as a collapsing
  // node collapses with it (PlanCollapse finds that group: Refine's
  // propagation run backwards). Freed node blocks and vertices go to free
  // lists and their ids are reused by later splits (which keeps the tables
  // bounded); so an id held across a collection may name another node or
  // vertex afterwards. Whoever keeps node ids across a release of the state
  // lock compares StructureGeneration() (bumped by every Collapse) and maps
  // again when it changed; the SMA never collapses what a client holds or a
  // renderer is shading (collector.h), so those ids stay valid.

  /// The collector's clock, in ticks (the SMA: 100 ms). Splits stamp their
  /// children with it. Any thread.
  void SetTick(uint32_t tick) const { std::atomic_ref<uint32_t>(tick_).store(tick, std::memory_order_relaxed); }
  uint32_t Tick() const { return std::atomic_ref<uint32_t>(tick_).load(std::memory_order_relaxed); }
  /// A view displays node `id` (or a prediction asks for it): its age
  /// restarts. Any thread, concurrently with other readers (a relaxed
  /// atomic store); roots have no age (they are never collected).
  void Touch(NodeId id) const {
    if (id >= RootCount() && id < NodeCount())
      std::atomic_ref<uint32_t>(const_cast<uint32_t&>(touched_[id - RootCount()])).store(Tick(), std::memory_order_relaxed);
  }
  /// The tick of a non-root node's last Touch (or of its making).
  uint32_t LastTouched(NodeId id) const {
    return std::atomic_ref<uint32_t>(const_cast<uint32_t&>(touched_[id - RootCount()])).load(std::memory_order_relaxed);
  }
  /// Whether `id` names a node (not a freed slot).
  bool Alive(NodeId id) const { return id < RootCount() || (id < NodeCount() && nodes_[id - RootCount()].depth != 0); }
  /// Whether `v` names a vertex (not a freed slot).
  bool VertexAlive(VertexId v) const { return v < BaseVertexCount() || (v < VertexCount() && Midpoint(v).depth != 0); }
  /// Bumped by every Collapse(): node and vertex ids read before may have
  /// been freed or reused since.
  uint64_t StructureGeneration() const { return generation_; }
  size_t LiveNodeCount() const { return NodeCount() - 4 * freeBlocks4_.size() - 2 * freeBlocks2_.size(); }
  size_t LiveVertexCount() const { return VertexCount() - freeVertices_.size(); }
  /// What the live nodes and vertices and the maps take: MemoryBytes() less
  /// the freed slots waiting for reuse and the tables' unused chunk tails,
  /// from counts (O(1), like MemoryBytes): what the collector steers by.
  size_t LiveBytes() const;

  /// A split node whose children are all leaves: what can collapse.
  bool Collapsible(NodeId id) const;
  /// Whether the node was collapsed before (a later split of it re-makes
  /// vertices that were evicted: the re-shading the budget costs).
  bool WasCollapsed(NodeId id) const { return NodeRef(id).collapsed; }

  /// A set of splits that collapse together, and what that frees.
  struct CollapseGroup {
    std::vector<NodeId> nodes;            // the split nodes that go, deepest first: whole subtrees
    std::vector<NodeId> freedNodes;       // their children
    std::vector<VertexId> freedVertices;  // the midpoints their splits added
  };
  /// The group that must collapse with `node` (a split node) so that no leaf
  /// keeps a T-vertex: `node`'s subtree, and the subtree of every node split
  /// on a point edge that a member split, until closed. False (group
  /// unspecified) if it would exceed `maxNodes` split nodes.
  bool PlanCollapse(NodeId node, size_t maxNodes, CollapseGroup& group) const;
  /// Frees the root records of chunks whose roots are all leaves, and every
  /// base vertex record: both are pure functions of the scene, made again
  /// on first use (as at start), so memory follows what views need now.
  /// Callers hold the hierarchy exclusively (no reader holds a record: the
  /// SMA's state lock exclusive). Forgets WasCollapsed() of those roots.
  /// Returns the bytes freed.
  size_t ReleaseSceneRecords();
  /// Collapses a group PlanCollapse made (with no split or collapse in
  /// between): the subtrees' tops become leaves; their descendants and the
  /// midpoints they added are freed.
  void Collapse(const CollapseGroup& group);

 private:
  using EdgeKey = uint64_t;
  static EdgeKey KeyOf(uint32_t a, uint32_t b) {
    return a < b ? (EdgeKey(a) << 32) | b : (EdgeKey(b) << 32) | a;
  }
  EdgeKey PointEdge(NodeId id, int edge) const;
  /// The midpoint vertex of a node's edge, made (or a freed slot reused)
  /// when the edge has none yet; `made` says which.
  VertexId MidpointVertex(NodeId id, int edge, bool& made);
  /// `count` (2 or 4) consecutive node ids for a split's children: a freed
  /// block, or new records.
  NodeId AllocateChildren(int count);
  void InitChild(NodeId child, NodeId parent, const std::array<VertexId, 3>& v, const std::array<Vec2, 3>& bary);
  void Split4(NodeId id, RefineResult& result);
  void Split2(NodeId id, int edge, RefineResult& result);
  bool IsRoot(NodeId id) const { return id < RootCount(); }
  static constexpr size_t kRootChunkNodes = 1024;  // root records made together (64 KiB)
  const Node& NodeRef(NodeId id) const {
    if (id >= RootCount()) return nodes_[id - RootCount()];
    const Node* chunk = rootChunks_[id / kRootChunkNodes].load(std::memory_order_acquire);
    if (!chunk) chunk = MakeRootChunk(id / kRootChunkNodes);
    return chunk[id % kRootChunkNodes];
  }
  // Writers (splits) hold the state lock exclusively.
  Node& MutableNode(NodeId id) { return const_cast<Node&>(NodeRef(id)); }
  // Whether a root has no children, without making its record.
  bool RootIsLeaf(NodeId root) const {
    const Node* chunk = rootChunks_[root / kRootChunkNodes].load(std::memory_order_acquire);
    return !chunk || chunk[root % kRootChunkNodes].IsLeaf();
  }
  std::array<VertexId, 3> RootCorners(NodeId root) const;
  Node* MakeRootChunk(size_t chunk) const;
  static constexpr size_t kBaseChunkVertices = 1024;  // base vertex records made together (44 KiB)
  const SampleVertex& VertexRef(VertexId id) const {
    if (id >= baseVertexCount_) return Midpoint(id);
    const SampleVertex* chunk = baseChunks_[id / kBaseChunkVertices].load(std::memory_order_acquire);
    if (!chunk) chunk = MakeBaseChunk(id / kBaseChunkVertices);
    return chunk[id % kBaseChunkVertices];
  }
  // The one place midpoints are found in vertices_ (which holds only them).
  const SampleVertex& Midpoint(VertexId id) const { return vertices_[id - baseVertexCount_]; }
  SampleVertex& MutableMidpoint(VertexId id) { return vertices_[id - baseVertexCount_]; }
  SampleVertex* MakeBaseChunk(size_t chunk) const;
  // A vertex's point id, without making a base vertex's record.
  uint32_t PointOf(VertexId id) const {
    const size_t sceneVertices = basePlaces_.size();
    if (id < sceneVertices) return basePlaces_[id].point;
    if (id < BaseVertexCount()) return basePlaces_[id - sceneVertices].point + frontPointCount_;
    return Midpoint(id).point;
  }
  // Calls f(root) for every root with an edge on the two points of `key`
  // (split or not), in the order of their ids, a root once per such edge.
  template <class F>
  void ForEachRootOnPointEdge(EdgeKey key, F&& f) const;
  void LinkEdges(NodeId id);    // non-root leaves only: roots are in the root edge table
  void UnlinkEdges(NodeId id);
  /// The leaves whose edge joins the two points of `key`: unsplit roots
  /// from the root edge table (by root id), then other leaves (in the
  /// order they were made) -- the order Refine() splits them in.
  boost::container::small_vector<NodeId, 2> LeavesOnPointEdge(EdgeKey key) const;
  float HeightToEdgeRatio(NodeId id, int edge) const;
  /// MemoryBytes() without the rare out-of-line leaf lists: O(1).
  size_t TableBytes() const;
  /// Whether node `id` is split on point edge `key` (has a midpoint on it).
  bool SplitsPointEdge(NodeId id, EdgeKey key) const;

  const Scene& scene_;
  ChunkedArray<Node> nodes_;  // nodes made by splits: id RootCount() + i (chunked: growth never copies)
  // Root records (issue 15: a base triangle costs no node record until
  // something needs it): chunk pointers, null until made; made chunks are
  // owned by rootChunkStore_ and freed only by ReleaseSceneRecords.
  // rootMutex_ (a leaf) guards rootChunkStore_ and serialises making; held
  // in unique_ptrs so that a Hierarchy stays movable.
  std::unique_ptr<std::atomic<Node*>[]> rootChunks_;
  std::unique_ptr<std::mutex> rootMutex_;
  mutable std::vector<std::pair<size_t, std::unique_ptr<Node[]>>> rootChunkStore_;  // (chunk, records)
  // Base vertices (issue 15: a scene vertex costs 8 bytes until something
  // needs its record): per scene vertex, what the records are made from
  // besides the scene; records are made like roots' (baseChunks_ null until
  // made, owned by baseChunkStore_ under baseMutex_, a leaf).
  struct BasePlace {
    uint32_t point;         // the front vertex's; the back's is this + frontPointCount_
    uint32_t baseTriangle;  // the lowest-numbered triangle using the vertex (0 for none)
  };
  std::vector<BasePlace> basePlaces_;
  size_t baseVertexCount_ = 0;    // BaseVertexCount(), kept for GetVertex's fast path
  uint32_t frontPointCount_ = 0;  // points of the front base vertices: 0 .. frontPointCount_ - 1
  std::unique_ptr<std::atomic<SampleVertex*>[]> baseChunks_;
  std::unique_ptr<std::mutex> baseMutex_;
  mutable std::vector<std::pair<size_t, std::unique_ptr<SampleVertex[]>>> baseChunkStore_;  // (chunk, records)
  ChunkedArray<SampleVertex> vertices_;  // midpoints only: id BaseVertexCount() + i (chunked, like nodes_)
  uint32_t pointCount_ = 0;
  std::unordered_map<EdgeKey, VertexId> midpointOfVertexEdge_;  // vertex edge -> midpoint vertex
  std::unordered_map<EdgeKey, uint32_t> midpointOfPointEdge_;   // point edge -> midpoint point
  // Leaves by point edge, for leaves that are not roots.
  std::unordered_map<EdgeKey, boost::container::small_vector<NodeId, 2>> leavesOfPointEdge_;
  // Bytes of the lists above that left their inline storage (more than two
  // leaves on a point edge: non-manifold input), kept as they change so that
  // MemoryBytes (asked by every stats request) does not walk the table.
  size_t leafListHeapBytes_ = 0;
  // Roots' edges by point edge (issue 15: a base triangle costs no hash map
  // entries until it is split), made once, front roots only (a back root's
  // edges are its front's, points shifted by frontPointCount_): the edges
  // whose smaller point is p are rootEdges_[rootEdgeStart_[p] ..
  // rootEdgeStart_[p + 1]), each as 3 * root + edge, ascending; the other
  // point is read from the root's corners. A root in them is a leaf while it
  // has no children.
  std::vector<uint32_t> rootEdgeStart_;
  std::vector<uint32_t> rootEdges_;
  // Collection (see "Collection" above).
  ChunkedArray<uint32_t> touched_;   // per non-root node: tick of its last Touch (atomic_ref)
  alignas(std::atomic_ref<uint32_t>::required_alignment) mutable uint32_t tick_ = 0;  // atomic_ref (keeps Hierarchy movable)
  uint64_t generation_ = 0;
  std::vector<NodeId> freeBlocks4_;  // first ids of freed blocks of 4 children
  std::vector<NodeId> freeBlocks2_;  // ... of 2 children
  std::vector<VertexId> freeVertices_;
};

// --- Template definitions ---------------------------------------------------

template <class DescendPredicate>
NodeId Hierarchy::Descend(NodeId from, std::array<float, 3>& l, DescendPredicate descend) const {
  NodeId id = from;
  while (true) {
    const Node& n = NodeRef(id);
    if (n.childCount == 0 || !descend(n)) return id;
    if (n.childCount == 4) {
      // Child order and the barycentric maps are derived in hierarchy.cpp.
      if (l[0] >= 0.5f) {
        l = {2.0f * l[0] - 1.0f, 2.0f * l[1], 2.0f * l[2]};
        id = n.firstChild;
      } else if (l[1] >= 0.5f) {
        l = {2.0f * l[0], 2.0f * l[1] - 1.0f, 2.0f * l[2]};
        id = n.firstChild + 1;
      } else if (l[2] >= 0.5f) {
        l = {2.0f * l[0], 2.0f * l[1], 2.0f * l[2] - 1.0f};
        id = n.firstChild + 2;
      } else {
        l = {1.0f - 2.0f * l[0], 1.0f - 2.0f * l[1], 1.0f - 2.0f * l[2]};
        id = n.firstChild + 3;
      }
    } else {
      // Split of edge k (corners i = k+1, j = k+2) at its midpoint m:
      // child 0 = (k, i, m), child 1 = (k, m, j).
      const int k = n.splitEdge, i = (k + 1) % 3, j = (k + 2) % 3;
      if (l[i] >= l[j]) {
        l = {l[k], l[i] - l[j], 2.0f * l[j]};
        id = n.firstChild;
      } else {
        l = {l[k], 2.0f * l[i], l[j] - l[i]};
        id = n.firstChild + 1;
      }
    }
  }
}

template <class DescendPredicate>
NodeId Hierarchy::Locate(uint32_t baseTriangle, bool backFace, float b1, float b2, DescendPredicate descend) const {
  const NodeId root = RootOf(baseTriangle, backFace);
  // A back root's corners are the base triangle's in the order (0, 2, 1).
  std::array<float, 3> lambda = NodeRef(root).back ? std::array<float, 3>{1.0f - b1 - b2, b2, b1}
                                                  : std::array<float, 3>{1.0f - b1 - b2, b1, b2};
  return Descend(root, lambda, descend);
}

template <class F>
void Hierarchy::ForEachLeaf(NodeId root, F&& f) const {
  if (root == kNoNode) {
    for (NodeId r = 0; r < RootCount(); ++r) ForEachLeaf(r, f);
    return;
  }
  // Iterative: hierarchies can be deep.
  boost::container::small_vector<NodeId, 64> stack{root};
  while (!stack.empty()) {
    const NodeId id = stack.back();
    stack.pop_back();
    const Node& n = NodeRef(id);
    if (n.childCount == 0) {
      f(id);
      continue;
    }
    for (uint8_t c = 0; c < n.childCount; ++c) stack.push_back(n.firstChild + c);
  }
}

}  // namespace penumbra::sma
