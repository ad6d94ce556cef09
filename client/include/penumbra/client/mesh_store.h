#pragma once
// What the client holds: the visible, shaded triangles and their vertices,
// exactly as the SMA's deltas built them (docs/protocol.md, "Delta"), laid
// out in slots that mirror the GPU buffers one to one.
//
// Vertices live in one slot array (a texture buffer on the GPU, fetched by
// slot index); triangles live in per-texture groups of slots, each corner
// naming its vertex slot, so that the renderer draws each group with one
// call and one texture bound. A delta touches only the slots it adds or
// removes: removed triangle slots are rewritten as empty (drawn as nothing)
// and reused by later additions, and the touched slots are recorded as
// dirty ranges for the renderer to upload. No GL here.
//
// Movable objects (issue 14): a vertex of a movable object is kept in its
// object's space, with the object's id, and the vertex shader places it
// with the object's transform from a small table (one entry per object,
// entry 0 the identity for the static part). A MOVED delta changes only
// that table: no vertex slot is rewritten or re-uploaded, however large the
// object, and the geometry is never re-sent. (The alternative, world
// positions re-computed on the CPU, would re-upload every vertex of the
// object on each move: 30 moves/s of a 100k-vertex chair is 144 MB/s.)
//
// Threads: owned by the render thread; not thread-safe.

#include <cstdint>
#include <optional>
#include <span>
#include <unordered_map>
#include <utility>
#include <vector>

#include "penumbra/client/slots.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/math.h"
#include "penumbra/common/rigid_transform.h"
#include "penumbra/common/tonemap.h"

namespace penumbra::wire {
class Delta;  // penumbra/wire.pb.h, included by mesh_store.cpp
}

namespace penumbra::client {

/// One vertex slot as the vertex shader fetches it: three RGBA32F texels.
struct GpuVertex {
  float position[4];    // xyz: world space (static), object space (movable); w: object id, 0 static
  float radiance[4];    // linear RGB leaving the surface toward the viewer side; a unused
  float irradiance[4];  // linear RGB irradiance E (textured materials); a unused
};
static_assert(sizeof(GpuVertex) == 48, "the shader reads three vec4 texels per vertex");

/// One entry of the object transform table the vertex shader reads: the
/// object-to-world transform's three rows (r0 r1 r2 t), one RGBA32F texel each.
struct GpuObjectTransform {
  float rows[3][4];
};
static_assert(sizeof(GpuObjectTransform) == 48, "three vec4 texels per object");

/// Material index of a triangle slot that holds no triangle; the vertex
/// shader places such corners outside the clip volume.
inline constexpr uint32_t kEmptyTriangleSlot = 0xffffffffu;

/// One corner of a triangle slot, as the vertex shader reads it (one
/// attribute record per corner, drawn with glDrawArrays).
struct GpuCorner {
  uint32_t vertexSlot = 0;
  uint32_t material = kEmptyTriangleSlot;
  float uv[2] = {0.0f, 0.0f};  // zero for untextured materials
};
struct GpuTriangle {
  GpuCorner corners[3];
};
static_assert(sizeof(GpuTriangle) == 48, "tightly packed corner records");

/// Triangles drawn with one texture bound. Group 0 holds untextured
/// materials; group t + 1 holds the materials that use texture t.
struct TriangleGroup {
  int32_t texture = -1;
  std::vector<GpuTriangle> slots;  // CPU mirror; the first allocator.HighWater() are meaningful
  SlotAllocator allocator;
  DirtyRanges dirty;
};

/// What the SMA said of a view's progress in its last delta.
struct ViewProgress {
  /// Renderers the SMA can send work to; nullopt from an SMA that does not say.
  std::optional<uint32_t> renderersConnected;
  uint32_t stage1Total = 0;  // samples stage 1 needed that the cache lacked
  uint32_t stage1Done = 0;
  uint32_t refinementTotal = 0;  // samples refinement's splits asked for so far
  uint32_t refinementDone = 0;
};

class MeshStore {
 public:
  /// Empties the store and sets the scene's materials: the texture index of
  /// each material (-1: none), each below `textureCount`. Called on every
  /// (re)connection, so the mesh always starts empty.
  /// `objectToWorld` has the scene's movable objects' transforms (object id
  /// i + 1 at index i) at `sceneEpoch`; empty for a static scene.
  void Reset(std::span<const int32_t> materialTextures, uint32_t textureCount,
             std::span<const RigidTransform> objectToWorld = {}, uint64_t sceneEpoch = 0);
  /// Where new vertices may lie, after Reset: index 0 the static part's
  /// world bounds (SceneInfo's), index i object i's object-space bounds (one
  /// per movable object). Every vertex the SMA makes is a corner of a scene
  /// triangle or a point between corners, so it lies inside its space's
  /// bounds; Apply refuses a new vertex farther out than 1e-3 of that box's
  /// diagonal (1e-6 at least) -- a peer's garbage or an SMA bug, which a
  /// rasterizer would otherwise be handed as a triangle kilometres wide.
  /// Reset clears them (nothing checked until set). Fails, changing nothing,
  /// on a count other than 1 + ObjectCount() or a box that is empty or not
  /// finite.
  Status SetVertexBounds(std::span<const Bounds3> spaceBounds);

  /// Applies one delta in the protocol's order: removals, then vertices, then
  /// triangles. Fails with a message naming the delta's sequence and the
  /// offending id on any violation: a sequence gap, arrays of inconsistent
  /// length, a value that is not finite, an unknown material, a removal of a
  /// triangle not held, a vertex sent while held, a triangle added while held
  /// or using a vertex not held, a vertex sent but used by no triangle, a new
  /// vertex outside its space's bounds (SetVertexBounds). After
  /// With movable objects: vertex_objects (one per new vertex, ids in
  /// range, corners of a triangle all of one object) is checked too; a
  /// MOVED delta carries only valid ids and rigid transforms (12 floats
  /// each) and no epoch older than the store's; MOVED and RESHADED carry no
  /// triangles or new vertices; a MOVED with view id 0 (sent before the
  /// SMA had this client's first view) leaves the view's progress as it
  /// was. After
  /// a failure the store is consistent (every held triangle's vertices are
  /// held and counted) but holds part of the delta; the caller drops the
  /// connection and calls Reset().
  Status Apply(const wire::Delta& delta);

  size_t TriangleCount() const { return triangles_.size(); }
  size_t VertexCount() const { return vertices_.size(); }
  bool HoldsTriangle(uint64_t id) const { return triangles_.contains(id); }
  /// How many held triangles use vertex `id`; nullopt when it is not held.
  std::optional<uint32_t> VertexRefs(uint64_t id) const;

  // --- Movable objects
  /// Movable objects of the scene (ids 1..ObjectCount()).
  uint32_t ObjectCount() const { return uint32_t(objectToWorld_.size()); }
  /// The scene epoch of the last MOVED delta (or of the SceneInfo).
  uint64_t SceneEpoch() const { return sceneEpoch_; }
  /// MOVED deltas applied since the last reset.
  uint64_t MovesApplied() const { return movesApplied_; }
  /// Object `id`'s transform as the SMA last said (id in 1..ObjectCount();
  /// 0 or out of range: the identity).
  RigidTransform ConfirmedTransform(uint32_t id) const;
  /// The transform object `id` is drawn with: a local one (SetLocalTransform)
  /// if set, else the confirmed one.
  RigidTransform DisplayedTransform(uint32_t id) const;
  /// Draws object `id` at `t` instead of where the SMA put it (a drag shown
  /// before the SMA confirms it); nullopt: back to the confirmed transform.
  /// Ignored for ids out of range.
  void SetLocalTransform(uint32_t id, const std::optional<RigidTransform>& t);
  /// The object id of held vertex `id` (0: static); nullopt when not held.
  std::optional<uint32_t> VertexObject(uint64_t id) const;
  /// World position of held vertex `id` as drawn; nullopt when not held.
  std::optional<Vec3> WorldPosition(uint64_t id) const;
  /// World position of vertex slot `slot` (< VertexSlots().size()) as drawn.
  Vec3 WorldPositionOfSlot(uint32_t slot) const;

  /// From the last applied delta (0 / false before the first).
  uint64_t LastSequence() const { return sequence_; }
  uint64_t LastViewId() const { return viewId_; }
  uint32_t PendingSamples() const { return pendingSamples_; }
  bool Converged() const { return converged_; }
  /// The SMA is refining the view: stage 1 is done, stage 2 runs.
  bool Refining() const { return refining_; }
  /// The SMA's progress report for the view (Delta fields 19-23).
  const ViewProgress& Progress() const { return progress_; }
  /// Triangles added over every delta applied since the last reset (the
  /// paper's Delta_total: what had to be sent, refined-away ones included).
  uint64_t TrianglesAdded() const { return trianglesAdded_; }

  /// MeasureLuminance (common/tonemap.h) of the held vertices' radiance,
  /// maintained incrementally: O(1) per added or removed vertex, plus a scan
  /// of the vertex slots the first time it is asked after the brightest
  /// vertex was removed.
  ViewLuminance HeldLuminance();

  // --- GPU mirror (read by the renderer, which then takes the dirty ranges)
  /// Vertex slots [0, HighWater); free slots hold zeros.
  std::span<const GpuVertex> VertexSlots() const { return {vertexSlots_.data(), vertexAllocator_.HighWater()}; }
  DirtyRanges& DirtyVertices() { return dirtyVertices_; }
  /// The transform table: entry 0 the identity, entry i object i's displayed transform.
  std::span<const GpuObjectTransform> ObjectTransforms() const { return objectSlots_; }
  /// Whether the table changed since the last call (the renderer then uploads it whole: at most
  /// kMaxClientSceneObjects * 48 bytes).
  bool TakeObjectTransformsChanged() { return std::exchange(objectsChanged_, false); }
  std::span<TriangleGroup> Groups() { return groups_; }
  std::span<const TriangleGroup> Groups() const { return groups_; }

 private:
  struct VertexRecord {
    uint32_t slot = 0;
    uint32_t refs = 0;
  };
  struct TriangleRecord {
    uint32_t group = 0;
    uint32_t slot = 0;
  };

  Status CheckShape(const wire::Delta& d) const;
  Status CheckObjects(const wire::Delta& d) const;
  Status CheckPositions(const wire::Delta& d) const;
  void ApplyMoves(const wire::Delta& d);
  void WriteObjectSlot(uint32_t id);
  Status RemoveTriangle(uint64_t id);
  Status AddVertex(const wire::Delta& d, int index);
  Status AddTriangle(const wire::Delta& d, int index, int uvIndex);
  void ReleaseVertex(uint64_t id, uint32_t slot);

  // Luminance bookkeeping (MeasureLuminance's rules: only positive values).
  void CountLuminance(float luminance);
  Status UpdateVertex(const wire::Delta& d, int i);
  void UncountLuminance(float luminance);

  std::vector<int32_t> materialTextures_;
  std::unordered_map<uint64_t, VertexRecord> vertices_;
  std::unordered_map<uint64_t, TriangleRecord> triangles_;
  std::vector<GpuVertex> vertexSlots_;
  std::vector<uint64_t> vertexSlotIds_;  // slot -> vertex id, to release a removed triangle's vertices
  SlotAllocator vertexAllocator_;
  DirtyRanges dirtyVertices_;
  std::vector<TriangleGroup> groups_;
  std::vector<RigidTransform> objectToWorld_;  // confirmed; id i + 1 at index i
  std::vector<std::optional<RigidTransform>> localTransform_;  // same indices
  std::vector<GpuObjectTransform> objectSlots_;  // 1 + ObjectCount(): the displayed transforms
  std::vector<Bounds3> vertexBounds_;  // SetVertexBounds, grown by the tolerance; empty: unchecked
  bool objectsChanged_ = true;
  uint64_t sceneEpoch_ = 0;
  uint64_t movesApplied_ = 0;

  uint64_t sequence_ = 0;
  uint64_t viewId_ = 0;
  uint32_t pendingSamples_ = 0;
  bool converged_ = false;
  bool refining_ = false;
  ViewProgress progress_;
  uint64_t trianglesAdded_ = 0;

  size_t luminanceCount_ = 0;
  double logLuminanceSum_ = 0.0;
  float maxLuminance_ = 0.0f;
  bool maxStale_ = false;  // the brightest vertex left; rescan on demand
};

}  // namespace penumbra::client
