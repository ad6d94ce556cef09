#pragma once
// Visibility from a client's camera, at the client's resolution (paper §2):
// which leaves of the hierarchy are visible and how many pixels each covers.
//
// Two steps, so that refinement never touches the acceleration structure:
//  1. VisibilityTracer::Trace casts one primary ray per pixel centre against
//     the scene's *base* triangles (Embree, packets, all cores), recording the
//     base triangle and barycentrics hit. This depends only on the camera and
//     is cached per client view.
//  2. MapHitsToNodes maps each hit to a node of the hierarchy by barycentric
//     descent (Hierarchy::Locate), following a predicate (the SMA descends
//     into a node's children once their vertices are shaded). Re-running
//     step 2 alone picks up refinement for an unchanged camera.
//
// visibility.cpp is the only SMA file that includes Embree.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "penumbra/common/camera.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/scene.h"
#include "penumbra/sma/hierarchy.h"

namespace penumbra {
class PosedEmbreeScene;
}

namespace penumbra::sma {

inline constexpr uint32_t kNoHit = ~uint32_t(0);

/// What the primary ray through one pixel centre hit.
struct PixelHit {
  uint32_t triangle = kNoHit;  // base triangle, or kNoHit for background
  float b1 = 0.0f;             // barycentrics on that triangle
  float b2 = 0.0f;
  bool backFace = false;       // the ray met the side its geometric normal points away from
};

/// Primary hits for one camera view, row-major, row 0 at the top.
struct HitBuffer {
  CameraView view;
  uint64_t epoch = 0;          // the scene epoch (pose) it was traced at
  std::vector<PixelHit> hits;  // view.width * view.height
};

/// Which plain Embree calls VisibilityTracer::TraceRaw makes.
enum class RawTrace {
  kSingleRays,  // one rtcIntersect1 per pixel, in scanline order
  kPackets,     // the rtcIntersect16 packets Trace uses, in Trace's order
};

/// The scene's base triangles in an Embree BVH, and primary rays against it.
/// Build, then query: a built tracer is read-only, and any number of threads
/// may call Trace on it at once.
class VisibilityTracer {
 public:
  /// Builds the acceleration structure over the scene's base triangles
  /// (high-quality build: it is built once and traced many times). Vertex
  /// data is copied; the scene need not outlive the tracer. Embree's errors
  /// go to the "sma.visibility" logger and come back as an Error.
  static Expected<std::unique_ptr<VisibilityTracer>> Build(const Scene& scene);
  ~VisibilityTracer();
  VisibilityTracer(const VisibilityTracer&) = delete;
  VisibilityTracer& operator=(const VisibilityTracer&) = delete;

  /// The scene at `pose` (movable objects placed by it), for Trace; built in
  /// microseconds (a top level of instances over BVHs built once).
  /// Thread-safe. Without movable objects: always the one static scene.
  Expected<std::shared_ptr<const PosedEmbreeScene>> AtPose(const ScenePose& pose) const;
  /// The scene as loaded (epoch 0).
  std::shared_ptr<const PosedEmbreeScene> Initial() const;

  /// Casts a ray through every pixel centre of `view` (PinholeCamera
  /// conventions) and fills `out` (resized to width * height; its storage is
  /// reused from call to call). Rays start at the eye, with no near plane,
  /// and hit both faces of every triangle. The view must have passed
  /// ValidateCameraView. Thread-safe; runs on the TBB threads of the calling
  /// thread's arena. When `cancel` becomes true (looked at per tile) it
  /// returns early, `out` half-filled: the caller drops it.
  /// Hits name base triangles (object triangles too: their barycentrics are
  /// the same in object and world space) and the side met, decided against
  /// the triangle's world normal at `posed`'s pose; `out.epoch` is its epoch.
  /// Null `posed`: the scene as loaded.
  void Trace(const CameraView& view, HitBuffer& out, const std::atomic<bool>* cancel = nullptr,
             const PosedEmbreeScene* posed = nullptr) const;

  /// For benchmarks only: Trace's rays for `view`, traced on the calling
  /// thread by plain Embree calls that record nothing but whether they hit.
  /// Returns the number of rays that hit. Thread-safe.
  size_t TraceRaw(const CameraView& view, RawTrace mode) const;

  struct Impl;

 private:
  explicit VisibilityTracer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// The nodes seen through a camera: per pixel, and as a list with coverage.
struct VisibleSet {
  std::vector<NodeId> pixelNode;  // per pixel, kNoNode for background
  /// Every visible node once, with the number of pixels it covers, in
  /// increasing NodeId order.
  std::vector<NodeId> nodes;
  std::vector<uint32_t> coverage;  // parallel to `nodes`
  /// Hierarchy::StructureGeneration() when mapped: node ids are valid while
  /// it is the hierarchy's (a collection since may have freed them).
  uint64_t structureGeneration = 0;
  /// Set by RemapHitsToNodes: every pixel kept its node from `previous` (so
  /// `nodes` and `coverage` are previous's too). False from MapHitsToNodes.
  bool sameAsPrevious = false;
};

/// Maps every hit to the deepest node reachable from the root of the side of
/// its base triangle that the ray met, while `descend(node)` is true: the
/// node Hierarchy::Locate returns, exactly. `descend` is asked only about nodes with children, and not
/// necessarily once per pixel (a hit well inside the node its neighbour went
/// to goes there too). It is called concurrently from TBB threads and must be
/// thread-safe (read-only). The caller keeps the hierarchy unchanged
/// meanwhile (the SMA holds its state lock shared). `hierarchy` must be built
/// on the scene `hits` was traced in. `out`'s storage is reused from call to
/// call. When `cancel` becomes true (looked at per band of rows) it returns
/// early with `out` incomplete: the caller drops it.
using DescendFunction = bool (*)(const Node& node, const void* context);
void MapHitsToNodes(const Hierarchy& hierarchy, const HitBuffer& hits, DescendFunction descend,
                    const void* context, VisibleSet& out, const std::atomic<bool>* cancel = nullptr);

/// MapHitsToNodes again, for the same `hits`, starting from `previous` (a
/// complete mapping of these hits, not `out`): a pixel keeps its previous
/// node when that node is a leaf or `descend` refuses it, and only the other
/// pixels are located from their root. The result equals a mapping from
/// scratch provided `descend` only ever turned from false to true for the
/// nodes above the previous ones since `previous` was made, and no node was
/// freed: the SMA's ChildrenShaded between collections (samples are only
/// added, a move's invalidated ones still count as awaiting re-shading) --
/// a refresh, which re-maps a view every time new samples may complete a
/// node's children, then costs a look at each pixel's node instead of a
/// descent from its root. When `previous` was made at another
/// StructureGeneration() or for another view size, this is MapHitsToNodes.
void RemapHitsToNodes(const Hierarchy& hierarchy, const HitBuffer& hits, DescendFunction descend,
                      const void* context, const VisibleSet& previous, VisibleSet& out,
                      const std::atomic<bool>* cancel = nullptr);

}  // namespace penumbra::sma
