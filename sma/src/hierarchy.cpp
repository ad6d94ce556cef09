#include "penumbra/sma/hierarchy.h"

#include <algorithm>
#include <cstring>
#include <deque>

#include <fmt/format.h>

#include "penumbra/common/hash.h"
#include "penumbra/sma/memory_usage.h"

namespace penumbra::sma {

// Child layouts (edge k is opposite corner k; m_k is its midpoint):
//   1 -> 4: child 0 = (c0, m2, m1)   child 1 = (m2, c1, m0)
//           child 2 = (m1, m0, c2)   child 3 = (m0, m1, m2)  (the middle one)
//   1 -> 2 on edge k, with i = k+1, j = k+2 (mod 3):
//           child 0 = (ck, ci, mk)   child 1 = (ck, mk, cj)
// All children keep the parent's counter-clockwise orientation. The
// barycentric maps in Hierarchy::Descend follow from these layouts: e.g. for
// child 0 of a 1 -> 4 split, p = l0 c0 + l1 c1 + l2 c2 = mu0 c0 + mu1 (c0+c1)/2
// + mu2 (c0+c2)/2 gives mu = (2 l0 - 1, 2 l1, 2 l2).

namespace {

struct PointKey {
  uint32_t x, y, z;
  bool operator==(const PointKey&) const = default;
};
struct PointKeyHash {
  size_t operator()(const PointKey& k) const { return size_t(HashCombine(HashCombine(Mix64(k.x), k.y), k.z)); }
};
PointKey KeyOfPosition(const Vec3& p) {
  PointKey k;
  const float x = p.x + 0.0f, y = p.y + 0.0f, z = p.z + 0.0f;  // fold -0 into +0
  std::memcpy(&k.x, &x, 4);
  std::memcpy(&k.y, &y, 4);
  std::memcpy(&k.z, &z, 4);
  return k;
}

constexpr std::array<Vec2, 3> kRootBary = {Vec2(0.0f, 0.0f), Vec2(1.0f, 0.0f), Vec2(0.0f, 1.0f)};
// A back root's corners: the base triangle's 0, 2, 1.
constexpr std::array<Vec2, 3> kBackRootBary = {Vec2(0.0f, 0.0f), Vec2(0.0f, 1.0f), Vec2(1.0f, 0.0f)};

}  // namespace

Hierarchy::Hierarchy(const Scene& scene) : scene_(scene) {
  // Base vertices: one per scene vertex (and side); vertices at one point
  // (split at a crease) share a point id. Their records are made on first
  // use (MakeBaseChunk); here only what that needs besides the scene.
  const size_t sceneVertices = scene.vertices.size();
  const size_t triangles = scene.triangles.size();
  PENUMBRA_CHECK(triangles <= (size_t(1) << 31) / 3 && sceneVertices <= (size_t(1) << 31),
                 "scene too large for 32-bit hierarchy ids");
  basePlaces_.resize(sceneVertices, BasePlace{0, 0});
  std::unordered_map<PointKey, uint32_t, PointKeyHash> pointOf;
  pointOf.reserve(scene.vertices.size());
  // Movable objects' vertices are in their own object spaces, stored part
  // after part: a point of one part is never a point of another (an
  // object-space corner at the static floor's world corner is no neighbour).
  std::vector<bool> partStarts(sceneVertices + 1, false);
  for (const MovableObject& o : scene.objects)
    if (o.firstVertex < sceneVertices) partStarts[o.firstVertex] = true;
  for (size_t i = 0; i < scene.vertices.size(); ++i) {
    if (partStarts[i]) pointOf.clear();  // ids keep counting: pointOf.size() below is not the next id
    auto [it, added] = pointOf.try_emplace(KeyOfPosition(scene.vertices[i].position), pointCount_);
    pointCount_ += added;
    basePlaces_[i].point = it->second;
  }
  // Each base vertex needs a triangle it lies on, for the renderer: the
  // lowest-numbered one (its corner is found again in MakeBaseChunk).
  for (uint32_t t = uint32_t(triangles); t-- > 0;)
    for (int c = 0; c < 3; ++c) basePlaces_[scene.triangles[t].v[c]].baseTriangle = t;
  frontPointCount_ = pointCount_;
  // The back side's vertices: the same places, the normals negated, and
  // points of their own, so that adjacency never crosses between sides.
  if (scene.twoSided) pointCount_ *= 2;
  baseVertexCount_ = BaseVertexCount();
  const size_t baseChunks = (BaseVertexCount() + kBaseChunkVertices - 1) / kBaseChunkVertices;
  baseChunks_.reset(new std::atomic<SampleVertex*>[baseChunks]());
  baseMutex_ = std::make_unique<std::mutex>();
  // Root records are made on first use (RootNode), a chunk at a time.
  rootChunks_.reset(new std::atomic<Node*>[(RootCount() + kRootChunkNodes - 1) / kRootChunkNodes]());
  rootMutex_ = std::make_unique<std::mutex>();
  // The root edge table, front roots only, by a counting sort on each edge's
  // smaller point; filled in root order, so each point's edges ascend.
  const auto pointOfCorner = [&](uint32_t t, int c) { return basePlaces_[scene.triangles[t].v[c]].point; };
  rootEdgeStart_.assign(size_t(frontPointCount_) + 1, 0);
  for (uint32_t t = 0; t < triangles; ++t)
    for (int k = 0; k < 3; ++k)
      ++rootEdgeStart_[std::min(pointOfCorner(t, (k + 1) % 3), pointOfCorner(t, (k + 2) % 3)) + 1];
  for (size_t p = 0; p < frontPointCount_; ++p) rootEdgeStart_[p + 1] += rootEdgeStart_[p];
  rootEdges_.resize(3 * triangles);
  std::vector<uint32_t> next(rootEdgeStart_.begin(), rootEdgeStart_.end() - 1);
  for (uint32_t t = 0; t < triangles; ++t)
    for (int k = 0; k < 3; ++k)
      rootEdges_[next[std::min(pointOfCorner(t, (k + 1) % 3), pointOfCorner(t, (k + 2) % 3))]++] = 3 * t + uint32_t(k);
}

SampleVertex* Hierarchy::MakeBaseChunk(size_t chunk) const {
  std::lock_guard lock(*baseMutex_);
  SampleVertex* vertices = baseChunks_[chunk].load(std::memory_order_relaxed);
  if (vertices) return vertices;  // another reader made it meanwhile
  auto made = std::make_unique<SampleVertex[]>(kBaseChunkVertices);
  const size_t sceneVertices = basePlaces_.size();
  for (size_t i = 0; i < kBaseChunkVertices; ++i) {
    const size_t id = chunk * kBaseChunkVertices + i;
    if (id >= BaseVertexCount()) break;
    const bool back = id >= sceneVertices;
    const size_t index = back ? id - sceneVertices : id;
    const BasePlace& place = basePlaces_[index];
    SampleVertex& v = made[i];
    v.position = scene_.vertices[index].position;
    v.normal = back ? -scene_.vertices[index].normal : scene_.vertices[index].normal;
    v.point = place.point + (back ? frontPointCount_ : 0);
    v.baseTriangle = place.baseTriangle;
    // The vertex's corner of its base triangle (the last, should it be
    // there twice); none for a vertex no triangle uses: (0, 0) on triangle 0.
    if (place.baseTriangle < scene_.triangles.size()) {
      const auto& corners = scene_.triangles[place.baseTriangle].v;
      for (int c = 2; c >= 0; --c)
        if (corners[c] == index) {
          v.bary = kRootBary[c];
          break;
        }
    }
  }
  vertices = made.get();
  baseChunkStore_.emplace_back(chunk, std::move(made));
  // Release: a reader that finds the pointer finds the records whole.
  baseChunks_[chunk].store(vertices, std::memory_order_release);
  return vertices;
}

std::array<VertexId, 3> Hierarchy::RootCorners(NodeId root) const {
  const size_t triangles = BaseTriangleCount();
  if (root < triangles) return scene_.triangles[root].v;
  const auto& v = scene_.triangles[root - triangles].v;
  const VertexId offset = VertexId(scene_.vertices.size());
  return {offset + v[0], offset + v[2], offset + v[1]};
}

Node* Hierarchy::MakeRootChunk(size_t chunk) const {
  std::lock_guard lock(*rootMutex_);
  Node* nodes = rootChunks_[chunk].load(std::memory_order_relaxed);
  if (nodes) return nodes;  // another reader made it meanwhile
  auto made = std::make_unique<Node[]>(kRootChunkNodes);
  const size_t triangles = BaseTriangleCount();
  for (size_t i = 0; i < kRootChunkNodes; ++i) {
    const NodeId root = NodeId(chunk * kRootChunkNodes + i);
    if (root >= RootCount()) break;
    Node& n = made[i];
    n.back = root >= triangles;
    n.baseTriangle = uint32_t(n.back ? root - triangles : root);
    n.v = RootCorners(root);
    n.bary = n.back ? kBackRootBary : kRootBary;
  }
  nodes = made.get();
  rootChunkStore_.emplace_back(chunk, std::move(made));
  // Release: a reader that finds the pointer finds the records whole.
  rootChunks_[chunk].store(nodes, std::memory_order_release);
  return nodes;
}

Hierarchy::EdgeKey Hierarchy::PointEdge(NodeId id, int edge) const {
  const Node& n = NodeRef(id);
  return KeyOf(PointOf(n.v[(edge + 1) % 3]), PointOf(n.v[(edge + 2) % 3]));
}

namespace {
template <class SmallVector>
size_t HeapBytes(const SmallVector& v) {
  return v.capacity() > v.static_capacity ? v.capacity() * sizeof(typename SmallVector::value_type) : 0;
}
}  // namespace

void Hierarchy::LinkEdges(NodeId id) {
  if (IsRoot(id)) return;
  for (int k = 0; k < 3; ++k) {
    auto& leaves = leavesOfPointEdge_[PointEdge(id, k)];
    leafListHeapBytes_ -= HeapBytes(leaves);
    leaves.push_back(id);
    leafListHeapBytes_ += HeapBytes(leaves);
  }
}

void Hierarchy::UnlinkEdges(NodeId id) {
  if (IsRoot(id)) return;  // a split root leaves the table's leaves by having children
  for (int k = 0; k < 3; ++k) {
    auto it = leavesOfPointEdge_.find(PointEdge(id, k));
    if (it == leavesOfPointEdge_.end()) continue;
    auto& leaves = it->second;
    leafListHeapBytes_ -= HeapBytes(leaves);
    leaves.erase(std::remove(leaves.begin(), leaves.end(), id), leaves.end());
    if (leaves.empty()) leavesOfPointEdge_.erase(it);
    else leafListHeapBytes_ += HeapBytes(leaves);
  }
}

template <class F>
void Hierarchy::ForEachRootOnPointEdge(EdgeKey key, F&& f) const {
  uint32_t a = uint32_t(key >> 32), b = uint32_t(key);  // a <= b
  // Only base vertices' points are in the table: the front's below
  // frontPointCount_, the back's (two-sided scenes) the next as many.
  NodeId side = 0;
  if (a >= frontPointCount_) {
    if (!TwoSided() || b >= 2 * size_t(frontPointCount_)) return;
    a -= frontPointCount_;
    b -= frontPointCount_;
    side = NodeId(BaseTriangleCount());
  } else if (b >= frontPointCount_) {
    return;
  }
  for (uint32_t i = rootEdgeStart_[a]; i < rootEdgeStart_[a + 1]; ++i) {
    const uint32_t t = rootEdges_[i] / 3, k = rootEdges_[i] % 3;
    const auto& corners = scene_.triangles[t].v;
    if (std::max(basePlaces_[corners[(k + 1) % 3]].point, basePlaces_[corners[(k + 2) % 3]].point) == b)
      f(NodeId(side + t));
  }
}

boost::container::small_vector<NodeId, 2> Hierarchy::LeavesOnPointEdge(EdgeKey key) const {
  boost::container::small_vector<NodeId, 2> out;
  ForEachRootOnPointEdge(key, [&](NodeId root) {
    if (RootIsLeaf(root)) out.push_back(root);
  });
  if (auto it = leavesOfPointEdge_.find(key); it != leavesOfPointEdge_.end())
    out.insert(out.end(), it->second.begin(), it->second.end());
  return out;
}

VertexId Hierarchy::MidpointVertex(NodeId id, int edge, bool& made) {
  const int i = (edge + 1) % 3, j = (edge + 2) % 3;
  const Node& n = NodeRef(id);
  const VertexId a = n.v[i], b = n.v[j];
  // A freed slot is reused first (the collector's free list), else a new one.
  const VertexId next = freeVertices_.empty() ? VertexId(VertexCount()) : freeVertices_.back();
  auto [it, inserted] = midpointOfVertexEdge_.try_emplace(KeyOf(a, b), next);
  made = inserted;
  if (!inserted) return it->second;

  const SampleVertex& va = VertexRef(a);
  const SampleVertex& vb = VertexRef(b);
  SampleVertex m;
  // The midpoint of the two positions, computed the same way on both sides
  // of the edge, so neighbours agree on it to the bit.
  m.position = 0.5f * (va.position + vb.position);
  const Vec3 sum = va.normal + vb.normal;
  const float len = glm::length(sum);
  m.normal = len > 1e-6f ? sum / len : va.normal;
  m.point = midpointOfPointEdge_.try_emplace(KeyOf(va.point, vb.point), pointCount_).first->second;
  if (m.point == pointCount_) ++pointCount_;
  m.baseTriangle = n.baseTriangle;
  m.bary = 0.5f * (n.bary[i] + n.bary[j]);
  m.depth = uint8_t(std::min(255, n.depth + 1));
  if (next == VertexCount()) {
    vertices_.push_back(m);
  } else {
    freeVertices_.pop_back();
    MutableMidpoint(next) = m;
  }
  return it->second;
}

NodeId Hierarchy::AllocateChildren(int count) {
  std::vector<NodeId>& freed = count == 4 ? freeBlocks4_ : freeBlocks2_;
  if (!freed.empty()) {
    const NodeId first = freed.back();
    freed.pop_back();
    return first;
  }
  if (count == 2 && !freeBlocks4_.empty()) {  // half of a freed block of 4; the other half waits
    const NodeId first = freeBlocks4_.back();
    freeBlocks4_.pop_back();
    freeBlocks2_.push_back(first + 2);
    return first;
  }
  const NodeId first = NodeId(RootCount() + nodes_.size());
  for (int i = 0; i < count; ++i) {
    nodes_.push_back(Node{});
    touched_.push_back(0);
  }
  return first;
}

void Hierarchy::InitChild(NodeId id, NodeId parent, const std::array<VertexId, 3>& v,
                          const std::array<Vec2, 3>& bary) {
  Node child;
  const Node& p = NodeRef(parent);
  child.baseTriangle = p.baseTriangle;
  child.back = p.back;
  child.v = v;
  child.bary = bary;
  child.parent = parent;
  child.depth = uint8_t(std::min(255, p.depth + 1));
  nodes_[id - RootCount()] = child;
  touched_[id - RootCount()] = Tick();  // born young: the collector leaves it alone for a while
  LinkEdges(id);
}

void Hierarchy::Split4(NodeId id, RefineResult& result) {
  std::array<VertexId, 3> m;
  for (int k = 0; k < 3; ++k) {
    bool made = false;
    m[k] = MidpointVertex(id, k, made);
    if (made) result.newVertices.push_back(m[k]);
    if (made && NodeRef(id).collapsed) ++result.remadeVertices;
  }
  UnlinkEdges(id);
  const std::array<VertexId, 3> c = NodeRef(id).v;
  const std::array<Vec2, 3> b = NodeRef(id).bary;
  const std::array<Vec2, 3> mb = {0.5f * (b[1] + b[2]), 0.5f * (b[2] + b[0]), 0.5f * (b[0] + b[1])};
  const NodeId first = AllocateChildren(4);
  InitChild(first, id, {c[0], m[2], m[1]}, {b[0], mb[2], mb[1]});
  InitChild(first + 1, id, {m[2], c[1], m[0]}, {mb[2], b[1], mb[0]});
  InitChild(first + 2, id, {m[1], m[0], c[2]}, {mb[1], mb[0], b[2]});
  InitChild(first + 3, id, {m[0], m[1], m[2]}, {mb[0], mb[1], mb[2]});
  Node& n = MutableNode(id);
  n.firstChild = first;
  n.childCount = 4;
  n.mid = m;
  result.split.push_back(id);
}

void Hierarchy::Split2(NodeId id, int k, RefineResult& result) {
  bool made = false;
  const VertexId m = MidpointVertex(id, k, made);
  if (made) result.newVertices.push_back(m);
  if (made && NodeRef(id).collapsed) ++result.remadeVertices;
  UnlinkEdges(id);
  const int i = (k + 1) % 3, j = (k + 2) % 3;
  const std::array<VertexId, 3> c = NodeRef(id).v;
  const std::array<Vec2, 3> b = NodeRef(id).bary;
  const Vec2 mb = 0.5f * (b[i] + b[j]);
  const NodeId first = AllocateChildren(2);
  InitChild(first, id, {c[k], c[i], m}, {b[k], b[i], mb});
  InitChild(first + 1, id, {c[k], m, c[j]}, {b[k], mb, b[j]});
  Node& n = MutableNode(id);
  n.firstChild = first;
  n.childCount = 2;
  n.splitEdge = uint8_t(k);
  n.mid[k] = m;
  result.split.push_back(id);
}

float Hierarchy::HeightToEdgeRatio(NodeId id, int edge) const {
  const Node& n = NodeRef(id);
  const Vec3& pk = VertexRef(n.v[edge]).position;
  const Vec3& pi = VertexRef(n.v[(edge + 1) % 3]).position;
  const Vec3& pj = VertexRef(n.v[(edge + 2) % 3]).position;
  const float base = glm::length(pj - pi);
  if (!(base > 0.0f)) return 0.0f;
  // height = 2 * area / base; the ratio to the base is 2 * area / base^2.
  return glm::length(glm::cross(pi - pk, pj - pk)) / (base * base);
}

RefineResult Hierarchy::Refine(NodeId leaf, const RefineOptions& options) {
  RefineResult result;
  if (!Alive(leaf) || !NodeRef(leaf).IsLeaf() || NodeRef(leaf).depth >= options.maxDepth) return result;

  // Point edges that have just received a midpoint: every leaf still having
  // such an edge whole must be split on it.
  std::deque<EdgeKey> splitEdges;
  auto split4 = [&](NodeId id) {
    const EdgeKey keys[3] = {PointEdge(id, 0), PointEdge(id, 1), PointEdge(id, 2)};
    Split4(id, result);
    splitEdges.insert(splitEdges.end(), std::begin(keys), std::end(keys));
  };
  uint32_t budget = options.maxSplits4;
  split4(leaf);
  --budget;
  while (!splitEdges.empty()) {
    const EdgeKey key = splitEdges.front();
    splitEdges.pop_front();
    while (true) {
      const auto leaves = LeavesOnPointEdge(key);
      if (leaves.empty()) break;
      const NodeId neighbour = leaves.front();  // splitting it removes it from the list
      int edge = 0;
      while (edge < 2 && PointEdge(neighbour, edge) != key) ++edge;
      const bool tall = HeightToEdgeRatio(neighbour, edge) >= options.aspectThreshold;
      if (tall && budget > 0 && NodeRef(neighbour).depth < options.maxDepth) {
        split4(neighbour);
        --budget;
      } else {
        Split2(neighbour, edge, result);
      }
    }
  }
  return result;
}

Status Hierarchy::ApplySplit(NodeId node, uint8_t childCount, uint8_t splitEdge) {
  if (!Alive(node)) return Fail(fmt::format("node {} does not exist ({} nodes)", node, NodeCount()));
  if (!NodeRef(node).IsLeaf()) return Fail(fmt::format("node {} is split already", node));
  RefineResult ignored;
  if (childCount == 4) {
    if (NodeRef(node).depth >= kMaxSplitDepth)
      return Fail(fmt::format("node {} is at depth {}, too deep for a 1 -> 4 split", node, NodeRef(node).depth));
    Split4(node, ignored);
  } else if (childCount == 2 && splitEdge < 3) {
    Split2(node, splitEdge, ignored);
  } else {
    return Fail(fmt::format("node {}: no split into {} children across edge {}", node, childCount, splitEdge));
  }
  return Status::Ok();
}

void Hierarchy::Reserve(size_t nodes, size_t vertices) {
  nodes_.reserve(nodes > RootCount() ? nodes - RootCount() : 0);
  touched_.reserve(nodes > RootCount() ? nodes - RootCount() : 0);
  vertices_.reserve(vertices > BaseVertexCount() ? vertices - BaseVertexCount() : 0);
  const size_t midpoints = vertices > VertexCount() ? vertices - VertexCount() : 0;
  midpointOfVertexEdge_.reserve(midpointOfVertexEdge_.size() + midpoints);
  midpointOfPointEdge_.reserve(midpointOfPointEdge_.size() + midpoints);
  // About 3/4 of the nodes are leaves, with 3 edges each, most shared by two.
  leavesOfPointEdge_.reserve(std::max(leavesOfPointEdge_.size(), nodes + nodes / 8));
}

bool Hierarchy::Conforming() const {
  for (const auto& [key, leaves] : leavesOfPointEdge_)
    if (!leaves.empty() && midpointOfPointEdge_.contains(key)) return false;
  // An unsplit root on a point edge that has a midpoint: asked per midpoint
  // (the roots' table has no entry per side to walk).
  for (const auto& [key, point] : midpointOfPointEdge_) {
    bool leaf = false;
    ForEachRootOnPointEdge(key, [&](NodeId root) { leaf = leaf || RootIsLeaf(root); });
    if (leaf) return false;
  }
  return true;
}

boost::container::small_vector<NodeId, 2> Hierarchy::EdgeNeighbours(NodeId leaf, int edge) const {
  boost::container::small_vector<NodeId, 2> out;
  for (NodeId n : LeavesOnPointEdge(PointEdge(leaf, edge)))
    if (n != leaf) out.push_back(n);
  return out;
}

size_t Hierarchy::TableBytes() const {
  size_t rootChunks, baseChunks;
  {
    std::lock_guard lock(*rootMutex_);
    rootChunks = rootChunkStore_.size();
  }
  {
    std::lock_guard lock(*baseMutex_);
    baseChunks = baseChunkStore_.size();
  }
  size_t bytes = nodes_.MemoryBytes() + touched_.MemoryBytes() + vertices_.MemoryBytes() +
                 (freeBlocks4_.capacity() + freeBlocks2_.capacity() + freeVertices_.capacity()) * sizeof(NodeId) +
                 rootChunks * kRootChunkNodes * sizeof(Node) +
                 (RootCount() + kRootChunkNodes - 1) / kRootChunkNodes * sizeof(std::atomic<Node*>) +
                 baseChunks * kBaseChunkVertices * sizeof(SampleVertex) +
                 (BaseVertexCount() + kBaseChunkVertices - 1) / kBaseChunkVertices *
                     sizeof(std::atomic<SampleVertex*>) +
                 basePlaces_.capacity() * sizeof(BasePlace) + rootEdgeStart_.capacity() * sizeof(uint32_t) +
                 rootEdges_.capacity() * sizeof(uint32_t);
  bytes += UnorderedMapBytes(midpointOfVertexEdge_) + UnorderedMapBytes(midpointOfPointEdge_) +
           UnorderedMapBytes(leavesOfPointEdge_);
  return bytes;
}

size_t Hierarchy::MemoryBytes() const {
  // A list of more than two leaves on one point edge (non-manifold input)
  // leaves the small_vector's inline storage; rare, and counted whole.
  return TableBytes() + leafListHeapBytes_;
}

float Hierarchy::Area(NodeId id) const {
  const Node& n = NodeRef(id);
  const Vec3& p0 = VertexRef(n.v[0]).position;
  return 0.5f * glm::length(glm::cross(VertexRef(n.v[1]).position - p0, VertexRef(n.v[2]).position - p0));
}

Vec2 Hierarchy::CornerUv(NodeId id, int corner) const {
  const Node& n = NodeRef(id);
  const Triangle& t = scene_.triangles[n.baseTriangle];
  const Vec2 b = n.bary[corner];
  return (1.0f - b.x - b.y) * t.uv[0] + b.x * t.uv[1] + b.y * t.uv[2];
}

}  // namespace penumbra::sma
