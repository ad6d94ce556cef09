// Visibility: primary rays against the base triangles (the SMA's one contact
// with Embree), then hits mapped to hierarchy nodes.
//
// Trace cuts the image into square tiles that TBB spreads over its threads;
// a tile is traced as 4x4-pixel packets with rtcIntersect16. Sixteen rays
// from one eye through a 4x4 block are as coherent as rays get, which is what
// Embree's packet traversal (and the coherent context flag) is built for.
//
// MapHitsToNodes walks the hits row by row on TBB threads, locating each in
// the hierarchy and counting runs of equal nodes along the row, folded
// together across nearby rows; the runs, far fewer than pixels, are then
// sorted by node and summed into coverage.

#include "penumbra/sma/visibility.h"

#include <embree3/rtcore.h>
#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <xmmintrin.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>
#include <utility>

#include "penumbra/common/check.h"
#include "penumbra/common/embree_scene.h"
#include "penumbra/common/fork_join_annotation.h"
#include "penumbra/common/logging.h"

namespace penumbra::sma {

namespace {

constexpr int kPacketSide = 4;                         // rtcIntersect16: 4x4 pixels
constexpr int kPacketSize = kPacketSide * kPacketSide;
constexpr int kTileSide = 32;                          // pixels; ~900 tasks at 1280x720

std::shared_ptr<spdlog::logger> VisibilityLog() { return Logger("sma.visibility"); }

// Embree asks for flush-to-zero and denormals-are-zero on every thread that
// traces. TBB's threads also run the rest of the SMA, so a task sets the two
// MXCSR bits for its own duration and then puts the register back: two
// register writes per task of a few tiles.
class ScopedFlushToZero {
 public:
  ScopedFlushToZero() : saved_(_mm_getcsr()) { _mm_setcsr(saved_ | kFlushToZero | kDenormalsAreZero); }
  ~ScopedFlushToZero() { _mm_setcsr(saved_); }
  ScopedFlushToZero(const ScopedFlushToZero&) = delete;
  ScopedFlushToZero& operator=(const ScopedFlushToZero&) = delete;

 private:
  static constexpr unsigned kFlushToZero = 0x8000;      // _MM_FLUSH_ZERO_ON
  static constexpr unsigned kDenormalsAreZero = 0x0040;  // _MM_DENORMALS_ZERO_ON
  unsigned saved_;
};

RTCIntersectContext CoherentContext() {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  return context;
}

// The primary rays of a view. PinholeCamera is the one definition of the
// camera; its directions, rescaled to a unit component along the view axis,
// are affine in the pixel position, so three of them give every ray as
// corner + px * perPixelX + py * perPixelY, with no normalisation per pixel
// (Embree takes directions of any length).
struct PrimaryRays {
  Vec3 origin;
  Vec3 corner, perPixelX, perPixelY;

  explicit PrimaryRays(const CameraView& view) {
    const PinholeCamera camera(view);
    const auto onImagePlane = [&](float px, float py) {
      const Vec3 d = camera.DirectionThrough(px, py);
      return d / glm::dot(d, camera.Forward());
    };
    origin = camera.Origin();
    corner = onImagePlane(0.0f, 0.0f);
    perPixelX = (onImagePlane(float(view.width), 0.0f) - corner) / float(view.width);
    perPixelY = (onImagePlane(0.0f, float(view.height)) - corner) / float(view.height);
  }

  Vec3 ThroughPixel(int x, int y) const {
    return corner + (float(x) + 0.5f) * perPixelX + (float(y) + 0.5f) * perPixelY;
  }
};

// The image cut into kTileSide-square tiles, row-major; edge tiles are cut
// short.
struct Tiling {
  int width, height, columns, rows;

  Tiling(int w, int h)
      : width(w), height(h), columns((w + kTileSide - 1) / kTileSide), rows((h + kTileSide - 1) / kTileSide) {}
  int Count() const { return columns * rows; }

  // Calls f(x0, y0) for the top-left pixel of each packet of tile `tile`.
  template <class F>
  void ForEachPacket(int tile, F&& f) const {
    const int tileX = (tile % columns) * kTileSide, tileY = (tile / columns) * kTileSide;
    const int endX = std::min(tileX + kTileSide, width), endY = std::min(tileY + kTileSide, height);
    for (int y0 = tileY; y0 < endY; y0 += kPacketSide)
      for (int x0 = tileX; x0 < endX; x0 += kPacketSide) f(x0, y0);
  }
};

constexpr int LaneX(int lane) { return lane % kPacketSide; }
constexpr int LaneY(int lane) { return lane / kPacketSide; }

// One packet of primary rays: the 4x4 pixels from (x0, y0), lanes outside the
// image masked off.
struct Packet {
  alignas(64) std::array<int, kPacketSize> valid;
  RTCRayHit16 rayHit;  // Embree declares it 64-byte aligned

  void Trace(RTCScene scene, RTCIntersectContext& context, const PrimaryRays& rays, int width, int height, int x0,
             int y0) {
    for (int lane = 0; lane < kPacketSize; ++lane) {
      const int x = x0 + LaneX(lane), y = y0 + LaneY(lane);
      valid[lane] = x < width && y < height ? -1 : 0;
      const Vec3 d = rays.ThroughPixel(x, y);
      rayHit.ray.org_x[lane] = rays.origin.x;
      rayHit.ray.org_y[lane] = rays.origin.y;
      rayHit.ray.org_z[lane] = rays.origin.z;
      rayHit.ray.tnear[lane] = 0.0f;  // from the eye: no near plane
      rayHit.ray.dir_x[lane] = d.x;
      rayHit.ray.dir_y[lane] = d.y;
      rayHit.ray.dir_z[lane] = d.z;
      rayHit.ray.time[lane] = 0.0f;
      rayHit.ray.tfar[lane] = std::numeric_limits<float>::infinity();
      rayHit.ray.mask[lane] = ~0u;
      rayHit.ray.id[lane] = 0;
      rayHit.ray.flags[lane] = 0;
      rayHit.hit.geomID[lane] = RTC_INVALID_GEOMETRY_ID;
      rayHit.hit.instID[0][lane] = RTC_INVALID_GEOMETRY_ID;
    }
    rtcIntersect16(valid.data(), scene, &context, &rayHit);
  }

  bool Hit(int lane) const { return rayHit.hit.geomID[lane] != RTC_INVALID_GEOMETRY_ID; }
};

}  // namespace

struct VisibilityTracer::Impl {
  std::unique_ptr<EmbreeScene> embree;
  RTCScene Handle() const { return embree->Initial()->Handle(); }  // TraceRaw's queries: the scene as loaded
  // Per base triangle, its geometric normal (counter-clockwise front): which
  // side a ray meets decides which of the hierarchy's roots it sees. Ours,
  // not Embree's Ng, so that "front" means one thing in every tier. In
  // object space: a movable object's are turned into the world by the pose
  // (PosedEmbreeScene::WorldNormal) before they meet a ray.
  std::vector<Vec3> faceNormals;
};

Expected<std::unique_ptr<VisibilityTracer>> VisibilityTracer::Build(const Scene& scene) {
  // Not robust, unlike the renderer (which must not leak light through
  // shared edges): robust traversal makes Trace ~45% slower on Sponza and
  // raised the 32-client cached view -> first delta p99 (docs/performance.md),
  // and the one-pixel "cracks" it was tried against were a surface shaded
  // black, not holes (ClientTest.RefinedViewsHaveNoCracksAlongSharedEdges
  // now reads the screenshot's coverage). A ray slipping through an edge
  // gives one pixel to the surface behind.
  auto embree = EmbreeScene::Build(scene, EmbreeSceneOptions{.logger = "sma.visibility", .robust = false});
  if (!embree) return embree.error();
  auto impl = std::make_unique<Impl>();
  impl->embree = std::move(*embree);
  impl->faceNormals.resize(scene.triangles.size());
  for (uint32_t t = 0; t < scene.triangles.size(); ++t) impl->faceNormals[t] = scene.GeometricNormal(t);
  VisibilityLog()->debug("BVH over {} base triangles built", scene.triangles.size());
  return std::unique_ptr<VisibilityTracer>(new VisibilityTracer(std::move(impl)));
}

VisibilityTracer::VisibilityTracer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
VisibilityTracer::~VisibilityTracer() = default;

Expected<std::shared_ptr<const PosedEmbreeScene>> VisibilityTracer::AtPose(const ScenePose& pose) const {
  return impl_->embree->AtPose(pose);
}

std::shared_ptr<const PosedEmbreeScene> VisibilityTracer::Initial() const { return impl_->embree->Initial(); }

void VisibilityTracer::Trace(const CameraView& view, HitBuffer& out, const std::atomic<bool>* cancel,
                             const PosedEmbreeScene* posedScene) const {
  const int width = view.width, height = view.height;
  // Kept alive by the caller (or by the EmbreeScene, for the initial pose)
  // for the whole trace.
  const PosedEmbreeScene& posed = posedScene ? *posedScene : *impl_->embree->Initial();
  const RTCScene scene = posed.Handle();
  out.view = view;
  out.epoch = posed.Pose().epoch;
  out.hits.resize(size_t(width) * size_t(height));
  const PrimaryRays rays(view);
  const Tiling tiling(width, height);
  ForkJoinAnnotation order;  // TBB's hand-offs, for ThreadSanitizer
  order.Fork();
  tbb::parallel_for(tbb::blocked_range<int>(0, tiling.Count()), [&](const tbb::blocked_range<int>& tiles) {
    order.Enter();
    const ScopedFlushToZero flushToZero;
    RTCIntersectContext context = CoherentContext();
    Packet packet;
    for (int tile = tiles.begin(); tile != tiles.end(); ++tile) {
      // A big view takes seconds; a shutdown should not wait for it.
      if (cancel && cancel->load(std::memory_order_relaxed)) break;
      tiling.ForEachPacket(tile, [&](int x0, int y0) {
        packet.Trace(scene, context, rays, width, height, x0, y0);
        for (int lane = 0; lane < kPacketSize; ++lane) {
          if (!packet.valid[lane]) continue;
          PixelHit& hit = out.hits[size_t(y0 + LaneY(lane)) * size_t(width) + size_t(x0 + LaneX(lane))];
          if (!packet.Hit(lane)) {
            hit = PixelHit{};
            continue;
          }
          const unsigned instance = packet.rayHit.hit.instID[0][lane];
          const uint32_t triangle = posed.Triangle(instance, packet.rayHit.hit.primID[lane]);
          // The side met is decided in the world: an object's normal turns with it.
          const Vec3 n = posed.WorldNormal(instance, impl_->faceNormals[triangle]);
          const float towardNormal = packet.rayHit.ray.dir_x[lane] * n.x + packet.rayHit.ray.dir_y[lane] * n.y +
                                     packet.rayHit.ray.dir_z[lane] * n.z;
          hit = PixelHit{triangle, packet.rayHit.hit.u[lane], packet.rayHit.hit.v[lane], towardNormal > 0.0f};
        }
      });
    }
    order.Leave();
  });
  order.Join();
}

size_t VisibilityTracer::TraceRaw(const CameraView& view, RawTrace mode) const {
  const ScopedFlushToZero flushToZero;
  RTCIntersectContext context = CoherentContext();
  const PrimaryRays rays(view);
  size_t hits = 0;
  if (mode == RawTrace::kSingleRays) {
    for (int y = 0; y < view.height; ++y) {
      for (int x = 0; x < view.width; ++x) {
        const Vec3 d = rays.ThroughPixel(x, y);
        RTCRayHit rayHit;
        rayHit.ray = RTCRay{rays.origin.x, rays.origin.y, rays.origin.z, 0.0f, d.x, d.y, d.z, 0.0f,
                            std::numeric_limits<float>::infinity(), ~0u, 0, 0};
        rayHit.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rayHit.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        rtcIntersect1(impl_->Handle(), &context, &rayHit);
        hits += rayHit.hit.geomID != RTC_INVALID_GEOMETRY_ID;
      }
    }
    return hits;
  }
  const Tiling tiling(view.width, view.height);
  Packet packet;
  for (int tile = 0; tile < tiling.Count(); ++tile) {
    tiling.ForEachPacket(tile, [&](int x0, int y0) {
      packet.Trace(impl_->Handle(), context, rays, view.width, view.height, x0, y0);
      for (int lane = 0; lane < kPacketSize; ++lane) hits += packet.valid[lane] && packet.Hit(lane);
    });
  }
  return hits;
}

// --- Mapping hits to nodes ---------------------------------------------------

namespace {

// Hierarchy::Locate with a memory of the node it returned last. A hit on the
// same base triangle that lies well inside that node goes to it without the
// descent: coherent primary rays make that most pixels, and it saves the
// descent's unpredictable branches and its predicate calls.
//
// "Well inside" keeps the answer exactly Locate's. Locate's barycentrics
// start about an ulp off and every level doubles their error in the child's
// coordinates, so its choice near a node's edges is certain only beyond
// ~2^depth ulps of the node's own barycentrics. The margin, 2^depth * 1e-5
// there (1e-5 of the base triangle), is two orders of magnitude beyond.
class NodeFinder {
 public:
  NodeFinder(const Hierarchy& hierarchy, DescendFunction descend, const void* context)
      : hierarchy_(hierarchy), descend_(descend), context_(context) {}

  NodeId Find(const PixelHit& hit) {
    if (hit.triangle == triangle_ && hit.backFace == backFace_ && (wholeTriangle_ || WellInside(hit.b1, hit.b2)))
      return node_;
    PENUMBRA_CHECK(hit.triangle < hierarchy_.BaseTriangleCount(),
                   fmt::format("hit on base triangle {}, but the hierarchy has {}", hit.triangle,
                               hierarchy_.BaseTriangleCount()));
    node_ = hierarchy_.Locate(hit.triangle, hit.backFace, hit.b1, hit.b2,
                              [this](const Node& n) { return descend_(n, context_); });
    triangle_ = hit.triangle;
    backFace_ = hit.backFace;
    const Node& n = hierarchy_.GetNode(node_);
    wholeTriangle_ = n.depth == 0;
    if (!wholeTriangle_) Remember(n);
    return node_;
  }

 private:
  static constexpr float kMarginOfBaseTriangle = 1e-5f;

  // Prepares WellInside for node `n`: its barycentrics (l1, l2) are the
  // inverse of the map l -> bary[0] + l1 (bary[1] - bary[0]) + l2 (bary[2] - bary[0]).
  void Remember(const Node& n) {
    const Vec2 e1 = n.bary[1] - n.bary[0], e2 = n.bary[2] - n.bary[0];
    const float invDet = 1.0f / (e1.x * e2.y - e1.y * e2.x);
    origin_ = n.bary[0];
    inverse_ = {e2.y * invDet, -e2.x * invDet, -e1.y * invDet, e1.x * invDet};
    margin_ = std::ldexp(kMarginOfBaseTriangle, n.depth);
  }

  bool WellInside(float b1, float b2) const {
    const float dx = b1 - origin_.x, dy = b2 - origin_.y;
    const float l1 = inverse_[0] * dx + inverse_[1] * dy;
    const float l2 = inverse_[2] * dx + inverse_[3] * dy;
    return l1 > margin_ && l2 > margin_ && 1.0f - l1 - l2 > margin_;
  }

  const Hierarchy& hierarchy_;
  DescendFunction descend_;
  const void* context_;
  uint32_t triangle_ = kNoHit;  // the last hit's base triangle, side and node
  bool backFace_ = false;
  NodeId node_ = kNoNode;
  bool wholeTriangle_ = false;  // node_ is the root: every hit on triangle_ goes there
  Vec2 origin_{0.0f};
  std::array<float, 4> inverse_{};
  float margin_ = 0.0f;
};

// Pixels that map to one node.
struct Run {
  NodeId node;
  uint32_t pixels;
};

constexpr int kRowsPerChunk = 16;  // rows per unit of work (and per run list)

// Sums the runs of a chunk's rows before they reach the sort. A node's runs
// in neighbouring rows come a row apart, so a small direct-mapped table
// catches most of them; a run that evicts another just passes the evicted
// one on, to be summed after the sort.
class RunFolder {
 public:
  RunFolder() { slots_.fill(Run{kNoNode, 0}); }

  void Add(const Run& run, std::vector<Run>& out) {
    Run& slot = slots_[run.node % kSlots];
    if (slot.node == run.node) {
      slot.pixels += run.pixels;
      return;
    }
    if (slot.node != kNoNode) out.push_back(slot);
    slot = run;
  }

  void Flush(std::vector<Run>& out) {
    for (Run& slot : slots_) {
      if (slot.node != kNoNode) out.push_back(slot);
      slot = Run{kNoNode, 0};
    }
  }

 private:
  static constexpr size_t kSlots = 2048;  // 16 KiB: stays in L1
  std::array<Run, kSlots> slots_;
};

// Sorts runs by node with a least-significant-digit radix sort over the bits
// that ids below `nodeCount` use: linear in the number of runs, whatever the
// size of the hierarchy.
void SortByNode(std::vector<Run>& runs, std::vector<Run>& scratch, size_t nodeCount) {
  constexpr int kDigitBits = 11;
  constexpr uint32_t kDigitMask = (1u << kDigitBits) - 1;
  const int keyBits = std::bit_width(nodeCount);
  scratch.resize(runs.size());
  for (int shift = 0; shift < keyBits; shift += kDigitBits) {
    std::array<uint32_t, size_t(1) << kDigitBits> next{};
    for (const Run& r : runs) ++next[(r.node >> shift) & kDigitMask];
    uint32_t sum = 0;
    for (uint32_t& n : next) sum += std::exchange(n, sum);
    for (const Run& r : runs) scratch[next[(r.node >> shift) & kDigitMask]++] = r;
    runs.swap(scratch);
  }
}

}  // namespace

namespace {

// `previous`: null, or a mapping of the same hits at the hierarchy's
// structure generation (RemapHitsToNodes).
void MapHits(const Hierarchy& hierarchy, const HitBuffer& hits, DescendFunction descend, const void* context,
             const VisibleSet* previous, VisibleSet& out, const std::atomic<bool>* cancel) {
  const size_t width = size_t(hits.view.width);
  const int height = hits.view.height;
  PENUMBRA_CHECK(hits.hits.size() == width * size_t(height),
                 fmt::format("{} hits for a {}x{} view", hits.hits.size(), width, height));
  PENUMBRA_CHECK(previous != &out, "RemapHitsToNodes: `previous` and `out` must be different sets");
  out.pixelNode.resize(hits.hits.size());
  out.structureGeneration = hierarchy.StructureGeneration();

  const int chunkCount = (height + kRowsPerChunk - 1) / kRowsPerChunk;
  std::vector<std::vector<Run>> runsOfChunk(static_cast<size_t>(chunkCount));
  // The tasks read the hierarchy and, through `descend`, whatever the caller
  // guards with its lock: TBB's hand-offs must be visible to ThreadSanitizer.
  std::atomic<bool> anyChanged{false};  // a pixel's node differs from previous's
  ForkJoinAnnotation order;
  order.Fork();
  tbb::parallel_for(tbb::blocked_range<int>(0, chunkCount), [&](const tbb::blocked_range<int>& chunks) {
    order.Enter();
    NodeFinder finder(hierarchy, descend, context);
    RunFolder folder;
    NodeId kept = kNoNode;  // the last previous node found to stay (runs of pixels share it)
    bool changed = false;
    for (int chunk = chunks.begin(); chunk != chunks.end(); ++chunk) {
      if (cancel && cancel->load(std::memory_order_relaxed)) break;
      std::vector<Run>& runs = runsOfChunk[size_t(chunk)];
      const int endY = std::min(height, (chunk + 1) * kRowsPerChunk);
      for (int y = chunk * kRowsPerChunk; y < endY; ++y) {
        const PixelHit* rowHits = hits.hits.data() + size_t(y) * width;
        NodeId* rowNodes = out.pixelNode.data() + size_t(y) * width;
        const NodeId* rowBefore = previous ? previous->pixelNode.data() + size_t(y) * width : nullptr;
        Run run{kNoNode, 0};
        for (size_t x = 0; x < width; ++x) {
          NodeId node = kNoNode;
          if (rowHits[x].triangle == kNoHit) {
            node = kNoNode;
          } else if (rowBefore && rowBefore[x] != kNoNode &&
                     (rowBefore[x] == kept || [&] {
                       const Node& n = hierarchy.GetNode(rowBefore[x]);
                       return n.IsLeaf() || !descend(n, context);
                     }())) {
            // The descent from the root passes through the previous node
            // (everything above it still descends) and stops there.
            node = kept = rowBefore[x];
          } else {
            node = finder.Find(rowHits[x]);
            changed = changed || !rowBefore || node != rowBefore[x];
          }
          rowNodes[x] = node;
          if (node != run.node) {
            if (run.node != kNoNode) folder.Add(run, runs);
            run = {node, 0};
          }
          ++run.pixels;
        }
        if (run.node != kNoNode) folder.Add(run, runs);
      }
      folder.Flush(runs);
    }
    if (changed) anyChanged.store(true, std::memory_order_relaxed);
    order.Leave();
  });
  order.Join();
  out.sameAsPrevious = false;
  if (cancel && cancel->load()) {
    out.nodes.clear();
    out.coverage.clear();
    return;
  }
  if (previous && !anyChanged.load(std::memory_order_relaxed)) {
    out.nodes = previous->nodes;
    out.coverage = previous->coverage;
    out.sameAsPrevious = true;
    return;
  }

  std::vector<Run> runs, scratch;
  size_t runCount = 0;
  for (const auto& r : runsOfChunk) runCount += r.size();
  runs.reserve(runCount);
  for (const auto& r : runsOfChunk) runs.insert(runs.end(), r.begin(), r.end());
  SortByNode(runs, scratch, hierarchy.NodeCount());

  out.nodes.clear();
  out.coverage.clear();
  for (const Run& r : runs) {
    if (!out.nodes.empty() && out.nodes.back() == r.node) {
      out.coverage.back() += r.pixels;
    } else {
      out.nodes.push_back(r.node);
      out.coverage.push_back(r.pixels);
    }
  }
}

}  // namespace

void MapHitsToNodes(const Hierarchy& hierarchy, const HitBuffer& hits, DescendFunction descend, const void* context,
                    VisibleSet& out, const std::atomic<bool>* cancel) {
  MapHits(hierarchy, hits, descend, context, nullptr, out, cancel);
}

void RemapHitsToNodes(const Hierarchy& hierarchy, const HitBuffer& hits, DescendFunction descend,
                      const void* context, const VisibleSet& previous, VisibleSet& out,
                      const std::atomic<bool>* cancel) {
  const bool usable = previous.structureGeneration == hierarchy.StructureGeneration() &&
                      previous.pixelNode.size() == hits.hits.size() && !previous.nodes.empty();
  MapHits(hierarchy, hits, descend, context, usable ? &previous : nullptr, out, cancel);
}

}  // namespace penumbra::sma
